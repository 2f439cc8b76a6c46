"""What launch/pepper.launch.py decides, without launch: audio2pose_ros.ros.launch_support.

The launch file itself runs in test/test_launch_pepper.py (launch_testing, on a ROS distro) and
in support/launch_check.sh (the launch stack built from source); these tests cover the
decisions on every machine.
"""

import copy
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from launch_arguments import arguments

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.ros.launch_support import (
    ARGUMENTS,
    EXIT_CONFIGURATION_ERROR,
    GaveUpError,
    RespawnBudget,
    check_params_file,
    describe_exit,
    model_path_override,
    normalize_namespace,
    normalize_topic,
    parse_bool,
    plan_launch,
    single_process_arguments,
)

ROOT = Path(__file__).resolve().parent.parent


def test_when_importing_launch_support_expect_no_launch_or_rclpy_module():
    code = (
        "import sys, audio2pose_ros.ros.launch_support; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in "
        "('launch', 'launch_ros', 'rclpy')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "[]"


@pytest.mark.parametrize("text", ["true", "True", "TRUE", "1", " true "])
def test_when_a_word_ifcondition_takes_as_true_expect_true(text):
    assert parse_bool("rviz", text) is True


@pytest.mark.parametrize("text", ["false", "False", "FALSE", "0", "0 "])
def test_when_a_word_ifcondition_takes_as_false_expect_false(text):
    assert parse_bool("rviz", text) is False


@pytest.mark.parametrize("text", ["yes", "on", "", "2", "t", "truee"])
def test_when_a_word_ifcondition_refuses_expect_one_line_naming_the_argument(text):
    with pytest.raises(ConfigurationError, match=r"^launch argument rviz:=.* is not a boolean"):
        parse_bool("rviz", text)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("/audio", "/audio"),
        ("/mic/", "/mic"),
        ("//mic//front/", "/mic/front"),
        (" /mic ", "/mic"),
        ("/", ""),
        ("", ""),
        ("mic/", "mic"),
        ("_robot/mic_2", "_robot/mic_2"),
    ],
)
def test_when_normalizing_a_namespace_expect_no_trailing_or_doubled_slash(text, expected):
    assert normalize_namespace("audio_ns", text) == expected


@pytest.mark.parametrize("text", ["/mic/2nd", "/mi c", "/mic/~", "/mic-1", "/mic/{x}"])
def test_when_a_namespace_token_is_invalid_expect_one_line_naming_it(text):
    with pytest.raises(ConfigurationError, match=r"^launch argument audio_ns:=.* not a valid ROS"):
        normalize_namespace("audio_ns", text)


def test_when_the_audio_namespace_has_a_trailing_slash_expect_the_remap_targets_to_be_valid():
    plan = plan_launch(arguments(audio_ns="/mic/"))
    assert plan.audio_topics == {"audio/audio": "/mic/audio", "audio/audio_info": "/mic/audio_info"}


def test_when_the_audio_namespace_is_root_expect_topics_at_the_root():
    plan = plan_launch(arguments(audio_ns="/"))
    assert plan.audio_topics == {"audio/audio": "/audio", "audio/audio_info": "/audio_info"}


def test_when_the_controller_topic_is_empty_expect_a_refusal():
    with pytest.raises(ConfigurationError, match="controller_topic:='/' names no topic"):
        normalize_topic("controller_topic", "/")


def test_when_the_controller_topic_has_a_trailing_slash_expect_it_normalized():
    plan = plan_launch(arguments(controller_topic="/my_controller/joint_trajectory/"))
    assert plan.controller_topic == "/my_controller/joint_trajectory"


def test_when_the_params_file_is_missing_expect_one_line_naming_it(tmp_path):
    missing = tmp_path / "missing.yaml"
    with pytest.raises(ConfigurationError, match=rf"^params_file {missing}: no such file$"):
        check_params_file(str(missing))


def test_when_the_params_file_is_a_directory_expect_a_refusal(tmp_path):
    with pytest.raises(ConfigurationError, match="no such file"):
        check_params_file(str(tmp_path))


