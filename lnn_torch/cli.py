"""The ``lnn-torch`` command: a dispatcher over ``generate``, ``import``, ``evaluate``, ``simulate``,
``identify``, ``export``, ``list`` (modules of
``lnn_torch.commands``) and Lightning's ``fit``/``validate``/``test``/``predict``; and the command-line
conventions the project's scripts and benchmarks share (``HelpFormatter``, ``add_output_dir``,
``add_output_file``, ``wrote``): a folder of results is ``--output-dir`` / ``-o``, a single file
``--output`` / ``-o`` (an old spelling keeps working, hidden, with one line on stderr); a run ends by
printing every path it wrote (``wrote PATH, PATH, ...``); the help states each default once."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path

# the project's folder (a checkout; where the package is installed elsewhere, paths are shown as given)
ROOT = Path(__file__).resolve().parents[1]

LIGHTNING_COMMANDS = ("fit", "validate", "test", "predict")
# command -> (module of lnn_torch.commands, one-line help)
COMMANDS = {
    "generate": ("generate", "write a ground-truth trajectory dataset (HDF5)"),
    "import": ("import_recordings", "CSV recordings of a real system -> an HDF5 dataset"),
    "fit": (None, "train a model (LightningCLI; -c configs/quickstart.yaml)"),
    "validate": (None, "validation metrics of a checkpoint (--ckpt_path)"),
    "test": (None, "test-split metrics of a checkpoint (--ckpt_path)"),
    "predict": (None, "write test-split predictions to a file (--ckpt_path)"),
    "evaluate": ("evaluate", "report of a checkpoint: errors, rollouts, energy drift, stability, plots"),
    "simulate": ("simulate", "roll a trained (or shipped) model out from a state; CSV/HDF5 and a plot"),
    "identify": ("identify", "the physical parameters of a recorded trajectory, through a trained model"),
    "export": ("export", "the learned dynamics as torch.export programs (ONNX, AOTInductor) for a control loop"),
    "list": ("list_registry", "scenes, model variants and parts, shipped models and integrators"),
    "control": ("control", "design a controller on a model and run it in closed loop on a plant; report + animation"),
}


def lightning_main(argv: list[str]) -> int:
    """``fit``/``validate``/``test``/``predict`` with LightningCLI (YAML configs, ``--help``)."""
    from .commands.config_files import config_paths, read_config

    for path in config_paths(argv):  # a bad file in one line, before LightningCLI's own parse
        read_config(path)
    from lightning.fabric.utilities.exceptions import MisconfigurationException

    from .errors import InputError
    from .training.lightning_cli import run_cli

    try:
        run_cli(argv)
    except MisconfigurationException as err:  # a trainer setting this machine cannot take (a GPU it lacks, ...)
        import torch

        text = str(err).strip()
        hint = (" (this machine has no CUDA device: --trainer.accelerator cpu, or leave it out)"
                if any(w in text.lower() for w in ("gpu", "cuda")) and not torch.cuda.is_available() else "")
        first = text.splitlines()[0] if text else type(err).__name__
        raise InputError(f"the trainer cannot be set up as asked: {first}{hint}") from None
    # Lightning's DDP leaves the process group alive; left to interpreter shutdown, gloo's worker
    # threads can abort the process ("terminate called without an active exception", exit -6) after
    # a successful run. Only on success: a rank that failed must not wait on the others here.
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()
    return 0


def main(argv: list[str] | None = None) -> int:
    console = argv is None  # the console script (a Python caller keeps Python's own warnings)
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "--version":
        from ._version import __version__

        print(f"lnn-torch {__version__}")
        return 0
    if not argv or argv[0] in ("-h", "--help"):
        width = max(map(len, COMMANDS))
        print("usage: lnn-torch {" + ",".join(COMMANDS) + "} ...\n\n"
              + "\n".join(f"  {name:<{width}}  {text}" for name, (_, text) in COMMANDS.items())
              + "\n\nRun 'lnn-torch COMMAND --help' for a command's options; 'lnn-torch --version' for the version.")
        return 0 if argv else 2
    command, rest = argv[0], argv[1:]
    if command not in COMMANDS:
        print(f"lnn-torch: error: unknown command '{command}' (choose from {', '.join(COMMANDS)})", file=sys.stderr)
        return 2
    from .perf import configure_cpu

    configure_cpu()
    if console:
        _plain_warnings(command)
    try:
        load_plugins()
        if command in LIGHTNING_COMMANDS:
            return lightning_main(argv)
        return importlib.import_module(f"lnn_torch.commands.{COMMANDS[command][0]}").main(rest)
    except (ValueError, OSError, RuntimeError, KeyError) as err:  # InputError, DatasetFileError, FileExistsError, ...
        while err.__cause__ is not None and "Call to compute_fn of link" in str(err):  # jsonargparse's wrapper
            err = err.__cause__
        from .errors import InputError

        bare = isinstance(err, KeyError) and not isinstance(err, InputError) and err.args \
            and " " not in str(err.args[0])  # (a KeyError of one word: an internal lookup, named as one)
        message = f"missing key {err.args[0]!r} (KeyError)" if bare else err.args[0] \
            if isinstance(err, KeyError) and err.args else err
        print(f"lnn-torch {command}: error: {message}", file=sys.stderr)
        return 2


PLUGINS = "LNN_TORCH_PLUGINS"  # modules to import before a command (a scene, a part, a section of one's own)
ENTRY_POINTS = "lnn_torch.plugins"  # the same, as a package's entry points


def load_plugins() -> list[str]:
    """Import the modules that register a user's own scenes, model parts or metrics before a command runs: those
    ``LNN_TORCH_PLUGINS`` names (comma- or space-separated; the working directory is searched too, so a
    ``my_scene.py`` beside the data is found) and the entry points of group ``lnn_torch.plugins`` of installed
    packages. Returns their names; ``InputError`` in one line for a module that cannot be imported."""
    import os
    from importlib.metadata import entry_points

    from .errors import InputError

    names = [n for n in os.environ.get(PLUGINS, "").replace(",", " ").split() if n]
    loaded = []
    if names and os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    for name in names:
        try:
            importlib.import_module(name)
        except Exception as err:  # (its own error, whatever it is: named in one line)
            raise InputError(f"{PLUGINS}: cannot import '{name}' ({type(err).__name__}: {err})") from None
        loaded.append(name)
    for point in entry_points(group=ENTRY_POINTS):
        try:
            point.load()
        except Exception as err:
            raise InputError(f"plugin entry point '{point.name}' ({point.value}) of group {ENTRY_POINTS} cannot be "
                             f"loaded ({type(err).__name__}: {err})") from None
        loaded.append(point.value)
    return loaded


def _plain_warnings(command: str) -> None:
    """The package's own warnings printed as one line for a user, ``lnn-torch COMMAND: warning: ...`` (not the
    library's file, line and source); other packages' as Python prints them."""
    import warnings

    package = str(Path(__file__).resolve().parent)
    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if not str(filename).startswith(package):
            return shown(message, category, filename, lineno, file, line)
        print(f"lnn-torch {command}: warning: {message}", file=sys.stderr if file is None else file)

    warnings.showwarning = show


if __name__ == "__main__":
    sys.exit(main())


# ---------------------------------------------------------------------------- the command-line conventions
def _shown(default) -> str:
    """A default as one would type it: lists space-separated, paths in the project from its root."""
    if isinstance(default, (list, tuple)):
        return " ".join(str(x) for x in default)
    if isinstance(default, (str, Path)) and os.path.isabs(default):
        rel = os.path.relpath(default, ROOT)
        if not rel.startswith(os.path.join("..", "..")):
            return f"<project>/{rel}"
    return str(default)


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """The description as written; each option's default once (added where its help does not say it)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if ("default" in text or default is None or default is False or default is argparse.SUPPRESS
                or (isinstance(default, (str, list, tuple)) and not default)
                or not (action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE))):
            return text
        shown = _shown(default).replace("%", "%%")
        return f"{text} (default: {shown})" if text else f"default: {shown}"


