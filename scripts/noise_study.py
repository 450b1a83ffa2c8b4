"""Noise study: what measured data (noisy, quantised encoder angles; noisy velocities; no
accelerations) does to the training targets and to the trained model, on the actuated double pendulum.

Part 1, targets (no training): synthetic recordings (seeded, from the generator at 1 kHz, thinned to
each rate) with position noise sigma, a 12-bit encoder's quantisation and velocity noise; the
relative L2 error of each target mode's accelerations against the exact ones: plain finite
differences of the positions (what the JAX original does), finite differences of the measured
velocities, Butterworth, Savitzky-Golay and smoothing-spline estimates.

Part 2, training (``--train``): at ``--rate`` Hz and ``--sigma`` rad, one model per target mode
(exact accelerations of clean data; finite differences, smoothed estimates and trajectory matching of
the noisy data), a fixed number of steps each (trained as ``lnn-torch fit`` trains: ``make_trainer``,
gradients clipped at norm 1), judged on clean held-out trajectories: acceleration
error against the truth and the median time until an open-loop rollout (driven by the recorded
torques) first leaves 0.1 rad.

    python scripts/noise_study.py -o results/noise_study                  # part 1 (a minute)
    python scripts/noise_study.py --train -o results/noise_study      # + part 2 (10,000 steps per row)
    python scripts/noise_study.py --train --skip-targets --steps 30000 --training-name training_30k_steps \
        --modes "exact accelerations, clean data" "finite differences of positions" "Savitzky-Golay 0.1 s"
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from _common import HelpFormatter, add_output_dir, wrote

SCENE = "actuated_double_pendulum"
ENCODER = 2 * np.pi / 4096  # a 12-bit encoder's step, rad


def corrupt(q, qd, dt, sigma, rng, quantise=True, velocity_sigma=None):
    """Noisy, quantised positions and noisy velocities (``(N, T, dof)``)."""
    qn = q + rng.normal(0.0, sigma, q.shape) if sigma else q.copy()
    if quantise:
        qn = np.round(qn / ENCODER) * ENCODER
    vs = velocity_sigma if velocity_sigma is not None else (10 * sigma if sigma else 0.0)
    qdn = qd + rng.normal(0.0, vs, qd.shape) if vs else qd.copy()
    return qn, qdn


TARGET_MODES = {
    "finite differences of positions": {"method": "finite_difference", "use_measured_velocity": False},
    "finite differences of velocities": {"method": "finite_difference", "use_measured_velocity": True},
    "Butterworth 10 Hz": {"method": "butterworth", "cutoff": 10.0, "order": 4, "use_measured_velocity": True},
    "Savitzky-Golay 0.1 s": {"method": "savgol", "window": None, "polyorder": 3, "use_measured_velocity": True},
    "smoothing spline (GCV)": {"method": "spline", "lam": None, "use_measured_velocity": False},
}


def settings_at(mode: dict, dt: float) -> dict:
    from lnn_torch.data import derivatives

    mode = dict(mode)
    if mode.get("method") == "savgol":  # 0.1 s at every rate
        mode["window"] = max(5, int(round(0.1 / dt)) | 1)
    return derivatives.settings(mode)


def part_targets(args, out: Path) -> list[Path]:
    """Part 1; the paths it wrote."""
    from lnn_torch.data import DatasetSpec, derivatives, generate_dataset, read_dataset
    from lnn_torch.evaluation import table_header, table_row

    path = Path(args.work) / "targets_1khz.h5"
    generated = [] if path.exists() else [path]
    if generated:
        generate_dataset(DatasetSpec(scene=SCENE, num_trajectories=args.target_trajectories, duration=4.0, dt=0.001,
                                     seed=11, split=[0.5, 0.25, 0.25]), path)
    tr = read_dataset(path).trajectories(None)
    rows = []
    for rate in args.rates:
        k = int(round(1000 / rate))
        q, qd, qdd = (x[:, ::k].double().numpy() for x in (tr.q, tr.qd, tr.qdd))
        dt = tr.dt * k
        for sigma in args.sigmas:
            qn, qdn = corrupt(q, qd, dt, sigma, np.random.default_rng(0), quantise=sigma > 0)
            for name, mode in TARGET_MODES.items():
                s = settings_at(mode, dt)
                if s["method"] == "spline" and len(qn[0]) > 1000:  # GCV on long records: minutes each
                    continue
                est = np.stack([derivatives.estimate(qn[i], dt, s, qdn[i])[1] for i in range(len(qn))])
                cut = slice(int(0.1 / dt), -int(0.1 / dt))  # the ends, where every estimate is worst
                err = float(np.sqrt(((est[:, cut] - qdd[:, cut]) ** 2).sum() / (qdd[:, cut] ** 2).sum()))
                rows.append({"rate_hz": rate, "sigma": sigma, "mode": name, "acc_rel_err": err})
                print(f"{rate:5.0f} Hz  sigma {sigma:g}  {name:34s} {100 * err:9.3f} %", flush=True)
    (out / "targets.json").write_text(json.dumps(rows, indent=1))
    lines = ["Relative L2 error of the target accelerations against the exact ones (ends of 0.1 s left out); "
             "noise: position sigma plus 12-bit quantisation, velocity noise 10 sigma rad/s.", "",
             *table_header(["rate", "sigma (rad)", *TARGET_MODES])]
    for rate in args.rates:
        for sigma in args.sigmas:
            cells = []
            for name in TARGET_MODES:
                r = [x for x in rows if x["rate_hz"] == rate and x["sigma"] == sigma and x["mode"] == name]
                cells.append(f"{100 * r[0]['acc_rel_err']:.3g} %" if r else "–")
            lines.append(table_row([f"{rate:g} Hz", f"{sigma:g}", *cells]))
    (out / "targets.md").write_text("\n".join(lines) + "\n")
    plot_targets(rows, args, out / "targets.png")
    return [out / "targets.json", out / "targets.md", out / "targets.png", *generated]


def plot_targets(rows, args, path: Path) -> None:
    from lnn_torch.evaluation import plots

    plt = plots.plt
    fig, axes = plt.subplots(1, len(args.rates), figsize=(3.2 * len(args.rates), 3.2), sharey=True, squeeze=False)
    for ax, rate in zip(axes[0], args.rates, strict=True):
        for k, name in enumerate(TARGET_MODES):
            r = sorted((x for x in rows if x["rate_hz"] == rate and x["mode"] == name), key=lambda x: x["sigma"])
            if r:
                ax.plot([max(x["sigma"], 1e-5) for x in r], [100 * x["acc_rel_err"] for x in r], "o-", color=f"C{k}",
                        label=name)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{rate:g} Hz")
        ax.set_xlabel("position noise sigma (rad; 1e-5 = none)")
    axes[0, 0].set_ylabel("target acceleration error (%)")
    axes[0, 0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def part_training(args, out: Path) -> list[Path]:
    """Part 2; the paths it wrote."""
    from lnn_torch import LNNModule, TrajectoryDataModule
    from lnn_torch.data import DatasetSpec, copy_dataset, generate_dataset, read_dataset
    from lnn_torch.evaluation import evaluate_model, table_header, table_row
    from lnn_torch.training import make_trainer

    dt = 1.0 / args.rate
    clean = Path(args.work) / f"train_{args.rate:g}hz.h5"
    noisy = Path(args.work) / f"train_{args.rate:g}hz_sigma{args.sigma:g}.h5"
    generated = [p for p in (clean, noisy) if not p.exists()]
    if not clean.exists():
        generate_dataset(DatasetSpec(scene=SCENE, num_trajectories=args.train_trajectories, duration=4.0, dt=dt,
                                     seed=12), clean)
    if not noisy.exists():  # the clean file with noisy angles and velocities
        f = read_dataset(clean)
        qn, qdn = corrupt(f.read("q"), f.read("qd"), dt, args.sigma, np.random.default_rng(1))
        copy_dataset(clean, noisy, arrays={"q": qn, "qd": qdn})
    spec = dict(read_dataset(clean).spec)
    test = TrajectoryDataModule(path=str(clean), spec=spec).trajectories("test", args.test_trajectories)
    sg = settings_at(TARGET_MODES["Savitzky-Golay 0.1 s"], dt)
    # name -> (file, targets, data options, model options). Acceleration targets train on batches of
    # single points (as configs/actuated_double_pendulum.yaml); trajectory matching needs windows
    # (chunks of 8 points: 7 steps), with the same number of points per batch.
    points = {"chunk_len": args.chunk_len, "chunks_per_batch": args.chunks_per_batch}
    windows = {"chunk_len": 8, "chunks_per_batch": max(1, args.chunk_len * args.chunks_per_batch // 8)}
    runs = {
        "exact accelerations, clean data": (clean, "file", points, {}),
        "finite differences of positions": (noisy, TARGET_MODES["finite differences of positions"], points, {}),
        "Savitzky-Golay 0.1 s": (noisy, sg, points, {}),
        "Savitzky-Golay 0.1 s, torques filtered alike": (noisy, sg, {**points, "smooth_inputs": True}, {}),
        "trajectory matching": (noisy, "file", windows, {"loss": "trajectory"}),
    }
    if args.modes:
        unknown = sorted(set(args.modes) - set(runs))
        if unknown:
            raise SystemExit(f"unknown --modes {unknown}; choose from {list(runs)}")
        runs = {k: v for k, v in runs.items() if k in args.modes}
    rows = []
    for name, (path, targets, data_options, extra) in runs.items():
        torch.manual_seed(0)
        dm = TrajectoryDataModule(path=str(path), spec=spec, targets=targets, steps_per_epoch=args.steps,
                                  **data_options)
        module = LNNModule(scene=SCENE, hidden_dims=[64, 64], val_rollouts=0, lr=3e-3, **extra)
        # as `lnn-torch fit` trains (gradient clipping at 1.0), without its logger, checkpoints and validation
        trainer = make_trainer(max_epochs=1, logger=False, callbacks=[], enable_checkpointing=False,
                               enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0,
                               num_sanity_val_steps=0)
        start = time.perf_counter()
        trainer.fit(module, dm)
        seconds = time.perf_counter() - start
        module.eval()
        r = evaluate_model(module.model, module.system, test, sections=("accelerations", "rollouts"),
                           horizon=args.horizon, thresholds=(0.1,))
        row = {"mode": name, "batch": f"{dm.hparams.chunks_per_batch} x {dm.hparams.chunk_len}",
               "acc_rel_err": r["acc_rel_err"]["total"],
               "time_to_0.1_median": r["divergence_time@0.1"]["model"]["median"], "train_seconds": seconds}
        rows.append(row)
        print(f"{name:34s} acc {100 * row['acc_rel_err']:.2f} %  time to 0.1 rad {row['time_to_0.1_median']:.2f} s "
              f"({seconds:.0f} s training)", flush=True)
    name = args.training_name
    (out / f"{name}.json").write_text(json.dumps({"rate_hz": args.rate, "sigma": args.sigma, "steps": args.steps,
                                                  "rows": rows}, indent=1))
    lines = [f"Actuated double pendulum at {args.rate:g} Hz, position noise {args.sigma:g} rad + 12-bit quantisation, "
             f"velocity noise {10 * args.sigma:g} rad/s; film_lnn 64x64, {args.steps} steps each; judged on "
             f"{len(test)} clean held-out trajectories (rollouts {args.horizon:g} s, driven by the recorded "
             "torques).", "",
             *table_header(["training target", "batch (chunks x points)", "held-out acc. rel. L2",
                            "median time within 0.1 rad (s)", "training (s)"])]
    for r in rows:
        lines.append(table_row([r["mode"], r["batch"], f"{100 * r['acc_rel_err']:.2f} %",
                                f"{r['time_to_0.1_median']:.2f}", f"{r['train_seconds']:.0f}"]))
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")
    return [out / f"{name}.json", out / f"{name}.md", *generated]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--rates", type=float, nargs="+", default=[100, 250, 500, 1000], help="part 1: sampling rates, Hz")
    ap.add_argument("--sigmas", type=float, nargs="+", default=[0, 1e-4, 1e-3, 1e-2],
                    help="part 1: position noise levels, rad")
    ap.add_argument("--target-trajectories", type=int, default=20, help="part 1: synthetic recordings")
    ap.add_argument("--train", action="store_true", help="also part 2 (training, minutes per mode)")
    ap.add_argument("--rate", type=float, default=500.0, help="part 2: sampling rate, Hz")
    ap.add_argument("--sigma", type=float, default=1e-3, help="part 2: position noise, rad")
    ap.add_argument("--steps", type=int, default=10000, help="part 2: training steps per mode")
    ap.add_argument("--chunk-len", type=int, default=1, help="points per chunk of the acceleration-target runs")
    ap.add_argument("--chunks-per-batch", type=int, default=512,
                    help="chunks per batch of the acceleration-target runs")
    ap.add_argument("--modes", nargs="+", help="only these training rows (names as in the table)")
    ap.add_argument("--training-name", default="training", help="part 2 writes NAME.json and NAME.md")
    ap.add_argument("--train-trajectories", type=int, default=100, help="part 2: training recordings")
    ap.add_argument("--test-trajectories", type=int, default=10, help="part 2: clean held-out trajectories")
    ap.add_argument("--horizon", type=float, default=4.0, help="part 2: rollout horizon, s")
    ap.add_argument("--work", default="data/noise_study", help="where the generated datasets go")
    ap.add_argument("--skip-targets", action="store_true", help="skip part 1")
    add_output_dir(ap, "results/noise_study", "the folder of the tables and the plot", old=())
    args = ap.parse_args()
    torch.set_num_threads(1)
    Path(args.work).mkdir(parents=True, exist_ok=True)
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    if not args.skip_targets:
        written += part_targets(args, out)
    if args.train:
        written += part_training(args, out)
    wrote(written)


if __name__ == "__main__":
    main()
