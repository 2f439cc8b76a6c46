"""The public Python API: every name of ``__all__`` imports from the package, lazily."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

import audio2pose_ros


@pytest.mark.parametrize("name", audio2pose_ros.__all__)
def test_when_a_public_name_is_imported_expect_the_object_of_its_module(name):
    value = getattr(audio2pose_ros, name)
    module = importlib.import_module(audio2pose_ros._PUBLIC[name])
    assert value is getattr(module, name)


def test_when_the_feature_spec_is_imported_from_the_package_expect_it_works():
    from audio2pose_ros import FeatureSpec

    assert FeatureSpec().dim > 0


def test_when_an_unknown_name_is_asked_expect_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        audio2pose_ros.Nope  # noqa: B018


def test_when_the_package_is_imported_expect_no_heavy_modules_loaded():
    heavy = "{'torch', 'numpy', 'rclpy'}"
    code = f"import sys, audio2pose_ros; print(sorted({heavy} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
