"""
``sorter demo --stations N`` (N > 1): a line of N diverters, its PLCs and its WCS, over ROS 2.

In one process, one rclpy context and one executor: the line node (``sorter_line``,
N stations in namespaces S01 ..), one controller node per station (this project's
PLC program, in the station's namespace), the warehouse node (``sorter_wcs``: the
sort plan, the requests, the tracking between stations, the dispositions) and an
observer. The sort plan sends destinations D01 .. D(2N) to the 2N chutes in order;
each parcel (labels P00001, P00002, ...) is requested to a destination drawn
uniformly, before it reaches the scanner. The line runs as fast as possible in
lock-step on the run loop (``time_mode: lockstep``, a slice to the stations' next
scan), or on the wall clock at ``--rtf F``; ``--foxglove`` serves the whole line's
live view, ``--record`` records it into one MCAP file. After ``--sim-time`` the
infeed stops and the line runs empty, so that every parcel has its disposition
(``--dispositions FILE.jsonl`` writes them, one a line).

The summary (``--json``: one object) has ``stations``, ``inducted``, ``mis_sorted``,
``jams``, ``in_cell_at_end``, ``exits`` (chute -> count), ``dispositions`` (code ->
count), ``throughput_pcs_h``, ``real_time_factor`` and the wall and simulated times.
"""

from __future__ import annotations

import json
import math
import time
from collections import Counter

from sorter_cell.line_segment import LOCKSTEP_SLICE
from sorter_ros.outcomes import values
from sorter_ros.run_loop import RunLoop

READY_POLL_S = 0.1  # s between two looks at the segments said ready while others start
ANSWER_S = 2.0  # s station 1 has to answer a parameter change before it is sent again


def run_line(args) -> int | str:
    """
    Run the line demo.

    Parameters
    ----------
    args : argparse.Namespace
        ``sorter demo``'s arguments (``stations``, ``segments``, ``sim_time``, ``seed``,
        ``json``, ...).

    Returns
    -------
    int or str
        0 when nothing was mis-sorted or jammed and every disposition is counted, 1
        otherwise; a message for a refused input.

    """
    from sorter_ros.env import StopSignals
    from sorter_sim.runtime.params import ParamError

    n = args.stations
    k_seg = getattr(args, 'segments', None)
    k_seg = 1 if k_seg is None else k_seg
    problem = _args_problem(args, n, k_seg)
    if problem:
        return problem
    from sorter_ros.line_key import LineKeyError, key_from_env

    try:
        key_from_env()  # SORTER_LINE_KEY: every segment and the warehouse read it
    except LineKeyError as exc:
        return str(exc)
    # Ctrl-C (or SIGTERM) is a flag the spin loop reads between callbacks: a signal
    # raised inside the executor's wait would come out of rclpy as a RuntimeError and
    # could leave its wait set half torn down (see StopSignals)
    stop = StopSignals().install()
    fast = args.rtf == 'fast'
    run = None
    try:
        run = _LineRun(args, stop, lockstep=fast and k_seg == 1)
        if k_seg == 1:
            try:
                line, ctls = _build_line(run, args, n, fast)
            except ParamError as exc:  # the cell's file and the command line disagree
                return f"the line's stations refuse their parameters: {exc}"
            run.add_line(line, ctls)
        else:
            try:
                run.add_segments(_start_segments(args, n, k_seg, stop))
            except SegmentDied as exc:
                return str(exc)  # (Ctrl-C while they start: _start_segments says 130)
        try:
            with stop.hurry_interrupts():  # a second Ctrl-C mid-spin: exit 130
                problem = run.prepare() or run.stream()
                return problem or run.report(run.drain())
        except SegmentDied as exc:
            if stop.is_set():
                raise KeyboardInterrupt from None  # Ctrl-C ended it too: a stop (130)
            # the line cannot finish without it: say so at once rather than wait
            return str(exc)
    finally:
        stop.quiet = True  # the teardown is short and bounded: let it finish
        procs = run.procs if run is not None else []
        for proc, _ in procs:
            if proc.poll() is None:
                proc.terminate()
        for proc, _ in procs:
            try:
                proc.wait(timeout=20)
            except Exception:  # noqa: BLE001 - a segment that will not stop is killed
                proc.kill()
        if run is not None:
            run.close()
        stop.restore()


