"""Dataset generation around a scene's recorder (``lnn_torch.systems.recording``): here alone the seeding (one
generator per trajectory, ``trajectory_rng``), the progress, the targets, the energy, the arrays, the
split and every file attribute; float64 throughout."""

from __future__ import annotations

import json
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .._version import __version__
from ..errors import InputError
from ..systems.ground_truth import relative_residual
from ..systems.recording import Recording, sample_conditions
from .hdf5 import check_writable, write_dataset
from .spec import DatasetSpec

_SPLIT_TAG = 2**31 - 1  # spawn key of the split permutation (trajectory keys are 0..N-1)


def trajectory_rng(seed: int, index: int) -> np.random.Generator:
    """The random generator of trajectory ``index``: depends on (seed, index) only."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(index),)))


def sample_initial_conditions(spec: DatasetSpec, indices=None, inputs: bool = False):
    """Parameters and initial states of the given trajectories (default: all), float64 arrays; with
    ``inputs``, also each trajectory's input signal ``(N, num_points, n_u)`` (``lnn_torch.systems.excitation``;
    drawn after the state from the same generator, so parameters and states do not depend on it)."""
    indices = range(spec.num_trajectories) if indices is None else indices
    t = np.arange(spec.num_points) * spec.dt
    return sample_conditions(spec.system, [trajectory_rng(spec.seed, i) for i in indices], t,
                             spec.input_signal() if inputs else None)


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
    """Record the given trajectories of ``spec`` (default: all) with its scene's recorder
    (``System.recorder``: the closed form integrated by ``integrate_ground_truth``, or the robot arm's
    tracking experiment). Returns float64 numpy arrays ``t (T,)``, ``q``, ``qd``, ``qdd`` ``(N, T,
    dof)``, ``params (N, P)``, ``energy (N, T)`` (J, of the true motion) and ``integrator_steps (N,)``
    (the steps each trajectory took); with forces the work ``(N, T, 2)`` of the inputs and of friction
    (J), for an actuated scene the inputs ``tau (N, T, n_u)`` (input k acts on ``[t_k, t_{k+1})``), and
    the scene's own arrays (``robot_arm``: ``q_ref``)."""
    return _record(spec, indices, progress)[0]


def _record(spec: DatasetSpec, indices, progress: bool) -> tuple[dict, Recording]:
    """The arrays of ``generate_arrays`` and the recorder's ``Recording`` (how it recorded them).

    Here alone: the seeding (one generator per trajectory), the progress bar, the targets (the
    recorder's measured accelerations or the scene's closed form, or finite differences of ``qd``),
    the energy (of the true motion) and the arrays."""
    system = spec.system
    recorder = system.recorder(spec)
    indices = list(range(spec.num_trajectories)) if indices is None else [int(i) for i in indices]
    rngs = [trajectory_rng(spec.seed, i) for i in indices]
    bar = None
    if progress:
        bar = tqdm(total=len(indices) * (spec.num_points - 1), desc=f"generate {spec.scene}", unit="step",
                   unit_scale=True, file=sys.stderr, mininterval=1.0)
    try:
        rec = recorder.record(rngs, indices, advance=bar.update if bar else None)
    finally:
        if bar:
            bar.close()
    with torch.no_grad():
        q_true = torch.from_numpy(rec.q if rec.q_true is None else rec.q_true)
        qd, params = torch.from_numpy(rec.qd), torch.from_numpy(rec.params)
        p_b = params[:, None, :].expand(-1, q_true.shape[1], -1)
        if spec.targets == "finite_difference":
            qdd = np.gradient(rec.qd, spec.dt, axis=1, edge_order=2)
        elif rec.qdd is not None:
            qdd = rec.qdd
        else:
            qdd = system.acceleration(q_true, qd, p_b, None if rec.tau is None else torch.from_numpy(rec.tau)).numpy()
        energy = system.energy(q_true, qd, p_b).numpy()
    out = {"t": np.arange(spec.num_points) * spec.dt, "q": rec.q, "qd": rec.qd, "qdd": qdd, "params": rec.params,
           "energy": energy, "integrator_steps": rec.steps}
    if rec.work is not None:
        out["work"] = rec.work
    if rec.tau is not None:
        out["tau"] = rec.tau
    out.update(rec.arrays)
    return out, rec


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
        arrays, rec = _record(spec, indices, progress)
        elapsed = time.perf_counter() - start
    finally:
        torch.set_num_threads(old_threads)
    system = spec.system
    energy, params = (torch.from_numpy(arrays[k]) for k in ("energy", "params"))
    work = torch.from_numpy(arrays["work"]).sum(-1) if "work" in arrays else torch.zeros_like(energy)
    residual = float(relative_residual(energy, work, system.energy_scale(params)).max())
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
        "integrator": rec.integrator,
        "substeps": int(spec.substeps),
        "tolerances": json.dumps({
            "method": rec.method,
            "check": rec.check,
            **rec.tolerances,
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
        **rec.attrs,
    }
    if indices is not None:
        arrays["trajectory_index"] = indices
        attrs["subset"] = json.dumps(list(splits))
    return write_dataset(path, arrays, split_idx, attrs, overwrite=overwrite)


