"""Packaging for audio2pose_ros (ament_python; also installs with pip into a plain venv)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "audio2pose_ros"

setup(
    # Here, not in setup.cfg: setup.cfg turns it into a SpecifierSet, which colcon's setup.py
    # introspection (ast.literal_eval of the setup arguments) cannot parse.
    python_requires=">=3.10",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml", "README.md"]),
        (
            f"share/{PACKAGE}/config",
            glob("config/*.yaml") + glob("config/*.rviz") + glob("config/*.xml"),
        ),
        (f"share/{PACKAGE}/config/styles", glob("config/styles/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/urdf", glob("urdf/*")),
        (f"share/{PACKAGE}/models/default", glob("models/default/*")),
        (f"share/{PACKAGE}/data/speech", glob("data/speech/*")),
        (f"share/{PACKAGE}/data/video", glob("data/video/*")),
        # the operator console's front end, built by `cd web && npm ci && npm run build`
        (f"share/{PACKAGE}/web/dist", glob("web/dist/*")),
    ],
)
