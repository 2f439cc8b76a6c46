"""The named style presets, measured from our own sources: ``make style-presets`` rebuilds them.

- ``calm_reader``: the GRID clips (8 speakers reading short sentences to a camera; head only);
- ``addressing_camera``: the Obama weekly-address clips (one speaker addressing a camera; head
  only);
- ``lecturer``: the lecture video (a lecturer at a blackboard; arms and hip where visible).

Each is measured (:func:`~audio2pose_ros.style.figures.measure`) from the clips the training
importers make of the shared data (the same importers as ``make default-model``), and written
to ``config/styles/<name>.yaml`` with its source, licence and this command. A preset adapts
only the parts its source observes.

Resolving a preset (:func:`~audio2pose_ros.style.figures.resolve`) needs the model's own motion
on the bundled speech, 20 to 30 s of synthesis; so each preset also keeps the settings resolved
against the packaged model (its ``fitted`` entry, with the checkpoint's SHA-256), and a start
with the packaged model reads them instead. ``--resolve`` renews them after the model changes
(``make default-model`` runs it).

Usage: ``python -m audio2pose_ros.style.presets TALKING_HEADS_DIR LECTURE_VIDEO WORK_DIR
[OUT_DIR]`` (the data sets are imported into WORK_DIR unless they are there already), or
``python -m audio2pose_ros.style.presets --resolve [PRESETS_DIR]``.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

from audio2pose_ros.data.dataset import Dataset
from audio2pose_ros.robot.description import RobotDescription, load_robot
from audio2pose_ros.style.figures import StyleFile, measure, read_style, resolve

COMMAND = "make style-presets"
USAGE = (
    "usage: python -m audio2pose_ros.style.presets TALKING_HEADS_DIR LECTURE_VIDEO WORK_DIR "
    "[OUT_DIR]\n       python -m audio2pose_ros.style.presets --resolve [PRESETS_DIR]"
)
# name -> (data set in the work dir, clip id prefix, description)
PRESETS = {
    "calm_reader": (
        "talking_heads",
        "grid",
        "a calm reader: GRID speakers reading short sentences (head only)",
    ),
    "addressing_camera": (
        "talking_heads",
        "obama",
        "someone addressing a camera: weekly addresses (head only)",
    ),
    "lecturer": (
        "lecture",
        "lecture",
        "a lecturer at a blackboard: the lecture video where the arms are seen (arms, hip)",
    ),
}


def measure_preset(
    dataset_dir: Path, prefix: str, name: str, description: str, robot: RobotDescription
) -> StyleFile:
    """The preset ``name`` measured from the clips of ``dataset_dir`` starting with ``prefix``.

    Its source names the clips' count and licences.
    """
    dataset = Dataset.open(dataset_dir, robot)
    infos = [info for info in dataset.clips if info.clip_id.startswith(prefix)]
    clips = [dataset.load(info.clip_id) for info in infos]
    licences = sorted({info.licence for info in infos})
    source = f"{len(clips)} clips of {prefix} ({'; '.join(licences)})"
    return StyleFile(
        name=name,
        description=description,
        source=source,
        command=COMMAND,
        parts=measure([(c.angles_rad, c.mask) for c in clips], robot),
    )


def build_presets(
    talking_heads: Path, lecture_video: Path, work_dir: Path, out_dir: Path
) -> list[Path]:
    """Import the shared sources into ``work_dir`` (unless there) and write every preset."""
    from audio2pose_ros.data.importers.lecture import import_lecture
    from audio2pose_ros.learning.default_model import import_talking_heads

    robot = load_robot()
    if not (work_dir / "talking_heads" / "index.json").is_file():
        import_talking_heads(talking_heads, work_dir / "talking_heads", robot)
    if not (work_dir / "lecture" / "index.json").is_file():
        import_lecture(lecture_video, work_dir / "lecture", robot)
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, (dataset, prefix, description) in PRESETS.items():
        style = measure_preset(work_dir / dataset, prefix, name, description, robot)
        style.write(out_dir / f"{name}.yaml")
    return resolve_presets(out_dir)


def resolve_presets(presets: Path, checkpoint: Path | None = None) -> list[Path]:
    """Keep in every preset of ``presets`` its settings resolved against ``checkpoint``.

    ``checkpoint`` defaults to the packaged model. Each file's ``fitted`` entry is replaced by
    (the checkpoint's SHA-256, the resolved settings); the figures are left as they are.
    """
    from audio2pose_ros.resources import default_checkpoint_path
    from audio2pose_ros.style.personal import checkpoint_digest, model_reference

    checkpoint = checkpoint or default_checkpoint_path()
    robot = load_robot()
    reference = model_reference(checkpoint)
    digest = checkpoint_digest(checkpoint)
    written = []
    for path in sorted(presets.glob("*.yaml")):
        style = read_style(path)
        settings = resolve(style.parts, reference, robot)
        written.append(dataclasses.replace(style, fitted=(digest, settings)).write(path))
    return written


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring."""
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["--resolve"]:
        if len(args) > 2:
            print(USAGE, file=sys.stderr)
            return 2
        presets = Path(args[1]) if len(args) == 2 else Path("config") / "styles"
        for path in resolve_presets(presets):
            print(f"resolved {path}")
        return 0
    if len(args) not in (3, 4) or any(arg.startswith("-") for arg in args):
        print(USAGE, file=sys.stderr)
        return 2
    out = Path(args[3]) if len(args) == 4 else Path("config") / "styles"
    for path in build_presets(Path(args[0]), Path(args[1]), Path(args[2]), out):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
