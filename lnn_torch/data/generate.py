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
from ..errors import InputError
from ..excitation import sample
from ..ground_truth import integrate_ground_truth, relative_residual
from .hdf5 import check_writable, write_dataset
from .spec import DatasetSpec

_SPLIT_TAG = 2**31 - 1  # spawn key of the split permutation (trajectory keys are 0..N-1)


def trajectory_rng(seed: int, index: int) -> np.random.Generator:
    """The random generator of trajectory ``index``: depends on (seed, index) only."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(index),)))


def sample_initial_conditions(spec: DatasetSpec, indices=None, inputs: bool = False):
    """Parameters and initial states of the given trajectories (default: all), float64 arrays; with
    ``inputs``, also each trajectory's input signal ``(N, num_points, n_u)`` (``lnn_torch.excitation``;
    drawn after the state from the same generator, so parameters and states do not depend on it)."""
    system = spec.build_system()
    indices = range(spec.num_trajectories) if indices is None else indices
    t = np.arange(spec.num_points) * spec.dt
    excitation = spec.input_signal() if inputs else None
    params, q0, qd0, tau = [], [], [], []
    for i in indices:
        rng = trajectory_rng(spec.seed, i)
        params.append(system.sample_params(rng, 1)[0])
        q, qd = system.sample_state(rng, 1)
        q0.append(q[0])
        qd0.append(qd[0])
        if inputs:
            tau.append(sample(excitation, rng, t, system.num_inputs))
    out = (np.array(params), np.array(q0), np.array(qd0))
    return (*out, np.array(tau).reshape(len(q0), spec.num_points, system.num_inputs)) if inputs else out


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
    including ``integrator_steps`` (N,): steps each trajectory took (``integrate_ground_truth``), and
    for an actuated scene the inputs ``tau (N, T, n_u)`` (input k acts on ``[t_k, t_{k+1})``). A scene
    that records its data its own way (``System.generate_trajectories``) returns them instead."""
    system = spec.build_system()
    own = system.generate_trajectories(spec, indices, progress)
    if own is not None:
        return own
    actuated = system.num_inputs > 0
    sampled = sample_initial_conditions(spec, indices, inputs=actuated)
    params, q0, qd0 = (torch.from_numpy(a) for a in sampled[:3])
    tau = torch.from_numpy(sampled[3]) if actuated else None
    system.check_params(params)
    system.check_state(q0, qd0)
    steps = spec.num_points - 1
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, desc=f"generate {spec.scene}", unit="step", file=sys.stderr, mininterval=1.0)
    try:
        with torch.no_grad():
            q, qd, n_steps, work = integrate_ground_truth(
                system, q0, qd0, params, spec.dt, steps, spec.integrator, spec.substeps, spec.energy_tol,
                spec.adaptive_tol, callback=(lambda i: bar.update(1)) if bar else None, indices=indices,
                tau=None if tau is None else tau[:, :-1], return_work=True)
    finally:
        if bar:
            bar.close()
    with torch.no_grad():
        p_b = params[:, None, :].expand(-1, q.shape[1], -1)
        if spec.targets == "analytic":
            qdd = system.acceleration(q, qd, p_b, tau)
        else:
            qdd = torch.from_numpy(np.gradient(qd.numpy(), spec.dt, axis=1, edge_order=2))
        energy = system.energy(q, qd, p_b)
    t = np.arange(spec.num_points) * spec.dt
    out = {"t": t, "q": q.numpy(), "qd": qd.numpy(), "qdd": qdd.numpy(), "params": params.numpy(),
           "energy": energy.numpy(), "integrator_steps": n_steps.numpy()}
    if system.has_forces:
        out["work"] = work.numpy()
    if tau is not None:
        out["tau"] = tau.numpy()
    return out


def generate_dataset(spec: DatasetSpec, path: str | Path, overwrite: bool = False, progress: bool = False,
                     num_threads: int | None = None, splits: tuple[str, ...] | None = None) -> Path:
    """Generate ``spec`` and write it to ``path`` (atomically). Refuses to overwrite unless asked.

    ``splits``: generate only the trajectories of these splits (e.g. ``("test",)`` to evaluate a
    model); the file then holds those trajectories alone, its other splits are empty and the array
    ``trajectory_index`` gives each trajectory's index in the full specification (the same
    trajectories as in the full file: each depends on ``(seed, index)`` only).

    Returns the path written.
    """
    spec.validate()
    path = check_writable(path, overwrite)
    split_idx = split_indices(spec)
    indices = None
    if splits is not None:
        unknown = sorted(set(splits) - set(split_idx))
        if unknown:
            raise InputError(f"unknown split(s) {', '.join(unknown)}: choose from {', '.join(split_idx)}")
        indices = np.sort(np.concatenate([split_idx[s] for s in splits]))
        if len(indices) == 0:
            raise InputError(f"the specification's {'/'.join(splits)} split is empty (split = {list(spec.split)})")
        position = {int(j): k for k, j in enumerate(indices)}
        split_idx = {s: (np.array([position[int(j)] for j in idx], dtype=np.int64) if s in splits
                         else np.zeros(0, dtype=np.int64)) for s, idx in split_idx.items()}
    old_threads = torch.get_num_threads()
    if num_threads:
        torch.set_num_threads(num_threads)
    try:
        start = time.perf_counter()
        arrays = generate_arrays(spec, indices, progress=progress)
        elapsed = time.perf_counter() - start
    finally:
        torch.set_num_threads(old_threads)
    system = spec.build_system()
    energy, params = (torch.from_numpy(arrays[k]) for k in ("energy", "params"))
    work = torch.from_numpy(arrays["work"]).sum(-1) if "work" in arrays else torch.zeros_like(energy)
    residual = float(relative_residual(energy, work, system.energy_scale(params)).max())
    refined = int((arrays["integrator_steps"] != (spec.num_points - 1) * spec.substeps).sum())
    check = "power-balance residual |E(t) - E(0) - W(t)|" if system.has_forces else "energy drift"
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
                      f"whose relative {check} exceeds {spec.energy_tol:g} of the energy scale are integrated again "
                      f"with adaptive DOP853 steps (rtol = atol = {spec.adaptive_tol:g}; ten, then a hundred times "
                      "tighter for those that still exceed it)",
            "check": check,
            "energy_tol": spec.energy_tol,
            "adaptive_tol": spec.adaptive_tol,
            "refined_trajectories": refined,
            ("max_power_balance_residual_rel" if system.has_forces else "max_energy_drift_rel"): residual,
        }),
        "targets": spec.targets,
        **({"inputs": json.dumps({"names": list(system.input_names), "units": ["N m"] * system.num_inputs,
                                  "input_matrix": system.input_matrix().tolist(), "excitation": spec.input_signal(),
                                  "hold": "zero-order: input k acts on [t_k, t_k+1); the last sample is the "
                                          "signal's next value"})}
           if system.num_inputs else {}),
        "package_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "generation_seconds": elapsed,
    }
    attrs.update(system.generation_attrs(spec, arrays, residual))
    if indices is not None:
        arrays["trajectory_index"] = indices
        attrs["subset"] = json.dumps(list(splits))
    return write_dataset(path, arrays, split_idx, attrs, overwrite=overwrite)


simulate = generate_arrays  # the former name (``lnn_torch.data.simulate``)
