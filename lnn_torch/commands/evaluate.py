"""``lnn-torch evaluate``: a checkpoint against a dataset split, with the closed-form scene as ground truth.

Reports (JSON, Markdown and PNG plots in ``--output-dir``) every section of
``lnn_torch.evaluation.evaluate_model``:

* relative L2 acceleration error: total, per coordinate, per-trajectory median and 90th percentile;
* rollouts (chosen integrator and dt) from the true initial states: time until the coordinate error
  first exceeds 0.1 and 0.5 (median and quartiles), beside the same figure for the exact system
  started 1e-6 off (the predictability limit);
* true-energy drift |E(t) - E(0)| / (V_max - V_min) of the model's rollouts (closed-form energy);
  for a scene with inputs or friction the power-balance error |E(t) - E(0) - W(t)| instead, the
  rollouts driven by the recorded inputs;
* inverse dynamics: the normalised RMSE of the torques the model needs for the data's accelerations;
* learned against true friction curves, and a free decay from rest with the inputs off;
* mass-matrix error against the scene's M (relative Frobenius after the best scale per system) and
  the condition number of the learned M (structured variants);
* the scene's out-of-distribution cases;
* open-loop horizons from many start points, driven by the recorded inputs;
* a stability table on the scene's hard cases (``lnn_torch.evaluation.stability``): non-finite fraction, max
  true-energy drift and the condition number of the learned mass matrix, including a long horizon
  of 1e5 RK4 steps.

A section the model or the scene cannot give (no mass matrix, no energy of its own, no closed form
of a measured system...) is listed at the end of the report with the reason. The report is what the
sections of ``lnn_torch.evaluation`` present: a new section appears here without an edit.

The checkpoint may be ``pretrained:<name>`` for a shipped model. ``--data`` defaults to the file the
checkpoint was trained on; where that is not there (a shipped model), the requested split alone is
generated from the specification the checkpoint records into the user's cache
(``$LNN_TORCH_CACHE``, default ``~/.cache/lnn_torch``) and read from there afterwards.
For the shipped model, ``lnn-torch evaluate pretrained:NAME --threads 1`` takes about 1.5 minutes
(the first time 6 s more, generating its 200 test trajectories) and writes its report to
``evaluation/NAME``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..evaluation.report import table_header
from .parser import CommandParser


def write_report(result: dict, output_dir: Path) -> list[Path]:
    """metrics.json, report.md and PNG plots: the header, then what each computed section presents
    (its rows of the main table, its own blocks, its figures) in order, then the skipped sections
    and why."""
    from ..evaluation.plots import evaluation_plots

    output_dir.mkdir(parents=True, exist_ok=True)
    clean = {k: v for k, v in result.items() if not k.startswith("_")}
    (output_dir / "metrics.json").write_text(json.dumps(clean, indent=2))
    pngs = evaluation_plots(result, output_dir)
    sections = result.get("_sections", {}).values()
    lines = [f"# Evaluation: {clean['variant']} on {clean.get('data', '?')} ({clean.get('split', '?')} split, "
             f"{clean['num_trajectories']} trajectories)", "",
             f"Rollouts: {clean['integrator']}, dt = {clean['dt']:g} s, horizon {clean['horizon_s']:g} s."
             + (f" Reference accelerations: {clean['reference']}." if clean.get("reference") else ""), "",
             *table_header(["metric", "value"])]
    for s in sections:
        lines += s.rows
    for s in sections:
        lines += s.blocks
    if clean.get("skipped"):
        lines += ["", "Skipped sections:", ""] + [f"* {name}: {why}" for name, why in clean["skipped"].items()]
    lines += ["", "Plots: " + ", ".join(p.name for p in pngs)]
    (output_dir / "report.md").write_text("\n".join(lines) + "\n")
    return [output_dir / "metrics.json", output_dir / "report.md", *pngs]


def _parser() -> argparse.ArgumentParser:
    ap = CommandParser(prog="lnn-torch evaluate", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", help="a .ckpt written by lnn-torch fit, or pretrained:<name> for a shipped model")
    ap.add_argument("--data", default=None, help="HDF5 dataset (default: the checkpoint's data path)")
    ap.add_argument("--split", default="test", choices=("train", "val", "test"))
    ap.add_argument("--integrator", default="rk4", help="rk4, rk8, leapfrog or semi_implicit_euler")
    ap.add_argument("--dt", type=float, default=None, help="rollout step, s (default: the data's)")
    ap.add_argument("--horizon", type=float, default=15.0, help="rollout length, s")
    ap.add_argument("--max-trajectories", type=int, default=None)
    ap.add_argument("--stability-seconds", type=float, default=5.0, help="horizon of the hard cases (0: skip them)")
    ap.add_argument("--long-horizon-steps", type=int, default=100_000,
                    help="RK4 steps of the long-horizon case (0: skip)")
    ap.add_argument("--output-dir", "-o", default=None, help="default: <checkpoint folder>/../evaluation")
    ap.add_argument("--sections", nargs="+", default=None, metavar="NAME",
                    help="the report's sections to compute (default: all of them; a section of one's own registered "
                         "with lnn_torch.evaluation.section, e.g. through LNN_TORCH_PLUGINS, is one)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--compile", action="store_true",
                    help="accelerations through torch.compile (compiled once per batch shape; falls back to eager)")
    return ap


def _data_file(saved: dict, split: str, resolved: str | None = None) -> str:
    """The checkpoint's dataset file (``saved``: its data hyper-parameters) where it exists, else its
    ``split`` alone from the user's cache (generated there from the specification it records, the
    first time); ``resolved``: the file's absolute path when the checkpoint was saved."""
    from ..data import DatasetSpec
    from ..data.cache import cached_split
    from ..errors import InputError

    path = saved.get("path")
    if path and Path(path).exists():
        return path
    if not saved.get("spec"):
        where = f" ({resolved} where it was trained)" if resolved and str(resolved) != str(path) else ""
        raise InputError(f"the checkpoint's data file {path}{where} is not there, and the checkpoint records no "
                         "specification to generate it from (the fit was given the file: an import, or one "
                         "generated apart): pass --data")
    return str(cached_split(DatasetSpec(**saved["spec"]), split, progress=True))


