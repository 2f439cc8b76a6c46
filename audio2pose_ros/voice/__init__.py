"""ROS-free: the operator's voice out of the robot, held back to be heard with the motion.

- :mod:`~audio2pose_ros.voice.framing`: ALAudioDevice's format (16-bit interleaved stereo, at
  most 16384 frames a call, its output rates) and naoqi_driver's microphone format;
- :mod:`~audio2pose_ros.voice.delay`: the delay line, the model of the loudspeaker's queue, and
  the simulated Pepper's delayed joint commands;
- :mod:`~audio2pose_ros.voice.lag`: lags between stamped signals (motion, loudness) and the
  pairing of audio chunks with the poses made from them;
- :mod:`~audio2pose_ros.voice.sync`: the three measured latencies and the voice's delay;
- :mod:`~audio2pose_ros.voice.offset`: the voice-to-motion offset judged from what the robot
  reports;
- :mod:`~audio2pose_ros.voice.naoqi`: the link to NAOqi's ALAudioDevice over ``qi`` (a thread,
  a bounded queue, reconnection);
- :mod:`~audio2pose_ros.voice.robot_double`: the robot's side for the simulated Pepper (a fake
  ALAudioDevice served through real libqi, loudspeaker, microphones).
"""
