"""Render trajectories as a video: the robot from the URDF, its joint curves, the audio track.

Headless and CPU only. pybullet (``p.DIRECT``, TinyRenderer software rasteriser) draws the URDF's
primitive shapes at each frame's joint angles; matplotlib draws the static parts once (labels,
the joint curves of the whole clip); each frame pastes the robot images and a time cursor into a
copy of that background and goes to ffmpeg (imageio-ffmpeg's binary), which muxes the audio in.
"""

from __future__ import annotations

import math
import subprocess
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.offline.trajectory import Trajectory
from audio2pose_ros.robot.kinematics import RobotKinematics
from audio2pose_ros.robot.quiet import quiet_c_output
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

VIEWS = ("front", "side")
MAX_FPS = 240.0  # video frame rate cap (Hz)
MAX_VIEW_PX = 4096  # largest view or panel side in pixels
BACKGROUND_RGB = (214, 222, 235)
CURSOR_RGB = (220, 30, 30)
CAMERA_TARGET_M = (0.0, 0.0, -0.2)  # between the wheels (z -0.82) and the raised hands (z 0.45)
CAMERA_DISTANCE_M = 2.9
CAMERA_FOV_DEG = 30.0
LIGHT_DIRECTION = (2.0, 1.0, 3.0)
TITLE_HEIGHT_PX = 28
JOINT_GROUPS = ("head", "arms", "hip")
# The joint-curve panel: one axes per group, stacked, with fixed margins for the tick labels.
CURVES_MARGIN_LEFT_PX = 52  # the y tick labels and the group's name
CURVES_MARGIN_RIGHT_PX = 8
CURVES_MARGIN_BOTTOM_PX = 26  # the time ticks and their label, under the last axes
CURVES_GAP_PX = 6  # above each axes
MIN_AXES_PX = 8  # smallest width and height of one group's axes
MIN_VIEW_PX = 32  # smallest robot view side
GROUND_LINK = "Tibia"  # Pepper's wheeled base: kept still while the hips move the body above it


def _even_up(px: int) -> int:
    return px + px % 2


# The smallest value of each size in RenderSettings (and of its --view-width, --view-height,
# --curves-height option): what the layout above needs, rounded up to even for yuv420p. A
# column (one view per camera) must hold the axes between their margins; the curve panel must
# hold every group's axes, the gaps and the bottom margin.
MIN_SIZE_PX = {
    "view_width_px": _even_up(
        max(MIN_VIEW_PX, CURVES_MARGIN_LEFT_PX + MIN_AXES_PX + CURVES_MARGIN_RIGHT_PX)
    ),
    "view_height_px": _even_up(MIN_VIEW_PX),
    "curves_height_px": _even_up(
        CURVES_MARGIN_BOTTOM_PX
        + (len(JOINT_GROUPS) + 1) * CURVES_GAP_PX
        + len(JOINT_GROUPS) * MIN_AXES_PX
    ),
}


class RenderError(InputError):
    """ffmpeg failed or there is nothing to render."""


@dataclass(frozen=True)
class RenderSettings:
    """Video geometry and encoding.

    Attributes:
        fps: video frame rate (Hz).
        view_width_px: width of one robot view (one column per view and trajectory).
        view_height_px: height of the robot views.
        curves_height_px: height of the joint-curve panel under each robot.
        side_view: add a view from the robot's right next to the front view.
        crf: x264 constant rate factor (lower is better and bigger).

    Each size is even and lies in [:data:`MIN_SIZE_PX`, :data:`MAX_VIEW_PX`].

    """

    fps: float = 25.0
    view_width_px: int = 400
    view_height_px: int = 480
    curves_height_px: int = 300
    side_view: bool = False
    crf: int = 23

    def __post_init__(self) -> None:
        """Reject sizes the layout cannot hold or x264 cannot encode (yuv420p needs even ones)."""
        if not (math.isfinite(self.fps) and 0 < self.fps <= MAX_FPS):
            raise ConfigurationError(f"fps must be a finite positive number, got {self.fps}")
        for name, low in MIN_SIZE_PX.items():
            value = getattr(self, name)
            if not low <= value <= MAX_VIEW_PX or value % 2:
                raise ConfigurationError(
                    f"{name} must be an even number in [{low}, {MAX_VIEW_PX}], got {value}"
                )

    @property
    def views(self) -> tuple[str, ...]:
        """The camera views drawn for each trajectory."""
        return VIEWS if self.side_view else VIEWS[:1]


