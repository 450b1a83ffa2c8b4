"""Is a residual chosen by validation ever worse than the physics alone? Nested cross-validation on the
real double pendulum.

The residual of issue 37 is one that never hurts: it is kept only where validation says it pays. This
study judges that rule, not one fixed residual. The outer loop holds each non-test recording out in turn
(as ``scripts/real_pendulum_cv.py``); on the other five, an inner leave-one-recording-out
cross-validation fits every candidate (``--candidates``, names of that script's ``SETTINGS``: the first
is the physics alone) and a rule picks one (``choose``: the lowest pooled inner error, or the physics
alone unless a residual's paired inner-fold differences favour it by more than one standard error); the
pick, fitted on all five, predicts the
held-out recording, which no choice saw. The pooled error of those predictions is the rule's
cross-validated error, beside each candidate's own and beside classical least squares fitted to the same
five recordings (``RigidArmModel.fit_recordings``) and the lab's identified model; with
each model's open-loop time on the held-out recording (within 0.1 rad, driven by the recorded torques).

    python scripts/real_pendulum_nested_cv.py           # 42 fits, two at a time: about 45 min on two cores
    python scripts/real_pendulum_nested_cv.py --report-only

Writes ``nested.json`` and ``nested.md`` to ``--output-dir``; the fits stay in ``--work`` (a fit whose
checkpoint is there is not run again: delete the folder after changing the data or the config).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch
from _common import (
    CONFIGURATION,
    LAB,
    LEAST_SQUARES,
    PARAMS,
    SETTINGS,
    HelpFormatter,
    add_output_dir,
    fold_file,
    setting_arguments,
    squared_errors,
    wrote,
)

ROOT = Path(__file__).resolve().parents[1]
RESIDUAL = "the configuration + local force residual (L2 1)"
RULES = {"lowest": "chosen by inner cross-validation: the lowest pooled error",
         "one_se": "chosen by inner cross-validation: physics alone unless a residual is better by one standard error "
                   "of the paired differences"}


def choose(inner: dict, candidates: list[str]) -> dict[str, str]:
    """Each rule's choice from the inner folds' errors (``inner[candidate]``: per inner fold, (squared
    error, squared reference)). ``lowest``: the lowest pooled error (a tie keeps the earlier candidate).
    ``one_se``: the physics alone (the first candidate) unless another's relative error is lower on average
    over the inner folds by more than one standard error of the paired differences (a paired variant of
    the one-standard-error rule of model selection, which keeps the simplest model within one standard
    error of the best; paired because every candidate sees the same folds); of those that are, the
    lowest pooled error."""
    pooled = {s: float(np.sqrt(sum(e for e, _ in v) / sum(r for _, r in v))) for s, v in inner.items()}
    lowest = min(candidates, key=lambda s: (pooled[s], candidates.index(s)))
    base = np.sqrt([e / r for e, r in inner[candidates[0]]])
    better = []
    for s in candidates[1:]:
        d = np.sqrt([e / r for e, r in inner[s]]) - base
        if d.mean() + d.std(ddof=1) / np.sqrt(len(d)) < 0:
            better.append(s)
    one_se = min(better, key=lambda s: pooled[s]) if better else candidates[0]
    return {"lowest": lowest, "one_se": one_se}


def fit_folder(work: Path, train: list[str], setting: str) -> Path:
    """Where a setting's fit on the recordings ``train`` lives (beside it, its fold files ``held_NAME.h5``),
    named by a digest of the setting's options: a changed setting is fitted again, never mistaken for another."""
    digest = hashlib.sha1(json.dumps(SETTINGS[setting], sort_keys=True).encode()).hexdigest()[:12]
    return work / f"train_{'+'.join(train)}" / f"setting_{digest}"


def checkpoint(folder: Path) -> Path:
    return folder / "lightning_logs" / "version_0" / "checkpoints" / "last.ckpt"


