"""``audio2pose dataset ...``: build data sets from recordings, and describe them.

Sub-verbs: ``import-video`` (any video with sound: head by MediaPipe FaceMesh, arms and hip by
MediaPipe Pose where visible), ``import-openface`` (OpenFace 2.0 CSV + its audio),
``import-bvh`` (BVH mocap + its audio, through a skeleton mapping), ``info`` and
``build-default`` (rebuild the default model from the shared clips, end to end). Importers take
files or folders; a file that fails is reported with its name and the reason, the others are
imported, and the exit code is 1 when any failed. Each file becomes the clip named after its
stem: two inputs of one run that would get the same id, or an id the data set holds already
(unless ``--replace`` is given), are reported as failed files, never written over. The output
(``-o``) is an existing data set, an empty folder or a new folder in an existing one; anything
else is refused before any input is read. :func:`register` adds the verb to the main parser.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from audio2pose_ros.cli.options import (
    MAX_SEED,
    Verbs,
    bounded_float,
    bounded_int,
    input_dir,
    input_file,
    new_dir,
)
from audio2pose_ros.errors import Audio2PoseError, InputError, UsageError

if TYPE_CHECKING:
    from audio2pose_ros.checkpoints.torch_io import Checkpoint
    from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
    from audio2pose_ros.robot.description import RobotDescription

VIDEO_SUFFIXES = (".mp4", ".mpg", ".mpeg", ".mov", ".avi", ".mkv", ".webm", ".m4v")
AUDIO_SUFFIXES = (".wav", ".flac", ".mp3", ".ogg", ".m4a", *VIDEO_SUFFIXES)


def _expand(paths: list[str], suffixes: tuple[str, ...]) -> list[Path]:
    """Files as given, plus the files with one of ``suffixes`` inside given folders (sorted)."""
    files: list[Path] = []
    for name in paths:
        path = Path(name)
        if path.is_dir():
            files += sorted(p for p in path.iterdir() if p.suffix.lower() in suffixes)
        else:
            files.append(path)
    return files


def _clip_id(path: Path) -> str:
    """A safe clip id from a file name."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", path.stem).lstrip(".") or "clip"


def _paired_audio(path: Path, audio_dir: str | None) -> Path:
    """The recording whose audio goes with a CSV / BVH file: same stem, audio or video suffix."""
    from audio2pose_ros.data.importers import ImporterError

    folder = Path(audio_dir) if audio_dir else path.parent
    for suffix in AUDIO_SUFFIXES:
        for candidate in (folder / (path.stem + suffix), folder / (path.stem + suffix.upper())):
            if candidate.is_file() and candidate != path:
                return candidate
    raise ImporterError(
        f"{path}: no audio next to it ({path.stem}.wav / .mp4 / ... in {folder}); use --audio-dir"
    )


def _output_dataset(name: str, robot: RobotDescription) -> Dataset:
    """The data set ``-o`` names: an existing one, or a new one in an empty or a new folder.

    Raises:
        UsageError: it exists and is neither a data set nor an empty folder, or it is new and
            its folder is missing or not writable (:func:`~audio2pose_ros.cli.options.new_dir`).
        DatasetError: the data set there is unusable (its index, its joints).
    """
    from audio2pose_ros.data.dataset import INDEX_FILE, Dataset

    path = Path(name)
    if not (path.exists() or path.is_symlink()):
        return Dataset.create(new_dir(path, "-o"), robot)
    if path.is_dir() and ((path / INDEX_FILE).exists() or (path / INDEX_FILE).is_symlink()):
        return Dataset.open(input_dir(path, "data set folder"), robot)
    if path.is_dir() and not any(input_dir(path, "data set folder").iterdir()):
        return Dataset.create(path, robot)
    raise UsageError(f"-o {path}: exists and is not a data set folder")


