"""
The cell under test: the simulation node in a private rclpy Context, in lock-step.

``SorterCell`` starts the real simulation node (``sorter_sim.frontends.node.SimNode``)
in a Context of its own, with ``time_mode: lockstep``, and an executor that spins
it with every node the test adds. ``run(seconds)`` advances simulated time a slice
at a time (5 ms by default: half the controller's 10 ms scan) and, after each
slice, serves every callback that is ready until the graph has been quiet for
``grace`` seconds of wall time: the nodes see each sensor edge, label and clock
tick, and their answers (service calls, parameters, heartbeats) reach the cell
before the next slice, whatever the machine's speed. Everything between the
nodes goes over DDS, as in the field; only the clock is the test's.

What the test reads comes from an observer node subscribed like any warehouse
client: ``outcomes`` (the cell's ``sort/outcomes``) and ``confirmations`` (a
controller's ``sort/confirmations``, when one runs).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field

GRACE_S = 0.0005  # wall time without a ready callback that ends a slice's spin
SLICE_S = 0.005  # simulated time per slice


@dataclass(frozen=True)
class OutcomeRecord:
    """
    Where the cell says a parcel went (``sort/outcomes``).

    label, id, exit (left | right | straight | jammed), t (simulated, s), cause (what
    jammed it, or '').
    """

    label: str
    id: int
    exit: str
    t: float
    cause: str = ''

    @property
    def jammed(self) -> bool:
        return self.exit == 'jammed'


@dataclass
class _Observer:
    node: object
    outcomes: list = field(default_factory=list)
    confirmations: list = field(default_factory=list)


def _values(msg) -> dict:
    return {kv.key: kv.value for kv in msg.values}


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


class SorterCell:
    """
    The simulation node in a private Context, advanced by the test (see the module).

    Parameters
    ----------
    params : dict, optional
        The cell's parameters over config/cell.yaml (``time_mode`` is lockstep and
        ``arrival`` none unless given: parcels come from ``induct`` or the stream the
        test asks for).
    domain_id : int, optional
        The ROS domain (default: ``pick_domain_id()``).
    slice_s : float
        Simulated seconds per slice of ``run``.
    grace_s : float
        Wall seconds of quiet that end a slice's spin.

    """

    def __init__(
        self,
        params: dict | None = None,
        *,
        domain_id: int | None = None,
        slice_s: float = SLICE_S,
        grace_s: float = GRACE_S,
    ):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter
        from rclpy.signals import SignalHandlerOptions

        from sorter_ros.env import apply_ros_env_defaults, find_config_dir
        from sorter_sim.frontends.node import SimNode

        if not (isinstance(slice_s, (int, float)) and 0.0 < slice_s <= 1.0):
            raise ValueError(f'slice_s must be in (0, 1] s, got {slice_s!r}')
        apply_ros_env_defaults()
        self.config_dir = find_config_dir()
        self.slice_s = float(slice_s)
        self.grace_s = float(grace_s)
        self.nodes: list = []
        self.context = Context()
        rclpy.init(
            context=self.context,
            domain_id=pick_domain_id() if domain_id is None else domain_id,
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
        try:
            values = {'time_mode': 'lockstep', 'arrival': 'none', **(params or {})}
            self.sim = SimNode(
                context=self.context,
                parameter_overrides=[Parameter(k, value=v) for k, v in values.items()],
            )
            self.executor = SingleThreadedExecutor(context=self.context)
            self.add_node(self.sim)
            self._obs = _Observer(rclpy.create_node('sorter_cell_observer', context=self.context))
            self.add_node(self._obs.node)
            self._subscribe()
        except BaseException:
            self.close()
            raise
        self.t0 = self.t

    # ------------------------------------------------------------------ set-up
    def _subscribe(self) -> None:
        from diagnostic_msgs.msg import DiagnosticStatus

        from sorter_ros.interface import EVENT_QOS

        def on_outcome(msg):
            v = _values(msg)
            self._obs.outcomes.append(
                OutcomeRecord(
                    v.get('label', ''),
                    int(v.get('id', '0')),
                    v.get('exit', msg.message),
                    float(v.get('t', 'nan')),
                    v.get('cause', ''),
                )
            )

        def on_confirmation(msg):
            self._obs.confirmations.append(_values(msg))

        node = self._obs.node
        node.create_subscription(DiagnosticStatus, 'sort/outcomes', on_outcome, EVENT_QOS)
        node.create_subscription(
            DiagnosticStatus, 'sort/confirmations', on_confirmation, EVENT_QOS
        )

    def add_node(self, node):
        """
        Spin ``node`` with the cell; it must be created in ``context``.

        Parameters
        ----------
        node : rclpy.node.Node
            The node.

        Returns
        -------
        rclpy.node.Node
            The same node.

        """
        if node.context is not self.context:
            raise ValueError(
                f'node {node.get_name()!r} belongs to another rclpy Context: create it '
                'with context=sorter_cell.context'
            )
        if node not in self.nodes:
            self.nodes.append(node)
            self.executor.add_node(node)
        return node

    def add_controller(self, params: dict | None = None, timeout_s: float = 60.0):
        """
        Start the project's controller node in this cell and wait until it sorts.

        Parameters
        ----------
        params : dict, optional
            Its parameters over config/controller.yaml (``use_sim_time`` is set).
        timeout_s : float
            The longest wall time to wait for it to run.

        Returns
        -------
        sorter_control.node.ControllerNode
            The controller.

        """
        from rclpy.parameter import Parameter

        from sorter_control.node import ControllerNode

        values = {'use_sim_time': True, **(params or {})}
        ctl = ControllerNode(
            context=self.context,
            parameter_overrides=[Parameter(k, value=v) for k, v in values.items()],
        )
        self.add_node(ctl)
        deadline = time.monotonic() + timeout_s
        # the controller asks the cell for its geometry, then warms its timing model;
        # the cell's clock runs meanwhile (the belt is empty: nothing happens)
        while not (ctl.logic is not None and ctl.logic.state == 'running'):
            if time.monotonic() > deadline:
                raise RuntimeError(f'the controller did not start within {timeout_s:g} s')
            self.run(self.slice_s)
        self.t0 = self.t
        return ctl

    # ------------------------------------------------------------------ time
    @property
    def dt(self) -> float:
        """Return the cell's control period [s]."""
        return self.sim.cell.dt

    @property
    def t(self) -> float:
        """Return the simulated time [s]."""
        return self.sim.cell.t

    def spin_idle(self) -> None:
        """Serve every ready callback until none has come for ``grace_s`` of wall time."""
        from rclpy.executors import ShutdownException, TimeoutException

        while True:
            try:
                handler, _, _ = self.executor.wait_for_ready_callbacks(timeout_sec=self.grace_s)
            except (TimeoutException, ShutdownException):
                return
            handler()

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
        self.spin_idle()
        while total > 0:
            n = min(step, total)
            self.sim.advance(n)
            total -= n
            self.spin_idle()

    def run_until(self, predicate, timeout_s: float = 60.0) -> bool:
        """
        Advance slice by slice until ``predicate()`` holds or ``timeout_s`` simulated seconds.

        Parameters
        ----------
        predicate : callable
            What to wait for.
        timeout_s : float
            The most simulated time to run [s].

        Returns
        -------
        bool
            Whether it came true.

        """
        t_end = self.t + timeout_s
        while not predicate():
            if self.t >= t_end - 1e-12:
                return False
            self.run(min(self.slice_s, t_end - self.t))
        return True

    # ------------------------------------------------------------------ the cell
    def induct(
        self,
        label: str = '',
        *,
        length: float = 0.4,
        width: float = 0.3,
        mass: float = 5.0,
        skew_deg: float = 0.0,
        y: float = 0.0,
    ) -> None:
        """
        Queue a parcel at the induction; it goes on the belt when the gap allows.

        Parameters
        ----------
        label : str
            Its label ('' for one from the cell's pattern).
        length : float
            Its length along the belt A [m].
        width : float
            Its width B [m].
        mass : float
            Its mass [kg].
        skew_deg : float
            Its skew on the belt [deg].
        y : float
            Its centre's offset across the belt [m].

        Raises
        ------
        ValueError
            A value out of range (``ParamError``), named; nothing is queued.

        """
        from sorter_sim.runtime.cell import ParcelSpec

        self.sim.cell.induct(ParcelSpec(length, width, mass, math.radians(skew_deg), y, label))

    def inject(self, fault: str, **arguments) -> str:
        """
        Inject a fault (``sorter_sim.runtime.faults``: eye, chute_full, jam, heartbeat, estop).

        Parameters
        ----------
        fault : str
            The fault.
        **arguments
            Its arguments, e.g. ``inject('eye', sensor='pe_entry', mode='blocked')``.

        Returns
        -------
        str
            What the cell did.

        """
        done = self.sim.inject_fault(fault, arguments)
        self.spin_idle()
        return done

    def reset(self) -> None:
        """Clear the e-stop and jams, as the cell's ``reset`` service does."""
        from std_srvs.srv import Trigger

        self.sim._srv_reset(Trigger.Request(), Trigger.Response())
        self.spin_idle()

    def sensor(self, name: str) -> bool:
        """
        Return what sensor ``name`` shows now (blocked True).

        Parameters
        ----------
        name : str
            The sensor.

        Returns
        -------
        bool
            Whether it is blocked.

        """
        states = self.sim.cell.sensor_states()
        if name not in states:
            raise KeyError(f'unknown sensor {name!r}; the cell has {", ".join(states)}')
        return states[name]

    # ------------------------------------------------------------------ parameters
    @property
    def params(self) -> dict:
        """Return the cell's parameters by name, as the node holds them."""
        names = self.sim.list_parameters([], 0).names
        return {p.name: p.value for p in self.sim.get_parameters(names)}

    def set_params(self, **values) -> None:
        """
        Set cell parameters through the node's parameter interface (its checks apply).

        Parameters
        ----------
        **values
            Name -> value.

        Raises
        ------
        ValueError
            The node refused one; its reason is the message. Nothing is set then.

        """
        from rclpy.parameter import Parameter

        result = self.sim.set_parameters_atomically(
            [Parameter(k, value=v) for k, v in values.items()]
        )
        if not result.successful:
            raise ValueError(result.reason)
        self.spin_idle()

    # ------------------------------------------------------------------ what happened
    @property
    def outcomes(self) -> list[OutcomeRecord]:
        """Return the cell's outcomes so far, in order."""
        return list(self._obs.outcomes)

    @property
    def confirmations(self) -> list[dict]:
        """Return a controller's sort confirmations so far (label, result, destination...)."""
        return list(self._obs.confirmations)

    def outcome(self, label: str) -> OutcomeRecord | None:
        """
        Return the outcome of the parcel labelled ``label``, or None while it has none.

        Parameters
        ----------
        label : str
            The label.

        Returns
        -------
        OutcomeRecord or None
            Its outcome.

        """
        return next((o for o in self._obs.outcomes if o.label == label), None)

    # ------------------------------------------------------------------ teardown
    def close(self) -> None:
        """Destroy the nodes and shut the Context down."""
        import rclpy

        for node in getattr(self, 'nodes', []):
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - a node's own teardown error ends nothing
                pass
        self.nodes = []
        if getattr(self, 'context', None) is not None:
            rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> SorterCell:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ['OutcomeRecord', 'SorterCell', 'pick_domain_id']
