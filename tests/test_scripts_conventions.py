"""The command-line conventions of the scripts and the benchmarks (``scripts/_cli.py``, the same as the
package's commands): a folder of results is ``--output-dir`` / ``-o``, a single file ``--output`` /
``-o``; the old spellings still work, hidden, with one deprecation line; each default stated once. And
what keeps them apart from the library's insides: no script or benchmark imports a private name, the
studies train through ``make_trainer``, and the machine header and the timing in turn are written once
(``benchmarks/timing.py``). Only ``--help`` and parsing run here: no script does its work."""

from __future__ import annotations

import contextlib
import importlib.util
import io
import os
import re
import runpy
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / "scripts"
BENCHMARKS = ROOT / "benchmarks"
HELPERS = {"timing", "jax_original"}  # modules the benchmarks import, not commands
PATHS = {p.stem: p for folder in (SCRIPTS, BENCHMARKS) for p in sorted(folder.glob("*.py"))
         if not p.name.startswith("_") and p.stem not in HELPERS}
SOURCES = {name: path.read_text() for name, path in PATHS.items()}
ALL_SOURCES = {f"{p.parent.name}/{p.name}": p.read_text() for folder in (SCRIPTS, BENCHMARKS)
               for p in sorted(folder.glob("*.py"))}
FOLDER = sorted(name for name, text in SOURCES.items() if "add_output_dir(" in text)
FILE = sorted(name for name, text in SOURCES.items() if "add_output_file(" in text)


def _runnable(name: str) -> bool:
    """False for a script that imports jax where jax is not installed (its --help cannot run)."""
    return not re.search(r"^import jax\b", SOURCES[name], re.M) or importlib.util.find_spec("jax") is not None


def test_the_timing_scripts_live_in_benchmarks_and_the_studies_in_scripts():
    assert len(PATHS) == len({p.stem for folder in (SCRIPTS, BENCHMARKS) for p in folder.glob("*.py")} - HELPERS
                             - {"_cli"})  # no name in both folders
    timing = {"benchmark_dynamics", "benchmark_arm_dynamics", "benchmark_compile_rule", "benchmark_export",
              "benchmark_first_call", "benchmark_jax_reference", "benchmark_mppi", "compare_compile",
              "cost_accuracy_front"}
    assert {name for name in timing if PATHS[name].parent == BENCHMARKS} == timing
    assert (BENCHMARKS / "timing.py").exists() and (BENCHMARKS / "jax_original.py").exists()
    assert {"noise_study", "real_pendulum_cv", "benchmark", "ablate"} <= {n for n, p in PATHS.items()
                                                                         if p.parent == SCRIPTS}


def test_every_output_option_goes_through_the_convention():
    assert {"benchmark", "make_real_subset", "real_pendulum", "real_pendulum_cv", "noise_study",
            "identification_study"} <= set(FOLDER)
    assert {"ablate", "benchmark_first_call"} <= set(FILE)
    for name, text in SOURCES.items():  # no script spells an output option of its own
        assert not re.search(r"add_argument\(\s*\"--(out|output|output-dir)\"", text), name


def _help(name: str, monkeypatch) -> str:
    """``python SCRIPT --help`` run in this process (``runpy``, as ``__main__``; a new interpreter would
    import torch and Lightning again for every script): what it printed, after checking it exited 0."""
    monkeypatch.setenv("COLUMNS", "200")
    monkeypatch.setattr(sys, "argv", [str(PATHS[name]), "--help"])
    monkeypatch.syspath_prepend(str(SCRIPTS))  # the scripts import _cli from their folder
    monkeypatch.syspath_prepend(str(PATHS[name].parent))  # the benchmarks import timing from theirs
    monkeypatch.chdir(ROOT)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as exit_:
        runpy.run_path(str(PATHS[name]), run_name="__main__")
    assert exit_.value.code in (0, None), exit_.value.code
    return out.getvalue()


@pytest.mark.parametrize("name", FOLDER + FILE)
def test_help_names_the_output_option_and_not_the_old_spellings(name, monkeypatch):
    if not _runnable(name):
        pytest.skip("needs jax")
    out = _help(name, monkeypatch)
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
    monkeypatch.syspath_prepend(str(PATHS[name].parent))  # the benchmarks import timing from theirs
    spec = importlib.util.spec_from_file_location(f"script_{name}", PATHS[name])
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


@pytest.mark.parametrize("name", sorted(ALL_SOURCES))
def test_no_script_or_benchmark_imports_a_private_name(name):
    text = ALL_SOURCES[name]
    # a private module of the library (lnn_torch.networks._kernels), or a private name from it (_h5py)
    assert not re.findall(r"\blnn_torch(?:\.\w+)*\._\w+", text), name
    assert not re.findall(r"^\s*from\s+lnn_torch[\w.]*\s+import\s+(?:\(\s*)?(?:\w+\s*,\s*)*_\w", text, re.M), name
    # nor another object's private attribute: a module's, a data module's, a model's, a helper module's
    assert not re.findall(r"\b(?:module|dm|model|m|arm|system|harness|derivatives|hdf5|_cli|timing)\._[a-z]\w*",
                          text), name


@pytest.mark.parametrize("name", sorted(ALL_SOURCES))
def test_studies_train_as_the_cli_does(name):
    """A hand-built ``Trainer`` drifts from ``lnn-torch fit`` (a study once trained without gradient
    clipping): scripts and benchmarks build theirs with ``lnn_torch.training.lightning_cli.make_trainer``."""
    assert not re.search(r"\bTrainer\(", ALL_SOURCES[name]), name
    assert not re.search(r"\.load_from_checkpoint\(", ALL_SOURCES[name]), name  # lnn_torch.load_model


def test_the_machine_header_and_the_timing_in_turn_are_written_once():
    timing = ALL_SOURCES["benchmarks/timing.py"]
    others = {n: t for n, t in ALL_SOURCES.items() if n != "benchmarks/timing.py"}
    for needle in ("/proc/cpuinfo", "platform.processor", "getloadavg", "process_time"):
        assert needle in timing, needle
        assert not [n for n, t in others.items() if needle in t], needle
    assert not [n for n, t in others.items() if "torch.__version__" in t]  # the versions: timing.machine()
    timed = [n for n, t in others.items() if "in turn" in t and n.startswith("benchmarks/")]
    assert len(timed) >= 5 and all("in_turn(" in ALL_SOURCES[n] for n in timed), timed
