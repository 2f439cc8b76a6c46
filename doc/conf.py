"""Sphinx configuration of the audio2pose_ros documentation (MyST Markdown, rosdoc2 layout).

``make docs`` builds it offline into ``out/docs/`` with warnings as errors; rosdoc2 finds it
through ``rosdoc2.yaml`` (``sphinx_sourcedir: doc``).
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # the checkout's package, not an installed copy

project = "audio2pose_ros"
author = "audio2pose_ros contributors"
copyright = "audio2pose_ros contributors, Apache-2.0"
release = "0.1.0"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}  # autosummary writes .rst
exclude_patterns: list[str] = []
root_doc = "index"

myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

autosummary_generate = True
# members defined in each module only: a name a package re-exports is documented where it lives
autodoc_default_options = {"members": True, "ignore-module-all": True}
autodoc_typehints = "description"
autodoc_member_order = "bysource"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
nitpicky = False

html_theme = "alabaster"
html_title = "audio2pose_ros"
html_static_path: list[str] = []