class _DeprecatedAlias(argparse.Action):
    """An old spelling of an option: stores into the new option's destination, with one line on stderr."""

    def __init__(self, option_strings, dest, new: str, **kwargs):
        self.new = new
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog}: {option_string} is deprecated; use {self.new}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def _aliases(ap: argparse.ArgumentParser, dest: str, new: str, old) -> None:
    for flag in old:
        ap.add_argument(flag, dest=dest, action=_DeprecatedAlias, new=new, default=argparse.SUPPRESS,
                        help=argparse.SUPPRESS)


def add_output_dir(ap: argparse.ArgumentParser, default, help: str, old=("--output",)) -> None:
    """``--output-dir`` / ``-o``: the folder the results go to; ``old`` are hidden deprecated spellings."""
    ap.add_argument("--output-dir", "-o", default=default, help=help)
    _aliases(ap, "output_dir", "--output-dir", old)


def add_output_file(ap: argparse.ArgumentParser, default, help: str, old=()) -> None:
    """``--output`` / ``-o``: the one file the script writes; ``old`` are hidden deprecated spellings."""
    ap.add_argument("--output", "-o", default=default, help=help)
    _aliases(ap, "output", "--output", old)


def wrote(*paths) -> None:
    """``wrote PATH, PATH, ...`` (nothing when no path is given); arguments may be paths or lists of them."""
    flat = [str(p) for x in paths for p in (x if isinstance(x, (list, tuple)) else [x])]
    if flat:
        print("wrote " + ", ".join(flat))
