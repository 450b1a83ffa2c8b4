"""Training ablations: the same data, seed and wall-clock budget for every setting; test-split metrics.

Each setting is a name and LightningCLI overrides on top of a base config. Every run trains for
``--minutes`` (``trainer.max_time``; the cosine learning-rate schedule ends with the budget), then
``test`` reports the relative L2 acceleration error on the test split and RK4 rollouts of
``--rollouts`` test trajectories (dt = the data's, ``--rollout-seconds`` long): median time to a
0.1 rad error and mean true-energy drift. Prints a Markdown table (and, with ``-o/--output FILE``,
writes it and the rows as JSON to that one Markdown file).

    # how to batch the points: chunk length x chunks per batch
    python scripts/ablate.py --minutes 4 \\
        --setting "8x64" data.chunk_len=8 data.chunks_per_batch=64 \\
        --setting "64x8" data.chunk_len=64 data.chunks_per_batch=8
    # the energy-conservation weight, on an equal step budget
    python scripts/ablate.py --steps 20000 --setting "w=0" model.energy_weight=0 \\
        --setting "w=0.1" model.energy_weight=0.1
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from _common import HelpFormatter, add_output_file, wrote

ROOT = Path(__file__).resolve().parents[1]


def run(name: str, overrides: list[str], args) -> dict:
    from lnn_torch import LNNModule, TrajectoryDataModule
    from lnn_torch.training import LNNCLI, TRAINER_DEFAULTS

    if args.steps:  # a step budget: deterministic, and immune to other load on the machine
        budget = [f"--trainer.max_steps={args.steps}", "--trainer.max_epochs=100000"]
    else:
        seconds = int(round(args.minutes * 60))
        max_time = f"00:{seconds // 3600:02d}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"  # DD:HH:MM:SS
        budget = [f"--trainer.max_time={max_time}", "--trainer.max_epochs=100000"]
    argv = ["-c", str(args.config), *budget, "--trainer.enable_progress_bar=false",
            f"--trainer.check_val_every_n_epoch={args.val_every}", "--trainer.logger.init_args.save_dir=lightning_logs",
            f"--trainer.logger.init_args.name={args.log_name}", f"--model.val_rollout_seconds={args.rollout_seconds}",
            "--model.val_rollouts=0", f"--model.test_rollouts={args.rollouts}", f"--seed_everything={args.seed}"]
    argv += [o if o.startswith("--") else f"--{o}" for o in overrides]
    cli = LNNCLI(LNNModule, TrajectoryDataModule, args=argv, run=False, trainer_defaults=TRAINER_DEFAULTS)
    start = time.perf_counter()
    cli.trainer.fit(cli.model, cli.datamodule)
    train_s = time.perf_counter() - start
    metrics = cli.trainer.test(cli.model, cli.datamodule, verbose=False)[0]
    row = {"name": name, "overrides": overrides, "train_seconds": train_s, "steps": cli.trainer.global_step,
           "skipped_steps": int(cli.model.skipped_steps), "log_dir": cli.trainer.log_dir,
           **{k: float(v) for k, v in metrics.items()}}
    print(json.dumps(row), flush=True)
    return row


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--config", default=str(ROOT / "configs" / "quickstart.yaml"), help="the base config")
    ap.add_argument("--setting", nargs="+", action="append", required=True, metavar=("NAME", "OVERRIDE"),
                    help="a name and LightningCLI overrides (key=value); repeat for each setting")
    ap.add_argument("--minutes", type=float, default=4.0, help="wall-clock training budget per setting")
    ap.add_argument("--steps", type=int, default=None, help="a step budget instead of --minutes")
    ap.add_argument("--seed", type=int, default=0, help="seed_everything, unless a setting sets it")
    ap.add_argument("--rollouts", type=int, default=10, help="test trajectories rolled out")
    ap.add_argument("--rollout-seconds", type=float, default=10.0, help="rollout horizon, s")
    ap.add_argument("--val-every", type=int, default=1000, help="validation interval in epochs")
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--log-name", default="ablate", help="TensorBoard run name under lightning_logs/")
    add_output_file(ap, None, "also write the table and the rows (JSON) to this one Markdown file")
    return ap


def main() -> None:
    args = parser().parse_args()
    from lnn_torch.evaluation import table_header, table_row

    torch.set_num_threads(args.threads)
    rows = [run(s[0], s[1:], args) for s in args.setting]
    budget = f"{args.steps} steps" if args.steps else f"{args.minutes:g} min"
    lines = [f"config {Path(args.config).name}, {budget} of training per setting on {args.threads} threads, "
             f"seed {args.seed} unless a setting sets one; test split; RK4 rollouts (data dt) of {args.rollouts} "
             f"test trajectories over {args.rollout_seconds:g} s", "",
             *table_header(["setting", "steps", "train time (s)", "test acc. rel. L2", "median time to 0.1 rad (s)",
                            "mean true-energy drift", "skipped steps"])]
    for r in rows:
        lines.append(table_row([r["name"], r["steps"], f"{r['train_seconds']:.0f}", f"{r['test/acc_rel_err']:.4f}",
                                f"{r['test/divergence_time']:.2f}", f"{r['test/energy_drift']:.2e}",
                                r["skipped_steps"]]))
    table = "\n".join(lines)
    print("\n" + table)
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        Path(args.output).write_text(table + "\n\n```json\n" + json.dumps(rows, indent=1) + "\n```\n")
    wrote([args.output] if args.output else [], [r["log_dir"] for r in rows if r["log_dir"]])  # + the training runs


if __name__ == "__main__":
    main()
