"""``TrajectoryDataModule``: contiguous trajectory chunks from an HDF5 dataset file.

Training batches are ``chunks_per_batch`` contiguous chunks of ``chunk_len`` points, each from one
training trajectory (the energy regulariser and trajectory matching need whole chunks of one
trajectory; a chunk never crosses a recording's end). Chunk ``i`` of epoch ``e`` is drawn from the
seed sequence ``(seed, e, i)``: reproducible, and under DDP the distributed sampler gives each rank
distinct indices. Validation and test loaders yield ONE item: the whole split as ``Trajectories``
(with ``eval_stride``), which the LightningModule hands to ``lnn_torch.evaluation.evaluate_model``;
``predict`` yields every ``eval_stride``-th point of each test trajectory, one trajectory per item.

Targets: the file's accelerations (generated data), or velocities and accelerations estimated from
the positions (and measured velocities) by ``lnn_torch.data.derivatives`` (``targets``), for
measured recordings, which have none; the model then also reads the estimated velocities. The file
is generated from ``spec`` if it is missing (imported recordings cannot be). Normalisation
statistics come from the training split only (``normalization_data``).
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import asdict
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from ..data import derivatives
from ..data.generate import generate_dataset
from ..data.hdf5 import TrajectoryFile, read_dataset, read_rows
from ..data.spec import DatasetSpec
from ..data.trajectories import Trajectories
from ..errors import InputError

FIELDS = ("q", "qd", "qdd")


class _Source:
    """Arrays of a set of trajectories: in memory, or read lazily with one h5py handle per process.

    ``targets``: derivative settings (``derivatives.settings``): velocities and accelerations are
    then estimated from the recorded signals, in memory, over each trajectory's own length. Entries
    that are time windows of a recording (the file's ``windows``) are cut to their window after that
    (the filters saw the recording around it)."""

    def __init__(self, file: TrajectoryFile, indices: np.ndarray, in_memory: bool, dtype: torch.dtype,
                 targets: dict | None = None, smooth_inputs: bool = False) -> None:
        self.file, self.indices, self.dtype = file, np.asarray(indices), dtype
        names = self._names()
        self.in_memory = in_memory or targets is not None or "qdd" not in names or "windows" in names
        self.fields = FIELDS + (("tau",) if file.num_inputs else ())
        self.params = torch.as_tensor(file.read("params")[self.indices], dtype=dtype)
        self.lengths = (np.asarray(file.read("lengths"))[self.indices] if "lengths" in names
                        else np.full(len(self.indices), file.num_points))
        self._arrays = None
        self.recorded_qd = None  # (N, T, dof) as recorded, where targets were estimated from recorded velocities
        self._handle, self._pid = None, None
        if self.in_memory:
            order = np.argsort(np.argsort(self.indices))
            with file.open() as f:
                arrays = {k: read_rows(f[k], np.sort(self.indices))[order] for k in self.fields if k in f}
            if targets is not None or "qdd" not in arrays:
                if targets is None:
                    raise ValueError(f"{file.path} has no accelerations (measured recordings): set data.targets to a "
                                     f"derivative method ({', '.join(derivatives.METHODS)}) or train by trajectory "
                                     "matching")
                if "qd" in arrays:  # the velocities as recorded, before the targets' smoothing
                    self.recorded_qd = np.array(arrays["qd"], dtype=np.float64)
                arrays["qd"], arrays["qdd"] = self._estimate(arrays["q"], arrays["qd"], file.dt, targets)
            if smooth_inputs and targets is not None and "tau" in arrays:
                tau = np.array(arrays["tau"], dtype=np.float64)
                for j, n in enumerate(self.lengths):
                    tau[j, :n] = derivatives.smooth_inputs(tau[j, :n], file.dt, targets)
                arrays["tau"] = tau
            if "windows" in names:
                windows = np.asarray(file.read("windows"))[self.indices]
                if self.recorded_qd is not None:
                    self.recorded_qd = self._cut({"qd": self.recorded_qd}, windows)["qd"]
                arrays = self._cut(arrays, windows)
            if self.recorded_qd is not None:
                self.recorded_qd = torch.as_tensor(self.recorded_qd, dtype=dtype)
            self._arrays = {k: torch.as_tensor(v, dtype=dtype) for k, v in arrays.items()}

    def _cut(self, arrays: dict, windows: np.ndarray) -> dict:
        """Each entry cut to its window ``[a, b)`` of its points, NaN after; ``lengths`` follow."""
        out = {}
        for k, v in arrays.items():
            v = np.asarray(v, dtype=np.float64)
            cut = np.full_like(v, np.nan)
            for j, (a, b) in enumerate(windows):
                cut[j, : b - a] = v[j, a:b]
            out[k] = cut
        self.lengths = (windows[:, 1] - windows[:, 0]).astype(self.lengths.dtype)
        return out

    def _names(self) -> set:
        with self.file.open() as f:
            return set(f.keys())

    def _estimate(self, q: np.ndarray, qd: np.ndarray, dt: float, targets: dict):
        qd_est, qdd_est = np.full_like(q, np.nan), np.full_like(q, np.nan)
        for j, n in enumerate(self.lengths):
            qd_est[j, :n], qdd_est[j, :n] = derivatives.estimate(q[j, :n], dt, targets, qd[j, :n])
        return qd_est, qdd_est

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_handle"], state["_pid"] = None, None  # h5py handles never cross processes
        return state

    def _h5(self):
        if self._handle is None or self._pid != os.getpid():
            self._handle, self._pid = self.file.open(), os.getpid()
        return self._handle

    def chunk(self, j: int, start: int, length: int, stride: int = 1) -> dict:
        """Points ``start, start + stride, ...`` (``length`` of them) of the j-th trajectory."""
        sl = slice(start, start + length * stride, stride)
        if self._arrays is not None:
            out = {k: self._arrays[k][j, sl] for k in self.fields}
        else:
            f = self._h5()
            out = {k: torch.as_tensor(f[k][int(self.indices[j]), sl], dtype=self.dtype) for k in self.fields}
        out["params"] = self.params[j].expand(out["q"].shape[0], -1)
        return out

    def chunks(self, js: np.ndarray, starts: np.ndarray, length: int) -> dict:
        """``len(js)`` chunks of ``length`` consecutive points: each field ``(C, length, .)``."""
        if self._arrays is None:
            parts = [self.chunk(int(j), int(s), length) for j, s in zip(js, starts, strict=True)]
            return {k: torch.stack([p[k] for p in parts]) for k in (*self.fields, "params")}
        rows = torch.as_tensor(js)[:, None]  # (C, 1)
        cols = torch.as_tensor(starts)[:, None] + torch.arange(length)  # (C, L)
        out = {k: self._arrays[k][rows, cols] for k in self.fields}  # one gather per field
        out["params"] = self.params[rows[:, 0]][:, None, :].expand(-1, length, -1)
        return out

    def trajectories(self, dt: float, num: int | None = None) -> Trajectories:
        """The first ``num`` trajectories (all for None) as ``Trajectories`` (this source's dtype)."""
        n = len(self.indices) if num is None else min(num, len(self.indices))
        T = int(self.lengths[:n].max())
        parts = [self.chunk(j, 0, T) for j in range(n)]
        stack = lambda k: torch.stack([p[k] for p in parts]) if k in parts[0] else None  # noqa: E731
        return Trajectories(stack("q"), stack("qd"), self.params[:n], dt, stack("qdd"),
                            torch.as_tensor(self.indices[:n]), stack("tau"), torch.as_tensor(self.lengths[:n]))


class ChunkDataset(Dataset):
    """Training batches of random contiguous chunks: item ``i`` of epoch ``e`` is a whole batch of
    ``chunks_per_batch`` chunks drawn from the seed sequence ``(seed, e, i)`` (reproducible; under
    DDP the distributed sampler gives each rank distinct items, hence distinct chunks). A chunk lies
    within its trajectory's own length (recordings differ in length)."""

    def __init__(self, source: _Source, num_points: int, chunk_len: int, chunks_per_batch: int, num_batches: int,
                 seed: int) -> None:
        if chunk_len < 1 or chunks_per_batch < 1 or num_batches < 1:
            raise ValueError("chunk_len, chunks_per_batch and steps_per_epoch must be >= 1, got "
                             f"{chunk_len}, {chunks_per_batch}, {num_batches}")
        if chunk_len > int(source.lengths.max()):
            raise ValueError(f"chunk_len {chunk_len} exceeds the trajectory length {int(source.lengths.max())}")
        self.source, self.num_points, self.chunk_len = source, num_points, chunk_len
        self.chunks_per_batch, self.num_batches, self.seed = chunks_per_batch, num_batches, seed
        self.usable = np.nonzero(source.lengths >= chunk_len)[0]  # trajectories long enough for a chunk
        self.epoch = 0

    def __len__(self) -> int:
        return self.num_batches

    def __getitem__(self, i: int) -> dict:
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(self.epoch, int(i))))
        js = self.usable[rng.integers(len(self.usable), size=self.chunks_per_batch)]
        if (self.source.lengths == self.num_points).all():  # trajectories of one length (generated data)
            starts = rng.integers(self.num_points - self.chunk_len + 1, size=self.chunks_per_batch)
        else:
            starts = rng.integers(self.source.lengths[js] - self.chunk_len + 1)
        return self.source.chunks(js, starts, self.chunk_len)


