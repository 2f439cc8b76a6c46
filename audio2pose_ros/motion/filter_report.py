"""The motion filter's figures for /diagnostics, read from its status objects (ROS-free).

``motion_filter_node`` publishes these as the key/values of its DiagnosticStatus, beside what
only the node knows (messages taken and dropped at its subscriptions, ticks, service requests,
where it started). The keys are the names users and tests read: changing one is a change of the
node's interface. Counters count since start. The raw messages' figures are
:meth:`~audio2pose_ros.motion.raw_intake.RawIntake.values`, the measured joint states'
:meth:`~audio2pose_ros.motion.measured_states.MeasuredStates.values`.
"""

from __future__ import annotations

import numpy as np

from audio2pose_ros.motion.filter import MotionFilter


class FilterReport:
    """The figures of one filter; the input rate counts the poses since the previous report."""

    def __init__(self, filt: MotionFilter, now_s: float) -> None:
        """Report on ``filt``; the first input rate counts from ``now_s`` (monotonic clock)."""
        self.filter = filt
        self._poses_at_last_report = 0
        self._last_report_s = now_s

    def values(self, now_s: float) -> dict[str, object]:
        """Poses and what happened to them, mode, limiter and body guard activity, health."""
        filt = self.filter
        status, counts, guard = filt.status, filt.limiter.counts, filt.body_guard.status
        input_rate_hz = (status.received - self._poses_at_last_report) / max(
            now_s - self._last_report_s, 1e-3
        )
        self._poses_at_last_report, self._last_report_s = status.received, now_s
        position, robot = filt.position_rad, filt.robot
        return {
            "poses_received": status.received,
            "poses_rejected": status.rejected,
            "poses_out_of_range": status.out_of_range,
            "poses_unreachable": status.implausible,
            "poses_truncated": status.truncated,
            "poses_dropped": status.dropped,
            "approaches": filt.approach.count,
            "head_inputs_rejected": status.external_rejected,
            "buffer_underruns": status.underruns,
            "poses_skipped_backlog": status.skipped,
            "buffered_poses": status.buffered,
            "mode": status.mode,
            "enabled": status.enabled,
            "stopped": status.stopped,
            "voice_active": status.voice_active,
            "head_target_active": status.head_target_active,
            "input_rate_hz": f"{input_rate_hz:.1f}",
            "position_limit_hits": counts.position,
            "velocity_limit_hits": counts.velocity,
            "acceleration_limit_hits": counts.acceleration,
            "gaps": status.gaps,
            "filter_faults": status.faults,
            "body_guard_interventions": guard.interventions,
            "body_guard_lead_out_steps": guard.lead_out_steps,
            "body_guard_holds": guard.holds,
            "body_clearance_cm": f"{guard.clearance_m * 100.0:.1f}",
            "body_closest_links": " / ".join(guard.links),
            # false: the command passed on the guard's travel bound without a query, and the
            # clearance is that bound (at least the margin; the true one may be larger)
            "body_clearance_exact": guard.clearance_exact,
            "body_guard_bound_checks": guard.bound_checks,
            "command_finite_and_in_limits": bool(
                np.isfinite(position).all()
                and np.all(position >= robot.lower_rad)
                and np.all(position <= robot.upper_rad)
            ),
        }
