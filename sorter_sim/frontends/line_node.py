"""
The line node ``sorter_line``: many diverter stations on one belt, one clock.

``LineNode`` starts one simulation node per station (``SimNode(station=True)``,
namespaces ``S01`` .. ``SNN`` under its own), each with the cell interface of a
single cell: its sensors, scanner, diverter state, outcomes, status bits, its
``diverter/popup``, ``estop`` and ``reset`` services, its ``alpha_deg`` parameter
and its own heartbeat and watchdog (a station whose controller stops lowers only
its own disks). The stations' cells form one ``runtime.line.Line``: a parcel that
leaves a station over its straight exit goes on to the next one as it was, and
only station 1 inducts (its stream, its ``parcels/induct``).

The line node itself publishes ``/clock`` (the one clock of the line), where each
parcel left the line on ``line/exits`` (a ``diagnostic_msgs/DiagnosticStatus``:
label, id, exit: a chute's name, ``straight_end``, ``jammed`` or ``lost`` (a parcel
handed to a segment that it could not take: no room, or a second parcel under an id
taken), station, t, cause) and each chute's full sensor on
``line/chutes/<name>/full`` (latched). With a line key (``SORTER_LINE_KEY``) every
message between segments and every exit carries its seal (``frontends.line_seal``).
Time runs as for a cell: ``lockstep`` (``line/step`` advances one period),
``fast`` (slices of ``fast_slice``) or ``realtime`` (``real_time_factor``).

Parameters (besides every station's cell parameters, from the params files'
``sorter_sim`` entries as for a single cell): ``stations`` (1-64), ``station_gap``
(belt between one station's exit and the next one's induct point, m),
``chute_names`` (2 per station, left then right; empty: S01L, S01R, ...),
``chute_capacity``, ``chute_drain_per_s``, ``time_mode``, ``fast_slice``,
``real_time_factor``, ``record_path`` (the whole line in one MCAP file),
``wait_for_warehouse`` (hold the time until the edges of every station after the
line's first have a reader: the warehouse that gives those stations their labels, and
after each of their scanner edges until the warehouse answered it: ``scan_answers``),
``modbus_port`` / ``opcua_port`` (0: off) and their ``*_host`` (127.0.0.1): one
fieldbus server pair for every station's I/O image, exchanged every period: station
k is Modbus unit id k (the single cell's addresses in each), and OPC UA folder
``sorter_line/Sk`` with its ``Inputs`` and ``Outputs``; ``foxglove_port`` (0: off),
``foxglove_host``, ``foxglove_rate_hz``: the whole line's live view, every station
in its frame (``Sk/cell``) placed along the belt. Bad values stop the node at
start with one line naming the parameter and what it allows.
"""

from __future__ import annotations

import math
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from sorter_ros.interface import (
    answer_every_parameter_request,
    EVENT_QOS,
    SENSOR_QOS,
    SERVICE_QOS,
    STREAM_QOS,
    declare_options,
    fix_at_start,
)
from sorter_ros.env import run_node
from sorter_ros.recording import open_recorder, publish_recorded, release_recorder
from sorter_sim.frontends.cdr import clock_cdr
from sorter_sim.frontends.fieldbus import FieldbusServers
from sorter_sim.frontends.node import SimNode, burst_limit, realtime_tick
from sorter_ros.line_seal import LineSeal
from sorter_ros.outcomes import exit_msg
from sorter_sim.frontends.scan_answers import ScanAnswers
from sorter_sim.frontends.segments import SegmentLink
from sorter_sim.model.description import chute_pairs, station_name
from sorter_sim.runtime.cell import STATE_NAMES, SensorEdge
from sorter_sim.runtime.handover import HandoverLimits
from sorter_sim.runtime.line import Line, LineExit, LineLayout, StationEvent
from sorter_ros.line_key import LineKeyError
from sorter_sim.runtime.params import SPECS, ParamError

NODE_NAME = 'sorter_line'
# s a fast-mode segment held back waits at most before it looks again (_tick_fast): a
# neighbour's message wakes it at once, this catches what comes without one (a claim
# settling, a reader matched)
RECHECK_S = 0.002
TIME_MODES = ('lockstep', 'fast', 'realtime')
SEGMENT_SYNCS = ('conservative', 'barrier')

