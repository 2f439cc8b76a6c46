"""Thin rclpy nodes: parameters and messages in, one core call, messages out."""