def fit(args, names, train: list[int], held: int, setting: str) -> tuple[Path, Path, float]:
    """Fit ``setting`` on the recordings ``train`` (the fold file with ``held`` as its validation split,
    written beforehand); reused when its checkpoint exists. Returns the fold file, the checkpoint and the
    seconds taken (NaN when reused)."""
    train_names = [names[i] for i in train]
    folder = fit_folder(Path(args.work), train_names, setting)
    path = folder.parent / f"held_{names[held]}.h5"
    timing = folder / "fit_seconds.txt"
    if checkpoint(folder).exists():
        return path, checkpoint(folder), float(timing.read_text()) if timing.exists() else float("nan")
    if folder.exists():
        shutil.rmtree(folder)
    options, extra = setting_arguments(SETTINGS[setting])
    if SETTINGS[setting].get("beside") is not None:
        raise SystemExit(f"{setting}: a residual trained beside another fit is not a candidate here")
    cmd = [sys.executable, "-m", "lnn_torch.cli", "fit", "-c", args.config, f"--data.path={path}",
           f"--model.model_options={json.dumps(options)}", f"--trainer.default_root_dir={folder}",
           "--trainer.enable_progress_bar=false", "--trainer.limit_val_batches=0", *extra]
    start = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    if done.returncode != 0:
        raise SystemExit(f"fit failed ({setting} on {train_names}):\n{done.stderr[-3000:]}")
    seconds = time.perf_counter() - start
    timing.write_text(f"{seconds:.1f}\n")
    return path, checkpoint(folder), seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--data", default=str(ROOT / "data" / "real_double_pendulum.h5"), help="the imported recordings")
    ap.add_argument("--config", default=str(ROOT / "configs" / "real_double_pendulum.yaml"),
                    help="the training config every fit starts from")
    ap.add_argument("--candidates", nargs="+", default=[CONFIGURATION, RESIDUAL],
                    help="settings of scripts/real_pendulum_cv.py the rule chooses among, the physics alone first")
    ap.add_argument("--work", default=str(ROOT / "data" / "real_nested_cv"), help="fold files and training runs")
    ap.add_argument("--jobs", type=int, default=2, help="fits run at once (one thread each)")
    add_output_dir(ap, str(ROOT / "results" / "real_double_pendulum" / "cross_validation" / "nested"),
                   "the folder of nested.json and nested.md")
    ap.add_argument("--report-only", action="store_true", help="rewrite nested.md from the folder's nested.json")
    args = ap.parse_args()
    out = Path(args.output_dir)
    if args.report_only:
        write_report(json.loads((out / "nested.json").read_text()), out)
        wrote(out / "nested.md")
        return
    unknown = [s for s in args.candidates if s not in SETTINGS]
    if unknown:
        raise SystemExit(f"unknown settings {unknown}; choose from {list(SETTINGS)}")
    from lnn_torch import load_model
    from lnn_torch.data import read_dataset
    from lnn_torch.evaluation import evaluate_model
    from lnn_torch.identification import RigidArmModel
    from lnn_torch.perf import configure_cpu
    from lnn_torch.training import TrajectoryDataModule, data_hparams

    configure_cpu(1)
    source = read_dataset(args.data)
    names = json.loads(source.attrs["recordings"])
    pool = sorted(np.concatenate([source.splits["train"], source.splits["val"]]).tolist())
    # every (training recordings, held-out recording) pair the study predicts; a fit depends only on its
    # training recordings (the validation split is not read in training), so pairs with the same training
    # recordings share one fit per candidate: 15 inner and 6 outer training sets
    pairs = [(outer, inner) for outer in pool for inner in [None] + [i for i in pool if i != outer]]

    def training(pair) -> tuple[int, ...]:
        return tuple(i for i in pool if i not in pair)

    def held(pair) -> int:
        return pair[1] if pair[1] is not None else pair[0]

    for pair in pairs:  # every fold file once, before the fits share them
        folder = fit_folder(Path(args.work), [names[i] for i in training(pair)], args.candidates[0]).parent
        if not (folder / f"held_{names[held(pair)]}.h5").exists():
            fold_file(Path(args.data), folder / f"held_{names[held(pair)]}.h5", held(pair), list(training(pair)),
                      source.splits["test"])
    fits = list(dict.fromkeys((training(pair), held(pair), s) for pair in pairs for s in args.candidates))
    fits = list({(t, s): (t, h, s) for t, h, s in fits}.values())  # one per training set and candidate
    with ThreadPoolExecutor(args.jobs) as workers:
        done = dict(zip([(t, s) for t, _, s in fits],
                        workers.map(lambda job: fit(args, names, list(job[0]), job[1], job[2]), fits), strict=True))
    lab = RigidArmModel.from_yaml(PARAMS)

    @functools.cache
    def module_of(ckpt: Path):
        return load_model(str(ckpt))

    def held_out_data(pair, smooth: bool):
        """The pair's held-out recording (its torques filtered like the reference where ``smooth``)."""
        ckpt = done[(training(pair), args.candidates[0])][1]
        return TrajectoryDataModule(path=str(ckpt.parents[4] / f"held_{names[held(pair)]}.h5"),
                                    targets=data_hparams(str(ckpt)).get("targets", "file")).trajectories(
                                        "val", smooth_inputs=smooth)

    def model_of(pair, setting, model=None):
        """``model``, or ``setting``'s fit on the pair's training recordings."""
        return model if model is not None else module_of(done[(training(pair), setting)][1]).model

    def errors(pair, setting, model=None) -> tuple[float, float]:
        """Summed squared error and reference on the pair's held-out recording of ``setting``'s fit on its
        training recordings (or of ``model``)."""
        with torch.no_grad():
            return squared_errors(model_of(pair, setting, model), held_out_data(pair, smooth=True))

    def open_loop(pair, setting, model=None) -> list[float]:
        """The time (s) within 0.1 rad of the pair's held-out recording from each of its start points (every
        0.25 s, 4 s at most; driven by the recorded torques, RK4 at the data's step: the ``horizons`` section
        as ``scripts/real_pendulum.py`` runs it) of ``setting``'s fit (or of ``model``)."""
        system = module_of(done[(training(pair), args.candidates[0])][1]).system
        r = evaluate_model(model_of(pair, setting, model), system, held_out_data(pair, smooth=False),
                           sections=("horizons",), thresholds=(0.1,), start_every=0.25, time_limit=4.0)
        return r["_horizons_arrays"]["time_to@0.1"].tolist()

    def seen(pair):
        """The pair's training recordings (the torques filtered like the reference)."""
        path = fit_folder(Path(args.work), [names[i] for i in training(pair)], args.candidates[0]).parent
        return TrajectoryDataModule(path=str(path / f"held_{names[held(pair)]}.h5"),
                                    targets=data_hparams(str(done[(training(pair), args.candidates[0])][1]))
                                    .get("targets", "file")).trajectories("train", smooth_inputs=True)

    folds = {}
    for outer in pool:
        rest = [i for i in pool if i != outer]
        inner = {s: [errors((outer, i), s) for i in rest] for s in args.candidates}
        inner_pooled = {s: float(np.sqrt(sum(e for e, _ in v) / sum(r for _, r in v))) for s, v in inner.items()}
        chosen = choose(inner, args.candidates)
        fixed = {LAB: lab, **{name: RigidArmModel.fit_recordings(seen((outer, None)), space)
                              for space, name in LEAST_SQUARES.items()}}
        held_out = {s: errors((outer, None), s) for s in args.candidates}
        held_out.update({name: errors((outer, None), args.candidates[0], m) for name, m in fixed.items()})
        times = {s: open_loop((outer, None), s) for s in args.candidates}
        times.update({name: open_loop((outer, None), args.candidates[0], m) for name, m in fixed.items()})
        folds[names[outer]] = {
            "open_loop_times": times,
            "inner_pooled": inner_pooled,
            "inner_per_recording": {s: {names[i]: float(np.sqrt(e / r)) for i, (e, r) in zip(rest, v, strict=True)}
                                    for s, v in inner.items()},
            "chosen": chosen, "held_out_sums": {s: list(v) for s, v in held_out.items()}}
        print(f"held out {names[outer]}: inner "
              + ", ".join(f"{s[:40]} {100 * v:.1f} %" for s, v in inner_pooled.items())
              + "; chosen: " + ", ".join(f"{rule} {c[:40]} (held out {100 * np.sqrt(np.divide(*held_out[c])):.1f} %)"
                                         for rule, c in chosen.items()), flush=True)
    seconds = {s: [v[2] for (_, c), v in done.items() if c == s and not np.isnan(v[2])] for s in args.candidates}
    config = Path(args.config).resolve()
    result = {"config": str(config.relative_to(ROOT) if config.is_relative_to(ROOT) else config),
              "candidates": {s: SETTINGS[s] for s in args.candidates}, "folds": folds, "fit_seconds": seconds}
    out.mkdir(parents=True, exist_ok=True)
    (out / "nested.json").write_text(json.dumps(result, indent=1))
    write_report(result, out)
    wrote(out / "nested.json", out / "nested.md", Path(args.work))


