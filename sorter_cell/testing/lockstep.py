"""
What a cell and a line under test share: a private Context, lock-step time, waits that explain.

``LockStep`` owns the rclpy Context (initialised with the shipped params files, found
through ``sorter_ros.env.find_config_dir``), the executor that spins the simulation
with every node the test adds, the slice loop of ``run`` and ``run_until``, and the
report a wait that times out gives: simulated and wall time, the parcels inducted, on
the belt and out with their exits, the active faults and PackML state, and where the
recording is. ``SorterCell`` (``harness``) and ``SorterLine`` (``line``) fill in
what a cell or a line has of each.

``load_node_factory`` and ``make_user_nodes`` turn ``"module:callable"`` into the
user's nodes, for scenario files and the station-contract check alike.
"""

from __future__ import annotations

import importlib
import math
import os
import sys
import time
from contextlib import contextmanager
from pathlib import Path

GRACE_S = 0.0005  # wall time without a ready callback that ends a slice's spin
SLICE_S = 0.005  # simulated time per slice
SETTLE_S = 0.2  # the most wall time a slice waits for answers to requests in flight
MATCH_S = 10.0  # the most wall time the first run waits for new nodes' topics to match


def pick_domain_id() -> int:
    """
    Return the ROS domain this process's cells use: ``ROS_DOMAIN_ID``, else one of 100-199.

    A test run should keep to a domain of its own so that concurrent runs (and any ROS
    graph on the machine) stay apart; above 232 Fast DDS fails, so the default is
    taken from the process id in 100-199.
    """
    value = os.environ.get('ROS_DOMAIN_ID', '').strip()
    if value.isdigit() and 0 <= int(value) <= 232:
        return int(value)
    return 100 + os.getpid() % 100


