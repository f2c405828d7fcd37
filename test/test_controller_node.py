"""
The controller node against the real simulation node, in-process over real DDS.

Each test gets a fresh rclpy Context (fixture ``ros``) holding the simulation
node (``sorter_sim``, as fast as possible in small slices), the controller
(``sorter_controller`` on the simulation clock, reading the cell's geometry from
the simulation node's parameters) and a watcher node that plays the warehouse
and the maintenance engineer: it inducts parcels, sends routing updates, forces
sensors (the controller's sensor topic remapped to one the watcher drives) and
withholds a service (a stand-in server that stops answering). Outcomes are the
cell's ground truth on ``sort/outcomes``; the controller's state and diagnostics
come from its ``diagnostics`` topic.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Bool, String
from std_srvs.srv import SetBool, Trigger

from sorter_control.node import ControllerNode
from sorter_ros.interface import EVENT_QOS, SENSOR_QOS, STREAM_QOS
from sorter_sim.frontends.node import SimNode

pytestmark = pytest.mark.ros

# as fast as possible, in 5 ms slices the executor interleaves with the controller: it sees
# the cell within a slice of simulated time however loaded the machine is
CELL = {
    "time_mode": "fast",
    "fast_slice": 0.005,
    "arrival": "none",
    "induct_x": -2.4,
    "pose_rate_hz": 50.0,
    "parcel_phi0_deg": [0.0, 0.0],
    "parcel_y0": [0.0, 0.0],
}
ROUTING = ["A*=left", "B*=right", "C*=straight"]
CONTROLLER = {
    "use_sim_time": True,
    "routing.rules": ROUTING,
    "diagnostics_period": 0.2,
    "service_timeout": 0.3,
    "timing_margin": 0.03,
}


def routed(label: str) -> str:
    return {"A": "left", "B": "right", "C": "straight"}.get(label[:1], "straight")


class Cell:
    """The simulation node, the controller and a watcher in one context."""

    def __init__(self, ros, sim=None, ctl=None, remaps=()):
        self.ros = ros
        self.sim = ros.add(
            SimNode(
                context=ros.context,
                parameter_overrides=[
                    Parameter(k, value=v) for k, v in {**CELL, **(sim or {})}.items()
                ],
            )
        )
        cli = ["--ros-args"] + [a for r in remaps for a in ("-r", r)] if remaps else None
        self.ctl = ros.add(
            ControllerNode(
                context=ros.context,
                cli_args=cli,
                parameter_overrides=[
                    Parameter(k, value=v) for k, v in {**CONTROLLER, **(ctl or {})}.items()
                ],
            )
        )
        self.w = ros.make_node("watcher")
        self.outcomes: list[dict] = []
        self.confirmations: list[dict] = []
        self.labels: list[str] = []
        self.status = None  # the controller's latest DiagnosticStatus
        self.cell_status = None
        w = self.w
        w.create_subscription(
            DiagnosticStatus,
            "sort/outcomes",
            lambda m: self.outcomes.append(_values(m)),
            EVENT_QOS,
        )
        w.create_subscription(
            DiagnosticStatus,
            "sort/confirmations",
            lambda m: self.confirmations.append(_values(m)),
            EVENT_QOS,
        )
        w.create_subscription(
            String, "scanner/label", lambda m: self.labels.append(m.data), EVENT_QOS
        )
        w.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, STREAM_QOS)
        self.induct_pub = w.create_publisher(DiagnosticStatus, "parcels/induct", EVENT_QOS)
        self.route_pub = w.create_publisher(KeyValue, "routing/updates", EVENT_QOS)
        ros.spin_until(
            lambda: self.ctl.logic is not None, 15.0, "the controller to read the cell and start"
        )
        ros.spin_until(
            lambda: self.status is not None and self.status.message == "running",
            10.0,
            "the controller's diagnostics",
        )
        ros.spin_until_matched()  # its sensors' first edges must reach the controller

    def _on_diag(self, msg):
        for st in msg.status:
            if st.name.endswith(": controller"):
                self.status = st
            elif st.name.endswith(": cell"):
                self.cell_status = st

    @property
    def state(self) -> str:
        return _values(self.status)["state"] if self.status is not None else "none"

    def value(self, key: str) -> str:
        return _values(self.status)[key]

    def induct(self, label: str, A: float = 0.4, B: float = 0.3) -> None:
        self.induct_pub.publish(
            DiagnosticStatus(
                values=[
                    KeyValue(key="label", value=label),
                    KeyValue(key="A", value=str(A)),
                    KeyValue(key="B", value=str(B)),
                ]
            )
        )

    def outcome(self, label: str):
        return next((o for o in self.outcomes if o["label"] == label), None)

    def confirmation(self, label: str):
        return next((c for c in self.confirmations if c["label"] == label), None)

    def wait_state(self, state: str, timeout: float = 10.0) -> None:
        self.ros.spin_until(
            lambda: self.state == state, timeout, f"controller state {state} (now {self.state})"
        )

    def start_stream(self) -> None:
        """Switch the cell's parcel stream on (over its set_parameters service)."""
        r = self.call(
            SetParameters,
            "sorter_sim/set_parameters",
            SetParameters.Request(
                parameters=[
                    ParameterMsg(
                        name="arrival",
                        value=ParameterValue(
                            type=ParameterType.PARAMETER_STRING, string_value="gap"
                        ),
                    )
                ]
            ),
        )
        assert r.results[0].successful, r.results[0].reason

    def call(self, srv_type, name: str, request):
        client = self.w.create_client(srv_type, name)
        return self.ros.call(client, request)


