"""A console page in real Chromium on the whole graph with the simulated Pepper and its voice out.

What the browser tests of the room and the voice share: the node graph from the package's own
``config/pepper.yaml`` (its filter state kept in the test's folder), ``voice_out_node`` sending
to the simulated Pepper's fake ALAudioDevice over NAOqi's protocol, ``console_node`` with a
token, and Debian's Chromium (Playwright) with a fake microphone playing the bundled speech,
opened on the console with that token.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import yaml
from test_console_browser import CHROMIUM, CHROMIUM_ARGS, _answers, _console_url, _wait

from audio2pose_ros.resources import bundled_speech_path, share_path

PAGE_WAIT_MS = 120_000  # a page rendering in software on two loaded cores; only a hung page


@contextmanager
def sim_console_page(
    tmp_path: Path, token: str, height: int, chromium_args: Sequence[str] = ()
) -> Iterator[Any]:
    """The graph, the simulated Pepper and the console running; a page open on the console.

    Args:
        tmp_path: the test's folder (the graph's logs, the filter's state, the parameters).
        token: the console's operator token, given to the page in its address.
        height: the page's height in pixels (1100 wide).
        chromium_args: Chromium switches beside the project's own and the fake microphone.

    Yields:
        The Playwright page, its default wait :data:`PAGE_WAIT_MS`; its browser is closed after.
    """
    from playwright.sync_api import sync_playwright

    from audio2pose_ros.ros.console_runner import CONSOLE_NODE, console_command
    from audio2pose_ros.ros.supervisor import executable_command, node_graph
    from audio2pose_ros.ros.voice_graph import voice_out_processes

    params = yaml.safe_load(share_path("config", "pepper.yaml").read_text(encoding="utf-8"))
    params["motion_filter_node"]["ros__parameters"]["state_file"] = str(tmp_path / "state.json")
    params_file = tmp_path / "params.yaml"
    params_file.write_text(yaml.safe_dump(params), encoding="utf-8")
    command = console_command(params_file, {"port": 0, "token": token}, tmp_path)
    voice_nodes, sim_args = voice_out_processes("naoqi", True, executable_command)
    logs = tmp_path / "logs"
    with (
        node_graph(
            params_file,
            log_dir=logs,
            sim=True,
            sim_args=sim_args,
            more_nodes={CONSOLE_NODE: command, **voice_nodes},
        ),
        tempfile.TemporaryDirectory(prefix="audio2pose_chromium_") as profile,
        sync_playwright() as p,
    ):
        url = _console_url(logs / f"{CONSOLE_NODE}.log")
        _wait(lambda: _answers(url), 60.0, "the console's page")
        browser = p.chromium.launch_persistent_context(
            profile,
            executable_path=str(CHROMIUM),
            headless=True,
            viewport={"width": 1100, "height": height},
            bypass_csp=True,
            args=[
                *CHROMIUM_ARGS,
                *chromium_args,
                f"--use-file-for-fake-audio-capture={bundled_speech_path()}",
            ],
        )
        try:
            page = browser.new_page()
            page.set_default_timeout(PAGE_WAIT_MS)
            page.goto(f"{url}#token={token}")
            yield page
        finally:
            browser.close()
