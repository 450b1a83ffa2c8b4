"""The repository passes its own lint configuration (``[tool.ruff]`` in pyproject.toml: pycodestyle,
pyflakes, import order, pyupgrade and bugbear, lines <= 120 characters). Runs the ``ruff`` of the
test's own environment (the dev extra installs it); skipped where it is not installed."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def ruff_command() -> list[str] | None:
    """``python -m ruff`` of this interpreter's environment, else a ``ruff`` on the PATH, else None."""
    if importlib.util.find_spec("ruff") is not None:
        return [sys.executable, "-m", "ruff"]
    exe = shutil.which("ruff")
    return [exe] if exe else None


def test_repository_is_clean_under_the_projects_ruff_configuration():
    cmd = ruff_command()
    if cmd is None:
        pytest.skip("ruff is not installed (pip install -e '.[dev]' installs it)")
    # the project's configuration, read from pyproject.toml at the root; --no-cache: write nothing into the tree
    result = subprocess.run([*cmd, "check", "--config", str(ROOT / "pyproject.toml"), "--no-cache",
                             "--output-format", "concise", "."], cwd=ROOT, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, f"ruff check found problems:\n{result.stdout}{result.stderr}"