def _values(msg) -> dict:
    return {kv.key: kv.value for kv in msg.values}


def _popups(ctl):
    return [e for e in ctl.command_log if e[0] == "popup"]


# --------------------------------------------------------------------------- sorting


def test_mixed_stream_with_routing_table_has_zero_mis_sorts(ros):
    labels = ["A", "B", "C", "A", "D", "B", "A", "A", "C", "B"]
    cell = Cell(
        ros,
        sim={
            "arrival_gap": [1.6, 1.9],
            "labels": labels,
            "parcel_A": [0.3, 0.5],
            "parcel_B": [0.2, 0.35],
        },
    )
    cell.start_stream()
    n = 8
    ros.spin_until(lambda: len(cell.outcomes) >= n, 40.0, f"{n} parcels to leave the cell")
    for o in cell.outcomes[:n]:
        assert o["exit"] == routed(o["label"]), o
    ros.spin_until(
        lambda: all(cell.confirmation(o["label"]) for o in cell.outcomes[:n]),
        5.0,
        "a confirmation for every parcel out",
    )
    for o in cell.outcomes[:n]:
        c = cell.confirmation(o["label"])
        assert c["destination_reached"] == o["exit"] == c["destination_asked"]
        assert c["result"] == ("rejected" if o["label"].startswith("D") else "sorted")
    assert {o["exit"] for o in cell.outcomes[:n]} == {"left", "right", "straight"}
    assert cell.state == "running" and cell.value("mis_sorted") == "0"


def test_routing_update_after_the_scan_changes_the_destination(ros):
    cell = Cell(ros)
    cell.induct("Q17")  # no rule: the reject destination, straight
    ros.spin_until(lambda: "Q17" in cell.labels, 10.0, "the scanner to read Q17")
    cell.route_pub.publish(KeyValue(key="Q17", value="left"))
    ros.spin_until(lambda: cell.outcome("Q17") is not None, 10.0, "Q17 to leave the cell")
    assert cell.outcome("Q17")["exit"] == "left"
    ros.spin_until(lambda: cell.confirmation("Q17") is not None, 5.0, "Q17's confirmation")
    c = cell.confirmation("Q17")
    assert (c["destination_asked"], c["destination_reached"], c["result"]) == (
        "left",
        "left",
        "sorted",
    )
    # one truth: the parameter shows the live table, as another tool reads it
    client = cell.w.create_client(GetParameters, "/sorter_controller/get_parameters")

    def rules():
        reply = ros.call(client, GetParameters.Request(names=["routing.rules"]))
        return list(reply.values[0].string_array_value)

    assert rules() == ["Q17=left"] + ROUTING  # exact labels first, then the prefixes
    # removing a rule that does not exist, or a pattern outside the grammar: refused, counted
    cell.route_pub.publish(KeyValue(key="Q99", value=""))
    cell.route_pub.publish(KeyValue(key="D;1", value="left"))
    ros.spin_until(
        lambda: int(cell.value("routing_rejected")) >= 2, 5.0, "two refused routing updates"
    )
    assert "Q17=left" in rules() and not any(r.startswith(("Q99", "D;1")) for r in rules())
    # a removal that exists changes the parameter back
    cell.route_pub.publish(KeyValue(key="Q17", value=""))
    ros.spin_until(lambda: "Q17=left" not in rules(), 5.0, "the parameter to drop Q17")


