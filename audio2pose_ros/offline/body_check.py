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
