"""What a correction of the configuration's forces learns across the real double pendulum's recordings.

The force residual beside the configuration does not pay in the leave-one-recording-out study
(``results/real_double_pendulum/cross_validation/residual/``), and it is trained with the physics, whose
constants can move to make room for it. This script asks the question without either: per fold of that
study, the configuration fitted without the held-out recording stays as it is, and a force correction
``Q_j = X_j w_j`` per joint (features ``X_j`` of the joint's own state and torque) is fitted by ridge
regression to the fold's training recordings (the acceleration residual, through the model's ``M^-1``:
the criterion's own metric), then judged on the held-out recording. The pooled held-out error of each
feature set is reported at every ridge weight; choosing the weight on these same held-out errors favours
the correction, so a set that still does not beat "no correction" cannot pay on these recordings.

    python scripts/real_pendulum_cv.py --settings "rigid chain + its gravity + static friction (the configuration)" \\
        --work data/real_cv -o /tmp/cv            # the folds' configurations (6 fits)
    python scripts/real_pendulum_corrections.py --work data/real_cv \\
        -o results/real_double_pendulum/cross_validation/residual

Writes ``corrections.md`` and ``corrections.json`` to ``--output-dir``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from _common import CONFIGURATION, SETTINGS, HelpFormatter, add_output_dir, fold_checkpoint, wrote

ROOT = Path(__file__).resolve().parents[1]
FEATURES = {
    "an offset": ("offset",),
    "friction shapes (tanh(v/0.02), tanh(v/0.2), v, v abs(v))": ("friction",),
    "friction shapes + an offset": ("offset", "friction"),
    "its angle's harmonics (k = 1-3)": ("angle",),
    "load-dependent friction (abs(tau) tanh(v/0.05), tau)": ("load",),
    "a torque gain (tau, tau abs(tau))": ("gain",),
    "friction shapes + an offset + harmonics": ("offset", "friction", "angle"),
    "all of the above": ("offset", "friction", "angle", "load", "gain"),
}
RIDGE = (1e-6, 1e-4, 1e-2, 1.0)  # times the number of rows, on standardised columns


def joint_features(r: dict, j: int, kinds) -> torch.Tensor:
    """The columns of joint ``j``'s correction from a recording's state ``r``."""
    q, v, tau = r["q"][:, j], r["qd"][:, j], r["tau"][:, j]
    cols = []
    if "offset" in kinds:
        cols += [torch.ones_like(v)]
    if "friction" in kinds:
        cols += [torch.tanh(v / 0.02), torch.tanh(v / 0.2), v, v * v.abs()]
    if "angle" in kinds:
        cols += [f(k * q) for k in (1, 2, 3) for f in (torch.sin, torch.cos)]
    if "load" in kinds:
        cols += [tau.abs() * torch.tanh(v / 0.05), tau]
    if "gain" in kinds:
        cols += [tau, tau * tau.abs()]
    return torch.stack(cols, -1)


def design(r: dict, kinds) -> torch.Tensor:
    """``(N * dof, columns)``: the change of the accelerations per unit of each weight, ``M^-1 e_j X_j``."""
    blocks = [r["Minv"][:, :, j:j + 1] * joint_features(r, j, kinds)[:, None, :] for j in range(r["q"].shape[1])]
    a = torch.cat(blocks, -1)
    return a.reshape(-1, a.shape[-1])


def recordings(model, path: Path, targets: dict, split: str) -> list[dict]:
    """Per recording of a fold file's split: the state, torques through the targets' filter (the fit's own
    ``targets``), ``M^-1`` and the configuration's acceleration residual."""
    from lnn_torch.training import TrajectoryDataModule

    data = TrajectoryDataModule(path=str(path), targets=targets).trajectories(split, smooth_inputs=True)
    out = []
    for b, n in enumerate(data.lengths.tolist()):
        q, qd, qdd, tau = (getattr(data, k)[b, :n].double() for k in ("q", "qd", "qdd", "tau"))
        p = data.params[b].double().expand(n, -1)
        residual = qdd - model.forward(q, qd, p, tau)
        out.append({"q": q, "qd": qd, "qdd": qdd, "tau": tau, "e": residual,
                    "Minv": torch.linalg.inv(model.mass_matrix(q, p))})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--work", default=str(ROOT / "data" / "real_cv"),
                    help="the cross-validation's folder of fold files and runs (scripts/real_pendulum_cv.py --work)")
    ap.add_argument("--setting", default=CONFIGURATION, choices=list(SETTINGS), metavar="NAME",
                    help="the setting of scripts/real_pendulum_cv.py whose fitted folds are corrected")
    add_output_dir(ap, str(ROOT / "results" / "real_double_pendulum" / "cross_validation" / "residual"),
                   "the folder of corrections.md and corrections.json")
    args = ap.parse_args()
    from lnn_torch import load_model
    from lnn_torch.training import data_hparams

    torch.set_grad_enabled(False)
    work = Path(args.work)
    folds = sorted(work.glob("fold_*.h5"))
    if not folds:
        raise SystemExit(f"no fold files (fold_*.h5) in {work}: run scripts/real_pendulum_cv.py --work {work} first")
    data = {}
    for path in folds:
        rec = path.stem.removeprefix("fold_")
        ckpt = fold_checkpoint(work, rec, args.setting)
        if not ckpt.exists():
            raise SystemExit(f"missing {ckpt}: fit the setting on every fold first")
        model, targets = load_model(str(ckpt)).model.double(), data_hparams(str(ckpt))["targets"]
        data[rec] = (recordings(model, path, targets, "train"), recordings(model, path, targets, "val")[0])
    result = {"work": str(work), "setting": args.setting, "none": {}, "sets": {}}
    ref = {rec: float(held["qdd"].pow(2).sum()) for rec, (_, held) in data.items()}
    none = {rec: float(held["e"].pow(2).sum()) for rec, (_, held) in data.items()}
    result["none"] = _summary(none, ref)
    for name, kinds in FEATURES.items():
        folds = {}  # per fold, once for every ridge weight: the normal equations and the held-out design
        for rec, (train, held) in data.items():
            A = torch.cat([design(r, kinds) for r in train])
            y = torch.cat([r["e"].reshape(-1) for r in train])
            sd = A.std(0).clamp_min(1e-12)
            An = A / sd
            folds[rec] = (An.T @ An, An.T @ y, len(y), sd, design(held, kinds), held["e"].reshape(-1))
        rows = {}
        for lam in RIDGE:
            err = {}
            for rec, (gram, rhs, n, sd, Ah, eh) in folds.items():
                w = torch.linalg.solve(gram + lam * n * torch.eye(len(sd), dtype=gram.dtype), rhs) / sd
                err[rec] = float((eh - Ah @ w).pow(2).sum())
            rows[f"{lam:g}"] = _summary(err, ref)
        result["sets"][name] = rows
        best = min(rows.values(), key=lambda r: r["pooled"])
        print(f"{name}: best pooled {100 * best['pooled']:.1f} % "
              f"(no correction {100 * result['none']['pooled']:.1f} %)", flush=True)
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "corrections.json").write_text(json.dumps(result, indent=1) + "\n")
    (out / "corrections.md").write_text(markdown(result))
    print(markdown(result))
    wrote(out / "corrections.md", out / "corrections.json")