# name -> (default, check, what it allows)
LINE_PARAMS = {
    'stations': (1, lambda v: isinstance(v, int) and 1 <= v <= 64, 'an integer in [1, 64]'),
    'station_gap': (
        0.0,
        lambda v: isinstance(v, float) and 0.0 <= v <= 1000.0,
        'a number in [0, 1000] m',
    ),
    'chute_names': (
        [''],
        lambda v: isinstance(v, list) and all(isinstance(x, str) for x in v),
        'a list of chute names, two per station (left, right); [""] for S01L, S01R, ...',
    ),
    'chute_capacity': (
        20,
        lambda v: isinstance(v, int) and 1 <= v <= 10_000,
        'an integer in [1, 10000] parcels',
    ),
    'chute_drain_per_s': (
        1.0,
        lambda v: isinstance(v, float) and 0.0 <= v <= 100.0,
        'a number in [0, 100] parcels/s',
    ),
    'first_station': (
        1,
        lambda v: isinstance(v, int) and 1 <= v <= 64,
        'an integer in [1, 64]: the number on the line of this node\'s first station',
    ),
    'line_stations': (
        0,
        lambda v: isinstance(v, int) and 0 <= v <= 64,
        'an integer in [0, 64]: the stations of the whole line (0: the line ends with '
        'this node\'s last station)',
    ),
    'time_mode': ('realtime', lambda v: v in TIME_MODES, f'one of {", ".join(TIME_MODES)}'),
    'segment_sync': (
        'conservative',
        lambda v: v in SEGMENT_SYNCS,
        f'one of {", ".join(SEGMENT_SYNCS)} (lock-step and fast segments: each behind its '
        'upstream neighbour, or all within one slice of each other)',
    ),
    'wait_for_warehouse': (
        False,
        lambda v: isinstance(v, bool),
        'true or false: hold the line\'s time until a reader (the warehouse node) takes the '
        'edges of each of its stations after the line\'s first, which get their labels from '
        'what the warehouse hears, and (lockstep, fast) after each of their scanner edges '
        'until the warehouse answered it',
    ),
    'fast_slice': (
        0.005,
        lambda v: isinstance(v, float) and 0.0 < v <= 1.0,
        'a number in (0, 1] s',
    ),
    'real_time_factor': (
        1.0,
        lambda v: isinstance(v, float) and 0.001 <= v <= 1000.0,
        'a number in [0.001, 1000]',
    ),
    'modbus_port': (
        0,
        lambda v: isinstance(v, int) and 0 <= v <= 65535,
        'a port in [0, 65535] (0: off)',
    ),
    'modbus_host': (
        '127.0.0.1',
        lambda v: isinstance(v, str) and bool(v.strip()),
        'a host name or address',
    ),
    'opcua_port': (
        0,
        lambda v: isinstance(v, int) and 0 <= v <= 65535,
        'a port in [0, 65535] (0: off)',
    ),
    'opcua_host': (
        '127.0.0.1',
        lambda v: isinstance(v, str) and bool(v.strip()),
        'a host name or address',
    ),
    'foxglove_port': (
        0,
        lambda v: isinstance(v, int) and 0 <= v <= 65535,
        'a port in [0, 65535] (0: off)',
    ),
    'foxglove_host': (
        '127.0.0.1',
        lambda v: isinstance(v, str) and bool(v.strip()),
        'a host name or address',
    ),
    'foxglove_rate_hz': (
        30.0,
        lambda v: isinstance(v, float) and 0.1 <= v <= 1000.0,
        'a number in [0.1, 1000] frames per wall second',
    ),
    'record_path': (
        '',
        lambda v: isinstance(v, str) and len(v) <= 4096,
        'an MCAP file path, or empty for no recording',
    ),
}

# the line's options no station takes: dropped from what the process's arguments give
# a station (a plain ``-p stations:=6`` reaches every node of the process)
LINE_ONLY = frozenset(LINE_PARAMS) - frozenset(SPECS)


