"""A dataset's trajectories written as a lab logs its recordings: one CSV per trajectory, and the import
configuration (``lnn_torch.data.importer.ImportSpec`` fields, YAML) that reads them back with
``lnn-torch import``.

Each CSV has a header row and the columns ``time`` (s), ``q1..qN`` (rad or m), ``dq1..dqN`` (rad/s or
m/s) and, for an actuated scene, ``tau1..tau_n`` (N m); values are written with Python's shortest
round-trip representation, so reading a file back gives the dataset's float64 values exactly. The
recordings are named ``{prefix}_{index:04d}`` after the trajectory's index in the dataset's
specification. Nothing the recordings would not carry is written: no accelerations, energies or
references (an importer estimates accelerations from the signals).

The configuration declares the scene as a lab would: the columns, the coordinates' names and angles,
the scene's conventions, its inputs and joint friction, a robot arm's description (``robot``: the
scene's description as written; a perturbed arm's recordings still name the shipped description, as a
lab with a URDF and a real robot does), the known parameters of every recording
(``parameters: {names, units, kinds, values: {recording: [...]}}``: a robot arm's payload), the
sampling interval and the dataset's own train/val/test split by recording.

``jitter`` (s): irregular time stamps, each but the first and the last moved by ``U(-jitter, jitter)``
(less than half the sampling interval, so that stamps still increase), the values those of the motion
at the moved stamps: ``q`` and ``qd`` by cubic Hermite interpolation between samples (with ``qd`` and
``qdd`` as slopes; without accelerations ``qd`` linearly), the inputs held (zero-order hold, as
recorded). The importer resamples such recordings onto the uniform grid again, by linear
interpolation, which is not exact.
"""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

from ..errors import InputError
from .hdf5 import TrajectoryFile, read_dataset


def recording_name(prefix: str, index: int) -> str:
    """The name (file stem) of the recording of trajectory ``index``."""
    return f"{prefix}_{int(index):04d}"


def import_config(f: TrajectoryFile, names: list[str]) -> dict:
    """The import configuration (``ImportSpec`` fields) of the recordings ``names`` (one per trajectory
    of ``f``, in file order): columns, the scene's declaration, each recording's parameters, the split."""
    scene = f.scene
    dof = int(scene["dof"])
    n_u = int(f.num_inputs)
    config = scene.get("config") or {}
    spec = {"label": f"{scene['name']}_recordings", "time": "time",
            "coordinates": [f"q{i + 1}" for i in range(dof)], "velocities": [f"dq{i + 1}" for i in range(dof)]}
    if n_u:
        spec["inputs"] = [f"tau{i + 1}" for i in range(n_u)]
    spec["coord_names"] = list(scene["coord_names"])
    if n_u and scene.get("input_names"):
        spec["input_names"] = list(scene["input_names"])
    if not all(scene["angle_mask"]):
        spec["angle_mask"] = [bool(a) for a in scene["angle_mask"]]
    spec["angle_units"] = "rad"
    if config.get("description") is not None:  # a robot arm: its description as written
        spec["robot"] = config["description"]
    spec["conventions"] = f"recordings of the simulated scene {scene['name']}: {scene.get('conventions', '')}"
    if scene.get("angle_combinations"):
        spec["angle_combinations"] = [list(map(float, row)) for row in scene["angle_combinations"]]
    if n_u and scene.get("input_matrix") is not None:
        B = np.asarray(scene["input_matrix"], dtype=np.float64)
        if not np.array_equal(B, np.eye(dof)[:, :n_u]):
            spec["input_matrix"] = B.tolist()
    spec["friction"] = scene.get("friction") is not None
    if spec["friction"]:
        D = np.asarray(scene["joint_map"], dtype=np.float64)
        if not np.array_equal(D, np.eye(dof)):
            spec["joint_map"] = D.tolist()
        spec["coulomb_velocity"] = float(scene["coulomb_velocity"])
    params = np.asarray(f.read("params"), dtype=np.float64)
    if params.shape[1]:
        spec["parameters"] = {"names": list(scene["param_names"]), "units": list(scene["param_units"]),
                              "kinds": list(scene.get("param_kinds") or ["positive"] * params.shape[1]),
                              "values": {n: [float(v) for v in row] for n, row in zip(names, params, strict=True)}}
    spec["dt"] = float(f.dt)
    spec["split"] = {part: [names[i] for i in np.sort(f.splits[part])] for part in ("train", "val", "test")}
    return spec