class PointDataset(Dataset):
    """Fixed evaluation points: every ``stride``-th point of each trajectory, one item per trajectory."""

    def __init__(self, source: _Source, num_points: int, stride: int) -> None:
        self.source, self.stride = source, stride
        self.length = (num_points + stride - 1) // stride

    def __len__(self) -> int:
        return len(self.source.indices)

    def __getitem__(self, j: int) -> dict:
        out = self.source.chunk(j, 0, self.length, self.stride)
        out["trajectory"] = torch.tensor(int(self.source.indices[j]))
        return out


class SplitDataset(Dataset):
    """One item: the whole split ``{"trajectories": Trajectories, "accel_stride": int}`` (under DDP
    the distributed sampler pads it to one item per rank)."""

    def __init__(self, datamodule: TrajectoryDataModule, split: str, stride: int) -> None:
        self.datamodule, self.split, self.stride = datamodule, split, stride
        self._data = None

    def __len__(self) -> int:
        return 1

    def __getitem__(self, i: int) -> dict:
        if self._data is None:
            self._data = self.datamodule.trajectories(self.split)
        return {"trajectories": self._data, "accel_stride": self.stride}


class TrajectoryDataModule(L.LightningDataModule):
    """Serves an lnn_torch HDF5 dataset (generated from ``spec`` when ``path`` is missing).

    Args:
        path: the dataset file (generated, or imported with ``lnn-torch import``).
        spec: ``DatasetSpec`` fields used to generate the file when it is missing (and to check the
            scene); ``None`` means the defaults. Not used for imported recordings.
        chunk_len: points per training chunk.
        chunks_per_batch: chunks per training batch.
        steps_per_epoch: training batches per epoch.
        eval_stride: stride of the fixed validation/test points.
        eval_trajectories_per_batch: trajectories per predict batch.
        num_workers: DataLoader workers (each opens its own h5py handle when not in memory).
        in_memory: load the needed splits into memory (fast; default; always with ``targets``).
        seed: seed of the chunk sampling.
        targets: ``"file"`` (the file's accelerations) or the estimate of velocities and
            accelerations from the recorded signals: a method of ``lnn_torch.data.derivatives``
            (``finite_difference``, ``butterworth``, ``savgol``, ``spline``) as a name or a dict with
            its settings, e.g. ``{"method": "butterworth", "cutoff": 10}``.
        smooth_inputs: with estimated targets, pass the training split's recorded inputs through the
            same smoothing (both sides of ``M qdd + ... = B tau`` filtered alike, so that the inputs'
            noise does not bias a fit of smoothed accelerations to them); validation and test keep
            the recorded inputs.
    """

    def __init__(self, path: str = "data/double_pendulum.h5", spec: dict | None = None, chunk_len: int = 64,
                 chunks_per_batch: int = 8, steps_per_epoch: int = 250, eval_stride: int = 10,
                 eval_trajectories_per_batch: int = 16, num_workers: int = 0, in_memory: bool = True,
                 seed: int = 0, targets: dict | str = "file", smooth_inputs: bool = False) -> None:
        super().__init__()
        for name, value in (("eval_stride", eval_stride), ("eval_trajectories_per_batch", eval_trajectories_per_batch)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"data.{name} must be a whole number >= 1, got {value!r}")
        self.save_hyperparameters()
        self.path = Path(path)
        self.spec_fields = dict(spec or {})
        self.targets = derivatives.settings(targets)
        self.file: TrajectoryFile | None = None
        self._sources: dict = {}
        self.train_set: ChunkDataset | None = None
        if not self.path.exists():
            self._refuse_to_generate_recordings()

    # ------------------------------------------------------------------ preparation
    @property
    def spec(self) -> DatasetSpec:
        """The dataset specification (that generates the file when it is missing)."""
        return DatasetSpec(**self.spec_fields)

    def prepare_data(self) -> None:
        if not self.path.exists():
            self._refuse_to_generate_recordings()
            spec = self.spec
            print(f"dataset {self.path} not found: generating it ({spec.num_trajectories} trajectories)")
            generate_dataset(spec, self.path, progress=True)

    def _open(self) -> TrajectoryFile:
        if self.file is None:
            self.prepare_data()
            self.file = read_dataset(self.path)
            if not self.file.measured and self.spec_fields:  # a file given alone is what it holds
                self._check_spec()
        return self.file

    def _check_spec(self) -> None:
        spec = self.spec
        if self.file.attrs["scene"] != spec.scene:
            raise ValueError(f"{self.path} holds scene '{self.file.attrs['scene']}', but the data spec "
                             f"says '{spec.scene}'")
        recorded, configured = self.file.spec, asdict(spec)
        differ = sorted(k for k in configured if k in recorded and json.dumps(recorded[k], sort_keys=True)
                        != json.dumps(configured[k], sort_keys=True))
        if differ:
            warnings.warn(f"{self.path} was generated with a different specification than configured "
                          f"({', '.join(f'{k}: file {recorded[k]!r} vs config {configured[k]!r}' for k in differ)}); "
                          "using the file (delete it, or point data.path elsewhere, to regenerate)", UserWarning,
                          stacklevel=2)

    def source(self, split: str, dtype=torch.float32, smooth_inputs: bool | None = None) -> _Source:
        """The arrays of a split; ``smooth_inputs`` None: the configured smoothing of the inputs
        (training split only), True/False: the inputs smoothed alike with the targets or recorded."""
        smooth = (bool(self.hparams.get("smooth_inputs", False)) and split == "train") if smooth_inputs is None \
            else bool(smooth_inputs)
        key = (split, dtype, smooth)
        if key not in self._sources:
            f = self._open()
            self._sources[key] = _Source(f, f.splits[split], self.hparams.in_memory, dtype, self.targets, smooth)
        return self._sources[key]

    def shared_recordings(self, first: str = "train", second: str = "val") -> list[str]:
        """The recordings that both splits take time windows of (an import's ``provenance`` entries); none where
        the splits hold whole recordings (or a generated dataset's trajectories) of their own."""
        f = self._open()
        provenance = json.loads(f.attrs.get("provenance", "{}") or "{}")
        entries = provenance.get("entries") or []
        if not entries or first not in f.splits or second not in f.splits:
            return []
        of = lambda split: {entries[int(i)]["recording"] for i in f.splits[split] if int(i) < len(entries)}  # noqa: E731
        return sorted(of(first) & of(second))

    def split_names(self) -> list[str]:
        """The splits the dataset file holds with at least one entry (``train``, ``val``, ``test``...)."""
        return [name for name, entries in self._open().splits.items() if len(entries)]

    def recorded_velocities(self, split: str = "val") -> torch.Tensor:
        """The velocities of a split as recorded (float64 ``(N, T, dof)``, NaN after each trajectory's
        length), point for point with ``trajectories(split)``, whose velocities are the targets' smoothed
        ones: their difference is what the recorded velocity holds above the targets' band
        (``lnn_torch.identification.velocity_feedback``). Needs estimated targets and recorded velocities."""
        if self.targets is None:
            raise ValueError("recorded_velocities needs estimated targets (data.targets): without them the "
                             "file's velocities are the ones used")
        src = self.source(split, torch.float64, False)
        recorded = None if src.recorded_qd is None else src.recorded_qd[:, : int(src.lengths.max())]
        if recorded is None or any(not torch.isfinite(recorded[j, :n]).all() for j, n in enumerate(src.lengths)):
            raise ValueError(f"{self.path}: a recording of its '{split}' split has no recorded velocities: there "
                             "is no recorded velocity to compare")
        return recorded

    @property
    def scene(self) -> dict:
        return self._open().scene

    def model_scene(self) -> tuple[str, dict]:
        """``(scene name, scene configuration)`` for the model: the file's when it exists (imported
        recordings declare a measured system there), else the spec's."""
        if self.path.exists():
            scene = read_dataset(self.path).scene
            return scene["name"], scene.get("config", {})
        return self.spec_fields.get("scene", "double_pendulum"), dict(self.spec_fields.get("scene_config", {}))

    def _refuse_to_generate_recordings(self) -> None:
        """Derivative targets without a spec mean measured recordings: a missing file is then not
        something to generate (it would be a simulated double pendulum) but to import."""
        if self.targets is not None and not self.spec_fields:
            raise FileNotFoundError(f"data file {self.path} not found: it is set up for measured recordings "
                                    f"(data.targets, no data.spec); import them first: lnn-torch import RECORDINGS.csv "
                                    f"--config configs/import/<name>.yaml -o {self.path}")

    @property
    def dt(self) -> float:
        """The data's sampling interval, s."""
        return self._open().dt

    def setup(self, stage: str | None = None) -> None:
        f = self._open()
        if stage in ("fit", None):
            if not len(f.splits.get("train", ())):
                raise InputError(f"{f.path}: no training recordings (a file imported to evaluate or identify with "
                                 "only): import recordings with a train split to fit on")
            # float64 training (--trainer.precision 64) reads the data in float64 (a float32 copy rounded them)
            dtype = torch.float64 if "64" in str(getattr(getattr(self, "trainer", None), "precision", "")) \
                else torch.float32
            self.train_set = ChunkDataset(self.source("train", dtype), f.num_points, self.hparams.chunk_len,
                                          self.hparams.chunks_per_batch, self.hparams.steps_per_epoch,
                                          self.hparams.seed)
            note = self._velocity_note(f, self.source("train", dtype))
            if note:
                print(note)
        off = getattr(getattr(self, "trainer", None), "limit_val_batches", None) == 0  # (validation switched off)
        for split in ("val", "test"):
            if len(f.splits[split]) == 0 and stage in (("test",) if split == "test" else ("validate",) if off
                                                       else ("validate", "fit")):
                raise ValueError(f"{self.path} has an empty '{split}' split"
                                 + (" (a fit validates on it; --trainer.limit_val_batches 0 trains without validation)"
                                    if split == "val" and stage == "fit" else ""))

    def _velocity_note(self, f, train: _Source) -> str | None:
        """A line where the targets are to take measured velocities (``use_measured_velocity``) and the training
        recordings (``train``, read with them) have none: the positions are differentiated instead."""
        targets = self.targets
        if not targets or not targets.get("use_measured_velocity"):
            return None
        if train.recorded_qd is not None and torch.isfinite(train.recorded_qd).any():
            return None
        return (f"note: {f.path} has no measured velocities: the targets differentiate the positions (twice) "
                f"instead ({derivatives.describe({**targets, 'use_measured_velocity': False})})")

    def set_epoch(self, epoch: int) -> None:
        if self.train_set is not None:
            self.train_set.epoch = int(epoch)

    # ------------------------------------------------------------------ loaders
    def train_dataloader(self) -> DataLoader:
        # each item is already a whole batch (batch_size=None: no collation)
        return DataLoader(self.train_set, batch_size=None, shuffle=False, num_workers=self.hparams.num_workers,
                          persistent_workers=False)

    def _points(self, split: str) -> DataLoader:
        f = self._open()
        ds = PointDataset(self.source(split), f.num_points, self.hparams.eval_stride)
        return DataLoader(ds, batch_size=self.hparams.eval_trajectories_per_batch, shuffle=False,
                          num_workers=self.hparams.num_workers)

    def _split(self, split: str) -> DataLoader:
        return DataLoader(SplitDataset(self, split, self.hparams.eval_stride), batch_size=None)

    def val_dataloader(self) -> DataLoader:
        return self._split("val")

    def test_dataloader(self) -> DataLoader:
        return self._split("test")

    def predict_dataloader(self) -> DataLoader:
        return self._points("test")

    # ------------------------------------------------------------------ for the model
    def normalization_data(self, max_points: int = 200_000) -> dict:
        """Training-split samples (float64) for the normaliser: q, qd, qdd ``(n, dof)``, params ``(m, P)``
        per trajectory, ``params_points (n, P)`` aligned with the points and the inputs ``tau``
        where recorded (the valid points of every trajectory, subsampled to at most ``max_points``)."""
        src = self.source("train", torch.float64)
        total = int(src.lengths.sum())
        stride = max(1, total // max_points)
        parts = [src.chunk(j, 0, (int(n) + stride - 1) // stride, stride) for j, n in enumerate(src.lengths)]
        out = {k: torch.cat([p[k] for p in parts]) for k in src.fields}
        out["params"] = src.params
        out["params_points"] = torch.cat([p["params"] for p in parts])
        for name, x in out.items():  # (a NaN here makes the normaliser NaN, and every training step skipped)
            bad = ~torch.isfinite(x).reshape(len(x), -1).all(-1)
            if bad.any():
                raise InputError(f"{self.path}: the training split holds NaN or Inf in '{name.split('_')[0]}' at "
                                 f"{int(bad.sum())} of its {len(x)} {'recordings' if name == 'params' else 'points'}"
                                 f"{' read' if stride > 1 else ''} (within the recordings' lengths): mend or drop them")
        return out

    def trajectories(self, split: str = "val", num_trajectories: int | None = None,
                     smooth_inputs: bool | None = None) -> Trajectories:
        """Whole trajectories of a split (float64 ``Trajectories``, with the estimated velocities
        and accelerations where ``targets`` asks for them): the first ``num_trajectories`` (None: all).
        ``smooth_inputs``: as ``source`` (True: the inputs through the targets' smoothing, e.g. to
        compare predicted accelerations with smoothed ones in the same band; needs ``targets``)."""
        if smooth_inputs and self.targets is None:
            raise ValueError("smooth_inputs needs estimated targets (data.targets): there is no smoothing to apply")
        if self.targets is None and not self._open().measured:
            return self._open().trajectories(split, num_trajectories)
        return self.source(split, torch.float64, smooth_inputs).trajectories(self.dt, num_trajectories)
