"""
A ROS subscriber of the cell's output topics, in a process of its own (bench_cell.py).

Subscribes to every topic the simulation node publishes as a controller or a monitor
does, with the node's QoS, until SIGTERM; then prints how many messages it received.
With ``--raw`` it takes each message as its serialized bytes (as rosbag2 records, or
a C++ node whose deserialization costs little) instead of rclpy's Python objects.

    python benchmarks/topic_subscriber.py [--raw] SENSOR [SENSOR ...]
"""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from geometry_msgs.msg import PoseArray
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState, TimeReference
    from std_msgs.msg import Bool, String, UInt32MultiArray

    from sorter_ros.env import apply_ros_env_defaults
    from sorter_ros.interface import EVENT_QOS, SENSOR_QOS, STREAM_QOS

    apply_ros_env_defaults()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('bench_subscriber', context=ctx)
    raw = '--raw' in sys.argv[1:]
    sensors = [a for a in sys.argv[1:] if a != '--raw']
    received = [0]
    topics = {
        'parcels/poses': (PoseArray, STREAM_QOS),
        'parcels/ids': (UInt32MultiArray, STREAM_QOS),
        'diverter/state': (JointState, STREAM_QOS),
        'sensors/edges': (TimeReference, EVENT_QOS),
        'scanner/label': (String, EVENT_QOS),
        'sort/outcomes': (DiagnosticStatus, EVENT_QOS),
        'status/packml': (String, SENSOR_QOS),
        **{f'sensors/{s}': (Bool, SENSOR_QOS) for s in sensors},
    }

    def count(_msg) -> None:
        received[0] += 1

    for topic, (msg_type, qos) in topics.items():
        node.create_subscription(msg_type, topic, count, qos, raw=raw)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    print('ready', flush=True)
    while not stop.is_set():
        executor.spin_once(timeout_sec=0.1)
    print(f'received={received[0]}', flush=True)
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)
    return 0


if __name__ == '__main__':
    sys.exit(main())
