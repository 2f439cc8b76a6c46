"""Every topic and service name of the node graph, defined once.

Nodes create these names relative (no leading slash), so a namespace (``ros2 launch ...
namespace:=pepper``) or a remap (``-r joint_angles:=/naoqi/joint_angles``) moves them, as ROS 2
conventions ask. Tools that talk to the graph from the root namespace (the runner, the player,
bags, benchmarks, tests) use :func:`absolute`. ``/diagnostics`` is absolute by convention: every
node of a robot reports to the one aggregator.

Name (type): publisher -> subscriber

- audio/audio, audio/audio_info (audio_common_msgs AudioData, AudioInfo latched): microphone ->
  features; or audio/audio (naoqi_bridge_msgs AudioBuffer): naoqi_driver -> features
- features (std_msgs Float32MultiArray): features -> inference
- voice_activity (std_msgs Bool): features -> filter
- raw_trajectory (trajectory_msgs JointTrajectory): inference -> filter
- joint_angles (naoqi_bridge_msgs JointAnglesWithSpeed): filter -> naoqi_driver
- joint_trajectory_controller/joint_trajectory (JointTrajectory): filter -> ros2_control
- commanded_joint_states (sensor_msgs JointState): filter -> robot_state_publisher, RViz
- joint_states (sensor_msgs JointState, measured): naoqi_driver -> filter
- head_target, head_offset (sensor_msgs JointState): perception -> filter
- enable, stop (std_msgs Bool, latched): operator -> filter
- emergency_stop, disable_motion (std_srvs Trigger, services of the filter): operator -> filter,
  a stop or a disable and nothing else (no flood of ``stop: false`` on the topic can displace
  it); released on the topics
- audio_out, audio_out_info (audio_common_msgs AudioData, AudioInfo latched): voice_out_node
  -> audio_common's audio_play (the operator's voice, held back to be heard with the motion)
- audio (naoqi_bridge_msgs AudioBuffer): the robot's microphones (naoqi_driver) -> voice_out_node,
  console
- camera/front/image_raw, camera/front/camera_info (sensor_msgs Image rgb8, CameraInfo): the
  robot's head camera (naoqi_driver) -> console
"""

from __future__ import annotations

AUDIO = "audio/audio"
AUDIO_INFO = "audio/audio_info"
FEATURES = "features"
VOICE_ACTIVITY = "voice_activity"
RAW_TRAJECTORY = "raw_trajectory"
JOINT_ANGLES = "joint_angles"
JOINT_TRAJECTORY = "joint_trajectory_controller/joint_trajectory"
COMMANDED_JOINT_STATES = "commanded_joint_states"
JOINT_STATES = "joint_states"
HEAD_TARGET = "head_target"
HEAD_OFFSET = "head_offset"
ENABLE = "enable"
STOP = "stop"
EMERGENCY_STOP = "emergency_stop"
DISABLE_MOTION = "disable_motion"
AUDIO_OUT = "audio_out"
AUDIO_OUT_INFO = "audio_out_info"
DIAGNOSTICS = "/diagnostics"
ROBOT_DESCRIPTION = "robot_description"
TF = "tf"
ROBOT_MICROPHONES = "audio"
CAMERA_IMAGE = "camera/front/image_raw"
CAMERA_INFO = "camera/front/camera_info"


def absolute(name: str) -> str:
    """The topic ``name`` resolves to in the root namespace (``features`` -> ``/features``)."""
    return name if name.startswith("/") else f"/{name}"
