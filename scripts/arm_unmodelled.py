"""The 7-joint arm with physics its description cannot write (scene ``robot_arm``, scene option
``unmodelled``: Stribeck and load-dependent Coulomb friction, a nonlinear spring on joints 1-2, motor
cogging, a torque-sensor offset; ``lnn_torch.robots.unmodelled``), the truth known: the grey box of the
description (``kinetic: {spatial: {}}``, ``potential: {spatial: {}}``, learned joint friction) against
the grey box with residuals beside it (``--residuals``: ``parts``, a Cholesky MLP, a potential MLP and a
force residual ``Q_r`` of the whole state, each starting at zero, FiLM on the payload; ``alone``, that
force residual alone; ``local``, a force network per joint of its own angle, velocity and the payload;
``residual_force``), trained alike, the residual and its weight chosen by the validation split's
torque error (the grey box alone among the candidates: where no residual pays, the grey box is the
answer and the report says so).

Reported on the test split: the inverse-dynamics torque error (normalised MSE per joint, mean in
bold), open-loop rollouts driven by the recorded torques (median time within 0.1 rad); each effect's
share before and after: its torque RMS per joint, and how much of it each model still misses (per
joint, least squares of the model's torque error on the effects' torques, ``1`` = all of it missed, ``0``
= captured; pooled over joints weighted by the effect's torque variance) and its part of the model's
torque nMSE; and how much of the torque each residual carries (``lnn_torch.networks.shares``). The
description (the engine's arm without the effects, nothing learned) is the first row: it misses
every effect exactly.

    python scripts/arm_unmodelled.py -o /tmp/arm_unmodelled            # small: 200 x 2 s, 3,000 steps each
    python scripts/arm_unmodelled.py --harmonics 6 --trajectories 400 --steps 8000 --residuals parts local \\
        -o results/robot_arm/unmodelled                                  # the report

Writes ``README.md`` (the tables) and ``result.json`` to ``--output-dir``; the dataset goes to ``--data``
(default ``data/robot_arm_unmodelled_<N>x<duration>s.h5``, generated if absent).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from _common import ROOT, HelpFormatter, add_output_dir, wrote

EFFECTS = {"friction": {}, "spring": {}, "cogging": {}, "sensor_offset": {}}
GREY_BOX = {"kinetic": {"spatial": {}}, "potential": {"spatial": {}}}
# the residuals beside the grey box (--residuals) and their rows' names
KINDS = {"parts": "residual", "alone": "residual alone", "local": "local residual",
         "local_beside": "local residual trained alone beside it"}


def residual_options(weight: float, hidden: list[int], parts: bool, harmonics: int, local: bool = False) -> dict:
    """The grey box with its residuals: the force residual (``local``: a network per joint) and (``parts``)
    the kinetic and potential MLPs."""
    parts_spec = ({"kinetic": {"spatial": {}, "mlp": {}}, "potential": {"spatial": {}, "mlp": {}}} if parts
                  else dict(GREY_BOX))
    force = {"hidden": list(hidden), "weight": weight, "harmonics": harmonics, **({"local": True} if local else {})}
    return {**parts_spec, "residual_force": force}


# ---------------------------------------------------------------------------- training
def fit(model_options: dict, dm, scene_config: dict, args, save: Path | None = None,
        beside: Path | None = None) -> tuple:
    """A film_lnn with ``model_options`` trained as ``lnn-torch fit`` trains (acceleration and torque
    losses, the configs' optimiser and schedule) for ``args.steps`` steps; returns the module in
    evaluation mode and the training seconds. ``save``: its checkpoint; ``beside``: a checkpoint of the
    fitted grey box, whose weights start the run and stay as they are (only the force residual trains:
    ``init_from``, ``train_only: residual_force``)."""
    from lnn_torch import LNNModule
    from lnn_torch.training import make_trainer

    torch.manual_seed(args.seed)
    module = LNNModule(scene="robot_arm", scene_config=scene_config, variant="film_lnn", eps=0.0,
                       model_options=model_options, torque_weight=1.0, val_rollouts=0, lr=args.lr, lr_min=args.lr / 100,
                       **({"init_from": str(beside), "train_only": "residual_force"} if beside else {}))
    trainer = make_trainer(max_steps=args.steps, max_epochs=-1, limit_val_batches=0, num_sanity_val_steps=0,
                           enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
                           logger=False, callbacks=[], accelerator="cpu", devices=1)
    start = time.perf_counter()
    trainer.fit(module, dm)
    if save is not None:
        trainer.save_checkpoint(save)
    module.eval()
    return module, time.perf_counter() - start


# ---------------------------------------------------------------------------- evaluation
def points(data, stride: int) -> dict:
    """Every ``stride``-th point of a split's trajectories, flattened: q, qd, qdd, tau ``(N, 7)``, params."""
    from lnn_torch.data import points as flatten

    return dict(zip(("q", "qd", "qdd", "tau", "params"), flatten(data, stride), strict=True))


def nmse(pred: torch.Tensor, tau: torch.Tensor) -> list[float]:
    """Per joint: mean squared error over the data's variance."""
    return ((pred - tau).pow(2).mean(0) / tau.var(0)).tolist()


def effect_shares(err: torch.Tensor, effects: dict, tau: torch.Tensor) -> dict:
    """How much of each effect a torque error ``err (N, n)`` still holds: per joint, least squares of
    ``err`` on the effects' torques (columns where the effect acts) gives ``alpha_ej`` (1: all of it
    missed, 0: captured); ``missing``: ``alpha`` pooled over joints weighted by the effect's torque
    variance; ``nmse``: ``alpha_ej tau_ej``'s part of the mean-over-joints nMSE; ``rest``: the nMSE left
    when every effect's part is taken off (what no effect explains)."""
    names = list(effects)
    n = err.shape[1]
    var = tau.var(0)
    alpha = torch.full((len(names), n), float("nan"), dtype=torch.float64)
    rest = err.clone()
    for j in range(n):
        cols = [k for k, name in enumerate(names) if effects[name][:, j].abs().max() > 1e-9]
        if not cols:
            continue
        X = torch.stack([effects[names[k]][:, j] for k in cols], -1)
        coef = torch.linalg.lstsq(X, err[:, j:j + 1]).solution[:, 0]
        alpha[cols, j] = coef
        rest[:, j] = err[:, j] - X @ coef
    out = {}
    for k, name in enumerate(names):
        weight = effects[name].pow(2).sum(0)
        ok = ~torch.isnan(alpha[k])
        part = (alpha[k].nan_to_num() * effects[name]).pow(2).mean(0) / var
        out[name] = {"missing": float((alpha[k][ok] * weight[ok]).sum() / weight[ok].sum()),
                     "missing_per_joint": alpha[k].tolist(), "nmse": float(part.mean())}
    out["rest"] = {"nmse": float((rest.pow(2).mean(0) / var).mean())}
    return out


def rollout_times(model, system, test, horizon: float) -> dict:
    from lnn_torch.evaluation import evaluate_model

    r = evaluate_model(model, system, test, sections=("rollouts",), horizon=horizon, thresholds=(0.1,))
    return r["divergence_time@0.1"]["model"]


def evaluate(name: str, module, system, split: dict, test, args) -> dict:
    """A trained model's row: torque nMSE per joint, the effects still in its torque error, the rollouts,
    the residuals' torque shares."""
    from lnn_torch.networks import torque_shares

    model = module.model.double()
    with torch.no_grad():
        pred = model.inverse(split["q"], split["qd"], split["qdd"], split["params"])
    row = {"torque_nmse": nmse(pred, split["tau"]),
           "effects": effect_shares(split["tau"] - pred, split["effects"], split["tau"]),
           "shares": torque_shares(model, split["q"], split["qd"], split["qdd"], split["params"], split["tau"]),
           "time_to_0.1": rollout_times(model, system, test, args.horizon)}
    print(f"{name}: torque nMSE {100 * np.mean(row['torque_nmse']):.3g} %, within 0.1 rad for "
          f"{row['time_to_0.1']['median']:.2f} s", flush=True)
    return row


def description_row(system, split: dict, test, args) -> dict:
    """The engine's arm without the effects (the description, nothing learned)."""
    from lnn_torch.systems import ClosedForm, get_system

    nominal = get_system("robot_arm")
    pred = nominal.arm.inverse(split["q"], split["qd"], split["qdd"], split["params"])
    return {"torque_nmse": nmse(pred, split["tau"]),
            "effects": effect_shares(split["tau"] - pred, split["effects"], split["tau"]),
            "time_to_0.1": rollout_times(ClosedForm(nominal), system, test, args.horizon)}


def validation_nmse(module, val: dict) -> float:
    with torch.no_grad():
        pred = module.model.double().inverse(val["q"], val["qd"], val["qdd"], val["params"])
    return float(np.mean(nmse(pred, val["tau"])))


# ---------------------------------------------------------------------------- report
def markdown(result: dict) -> str:
    from lnn_torch.evaluation import pct, table_header, table_row

    rows = result["rows"]
    lines = [f"Test split of `{result['data']}` ({result['num_test']} trajectories of {result['duration']:g} s, "
             f"every {result['stride']}th point for the torques); rollouts with RK4 at the data's dt, driven by the "
             f"recorded torques, over {result['horizon']:g} s. Effects (seed {result['effects_seed']}): "
             f"{', '.join(result['effects'])}, defaults. Training: {result['steps']} steps each, batch "
             f"{result['batch']}, one thread. Command: `{result['command']}`", "",
             *table_header(["model", "torque nMSE, mean over joints", "per joint (1-7)", "validation torque nMSE",
                            "time within 0.1 rad, median (q25)", "training"])]
    for name, r in rows.items():
        t = r["time_to_0.1"]
        val = pct(r["val_nmse"]) if "val_nmse" in r else "-"
        train = f"{r['train_seconds'] / 60:.1f} min" if "train_seconds" in r else "-"
        lines.append(table_row([name, f"**{pct(np.mean(r['torque_nmse']))}**",
                                f"{' / '.join(f'{100 * v:.3g}' for v in r['torque_nmse'])} %", val,
                                f"{t['median']:.2f} s ({t['q25']:.2f})", train]))
    lines += ["", result["selection"], "", "Each effect before and after: its torque RMS per joint (N m), and the "
              "share of it each model's torque error still holds (1 = all of it missed, 0 = captured; least "
              "squares per joint, pooled weighted by the effect's variance), with its part of the model's torque "
              "nMSE (mean over joints) in brackets; `rest`: the nMSE no effect explains.", "",
              *table_header(["effect", "torque RMS per joint (N m)", *rows])]
    for effect, rms in result["effect_rms"].items():
        cells = [f"{r['effects'][effect]['missing']:.3g} ({pct(r['effects'][effect]['nmse'])})" for r in rows.values()]
        lines.append(table_row([effect, " / ".join(f"{v:.3g}" for v in rms), *cells]))
    lines.append(table_row(["rest", "", *(pct(r["effects"]["rest"]["nmse"]) for r in rows.values())]))
    lines += ["", "The torque each residual carries on the test split (RMS per joint, N m; beside the model's torque "
              "RMS):", "", *table_header(["model", "residual", "RMS per joint (N m)",
                                          "share of the model's torque, mean"])]
    for name, r in rows.items():
        shares = r.get("shares")
        if not shares:
            continue
        lines.append(table_row([name, "(model's torque)", " / ".join(f"{v:.3g}" for v in shares["model_rms"]), ""]))
        for res, s in shares["residuals"].items():
            lines.append(table_row([name, res, " / ".join(f"{v:.3g}" for v in s["rms"]), pct(s["share_mean"])]))
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- main
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--trajectories", type=int, default=200, help="trajectories of the dataset (80/10/10 %% split)")
    ap.add_argument("--duration", type=float, default=2.0, help="seconds per trajectory")
    ap.add_argument("--dt", type=float, default=0.005, help="sample interval (s)")
    ap.add_argument("--seed", type=int, default=0, help="the dataset's and the training's seed")
    ap.add_argument("--effects-seed", type=int, default=1, help="the seed of the effects' values")
    ap.add_argument("--data", default=None, help="the dataset (default: data/robot_arm_unmodelled_<N>x<duration>s.h5)")
    ap.add_argument("--steps", type=int, default=3000, help="optimiser steps per model")
    ap.add_argument("--batch", type=int, default=256, help="single points per batch (from as many trajectories)")
    ap.add_argument("--lr", type=float, default=3e-3, help="peak learning rate (cosine to lr / 100)")
    ap.add_argument("--weights", type=float, nargs="+", default=[1e-3],
                    help="the force residual's L2 weights to try (the validation split chooses)")
    ap.add_argument("--hidden", type=int, nargs="+", default=[64, 64], help="the force residual's hidden widths")
    ap.add_argument("--harmonics", type=int, default=1,
                    help="the force residual reads sin/cos of k times the angles, k <= this")
    ap.add_argument("--residuals", nargs="+", choices=list(KINDS), default=["parts"],
                    help="the residuals beside the grey box, each kind a candidate per weight: parts (a force "
                         "residual of the whole state and the kinetic and potential MLPs), alone (that force "
                         "residual alone), local (a force network per joint of its own angle, velocity and the "
                         "payload), local_beside (that network trained alone beside the fitted grey box)")
    ap.add_argument("--no-residual-parts", action="store_const", const=["alone"], dest="residuals",
                    help=argparse.SUPPRESS)  # the old spelling of --residuals alone
    ap.add_argument("--horizon", type=float, default=None, help="rollout horizon (s; default: --duration)")
    ap.add_argument("--stride", type=int, default=5, help="every stride-th point for the torque errors")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    add_output_dir(ap, ROOT / "results" / "robot_arm" / "unmodelled", "the folder of README.md and result.json")
    args = ap.parse_args()
    args.horizon = args.duration if args.horizon is None else args.horizon
    torch.set_num_threads(args.threads)

    from lnn_torch import TrajectoryDataModule
    from lnn_torch.evaluation import pct
    from lnn_torch.systems import get_system

    scene_config = {"unmodelled": {"seed": args.effects_seed, **EFFECTS}}
    path = Path(args.data or ROOT / "data" / f"robot_arm_unmodelled_{args.trajectories}x{args.duration:g}s.h5")
    spec = dict(scene="robot_arm", scene_config=scene_config, num_trajectories=args.trajectories,
                duration=args.duration, dt=args.dt, seed=args.seed)
    dm = TrajectoryDataModule(path=str(path), spec=spec, chunk_len=1, chunks_per_batch=args.batch,
                              steps_per_epoch=500, seed=args.seed)
    start = time.perf_counter()
    dm.prepare_data()
    print(f"data: {path} ({time.perf_counter() - start:.0f} s)", flush=True)
    system = get_system("robot_arm", **scene_config)
    val_t, test = dm.trajectories("val"), dm.trajectories("test")
    splits = {}
    for name, data in (("val", val_t), ("test", test)):
        split = points(data, args.stride)
        split["effects"] = system.effect_torques(split["q"], split["qd"], split["params"])
        splits[name] = split

    rows = {"description (engine, no effects, nothing learned)": description_row(system, splits["test"], test, args)}
    candidates = [("grey box", dict(GREY_BOX), None)]  # (row name, model options, residual kind)
    candidates += [(f"grey box + {KINDS[kind]} (weight {w:g})",
                    residual_options(w, args.hidden, kind == "parts", args.harmonics, kind.startswith("local")), kind)
                   for kind in args.residuals for w in args.weights]
    chosen, best = None, float("inf")
    with tempfile.TemporaryDirectory() as scratch:  # gone however the study ends
        grey_box = Path(scratch) / "grey_box.ckpt"  # what the residuals trained alone beside it start from
        for name, options, kind in candidates:
            print(f"fitting {name} ({args.steps} steps)", flush=True)
            module, seconds = fit(options, dm, scene_config, args, save=grey_box if kind is None else None,
                                  beside=grey_box if kind == "local_beside" else None)
            row = evaluate(name, module, system, splits["test"], test, args)
            row.update(val_nmse=validation_nmse(module, splits["val"]), train_seconds=seconds, options=options)
            rows[name] = row
            if row["val_nmse"] < best:
                chosen, best = name, row["val_nmse"]
    grey = rows["grey box"]
    if chosen == "grey box":
        selection = ("**Chosen by the validation split: the grey box alone** (no residual lowered its validation "
                     "torque error: here the residual does not pay).")
    else:
        cut = np.mean(grey["torque_nmse"]) / np.mean(rows[chosen]["torque_nmse"])
        selection = (f"**Chosen by the validation split: {chosen}** (validation torque nMSE {pct(best)} against the "
                     f"grey box's {pct(grey['val_nmse'])}); on the test split it cuts the grey box's torque nMSE "
                     f"{cut:.3g}x and holds 0.1 rad open loop for {rows[chosen]['time_to_0.1']['median']:.2f} s "
                     f"against {grey['time_to_0.1']['median']:.2f} s (median).")
    print(selection, flush=True)
    effect_rms = {name: t.pow(2).mean(0).sqrt().tolist() for name, t in splits["test"]["effects"].items()}
    result = {"data": str(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path), "num_test": len(test),
              "duration": args.duration, "horizon": args.horizon, "stride": args.stride, "steps": args.steps,
              "batch": args.batch, "effects_seed": args.effects_seed, "effects": list(EFFECTS),
              "effect_values": system.unmodelled.report(), "effect_rms": effect_rms, "chosen": chosen,
              "selection": selection, "rows": rows,
              "command": "python scripts/arm_unmodelled.py " + " ".join(sys.argv[1:])}
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "result.json").write_text(json.dumps(result, indent=1))
    (out / "README.md").write_text("# The arm with unmodelled effects\n\n" + markdown(result))
    wrote(out / "README.md", out / "result.json")


if __name__ == "__main__":
    main()
