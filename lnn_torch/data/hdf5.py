"""The HDF5 dataset schema: the only module that imports h5py.

Layout of a dataset file (float64 throughout; N trajectories, T points, dof, P parameters):

=================  ===============  =====================================================
name               shape            meaning
=================  ===============  =====================================================
``t``              ``(T,)``         sample times, s
``q``              ``(N, T, dof)``  generalised coordinates (rad or m)
``qd``             ``(N, T, dof)``  velocities (rad/s or m/s)
``qdd``            ``(N, T, dof)``  accelerations (rad/s^2 or m/s^2): closed form by default
``params``         ``(N, P)``       physical parameters (SI, order in attribute ``param_names``)
``energy``         ``(N, T)``       the scene's closed-form total energy, J
``integrator_steps`` ``(N,)``       integrator steps each trajectory took (more where refined)
``tau``            ``(N, T, n_u)``  inputs of an actuated scene (N m), held over each interval (optional)
``work``           ``(N, T, 2)``    work of the inputs and of dissipation since t = 0, J (scenes with forces)
``lengths``        ``(N,)``         points of each trajectory; the rest is NaN padding (imported recordings)
``splits/train``   ``(n_train,)``   trajectory indices of the training split (also ``val``, ``test``)
``trajectory_index`` ``(N,)``       each trajectory's index in the full specification (files of some splits only)
``q_ref``          ``(N, T, dof)``  the reference a tracking controller followed (``robot_arm``; optional)
``windows``        ``(N, 2)``       imported time windows: each entry's own points ``[a, b)``; the rest is
                                    context for derivative filters, cut after them (optional)
=================  ===============  =====================================================

Root attributes: ``format``, ``format_version``, ``scene``, ``scene_json`` (the scene's full
description: dof, angle mask, names, units, sampler configuration), ``conventions``, ``units``
(JSON), ``gravity``, ``param_names``, ``spec`` (the ``DatasetSpec`` as JSON), ``seed``,
``integrator``, ``substeps``, ``tolerances`` (JSON: the accuracy check, energy drift or power
balance, and its measured maximum), ``targets``, ``inputs`` (JSON, actuated scenes: names, units,
input matrix, excitation, hold), ``package_version``, ``created``, ``complete`` and, in a file of some
splits only, ``subset`` (JSON list of the splits it holds). A scene that records its own data adds its
method (``robot_arm``: ``recording``, the controller, gains, rates, reference and noise; ``robot``, the
description and its perturbation; ``energy`` and ``work`` are then those of the true motion, ``q`` may
carry encoder noise). Files written before ``tau`` existed read as unactuated. Imported recordings
(``lnn-torch import``; attribute ``measured``) have no ``qdd`` and no ``energy`` (nothing is known but
the measurements), a scene ``measured`` (with each recording's known parameters, if any, and a robot
arm's description), ``lengths``, ``recordings`` (the entries' names: recordings or time windows) and
``provenance`` (sources, checksums, each recording's timing and what resampling did, every setting).
A file whose scene names robot description files carries their compiled models in the group
``robot_descriptions`` (one byte array each, attributes ``description`` and ``mujoco``; read where the
file is gone: ``lnn_torch.robots.description``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import DatasetFileError
from .trajectories import Trajectories

FORMAT = "lnn_torch.trajectories"
FORMAT_VERSION = 1
ARRAYS = ("t", "q", "qd", "params")  # every file
SIMULATED_ARRAYS = ("qdd", "energy")  # generated files (not measured ones)
OPTIONAL_ARRAYS = ("qdd", "energy", "integrator_steps", "tau", "work", "lengths", "trajectory_index", "q_ref",
                   "windows")
SPLITS = ("train", "val", "test")


def _h5py():
    import h5py

    return h5py


def write_dataset(path: str | Path, arrays: dict, splits: dict, attrs: dict, overwrite: bool = False) -> Path:
    """Write a dataset file atomically: a temporary name in the same folder, then a rename.

    Raises ``FileExistsError`` if ``path`` exists and ``overwrite`` is False.
    """
    h5py = _h5py()
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; refusing to overwrite it (pass --overwrite / overwrite=True)")
    _make_parent(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with h5py.File(tmp, "w") as f:
            for name in ARRAYS + tuple(n for n in OPTIONAL_ARRAYS if n in arrays):
                if name not in arrays:
                    continue
                data = np.asarray(arrays[name])
                chunks = (1,) + data.shape[1:] if data.ndim == 3 else None
                f.create_dataset(name, data=data, chunks=chunks)
            grp = f.create_group("splits")
            for name in SPLITS:
                grp.create_dataset(name, data=np.asarray(splits[name], dtype=np.int64))
            for key, value in attrs.items():
                f.attrs[key] = value
            _write_description_copies(f, attrs)
            f.attrs["format"] = FORMAT
            f.attrs["format_version"] = FORMAT_VERSION
            f.attrs["complete"] = True
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def check_writable(path: str | Path, overwrite: bool) -> Path:
    """Fail early (before any work) if ``path`` cannot be written."""
    raw, path = str(path), Path(path)
    if path.is_dir() or raw.endswith(("/", os.sep)):  # (Path drops a trailing slash: the text says it is a folder)
        raise IsADirectoryError(f"{path} names a folder: give the dataset file's path (e.g. {path / 'data.h5'})")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; refusing to overwrite it (pass --overwrite / overwrite=True)")
    # the nearest folder that exists (the rest is created when the file is written: a refused run leaves none)
    parent = (path.parent if str(path.parent) else Path(".")).absolute()
    existing = next(p for p in (parent, *parent.parents) if p.exists())
    if not existing.is_dir():
        raise NotADirectoryError(f"cannot create folder {parent}: {existing} is a file")
    if not os.access(existing, os.W_OK):
        raise PermissionError(f"cannot write to {existing}: permission denied")
    return path


def _make_parent(path: Path) -> None:
    """The folders ``path`` goes in, created at the moment it is written."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise PermissionError(f"cannot create folder {path.parent}: {err.strerror}") from None