def test_when_the_params_file_has_a_yaml_syntax_error_expect_line_and_column(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("motion_filter_node:\n  ros__parameters:\n    rate_hz: [1,\n")
    with pytest.raises(ConfigurationError, match=r"not valid YAML at line 4, column 1: ") as err:
        check_params_file(str(bad))
    assert "\n" not in str(err.value)


def test_when_the_params_file_is_not_a_mapping_expect_a_refusal(tmp_path):
    listed = tmp_path / "list.yaml"
    listed.write_text("- motion_filter_node\n")
    with pytest.raises(ConfigurationError, match=r"expected a mapping .* got list"):
        check_params_file(str(listed))


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("motion_filter_node:\n  ros__parameters: [1, 2]\n", "motion_filter_node/ros__parameters"),
        ("motion_filter_node: 3\n", "motion_filter_node must"),
        ("/robot:\n  motion_filter_node: [rate_hz]\n", "/robot/motion_filter_node must"),
    ],
)
def test_when_the_params_file_is_not_laid_out_as_rcl_reads_it_expect_the_section_named(
    tmp_path, text, where
):
    # rcl accepts these and sets nothing: the parameters the user meant would be ignored.
    odd = tmp_path / "odd.yaml"
    odd.write_text(text)
    with pytest.raises(ConfigurationError, match=re.escape(where)):
        check_params_file(str(odd))


@pytest.mark.parametrize(
    "text",
    [
        "/robot:\n  motion_filter_node:\n    ros__parameters:\n      rate_hz: 50.0\n",
        "motion_filter_node:\n  ros__parameters:\n",
        "",
    ],
)
def test_when_the_params_file_is_one_rcl_reads_expect_it_accepted(tmp_path, text):
    good = tmp_path / "good.yaml"
    good.write_text(text)
    assert check_params_file(str(good)) == good


def test_when_the_params_file_is_not_utf8_expect_a_refusal(tmp_path):
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigurationError, match="not UTF-8 text"):
        check_params_file(str(binary))


def test_when_the_params_file_is_the_packaged_one_expect_it_accepted():
    assert (
        check_params_file(str(ROOT / "config" / "pepper.yaml")) == ROOT / "config" / "pepper.yaml"
    )


def test_when_model_path_argument_is_empty_expect_no_override_so_the_file_decides():
    # Before: the launch file always passed {"model_path": ""} after the parameters file, so a
    # model_path in the file was replaced by the argument's default ''.
    assert model_path_override("") == {}
    assert model_path_override("  ") == {}


def test_when_model_path_argument_is_given_expect_it_to_override_the_file():
    assert model_path_override("/models/mine.safetensors") == {
        "model_path": "/models/mine.safetensors"
    }


def test_when_robot_state_publisher_is_on_without_sim_expect_the_commanded_pose_branch():
    assert plan_launch(arguments(robot_state_publisher="1")).commanded_state_publisher
    assert not plan_launch(arguments(robot_state_publisher="0")).commanded_state_publisher
    gz = plan_launch(arguments(robot_state_publisher="True", sim="gz"))
    assert not gz.commanded_state_publisher  # the simulated robot publishes its own state
    pybullet = plan_launch(arguments(robot_state_publisher="True", sim="PyBullet"))
    assert pybullet.sim == "pybullet"
    assert not pybullet.commanded_state_publisher


def test_when_sim_is_unknown_expect_a_refusal():
    with pytest.raises(ConfigurationError, match="sim:='mujoco' is not one of none, gz, pybullet"):
        plan_launch(arguments(sim="mujoco"))


def test_when_voice_out_is_given_expect_it_checked_before_anything_runs():
    assert plan_launch(arguments()).voice_out == "off"
    plan = plan_launch(arguments(voice_out="naoqi:192.168.1.10"))
    assert plan.voice_out == "naoqi:tcp://192.168.1.10:9559"
    with pytest.raises(ConfigurationError, match="voice out 'speaker'"):
        plan_launch(arguments(voice_out="speaker"))


def test_when_planning_expect_exactly_the_arguments_the_launch_file_declares():
    assert set(arguments()) == set(ARGUMENTS)
    with pytest.raises(KeyError):
        plan_launch({k: v for k, v in arguments().items() if k != "audio_ns"})


def test_when_a_node_crashes_expect_first_restart_at_once_then_back_off_then_give_up():
    budget = RespawnBudget()
    delays = []
    for _ in range(5):
        decision = budget.on_exit("motion_filter_node", -signal.SIGKILL, ran_s=3.0)
        assert decision.restart
        delays.append(decision.delay_s)
    assert delays == [0.0, 2.0, 4.0, 8.0, 8.0]
    final = budget.on_exit("motion_filter_node", -signal.SIGKILL, ran_s=3.0)
    assert not final.restart
    assert isinstance(final.error(), GaveUpError)
    assert "after 5 restarts in a row" in final.message


