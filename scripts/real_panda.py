"""The real Franka Panda: every model beside classical identification, per joint, in N m, on the held-out
window of its one recording (Gaz et al. 2019; ``../shared/data/real_panda/``, GPL-3.0: read from there,
never shipped).

The recording is imported with ``configs/import/real_panda.yaml``: the robot without its hand, armature
and damping zero as written; training 0.5-8.0 s, validation 8.0-10.5 s, test 10.5-13.8 s (the part of
the first period of the 13.33 s periodic motion that the rest of the recording does not repeat: samples
after 13.8 s repeat the first period, and no training sample lies in it). Every model is judged on
the same points with the same targets (the checkpoints' derivative estimates) against the measured
torques: the models trained by ``lnn-torch fit`` (each checkpoint given), classical least squares on
the base parameters with the same drive model (ordinary, weighted, physically consistent;
``lnn_torch.identification.classical_arm``) fitted on the training window, and the robot's description as shipped
and as matched to the robot (rigid body only: the description's damping is its only friction).

    lnn-torch import ../shared/data/real_panda/exciting_trajectory_1.csv.gz \\
        --config configs/import/real_panda.yaml -o data/real_panda.h5
    lnn-torch fit -c configs/real_panda.yaml --trainer.default_root_dir runs/real_panda/grey_box_vco
    python scripts/real_panda.py grey_box=runs/real_panda/grey_box_vco/lightning_logs/version_0/checkpoints/last.ckpt

Writes ``metrics.json``, ``README.md`` (the tables, with the commands given by ``--command``) and
``torques.png`` (measured and predicted torques of the first model on the held-out window) to
``--output-dir``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from _common import HelpFormatter, add_output_dir, wrote

MATCHED = {"source": "franka_panda", "remove": ["hand"], "armature": "zero", "damping": "zero"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("models", nargs="*", help="LABEL=CHECKPOINT, each trained on the imported recording")
    ap.add_argument("--data", default="data/real_panda.h5", help="the imported recording")
    ap.add_argument("--drive", default="viscous+coulomb+offset", help="the classical fits' drive model")
    ap.add_argument("--classical", nargs="*", default=["least squares", "weighted least squares",
                                                       "physically consistent"], help="the classical fits")
    ap.add_argument("--targets", default=None, help="derivative settings as JSON (default: the first checkpoint's)")
    ap.add_argument("--command", action="append", default=[], metavar="LABEL=COMMAND",
                    help="the command that trained a model, for the report's table (repeatable)")
    add_output_dir(ap, "real_panda", "the folder of metrics.json, README.md and torques.png")
    ap.add_argument("--note", default="", help="a paragraph that says what this comparison is, placed first "
                    "in README.md (the text after it describes the study as configs/real_panda.yaml runs it)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--feedback", action="store_true", help="also each model and classical fit with the robot's "
                    "feedback on its measured velocity (lnn_torch.identification.velocity_feedback: one gain per "
                    "joint on the "
                    "recorded velocity's part above the targets' band, fitted on the training window, kept where "
                    "validation prefers it): rows 'LABEL + velocity feedback'")
    ap.add_argument("--add", action="store_true", help="keep the rows of the output folder's metrics.json that "
                    "this run does not compute (with their commands), e.g. to add a model to the table")
    ap.add_argument("--open-loop", type=float, default=1.0, help="open-loop horizon (s): how long each model, "
                    "driven by the measured torques from a start every 0.25 s of the held-out window, stays "
                    "within 0.1 rad of the recording (censored there)")
    args = ap.parse_args()
    from lnn_torch import load_model
    from lnn_torch.data import points, read_dataset
    from lnn_torch.evaluation import torque_figure
    from lnn_torch.identification import (
        classical_torque,
        compare_on_arm,
        description_model,
        feedback_rows,
        fit_classical,
        model_torque,
    )
    from lnn_torch.perf import configure_cpu
    from lnn_torch.training import TrajectoryDataModule, data_hparams

    configure_cpu(args.threads)
    models = dict(item.split("=", 1) for item in args.models)
    targets = json.loads(args.targets) if args.targets else (
        data_hparams(next(iter(models.values())))["targets"] if models else
        {"method": "butterworth", "cutoff": 10.0, "order": 4, "use_measured_velocity": True})
    dm = TrajectoryDataModule(path=args.data, targets=targets)
    system = _system(read_dataset(args.data))
    train, val, test = (dm.trajectories(s) for s in ("train", "val", "test"))
    # the consistent fit's prior chosen on the validation window, as identify and the grey box's start choose it
    fits = fit_classical(system, train, drive=args.drive, methods=tuple(args.classical), val=val)
    # the anchor as the issue states it: least squares on all of 0.5-10.5 s (training and validation)
    fits.update({f"{k} (fitted on 0.5-10.5 s)": v for k, v in fit_classical(
        system, [train, val], drive=args.drive, methods=("least squares",)).items()})
    descriptions = {"description as shipped": description_model(system, "franka_panda"),
                    "description matched to the robot": description_model(system, MATCHED)}
    result = compare_on_arm(None, system, test, fits, descriptions, open_loop_limit=args.open_loop)
    on_val = compare_on_arm(None, system, val, fits, descriptions)
    figure = None
    modules = {label: load_model(path) for label, path in models.items()}
    for label, path in models.items():
        module = modules[label]
        on_test = compare_on_arm(module.model, system, test, {}, {}, open_loop_limit=args.open_loop)
        result["rows"][label] = {**on_test["rows"][module.model.variant],
                                 "checkpoint": path}
        on_val["rows"][label] = compare_on_arm(module.model, system, val, {}, {})["rows"][module.model.variant]
        carried = _carried(module.model, test, result["joints"])
        if carried:
            result["rows"][label]["carried"] = carried
        if figure is None:
            q, qd, qdd, tau, params = points(test)
            pred = model_torque(module.model)(q, qd, qdd, params)
            figure = {"t": torch.arange(len(q)) * dm.dt, "measured": tau, "predicted": pred,
                      "names": result["joints"]}
    for label, row in result["rows"].items():
        row["val_rms_mean"] = on_val["rows"][label]["rms_mean"]
    if args.feedback:
        predictors = {label: classical_torque(fit) for label, fit in fits.items()}
        predictors.update({label: model_torque(modules[label].model) for label in models})
        result["rows"].update(feedback_rows(dm, predictors, result["joints"]))
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    result["commands"] = dict(item.split("=", 1) for item in args.command)
    result.update(data=args.data, targets=targets)
    if args.add and (out / "metrics.json").exists():
        _merge(result, json.loads((out / "metrics.json").read_text()), out / "metrics.json")
    (out / "metrics.json").write_text(json.dumps(result, indent=2) + "\n")
    text = README.format(table=report(result), data=args.data, drive=args.drive)
    if args.note:
        title, rest = text.split("\n\n", 1)
        text = f"{title}\n\n{args.note}\n\n{rest}"
    (out / "README.md").write_text(text)
    paths = [out / "metrics.json", out / "README.md"]
    if figure is not None:
        fig = torque_figure(figure)
        fig.suptitle(f"{next(iter(models))} on the real Panda, held-out window 10.5-13.8 s", fontsize=10)
        fig.tight_layout()
        fig.savefig(out / "torques.png", dpi=100)
        paths.append(out / "torques.png")
    print(report(result))
    wrote(paths)


FEEDBACK = " + velocity feedback"


def _merge(result: dict, before: dict, path) -> None:
    """``--add``: the rows of an earlier ``metrics.json`` this run does not compute, with their commands (a
    recomputed row keeps its earlier command unless given again); an earlier feedback row of a recomputed
    model is dropped (it belonged to the earlier fit). Refused where the earlier table was judged on other
    data, targets or points."""
    for key in ("data", "targets", "test_points"):
        if key in before and before[key] != result[key]:
            raise SystemExit(f"--add: {path} was made with {key} {before[key]!r}, this run has {result[key]!r}; "
                             "write to another folder")
    for label, row in before["rows"].items():
        recomputed_base = label.endswith(FEEDBACK) and label[: -len(FEEDBACK)] in result["rows"]
        if label not in result["rows"] and not recomputed_base:
            result["rows"][label] = row
        if label in result["rows"] and label in before.get("commands", {}):
            result["commands"].setdefault(label, before["commands"][label])


def _carried(model, data, joints) -> dict | None:
    """What each of the model's residuals carries on ``data`` (``lnn_torch.networks.shares``): per joint,
    the RMS of the torque it adds to the inverse dynamics (N m) and its share of the model's torque; None
    for a model without residuals."""
    from lnn_torch.data import points
    from lnn_torch.networks import torque_shares

    if not getattr(model, "residual_names", tuple)():
        return None
    q, qd, qdd, tau, params = points(data)
    shares = torque_shares(model, q, qd, qdd, params, tau)
    return {name: {"rms": dict(zip(joints, r["rms"], strict=True)), "share": dict(zip(joints, r["share"], strict=True))}
            for name, r in shares["residuals"].items()}


def _system(f):
    from lnn_torch.systems import get_system

    scene = json.loads(f.attrs["scene_json"])
    return get_system("measured", **scene["config"])


README = """# The real Franka Panda: every model beside classical identification

