"""The console's learning process: ``python -m audio2pose_ros.console.enroll_worker REC FOLDER``.

Run by :class:`~audio2pose_ros.console.enrollment.Enrollments` in a child process, so that the
console never loads MediaPipe, torch or the model: it lowers its own priority (the node graph
keeps the cores) and bounds its own data (heap and anonymous mappings, ``RLIMIT_DATA``) to
:data:`~audio2pose_ros.console.enrollment.ENROLL_MEMORY_BYTES`, a bound its ffmpeg children
inherit. It learns the style of the recording ``REC`` as ``audio2pose enroll`` does
(:func:`~audio2pose_ros.style.personal.enroll`) into ``FOLDER``, prints one progress line per
step, then the personal model as one JSON line after
:data:`~audio2pose_ros.console.enrollment.MODEL_PREFIX` (the style fitted to the folder's model
and, per part, what cross-validation decided: :func:`model_line`) and, last, the filter's style
settings the style alone resolves to against the packaged model, as one JSON line after
:data:`~audio2pose_ros.console.enrollment.SETTINGS_PREFIX`. A recording it cannot learn from
exits 1 with the reason as its last line, after
:data:`~audio2pose_ros.console.enrollment.FAILED_PREFIX`: the importer's refusal, the memory
bound reached, or any other error (its traceback goes to the standard error, the console's
learning log).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import resource
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from audio2pose_ros.console import enrollment
from audio2pose_ros.errors import Audio2PoseError

if TYPE_CHECKING:
    from audio2pose_ros.style.personal import Enrollment


def bound_memory(limit_bytes: int) -> None:
    """Bound this process's data, and its future children's, to ``limit_bytes`` (RLIMIT_DATA).

    A hard limit set lower already stays. Past the bound an allocation fails: Python raises
    MemoryError, ffmpeg stops with an error.
    """
    _, hard = resource.getrlimit(resource.RLIMIT_DATA)
    soft = limit_bytes if hard == resource.RLIM_INFINITY else min(limit_bytes, hard)
    resource.setrlimit(resource.RLIMIT_DATA, (soft, hard))


def main(argv: Sequence[str] | None = None) -> int:
    """Learn one recording's style; 0 on success, 1 with the reason when it fails."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 2:
        print("usage: python -m audio2pose_ros.console.enroll_worker RECORDING FOLDER")
        return 2
    with contextlib.suppress(OSError):
        os.nice(10)
    limit = enrollment.ENROLL_MEMORY_BYTES
    bound_memory(limit)

    def failed(reason: str) -> int:
        print(enrollment.FAILED_PREFIX + " ".join(reason.split()), flush=True)
        return 1

    try:
        from audio2pose_ros.robot.description import load_robot
        from audio2pose_ros.style.personal import enroll

        def progress(line: str) -> None:
            print(line, flush=True)

        result = enroll(Path(args[0]), Path(args[1]), load_robot(), progress=progress)
    except Audio2PoseError as exc:
        return failed(str(exc))
    except MemoryError:
        traceback.print_exc()
        return failed(f"learning needs more memory than its bound of {limit / 2**30:g} GiB")
    except Exception as exc:  # the process's boundary: the console shows why, not a progress line
        traceback.print_exc()
        return failed(f"learning failed: {type(exc).__name__}: {exc}")
    print(enrollment.MODEL_PREFIX + model_line(result), flush=True)
    print(enrollment.SETTINGS_PREFIX + json.dumps(dataclasses.asdict(result.settings)), flush=True)
    return 0


def model_line(result: Enrollment) -> str:
    """The personal model as JSON: its style settings and each part's verdict.

    ``settings``: the style fitted to the folder's model (its checkpoint when enrolment wrote
    one, else the packaged model); ``verdicts``: per part, ``part``, ``learned`` (False: the
    default kept), ``gain`` and ``spread`` (the expected gain on unseen stretches and its
    standard deviation over the folds), ``reason`` (why the default was kept) and ``line``
    (the sentence that says it).
    """
    fitted = result.style.fitted[1] if result.style.fitted else result.settings
    verdicts = [
        {
            "part": v.part,
            "learned": not v.kept_default,
            "gain": round(v.gain, 4),
            "spread": round(v.spread, 4),
            "reason": v.reason,
            "line": v.line(),
        }
        for v in result.verdicts
    ]
    return json.dumps({"settings": dataclasses.asdict(fitted), "verdicts": verdicts})


if __name__ == "__main__":
    raise SystemExit(main())