def test_too_short_gap_is_sent_straight_and_flagged(ros):
    cell = Cell(
        ros,
        sim={
            "arrival_gap": [0.5, 0.5],
            "labels": ["A", "B"],
            "parcel_A": [0.4, 0.4],
            "parcel_B": [0.3, 0.3],
        },
    )
    cell.start_stream()
    ros.spin_until(lambda: len(cell.outcomes) >= 6, 30.0, "6 parcels to leave the cell")
    ros.spin_until(
        lambda: all(cell.confirmation(o["label"]) for o in cell.outcomes[:6]),
        5.0,
        "their confirmations",
    )
    flagged = 0
    for o in cell.outcomes[:6]:
        c = cell.confirmation(o["label"])
        if c["result"] == "gap_too_short":
            flagged += 1
            assert o["exit"] == "straight" and c["destination_reached"] == "straight"
            assert c["destination_asked"] == routed(o["label"])
        else:
            assert o["exit"] == c["destination_asked"] == routed(o["label"])
    assert flagged >= 4
    assert all(o["exit"] != "jammed" for o in cell.outcomes)
    assert int(cell.value("gap_too_short")) >= 4 and cell.value("mis_sorted") == "0"


# --------------------------------------------------------------------------- faults


def test_jam_photo_eye_blocked_too_long(ros):
    cell = Cell(ros, remaps=["sensors/pe_divert:=forced/pe_divert"])
    forced = cell.w.create_publisher(Bool, "forced/pe_divert", SENSOR_QOS)
    held = []

    def relay(msg):  # pass the eye through until it blocks, then hold it blocked
        if held:
            return
        forced.publish(Bool(data=msg.data))
        if msg.data:
            held.append(True)

    cell.w.create_subscription(Bool, "sensors/pe_divert", relay, SENSOR_QOS)
    cell.induct("C1")
    cell.wait_state("jam", 15.0)
    assert "pe_divert" in cell.status.message and "blocked for" in cell.status.message
    assert cell.status.level == DiagnosticStatus.ERROR and cell.value("fault_jam") == "1"
    # the controller stopped the belt through the cell's e-stop
    ros.spin_until(
        lambda: cell.cell_status is not None and _values(cell.cell_status)["estop"] == "true",
        5.0,
        "the cell's e-stop",
    )
    assert not any(e[1] is True for e in _popups(cell.ctl))


def test_stuck_on_photo_eye(ros):
    cell = Cell(ros, remaps=["sensors/pe_divert:=forced/pe_divert"])
    forced = cell.w.create_publisher(Bool, "forced/pe_divert", SENSOR_QOS)
    forced.publish(Bool(data=True))
    cell.wait_state("stuck_on", 10.0)
    assert "no parcel due" in cell.status.message and cell.value("fault_stuck_on") == "1"


def test_stuck_off_photo_eye(ros):
    cell = Cell(ros, remaps=["sensors/pe_divert:=forced/pe_divert"])
    forced = cell.w.create_publisher(Bool, "forced/pe_divert", SENSOR_QOS)
    forced.publish(Bool(data=False))
    cell.induct("C2")
    cell.wait_state("stuck_off", 15.0)
    assert "pe_divert" in cell.status.message and "should have blocked" in cell.status.message


def test_missed_divert_without_chute_sensor(ros):
    cell = Cell(ros, remaps=["sensors/chute_left:=forced/chute_left"])
    forced = cell.w.create_publisher(Bool, "forced/chute_left", SENSOR_QOS)
    forced.publish(Bool(data=False))
    cell.induct("A3")
    cell.wait_state("missed_divert", 15.0)
    assert "chute_left" in cell.status.message
    ros.spin_until(lambda: cell.confirmation("A3") is not None, 5.0, "A3's confirmation")
    assert cell.confirmation("A3")["result"] == "missed"


def test_on_the_simulation_clock_a_call_times_out_once_both_clocks_are_past(ros):
    """
    ``service_timeout`` counts on the wall clock and on the controller's own.

    On the simulation's clock, a process too loaded to take the cell's answer in time
    holds the simulated time back too: its calls do not time out until that time has
    run on as well (a lock-step line under load lost every later divert to a
    ``diverter_timeout`` whose answer was already on its way).
    """
    from builtin_interfaces.msg import Time
    from rosgraph_msgs.msg import Clock

    from sorter_control.logic.image import Command

    ctl = ros.add(
        ControllerNode(
            context=ros.context,
            namespace="/no_cell",  # nobody serves its pop-up: no call is ever answered
            parameter_overrides=[
                Parameter("use_sim_time", value=True),
                Parameter("service_timeout", value=1.0),
            ],
        )
    )
    clock = ros.make_node("clock").create_publisher(Clock, "/clock", 10)

    def at(t):
        clock.publish(Clock(clock=Time(sec=int(t), nanosec=round(t % 1 * 1e9))))
        ros.spin_until(lambda: abs(ctl._now() - t) < 1e-6, 10.0, f"the clock at {t} s")

    def timed_out():
        ctl._expire_calls()
        return [r.command_id for r in ctl._replies if r.timed_out]

    at(1.0)
    sent = time.monotonic()
    ctl._call(Command(1, "popup", True, 1.0), 0.0)
    at(5.0)  # the simulated time ran on; the wall clock has not
    if time.monotonic() - sent < 1.0:
        assert timed_out() == []
    time.sleep(max(0.0, sent + 1.05 - time.monotonic()))
    assert timed_out() == [1]  # both past

    sent = time.monotonic()
    ctl._call(Command(2, "popup", False, 5.0), 0.0)
    time.sleep(1.05)  # the wall clock ran on; the simulated time has not
    assert timed_out() == [1]
    at(5.5)
    assert timed_out() == [1]
    at(6.01)
    assert timed_out() == [1, 2]


