"""ROS 2 adapter: node, message conversions, diagnostics, parameters, shared frame processing.

Importing this package needs rclpy and the message packages (sensor_msgs,
diagnostic_msgs, rcl_interfaces); the core does not.
"""