One exciting trajectory of a real Panda with measured joint torques (Gaz et al. 2019; the recording is
GPL-3.0 and stays in `../shared/data/real_panda/`), imported as the robot was logged: the shipped
description without its hand, armature and damping zero as written (`configs/import/real_panda.yaml`).
The motion is periodic (13.33 s): samples after 13.8 s repeat the first period, so the held-out window
is 10.5-13.8 s, the part of the first period that no other sample repeats; the models train on
0.5-8.0 s and are chosen on 8.0-10.5 s (the classical fits train on 0.5-8.0 s too). Targets for every
row: velocities and accelerations from a zero-phase 4th-order 10 Hz Butterworth filter of the measured
velocities; errors against the measured torques, unfiltered. Open loop: the median (quartiles) over
starts every 0.25 s of the held-out window of how long each model, driven by the measured torques from
the recorded state, stays within 0.1 rad of the recorded joint angles (RK4 at 1 ms; censored at the
horizon).

Held-out joint-torque RMS error in N m (lower is better; sorted by the test mean):

{table}
The classical rows are least squares on the base parameters of the description's kinematic chain with
the drive model `{drive}` per joint (`lnn_torch.identification.classical_arm`): ordinary, weighted (each joint's
rows divided by its ordinary residual's standard deviation) and physically consistent (log-Cholesky
inertias pulled towards the description by a LogDet prior, its strength chosen among
`classical_arm.PRIORS` on the validation window). The grey box of `configs/real_panda.yaml` starts from
that consistent fit (`model.classical_start`, the default for an arm grey box trained on torques),
refines it by gradient and ends with the state the validation window prefers, the start included: on
this robot validation kept the start (its gradient steps, on the per-joint normalised Huber loss, raised
the validation error: the run's checkpoint lists each validation), so the grey box and the consistent fit
are the same model here. The rows "from the description" are the grey box trained before the classical
start existed (10,000 steps from the description: the command given). The descriptions are the rigid body alone
(their damping their only friction). `film_lnn` and DeLaN from the data alone are one model here: the
recording has no parameters to condition on, so FiLM and concatenation both vanish (same seed, same
weights); ten seconds of one robot are far too little for networks alone. A force residual trained with
the grey box (a network of the joint angles and velocities, zero at the start, L2 on its output layer;
or `local`, a network per joint of its own angle and velocity) does not pay on this robot: validation
prefers the grey box alone, and so does the held-out window. Why ([floor.md](floor.md), `python
scripts/real_panda_floor.py CHECKPOINT`): 0.22 N m of the grey box's 0.27 N m is the measured torque
above the targets' 10 Hz band, which no model of the filtered state predicts (targets filtered at
15-30 Hz make the error larger, so it is not motion the filter removed), and a ridge correction on any
features of the state, chosen on the validation window, lowers the held-out mean by at most 0.004 N m.
Part of that torque is a ripple locked to the joint angle: about 241 cycles per joint revolution on
joints 1-4, 10-16 ms behind the angle, 0.1-0.3 N m in amplitude on the training window (at this arm's
speeds 20-60 Hz, far above the targets' band). Its amplitude does not stay constant: fitted on the
training window, it is kept by validation on three joints and lowers the held-out mean to 0.268 N m
only. What is left is not a function of the state that 7.5 s of this robot can teach. Trained with the
grey box, a residual also moves its physics; trained alone beside the fitted grey box
(`--model.init_from` its checkpoint, `--model.train_only residual_force`: the physics stays as fitted),
the local residual comes closer (0.278 and 0.277 N m at L2 1e-2 and 1e-1) and validation even prefers
the second by 0.004 N m, but the held-out window does not: within what this one recording can tell
apart, no residual of the state pays. What the residuals carry (the table after the errors): trained
with the grey box, 0.06-0.47 N m on joints 1-4, of the order of the error they were to remove
(0.33-0.48 N m), and on joint 7 57-109 % of the model's torque (there they trade with the learned
friction); alone beside the fitted grey box, 0.02-0.17 N m.