class SegmentDied(RuntimeError):
    """A segment process of the line ended while the line ran: the message names it."""


def _args_problem(args, n, k_seg) -> str | None:
    """Say what is wrong with the line demo's arguments, or None."""
    if not (isinstance(n, int) and 1 <= n <= 64):
        return f'--stations must be an integer in [1, 64], got {n}'
    if not (isinstance(k_seg, int) and 1 <= k_seg <= n):
        return f'--segments must be an integer in [1, --stations] = [1, {n}], got {k_seg}'
    if not (isinstance(args.parcels, int) and 0 <= args.parcels <= 100_000):
        return f'--parcels must be an integer in [0, 100000], got {args.parcels}'
    if getattr(args, 'sync', None) and k_seg == 1:
        return '--sync is how segments keep time together: use it with --segments K > 1'
    restarts = getattr(args, 'restart', 0) or 0
    if not (isinstance(restarts, int) and 0 <= restarts <= 100):
        return f'--restart must be an integer in [0, 100], got {restarts}'
    if restarts and k_seg == 1:
        return '--restart starts a segment process again: use it with --segments K > 1'
    if k_seg > 1 and (args.record or args.foxglove):
        return (
            '--segments K > 1: --record and --foxglove are a single process\'s, not a segment\'s'
        )
    return None


def _build_line(run, args, n: int, fast: bool):
    """Return the line node and its stations' controllers of a line wholly in this process."""
    from sorter_cell.line_segment import SegmentRun, SegmentStream, build_segment

    return build_segment(
        run.context,
        first=1,
        stations=n,
        line_stations=n,
        stream=SegmentStream(seed=args.seed, gap=args.gap, count=args.parcels or 0),
        run=SegmentRun(
            fast=fast,
            lockstep=run.lockstep,
            rtf=1.0 if fast else float(args.rtf),
            record=args.record or '',
            foxglove=int(args.foxglove or 0),
            contact=getattr(args, 'contact', None) or '',
        ),
    )


def _dead_segment(procs) -> str:
    """Return which segment process ended (and how), or '' while all run."""
    j = _ended(procs)
    if j is None:
        return ''
    proc = procs[j][0]
    return f'segment {j + 1} of {len(procs)} (process {proc.pid}) ended with {_how(proc.poll())}'


def _ended(procs) -> int | None:
    """Return the index of a segment process that ended, or None while all run."""
    return next((j for j, (proc, _) in enumerate(procs) if proc.poll() is not None), None)


class Restarts:
    """
    ``--restart R``: a segment process after station 1's that ends is started again, R times.

    The new process is the same segment under the same node name: its claim succeeds
    the dead one's at once, the segment upstream sends it back every parcel it answers
    for, and it runs its time up to the present before it goes on
    (``frontends.segments``). Station 1's segment is the stream itself and is not
    restarted: its end ends the demo.
    """

    POLL_S = 0.005

    def __init__(self, procs: list, cmds: list, allowed: int):
        self.procs = procs
        self.cmds = cmds
        self.left = allowed
        self.done: list[str] = []  # what was restarted, said in the summary
        self._due = 0.0  # the monotonic time of the next look at the processes

    def check(self) -> None:
        """Start an ended segment again when allowed; SegmentDied otherwise."""
        # called after every callback the line's executor runs, thousands a second: the
        # processes are polled (a system call each) every POLL_S, which is soon enough
        now = time.monotonic()
        if now < self._due:
            return
        self._due = now + self.POLL_S
        j = _ended(self.procs)
        if j is None:
            return
        import subprocess
        import sys

        dead = _dead_segment(self.procs)
        if j == 0 or self.left <= 0:
            why = (
                'station 1\'s segment is the stream: not restarted'
                if j == 0 and self.left > 0
                else f'{len(self.done)} restart(s) of --restart {len(self.done) + self.left} used'
                if self.done
                else ''
            )
            raise SegmentDied(f'{dead} ({why})' if why else dead)
        proc, clock = self.procs[j]
        proc.communicate()  # what it said before it ended: nothing more will come
        self.left -= 1
        self.procs[j] = (
            subprocess.Popen(
                self.cmds[j],
                stdout=subprocess.PIPE,
                text=True,
                bufsize=1,
                preexec_fn=_end_with_parent,
            ),
            clock,
        )
        self.done.append(dead)
        print(f'{dead}: started again (process {self.procs[j][0].pid})', file=sys.stderr)


