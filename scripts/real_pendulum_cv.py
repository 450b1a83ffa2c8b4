"""Leave-one-recording-out cross-validation of model settings on the real double pendulum.

The held-out test recordings of ``configs/import/real_double_pendulum.yaml`` stay out of it. Each of the
other recordings (training and validation) is held out in turn; for every setting (its
``model.model_options`` and any other overrides of the config, ``SETTINGS``), ``lnn-torch fit -c
configs/real_double_pendulum.yaml`` trains on the rest and the held-out recording is predicted: the
acceleration error against the filtered reference with the torques through the same filter (as
``scripts/real_pendulum.py`` leads with), beside the lab's identified model. The criterion is the pooled
relative L2 error over all folds (every recording's squared errors summed, then divided by the summed
squared reference). One validation recording of moderate swings says little about angles and speeds no
other recording reaches; holding out each recording in turn, the high-energy one included, does. The
fits skip Lightning's validation (``--trainer.limit_val_batches=0``: open-loop rollouts that cost more
than the training and change nothing in it); the study evaluates each held-out recording itself.

    lnn-torch import lnn_torch/datasets/real_double_pendulum/recordings/*.csv.gz \\
        --config configs/import/real_double_pendulum.yaml -o data/real_double_pendulum.h5
    python scripts/real_pendulum_cv.py      # about 35-65 s per fit on one thread, alone on the machine
    python scripts/real_pendulum_cv.py --define NAME '{"model_options": {...}, "args": ["--model.lr=1e-2"]}' \
        --folds sysid_04 sysid_12          # a setting of your own on some folds: printed, not saved
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch
from _common import (
    LAB,
    LEAST_SQUARES,
    PARAMS,
    SETTINGS,
    HelpFormatter,
    add_output_dir,
    fold_checkpoint,
    fold_file,
    run_folder,
    setting_arguments,
    squared_errors,
    wrote,
)

ROOT = Path(__file__).resolve().parents[1]


def carried(model, data) -> dict | None:
    """What the model's residuals carry on a split's recordings (``lnn_torch.networks.shares``, over their
    own lengths): ``n`` points, and per residual, per motor, the sums of squares of its torque and of the
    model's (N m^2: pooled over folds by adding); None for a model without residuals."""
    from lnn_torch.data import points
    from lnn_torch.networks import torque_shares

    if not getattr(model, "residual_names", tuple)():
        return None
    q, qd, qdd, tau, params = points(data)
    shares = torque_shares(model, q, qd, qdd, params, tau)
    n = len(q)
    return {"n": n, "model": [n * r * r for r in shares["model_rms"]],
            "residuals": {name: [n * r * r for r in s["rms"]] for name, s in shares["residuals"].items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--data", default=str(ROOT / "data" / "real_double_pendulum.h5"), help="the imported recordings")
    ap.add_argument("--config", default=str(ROOT / "configs" / "real_double_pendulum.yaml"),
                    help="the training config every fit starts from")
    ap.add_argument("--settings", nargs="+", default=list(SETTINGS),
                    help="names of SETTINGS to compare (default: all)")
    ap.add_argument("--define", nargs=2, action="append", default=[], metavar=("NAME", "JSON"),
                    help="one more setting (model options, or {\"model_options\": ..., \"args\": [...]}), compared "
                         "as NAME; repeatable")
    ap.add_argument("--folds", nargs="+", default=None, help="hold out only these recordings (a quick look; "
                    "the pooled criterion needs them all)")
    ap.add_argument("--work", default=str(ROOT / "data" / "real_cv"), help="fold files and training runs")
    add_output_dir(ap, str(ROOT / "results" / "real_double_pendulum" / "cross_validation"),
                   "the folder of cross_validation.json and cross_validation.md")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--report-only", action="store_true",
                    help="rewrite cross_validation.md from the output folder's cross_validation.json")
    ap.add_argument("--add", action="store_true",
                    help="keep the other settings' results in the output folder's cross_validation.json (same folds "
                         "and config) and add these")
    args = ap.parse_args()
    if args.report_only:
        out = Path(args.output_dir)
        write_report(json.loads((out / "cross_validation.json").read_text()), out)
        wrote(out / "cross_validation.md")
        return
    for name, text in args.define:
        SETTINGS[name] = json.loads(text)
    if args.define and args.settings == list(SETTINGS)[:len(SETTINGS) - len(args.define)]:
        args.settings = [name for name, _ in args.define]  # only the defined ones unless others are named
    unknown = [s for s in args.settings if s not in SETTINGS]
    if unknown:
        raise SystemExit(f"unknown settings {unknown}; choose from {list(SETTINGS)}")
    from lnn_torch import load_model
    from lnn_torch.data import read_dataset
    from lnn_torch.identification import RigidArmModel
    from lnn_torch.perf import configure_cpu
    from lnn_torch.training import TrajectoryDataModule, data_hparams

    configure_cpu(args.threads)
    source = read_dataset(args.data)
    names = json.loads(source.attrs["recordings"])
    pool = sorted(np.concatenate([source.splits["train"], source.splits["val"]]).tolist())
    lab = RigidArmModel.from_yaml(PARAMS)
    work, out = Path(args.work), Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    # held-out recording: (squared error, squared reference)
    sums = {name: {} for name in [LAB, *LEAST_SQUARES.values(), *args.settings]}
    fitted = {name: {} for name in sums}  # the fold's training recordings, alike
    carries = {name: {} for name in args.settings}  # held-out recording: what the residuals carry there
    seconds = {name: [] for name in args.settings}
    written = []  # the fold files and the folders of their training runs
    if args.folds:
        pool_names = [names[i] for i in pool]
        if not set(args.folds) <= set(pool_names):
            raise SystemExit(f"--folds must name recordings of {pool_names}, got {args.folds}")
    for held in pool:
        rec = names[held]
        if args.folds and rec not in args.folds:
            continue
        path = work / f"fold_{rec}.h5"
        fold_file(Path(args.data), path, held, [i for i in pool if i != held], source.splits["test"])
        written += [path, work / f"fold_{rec}"]
        reference = None
        for setting in args.settings:
            run_dir = run_folder(work, rec, setting)
            if run_dir.exists():
                shutil.rmtree(run_dir)
            options, extra = setting_arguments(SETTINGS[setting])
            beside = SETTINGS[setting].get("beside")
            if beside is not None:
                base = fold_checkpoint(work, rec, beside)
                if not base.exists():
                    raise SystemExit(f"{setting}: fit {beside!r} on the fold {rec} first (in --work {work})")
                extra += [f"--model.init_from={base}", "--model.train_only=residual_force"]
            cmd = [sys.executable, "-m", "lnn_torch.cli", "fit", "-c", args.config, f"--data.path={path}",
                   f"--model.model_options={json.dumps(options)}", f"--trainer.default_root_dir={run_dir}",
                   "--trainer.enable_progress_bar=false", "--trainer.limit_val_batches=0", *extra]
            start = time.perf_counter()
            done = subprocess.run(cmd, capture_output=True, text=True)
            seconds[setting].append(time.perf_counter() - start)
            if done.returncode != 0:
                raise SystemExit(f"fit failed ({setting}, held out {rec}):\n{done.stderr[-3000:]}")
            ckpt = str(fold_checkpoint(work, rec, setting))
            module = load_model(ckpt)
            if reference is None:
                saved = data_hparams(ckpt)
                dm = TrajectoryDataModule(path=str(path), targets=saved.get("targets", "file"))
                reference = dm.trajectories("val", smooth_inputs=True)
                seen = dm.trajectories("train", smooth_inputs=True)
                sums[LAB][rec], fitted[LAB][rec] = squared_errors(lab, reference), squared_errors(lab, seen)
                for space, name in LEAST_SQUARES.items():
                    ls = RigidArmModel.fit_recordings(seen, space)
                    sums[name][rec], fitted[name][rec] = squared_errors(ls, reference), squared_errors(ls, seen)
            with torch.no_grad():
                sums[setting][rec] = squared_errors(module.model, reference)
                fitted[setting][rec] = squared_errors(module.model, seen)
                carries[setting][rec] = carried(module.model.double(), reference)
            e, r = sums[setting][rec]
            print(f"held out {rec}: {setting:36s} {100 * np.sqrt(e / r):6.1f} %  "
                  f"(lab {100 * np.sqrt(np.divide(*sums[LAB][rec])):.1f} %)",
                  flush=True)
    def pooled(per: dict) -> float:
        return float(np.sqrt(sum(e for e, _ in per.values()) / sum(r for _, r in per.values())))

    table = {name: {"per_recording": {rec: float(np.sqrt(e / r)) for rec, (e, r) in per.items()},
                    "pooled": pooled(per), "training_recordings_pooled": pooled(fitted[name])}
             for name, per in sums.items()}
    for name, per in carries.items():
        if any(c is not None for c in per.values()):
            table[name]["carried"] = pooled_carried(per)
    config = Path(args.config).resolve()
    config = str(config.relative_to(ROOT) if config.is_relative_to(ROOT) else config)
    result = {"config": config, "settings": {s: SETTINGS[s] for s in args.settings}, "fit_seconds": seconds,
              "results": table}
    if args.folds:  # a quick look at some folds: printed, never written over the study's files
        write_report(result, out, save=False)
        wrote(written)
        return
    previous = out / "cross_validation.json"
    if args.add and previous.exists():  # the other settings' earlier results, in SETTINGS order
        old = json.loads(previous.read_text())
        if old.get("config") != config or not _close(old["results"][LAB], table[LAB]):
            raise SystemExit(f"{previous} was made with other folds or another config: run without --add")
        order = [s for s in SETTINGS if s in old["settings"] or s in args.settings]
        settings = {**old["settings"], **result["settings"]}
        seconds = {**old["fit_seconds"], **seconds}
        results = {**old["results"], **table}
        result = {"config": config, "settings": {s: settings[s] for s in order},
                  "fit_seconds": {s: seconds[s] for s in order},
                  "results": {s: results[s] for s in [LAB, *LEAST_SQUARES.values(), *order] if s in results},
                  **({"note": old["note"]} if "note" in old else {})}
    (out / "cross_validation.json").write_text(json.dumps(result, indent=1))
    write_report(result, out)
    wrote(out / "cross_validation.json", out / "cross_validation.md", written)


def pooled_carried(per: dict) -> dict:
    """Per residual, its torque's RMS per motor over all folds' held-out recordings (N m) and its share of
    the model's torque there (the same RMS over the model's)."""
    n = sum(c["n"] for c in per.values())
    model = [sum(c["model"][j] for c in per.values()) for j in range(len(next(iter(per.values()))["model"]))]
    out = {}
    for name in next(iter(per.values()))["residuals"]:
        ss = [sum(c["residuals"][name][j] for c in per.values()) for j in range(len(model))]
        out[name] = {"rms": [math.sqrt(x / n) for x in ss],
                     "share": [math.sqrt(x / m) for x, m in zip(ss, model, strict=True)]}
    return out


def _close(a, b, rel: float = 1e-9) -> bool:
    """Whether two results (nested dicts of numbers) are the same up to the last bits of their floats."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k], rel) for k in a)
    return isinstance(a, (int, float)) and isinstance(b, (int, float)) and math.isclose(a, b, rel_tol=rel)


def write_report(result: dict, out: Path, save: bool = True) -> None:
    """``cross_validation.md`` from the study's JSON (printed; written unless ``save`` is False)."""
    from lnn_torch.evaluation import table_header, table_row

    table, seconds = result["results"], result["fit_seconds"]
    recs = list(table[LAB]["per_recording"])
    lines = [f"Leave-one-recording-out cross-validation over the non-test recordings ({', '.join(recs)}): each held "
             f"out in turn, `lnn-torch fit -c {result.get('config', 'configs/real_double_pendulum.yaml')}` on the "
             "rest with the setting's `model.model_options`; acceleration relative L2 error on the held-out recording "
             "against the filtered reference, torques filtered alike. Pooled: all folds' squared errors over all "
             "folds' squared reference (the criterion). Seen: the same error on each fold's own training "
             "recordings, pooled over the folds. Fit: wall-clock seconds of the whole command (one thread; other jobs "
             "may have shared the machine). `python scripts/real_pendulum_cv.py`", "",
             *table_header(["model", "pooled", *recs, "seen", "fit (s, median)"])]
    for name, r in table.items():
        fit = f"{np.median(seconds[name]):.0f}" if name in seconds else "–"
        seen = f"{100 * r['training_recordings_pooled']:.1f} %" if "training_recordings_pooled" in r else "–"
        lines.append(table_row([name, f"{100 * r['pooled']:.1f} %",
                                *(f"{100 * r['per_recording'][rec]:.1f} %" for rec in recs), seen, fit]))
    carriers = {name: r["carried"] for name, r in table.items() if r.get("carried")}
    if carriers:
        lines += ["", "What each residual carries on the held-out recordings (`lnn_torch.networks.shares`: the RMS "
                  "over all folds of the torque it adds to the model's inverse dynamics, per motor, N m; in brackets, "
                  "its share of the model's torque there):", "",
                  *table_header(["model", "residual", "motor 1", "motor 2"])]
        for name, carried_ in carriers.items():
            for part, c in carried_.items():
                lines.append(table_row([name, part, *(f"{r:.3f} ({100 * s:.1f} %)"
                                                      for r, s in zip(c["rms"], c["share"], strict=True))]))
    if result.get("note"):
        lines += ["", result["note"]]
    text = "\n".join(lines) + "\n"
    if save:
        (out / "cross_validation.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