def _progress():
    """Prints each section as it starts, with the time since the first, to stderr (the report comes at
    the end; the long sections take a minute on one thread)."""
    import sys
    import time

    start = time.perf_counter()

    def tell(name: str) -> None:
        print(f"evaluate: {name} ({time.perf_counter() - start:.0f} s)", file=sys.stderr, flush=True)

    return tell


def main(argv: list[str]) -> int:
    from ..data import derivatives, read_dataset
    from ..errors import InputError
    from ..evaluation import evaluate_model, report_sections
    from ..perf import configure_cpu, quiet_compile_logs
    from ..training.checkpoint_format import DATA_PATH, data_hparams, output_dir, read_checkpoint
    from ..training.checkpoints import load_model
    from ..training.datamodule import TrajectoryDataModule

    args = _parser().parse_args(argv)
    configure_cpu(args.threads)
    quiet_compile_logs()
    module = load_model(args.checkpoint)
    if args.compile:
        module.model.compile_dynamics()
    saved = data_hparams(args.checkpoint)
    data = args.data or _data_file(saved, args.split, read_checkpoint(args.checkpoint).get(DATA_PATH))
    if args.data and not Path(args.data).exists():
        raise InputError(f"dataset file {args.data} does not exist (write it first, or leave --data out: the "
                         "model's own data file, a simulated scene's generated from its spec)")
    f = read_dataset(data)
    problem = module.system.mismatch(f.scene)
    if problem:
        raise InputError(f"{data} does not fit the checkpoint's model of '{module.system.name}': the file holds "
                         f"{problem}")
    # the reference as in training: the file's accelerations, or the checkpoint's derivative estimates
    dm = TrajectoryDataModule(path=str(data), spec=None if f.measured else dict(f.spec),
                              targets=saved.get("targets", "file"))
    sections = report_sections()
    if args.sections:
        from ..evaluation import SECTIONS

        unknown = [n for n in args.sections if n not in SECTIONS]
        if unknown:
            raise InputError(f"--sections: no section {', '.join(map(repr, unknown))}; the sections: "
                             f"{', '.join(SECTIONS)}")
        sections = tuple(args.sections)
    result = evaluate_model(module.model, module.system, dm.trajectories(args.split, args.max_trajectories),
                            sections=sections, integrator=args.integrator, dt=args.dt, horizon=args.horizon,
                            stability_seconds=args.stability_seconds, long_horizon_steps=args.long_horizon_steps,
                            progress=_progress())
    targets = dm.targets
    if targets and targets.get("use_measured_velocity") and not _has_velocities(f):  # (as the fit said: the
        targets = {**targets, "use_measured_velocity": False}                        # positions, differentiated)
    result = {"checkpoint": args.checkpoint, "data": str(data), "split": args.split,
              "reference": derivatives.describe(targets), **result}
    out_dir = output_dir(args.checkpoint, args.output_dir, "evaluation")
    files = write_report(result, out_dir)
    print((out_dir / "report.md").read_text())
    print("wrote " + ", ".join(str(p) for p in files))
    return 0


def _has_velocities(f) -> bool:
    """Whether the dataset file ``f`` holds measured velocities (an import of positions alone holds NaN)."""
    import numpy as np

    try:
        return bool(np.isfinite(np.asarray(f.read("qd"))).any())
    except KeyError:
        return False
