"""
The simulation node ``sorter_sim``: the sorter cell on ROS 2, driven like hardware.

A thin shell around ``sorter_sim.runtime.cell.Cell``: parameters (declared from
``params.SCHEMA``) become a ``CellParams``, services and the ``alpha_deg``
parameter become actuator commands, and what the cell reports (sensor edges,
scanner reads, outcomes, poses, actuator state) becomes messages on the topics
of the interface contract (README, "Simulation node"). Time runs in one of
three modes: ``realtime`` (a wall timer, scaled by ``real_time_factor``),
``fast`` (as fast as possible, in slices that hand the executor back so
services and parameters are served) and ``lockstep`` (one control period per
``step`` call). The node publishes ``/clock``; it must not itself run on
``use_sim_time``.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import Counter

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Bool, String, UInt32, UInt32MultiArray
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import Marker, MarkerArray

from sorter_ros.env import run_node
from sorter_ros.interface import (
    EVENT_QOS,
    SENSOR_QOS,
    SERVICE_QOS,
    STREAM_QOS,
    accept_integers_for_doubles,
    declare_typed,
    parameter_problem,
    plain,
    quiet_publisher_events,
)
from sorter_ros.interface import descriptor as ros_descriptor
from sorter_ros.recording import open_recorder, publish_recorded, release_recorder
from sorter_sim.frontends.cdr import (
    JointStateCdr,
    bool_cdr,
    clock_cdr,
    pose_array_cdr,
    stamp,
    uint32_array_cdr,
)
from sorter_sim.frontends.fieldbus import IOImage, ScannerQueue
from sorter_sim.frontends.fieldbus_process import FieldbusProcess
from sorter_sim.frontends.live_view import PARCEL_HEIGHT, STATE_COLOURS, CellLayout
from sorter_sim.frontends.live_view_process import LiveViewProcess
from sorter_sim.model.description import shown
from sorter_sim.model.io_map import io_map
from sorter_sim.model.packml import COMMAND_BY_NUMBER as PACKML_BY_NUMBER
from sorter_sim.model.packml import COMMANDS as PACKML_COMMANDS
from sorter_sim.runtime.cell import (
    STATE_NAMES,
    WATCHDOG_REFUSAL,
    Cell,
    LabelRead,
    Outcome,
    ParcelSpec,
    SensorEdge,
    WatchdogTrip,
)
from sorter_sim.runtime.faults import apply_fault
from sorter_sim.runtime.params import SCHEMA, SPECS, CellParams, ParamError
from sorter_sim.runtime.warmup import warm_cell

NODE_NAME = 'sorter_sim'
FRAME_ID = 'conveyor'  # the cell's frame in the root namespace (see frame_id)
RECORDING_METADATA = 'sorter_sim parameters'  # the metadata record of the cell's parameters
MAX_CATCH_UP_S = 0.25  # realtime mode: simulated time one tick may catch up

# status/<bit>: std_msgs/Bool each; fault = estop or jam or watchdog
STATUS_BITS = ('estop', 'jam', 'watchdog', 'fault')

# induct message keys -> (ParcelSpec field, conversion)
INDUCT_KEYS = ('label', 'A', 'B', 'm', 'phi0_deg', 'y')


def descriptor(spec) -> ParameterDescriptor:
    """
    Return the ROS descriptor of a schema entry: type, description, range, read-only.

    Parameters
    ----------
    spec : ParamSpec
        The schema entry.

    Returns
    -------
    ParameterDescriptor
        Its descriptor.

    """
    units = f' [{spec.units}]' if spec.units else ''
    return ros_descriptor(
        spec.name,
        spec.type,
        spec.description + units,
        lo=spec.lo,
        hi=spec.hi,
        read_only=spec.read_only,
        constraints=spec.allowed,
    )


def burst_limit(watchdog_timeout: float) -> float:
    """
    Return the simulated time one realtime tick may run at most [s].

    A quarter of the watchdog's timeout, so that heartbeats are taken between bursts
    (see ``realtime_tick``); MAX_CATCH_UP_S without a watchdog.

    Parameters
    ----------
    watchdog_timeout : float
        The cell's watchdog timeout [s], 0 for none.

    Returns
    -------
    float
        The longest burst [s].

    """
    return min(MAX_CATCH_UP_S, watchdog_timeout / 4) if watchdog_timeout > 0 else MAX_CATCH_UP_S


def realtime_tick(node, clock, real_time_factor: float, burst_s: float) -> None:
    """
    Run the simulated time the wall clock asks for since the last tick, in bursts.

    Shared by a cell and a line: ``node`` has ``advance(n)``, ``_wall_ref`` (the realtime
    anchor, None before the first tick) and a logger; ``clock`` has the period index
    ``k`` and the period ``dt``.

    Parameters
    ----------
    node : rclpy.node.Node
        The node that advances.
    clock : Cell or Line
        What it advances.
    real_time_factor : float
        Simulated seconds per wall second.
    burst_s : float
        The most simulated time one tick runs (``burst_limit``).

    """
    if node._wall_ref is None:
        # anchor simulated to wall time after one period has run: that first period
        # loads the compiled kernels (seconds on a fresh clone), start-up rather than
        # simulated time to drop
        node.advance(1)
        node._wall_ref = (time.monotonic(), clock.k)
        return
    now = time.monotonic()
    wall0, k0 = node._wall_ref
    target = k0 + int((now - wall0) * real_time_factor / clock.dt)
    n = target - clock.k
    limit = max(1, int(MAX_CATCH_UP_S / clock.dt))
    if n > limit:
        # too slow for this real-time factor: keep at most MAX_CATCH_UP_S to catch up
        # and drop the rest, rather than trying to catch up without end
        node.get_logger().warning(
            f'cannot keep real_time_factor {real_time_factor:g}: dropping '
            f'{(n - limit) * clock.dt:.3f} s of simulated time',
            throttle_duration_sec=5.0,
        )
        node._wall_ref = (now, clock.k + limit)
        n = limit
    # Catch up in bursts the controller can follow: during one burst no heartbeat can
    # reach the cell (it waits in the executor's queue) and the controller, on the
    # cell's clock, sees the burst's simulated time only afterwards. A burst as long as
    # the watchdog's timeout trips it with a healthy controller, as a host that stalls
    # the node for a quarter second can make it; the rest of the lag is run in the
    # next ticks, after the executor has taken what came in meanwhile.
    burst = max(1, int(burst_s / clock.dt))
    if n > 0:
        node.advance(min(n, burst))


def _time_msg(t_ns: int) -> Time:
    sec, nsec = stamp(t_ns)
    return Time(sec=sec, nanosec=nsec)


class SimNode(Node):
    """The cell's ROS face; see the module docstring and the README interface table."""

    # ``sim_node`` is spun by rclpy's events executor: the single-threaded one builds a
    # wait set of every entity in Python on each pass, a tenth of the node's time in
    # fast mode (bench_cell.py: 45 -> 53 times real time). Its timers are on the wall
    # clock (the cell owns simulated time), which the events executor serves on time.
    executor_kind = 'events'

    def __init__(self, *, station: bool = False, not_mine=frozenset(), **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        # a line's options reach its stations through the process's arguments too
        # (``not_mine``, given by the line): they are the line's, not unknown names
        explicit = {p.name for p in kwargs.get('parameter_overrides') or ()}
        for name in set(not_mine) - explicit:
            self._parameter_overrides.pop(name, None)
        # a station of a line (``frontends/line_node.py``): the line advances its cell
        # with the others and publishes the one clock; this node publishes the rest
        self.station = station
        self.params = self._declare_parameters()
        if station:
            on = [
                name
                for name in ('foxglove_port', 'modbus_port', 'opcua_port', 's7_port')
                if getattr(self.params, name)
            ]
            if on:
                raise ParamError(
                    f'parameter(s) {", ".join(on)}: a station of a line has no live view or '
                    'fieldbus server of its own: set the line\'s (its stations are unit ids '
                    'and folders of one server); leave them 0'
                )
        warm_s = warm_cell(self.params)
        if warm_s > 1.0:
            self.get_logger().info(
                f'compiled the model\'s kernels in {warm_s:.1f} s (once per clone; cached)'
            )
        ns = self.get_namespace().strip('/')
        self.frame_id = self.params.frame_id or (f'{ns}/{FRAME_ID}' if ns else FRAME_ID)
        self.cell = Cell(self.params)
        p = self.params
        self.published = Counter()  # messages per topic, counted where they are published
        self._topic_names = {}
        self.recorder = None
        self.live_view = None
        self.io_image = None  # the fieldbus I/O image, when a server is on
        self.fieldbus = None
        self._open_outputs()
        self._pub_poses = self._publisher(PoseArray, 'parcels/poses', STREAM_QOS)
        self._pub_ids = self._publisher(UInt32MultiArray, 'parcels/ids', STREAM_QOS)
        self._pub_markers = self._publisher(MarkerArray, 'parcels/markers', STREAM_QOS)
        self._pub_sensor = {
            name: self._publisher(Bool, f'sensors/{name}', SENSOR_QOS)
            for name in self.cell.sensor_names
        }
        self._pub_edges = self._publisher(TimeReference, 'sensors/edges', EVENT_QOS)
        self._pub_label = self._publisher(String, 'scanner/label', EVENT_QOS)
        self._pub_diverter = self._publisher(JointState, 'diverter/state', STREAM_QOS)
        self._pub_outcomes = self._publisher(DiagnosticStatus, 'sort/outcomes', EVENT_QOS)
        # absolute, where diagnostic aggregators and tools look; the status names the node
        self._pub_diag = self._publisher(DiagnosticArray, '/diagnostics', STREAM_QOS)
        # the cell's state bits, as a PLC reads them: latched, published when they change
        self._pub_status = {
            name: self._publisher(Bool, f'status/{name}', SENSOR_QOS) for name in STATUS_BITS
        }
        self._status_sent = None
        self._packml_sent = None
        # the machine state (PackML), latched: a late subscriber gets the state now
        self._pub_packml = self._publisher(String, 'status/packml', SENSOR_QOS)
        for command in PACKML_COMMANDS:
            self.create_service(
                Trigger,
                f'packml/{command}',
                lambda request, response, c=command: self._srv_packml(c, response),
                qos_profile=SERVICE_QOS,
            )
        self._safe_alpha_set = False  # the watchdog itself sets alpha_deg to its safe value
        self._pub_clock = None if station else self._publisher(Clock, '/clock', STREAM_QOS)
        self._clock_publishers_warned = 0
        self.create_service(SetBool, 'diverter/popup', self._srv_popup, qos_profile=SERVICE_QOS)
        self.create_service(SetBool, 'estop', self._srv_estop, qos_profile=SERVICE_QOS)
        self.create_service(Trigger, 'reset', self._srv_reset, qos_profile=SERVICE_QOS)
        self.create_service(Trigger, 'step', self._srv_step, qos_profile=SERVICE_QOS)
        self.create_subscription(DiagnosticStatus, 'parcels/induct', self._on_induct, EVENT_QOS)
        self.create_subscription(UInt32, 'controller/heartbeat', self._on_heartbeat, STREAM_QOS)
        self.create_subscription(DiagnosticStatus, 'faults/inject', self._on_fault, EVENT_QOS)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._post_set_parameters)
        # the messages of every pose period go out as CDR written here (cdr.py)
        self._joint_state_cdr = JointStateCdr(self.frame_id, ('disk_angle', 'popup_stroke'))
        # bookkeeping for diagnostics
        self._cost = {'step_s': 0.0, 'periods': 0, 'publish_s': 0.0, 'messages': 0}
        self._diag_ref = (time.perf_counter(), self.cell.k)
        self.n_messages = 0
        self.n_marker_arrays = 0
        self.faults_injected = 0
        # the initial state: every sensor clear, actuators where they are, t = 0
        self._publish_status()
        self._publish_sensors()
        self._publish_diverter()
        self._publish_clock()
        self._wall_ref = None  # (wall time, period index) of the realtime anchor: first tick
        # simulated time one realtime tick runs at most: a quarter of the watchdog's
        # timeout, so that heartbeats are taken between bursts (see _tick_realtime)
        self._burst_s = burst_limit(p.watchdog_timeout)
        if station:
            self._timer = None
        elif p.time_mode == 'realtime':
            self._timer = self.create_timer(p.wall_tick, self._tick_realtime)
        elif p.time_mode == 'fast':
            # a zero-period timer is ready at every executor pass: each call runs a slice
            # of simulated time (fast_slice), then services, parameter changes and other
            # callbacks of the executor get their turn
            self._timer = self.create_timer(0.0, self._tick_fast)
        else:
            self._timer = None
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(
            f'sorter cell ready: {p.time_mode} mode, control period {p.control_period * 1e3:g} '
            f'ms, belt {p.belt_speed:g} m/s x {p.belt_width:g} m, disk field '
            f'{p.disk_field_length:g} m, sensors {", ".join(self.cell.sensor_names)}'
        )

    def _open_outputs(self) -> None:
        """Open the recording and the live view the parameters ask for; ParamError if not."""
        p = self.params
        try:
            if p.record_path:
                try:
                    self.recorder = open_recorder(p.record_path, self.get_logger().error)
                except ValueError as exc:
                    raise ParamError(f'parameter \'record_path\': {exc}') from None
                # the cell's parameters travel with the recording: `sorter replay` draws the
                # cell from them, with nothing but the file
                self.recorder.add_metadata(
                    RECORDING_METADATA,
                    {
                        'node': self.get_fully_qualified_name(),
                        **{k: json.dumps(v) for k, v in p.as_values().items()},
                    },
                )
            if p.foxglove_port:
                ns = self.get_namespace().rstrip('/')
                try:
                    self.live_view = LiveViewProcess(
                        self.live_layout(),
                        host=p.foxglove_host,
                        port=p.foxglove_port,
                        prefix=f'{ns}/live',
                        max_rate_hz=p.foxglove_rate_hz,
                        on_failure=self.get_logger().error,
                    )
                except ValueError as exc:
                    raise ParamError(f'parameter \'foxglove_port\': {exc}') from None
                self.get_logger().info(
                    f'live view: Foxglove WebSocket server on '
                    f'ws://{p.foxglove_host}:{self.live_view.port}'
                )
            if p.modbus_port or p.opcua_port or p.s7_port:
                self._open_fieldbus()
        except ParamError:
            self._close_outputs()
            raise

    def attach_io_image(self) -> IOImage:
        """
        Give this node a fieldbus I/O image, exchanged every period, and return it.

        A cell serves it itself (``modbus_port`` / ``opcua_port``); a line's stations
        are served together by the line's servers (``LineNode``).
        """
        self.io_image = IOImage(io_map(self.cell.sensor_names), self._initial_outputs())
        self._start_io_image()
        return self.io_image

    def _initial_outputs(self) -> dict:
        return {
            'diverter.popup': False,
            'cell.reset': False,
            'belt.run': True,
            'scanner.ack': False,
            'cell.estop': False,
            'diverter.alpha_setpoint': self.params.alpha_deg,
            'plc.heartbeat': 0,
            'packml.command': 0,  # none yet; a write issues one
        }

    def _start_io_image(self) -> None:
        self._scanner = ScannerQueue()
        self._belt_travel = 0.0
        self._io_events = []  # what the periods of the current I/O cycle reported so far
        self._io_refused = 0
        self._servers_ended_said = False
        self._refresh_io([])

    def io_before_period(self) -> None:
        """Apply the outputs the PLC wrote, at the start of a period (a line's station)."""
        self._publish_events(self._apply_io())
        self._belt_travel += self.cell.belt_velocity * self.cell.dt

    def io_after_period(self, events) -> None:
        """Latch the inputs at the end of a period (a line's station)."""
        self._refresh_io(events)

    def _open_fieldbus(self) -> None:
        p = self.params
        # the servers run in a process of their own, sharing the image: a client's request
        # never holds the physics (sorter_sim/frontends/fieldbus_process.py)
        self.fieldbus = FieldbusProcess(
            io_map(self.cell.sensor_names),
            self._initial_outputs(),
            modbus=(p.modbus_host, p.modbus_port) if p.modbus_port else None,
            opcua=(p.opcua_host, p.opcua_port) if p.opcua_port else None,
            s7=(p.s7_host, p.s7_port) if p.s7_port else None,
            cell_name=self.get_namespace().strip('/').replace('/', '_') or 'cell',
        )
        self.io_image = self.fieldbus.image
        self._start_io_image()
        try:
            self.fieldbus.start()
        except ValueError as exc:
            self.fieldbus = None
            text = str(exc)
            key = (
                'modbus_port' if 'Modbus' in text else 's7_port' if 'S7' in text else 'opcua_port'
            )
            raise ParamError(f'parameter {key!r}: {exc}') from None
        served = []
        if self.fieldbus.modbus_port:
            served.append(f'Modbus TCP on {p.modbus_host}:{self.fieldbus.modbus_port}')
        if self.fieldbus.opcua_endpoint:
            served.append(f'OPC UA on {self.fieldbus.opcua_endpoint}')
        if self.fieldbus.s7_port:
            served.append(f'S7 on {p.s7_host}:{self.fieldbus.s7_port} (DB1 inputs, DB2 outputs)')
        self.get_logger().info('fieldbus I/O image: ' + ', '.join(served))

    def _apply_io(self) -> list:
        """
        Apply what the PLC wrote since the last period (outputs of the I/O image).

        Returns the sensor edges that follow (jammed parcels a reset or a PackML command
        took off), to be published in order with the period's own.
        """
        out, rises = self.io_image.take_outputs()
        if not out:
            return []
        c = self.cell
        edges = []
        for name, value in out.items():
            ok = True
            if name == 'diverter.popup':
                ok, _ = c.popup(bool(value))
            elif name == 'belt.run':
                ok, _ = c.run_belt(bool(value))
            elif name == 'plc.heartbeat':
                # a rewrite of the same value reaches here too: the cell feeds its watchdog
                # only with a changed counter
                if c.heartbeat(int(value)):
                    self.get_logger().info('PLC heartbeat back: watchdog cleared')
                    self._publish_status()
            elif name == 'diverter.alpha_setpoint':
                result = self.set_parameters([Parameter('alpha_deg', value=float(value))])[0]
                ok = result.successful
            elif name == 'packml.command':
                ok, text = c.packml_command(PACKML_BY_NUMBER[int(value)])
                if ok:
                    edges += c.take_packml_edges()
                else:
                    self.get_logger().warning(f'packml.command from the PLC: {text}')
            self._io_refused += not ok
        if 'cell.estop' in rises:
            c.engage_estop()
            self._publish_status()
            self.get_logger().warning('e-stop engaged by the PLC: belt stopped, disks dropping')
        if 'cell.reset' in rises:
            edges += c.reset()
        if 'scanner.ack' in rises:
            self._scanner.ack()
        return edges

    def _refresh_io(self, events) -> None:
        """Latch the cell's state into the inputs of the I/O image (end of a period)."""
        c = self.cell
        values = {}
        for e in events:
            if isinstance(e, SensorEdge):
                values[f'sensor.{e.sensor}'] = e.blocked
                edge = 'rise' if e.blocked else 'fall'
                values[f'sensor.{e.sensor}.{edge}_time'] = e.t_ns * 1e-9
            elif isinstance(e, LabelRead):
                self._scanner.read(e.label)
        if not events and c.k == 0:
            values.update({f'sensor.{n}': b for n, b in c.sensor_states().items()})
        q = self._scanner
        stroke = c.stroke
        values.update(
            {
                'scanner.ready': bool(q.waiting),
                'scanner.label': q.waiting[0] if q.waiting else '',
                'scanner.sequence': q.sequence,
                'diverter.up': stroke >= 0.999,
                'diverter.down': stroke <= 0.001,
                'diverter.alpha': math.degrees(c.alpha),
                'diverter.stroke': stroke,
                'status.estop': c.estop,
                'status.jam': c.jam,
                'status.watchdog': c.watchdog_tripped,
                'status.fault': bool(c.faults),
                'packml.state': c.packml.number,
                'belt.encoder': self._belt_travel,
                'cell.time': c.t_ns * 1e-9,
            }
        )
        self.io_image.refresh_inputs(values)

    def _close_outputs(self) -> None:
        # the servers stop side by side, each within its bound, so that a node with
        # clients still connected stops in well under ros2 launch's 10 s
        stopping = None
        if self.fieldbus is not None:
            stopping = threading.Thread(target=self.fieldbus.stop, name='fieldbus-stop')
            stopping.start()
        if self.live_view is not None:
            self.live_view.close()
            self.live_view = None
        if stopping is not None:
            stopping.join()
            self.fieldbus = None
        if self.recorder is not None:
            release_recorder(self.recorder)
            self.recorder = None

    def destroy_node(self):
        """Finish the recording and stop the live view, then destroy the node."""
        self._close_outputs()
        return super().destroy_node()

    # ------------------------------------------------------------------ parameters
    def _declare_parameters(self) -> CellParams:
        accept_integers_for_doubles(self, {spec.name: descriptor(spec).type for spec in SCHEMA})
        values = {}
        for spec in SCHEMA:
            try:
                param = declare_typed(self, spec.name, spec.default, descriptor(spec))
            except (InvalidParameterTypeException, InvalidParameterValueException):
                given = self._parameter_overrides[spec.name]
                raise ParamError(
                    f'parameter {spec.name!r} must be {spec.allowed}, got {plain(given.value)!r} '
                    f'({given.type_.name.lower()})'
                ) from None
            values[spec.name] = plain(param.value)
        # rclpy ignores values given for names nobody declares: a misspelt parameter in a
        # params file would silently keep its default, so name it instead
        given = getattr(self, '_parameter_overrides', {})
        unknown = sorted(
            n for n in given if not self.has_parameter(n) and not n.startswith('qos_overrides.')
        )
        if unknown:
            raise ParamError(
                f'unknown parameter(s) {", ".join(map(repr, unknown))} for '
                f'{NODE_NAME}; the README table lists the allowed names'
            )
        if self.get_parameter('use_sim_time').value:
            raise ParamError(
                'parameter \'use_sim_time\' must be false: this node is the '
                'simulation clock (it publishes /clock)'
            )
        return CellParams.from_values(values)

    def _changes(self, parameters) -> dict:
        return {p.name: plain(p.value) for p in parameters if p.name in SPECS}

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        """Validate a run-time change as a whole; nothing changes unless all of it is valid."""
        problem = parameter_problem(self, parameters)
        if problem:
            return SetParametersResult(successful=False, reason=problem)
        for p in parameters:
            if p.name == 'use_sim_time' and p.value:
                return SetParametersResult(
                    successful=False,
                    reason='use_sim_time must stay false: this node is the simulation clock',
                )
        changes = self._changes(parameters)
        if not changes:
            return SetParametersResult(successful=True)
        if 'alpha_deg' in changes and self.cell.estop:
            return SetParametersResult(
                successful=False, reason='refused: e-stop engaged (call reset first)'
            )
        if 'alpha_deg' in changes and self.cell.watchdog_tripped and not self._safe_alpha_set:
            return SetParametersResult(successful=False, reason=WATCHDOG_REFUSAL)
        try:
            self.params.with_changes(changes)
        except ParamError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _post_set_parameters(self, parameters) -> None:
        changes = self._changes(parameters)
        if not changes:
            return
        self.params = self.params.with_changes(changes)
        self.cell.update_params(self.params)
        if 'real_time_factor' in changes:
            self._wall_ref = None

    # ------------------------------------------------------------------ time
    def _tick_realtime(self) -> None:
        realtime_tick(self, self.cell, self.params.real_time_factor, self._burst_s)

    def _tick_fast(self) -> None:
        self.advance(self.params.fast_slice_periods)

    def advance(self, n: int) -> None:
        """
        Advance ``n`` control periods, publishing everything that falls due on the way.

        Parameters
        ----------
        n : int
            How many control periods.

        """
        if self.station:
            raise RuntimeError('a station is advanced by its line (LineNode.advance)')
        p = self.params
        cycle = p.io_stride if self.io_image is not None else 0
        # a chunk ends where an I/O cycle of several periods does (one of a single period
        # is run period by period inside the chunk)
        strides = (p.pose_stride, p.marker_stride, p.heartbeat_stride) + (
            (cycle,) if cycle > 1 else ()
        )
        while n > 0:
            k = self.cell.k
            m = min([n] + [s - k % s for s in strides])
            t0 = time.perf_counter()
            if self.io_image is None:
                events = self.cell.advance(m)
            elif cycle == 1:
                # the I/O image is exchanged every period; what the periods report is
                # published together after them, as without a fieldbus
                events = []
                for _ in range(m):
                    events += self._apply_io()
                    self._belt_travel += self.cell.belt_velocity * self.cell.dt
                    period = self.cell.advance(1)
                    self._refresh_io(period)
                    events += period
            else:
                # an I/O cycle of several periods, run by the kernel in one go: the outputs
                # at its start, the inputs latched at its end with what the whole cycle
                # reported (a cycle may span several of these chunks: strides split it)
                events = self._apply_io() if k % cycle == 0 else []
                v_dt = self.cell.belt_velocity * self.cell.dt  # the belt is set between calls
                for _ in range(m):
                    self._belt_travel += v_dt  # summed per period, as an exchange per period does
                chunk = self.cell.advance(m)
                self._io_events += chunk
                if self.cell.k % cycle == 0:
                    self._refresh_io(self._io_events)
                    self._io_events = []
                events += chunk
            t1 = time.perf_counter()
            self._cost['step_s'] += t1 - t0
            self._cost['periods'] += m
            n -= m
            self.publish_period(events)
            self._cost['publish_s'] += time.perf_counter() - t1

    def publish_period(self, events) -> None:
        """
        Publish what the periods just run report, and what falls due at the period reached.

        Parameters
        ----------
        events : list
            The cell's events over those periods.

        """
        p = self.params
        k = self.cell.k
        self._publish_events(events)
        if k % p.pose_stride == 0:
            self._publish_poses()
            self._publish_diverter()
        if k % p.marker_stride == 0 and self._pub_markers.get_subscription_count() > 0:
            self._publish_markers()
        if self.live_view is not None and k % p.pose_stride == 0 and self.live_view.due():
            self._update_live_view()
        if k % p.heartbeat_stride == 0:
            self._publish_sensors()
        self._publish_clock()

    # ------------------------------------------------------------------ publishing
    def _publisher(self, msg_type, topic: str, qos):
        return self.create_publisher(
            msg_type, topic, qos, event_callbacks=quiet_publisher_events()
        )

    def _publish(self, publisher, msg) -> None:
        """Publish ``msg`` (or its CDR bytes), count it per topic and record it."""
        publish_recorded(publisher, msg, self.recorder, self.cell.t_ns)
        self._cost['messages'] += 1
        self.n_messages += 1
        # rclpy's topic_name asks the C handle every time: once per publisher is enough
        topic = self._topic_names.get(publisher)
        if topic is None:
            topic = self._topic_names[publisher] = publisher.topic_name
        self.published[topic] += 1

    def live_layout(self) -> CellLayout:
        """Return where things are in this cell's frame, for a live view."""
        p = self.params
        return CellLayout(
            frame_id=self.frame_id,
            belt_width=p.belt_width,
            disk_field_length=p.disk_field_length,
            chute_x_range=p.chute_x_range,
            induct_x=p.induct_x,
            exit_x=p.exit_x,
            scanner_x=p.scanner_x,
            photo_eyes=tuple(zip(p.photo_eyes_names, p.photo_eyes_x)),
        )

    def live_state(self) -> dict:
        """Return what a live view shows of this cell now (``LiveView.update``'s values)."""
        c = self.cell
        return {
            'parcels': c.parcels(),
            'motion': c.parcel_motion(),
            'alpha': c.alpha,
            'stroke': c.stroke,
            'sensors': c.sensor_states(),
        }

    def _update_live_view(self) -> None:
        self.live_view.update(self.cell.t_ns, state_names=STATE_NAMES, **self.live_state())

    def _publish_status(self) -> None:
        """
        Publish the state bits (status/estop, status/jam, status/fault) if one changed.

        Only on change: a reset publishes the cleared bits before its reply, and no
        periodic copy of an old value can follow it.
        """
        bits = {
            'estop': self.cell.estop,
            'jam': self.cell.jam,
            'watchdog': self.cell.watchdog_tripped,
        }
        bits['fault'] = bits['estop'] or bits['jam'] or bits['watchdog']
        if bits != self._status_sent:
            for name in STATUS_BITS:
                self._publish(self._pub_status[name], bool_cdr(bits[name]))
            self._status_sent = bits
        self._publish_packml()

    def _publish_packml(self) -> None:
        """Bring the PackML state up to the cell's conditions; publish each transition."""
        machine = self.cell.packml
        if self.cell.packml_dirty:
            self.cell.update_packml()  # a command or a fault since the cell last looked
        if self._packml_sent is None:
            machine.take_transitions()  # the power-up sequence: the state reached is enough
        else:
            for tr in machine.take_transitions():
                self.get_logger().info(
                    f'PackML {tr.previous} -> {tr.state} ({tr.cause}) at t = '
                    f'{tr.t_ns * 1e-9:.3f} s'
                )
                self._publish(self._pub_packml, String(data=tr.state))
                self._packml_sent = tr.state
        if machine.state != self._packml_sent:
            self._publish(self._pub_packml, String(data=machine.state))
            self._packml_sent = machine.state

    def _publish_events(self, events) -> None:
        self._publish_status()
        for e in events:
            if isinstance(e, SensorEdge):
                self._publish(self._pub_sensor[e.sensor], bool_cdr(e.blocked))
                ref = TimeReference(source='rising' if e.blocked else 'falling')
                ref.header.stamp = _time_msg(e.t_ns)
                ref.header.frame_id = f'{self.frame_id}/{e.sensor}'
                ref.time_ref = _time_msg(e.t_ns)
                self._publish(self._pub_edges, ref)
            elif isinstance(e, LabelRead):
                self._publish(self._pub_label, String(data=e.label))
            elif isinstance(e, Outcome):
                self._publish(self._pub_outcomes, self._outcome_msg(e))
                if e.jammed:
                    self.get_logger().warning(
                        f'jam: parcel {e.parcel_id} ({e.label}) stopped at '
                        f'x = {e.x:.3f} m, y = {e.y:.3f} m ({e.cause})'
                    )
            elif isinstance(e, WatchdogTrip):
                self._command_safe_alpha()
                self.get_logger().error(
                    f'watchdog: no controller heartbeat for {e.silent_s:.3f} s (simulated); '
                    f'disks dropping, disk angle to {self.params.safe_alpha_deg:g} deg until '
                    f'heartbeats return'
                )
        if any(isinstance(e, WatchdogTrip) for e in events):
            self._publish_status()

    def _outcome_msg(self, e: Outcome) -> DiagnosticStatus:
        values = [
            ('id', str(e.parcel_id)),
            ('label', e.label),
            ('exit', e.exit),
            ('t', f'{e.t_ns * 1e-9:.9f}'),
            ('jammed', 'true' if e.jammed else 'false'),
            ('x_exit', f'{e.x:.6f}'),
            ('y_exit', f'{e.y:.6f}'),
        ]
        if e.cause:
            values.append(('cause', e.cause))
        return DiagnosticStatus(
            level=DiagnosticStatus.WARN if e.jammed else DiagnosticStatus.OK,
            name=f'parcel/{e.parcel_id}',
            message=e.exit,
            hardware_id=self.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=v) for k, v in values],
        )

    def _publish_sensors(self) -> None:
        for name, blocked in self.cell.sensor_states().items():
            self._publish(self._pub_sensor[name], bool_cdr(blocked))

    def _publish_poses(self) -> None:
        parcels = self.cell.parcels()
        self._publish(self._pub_ids, uint32_array_cdr(parcels['id']))
        self._publish(
            self._pub_poses,
            pose_array_cdr(
                self.cell.t_ns, self.frame_id, parcels['x'], parcels['y'], parcels['phi']
            ),
        )

    def _publish_diverter(self) -> None:
        c = self.cell
        msg = self._joint_state_cdr(c.t_ns, (c.alpha, c.stroke), (c.alpha_rate, c.stroke_rate))
        self._publish(self._pub_diverter, msg)

    def _publish_markers(self) -> None:
        parcels = self.cell.parcels()
        stamp_msg = _time_msg(self.cell.t_ns)
        clear = Marker(action=Marker.DELETEALL, ns='parcels')
        clear.header.frame_id = self.frame_id
        markers = [clear]
        for pid, x, y, phi, A, B, code in zip(
            *(parcels[k].tolist() for k in ('id', 'x', 'y', 'phi', 'A', 'B', 'state'))
        ):
            m = Marker(ns='parcels', id=int(pid), type=Marker.CUBE, action=Marker.ADD)
            m.header.frame_id = self.frame_id
            m.header.stamp = stamp_msg
            m.pose.position.x = x
            m.pose.position.y = y
            m.pose.position.z = 0.5 * PARCEL_HEIGHT
            m.pose.orientation.z = math.sin(0.5 * phi)
            m.pose.orientation.w = math.cos(0.5 * phi)
            m.scale.x, m.scale.y, m.scale.z = A, B, PARCEL_HEIGHT
            r, g, b = STATE_COLOURS[STATE_NAMES[code]]
            m.color.r, m.color.g, m.color.b, m.color.a = r, g, b, 1.0
            m.text = STATE_NAMES[code]
            markers.append(m)
        self._publish(self._pub_markers, MarkerArray(markers=markers))
        self.n_marker_arrays += 1

    def _publish_clock(self) -> None:
        if self._pub_clock is None:
            return  # a station: the line publishes the clock
        self._publish(self._pub_clock, clock_cdr(self.cell.t_ns))

    def _check_clock_publishers(self) -> int:
        """Warn (once per change) when another node publishes /clock too: time is then two."""
        n = self.count_publishers('/clock')
        if n > 1 and n != self._clock_publishers_warned:
            others = [
                f'{i.node_namespace.rstrip("/")}/{i.node_name}'
                for i in self.get_publishers_info_by_topic('/clock')
                if (i.node_name, i.node_namespace) != (self.get_name(), self.get_namespace())
            ]
            self.get_logger().warning(
                f'{n} publishers on /clock ({", ".join(others) or "another node"} besides this '
                'cell): controllers on simulated time see it jump; give each cell its own '
                'clock (remap /clock) or run one cell per ROS_DOMAIN_ID'
            )
        self._clock_publishers_warned = n if n > 1 else 0
        return n

    def _publish_diagnostics(self) -> None:
        clock_publishers = self._check_clock_publishers()
        now = time.perf_counter()
        wall0, k0 = self._diag_ref
        self._diag_ref = (now, self.cell.k)
        c = self._cost
        rtf = (self.cell.k - k0) * self.cell.dt / max(now - wall0, 1e-9)
        step_us = 1e6 * c['step_s'] / c['periods'] if c['periods'] else 0.0
        pub_us = 1e6 * c['publish_s'] / c['messages'] if c['messages'] else 0.0
        self._cost = {'step_s': 0.0, 'periods': 0, 'publish_s': 0.0, 'messages': 0}
        faults = self.cell.faults
        level = (
            DiagnosticStatus.ERROR
            if 'jam' in faults
            else DiagnosticStatus.WARN
            if faults
            else DiagnosticStatus.OK
        )
        counts = self.cell.outcome_counts
        values = {
            'real_time_factor': f'{rtf:.3f}',
            'step_cost_us': f'{step_us:.2f}',
            'publish_cost_us': f'{pub_us:.2f}',
            'parcels_in_cell': str(self.cell.n_parcels),
            'faults': ','.join(faults) or 'none',
            'estop': str(self.cell.estop).lower(),
            'jam': str(self.cell.jam).lower(),
            'sim_time': f'{self.cell.t:.6f}',
            'time_mode': self.params.time_mode,
            'inducted': str(self.cell.n_inducted),
            'pending_inducts': str(self.cell.pending_inducts),
            'inducts_refused': str(self.cell.n_induct_refused),
            'clock_publishers': str(clock_publishers),
            'watchdog_trips': str(self.cell.watchdog_trips),
            'faults_injected': str(self.faults_injected),
            'injected_now': ','.join(self._injected_now()) or 'none',
            'callback_errors': str(getattr(self, 'callback_errors', 0)),
            'packml_state': self.cell.packml.state,
            'packml_cause': self.cell.packml.cause,
            'packml_commands': str(self.cell.packml.counts['commands']),
            'packml_refused': str(self.cell.packml.counts['refused']),
            **self._fieldbus_diagnostics(),
            **{f'exits_{k}': str(v) for k, v in counts.items()},
        }
        status = DiagnosticStatus(
            level=level,
            name=f'{self.get_fully_qualified_name()}: cell',
            message=('faults: ' + ', '.join(faults)) if faults else 'running',
            hardware_id=self.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = _time_msg(self.cell.t_ns)
        self._publish(self._pub_diag, msg)

    def _fieldbus_diagnostics(self) -> dict:
        if self.io_image is None:
            return {}
        st = self.io_image.stats
        servers = 'running'
        if isinstance(self.fieldbus, FieldbusProcess) and not self.fieldbus.alive:
            servers = 'ended'
            if not self._servers_ended_said:
                self._servers_ended_said = True
                self.get_logger().error(
                    'the fieldbus servers\' process ended: no client is served; the cell '
                    'runs on (restart the node to serve again)'
                )
        return {
            'fieldbus_servers': servers,
            'fieldbus_writes': str(st['writes']),
            'fieldbus_writes_refused': str(st['refused']),
            # Modbus reads refused (an address or count no table has), function codes the
            # image does not serve, frames dropped (wrong protocol id, impossible length)
            'fieldbus_reads_refused': str(st['reads_refused']),
            'fieldbus_illegal_functions': str(st['illegal_functions']),
            'fieldbus_frames_dropped': str(st['frames_dropped']),
            # OPC UA warehouse method calls refused for their arguments
            'fieldbus_calls_refused': str(self.fieldbus.warehouse.refused if self.fieldbus else 0),
            # outputs a newer write replaced before the cell applied them: lost updates
            'fieldbus_outputs_lost': str(st['overwritten']),
            'fieldbus_outputs_refused_by_cell': str(self._io_refused),
            'fieldbus_labels_dropped': str(self._scanner.dropped),
        }

    # ------------------------------------------------------------------ services
    def _srv_popup(self, request, response):
        response.success, response.message = self.cell.popup(bool(request.data))
        return response

    def _srv_estop(self, request, response):
        if not request.data:
            response.success = False
            response.message = 'refused: an e-stop is released with the reset service (use reset)'
            return response
        self.cell.engage_estop()
        self._publish_status()
        self.get_logger().warning('e-stop engaged: belt stopped, disks dropping')
        response.success = True
        response.message = 'e-stop engaged: belt stopped, disks dropping; reset to resume'
        return response

    def _srv_reset(self, request, response):
        cleared = self.cell.faults
        self._publish_events(self.cell.reset())
        response.success = True
        response.message = ('cleared ' + ', '.join(cleared)) if cleared else 'nothing to clear'
        return response

    def _srv_packml(self, command: str, response):
        """Take a PackML command (packml/<command>), or refuse it with the reason."""
        ok, text = self.cell.packml_command(command)
        response.success = ok
        if ok:
            self._publish_events(self.cell.take_packml_edges())
            response.message = f'{text} (now {self.cell.packml.state})'
        else:
            self.get_logger().warning(f'packml/{command} {text}')
            response.message = f'refused: {text}'
        return response

    def _srv_step(self, request, response):
        if self.station:
            response.success = False
            response.message = 'refused: this station is part of a line; step the line'
            return response
        if self.params.time_mode != 'lockstep':
            response.success = False
            response.message = (
                f'refused: step works in time_mode lockstep; this cell runs in '
                f'{self.params.time_mode}'
            )
            return response
        self.advance(1)
        response.success = True
        response.message = f't = {self.cell.t:.9f} s'
        return response

    # ------------------------------------------------------------------ induct
    def _command_safe_alpha(self) -> None:
        """
        Make the alpha_deg parameter say what the tripped watchdog commands.

        The parameter is the commanded disk angle; keeping it true means a controller that
        takes over sees the safe angle and its next command is a change the cell applies.
        """
        self._safe_alpha_set = True
        try:
            self.set_parameters([Parameter('alpha_deg', value=self.params.safe_alpha_deg)])
        finally:
            self._safe_alpha_set = False

    def _on_heartbeat(self, msg: UInt32) -> None:
        """Take the controller's heartbeat: a counter, which feeds the watchdog when it changes."""
        if self.cell.heartbeat(int(msg.data)):
            self.get_logger().info('controller heartbeat back: watchdog cleared')
            self._publish_status()

    def _on_induct(self, msg: DiagnosticStatus) -> None:
        """Return an external induct request; bad values are logged and the message dropped."""
        try:
            spec = self._induct_spec(msg)
            self.cell.induct(spec)
        except ParamError as exc:
            self.get_logger().warning(f'parcels/induct dropped: {exc}')

    def _on_fault(self, msg: DiagnosticStatus) -> None:
        """Inject a test-bench fault (``runtime.faults``); a bad request is logged and dropped."""
        try:
            self.inject_fault(msg.name, {kv.key: kv.value for kv in msg.values})
        except ParamError as exc:
            self.get_logger().warning(f'faults/inject dropped: {exc}')

    def inject_fault(self, name: str, values: dict) -> str:
        """
        Inject one fault (``runtime.faults.apply_fault``) and publish what it shows.

        Parameters
        ----------
        name : str
            The fault.
        values : dict
            Its arguments.

        Returns
        -------
        str
            What was done, in words.

        Raises
        ------
        ParamError
            A bad request; nothing changes.

        """
        events, done = apply_fault(self.cell, name, values)
        self.faults_injected += 1
        self._publish_events(events)
        self._publish_status()
        self.get_logger().warning(f'injected fault: {done}')
        return done

    def _injected_now(self) -> list[str]:
        out = [f'eye {n} {f.fault}' for n, f in self.cell.sensor_faults.items()]
        if self.cell.heartbeat_cut:
            out.append('heartbeat lost')
        return out

    def _induct_spec(self, msg: DiagnosticStatus) -> ParcelSpec:
        return induct_spec([(kv.key, kv.value) for kv in msg.values], self.params)


def induct_spec(pairs, p: CellParams) -> ParcelSpec:
    """
    Return the parcel a parcels/induct message asks for, from its (key, value) pairs.

    Raises ParamError naming what is wrong: an unknown or repeated key, a value that
    is not a finite number. Missing sizes take the middle of the stream's ranges;
    the parcel itself is checked when it is queued (``Cell.induct``).

    Parameters
    ----------
    pairs : list of (str, str)
        The message's key/value pairs.
    p : CellParams
        The cell's parameters (the stream's ranges, the belt).

    Returns
    -------
    ParcelSpec
        The parcel.

    """
    given = {}
    for key, value in pairs:
        if key not in INDUCT_KEYS:
            raise ParamError(f'unknown key {shown(key)}; allowed: {", ".join(INDUCT_KEYS)}')
        if key in given:
            raise ParamError(f'key {shown(key)} given twice')
        given[key] = value
    numbers = {}
    for key in ('A', 'B', 'm', 'phi0_deg', 'y'):
        if key in given:
            try:
                numbers[key] = float(given[key])
            except ValueError:
                raise ParamError(f'{key} must be a number, got {shown(given[key])}') from None
            if not math.isfinite(numbers[key]):
                raise ParamError(f'{key} must be finite, got {shown(given[key])}')
    # missing sizes take the middle of the configured stream's ranges
    return ParcelSpec(
        A=numbers.get('A', 0.5 * sum(p.parcel_A)),
        B=numbers.get('B', 0.5 * sum(p.parcel_B)),
        m=numbers.get('m', 0.5 * sum(p.parcel_m)),
        phi0=math.radians(numbers.get('phi0_deg', 0.0)),
        y0=numbers.get('y', 0.0),
        label=given.get('label', ''),
    )


def main(args=None, stop=None):
    """
    Run the node; ``stop``: the executable's StopSignals, when it installed them first.

    Parameters
    ----------
    args : list of str, optional
        The command line.
    stop : StopSignals, optional
        The executable's signal handlers.

    """
    run_node(SimNode, 'sim_node', (ParamError,), args, stop)


if __name__ == '__main__':
    main()