**What does pay is the robot's feedback on its own measured velocity** (the rows `+ velocity feedback`,
`--feedback`; `lnn_torch.identification.velocity_feedback`). The torque above the band is not a function of the
filtered state, but most of it follows the recorded velocity's part above the band (recorded velocity
less the targets' smoothed one): per joint, the measured torque holds `-D` times it, with one gain `D`
fitted on the training window's error of each model and kept where the validation window prefers it.
The gains come out at 22-31 N m s/rad on joints 1-4 and 5-7 on joints 5-6 (`metrics.json`, each row's
`feedback`; fitted on each window alone 22-41 on joints 1-4 and 5-7 on 5-6: `floor.md`), the order of the damping
of the robot's joint impedance controller; the angles' own
derivative above the band predicts none of it ([floor.md](floor.md)): consistent with the controller
answering the velocity it measures with torque whose motion is too small to show in the angles. It is
not a force of the state, so it has no open loop and no place in a simulation: it is what a model of
the measured torque (identification, collision detection, external-torque estimation) should add
beside any rigid-body model. With it the grey box reaches 0.238 N m, least squares 0.263 (fitted on
0.5-10.5 s, 0.239): it helps every model alike. A feedback row's validation mean is on the window that
chose its gains. Every number:

    lnn-torch import ../shared/data/real_panda/exciting_trajectory_1.csv.gz \\
        --config configs/import/real_panda.yaml -o data/real_panda.h5
    # each fit of the table's command column, then
    python scripts/real_panda.py "LABEL=CHECKPOINT" ... --command "LABEL=COMMAND" ... -o results/real_panda
    # the rows with the velocity feedback, added to the table (the grey box's checkpoint)
    python scripts/real_panda.py "grey box + viscous+coulomb+offset=CHECKPOINT" --feedback --add -o results/real_panda