class LineNode(Node):
    """The line's clock and its stations (see the module)."""

    def __init__(
        self,
        *,
        station_params: dict | None = None,
        node_name: str = NODE_NAME,
        line_key: bytes | None = None,
        **kwargs,
    ):
        # the segments of a line in one ROS graph each need a name of their own
        super().__init__(node_name, **kwargs)
        try:
            # the line key (None: SORTER_LINE_KEY's file, or an open line): read first, so
            # that a key that cannot be used stops the node before anything starts
            self.seal = LineSeal(line_key)
        except LineKeyError as exc:
            raise ParamError(str(exc)) from None
        answer_every_parameter_request(self)  # a request rclpy cannot read too
        self.values = values = declare_options(self, LINE_PARAMS, ParamError)
        self._refuse_unknown_parameters()
        # the line reads its own options once, and it is the simulation clock (/clock)
        fix_at_start(
            self,
            {name: allowed for name, (_, _, allowed) in LINE_PARAMS.items()}
            | {'use_sim_time': 'false: the line is the simulation clock (it publishes /clock)'},
        )
        n = values['stations']
        f0, last, total = self._segment_span(n)
        chutes = self._station_chutes(n, f0, last)
        ns = self.get_namespace().rstrip('/')
        station_params = self._open_line_recorder(dict(station_params or {}))
        overrides = [
            Parameter(k, value=v) for k, v in {**self._line_owned(), **station_params}.items()
        ]
        self.stations: list[SimNode] = []
        self._build_line(ns, f0, n, overrides, chutes)
        self.fieldbus = None
        self.live_view = None
        if values['foxglove_port']:
            self._open_live_view()
        if values['modbus_port'] or values['opcua_port']:
            self._open_fieldbus()
        self._create_line_interfaces()
        self._link_segments(f0, n, last, total)
        self.exits = 0
        self._warehouse_heard = False  # wait_for_warehouse: every station's edges read
        self._answers = None  # wait_for_warehouse: the scanner edges it has yet to answer
        # wall time spent in the line's physics and in publishing what it reports
        self.cost = {'physics_s': 0.0, 'publish_s': 0.0}
        self._wall_ref = None
        mode = values['time_mode']
        if mode == 'fast':
            self._timer = self.create_timer(0.0, self._tick_fast)
            self._recheck = self.create_timer(RECHECK_S, self._wake)
            self._recheck.cancel()
            self.segment.on_heard = self._wake
        elif mode == 'realtime':
            self._timer = self.create_timer(0.001, self._tick_realtime)
        else:
            self._timer = None
        if values['wait_for_warehouse'] and mode != 'realtime':
            self._answers = ScanAnswers(
                self, self.stations, self.first, self._wake if mode == 'fast' else None
            )
        self._publish_clock()
        if self.segment.upstream or self.segment.downstream or self.seal.keyed:
            # said once: an open line takes any message in an owner's name on what it says
            say = self.get_logger().info if self.seal.keyed else self.get_logger().warning
            say(self.seal.describe())
        self.get_logger().info(
            f'sorter line ready: {n} stations ({", ".join(a + "/" + b for a, b in chutes[:3])}'
            f'{", ..." if n > 3 else ""}), {mode} mode'
        )

    def _segment_span(self, n: int) -> tuple[int, int, int]:
        """
        Place this node's ``n`` stations on the line; return (first, end, the line's total).

        A segment of a longer line runs stations ``first_station`` .. ``first_station +
        n - 1`` of ``line_stations`` (0-based here: ``first`` .. ``end - 1``); it hands
        parcels on when the line goes on past its end.
        """
        values = self.values
        f0 = self.first = values['first_station'] - 1
        last = f0 + n
        total = values['line_stations'] or last
        if last > 64:
            raise ParamError(
                f"parameters 'first_station' + 'stations': stations {f0 + 1} to {last} "
                'run past the 64 a line can have'
            )
        if total < last:
            raise ParamError(
                f"parameter 'line_stations' must be 0 or at least {last} (this node's last "
                f'station), got {total}'
            )
        self.hand_on = last < total
        return f0, last, total

    def _station_chutes(self, n: int, f0: int, last: int) -> list:
        """Return the stations' (left, right) chute names: the ones given, or the line's."""
        names = self.values['chute_names']
        try:
            # names given name this node's stations; the default ones follow the line's
            chutes = chute_pairs(n, names)
            if not any(names):
                chutes = chute_pairs(last)[f0:]
        except ValueError as exc:
            raise ParamError(str(exc)) from None
        return chutes

    def _open_line_recorder(self, station_params: dict) -> dict:
        """
        Open the line's recorder when it records; return the stations' params, recording too.

        One file for the whole line: every station records into the line's recorder
        (``open_recorder`` shares a path within a process), the line its own topics.
        """
        path = self.values['record_path']
        self.recorder = None
        if path:
            given = station_params.get('record_path', path)
            if given != path:
                raise ParamError(
                    f"parameter 'record_path': the stations record to {given!r}, the line to "
                    f"{path!r}; a line records into one file"
                )
            station_params['record_path'] = path
            try:
                self.recorder = open_recorder(path, self.get_logger().error)
            except ValueError as exc:
                raise ParamError(f"parameter 'record_path': {exc}") from None
        return station_params

    def _build_line(self, ns: str, f0: int, n: int, overrides: list, chutes: list) -> None:
        """
        Start the stations and join their cells into the line, laid out a pitch apart.

        The stations must publish at the same rates: the line publishes for them all on
        one count of periods. On a failure, what was started is released.
        """
        values = self.values
        try:
            self._start_stations(ns, f0, n, overrides)
            p0 = self.stations[0].params
            self._pitch = span = p0.exit_x - p0.induct_x + values['station_gap']
            layout = LineLayout(
                positions=[-p0.induct_x + (f0 + k) * span for k in range(n)],
                chutes=chutes,
                capacity=values['chute_capacity'],
                drain_per_s=values['chute_drain_per_s'],
                first=f0,
                hand_on=self.hand_on,
            )
            self.line = Line.from_cells([s.cell for s in self.stations], layout)
            strides = {
                (s.params.pose_stride, s.params.marker_stride, s.params.heartbeat_stride)
                for s in self.stations
            }
            if len(strides) != 1:
                raise ParamError(
                    'the stations must publish at the same rates (pose_rate_hz, marker_rate_hz, '
                    'heartbeat_rate_hz)'
                )
            self._strides = strides.pop()
        except BaseException:
            for s in self.stations:
                s.destroy_node()
            if self.recorder is not None:
                release_recorder(self.recorder)
            raise

    def _create_line_interfaces(self) -> None:
        """Create the line's clock, exit and chute-full publishers and its step service."""
        self._pub_clock = self.create_publisher(Clock, '/clock', STREAM_QOS)
        self._pub_exits = self.create_publisher(DiagnosticStatus, 'line/exits', EVENT_QOS)
        self._pub_full = {
            c.name: self.create_publisher(Bool, f'line/chutes/{c.name}/full', SENSOR_QOS)
            for c in self.line.chutes
        }
        for pub in self._pub_full.values():
            self._publish(pub, Bool(data=False))
        self.create_service(Trigger, 'line/step', self._srv_step, qos_profile=SERVICE_QOS)

    def _link_segments(self, f0: int, n: int, last: int, total: int) -> None:
        """
        Size the line's passes and link it to the segments up and down the line.

        A pass is a slice in fast mode, or a burst every station's watchdog can follow
        (``node.burst_limit``) on the wall clock; the hand-overs between segments
        (``segments.py``) are the next segment's entry, and ours.
        """
        values = self.values
        self._slice = max(1, round(values['fast_slice'] / self.line.dt))
        self._burst_s = min(burst_limit(s.params.watchdog_timeout) for s in self.stations)
        p0 = self.stations[0].params
        self.segment = SegmentLink(
            self,
            upstream=station_name(f0) if f0 else None,
            downstream=station_name(last) if self.hand_on else None,
            dx=-self._pitch,
            dt_ns=p0.control_period_ns,
            owned=(f0, n, total),
            limits=HandoverLimits.from_params(p0),
            # the most the segment upstream runs in one pass: a slice, or a burst on the
            # wall clock
            max_step_k=max(self._slice, math.ceil(self._burst_s / self.line.dt) + 1),
            room=lambda: p0.max_parcels - self.stations[0].cell.n_parcels,
            barrier=values['segment_sync'] == 'barrier',
        )
        self.segment.on_lost = self._lost_on_arrival

    def _start_stations(self, ns: str, f0: int, n: int, overrides: list) -> None:
        """Start this node's ``n`` stations, the line's ``f0 + 1`` .. ``f0 + n``."""
        for k in range(n):
            self.stations.append(
                SimNode(
                    station=True,
                    not_mine=LINE_ONLY,
                    context=self.context,
                    namespace=f'{ns}/{station_name(f0 + k)}',
                    parameter_overrides=list(overrides)
                    # only the line's first station inducts a stream
                    + ([Parameter('arrival', value='none')] if f0 + k else []),
                )
            )

    def _refuse_unknown_parameters(self) -> None:
        """Refuse a name neither the line nor its stations take, in one line."""
        unknown = sorted(
            name
            for name in self._parameter_overrides
            if name not in LINE_PARAMS
            and name not in SPECS
            and name != 'use_sim_time'
            and not name.startswith('qos_overrides.')
        )
        if unknown:
            raise ParamError(
                f'unknown parameter(s) {", ".join(map(repr, unknown))}: the line takes '
                f'{", ".join(LINE_PARAMS)}; its stations take the cell\'s parameters '
                '(docs/simulation-node.md), as -p NAME:=VALUE or a params file\'s sorter_sim '
                'entries'
            )

    def _line_owned(self) -> dict:
        """
        Return what every station is given of the options the line owns.

        A plain ``-p modbus_port:=1502`` or ``-p time_mode:=fast`` reaches every node of
        the process, the stations too; the line serves the fieldbus and the live view for
        all its stations, records them into its file and drives their time, so a
        station is given the line's time options and no server of its own.
        """
        v = self.values
        owned = {name: v[name] for name in ('time_mode', 'fast_slice', 'real_time_factor')}
        owned.update(modbus_port=0, opcua_port=0, foxglove_port=0)
        owned['record_path'] = v['record_path']
        return owned

    def _open_live_view(self) -> None:
        """Serve the whole line to Foxglove: every station in its frame, placed along the belt."""
        from sorter_sim.frontends.live_view_process import LiveViewProcess

        v = self.values
        stations = [
            (station_name(self.first + k), s.live_layout(), x)
            for k, (s, x) in enumerate(zip(self.stations, self.line.positions))
        ]
        try:
            self.live_view = LiveViewProcess(
                None,
                host=v['foxglove_host'],
                port=v['foxglove_port'],
                prefix=f'{self.get_namespace().rstrip("/")}/live',
                max_rate_hz=v['foxglove_rate_hz'],
                stations=stations,
                on_failure=self.get_logger().error,
            )
        except ValueError as exc:
            self._release_stations()
            raise ParamError(f"parameter 'foxglove_port': {exc}") from None
        self.get_logger().info(
            f'live view of the line: Foxglove WebSocket server on '
            f'ws://{v["foxglove_host"]}:{self.live_view.port}'
        )

    def _release_stations(self) -> None:
        """Undo what the constructor built, when a later part of it fails."""
        if self.live_view is not None:
            self.live_view.close()
            self.live_view = None
        for s in self.stations:
            s.destroy_node()
        if self.recorder is not None:
            release_recorder(self.recorder)

    def _open_fieldbus(self) -> None:
        """Serve every station's I/O image: Modbus unit id k and OPC UA folder Sk for station k."""
        v = self.values
        stations = [
            (station_name(self.first + k), s.fieldbus_bridge.attach_io_image())
            for k, s in enumerate(self.stations)
        ]
        self.fieldbus = FieldbusServers(
            stations=stations,
            modbus=(v['modbus_host'], v['modbus_port']) if v['modbus_port'] else None,
            opcua=(v['opcua_host'], v['opcua_port']) if v['opcua_port'] else None,
            cell_name=self.get_namespace().strip('/').replace('/', '_') or 'sorter_line',
        )
        try:
            self.fieldbus.start()
        except ValueError as exc:
            self.fieldbus = None
            self._release_stations()
            key = 'modbus_port' if 'Modbus' in str(exc) else 'opcua_port'
            raise ParamError(f'parameter {key!r}: {exc}') from None
        served = []
        if self.fieldbus.modbus_port:
            served.append(
                f'Modbus TCP on {v["modbus_host"]}:{self.fieldbus.modbus_port} '
                '(station k: unit id k)'
            )
        if self.fieldbus.opcua_endpoint:
            served.append(f'OPC UA on {self.fieldbus.opcua_endpoint} (a folder per station)')
        self.get_logger().info('fieldbus I/O images: ' + ', '.join(served))

    @property
    def nodes(self) -> list:
        """Return this node and its stations: everything an executor must spin."""
        return [self, *self.stations]

    # ------------------------------------------------------------------ time
    def advance(self, n: int) -> None:
        """
        Advance the line ``n`` control periods, every station publishing what falls due.

        Parameters
        ----------
        n : int
            Control periods.

        """
        link = self.segment
        link.service()
        if self._held():
            return
        if self.values['time_mode'] != 'realtime':
            if link.upstream is not None:
                # in step with the segment upstream: never past the time it has handed over to
                n = min(n, link.horizon_k - self.line.k)
            if self.values['segment_sync'] == 'barrier':
                # the whole line in one slice: never more than a slice past the segment
                # furthest behind (a barrier per slice, for comparison with the above)
                n = min(n, link.line_k() + self._slice - self.line.k)
        ran = n > 0
        while n > 0:
            k = self.line.k
            # with a fieldbus, one period at a time: the I/O images are exchanged every period
            m = 1 if self.fieldbus is not None else min([n] + [s - k % s for s in self._strides])
            per_station: list[list] = [[] for _ in self.stations]
            t0 = time.perf_counter()
            if self.fieldbus is not None:
                for node in self.stations:
                    node.fieldbus_bridge.before_period()
            events = self.line.advance(m, link.due(k + m))
            t1 = time.perf_counter()
            self.cost['physics_s'] += t1 - t0
            for e in events:
                if isinstance(e, StationEvent):
                    per_station[e.station].append(e.event)
                elif isinstance(e, LineExit):
                    self._publish_exit(e)
                    link.left(e.parcel_id)
                elif isinstance(e, SensorEdge):
                    self._publish(self._pub_full[e.sensor.rsplit('.', 1)[0]], Bool(data=e.blocked))
            if self.fieldbus is not None:
                for node, evs in zip(self.stations, per_station):
                    node.fieldbus_bridge.after_period(evs)
                time.sleep(0)  # the servers' thread serves a waiting request within a period
            for node, evs in zip(self.stations, per_station):
                node.publisher_set.publish_period(evs)
            view = self.live_view
            if view is not None and self.line.k % self._strides[0] == 0 and view.due():
                view.update_stations(
                    self.line.t_ns, [s.live_state() for s in self.stations], STATE_NAMES
                )
            link.hand_on(self.line.take_outgoing())
            self._publish_clock()
            self.cost['publish_s'] += time.perf_counter() - t1
            n -= m
            if self._answers is not None and self._answers.sent(per_station):
                break  # a label the warehouse gives: it reaches the program before time runs on
        if ran:
            # once a call: every parcel up to now is sent (a fast segment running on says
            # one every HORIZON_STRIDE - 1 slices; _tick_fast says the newest when it stops)
            link.horizon(self.line.t_ns, coalesce=self.values['time_mode'] == 'fast')
            if self.values['segment_sync'] == 'barrier':
                link.progress(self.line.k)

    def _held(self) -> bool:
        """Return True when the line must not run now: its segment or a neighbour holds it."""
        link = self.segment
        if link.holds():
            return True  # its stations are another segment's, or its claim has not settled yet
        if self.values['time_mode'] == 'realtime':
            return False
        if link.downstream is not None and not link.connected():
            return True  # no segment downstream to take the hand-overs yet: they would be lost
        if link.backlogged():
            return True  # the segment downstream has not taken what it was sent yet
        if self.values['wait_for_warehouse'] and not self._warehouse_reads():
            return True  # an edge sent now would be lost, and its parcel would have no label
        if self._answers is not None and self._answers.waiting():
            return True  # the warehouse has not yet answered a scanner edge (scan_answers)
        # what the segment upstream answers for (a restart's parcels) not all in yet: run
        # now and they would be taken late
        return not link.answered

    def _warehouse_reads(self) -> bool:
        """Return True once every station after the line's first has a reader of its edges."""
        if self._warehouse_heard:
            return True
        for j, node in enumerate(self.stations):
            # self.first: the 0-based line number of this node's first station
            if self.first + j > 0 and node.publisher_set.pub_edges.get_subscription_count() == 0:
                self.get_logger().info(
                    f'holding: nobody reads {node.publisher_set.pub_edges.topic_name} yet '
                    '(wait_for_warehouse)',
                    throttle_duration_sec=5.0,
                )
                return False
        silent = self._answers.silent() if self._answers is not None else []
        if silent:
            # the warehouse answers each scanner edge there: until it is heard, an edge
            # would not wait for its label
            self.get_logger().info(
                f'holding: nobody answers on {silent[0]} yet (wait_for_warehouse)',
                throttle_duration_sec=5.0,
            )
            return False
        self._warehouse_heard = True  # not looked at again: a count is a query of the graph
        return True

    def _tick_fast(self) -> None:
        k = self.line.k
        self.advance(max(1, round(self.values['fast_slice'] / self.line.dt)))
        if self.line.k != k:
            return
        self.segment.flush_horizon()  # what it ran up to, said before it waits
        # held back by a neighbour: wait in the executor, not in this callback, so the
        # message that lets it go on (a horizon, a barrier's progress, an answer) is taken
        # the moment it comes and wakes it (_wake); a sleep here held that message back
        # for the rest of the sleep, a barrier line's every slice
        self._timer.cancel()
        self._recheck.reset()

    def _wake(self) -> None:
        """Run the held fast-mode line again: a neighbour spoke, or it is time to look."""
        if self._timer.is_canceled():
            self._recheck.cancel()
            self._timer.reset()

    def _tick_realtime(self) -> None:
        realtime_tick(self, self.line, self.values['real_time_factor'], self._burst_s)

    def _srv_step(self, request, response):
        if self.values['time_mode'] != 'lockstep':
            response.success = False
            response.message = (
                f'refused: step works in time_mode lockstep; this line runs in '
                f'{self.values["time_mode"]}'
            )
            return response
        k = self.line.k
        self.advance(1)
        if self.line.k == k:
            response.success = False
            response.message = (
                f'waiting: the segment upstream has handed over up to '
                f'{self.segment.horizon_k * self.line.dt:.9f} s; this one is at '
                f'{self.line.t:.9f} s'
            )
            return response
        response.success = True
        response.message = f't = {self.line.t:.9f} s'
        return response

    # ------------------------------------------------------------------ publishing
    def _publish(self, publisher, msg) -> None:
        """Publish ``msg``, and record it when the line records."""
        publish_recorded(publisher, msg, self.recorder, self.line.t_ns)

    def _publish_clock(self) -> None:
        self._publish(self._pub_clock, clock_cdr(self.line.t_ns))

    def _lost_on_arrival(self, h, why: str) -> None:
        """Say a parcel handed to this segment lost, at its first station, with why."""
        self._publish_exit(LineExit(h.t_ns, h.parcel_id, h.label, 'lost', 0, why))

    def _publish_exit(self, e: LineExit) -> None:
        self.exits += 1
        msg = exit_msg(e, station_name(self.first + e.station), self.get_fully_qualified_name())
        self._publish(self._pub_exits, self.seal.sealed(self._pub_exits.topic_name, msg))

    def destroy_node(self):
        """Stop the fieldbus servers and the live view, destroy the stations, then this node."""
        if self.live_view is not None:
            self.live_view.close()
            self.live_view = None
        if self.fieldbus is not None:
            self.fieldbus.stop()
            self.fieldbus = None
        for s in self.stations:
            s.destroy_node()
        self.stations = []
        if self.recorder is not None:
            release_recorder(self.recorder)
            self.recorder = None
        return super().destroy_node()


