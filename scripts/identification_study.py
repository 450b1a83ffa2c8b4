"""Identification study: the shipped double-pendulum model identifies the parameters of held-out
trajectories (fresh draws from its training distribution), against observation length and position
noise, beside the same fit on the true equations (the closed form) and classical linear least squares.

    python scripts/identification_study.py --trajectories 20 --lengths 2 -o /tmp/id   # a quick look
    python scripts/identification_study.py -o results/identification   # the README's study (~30 min)

Writes ``study.json`` (every estimate), ``study.md`` (the table) and ``study.png`` (error against
length and noise). The dataset (``--data``, generated when missing: seed 2026, never used in training)
holds 5 s trajectories; shorter observations are their beginnings. Velocities and accelerations are
estimated from the (noisy) positions alone. Times are per identification, in a batch of
``--batch`` trajectories on one thread.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from _common import HelpFormatter, add_output_dir, wrote

QUANTITIES = ("l1", "l2", "m2/m1")


def truth_of(params: torch.Tensor) -> dict:
    m1, m2, l1, l2 = params.double().unbind(-1)
    return {"l1": l1, "l2": l2, "m2/m1": m2 / m1}


def run_case(model, system, tr, seconds: float, noise: float, args, rng) -> dict:
    from lnn_torch.identification import identify_batch, least_squares_reference
    from lnn_torch.systems import ClosedForm

    T = int(round(seconds / tr.dt)) + 1
    t = np.arange(T) * tr.dt
    q = tr.q[:, :T].double().numpy()
    q = q + rng.normal(0.0, noise, q.shape) if noise else q
    truth = truth_of(tr.params)
    rows = {name: {"model": [], "closed_form": [], "least_squares": [], "rel_std": []} for name in QUANTITIES}
    seconds_per_id, unidentified, at_bound = [], 0, 0
    for b in range(0, len(q), args.batch):
        chunk = q[b:b + args.batch]
        start = time.perf_counter()
        found = identify_batch(model, system, t, chunk, method=args.method, starts=args.starts, steps=args.steps)
        seconds_per_id.append((time.perf_counter() - start) / len(chunk))
        exact = identify_batch(ClosedForm(system), system, t, chunk, method="acceleration", starts=args.starts,
                               steps=args.steps)
        for i, (r, e) in enumerate(zip(found, exact, strict=True)):
            j = b + i
            ls = least_squares_reference(system, t, chunk[i])
            unidentified += any(set(d["direction"]) >= {"m1", "m2"} for d in r.unidentifiable)
            at_bound += bool(r.at_bound)
            for name in QUANTITIES:
                true = float(truth[name][j])
                rows[name]["model"].append(r.quantities[name]["value"] / true - 1)
                rows[name]["rel_std"].append(r.quantities[name]["rel_std"])
                rows[name]["closed_form"].append(e.quantities[name]["value"] / true - 1)
                rows[name]["least_squares"].append(ls[name]["value"] / true - 1)
    summary = {}
    for name, r in rows.items():
        err = np.abs(np.asarray(r["model"]))
        z = err / np.asarray([s if s else np.nan for s in r["rel_std"]])
        summary[name] = {"median": float(np.median(err)), "p90": float(np.quantile(err, 0.9)),
                         "closed_form_median": float(np.median(np.abs(r["closed_form"]))),
                         "least_squares_median": float(np.median(np.abs(r["least_squares"]))),
                         "within_2std": float(np.mean(z < 2))}
    return {"seconds": seconds, "noise": noise, "trajectories": len(q), "time_per_id": float(np.median(seconds_per_id)),
            "mass_scale_flagged": unidentified / len(q), "at_bound": at_bound / len(q), "summary": summary,
            "errors": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--checkpoint", default="pretrained:double_pendulum_box",
                    help="the model: a .ckpt or pretrained:NAME (default: the box model, whose table results/ shows)")
    ap.add_argument("--data", default="data/identification_study.h5", help="the dataset (generated when missing)")
    ap.add_argument("--trajectories", type=int, default=200, help="at the headline length (2 s)")
    ap.add_argument("--sweep-trajectories", type=int, default=30, help="at the other lengths")
    ap.add_argument("--lengths", type=float, nargs="+", default=[0.5, 1.0, 2.0, 5.0], help="observation lengths, s")
    ap.add_argument("--noise", type=float, nargs="+", default=[0.0, 1e-3], help="position noise levels, rad")
    ap.add_argument("--method", default="acceleration", help="acceleration, trajectory or both (as lnn-torch identify)")
    ap.add_argument("--starts", type=int, default=4, help="random starts per trajectory")
    ap.add_argument("--steps", type=int, default=150, help="Adam steps per fit (then L-BFGS)")
    ap.add_argument("--batch", type=int, default=20, help="trajectories identified together")
    add_output_dir(ap, "results/identification", "the folder of study.json, study.md and study.png", old=())
    ap.add_argument("--combine", nargs="+", default=None, metavar="DIR",
                    help="only write the table and plot of the cases in these output folders (runs split by noise)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.combine:
        out = Path(args.output_dir)
        out.mkdir(parents=True, exist_ok=True)
        cases = [c for d in args.combine for c in json.loads((Path(d) / "study.json").read_text())["cases"]]
        (out / "study.json").write_text(json.dumps({"checkpoint": args.checkpoint, "method": args.method,
                                                    "cases": cases}, indent=1))
        write_table(cases, out / "study.md", args)
        plot(cases, out / "study.png")
        print((out / "study.md").read_text())
        wrote(out / "study.json", out / "study.md", out / "study.png")
        return

    from lnn_torch import load_model
    from lnn_torch.data import DatasetSpec, generate_dataset, read_dataset

    generated = [] if Path(args.data).exists() else [args.data]
    if generated:
        generate_dataset(DatasetSpec(scene="double_pendulum", num_trajectories=max(args.trajectories, 2) * 2,
                                     duration=5.0, seed=2026, split=[0.25, 0.25, 0.5]), args.data)
    module = load_model(args.checkpoint)
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    f = read_dataset(args.data)
    cases = []
    for noise in args.noise:
        for seconds in args.lengths:
            n = args.trajectories if seconds == 2.0 else args.sweep_trajectories
            tr = f.trajectories("test", n)
            case = run_case(module.model, module.system, tr, seconds, noise, args, np.random.default_rng(0))
            cases.append(case)
            s = case["summary"]
            print(f"{seconds:4.1f} s noise {noise:g}: "
                  + ", ".join(f"{k} {100 * v['median']:.3f} %" for k, v in s.items())
                  + f" ({case['trajectories']} trajectories, {case['time_per_id']:.2f} s each)", flush=True)
            (out / "study.json").write_text(json.dumps({"checkpoint": args.checkpoint, "method": args.method,
                                                        "cases": cases}, indent=1))
    write_table(cases, out / "study.md", args)
    plot(cases, out / "study.png")
    wrote(out / "study.json", out / "study.md", out / "study.png", generated)


def write_table(cases, path: Path, args) -> None:
    from lnn_torch.evaluation import pct, table_header, table_row

    lines = [f"Median relative error (90th percentile) of the identified quantities; {args.checkpoint}, "
             f"{args.method} fit, {args.starts} starts; beside it the same fit on the true equations (closed form) "
             "and linear least squares on the true equations, from the same positions.", "",
             *table_header(["observation", "noise (rad)", "trajectories", *QUANTITIES, "closed form l1 / l2 / m2/m1",
                            "least squares l1 / l2 / m2/m1", "within 2 std", "mass scale flagged",
                            "s per identification"])]
    for c in cases:
        s = c["summary"]
        lines.append(table_row([f"{c['seconds']:g} s", f"{c['noise']:g}", c["trajectories"],
                                *(f"{pct(s[k]['median'], 2)} ({pct(s[k]['p90'], 2)})" for k in QUANTITIES),
                                " / ".join(pct(s[k]["closed_form_median"], 2) for k in QUANTITIES),
                                " / ".join(pct(s[k]["least_squares_median"], 2) for k in QUANTITIES),
                                " / ".join(f"{100 * s[k]['within_2std']:.0f} %" for k in QUANTITIES),
                                f"{100 * c['mass_scale_flagged']:.0f} %", f"{c['time_per_id']:.2f}"]))
    path.write_text("\n".join(lines) + "\n")


def plot(cases, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(QUANTITIES), figsize=(11, 3.2), sharey=True)
    for ax, name in zip(axes, QUANTITIES, strict=True):
        for k, noise in enumerate(sorted({c["noise"] for c in cases})):
            sel = sorted((c for c in cases if c["noise"] == noise), key=lambda c: c["seconds"])
            x = [c["seconds"] for c in sel]
            ax.plot(x, [100 * c["summary"][name]["median"] for c in sel], "o-", color=f"C{k}",
                    label=f"model, noise {noise:g} rad")
            ax.plot(x, [100 * c["summary"][name]["closed_form_median"] for c in sel], "s:", color=f"C{k}", alpha=0.6,
                    label=f"true equations, noise {noise:g} rad")
        ax.set_xscale("log")
        ax.set_yscale("log")
        lengths = sorted({c["seconds"] for c in cases})
        ax.set_xticks(lengths, [f"{x:g}" for x in lengths])
        ax.minorticks_off()
        ax.set_title(name)
        ax.set_xlabel("observation length [s]")
    axes[0].set_ylabel("median relative error [%]")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