def _events_executor_class():
    """Return rclpy's events executor (C++, walks no wait set), or None where it is missing."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:
        return None
    return EventsExecutor


class WaitTimedOut:
    """
    What ``run_until`` returns when the predicate did not come true: false, and why.

    ``assert cell.run_until(...)`` then fails with the report (pytest shows this
    object's text in the assertion), so the failure says where the run was.
    """

    def __init__(self, text: str):
        self.text = text

    def __bool__(self) -> bool:
        return False

    def __repr__(self) -> str:
        return self.text

    __str__ = __repr__


class LockStep:
    """The Context, the executor and the clock of a cell or line under test (see the module)."""

    what = 'the cell'

    def _start_context(
        self, domain_id: int | None, slice_s: float, grace_s: float, events: bool = False
    ) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from sorter_ros.env import apply_ros_env_defaults, find_config_dir

        if not (isinstance(slice_s, (int, float)) and 0.0 < slice_s <= 1.0):
            raise ValueError(f'slice_s must be in (0, 1] s, got {slice_s!r}')
        apply_ros_env_defaults()
        self.wall0 = time.monotonic()
        self.config_dir = find_config_dir()
        self.slice_s = float(slice_s)
        self.grace_s = float(grace_s)
        self.nodes: list = []
        self.record_path = ''
        self.domain_id = pick_domain_id() if domain_id is None else int(domain_id)
        self.context = Context()
        rclpy.init(
            context=self.context,
            domain_id=self.domain_id,
            signal_handler_options=SignalHandlerOptions.NO,
            args=[
                '--ros-args',
                '--params-file',
                str(self.config_dir / 'cell.yaml'),
                '--params-file',
                str(self.config_dir / 'controller.yaml'),
                '--log-level',
                'warn',
            ],
        )
        self._events = events and _events_executor_class() is not None
        if self._events:
            self.executor = _events_executor_class()(context=self.context)
        else:
            self.executor = SingleThreadedExecutor(context=self.context)

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
            self.nodes.append(node)
            self.executor.add_node(node)
            self._joined = True
        return node

    def _unmatched(self) -> list[str]:
        """
        Return the topics a node of ours publishes that our own readers are not all matched on.

        Our own readers only: the graph may still list those of a process that ended
        (until its lease runs out), which no writer will ever match.
        """
        readers: dict[str, int] = {}
        for node in self.nodes:
            for sub in node.subscriptions:
                readers[sub.topic_name] = readers.get(sub.topic_name, 0) + 1
        out = []
        for node in self.nodes:
            for pub in node.publishers:
                if pub.get_subscription_count() < readers.get(pub.topic_name, 0):
                    out.append(pub.topic_name)
        return out

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
            self.executor.remove_node(node)
            self.executor.spin_once(timeout_sec=0.0)
        node.destroy_node()

    # ------------------------------------------------------------------ time
    # set by a subclass: the node whose ``advance(n)`` runs n control periods and the
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

    def _unsettled(self) -> bool:
        """
        Return True while a node has not yet caught up with the slice just run.

        Caught up: every node on simulated time has taken the clock's last tick, every
        timer on that clock that fell due has run, and every service call has its answer.
        An executor that runs timers from a thread of its own (the events executor) or a
        loaded machine can leave any of these for longer than the grace; waiting for them
        makes each slice end in the same state on every run.
        """
        from rclpy.clock import ROSClock

        t_ns = self.t_ns
        for node in self.nodes:
            if any(c._pending_requests for c in node.clients):
                return True
            clock = node.get_clock()
            if not (isinstance(clock, ROSClock) and clock.ros_time_is_active):
                continue
            if clock.now().nanoseconds < t_ns:
                return True
            for timer in node.timers:
                if timer.clock is clock and not timer.is_canceled():
                    left = timer.time_until_next_call()
                    if left is not None and left <= 0:
                        return True
        return False

    def spin_idle(self) -> None:
        """
        Serve every ready callback until none has come for ``grace_s`` of wall time.

        Then, up to ``SETTLE_S`` of wall time, until every node has caught up with the
        slice (``_unsettled``): on a loaded machine a service's answer or a timer can
        take longer than the grace, and a command must reach the cell in the slice it
        was given in, or two runs would differ.
        """
        settle_end = None
        while True:
            if self._serve_one():
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

    def _serve_one(self) -> bool:
        """Serve one ready callback; return False when none came within ``grace_s``."""
        from rclpy.executors import ShutdownException, TimeoutException

        if self._events:
            # the events executor says nothing of what it did: a call that returns before
            # the grace is up served an event
            t0 = time.perf_counter()
            self.executor.spin_once(timeout_sec=self.grace_s)
            return time.perf_counter() - t0 < self.grace_s
        try:
            handler, _, _ = self.executor.wait_for_ready_callbacks(timeout_sec=self.grace_s)
        except (TimeoutException, ShutdownException):
            return False
        handler()
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
            time.sleep(0.001)  # the starting node's own threads (a service answer) get the core

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
            n = min(step, total)
            self._advance(n)
            total -= n
            self.spin_idle()

    def run_until(self, predicate, timeout_s: float = 60.0, what: str = ''):
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

        Returns
        -------
        True or WaitTimedOut
            True when it came true; else a false value whose text is ``explain()``.

        """
        t_start = self.t
        t_end = t_start + timeout_s
        while not predicate():
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
        """Return the lines of the report after the time: parcels, faults, PackML."""
        raise NotImplementedError

    def explain(self, headline: str = '') -> str:
        """
        Return where the run is, for a failure: times, parcels, faults, PackML, the recording.

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


# a parcel a test inducts without saying more (SorterCell.induct's defaults)
PARCEL_DEFAULTS = {'length': 0.4, 'width': 0.3, 'mass': 5.0, 'skew_deg': 0.0, 'y': 0.0}


def parcel_spec(label: str, length: float, width: float, mass: float, skew_deg: float, y: float):
    """Return the cell's ``ParcelSpec`` of a parcel a test inducts (see ``SorterCell.induct``)."""
    from sorter_sim.runtime.cell import ParcelSpec

    return ParcelSpec(length, width, mass, math.radians(skew_deg), y, label)


def exits_text(records, limit: int = 12) -> str:
    """Return ``label exit at t`` for the first ``limit`` of (label, exit, t) records."""
    parts = [f'{label or "(no label)"} {exit} at {t:.3f} s' for label, exit, t in records[:limit]]
    if len(records) > limit:
        parts.append(f'... {len(records) - limit} more')
    return ', '.join(parts) or 'none'


# ---------------------------------------------------------------------- user nodes
class FactoryError(ValueError):
    """A ``module:callable`` that cannot be used: the message says what is wrong."""


@contextmanager
def _importable_from(folder):
    added = folder is not None and str(folder) not in sys.path
    if added:
        sys.path.insert(0, str(folder))
    try:
        yield
    finally:
        if added:
            sys.path.remove(str(folder))


def load_node_factory(spec: str, folder: str | Path | None = None):
    """
    Return the callable ``"module:callable"`` names, importing the module from ``folder`` first.

    Parameters
    ----------
    spec : str
        ``module:callable`` (a dotted module, a dotted attribute path).
    folder : str or Path, optional
        A folder tried before ``sys.path`` (a scenario file's).

    Returns
    -------
    callable
        The factory.

    Raises
    ------
    FactoryError
        A malformed spec, a module that does not import, a name it does not have.

    """
    if not isinstance(spec, str) or spec.count(':') != 1 or not all(spec.split(':')):
        raise FactoryError(f'must be "module:callable", got {spec!r}')
    module_name, attr = spec.split(':')
    with _importable_from(folder):
        try:
            obj = importlib.import_module(module_name)
        except Exception as exc:  # noqa: BLE001 - any import error is the user's to see
            raise FactoryError(
                f'cannot import {module_name!r} (from {folder or "sys.path"}): '
                f'{type(exc).__name__}: {exc}'
            ) from None
    for part in attr.split('.'):
        if not hasattr(obj, part):
            raise FactoryError(f'{module_name!r} has no {attr!r}')
        obj = getattr(obj, part)
    if not callable(obj):
        raise FactoryError(f'{spec!r} is not callable')
    return obj


def make_user_nodes(factory, context, parameters: dict | None = None, **kwargs) -> list:
    """
    Call ``factory(context=..., parameter_overrides=[...], **kwargs)`` and return its nodes.

    ``use_sim_time`` is always among the overrides: a node under test runs on the
    simulation's clock (the test's), or it would run on the wall clock beside it.

    Parameters
    ----------
    factory : callable
        Returns a node or a list of nodes.
    context : rclpy.context.Context
        The simulation's.
    parameters : dict, optional
        Parameter overrides, name -> value.
    **kwargs
        More keyword arguments (``namespace`` for a station's program).

    Returns
    -------
    list of rclpy.node.Node
        The nodes.

    """
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    values = {'use_sim_time': True, **(parameters or {})}
    overrides = [Parameter(k, value=v) for k, v in values.items()]
    made = factory(context=context, parameter_overrides=overrides, **kwargs)
    nodes = list(made) if isinstance(made, (list, tuple)) else [made]
    if not nodes or not all(isinstance(n, Node) for n in nodes):
        for n in nodes:
            if isinstance(n, Node):
                n.destroy_node()
        raise FactoryError(f'{factory!r} must return a node or a list of nodes, got {made!r}')
    return nodes
