"""How often motion needs the self-collision guard, and how deep it would go (``check-body``).

For a trajectory of poses this measures, against the robot's collision shapes
(:class:`~audio2pose_ros.robot.body.BodyModel`), the share of frames closer to the body than
the guard's margin, the share more than ``DEEP_M`` inside it (the measure robots are judged by:
an arm visibly through the torso or tablet) and the deepest penetration. ``audio2pose
check-body`` prints it for the model's raw output on speech and for the guarded output that the
robot would receive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from audio2pose_ros.robot.body import BodyModel

DEEP_M = 0.01  # an arm link more than this inside the body counts as "through" it (m)


@dataclass(frozen=True)
class BodyReport:
    """Body clearance of one trajectory."""

    frames: int
    within_margin_pct: float  # frames with clearance below the margin (%)
    inside_pct: float  # frames with an arm link more than DEEP_M inside the body (%)
    deepest_cm: float  # largest penetration (cm; 0 when nothing is inside)
    min_clearance_cm: float  # smallest clearance (cm; negative: inside)
    closest_links: tuple[str, str]  # the pair of the smallest clearance

    def row(self) -> str:
        """One table row: frames, % within margin, % inside, deepest, the closest links."""
        return (
            f"{self.frames:>7}{self.within_margin_pct:>12.1f}{self.inside_pct:>10.1f}"
            f"{self.deepest_cm:>12.1f}{self.min_clearance_cm:>16.2f}  "
            f"{' / '.join(self.closest_links)}"
        )


HEADER = (
    f"{'frames':>7}{'< margin %':>12}{'inside %':>10}{'deepest cm':>12}{'min clearance cm':>16}"
    "  closest links"
)


def check_trajectory(body: BodyModel, angles_rad: np.ndarray, margin_m: float) -> BodyReport:
    """Measure a (n_frames, n_joints) trajectory against the body (see the module text)."""
    angles = np.atleast_2d(np.asarray(angles_rad, dtype=np.float64))
    clearance = body.clearance(angles) if len(angles) else np.zeros(0)
    if len(clearance) == 0:
        return BodyReport(0, 0.0, 0.0, 0.0, float("inf"), ("", ""))
    worst = int(np.argmin(clearance))
    _, link_a, link_b = body.closest_pair(angles[worst])
    return BodyReport(
        frames=len(clearance),
        within_margin_pct=100.0 * float(np.mean(clearance < margin_m)),
        inside_pct=100.0 * float(np.mean(clearance < -DEEP_M)),
        deepest_cm=max(0.0, -100.0 * float(clearance[worst])),
        min_clearance_cm=100.0 * float(clearance[worst]),
        closest_links=(link_a, link_b),
    )


@dataclass(frozen=True)
class GlideReport:
    """Random start poses clear of the body, each left to glide to neutral (motion disabled)."""

    poses: int
    reached: int  # every joint within REACHED_RAD of neutral at the end
    worst_error_rad: float  # largest joint error of the worst pose at the end
    min_clearance_m: float  # closest any command came to the body on the way

    def row(self) -> str:
        """One line for ``audio2pose check-body --glides``."""
        return (
            f"{self.reached} of {self.poses} random start poses clear of the body reached "
            f"neutral; worst joint error left {self.worst_error_rad:.3f} rad; closest command "
            f"{self.min_clearance_m * 100:.2f} cm from the body"
        )


REACHED_RAD = 0.01  # a glide that ends this close to neutral (every joint) reached it


def check_glides(
    body: BodyModel, n_poses: int, seed: int, margin_m: float, seconds: float = 4.0
) -> GlideReport:
    """Start the motion filter at ``n_poses`` random poses clear of the body, disable motion.

    Each pose is drawn uniformly within the joint ranges (``numpy.random.default_rng(seed)``),
    kept only if its clearance is at least ``margin_m``; the filter (default settings, the body
    margin ``margin_m``) then glides it to neutral for ``seconds``. What the self-collision guard
    cannot go round shows as poses that do not reach neutral.
    """
    from audio2pose_ros.motion.filter import MotionFilter
    from audio2pose_ros.motion.filter_settings import MotionFilterSettings

    robot = body.robot
    rng = np.random.default_rng(seed)
    settings = MotionFilterSettings(body_margin_m=margin_m)
    reached, worst, closest = 0, 0.0, float("inf")
    for _ in range(n_poses):
        start = rng.uniform(robot.lower_rad, robot.upper_rad)
        while body.clearance(start) < margin_m:
            start = rng.uniform(robot.lower_rad, robot.upper_rad)
        filt = MotionFilter(robot, settings, start_pose_rad=start)
        filt.set_enabled(False)
        ticks = max(1, round(seconds / filt.period_s))
        poses = np.array([filt.tick(filt.period_s * (k + 1))[0].copy() for k in range(ticks)])
        error = float(np.abs(poses[-1] - filt.neutral_rad).max())
        reached += int(error <= REACHED_RAD)
        worst = max(worst, error)
        closest = min(closest, float(body.clearance(poses).min()))
    return GlideReport(n_poses, reached, worst, closest)
