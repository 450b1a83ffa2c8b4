"""More training trajectories for a generated dataset: join a second file of the same scene (another
seed) to a first one, the first file's validation and test splits kept as they are and every trajectory
of the second added to training. A run on the joined file is then judged on the same validation
trajectories as a run on the first file alone, so their curves compare.

    lnn-torch generate --scene robot_arm -n 12000 --duration 3 --dt 0.005 --seed 1 -o data/robot_arm_12000_seed1.h5
    python scripts/join_trajectories.py data/robot_arm_12000.h5 data/robot_arm_12000_seed1.h5 \\
        -o data/robot_arm_24000.h5

Both files must be generated (not imported), of one scene with the same configuration, time grid,
parameters and targets; the seeds must differ (the same seed repeats the same trajectories). The joined
file records both sources (attribute ``joined``); its ``spec`` is the first file's with the number of
trajectories of both. Both files are read into memory.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from _common import HelpFormatter, add_output_file, wrote

SAME = ("scene", "scene_json", "robot", "param_names", "targets", "integrator", "substeps", "gravity", "conventions",
        "units")


def _read(path: Path) -> tuple[dict, dict, dict]:
    from lnn_torch.data import read_arrays, read_dataset

    info = read_dataset(path)  # checks the format, names the file in its error
    if info.measured:
        raise SystemExit(f"{path} holds imported recordings; only generated files can be joined")
    return read_arrays(info)


def join(first: Path, second: Path) -> tuple[dict, dict, dict]:
    """The joined arrays, splits and attributes (see the module's docstring)."""
    a, sa, attrs = _read(first)
    b, _, attrs_b = _read(second)
    for key in SAME:
        if str(attrs.get(key)) != str(attrs_b.get(key)):
            raise SystemExit(f"{first} and {second} differ in '{key}': they are not one dataset's trajectories")
    spec, spec_b = json.loads(attrs["spec"]), json.loads(attrs_b["spec"])
    differ = sorted(k for k in spec if k not in ("num_trajectories", "seed", "split") and spec[k] != spec_b.get(k))
    if differ:
        raise SystemExit(f"{first} and {second} were generated with different {', '.join(differ)}")
    if spec["seed"] == spec_b["seed"]:
        raise SystemExit(f"{first} and {second} have the same seed {spec['seed']}: their trajectories repeat")
    if not np.array_equal(a["t"], b["t"]) or set(a) != set(b):
        raise SystemExit(f"{first} and {second} differ in their time grid or arrays")
    n = len(a["params"])
    arrays = {k: a[k] if k == "t" else np.concatenate([a[k], b[k]]) for k in a}
    splits = {"train": np.concatenate([sa["train"], n + np.arange(len(b["params"]))]),
              "val": sa["val"], "test": sa["test"]}
    spec["num_trajectories"] = n + len(b["params"])
    out = {k: v for k, v in attrs.items() if k not in ("format", "format_version", "complete")}
    out["spec"] = json.dumps(spec, sort_keys=True)
    out["generation_seconds"] = float(attrs.get("generation_seconds", 0.0)) + float(
        attrs_b.get("generation_seconds", 0.0))
    out["joined"] = json.dumps({"first": {"path": str(first), "seed": int(attrs["seed"]),
                                          "trajectories": n, "splits": "kept"},
                                "second": {"path": str(second), "seed": int(attrs_b["seed"]),
                                           "trajectories": len(b["params"]), "splits": "all in train"}})
    return arrays, splits, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("first", type=Path, help="the dataset whose validation and test splits are kept")
    ap.add_argument("second", type=Path, help="the dataset whose trajectories all go to training")
    add_output_file(ap, None, "the joined file (required)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    args = ap.parse_args()
    if args.output is None:
        ap.error("name the joined file: --output / -o")
    from lnn_torch.data import check_writable, write_dataset

    check_writable(args.output, args.overwrite)
    arrays, splits, attrs = join(args.first, args.second)
    write_dataset(args.output, arrays, splits, attrs, overwrite=args.overwrite)
    print(f"{len(arrays['params'])} trajectories: {len(splits['train'])} train, {len(splits['val'])} val, "
          f"{len(splits['test'])} test")
    wrote(args.output)


if __name__ == "__main__":
    main()