def _end_with_parent() -> None:
    """Have a segment process end when the demo does (killed too): no orphan keeps its claim."""
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass  # not Linux: the demo's own teardown ends them


def _how(code: int) -> str:
    """Say how a process ended, from its return code."""
    return f'signal {-code}' if code < 0 else f'exit code {code}'


def segment_bounds(n: int, k_seg: int) -> list[tuple[int, int]]:
    """
    Return (first station, stations) of each of ``k_seg`` segments of ``n`` stations.

    As even as can be, the longer segments upstream: 10 stations in 3 segments are
    4 + 3 + 3.

    Parameters
    ----------
    n : int
        The line's stations.
    k_seg : int
        Segments, 1..n.

    Returns
    -------
    list of (int, int)
        Per segment, its first station (1-based) and its count.

    """
    base, extra = divmod(n, k_seg)
    out, first = [], 1
    for j in range(k_seg):
        count = base + (1 if j < extra else 0)
        out.append((first, count))
        first += count
    return out


def _start_segments(args, n: int, k_seg: int, stop=None) -> list:
    """Start one process per segment; return (process, clock topic) each, once all are ready."""
    import select
    import subprocess

    procs = []
    for cmd, clock in segment_commands(args, n, k_seg):
        procs.append(
            (
                subprocess.Popen(
                    cmd,
                    stdout=subprocess.PIPE,
                    text=True,
                    bufsize=1,
                    preexec_fn=_end_with_parent,
                ),
                clock,
            )
        )
    # every segment's first line, as it comes: one that ends first is said at once, and
    # so is one that ends after its ``ready`` while the others still start (looked at
    # every READY_POLL_S: its pipe is no longer watched)
    waiting = {proc.stdout.fileno(): (j, proc) for j, (proc, _) in enumerate(procs, 1)}
    while waiting:
        ready, _, _ = select.select(list(waiting), [], [], READY_POLL_S)
        gone = _ended(procs)
        if gone is not None and procs[gone][0].stdout.fileno() not in waiting:
            dead = _dead_segment(procs)  # said before the others are ended too
            for other, _ in procs:
                other.kill()
                other.wait()
            raise SegmentDied(f'{dead}, while the others started')
        for fd in ready:
            j, proc = waiting.pop(fd)
            line = proc.stdout.readline().strip()
            if line == 'ready':
                continue
            for other, _ in procs:
                if other is not proc:
                    other.kill()
                other.wait()
            if stop is not None and stop.is_set():
                raise KeyboardInterrupt  # Ctrl-C while they started: they stopped with it (130)
            said = f'said {line[:200]!r}' if line else f'ended with {_how(proc.returncode)}'
            raise SegmentDied(
                f'segment {j} of {len(procs)} (process {proc.pid}) did not start: {said}'
            )
    return procs


def segment_commands(args, n: int, k_seg: int) -> list[tuple[list, str]]:
    """Return the command line and clock topic of each segment process."""
    import sys

    out = []
    for j, (first, count) in enumerate(segment_bounds(n, k_seg), 1):
        clock = f'/line/segment{j}/clock'
        cmd = [
            sys.executable,
            '-m',
            'sorter_cell.line_segment',
            '--first',
            str(first),
            '--stations',
            str(count),
            '--line-stations',
            str(n),
            '--seed',
            str(int(args.seed)),
            '--clock',
            clock,
            '--warehouse',  # the demo's warehouse node gives the stations their labels
        ]
        if args.gap:
            cmd += ['--gap', *(str(float(g)) for g in args.gap)]
        if args.parcels:
            cmd += ['--parcels', str(args.parcels)]
        if getattr(args, 'contact', None):
            cmd += ['--contact', args.contact]
        if args.rtf != 'fast':
            cmd += ['--rtf', str(float(args.rtf))]
        if getattr(args, 'sync', None):
            cmd += ['--sync', args.sync]
        out.append((cmd, clock))
    return out


