"""
A third-party station program for a line: the warehouse's routing, left and right, confirmed.

Not part of sorter_cell: an example of a station program someone else wrote, tested on
a line with the ``sorter_line`` fixture (test_station_program.py) and through a
scenario file (line_scenario.yaml). It keeps the station-program contract of
docs/testing.md, in its station's namespace (``/S01``, ...):

- reads ``routing/updates`` (label -> left | right | straight | '' to remove, ``*``
  the default) and ``scanner/label``;
- reads ``sensors/edges``: at the divert eye it raises the disks for a parcel bound
  left or right, at the chute's eye it lowers them, at the exit eye the parcel has
  passed on;
- sets the disks' angle (``sorter_sim``'s ``alpha_deg``) when it reads a label;
- publishes ``sort/confirmations`` for every parcel (``destination_reached`` left,
  right or straight: the warehouse passes a straight one's label to the next station);
- publishes ``controller/heartbeat`` (a counter) every 50 ms of the line's time;
- reads ``status/packml`` and diverts only in ``Execute`` (else ``not_executing``).

First in, first out: one parcel between the scanner and the disks at a time is
enough for this program (it sets the angle when the label is read).
"""

from collections import deque

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import TimeReference
from std_msgs.msg import String, UInt32
from std_srvs.srv import SetBool

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
ANGLE_DEG = {'left': 90.0, 'right': -90.0}


class StationProgram(Node):
    """One station's sorting, by the warehouse's rules (see the module)."""

    def __init__(self, **kwargs):
        super().__init__('station_program', **kwargs)
        self.rules = {}
        self.default = 'straight'
        self.packml = 'Execute'
        self.read = deque()  # (label, side) read, not yet at the disks
        self.on_disks = deque()  # (label, side) past the divert eye
        self.passing = deque()  # labels going straight, not yet at the exit eye
        self.beats = 0
        self.popup = self.create_client(SetBool, 'diverter/popup')
        self.cell = AsyncParameterClient(self, 'sorter_sim')
        self.pub_beat = self.create_publisher(UInt32, 'controller/heartbeat', 10)
        self.pub_confirm = self.create_publisher(DiagnosticStatus, 'sort/confirmations', RELIABLE)
        self.create_subscription(KeyValue, 'routing/updates', self.on_rule, RELIABLE)
        self.create_subscription(String, 'scanner/label', self.on_label, RELIABLE)
        self.create_subscription(TimeReference, 'sensors/edges', self.on_edge, RELIABLE)
        self.create_subscription(String, 'status/packml', self.on_packml, LATCHED)
        self.heartbeat_timer = self.create_timer(0.05, self.on_beat)

    def on_rule(self, msg):
        if msg.key == '*':
            self.default = msg.value or 'straight'
        elif msg.value:
            self.rules[msg.key] = msg.value
        else:
            self.rules.pop(msg.key, None)

    def on_packml(self, msg):
        self.packml = msg.data

    def on_label(self, msg):
        side = self.rules.get(msg.data, self.default)
        self.read.append((msg.data, side))
        if side in ANGLE_DEG:
            self.cell.set_parameters([Parameter('alpha_deg', value=ANGLE_DEG[side])])

    def on_edge(self, msg):
        sensor = msg.header.frame_id.rsplit('/', 1)[-1]
        if msg.source != 'rising':
            return
        if sensor == 'pe_divert' and self.read:
            label, side = self.read.popleft()
            if side in ANGLE_DEG and self.packml == 'Execute':
                self.popup.call_async(SetBool.Request(data=True))
                self.on_disks.append((label, side))
            else:
                self.passing.append((label, side))
        elif sensor in ('chute_left', 'chute_right') and self.on_disks:
            label, side = self.on_disks.popleft()
            self.popup.call_async(SetBool.Request(data=False))
            reached = sensor.split('_')[1]
            self.confirm(label, side, reached, 'sorted' if reached == side else 'mis-sorted')
        elif sensor == 'pe_exit' and self.passing:
            label, side = self.passing.popleft()
            result = 'sorted' if side == 'straight' else 'not_executing'
            self.confirm(label, side, 'straight', result)

    def confirm(self, label, asked, reached, result):
        values = {
            'label': label,
            'destination_asked': asked,
            'destination_reached': reached,
            'result': result,
        }
        self.pub_confirm.publish(
            DiagnosticStatus(
                name=label,
                message=result,
                values=[KeyValue(key=k, value=v) for k, v in values.items()],
            )
        )

    def on_beat(self):
        self.beats += 1
        self.pub_beat.publish(UInt32(data=self.beats))
