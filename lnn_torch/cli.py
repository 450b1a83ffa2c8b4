"""The ``lnn-torch`` command: a dispatcher over ``generate``, ``import``, ``evaluate``, ``simulate``,
``identify``, ``export``, ``list`` (modules of
``lnn_torch.commands``) and Lightning's ``fit``/``validate``/``test``/``predict``."""

from __future__ import annotations

import importlib
import sys

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
    from .training.lightning_cli import run_cli

    run_cli(argv)
    # Lightning's DDP leaves the process group alive; left to interpreter shutdown, gloo's worker
    # threads can abort the process ("terminate called without an active exception", exit -6) after
    # a successful run. Only on success: a rank that failed must not wait on the others here.
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()
    return 0


def main(argv: list[str] | None = None) -> int:
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
    try:
        if command in LIGHTNING_COMMANDS:
            return lightning_main(argv)
        return importlib.import_module(f"lnn_torch.commands.{COMMANDS[command][0]}").main(rest)
    except (ValueError, OSError, RuntimeError, KeyError) as err:  # InputError, DatasetFileError, FileExistsError, ...
        while err.__cause__ is not None and "Call to compute_fn of link" in str(err):  # jsonargparse's wrapper
            err = err.__cause__
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"lnn-torch {command}: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
