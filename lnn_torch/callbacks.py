"""Lightning callbacks: writing ``predict`` results and ``test`` metrics to files."""

from __future__ import annotations

import json
from pathlib import Path

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import BasePredictionWriter


class PredictionWriter(BasePredictionWriter):
    """Writes ``predict`` outputs (per test trajectory: q, qd, params, true and predicted qdd) to an
    ``.npz`` file: ``output`` if given, else ``<log_dir>/predictions.npz``. Refuses to replace an
    existing file unless ``overwrite``."""

    def __init__(self, output: str | None = None, overwrite: bool = False) -> None:
        super().__init__(write_interval="epoch")
        self.output, self.overwrite = output, overwrite
        self.path: Path | None = None

    def write_on_epoch_end(self, trainer: L.Trainer, pl_module, predictions, batch_indices) -> None:
        if not predictions:
            return
        if isinstance(predictions[0], list):  # several dataloaders
            predictions = [p for group in predictions for p in group]
        arrays = {k: torch.cat([p[k] for p in predictions]).cpu().numpy() for k in predictions[0]}
        if trainer.world_size > 1:
            path = self._path(trainer).with_suffix(f".rank{trainer.global_rank}.npz")
        else:
            path = self._path(trainer)
        if path.exists() and not self.overwrite:
            raise FileExistsError(f"{path} exists; refusing to overwrite it (set overwrite: true on the PredictionWriter)")
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **arrays)
        self.path = path
        print(f"predictions written to {path}")

    def _path(self, trainer) -> Path:
        if self.output:
            return Path(self.output)
        return Path(trainer.log_dir or ".") / "predictions.npz"


class TestMetricsWriter(L.Callback):
    """Writes the metrics of ``test`` to ``<log_dir>/test_metrics.json`` (as ``lnn-torch test`` prints them)."""

    def on_test_end(self, trainer: L.Trainer, pl_module) -> None:
        if not trainer.is_global_zero:
            return
        metrics = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("test/")}
        path = Path(trainer.log_dir or ".") / "test_metrics.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(metrics, indent=2) + "\n")
        print(f"test metrics written to {path}")
