"""
The simulation node's health: its ``/diagnostics`` report, and the faults a test bench injects.

``CellDiagnostics`` publishes, once a second, one ``DiagnosticStatus`` of the cell:
its level (ERROR on a jam, WARN on any other fault), the real-time factor and the
wall time a period and a message cost (``RunCost``), the counters of parcels,
inducts, watchdog trips, PackML commands and fieldbus traffic, and the faults
injected. It warns when another node publishes ``/clock`` too. Faults arrive on
``faults/inject`` (or ``inject_fault``) and are applied by ``runtime.faults``.
"""

from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from sorter_ros.graph_counts import publisher_count
from sorter_ros.interface import EVENT_QOS, STREAM_QOS
from sorter_sim.frontends.node_publishers import time_msg
from sorter_sim.runtime.faults import apply_fault
from sorter_sim.runtime.params import ParamError


class RunCost:
    """
    Wall time the node spent stepping the cell and publishing, since the last report.

    Attributes
    ----------
    step_s : float
        Wall time in the cell's ``advance`` [s].
    periods : int
        Control periods run.
    publish_s : float
        Wall time publishing what they reported [s].
    messages : int
        Messages published.

    """

    __slots__ = ('step_s', 'periods', 'publish_s', 'messages')

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        """Start counting again from zero."""
        self.step_s = 0.0
        self.periods = 0
        self.publish_s = 0.0
        self.messages = 0


class CellDiagnostics:
    """
    The cell's diagnostics report and its fault injection, created on ``node``.

    Parameters
    ----------
    node : SimNode
        The node reported on: its cell, its ``params`` (read at each use), its names.
    publishers : CellPublishers
        Where the report and what an injected fault shows are published.
    fieldbus_bridge : FieldbusBridge
        Whose counters join the report.
    cost : RunCost
        What stepping and publishing cost since the last report; reset by each report.

    """

    def __init__(self, node, publishers, fieldbus_bridge, cost: RunCost):
        self._node = node
        self._cell = node.cell
        self._publishers = publishers
        self._fieldbus_bridge = fieldbus_bridge
        self.cost = cost
        self.faults_injected = 0
        self._clock_publishers_warned = 0
        # (wall time, period index) of the last report: the real-time factor is over since
        self._ref = (time.perf_counter(), self._cell.k)
        # absolute, where diagnostic aggregators and tools look; the status names the node
        self._pub = publishers.create(DiagnosticArray, '/diagnostics', STREAM_QOS)
        node.create_subscription(DiagnosticStatus, 'faults/inject', self._on_fault, EVENT_QOS)

    def publish(self) -> None:
        """Publish the cell's diagnostics (the node's 1 s timer)."""
        node, cell = self._node, self._cell
        clock_publishers = self._check_clock_publishers()
        now = time.perf_counter()
        wall0, k0 = self._ref
        self._ref = (now, cell.k)
        c = self.cost
        rtf = (cell.k - k0) * cell.dt / max(now - wall0, 1e-9)
        step_us = 1e6 * c.step_s / c.periods if c.periods else 0.0
        pub_us = 1e6 * c.publish_s / c.messages if c.messages else 0.0
        c.reset()
        faults = cell.faults
        level = (
            DiagnosticStatus.ERROR
            if 'jam' in faults
            else DiagnosticStatus.WARN
            if faults
            else DiagnosticStatus.OK
        )
        counts = cell.outcome_counts
        values = {
            'real_time_factor': f'{rtf:.3f}',
            'step_cost_us': f'{step_us:.2f}',
            'publish_cost_us': f'{pub_us:.2f}',
            'parcels_in_cell': str(cell.n_parcels),
            'faults': ','.join(faults) or 'none',
            'estop': str(cell.estop).lower(),
            'jam': str(cell.jam).lower(),
            'sim_time': f'{cell.t:.6f}',
            'time_mode': node.params.time_mode,
            'inducted': str(cell.n_inducted),
            'pending_inducts': str(cell.pending_inducts),
            'inducts_refused': str(cell.n_induct_refused),
            'clock_publishers': str(clock_publishers),
            'watchdog_trips': str(cell.watchdog_trips),
            'faults_injected': str(self.faults_injected),
            'injected_now': ','.join(self._injected_now()) or 'none',
            # set by the spin loop that survives them (sorter_ros.env.spin_surviving)
            'callback_errors': str(getattr(node, 'callback_errors', 0)),
            'packml_state': cell.packml.state,
            'packml_cause': cell.packml.cause,
            'packml_commands': str(cell.packml.counts['commands']),
            'packml_refused': str(cell.packml.counts['refused']),
            **self._fieldbus_bridge.diagnostics(),
            **{f'exits_{k}': str(v) for k, v in counts.items()},
        }
        status = DiagnosticStatus(
            level=level,
            name=f'{node.get_fully_qualified_name()}: cell',
            message=('faults: ' + ', '.join(faults)) if faults else 'running',
            hardware_id=node.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = time_msg(cell.t_ns)
        self._publishers.publish(self._pub, msg)

    def _check_clock_publishers(self) -> int:
        """Warn (once per change) when another node publishes /clock too: time is then two."""
        node = self._node
        # the stations of a line and their programs share a Context: one look at the
        # graph a simulated second serves them all (each costs a walk of every endpoint)
        n = publisher_count(node, '/clock', self._cell.t_ns)
        if n > 1 and n != self._clock_publishers_warned:
            others = [
                f'{i.node_namespace.rstrip("/")}/{i.node_name}'
                for i in node.get_publishers_info_by_topic('/clock')
                if (i.node_name, i.node_namespace) != (node.get_name(), node.get_namespace())
            ]
            node.get_logger().warning(
                f'{n} publishers on /clock ({", ".join(others) or "another node"} besides this '
                'cell): controllers on simulated time see it jump; give each cell its own '
                'clock (remap /clock) or run one cell per ROS_DOMAIN_ID'
            )
        self._clock_publishers_warned = n if n > 1 else 0
        return n

    # ------------------------------------------------------------------ faults
    def _on_fault(self, msg: DiagnosticStatus) -> None:
        """Inject a test-bench fault (``runtime.faults``); a bad request is logged and dropped."""
        try:
            self.inject_fault(msg.name, {kv.key: kv.value for kv in msg.values})
        except ParamError as exc:
            self._node.get_logger().warning(f'faults/inject dropped: {exc}')

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
        events, done = apply_fault(self._cell, name, values)
        self.faults_injected += 1
        self._publishers.publish_events(events)
        self._publishers.publish_status()
        self._node.get_logger().warning(f'injected fault: {done}')
        return done

    def _injected_now(self) -> list[str]:
        out = [f'eye {n} {f.fault}' for n, f in self._cell.sensor_faults.items()]
        if self._cell.heartbeat_cut:
            out.append('heartbeat lost')
        return out
