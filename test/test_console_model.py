"""console_node sets the model the inference node runs, over the nodes' parameter services.

The real console, inference and motion filter nodes in one process, their services called over
DDS: a personal folder is run (the inference node's model_path) and given back; a folder whose
model the inference node refuses leaves the model running, the page is told why, and the filter
gets the fallback style (the style alone, fitted to the model that keeps running).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest
from rclpy.executors import SingleThreadedExecutor

from audio2pose_ros.ros.player import rclpy_session

pytestmark = [pytest.mark.ros]


def test_when_the_console_sets_a_personal_model_expect_it_run_or_refused_with_the_fallback(
    tmp_path,
):
    from audio2pose_ros.ros.nodes.console_node import ConsoleNode
    from audio2pose_ros.ros.nodes.inference_node import InferenceNode
    from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode

    good, bad = tmp_path / "me", tmp_path / "broken"
    for folder in (good, bad):
        folder.mkdir()
        (folder / "style.yaml").write_text("name: me\n", encoding="utf-8")
    (bad / "model.safetensors").write_bytes(b"\x00" * 64)  # not a checkpoint
    args = ["--ros-args", "-p", "port:=0", "-p", f"state_file:={tmp_path / 'filter.json'}"]
    with rclpy_session(args):
        inference, motion_filter = InferenceNode(), MotionFilterNode()
        console = ConsoleNode()
        executor = SingleThreadedExecutor()
        for node in (inference, motion_filter, console):
            executor.add_node(node)

        def spin_until(done: Callable[[], bool], what: str) -> None:
            end = time.monotonic() + 30.0  # a bound on a hang only
            while not done():
                assert time.monotonic() < end, f"never: {what}"
                executor.spin_once(timeout_sec=0.05)

        def problem() -> str:
            return str(console.status()["style_problem"])

        try:
            spin_until(
                lambda: all(
                    client.service_is_ready()
                    for client in (
                        console.model_set_client,
                        console.model_get_client,
                        console.set_client,
                        console.get_client,
                    )
                ),
                "the services",
            )
            console.set_model(str(bad), fallback={"head_gain": 0.7})
            spin_until(lambda: "refused" in problem(), "the refusal shown")
            assert "not an audio2pose checkpoint" in problem()
            spin_until(
                lambda: (console.style_values or {}).get("head_gain") == 0.7, "the fallback style"
            )
            assert inference.parameters["model_path"] == ""  # the running model goes on
            assert inference.incoming is None
            console.set_model(str(good), fallback={"head_gain": 0.5})
            spin_until(lambda: console.status()["model_path"] == str(good), "the folder read back")
            assert inference.parameters["model_path"] == str(good)
            assert problem() == ""
            assert console.style_values["head_gain"] == 0.7  # accepted: no fallback
            console.set_model(None)  # back to the model it started with
            spin_until(lambda: console.status()["model_path"] == "", "its own model back")
            assert inference.parameters["model_path"] == ""
        finally:
            for node in (console, motion_filter, inference):
                executor.remove_node(node)
                node.destroy_node()
