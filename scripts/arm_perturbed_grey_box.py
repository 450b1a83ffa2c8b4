"""The open-loop time of a physics model of the 7-joint arm against its acceleration error: the grey box
(the description's rigid-body model, which equals the engine) with its inertial parameters perturbed by
known amounts, judged like the learned models (``scripts/arm_results.py``: the same rows, the same test
data). It asks whether the line of ``scripts/arm_open_loop_vs_error.py`` (open-loop time against
acceleration error, fitted to the learned models) is a property of the learned models or of the task: a
model of the exact form with a given acceleration error should stay within 0.1 rad about as long.

Each level perturbs the log-Cholesky parameters of every link's pseudo-inertia (``kinetic.spatial.raw``:
the logs of the factor's diagonal and its six upper entries; physically consistent for every value) by
Gaussian noise of the given standard deviation (for each seed, one draw scaled to every level: the
direction of the error matters as much as its size), nothing else (armature, friction and the payload's
exact conditioning as fitted):

    python scripts/arm_perturbed_grey_box.py --data data/robot_arm_seed11.h5 \\
        -o results/robot_arm/film_lnn/open_loop/perturbed_grey_box.md

Writes the table (Markdown) and its JSON (the format of ``scripts/arm_results.py``) beside it.
"""

from __future__ import annotations

import argparse
import copy

import torch
from _common import ROOT, HelpFormatter, add_output_file, add_row, evaluate_arm, save_arm_table

NOISE = (1e-4, 1.5e-4, 3e-4, 1e-3, 2e-3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--data", required=True, help="the arm's dataset (.h5); its test split is used")
    ap.add_argument("--checkpoint", default="pretrained:robot_arm_grey_box", help="the grey box to perturb")
    ap.add_argument("--noise", nargs="+", type=float, default=list(NOISE),
                    help="standard deviations of the noise on the raw inertial parameters")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2], help="seeds of the noise (a row each)")
    ap.add_argument("--test-trajectories", type=int, default=100, help="test trajectories (at most)")
    ap.add_argument("--horizon", type=float, default=3.0, help="rollout horizon, s")
    add_output_file(ap, str(ROOT / "results" / "robot_arm" / "film_lnn" / "open_loop" / "perturbed_grey_box.md"),
                    "the Markdown table (the JSON is written beside it)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    from lnn_torch import load_model
    from lnn_torch.data import read_dataset

    data = read_dataset(args.data)
    test = data.trajectories("test", args.test_trajectories)
    base = load_model(args.checkpoint)
    spatial = getattr(getattr(base.model, "kinetic", None), "spatial", None)
    if spatial is None or not hasattr(spatial, "raw"):
        raise SystemExit(f"{args.checkpoint} is not a grey box of a spatial arm (no kinetic.spatial.raw)")
    result = {"data": args.data, "num_test": len(test), "seconds": data.spec["duration"], "horizon": args.horizon,
              "rows": {}, "command": "python scripts/arm_perturbed_grey_box.py " + " ".join(
                  [f"--data {args.data}", f"--checkpoint {args.checkpoint}",
                   "--noise " + " ".join(f"{s:g}" for s in args.noise), "--seeds " + " ".join(map(str, args.seeds)),
                   f"--test-trajectories {args.test_trajectories} --horizon {args.horizon:g} --output {args.output}"])}
    for seed in args.seeds:
        noise = torch.randn(spatial.raw.shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
        for s in args.noise:
            module = copy.deepcopy(base)
            raw = module.model.kinetic.spatial.raw
            with torch.no_grad():
                raw.add_(s * noise.to(raw.dtype))
            add_row(result, f"grey box, inertials perturbed (noise {s:g}, seed {seed})",
                    evaluate_arm(module.model, module.system, test, args.horizon))
    save_arm_table(result, args.output)


if __name__ == "__main__":
    main()