def test_diverter_service_withheld_times_out_without_retry(ros):
    cell_kw = dict(remaps=["diverter/popup:=withheld/popup"])
    # a stand-in for the pop-up service that answers once, then is no longer served
    stand_in = ros.make_node("stand_in")
    answered = []

    def serve(request, response):
        answered.append(request.data)
        response.success, response.message = True, "ok"
        return response

    stand_in.create_service(SetBool, "withheld/popup", serve)
    # on the wall clock: the call's timeout is wall time, and a cell running as fast as possible
    # would let the parcel miss its chute (another fault) before the timeout
    cell = Cell(ros, sim={"time_mode": "realtime", "real_time_factor": 1.0}, **cell_kw)
    ros.spin_until(lambda: answered, 5.0, "the controller's first pop-up command")
    ros.executor.remove_node(stand_in)  # from now on nobody answers
    cell.induct("A4")
    cell.wait_state("diverter_timeout", 30.0)  # wall time: a loaded machine lags
    assert "not retried" in cell.status.message
    ros.spin_for(1.0)
    popups = _popups(cell.ctl)
    assert [e[1] for e in popups] == [False, True]  # the raise went out once
    assert popups[1][3] is None  # and was never answered
    assert cell.value("timeouts") == "1"


def test_estop_and_reset_through_the_controller(ros):
    cell = Cell(ros)
    ok = cell.call(SetBool, "/sorter_controller/estop", SetBool.Request(data=True))
    assert ok.success
    cell.wait_state("estop", 5.0)
    ros.spin_until(
        lambda: cell.cell_status is not None and _values(cell.cell_status)["estop"] == "true",
        5.0,
        "the cell's e-stop",
    )
    refused = cell.call(SetBool, "/sorter_controller/estop", SetBool.Request(data=False))
    assert not refused.success and "reset" in refused.message
    ok = cell.call(Trigger, "/sorter_controller/reset", Trigger.Request())
    assert ok.success
    cell.wait_state("running", 5.0)
    ros.spin_until(lambda: _values(cell.cell_status)["estop"] == "false", 5.0, "the cell to reset")
    # and it sorts again
    cell.induct("B5")
    ros.spin_until(lambda: cell.outcome("B5") is not None, 10.0, "B5 to leave")
    assert cell.outcome("B5")["exit"] == "right"


