"""config/pepper.yaml, the parameter page and the name list: the declarations, written out."""

from __future__ import annotations

import pytest
import yaml

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.parameters import specs_of, validate_values
from audio2pose_ros.resources import share_path
from audio2pose_ros.ros.parameter_docs import GENERATED, node_parameters, parameters_yaml

ROOT = share_path("config", "pepper.yaml").parent.parent


def test_shipped_parameters_file_is_the_declarations_written_out():
    shipped = (ROOT / "config" / "pepper.yaml").read_text(encoding="utf-8")
    assert shipped == parameters_yaml(), (
        "config/pepper.yaml differs from the declarations: run "
        "python -m audio2pose_ros.ros.parameter_docs --write ."
    )


@pytest.mark.parametrize("relative", sorted(GENERATED))
def test_every_generated_file_is_the_declarations_written_out(relative):
    """The parameter page and the name list too: a parameter added to a node shows in both."""
    shipped = (ROOT / relative).read_text(encoding="utf-8")
    assert shipped == GENERATED[relative](), (
        f"{relative} differs from the declarations: run "
        "python -m audio2pose_ros.ros.parameter_docs --write ."
    )


def test_the_name_list_holds_every_declared_name_and_the_simulated_robots():
    from audio2pose_ros.ros.nodes import pepper_sim_node
    from audio2pose_ros.ros.parameter_names import NODE_PARAMETER_NAMES

    every = {spec.name for specs in node_parameters().values() for spec in specs}
    assert every | {spec.name for spec in pepper_sim_node.PARAMETERS} == NODE_PARAMETER_NAMES


def test_every_value_in_the_parameters_file_is_declared_by_a_node_and_valid():
    document = yaml.safe_load((ROOT / "config" / "pepper.yaml").read_text(encoding="utf-8"))
    nodes = node_parameters()
    every = {spec.name: spec for specs in nodes.values() for spec in specs}
    for section, body in document.items():
        declared = every if section == "/**" else {s.name: s for s in nodes[section]}
        for name, value in (body["ros__parameters"] or {}).items():
            assert name in declared, f"{section}: {name} is declared by no node"
            assert declared[name].validate(value) == value


def test_every_declared_parameter_has_a_description_and_is_written_once():
    for node, specs in node_parameters().items():
        names = [spec.name for spec in specs]
        assert len(names) == len(set(names)), node
        assert all(spec.description for spec in specs), node
    text = parameters_yaml()
    for specs in node_parameters().values():
        for spec in specs:
            assert text.count(f"\n    {spec.name}: ") == 1, spec.name


def test_when_a_refused_value_is_huge_expect_a_short_reason():
    """A 100 kB string for a number is refused in one short line, not echoed whole."""
    spec = {s.name: s for s in specs_of(MotionFilterSettings)}["watchdog_timeout_s"]
    with pytest.raises(ConfigurationError, match="watchdog_timeout_s") as refused:
        spec.validate("x" * 100_000)
    assert len(str(refused.value)) < 300
    assert "100002 characters" in str(refused.value)
    with pytest.raises(ConfigurationError, match="unknown parameter") as unknown:
        validate_values([spec], {"y" * 100_000: 1.0})
    assert len(str(unknown.value)) < 300


def test_when_a_value_lies_in_a_declared_gap_expect_it_refused_naming_the_gap():
    """joint_angles_speed: negative means velocity_fraction; 0 is a speed the robot refuses."""
    (spec,) = [s for s in node_parameters()["motion_filter_node"] if s.name == "joint_angles_speed"]
    for bad in (0.0, 1e-300, 0.005):
        with pytest.raises(
            ConfigurationError, match=r"excluded gap; allowed: .*not in \[0, 0.01\)"
        ):
            spec.validate(bad)
    for good in (-1.0, -1e-9, 0.01, 0.5, 1.0):
        assert spec.validate(good) == good
