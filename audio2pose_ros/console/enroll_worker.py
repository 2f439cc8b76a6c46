"""The console's learning process: ``python -m audio2pose_ros.console.enroll_worker REC FOLDER``.

Run by :class:`~audio2pose_ros.console.enrollment.Enrollments` in a child process, so that the
console never loads MediaPipe, torch or the model: it lowers its own priority (the node graph
keeps the cores), learns the style of the recording ``REC`` as ``audio2pose enroll`` does
(:func:`~audio2pose_ros.style.personal.enroll`) into ``FOLDER``, prints one progress line per
step and, last, the filter's style settings it resolves to, as one JSON line after
:data:`~audio2pose_ros.console.enrollment.SETTINGS_PREFIX`. A refused recording exits 1 with
the reason as its last line.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from audio2pose_ros.console.enrollment import SETTINGS_PREFIX
from audio2pose_ros.errors import Audio2PoseError


def main(argv: Sequence[str] | None = None) -> int:
    """Learn one recording's style; 0 on success, 1 with the reason when it is refused."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 2:
        print("usage: python -m audio2pose_ros.console.enroll_worker RECORDING FOLDER")
        return 2
    with contextlib.suppress(OSError):
        os.nice(10)
    from audio2pose_ros.robot.description import load_robot
    from audio2pose_ros.style.personal import enroll

    def progress(line: str) -> None:
        print(line, flush=True)

    try:
        result = enroll(Path(args[0]), Path(args[1]), load_robot(), progress=progress)
    except Audio2PoseError as exc:
        print(f"{exc}", flush=True)
        return 1
    print(SETTINGS_PREFIX + json.dumps(dataclasses.asdict(result.settings)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
