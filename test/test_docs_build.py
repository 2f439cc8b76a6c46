"""``make docs``: the documentation builds offline, without one warning.

The same Sphinx command as the Makefile's, from scratch (``-E``, a fresh output folder), with the
network pointed at a closed port so that anything the build would fetch fails it.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
OFFLINE = {
    name: "http://127.0.0.1:9"
    for name in ("http_proxy", "https_proxy", "HTTP_PROXY", "HTTPS_PROXY", "all_proxy")
}


def sphinx_command(out: Path) -> list[str]:
    """The Makefile's ``docs`` command, with this interpreter and ``out`` as output folder."""
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    (line,) = re.findall(r"^\t\$\(VENV_BIN\)/python -m sphinx (.*) doc out/docs$", makefile, re.M)
    return [sys.executable, "-m", "sphinx", *line.split(), "-E", "doc", str(out)]


@pytest.mark.slow
def test_documentation_builds_offline_without_warnings(tmp_path):
    shutil.rmtree(ROOT / "doc" / "generated", ignore_errors=True)  # stubs of removed modules
    env = {**os.environ, **OFFLINE, "PYTHONPATH": str(ROOT)}
    result = subprocess.run(
        sphinx_command(tmp_path / "html"),
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "WARNING" not in result.stderr, result.stderr[-3000:]
    for page in ("index", "troubleshooting", "parameters", "api", "model_card"):
        assert (tmp_path / "html" / f"{page}.html").is_file()
    api = (tmp_path / "html" / "generated" / "audio2pose_ros.motion.filter.html").read_text()
    assert "MotionFilter" in api  # the API pages come from the docstrings


def test_the_documentation_needs_nothing_from_the_network():
    """No intersphinx inventories or remote images: the build must not fetch."""
    conf = (ROOT / "doc" / "conf.py").read_text(encoding="utf-8")
    assert "intersphinx" not in conf
    for page in (ROOT / "doc").glob("*.md"):
        assert not re.search(r"!\[[^\]]*\]\(https?://", page.read_text(encoding="utf-8")), page