def test_the_controller_sorts_only_in_execute_and_its_reset_walks_the_cell_there(ros):
    """A cell that waits for its commands (packml_auto false): real services both ways."""
    cell = Cell(ros, sim={"packml_auto": False})
    states = []
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    latched = QoSProfile(
        depth=20,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    cell.w.create_subscription(String, "status/packml", lambda m: states.append(m.data), latched)
    ros.spin_until(lambda: states and states[-1] == "Stopped", 5.0, "the cell Stopped")
    cell.induct("B1")  # the infeed is closed while Stopped: it waits there
    ros.spin_for(1.0)
    assert cell.outcome("B1") is None and not cell.labels
    ok = cell.call(Trigger, "/sorter_controller/reset", Trigger.Request())
    assert ok.success
    ros.spin_until(lambda: states[-1] == "Execute", 10.0, "the controller to start the cell")
    assert [c[1] for c in cell.ctl.command_log if c[0] == "packml"] == ["reset", "start"]
    ros.spin_until(lambda: cell.outcome("B1") is not None, 15.0, "B1 to leave")
    assert cell.outcome("B1")["exit"] == "right"
    # an operator holds the cell: the next parcel goes straight, flagged, not mis-sorted
    held = cell.call(Trigger, "packml/hold", Trigger.Request())
    assert held.success and "Held" in held.message
    ros.spin_until(lambda: states[-1] == "Held", 5.0, "Held")
    cell.induct("B2")
    ros.spin_until(
        lambda: cell.confirmation("B2") is not None and cell.outcome("B2") is not None,
        15.0,
        "B2 out and confirmed",
    )
    assert cell.outcome("B2")["exit"] == "straight"
    assert cell.confirmation("B2")["result"] == "not_executing"
    # the controller's reset unholds it, and it sorts again
    assert cell.call(Trigger, "/sorter_controller/reset", Trigger.Request()).success
    ros.spin_until(lambda: states[-1] == "Execute", 10.0, "unheld")
    cell.induct("B3")
    ros.spin_until(lambda: cell.outcome("B3") is not None, 15.0, "B3 to leave")
    assert cell.outcome("B3")["exit"] == "right"
    assert cell.value("mis_sorted") == "0" and cell.value("not_executing") == "1"


def test_a_second_clock_is_one_clock_fault_until_it_is_gone(ros):
    from rosgraph_msgs.msg import Clock

    cell = Cell(ros)
    # a second node publishing /clock (a second cell started without its own namespace)
    other = ros.make_node("other_cell")
    clock = other.create_publisher(Clock, "/clock", STREAM_QOS)
    cell.wait_state("clock", 5.0)
    assert "2 nodes publish /clock" in cell.status.message
    assert cell.value("fault_clock") == "1"
    ros.spin_until(
        lambda: (
            cell.cell_status is not None
            and _values(cell.cell_status).get("clock_publishers") == "2"
        ),
        5.0,
        "the cell to report two /clock publishers",
    )
    refused = cell.call(Trigger, "/sorter_controller/reset", Trigger.Request())
    assert refused.success  # taken; the next scan refuses it while the cause remains
    ros.spin_for(0.5)
    assert cell.state == "clock"
    other.destroy_publisher(clock)
    ros.spin_for(1.5)  # the controller sees the graph change at its next diagnostics period
    assert cell.call(Trigger, "/sorter_controller/reset", Trigger.Request()).success
    cell.wait_state("running", 5.0)
    cell.induct("A7")
    ros.spin_until(lambda: cell.outcome("A7") is not None, 10.0, "A7 to leave")
    assert cell.outcome("A7")["exit"] == "left"


def test_estop_engaged_at_the_cell_is_seen(ros):
    cell = Cell(ros)
    assert cell.call(SetBool, "estop", SetBool.Request(data=True)).success  # the operator's button
    cell.wait_state("estop", 5.0)
    assert cell.status.level == DiagnosticStatus.ERROR


# --------------------------------------------------------------------------- bad input


def test_bad_messages_change_nothing_and_the_node_survives(ros):
    cell = Cell(ros)
    w = cell.w
    edges = w.create_publisher(TimeReference, "sensors/edges", EVENT_QOS)
    joints = w.create_publisher(JointState, "diverter/state", STREAM_QOS)
    bad = TimeReference(source="sideways")
    bad.header.frame_id = "pe_divert"
    edges.publish(bad)
    joints.publish(JointState(name=["disk_angle"], position=[math.nan]))
    cell.route_pub.publish(KeyValue(key="A*", value="up"))
    cell.route_pub.publish(KeyValue(key="", value="left"))
    ros.spin_until(
        lambda: int(cell.value("bad_messages")) >= 2 and int(cell.value("routing_rejected")) >= 2,
        5.0,
        "the bad messages to be counted",
    )
    assert cell.state == "running"
    assert cell.value("routing") == ";".join(ROUTING)
    cell.induct("A6")
    ros.spin_until(lambda: cell.outcome("A6") is not None, 10.0, "A6 to leave")
    assert cell.outcome("A6")["exit"] == "left"


def test_the_nodes_publishers_carry_no_qos_event_handlers(ros):
    # each handler is a waitable of every executor pass (sorter_ros.interface's
    # quiet_publisher_events); the subscribing side still warns of a QoS mismatch.
    # /parameter_events is rclpy's own publisher.
    cell = Cell(ros)
    for node in (cell.sim, cell.ctl):
        publishers = [p for p in node.publishers if p.topic_name != "/parameter_events"]
        assert len(publishers) >= 3
        loud = [p.topic_name for p in publishers if p.event_handlers]
        assert loud == [], (node.get_name(), loud)


def test_parameters_validated_at_start_and_at_run_time(ros):
    with pytest.raises(ValueError, match="routing"):
        ControllerNode(
            context=ros.context,
            parameter_overrides=[
                Parameter("routing.rules", value=["A=up"]),
                Parameter("cell_node", value=""),
            ],
        )
    with pytest.raises(ValueError, match="photo_eyes"):
        ControllerNode(
            context=ros.context,
            parameter_overrides=[
                Parameter("photo_eyes.x", value=[-2.0]),
                Parameter("cell_node", value=""),
            ],
        )
    ctl = ros.add(
        ControllerNode(context=ros.context, parameter_overrides=[Parameter("cell_node", value="")])
    )
    w = ros.make_node("setter")
    client = w.create_client(SetParameters, "/sorter_controller/set_parameters")

    def set_param(name, pv):
        return ros.call(
            client, SetParameters.Request(parameters=[ParameterMsg(name=name, value=pv)])
        ).results[0]

    before = ctl.logic.routing.rules()
    r = set_param(
        "routing.rules",
        ParameterValue(
            type=ParameterType.PARAMETER_STRING_ARRAY, string_array_value=["A=sideways"]
        ),
    )
    assert not r.successful and "sideways" in r.reason
    r = set_param(
        "scan_period", ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=0.02)
    )
    assert not r.successful and "read-only" in r.reason
    assert ctl.logic.routing.rules() == before
    r = set_param(
        "routing.rules",
        ParameterValue(type=ParameterType.PARAMETER_STRING_ARRAY, string_array_value=["Z*=right"]),
    )
    assert r.successful
    assert ctl.logic.routing.lookup("Z1") == ("right", "prefix")


