"""What decides how long a model of the real double pendulum stays close open loop: least squares of the
accelerations against the learned configuration, the Coulomb friction's shape and each parameter.

Least squares of the accelerations (``RigidArmModel.fit_recordings``: the lab model's form, ten base
parameters, Coulomb friction ``cf arctan(k qd)``) is fitted to the checkpoint's training recordings once
for each slope ``k`` (``--slopes``; the lab's form has 100), and with ``cf tanh(k qd)`` for each of
``--tanh-slopes`` (the learned models' smoothing); each fit and each model of ``--model LABEL=CHECKPOINT``
is judged on the held-out recordings as ``scripts/real_pendulum.py`` judges them: the relative
acceleration error with the torques filtered like the reference, and open loop, driven by the recorded
torques from every start point (every ``--start-every`` s), the median time within 0.1 rad, pooled and
per recording. The learned models are evaluated on their own checkpoint's data where it names any (a
re-import with another ``--coulomb-velocity`` holds the same recordings and targets). ``--swap
CHECKPOINT``: a learned model of the lab's form read as base parameters beside least squares of the same
family, and each group of parameters swapped between them.

    python scripts/real_pendulum_open_loop.py pretrained:real_double_pendulum \
        --model "the configuration=pretrained:real_double_pendulum" --swap LAB_FORM_CHECKPOINT \
        -o results/real_double_pendulum/open_loop

Writes ``open_loop.json`` and ``open_loop.md`` to ``--output-dir``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from _common import HelpFormatter, acceleration_report, add_output_dir, wrote


def judge(model, system, data, smoothed, names, start_every: float, time_limit: float) -> dict:
    """Held-out acceleration error (torques filtered alike) and open-loop median time within 0.1 rad,
    pooled and per recording (``names``)."""
    from lnn_torch.evaluation import evaluate_model

    r = evaluate_model(model, system, data, sections=("horizons",), thresholds=(0.1,), horizons=(0.5,),
                       start_every=start_every, time_limit=time_limit)
    starts = r["_horizons_arrays"]
    pooled, per = acceleration_report(model, smoothed, system.coord_names)
    times = np.asarray(starts["time_to@0.1"], dtype=float)
    return {"acc_rel_err": float(pooled["total"]), "time_to@0.1": float(np.median(times)),
            "per_recording": {rec: {"acc_rel_err": float(e),
                                    "time_to@0.1": float(np.median(times[np.asarray(starts["trajectory"]) == b])),
                                    "starts_time_to@0.1": times[np.asarray(starts["trajectory"]) == b].tolist()}
                              for b, (rec, e) in enumerate(zip(names, per, strict=True))}}


def held_out(checkpoint: str, data_of: str | None = None):
    """``(module, system, test data, its torques filtered, recording names, training data filtered)``; the
    data of the checkpoint ``data_of`` where ``checkpoint`` names none (a copy of a shipped model)."""
    from lnn_torch import load_model
    from lnn_torch.data import read_dataset
    from lnn_torch.training import TrajectoryDataModule, data_hparams

    module = load_model(checkpoint)
    saved = data_hparams(checkpoint)
    if "path" not in saved and data_of is not None:
        saved = data_hparams(data_of)
    dm = TrajectoryDataModule(path=saved["path"], targets=saved.get("targets", "file"))
    data = dm.trajectories("test")
    names = json.loads(read_dataset(dm.path).attrs["recordings"])
    return (module, module.system, data, dm.trajectories("test", smooth_inputs=True),
            [names[int(i)] for i in data.index], dm.trajectories("train", smooth_inputs=True))


GROUPS = {"inertia (A, B, C, K)": ("A", "B", "C", "K"), "gravity (P1, P2)": ("P1", "P2"),
          "viscous friction (b1, b2)": ("b1", "b2"), "Coulomb friction (cf1, cf2)": ("cf1", "cf2")}


def swapped(checkpoint: str, data_of: str, q, qd, qdd, tau, judged) -> dict:
    """Rows of the learned model ``checkpoint`` (of the lab's form: Coulomb ``tanh(qd / v)``, no static
    friction, centres of mass on the links' lines) read as base parameters, of least squares of ``cf
    tanh(qd / v)`` (the same family), and of each with one group of the other's parameters (``GROUPS``);
    ``judged(model)`` gives a row. The learned model's base parameters are those whose torques its own
    accelerations at the training points give exactly; a model whose largest torque residual there is
    above 1e-9 N m is not of that family and is refused."""
    from lnn_torch.identification import BASE, RigidArmModel, base_regressor

    module = held_out(checkpoint, data_of)[0]
    slope = 1.0 / float(module.system.coulomb_velocity)
    with torch.no_grad():
        acc = module.model.double().acceleration(q, qd, torch.zeros(len(q), 0, dtype=q.dtype), tau)
    Y = base_regressor(q, qd, acc, 9.81, slope, "tanh").reshape(-1, len(BASE))
    beta = torch.linalg.lstsq(Y, tau.reshape(-1, 1)).solution[:, 0]
    residual = float((Y @ beta - tau.reshape(-1)).abs().max())
    print(f"{checkpoint} as base parameters: largest torque residual {residual:.1e} N m", flush=True)
    if not residual < 1e-9:
        raise SystemExit(f"--swap {checkpoint}: not of the lab model's form (largest torque residual {residual:.2g} "
                         "N m in its base parameters); fit it without static friction and with across: false")
    learned = dict(zip(BASE, beta.tolist(), strict=True))
    ls = RigidArmModel.least_squares(q, qd, qdd, tau, space="acceleration", coulomb_slope=slope,
                                     coulomb_shape="tanh").base
    model = lambda base: RigidArmModel.from_base(base, coulomb_slope=slope, coulomb_shape="tanh")  # noqa: E731
    rows = {f"least squares, cf tanh({slope:g} qd)": judged(model(ls)), "the learned model": judged(model(learned))}
    for name, keys in GROUPS.items():
        rows[f"least squares with the learned model's {name}"] = judged(model({**ls, **{k: learned[k] for k in keys}}))
        rows[f"the learned model with least squares' {name}"] = judged(model({**learned, **{k: ls[k] for k in keys}}))
    rows["base parameters (least squares; learned)"] = {k: [ls[k], learned[k]] for k in BASE}
    rows["the learned model's largest torque residual in its base parameters (N m)"] = {"value": residual}
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("checkpoint", help="a checkpoint trained on the imported recordings (its data and splits)")
    ap.add_argument("--slopes", type=float, nargs="+", default=[10.0, 20.0, 50.0, 100.0, 300.0, 1000.0],
                    help="Coulomb slopes k of the least-squares fits, s/rad")
    ap.add_argument("--tanh-slopes", type=float, nargs="*", default=[50.0],
                    help="slopes k of least-squares fits with Coulomb friction cf tanh(k qd) instead (50: the "
                         "learned models' tanh(qd / 0.02))")
    ap.add_argument("--model", action="append", default=[], metavar="LABEL=CHECKPOINT",
                    help="a learned model to judge beside them (repeatable)")
    ap.add_argument("--swap", default=None, metavar="CHECKPOINT",
                    help="a learned model of the lab's form (kinetic chain with across: false, potential chain, "
                         "joint friction): its base parameters beside least squares of cf tanh(50 qd) (the same "
                         "family), and each group of them (inertia, gravity, viscous, Coulomb) swapped between the two")
    ap.add_argument("--start-every", type=float, default=0.25, help="seconds between the rollouts' starts")
    ap.add_argument("--time-limit", type=float, default=4.0, help="rollout length, s (censored there)")
    add_output_dir(ap, "results/real_double_pendulum/open_loop", "the folder of open_loop.json and open_loop.md")
    args = ap.parse_args()
    from lnn_torch.data import points
    from lnn_torch.evaluation import table_header, table_row
    from lnn_torch.identification import RigidArmModel
    from lnn_torch.perf import configure_cpu

    configure_cpu(1)
    bad = [m for m in args.model if "=" not in m]
    if bad:
        raise SystemExit(f"--model takes LABEL=CHECKPOINT, got {bad[0]!r}")
    _, system, data, smoothed, names, seen = held_out(args.checkpoint)
    q, qd, qdd, tau, _ = points(seen)
    rows = {}
    for shape, slopes in (("arctan", args.slopes), ("tanh", args.tanh_slopes)):
        for k in slopes:
            fit = RigidArmModel.least_squares(q, qd, qdd, tau, space="acceleration", coulomb_slope=k,
                                              coulomb_shape=shape)
            rows[f"least squares of the accelerations, Coulomb cf {shape}({k:g} qd)"] = judge(
                fit, system, data, smoothed, names, args.start_every, args.time_limit)
            print(f"{shape} {k:g}: done", flush=True)
    for spec in args.model:
        label, _, checkpoint = spec.partition("=")
        m, s, d, sm, n, _ = held_out(checkpoint, args.checkpoint)
        if n != names:
            raise SystemExit(f"{checkpoint}: its held-out recordings {n} are not {names}")
        rows[label] = judge(m.model, s, d, sm, n, args.start_every, args.time_limit)
    if args.swap:
        rows.update(swapped(args.swap, args.checkpoint, q, qd, qdd, tau, lambda m: judge(
            m, system, data, smoothed, names, args.start_every, args.time_limit)))
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "open_loop.json").write_text(json.dumps({"checkpoint": args.checkpoint, "recordings": names,
                                                    "models": args.model, "swap": args.swap, "rows": rows}, indent=1))
    lines = table_header(["model", "acc. rel. L2, torques filtered alike", "median time within 0.1 rad", *names])
    for label, r in rows.items():
        if "per_recording" not in r:
            continue
        cells = [f"{p['acc_rel_err']:.1%}; {p['time_to@0.1']:.2f} s" for p in r["per_recording"].values()]
        lines.append(table_row([label, f"{r['acc_rel_err']:.1%}", f"{r['time_to@0.1']:.2f} s", *cells]))
    (out / "open_loop.md").write_text("Held-out recordings; per recording: acceleration error; median time within "
                                    "0.1 rad.\n\n" + "\n".join(lines).replace("%", " %") + "\n")
    wrote(out / "open_loop.json", out / "open_loop.md")


if __name__ == "__main__":
    main()
