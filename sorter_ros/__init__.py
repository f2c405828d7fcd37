"""ROS 2 plumbing shared by the simulation node, the controller node and their tools."""
