"""A generated dataset's trajectories written as a lab logs its recordings: one CSV per trajectory
(``time, q1..qN, dq1..dqN, tau1..``) and the import configuration that reads them back, each
recording's known parameters (the simulated arm's payload) in it and the dataset's own train/val/test
split by recording (``lnn_torch.data.export_csv``). Then import them as a lab's recordings:

    python scripts/arm_recordings.py data/robot_arm.h5 -o data/robot_arm_recordings
    lnn-torch import data/robot_arm_recordings/traj_*.csv --config data/robot_arm_recordings/import.yaml \\
        -o data/robot_arm_recordings.h5

``--jitter S`` moves every time stamp but the first and the last by up to S seconds (the values those of
the motion at the moved stamps), as a logger's jitter does; without it the import gives the dataset's
values exactly. ``scripts/arm_recordings_compare.py`` compares models trained both ways.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from _common import HelpFormatter, add_output_dir, wrote


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("data", help="the generated dataset (.h5)")
    add_output_dir(ap, "data/robot_arm_recordings", "the folder the CSV recordings go to")
    ap.add_argument("--config", default=None, help="the import configuration to write (YAML; default: "
                    "import.yaml in the output folder)")
    ap.add_argument("--prefix", default="traj", help="recording names: PREFIX_INDEX")
    ap.add_argument("--jitter", type=float, default=0.0, help="time-stamp jitter, s (uniform, < dt / 2)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the jitter")
    ap.add_argument("--gzip", action="store_true", help="write .csv.gz files")
    ap.add_argument("--overwrite", action="store_true", help="replace existing files")
    return ap


def main() -> None:
    args = parser().parse_args()
    from lnn_torch.data import export_recordings

    config = args.config or str(Path(args.output_dir) / "import.yaml")
    paths, config_path = export_recordings(args.data, args.output_dir, config, prefix=args.prefix,
                                           jitter=args.jitter, seed=args.seed, compress=args.gzip,
                                           overwrite=args.overwrite)
    print(f"{len(paths)} recordings in {args.output_dir}; import them with: lnn-torch import "
          f"{args.output_dir}/{args.prefix}_*.csv{'.gz' if args.gzip else ''} --config {config_path} -o DATASET.h5")
    wrote(config_path, f"{args.output_dir}/{args.prefix}_*.csv{'.gz' if args.gzip else ''} ({len(paths)} files)")


if __name__ == "__main__":
    main()
