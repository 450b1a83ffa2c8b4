"""What is left to learn on the real Panda: the grey box's held-out torque error beside the part of the
measured torque no model of the filtered state can predict, and what the state explains of the rest.

Five measurements on the recording's windows (``configs/import/real_panda.yaml``: training 0.5-8.0 s,
validation 8.0-10.5 s, held out 10.5-13.8 s), with a fitted grey box (``lnn-torch fit -c
configs/real_panda.yaml``):

1. **The torque above the targets' band**: the RMS per joint of the measured torque minus the same
   torque through the targets' own zero-phase low-pass (Butterworth, 10 Hz, 4th order in the config). A
   model reads velocities and accelerations filtered at that cutoff, so what the torque holds above
   it is error for every model unless it is motion the filter removed; item 2 tests that.
2. **The targets' cutoff**: the same fitted grey box judged with targets filtered at other cutoffs
   (nothing refitted): if the torque above 10 Hz were motion, higher cutoffs would lower the error.
3. **What the state explains**: per joint, ridge regression of the grey box's torque error on features
   of the state (the joint's own friction shapes, its load, its angle's harmonics, its acceleration;
   every joint's accelerations, velocities, angles), fitted on the training window, the ridge weight
   chosen on the validation window; the held-out error after the correction. A feature set that lowers
   it is what a residual of those inputs could learn from this recording; one that raises it is what a
   residual would overfit.
4. **A ripple locked to the joint angle**: per joint, the strongest component ``sin(k q(t - d) + phi)``
   of the grey box's training-window error over ``k`` in ``--ripple-k`` (cycles per joint revolution)
   and ``d`` in 0-20 ms (a delay between angle and torque), fitted at a constant amplitude on the
   training window and kept where it lowers the validation error; the held-out error after it. The
   torque error of the real Panda holds such a ripple (about 241 cycles per revolution on joints 1-4:
   well above the targets' band at the arm's speeds); whether it is a function of the state that this
   recording can teach is what the held-out row says.
5. **The robot's feedback on its measured velocity** (``lnn_torch.identification.velocity_feedback``): per joint, the
   grey box's torque error against the recorded velocity's part above the targets' band (recorded
   velocity less the targets' smoothed one), one gain per joint by least squares on the training window,
   kept where it lowers the validation error; the same with the velocity derived from the angles instead
   of the recorded one (the positions' derivative at a 200 Hz cutoff less the same at the targets'
   cutoff, ``use_measured_velocity: false``) tells whether the angles show that motion.

    python scripts/real_panda_floor.py runs/real_panda/grey_box_vco/lightning_logs/version_0/checkpoints/last.ckpt \\
        -o results/real_panda

Writes ``floor.md`` and ``floor.json`` to ``--output-dir``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from _common import HelpFormatter, add_output_dir, wrote

FEATURES = {
    "its own friction shapes (tanh(v/0.02), v, tanh(v/0.2), v abs(v))": ("fric",),
    "+ its load (abs of its gravity and of its torque, times tanh(v/0.02))": ("fric", "load"),
    "+ its angle's harmonics (k = 1-3)": ("fric", "pos"),
    "+ its acceleration": ("fric", "acc"),
    "+ every joint's acceleration": ("fric", "all_acc"),
    "+ every joint's velocity shapes": ("fric", "all_v"),
    "+ every joint's angle (sin, cos)": ("fric", "all_q"),
    "all of the above": ("fric", "load", "pos", "acc", "all_acc", "all_v", "all_q"),
}
RIDGE = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0)  # times the number of rows, on standardised features
DELAYS = np.arange(0.0, 0.0201, 0.002)  # s, between the angle and the ripple in the torque


def features(d: dict, j: int, kinds) -> torch.Tensor:
    """The columns (a constant first) of joint ``j``'s regression from the split's state ``d``."""
    q, v, a = d["q"][:, j], d["qd"][:, j], d["qdd"][:, j]
    cols = [torch.ones_like(v)]
    if "fric" in kinds:
        cols += [torch.tanh(v / 0.02), v, torch.tanh(v / 0.2), v * v.abs()]
    if "load" in kinds:
        cols += [d["g"][:, j].abs() * torch.tanh(v / 0.02), d["pred"][:, j].abs() * torch.tanh(v / 0.02)]
    if "pos" in kinds:
        cols += [f(k * q) for k in (1, 2, 3) for f in (torch.sin, torch.cos)]
    if "acc" in kinds:
        cols += [a]
    if "all_acc" in kinds:
        cols += list(d["qdd"].T)
    if "all_v" in kinds:
        cols += [*torch.tanh(d["qd"].T / 0.02), *d["qd"].T]
    if "all_q" in kinds:
        cols += [f(d["q"][:, i]) for i in range(d["q"].shape[1]) for f in (torch.sin, torch.cos)]
    return torch.stack(cols, -1)


def ridge_row(splits: dict, kinds) -> dict:
    """Per joint: the ridge weight chosen on validation and the held-out RMS after the correction."""
    test, val, weights = [], [], []
    for j in range(splits["train"]["q"].shape[1]):
        X, y = features(splits["train"], j, kinds), splits["train"]["r"][:, j]
        mu, sd = X.mean(0), X.std(0).clamp_min(1e-12)
        mu[0], sd[0] = 0.0, 1.0
        Xn = (X - mu) / sd
        held = {s: ((features(splits[s], j, kinds) - mu) / sd, splits[s]["r"][:, j]) for s in ("val", "test")}
        best = None
        for lam in RIDGE:
            w = torch.linalg.solve(Xn.T @ Xn + lam * len(y) * torch.eye(X.shape[1], dtype=X.dtype), Xn.T @ y)
            errs = {s: float((r - Z @ w).pow(2).mean().sqrt()) for s, (Z, r) in held.items()}
            if best is None or errs["val"] < best[1]["val"]:
                best = (lam, errs)
        weights.append(best[0])
        val.append(best[1]["val"])
        test.append(best[1]["test"])
    return {"test": test, "test_mean": float(np.mean(test)), "val_mean": float(np.mean(val)), "ridge": weights}


def ripple(splits: dict, ks: np.ndarray) -> dict:
    """Per joint: the training window's strongest angle-locked component ``k, d`` (module docstring, item
    4), its amplitude, whether validation keeps it, and the held-out RMS with it (kept) or without."""
    rows = {"k": [], "delay_ms": [], "amplitude": [], "kept": [], "test": [], "val": []}
    for j in range(splits["train"]["q"].shape[1]):
        err = {s: d["r"][:, j].numpy() for s, d in splits.items()}
        best = None
        for delay in DELAYS:
            th = splits["train"]["q"][:, j].numpy() - delay * splits["train"]["qd"][:, j].numpy()
            power = np.abs(np.exp(-1j * np.outer(ks, th)) @ (err["train"] - err["train"].mean()))
            if best is None or power.max() > best[0]:
                best = (power.max(), float(ks[power.argmax()]), float(delay))
        _, k, delay = best
        angle = {s: (d["q"][:, j] - delay * d["qd"][:, j]).numpy() for s, d in splits.items()}
        cols = {s: np.stack([np.ones_like(a), np.sin(k * a), np.cos(k * a)], -1) for s, a in angle.items()}
        w = np.linalg.lstsq(cols["train"], err["train"], rcond=None)[0]
        rms = {s: float(np.sqrt(np.mean((err[s] - cols[s] @ w) ** 2))) for s in ("val", "test")}
        kept = rms["val"] < float(np.sqrt(np.mean(err["val"] ** 2)))
        for s in ("val", "test"):
            rows[s].append(rms[s] if kept else float(np.sqrt(np.mean(err[s] ** 2))))
        rows["k"].append(k)
        rows["delay_ms"].append(1000 * delay)
        rows["amplitude"].append(float(np.hypot(w[1], w[2])))
        rows["kept"].append(kept)
    return {**rows, "test_mean": float(np.mean(rows["test"])), "val_mean": float(np.mean(rows["val"]))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("checkpoint", help="a grey box fitted on the imported recording")
    ap.add_argument("--data", default="data/real_panda.h5", help="the imported recording")
    ap.add_argument("--cutoffs", type=float, nargs="+", default=[5.0, 10.0, 15.0, 20.0, 30.0],
                    help="the targets' cutoffs to judge the grey box with (Hz)")
    ap.add_argument("--ripple-k", type=float, nargs=3, default=[200.0, 290.0, 0.05], metavar=("FROM", "TO", "STEP"),
                    help="the angle-locked ripple's search: cycles per joint revolution")
    add_output_dir(ap, "results/real_panda", "the folder of floor.md and floor.json")
    args = ap.parse_args()
    from lnn_torch import load_model
    from lnn_torch.data import points
    from lnn_torch.identification import feedback_band, velocity_feedback
    from lnn_torch.training import TrajectoryDataModule, data_hparams

    torch.set_grad_enabled(False)
    model = load_model(args.checkpoint).model.double()
    targets = data_hparams(args.checkpoint)["targets"]
    dm = TrajectoryDataModule(path=args.data, targets=targets)
    splits = {}
    for s in ("train", "val", "test"):
        q, qd, qdd, tau, p = points(dm.trajectories(s))
        pred = model.inverse(q, qd, qdd, p)
        splits[s] = {"q": q, "qd": qd, "qdd": qdd, "tau": tau, "pred": pred, "g": model.gravity(q, p),
                     "r": tau - pred}
    joints = splits["test"]["q"].shape[1]
    grey = splits["test"]["r"].pow(2).mean(0).sqrt().tolist()
    # 1. the measured torque above the targets' band, on the held-out window: the torque less the same
    # torque through the targets' own smoothing
    smoothed = points(dm.trajectories("test", smooth_inputs=True))[3]
    above = (splits["test"]["tau"] - smoothed).pow(2).mean(0).sqrt().tolist()
    # 2. the targets' cutoff
    cutoffs = {}
    for cut in args.cutoffs:
        other = TrajectoryDataModule(path=args.data, targets={**targets, "cutoff": cut})
        q, qd, qdd, tau, p = points(other.trajectories("test"))
        cutoffs[cut] = (tau - model.inverse(q, qd, qdd, p)).pow(2).mean(0).sqrt().tolist()
    # 3. what the state explains
    ridge = {name: ridge_row(splits, kinds) for name, kinds in FEATURES.items()}
    # 4. an angle-locked ripple
    locked = ripple(splits, np.arange(*args.ripple_k))
    # 5. the robot's feedback on its measured velocity, and the same from the angles' own derivative
    bands = {"the recorded velocity": {s: feedback_band(dm, s) for s in splits}}
    # the angles' own: their derivative at 200 Hz less their derivative through the targets' smoothing
    from_angles = {**targets, "use_measured_velocity": False}
    fine, smooth = (TrajectoryDataModule(path=args.data, targets={**from_angles, **cut})
                    for cut in ({"cutoff": 200.0}, {}))
    bands["the angles' derivative"] = {s: points(fine.trajectories(s))[1] - points(smooth.trajectories(s))[1]
                                       for s in splits}
    feedback = {}
    for name, b in bands.items():
        fb = velocity_feedback.fit(splits["train"]["r"], b["train"], splits["val"]["r"], b["val"])
        test = (splits["test"]["r"] + b["test"] * fb.gains).pow(2).mean(0).sqrt().tolist()
        alone = {s: velocity_feedback.least_squares(splits[s]["r"], b[s]).tolist() for s in splits}
        feedback[name] = {**fb.report(), "test": test, "test_mean": float(np.mean(test)),
                          "val_mean": float(np.mean(fb.val_rms_after)), "gains_per_window": alone}
    result = {"checkpoint": args.checkpoint, "targets": targets, "grey_box_test": grey, "above_cutoff": above,
              "cutoffs": {str(k): v for k, v in cutoffs.items()}, "ridge": ridge, "ripple": locked,
              "feedback": feedback}
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "floor.json").write_text(json.dumps(result, indent=1) + "\n")
    (out / "floor.md").write_text(markdown(result, joints))
    print(markdown(result, joints))
    wrote(out / "floor.md", out / "floor.json")


def _cells(values) -> list[str]:
    """A row's cells of per-joint values and their mean (in bold)."""
    return [*(f"{v:.3f}" for v in values), f"**{np.mean(values):.3f}**"]


