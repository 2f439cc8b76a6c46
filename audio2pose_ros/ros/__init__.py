"""The only layer that imports rclpy: nodes, the graph supervisor and its tools."""
