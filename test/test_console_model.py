"""console_node sets the model the inference node runs, over the nodes' parameter services.

The real console, inference and motion filter nodes in one process, their services called over
DDS: a personal folder is run (the inference node's model_path) and given back; a folder whose
model the inference node refuses leaves the model running, the page is told why, and the filter
gets the fallback style (the style alone, fitted to the model that keeps running). With the graph
as supervised processes, the learned model and style are set again on an inference node and a
filter that crashed and were restarted with their start-up values.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest
from background_node import ParameterReader, spinning
from personal_models import personal_folder
from rclpy.executors import SingleThreadedExecutor

from audio2pose_ros.ros.player import rclpy_session

pytestmark = [pytest.mark.ros]


def test_when_the_console_sets_a_personal_model_expect_it_run_or_refused_with_the_fallback(
    tmp_path,
):
    from audio2pose_ros.ros.nodes.console_node import ConsoleNode
    from audio2pose_ros.ros.nodes.inference_node import InferenceNode
    from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode

    good, bad = personal_folder(tmp_path / "me"), personal_folder(tmp_path / "broken")
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
                lambda: console.inference_model.ready() and console.filter_style.ready(),
                "the services",
            )
            console.set_model(str(bad), fallback={"head_gain": 0.7})
            spin_until(lambda: "refused" in problem(), "the refusal shown")
            assert "not an audio2pose checkpoint" in problem()
            spin_until(
                lambda: (console.filter_style.values or {}).get("head_gain") == 0.7,
                "the fallback style",
            )
            assert inference.parameters["model_path"] == ""  # the running model goes on
            assert inference.incoming is None
            console.set_model(str(good), fallback={"head_gain": 0.5})
            spin_until(lambda: console.status()["model_path"] == str(good), "the folder read back")
            assert inference.parameters["model_path"] == str(good)
            assert problem() == ""
            assert console.status()["style_values"]["head_gain"] == 0.7  # accepted: no fallback
            console.set_model(None)  # back to the model it started with
            spin_until(lambda: console.status()["model_path"] == "", "its own model back")
            assert inference.parameters["model_path"] == ""
        finally:
            for node in (console, motion_filter, inference):
                executor.remove_node(node)
                node.destroy_node()


@pytest.mark.slow
def test_when_the_inference_node_and_filter_restart_expect_the_learned_model_and_style_set_again(
    tmp_path, capfd
):
    import os
    import signal

    from test_console_browser import _wait

    from audio2pose_ros.ros.nodes.console_node import ConsoleNode
    from audio2pose_ros.ros.supervisor import node_graph

    folder = str(personal_folder(tmp_path / "me"))
    logs = tmp_path / "logs"
    names = ("inference_node", "motion_filter_node")
    with node_graph(log_dir=logs, no_robot=True) as graph:
        model, style = ParameterReader(names[0]), ParameterReader(names[1])
        try:
            with rclpy_session(["--ros-args", "-p", "port:=0"]):
                console = ConsoleNode()
                with spinning(console, SingleThreadedExecutor()):
                    _wait(
                        lambda: console.inference_model.ready() and console.filter_style.ready(),
                        120.0,
                        "the nodes' parameter services",
                    )
                    # what learning my style does: the style fitted to the model, then the model
                    console.set_style({"head_gain": 0.7})
                    console.set_model(folder, fallback={"head_gain": 0.5})
                    _wait(lambda: model.read("model_path") == folder, 30.0, "the personal model")
                    _wait(lambda: style.read("head_gain") == 0.7, 30.0, "the personal style")
                    victims = {name: graph.processes[name] for name in names}
                    for victim in victims.values():
                        os.kill(victim.pid, signal.SIGKILL)
                    _wait(
                        lambda: all(graph.processes[n] is not v for n, v in victims.items()),
                        120.0,
                        "the restarts",
                    )
                    _wait(lambda: model.read("model_path") is not None, 120.0, "the new node")
                    _wait(lambda: style.read("head_gain") is not None, 120.0, "the new filter")
                    _wait(lambda: model.read("model_path") == folder, 30.0, "the model set again")
                    _wait(lambda: style.read("head_gain") == 0.7, 30.0, "the style set again")
                    _wait(lambda: console.status()["model_path"] == folder, 10.0, "the page told")
        finally:
            model.close()
            style.close()
    console_log = capfd.readouterr().err
    assert f"inference_node's model_path is '', the operator chose {folder!r}: set again" in (
        console_log
    )
    assert "the operator chose 0.7: set again" in console_log
    inference_log = (logs / "inference_node.log").read_text(encoding="utf-8")
    assert inference_log.count(f"model_path={folder!r}") >= 2  # each process ran the folder