def _head(joints: int, extra: tuple[str, ...] = ()) -> str:
    from lnn_torch.evaluation import table_header

    return "\n".join(table_header(["", *(f"joint{j + 1}" for j in range(joints)), "mean", *extra]))


def markdown(r: dict, joints: int) -> str:
    from lnn_torch.evaluation import table_header, table_row

    t = r["targets"]
    lines = ["# The real Panda: what is left to learn", "",
             "Held-out window 10.5-13.8 s, N m RMS per joint (`python scripts/real_panda_floor.py CHECKPOINT`; "
             f"the grey box `{r['checkpoint']}`; targets: {t['method']}, {t['cutoff']:g} Hz, order {t['order']}).",
             "", _head(joints),
             table_row(["the grey box's torque error", *_cells(r["grey_box_test"])]),
             table_row([f"the measured torque above {t['cutoff']:g} Hz (less its targets' low-pass)",
                        *_cells(r["above_cutoff"])]),
             "", "The same grey box (nothing refitted) judged with targets filtered at other cutoffs:", "",
             _head(joints)]
    lines += [table_row([f"{k} Hz", *_cells(v)]) for k, v in r["cutoffs"].items()]
    lines += ["", "The grey box's error after a ridge correction on features of the state, fitted on the training "
              "window, its weight chosen on the validation window (validation mean in the last column):", "",
              _head(joints, ("validation",))]
    lines += [table_row([name, *_cells(row["test"]), f"{row['val_mean']:.3f}"]) for name, row in r["ridge"].items()]
    if "ripple" in r:
        rp = r["ripple"]
        lines += ["", "An angle-locked ripple `a sin(k q(t - d) + phi)` per joint: its training window's strongest "
                  "component (cycles per revolution k, delay d) at a constant amplitude, kept where it lowers the "
                  "validation error:", "", _head(joints, ("validation",)),
                  table_row(["k (cycles per revolution)", *(f"{k:.1f}" for k in rp["k"]), "", ""]),
                  table_row(["delay d (ms)", *(f"{d:.0f}" for d in rp["delay_ms"]), "", ""]),
                  table_row(["amplitude on the training window", *(f"{a:.3f}" for a in rp["amplitude"]), "", ""]),
                  table_row(["kept by validation", *("yes" if k else "no" for k in rp["kept"]), "", ""]),
                  table_row(["the grey box's error with it", *_cells(rp["test"]), f"{rp['val_mean']:.3f}"])]
    if "feedback" in r:
        lines += ["", "The robot's feedback on its measured velocity: the grey box's error against the velocity's part "
                  f"above {t['cutoff']:g} Hz, one gain D per joint (torque -D times that part; N m s/rad) fitted on "
                  "the training window, kept where it lowers the validation error:", "", _head(joints, ("validation",))]
        for name, fb in r["feedback"].items():
            lines += [table_row([f"D from {name}", *(f"{g:.1f}" for g in fb["gains"]), "", ""]),
                      table_row(["the grey box's error with it", *_cells(fb["test"]), f"{fb['val_mean']:.3f}"])]
        fb = next(iter(r["feedback"].values()))
        lines += ["", "The recorded velocity's gains fitted on each window alone (N m s/rad):", "",
                  *table_header(["window", *(f"joint{j + 1}" for j in range(joints))])]
        lines += [table_row([w, *(f"{g:.1f}" for g in gains)]) for w, gains in fb["gains_per_window"].items()]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
