"""The scripts' command-line conventions (``scripts/_cli.py``, the same as the package's commands): a
folder of results is ``--output-dir`` / ``-o``, a single file ``--output`` / ``-o``; the old spellings
still work, hidden, with one deprecation line; each default stated once. Only ``--help`` and parsing
run here: no script does its work."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / "scripts"
SOURCES = {p.stem: p.read_text() for p in sorted(SCRIPTS.glob("*.py")) if not p.name.startswith("_")}
FOLDER = sorted(name for name, text in SOURCES.items() if "add_output_dir(" in text)
FILE = sorted(name for name, text in SOURCES.items() if "add_output_file(" in text)


def _runnable(name: str) -> bool:
    """False for a script that imports jax where jax is not installed (its --help cannot run)."""
    return not re.search(r"^import jax\b", SOURCES[name], re.M) or importlib.util.find_spec("jax") is not None


def test_every_output_option_goes_through_the_convention():
    assert {"benchmark", "make_real_subset", "real_pendulum", "real_pendulum_cv", "noise_study",
            "identification_study"} <= set(FOLDER)
    assert {"ablate", "benchmark_first_call"} <= set(FILE)
    for name, text in SOURCES.items():  # no script spells an output option of its own
        assert not re.search(r"add_argument\(\s*\"--(out|output|output-dir)\"", text), name


def _help(name: str) -> str:
    env = {**os.environ, "COLUMNS": "200", "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, str(SCRIPTS / f"{name}.py"), "--help"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.mark.parametrize("name", FOLDER + FILE)
def test_help_names_the_output_option_and_not_the_old_spellings(name):
    if not _runnable(name):
        pytest.skip("needs jax")
    out = _help(name)
    if name in FOLDER:
        assert "--output-dir OUTPUT_DIR, -o OUTPUT_DIR" in out
        assert "--output " not in out
    else:
        assert "--output OUTPUT, -o OUTPUT" in out
        assert "--output-dir" not in out
    assert "--out " not in out
    assert "(default: None)" not in out and "(default: False)" not in out and "(default: )" not in out


def _script(name: str, monkeypatch):
    monkeypatch.syspath_prepend(str(SCRIPTS))  # the scripts import _cli from their folder
    spec = importlib.util.spec_from_file_location(f"script_{name}", SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_old_spellings_map_to_the_new_options(monkeypatch, capsys):
    folder = _script("make_real_subset", monkeypatch).parser()
    assert folder.parse_args(["--output", "x"]).output_dir == "x"
    assert capsys.readouterr().err.strip() == f"{folder.prog}: --output is deprecated; use --output-dir"
    assert folder.parse_args(["-o", "y"]).output_dir == "y"
    assert folder.parse_args([]).output_dir.endswith(os.path.join("datasets", "real_double_pendulum"))
    assert capsys.readouterr().err == ""
    one_file = _script("benchmark_first_call", monkeypatch).parser()
    assert one_file.parse_args(["--out", "t.md"]).output == "t.md"
    assert "--out is deprecated; use --output" in capsys.readouterr().err


def test_help_states_each_default_once_and_wrote_lists_the_paths(monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(SCRIPTS))
    import argparse

    import _cli

    ap = argparse.ArgumentParser(formatter_class=_cli.HelpFormatter)
    ap.add_argument("--a", type=int, default=3, help="said (default 3)")
    ap.add_argument("--b", type=int, default=4, help="not said")
    ap.add_argument("--c", default=None, help="none")
    ap.add_argument("--d", nargs="+", default=[1, 2], help="a list")
    ap.add_argument("--e", default=str(ROOT / "results"), help="a path in the project")
    text = " ".join(ap.format_help().split())
    assert "said (default 3) --b" in text and "not said (default: 4)" in text and "none --d" in text
    assert "a list (default: 1 2)" in text and "(default: <project>/results)" in text
    _cli.wrote(Path("a"), [Path("b"), "c"])
    _cli.wrote([])
    assert capsys.readouterr().out == "wrote a, b, c\n"
