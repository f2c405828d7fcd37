"""
The minimal controller as a process of its own, as ``controller: {command: ...}`` starts it.

It runs on the cell's clock (``use_sim_time``, set in MinimalController), in the
ROS domain the scenario gives it (``ROS_DOMAIN_ID``), until it is stopped.
"""

import rclpy
from rclpy.executors import ExternalShutdownException

from minimal_controller import MinimalController


def main(args=None):
    rclpy.init(args=args)
    node = MinimalController()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
