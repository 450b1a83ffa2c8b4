"""Recordings of hardware the package knows nothing about, simulated: the stand-in for a lab's own
system on which ``configs/measured.yaml`` (and ``configs/import/measured.yaml``, the import template)
is checked (``results/measured/README.md``).

One actuated double pendulum with friction (``actuated_double_pendulum`` with every parameter fixed:
one machine, not a family): 40 recordings of 5 s at 5 ms, driven by the scene's random torques,
written as CSV files with column names of a lab's logger, and beside them ``import.yaml``, the import
configuration a lab would write (the columns, the input matrix, friction, a seeded split by
fractions) and nothing the package's scene knows (no conventions, parameters or feature angles):

    python scripts/stand_in_recordings.py -o runs/stand_in
    lnn-torch import runs/stand_in/run_*.csv --config runs/stand_in/import.yaml -o data/stand_in.h5
    lnn-torch fit -c configs/measured.yaml --data.path=data/stand_in.h5

``--pendubot``: only the first joint driven (one input; its input matrix ``[[1], [0]]``).
``--positions-only``: no velocity columns. ``--noise S``: Gaussian noise of S rad on the angles.

The simulation's exact signals go to ``truth.npz`` beside the recordings (a lab never has them), so
that a model trained on the recordings is judged against the machine itself, on the dataset's test
recordings, at the exact states and torques:

    python scripts/stand_in_recordings.py --score CHECKPOINT data/stand_in.h5 -o runs/stand_in
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from _common import HelpFormatter, add_output_dir, wrote

# one machine: every parameter range of the scene collapsed to a value (a range needs low < high)
MACHINE = {"m_range": 0.6, "l1_range": 0.25, "l2_range": 0.22, "com_ratio": 0.8, "inertia_excess": 0.2,
           "viscous_range": 0.03, "coulomb_range": 0.08}
STATES = {"theta_range": (-2.5, 2.5), "omega_range": (-3.0, 3.0)}


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    add_output_dir(ap, "runs/stand_in", "the folder the CSV recordings and import.yaml go to")
    ap.add_argument("--recordings", type=int, default=40, help="how many recordings")
    ap.add_argument("--duration", type=float, default=5.0, help="seconds per recording")
    ap.add_argument("--pendubot", action="store_true", help="only the first joint driven")
    ap.add_argument("--positions-only", action="store_true", help="no velocity columns")
    ap.add_argument("--noise", type=float, default=0.0, help="Gaussian noise on the angles, rad")
    ap.add_argument("--seed", type=int, default=3, help="the simulation's seed (the noise's: seed + 1)")
    ap.add_argument("--overwrite", action="store_true", help="replace existing files")
    ap.add_argument("--score", nargs=2, metavar=("CHECKPOINT", "DATASET"),
                    help="instead: a model's acceleration and torque errors against the exact signals of the "
                         "dataset's test recordings (truth.npz in the output folder)")
    return ap


def score(checkpoint: str, dataset: str, folder: Path) -> dict:
    """``{acc_rel_err, torque_nrmse}`` of the model against the simulation's exact accelerations and
    torques (its inverse dynamics at the exact accelerations) at the exact states of the dataset's test
    recordings, every point."""
    import torch

    from lnn_torch import load_model
    from lnn_torch.data import read_dataset

    truth = np.load(folder / "truth.npz")
    test = read_dataset(dataset).splits["test"]
    q, qd, qdd, tau = (torch.from_numpy(truth[k][test].reshape(-1, truth[k].shape[-1])) for k in ("q", "qd", "qdd",
                                                                                                    "tau"))
    model = load_model(checkpoint).model.double()
    params = q.new_zeros(len(q), 0)
    with torch.no_grad():
        a = model.acceleration(q, qd, params, tau)
        torques = model.inverse(q, qd, qdd, params)
    return {"acc_rel_err": float((a - qdd).norm() / qdd.norm()),
            "torque_nrmse": float((torques - tau).norm() / tau.norm()), "test_recordings": len(test)}


def main() -> None:
    args = parser().parse_args()
    if args.score:
        result = score(*args.score, Path(args.output_dir))
        print(f"against the exact signals of {result['test_recordings']} test recordings: acceleration error "
              f"{100 * result['acc_rel_err']:.2f} %, inverse-dynamics torque error "
              f"{100 * result['torque_nrmse']:.2f} %")
        return
    import yaml

    from lnn_torch import InputError
    from lnn_torch.data import DatasetSpec, generate_arrays

    out = Path(args.output_dir)
    config_path = out / "import.yaml"
    if config_path.exists() and not args.overwrite:
        raise SystemExit(f"{config_path} exists: pass --overwrite to replace the stand-in recordings")
    scene_config = {k: (v, v * (1 + 1e-7)) for k, v in MACHINE.items()} | STATES
    if args.pendubot:
        scene_config["actuated"] = (True, False)
    try:
        arrays = generate_arrays(DatasetSpec(scene="actuated_double_pendulum", scene_config=scene_config,
                                             num_trajectories=args.recordings, duration=args.duration, dt=0.005,
                                             seed=args.seed))
    except InputError as err:
        raise SystemExit(f"stand_in_recordings: {err}") from None
    rng = np.random.default_rng(args.seed + 1)
    columns = ["stamp", "shoulder", "elbow"] + ([] if args.positions_only else ["shoulder_rate", "elbow_rate"])
    inputs = ["shoulder_torque"] + ([] if args.pendubot else ["elbow_torque"])
    out.mkdir(parents=True, exist_ok=True)
    t = arrays["t"]
    for i in range(args.recordings):
        q = arrays["q"][i] + rng.normal(0.0, args.noise, arrays["q"][i].shape) if args.noise else arrays["q"][i]
        values = [t[:, None], q] + ([] if args.positions_only else [arrays["qd"][i]]) + [arrays["tau"][i]]
        np.savetxt(out / f"run_{i:03d}.csv", np.concatenate(values, -1), delimiter=",",
                   header=",".join(columns + inputs), comments="", fmt="%.9g")
    config = {"label": "stand_in_pendubot" if args.pendubot else "stand_in_double_pendulum", "time": "stamp",
              "coordinates": ["shoulder", "elbow"]}
    if not args.positions_only:
        config["velocities"] = ["shoulder_rate", "elbow_rate"]
    config["inputs"] = inputs
    if args.pendubot:
        config["input_matrix"] = [[1], [0]]
    config |= {"friction": True, "split": {"train": 0.7, "val": 0.15, "test": 0.15}}
    np.savez(out / "truth.npz", **{k: arrays[k] for k in ("t", "q", "qd", "qdd", "tau")})
    config_path.write_text(f"# written by scripts/stand_in_recordings.py: {args.recordings} recordings of one "
                           f"simulated machine\n" + yaml.safe_dump(config, sort_keys=False, default_flow_style=None))
    print(f"import them with: lnn-torch import {out}/run_*.csv --config {config_path} -o DATASET.h5")
    wrote(config_path, out / "truth.npz", f"{out}/run_*.csv ({args.recordings} files)")


if __name__ == "__main__":
    main()
