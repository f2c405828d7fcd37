"""
The run loop every runner of the cell and the line shares: one start-up, executor and slice loop.

``RunLoop`` owns a private rclpy ``Context`` (initialised with the shipped parameter
files, found through ``find_config_dir``, with discovery on this host unless the user
chose otherwise), the executor that spins the simulation with
every node added to it, and simulated time: ``run`` and ``run_until`` advance the
stepper (a simulation node or a line in ``lockstep`` time mode) slice by slice, and
after each slice ``spin_idle`` serves every callback until each node has caught up
with it. The demo (``sorter_cell.demo``), the line demo, the soft-PLC demo, and the
test harnesses (``sorter_cell.testing.SorterCell`` and ``SorterLine``) are faces of it
that say only what differs: which nodes, which observer, which report.

Why a slice ends where it ends. A node on simulated time has caught up when it has
taken the clock's last tick, every timer on that clock that fell due has run and every
service call it made has its answer; only then may time move on, or a scan or a command
would land in another slice on another run. With rclpy's events executor (the default)
the loop knows this exactly and at no cost in wall time: a message between nodes of one
process is delivered inside the publisher's call (Fast DDS's intra-process delivery)
and queued in order, so a marker message the loop sends itself after a slice is served
only after everything the slice caused (``_drain``). The single-threaded executor gives no such
order; with it, and for nodes in other processes, a slice ends after ``grace_s`` of
wall time in which no callback came.
"""

from __future__ import annotations

import math
import time

# the one executor picker, with the environment it depends on (sorter_ros.env)
from sorter_ros.env import events_executor_class, make_executor  # noqa: F401

SLICE_S = 0.005  # simulated time per slice [s]
# wall time without a ready callback that ends a slice's spin with the single-threaded
# executor (the events executor drains the nodes of this process exactly: no grace)
GRACE_S = 0.0005
SETTLE_S = 0.2  # the most wall time a slice waits for answers to requests in flight
MATCH_S = 10.0  # the most wall time the first run waits for new nodes' topics to match
DRAIN_WALL_S = 5.0  # wall time after which a drain that never ends is given up (a stuck node)
DRAIN_ROUNDS = 64  # drain rounds a slice takes at most (a node that answers every marker)


class WaitTimedOut:
    """
    What ``run_until`` returns when the predicate did not come true: false, and why.

    ``assert loop.run_until(...)`` then fails with the report (pytest shows this object's
    text in the assertion), so the failure says where the run was.
    """

    def __init__(self, text: str):
        self.text = text

    def __bool__(self) -> bool:
        return False

    def __repr__(self) -> str:
        return self.text

    __str__ = __repr__


def unmatched_topics(nodes) -> list[str]:
    """
    Return the topics ``nodes`` publish that their own readers are not all matched on.

    Their own readers only: the graph may still list those of a process that ended
    (until its lease runs out), which no writer will ever match.
    """
    readers: dict[str, int] = {}
    for node in nodes:
        for sub in node.subscriptions:
            readers[sub.topic_name] = readers.get(sub.topic_name, 0) + 1
    out = []
    for node in nodes:
        for pub in node.publishers:
            if pub.get_subscription_count() < readers.get(pub.topic_name, 0):
                out.append(pub.topic_name)
    return out


def _falls_due(timer) -> bool:
    """Return whether ``timer`` is due now (its next call is not ahead; not cancelled)."""
    left = timer.time_until_next_call()  # None: cancelled
    return left is not None and left <= 0


