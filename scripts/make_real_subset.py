"""Copy the columns of the real double pendulum's recordings that a model needs (time, measured
positions, velocities and torques) into the package, gzipped, with the licence and the lab's
identified parameters (``lnn_torch/datasets/real_double_pendulum``).

    python scripts/make_real_subset.py [--source ../shared/data/real_double_pendulum] [-o FOLDER]

The values are copied as text, unchanged; only the other columns are left out.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import shutil
from pathlib import Path

from _common import HelpFormatter, add_output_dir, wrote

ROOT = Path(__file__).resolve().parents[1]
COLUMNS = ["time", "pos_meas1", "pos_meas2", "vel_meas1", "vel_meas2", "tau_meas1", "tau_meas2"]


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--source", default=str(ROOT.parent / "shared" / "data" / "real_double_pendulum"),
                    help="the lab's folder: recordings/*.csv, LICENSE, identified_parameters.yml")
    add_output_dir(ap, str(ROOT / "lnn_torch" / "datasets" / "real_double_pendulum"),
                   "the folder to write (recordings/*.csv.gz, LICENSE, identified_parameters.yml)")
    return ap


def main() -> None:
    args = parser().parse_args()
    src, out = Path(args.source), Path(args.output_dir)
    (out / "recordings").mkdir(parents=True, exist_ok=True)
    written = []
    for path in sorted((src / "recordings").glob("*.csv")):
        with path.open(newline="") as fh:
            reader = csv.reader(fh)
            header = next(reader)
            index = [header.index(c) for c in COLUMNS]
            rows = [[row[i] for i in index] for row in reader]
        with gzip.open(out / "recordings" / f"{path.name}.gz", "wt", compresslevel=9, newline="") as fh:
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(COLUMNS)
            writer.writerows(rows)
        written.append(out / "recordings" / f"{path.name}.gz")
        print(f"{path.name}: {len(rows)} rows")
    for name in ("LICENSE", "identified_parameters.yml"):
        shutil.copy(src / name, out / name)
        written.append(out / name)
    wrote(written)


if __name__ == "__main__":
    main()
