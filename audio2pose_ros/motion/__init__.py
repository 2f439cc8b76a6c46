"""Motion post-processing without ROS: smoothing, joint limits, the online filter, prosody rule."""