def write_report(result: dict, out: Path) -> None:
    """``nested.md`` from the study's JSON (also printed)."""
    from lnn_torch.evaluation import table_header, table_row

    folds, candidates = result["folds"], list(result["candidates"])
    recs = list(folds)

    def pooled(sums):
        return 100 * float(np.sqrt(sum(e for e, _ in sums) / sum(r for _, r in sums)))

    rows = {name: [folds[rec]["held_out_sums"][name] for rec in recs]
            for name in [LAB, *LEAST_SQUARES.values(), *candidates] if name in folds[recs[0]]["held_out_sums"]}
    for rule, name in RULES.items():
        rows[name] = [folds[rec]["held_out_sums"][folds[rec]["chosen"][rule]] for rec in recs]
    lines = ["Nested leave-one-recording-out cross-validation (`python scripts/real_pendulum_nested_cv.py`): each "
             "recording held out in turn; on the other five, an inner leave-one-recording-out cross-validation "
             "picks a candidate by each rule (the lowest pooled inner error; or the physics alone unless a residual's "
             "error is lower on average over the inner folds by more than one standard error of the paired "
             "differences), which, fitted on all five, predicts the held-out recording. Least squares: the lab "
             "model's form fitted to the same five recordings. Every fit: "
             f"`lnn-torch fit -c {result['config']}` with the candidate's "
             "`model.model_options`. Acceleration relative L2 error against the filtered reference, torques "
             "filtered alike; pooled over the held-out recordings.", "",
             *table_header(["model", "pooled", *recs])]
    for name, sums in rows.items():
        lines.append(table_row([name, f"{pooled(sums):.1f} %", *(f"{100 * np.sqrt(e / r):.1f} %" for e, r in sums)]))
    if "open_loop_times" in folds[recs[0]]:
        times = {name: [folds[rec]["open_loop_times"][name] for rec in recs]
                 for name in [LAB, *LEAST_SQUARES.values(), *candidates]}
        for rule, name in RULES.items():
            times[name] = [folds[rec]["open_loop_times"][folds[rec]["chosen"][rule]] for rec in recs]
        lines += ["", "Open loop on the held-out recordings: the time within 0.1 rad from each start point (every "
                  "0.25 s, 4 s at most; driven by the recorded torques, RK4 at the data's 2 ms step), median over all "
                  "folds' start points and per recording:", "",
                  *table_header(["model", "all", *recs])]
        for name, per in times.items():
            lines.append(table_row([name, f"{np.median(np.concatenate(per)):.2f} s",
                                    *(f"{np.median(t):.2f} s" for t in per)]))
    lines += ["", "What the inner cross-validation saw (pooled over the five inner folds) and chose:", "",
              *table_header(["held out", *candidates, "chosen: lowest", "chosen: one standard error"])]
    for rec in recs:
        f = folds[rec]
        lines.append(table_row([rec, *(f"{100 * f['inner_pooled'][s]:.1f} %" for s in candidates),
                                f["chosen"]["lowest"], f["chosen"]["one_se"]]))
    text = "\n".join(lines) + "\n"
    (out / "nested.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