@dataclass(frozen=True)
class RenderResult:
    """What :func:`render_video` wrote."""

    path: Path
    n_frames: int
    duration_s: float
    wall_time_s: float


class RobotCamera:
    """The URDF in a headless pybullet world, photographed at given joint positions."""

    def __init__(self, kinematics: RobotKinematics, width_px: int, height_px: int) -> None:
        """Load the URDF (fixed base) and set every joint to its default position."""
        with quiet_c_output():  # pybullet prints its build date on import
            import pybullet
            from pybullet_utils.bullet_client import BulletClient

            self._client = BulletClient(connection_mode=pybullet.DIRECT)
            self._body = self._client.loadURDF(str(kinematics.urdf_path), useFixedBase=True)
        self._p = pybullet
        self._index = {
            self._client.getJointInfo(self._body, i)[1].decode(): i
            for i in range(self._client.getNumJoints(self._body))
        }
        self.width_px, self.height_px = width_px, height_px
        self._kinematics = kinematics
        self._ground_pose = kinematics.link_poses({})[GROUND_LINK]
        self.set_positions({})
        self._projection = self._client.computeProjectionMatrixFOV(
            CAMERA_FOV_DEG, width_px / height_px, 0.1, 10.0
        )
        tx, ty, tz = CAMERA_TARGET_M
        eyes = {"front": (tx + CAMERA_DISTANCE_M, ty, tz), "side": (tx, ty - CAMERA_DISTANCE_M, tz)}
        self._views = {
            name: self._client.computeViewMatrix(eye, CAMERA_TARGET_M, (0.0, 0.0, 1.0))
            for name, eye in eyes.items()
        }

    def set_positions(self, positions: Mapping[str, float]) -> None:
        """Pose the robot: the named joints (radians), the others at their defaults.

        The base (``GROUND_LINK``) stays where it is in the default pose, as on the floor: the
        hip joints then tilt the upper body, not the base.
        """
        from scipy.spatial.transform import Rotation  # only the renderer needs scipy

        full = self._kinematics.resolve(positions)
        for name, value in full.items():
            self._client.resetJointState(self._body, self._index[name], value)
        root = self._ground_pose @ np.linalg.inv(self._kinematics.link_poses(full)[GROUND_LINK])
        self._client.resetBasePositionAndOrientation(
            self._body, root[:3, 3].tolist(), Rotation.from_matrix(root[:3, :3]).as_quat().tolist()
        )

    def link_pose(self, link: str) -> np.ndarray:
        """(4, 4) world pose of a link's frame, from pybullet's own forward kinematics."""
        from scipy.spatial.transform import Rotation

        for index in self._index.values():
            if self._client.getJointInfo(self._body, index)[12].decode() == link:
                state = self._client.getLinkState(self._body, index, computeForwardKinematics=True)
                pose = np.eye(4)
                pose[:3, :3] = Rotation.from_quat(state[5]).as_matrix()
                pose[:3, 3] = state[4]
                return pose
        raise KeyError(f"{link} is not a child link in pybullet's model")

    def shoot(self, view: str) -> np.ndarray:
        """(height_px, width_px, 3) uint8 image from the ``'front'`` or ``'side'`` camera."""
        _, _, rgba, _, segmentation = self._client.getCameraImage(
            self.width_px,
            self.height_px,
            self._views[view],
            self._projection,
            renderer=self._p.ER_TINY_RENDERER,
            shadow=0,
            lightDirection=LIGHT_DIRECTION,
        )
        shape = (self.height_px, self.width_px)
        image = np.reshape(np.asarray(rgba, dtype=np.uint8), (*shape, 4))[:, :, :3].copy()
        image[np.reshape(np.asarray(segmentation), shape) < 0] = BACKGROUND_RGB
        return image

    def close(self) -> None:
        """Disconnect from pybullet."""
        self._client.disconnect()


