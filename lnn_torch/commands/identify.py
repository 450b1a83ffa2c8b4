"""``lnn-torch identify``: which member of the model's family produced this recording?

Finds the physical parameters that make a trained (or shipped) parameter-conditioned model best
explain one observed trajectory (``lnn_torch.identification.learned``), reports what the observation can
and cannot determine, and puts the classical least-squares estimate on the scene's true equations
beside it where the scene has one.

    lnn-torch identify pretrained:double_pendulum data/double_pendulum.h5 --trajectory 3 --duration 2
    lnn-torch identify pretrained:double_pendulum observed.csv --coordinates theta1 theta2

A model of a measured robot arm (recordings imported with its robot description, no parameters to
find) is identified the way robotics labs do it instead: classical least squares on the base
parameters with the model's drive model (ordinary, weighted, physically consistent;
``lnn_torch.identification.arm_comparison``), fitted on the dataset's training split, beside the model, as the
held-out joint-torque error per joint in N m on ``--split`` (default test); ``--feedback`` adds each
with the robot's feedback on its measured velocity (``lnn_torch.identification.velocity_feedback``). A dataset
without a training split (a new log imported alone) gets the model's own error there, beside its description,
and the loads it carries identified against the model.

    lnn-torch identify runs/real_panda/.../last.ckpt data/real_panda.h5 --feedback

The recording is a trajectory of a dataset file (``--split``, ``--trajectory``; generated files know
the true parameters, and the report gives the errors) or a CSV file (a time column and a column per
coordinate, optionally velocities and inputs; lines starting with ``#`` are comments). Writes
``identification.json``, ``report.md`` and ``fit.png`` (observed and re-simulated coordinates) to
``--output-dir`` (default: per model and recording, ``_default_output``).
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..data.import_tools import correlation_block
from ..errors import InputError
from ..evaluation.report import markdown_table, number, pct, table_header, table_row
from ..mechanics.friction import DriveModel
from .parser import CommandParser


@dataclass
class Observation:
    """One observed trajectory in SI units (``t (T,)``, ``q``/``qd``/``qdd (T, dof)``, ``tau (T, n_u)``)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray | None
    tau: np.ndarray | None
    qdd: np.ndarray | None
    truth: dict | None  # the true parameters, where the file knows them
    source: str


