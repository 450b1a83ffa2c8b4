"""Why ``film_lnn``'s accelerations on the 7-joint arm were far off while its torques were close, and
what fixes it: training settings of ``configs/robot_arm.yaml`` side by side, their validation curves.

Each setting is ``lnn-torch fit -c configs/robot_arm.yaml`` with some overrides (``SETTINGS``), one
thread, its run under ``--runs``; the curves are each run's validation acceleration error (relative L2,
pooled over the validation split, every 5,000 steps) and open-loop time, read from its TensorBoard run.
Writes ``curves.png`` and ``curves.json`` and prints a table. The held-out comparison of the resulting
checkpoints is ``scripts/arm_results.py`` on trajectories of another seed (``results/robot_arm/film_lnn``).

    python scripts/arm_film_study.py                     # every setting (about 10 min each for 20,000 steps)
    python scripts/arm_film_study.py --settings "4000 trajectories" "4000 trajectories, 128 x 128"
    python scripts/arm_film_study.py --run "NAME=runs/x/lightning_logs/version_0"   # a run made before
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from _common import HelpFormatter, add_output_dir, wrote

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "robot_arm.yaml"
RUNS = "runs/arm_film_study"
STEPS_20K = ["--trainer.max_steps=20000"]
STEPS_60K = ["--trainer.max_steps=60000"]  # the config: 100,000
NARROW = ["--model.hidden_dims=[64,64]"]  # the width before (the config: 128 x 128)
DATA_1000 = ["--data.path=data/robot_arm.h5", "--data.spec.num_trajectories=1000", *NARROW]  # the config before
DATA_4000 = ["--data.path=data/robot_arm_4000.h5", "--data.spec.num_trajectories=4000"]
DATA_12000: list[str] = []  # the config: 12000 trajectories (data/robot_arm_12000.h5)
# 12000 more trajectories (seed 1) for training, the same validation split (about 25 min on one thread):
#   lnn-torch generate --scene robot_arm -n 12000 --duration 3 --dt 0.005 --seed 1 -o data/robot_arm_12000_seed1.h5
#   python scripts/join_trajectories.py data/robot_arm_12000.h5 data/robot_arm_12000_seed1.h5 \
#       -o data/robot_arm_24000.h5
DATA_24000 = ["--data.path=data/robot_arm_24000.h5", "--data.spec.num_trajectories=24000"]
PRODUCTS = ['--model.model_options={"mass_invariant": [0], "film_hidden": 32, '
            '"potential": {"products": {"skip": [0], "film_hidden": 0}}}']


THE_CONFIG = "12000 trajectories, 128 x 128, 100,000 steps (the config)"
# settings that start from another setting's last weights (``--model.init_from``): its steps come first
WARM = "the config, then a warm restart of 60,000 steps (lr 1e-3 to 1e-5)"
WARM2 = "the config, then two warm restarts of 60,000 steps (lr 1e-3 to 1e-5)"
WARM3 = "the config, then three warm restarts of 60,000 steps (lr 1e-3 to 1e-5)"
WARM3_MORE = "the config, two warm restarts, then a third on 24000 trajectories (12000 more)"
STARTS_AT = {WARM: 100000, WARM2: 160000, WARM3: 220000, WARM3_MORE: 220000}


def slug(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")[:60]


SETTINGS = {
    "1000 trajectories": [*DATA_1000, *STEPS_20K],
    "1000 trajectories, FiLM quadratic in the payload": [
        *DATA_1000, *STEPS_20K, '--model.model_options={"mass_invariant": [0], "film_hidden": 0}'],
    "4000 trajectories": [*DATA_4000, *STEPS_20K, *NARROW],
    "4000 trajectories, product-series potential": [*DATA_4000, *STEPS_20K, *NARROW, *PRODUCTS],
    "4000 trajectories, 60,000 steps": [*DATA_4000, *STEPS_60K, *NARROW],
    "4000 trajectories, 128 x 128": [*DATA_4000, *STEPS_20K],
    "delan, 4000 trajectories": [*DATA_4000, *STEPS_20K, *NARROW, "--model.variant=delan",
                                 '--model.model_options={"mass_invariant": [0]}'],
    "4000 trajectories, 128 x 128, 60,000 steps": [*DATA_4000, *STEPS_60K],
    "12000 trajectories, 128 x 128, 60,000 steps": [*DATA_12000, *STEPS_60K],
    THE_CONFIG: [*DATA_12000],
    WARM: [
        *STEPS_60K, f"--model.init_from={RUNS}/{slug(THE_CONFIG)}/lightning_logs/version_0/checkpoints/last.ckpt",
        "--model.lr=1e-3", "--model.lr_min=1e-5"],
    WARM2: [*STEPS_60K, f"--model.init_from={RUNS}/{slug(WARM)}/lightning_logs/version_0/checkpoints/last.ckpt",
            "--model.lr=1e-3", "--model.lr_min=1e-5"],
    WARM3: [*STEPS_60K, f"--model.init_from={RUNS}/{slug(WARM2)}/lightning_logs/version_0/checkpoints/last.ckpt",
            "--model.lr=1e-3", "--model.lr_min=1e-5"],
    WARM3_MORE: [*DATA_24000, *STEPS_60K,
                 f"--model.init_from={RUNS}/{slug(WARM2)}/lightning_logs/version_0/checkpoints/last.ckpt",
                 "--model.lr=1e-3", "--model.lr_min=1e-5"],
    "delan, 12000 trajectories, 128 x 128, 60,000 steps": [*DATA_12000, *STEPS_60K, "--model.variant=delan",
                                                           '--model.model_options={"mass_invariant": [0]}'],
}


def fit(name: str, runs: Path) -> Path:
    """Train one setting (skipped when its run exists) and return its TensorBoard run folder."""
    root = runs / slug(name)
    run = root / "lightning_logs" / "version_0"
    if (run / "checkpoints" / "last.ckpt").exists():
        return run
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "lnn_torch.cli", "fit", "-c", str(CONFIG), *SETTINGS[name],
           f"--trainer.default_root_dir={root}", "--trainer.enable_progress_bar=false"]
    print("$", " ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, cwd=ROOT, env=env, check=True)
    return run


def curves(run: Path, start: int = 0) -> dict:
    """``{tag: [[step, value], ...]}`` of the validation acceleration error and open-loop time; ``start``:
    the steps before the run (a run from another's weights)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run), size_guidance={"scalars": 0})
    acc.Reload()
    tags = ("val/acc_rel_err", "val/divergence_time", "train/huber", "train/torque")
    return {t: [[e.step + start, e.value] for e in acc.Scalars(t)] for t in tags if t in acc.Tags()["scalars"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--settings", nargs="+", default=list(SETTINGS), help="names of SETTINGS to train and compare")
    ap.add_argument("--run", action="append", default=[], metavar="NAME=RUN",
                    help="a setting's existing TensorBoard run (its folder) instead of training it; repeatable")
    ap.add_argument("--runs", default=str(ROOT / RUNS), help="where the runs go")
    add_output_dir(ap, str(ROOT / "results" / "robot_arm" / "film_lnn"), "the folder of curves.png and curves.json")
    args = ap.parse_args()
    given = dict(item.split("=", 1) for item in args.run)
    unknown = [s for s in [*args.settings, *given] if s not in SETTINGS]
    if unknown:
        raise SystemExit(f"unknown settings {unknown}; choose from {list(SETTINGS)}")
    names = [s for s in SETTINGS if s in args.settings or s in given]
    result = {}
    for name in names:
        run = Path(given[name]) if name in given else fit(name, Path(args.runs))
        result[name] = {"overrides": SETTINGS[name], "curves": curves(run, STARTS_AT.get(name, 0))}
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "curves.json").write_text(json.dumps(result, indent=1))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax in axes:
        ax.set_prop_cycle(color=plt.cm.tab20.colors)  # a colour of its own for each of up to 20 settings
    for name, r in result.items():
        for ax, tag in zip(axes, ("val/acc_rel_err", "val/divergence_time"), strict=True):
            pts = r["curves"].get(tag, [])
            if pts:
                steps, values = zip(*pts, strict=True)
                ax.plot(steps, [100 * v if tag == "val/acc_rel_err" else v for v in values], "o-", label=name)
    axes[0].set(xlabel="training step", ylabel="validation acceleration error, rel. L2 (%)", yscale="log")
    axes[1].set(xlabel="training step", ylabel="validation open loop within 0.1 rad, median (s)")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=110)
    from lnn_torch.evaluation import table_header, table_row

    marks = (5000, 10000, 15000, 20000, 60000, 100000, 160000, 220000, 280000)
    head = [f"val. acc. error at {' / '.join(f'{k // 1000}k' for k in marks)} steps", "open loop (s), last"]
    print("\n".join(table_header(["setting", *head])))
    for name, r in result.items():
        acc = dict((int(s), v) for s, v in r["curves"].get("val/acc_rel_err", []))
        cells = " / ".join(f"{100 * acc[k - 1]:.1f} %" if k - 1 in acc else "–"
                           for k in marks)
        div = r["curves"].get("val/divergence_time", [[0, float("nan")]])[-1][1]
        print(table_row([name, cells, f"{div:.2f}"]))
    wrote(out / "curves.json", out / "curves.png")


if __name__ == "__main__":
    main()