def read_rows(dataset, rows) -> np.ndarray:
    """``dataset[rows]`` for sorted, distinct row indices ``rows``, read as one slice per run of consecutive
    rows (h5py's point selection of a long index list is several times slower than that)."""
    rows = np.asarray(rows, dtype=np.int64)
    if rows.size == 0:
        return dataset[rows]
    breaks = np.flatnonzero(np.diff(rows) != 1) + 1
    starts, ends = np.r_[0, breaks], np.r_[breaks, rows.size]
    return np.concatenate([dataset[int(rows[a]):int(rows[b - 1]) + 1] for a, b in zip(starts, ends, strict=True)])


@dataclass
class TrajectoryFile:
    """A validated, opened-on-demand view of a dataset file (arrays are read lazily)."""

    path: Path
    attrs: dict
    splits: dict
    num_trajectories: int
    num_points: int
    dof: int
    num_params: int
    num_inputs: int = 0

    @property
    def scene(self) -> dict:
        return json.loads(self.attrs["scene_json"])

    @property
    def spec(self) -> dict:
        return json.loads(self.attrs["spec"])

    def open(self):
        """A read-only h5py handle (open one per process / DataLoader worker)."""
        return _h5py().File(self.path, "r")

    def read(self, name: str, index=None) -> np.ndarray:
        with self.open() as f:
            return f[name][()] if index is None else f[name][index]

    @property
    def dt(self) -> float:
        """The sampling interval, s."""
        t = self.read("t", slice(0, 2))
        return float(t[1] - t[0]) if len(t) > 1 else float("nan")

    def trajectories(self, split: str | None = "test", max_trajectories: int | None = None):
        """The trajectories of a split (``None``: all), in file order, as float64 ``Trajectories``."""
        if split is not None and split not in self.splits:
            raise DatasetFileError(f"{self.path} has no split '{split}' (splits: {', '.join(self.splits)})")
        idx = np.arange(self.num_trajectories) if split is None else np.sort(self.splits[split])
        if len(idx) == 0:
            raise DatasetFileError(f"{self.path} has an empty '{split}' split")
        idx = idx[:max_trajectories] if max_trajectories else idx
        with self.open() as f:
            arrays = {k: torch.from_numpy(read_rows(f[k], idx)) for k in ("q", "qd", "qdd", "params", "tau", "lengths")
                      if k in f}
            index = f["trajectory_index"][idx] if "trajectory_index" in f else idx
        return Trajectories(arrays["q"], arrays["qd"], arrays["params"], self.dt, arrays.get("qdd"),
                            torch.from_numpy(index), arrays.get("tau"), arrays.get("lengths"))

    @property
    def measured(self) -> bool:
        """Imported recordings (no closed form, no true accelerations)."""
        return bool(self.attrs.get("measured", False))