# --------------------------------------------------------------------------- the main job


def test_sorter_demo_sorts_and_reports(tmp_path, capsys):
    import json

    from sorter_cell.cli import main

    png = tmp_path / "paths.png"
    assert main(["demo", "--sim-time", "12", "--json", "--out", str(png)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["mis_sorted"] == 0 and summary["jams"] == 0 and summary["untracked"] == 0
    assert summary["sorted_left"] >= 2 and summary["sorted_right"] >= 2
    out = summary["sorted_left"] + summary["sorted_right"] + summary["straight"]
    assert summary["inducted"] == out + summary["in_cell_at_end"]
    assert summary["throughput_pcs_h"] == pytest.approx(
        3600.0 * out / summary["sim_time_s"], rel=1e-3
    )
    assert summary["controller_state"] == "running" and summary["late_decisions"] == 0
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_sorter_demo_runs_a_touching_stream_under_rigid_contact(tmp_path, capsys):
    """
    --gap 0 0: parcels end to end, run under contact: rigid, sorted by the shipped rules.

    The controller needs 1.40 m between parcels to divert one (its least mixed-stream
    gap): at gap 0 every divert is refused and its parcel sent straight, flagged
    gap_too_short. Riding the belt together the parcels push nothing (no jam); a parcel
    in a chute would be a mis-sort, since none was routed to one.
    """
    import json

    from sorter_cell.cli import main

    png = tmp_path / "paths.png"
    argv = ["demo", "--gap", "0", "0", "--sim-time", "8", "--json", "--out", str(png)]
    assert main(argv) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["contact"] == "rigid" and s["stream_gap_m"] == [0.0, 0.0]
    assert s["jams"] == 0 and s["mis_sorted"] == 0 and s["untracked"] == 0
    assert s["controller_state"] == "running" and not s["controller_faults"]
    assert s["sorted_left"] == s["sorted_right"] == 0
    assert s["flagged"]["gap_too_short"] >= 5
    # every parcel that left went straight: flagged, rejected (label D) or asked straight
    assert s["straight"] >= s["straight_flagged"] + s["rejected"]
    assert s["inducted"] == s["straight"] + s["in_cell_at_end"]
    # end to end: one parcel every mean length / belt speed (0.5 m / 1.5 m/s)
    assert s["inducted"] >= 8.0 * 1.5 / 0.7


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--sim-time", "0"], "--sim-time"),
        (["--rtf", "warp"], "--rtf"),
        (["--gap", "1.0", "0.5"], "--gap"),
        (["--gap", "-0.1", "0"], "[0, 100] m"),
        (["--gap", "0", "0", "--contact", "jam"], "needs --contact rigid"),
        (["--gap", "0", "0", "--stations", "2", "--contact", "jam"], "needs --contact rigid"),
        (["--out", "paths.svg"], "--out"),
        (["--out", "/proc/version/paths.png"], "is not a folder"),
    ],
)
def test_sorter_demo_bad_arguments_exit_2(argv, words, capsys):
    from sorter_cell.cli import main

    assert main(["demo", *argv]) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1


# --------------------------------------------------------------------------- watchdog