def _summary(err: dict, ref: dict) -> dict:
    """Pooled and per-recording relative L2 errors from summed squared errors and references."""
    return {"pooled": float(np.sqrt(sum(err.values()) / sum(ref.values()))),
            "per_recording": {rec: float(np.sqrt(err[rec] / ref[rec])) for rec in err}}


def markdown(r: dict) -> str:
    from lnn_torch.evaluation import table_header, table_row

    recs = list(r["none"]["per_recording"])
    head = "\n".join(table_header(["correction", "ridge", "pooled", *recs]))

    def row(name: str, lam: str, s: dict) -> str:
        return table_row([name, lam, f"**{100 * s['pooled']:.1f} %**",
                          *(f"{100 * v:.1f} %" for v in s["per_recording"].values())])

    lines = ["# The real double pendulum: what a force correction of the configuration learns across recordings", "",
             "Leave-one-recording-out: each fold's configuration (fitted without the held-out recording) as it is, "
             "and with a linear force correction per joint fitted by ridge regression to the fold's training "
             "recordings; acceleration relative L2 error on the held-out recording, torques filtered alike "
             "(`python scripts/real_pendulum_corrections.py`).", "", head,
             row("none (the configuration)", "–", r["none"])]
    for name, rows in r["sets"].items():
        lam, best = min(rows.items(), key=lambda kv: kv[1]["pooled"])
        lines.append(row(name, lam, best))
    lines += ["", "Each correction's row is its best ridge weight, chosen on these held-out errors themselves (which "
              "favours the correction); `corrections.json` holds every weight."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