(`metrics.json` holds the normalised MSE per joint, the validation errors and the open-loop times too).
"""


def _open_loop(row: dict) -> str:
    """The median and quartiles of a row's open-loop times; '≥' where the median reached the horizon."""
    if "open_loop" not in row:
        return ""
    lo, mid, hi = row["open_loop"]["quartiles"]
    sign = "≥ " if mid >= row["open_loop"]["limit"] else ""
    return f"{sign}{mid:.2f} ({lo:.2f}-{hi:.2f})"


def report(result: dict) -> str:
    from lnn_torch.evaluation import table_header, table_row

    names = result["joints"]
    header = ["model", *names, "mean, test", "mean, validation", "open loop within 0.1 rad (s)", "command"]
    order = sorted(result["rows"], key=lambda k: result["rows"][k]["rms_mean"])
    lines = table_header(header)
    for name in order:
        r = result["rows"][name]
        cmd = result.get("commands", {}).get(name, "")
        lines.append(table_row([name, *(f"{r['rms'][n]:.2f}" for n in names), f"**{r['rms_mean']:.3f}**",
                                f"{r['val_rms_mean']:.3f}", _open_loop(r), f"`{cmd}`" if cmd else ""]))
    lines.append(table_row(["torque std of the data", *(f"{result['torque_std'][n]:.2f}" for n in names),
                            "", "", "", ""]))
    carriers = [(name, part, c) for name in order for part, c in result["rows"][name].get("carried", {}).items()]
    if carriers:
        lines += ["", "What each residual carries on the held-out window (`lnn_torch.networks.shares`: the RMS of the "
                  "torque it adds to the model's inverse dynamics, N m per joint; in brackets, its share of the "
                  "model's torque):", "", *table_header(["model", "residual", *names])]
        lines += [table_row([name, part, *(f"{c['rms'][n]:.3f} ({100 * c['share'][n]:.0f} %)" for n in names)])
                  for name, part, c in carriers]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
