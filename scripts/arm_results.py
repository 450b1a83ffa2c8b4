"""Held-out results of trained models of the 7-joint arm (scene ``robot_arm``) through the one evaluation
pipeline (``lnn_torch.evaluation.evaluate_model``): inverse-dynamics torque error (normalised MSE per
joint, as Deep Lagrangian Networks report it, and its root), forward acceleration error, open-loop
rollouts driven by the recorded torques (median time within 0.1 rad of the engine's motion) and the
power-balance error, on the test split of each model's own dataset. For a perturbed arm the shipped
description itself, run by the engine (what a user with only the description has), is the first row.

    python scripts/arm_results.py --data data/robot_arm.h5 \\
        --model "film_lnn=results/benchmark/checkpoints/robot_arm_film_lnn.ckpt" \\
        --model "grey box=results/benchmark/checkpoints/robot_arm_grey_box.ckpt" --output results/robot_arm/nominal.md

Writes the table (Markdown) and its JSON beside it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from _common import HelpFormatter, add_output_file, add_row, evaluate_arm, save_arm_table

ROOT = Path(__file__).resolve().parents[1]


def description_row(system, test, horizon: float) -> dict:
    """The shipped (unperturbed) description in the engine against a perturbed arm's data."""
    from lnn_torch.evaluation import evaluate_model, normalized_rmse
    from lnn_torch.robots import MujocoArm
    from lnn_torch.systems import ClosedForm, get_system

    nominal = get_system("robot_arm", description=system.description)
    r = evaluate_model(ClosedForm(nominal), system, test, sections=("accelerations", "rollouts", "energy"),
                       accel_stride=5, horizon=horizon, thresholds=(0.1,))
    arm = MujocoArm(system.description)
    sub = slice(0, None, 5)
    B, T, dof = test.q[:, sub].shape
    flat = lambda x: x[:, sub].reshape(B * T, -1)  # noqa: E731
    params = test.params[:, None].expand(-1, T, -1).reshape(B * T, -1)
    pred = arm.inverse(flat(test.q), flat(test.qd), flat(test.qdd), params)
    err = normalized_rmse(pred, flat(test.tau).double())
    names = list(system.input_names)
    return {"acc_rel_err": r["acc_rel_err"]["total"],
            "torque_nmse": {"mean": float(err.pow(2).mean()),
                            **{n: float(e) ** 2 for n, e in zip(names, err, strict=True)}},
            "torque_nrmse": {"mean": float(err.mean()), **{n: float(e) for n, e in zip(names, err, strict=True)}},
            "time_to_0.1": r["divergence_time@0.1"]["model"], "power_balance_mean": r["power_balance_error"]["mean"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--data", required=True, help="the arm's dataset (.h5); its test split is used (--split)")
    ap.add_argument("--model", action="append", default=[], metavar="NAME=CHECKPOINT", help="a row (repeatable)")
    ap.add_argument("--description-row", action="store_true",
                    help="first row: the shipped description in the engine (for a perturbed arm's data)")
    ap.add_argument("--split", choices=("test", "val", "train"), default="test",
                    help="the split to judge on (val or train: how far a model fits the trajectories it saw)")
    ap.add_argument("--test-trajectories", type=int, default=100, help="the split's first trajectories (at most)")
    ap.add_argument("--horizon", type=float, default=3.0, help="rollout horizon, s")
    add_output_file(ap, str(ROOT / "results" / "robot_arm" / "table.md"),
                    "the Markdown table (the JSON is written beside it)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    from lnn_torch import load_model
    from lnn_torch.data import read_dataset
    from lnn_torch.systems import get_system

    data = read_dataset(args.data)
    spec = data.spec
    test = data.trajectories(args.split, args.test_trajectories)
    system = get_system("robot_arm", **spec.get("scene_config", {}))
    result = {"data": args.data, "split": args.split, "num_test": len(test), "seconds": spec["duration"],
              "horizon": args.horizon, "rows": {},
              "command": "python scripts/arm_results.py " + " ".join(
                  [f"--data {args.data}"] + ([f"--split {args.split}"] if args.split != "test" else [])
                  + (["--description-row"] if args.description_row else [])
                  + [f'--model "{m}"' for m in args.model]
                  + [f"--test-trajectories {args.test_trajectories} --horizon {args.horizon:g} "
                     f"--output {args.output}"])}
    if args.description_row:
        result["rows"]["shipped description (engine)"] = description_row(system, test, args.horizon)
    for item in args.model:
        name, _, path = item.partition("=")
        module = load_model(path)
        add_row(result, name, evaluate_arm(module.model, module.system, test, args.horizon))
    save_arm_table(result, args.output)


if __name__ == "__main__":
    main()