@dataclass
class _Layout:
    """The static background and where each frame's moving parts go (pixel rows/columns)."""

    background: np.ndarray  # (H, W, 3) uint8
    view_origins: list[list[tuple[int, int]]]  # [trajectory][view] -> (row, column) top-left
    cursor_spans: list[tuple[int, int, int, int]]  # [trajectory] -> column 0, column 1, row 0, 1
    duration_s: float

    def cursor_column(self, index: int, t_s: float) -> int:
        """Image column of time ``t_s`` in trajectory ``index``'s curves."""
        col0, col1, _, _ = self.cursor_spans[index]
        return round(col0 + (col1 - col0) * min(max(t_s / self.duration_s, 0.0), 1.0))


def _build_layout(
    trajectories: Sequence[Trajectory],
    groups: dict[str, str],
    duration_s: float,
    settings: RenderSettings,
) -> _Layout:
    """Draw titles and joint curves with matplotlib; return them with the panel positions."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    dpi = 100
    column_px = settings.view_width_px * len(settings.views)
    width_px = column_px * len(trajectories)
    height_px = TITLE_HEIGHT_PX + settings.view_height_px + settings.curves_height_px
    figure = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi, facecolor="white")
    canvas = FigureCanvasAgg(figure)
    margin_left_px, margin_right_px = CURVES_MARGIN_LEFT_PX, CURVES_MARGIN_RIGHT_PX
    gap_px = CURVES_GAP_PX
    curves_top_px = TITLE_HEIGHT_PX + settings.view_height_px
    panel_px = (
        settings.curves_height_px - CURVES_MARGIN_BOTTOM_PX - (len(JOINT_GROUPS) + 1) * gap_px
    ) / len(JOINT_GROUPS)
    axes_by_trajectory = []
    for i, trajectory in enumerate(trajectories):
        x0_px = i * column_px
        views = ", ".join(settings.views)
        figure.text(
            (x0_px + column_px / 2) / width_px,
            1 - (TITLE_HEIGHT_PX / 2) / height_px,
            f"{trajectory.label} ({views})",
            ha="center",
            va="center",
            fontsize=11,
        )
        axes = []
        for g, group in enumerate(JOINT_GROUPS):
            top_px = curves_top_px + gap_px + g * (panel_px + gap_px)
            ax = figure.add_axes(
                (
                    (x0_px + margin_left_px) / width_px,
                    1 - (top_px + panel_px) / height_px,
                    (column_px - margin_left_px - margin_right_px) / width_px,
                    panel_px / height_px,
                )
            )
            for j, name in enumerate(trajectory.joint_names):
                if groups.get(name) == group:
                    ax.plot(trajectory.times_s, trajectory.angles_rad[:, j], lw=0.9, label=name)
            ax.set_xlim(0.0, duration_s)
            ax.set_ylabel(f"{group} (rad)", fontsize=7)
            ax.tick_params(labelsize=6, length=2)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=5, ncol=4, loc="upper right", framealpha=0.6, handlelength=1)
            if g < len(JOINT_GROUPS) - 1:
                ax.tick_params(labelbottom=False)
            else:
                ax.set_xlabel("time (s)", fontsize=7, labelpad=1)
            axes.append(ax)
        axes_by_trajectory.append(axes)
    # matplotlib's Agg canvas methods are unannotated
    canvas.draw()  # type: ignore[no-untyped-call]
    rgba = canvas.buffer_rgba()  # type: ignore[no-untyped-call]
    background = np.asarray(rgba)[:, :, :3].copy()
    spans = []
    for axes in axes_by_trajectory:
        top, bottom = axes[0].get_window_extent(), axes[-1].get_window_extent()
        spans.append(
            (
                round(top.x0),
                round(top.x1) - 1,
                height_px - round(top.y1),
                height_px - round(bottom.y0),
            )
        )
    origins = [
        [
            (TITLE_HEIGHT_PX, i * column_px + v * settings.view_width_px)
            for v in range(len(settings.views))
        ]
        for i in range(len(trajectories))
    ]
    return _Layout(background, origins, spans, duration_s)


def _write_wav(path: Path, audio_16k: np.ndarray) -> None:
    from scipy.io import wavfile

    samples = np.clip(np.asarray(audio_16k, dtype=np.float64), -1.0, 1.0)
    wavfile.write(path, SAMPLE_RATE_HZ, (samples * 32767).astype(np.int16))


def render_video(
    out_path: str | Path,
    trajectories: Sequence[Trajectory],
    audio_16k: np.ndarray,
    kinematics: RobotKinematics,
    groups: dict[str, str],
    settings: RenderSettings | None = None,
    progress: bool = True,
) -> RenderResult:
    """Render one robot per trajectory, side by side, moving in time with the audio.

    Args:
        out_path: the MP4 to write (H.264 + AAC); its folder is created.
        trajectories: one or more trajectories of joints of the URDF (times from audio start).
        audio_16k: the speech, 16 kHz mono float in [-1, 1]; it sets the video's duration.
        kinematics: the robot's URDF.
        groups: joint name -> curve panel ('head', 'arms' or 'hip'); others are not plotted.
        settings: geometry and encoding (defaults: :class:`RenderSettings`).
        progress: show a tqdm progress bar on stderr.

    Raises:
        RenderError: ffmpeg failed (its message is included).

    """
    import imageio_ffmpeg
    from tqdm import tqdm

    settings = settings or RenderSettings()
    if not trajectories:
        raise RenderError("nothing to render: no trajectories")
    duration_s = len(audio_16k) / SAMPLE_RATE_HZ
    n_frames = max(1, round(duration_s * settings.fps))
    frame_times_s = np.arange(n_frames) / settings.fps
    layout = _build_layout(trajectories, groups, duration_s, settings)
    height_px, width_px, _ = layout.background.shape
    samples = [t.sample(frame_times_s) for t in trajectories]
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    camera = RobotCamera(kinematics, settings.view_width_px, settings.view_height_px)
    with tempfile.TemporaryDirectory(prefix="audio2pose_render_") as tmp:
        wav = Path(tmp) / "audio.wav"
        _write_wav(wav, audio_16k)
        command = [
            imageio_ffmpeg.get_ffmpeg_exe(),
            "-y", "-loglevel", "error",
            "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width_px}x{height_px}",
            "-r", f"{settings.fps}", "-i", "-",
            "-i", str(wav),
            "-c:v", "libx264", "-preset", "veryfast", "-crf", str(settings.crf),
            "-pix_fmt", "yuv420p", "-c:a", "aac", "-b:a", "96k",
            "-t", f"{n_frames / settings.fps:.3f}", str(out),
        ]  # fmt: skip
        encoder = subprocess.Popen(command, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        assert encoder.stdin is not None
        try:
            for k in tqdm(range(n_frames), desc="render", unit="frame", disable=not progress):
                frame = layout.background.copy()
                for i, trajectory in enumerate(trajectories):
                    camera.set_positions(
                        dict(zip(trajectory.joint_names, samples[i][k].tolist(), strict=True))
                    )
                    for (row, col), view in zip(
                        layout.view_origins[i], settings.views, strict=True
                    ):
                        frame[row : row + camera.height_px, col : col + camera.width_px] = (
                            camera.shoot(view)
                        )
                    x = layout.cursor_column(i, float(frame_times_s[k]))
                    _, _, row0, row1 = layout.cursor_spans[i]
                    frame[row0:row1, max(x - 1, 0) : x + 1] = CURSOR_RGB
                encoder.stdin.write(frame.tobytes())
            encoder.stdin.close()
        except BrokenPipeError:
            pass  # ffmpeg stopped early: its exit code and message are reported below
        finally:
            camera.close()
        error = encoder.stderr.read().decode(errors="replace") if encoder.stderr else ""
        if encoder.wait() != 0:
            raise RenderError(f"ffmpeg failed writing {out}: {error.strip()}")
    return RenderResult(out, n_frames, n_frames / settings.fps, time.monotonic() - start)
