"""The package stays buildable by colcon (ament_python) on a machine with a ROS distro.

colcon (colcon-python-setup-py) does not run setup.py the pip way: it calls
``distutils.core.run_setup("setup.py", ("--dry-run",), stop_after="config")`` in a subprocess and
reads the distribution's attributes back with ``ast.literal_eval``. Anything whose repr is not a
Python literal (e.g. the SpecifierSet that setup.cfg's ``python_requires`` becomes) makes
``colcon build`` fail before building. And when setup.py's text contains ``setup()`` colcon reads
only setup.cfg, which has no ``data_files``: package.xml, config/, launch/ and models/ are then
not installed.
"""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

COLCON_INTROSPECTION = """
import sys
from distutils.core import run_setup
dist = run_setup("setup.py", script_args=("--dry-run",), stop_after="config")
skip = ("cmdclass", "distclass", "ext_modules", "metadata")
data = {
    k: v for k, v in dist.__dict__.items()
    if not k.startswith("_") and not callable(v) and k not in skip
    and k not in dist.display_option_names
}
sys.stdout.write(repr(data))
"""


def test_setup_py_is_readable_by_colcon():
    out = subprocess.run(
        [sys.executable, "-c", COLCON_INTROSPECTION],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    data = ast.literal_eval(out)  # what colcon does; fails on non-literal values
    installed = {
        f"{dest}/{Path(src).name}" for dest, sources in data["data_files"] for src in sources
    }
    assert "share/ament_index/resource_index/packages/audio2pose_ros" in installed
    assert "share/audio2pose_ros/package.xml" in installed
    assert "share/audio2pose_ros/config/pepper.yaml" in installed
    assert "share/audio2pose_ros/launch/pepper.launch.py" in installed
    assert "share/audio2pose_ros/models/default/default.safetensors" in installed


def test_colcon_does_not_take_the_setup_cfg_only_shortcut():
    assert "setup()" not in (ROOT / "setup.py").read_text()
