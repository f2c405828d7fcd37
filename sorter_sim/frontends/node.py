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

The node itself declares and checks the parameters and runs the time; what it
publishes (``node_publishers.py``), its fieldbus I/O image (``node_fieldbus.py``),
its services and commands (``node_commands.py``) and its diagnostics and fault
injection (``node_diagnostics.py``) are collaborators of their own.
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from sorter_ros.env import run_node
from sorter_ros.interface import (
    answer_every_parameter_request,
    accept_integers_for_doubles,
    declare_typed,
    parameter_problem,
    plain,
)
from sorter_ros.interface import descriptor as ros_descriptor
from sorter_ros.recording import open_recorder, release_recorder
from sorter_sim.frontends.fieldbus_process import FieldbusProcess
from sorter_sim.frontends.live_view import CellLayout
from sorter_sim.frontends.live_view_process import LiveViewProcess
from sorter_sim.frontends.node_commands import CellCommands
from sorter_sim.frontends.node_diagnostics import CellDiagnostics, RunCost
from sorter_sim.frontends.node_fieldbus import FieldbusBridge
from sorter_sim.frontends.node_publishers import CellPublishers
from sorter_sim.model.compile_progress import compiles
from sorter_sim.runtime.cell import WATCHDOG_REFUSAL, Cell
from sorter_sim.runtime.cell_contacts import RAIL_THICKNESS
from sorter_sim.runtime.params import SCHEMA, SPECS, CellParams, ParamError
from sorter_sim.runtime.warmup import warm_cell

NODE_NAME = 'sorter_sim'
FRAME_ID = 'conveyor'  # the cell's frame in the root namespace (see frame_id)
RECORDING_METADATA = 'sorter_sim parameters'  # the metadata record of the cell's parameters
MAX_CATCH_UP_S = 0.25  # realtime mode: simulated time one tick may catch up


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


class SimNode(Node):
    """
    The cell's ROS face; see the module docstring and the README interface table.

    The node owns the cell, its parameters and its time; each of its other jobs is a
    collaborator's: ``publisher_set`` (``CellPublishers``: what it publishes, recorded
    and shown live; not ``publishers``, which is rclpy's list of them),
    ``fieldbus_bridge`` (``FieldbusBridge``: the I/O image and its servers),
    ``commands`` (``CellCommands``: the services, PackML commands, heartbeat and
    inducts) and ``diagnostics`` (``CellDiagnostics``: ``/diagnostics`` and the
    injected faults).
    """

    # ``sim_node`` is spun by rclpy's events executor: the single-threaded one builds a
    # wait set of every entity in Python on each pass, a tenth of the node's time in
    # fast mode (bench_cell.py: 45 -> 53 times real time). Its timers are on the wall
    # clock (the cell owns simulated time), which the events executor serves on time.
    executor_kind = 'events'

    def __init__(self, *, station: bool = False, not_mine=frozenset(), **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        answer_every_parameter_request(self)  # a request rclpy cannot read too
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
        compiled_before = compiles()
        warm_s = warm_cell(self.params)
        if compiles() > compiled_before:
            self.get_logger().info(
                f'compiled {compiles() - compiled_before} of the model\'s functions in '
                f'{warm_s:.1f} s (once; cached for later starts)'
            )
        ns = self.get_namespace().strip('/')
        self.frame_id = self.params.frame_id or (f'{ns}/{FRAME_ID}' if ns else FRAME_ID)
        self.cell = Cell(self.params)
        p = self.params
        self.recorder = None
        self.live_view = None
        self.fieldbus_bridge = FieldbusBridge(self)
        # the outputs open before any publisher is made: a node refused for one of them
        # (a busy port, say) leaves no /clock or other publisher behind in its process
        self._open_outputs()
        self.cost = RunCost()  # what stepping and publishing cost, for the diagnostics
        self.publisher_set = CellPublishers(
            self, self.cost, on_watchdog_trip=self._command_safe_alpha, clock=not station
        )
        self._safe_alpha_set = False  # the watchdog itself sets alpha_deg to its safe value
        self.commands = CellCommands(self, self.publisher_set)
        self.diagnostics = CellDiagnostics(
            self, self.publisher_set, self.fieldbus_bridge, self.cost
        )
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._post_set_parameters)
        self.publisher_set.publish_initial_state()
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
        self.create_timer(1.0, self.diagnostics.publish)
        self.get_logger().info(
            f'sorter cell ready: {p.time_mode} mode, control period {p.control_period * 1e3:g} '
            f'ms, belt {p.belt_speed:g} m/s x {p.belt_width:g} m, disk field '
            f'{p.disk_field_length:g} m, sensors {", ".join(self.cell.sensor_names)}'
        )

    # ------------------------------------------------------------------ outputs
    @property
    def published(self) -> Counter:
        """Return the messages published so far, per topic."""
        return self.publisher_set.published

    @property
    def fieldbus(self) -> FieldbusProcess | None:
        """Return the cell's fieldbus servers, None when off (or a line's station)."""
        return self.fieldbus_bridge.fieldbus

    def _open_outputs(self) -> None:
        """Open the recording, live view and fieldbus servers asked for; ParamError if not."""
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
                self.fieldbus_bridge.open_servers()
        except ParamError:
            self._close_outputs()
            raise

    def _close_outputs(self) -> None:
        # the servers stop side by side, each within its bound, so that a node with
        # clients still connected stops in well under ros2 launch's 10 s
        stopping = None
        if self.fieldbus_bridge.fieldbus is not None:
            stopping = threading.Thread(
                target=self.fieldbus_bridge.close_servers, name='fieldbus-stop'
            )
            stopping.start()
        if self.live_view is not None:
            self.live_view.close()
            self.live_view = None
        if stopping is not None:
            stopping.join()
        if self.recorder is not None:
            release_recorder(self.recorder)
            self.recorder = None

    def destroy_node(self):
        """Finish the recording and stop the live view, then destroy the node."""
        self._close_outputs()
        return super().destroy_node()

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
            rails=p.rail_segments,
            rail_thickness=RAIL_THICKNESS,
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
            # the contacts only where parcels touch as rigid boxes (contact: rigid)
            'contacts': c.contact_points() if c.params.contact == 'rigid' else None,
        }

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
        bridge = self.fieldbus_bridge
        cycle = p.io_stride if bridge.io_image is not None else 0
        # a chunk ends where an I/O cycle of several periods does (one of a single period
        # is latched when a read asks, and at the end of the run: FieldbusBridge.advance)
        strides = (p.pose_stride, p.marker_stride, p.heartbeat_stride) + (
            (cycle,) if cycle > 1 else ()
        )
        if bridge.io_image is None:
            self._run(n, strides)
            return
        bridge.start_run(cycle)
        try:
            self._run(n, strides, bridge, cycle)
        finally:
            bridge.end_run(cycle)

    def _run(self, n: int, strides, bridge=None, cycle: int = 0) -> None:
        """Run ``n`` periods in chunks that end at ``strides``, publishing after each."""
        cost = self.cost
        while n > 0:
            k = self.cell.k
            m = min([n] + [s - k % s for s in strides])
            t0 = time.perf_counter()
            if bridge is None:
                events = self.cell.advance(m)
            else:
                events = bridge.advance(m, cycle)
            t1 = time.perf_counter()
            cost.step_s += t1 - t0
            cost.periods += m
            n -= m
            self.publisher_set.publish_period(events)
            cost.publish_s += time.perf_counter() - t1


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
