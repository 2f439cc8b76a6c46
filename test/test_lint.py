"""Linters are tests: ruff check and ruff format over the whole repository."""

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
