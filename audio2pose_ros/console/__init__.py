"""The operator's web console, without ROS: settings, access, browser messages, floor, latency.

The console is a web page and a WebSocket served by ``console_node``: the operator talks into
the browser's microphone, sees the robot in 3D, stops it and sets the gesture amplitude. This
package holds everything that decides what the console does, so that it can be tested without a
middleware; ``audio2pose_ros.ros.nodes.console_node`` only connects it to topics and services.

- :mod:`~audio2pose_ros.console.settings`: the node's parameters, checked as one (a network bind
  needs a token and a certificate);
- :mod:`~audio2pose_ros.console.access`: tokens, loopback binds, Host and Origin checks;
- :mod:`~audio2pose_ros.console.protocol`: what the browser may send (size, type, rate) and what
  it is sent;
- :mod:`~audio2pose_ros.console.floor`: one voice at a time;
- :mod:`~audio2pose_ros.console.latency`: the operator's voice to the robot's command;
- :mod:`~audio2pose_ros.console.voice_status`: the voice out of the robot as the page shows it
  (mute, the three latencies and the offset);
- :mod:`~audio2pose_ros.console.server`: the HTTP and WebSocket server (aiohttp) around them.
"""
