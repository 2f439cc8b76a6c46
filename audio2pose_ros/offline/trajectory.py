"""Joint trajectories to look at: synthesized, recorded in a bag, or a data set's ground truth.

A :class:`Trajectory` is timed joint angles (seconds, radians) with labels; renderers and bag
writers sample it at their own rate.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.style import StyleSettings
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.topics import (
    AUDIO,
    COMMANDED_JOINT_STATES,
    JOINT_ANGLES,
    JOINT_STATES,
    absolute,
)

# Topics bag_trajectory reads the commanded pose from, in order of preference, with their type.
POSE_TOPICS = {
    absolute(COMMANDED_JOINT_STATES): "sensor_msgs/msg/JointState",
    absolute(JOINT_STATES): "sensor_msgs/msg/JointState",
    absolute(JOINT_ANGLES): "naoqi_bridge_msgs/msg/JointAnglesWithSpeed",
}


class TrajectoryError(InputError):
    """A trajectory source holds no usable joint angles."""


@dataclass(frozen=True)
class Trajectory:
    """Joint angles over time.

    Attributes:
        label: what produced it (shown in videos), e.g. a checkpoint's file name.
        times_s: (T,) increasing sample times from the start of the audio.
        angles_rad: (T, J) angles in ``joint_names`` order.
        joint_names: the J joint names.

    """

    label: str
    times_s: np.ndarray
    angles_rad: np.ndarray
    joint_names: tuple[str, ...]

    def __post_init__(self) -> None:
        """Reject empty or misshapen trajectories."""
        shape = (len(self.times_s), len(self.joint_names))
        if self.angles_rad.shape != shape or shape[0] == 0:
            raise TrajectoryError(
                f"{self.label}: angles of shape {self.angles_rad.shape}, expected {shape}, T > 0"
            )

    @property
    def duration_s(self) -> float:
        """Time of the last sample."""
        return float(self.times_s[-1])

    def sample(self, times_s: np.ndarray) -> np.ndarray:
        """Linearly interpolated angles at ``times_s``: (len(times_s), J); held at both ends."""
        return np.stack(
            [np.interp(times_s, self.times_s, column) for column in self.angles_rad.T], axis=1
        )


def synthesized_trajectory(
    checkpoint_path: str | Path,
    signal_16k: np.ndarray,
    robot: RobotDescription,
    style: StyleSettings | None = None,
    label: str = "",
    seed: int = 0,
) -> Trajectory:
    """Offline synthesis (seed 003 section 4.4.1) of a 16 kHz utterance with a checkpoint.

    ``style`` is applied as the live filter applies it; ``label`` names the trajectory
    (default: the checkpoint's file stem); ``seed`` is a sampling model's noise seed.
    """
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.offline.synthesis import synthesize

    checkpoint = load_checkpoint(checkpoint_path, robot=robot)
    times_s, angles_rad = synthesize(checkpoint, signal_16k, seed=seed, style=style)
    return Trajectory(label or Path(checkpoint_path).stem, times_s, angles_rad, robot.names)


def clip_trajectory(
    dataset_dir: str | Path, clip_id: str, robot: RobotDescription
) -> tuple[Trajectory, np.ndarray]:
    """A data set clip's recorded motion (unobserved angles at neutral) and its 16 kHz audio."""
    from audio2pose_ros.data.dataset import Dataset
    from audio2pose_ros.timebase import FRAME_RATE_HZ

    clip = Dataset.open(dataset_dir, robot).load(clip_id)
    angles_rad = np.where(clip.mask, clip.angles_rad, robot.neutral_rad)
    times_s = np.arange(clip.n_frames) / FRAME_RATE_HZ
    return Trajectory(f"ground truth {clip_id}", times_s, angles_rad, robot.names), clip.audio


def bag_trajectory(bag_path: str | Path, robot: RobotDescription) -> Trajectory:
    """Joint angles recorded by ``audio2pose run --record`` (or any rosbag2 with these topics).

    The first of :data:`POSE_TOPICS` the bag holds with the expected type is used:
    /commanded_joint_states or /joint_states (sensor_msgs/JointState), else /joint_angles
    (naoqi_bridge_msgs/JointAnglesWithSpeed). Times count from the first audio message on
    /audio/audio when the bag has one (the recorder stores the audio it played), else from the
    first joint message. Joints a message leaves out keep their previous (initially neutral)
    value; a non-finite value is ignored the same way.

    Raises:
        TrajectoryError: the bag has none of the topics or no messages on it.
        BagError: the bag cannot be read or holds invalid CDR.

    """
    from audio2pose_ros.data.bag import bag_topics, deserialize, read_messages, typestore

    present = bag_topics(bag_path)
    topic = next((t for t in POSE_TOPICS if present.get(t) == POSE_TOPICS[t]), None)
    if topic is None:
        raise TrajectoryError(
            f"{bag_path}: none of {sorted(POSE_TOPICS)} with its type (topics: {sorted(present)})"
        )
    start_ns = next((m.timestamp_ns for m in read_messages(bag_path, [absolute(AUDIO)])), None)
    store = typestore()
    index = {name: i for i, name in enumerate(robot.names)}
    current = robot.neutral_rad.copy()
    stamps_ns, rows = [], []
    for message in read_messages(bag_path, [topic]):
        msg = deserialize(store, message, bag_path)
        names, values = (
            (msg.joint_names, msg.joint_angles)
            if topic == absolute(JOINT_ANGLES)
            else (msg.name, msg.position)
        )
        for name, value in zip(names, values, strict=False):
            if name in index and np.isfinite(value):
                current[index[name]] = value
        stamps_ns.append(message.timestamp_ns)
        rows.append(current.copy())
    if not rows:
        raise TrajectoryError(f"{bag_path}: no messages on {topic}")
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    times_s = (stamps - (start_ns if start_ns is not None else stamps[0])) * 1e-9
    return Trajectory(f"bag {Path(bag_path).name}", times_s, np.asarray(rows), robot.names)


@dataclass(frozen=True)
class Execution:
    """What the simulated Pepper did with a commanded trajectory.

    Attributes:
        trajectory: the measured joint angles at the command times.
        error_rad: (T,) largest joint error, commanded vs measured, at each command time.
        self_collision_steps: simulation steps with an arm inside the body.
    """

    trajectory: Trajectory
    error_rad: np.ndarray
    self_collision_steps: int


def executed_trajectory(commanded: Trajectory, robot: RobotDescription, speed: float) -> Execution:
    """Send every sample of ``commanded`` to a simulated Pepper as naoqi_driver would, and measure.

    Each sample becomes one ``setAngles`` call (ALMotion's meaning: the new target of every
    joint, reached no faster than ``speed`` x its velocity limit) at its time, the way the motion
    filter's ``JointAnglesWithSpeed`` commands reach the robot; the simulated robot
    (:class:`~audio2pose_ros.robot.simulated_pepper.SimulatedPepper`, pybullet) starts at rest at
    the first commanded pose. Its measured pose at each command time is the executed trajectory.
    """
    from audio2pose_ros.robot.simulated_pepper import STEP_S, SimulatedPepper

    names = list(robot.names)
    missing = [name for name in names if name not in commanded.joint_names]
    if missing:
        raise TrajectoryError(f"{commanded.label}: no angles for joints {missing}")
    angles = commanded.angles_rad[:, [commanded.joint_names.index(name) for name in names]]
    sim = SimulatedPepper(robot)
    try:
        sim.set_angles(names, angles[0], 1.0)
        sim.step(2.0)  # settled at the first pose before the clock starts
        start_s, start_steps = sim.time_s, sim.counts.self_collision_steps
        measured = np.empty_like(angles)
        for k, (t, pose) in enumerate(zip(commanded.times_s, angles, strict=True)):
            while sim.time_s - start_s < t - commanded.times_s[0] - 0.5 * STEP_S:
                sim.step(STEP_S)
            measured[k] = sim.measured()[0]
            sim.set_angles(names, pose, speed)
        steps = sim.counts.self_collision_steps - start_steps
    finally:
        sim.close()
    executed = Trajectory(
        f"executed (simulated Pepper): {commanded.label}",
        commanded.times_s.copy(),
        measured,
        tuple(names),
    )
    return Execution(executed, np.abs(measured - angles).max(axis=1), steps)