def _hermite(t: np.ndarray, x: np.ndarray, xd: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``x (T, n)`` with slopes ``xd`` at the uniform times ``t (T,)``, by cubic Hermite interpolation at
    the times ``s (S,)`` inside ``[t_0, t_-1]``: ``(S, n)``."""
    dt = t[1] - t[0]
    k = np.clip(np.floor((s - t[0]) / dt).astype(np.int64), 0, len(t) - 2)
    u = ((s - t[k]) / dt)[:, None]
    h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
    return h00 * x[k] + h10 * dt * xd[k] + h01 * x[k + 1] + h11 * dt * xd[k + 1]


def _jittered(t: np.ndarray, q, qd, qdd, tau, jitter: float, rng: np.random.Generator):
    """The stamps moved by ``U(-jitter, jitter)`` (the first and last kept) and the signals there."""
    s = t + rng.uniform(-jitter, jitter, len(t))
    s[0], s[-1] = t[0], t[-1]
    q_s = _hermite(t, q, qd, s)
    if qdd is not None:
        qd_s = _hermite(t, qd, qdd, s)
    else:
        qd_s = np.stack([np.interp(s, t, qd[:, j]) for j in range(qd.shape[1])], -1)
    tau_s = None
    if tau is not None:  # held over each interval [t_k, t_k+1)
        k = np.clip(np.searchsorted(t, s, side="right") - 1, 0, len(t) - 1)
        tau_s = tau[k]
    return s, q_s, qd_s, tau_s


def _write_csv(path: Path, header: list[str], rows: np.ndarray) -> None:
    text = ",".join(header) + "\n" + "".join(",".join(map(repr, row)) + "\n" for row in rows.tolist())
    if path.suffix == ".gz":
        with gzip.open(path, "wt", newline="") as fh:
            fh.write(text)
    else:
        path.write_text(text)


def export_recordings(dataset, output_dir, config: str | Path | None = None, *, prefix: str = "traj",
                      jitter: float = 0.0, seed: int = 0, compress: bool = False,
                      overwrite: bool = False) -> tuple[list[Path], Path | None]:
    """Write every trajectory of ``dataset`` (a path or ``TrajectoryFile``) as a CSV recording into
    ``output_dir`` and its import configuration to ``config`` (YAML; None: not written).

    ``jitter``: irregular stamps (s, module docstring; seeded by ``seed``), 0: the dataset's uniform
    grid. ``compress``: ``.csv.gz`` files. Returns ``(the CSV paths in file order, the config path)``;
    refuses (``InputError``) existing files unless ``overwrite``, a jitter of half the sampling interval
    or more, and a file without time samples.
    """
    import yaml

    f = dataset if isinstance(dataset, TrajectoryFile) else read_dataset(dataset)
    dt = float(f.dt)
    if not (np.isfinite(jitter) and 0 <= jitter < dt / 2):
        raise InputError(f"export: jitter must be in [0, dt / 2) = [0, {dt / 2:g}) s, got {jitter}")
    index = (np.asarray(f.read("trajectory_index")) if "trajectory_index" in _names(f)
             else np.arange(f.num_trajectories))
    names = [recording_name(prefix, i) for i in index]
    out = Path(output_dir)
    paths = [out / f"{n}.csv{'.gz' if compress else ''}" for n in names]
    targets = paths + ([Path(config)] if config is not None else [])
    existing = [p for p in targets if p.exists()]
    if existing and not overwrite:
        raise InputError(f"export: {existing[0]} exists ({len(existing)} files in all); pass overwrite to replace")
    dof, n_u = f.dof, f.num_inputs
    header = ["time", *[f"q{i + 1}" for i in range(dof)], *[f"dq{i + 1}" for i in range(dof)],
              *[f"tau{i + 1}" for i in range(n_u)]]
    rng = np.random.default_rng(np.random.SeedSequence(int(seed)))
    out.mkdir(parents=True, exist_ok=True)
    t_all = np.asarray(f.read("t"), dtype=np.float64)
    keys = [k for k in ("q", "qd", "qdd", "tau", "lengths") if k in _names(f)]
    with f.open() as h5:
        for j, path in enumerate(paths):
            arrays = {k: np.asarray(h5[k][j], dtype=np.float64) for k in keys}
            n = int(arrays.get("lengths", len(t_all)))
            t, q, qd = t_all[:n], arrays["q"][:n], arrays["qd"][:n]
            qdd = arrays["qdd"][:n] if "qdd" in arrays else None
            tau = arrays["tau"][:n] if "tau" in arrays else None
            if jitter:
                t, q, qd, tau = _jittered(t, q, qd, qdd, tau, jitter, rng)
            columns = [t[:, None], q, qd] + ([tau] if tau is not None else [])
            _write_csv(path, header, np.concatenate(columns, -1))
    config_path = None
    if config is not None:
        config_path = Path(config)
        config_path.parent.mkdir(parents=True, exist_ok=True)
        spec = import_config(f, names)
        head = (f"# How lnn-torch import reads the recordings of {f.path.name} (written by "
                f"lnn_torch.data.export_csv{f', jitter {jitter:g} s' if jitter else ''}):\n"
                f"#   lnn-torch import {out}/{prefix}_*.csv{'.gz' if compress else ''} --config {config_path} "
                f"-o DATASET.h5\n")
        config_path.write_text(head + yaml.safe_dump(spec, sort_keys=False, width=120, default_flow_style=None))
    return paths, config_path


def _names(f: TrajectoryFile) -> set:
    with f.open() as h5:
        return set(h5.keys())


__all__ = ["export_recordings", "import_config", "recording_name"]