@pytest.mark.parametrize("period, watchdog", [(0.0, 0.3), (0.05, 0.3), (0.05, 0.1)])
def test_the_heartbeat_beats_every_heartbeat_period_and_keeps_the_watchdog(ros, period, watchdog):
    """
    A beat at the first 10 ms scan at or after each heartbeat_period (0: every scan).

    The period is fitted to a quarter of the cell's watchdog_timeout at most (0.1 s:
    0.025 s, a beat every third scan); the watchdog sees a beat in time: armed, never
    tripped.
    """
    scans = max(1, math.ceil(min(period, watchdog / 4) / 0.01 - 1e-6))
    per_second = 100.0 / scans  # 100, 20 and 33.3 beats a second
    cell = Cell(ros, sim={"watchdog_timeout": watchdog}, ctl={"heartbeat_period": period})
    sim, ctl = cell.sim, cell.ctl
    ros.spin_until(lambda: sim.cell.watchdog_armed, 20.0, "the controller's first heartbeat")
    topic = ctl._pub_heartbeat.topic_name
    t0, n0 = ctl._now(), ctl.published[topic]
    ros.spin_until(lambda: ctl._now() >= t0 + 2.0, 60.0, "two simulated seconds")
    beats = ctl.published[topic] - n0
    seconds = ctl._now() - t0
    assert abs(beats - per_second * seconds) <= 2, (beats, seconds)
    assert sim.cell.watchdog_armed and not sim.cell.watchdog_tripped
    assert ctl.get_parameter("heartbeat_period").value == period


def test_a_stopped_controller_leaves_the_disks_down_and_a_new_one_takes_over(ros):
    cell = Cell(ros, sim={"watchdog_timeout": 0.3})
    sim = cell.sim
    ros.spin_until(lambda: sim.cell.watchdog_armed, 20.0, "the controller's first heartbeat")
    # the controller lowers the disks once as it starts: that command is through before
    # the test raises them (else it lands after and lowers them again)
    ros.spin_until(
        lambda: any(e[1] is False and e[3] is not None for e in _popups(cell.ctl)),
        20.0,
        "the controller's first pop-up command answered",
    )
    # the disks up, as a divert in progress leaves them; then the controller stops
    assert sim.cell.popup(True)[0]
    ros.spin_until(lambda: sim.cell.stroke == 1.0, 20.0, "the disks up")
    ros.executor.remove_node(cell.ctl)
    ros.nodes.remove(cell.ctl)
    cell.ctl.destroy_node()
    t_stop = sim.cell.t
    ros.spin_until(lambda: sim.cell.watchdog_tripped, 30.0, "the watchdog to trip")
    # within the timeout (simulated), plus at most one fast-mode slice of lag
    assert sim.cell.t - t_stop <= 0.3 + CELL["fast_slice"] + 0.011
    ros.spin_until(lambda: sim.cell.stroke == 0.0, 20.0, "the disks down")
    # a controller started again takes over: its heartbeat clears the watchdog, it runs
    ctl = ros.add(
        ControllerNode(
            context=ros.context,
            parameter_overrides=[Parameter(k, value=v) for k, v in CONTROLLER.items()],
        )
    )
    ros.spin_until(lambda: not sim.cell.watchdog_tripped, 30.0, "the watchdog to clear")
    ros.spin_until(
        lambda: ctl.logic is not None and ctl.logic.state == "running",
        30.0,
        "the new controller to run",
    )
    # and hears the cell: in fast mode a parcel reaches the scanner a few wall-clock ms after
    # its induction, sooner than DDS may match a new subscription; an eye whose first state
    # the controller learns with a parcel already in it has no rising edge, and a parcel the
    # controller never saw is (rightly) passed straight
    ros.spin_until(
        lambda: (
            all(s.get_publisher_count() > 0 for s in ctl.subscriptions)
            and all(bit is not None for bit in ctl.logic.edges.bits.values())
        ),
        30.0,
        "the new controller to hear every topic and know every eye",
    )
    assert sim.cell.faults == []
    # and the next parcels go where routing says
    for n, label in enumerate(("A00001", "B00002"), start=1):
        cell.induct(label)
        ros.spin_until(lambda n=n: len(cell.outcomes) == n, 30.0, f"outcome {n}")
    assert [o["exit"] for o in cell.outcomes] == ["left", "right"], cell.outcomes


def test_the_wait_for_the_cells_parameters_counts_from_the_first_spin(ros):
    """A controller made long before it spins (a line's 48 stations) still asks the cell."""
    ctl = ros.add(
        ControllerNode(
            context=ros.context,
            parameter_overrides=[
                Parameter(k, value=v) for k, v in {**CONTROLLER, "cell_timeout": 0.5}.items()
            ],
        )
    )
    time.sleep(1.0)  # twice cell_timeout, nothing spinning
    cell = {**CELL, "belt_speed": 1.7}
    ros.add(
        SimNode(
            context=ros.context,
            parameter_overrides=[Parameter(k, value=v) for k, v in cell.items()],
        )
    )
    ros.spin_until(lambda: getattr(ctl, "config", None) is not None, 20.0, "the controller")
    assert ctl.config.belt_speed == 1.7  # the cell's, not its own file's 1.5


