"""
The node ``sorter_wcs``: the line's warehouse side on ROS 2 (logic in ``wcs.LineWcs``).

Topics (relative to its namespace, the line's):

========================== ==================================== ===================================
topic                      type                                 meaning
========================== ==================================== ===================================
``wcs/sort_plan`` (sub)    diagnostic_msgs/DiagnosticStatus     a new plan: ``name`` its version,
                                                                ``values`` destination -> chute
``wcs/sort_plan/active``   diagnostic_msgs/DiagnosticStatus     the plan in force (latched)
``wcs/sort_plan/refused``  std_msgs/String                      why a plan was refused
``wcs/requests`` (sub)     diagnostic_msgs/KeyValue             label -> destination ('' drops
                                                                it); reliable, keep all
``wcs/requests/answers``   diagnostic_msgs/KeyValue             one per request: label -> '' taken,
                                                                or why it was refused
``wcs/dispositions``       diagnostic_msgs/DiagnosticStatus     one per parcel: ``name`` its label,
                                                                ``message`` the code, ``values``
                                                                label, code, destination, chute,
                                                                station, t
========================== ==================================== ===================================

Per station k it listens to ``Sk/sort/confirmations`` and (k > 1) ``Sk/sensors/edges``,
and writes ``Sk/routing/updates`` and (k > 1) ``Sk/scanner/label`` and, after each
scanner edge it hears, ``Sk/scanner/answered`` (the edge's time, ``source`` ``label`` or
``none``: a line that waits for its warehouse runs on once it has it); it reads
``line/exits`` (an exit that is not the line's: a time not finite, a station or a
chute the line does not have, a label outside the grammar, is refused in one line and
counted, ``n_refused_exits``) and ``line/chutes/<name>/full``. At most ``MAX_PENDING``
requests wait for their parcels (more are refused, each answered); a parcel's request
and rule go when it leaves the line, so a request costs the same however many came
before. Parameters: ``stations`` and
``chute_names`` as the line's, ``scan_eye`` (the stations' scanner eye),
``opcua_port`` (0: no OPC UA) and ``opcua_host`` (default 127.0.0.1): the same plan,
requests and dispositions in an OPC UA ``Warehouse`` folder (``wcs_opcua``).

Its callbacks and the OPC UA calls (another thread) meet ``LineWcs`` under one lock.
Run it alone with ``wcs_node --ros-args -p stations:=6`` (``ros2 run sorter_cell
wcs_node``); a bad parameter is one line and exit code 2.
"""

from __future__ import annotations

import threading

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import TimeReference
from std_msgs.msg import Bool, String

from sorter_control.wcs import LineWcs, PlanError, parse_exit
from sorter_ros.line_seal import LineSeal
from sorter_ros.outcomes import disposition_msg, values
from sorter_sim.model.description import chute_pairs, shown, station_name
from sorter_ros.env import run_node
from sorter_ros.recording import open_recorder, publish_recorded, release_recorder
from sorter_ros.interface import (
    answer_every_parameter_request,
    EVENT_QOS,
    SENSOR_QOS,
    declare_options,
    fix_at_start,
)

NODE_NAME = 'sorter_wcs'
LATCHED = SENSOR_QOS
# requests: none dropped in a burst (a writer and a reader that keep all); each answered
REQUEST_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
MAX_ANSWERED_LABEL = 256  # an answer names the label, cut to this (the refusal says why)
MAX_REFUSAL = 400  # characters of a refusal as answered, published, logged and in LastRefusal
REFUSAL_LOG_S = 1.0  # wall s between two refusals logged; those between are counted


class RefusalLog:
    """
    Log refusals at most once per ``every_s``: a flood of bad requests is one line a second.

    The line logged says how many refusals came since the last one logged and were not.

    Parameters
    ----------
    log : callable
        Takes one line (the node's logger's ``warning``).
    every_s : float
        Wall seconds between two lines.
    clock : callable
        Wall time [s] (``time.monotonic``).

    """

    def __init__(self, log, every_s: float = REFUSAL_LOG_S, clock=None):
        import time

        self.log, self.every_s, self.clock = log, every_s, clock or time.monotonic
        self.last = -float('inf')
        self.unlogged = 0

    def __call__(self, text: str) -> None:
        now = self.clock()
        if now - self.last < self.every_s:
            self.unlogged += 1
            return
        more = f' ({self.unlogged} more refused since the last line)' if self.unlogged else ''
        self.log(text + more)
        self.last, self.unlogged = now, 0