class _LineRun(RunLoop):
    """
    One drive of the line as the demo sees it: the warehouse and an observer, and what it heard.

    A face of ``RunLoop`` (its Context, executor, drain and slices). ``run_line`` calls
    its steps in order: prepare (the controllers, the sort plan, the requests), stream
    (the infeed open for the simulated time or the batch), drain (the infeed closed until
    every parcel has its disposition) and report. A line in this process in fast mode
    runs in lock-step: the clock stands still while the nodes start and the requests go
    out, then each slice ends at the stations' next PLC scan (``align_to_timers``), so
    that every scan sees the line where the scan period says and nothing waits on the
    wall clock. A line on the wall clock, or in segment processes, runs its own time;
    the waits then only spin. Every wait goes through ``wait``/``wait_sim``, which also
    restart (or report) a segment process that ended, so that no wait misses one.
    """

    what = 'the line'

    def __init__(self, args, stop, lockstep: bool):
        self.args, self.stop, self.lockstep = args, stop, lockstep
        self.line = self.ctls = None
        self.procs: list = []
        self.n = args.stations
        self.contact = getattr(args, 'contact', None) or ''
        self.restarts = Restarts([], [], 0)
        RunLoop.__init__(
            self,
            slice_s=LOCKSTEP_SLICE,
            events=(args.executor or 'events') == 'events',
            log_level='error',
            align_to_timers=True,
        )

    def add_line(self, line, ctls) -> None:
        """Spin the line in this process: its node, its stations and their controllers."""
        self.line, self.ctls = line, ctls
        if self.lockstep:
            self._stepper, self._timebase = line, line.line
        self.add_node([*line.nodes, *ctls])
        self._start_observer()

    def add_segments(self, procs: list) -> None:
        """Watch the line's segment processes (restarted by ``--restart``)."""
        self.procs = procs
        self.restarts = Restarts(
            procs,
            [cmd for cmd, _ in segment_commands(self.args, self.n, len(procs))],
            getattr(self.args, 'restart', 0) or 0,
        )
        self._start_observer()

    @property
    def segments(self) -> int:
        return len(self.procs) or 1

    def _start_observer(self) -> None:
        import rclpy
        from rclpy.parameter import Parameter

        from sorter_control.wcs_node import WcsNode

        self.wcs = self.add_node(
            WcsNode(
                context=self.context,
                parameter_overrides=[
                    Parameter('stations', value=self.n),
                    # a recording on the line's clock
                    Parameter('use_sim_time', value=self.line is not None),
                    Parameter('record_path', value=self.args.record or ''),
                ],
            )
        )
        self.obs = rclpy.create_node('sorter_line_demo', context=self.context)
        self._listen()
        self._open_outputs()
        self.add_node(self.obs)

    def _listen(self) -> None:
        """
        Subscribe the observer to what the report counts and the waits watch.

        The dispositions and exits are the summary's; the scanner's labels count what
        was inducted where a segment process holds station 1; the clocks (of a line not
        in this loop's hands), station 1's PackML state and the active sort plan are
        what the steps wait on.
        """
        from diagnostic_msgs.msg import DiagnosticStatus
        from rosgraph_msgs.msg import Clock
        from std_msgs.msg import String

        from sorter_ros.interface import EVENT_QOS, SENSOR_QOS, STREAM_QOS

        obs, procs = self.obs, self.procs
        self.records: list[dict] = []  # every disposition, in the order the WCS gave them
        self.exits: dict[str, str] = {}
        self.scanned: set[str] = set()
        self.clock = {'t': 0.0}
        obs.create_subscription(
            DiagnosticStatus,
            'wcs/dispositions',
            lambda m: self.records.append(values(m)),
            EVENT_QOS,
        )
        self._exits = obs.create_subscription(
            DiagnosticStatus,
            'line/exits',
            lambda m: self.exits.__setitem__(values(m)['label'], m.message),
            EVENT_QOS,
        )
        obs.create_subscription(
            String, '/S01/scanner/label', lambda m: self.scanned.add(m.data), EVENT_QOS
        )
        # the line's time: its last segment's (the others are ahead of it in a lock-step line);
        # and station 1's, whose stream the run is
        self.first_clock = {'t': 0.0}
        if not self.lockstep:
            for topic, into in (
                (procs[-1][1] if procs else '/clock', self.clock),
                (procs[0][1] if procs else '/clock', self.first_clock),
            ):
                obs.create_subscription(
                    Clock,
                    topic,
                    lambda m, into=into: into.__setitem__(
                        't', m.clock.sec + 1e-9 * m.clock.nanosec
                    ),
                    STREAM_QOS,
                )
        self.packml = {'state': ''}  # station 1's machine state: Completing once its stream is out
        obs.create_subscription(
            String,
            '/S01/status/packml',
            lambda m: self.packml.__setitem__('state', m.data),
            SENSOR_QOS,
        )
        self.active = []
        obs.create_subscription(
            DiagnosticStatus, 'wcs/sort_plan/active', self.active.append, SENSOR_QOS
        )

    def _open_outputs(self) -> None:
        """Make the plan and request publishers and station 1's parameter client."""
        from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
        from rclpy.parameter_client import AsyncParameterClient

        from sorter_control.wcs_node import REQUEST_QOS
        from sorter_ros.interface import EVENT_QOS

        self.pub_plan = self.obs.create_publisher(DiagnosticStatus, 'wcs/sort_plan', EVENT_QOS)
        self.pub_req = self.obs.create_publisher(KeyValue, 'wcs/requests', REQUEST_QOS)
        self.infeed = AsyncParameterClient(self.obs, '/S01/sorter_sim')

    # ------------------------------------------------------------------ time
    def line_t(self) -> float:
        """Return the line's time: its last segment's [s]."""
        return self.line.line.t if self.lockstep else self.clock['t']

    def first_t(self) -> float:
        """Return station 1's time [s] (one process: the line's)."""
        return self.line.line.t if self.lockstep else self.first_clock['t']

    def _checked(self, pred):
        """Return ``pred`` with the stop flag and the segment processes looked at on each call."""

        def checked():
            if self.stop.is_set():
                raise KeyboardInterrupt  # Ctrl-C: the line stops where it is (exit 130)
            self.restarts.check()
            return pred()

        return checked

    def wait(self, pred, wall_s) -> bool:
        """Spin, simulated time standing still in lock-step, until ``pred()`` or ``wall_s``."""
        if self.lockstep:
            self.spin_idle()
        return self.spin_until(self._checked(pred), wall_s)

    def wait_sim(self, pred) -> None:
        """Let simulated time run until ``pred()``: in lock-step, slice by slice."""
        pred = self._checked(pred)
        if not self.lockstep:
            self.spin_until(pred)
            return
        while not pred():
            self.run(self.slice_s)

    def set_arrival(self, value, **more) -> bool:
        """
        Set station 1's arrival (and ``more`` parameters); True once it took them all.

        Sent again when no answer comes within ``ANSWER_S``, for 20 s: an answer is lost
        when station 1's side of discovery has not yet matched this client's reader (its
        server drops it: "client will not receive response"), though the client already
        saw the service. The same values again change nothing: a stream already open
        keeps its span, one closed stays closed.
        """
        from rclpy.parameter import Parameter

        values = [Parameter('arrival', value=value)]
        values += [Parameter(k, value=v) for k, v in more.items()]
        end = time.monotonic() + 20.0
        while (left := end - time.monotonic()) > 0:
            fut = self.infeed.set_parameters(values)
            if self.wait(fut.done, min(ANSWER_S, left)):
                return all(r.successful for r in fut.result().results)
        return False

    def prepare(self) -> str | None:
        """
        Have every station ready and every parcel requested before the infeed opens.

        The controllers running, station 1's parameters served, the sort plan taken and
        every request taken by the warehouse: a parcel that reached its scanner first
        would have no destination. Return what failed, or None.
        """
        import numpy as np
        from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

        args, ctls, wait = self.args, self.ctls, self.wait
        if ctls is not None and not wait(
            lambda: all(c.logic is not None and c.logic.state == 'running' for c in ctls), 120.0
        ):
            return 'the stations\' controllers did not start within 120 s'
        if not wait(self.infeed.services_are_ready, 30.0):
            return 'station 1\'s parameter services did not appear within 30 s'
        # every station's edges, labels, routes and confirmations matched with the
        # warehouse, and every segment's exits with it and the observer: discovery across
        # processes can take seconds, and what is sent before it is lost
        writers = self.segments

        def unmatched():
            out = self.wcs.unmatched(writers)
            return out + ['line/exits (the demo)'] * (self._exits.get_publisher_count() < writers)

        if not wait(lambda: not unmatched(), 30.0):
            missing = unmatched()
            return (
                f'the warehouse had no peer on {len(missing)} of the line\'s topics after '
                f'30 s: {", ".join(missing[:6])}' + (', ...' if len(missing) > 6 else '')
            )
        self.chutes = [name for pair in self.wcs.wcs.chutes for name in pair]
        dests = [f'D{j + 1:02d}' for j in range(len(self.chutes))]
        wait(lambda: self.pub_plan.get_subscription_count() > 0, 10.0)
        self.pub_plan.publish(
            DiagnosticStatus(
                name='v1', values=[KeyValue(key=d, value=c) for d, c in zip(dests, self.chutes)]
            )
        )
        if not wait(lambda: self.active, 10.0):
            return 'the warehouse node did not take the sort plan'
        rng = np.random.default_rng(int(args.seed))
        # more than the infeed can send in the time, or the batch
        expected = args.parcels or math.ceil(args.sim_time * 1.5) + 10
        for i in range(1, expected + 1):
            self.pub_req.publish(
                KeyValue(key=f'P{i:05d}', value=dests[int(rng.integers(len(dests)))])
            )
            if i % 50 == 0:
                wait(lambda i=i: self.wcs.wcs.n_taken >= i, 10.0)
        if not wait(lambda: self.wcs.wcs.n_taken == expected, 10.0):
            return f'the warehouse node took {self.wcs.wcs.n_taken} of {expected} requests'
        return None

    def stream(self) -> str | None:
        """
        Open the infeed and run the line for the simulated time, or until the batch is out.

        What the summary measures (wall and simulated time, parcels out, where the wall
        time went) is taken here, before the drain, so that the throughput is the open
        infeed's. Return what failed, or None.
        """
        args, line, ctls = self.args, self.line, self.ctls
        if self.lockstep:
            if self._joined:
                self._settle_graph()  # the new nodes' topics matched before time moves
            self.spin_idle()  # the routing updates reach the stations
        else:
            self.wait(lambda: False, 0.3)  # the routing updates reach the stations
            self.wait(lambda: self.clock['t'] > 0.0, 30.0)
        t0, wall0 = self.line_t(), time.monotonic()
        if line is not None:
            line.cost = {'physics_s': 0.0, 'publish_s': 0.0}
            scans0 = [c.logic.scan_wall_total for c in ctls]
        # a timed stream is station 1's own span of simulated time (arrival_duration_s), so
        # that it gives the same parcels whatever the line's split and pace; a batch, its count
        self.span = {} if args.parcels else {'arrival_duration_s': float(args.sim_time)}
        if not self.set_arrival('gap', **self.span):
            return 'station 1 did not take arrival: gap'
        # station 1's time once it answered: the stream opened before
        self.t_opened = self.first_t()
        p0 = line.stations[0].params if line is not None else _cell_params()
        self.transit = self.n * (p0.exit_x - p0.induct_x) / p0.belt_speed
        # what a touch is: the stations' own (``--contact`` set it in process; segment
        # processes were given it on their command lines)
        self.contact = p0.contact if line is not None else self.contact or p0.contact
        if args.parcels:
            # a batch: until every parcel has its disposition (10 s a parcel at the most)
            end = t0 + 10.0 * args.parcels + 2.0 * self.transit
            self.wait_sim(lambda: len(self.records) >= args.parcels or self.line_t() >= end)
        else:
            self.wait_sim(lambda: self.line_t() >= t0 + args.sim_time - 1e-9)
        self.wall = time.monotonic() - wall0
        self.sim = self.line_t() - t0
        self.n_out = len(self.exits)
        self.cost = None
        if line is not None:
            ctl_s = sum(c.logic.scan_wall_total - w0 for c, w0 in zip(ctls, scans0))
            c = line.cost
            self.cost = {
                'physics': round(c['physics_s'], 3),
                'publishing': round(c['publish_s'], 3),
                'controllers': round(ctl_s, 3),
                'other': round(self.wall - c['physics_s'] - c['publish_s'] - ctl_s, 3),
            }
        return None

    def drain(self) -> int:
        """
        Close the infeed and run the line empty; return the parcels inducted.

        Every parcel inducted gets its disposition this way, so that the report's
        balance (dispositions + parcels still on the line = inducted) can be checked.
        """
        args, line = self.args, self.line
        if self.span and not args.no_drain:
            # the stream ends on station 1's clock, ahead of the one measured by: wait until
            # it has (station 1 completes once its last parcel is out), or station 1 is well
            # past the span's end (held by a jam, say)
            t_closed = self.t_opened + args.sim_time + 2.0 * self.transit / self.n + 10.0
            self.wait_sim(
                lambda: (
                    self.packml['state'] in ('Completing', 'Complete')
                    or self.first_t() >= t_closed
                )
            )
        # the infeed stops and the line runs empty, so that every parcel inducted gets its
        # disposition: at most the belt's transit over the whole line, twice, + 10 s
        self.set_arrival('none')
        # (--no-drain: at once)
        t_drain = self.line_t() + (0.0 if args.no_drain else 2.0 * self.transit + 10.0)
        if args.no_drain:
            inducted = line.stations[0].cell.n_inducted if line is not None else len(self.scanned)
        elif line is not None:
            self.wait_sim(lambda: line.line.n_parcels == 0 or line.line.t >= t_drain)
            inducted = line.stations[0].cell.n_inducted
        else:
            self.wait_sim(
                lambda: len(self.records) >= len(self.scanned) or self.line_t() >= t_drain
            )
            inducted = len(self.scanned)
        if line is not None and not self.lockstep:
            for timer in line.timers:
                timer.cancel()  # stop the clock; let the last messages in
        self.wait(lambda: len(self.records) >= inducted, 0.5 if args.no_drain else 5.0)
        return inducted

    def report(self, inducted: int) -> int | str:
        """
        Stop the segments, write the dispositions, print the summary; return the exit code.

        ``line_exit_code``'s; a message when the dispositions file cannot be written.
        """
        args, line, records = self.args, self.line, self.records
        seg_stats = _stop_segments(self.procs)
        # the parcels still on the stations' belts and disks, counted where they are
        if line is not None:
            on_line = line.line.n_in_flight
        else:
            on_line = sum(st['parcels'] for st in seg_stats)
            # station 1's own count, where its segment said it (every parcel scanned, else)
            inducted = next((st['inducted'] for st in seg_stats if 'inducted' in st), inducted)
        exit_counts = Counter(self.exits.values())
        codes = Counter(r['code'] for r in records)
        if args.dispositions:
            try:
                with open(args.dispositions, 'w', encoding='utf-8') as f:
                    for r in records:
                        f.write(json.dumps(r, sort_keys=True) + '\n')
            except OSError as exc:  # a full disk, a device that refuses: one line, exit 2
                return (
                    f'--dispositions {args.dispositions!r}: cannot write ({exc.strerror or exc})'
                )
        sim, wall = self.sim, self.wall
        summary = {
            'stations': self.n,
            'segments': self.segments,
            'inducted': inducted,
            'mis_sorted': codes.get('mis_sorted', 0),
            'jams': codes.get('jammed', 0),
            'lost': codes.get('lost', 0),
            'in_cell_at_end': on_line,
            'exits': dict(sorted(exit_counts.items())),
            'dispositions': dict(sorted(codes.items())),
            'throughput_pcs_h': 3600.0 * self.n_out / sim if sim > 0 else 0.0,
            'real_time_factor': sim / wall if wall > 0 else 0.0,
            'sim_time_s': sim,
            'executor': type(self.executor).__name__,
            'wall_s': wall,
            'chutes_reached': sum(1 for c in self.chutes if exit_counts.get(c)),
            'chutes': len(self.chutes),
            'contact': self.contact,
        }
        if self.cost is not None:
            # where the wall time went: the line's physics, the stations' publishing, the PLC
            # programs' scans; the rest is DDS, the executor and the callbacks around them
            summary['cost_s'] = self.cost
        if self.restarts.done:
            summary['restarted'] = self.restarts.done
        if seg_stats:
            summary['segment_stats'] = seg_stats
            summary['handovers'] = sum(s['handed_on'] for s in seg_stats)
        code = line_exit_code(summary, seg_stats)
        if args.json:
            print(json.dumps(summary, sort_keys=True))
        else:
            print_line_table(summary)
        return code


