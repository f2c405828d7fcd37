"""
The simulator's front ends: the ROS 2 node, and what it serves beside ROS.

``node`` publishes the cell's poses and sensors and takes the diverter's commands;
``fieldbus`` and ``modbus_server`` serve the I/O image over OPC UA and Modbus TCP;
``live_view`` is the Foxglove WebSocket server; ``cdr`` encodes poses once for both
the topic and the recording.
"""
