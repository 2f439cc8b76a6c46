"""audio2pose_ros: speech-driven upper-body motion for the Pepper humanoid.

The subpackages ``audio``, ``motion`` and ``models`` and the modules ``robot``, ``synthesis``,
``training`` and ``resources`` form a ROS-free core; ``nodes`` holds the thin rclpy nodes and
``cli`` the ``audio2pose`` command.
"""

__version__ = "0.1.0"
