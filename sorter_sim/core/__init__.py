"""
The ROS-free model core: friction laws, footprint geometry, wrenches, integrators.

Nothing under this package imports rclpy or any message module (a test enforces it).
"""
