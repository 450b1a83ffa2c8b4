"""The command-line conventions of the scripts and the benchmarks (``lnn_torch.cli``, through
``scripts/_common.py`` and ``benchmarks/timing.py``): a folder of results is ``--output-dir`` / ``-o``, a
single file ``--output`` / ``-o``; the old spellings still work, hidden, with one deprecation line; each
default stated once. And what keeps them apart from the library's insides and from each other: they
import the library through its public face and its packages only (at most twelve ``lnn_torch.*`` paths
beside the root, no private name), no script or benchmark imports another (each folder has its one
helper and neither puts the other on ``sys.path``), they write HDF5 only through ``lnn_torch.data`` and
Markdown tables only through ``lnn_torch.evaluation``'s report helpers, the studies train through
``make_trainer``, and the machine header (``lnn_torch.perf``) and the timing in turn are written once.
Only ``--help``, parsing and the helpers run here: no script does its work."""

from __future__ import annotations

import ast
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
# the one helper module of each folder (benchmarks: and the wrapper of the JAX original some of them time)
OWN_HELPERS = {"scripts": {"_common"}, "benchmarks": {"timing", "jax_original"}}
# the library as the scripts and benchmarks see it: its public face and its packages (the second tier)
ALLOWED_PATHS = {"lnn_torch", *(f"lnn_torch.{p}" for p in ("mechanics", "systems", "robots", "networks", "data",
                                                            "evaluation", "identification", "control", "export",
                                                            "training", "perf", "cli"))}
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
                             - {"_common"})  # no name in both folders
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
    monkeypatch.syspath_prepend(str(PATHS[name].parent))  # each imports its folder's helper
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
    monkeypatch.syspath_prepend(str(PATHS[name].parent))  # each imports its folder's helper
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


