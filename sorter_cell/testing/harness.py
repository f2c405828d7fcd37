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
controller's ``sort/confirmations``, when one runs). A wait that times out
(``run_until``, ``require``) reports where the cell is (``LockStep.explain``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sorter_cell.testing.lockstep import (
    SLICE_S,
    LockStep,
    WaitTimedOut,
    exits_text,
    parcel_spec,
    pick_domain_id,
)
from sorter_ros.outcomes import ConfirmationRecord, OutcomeRecord, read_confirmation, read_outcome


@dataclass
class _Observer:
    node: object
    outcomes: list = field(default_factory=list)
    confirmations: list = field(default_factory=list)


class SorterCell(LockStep):
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
    grace_s : float, optional
        Wall seconds of quiet that end a slice's spin, for nodes in other processes
        (default: none with the events executor, which drains this process's nodes
        exactly; 0.5 ms with the single-threaded one).
    heartbeat_wait_s : float
        For a controller in another process: the most wall seconds a slice that would
        trip the watchdog waits first for the controller's next heartbeat (0: none).
        A process starved of the core lags in wall time, not in simulated time; a
        frozen one still trips, at the same simulated moment, a wait later.
    record : str, optional
        An MCAP file: everything the cell publishes (named in every report).
    events : bool
        Spin with rclpy's events executor (the default, where it exists), else the
        single-threaded one. The events executor serves requests in the order they
        came and lets the run loop drain this process's nodes exactly after each slice
        (``sorter_ros.run_loop``); the single-threaded one builds a wait set of every
        entity on each pass, serves requests that arrive together in its entities'
        order, and ends a slice after ``grace_s`` of quiet.

    """

    def __init__(
        self,
        params: dict | None = None,
        *,
        domain_id: int | None = None,
        slice_s: float = SLICE_S,
        grace_s: float | None = None,
        heartbeat_wait_s: float = 0.0,
        record: str | None = None,
        events: bool = True,
    ):
        import rclpy
        from rclpy.parameter import Parameter

        from sorter_sim.frontends.node import SimNode

        if not (isinstance(heartbeat_wait_s, (int, float)) and 0.0 <= heartbeat_wait_s <= 60.0):
            raise ValueError(f'heartbeat_wait_s must be in [0, 60] s, got {heartbeat_wait_s!r}')
        self.heartbeat_wait_s = float(heartbeat_wait_s)
        self._start_context(domain_id, slice_s, grace_s, events=events)
        try:
            values = {'time_mode': 'lockstep', 'arrival': 'none', **(params or {})}
            if record:
                values['record_path'] = str(record)
            self.record_path = values.get('record_path', '')
            self.sim = SimNode(
                context=self.context,
                parameter_overrides=[Parameter(k, value=v) for k, v in values.items()],
            )
            self._stepper, self._timebase = self.sim, self.sim.cell
            self.add_node(self.sim)
            self._obs = _Observer(rclpy.create_node('sorter_cell_observer', context=self.context))
            self.add_node(self._obs.node)
            self._subscribe()
        except BaseException:
            self.close()
            raise
        self.t0 = self.t

    def _slice(self, n: int) -> int:
        """Run one slice; first, if it would trip the watchdog, wait for a late heartbeat."""
        if self.heartbeat_wait_s > 0.0:
            cell, dog = self.sim.cell, self.sim.cell.watchdog
            deadline = cell.watchdog_deadline()
            if deadline is not None and deadline <= cell.k + n:
                # any heartbeat that came says the controller lives: fed, frozen or cut
                seen = (dog.fed_k, dog.frozen, dog.lost)
                self.spin_until(
                    lambda: (dog.fed_k, dog.frozen, dog.lost) != seen, self.heartbeat_wait_s
                )
        return super()._slice(n)

    # ------------------------------------------------------------------ set-up
    def _subscribe(self) -> None:
        from diagnostic_msgs.msg import DiagnosticStatus

        from sorter_ros.interface import EVENT_QOS

        def on_outcome(msg):
            self._obs.outcomes.append(read_outcome(msg))

        def on_confirmation(msg):
            self._obs.confirmations.append(read_confirmation(msg))

        node = self._obs.node
        node.create_subscription(DiagnosticStatus, 'sort/outcomes', on_outcome, EVENT_QOS)
        node.create_subscription(
            DiagnosticStatus, 'sort/confirmations', on_confirmation, EVENT_QOS
        )

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
        # it asks the cell for its geometry, then warms its timing model: with the
        # clock stopped, so that the test starts at the same time on any machine
        self.wait_started(
            lambda: ctl.logic is not None and ctl.logic.state == 'running',
            timeout_s,
            'the controller did not start',
        )
        self.t0 = self.t
        return ctl

    def state_lines(self) -> list[str]:
        """Return the report's parcels, faults and PackML state (``LockStep.explain``)."""
        c = self.sim.cell
        out = [(o.label, o.exit, o.t) for o in self._obs.outcomes]
        sensors = ', '.join(f'{k} {f.fault}' for k, f in c.sensor_faults.items())
        return [
            f'parcels: {c.n_inducted} inducted, {c.n_in_flight} on the cell, '
            f'{c.pending_inducts} waiting at the induction, {len(out)} out: ' + exits_text(out),
            f'faults: {", ".join(c.faults) or "none"}'
            + (f'; sensors faulted: {sensors}' if sensors else '')
            + f'; PackML: {c.packml.state}',
        ]

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
        self.sim.cell.induct(parcel_spec(label, length, width, mass, skew_deg, y))

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
        done = self.sim.diagnostics.inject_fault(fault, arguments)
        self.spin_idle()
        return done

    def reset(self) -> None:
        """Clear the e-stop and jams, as the cell's ``reset`` service does."""
        from std_srvs.srv import Trigger

        self.sim.commands.reset(Trigger.Request(), Trigger.Response())
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
    def confirmations(self) -> list[ConfirmationRecord]:
        """Return a controller's sort confirmations so far, in order (``ConfirmationRecord``)."""
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


__all__ = ['OutcomeRecord', 'SorterCell', 'WaitTimedOut', 'pick_domain_id']
