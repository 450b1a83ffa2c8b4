"""LQR about the upright of the double pendulum, designed on a learned model at held-out parameter
sets, run on the true (nonlinear) double pendulum: does it stabilise wherever the LQR designed on the
truth does?

For each of ``--sets`` parameter sets drawn from the scene's sampler (a seed the training data do not
use), a ball of ``--starts`` initial states around the upright (angles within ``--ball`` rad, at
rest): the truth-designed LQR and the model-designed LQR (the same weights, digital at the control
rate) each run ``--seconds`` on the truth. A start counts as stabilised when both angles end within
0.01 rad of the upright. The model's Lagrangian, learned without inputs, is known only up to a scale
per parameter set: its LQR is designed with that scale calibrated from ``--calibration-seconds`` of
the true system driven by random torques (the recording a user makes), and, for comparison, without
calibration (scale 1).

    python scripts/control_lqr_family.py CHECKPOINT [--actuation full|pendubot|acrobot] [-o results/control]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import HelpFormatter, add_output_dir, wrote  # noqa: E402

MASKS = {"full": None, "pendubot": (True, False), "acrobot": (False, True)}


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("checkpoint", help="a double-pendulum model (path or pretrained:NAME) whose data cover the upright")
    ap.add_argument("--actuation", default="full", choices=sorted(MASKS))
    ap.add_argument("--sets", type=int, default=200, help="held-out parameter sets")
    ap.add_argument("--starts", type=int, default=8, help="initial states per set")
    ap.add_argument("--ball", type=float, default=0.1, help="initial angle offsets from the upright, rad")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--control-hz", type=float, default=500.0)
    ap.add_argument("--calibration-seconds", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=12345)
    add_output_dir(ap, "results/control", "folder of the report (Markdown and JSON)", old=())
    return ap


def main(argv=None) -> int:
    from lnn_torch import load_model
    from lnn_torch.control import LQR, calibrate_on, closed_loop, plant_of, wrap
    from lnn_torch.evaluation import table_header, table_row

    args = parser().parse_args(argv)
    torch.set_num_threads(1)
    module = load_model(args.checkpoint)
    system = module.system
    if system.name != "double_pendulum":
        raise SystemExit(f"the model is of scene '{system.name}', not the double pendulum")
    rng = np.random.default_rng(args.seed)
    S, K = args.sets, args.starts
    params = torch.tensor(system.sample_params(rng, S), dtype=torch.float64)
    mask = MASKS[args.actuation]
    true_plant = plant_of(system, actuation=mask)
    start = time.perf_counter()
    scales = calibrate_on(true_plant, plant_of(module, actuation=mask), params, args.calibration_seconds, args.seed)
    up = torch.full((S, 2), math.pi, dtype=torch.float64)
    weights = dict(Q=[10, 10, 1, 1], R=0.1, dt=1 / args.control_hz)
    designs = {"truth": LQR(true_plant, up, params, **weights),
               "model, calibrated scale": LQR(plant_of(module, actuation=mask, torque_scale=scales), up, params,
                                               **weights),
               "model, scale 1": LQR(plant_of(module, actuation=mask), up, params, **weights)}
    design_seconds = time.perf_counter() - start
    offsets = args.ball * (2 * torch.tensor(rng.uniform(size=(S, K, 2))) - 1)
    q0 = (up[:, None] + offsets).reshape(S * K, 2)
    p_rep = params.repeat_interleave(K, 0)
    ok = {}
    for name, lqr in designs.items():
        per_start = lqr.repeat_interleave(K)  # the same gains, one row per start
        ep = closed_loop(true_plant, per_start, q0, torch.zeros_like(q0), p_rep, args.seconds, 1 / args.control_hz,
                         substeps=2)
        final = wrap(ep["q"][:, -1] - per_start.q_eq, (True, True)).abs().amax(-1)
        ok[name] = (torch.nan_to_num(final, nan=math.inf) < 0.01).reshape(S, K)
    truth = ok["truth"]
    rows = {}
    for name in designs:
        if name == "truth":
            continue
        where = ok[name] | ~truth  # stabilises every start the truth's LQR stabilises
        rows[name] = {"sets_all_truth_starts_stabilised": float(where.all(1).double().mean()),
                      "starts_stabilised_of_truths": float(ok[name][truth].double().mean())}
    result = {"checkpoint": args.checkpoint, "actuation": args.actuation, "sets": S, "starts_per_set": K,
              "ball_rad": args.ball, "seconds": args.seconds, "control_hz": args.control_hz,
              "truth_starts_stabilised": float(truth.double().mean()), "models": rows,
              "torque_scale_median": float(scales.median()), "torque_scale_range": [float(scales.min()),
                                                                                     float(scales.max())],
              "seconds_total": time.perf_counter() - start, "design_seconds": design_seconds}
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"lqr_family_{args.actuation}"
    lines = [f"# LQR about the upright, {args.actuation} actuation: designed on the model, run on the truth", "",
             f"`python scripts/control_lqr_family.py {args.checkpoint} --actuation {args.actuation}` — {S} held-out "
             f"parameter sets, {K} starts each within {args.ball:g} rad of the upright, {args.seconds:g} s at "
             f"{args.control_hz:g} Hz; stabilised: both angles within 0.01 rad at the end.", "",
             f"The truth-designed LQR stabilises {100 * result['truth_starts_stabilised']:.1f} % of the starts.", "",
             *table_header(["design", "sets where it stabilises every start the truth's LQR does",
                            "starts stabilised of the truth's"])]
    lines += [table_row([name, f"{100 * r['sets_all_truth_starts_stabilised']:.1f} %",
                         f"{100 * r['starts_stabilised_of_truths']:.1f} %"]) for name, r in rows.items()]
    lines += ["", f"Calibrated torque scales (model units per N m): median {result['torque_scale_median']:.3g}, "
                  f"range {result['torque_scale_range'][0]:.3g}–{result['torque_scale_range'][1]:.3g} "
                  f"(from {args.calibration_seconds:g} s of random torques per set)."]
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    (out / f"{stem}.json").write_text(json.dumps(result, indent=2) + "\n")
    print("\n".join(lines))
    wrote(out / f"{stem}.md", out / f"{stem}.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
