"""
The controller node ``sorter_controller``: the sorter PLC on ROS 2, a thin shell around the logic.

Parameters (declared with descriptors, read once into ``ControllerConfig``) and
the cell's own structural parameters (read from the simulation node over its
standard ``get_parameters`` service when ``cell_node`` names it) configure
``sorter_control.logic.SorterLogic``. Subscriptions only buffer what arrives
(sensor bits, latched edges, labels, the diverter's state, the cell's e-stop and
jam bits, routing updates); a timer at the scan period, on
the simulation clock, hands the buffer to the logic as one input image and turns
what the logic returns into asynchronous service calls (pop-up, disk angle via
the cell's ``set_parameters``, e-stop, reset), sort confirmations, diagnostics
and log lines. No callback ever waits: a call that has no answer within
``service_timeout`` (on the wall clock and on the node's own, which is the
simulation's under ``use_sim_time``) is dropped with ``remove_pending_request`` and
reported to the logic as timed out, which it does not retry.

Interface (all names relative): subscribes ``sensors/<name>`` (std_msgs/Bool),
``sensors/edges`` (sensor_msgs/TimeReference), ``scanner/label``
(std_msgs/String), ``diverter/state`` (sensor_msgs/JointState), ``status/estop``
and ``status/jam`` (std_msgs/Bool, the cell's state bits), ``routing/updates``
(diagnostic_msgs/KeyValue: key = label, ``prefix*`` or ``*``, value = left | right |
straight, or empty to remove);
publishes ``controller/heartbeat`` (std_msgs/UInt32, a counter, every
``heartbeat_period`` of simulated time or every scan: the cell's watchdog),
``sort/confirmations`` (diagnostic_msgs/DiagnosticStatus) and
``diagnostics`` (diagnostic_msgs/DiagnosticArray); serves ``~/reset``
(std_srvs/Trigger) and ``~/estop`` (std_srvs/SetBool).
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue, SetParametersResult
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter as RclpyParameter
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Bool, String, UInt32
from std_srvs.srv import SetBool, Trigger

from sorter_control.logic import (
    DiverterState,
    Edge,
    InputImage,
    Reply,
    RoutingError,
    RoutingTable,
    SorterLogic,
)
from sorter_control.parameters import (
    CELL_KEYS,
    ROUTING_KEYS,
    SCHEMA,
    SPECS,
    _value,
    config_from_values,
    descriptor,
)
from sorter_ros.env import run_node
from sorter_ros.graph_counts import publisher_count
from sorter_sim.model.packml import COMMANDS as PACKML_COMMANDS
from sorter_sim.model.packml import STATES as PACKML_STATES
from sorter_ros.interface import (
    answer_every_parameter_request,
    EVENT_QOS,
    SENSOR_QOS,
    SERVICE_QOS,
    STREAM_QOS,
    accept_integers_for_doubles,
    declare_checked,
    parameter_problem,
    plain,
    quiet_publisher_events,
)
from sorter_ros.recording import open_recorder, publish_recorded, release_recorder

NODE_NAME = "sorter_controller"
LAST_WORDS_TIMEOUT = 0.5  # [s, wall] to lower the disks when stopping


LEVELS = {
    "sorted": DiagnosticStatus.OK,
    "rejected": DiagnosticStatus.OK,
    "mis-sorted": DiagnosticStatus.ERROR,
    "missed": DiagnosticStatus.ERROR,
}


class ControllerNode(Node):
    """The sorter PLC's ROS face; see the module docstring."""

    def __init__(self, **kwargs):
        kwargs.setdefault("parameter_overrides", [])
        super().__init__(NODE_NAME, **kwargs)
        answer_every_parameter_request(self)  # a request rclpy cannot read too
        self.values = {}
        accept_integers_for_doubles(self, {spec.name: descriptor(spec).type for spec in SCHEMA})
        for spec in SCHEMA:
            # a value of another type is refused naming what the parameter allows
            p = declare_checked(self, spec.name, spec.default, spec.allowed, descriptor(spec))
            self.values[spec.name] = plain(p.value)
        config_from_values(self.values)  # fail now, naming the parameter
        self.published = Counter()  # messages per topic, counted where they are published
        self.recorder = None
        if self.values["record_path"]:
            try:
                self.recorder = open_recorder(self.values["record_path"], self.get_logger().error)
            except ValueError as exc:
                raise ValueError(f"parameter 'record_path': {exc}") from None
        self.logic: SorterLogic | None = None
        self._svc = {
            "popup": self.create_client(SetBool, "diverter/popup"),
            "estop": self.create_client(SetBool, "estop"),
            "reset": self.create_client(Trigger, "reset"),
        }
        for command in PACKML_COMMANDS:
            self._svc[f"packml/{command}"] = self.create_client(Trigger, f"packml/{command}")
        cell = self.values["cell_node"]
        self._cell_params_client = (
            self.create_client(GetParameters, f"{cell}/get_parameters") if cell else None
        )
        self._svc["alpha"] = self.create_client(
            SetParameters, f"{cell or 'sorter_sim'}/set_parameters"
        )
        self._cell_request = None
        # the wait counts from the first look, once the node spins: a line's process
        # makes its stations one after another, minutes with 48 of them, before any spins
        self._cell_wait_start = None
        # without rclpy's default QoS-event handlers, as the cell's publishers: each is a
        # waitable of every executor pass, and the subscribers warn of a mismatch anyway
        quiet = quiet_publisher_events
        self._pub_confirm = self.create_publisher(
            DiagnosticStatus, "sort/confirmations", EVENT_QOS, event_callbacks=quiet()
        )
        # absolute, where diagnostic aggregators and tools look; the status names the node
        self._pub_diag = self.create_publisher(
            DiagnosticArray, "/diagnostics", STREAM_QOS, event_callbacks=quiet()
        )
        # the cell's watchdog expects this every heartbeat_period: a scan that stops, stops it
        self._pub_heartbeat = self.create_publisher(
            UInt32, "controller/heartbeat", STREAM_QOS, event_callbacks=quiet()
        )
        self._beats = 0
        self._last_beat = self._next_beat = -math.inf  # the first scan beats
        self._beat_period = self.values["heartbeat_period"]  # fitted to the cell's watchdog
        self.create_service(Trigger, "~/reset", self._srv_reset, qos_profile=SERVICE_QOS)
        self.create_service(SetBool, "~/estop", self._srv_estop, qos_profile=SERVICE_QOS)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._post_set_parameters)
        # the input buffer the next scan reads
        self._bits: dict[str, bool] = {}
        self._edges: list[Edge] = []
        self._labels: list[tuple[float, str]] = []
        self._diverter: DiverterState | None = None
        self._routing: list[tuple[str, str]] = []
        self._clock_sources: int | None = None  # publishers of /clock, when on sim time
        self._replies: list[Reply] = []
        self._cell_estop: bool | None = None
        self._cell_watchdog: bool | None = None
        self._cell_jam: bool | None = None
        self._cell_packml: str | None = None  # latched: the cell's state, as last heard
        self._cell_status_t: float | None = None
        # command id -> (future, client, (wall deadline, clock deadline), cmd, log entry)
        self._in_flight: dict[int, tuple] = {}
        # [kind, value, wall at the scan's start, wall answered, accepted, wall sent]
        self.command_log: deque = deque(maxlen=10000)
        self.confirmations: deque = deque(maxlen=10000)
        self.n_bad_messages = 0
        self._clock_warned = False
        steady = rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME)
        self._scan_timer = self.create_timer(self.values["scan_period"], self._scan)
        self.create_timer(
            self.values["diagnostics_period"], self._publish_diagnostics, clock=steady
        )
        if cell:
            # the simulation clock may not run before the cell does: poll on the wall clock
            self._startup_timer = self.create_timer(0.05, self._poll_cell_parameters, clock=steady)
            self.get_logger().info(
                f"waiting for the cell's parameters from {self._cell_params_client.srv_name}"
            )
        else:
            self._start(dict(self.values))

    # ------------------------------------------------------------------ start-up
    def _start(self, values: dict) -> None:
        config = config_from_values(values)
        self.config = config
        self.logic = SorterLogic(config)
        # warm the model core (numba) and the nominal spacing rules before the first parcel
        nominal = min(self.values["nominal_parcel_length"], config.max_parcel_length)
        gaps = self.logic.min_gap(nominal)
        lo, hi = (list(values["warm_lengths"]) + [0.0, 0.0])[:2]
        # predicted a length at a time between scans, so no callback holds the executor long
        self._warm = deque(self.logic.warm_lengths(lo, hi) if 0.0 < lo <= hi else [])
        n_warm = len(self._warm)
        if self._warm:
            steady = rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME)
            self._warm_timer = self.create_timer(0.02, self._warm_step, clock=steady)
        for name in config.eyes:
            self._subscribe_sensor(name)
        for name in config.chutes.values():
            self._subscribe_sensor(name)
        self.create_subscription(TimeReference, "sensors/edges", self._on_edge, EVENT_QOS)
        self.create_subscription(String, "scanner/label", self._on_label, EVENT_QOS)
        self.create_subscription(JointState, "diverter/state", self._on_diverter, STREAM_QOS)
        # the cell's state bits (latched, sent on change); its diagnostics are for humans
        self.create_subscription(Bool, "status/estop", self._on_cell_estop, SENSOR_QOS)
        self.create_subscription(Bool, "status/watchdog", self._on_cell_watchdog, SENSOR_QOS)
        self.create_subscription(Bool, "status/jam", self._on_cell_jam, SENSOR_QOS)
        self.create_subscription(String, "status/packml", self._on_cell_packml, SENSOR_QOS)
        self.create_subscription(KeyValue, "routing/updates", self._on_routing, EVENT_QOS)
        self.min_gaps = gaps
        self.get_logger().info(
            f"sorter controller running: scan {config.scan_period * 1e3:g} ms, belt "
            f"{config.belt_speed:g} m/s, "
            f"disk field {config.cell.disk_field_length:g} m; {nominal:g} m parcels need a gap of "
            f"{gaps['worst']:.3f} m in a mixed stream ({gaps['capacity_pcs_h']:.0f} pcs/h), "
            f"{gaps['left->left']:.3f} m behind one to the same side; predicting {n_warm} lengths "
            "ahead"
        )
        if not self.logic.lookahead_ok(nominal):
            self.get_logger().info(
                f"the scanner eye at x = {self.logic.x_scan:g} m is too close to the disk field "
                "to see a "
                f"follower before deciding a {nominal:g} m parcel: close same-side pairs will be "
                "refused"
            )

    def _warm_step(self) -> None:
        if self._warm:
            self.logic.warm_up([self._warm.popleft()])
        else:
            self._warm_timer.cancel()

    def _subscribe_sensor(self, name: str) -> None:
        self.create_subscription(
            Bool, f"sensors/{name}", lambda msg, n=name: self._on_bit(n, msg), SENSOR_QOS
        )

    def _poll_cell_parameters(self) -> None:
        """Ask the cell for its structural parameters (once it serves them), without waiting."""
        client = self._cell_params_client
        if client is None:
            self._startup_timer.cancel()
            return
        if self._cell_request is None:
            if self._cell_wait_start is None:
                self._cell_wait_start = time.monotonic()
            if time.monotonic() - self._cell_wait_start > self.values["cell_timeout"]:
                self.get_logger().error(
                    f"no answer from {client.srv_name} after {self.values['cell_timeout']:g} s; "
                    "using this "
                    "node's cell parameters"
                )
                self._cell_params_client = None
                self._startup_timer.cancel()
                self._start(dict(self.values))
                return
            if client.service_is_ready():
                # and the cell's watchdog, which the heartbeat must keep fed
                self._cell_request = client.call_async(
                    GetParameters.Request(names=[*CELL_KEYS, "watchdog_timeout"])
                )
            return
        if not self._cell_request.done():
            return
        try:
            response = self._cell_request.result()
        except Exception as exc:  # a failed call: ask again on the next scan
            self.get_logger().warning(f"{client.srv_name} failed: {exc}")
            self._cell_request = None
            return
        values = dict(self.values)
        for key, pv in zip(CELL_KEYS, response.values):
            v = _value(pv)
            if v is not None:
                values[key] = v
        if len(response.values) > len(CELL_KEYS):
            self._fit_heartbeat(_value(response.values[len(CELL_KEYS)]))
        self._cell_params_client = None
        self._startup_timer.cancel()  # now, not on a tick to come: the node may be gone by then
        try:
            self._start(values)
        except ValueError as exc:
            self.get_logger().error(f"the cell's parameters do not make a controller: {exc}")
            raise

    def _fit_heartbeat(self, watchdog_timeout) -> None:
        """Beat at least four times a watchdog_timeout of the cell's (when it has one)."""
        if not isinstance(watchdog_timeout, float) or not watchdog_timeout > 0.0:
            return
        most = watchdog_timeout / 4.0
        if self._beat_period > most:
            self.get_logger().warning(
                f"heartbeat_period {self._beat_period:g} s is more than a quarter of the "
                f"cell's watchdog_timeout ({watchdog_timeout:g} s): beating every {most:g} s"
            )
            self._beat_period = most

    # ------------------------------------------------------------------ inputs (buffer only)
    def _on_bit(self, name: str, msg: Bool) -> None:
        self._bits[name] = bool(msg.data)

    def _on_edge(self, msg: TimeReference) -> None:
        # stamped <cell frame>/<sensor>: the sensor is the last name
        name = msg.header.frame_id.rpartition("/")[2]
        t = msg.time_ref.sec + 1e-9 * msg.time_ref.nanosec
        if msg.source not in ("rising", "falling") or not name or not math.isfinite(t):
            self.n_bad_messages += 1
            return
        self._edges.append(Edge(name, t, msg.source == "rising"))
        if abs(t - self._now()) > 5.0 and not self._clock_warned:
            # sensor stamps on another clock: a cell on simulated time with this node on wall time
            self._clock_warned = True
            self.get_logger().warning(
                f"sensor edges are stamped {t - self._now():+.1f} s from this node's clock; with "
                "sim_node, "
                "run the controller with use_sim_time:=true (config/controller.yaml does)"
            )

    def _on_label(self, msg: String) -> None:
        self._labels.append((self._now(), msg.data))

    def _on_diverter(self, msg: JointState) -> None:
        try:
            pos = dict(zip(msg.name, msg.position))
            vel = dict(zip(msg.name, msg.velocity)) if msg.velocity else {}
            alpha, stroke = float(pos["disk_angle"]), float(pos["popup_stroke"])
        except (KeyError, TypeError, ValueError):
            self.n_bad_messages += 1
            return
        if not (math.isfinite(alpha) and math.isfinite(stroke)):
            self.n_bad_messages += 1
            return
        self._diverter = DiverterState(
            alpha, stroke, float(vel.get("disk_angle", 0.0)), float(vel.get("popup_stroke", 0.0))
        )

    # The bits are sent when they change (a reset sends the cleared bits before it
    # answers), so each one received is current: no stamp to check against the last reset.
    def _on_cell_watchdog(self, msg: Bool) -> None:
        # a level, not an event: the latched topic always holds the cell's current bit
        self._cell_watchdog = bool(msg.data)

    def _on_cell_estop(self, msg: Bool) -> None:
        self._cell_estop = bool(msg.data)

    def _on_cell_packml(self, msg: String) -> None:
        if msg.data in PACKML_STATES:
            self._cell_packml = msg.data
        else:
            self.n_bad_messages += 1
            self.get_logger().warning(
                f"status/packml dropped: {msg.data[:80]!r} is not a PackML state "
                f"({', '.join(PACKML_STATES)})"
            )

    def _on_cell_jam(self, msg: Bool) -> None:
        self._cell_jam = bool(msg.data)

    def _on_routing(self, msg: KeyValue) -> None:
        self._routing.append((msg.key, msg.value))

    # ------------------------------------------------------------------ the scan
    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _scan(self) -> None:
        if self.logic is None:
            return
        wall0 = time.perf_counter()
        now = self._now()
        if not self._last_beat <= now < self._next_beat:  # due, or the clock went back
            # the cell's watchdog needs a beat within its timeout, not every scan: one a
            # heartbeat_period is one message fewer for each scan between
            self._beats = (self._beats + 1) & 0xFFFFFFFF
            self._publish(self._pub_heartbeat, UInt32(data=self._beats))
            self._last_beat = now
            self._next_beat = now + self._beat_period - 1e-9
        self._expire_calls()
        image = InputImage(
            t=now,
            bits=dict(self._bits),
            edges=self._edges,
            labels=self._labels,
            diverter=self._diverter,
            replies=self._replies,
            routing_updates=self._routing,
            cell_estop=self._cell_estop,
            cell_jam=self._cell_jam,
            cell_watchdog=self._cell_watchdog,
            cell_status_t=self._cell_status_t,
            clock_sources=self._clock_sources,
            cell_packml=self._cell_packml,
        )
        self._edges, self._labels, self._replies, self._routing = [], [], [], []
        self._cell_estop = self._cell_jam = self._cell_status_t = None
        out = self.logic.scan(image)
        for cmd in out.commands:
            self._call(cmd, wall0)
        for c in out.confirmations:
            self._publish_confirmation(c)
        for level, text in out.log:
            self._log(level, text)
        self._publish_routing()
        self.logic.record_scan_wall(time.perf_counter() - wall0)

    def _publish_routing(self) -> None:
        """Keep the routing parameters equal to the live table (updates change both)."""
        live = self.logic.routing
        rules, default = live.rules(with_default=False), live.default or ""
        if rules == self.values["routing.rules"] and default == self.values["routing.default"]:
            return
        result = self.set_parameters(
            [
                RclpyParameter("routing.rules", RclpyParameter.Type.STRING_ARRAY, rules),
                RclpyParameter("routing.default", RclpyParameter.Type.STRING, default),
            ]
        )
        if not all(r.successful for r in result):
            # cannot happen for a table the logic accepted; say so rather than drift apart
            self.get_logger().error(
                "routing parameters not updated to the live table: "
                + "; ".join(r.reason for r in result if not r.successful)
            )

    def _log(self, level: str, text: str) -> None:
        # one call site per severity: rclpy refuses to change a call site's severity
        log = self.get_logger()
        if level == "error":
            log.error(text)
        elif level == "warn":
            log.warning(text)
        else:
            log.info(text)

    def last_words(self, executor, timeout: float = LAST_WORDS_TIMEOUT) -> bool:
        """
        Lower the disks before the controller goes; return whether the cell confirmed it.

        A PLC that stops cleanly leaves its diverter safe rather than relying on the
        cell's watchdog: the disks drop within one service round trip. Waits at most
        ``timeout`` seconds of wall time; if the cell does not answer, its watchdog
        still drops the disks once the heartbeat stops.

        Parameters
        ----------
        executor : rclpy.executors.Executor
            The executor that spins the node.
        timeout : float
            The most to wait [s, wall].

        Returns
        -------
        bool
            Whether the cell confirmed the disks down.

        """
        client = self._svc["popup"]
        deadline = time.monotonic() + timeout
        # stopped soon after its start, on a loaded machine, the controller may not have
        # discovered the cell's service yet: discovery runs in DDS's own threads, so wait
        # for it within the same budget rather than leave the disks up (rclpy's
        # wait_for_service polls every 0.25 s, half of this whole budget)
        while not client.service_is_ready() and time.monotonic() < deadline:
            time.sleep(0.01)
        if not client.service_is_ready():
            self.get_logger().warning("stopping: the cell's diverter/popup is not there")
            return False
        future = client.call_async(SetBool.Request(data=False))
        while not future.done() and time.monotonic() < deadline and self.context.ok():
            executor.spin_once(timeout_sec=0.02)
        ok = future.done() and future.exception() is None and bool(future.result().success)
        if ok:
            self.get_logger().info("stopping: disks lowered")
        else:
            client.remove_pending_request(future)
            self.get_logger().warning(
                "stopping: the cell did not confirm lowering the disks; its watchdog will"
            )
        return ok

    def _call(self, cmd, wall0: float) -> None:
        client = self._svc[f"packml/{cmd.value}" if cmd.kind == "packml" else cmd.kind]
        if cmd.kind == "popup" or cmd.kind == "estop":
            req = SetBool.Request(data=bool(cmd.value))
        elif cmd.kind in ("reset", "packml"):
            req = Trigger.Request()
        else:
            req = SetParameters.Request(
                parameters=[
                    Parameter(
                        name="alpha_deg",
                        value=ParameterValue(
                            type=ParameterType.PARAMETER_DOUBLE, double_value=float(cmd.value)
                        ),
                    )
                ]
            )
        future = client.call_async(req)
        timeout = self.values["service_timeout"]
        deadline = (time.monotonic() + timeout, self._now() + timeout)
        entry = [cmd.kind, cmd.value, wall0, None, None, time.perf_counter()]
        self.command_log.append(entry)
        self._in_flight[cmd.id] = (future, client, deadline, cmd, entry)
        future.add_done_callback(lambda f, cid=cmd.id: self._on_answer(cid, f))

    def _on_answer(self, cid: int, future) -> None:
        item = self._in_flight.pop(cid, None)
        if item is None:
            return  # already timed out
        _, _, _, cmd, entry = item
        entry[3] = time.perf_counter()
        try:
            resp = future.result()
        except Exception as exc:
            entry[4] = False
            self._replies.append(Reply(cid, False, f"call failed: {exc}"))
            return
        if cmd.kind == "alpha":
            result = resp.results[0] if resp.results else None
            ok = bool(result and result.successful)
            msg = result.reason if result else "no result"
        else:
            ok, msg = bool(resp.success), resp.message
        entry[4] = ok
        self._replies.append(Reply(cid, ok, msg))

    def _expire_calls(self) -> None:
        # a call fails once service_timeout has passed on the wall clock and on the
        # controller's own: on the simulation's clock, a process too loaded to serve the
        # cell's answer in time (a lock-step line's executor, a busy machine) also holds the
        # simulated time back, and a cell that answers nothing still times out once its
        # time runs on. On the wall clock the two are one.
        now, clock = time.monotonic(), self._now()
        for cid, (future, client, deadline, cmd, entry) in list(self._in_flight.items()):
            if now > deadline[0] and clock > deadline[1] and not future.done():
                client.remove_pending_request(future)
                del self._in_flight[cid]
                entry[4] = None
                self._replies.append(
                    Reply(cid, False, f"no answer from {client.srv_name}", timed_out=True)
                )

    # ------------------------------------------------------------------ outputs
    def _publish_confirmation(self, c) -> None:
        self.confirmations.append(c)
        values = [
            ("label", c.label),
            ("destination_asked", c.destination_asked),
            ("destination_reached", c.destination_reached),
            ("result", c.result),
            ("seq", str(c.seq)),
            ("t", f"{c.t:.6f}"),
        ]
        level = LEVELS.get(c.result, DiagnosticStatus.WARN)
        self._publish(
            self._pub_confirm,
            DiagnosticStatus(
                level=level,
                name=c.label,
                message=c.result,
                hardware_id=self.get_fully_qualified_name(),
                values=[KeyValue(key=k, value=v) for k, v in values],
            ),
        )

    def diagnostic_status(self) -> DiagnosticStatus:
        name = f"{self.get_fully_qualified_name()}: controller"
        if self.logic is None:
            return DiagnosticStatus(
                level=DiagnosticStatus.STALE,
                name=name,
                message="waiting for the cell's parameters",
                hardware_id=self.get_fully_qualified_name(),
            )
        st = self.logic.status()
        level = DiagnosticStatus.OK if st["state"] == "running" else DiagnosticStatus.ERROR
        message = (
            st["state"] if st["fault"] is None else f"{st['state']}: {st['fault']['message']}"
        )
        values = {
            "state": st["state"],
            "cell_packml": st["cell_packml"] or "unknown",
            "tracked": st["tracked"],
        }
        values.update(st["counts"])
        values.update({f"fault_{k}": v for k, v in st["faults"].items()})
        values.update(
            {
                "scan_wall_p50_ms": f"{st['scan_wall_p50_ms']:.3f}",
                "scan_wall_p99_ms": f"{st['scan_wall_p99_ms']:.3f}",
                "clock_lag_max_ms": f"{st['clock_lag_max_ms']:.1f}",
                "scan_wall_max_ms": f"{st['scan_wall_max_ms']:.3f}",
                "predictions": st["predictions"],
                "prediction_wall_s": f"{st['prediction_wall_s']:.3f}",
                "min_gap_m": f"{self.min_gaps['worst']:.3f}",
                "min_gap_same_side_m": f"{self.min_gaps['left->left']:.3f}",
                "nominal_parcel_length_m": f"{self.values['nominal_parcel_length']:g}",
                "routing": ";".join(st["routing"]),
                "bad_messages": self.n_bad_messages,
                "callback_errors": getattr(self, "callback_errors", 0),
            }
        )
        return DiagnosticStatus(
            level=level,
            name=name,
            message=message,
            hardware_id=self.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
        )

    def _publish_diagnostics(self) -> None:
        # who publishes the simulated clock, checked here (at each diagnostics period)
        # rather than per scan: more than one is a clock fault the next scan reports
        if self.get_parameter("use_sim_time").value:
            # one count a simulated second for every node of this process (a line's 48)
            t_ns = self.get_clock().now().nanoseconds
            self._clock_sources = publisher_count(self, "/clock", t_ns)
        msg = DiagnosticArray(status=[self.diagnostic_status()])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._publish(self._pub_diag, msg)

    def _publish(self, publisher, msg) -> None:
        """Publish ``msg``, count it per topic and record it (stamped with this node's clock)."""
        t_ns = self.get_clock().now().nanoseconds if self.recorder is not None else 0
        publish_recorded(publisher, msg, self.recorder, t_ns)
        self.published[publisher.topic_name] += 1

    def destroy_node(self):
        """Finish the recording, then destroy the node."""
        if self.recorder is not None:
            release_recorder(self.recorder)
            self.recorder = None
        return super().destroy_node()

    # ------------------------------------------------------------------ services and parameters
    def _srv_reset(self, request, response):
        if self.logic is None:
            response.success, response.message = (
                False,
                "not running yet: waiting for the cell's parameters",
            )
            return response
        response.success, response.message = True, self.logic.request_reset()
        return response

    def _srv_estop(self, request, response):
        if not request.data:
            response.success, response.message = False, "refused: release an e-stop with ~/reset"
            return response
        if self.logic is None:
            response.success, response.message = (
                False,
                "not running yet: waiting for the cell's parameters",
            )
            return response
        response.success, response.message = True, self.logic.request_estop()
        return response

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        problem = parameter_problem(self, parameters)
        if problem:
            return SetParametersResult(successful=False, reason=problem)
        for p in parameters:
            # switching clocks under a running PLC turns every time it holds into nonsense
            # (false jams, a storm of "time went back"); it is fixed at start-up
            if p.name == "use_sim_time" and p.value != self.get_parameter("use_sim_time").value:
                return SetParametersResult(
                    successful=False,
                    reason="use_sim_time is read-only while the controller runs: it keeps the "
                    "clock it started with (restart the node to change it)",
                )
        changes = {p.name: plain(p.value) for p in parameters if p.name in SPECS}
        for name in changes:
            if name not in ROUTING_KEYS:
                return SetParametersResult(
                    successful=False, reason=f"parameter {name!r} is read-only"
                )
        if not changes:
            return SetParametersResult(successful=True)
        merged = {k: changes.get(k, self.values[k]) for k in ROUTING_KEYS}
        try:
            if not isinstance(merged["routing.rules"], list):
                raise RoutingError("routing.rules must be a list of strings")
            RoutingTable(
                merged["routing.rules"], merged["routing.default"], merged["reject_destination"]
            )
        except (RoutingError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _post_set_parameters(self, parameters) -> None:
        changed = False
        for p in parameters:
            if p.name in ROUTING_KEYS:
                self.values[p.name] = plain(p.value)
                changed = True
        if changed and self.logic is not None:
            # a new table replaces the old one, run-time updates included
            self.logic.routing = RoutingTable(
                self.values["routing.rules"],
                self.values["routing.default"],
                self.values["reject_destination"],
            )
            self.get_logger().info(f"routing table: {'; '.join(self.logic.routing.rules())}")


def main(args=None, stop=None):
    """
    Run the node; ``stop``: the executable's StopSignals, when it installed them first.

    Parameters
    ----------
    args : list of str or argparse.Namespace
        The command line, or the parsed arguments.
    stop : StopSignals, optional
        The executable's signal handlers.

    """
    run_node(ControllerNode, "controller_node", (ValueError,), args, stop)


if __name__ == "__main__":
    main()
