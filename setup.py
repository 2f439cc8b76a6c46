"""Packaging for audio2pose_ros (ament_python; also installs with pip into a plain venv)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "audio2pose_ros"

setup(
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml", "README.md"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/urdf", glob("urdf/*")),
        (f"share/{PACKAGE}/models/default", glob("models/default/*")),
        (f"share/{PACKAGE}/data/speech", glob("data/speech/*")),
    ],
)