def test_when_a_node_ran_long_enough_before_crashing_expect_a_fresh_budget():
    budget = RespawnBudget()
    for _ in range(5):
        budget.on_exit("inference_node", 1, ran_s=1.0)
    decision = budget.on_exit("inference_node", 1, ran_s=budget.healthy_after_s)
    assert decision.restart
    assert decision.delay_s == 0.0  # a first crash in a row: restarted at once


def test_when_the_budget_forgets_expect_every_row_to_start_afresh():
    budget = RespawnBudget(max_restarts=2)
    for _ in range(2):
        budget.on_exit("motion_filter_node", -signal.SIGKILL, ran_s=1.0)
    unforgiving = copy.deepcopy(budget)
    assert not unforgiving.on_exit("motion_filter_node", -signal.SIGKILL, ran_s=1.0).restart
    budget.forget()
    decision = budget.on_exit("motion_filter_node", -signal.SIGKILL, ran_s=1.0)
    assert decision.restart
    assert decision.delay_s == 0.0


def test_when_one_node_exhausts_its_budget_expect_the_others_unaffected():
    budget = RespawnBudget(max_restarts=1)
    budget.on_exit("inference_node", 1, ran_s=0.5)
    assert not budget.on_exit("inference_node", 1, ran_s=0.5).restart
    assert budget.on_exit("audio_features_node", 1, ran_s=0.5).restart


def test_when_a_node_exits_with_a_configuration_error_expect_no_restart():
    decision = RespawnBudget().on_exit("inference_node", EXIT_CONFIGURATION_ERROR, ran_s=0.5)
    assert not decision.restart
    assert isinstance(decision.error(), ConfigurationError)
    assert "not restarting it" in decision.message


def test_when_describing_exits_expect_signal_names_for_negative_codes():
    assert describe_exit(-signal.SIGKILL) == "killed by SIGKILL"
    assert describe_exit(1) == "status 1"
    assert describe_exit(-200) == "killed by signal 200"


@pytest.mark.parametrize(("text", "expected"), [("false", False), ("TRUE", True), ("1", True)])
def test_when_the_console_argument_is_given_expect_it_read_as_a_boolean(text, expected):
    assert plan_launch(arguments(console=text)).console is expected


def test_when_the_console_argument_is_not_a_boolean_expect_one_line_naming_it():
    with pytest.raises(ConfigurationError, match="launch argument console:='web' is not a boolean"):
        plan_launch(arguments(console="web"))


def personal_model(folder, **fitted):
    """A personal model folder whose style was fitted to the packaged checkpoint."""
    from audio2pose_ros.resources import default_checkpoint_path
    from audio2pose_ros.style.personal import checkpoint_digest

    folder.mkdir()
    digest = checkpoint_digest(default_checkpoint_path())
    settings = ", ".join(f"{k}: {v}" for k, v in fitted.items())
    (folder / "style.yaml").write_text(
        "audio2pose_style: 1\nparts:\n  head:\n    seconds: 10\n    std_rad: 0.05\n"
        f"    speed_deciles_rad_s: {[0.01 * k for k in range(1, 10)]}\n"
        f"    accel_deciles_rad_s2: {[0.1 * k for k in range(1, 10)]}\n"
        f"fitted: {{checkpoint_sha256: {digest}, settings: {{{settings}}}}}\n"
    )
    return folder


def test_when_model_path_is_a_personal_model_expect_its_checkpoint_and_style(tmp_path):
    folder = personal_model(tmp_path / "me", head_gain=0.4, head_tempo=0.7)
    plan = plan_launch(arguments(model_path=str(folder)))
    assert plan.model_path["model_path"].endswith("default.safetensors")
    assert plan.style == {"head_gain": 0.4, "head_tempo": 0.7}
    document = yaml.safe_load(
        Path(single_process_arguments(plan, tmp_path)[4]).read_text(encoding="utf-8")
    )
    assert document["motion_filter_node"]["ros__parameters"] == plan.style
    assert plan_launch(arguments()).style == {}


def test_when_style_is_a_preset_expect_filter_style_parameters():
    plan = plan_launch(arguments(style="calm_reader"))
    assert plan.style["head_gain"] < 0.5  # a calm reader's head moves far less than the model's
    assert set(plan.style) <= {"head_gain", "head_tempo"}  # GRID shows the head only
    assert plan.model_path == {}


@pytest.mark.parametrize("style", ["nobody", "/no/such/style.yaml"])
def test_when_style_is_unusable_expect_one_line_naming_the_argument(style):
    with pytest.raises(ConfigurationError, match=r"launch argument style / model_path: .*style"):
        plan_launch(arguments(style=style))