def _cut(text: str) -> str:
    return text if len(text) <= MAX_REFUSAL else text[: MAX_REFUSAL - 3] + '...'


# the warehouse node's options: {name: (default, check, what it allows)}
WCS_PARAMS = {
    'stations': (1, lambda v: isinstance(v, int) and 1 <= v <= 64, 'an integer in [1, 64]'),
    'chute_names': (
        [''],
        lambda v: isinstance(v, list) and all(isinstance(x, str) for x in v),
        'a list of names',
    ),
    'scan_eye': ('pe_scan', lambda v: isinstance(v, str), "an eye's name"),
    'opcua_port': (
        0,
        lambda v: isinstance(v, int) and 0 <= v <= 65535,
        'an integer in [0, 65535]',
    ),
    'opcua_host': (
        '127.0.0.1',
        lambda v: isinstance(v, str) and bool(v.strip()),
        'a host name or address',
    ),
    'record_path': ('', lambda v: isinstance(v, str), 'a file path'),
}


class WcsNode(Node):
    """The line's warehouse side (see the module)."""

    def __init__(self, *, line_key: bytes | None = None, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        # the exits the line's segments seal with the line key (None: SORTER_LINE_KEY's
        # file, or an open line); a key that cannot be used is a ValueError naming it
        self.seal = LineSeal(line_key)
        answer_every_parameter_request(self)  # a request rclpy cannot read too
        # a value of another type (``stations:=x``) or out of range is refused naming what
        # is allowed; read once, at start-up
        values = declare_options(self, WCS_PARAMS)
        fix_at_start(
            self,
            {name: allowed for name, (_, _, allowed) in WCS_PARAMS.items()}
            | {'use_sim_time': 'whether the warehouse follows /clock'},
        )
        n, names, record = values['stations'], values['chute_names'], values['record_path']
        port, host = values['opcua_port'], values['opcua_host']
        self.scan_eye = values['scan_eye']
        chutes = chute_pairs(n, names)
        self.wcs = LineWcs(chutes)
        self.recorder = None
        if record:
            # in one process with the line, the same file: open_recorder shares a path
            try:
                self.recorder = open_recorder(record, self.get_logger().error)
            except ValueError as exc:
                raise ValueError(f"parameter 'record_path': {exc}") from None
        self.n_refused = 0
        self.n_refused_exits = 0
        self.log_refusal = RefusalLog(self.get_logger().warning)
        self._lock = threading.Lock()  # the executor's callbacks and the OPC UA calls
        self.opcua = None
        self._pub_routing = [
            self.create_publisher(KeyValue, f'{station_name(k)}/routing/updates', EVENT_QOS)
            for k in range(n)
        ]
        self._pub_label = {
            k: self.create_publisher(String, f'{station_name(k)}/scanner/label', EVENT_QOS)
            for k in range(1, n)
        }
        # each scanner edge answered, label or none: a line that waits for its warehouse
        # runs on once its label is out (sorter_sim.frontends.scan_answers)
        self._pub_answered = {
            k: self.create_publisher(
                TimeReference, f'{station_name(k)}/scanner/answered', EVENT_QOS
            )
            for k in range(1, n)
        }
        self._pub_disp = self.create_publisher(DiagnosticStatus, 'wcs/dispositions', EVENT_QOS)
        self._pub_active = self.create_publisher(DiagnosticStatus, 'wcs/sort_plan/active', LATCHED)
        self._pub_refused = self.create_publisher(String, 'wcs/sort_plan/refused', EVENT_QOS)
        self._sub_stations = []  # what the stations write to it: unmatched() looks at each
        for k in range(n):
            self._sub_stations.append(
                self.create_subscription(
                    DiagnosticStatus,
                    f'{station_name(k)}/sort/confirmations',
                    lambda m, k=k: self._on_confirmation(k, m),
                    EVENT_QOS,
                )
            )
            if k > 0:
                self._sub_stations.append(
                    self.create_subscription(
                        TimeReference,
                        f'{station_name(k)}/sensors/edges',
                        lambda m, k=k: self._on_edge(k, m),
                        EVENT_QOS,
                    )
                )
        self.create_subscription(DiagnosticStatus, 'wcs/sort_plan', self._on_plan, EVENT_QOS)
        self.create_subscription(KeyValue, 'wcs/requests', self._on_request, REQUEST_QOS)
        self._pub_answers = self.create_publisher(KeyValue, 'wcs/requests/answers', REQUEST_QOS)
        self._sub_exits = self.create_subscription(
            DiagnosticStatus, 'line/exits', self._on_exit, EVENT_QOS
        )
        for name in self.wcs.where:
            self.create_subscription(
                Bool, f'line/chutes/{name}/full', lambda m, c=name: self._on_full(c, m), LATCHED
            )
        # a station's controller that subscribes (late, or again after a restart) gets its
        # whole table: routing updates are changes, and a controller that missed some
        # would sort by its own defaults
        self._readers = [0] * n
        self.create_timer(0.1, self._resync, clock=Clock(clock_type=ClockType.STEADY_TIME))
        if port:
            from sorter_control.wcs_opcua import WcsOpcUa

            self.opcua = WcsOpcUa(host, port, set_plan=self.take_plan, request=self.take_request)
            try:
                self.opcua.start()
            except ValueError as exc:
                self.opcua = None
                raise ValueError(f"parameter 'opcua_port': {exc}") from None
            self.get_logger().info(f'warehouse over OPC UA on {self.opcua.endpoint}')
        # what a line's integrator checks first: how many stations and chutes it serves
        shown = ', '.join(list(self.wcs.where)[:3]) + (', ...' if len(self.wcs.where) > 3 else '')
        self.get_logger().info(
            f'sorter wcs ready: {n} station(s), {len(self.wcs.where)} chutes ({shown}); '
            'sort plan on wcs/sort_plan, requests on wcs/requests'
        )

    def destroy_node(self):
        """Stop the OPC UA server, finish the recording, then the node."""
        if self.opcua is not None:
            self.opcua.stop()
            self.opcua = None
        if self.recorder is not None:
            release_recorder(self.recorder)
            self.recorder = None
        return super().destroy_node()

    def unmatched(self, line_writers: int = 1) -> list[str]:
        """
        Return the line's topics on which this node has no peer yet.

        A station's cell and controller in another process (a segment of the line) are
        matched by DDS discovery, which on a loaded machine can take seconds: an edge
        sent before it is lost, and its parcel reaches the station with no label and
        goes straight on. A line opens its infeed once this is empty.

        Parameters
        ----------
        line_writers : int
            The processes that write ``line/exits`` (the line's segments).

        """
        out = [p.topic_name for p in self._pub_routing if p.get_subscription_count() == 0]
        out += [p.topic_name for p in self._pub_label.values() if p.get_subscription_count() == 0]
        out += [s.topic_name for s in self._sub_stations if s.get_publisher_count() == 0]
        if self._sub_exits.get_publisher_count() < line_writers:
            out.append(self._sub_exits.topic_name)
        return out

    def _publish(self, publisher, msg) -> None:
        """Publish ``msg``, and record it (stamped with the node's clock) when recording."""
        t_ns = self.get_clock().now().nanoseconds if self.recorder is not None else 0
        publish_recorded(publisher, msg, self.recorder, t_ns)

    def _resync(self) -> None:
        """Send a station's whole routing table to a controller that just subscribed."""
        for k, pub in enumerate(self._pub_routing):
            readers = pub.get_subscription_count()
            if readers > self._readers[k]:
                with self._lock:
                    # a station's own parcels only: everything else passes on
                    pub.publish(KeyValue(key='*', value='straight'))
                    for label, side in self.wcs.rules[k].items():
                        pub.publish(KeyValue(key=label, value=side))
            self._readers[k] = readers

    # ------------------------------------------------------------------ inputs
    def _send(self, updates) -> None:
        for k, label, side in updates:
            self._pub_routing[k].publish(KeyValue(key=label, value=side))

    def take_plan(self, version: str, entries: list) -> str:
        """
        Take a sort plan from any side (ROS or OPC UA); return '' or why it was refused.

        Parameters
        ----------
        version : str
            The plan's version.
        entries : list of (str, str)
            (destination, chute).

        """
        with self._lock:
            try:
                self._send(self.wcs.set_plan(version, list(entries)))
            except PlanError as exc:
                self.n_refused += 1
                text = _cut(f'sort plan {shown(version, 40)} refused: {exc}')
                self.log_refusal(text)
                self._publish(self._pub_refused, String(data=text))
                if self.opcua is not None:
                    self.opcua.refused_change(text)
                return text
            self._publish(
                self._pub_active,
                DiagnosticStatus(
                    name=self.wcs.version,
                    message='active',
                    values=[KeyValue(key=d, value=c) for d, c in sorted(self.wcs.plan.items())],
                ),
            )
            if self.opcua is not None:
                self.opcua.plan_changed(self.wcs.version, self.wcs.plan)
            return ''

    def take_request(self, label: str, destination: str) -> str:
        """Take a request (label -> destination, '' withdraws); return '' or why not."""
        with self._lock:
            try:
                self._send(self.wcs.request(label, destination))
            except PlanError as exc:
                self.n_refused += 1
                text = _cut(f'request refused: {exc}')
                self.log_refusal(text)
                if self.opcua is not None:
                    self.opcua.refused_change(text)
                return text
            if self.opcua is not None:
                self.opcua.requests_changed(len(self.wcs.requests))
            return ''

    def _on_plan(self, msg: DiagnosticStatus) -> None:
        self.take_plan(msg.name, [(kv.key, kv.value) for kv in msg.values])

    def _on_request(self, msg: KeyValue) -> None:
        # every request answered: '' taken, or why it was refused
        why = self.take_request(msg.key, msg.value)
        self._pub_answers.publish(KeyValue(key=msg.key[:MAX_ANSWERED_LABEL], value=why))

    def _on_full(self, chute: str, msg: Bool) -> None:
        with self._lock:
            self._send(self.wcs.chute_full(chute, bool(msg.data)))
            if self.opcua is not None:
                self.opcua.full_changed(self.wcs.full)

    def _on_confirmation(self, k: int, msg: DiagnosticStatus) -> None:
        v = values(msg)
        with self._lock:
            self.wcs.confirmed(
                k,
                v.get('label', ''),
                v.get('destination_reached', ''),
                v.get('result', msg.message),
            )

    def _on_edge(self, k: int, msg: TimeReference) -> None:
        if msg.source != 'rising' or msg.header.frame_id.rsplit('/', 1)[-1] != self.scan_eye:
            return
        t_ns = msg.time_ref.sec * 1_000_000_000 + msg.time_ref.nanosec
        with self._lock:
            label = self.wcs.arriving(k, t_ns)
        if label is not None:
            self._pub_label[k].publish(String(data=label))
        self._pub_answered[k].publish(
            TimeReference(
                header=msg.header,
                time_ref=msg.time_ref,
                source='none' if label is None else 'label',
            )
        )

    def _on_exit(self, msg: DiagnosticStatus) -> None:
        try:
            msg = self.seal.opened(self._sub_exits.topic_name, msg)
            label, exit, station, t, cause = parse_exit(
                [(kv.key, kv.value) for kv in msg.values], self.wcs.chutes
            )
        except ValueError as exc:  # PlanError, or a seal's HandoverError
            self.n_refused_exits += 1
            self.get_logger().warning(f'line/exits: {exc}; refused', throttle_duration_sec=1.0)
            return
        with self._lock:
            if label and label in self.wcs.dispositions:
                # a restarted segment that sorted it again (the segment upstream had not
                # yet heard it left): it has its disposition
                self.wcs.n_replayed += 1
                return
            d = self.wcs.exited(label, exit, station, t, cause)
            self._send(self.wcs.forget(label))  # its request and rule are no longer needed
        if self.opcua is not None:
            self.opcua.disposition(
                ';'.join((d.label, d.code, d.destination, d.chute, d.station, f'{d.t:.6f}'))
            )
        self._publish(self._pub_disp, disposition_msg(d))


def main(args=None, stop=None):
    """
    Run the warehouse node: ``wcs_node --ros-args -p stations:=6``.

    Parameters
    ----------
    args : list of str, optional
        The command line.
    stop : StopSignals, optional
        The executable's signal handlers, when it installed them first.

    """
    run_node(WcsNode, 'wcs_node', (ValueError,), args, stop)


if __name__ == '__main__':
    main()
