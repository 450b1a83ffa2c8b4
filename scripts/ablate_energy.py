"""Energy-regulariser ablation: train the quickstart setting with several energy weights (same
data, seed and step budget) and report test-split metrics of each.

    python scripts/ablate_energy.py --weights 0 0.1 1 --epochs 6 --steps-per-epoch 500

Each run uses contiguous chunks (``--chunk-len`` x ``--chunks``) so that the variance of the
model's Hamiltonian over a chunk is meaningful. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def run(weight: float, args) -> dict:
    from lnn_torch.lightning_cli import LNNCLI, TRAINER_DEFAULTS
    from lnn_torch import LNNModule, TrajectoryDataModule

    argv = ["-c", str(ROOT / "configs" / "quickstart.yaml"), f"--model.energy_weight={weight}",
            f"--trainer.max_epochs={args.epochs}", f"--data.steps_per_epoch={args.steps_per_epoch}",
            f"--data.chunk_len={args.chunk_len}", f"--data.chunks_per_batch={args.chunks}",
            "--trainer.enable_progress_bar=false", "--trainer.check_val_every_n_epoch=1000",
            "--trainer.logger.init_args.save_dir=lightning_logs", "--trainer.logger.init_args.name=ablate_energy", f"--model.val_rollout_seconds={args.rollout_seconds}",
            f"--model.val_rollouts={args.rollouts}"]
    cli = LNNCLI(LNNModule, TrajectoryDataModule, args=argv, run=False, trainer_defaults=TRAINER_DEFAULTS)
    start = time.perf_counter()
    cli.trainer.fit(cli.model, cli.datamodule)
    train_s = time.perf_counter() - start
    metrics = cli.trainer.test(cli.model, cli.datamodule, verbose=False)[0]
    metrics["train_seconds"] = train_s
    metrics["log_dir"] = cli.trainer.log_dir
    return metrics


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--weights", type=float, nargs="+", default=[0.0, 0.1, 1.0])
    ap.add_argument("--epochs", type=int, default=6)
    ap.add_argument("--steps-per-epoch", type=int, default=500)
    ap.add_argument("--chunk-len", type=int, default=16)
    ap.add_argument("--chunks", type=int, default=32)
    ap.add_argument("--rollouts", type=int, default=8)
    ap.add_argument("--rollout-seconds", type=float, default=10.0)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    rows = [(w, run(w, args)) for w in args.weights]
    print(f"\nquickstart data, {args.epochs * args.steps_per_epoch} steps of {args.chunks} x {args.chunk_len} points; "
          f"test split; rollouts RK4 dt=0.005 over {args.rollout_seconds} s of {args.rollouts} test trajectories\n")
    print("| energy_weight | test acc rel. L2 | median divergence time @0.1 rad (s) | mean true-energy drift | train time (s) |")
    print("|---|---|---|---|---|")
    for w, m in rows:
        print(f"| {w:g} | {m['test/acc_rel_err']:.4f} | {m['test/divergence_time']:.2f} | {m['test/energy_drift']:.2e} "
              f"| {m['train_seconds']:.0f} |")


if __name__ == "__main__":
    main()
