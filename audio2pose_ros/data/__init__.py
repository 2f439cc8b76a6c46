"""Data sets: clips, rosbag2 files and importers from recordings."""
