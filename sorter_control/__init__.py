"""sorter_control: the PLC-like sorter controller (pure logic + a thin ROS node)."""
