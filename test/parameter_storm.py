"""A set_parameters storm from its own process: ``python parameter_storm.py NAME SECONDS V...``.

Keeps ``IN_FLIGHT`` requests to ``/motion_filter_node/set_parameters`` waiting for an answer,
setting parameter NAME to the values V in turn, for SECONDS after the service is found; prints
``answered refused`` at the end. Run beside a test, it storms the node while the test's own
process stays free to stream poses and record commands. It sleeps until an answer comes and
sends the next request from the answer's callback, so its own CPU use follows the node's
answers instead of polling.
"""

from __future__ import annotations

import sys
import time

import rclpy
import rclpy.task
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters

from audio2pose_ros.ros.player import rclpy_session

IN_FLIGHT = 50


def main(name: str, seconds: float, values: list[float]) -> None:
    with rclpy_session():
        node = rclpy.create_node("parameter_storm")
        client = node.create_client(SetParameters, "/motion_filter_node/set_parameters")
        if not client.wait_for_service(timeout_sec=30):
            raise SystemExit("no set_parameters service")
        requests = [
            SetParameters.Request(
                parameters=[
                    Parameter(
                        name=name,
                        value=ParameterValue(
                            type=ParameterType.PARAMETER_DOUBLE, double_value=value
                        ),
                    )
                ]
            )
            for value in values
        ]
        sent = answered = refused = 0

        def send() -> None:
            nonlocal sent
            future = client.call_async(requests[sent % len(requests)])
            future.add_done_callback(answer)
            sent += 1

        def answer(future: rclpy.task.Future) -> None:
            nonlocal answered, refused
            answered += 1
            refused += not future.result().results[0].successful
            if time.monotonic() < end:
                send()  # another one in its place: IN_FLIGHT waiting at any time

        print("storming", flush=True)
        end = time.monotonic() + seconds
        for _ in range(IN_FLIGHT):
            send()
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        print(answered, refused, flush=True)
        node.destroy_node()


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), [float(v) for v in sys.argv[3:]])
