"""Checking a checkpoint before a running inference switches to it (``model_path`` set live).

:func:`load_replacement` loads the checkpoint with the same checks as at start-up
(:func:`~audio2pose_ros.checkpoints.numpy_runtime.load_streaming_model`: unreadable, modified
after saving, crafted, offline-only, made for other joints) and also requires what a switch
without a restart needs: the feature specification of the model that runs now (the features
node keeps sending the same frames), and a numpy kernel (loading torch would hold the node for
seconds). A refusal is a :class:`~audio2pose_ros.errors.ConfigurationError` that says why; the
running model is not touched.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.resources import default_checkpoint_path

if TYPE_CHECKING:  # the features node resolves a path only: it loads no model (footprint)
    from audio2pose_ros.checkpoints.numpy_runtime import StreamingModel
    from audio2pose_ros.robot.description import RobotDescription

__all__ = ["CHECKPOINT_FILE", "STYLE_FILE", "load_replacement", "resolve_model_path"]

# A personal model folder (``audio2pose enroll``, the console's "learn my style") holds its style
# and, when enrolment fitted the arms' own noise, its checkpoint.
STYLE_FILE = "style.yaml"
CHECKPOINT_FILE = "model.safetensors"


def resolve_model_path(model_path: str) -> Path:
    """The checkpoint ``model_path`` names.

    '' is the packaged default. A personal model folder (it holds :data:`STYLE_FILE`) runs its
    :data:`CHECKPOINT_FILE`, or the packaged default when enrolment wrote none (the person's
    style alone, which the motion filter applies). Anything else is taken as a checkpoint file.
    """
    if not model_path:
        return default_checkpoint_path()
    path = Path(model_path)
    if path.is_dir() and (path / STYLE_FILE).is_file():
        own = path / CHECKPOINT_FILE
        return own if own.is_file() else default_checkpoint_path()
    return path


def load_replacement(
    model_path: str, running: StreamingModel, robot: RobotDescription
) -> StreamingModel:
    """The checkpoint ``model_path`` names (:func:`resolve_model_path`), fit to replace ``running``.

    Raises:
        ConfigurationError: the file is missing or not a file, fails the start-up checks, is
            made for other joints (``robot``) or other features than ``running``'s, or has no
            numpy kernel. The message names the path and the reason.
    """
    from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model

    path = resolve_model_path(model_path)
    if not path.is_file():
        what = (
            f"a folder without {STYLE_FILE}, neither a checkpoint nor a personal model"
            if path.is_dir()
            else "no such file"
        )
        raise ConfigurationError(f"model_path {str(path)!r} refused: {what}")
    try:
        model = load_streaming_model(
            path, robot=robot, features=running.features, allow_torch=False
        )
    except ConfigurationError as exc:
        reason = str(exc).removeprefix(f"{path}: ")
        raise ConfigurationError(f"model_path {str(path)!r} refused: {reason}") from None
    return model
