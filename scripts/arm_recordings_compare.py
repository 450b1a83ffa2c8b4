"""Held-out torque errors of models of the 7-joint arm trained on the simulated scene directly and on
the same trajectories written as CSV recordings and imported (``scripts/arm_recordings.py``, then
``lnn-torch import``): the inverse-dynamics torque error as the normalised MSE per joint (Deep
Lagrangian Networks' figure; ``lnn_torch.evaluation``'s torques section), on the test split, with two
references for the accelerations: the engine's (the scene file's ``qdd``, the truth) and the estimate
from the recorded velocities (``--targets``, as training without accelerations has them). Every
model is evaluated on the same trajectories, whichever file it was trained on; the script first checks
that the two files' test splits hold the same signals and parameters.

    python scripts/arm_recordings_compare.py --scene-data data/robot_arm.h5 \\
        --recordings-data data/robot_arm_recordings.h5 \\
        --model "grey box | scene=CKPT" --model "grey box | recordings=CKPT" -o results/arm_recordings/table.md

A model's name is ``MODEL | SOURCE``: rows with the same MODEL are compared (the ratio of the second
source's error to the first's). Writes the Markdown table and its JSON beside it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from _common import HelpFormatter, add_output_file, wrote

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {"method": "butterworth", "cutoff": 10.0, "order": 4, "use_measured_velocity": True}


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--scene-data", required=True, help="the generated dataset (.h5): the engine's accelerations")
    ap.add_argument("--recordings-data", required=True, help="the same trajectories imported from CSV (.h5)")
    ap.add_argument("--model", action="append", default=[], metavar="MODEL | SOURCE=CHECKPOINT",
                    help="a row (repeatable)")
    ap.add_argument("--targets", default=json.dumps(TARGETS),
                    help="the estimated accelerations' settings (JSON, lnn_torch.data.derivatives)")
    ap.add_argument("--stride", type=int, default=5, help="every so many points of each test trajectory")
    add_output_file(ap, str(ROOT / "results" / "arm_recordings" / "table.md"),
                    "the Markdown table (the JSON is written beside it)")
    return ap


def same_signals(scene, recordings) -> dict:
    """The largest differences between the two files' test splits as recorded, ``q, qd, tau, params``
    (0: the same values)."""
    out = {}
    for key in ("q", "qd", "tau", "params"):
        a, b = getattr(scene, key), getattr(recordings, key)
        if a.shape != b.shape:
            raise SystemExit(f"the test splits differ in {key}: {tuple(a.shape)} against {tuple(b.shape)}")
        out[key] = float((a - b).abs().max())
    return out


def weight_difference(weights: dict, first: dict) -> float | None:
    """The largest difference between two models' weights and buffers (None: not the same tensors)."""
    if weights.keys() != first.keys() or any(weights[k].shape != first[k].shape for k in weights):
        return None
    return max((float((weights[k] - first[k]).abs().max()) for k in weights if weights[k].numel()), default=0.0)


def torque_nmse(module, data, stride: int) -> dict:
    from lnn_torch.evaluation import evaluate_model

    result = evaluate_model(module.model, module.system, data,
                            sections=("torques",), accel_stride=stride)
    return result["torque_nmse"]


def markdown(result: dict) -> str:
    from lnn_torch.evaluation import table_header, table_row

    joints = result["joints"]
    lines = [f"Test split ({result['num_test']} trajectories, every {result['stride']}th point); the reference: "
             f"the recorded velocities with the engine's accelerations (`{result['scene_data']}`), or velocities and "
             f"accelerations estimated from the recorded velocities as training had them ({result['targets_text']}); "
             "the recorded torques. The two files' test splits differ by at most "
             f"{max(result['signal_difference'].values()):.3g} (q, qd, tau, params). "
             f"Command: `{result['command']}`", "",
             *table_header(["model", "trained on", "torque nMSE, engine's accelerations", "per joint (1-7)",
                            "torque nMSE, estimated accelerations",
                            "ratio to the model's first row (engine / estimated)", "largest weight difference to it"])]
    first: dict = {}  # each model's first row, the reference of its ratios
    for name, r in result["rows"].items():
        model, _, source = (s.strip() for s in name.partition("|"))
        true, est = r["engine"]["mean"], r["estimated"]["mean"]
        if model not in first:
            first[model] = (true, est)
            ratio = "1 (reference)"
        else:
            ratio = f"{true / first[model][0]:.4f} / {est / first[model][1]:.4f}"
        per_joint = " / ".join(f"{100 * r['engine'][j]:.3g}" for j in joints) + " %"
        weights = r["weight_difference"]
        weights = "—" if weights is None else f"{weights:.3g}"
        lines.append(table_row([model, source, f"**{100 * true:.4g} %**", per_joint, f"{100 * est:.4g} %", ratio,
                                weights]))
    return "\n".join(lines) + "\n"


def main() -> None:
    args = parser().parse_args()
    torch.set_num_threads(1)
    from lnn_torch import load_model
    from lnn_torch.data import derivatives, read_dataset
    from lnn_torch.training import TrajectoryDataModule

    targets = derivatives.settings(json.loads(args.targets))
    scene_file = read_dataset(args.scene_data)
    truth = scene_file.trajectories("test")
    difference = same_signals(truth, read_dataset(args.recordings_data).trajectories("test"))
    estimated = TrajectoryDataModule(path=args.recordings_data, targets=targets).trajectories("test")
    names = list(json.loads(scene_file.attrs["scene_json"])["input_names"])
    result = {"scene_data": args.scene_data, "recordings_data": args.recordings_data, "num_test": len(truth),
              "stride": args.stride, "targets": targets, "targets_text": derivatives.describe(targets),
              "signal_difference": difference, "joints": names, "rows": {},
              "command": "python scripts/arm_recordings_compare.py " + " ".join(
                  [f"--scene-data {args.scene_data} --recordings-data {args.recordings_data}"]
                  + [f'--model "{m}"' for m in args.model] + [f"--output {args.output}"])}
    firsts: dict = {}  # each model's first row's weights
    for item in args.model:
        name, _, path = item.rpartition("=")
        module = load_model(path)
        rows = {}
        for ref, data in (("engine", truth), ("estimated", estimated)):
            nmse = torque_nmse(module, data, args.stride)
            rows[ref] = {"mean": nmse["mean"], **{j: v for j, v in zip(names, (nmse[k] for k in nmse if k != "mean"),
                                                                         strict=True)}}
        model = name.partition("|")[0].strip()
        weights = {k: v.detach().double() for k, v in module.model.state_dict().items()}
        first = firsts.setdefault(model, weights)
        result["rows"][name] = {**rows, "checkpoint": path, "scene": module.system.name,
                                "weight_difference": weight_difference(weights, first)}
        print(name, json.dumps({k: round(float(v["mean"]), 10) for k, v in rows.items()}), flush=True)
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(markdown(result))
    out.with_suffix(".json").write_text(json.dumps(result, indent=1, default=float))
    print(markdown(result))
    wrote(out, out.with_suffix(".json"))


if __name__ == "__main__":
    main()