def test_use_sim_time_cannot_change_while_the_controller_runs(ros):
    cell = Cell(ros)
    bad = ParameterMsg(
        name="use_sim_time",
        value=ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=False),
    )
    (result,) = cell.call(
        SetParameters, "sorter_controller/set_parameters", SetParameters.Request(parameters=[bad])
    ).results
    assert not result.successful and "read-only" in result.reason
    assert cell.ctl.get_parameter("use_sim_time").value is True
    ros.spin_for(0.5)
    assert cell.state == "running" and cell.ctl.logic.fault is None


# --------------------------------------------------------------------------- the defaults
CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


def test_defaults_agree():
    """The default stream (config/cell.yaml) is one the default controller can sort."""
    from sorter_cell.demo import stream_plan
    from sorter_ros.params_file import read_params_file
    from sorter_sim.runtime.params import SPECS

    cell = read_params_file(CONFIG_DIR / "cell.yaml", "sorter_sim")
    plan = stream_plan(tuple(cell["parcel_A"]), CONFIG_DIR)
    assert cell["arrival_gap"][0] >= plan["min_gap_m"], (cell["arrival_gap"], plan)
    assert list(SPECS["arrival_gap"].default) == list(cell["arrival_gap"])


@pytest.mark.slow
def test_the_default_cell_and_controller_sort_a_minute_with_no_gap_too_short(tmp_path, capsys):
    """
    A minute of config/cell.yaml's stream gaps, sorted by config/controller.yaml's rules.

    Run as ``sorter demo`` runs it (both files, the controller in lock-step with the
    cell, so every scan is where its period says however loaded the machine): the
    stream's least gap is the controller's least gap or more, so none is too short.
    """
    import json

    from sorter_cell.cli import main
    from sorter_ros.params_file import read_params_file

    lo, hi = read_params_file(CONFIG_DIR / "cell.yaml", "sorter_sim")["arrival_gap"]
    png = tmp_path / "paths.png"
    argv = ["demo", "--sim-time", "60", "--gap", str(lo), str(hi), "--json", "--out", str(png)]
    assert main(argv) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["stream_gap_m"] == [lo, hi] and s["sim_time_s"] >= 60.0
    assert s["inducted"] >= 20, s
    assert s["flagged"].get("gap_too_short", 0) == 0, s["flagged"]
    assert s["mis_sorted"] == 0 and s["jams"] == 0 and s["late_decisions"] == 0
    assert s["controller_state"] == "running" and not s["controller_faults"]


@pytest.mark.parametrize("signals", [1, 2], ids=["ctrl-c", "ctrl-c-twice"])
def test_ctrl_c_ends_the_demo_cleanly(ros, tmp_path, signals):
    import json
    import signal
    import subprocess
    import sys

    exe = Path(sys.executable).parent / "sorter"
    proc = subprocess.Popen(
        [str(exe), "demo", "--sim-time", "600", "--json", "--out", str(tmp_path / "p.png")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        states = []
        w = ros.make_node("demo_watcher")
        w.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda m: states.extend(s.message for s in m.status if s.name.endswith("controller")),
            STREAM_QOS,
        )
        ros.spin_until(lambda: "running" in states, 45.0, "the demo's controller to run")
        ros.spin_for(2.0)
        for _ in range(signals):
            proc.send_signal(signal.SIGINT)
            time.sleep(0.05)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "Traceback" not in err and "Exception ignored" not in err, err[-3000:]
    if signals == 1:
        # the first Ctrl-C ends the stream where it is; the summary covers what ran
        assert proc.returncode == 0, err[-2000:]
        summary = json.loads(out)
        assert 0 < summary["sim_time_s"] < 600 and summary["mis_sorted"] == 0
    else:
        assert proc.returncode in (0, 130), err[-2000:]


def test_the_demo_exits_1_when_its_controller_ends_faulted(capsys):
    from sorter_cell.demo_summary import exit_code

    clean = {'mis_sorted': 0, 'jams': 0, 'controller_state': 'running', 'controller_faults': {}}
    assert exit_code(clean) == 0
    assert exit_code({**clean, 'mis_sorted': 1}) == 1
    assert exit_code({**clean, 'jams': 2}) == 1
    faulted = {**clean, 'controller_state': 'faulted', 'controller_faults': {'watchdog': 1}}
    assert exit_code(faulted) == 1
    err = capsys.readouterr().err
    assert "ended 'faulted'" in err and 'watchdog' in err
