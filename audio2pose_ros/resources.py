"""Locate the package's shared files (config, launch, models, urdf) in every install layout.

The same files are found whether the package was built by colcon (``<prefix>/share/audio2pose_ros``
via the ament index), installed with pip (``sys.prefix/share/audio2pose_ros``) or used from a source
checkout (editable install: the repository root holds ``package.xml``).
"""

from __future__ import annotations

import sys
from functools import cache
from pathlib import Path

PACKAGE_NAME = "audio2pose_ros"


def _is_share(candidate: Path) -> bool:
    return (candidate / "package.xml").is_file() and (candidate / "config").is_dir()


def _ament_share() -> Path | None:
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        return None
    try:
        return Path(get_package_share_directory(PACKAGE_NAME))
    except (PackageNotFoundError, OSError):  # OSError: AMENT_PREFIX_PATH unset (plain venv)
        return None


@cache
def share_dir() -> Path:
    """Return the package's share directory.

    Returns:
        The first of: the source checkout (when the package is imported from one), the ament
        index entry, ``sys.prefix/share/audio2pose_ros``.

    Raises:
        FileNotFoundError: when none of them holds the package's ``package.xml`` and ``config/``.

    """
    source_root = Path(__file__).resolve().parent.parent
    if _is_share(source_root):
        return source_root
    searched = [source_root]
    for candidate in (_ament_share(), Path(sys.prefix) / "share" / PACKAGE_NAME):
        if candidate is not None:
            if _is_share(candidate):
                return candidate
            searched.append(candidate)
    raise FileNotFoundError(
        f"{PACKAGE_NAME} share directory not found (searched: {', '.join(map(str, searched))})"
    )


def share_path(*parts: str) -> Path:
    """Return a path inside the share directory, e.g. ``share_path("config", "pepper.yaml")``."""
    return share_dir().joinpath(*parts)


def default_checkpoint_path() -> Path:
    """The checkpoint shipped with the package (see models/default/MODEL_CARD.md)."""
    return share_path("models", "default", "default.safetensors")


def bundled_speech_path(name: str = "librivox_sense_and_sensibility_01_0870.wav") -> Path:
    """A bundled public-domain speech clip (see data/speech/SOURCES.md)."""
    return share_path("data", "speech", name)


def bundled_speech_paths() -> list[Path]:
    """Every bundled speech clip (see data/speech/SOURCES.md), in name order."""
    return sorted(share_path("data", "speech").glob("*.wav"))
