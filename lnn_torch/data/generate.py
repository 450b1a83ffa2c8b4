"""Ground-truth dataset generation: seeded, vectorised over trajectories, float64."""

from __future__ import annotations

import json
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..ground_truth import integrate_ground_truth
from ..metrics import energy_drift
from .hdf5 import check_writable, write_dataset
from .spec import DatasetSpec

_SPLIT_TAG = 2**31 - 1  # spawn key of the split permutation (trajectory keys are 0..N-1)


def trajectory_rng(seed: int, index: int) -> np.random.Generator:
    """The random generator of trajectory ``index``: depends on (seed, index) only."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(index),)))


def sample_initial_conditions(spec: DatasetSpec, indices=None):
    """Parameters and initial states of the given trajectories (default: all), float64 arrays."""
    system = spec.build_system()
    indices = range(spec.num_trajectories) if indices is None else indices
    params, q0, qd0 = [], [], []
    for i in indices:
        rng = trajectory_rng(spec.seed, i)
        params.append(system.sample_params(rng, 1)[0])
        q, qd = system.sample_state(rng, 1)
        q0.append(q[0])
        qd0.append(qd[0])
    return np.array(params), np.array(q0), np.array(qd0)


def split_indices(spec: DatasetSpec) -> dict:
    """Seeded train/val/test split by trajectory."""
    n = spec.num_trajectories
    perm = np.random.default_rng(np.random.SeedSequence(int(spec.seed), spawn_key=(_SPLIT_TAG,))).permutation(n)
    n_val = int(round(spec.split[1] * n))
    n_test = int(round(spec.split[2] * n))
    n_train = n - n_val - n_test
    return {
        "train": np.sort(perm[:n_train]),
        "val": np.sort(perm[n_train : n_train + n_val]),
        "test": np.sort(perm[n_train + n_val :]),
    }


def generate_arrays(spec: DatasetSpec, indices=None, progress: bool = False) -> dict:
    """Integrate the given trajectories of ``spec`` (default: all). Returns float64 numpy arrays,
    including ``integrator_steps`` (N,): steps each trajectory took (``integrate_ground_truth``)."""
    system = spec.build_system()
    params, q0, qd0 = (torch.from_numpy(a) for a in sample_initial_conditions(spec, indices))
    system.check_params(params)
    system.check_state(q0, qd0)
    steps = spec.num_points - 1
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, desc=f"generate {spec.scene}", unit="step", file=sys.stderr, mininterval=1.0)
    try:
        with torch.no_grad():
            q, qd, n_steps = integrate_ground_truth(
                system, q0, qd0, params, spec.dt, steps, spec.integrator, spec.substeps, spec.energy_tol,
                spec.adaptive_tol, callback=(lambda i: bar.update(1)) if bar else None, indices=indices)
    finally:
        if bar:
            bar.close()
    with torch.no_grad():
        p_b = params[:, None, :].expand(-1, q.shape[1], -1)
        if spec.targets == "analytic":
            qdd = system.acceleration(q, qd, p_b)
        else:
            qdd = torch.from_numpy(np.gradient(qd.numpy(), spec.dt, axis=1, edge_order=2))
        energy = system.energy(q, qd, p_b)
    t = np.arange(spec.num_points) * spec.dt
    return {"t": t, "q": q.numpy(), "qd": qd.numpy(), "qdd": qdd.numpy(), "params": params.numpy(),
            "energy": energy.numpy(), "integrator_steps": n_steps.numpy()}


def generate_dataset(spec: DatasetSpec, path: str | Path, overwrite: bool = False, progress: bool = False,
                     num_threads: int | None = None) -> Path:
    """Generate ``spec`` and write it to ``path`` (atomically). Refuses to overwrite unless asked.

    Returns the path written.
    """
    spec.validate()
    path = check_writable(path, overwrite)
    old_threads = torch.get_num_threads()
    if num_threads:
        torch.set_num_threads(num_threads)
    try:
        start = time.perf_counter()
        arrays = generate_arrays(spec, progress=progress)
        elapsed = time.perf_counter() - start
    finally:
        torch.set_num_threads(old_threads)
    system = spec.build_system()
    drift = float(energy_drift(system, *(torch.from_numpy(arrays[k]) for k in ("q", "qd", "params"))).max())
    refined = int((arrays["integrator_steps"] != (spec.num_points - 1) * spec.substeps).sum())
    attrs = {
        "scene": spec.scene,
        "scene_json": json.dumps(system.describe(), sort_keys=True),
        "conventions": system.conventions,
        "units": json.dumps({
            "t": "s", "q": list(system.coord_units), "qd": [u + "/s" for u in system.coord_units],
            "qdd": [u + "/s^2" for u in system.coord_units], "params": list(system.param_units), "energy": "J",
        }),
        "gravity": system.gravity,
        "param_names": json.dumps(list(system.param_names)),
        "spec": spec.to_json(),
        "seed": int(spec.seed),
        "integrator": spec.integrator,
        "substeps": int(spec.substeps),
        "tolerances": json.dumps({
            "method": f"fixed-step {spec.integrator}, h = dt / substeps = {spec.dt / spec.substeps:g} s; trajectories "
                      f"whose relative energy drift exceeds {spec.energy_tol:g} are integrated again with adaptive "
                      f"DOP853 steps (rtol = atol = {spec.adaptive_tol:g})",
            "energy_tol": spec.energy_tol,
            "adaptive_tol": spec.adaptive_tol,
            "refined_trajectories": refined,
            "max_energy_drift_rel": drift,
        }),
        "targets": spec.targets,
        "package_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "generation_seconds": elapsed,
    }
    return write_dataset(path, arrays, split_indices(spec), attrs, overwrite=overwrite)


simulate = generate_arrays  # the former name (``lnn_torch.data.simulate``)
