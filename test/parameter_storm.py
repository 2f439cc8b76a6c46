"""A set_parameters storm from its own process: ``python parameter_storm.py NAME SECONDS V...``.

Keeps ``IN_FLIGHT`` requests to ``/motion_filter_node/set_parameters`` waiting for an answer,
setting parameter NAME to the values V in turn, for SECONDS after the service is found; prints
``answered refused`` at the end. Run beside a test, it storms the node while the test's own
process stays free to stream poses and record commands.
"""

from __future__ import annotations

import sys
import time

import rclpy
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters

IN_FLIGHT = 50


def main(name: str, seconds: float, values: list[float]) -> None:
    with rclpy.init():
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
        pending: list = []
        sent = answered = refused = 0
        print("storming", flush=True)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for future in [f for f in pending if f.done()]:
                pending.remove(future)
                answered += 1
                refused += not future.result().results[0].successful
            while len(pending) < IN_FLIGHT:
                pending.append(client.call_async(requests[sent % len(requests)]))
                sent += 1
            rclpy.spin_once(node, timeout_sec=0.001)
        print(answered, refused, flush=True)
        node.destroy_node()


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), [float(v) for v in sys.argv[3:]])
