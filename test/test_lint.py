"""Linters are tests: ruff check and ruff format over the whole repository, mypy (strict) over
the package and the launch file (configuration in pyproject.toml)."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def ruff(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "ruff", *args, str(ROOT)], capture_output=True, text=True
    )


def test_when_ruff_check_runs_expect_no_findings():
    result = ruff("check")
    assert result.returncode == 0, result.stdout


def test_when_ruff_format_checks_expect_formatted_code():
    result = ruff("format", "--check")
    assert result.returncode == 0, result.stdout


def test_when_mypy_checks_the_package_and_launch_file_expect_no_errors():
    result = subprocess.run(
        [sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stdout + result.stderr