class RunLoop:
    """
    A Context, its executor and simulated time, for any runner (see the module).

    Parameters
    ----------
    domain_id : int, optional
        The ROS domain (default: ``ROS_DOMAIN_ID``, else rcl's own, 0).
    slice_s : float
        Simulated seconds per slice of ``run``, in (0, 1].
    grace_s : float, optional
        Wall seconds of quiet that end a slice's spin, for nodes the executor cannot
        drain (in other processes; every node with the single-threaded executor);
        default: none with the events executor, ``GRACE_S`` with the single-threaded one.
    events : bool
        Spin with rclpy's events executor (where there is one), else the single-threaded one.
    params_files : tuple of str
        The shipped parameter files the Context reads (names in ``find_config_dir()``).
    log_level : str
        The nodes' log level.
    ros_args : tuple of str
        More ROS arguments for the Context (a remapping: ``('-r', '/clock:=/mine')``).
    align_to_timers : bool
        End a slice early where a timer on simulated time falls due (``run``): a node
        that acts only in its timers (a PLC's scan) then sees every slice end at one of
        its scans, and a slice can be as long as the scan period with the same result.

    """

    what = 'the run'
    align_to_timers = False

    def __init__(
        self,
        *,
        domain_id: int | None = None,
        slice_s: float = SLICE_S,
        grace_s: float | None = None,
        events: bool = True,
        params_files: tuple = ('cell.yaml', 'controller.yaml'),
        log_level: str = 'warn',
        align_to_timers: bool = False,
        ros_args: tuple = (),
    ):
        self.align_to_timers = align_to_timers
        self._start_context(
            domain_id,
            slice_s,
            grace_s,
            events=events,
            params_files=params_files,
            log_level=log_level,
            ros_args=ros_args,
        )

    def _start_context(
        self,
        domain_id: int | None,
        slice_s: float,
        grace_s: float | None,
        events: bool = True,
        params_files: tuple = ('cell.yaml', 'controller.yaml'),
        log_level: str = 'warn',
        ros_args: tuple = (),
    ) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions

        from sorter_ros.env import apply_ros_env_defaults, find_config_dir

        if not (isinstance(slice_s, (int, float)) and 0.0 < slice_s <= 1.0):
            raise ValueError(f'slice_s must be in (0, 1] s, got {slice_s!r}')
        self._events = events and events_executor_class() is not None
        if grace_s is None:
            grace_s = 0.0 if self._events else GRACE_S
        if not (isinstance(grace_s, (int, float)) and 0.0 <= grace_s <= 1.0):
            raise ValueError(f'grace_s must be in [0, 1] s, got {grace_s!r}')
        apply_ros_env_defaults()
        self.wall0 = time.monotonic()
        self.config_dir = find_config_dir()
        self.slice_s = float(slice_s)
        self.grace_s = float(grace_s)
        self.nodes: list = []
        self._watch_key, self._watch = None, ([], [])  # _watched's lists and what they hold
        self._due, self._due_at = [], (None, -1)  # the timers due in the coming slice, when
        self._look = [None, -1, [], [], False]  # what _unsettled's last look left unsettled
        self.record_path = ''
        self._barrier = None
        self._barrier_served = None
        self._barrier_seen = False  # a marker came back: later drains need no timeout
        self.domain_id = None if domain_id is None else int(domain_id)
        self.context = Context()
        args = ['--ros-args']
        for name in params_files:
            args += ['--params-file', str(self.config_dir / name)]
        rclpy.init(
            context=self.context,
            **({} if self.domain_id is None else {'domain_id': self.domain_id}),
            signal_handler_options=SignalHandlerOptions.NO,
            args=args + [*ros_args, '--log-level', log_level],
        )
        self.executor = make_executor(self.context, self._events)

    # ------------------------------------------------------------------ nodes
    def add_node(self, node):
        """
        Spin ``node`` (or each of a list of nodes) with the simulation; it must be in ``context``.

        Parameters
        ----------
        node : rclpy.node.Node or list of them
            The node(s).

        Returns
        -------
        rclpy.node.Node or list
            The same.

        """
        if isinstance(node, (list, tuple)):
            return [self.add_node(n) for n in node]
        if getattr(node, 'context', None) is not self.context:
            name = node.get_name() if hasattr(node, 'get_name') else repr(node)
            raise ValueError(
                f'node {name!r} belongs to another rclpy Context: create it '
                'with context=sorter_cell.context'
            )
        if node not in self.nodes:
            if self._barrier is None and self._events:
                self._make_barrier(node)
            self.nodes.append(node)
            self.executor.add_node(node)
            self._joined = True
        return node

    def _unmatched(self) -> list[str]:
        """Return the topics our nodes publish that our own readers are not all matched on."""
        return unmatched_topics(self.nodes)

    def _graph_settled(self) -> bool:
        return not self._unmatched()

    def _settle_graph(self) -> None:
        """
        Before time moves after nodes joined: wait until their topics are matched.

        DDS matches a new reader to a writer on threads of its own; on a loaded machine
        that takes seconds, and a message sent before it is lost (a routing update, a
        label), so the run would depend on the machine. With the clock stopped until
        every reader the graph knows is matched, it does not.
        """
        self._joined = False
        deadline = time.monotonic() + MATCH_S
        while not self._graph_settled() and time.monotonic() < deadline:
            self.spin_idle()
            time.sleep(0.002)

    def remove_node(self, node) -> None:
        """Stop spinning ``node`` and destroy it."""
        if node in self.nodes:
            self.nodes.remove(node)
            # a timer of the node that came due just now may still be on the executor's
            # queue: cancelled, it stays quiet, and one spin lets the executor let go of
            # the node before it is destroyed (its callbacks would meet destroyed handles)
            for timer in list(node.timers):
                timer.cancel()
            if node is getattr(self, '_barrier_node', None):
                self._drop_barrier()
            self.executor.remove_node(node)
            self.executor.spin_once(timeout_sec=0.0)
        node.destroy_node()

    def _make_barrier(self, node) -> None:
        """
        Give the first node the drain's marker: a hidden topic it sends itself.

        Made before the executor takes the node, so that the executor knows it from the
        start. (The events executor serves no guard condition, which would cost less.)
        """
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.serialization import serialize_message
        from std_msgs.msg import Empty

        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=4, reliability=ReliabilityPolicy.RELIABLE
        )
        topic = '~/_run_loop_drain'
        self._barrier_node = node
        # sent and taken as its CDR bytes: a marker is a few a slice, and converting an
        # Empty to and from Python would cost each of them more than its delivery
        self._barrier_msg = serialize_message(Empty())
        self._barrier = node.create_publisher(Empty, topic, qos)
        self._barrier_sub = node.create_subscription(Empty, topic, self._on_barrier, qos, raw=True)

    def _drop_barrier(self) -> None:
        if self._barrier is not None:
            self._barrier_node.destroy_subscription(self._barrier_sub)
            self._barrier_node.destroy_publisher(self._barrier)
        self._barrier = self._barrier_node = self._barrier_sub = None
        self._barrier_seen = False

    # ------------------------------------------------------------------ time
    # set by a face: the node whose ``advance(n)`` runs n control periods and the
    # runtime whose ``dt``, ``t`` and ``t_ns`` are the simulated time (a cell, a line)
    _stepper = None
    _timebase = None
    _joined = False  # nodes were added since time last moved

    @property
    def dt(self) -> float:
        """Return the control period [s]."""
        return self._timebase.dt

    @property
    def t(self) -> float:
        """Return the simulated time [s]."""
        return self._timebase.t

    @property
    def t_ns(self) -> int:
        """Return the simulated time the clock last published [ns]."""
        return self._timebase.t_ns

    def _advance(self, n: int) -> None:
        self._stepper.advance(n)

    def _watched(self) -> tuple:
        """
        Return every node's clients and, per node, its ROS clock with the timers on it.

        Kept from one check to the next and made again when a node was added or
        removed, or made or dropped a client or a timer: the checks after each slice,
        a few a slice, then walk flat lists (24 stations: 51 nodes, 342 clients).
        """
        from rclpy.clock import ROSClock

        nodes = self.nodes
        # rclpy keeps a node's clients and timers in these lists (Node.clients, .timers);
        # a new one is appended: the count and the last one tell a change (the nodes
        # themselves, not their ids: a node made where a dropped one was is another)
        key = list(nodes)
        for node in nodes:
            for made in (node._clients, node._timers):
                key.append(id(made[-1]) if made else len(made))
                key.append(len(made))
        if key != self._watch_key:
            clients = [c for node in nodes for c in node._clients]
            clocked = []
            for node in nodes:
                clock = node.get_clock()
                if isinstance(clock, ROSClock):
                    clocked.append((clock, [t for t in node._timers if t.clock is clock]))
            self._watch_key, self._watch = key, (clients, clocked)
        return self._watch

    def _unsettled(self) -> bool:
        """
        Return True while a node has not yet caught up with the slice just run.

        Caught up: every node on simulated time has taken the clock's last tick, every
        timer on that clock that fell due has run, and every service call has its answer.
        Which timers fall due in a slice ``_periods_to_next_timer`` found before it ran
        (time stands still in between): only those are looked at again.
        """
        watch = self._watched()
        clients, clocked = watch
        for c in clients:
            if c._pending_requests:
                return True
        t_ns = self.t_ns
        look = self._look
        if look[0] is not watch or look[1] != t_ns:
            # the slice's first look: every clock, and the timers due in it if known (else
            # those of every clock on simulated time); a later look in the same slice
            # takes up only what the last one left (time stands still: a node caught up
            # stays so, a timer that ran is not due again)
            known = self._due_at[0] is watch and self._due_at[1] == t_ns
            look = self._look = [watch, t_ns, clocked, list(self._due) if known else [], known]
        behind, timers, known = [], look[3], look[4]
        for entry in look[2]:
            # one reading says both: behind the slice (not caught up), at it (on simulated
            # time), or past it (off simulated time: the wall's clock, whose timers the
            # slices do not wait for), as Clock.ros_time_is_active would at twice the cost
            now = entry[0].handle.get_now().nanoseconds
            if now < t_ns:
                behind.append(entry)
            elif now == t_ns and not known:
                timers += entry[1]
        look[2] = behind
        if behind:
            return True  # (a timer is judged on its clock once that has caught up)
        look[3] = [t for t in timers if _falls_due(t)]
        return bool(look[3])

    def _periods_to_next_timer(self, most: int, align: bool = True) -> int:
        """
        Return the control periods until a timer on simulated time falls due (1..most).

        A timer falls due at the first period boundary at or after its next call. The
        timers that fall due within those periods (``align=False``: within ``most``,
        which is returned) are kept for ``_unsettled``.
        """
        dt_ns = round(self.dt * 1e9)
        watch = self._watched()
        lefts = []
        t_ns = self.t_ns
        behind = False
        for clock, timers in watch[1]:
            now = clock.handle.get_now().nanoseconds
            if now <= t_ns:  # on simulated time (_unsettled)
                behind |= now < t_ns
                for timer in timers:
                    left = timer.time_until_next_call()  # None: cancelled
                    if left is not None:
                        lefts.append((left, timer))
        least = min([most * dt_ns] + [left for left, _ in lefts])
        n = min(most, max(1, -(-least // dt_ns))) if align else most
        # a clock still behind (a node just added, a slice that settled late) measures
        # its timers from its own time: which fall due is known only once it catches up
        self._due = [timer for left, timer in lefts if left <= n * dt_ns]
        self._due_at = (None, -1) if behind else (watch, t_ns + n * dt_ns)
        return n

    def _on_barrier(self, _msg) -> None:
        if self._barrier_served is not None:
            self._barrier_served.set_result(True)

    def _drain(self, looks: int, mark: bool = True) -> int:
        """
        Serve every callback queued so far and what they queue in turn, in order.

        The events executor serves its queue in the order events came, and a message
        between nodes of this process is queued inside the publisher's call: a marker
        sent now is served after everything already delivered. Once the first marker is
        back, each look sends another and serves one event: the marker itself (nothing
        came behind the last one: done), or something else, after which the look waits
        for its marker and looks again. Return the looks that found something (at most
        ``looks``: a node that answers every marker would keep each one busy).

        ``mark=False`` starts with the looks: after one callback was served alone (the
        scan's timer), what it queued is usually nothing, which one look tells; the first
        marker serves a slice's many messages in one call to the executor.
        """
        from rclpy.task import Future

        if not mark and self._barrier_seen:
            return self._looks(looks)
        self._barrier_served = Future()
        self._barrier.publish(self._barrier_msg)
        # the marker is queued before this call: no timeout (a timeout costs the executor
        # a timer, a third of the call) unless no marker has come back yet
        wait = {} if self._barrier_seen else {'timeout_sec': DRAIN_WALL_S}
        self.executor.spin_until_future_complete(self._barrier_served, **wait)
        if not self._barrier_served.done():
            return 0  # a callback that never lets go: the settle check waits on its own
        self._barrier_seen = True
        return self._looks(looks)

    def _looks(self, looks: int) -> int:
        """Look behind the last marker until nothing is (``_drain``); return the busy looks."""
        from rclpy.task import Future

        busy = 0
        while busy < looks:
            self._barrier_served = Future()
            self._barrier.publish(self._barrier_msg)
            # with an event queued, one spin_once serves it at once; a timeout of 0 costs
            # more than a long one that is never waited for
            self.executor.spin_once(timeout_sec=DRAIN_WALL_S)
            if self._barrier_served.done():
                return busy
            busy += 1
            self.executor.spin_until_future_complete(self._barrier_served)
        return busy

    def spin_idle(self) -> None:
        """
        Serve every ready callback until every node has caught up with the slice.

        With the events executor: drain its queue until nothing but the marker ran, then
        (for nodes in other processes) until none came for ``grace_s``. With the
        single-threaded one: until none came for ``grace_s``. Then, up to ``SETTLE_S``
        of wall time, until every node has caught up (``_unsettled``): on a loaded
        machine a service's answer or a timer can take longer, and a command must reach
        the cell in the slice it was given in, or two runs would differ.
        """
        settle_end = None
        rounds = 0
        served_one = False  # the last thing that ran was one callback, served alone
        while True:
            if self._barrier is not None and rounds < DRAIN_ROUNDS:
                # each look runs what the one before caused; a node that subscribed to
                # the marker itself would make every look busy: the bound ends that
                rounds += self._drain(DRAIN_ROUNDS - rounds, mark=not served_one)
            if self.grace_s > 0.0 and self.serve_one(self.grace_s):
                served_one = False
                continue
            if not self._unsettled():
                return
            if not self._events:
                # a timer on simulated time that the clock's tick made due does not wake
                # the single-threaded executor's wait by itself: it would run a slice late
                self.executor.wake()
            now = time.monotonic()
            settle_end = settle_end or now + SETTLE_S
            if now > settle_end:
                return
            # what is awaited comes from another thread (DDS, a timer's own): wait for it
            served_one = self.serve_one(0.0005)

    def serve_one(self, timeout_s: float) -> bool:
        """Serve one ready callback; return False when none came within ``timeout_s``."""
        from rclpy.executors import ShutdownException, TimeoutException

        if self._events:
            # the events executor says nothing of what it did: a call that returns before
            # the timeout is up served an event
            t0 = time.perf_counter()
            self.executor.spin_once(timeout_sec=timeout_s)
            return time.perf_counter() - t0 < timeout_s
        try:
            handler, _, _ = self.executor.wait_for_ready_callbacks(timeout_sec=timeout_s)
        except (TimeoutException, ShutdownException):
            return False
        handler()
        return True

    def spin_until(self, predicate, timeout_wall: float = math.inf, stop=None) -> bool:
        """
        Spin, without advancing simulated time, until ``predicate()`` or ``timeout_wall``.

        For a node that runs its own time (``realtime`` mode) or is starting up.

        Parameters
        ----------
        predicate : callable
            What to wait for.
        timeout_wall : float
            The most to wait [s, wall].
        stop : threading.Event-like, optional
            Ends the wait early when set (a SIGINT).

        Returns
        -------
        bool
            Whether the predicate came true in time.

        """
        deadline = time.monotonic() + timeout_wall
        while not predicate():
            if stop is not None and stop.is_set():
                return False
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def wait_started(self, predicate, timeout_s: float, what: str) -> None:
        """
        Spin, without advancing simulated time, until ``predicate()`` (nodes starting up).

        A node that starts (asks the cell for its geometry, warms a model) takes wall
        time that depends on the machine; with the clock stopped meanwhile, the run
        that follows starts at t = 0 on every machine, and runs repeat exactly.

        Raises
        ------
        RuntimeError
            Not within ``timeout_s`` wall seconds; the message is ``explain()``.

        """
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                raise RuntimeError(self.explain(f'{what} within {timeout_s:g} s of wall time'))
            self.spin_idle()
            # the starting node's own threads (a service answer) get the core
            self.serve_one(0.001)

    def run(self, seconds: float) -> None:
        """
        Advance simulated time by ``seconds``, spinning every node after each slice.

        Parameters
        ----------
        seconds : float
            Simulated seconds, >= 0 (rounded to whole control periods).

        """
        if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds >= 0):
            raise ValueError(f'seconds must be a finite number >= 0, got {seconds!r}')
        total = round(seconds / self.dt)
        step = max(1, round(self.slice_s / self.dt))
        if self._joined:
            self._settle_graph()
        self.spin_idle()
        while total > 0:
            total -= self._slice(min(step, total))

    def _slice(self, n: int) -> int:
        """Run one slice of at most ``n`` periods and serve what it caused; return its periods."""
        n = self._periods_to_next_timer(n, self.align_to_timers)
        self._advance(n)
        self.spin_idle()
        return n

    def step(self) -> bool:
        """
        Run one slice (``slice_s``, to the next timer when aligned); return whether time moved.

        For a stepper that may hold its time (a line segment waiting for its neighbours):
        when it did not move, ``serve_one`` waits for the message that lets it go on.
        """
        if self._joined:
            self._settle_graph()
        t = self.t
        self._slice(max(1, round(self.slice_s / self.dt)))
        return self.t != t

    def run_until(self, predicate, timeout_s: float = 60.0, what: str = '', stop=None):
        """
        Advance slice by slice until ``predicate()`` holds or ``timeout_s`` simulated seconds.

        Parameters
        ----------
        predicate : callable
            What to wait for.
        timeout_s : float
            The most simulated time to run [s].
        what : str
            What it waits for, in words, for the report.
        stop : threading.Event-like, optional
            Ends the run early when set (a SIGINT); the result is then a ``WaitTimedOut``
            that says so.

        Returns
        -------
        True or WaitTimedOut
            True when it came true; else a false value whose text is ``explain()``.

        """
        t_start = self.t
        t_end = t_start + timeout_s
        while not predicate():
            if stop is not None and stop.is_set():
                return WaitTimedOut(self.explain('stopped'))
            if self.t >= t_end - 1e-12:
                name = what or getattr(predicate, '__name__', 'the predicate')
                return WaitTimedOut(
                    self.explain(
                        f'waited {timeout_s:g} s of simulated time for {name}: it did not come'
                    )
                )
            self.run(min(self.slice_s, t_end - self.t))
        return True

    def require(self, predicate, timeout_s: float = 60.0, what: str = '') -> None:
        """Run as ``run_until``, but raise ``AssertionError`` with the report on a time-out."""
        done = self.run_until(predicate, timeout_s, what)
        if not done:
            raise AssertionError(str(done))

    # ------------------------------------------------------------------ the report
    def state_lines(self) -> list[str]:
        """Return the lines of the report after the time (a face says what it has)."""
        return []

    def explain(self, headline: str = '') -> str:
        """
        Return where the run is, for a failure: times, the face's state, the recording.

        Parameters
        ----------
        headline : str
            The first line (what went wrong).

        Returns
        -------
        str
            The report, one fact a line.

        """
        lines = [headline] if headline else []
        lines.append(
            f'{self.what}: t = {self.t:.3f} s simulated, '
            f'{time.monotonic() - self.wall0:.1f} s wall since it started'
        )
        try:
            lines += self.state_lines()
        except Exception as exc:  # noqa: BLE001 - a report must not hide the failure
            lines.append(f'(state not available: {exc})')
        if self.record_path:
            lines.append(f'recording: {self.record_path}')
        return '\n'.join(lines)

    # ------------------------------------------------------------------ teardown
    def close(self) -> None:
        """Destroy the nodes and shut the Context down."""
        import rclpy

        executor = getattr(self, 'executor', None)
        if executor is not None:
            for node in list(getattr(self, 'nodes', [])):
                executor.remove_node(node)
            executor.shutdown()
            self.executor = None
        if getattr(self, '_barrier', None) is not None:
            self._drop_barrier()
        for node in reversed(getattr(self, 'nodes', [])):
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - a node's own teardown error ends nothing
                pass
        self.nodes = []
        if getattr(self, 'context', None) is not None:
            rclpy.try_shutdown(context=self.context)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
