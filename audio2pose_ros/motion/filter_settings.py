"""The motion filter's settings: every one declared once, as a node parameter with its range.

:class:`MotionFilterSettings` are the settings of
:class:`~audio2pose_ros.motion.filter.MotionFilter` (rate, jitter buffer, gate, smoothing, stop
behaviour, neutral glide, head composition, body margin); :data:`READ_ONLY_SETTINGS` those of them
and of the joint limits (:class:`~audio2pose_ros.motion.limits.LimitSettings`) that cannot change
while the filter runs. :class:`MotionFilterNodeSettings` are those of ``motion_filter_node``
itself (outputs and their rates, the measured topic, the start-up wait, the state file, the raw
stamps' bounds). The node declares them all as its parameters (with their descriptors), and the
parameter documentation is generated from them.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field

from audio2pose_ros import topics
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.motion.limits import LimitSettings
from audio2pose_ros.motion.style import StyleSettings
from audio2pose_ros.parameters import param, specs_of, validate_settings

SMOOTHING_METHODS = ("lowpass", "kalman", "none")
STOP_BEHAVIOURS = ("hold", "neutral")


@dataclass(frozen=True)
class MotionFilterSettings:
    """Settings of :class:`MotionFilter`, declared as node parameters (see ``param``).

    Defaults are the ones shipped in config/pepper.yaml. Fields marked read-only in their
    declaration are fixed at start-up; the others may change while the filter runs
    (:meth:`MotionFilter.update_settings`).

    Attributes:
        rate_hz: filter clock (Hz); seed 003 clocks commands at f_f = 100 Hz.
        smoothing: 'lowpass' (a Butterworth low-pass as the seed's offline smoother of section
            4.2.3, run causally; the default), 'kalman' (the seed's online filter, section
            4.4.2) or 'none'. The commanded motion of the shipped model is closer to the real
            with the low-pass (MODEL_CARD.md, "On the robot"): the seed's Kalman filter raises
            motion at 1 to 2 Hz by about 1.3 and drives the fastest of it into the
            acceleration limits.
        kalman_q: Kalman process noise (seed value 0.5).
        kalman_r: Kalman measurement noise (seed value 0.01).
        lowpass_cutoff_hz: cut-off of the causal low-pass, below rate_hz / 2 (default 3 Hz).
        lowpass_order: order of the causal low-pass (default 2). The seed's offline 4 Hz, 5th
            order, run forwards, delays the motion by 0.18 s (cross-correlation with the
            offline synthesis, lecture's held-out stretch); 3 Hz, 2nd order by 0.12 s, with
            commanded arms and hip as close to the lecturer's or closer (chosen on the
            lecture's training and validation stretches, not on the held-out one).
        watchdog_timeout_s: without poses for this long, glide to the neutral pose (s).
        silence_timeout_s: with the voice inactive for this long, glide to neutral (s).
        neutral_glide_s: duration of the glide to the neutral pose (s).
        stop_behaviour: on an emergency stop, 'hold' (brake and stay) or 'neutral' (glide).
        max_buffer_s: poses queued beyond this much motion are dropped, oldest first (s).
        backlog_window_s: when the buffer never ran empty after a tick during this whole window,
            the poses it never went below are skipped, so a standing backlog (latency) drains (s).
        head_target_weight: weight of an external head target against generated head motion.
        external_timeout_s: an external head target or offset counts for this long (s).
        outlier_tolerance_rad: slack of the input gate: how far a raw target or head target may
            lie outside its joint's range (it is clamped) and how much further than the
            velocity limit allows it may be from the recent track (rad). The default 0.3 rad
            passes the default model's largest frame-to-frame jump on the bundled speech (0.25
            rad beyond the velocity limit); a single accepted one-frame spike of 0.25 rad moves
            the command 0.023 rad through the low-pass and the limits (0.027 rad with the
            Kalman filter).
        max_head_offset_rad: largest head offset accepted per joint (rad); larger ones are
            rejected.
        max_points_per_message: poses of one message beyond this many are dropped and counted.
        body_margin_m: no command brings an arm closer than this to the robot's body or the
            other arm (m; :mod:`~audio2pose_ros.motion.body_guard`, the last stage).
        head_gain: deprecated, use ``StyleSettings(head_gain=...)`` (the node parameter keeps
            its name); when given, it sets the style's head size (with a DeprecationWarning).
        arms_gain: deprecated, as ``head_gain``.
        hip_gain: deprecated, as ``head_gain``.
    """

    rate_hz: float = field(
        default=100.0,
        metadata=param(
            "filter clock (seed 003: 100 Hz)",
            minimum=1.0,
            maximum=1000.0,
            read_only=True,
            unit="Hz",
        ),
    )
    smoothing: str = field(
        default="lowpass",
        metadata=param(
            "causal smoothing of the tracked pose", choices=SMOOTHING_METHODS, read_only=True
        ),
    )
    kalman_q: float = field(
        default=0.5,
        metadata=param(
            "Kalman process noise (seed 003: 0.5)", minimum=1e-9, maximum=1e9, read_only=True
        ),
    )
    kalman_r: float = field(
        default=0.01,
        metadata=param(
            "Kalman measurement noise (seed 003: 0.01)", minimum=1e-9, maximum=1e9, read_only=True
        ),
    )
    lowpass_cutoff_hz: float = field(
        default=3.0,
        metadata=param(
            "cut-off of the causal low-pass, below rate_hz / 2 (seed 003 offline: 4 Hz)",
            minimum=0.01,
            maximum=500.0,
            read_only=True,
            unit="Hz",
        ),
    )
    lowpass_order: int = field(
        default=2,
        metadata=param(
            "order of the causal low-pass (seed 003 offline: 5)",
            minimum=1,
            maximum=8,
            read_only=True,
        ),
    )
    watchdog_timeout_s: float = field(
        default=0.5,
        metadata=param(
            "no pose for this long: glide to the neutral pose", minimum=0.01, maximum=60.0, unit="s"
        ),
    )
    silence_timeout_s: float = field(
        default=1.0,
        metadata=param(
            "voice inactive for this long: glide to the neutral pose",
            minimum=0.01,
            maximum=3600.0,
            unit="s",
        ),
    )
    neutral_glide_s: float = field(
        default=1.0,
        metadata=param(
            "duration of the minimum-jerk glide to the neutral pose",
            minimum=0.05,
            maximum=60.0,
            unit="s",
        ),
    )
    stop_behaviour: str = field(
        default="hold",
        metadata=param(
            "on stop: hold (brake and stay) or neutral (glide to neutral)", choices=STOP_BEHAVIOURS
        ),
    )
    max_buffer_s: float = field(
        default=0.3,
        metadata=param(
            "jitter buffer bound: queued motion beyond this is dropped",
            minimum=0.01,
            maximum=10.0,
            read_only=True,
            unit="s",
        ),
    )
    backlog_window_s: float = field(
        default=0.2,
        metadata=param(
            "buffer never empty for this long: skip the standing backlog",
            minimum=0.01,
            maximum=10.0,
            read_only=True,
            unit="s",
        ),
    )
    head_target_weight: float = field(
        default=0.8,
        metadata=param(
            "weight of head_target against generated head motion", minimum=0.0, maximum=1.0
        ),
    )
    external_timeout_s: float = field(
        default=0.5,
        metadata=param(
            "head_target / head_offset count this long after a message",
            minimum=0.01,
            maximum=60.0,
            unit="s",
        ),
    )
    outlier_tolerance_rad: float = field(
        default=0.3,
        metadata=param(
            "input gate slack: targets up to this far outside a joint's range are clamped, "
            "further out rejected; targets further from the recent track than the velocity "
            "limit allows plus this are rejected",
            minimum=0.0,
            maximum=1.0,
            unit="rad",
        ),
    )
    max_head_offset_rad: float = field(
        default=0.5,
        metadata=param(
            "largest accepted head_offset per joint", minimum=0.0, maximum=1.0, unit="rad"
        ),
    )
    max_points_per_message: int = field(
        default=200,
        metadata=param(
            "poses of one raw_trajectory message beyond this many are dropped",
            minimum=1,
            maximum=10000,
        ),
    )

    body_margin_m: float = field(
        default=0.02,
        metadata=param(
            "no command brings an arm link closer than this to the torso, tablet, head, hip, "
            "pelvis or the other arm (the self-collision guard, applied last)",
            minimum=0.0,
            maximum=0.1,
            unit="m",
        ),
    )

    # Deprecated (the sizes are part of the style now): not node parameters here.
    head_gain: float | None = None
    arms_gain: float | None = None
    hip_gain: float | None = None

    def __post_init__(self) -> None:
        """Validate every field against its declaration, then the one cross-field rule.

        Raises:
            ConfigurationError: a value is refused; the message names it and the allowed range.
        """
        validate_settings(self)
        legacy = self.legacy_gains()
        if legacy:
            warnings.warn(
                f"MotionFilterSettings({', '.join(legacy)}=...) is deprecated: use "
                "StyleSettings (audio2pose_ros.motion.style); the node parameters keep their names",
                DeprecationWarning,
                stacklevel=3,
            )
            StyleSettings(**legacy)  # refused values fail here, as they did before
        if self.lowpass_cutoff_hz >= self.rate_hz / 2.0:
            raise ConfigurationError(
                f"parameter lowpass_cutoff_hz: value {self.lowpass_cutoff_hz!r} is out of range; "
                f"allowed: below rate_hz / 2 = {self.rate_hz / 2.0:g}"
            )

    def legacy_gains(self) -> dict[str, float]:
        """The deprecated ``<group>_gain`` fields that were given."""
        names = ("head_gain", "arms_gain", "hip_gain")
        return {name: getattr(self, name) for name in names if getattr(self, name) is not None}


LIMIT_SETTINGS = frozenset(f.name for f in dataclasses.fields(LimitSettings))
READ_ONLY_SETTINGS = tuple(
    spec.name
    for spec in (*specs_of(MotionFilterSettings), *specs_of(LimitSettings))
    if spec.read_only
)


@dataclass(frozen=True)
class MotionFilterNodeSettings:
    """Parameters of the node itself (the filter's are in MotionFilterSettings, LimitSettings).

    Attributes:
        robot_description: robot description YAML ('' = config/pepper_robot.yaml).
        joint_angles_speed: JointAnglesWithSpeed.speed, a fraction of the maximum speed in
            [0.01, 1] (naoqi's setAngles refuses 0); negative = velocity_fraction.
        joint_angles_rate_hz: rate of /joint_angles (0 = off); 50 Hz = one command per
            ALMotion 20 ms cycle.
        joint_trajectory_rate_hz: rate of joint_trajectory (0 = off); Pepper's ros2_control
            controller runs at 50 Hz.
        joint_states_rate_hz: rate of commanded_joint_states (0 = off).
        measured_joint_states_topic: the robot's measured joint states.
        startup_timeout_s: how long to wait quietly for a measured pose before saying why none
            started the filter (and, with ``start_without_measured_pose``, at least this long
            before starting without one: :mod:`audio2pose_ros.motion.start_pose`).
        start_without_measured_pose: start from the saved pose or neutral once no measured
            pose can still come (a robot that publishes no joint states, or no robot); False:
            wait for the measured pose, however long, commanding nothing.
        state_file: where the last commanded pose and a stop are kept ('' = the default).
        state_save_period_s: how often the state file is rewritten while the pose changes.
        max_stamp_future_s: raw trajectories stamped further ahead of the clock are rejected.
        max_stamp_age_s: raw trajectories stamped further behind the clock are rejected.
    """

    robot_description: str = field(
        default="",
        metadata=param("robot description YAML ('' = config/pepper_robot.yaml)", read_only=True),
    )
    joint_angles_speed: float = field(
        default=-1.0,
        metadata=param(
            "JointAnglesWithSpeed.speed (fraction of max velocity); negative = velocity_fraction",
            minimum=-1.0,
            maximum=1.0,
            excluded=(0.0, 0.01),  # the robot refuses 0 and would crawl below velocity_fraction's
        ),
    )
    joint_angles_rate_hz: float = field(
        default=50.0,
        metadata=param(
            "rate of joint_angles, at most rate_hz (0 = off; 50 = one per ALMotion 20 ms cycle)",
            minimum=0.0,
            maximum=1000.0,
            read_only=True,
            unit="Hz",
        ),
    )
    joint_trajectory_rate_hz: float = field(
        default=50.0,
        metadata=param(
            "rate of joint_trajectory_controller/joint_trajectory, at most rate_hz (0 = off)",
            minimum=0.0,
            maximum=1000.0,
            read_only=True,
            unit="Hz",
        ),
    )
    joint_states_rate_hz: float = field(
        default=50.0,
        metadata=param(
            "rate of commanded_joint_states, at most rate_hz (0 = off)",
            minimum=0.0,
            maximum=1000.0,
            read_only=True,
            unit="Hz",
        ),
    )
    measured_joint_states_topic: str = field(
        default=topics.JOINT_STATES,
        metadata=param("the robot's measured joint states (naoqi_driver)", read_only=True),
    )
    startup_timeout_s: float = field(
        default=1.0,
        metadata=param(
            "wait this long for a measured pose before saying why none came (with "
            "start_without_measured_pose, before starting from the saved pose or neutral)",
            minimum=0.0,
            maximum=60.0,
            read_only=True,
            unit="s",
        ),
    )
    start_without_measured_pose: bool = field(
        default=False,
        metadata=param(
            "for a robot that publishes no joint states (or no robot): start from the saved "
            "pose or neutral once no measured pose can still come; false: wait for the measured "
            "pose, however long, commanding nothing",
            read_only=True,
        ),
    )
    state_file: str = field(
        default="",
        metadata=param(
            "file keeping the last commanded pose and a stop across restarts "
            "('' = $ROS_HOME/audio2pose_ros/<node>.json)",
            read_only=True,
        ),
    )
    state_save_period_s: float = field(
        default=0.5,
        metadata=param(
            "the state file is rewritten this often while the pose changes",
            minimum=0.05,
            maximum=60.0,
            read_only=True,
            unit="s",
        ),
    )
    max_stamp_future_s: float = field(
        default=0.5,
        metadata=param(
            "raw_trajectory stamped further ahead of the node clock is rejected",
            minimum=0.0,
            maximum=3600.0,
            unit="s",
        ),
    )
    max_stamp_age_s: float = field(
        default=5.0,
        metadata=param(
            "raw_trajectory stamped further behind the node clock is rejected",
            minimum=0.01,
            maximum=3600.0,
            unit="s",
        ),
    )

    def __post_init__(self) -> None:
        """Validate every field against its declaration."""
        validate_settings(self)
