"""Record in a shipped model the farthest parameter it was trained on (``Normalizer.param_z_max``), where its
checkpoint was written before the normaliser recorded it.

A model warns that its answers are extrapolation beyond ``Normalizer.EXTRAPOLATION`` standard deviations of its
training parameters, or beyond 1.1 times the farthest of them where that is farther; a checkpoint without the
farthest warns only beyond ``EXTRAPOLATION_UNKNOWN`` (4), too late for uniformly drawn lengths (the shipped double
pendulum warned from l1 = 7.2 m; its error is 7.5 % at 2.7 times its longest training length). A shipped model's
card records its dataset's specification; the training split's parameters are drawn again from it (no trajectory
is integrated: seconds), checked against the normaliser's own mean and standard deviation (to 1e-6 of a standard
deviation: the same draws, or nothing is written), and their farthest is written into the checkpoint in place.

    python scripts/record_param_range.py double_pendulum double_pendulum_box double_pendulum_control \\
        robot_arm_film_lnn robot_arm_grey_box
"""

from __future__ import annotations

import argparse
import json

import torch
from _common import ROOT, HelpFormatter, wrote

from lnn_torch import load_model
from lnn_torch.data import DatasetSpec, sample_initial_conditions, split_indices

KEY = "model.normalizer.param_z_max"


def farthest(name: str) -> torch.Tensor:
    """``(P,)``: the farthest training parameter of shipped model ``name`` in its normaliser's standard
    deviations, from the training split its card's dataset specification draws."""
    card = json.loads((ROOT / "lnn_torch" / "pretrained" / f"{name}.json").read_text())
    spec = DatasetSpec(**card["datamodule_hyper_parameters"]["spec"])
    params, _, _ = sample_initial_conditions(spec, split_indices(spec)["train"])
    norm = load_model(f"pretrained:{name}").model.normalizer
    mean, std = norm.param_log_mean.double(), norm.param_log_std.double()
    z = (norm._transform(torch.from_numpy(params)) - mean) / std
    drift = float(torch.cat([z.mean(0).abs(), (z.std(0) - 1).abs()]).max())
    if drift > 1e-6:
        raise SystemExit(f"{name}: the parameters drawn from its card's specification are not those its normaliser "
                         f"was fitted on (mean or standard deviation off by {drift:.2g} standard deviations)")
    return z.abs().amax(0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("names", nargs="+", help="shipped models (lnn-torch list)")
    ap.add_argument("--overwrite", action="store_true", help="replace a farthest parameter already recorded")
    args = ap.parse_args()
    written = []
    for name in args.names:
        path = ROOT / "lnn_torch" / "pretrained" / f"{name}.ckpt"
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
        state = ckpt["state_dict"]
        if KEY in state and bool((state[KEY] != 0).any()) and not args.overwrite:
            print(f"{name}: its farthest training parameter is recorded already ({state[KEY].tolist()}); "
                  "--overwrite to draw it again")
            continue
        z = farthest(name)
        state[KEY] = z.to(state["model.normalizer.param_log_mean"].dtype)
        torch.save(ckpt, path)
        print(f"{name}: farthest training parameter {', '.join(f'{v:.3f}' for v in z.tolist())} standard deviations")
        written.append(path)
    wrote(*written)


if __name__ == "__main__":
    main()
