"""Where a learned model of the 7-joint arm is wrong, part by part, against the engine.

On held-out trajectories of scene ``robot_arm``: per joint, the RMS of each part of the model's torque
error against a reference model (default: the shipped grey box, which equals the engine to 1e-9 N m):
the inertial torque ``(M - M_ref) qdd``, gravity ``g - g_ref``, Coriolis and centrifugal forces
``(n - g) - (n_ref - g_ref)`` and friction ``Q_f - Q_f_ref``, over all points and by payload mass; and in
open-loop rollouts driven by the recorded torques from each trajectory's first state, which joint is the
first to leave 0.1 rad and the RMS angle error of each joint at two times. It says which part of the
model the open-loop time waits on.

    python scripts/arm_error_parts.py --model pretrained:robot_arm_film_lnn --data data/robot_arm_seed11.h5

Writes ``error_parts.md`` and ``error_parts.json`` to ``--output-dir``.
"""

from __future__ import annotations

import argparse
import collections
import json
from pathlib import Path

import torch
from _common import ROOT, HelpFormatter, add_output_dir, wrote

BANDS = ((0.0, 0.5), (0.5, 1.5), (1.5, 2.5), (2.5, 3.0))  # payload mass bands (kg); the last one closed


def parts(model, q, qd, qdd, params) -> dict:
    """The model's torque parts (N m, ``(N, dof)`` each): inertial, gravity, Coriolis and friction."""
    M, g = model.mass_matrix(q, params), model.gravity(q, params)
    return {"inertial (M qdd)": (M @ qdd[..., None])[..., 0], "gravity": g,
            "Coriolis and centrifugal": model.bias(q, qd, params) - g, "friction": model.friction(q, qd, params)}


def rms(x: torch.Tensor) -> list[float]:
    return x.pow(2).mean(0).sqrt().tolist()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--model", default="pretrained:robot_arm_film_lnn", help="the learned model's checkpoint")
    ap.add_argument("--reference", default="pretrained:robot_arm_grey_box", help="the engine's stand-in")
    ap.add_argument("--data", default="data/robot_arm_seed11.h5", help="held-out trajectories")
    ap.add_argument("--trajectories", type=int, default=100, help="test trajectories used")
    ap.add_argument("--stride", type=int, default=5, help="every stride-th point for the torque parts")
    ap.add_argument("--threshold", type=float, default=0.1, help="the open-loop angle error (rad)")
    ap.add_argument("--times", type=float, nargs=2, default=(0.5, 0.9), help="when the angle errors are shown (s)")
    add_output_dir(ap, str(ROOT / "results" / "robot_arm" / "film_lnn" / "error_parts"),
                   "the folder of error_parts.md and error_parts.json")
    args = ap.parse_args()
    from lnn_torch import load_model
    from lnn_torch.data import points, read_dataset
    from lnn_torch.evaluation import evaluate_model

    torch.set_grad_enabled(False)
    module = load_model(args.model)
    model, ref = module.model.double(), load_model(args.reference).model.double()
    test = read_dataset(args.data).trajectories("test", args.trajectories)
    q, qd, qdd, _, params = points(test, args.stride)
    mine, truth = parts(model, q, qd, qdd, params), parts(ref, q, qd, qdd, params)
    mass = params[:, 0]
    bands = {f"{lo:g}-{hi:g} kg": (mass >= lo) & ((mass < hi) if hi < BANDS[-1][1] else (mass <= hi))
             for lo, hi in BANDS}
    errors = {name: {"all": rms(mine[name] - truth[name]),
                     **{b: rms(mine[name][m] - truth[name][m]) for b, m in bands.items() if m.any()}}
              for name in mine}
    size = {name: rms(t) for name, t in truth.items()}

    r = evaluate_model(model, module.system, test, sections=("accelerations", "rollouts"), accel_stride=args.stride,
                       thresholds=(args.threshold,))
    arrays = r["_arrays"]
    err = (arrays["q_model"] - arrays["q_true"]).abs()
    first = collections.Counter()
    for b in range(err.shape[0]):
        over = (err[b] > args.threshold).any(-1).nonzero()
        if len(over):
            first[f"joint{int(err[b, int(over[0])].argmax()) + 1}"] += 1
    at = {f"{t:g} s": rms(err[:, round(t / arrays["dt"])]) for t in args.times}
    result = {"model": args.model, "reference": args.reference, "data": args.data, "num_test": len(test),
              "acc_rel_err": r["acc_rel_err"], "time_to_threshold": r[f"divergence_time@{args.threshold:g}"]["model"],
              "reference_rms": size, "error_rms": errors, "first_joint_over": dict(first.most_common()),
              "angle_error_rms": at, "points_per_band": {b: int(m.sum()) for b, m in bands.items()},
              "command": "python scripts/arm_error_parts.py " + " ".join(
                  [f"--model {args.model}", f"--data {args.data}", f"--trajectories {args.trajectories}"])}
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "error_parts.json").write_text(json.dumps(result, indent=1) + "\n")
    (out / "error_parts.md").write_text(markdown(result, args.threshold))
    print(markdown(result, args.threshold))
    wrote(out / "error_parts.md", out / "error_parts.json")


def markdown(r: dict, threshold: float) -> str:
    from lnn_torch.evaluation import table_header, table_row

    dof = len(r["reference_rms"]["gravity"])
    joints = [f"joint {j + 1}" for j in range(dof)]

    lines = [f"`{r['model']}` against `{r['reference']}` on {r['num_test']} test trajectories of `{r['data']}` "
             f"(`{r['command']}`): acceleration error {100 * r['acc_rel_err']['total']:.2f} %, median time within "
             f"{threshold:g} rad {r['time_to_threshold']['median']:.2f} s.", "",
             "Torque error of each part, RMS per joint (N m); the reference's part in the first row of each:", "",
             *table_header(["part", "payload", *joints])]
    for name, by_band in r["error_rms"].items():
        lines.append(table_row([name, "(the reference's size)", *(f"{v:.3g}" for v in r["reference_rms"][name])]))
        for band, v in by_band.items():
            lines.append(table_row([name, band, *(f"{x:.3g}" for x in v)]))
    first = ", ".join(f"{j} {n}" for j, n in r["first_joint_over"].items())
    lines += ["", f"Open loop: the joint that first leaves {threshold:g} rad, per trajectory: {first}. Angle error, "
              "RMS over the trajectories (rad):", "", *table_header(["time", *joints])]
    lines += [table_row([t, *(f"{x:.3g}" for x in v)]) for t, v in r["angle_error_rms"].items()]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