def _helper(path: Path):
    """A folder's helper module, loaded from its file under a name of its own."""
    spec = importlib.util.spec_from_file_location(f"helper_{path.parent.name}_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("helper", [SCRIPTS / "_common.py", BENCHMARKS / "timing.py"], ids=lambda p: p.parent.name)
def test_help_states_each_default_once_and_wrote_lists_the_paths(helper, capsys):
    import argparse

    conventions = _helper(helper)
    ap = argparse.ArgumentParser(formatter_class=conventions.HelpFormatter)
    ap.add_argument("--a", type=int, default=3, help="said (default 3)")
    ap.add_argument("--b", type=int, default=4, help="not said")
    ap.add_argument("--c", default=None, help="none")
    ap.add_argument("--d", nargs="+", default=[1, 2], help="a list")
    ap.add_argument("--e", default=str(ROOT / "results"), help="a path in the project")
    conventions.add_output_dir(ap, str(ROOT / "out"), "a folder")
    text = " ".join(ap.format_help().split())
    assert "said (default 3) --b" in text and "not said (default: 4)" in text and "none --d" in text
    assert "a list (default: 1 2)" in text and "(default: <project>/results)" in text
    assert "--output-dir OUTPUT_DIR, -o OUTPUT_DIR a folder (default: <project>/out)" in text
    assert ap.parse_args(["--output", "x"]).output_dir == "x"
    assert capsys.readouterr().err.strip() == f"{ap.prog}: --output is deprecated; use --output-dir"
    conventions.wrote(Path("a"), [Path("b"), "c"])
    conventions.wrote([])
    assert capsys.readouterr().out == "wrote a, b, c\n"


def test_the_helpers_take_the_conventions_and_the_machine_header_from_the_library():
    """One copy of the conventions and of the machine header: the library's, which both helpers hand on."""
    import lnn_torch.cli
    import lnn_torch.perf

    common, timing = _helper(SCRIPTS / "_common.py"), _helper(BENCHMARKS / "timing.py")
    for name in ("HelpFormatter", "add_output_dir", "add_output_file", "wrote"):
        assert getattr(common, name) is getattr(timing, name) is getattr(lnn_torch.cli, name), name
    assert timing.machine_header is lnn_torch.perf.machine_header and timing.machine is lnn_torch.perf.machine
    assert common.ROOT == timing.ROOT == ROOT == lnn_torch.cli.ROOT


@pytest.mark.parametrize("name", sorted(ALL_SOURCES))
def test_no_script_or_benchmark_imports_a_private_name(name):
    text = ALL_SOURCES[name]
    # a private module of the library (lnn_torch.networks._kernels), or a private name from it (_h5py)
    assert not re.findall(r"\blnn_torch(?:\.\w+)*\._\w+", text), name
    assert not re.findall(r"^\s*from\s+lnn_torch[\w.]*\s+import\s+(?:\(\s*)?(?:\w+\s*,\s*)*_\w", text, re.M), name
    # nor another object's private attribute: a module's, a data module's, a model's, a helper module's
    assert not re.findall(r"\b(?:module|dm|model|m|arm|system|harness|derivatives|hdf5|_common|timing)\._[a-z]\w*",
                          text), name


@pytest.mark.parametrize("name", sorted(ALL_SOURCES))
def test_studies_train_as_the_cli_does(name):
    """A hand-built ``Trainer`` drifts from ``lnn-torch fit`` (a study once trained without gradient
    clipping): scripts and benchmarks build theirs with ``lnn_torch.training.lightning_cli.make_trainer``."""
    assert not re.search(r"\bTrainer\(", ALL_SOURCES[name]), name
    assert not re.search(r"\.load_from_checkpoint\(", ALL_SOURCES[name]), name  # lnn_torch.load_model


def test_the_machine_header_and_the_timing_in_turn_are_written_once():
    """The machine header in the library alone (``lnn_torch.perf.machine``), the timing in turn in
    ``benchmarks/timing.py`` alone."""
    timing = ALL_SOURCES["benchmarks/timing.py"]
    assert "/proc/cpuinfo" in (ROOT / "lnn_torch" / "perf.py").read_text()
    for needle in ("/proc/cpuinfo", "platform.processor", "getloadavg"):
        assert not [n for n, t in ALL_SOURCES.items() if needle in t], needle
    assert "process_time" in timing
    assert not [n for n, t in ALL_SOURCES.items() if "process_time" in t and n != "benchmarks/timing.py"]
    others = {n: t for n, t in ALL_SOURCES.items() if n != "benchmarks/timing.py"}
    assert not [n for n, t in others.items() if "torch.__version__" in t]  # the versions: perf.machine()
    timed = [n for n, t in others.items() if "in turn" in t and n.startswith("benchmarks/")]
    assert len(timed) >= 5 and all("in_turn(" in ALL_SOURCES[n] for n in timed), timed


# ---------------------------------------------------------------------------- the library as they use it
IMPORT_PATH = re.compile(r"^\s*(?:from|import)\s+(lnn_torch[\w.]*)", re.M)  # code in strings (child processes) too


def test_the_library_is_imported_through_few_public_paths():
    """Scripts and benchmarks import the public face (``lnn_torch``) and the packages (``lnn_torch.data``,
    ...): at most twelve distinct ``lnn_torch.*`` paths beside the root, never a module inside a package
    (its name is exported by the package's ``__init__``); a submodule is imported by name from its
    package."""
    found = {}
    for name, text in ALL_SOURCES.items():
        for path in IMPORT_PATH.findall(text):
            found.setdefault(path, []).append(name)
    outside = {path: names for path, names in found.items() if path not in ALLOWED_PATHS}
    assert not outside, f"import paths outside {sorted(ALLOWED_PATHS)}: {outside}"
    assert len(set(found) - {"lnn_torch"}) <= 12, sorted(found)


def _imports(text: str):
    """Every import of a module file (at any depth of its code): ``(module, [names])``, relative ones with
    their dots."""
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, []
        elif isinstance(node, ast.ImportFrom):
            yield "." * node.level + (node.module or ""), [a.name for a in node.names]


@pytest.mark.parametrize("name", sorted(ALL_SOURCES))
def test_no_private_name_from_the_library(name):
    for module, names in _imports(ALL_SOURCES[name]):
        if module == "lnn_torch" or module.startswith("lnn_torch."):
            assert not any(part.startswith("_") for part in module.split(".")), (name, module)
            assert not [n for n in names if n.startswith("_")], (name, module, names)


def test_each_folder_has_one_helper_and_no_script_imports_another():
    """Code two scripts share is the library's or the folder's helper's (``scripts/_common.py``;
    ``benchmarks/timing.py``, and ``benchmarks/jax_original.py``, the wrapper of the JAX original that
    the benchmarks time): a script or benchmark imports no other, and no module of the other folder."""
    assert sorted(p.name for p in SCRIPTS.glob("_*.py")) == ["_common.py"]
    assert not list(BENCHMARKS.glob("_*.py"))
    local = {p.stem: folder.name for folder in (SCRIPTS, BENCHMARKS) for p in folder.glob("*.py")}
    wrong = []
    for name, text in ALL_SOURCES.items():
        folder = name.split("/")[0]
        for module, _ in _imports(text):
            top = module.split(".")[0]
            if top in local and top not in OWN_HELPERS[folder]:
                wrong.append(f"{name} imports {module} ({local[top]}/)")
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("name", sorted(ALL_SOURCES))
def test_neither_folder_puts_the_other_on_sys_path(name):
    """``python scripts/X.py`` puts ``scripts/`` on ``sys.path`` and ``python benchmarks/X.py`` ``benchmarks/``;
    no file adds the other folder."""
    text = ALL_SOURCES[name]
    other = "benchmarks" if name.startswith("scripts/") else "scripts"
    tree = ast.parse(text)
    if not any(isinstance(n, ast.Attribute) and n.attr == "path" and getattr(n.value, "id", None) == "sys"
               for n in ast.walk(tree)):
        return
    docstring = ast.get_docstring(tree, clean=False)
    literals = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
                and n.value != docstring]
    assert not [s for s in literals if other in Path(s).parts], (name, other)


@pytest.mark.parametrize("name", sorted(ALL_SOURCES))
def test_hdf5_is_written_through_the_library_and_tables_through_its_report(name):
    """Dataset files through ``lnn_torch.data`` (the only module that imports h5py); Markdown tables
    through ``lnn_torch.evaluation``'s ``table_header``, ``table_row``, ``markdown_table``."""
    text = ALL_SOURCES[name]
    assert not re.search(r"^\s*(?:import|from)\s+h5py\b", text, re.M), name
    assert not re.search(r"\bh5py\.", text), name
    assert not re.search(r"[\"']\|-{3}", text), name  # a hand-written rule: |---|
    assert not re.search(r"[\"'] \| [\"']\s*\.join", text), name  # cells joined by hand
    assert not re.search(r"\bf?[\"']\| ", text), name  # a row written by hand: "| ..."