def read_dataset(path: str | Path) -> TrajectoryFile:
    """Open and validate a dataset file; raise ``DatasetFileError`` naming the problem."""
    h5py = _h5py()
    path = Path(path)
    if not path.exists():
        raise DatasetFileError(f"dataset file {path} does not exist")
    if path.is_file() and path.stat().st_size == 0:
        raise DatasetFileError(f"dataset file {path} is an empty file")
    if not h5py.is_hdf5(path):
        raise DatasetFileError(f"{path} is not an HDF5 file")
    try:
        with h5py.File(path, "r") as f:
            attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
            if attrs.get("format") != FORMAT:
                raise DatasetFileError(f"{path} is not an lnn_torch dataset "
                                       f"(attribute 'format' is {attrs.get('format')!r})")
            if not attrs.get("complete", False):
                raise DatasetFileError(f"{path} is incomplete (its writer did not finish)")
            required = ARRAYS + (() if attrs.get("measured", False) else SIMULATED_ARRAYS)
            missing = [n for n in required if n not in f] + [f"splits/{n}" for n in SPLITS if f"splits/{n}" not in f]
            if missing:
                raise DatasetFileError(f"{path} is malformed: missing {', '.join(missing)}")
            n, t, dof = f["q"].shape
            for name in ("qd", "qdd"):
                if name in f and f[name].shape != (n, t, dof):
                    raise DatasetFileError(f"{path} is malformed: '{name}' has shape {f[name].shape}, "
                                           f"expected {(n, t, dof)}")
            if f["t"].shape != (t,) or f["params"].shape[0] != n or ("energy" in f and f["energy"].shape != (n, t)):
                raise DatasetFileError(f"{path} is malformed: 't', 'params' or 'energy' shapes do not match "
                                       f"'q' {(n, t, dof)}")
            if "lengths" in f and (f["lengths"].shape != (n,) or f["lengths"][()].min() < 2
                                   or f["lengths"][()].max() > t):
                raise DatasetFileError(f"{path} is malformed: 'lengths' must be ({n},) values in [2, {t}]")
            splits = {name: f[f"splits/{name}"][()] for name in SPLITS}
            all_idx = np.concatenate(list(splits.values()))
            if len(all_idx) and (all_idx.min() < 0 or all_idx.max() >= n):
                raise DatasetFileError(f"{path} is malformed: split indices out of range [0, {n})")
            values, counts = np.unique(all_idx, return_counts=True)
            if (counts > 1).any():  # (a trajectory in two splits, or twice in one: a test on training data)
                twice = int(values[counts > 1][0])
                held = [name for name, idx in splits.items() if twice in idx]
                raise DatasetFileError(f"{path} is malformed: trajectory {twice} is in the splits more than once "
                                       f"({', '.join(held)})")
            num_params = f["params"].shape[1]
            num_inputs = f["tau"].shape[2] if "tau" in f else 0
            if "tau" in f and f["tau"].shape[:2] != (n, t):
                raise DatasetFileError(f"{path} is malformed: 'tau' has shape {f['tau'].shape}, "
                                       f"expected {(n, t)} + (n_u,)")
            copies = _read_description_copies(f)
    except OSError as err:
        raise DatasetFileError(f"cannot read {path}: {err}") from None
    if copies:
        from ..robots.description import register_copies

        register_copies(copies, f"dataset file {path}")
    return TrajectoryFile(path, attrs, splits, n, t, dof, num_params, num_inputs)


DESCRIPTION_GROUP = "robot_descriptions"


def _write_description_copies(f, attrs: dict) -> None:
    """The compiled robot descriptions the file's scene names (``robots.description.compiled_copies``)."""
    if "scene_json" not in attrs:
        return
    from ..robots.description import compiled_copies

    copies = compiled_copies(json.loads(attrs["scene_json"]))
    if copies:
        group = f.create_group(DESCRIPTION_GROUP)
        for i, (key, copy) in enumerate(copies.items()):
            data = group.create_dataset(str(i), data=np.frombuffer(copy["mjb"], dtype=np.uint8))
            data.attrs["description"], data.attrs["mujoco"] = key, copy["mujoco"]


def _read_description_copies(f) -> dict:
    if DESCRIPTION_GROUP not in f:
        return {}
    return {str(d.attrs["description"]): {"mjb": d[()].tobytes(), "mujoco": str(d.attrs["mujoco"])}
            for d in f[DESCRIPTION_GROUP].values()}


def write_arrays(path: str | Path, arrays: dict, attrs: dict, overwrite: bool = False) -> Path:
    """Write named arrays and attributes to an HDF5 file atomically (e.g. a simulated trajectory)."""
    h5py = _h5py()
    path = check_writable(path, overwrite)
    _make_parent(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with h5py.File(tmp, "w") as f:
            for name, value in arrays.items():
                f.create_dataset(name, data=np.asarray(value))
            for key, value in attrs.items():
                f.attrs[key] = value
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def read_arrays(f) -> tuple[dict, dict, dict]:
    """The arrays, splits and attributes of a dataset file (``f``: a path, read and checked by
    ``read_dataset``, or the ``TrajectoryFile`` it gave): every array of the schema the file
    holds, as numpy arrays."""
    f = read_dataset(f) if isinstance(f, (str, Path)) else f
    arrays = {}
    for name in ("t", "q", "qd", "params", *OPTIONAL_ARRAYS):
        try:
            arrays[name] = f.read(name)
        except KeyError:  # an optional array the file does not hold
            continue
    return arrays, dict(f.splits), dict(f.attrs)


def copy_dataset(source, dest, *, splits: dict | None = None, arrays: dict | None = None) -> Path:
    """A copy of the dataset file ``source`` at ``dest`` (replaced where it exists) with ``splits`` (``{name:
    indices}``) and ``arrays`` (``{name: values}``) in place of its own, the rest as it is; written by
    ``write_dataset``."""
    own, own_splits, attrs = read_arrays(source)
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    return write_dataset(dest, {**own, **(arrays or {})}, {**own_splits, **(splits or {})}, attrs, overwrite=True)
