"""Importers: recordings (video, OpenFace 2.0 CSV, BVH mocap) to data set clips.

Each importer turns one source file into a :class:`~audio2pose_ros.data.dataset.Clip`: 16 kHz mono
audio and Pepper's joint angles on the audio feature grid (100 Hz), smoothed and clamped as seed
003 section 4.2.3 prescribes, with a mask for the joints the source does not show.
"""

from audio2pose_ros.data.importers.common import ImporterError, mirror_angles

__all__ = ["ImporterError", "mirror_angles"]
