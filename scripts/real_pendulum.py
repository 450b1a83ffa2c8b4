"""A model of the real double pendulum against the lab's identified physics model, on held-out recordings.

Both are evaluated the same way (``lnn_torch.evaluation.evaluate_model``) on the test recordings of
the imported dataset: the relative L2 acceleration error against the filtered reference (the
checkpoint's derivative estimate of the recordings), with the torques passed through the same
zero-phase filter (both sides of the equations of motion in the same band: the figure the report leads
with) and, beside it, with the recorded torques (their noise above the reference's band then counts as
error), pooled and per recording; and open-loop rollouts started every
``--start-every`` s of each recording with the measured state there, driven by the recorded torques:
the angle error after 0.1, 0.25, 0.5 and 1 s and the median time until it first exceeds 0.1 rad
(censored at ``--time-limit`` s).

    lnn-torch import lnn_torch/datasets/real_double_pendulum/recordings/*.csv.gz \\
        --config configs/import/real_double_pendulum.yaml -o data/real_double_pendulum.h5
    lnn-torch fit -c configs/real_double_pendulum.yaml
    python scripts/real_pendulum.py lightning_logs/version_0/checkpoints/last.ckpt

Writes ``metrics.json``, ``report.md`` and ``error_vs_horizon.png`` to ``--output-dir``.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import torch
from _common import LAB, LEAST_SQUARES, PARAMS, HelpFormatter, acceleration_report, add_output_dir, wrote


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("checkpoint", help="a .ckpt trained on the imported recordings")
    ap.add_argument("--data", default=None, help="default: the checkpoint's data path")
    ap.add_argument("--split", default="test", help="the recordings to judge on: train, val or test")
    ap.add_argument("--start-every", type=float, default=0.25, help="seconds between the rollouts' starts")
    ap.add_argument("--time-limit", type=float, default=4.0, help="rollout length, s (time to 0.1 rad censored there)")
    add_output_dir(ap, None, "the folder of metrics.json, report.md and error_vs_horizon.png (default: "
                   "real_pendulum/ beside the run's checkpoints folder, real_pendulum/NAME for pretrained:NAME; the "
                   "committed report is -o results/real_double_pendulum)")
    ap.add_argument("--note", default="", help="e.g. the training time, recorded in the report")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (more than one only on an idle machine)")
    args = ap.parse_args()
    from lnn_torch import load_model
    from lnn_torch.data import read_dataset
    from lnn_torch.evaluation import evaluate_model, quartiles, table_header, table_row
    from lnn_torch.identification import RigidArmModel
    from lnn_torch.perf import configure_cpu
    from lnn_torch.training import TrajectoryDataModule, data_hparams, output_dir

    configure_cpu(args.threads)
    module = load_model(args.checkpoint)
    saved = data_hparams(args.checkpoint)
    dm = TrajectoryDataModule(path=args.data or saved["path"], targets=saved.get("targets", "file"))
    if module.system.dof != 2 or module.system.num_inputs != 2:
        raise SystemExit(f"real_pendulum.py: {dm.path} is a system of {module.system.dof} coordinates and "
                         f"{module.system.num_inputs} input(s); this comparison is with the lab's model of the shipped "
                         "double pendulum (two coordinates, a motor at each joint): judge another system with "
                         "lnn-torch evaluate CHECKPOINT")
    data = dm.trajectories(args.split)
    smoothed = dm.trajectories(args.split, smooth_inputs=True)  # the torques in the reference's band
    names = json.loads(read_dataset(dm.path).attrs["recordings"])
    held_out = [names[int(i)] for i in data.index]
    lab = RigidArmModel.from_yaml(PARAMS)
    seen = dm.trajectories("train", smooth_inputs=True)  # what the checkpoint trained on
    fitted = [(LEAST_SQUARES[space], RigidArmModel.fit_recordings(seen, space)) for space in LEAST_SQUARES]
    horizons = (0.1, 0.25, 0.5, 1.0)
    results = {}
    for name, model in ((LAB, lab), *fitted, (f"{module.hparams.variant} (this checkpoint)", module.model)):
        r = evaluate_model(model, module.system, data, sections=("horizons",), thresholds=(0.1,), horizons=horizons,
                           start_every=args.start_every, time_limit=args.time_limit)
        starts = r["_horizons_arrays"]
        r = {k: v for k, v in r.items() if not k.startswith("_")}
        (r["acc_rel_err"], filtered), (r["acc_rel_err_recorded_torques"], recorded) = (
            acceleration_report(model, smoothed, module.system.coord_names),
            acceleration_report(model, data, module.system.coord_names))
        r["per_recording"] = {rec: {"filtered_torques": f, "recorded_torques": e}
                              for rec, f, e in zip(held_out, filtered, recorded, strict=True)}
        for b, rec in enumerate(held_out):  # the open-loop time of each recording's own start points
            r["per_recording"][rec]["time_to@0.1"] = quartiles(starts["time_to@0.1"][starts["trajectory"] == b])
        results[name] = r
    structure = compare_structure(module.model, lab, data, held_out)
    out = output_dir(args.checkpoint, args.output_dir, "real_pendulum")
    out.mkdir(parents=True, exist_ok=True)
    meta = {"checkpoint": args.checkpoint, "held_out": held_out, "targets": saved.get("targets"),
            "start_every_s": args.start_every, "time_limit_s": args.time_limit, "note": args.note}
    (out / "metrics.json").write_text(json.dumps({"meta": meta, "results": results, "structure": structure}, indent=1))
    lines = [f"Held-out recordings: {', '.join(held_out)}; reference accelerations: the checkpoint's estimate "
             f"({saved.get('targets')}); open-loop rollouts (RK4 at the data's 2 ms step, the recorded torques held "
             f"over each step) started every {args.start_every:g} s with the measured state. {args.note}", "",
             *table_header(["model", "acc. rel. L2, torques filtered alike (q1, q2)", "with the recorded torques",
                            "angle error after " + ", ".join(f"{h:g}" for h in horizons) + " s: median [p90] (rad)",
                            "time to 0.1 rad: median [q25, q75] (s)"])]
    for name, r in results.items():
        a, ar, h = r["acc_rel_err"], r["acc_rel_err_recorded_torques"], r["horizons"]
        errs = ", ".join(f"{h[f'error@{x:g}s']['median']:.3f} [{h[f'error@{x:g}s']['p90']:.3f}]" for x in horizons)
        t = h["time_to@0.1"]
        lines.append(table_row([name, f"{100 * a['total']:.1f} % ({100 * a['q1']:.1f} %, {100 * a['q2']:.1f} %)",
                                f"{100 * ar['total']:.1f} %", errs,
                                f"{t['median']:.2f} [{t['q25']:.2f}, {t['q75']:.2f}] (of {h['horizon_s']:g})"]))
    lines += ["", "Per recording, acc. rel. L2 with the torques filtered alike (with the recorded torques); the "
              "median time within 0.1 rad over the recording's own start points:", "",
              *table_header(["model", *held_out])]
    for name, r in results.items():
        lines.append(table_row([name, *(f"{100 * e['filtered_torques']:.1f} % ({100 * e['recorded_torques']:.1f} %); "
                                        f"{e['time_to@0.1']['median']:.2f} s" for e in r["per_recording"].values())]))
    m = structure["mass_matrix"]
    lines += ["", "Learned against the lab's model: mass matrix over q2 in [-pi, pi] (q1 = 0; the learned one in its "
              f"normalised units, after one best scale), relative Frobenius difference median {100 * m['median']:.1f} "
              f"%, max {100 * m['max']:.1f} %; static torque (inverse dynamics at zero velocity and acceleration: "
              "gravity) along each recording's measured angles, RMS [max] difference: "
              + ", ".join(f"{k} {v['rms']:.3f} [{v['max']:.3f}] N m" for k, v in structure["static_torque"].items())]
    if "identified" in structure:  # the lab's values of the same quantities
        lines += ["", "Identified rigid chain (SI) against the lab's parameters: " + ", ".join(
            f"{k} {v:.3f} ({lab.values[k]:.3f})" if k in lab.values else f"{k} {v:.3f}"
            for k, v in structure["identified"].items()) + " (kg, m; r: centre of mass along the link from its joint, "
            "r2_across: across link 2, 0 in the lab's model)"]
    if "friction" in structure:
        lab_friction = {**{f"b{i}": lab.values[f"b{i}"] for i in (1, 2)},
                        **{f"coulomb{i}": lab.values[f"cf{i}"] * math.pi / 2 for i in (1, 2)}}
        lines += ["", "Joint friction against the lab's: " + ", ".join(
            f"{k} {v:.4f} ({lab_friction[k]:.4f})" for k, v in structure["friction"].items())
            + " (b: viscous, N m s/rad; coulomb: the level at high speed, N m, the lab's cf arctan(100 qd) "
            "reaching cf pi / 2)"]
    table = "\n".join(lines) + "\n"
    (out / "report.md").write_text(table)
    print(table)
    plot(results, horizons, out)
    wrote(out / "metrics.json", out / "report.md", out / "error_vs_horizon.png")


def compare_structure(model, lab, data, names) -> dict:
    """The learned model's mass matrix and static (gravity) torque against the lab model's."""
    q2 = torch.linspace(-math.pi, math.pi, 73, dtype=torch.float64)
    q = torch.stack([torch.zeros_like(q2), q2], -1)
    none = torch.zeros(len(q2), 0, dtype=torch.float64)
    with torch.no_grad():
        M_lab, M = lab.mass_matrix(q), model.mass_matrix(q.to(model.dtype), none.to(model.dtype)).double()
    scale = (M_lab * M).sum() / (M * M).sum()
    err = torch.linalg.matrix_norm(scale * M - M_lab) / torch.linalg.matrix_norm(M_lab)
    static = {}
    for b, name in enumerate(names):
        n = int(data.lengths[b])
        qb, zero = data.q[b, :n], torch.zeros(n, 2, dtype=torch.float64)
        with torch.no_grad():
            lab_static = -(lab.mass_matrix(qb) @ lab.acceleration(qb, zero, tau=zero)[..., None])[..., 0]
            learned = model.inverse(qb, zero, zero, data.params[b : b + 1].expand(n, -1)).double()
        diff = (learned - lab_static).norm(dim=-1)
        static[name] = {"rms": float(diff.pow(2).mean().sqrt()), "max": float(diff.max())}
    out = {"mass_matrix": {"median": float(err.median()), "max": float(err.max())}, "static_torque": static}
    if getattr(model, "has_si_chain", False):  # gravity alone on the rigid chain: the chain in SI
        si = model.chain_si()
        out["identified"] = {"m1": float(si["mass"][0, 0]), "m2": float(si["mass"][0, 1]),
                             "l1": float(si["length"][0, 0]), "r1": float(si["along"][0, 0]),
                             "r2": float(si["along"][0, 1]), "r2_across": float(si["across"][0, 1])}
    forces = getattr(model, "forces", None)
    if forces is not None and forces.friction:  # viscous b and the Coulomb level (the lab's: cf pi / 2)
        with torch.no_grad():
            p_n = model.normalizer.params(data.params[:1].to(model.dtype))
            b, c = (x.reshape(-1) for x in forces.coefficients(p_n))
        out["friction"] = {**{f"b{i + 1}": float(v) for i, v in enumerate(b)},
                           **{f"coulomb{i + 1}": float(v) for i, v in enumerate(c)}}
    return out


def plot(results: dict, horizons, out: Path) -> None:
    from lnn_torch.evaluation import plots

    plt = plots.plt
    fig, ax = plt.subplots(figsize=(6, 3.4))
    for name, r in results.items():
        h = r["horizons"]
        ax.plot(horizons, [h[f"error@{x:g}s"]["median"] for x in horizons], "o-", label=f"{name}, median")
        ax.plot(horizons, [h[f"error@{x:g}s"]["p90"] for x in horizons], "o--", alpha=0.6, label=f"{name}, p90")
    ax.axhline(0.1, color="k", lw=0.8, ls=":")
    ax.set_xlabel("open-loop horizon (s)")
    ax.set_ylabel("angle error (rad)")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "error_vs_horizon.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    torch.set_num_threads(2)
    main()
