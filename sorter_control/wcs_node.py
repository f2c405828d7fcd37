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
``wcs/requests`` (sub)     diagnostic_msgs/KeyValue             label -> destination ('' withdraws)
``wcs/dispositions``       diagnostic_msgs/DiagnosticStatus     one per parcel: ``name`` its label,
                                                                ``message`` the code, ``values``
                                                                label, code, destination, chute,
                                                                station, t
========================== ==================================== ===================================

Per station k it listens to ``Sk/sort/confirmations`` and (k > 1) ``Sk/sensors/edges``,
and writes ``Sk/routing/updates`` and (k > 1) ``Sk/scanner/label``; it reads
``line/exits`` and ``line/chutes/<name>/full``. Parameters: ``stations`` and
``chute_names`` as the line's, ``scan_eye`` (the stations' scanner eye).
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.node import Node
from sensor_msgs.msg import TimeReference
from std_msgs.msg import Bool, String

from sorter_control.wcs import LineWcs, PlanError
from sorter_sim.model.description import chute_pairs, station_name
from sorter_ros.interface import EVENT_QOS, SENSOR_QOS

NODE_NAME = 'sorter_wcs'
LATCHED = SENSOR_QOS


class WcsNode(Node):
    """The line's warehouse side (see the module)."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        n = self.declare_parameter('stations', 1).value
        names = self.declare_parameter('chute_names', ['']).value
        self.scan_eye = self.declare_parameter('scan_eye', 'pe_scan').value
        if not (isinstance(n, int) and 1 <= n <= 64):
            raise ValueError(f"parameter 'stations' must be an integer in [1, 64], got {n!r}")
        chutes = chute_pairs(n, names)
        self.wcs = LineWcs(chutes)
        self.n_refused = 0
        self._pub_routing = [
            self.create_publisher(KeyValue, f'{station_name(k)}/routing/updates', EVENT_QOS)
            for k in range(n)
        ]
        self._pub_label = {
            k: self.create_publisher(String, f'{station_name(k)}/scanner/label', EVENT_QOS)
            for k in range(1, n)
        }
        self._pub_disp = self.create_publisher(DiagnosticStatus, 'wcs/dispositions', EVENT_QOS)
        self._pub_active = self.create_publisher(DiagnosticStatus, 'wcs/sort_plan/active', LATCHED)
        self._pub_refused = self.create_publisher(String, 'wcs/sort_plan/refused', EVENT_QOS)
        for k in range(n):
            self.create_subscription(
                DiagnosticStatus,
                f'{station_name(k)}/sort/confirmations',
                lambda m, k=k: self._on_confirmation(k, m),
                EVENT_QOS,
            )
            if k > 0:
                self.create_subscription(
                    TimeReference,
                    f'{station_name(k)}/sensors/edges',
                    lambda m, k=k: self._on_edge(k, m),
                    EVENT_QOS,
                )
        self.create_subscription(DiagnosticStatus, 'wcs/sort_plan', self._on_plan, EVENT_QOS)
        self.create_subscription(KeyValue, 'wcs/requests', self._on_request, EVENT_QOS)
        self.create_subscription(DiagnosticStatus, 'line/exits', self._on_exit, EVENT_QOS)
        for name in self.wcs.where:
            self.create_subscription(
                Bool, f'line/chutes/{name}/full', lambda m, c=name: self._on_full(c, m), LATCHED
            )
        for k in range(n):
            # a station's own parcels only: everything else passes on
            self._pub_routing[k].publish(KeyValue(key='*', value='straight'))

    # ------------------------------------------------------------------ inputs
    def _send(self, updates) -> None:
        for k, label, side in updates:
            self._pub_routing[k].publish(KeyValue(key=label, value=side))

    def _on_plan(self, msg: DiagnosticStatus) -> None:
        try:
            self._send(self.wcs.set_plan(msg.name, [(kv.key, kv.value) for kv in msg.values]))
        except PlanError as exc:
            self.n_refused += 1
            text = f'sort plan {msg.name!r} refused: {exc}'
            self.get_logger().warning(text)
            self._pub_refused.publish(String(data=text))
            return
        self._pub_active.publish(
            DiagnosticStatus(
                name=self.wcs.version,
                message='active',
                values=[KeyValue(key=d, value=c) for d, c in sorted(self.wcs.plan.items())],
            )
        )

    def _on_request(self, msg: KeyValue) -> None:
        try:
            self._send(self.wcs.request(msg.key, msg.value))
        except PlanError as exc:
            self.n_refused += 1
            self.get_logger().warning(f'request refused: {exc}')

    def _on_full(self, chute: str, msg: Bool) -> None:
        self._send(self.wcs.chute_full(chute, bool(msg.data)))

    def _on_confirmation(self, k: int, msg: DiagnosticStatus) -> None:
        v = {kv.key: kv.value for kv in msg.values}
        self.wcs.confirmed(
            k, v.get('label', ''), v.get('destination_reached', ''), v.get('result', msg.message)
        )

    def _on_edge(self, k: int, msg: TimeReference) -> None:
        if msg.source != 'rising' or msg.header.frame_id.rsplit('/', 1)[-1] != self.scan_eye:
            return
        label = self.wcs.arriving(k)
        if label is not None:
            self._pub_label[k].publish(String(data=label))

    def _on_exit(self, msg: DiagnosticStatus) -> None:
        v = {kv.key: kv.value for kv in msg.values}
        station = int(v.get('station', 'S01')[1:]) - 1
        d = self.wcs.exited(
            v.get('label', ''),
            v.get('exit', msg.message),
            station,
            float(v.get('t', 'nan')),
            v.get('cause', ''),
        )
        self._send(self.wcs.rebuild())  # its rule is no longer needed
        values = [
            ('label', d.label),
            ('code', d.code),
            ('destination', d.destination),
            ('chute', d.chute),
            ('station', d.station),
            ('t', f'{d.t:.6f}'),
        ]
        self._pub_disp.publish(
            DiagnosticStatus(
                level=DiagnosticStatus.OK if d.code == 'sorted' else DiagnosticStatus.WARN,
                name=d.label,
                message=d.code,
                values=[KeyValue(key=k, value=val) for k, val in values],
            )
        )