def _run_import(
    args: argparse.Namespace,
    files: list[Path],
    what: str,
    import_one: Callable[[Path, ClipInfo], tuple[Clip, dict[str, np.ndarray]]],
) -> int:
    """Import every file into the data set, reporting failures per file; exit code 1 if any.

    Each file must be a regular file (``what`` names its kind in the message); its clip id must
    not be that of an earlier file of this run, nor one already in the data set unless
    ``args.replace``.
    """
    from tqdm import tqdm

    from audio2pose_ros.data.dataset import ClipInfo
    from audio2pose_ros.data.importers.extras import save_extras
    from audio2pose_ros.robot.description import load_robot

    if not files:
        raise UsageError("no input files")
    robot = load_robot()
    dataset = _output_dataset(args.output, robot)
    out = dataset.root
    failures: list[str] = []
    imported: dict[str, Path] = {}  # clip id -> the file of this run it came from
    progress = tqdm(files, desc=f"dataset {args.dataset_verb}", unit="file", file=sys.stderr)
    for path in progress:
        progress.set_postfix_str(path.name)
        try:
            input_file(path, what)
            info = ClipInfo(
                clip_id=_clip_id(path),
                speaker=args.speaker or path.stem,
                source=args.source or path.name,
                licence=args.licence,
                split=args.split,
            )
            _check_clip_id(info.clip_id, imported, dataset, args.replace)
            clip, extras = import_one(path, info)
            dataset.add(clip, robot, replace=args.replace)
            save_extras(dataset, info.clip_id, extras)
            imported[info.clip_id] = path
        except (Audio2PoseError, OSError) as exc:  # this file failed; go on with the others
            failures.append(f"{path}: {exc}" if str(path) not in str(exc) else str(exc))
            progress.write(f"FAILED {failures[-1]}", file=sys.stderr)
    progress.close()
    print(f"{len(files) - len(failures)} of {len(files)} files imported into {out}")
    for failure in failures:
        print(f"  failed: {failure}", file=sys.stderr)
    return 1 if failures else 0


def _check_clip_id(
    clip_id: str, imported: dict[str, Path], dataset: Dataset, replace: bool
) -> None:
    """Refuse a clip id taken by an earlier file of this run, or by the data set (no ``replace``).

    Raises:
        InputError: the id is taken; the message names the file or data set that has it.
    """
    if clip_id in imported:
        raise InputError(
            f"clip id {clip_id!r} is that of {imported[clip_id]} imported before it; rename one "
            "of the two files"
        )
    if not replace and any(c.clip_id == clip_id for c in dataset.clips):
        raise InputError(
            f"clip id {clip_id!r} is in {dataset.root} already; give --replace to replace it"
        )


def command_import_video(args: argparse.Namespace) -> int:
    """Import video files (audio track + face + visible upper body)."""
    from audio2pose_ros.data.importers.video import VideoImportSettings, VideoTracks, import_video
    from audio2pose_ros.robot.description import load_robot

    robot = load_robot()
    settings = VideoImportSettings(mirror=args.mirror, centre=not args.no_centre, body=args.body)
    totals = {"frames": 0, "faces": 0, "seconds": 0.0}

    def count(tracks: VideoTracks) -> None:
        totals["frames"] += tracks.times_s.size
        totals["faces"] += int(tracks.face_found.sum())
        totals["seconds"] += tracks.seconds

    code = _run_import(
        args,
        _expand(args.inputs, VIDEO_SUFFIXES),
        "video file",
        lambda path, info: import_video(path, info, robot, settings, on_tracks=count),
    )
    if totals["frames"]:
        print(
            f"tracked {totals['frames']} video frames at "
            f"{totals['frames'] / max(totals['seconds'], 1e-9):.1f} frames/s; face found in "
            f"{100.0 * totals['faces'] / totals['frames']:.1f} %"
        )
    return code


def command_import_openface(args: argparse.Namespace) -> int:
    """Import OpenFace 2.0 CSV files with their audio."""
    from audio2pose_ros.data.importers.media import read_audio
    from audio2pose_ros.data.importers.openface import OpenFaceImportSettings, import_openface
    from audio2pose_ros.robot.description import load_robot

    robot = load_robot()
    settings = OpenFaceImportSettings(
        min_confidence=args.min_confidence,
        face_id=args.face_id,
        mirror=args.mirror,
        centre=not args.no_centre,
    )
    return _run_import(
        args,
        _expand(args.inputs, (".csv",)),
        "CSV file",
        lambda path, info: import_openface(
            path, read_audio(_paired_audio(path, args.audio_dir)), info, robot, settings
        ),
    )


def command_import_bvh(args: argparse.Namespace) -> int:
    """Import BVH files with their audio through a skeleton mapping."""
    from audio2pose_ros.data.importers.bvh import import_bvh, load_mappings
    from audio2pose_ros.data.importers.media import read_audio
    from audio2pose_ros.robot.description import load_robot

    robot = load_robot()
    mappings = load_mappings(args.mappings)
    if args.skeleton not in mappings:
        raise UsageError(f"unknown skeleton {args.skeleton!r}; known: {sorted(mappings)}")
    return _run_import(
        args,
        _expand(args.inputs, (".bvh",)),
        "BVH file",
        lambda path, info: import_bvh(
            path,
            read_audio(_paired_audio(path, args.audio_dir)),
            info,
            robot,
            mappings[args.skeleton],
            args.mirror,
        ),
    )


