"""
A minimal third-party sorter controller: labels starting with L go left, the rest straight.

Not part of sorter_cell: an example of a controller someone else wrote, tested
against the cell with the ``sorter_cell`` pytest fixture (test_minimal_controller.py).
It speaks only the cell's ROS interface: it reads the scanner's labels and the
photo-eyes' edges, raises the disks (``diverter/popup``) when an L parcel reaches
the divert eye and lowers them when the parcel is seen in the left chute, and it
feeds the cell's watchdog with a heartbeat.
"""

from collections import deque

from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import TimeReference
from std_msgs.msg import String, UInt32
from std_srvs.srv import SetBool


class MinimalController(Node):
    """First in, first out: the labels in the order read, matched to the divert eye's edges."""

    def __init__(self, **kwargs):
        # on the cell's clock (/clock), as a PLC scans in the cell's time
        kwargs.setdefault('parameter_overrides', [Parameter('use_sim_time', value=True)])
        super().__init__('minimal_controller', **kwargs)
        self.waiting = deque()  # labels read, not yet at the divert eye
        self.popup = self.create_client(SetBool, 'diverter/popup')
        self.beat = self.create_publisher(UInt32, 'controller/heartbeat', 10)
        self.count = 0
        self.create_subscription(String, 'scanner/label', self.on_label, 10)
        self.create_subscription(TimeReference, 'sensors/edges', self.on_edge, 10)
        self.heartbeat_timer = self.create_timer(0.05, self.on_beat)

    def on_label(self, msg):
        self.waiting.append(msg.data)

    def on_edge(self, msg):
        sensor, rising = msg.header.frame_id.rsplit('/', 1)[-1], msg.source == 'rising'
        if sensor == 'pe_divert' and rising and self.waiting:
            if self.waiting.popleft().startswith('L'):
                self.popup.call_async(SetBool.Request(data=True))
        elif sensor == 'chute_left' and rising:
            self.popup.call_async(SetBool.Request(data=False))

    def on_beat(self):
        self.count += 1
        self.beat.publish(UInt32(data=self.count))
