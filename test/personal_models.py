"""Personal models for tests: an enrolment's checkpoint and the folder ``model_path`` takes.

A personal model folder holds ``style.yaml`` and, when enrolment fitted the arms' own noise,
``model.safetensors`` (without it, the packaged model runs with the person's style).
"""

from __future__ import annotations

import shutil
from pathlib import Path

from audio2pose_ros.checkpoints.torch_io import load_checkpoint, save_checkpoint
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.style.personal import with_arms_noise


def arms_noise_checkpoint(path: Path, robot: RobotDescription) -> Path:
    """The packaged model with its arms sampling at 4 times their temperature (an enrolment's).

    Saved at ``path``, which is returned.
    """
    noisy = with_arms_noise(load_checkpoint(default_checkpoint_path(), robot=robot), 4.0)
    assert noisy is not None
    return save_checkpoint(path, noisy)


def personal_folder(folder: Path, checkpoint: Path | None = None) -> Path:
    """``folder`` made a personal model: its ``style.yaml``, and ``checkpoint`` copied in.

    Returns:
        ``folder``, as ``model_path`` takes it.
    """
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "style.yaml").write_text("name: me\n", encoding="utf-8")
    if checkpoint is not None:
        shutil.copyfile(checkpoint, folder / "model.safetensors")
    return folder