def main(args=None, stop=None):
    """
    Run the line: ``line_node --ros-args -p stations:=6 --params-file config/cell.yaml``.

    As every executable of the package (``sorter_ros.env.run_node``): a bad parameter is
    one line and exit code 2, a callback's exception never ends the line, SIGINT and
    SIGTERM stop it cleanly.

    Parameters
    ----------
    args : list of str, optional
        The command line.
    stop : StopSignals, optional
        The executable's signal handlers, when it installed them first.

    """
    import sys

    args, refused = station_rules(sys.argv if args is None else list(args))
    if refused:  # before rcl, which may not parse the rule at all
        print(f'line_node: {refused}', file=sys.stderr)
        raise SystemExit(2)
    run_node(LineNode, 'line_node', (ParamError,), args, stop)


STATION_NODE_PREFIXES = ('sorter_sim:', '/sorter_sim:')


def station_rules(args: list) -> tuple[list, str | None]:
    """
    Give every station the command line's ``-p sorter_sim:NAME:=VALUE`` rules.

    rcl matches such a rule's node name against a node's full name, and a line's
    stations are ``/S01/sorter_sim`` and on (rcl takes no wildcard in ``-p``): the rule
    reached none of them, silently. It is rewritten here as ``-p NAME:=VALUE``, which
    reaches every node of the process: the stations take it, the line passes over a
    cell parameter. A rule for one of the line's own options is refused, as the stations
    are given the line's.

    Parameters
    ----------
    args : list of str
        The command line.

    Returns
    -------
    tuple
        (the command line, rewritten; what is wrong, or None).

    """
    from sorter_ros.params_file import ros_arguments

    out = list(args)
    for i, flag, rule in ros_arguments(out):
        if flag in ('-r', '--remap'):
            out[i], refused = _line_remap(rule)
            if refused:
                return out, refused
        if flag not in ('-p', '--param'):
            continue
        prefix = next((p for p in STATION_NODE_PREFIXES if rule.startswith(p)), None)
        if prefix is None:
            continue
        name = rule[len(prefix) :].split(':=', 1)[0]
        if ':' in name:  # rcl would match the rest to a node named so: none, silently
            return out, (
                f'-p {rule[:120]}: a rule names one node, then the parameter: give it as '
                f'-p {prefix}{name.rsplit(":", 1)[-1][:60]}:=VALUE'
            )
        if name in LINE_PARAMS:
            return out, (
                f'-p {rule}: {name!r} is the line\'s option, and its stations take the '
                f"line's: give it as -p {name}:=VALUE"
            )
        out[i] = rule[len(prefix) :]
    return out, None


def _line_remap(rule: str) -> tuple[str, str | None]:
    """
    Give a ``-r`` rule that would move every node of the process to the line alone.

    ``-r __ns:=/line2`` would put every station at ``/line2/sorter_sim`` (each topic
    with one publisher per station): it is given to the line's node, whose namespace its
    stations go under (``/line2/S01/sorter_sim`` ...). A rule naming or moving every
    station alike (``__node``, ``sorter_sim:__ns``) is refused.
    """
    target, _, value = rule.partition(':=')
    node, _, what = target.rpartition(':')
    if what == '__ns' and node == '':
        return f'{NODE_NAME}:{rule}', None
    if what in ('__ns', '__node', '__name') and node in ('', 'sorter_sim', '/sorter_sim'):
        return rule, (
            f'-r {rule[:120]}: it would give every station the same name; the stations are '
            f'{station_name(0)}, {station_name(1)}, ... under the line\'s namespace '
            '(-r __ns:=/NAME moves the line)'
        )
    return rule, None


if __name__ == '__main__':
    main()