def print_line_table(s: dict) -> None:
    """
    Print the line demo's summary as a table, as the cell's (``demo_summary.print_table``).

    Parameters
    ----------
    s : dict
        The summary (``--json`` prints it whole).

    """

    def counts(d: dict) -> str:
        return ', '.join(f'{k} {v}' for k, v in d.items()) or 'none'

    how = f'in {s["segments"]} segment processes' if s['segments'] > 1 else 'in one process'
    rows = [
        (
            'simulated time',
            f'{s["sim_time_s"]:.1f} s in {s["wall_s"]:.1f} s wall '
            f'(real-time factor {s["real_time_factor"]:.2f}, {s["executor"]})',
        ),
        ('inducted', s['inducted']),
        ('contact', s.get('contact', 'rigid')),
        ('dispositions', counts(s['dispositions'])),
        ('mis-sorted', s['mis_sorted']),
        ('jams', s['jams']),
        ('lost', s['lost']),
        ('still on the line', s['in_cell_at_end']),
        ('throughput', f'{s["throughput_pcs_h"]:.0f} pcs/h'),
        ('chutes reached', f'{s["chutes_reached"]} of {s["chutes"]}'),
        ('exits', counts(s['exits'])),
    ]
    if 'cost_s' in s:
        c = s['cost_s']
        rows.append(
            (
                'wall time went to',
                f'physics {c["physics"]:.2f} s, publishing {c["publishing"]:.2f} s, '
                f'controllers {c["controllers"]:.2f} s, the rest {c["other"]:.2f} s',
            )
        )
    if s.get('segments', 1) > 1:
        rows.append(('hand-overs', s.get('handovers', 0)))
    for what in s.get('restarted', []):
        rows.append(('restarted', what))
    width = max(len(r[0]) for r in rows)
    print(f'sorter demo: a line of {s["stations"]} stations {how}, their PLCs and the warehouse')
    for name, value in rows:
        print(f'  {name:<{width}}  {value}')