def command_info(args: argparse.Namespace) -> int:
    """Print a data set's clips, speakers, splits, durations and observed joint groups."""
    from audio2pose_ros.data.dataset import SPLITS, Dataset
    from audio2pose_ros.robot.description import JOINT_GROUPS, load_robot
    from audio2pose_ros.timebase import SAMPLE_RATE_HZ

    robot = load_robot()
    dataset = Dataset.open(input_dir(args.data, "data set folder"), robot)
    print(f"{dataset.root}: {len(dataset.clips)} clips, {len(dataset.speakers)} speakers")
    print(f"{'clip':<27} {'speaker':<23} {'split':<10} {'seconds':>7}  observed (head/arms/hip)")
    totals = dict.fromkeys(SPLITS, 0.0)
    for info in dataset.clips:
        clip = dataset.load(info.clip_id)
        seconds = clip.audio.size / SAMPLE_RATE_HZ
        totals[info.split] += seconds
        observed = " / ".join(
            f"{100.0 * clip.mask[:, robot.group_mask(g)].mean():.0f}%" for g in JOINT_GROUPS
        )
        print(f"{info.clip_id:<27} {info.speaker:<23} {info.split:<10} {seconds:>7.1f}  {observed}")
    print("seconds per split: " + ", ".join(f"{s} {totals[s]:.1f}" for s in SPLITS))
    for licence in sorted({c.licence for c in dataset.clips}):
        count = sum(c.licence == licence for c in dataset.clips)
        print(f"licence: {licence} ({count} clips)")
    return 0


def _start_checkpoint(path: str | None, robot: RobotDescription) -> Checkpoint | None:
    """The ``--start`` checkpoint of ``build-default``: a ``live_groups`` model, or None.

    Raises:
        CheckpointError: the file is missing or unreadable, or made for another robot.
        UsageError: it holds another model family.

    """
    if path is None:
        return None
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.learning.source_holdout import MODEL_NAME

    start = load_checkpoint(Path(path), robot=robot)
    if start.model.name != MODEL_NAME:
        raise UsageError(
            f"--start {path}: a {start.model.name} checkpoint; the rebuild trains {MODEL_NAME}"
        )
    return start


def command_build_default(args: argparse.Namespace) -> int:
    """Rebuild the default model from the shared recordings (import, train, evaluate, card).

    ``--arms learned`` (default): head from the talking heads, arms and hip from the lecture
    video (``--lecture``, default ``<CLIPS_DIR>/../lecture_video/physicsworks.webm``). ``--arms
    prosody`` / ``neutral``: the seed's MLP with procedural or still arms.
    """
    from audio2pose_ros.learning.default_model import (
        LearnedBuildSettings,
        build_default_model,
        build_learned_default_model,
    )
    from audio2pose_ros.robot.description import load_robot

    out = Path(args.output)
    clips = input_dir(args.clips, "clips folder")
    work = Path(args.work_dir) if args.work_dir else out / "work"
    began = time.monotonic()

    def progress(message: str) -> None:
        minutes, seconds = divmod(int(time.monotonic() - began), 60)
        print(f"[{minutes:2d}:{seconds:02d}] {message}", file=sys.stderr, flush=True)

    if args.arms == "learned":
        lecture = (
            Path(args.lecture)
            if args.lecture
            else clips.parent / "lecture_video" / ("physicsworks.webm")
        )
        if not lecture.is_file():
            raise UsageError(f"--lecture {lecture}: no such file (the shared lecture video)")
        from audio2pose_ros.learning.parallel import default_workers

        epochs = args.max_epochs or LearnedBuildSettings.max_epochs
        settings = LearnedBuildSettings(
            max_epochs=epochs,
            seed=args.seed,
            workers=args.jobs or default_workers(),
        )
        robot = load_robot()
        start = _start_checkpoint(args.start, robot)
        result = build_learned_default_model(
            clips, lecture, out, work, robot, settings, progress, start
        )
    else:
        if args.start:
            raise UsageError("--start needs --arms learned (it pretrains live_groups)")
        result = build_default_model(
            clips,
            out,
            work,
            load_robot(),
            arms=args.arms,
            max_epochs=args.max_epochs or 2000,
            seed=args.seed,
            progress=progress,
        )
    progress(f"built {result.checkpoint}")
    print(result.table)
    print(f"wrote {result.checkpoint} and {result.model_card}")
    return 0