def _parser() -> argparse.ArgumentParser:
    ap = CommandParser(prog="lnn-torch identify", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", help="a .ckpt written by lnn-torch fit, or pretrained:<name>")
    ap.add_argument("recording", help="a dataset file (.h5) or a CSV recording (.csv, .csv.gz)")
    rec = ap.add_argument_group("which part of the recording")
    rec.add_argument("--split", default="test", help="dataset split (.h5; default test)")
    rec.add_argument("--trajectory", type=int, default=0, help="trajectory index within the split (.h5)")
    rec.add_argument("--start", type=float, default=0.0, help="first time used, s after the recording's start")
    rec.add_argument("--duration", type=float, default=None, help="seconds used (default: all)")
    rec.add_argument("--use", choices=("q", "q+qd", "q+qd+qdd"), default="q+qd",
                     help="what is taken from the recording; the rest is estimated (default q+qd: positions and "
                          "velocities, as encoders give; accelerations only where the file has true ones)")
    csv = ap.add_argument_group("CSV columns")
    csv.add_argument("--time", default="t", help="time column, s (default t)")
    csv.add_argument("--coordinates", nargs="+", default=None, help="coordinate columns (default: the scene's names)")
    csv.add_argument("--velocities", nargs="+", default=None, help="velocity columns (default: none)")
    csv.add_argument("--inputs", nargs="+", default=None, help="input columns (default: the scene's input names)")
    fit = ap.add_argument_group("the fit")
    fit.add_argument("--method", choices=("acceleration", "trajectory", "both"), default="acceleration",
                     help="acceleration fit (default; fast), trajectory matching, or both in turn")
    fit.add_argument("--starts", type=int, default=4, help="random starts (default 4)")
    fit.add_argument("--steps", type=int, default=150, help="Adam steps per stage (default 150)")
    fit.add_argument("--window", type=float, default=0.2, help="multiple-shooting window, s (default 0.2)")
    fit.add_argument("--noise", type=float, default=0.0,
                     help="add Gaussian noise of this std to the observed positions (studies; default 0)")
    fit.add_argument("--seed", type=int, default=0)
    arm = ap.add_argument_group("a measured arm")
    arm.add_argument("--feedback", action="store_true",
                     help="also the model and each fit with the robot's feedback on its measured velocity (one gain "
                          "per joint on the recorded velocity above the targets' band, fitted on the training split, "
                          "kept where the validation split prefers it; lnn_torch.identification.velocity_feedback)")
    ap.add_argument("--output-dir", "-o", default=None,
                    help="where the report goes (default: per model and recording, so that another model or "
                         "recording keeps this one's report: <run>/identification/<recording> beside a fit's "
                         "checkpoints folder, identification/<name>/<recording> for pretrained:<name>; the split "
                         "and trajectory of a dataset file after its name)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1: the fit's operations are small)")
    return ap


def read_observation(path: str | Path, system, *, split: str = "test", trajectory: int = 0, start: float = 0.0,
                     duration: float | None = None, use: str = "q+qd", time: str = "t", coordinates=None,
                     velocities=None, inputs=None) -> Observation:
    """One trajectory of a dataset file or a CSV recording, cut to ``[start, start + duration]``."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    name = path.name.lower()
    if name.endswith((".h5", ".hdf5")):
        from ..data import read_dataset

        f = read_dataset(path)
        if f.num_inputs and not system.num_inputs:  # (the file's torques reached a model without inputs)
            raise InputError(f"{path}: the recordings of scene '{f.attrs['scene']}' are driven by inputs (torques), "
                             f"which a model of '{system.name}' has none of: identify them with a model of their scene")
        if split not in f.splits:
            raise InputError(f"{path}: no split '{split}' (splits: {', '.join(f.splits)})")
        index = f.splits[split]
        if not 0 <= trajectory < len(index):
            raise InputError(f"{path}: split '{split}' has {len(index)} trajectories; --trajectory {trajectory} "
                             "is out of range")
        tr = f.trajectories(split)
        j = trajectory
        length = tr.q.shape[1] if tr.lengths is None else int(tr.lengths[j])
        q, qd = tr.q[j, :length].double().numpy(), tr.qd[j, :length].double().numpy()
        qdd = None if tr.qdd is None else tr.qdd[j, :length].double().numpy()
        tau = None if tr.tau is None else tr.tau[j, :length].double().numpy()
        t = np.arange(length) * tr.dt
        truth = None
        if f.attrs["scene"] == system.name and not f.measured and tr.params.shape[1] == system.num_params:
            truth = {p: float(v) for p, v in zip(system.param_names, tr.params[j].double(), strict=True)}
        source = f"{path} (split {split}, trajectory {trajectory}, file index {int(index[j])})"
    elif name.endswith((".csv", ".csv.gz")):
        from ..data.tables import read_csv_columns
        from ..identification.learned import UNIFORM

        coordinates = list(coordinates or system.coord_names)
        if len(coordinates) != system.dof:
            raise InputError(f"{path}: {len(coordinates)} coordinate column(s) given, but scene '{system.name}' "
                             f"has {system.dof} coordinates ({', '.join(system.coord_names)})")
        if system.num_inputs:
            inputs = list(inputs or system.input_names)
        cols = [time, *coordinates, *(velocities or []), *(inputs or [])]
        data = read_csv_columns(path, cols)
        t, q = data[:, 0], data[:, 1:1 + system.dof]
        qd = data[:, 1 + system.dof:1 + 2 * system.dof] if velocities else None
        tau = data[:, 1 + system.dof * (2 if velocities else 1):] if inputs else None
        qdd, truth, source = None, None, str(path)
        steps = np.diff(t)
        if (steps <= 0).any() or np.abs(steps - steps.mean()).max() > UNIFORM * max(steps.mean(), 1e-12):
            raise InputError(f"{path}: the time column '{time}' is not uniformly sampled (resample it, e.g. with "
                             "lnn-torch import)")
    else:
        raise InputError(f"{path}: unknown recording type (use a dataset .h5 or a .csv / .csv.gz file)")
    if q.shape[1] != system.dof:
        raise InputError(f"{path}: the recording has {q.shape[1]} coordinate(s), but scene '{system.name}' has "
                         f"{system.dof}")
    t = t - t[0]
    keep = (t >= start - 1e-9) & (t <= (np.inf if duration is None else start + duration) + 1e-9)
    cut = lambda x: None if x is None else x[keep]  # noqa: E731
    parts = set(use.split("+"))
    return Observation(t=t[keep] - t[keep][0] if keep.any() else t[keep], q=q[keep],
                       qd=cut(qd) if "qd" in parts else None, tau=cut(tau),
                       qdd=cut(qdd) if "qdd" in parts else None, truth=truth, source=source)


def main(argv: list[str]) -> int:
    from ..identification.learned import identify, least_squares_reference, mean_step
    from ..perf import configure_cpu
    from ..training.checkpoints import load_model

    args = _parser().parse_args(argv)
    configure_cpu(args.threads)
    module = load_model(args.checkpoint)
    system = module.system
    if _measured_arm(system):
        return _identify_arm(module, args)
    if args.feedback:
        raise InputError(f"--feedback is for a model of a measured robot arm (recordings imported with its "
                         f"description); {args.checkpoint} is a model of the scene {system.name}")
    obs = read_observation(args.recording, system, split=args.split, trajectory=args.trajectory, start=args.start,
                           duration=args.duration, use=args.use, time=args.time, coordinates=args.coordinates,
                           velocities=args.velocities, inputs=args.inputs)
    q = obs.q
    if args.noise > 0:
        q = q + np.random.default_rng(args.seed).normal(0.0, args.noise, q.shape)
    result = identify(module.model, system, obs.t, q, obs.qd, obs.tau, obs.qdd, method=args.method,
                      starts=args.starts, steps=args.steps, window=args.window, seed=args.seed)
    reference = least_squares_reference(system, obs.t, q, obs.qd, obs.tau, obs.qdd, window=args.window)
    true_structure = None
    # the same fit on the scene's own equations (the ceiling), where torch can differentiate them (an
    # engine-backed scene such as robot_arm has its least-squares reference instead)
    if system.closed_form and getattr(system, "differentiable", True):
        from ..systems.ground_truth import ClosedForm

        exact = identify(ClosedForm(system), system, obs.t, q, obs.qd, obs.tau, obs.qdd, method=args.method,
                         starts=args.starts, steps=args.steps, window=args.window, seed=args.seed)
        true_structure = {k: {"value": v["value"], "rel_std": v.get("rel_std")} for k, v in exact.quantities.items()
                          if v["identifiable"]}
    report = {"checkpoint": args.checkpoint, "recording": obs.source, "scene": system.name,
              "observation": {"seconds": float(obs.t[-1]), "points": len(obs.t),
                              "dt": mean_step(obs.t),
                              "used": "+".join(n for n, x in (("q", q), ("qd", obs.qd), ("qdd", obs.qdd))
                                               if x is not None), "noise_added": args.noise},
              **result.to_json(), "truth": obs.truth, "true_structure": true_structure, "least_squares": reference}
    out = Path(args.output_dir) if args.output_dir else _default_output(args)
    out.mkdir(parents=True, exist_ok=True)
    (out / "identification.json").write_text(json.dumps(report, indent=2) + "\n")
    _plot(module, system, obs, q, result, out / "fit.png")
    text = markdown(report, system)
    (out / "report.md").write_text(text)
    print(text)
    print(f"wrote {out / 'identification.json'}, {out / 'report.md'}, {out / 'fit.png'}")
    return 0


def _measured_arm(system) -> bool:
    """A measured robot arm: recordings imported with a robot description, driven by joint torques."""
    return not system.closed_form and bool(system.config().get("description")) and system.num_inputs > 0


def _identify_arm(module, args) -> int:
    """Classical identification of a measured arm beside its model (module docstring)."""
    from ..data import read_dataset
    from ..identification.arm_comparison import (
        classical_torque,
        compare_on_arm,
        feedback_rows,
        fit_classical,
        markdown,
        model_torque,
        per_recording,
        per_recording_markdown,
        uncertainty_markdown,
    )
    from ..training.checkpoint_format import data_hparams
    from ..training.datamodule import TrajectoryDataModule

    path = Path(args.recording)
    if path.suffix not in (".h5", ".hdf5"):
        raise InputError(f"{path}: a measured arm is identified from its imported dataset (.h5: its training split "
                         "for the fits, --split to judge them), not a single CSV")
    targets = data_hparams(args.checkpoint).get("targets", "file")
    dm = TrajectoryDataModule(path=str(path), targets=targets)
    f = read_dataset(path)
    if args.feedback and (dm.targets is None or not f.measured):
        raise InputError(f"--feedback needs recorded velocities and estimated targets: {path} is not a measured "
                         "recording or the model was not trained on estimated targets")
    friction = classical_drive(module)
    out = Path(args.output_dir) if args.output_dir else _default_output(args)
    out.mkdir(parents=True, exist_ok=True)
    tools, loads = tools_on_split(module, f, dm, args.split)
    width, trains = f.read("params").shape[-1], len(f.splits.get("train", ())) > 0
    if not trains or width != module.system.num_params:
        # a new recording alone (no training split), or payloads the model does not condition on: its tools
        why = ("no training split to fit the classical models on" if not trains else
               f"its recordings carry {width} payload parameters, the model conditions on {module.system.num_params}")
        result = {"checkpoint": args.checkpoint, "recording": str(path), "split": args.split, "tools": tools,
                  "comparison": f"left out: {why}", "model_start": _model_start(module)}
        text = f"# {module.model.variant} on {path} ({args.split} split)\n\nNo classical comparison: {why}.\n\n"
        P = module.system.num_params
        unloaded = width == 0 and P > 0 and all(n.startswith("payload_") for n in module.system.param_names)
        if args.split in dm.split_names() and (width == P or unloaded):
            # the model's own error on the split (beside its description), with the loads it identified; a
            # recording without payload columns carries none (a payload of zero mass)
            data = dm.trajectories(args.split)
            params = loads if loads is not None or not unloaded else torch.zeros(len(data), P,
                                                                                 dtype=data.params.dtype)
            own = compare_on_arm(module.model, module.system, data, {}, model_params=params)
            result.update(own)
            text += (f"Joint-torque RMS error on the split ({own['test_points']} points; N m"
                     + ("; the model carries the loads the import left unknown as identified against it, in the "
                        "last section" if loads is not None else "; no payload columns: no load" if unloaded else "")
                     + f"):\n\n{markdown(own)}\n\n")
        text += _tools_markdown(tools)
    else:
        other = _other_data(args.checkpoint, path)
        if other:
            print(f"note: {other}")
        val = dm.trajectories("val") if "val" in dm.split_names() else None  # the consistent fit's prior's choice
        # standard errors over blocks of the filtered residuals' correlation time (as the tools' at import), in
        # the points fitted (every 2nd)
        block = 1 if dm.targets is None else -(-correlation_block(dm.targets, float(f.dt)) // 2)
        fits = fit_classical(module.system, dm.trajectories("train"), drive=friction, val=val, stride=2, block=block)
        data = dm.trajectories(args.split)
        # a load the import left unknown: the model carries it as identified against the model itself (the
        # import's estimate is against the classical arm, or the description where every recording carries it)
        result = compare_on_arm(module.model, module.system, data, fits, model_params=loads)
        if args.feedback:
            predictors = {module.model.variant: model_torque(module.model),
                          **{label: classical_torque(fit) for label, fit in fits.items()}}
            result["rows"].update(feedback_rows(dm, predictors, result["joints"], args.split,
                                                split_params=None if loads is None else
                                                {module.model.variant: loads}))
        ordinary = next(fit for fit in fits.values() if fit.method == "least squares")
        recordings = json.loads(f.attrs.get("recordings", "[]"))
        indices = data.index.tolist() if data.index is not None else list(range(len(data)))
        names = [recordings[i] if i < len(recordings) else f"trajectory {i}" for i in map(int, indices)]
        by_recording = (per_recording(module.model, module.system, data, fits, names, model_params=loads)
                        if len(names) > 1 else None)
        result = {"checkpoint": args.checkpoint, "recording": str(path), "split": args.split, **result,
                  "per_recording": by_recording,
                  "uncertainty": ordinary.info["uncertainty"], "model_start": _model_start(module), "tools": tools}
        text = (f"# {module.model.variant} and classical identification on {path} ({args.split} split, "
                f"{result['test_points']} points; the fits on the training split, {result['train_points']} points"
                + (f": every {_ordinal(result['train_stride'])} sample" if (result.get("train_stride") or 1) > 1
                   else "") + ")\n\n"
                f"{result['model_start']}\n\nJoint-torque RMS error (N m"
                + ("; the model carries the loads the import left unknown as identified against it, in the last "
                   "section, the classical fits the dataset's" if loads is not None else "")
                + f"):\n\n{markdown(result)}\n\n"
                + _priors_line(fits)
                + ("" if by_recording is None else "Per recording of the split, the mean joint-torque RMS error "
                   f"(N m; the lowest in bold):\n\n{per_recording_markdown(by_recording)}\n\n")
                + "## What the training recordings determine "
                f"(ordinary least squares)\n\n{uncertainty_markdown(result['uncertainty'])}\n"
                + ("\n" + _tools_markdown(tools) if tools else ""))
        if other:
            result["note"], text = other, text.replace("\n\n", f"\n\nNote: {other}\n\n", 1)
    (out / "identification.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "report.md").write_text(text)
    print(text)
    print(f"wrote {out / 'identification.json'}, {out / 'report.md'}")
    return 0


def _other_data(checkpoint: str, path: Path) -> str | None:
    """A sentence where ``path`` is not the dataset the model was trained on (another file, or the same name
    holding other recordings), else None: the classical fits and what the data determine are then another
    dataset's than the model's."""
    from ..data import read_dataset
    from ..training.checkpoint_format import data_hparams

    trained = data_hparams(checkpoint).get("path")
    if not trained:
        return None
    ours = Path(trained)
    if ours.exists():
        if ours.resolve() == Path(path).resolve():
            return None
        a, b = read_dataset(ours), read_dataset(path)  # (a copy or a move of the same file is the same data)
        if a.attrs.get("recordings") == b.attrs.get("recordings") and a.read("q").shape == b.read("q").shape:
            return None
    elif Path(trained).name == Path(path).name:
        return None  # (the model's file is not here: the same name is taken for it)
    return (f"{path} is not the dataset this model was trained on ({trained}): the classical fits and what the "
            "training recordings determine are this file's training split's, and the model's start its own data's")


def _priors_line(fits: dict) -> str:
    """A sentence naming the prior of each physically consistent row (chosen on validation for its own rows'
    weighting and drive model, so not necessarily the model's start's), or nothing."""
    priors = [f"{label}: {fit.info['prior']:g}" for label, fit in fits.items() if fit.info.get("prior") is not None]
    if not priors:
        return ""
    return ("The prior towards the description of " + "; ".join(priors) + " (chosen on validation for that row's "
            "weighting and drive model; the model's start chose its own, above).\n\n")


def tools_on_split(module, f, dm, split: str, judging: bool = True) -> tuple[dict | None, torch.Tensor | None]:
    """The loads of the split's recordings whose tools the import left (partly) unknown, identified again
    against the model's own arm (its torques without payload, the tool's rigid body at the flange:
    ``identification.payload.identify_tools``): a tool the training or validation recordings carry from those
    recordings (as the import did, and never from the recordings judged), a tool only the split carries (a new
    recording's load) from the split's own. ``f``: the dataset file (``TrajectoryFile``). Returns the report and
    the split's parameters with those loads in place of the import's (``(B, P)``, one row per entry);
    ``(None, None)`` where the split carries no such tool. ``judging`` False: the split is not judged (export),
    its tools' sources say nothing of it."""
    from ..data.import_tools import TOOL_ROWS
    from ..identification.arm_comparison import arm_chain, model_torque
    from ..identification.payload import identify_tools
    from ..robots.tools import Tool

    provenance = json.loads(f.attrs["provenance"])
    if not provenance.get("tools") or split not in f.splits:
        return None, None
    width = f.read("params").shape[-1]
    declared = {name: Tool.declared(name, value, width)
                for name, value in (provenance["settings"].get("parameters") or {}).get("tools", {}).items()}
    names = json.loads(f.attrs["recordings"])
    carried = provenance["tools"]["entries"]
    torque = model_torque(module.model)
    P = module.system.num_params

    def arm(q, qd, qdd):
        return torque(q, qd, qdd, q.new_zeros(q.shape[0], P))

    def entries(s):  # (index in the split, recording, tool) of the split's entries carrying an unknown tool
        return [(j, names[int(k)], carried.get(names[int(k)])) for j, k in enumerate(f.splits.get(s, []))
                if carried.get(names[int(k)]) is not None and declared[carried[names[int(k)]]].unknown]

    judged = entries(split)
    if not judged:
        return None, None
    fitting = {s: entries(s) for s in ("train", "val") if s in f.splits}
    seen = {tool for rows in fitting.values() for _, _, tool in rows}
    words = {"train": "training", "val": "validation"}
    sources = {tool: (" and ".join(words[s] for s, rows in fitting.items() if any(t == tool for *_, t in rows))
                      + " recordings" + (" (the judged split among them)" if judging and split in fitting else "")
                      if tool in seen else "this split's recordings") for _, _, tool in judged}
    # a seen tool's training and validation entries, a new tool's entries of the split
    use = [(s, e) for s, listed in fitting.items() for e in listed if e[2] in sources]
    use += [(split, e) for e in judged if e[2] not in seen]
    picked, cache = [], {}
    for s, (j, name, tool) in use:
        data = cache.setdefault(s, dm.trajectories(s))
        picked.append((data, j, name, tool, data.valid_lengths()[j]))
    # long recordings thinned to at most TOOL_ROWS samples in all, as the import's tool fit
    stride = max(1, math.ceil(sum(n for *_, n in picked) / TOOL_ROWS))
    rows = [(name, *(getattr(data, a)[j, :n:stride].double() for a in ("q", "qd", "qdd", "tau")), tool)
            for data, j, name, tool, n in picked]
    data = cache.setdefault(split, dm.trajectories(split))
    imported = {tool: data.params[j].double().tolist() for j, _, tool in judged}
    used = {t: declared[t] for t in imported}
    block = correlation_block(dm.targets, float(data.dt)) if dm.targets is not None else 1
    block = max(1, math.ceil(block / stride))
    fit = identify_tools(arm_chain(module.system), rows, used, arm=arm, block=block,
                         against=f"the model's arm ({module.model.variant}, without payload)")
    report = fit.report()
    for tool, values in imported.items():
        report["tools"][tool]["at_import"] = values
        report["tools"][tool]["from"] = sources[tool]
    params = data.params.clone()
    for j, _, tool in judged:  # each entry's load as identified against the model
        params[j] = torch.as_tensor(np.asarray(fit.values[tool], dtype=np.float64), dtype=params.dtype)
    return report, params


def _tools_markdown(tools: dict | None) -> str:
    """The tools identified against the model, a row per entry: value, 95 % interval, the import's value."""
    if not tools:
        return ""
    lines = [f"## Loads identified against the model\n\nAgainst {tools['against']}; a tool the training or "
             "validation recordings carry from those (every few samples where they are long), a tool only this "
             "split carries from its own recordings; "
             f"intervals cluster-robust over {tools['block_samples']}-sample blocks, taking the model's arm as "
             "exact: they hold the torque noise, not what the fit leaves out (a point tool's own inertia, friction "
             "the model lacks, e.g. growing with the load), which can shift the values by more.\n"]
    for name, tool in tools["tools"].items():
        rows = []
        for k, (key, p) in enumerate(tool["parameters"].items()):
            at_import = tool["at_import"][k]
            if "std" in p:
                lo, hi = p["interval95"]
                rows.append([key, p["unit"], f"{p['value']:.5g}", f"[{lo:.5g}, {hi:.5g}]", f"{at_import:.5g}"])
            else:
                rows.append([key, p["unit"], f"{p['value']:.5g}", "known", f"{at_import:.5g}"])
        lines += [f"Tool {name} ({tool['declared']}; from {tool.get('from', 'this split')}: "
                  f"{', '.join(tool['recordings'])}):", "",
                  markdown_table(["entry", "unit", "identified", "95 % interval", "at import"], rows), ""]
    return "\n".join(lines)


def classical_drive(module) -> DriveModel:
    """The drive model of the classical fits beside ``module``: the model's configured forms with its smoothing
    velocities (the dataset's or those its classical start chose), less a term kept on evidence only
    (``classical_start.ON_EVIDENCE``) that its classical start left out (the other terms it left out stay: least
    squares as users fit it, with the drive's usual terms); else its configured forms with the scene's
    smoothing."""
    from ..identification.classical_start import ON_EVIDENCE

    forces = getattr(module.model, "forces", None)
    drive = getattr(forces, "drive", None)
    if drive is not None:
        drive = drive.with_forms(getattr(forces, "configured_forms", drive.forms))
        kept = (getattr(module, "classical_start", None) or {}).get("form")
        if kept:
            return drive.with_forms([f for f in drive.forms if f not in ON_EVIDENCE or f in kept.split("+")])
        return drive
    return DriveModel.of(module.hparams.get("model_options", {}).get("friction", "viscous+coulomb"),
                         coulomb_velocity=float(getattr(module.system, "coulomb_velocity", None) or 0.02))


def _model_start(module) -> str:
    """Where the model started and which state it ended with, in a sentence."""
    start, selection = module.classical_start, module.selection
    if start is None:
        return "The model started from its description (no classical start)."
    method = start.get("method", "physically consistent")
    text = (f"The model started from the {method} least-squares fit of its training split "
            f"(prior {start['prior']:g}" + (", chosen on validation" if start.get("validation_rms_mean") else "")
            + ("; the rows' weighting (as recorded, or per joint as weighted least squares) chosen on validation"
               if start.get("weighting_selection") else "")
            + (f"; friction {start['form']}, chosen on validation among {start['drive']} and its terms"
               if start.get("form_selection") else "")
            + (f"; Coulomb smoothing {start['coulomb_velocity']:g} rad/s, chosen on validation"
               if start.get("smoothing_selection") else "")
            + (f"; saturating friction over {start['saturation_velocity']:g} rad/s, chosen on validation"
               if start.get("saturation_selection") and "saturating" in start.get("form", "") else "") + ")")
    if selection is not None:
        kept = "the start itself" if selection["step"] == 0 else f"the state after {selection['step']} gradient steps"
        text += f"; validation kept {kept} ({selection['monitor']} {selection['value']:.4g})"
    return text + "."


def _default_output(args) -> Path:
    """Per model and recording: ``<run>/identification/<recording stem>`` beside a run's checkpoints folder
    (``<run>/identification/<checkpoint stem>/...`` for a checkpoint other than ``last.ckpt``),
    ``identification/<name>/...`` for ``pretrained:<name>`` or a checkpoint outside a run folder (by its
    name); ``-<split>-<trajectory>`` after the stem of a dataset file."""
    from ..training.checkpoint_format import output_dir

    path = Path(args.recording)
    stem = path.name.split(".")[0]
    if path.suffix in (".h5", ".hdf5"):
        stem += f"-{args.split}-{args.trajectory}"
    checkpoint = Path(str(args.checkpoint))
    if str(args.checkpoint).startswith("pretrained:"):
        return output_dir(args.checkpoint, None, "identification") / stem
    if checkpoint.parent.name != "checkpoints":  # a checkpoint outside a fit's run folder: here, by its name
        return Path("identification") / checkpoint.stem / stem
    folder = output_dir(args.checkpoint, None, "identification")
    return (folder if checkpoint.stem == "last" else folder / checkpoint.stem) / stem


def _unit(coefficients: dict, system) -> str:
    """`` kg``, `` m``...: the unit of a quantity that is one parameter; ratios and combinations have none."""
    if len(coefficients) == 1 and list(coefficients.values())[0] == 1:
        name = next(iter(coefficients))
        if name in system.param_names:
            return f" {system.param_units[list(system.param_names).index(name)]}"
    return ""


def markdown(report: dict, system) -> str:
    """The short report: estimates, uncertainties, the classical reference, residuals."""
    from ..identification.learned import FLAT_RATIO

    truth, ls, exact = report["truth"], report["least_squares"] or {}, report["true_structure"] or {}
    lines = [f"# Identification: {report['scene']}", "",
             f"Recording: {report['recording']}; {report['observation']['seconds']:.3g} s "
             f"({report['observation']['points']} points), used: {report['observation']['used']}"
             + (f", position noise added: {report['observation']['noise_added']:g}"
                if report["observation"]["noise_added"] else "") + ".",
             f"Model: {report['checkpoint']}; method {report['method']}, {report['starts']} starts, "
             f"{report['seconds']:.1f} s.", "",
             *table_header(["quantity", "estimate", "± 1 std (noise, given the model)", "same fit, true equations",
                            "linear least squares, true equations", *(("truth", "error") if truth else ())])]
    for name, qv in report["quantities"].items():
        if not qv["identifiable"]:
            est, std = "not identifiable", "–"
        else:
            est = number(qv["value"], ".5g") + _unit(qv["coefficients"], system)
            std = pct(qv["rel_std"], 2) if "rel_std" in qv else number(qv["std"], ".2g")
        ref = f"{number(ls[name]['value'], '.5g')} ± {pct(ls[name]['rel_std'], 2)}" if name in ls else "–"
        same = number(exact[name]["value"], ".5g") if name in exact else "–"
        cells = [name, est, std, same, ref]
        if truth:
            c = qv["coefficients"]
            true = float(np.exp(sum(v * np.log(truth[p]) for p, v in c.items()))) if "rel_std" in qv else \
                sum(v * truth[p] for p, v in c.items())
            err = pct(qv["value"] / true - 1, signed=True) if qv["identifiable"] and "rel_std" in qv else \
                (number(qv["value"] - true, "+.3g") if qv["identifiable"] else "–")
            cells += [number(true, ".5g"), err]
        lines.append(table_row(cells))
    lines.append("")
    for d in report["unidentifiable"]:
        combo = " ".join(f"{v:+.2f} log {p}" for p, v in d["direction"].items())
        if d.get("scale"):
            members = ", ".join(d["direction"])
            lines.append(f"Not identifiable from any motion without inputs: a common scale of {members} "
                         "(a Lagrangian times a constant has the same equations of motion); the parameters moving "
                         "along it get no number.")
            continue
        why = ("beyond half the search box along it" if d.get("why", "box") == "box" else
               f"over {FLAT_RATIO:g} times that of the best-determined direction: the observation moves it far less")
        lines.append(f"Not identifiable from this observation: the direction {combo} (its standard deviation "
                     f"{d['std']:.3g} in log units, {why}); the parameters moving along it get no number.")
    if report["at_bound"]:
        lines.append("On the edge of the search box (the model's training distribution): "
                     f"{', '.join(report['at_bound'])}; the truth may lie outside what the model was trained on.")
    lines.append("The ± column is the statistical uncertainty of the fit given the model: the model's own error is "
                 "not in it" + (" (compare the same fit on the true equations)" if exact else "")
                 + (", nor the bias of accelerations estimated from the positions (their smoothing; --method "
                    "trajectory fits the positions themselves)" if report["method"] == "acceleration"
                    and "qdd" not in report["observation"]["used"] else "") + ".")
    if report["observation"]["noise_added"] and "qd" in report["observation"]["used"]:
        lines.append("The noise is added to the positions only: the velocities are the recording's own, exact (with "
                     "--use q they are estimated from the noisy positions, as from a sensor's).")
    rms = ", ".join(f"{k} {v:.3g}" for k, v in report["residual_rms"].items())
    lines += ["", f"Residual rms of the fit (normalised: accelerations / their rms, or position error / "
                  f"(window² / 2) in acceleration units): {rms}.", ""]
    return "\n".join(lines)


def _plot(module, system, obs: Observation, q_used, result, path: Path) -> None:
    """Observed coordinates and the model re-simulated (open loop, from the first observed state) with
    the identified parameters."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..data.derivatives import estimate_derivatives

    dt = float(obs.t[1] - obs.t[0])
    q = torch.as_tensor(q_used, dtype=torch.float64)
    qd, _ = estimate_derivatives(q[None], dt, None if obs.qd is None else torch.as_tensor(obs.qd)[None])
    params = torch.tensor([list(result.params.values())], dtype=torch.float64)
    tau = None if obs.tau is None else torch.as_tensor(obs.tau[None, :-1])
    with torch.no_grad():
        sim, _ = module.model.rollout(q[None, 0], qd[:, 0], params, dt, len(obs.t) - 1, "rk4", tau=tau)
    fig, axes = plt.subplots(system.dof, 1, figsize=(8, 2.2 * system.dof), sharex=True, squeeze=False)
    for i, ax in enumerate(axes[:, 0]):
        ax.plot(obs.t, q_used[:, i], "k.", ms=2, label="observed")
        ax.plot(obs.t, sim[0, :, i].numpy(), "C1", label="model, identified parameters")
        ax.set_ylabel(f"{system.coord_names[i]} [{system.coord_units[i]}]")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle("open-loop re-simulation from the first observed state", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _ordinal(k: int) -> str:
    """``2nd``, ``3rd``, ``4th``, ..."""
    return f"{k}{'th' if 10 <= k % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(k % 10, 'th')}"
