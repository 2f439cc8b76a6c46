"""motion_filter_node: raw poses in; smooth, limited commands for naoqi, ros2_control, viewers out.

Subscriptions:
    raw_trajectory (trajectory_msgs/JointTrajectory): poses from inference_node (any joint order).
    voice_activity (std_msgs/Bool): from audio_features_node; silence -> glide to neutral.
    enable (std_msgs/Bool, latched): False -> glide to neutral and ignore generated motion.
    stop (std_msgs/Bool, latched): True -> emergency stop ('hold': brake and stay; 'neutral').
    head_target (sensor_msgs/JointState): absolute HeadYaw/HeadPitch targets, e.g. a look-at.
    head_offset (sensor_msgs/JointState): HeadYaw/HeadPitch offsets added to the head motion.
Publications:
    joint_angles (naoqi_bridge_msgs/JointAnglesWithSpeed): for naoqi_driver (absolute angles).
    joint_trajectory_controller/joint_trajectory (trajectory_msgs/JointTrajectory): one point,
        for ros2_control's joint_trajectory_controller.
    joint_states (sensor_msgs/JointState): the commanded pose, for robot_state_publisher / RViz.
    /diagnostics (diagnostic_msgs/DiagnosticArray)
Parameters (defaults in config/pepper.yaml; see MotionFilterSettings and LimitSettings):
    robot_description, rate_hz, smoothing, kalman_q, kalman_r, lowpass_cutoff_hz,
    watchdog_timeout_s, silence_timeout_s, neutral_glide_s, stop_behaviour, max_buffer_s,
    head_gain, arms_gain, hip_gain, head_target_weight, external_timeout_s,
    position_margin_rad, velocity_fraction, acceleration_fraction,
    joint_angles_speed (-1 = velocity_fraction), joint_angles_rate_hz,
    joint_trajectory_rate_hz, joint_states_rate_hz (0 disables an output).

Every command passes the joint limiter last. Malformed input is dropped with a warning; without
input the robot glides to the neutral pose.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.motion.filter import MotionFilter, MotionFilterSettings
from audio2pose_ros.motion.limits import LimitSettings
from audio2pose_ros.nodes.common import (
    DIAGNOSTICS_PERIOD_S,
    LATCHED_QOS,
    STREAM_QOS,
    StartupError,
    diagnostic_array,
    run_node,
    trajectory_msg,
    trajectory_positions,
)
from audio2pose_ros.robot import load_robot

WARN_THROTTLE_S = 5.0
MIN_TICK_SPACING = 0.1  # of a period: an arriving pose is commanded at once if the last tick
# is at least this long ago (keeps the command rate bounded and dt meaningful for the limits)


class MotionFilterNode(Node):
    """Pace, smooth and limit poses; publish them in three message types."""

    def __init__(self) -> None:
        """Declare parameters into the core settings, build the filter, wire topics and timers."""
        super().__init__("motion_filter_node")
        try:
            self.robot = load_robot(self.declare_parameter("robot_description", "").value)
            settings = MotionFilterSettings(**self._declare_from(MotionFilterSettings()))
            limits = LimitSettings(**self._declare_from(LimitSettings()))
            self.filter = MotionFilter(self.robot, settings, limits)
        except (OSError, ValueError) as exc:
            raise StartupError(str(exc)) from None
        speed = self.declare_parameter("joint_angles_speed", -1.0).value
        self.speed = limits.velocity_fraction if speed < 0 else min(float(speed), 1.0)
        self.input_messages = 0
        self.dropped_messages = 0
        self.latency_s = 0.0
        self.last_stamp_s = 0.0
        self.stale_messages = 0
        self.poses_at_last_report = 0
        self.last_problem = ""

        self.create_subscription(JointTrajectory, "raw_trajectory", self.on_raw, STREAM_QOS)
        self.create_subscription(Bool, "voice_activity", self.on_voice, STREAM_QOS)
        self.create_subscription(Bool, "enable", self.on_enable, LATCHED_QOS)
        self.create_subscription(Bool, "stop", self.on_stop, LATCHED_QOS)
        self.create_subscription(JointState, "head_target", self.on_head_target, 10)
        self.create_subscription(JointState, "head_offset", self.on_head_offset, 10)
        self.period_ns = round(self.filter.period_s * 1e9)
        self.tick_timer = self.create_timer(self.filter.period_s, self.on_timer)
        self.last_tick_s = -1.0
        self.last_tick_starved = True
        outputs = {
            "joint_angles": (JointAnglesWithSpeed, "joint_angles", self.publish_joint_angles),
            "joint_trajectory": (
                JointTrajectory,
                "joint_trajectory_controller/joint_trajectory",
                self.publish_joint_trajectory,
            ),
            "joint_states": (JointState, "joint_states", self.publish_joint_states),
        }
        # One timer: every output is published right after the tick that computed it, every
        # n-th tick for a lower rate (one rclpy timer callback costs far more than a tick).
        self.publishers_by_output = {}
        self.outputs: list[tuple[int, Callable[[], None]]] = []
        for key, (msg_type, topic, callback) in outputs.items():
            rate_hz = float(self.declare_parameter(f"{key}_rate_hz", settings.rate_hz).value)
            if rate_hz > 0:
                self.publishers_by_output[key] = self.create_publisher(msg_type, topic, 10)
                self.outputs.append((max(1, round(settings.rate_hz / rate_hz)), callback))
        self.ticks = 0
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)
        self.get_logger().info(
            f"{self.robot.n_joints} joints at {settings.rate_hz:.0f} Hz, {settings.smoothing} "
            f"smoothing, outputs: {', '.join(self.publishers_by_output) or 'none'}"
        )

    def _declare_from(self, defaults: object) -> dict[str, object]:
        """Declare one parameter per dataclass field, with the dataclass default."""
        fields = type(defaults).__dataclass_fields__  # type: ignore[attr-defined]
        return {
            name: self.declare_parameter(name, getattr(defaults, name)).value for name in fields
        }

    def now_s(self) -> float:
        """Node clock in seconds."""
        return self.get_clock().now().nanoseconds * 1e-9

    def on_raw(self, msg: JointTrajectory) -> None:
        """Queue the poses of one raw trajectory message."""
        self.input_messages += 1
        try:
            poses = trajectory_positions(msg, self.robot.names)
        except ValueError as exc:
            self.dropped_messages += 1
            self.last_problem = f"raw trajectory dropped: {exc}"
            self.get_logger().warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)
            return
        now = self.now_s()
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if stamp > 0:
            if stamp <= self.last_stamp_s:  # a duplicate or a late, reordered message
                self.stale_messages += 1
                self.last_problem = "duplicated or out-of-order raw trajectory dropped"
                self.get_logger().warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)
                return
            self.last_stamp_s = stamp
            self.latency_s = now - stamp
        was_waiting = self.filter.buffered == 0
        arrival_s = time.monotonic()
        if self.filter.push(poses, arrival_s) < len(poses):
            self.last_problem = "poses with NaN/inf dropped"
            self.get_logger().warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)
        # The clock follows the input: a pose that finds the buffer empty is commanded at once
        # (if the last tick is MIN_TICK_SPACING periods ago, or had no pose to command), and the
        # timer then waits 1.5 periods, or one if poses remain queued. A steady stream is served
        # on arrival; the timer ticks when input is late or comes several poses at a time.
        spaced = arrival_s - self.last_tick_s >= MIN_TICK_SPACING * self.filter.period_s
        if was_waiting and (spaced or self.last_tick_starved):
            self.on_tick()
            queued = self.filter.buffered > 0
            self.tick_timer.timer_period_ns = self.period_ns if queued else self.period_ns * 3 // 2
            self.tick_timer.reset()

    def on_voice(self, msg: Bool) -> None:
        """Voice activity from the features node."""
        self.filter.set_voice_active(msg.data, time.monotonic())

    def on_enable(self, msg: Bool) -> None:
        """Enable or disable generated motion."""
        self.filter.set_enabled(msg.data)
        self.get_logger().info("enabled" if msg.data else "disabled: gliding to neutral")

    def on_stop(self, msg: Bool) -> None:
        """Emergency stop on / off."""
        self.filter.set_stop(msg.data)
        if msg.data:
            self.get_logger().warning(f"STOP ({self.filter.settings.stop_behaviour})")
        else:
            self.get_logger().info("stop released")

    def _head_values(self, msg: JointState) -> dict[str, float]:
        if len(msg.name) != len(msg.position):
            raise ValueError(f"{len(msg.name)} names for {len(msg.position)} positions")
        return dict(zip(msg.name, (float(p) for p in msg.position), strict=True))

    def on_head_target(self, msg: JointState) -> None:
        """Absolute head target (e.g. a face tracker's look-at)."""
        try:
            self.filter.set_head_target(self._head_values(msg), time.monotonic())
        except ValueError as exc:
            self.last_problem = f"head_target ignored: {exc}"
            self.get_logger().warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)

    def on_head_offset(self, msg: JointState) -> None:
        """Head offset added to the generated head motion."""
        try:
            self.filter.set_head_offset(self._head_values(msg), time.monotonic())
        except ValueError as exc:
            self.last_problem = f"head_offset ignored: {exc}"
            self.get_logger().warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)

    def on_timer(self) -> None:
        """The fallback clock: tick, and return to the nominal period."""
        if self.tick_timer.timer_period_ns != self.period_ns:
            self.tick_timer.timer_period_ns = self.period_ns
        self.on_tick()

    def on_tick(self) -> None:
        """Advance the filter by one period and publish the outputs due at this tick."""
        self.last_tick_s = time.monotonic()
        underruns = self.filter.status.underruns
        self.filter.tick(self.last_tick_s)
        self.last_tick_starved = self.filter.status.underruns > underruns
        for every, publish in self.outputs:
            if self.ticks % every == 0:
                publish()
        self.ticks += 1

    def publish_joint_angles(self) -> None:
        """naoqi_driver command: absolute angles at ``speed`` fraction of max velocity."""
        msg = JointAnglesWithSpeed()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.joint_names = list(self.robot.names)
        msg.joint_angles = [float(v) for v in self.filter.position_rad]
        msg.speed = float(self.speed)
        msg.relative = 0
        self.publishers_by_output["joint_angles"].publish(msg)

    def publish_joint_trajectory(self) -> None:
        """ros2_control command: one point, one filter period ahead."""
        msg = trajectory_msg(
            self.robot.names,
            self.filter.position_rad[None, :],
            self.filter.period_s,
            self.filter.velocity_rad_s[None, :],
        )
        msg.header.stamp = self.get_clock().now().to_msg()
        self.publishers_by_output["joint_trajectory"].publish(msg)

    def publish_joint_states(self) -> None:
        """The commanded pose as a JointState (for robot_state_publisher and viewers)."""
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = list(self.robot.names)
        msg.position = [float(v) for v in self.filter.position_rad]
        msg.velocity = [float(v) for v in self.filter.velocity_rad_s]
        self.publishers_by_output["joint_states"].publish(msg)

    def publish_diagnostics(self) -> None:
        """Input rate and counters, latency, mode, limiter activity."""
        status, counts = self.filter.status, self.filter.limiter.counts
        input_rate_hz = (status.received - self.poses_at_last_report) / DIAGNOSTICS_PERIOD_S
        self.poses_at_last_report = status.received
        level = DiagnosticStatus.OK
        if self.dropped_messages or status.rejected or status.stopped:
            level = DiagnosticStatus.WARN
        self.diagnostics_pub.publish(
            diagnostic_array(
                self,
                level,
                status.mode + (f"; {self.last_problem}" if self.last_problem else ""),
                {
                    "input_messages": self.input_messages,
                    "dropped_messages": self.dropped_messages,
                    "stale_messages_dropped": self.stale_messages,
                    "poses_received": status.received,
                    "poses_rejected": status.rejected,
                    "poses_dropped": status.dropped,
                    "buffer_underruns": status.underruns,
                    "poses_skipped_backlog": status.skipped,
                    "buffered_poses": status.buffered,
                    "input_latency_ms": f"{self.latency_s * 1e3:.2f}",
                    "mode": status.mode,
                    "enabled": status.enabled,
                    "stopped": status.stopped,
                    "voice_active": status.voice_active,
                    "head_target_active": status.head_target_active,
                    "input_rate_hz": f"{input_rate_hz:.1f}",
                    "position_limit_hits": counts.position,
                    "velocity_limit_hits": counts.velocity,
                    "acceleration_limit_hits": counts.acceleration,
                },
            )
        )


def main(args: list[str] | None = None) -> None:
    """Run the node until shutdown."""
    run_node(MotionFilterNode, "motion_filter_node", args)


if __name__ == "__main__":
    main()