def _common_import_options(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("inputs", nargs="+", metavar="FILE_OR_DIR", help=what)
    parser.add_argument("-o", "--output", required=True, metavar="DATASET", help="data set folder")
    parser.add_argument("--speaker", help="speaker of every clip (default: each file's stem)")
    parser.add_argument("--source", help="where the recordings come from (default: file name)")
    parser.add_argument(
        "--licence", required=True, help="licence / attribution kept with every clip"
    )
    parser.add_argument("--split", default="train", choices=("train", "validation", "test"))
    parser.add_argument(
        "--mirror", action="store_true", help="exchange left and right (mirror image)"
    )
    parser.add_argument(
        "--replace",
        action="store_true",
        help="replace clips of the same id already in the data set (default: refuse the file)",
    )


def register(verbs: Verbs) -> None:
    """Add the ``dataset`` verb and its sub-verbs to the ``audio2pose`` parser."""
    dataset = verbs.add_parser("dataset", help="import recordings into a data set; describe one")
    sub = dataset.add_subparsers(dest="dataset_verb", required=True)

    video = sub.add_parser("import-video", help="videos with sound: head, and arms if visible")
    _common_import_options(video, "video files or folders of them")
    video.add_argument(
        "--no-centre",
        action="store_true",
        help="keep head angles relative to the camera (default: median pose -> neutral)",
    )
    video.add_argument(
        "--no-body", dest="body", action="store_false", help="head only (skip MediaPipe Pose)"
    )
    video.set_defaults(func=command_import_video)

    openface = sub.add_parser("import-openface", help="OpenFace 2.0 CSVs + their audio")
    _common_import_options(openface, "CSV files or folders of them")
    openface.add_argument("--audio-dir", help="folder of the audio (default: next to each CSV)")
    openface.add_argument("--min-confidence", type=bounded_float(0.0, 1.0), default=0.0)
    openface.add_argument(
        "--face-id", type=bounded_int(0, 1_000_000), help="face to use (default: the first row's)"
    )
    openface.add_argument(
        "--no-centre", action="store_true", help="keep head angles relative to the camera"
    )
    openface.set_defaults(func=command_import_openface)

    bvh = sub.add_parser("import-bvh", help="BVH mocap + audio, through a skeleton mapping")
    _common_import_options(bvh, "BVH files or folders of them")
    bvh.add_argument("--skeleton", required=True, help="mapping name (config/bvh_mappings.yaml)")
    bvh.add_argument("--mappings", metavar="YAML", help="your own mappings file")
    bvh.add_argument("--audio-dir", help="folder of the audio (default: next to each BVH)")
    bvh.set_defaults(func=command_import_bvh)

    build = sub.add_parser(
        "build-default", help="rebuild the default model from the shared recordings"
    )
    build.add_argument(
        "clips", metavar="CLIPS_DIR", help="talking-head clips (make default-model: TALKING_HEADS)"
    )
    build.add_argument("-o", "--output", required=True, metavar="DIR", help="checkpoint + card")
    build.add_argument("--work-dir", help="scratch data sets (default: <output>/work)")
    build.add_argument(
        "--arms",
        choices=("learned", "prosody", "neutral"),
        default="learned",
        help="learned from the lecture video (default), or the MLP with the prosody rule / still",
    )
    build.add_argument(
        "--lecture", metavar="VIDEO", help="default: CLIPS_DIR/../lecture_video/physicsworks.webm"
    )
    build.add_argument(
        "--max-epochs",
        type=bounded_int(1, 100_000),
        help="default 200 (learned; also per evaluation fold) or 2000 (prosody, neutral)",
    )
    build.add_argument("--seed", type=bounded_int(0, MAX_SEED), default=0)
    build.add_argument(
        "--start",
        metavar="CKPT",
        help="learned: start every training from this pretrained live_groups checkpoint (a "
        "fold that holds out a source it learned from starts from new weights)",
    )
    build.add_argument(
        "--jobs",
        type=bounded_int(1, 256),
        help="learned: trainings side by side, one process each (default: the usable cores)",
    )
    build.set_defaults(func=command_build_default)

    info = sub.add_parser("info", help="clips, speakers, splits and observed joints")
    info.add_argument("data", metavar="DATASET")
    info.set_defaults(func=command_info)