def line_exit_code(summary: dict, seg_stats: list) -> int:
    """
    Return the line demo's exit code from its summary and its segments' figures.

    0 when no parcel was mis-sorted, jammed or lost (it went on past the station of
    its destination, which never answered for it: the line lost track of it), every
    parcel inducted has its disposition or is still on the line, and no segment
    refused a hand-over; 1 otherwise.
    """
    accounted = sum(summary['dispositions'].values()) + summary['in_cell_at_end']
    ok = (
        summary['mis_sorted'] == 0
        and summary['jams'] == 0
        and summary['lost'] == 0
        and accounted == summary['inducted']
        and all(s['refused'] == 0 for s in seg_stats)
    )
    return 0 if ok else 1


def _cell_params():
    """Return the stations' parameters as the shipped params file sets them."""
    from sorter_ros.env import find_config_dir
    from sorter_ros.params_file import read_params_file
    from sorter_sim.runtime.params import CellParams

    return CellParams.from_values(read_params_file(find_config_dir() / 'cell.yaml', 'sorter_sim'))


def _stop_segments(procs) -> list[dict]:
    """Stop the segment processes; return what each reported."""
    out = []
    for proc, _ in procs:
        proc.terminate()
    for proc, _ in procs:
        try:
            text, _ = proc.communicate(timeout=30)
        except Exception:  # noqa: BLE001 - a segment that will not stop reports nothing
            proc.kill()
            continue
        for line in reversed(text.strip().splitlines()):
            if line.startswith('{'):
                out.append(json.loads(line))
                break
    return out
