"""Lightning callbacks: writing ``predict`` results and ``test`` metrics to files, and a summary at the
end of ``fit``."""

from __future__ import annotations

import json
import os
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
        print(f"wrote {path} (predictions)")

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
        print(f"wrote {path} (test metrics)")


class LastCheckpoint(L.Callback):
    """Writes ``last.ckpt`` beside the monitored checkpoints at the end of every training epoch: the
    final weights. (Lightning's ``save_last`` writes it only when the monitored metric improves, so
    there it would be the best, not the last, checkpoint.)"""

    def __init__(self, filename: str = "last.ckpt") -> None:
        self.filename = filename
        self.path: str | None = None

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module) -> None:
        if trainer.sanity_checking or trainer.fast_dev_run:
            return
        directory = getattr(trainer.checkpoint_callback, "dirpath", None) or os.path.join(
            trainer.log_dir or trainer.default_root_dir, "checkpoints")
        self.path = os.path.join(directory, self.filename)
        trainer.save_checkpoint(self.path)


def _divergence(module, seconds: float) -> str:
    """The validation rollouts' median time within the threshold, in words, ``≥ horizon`` when capped."""
    hp = getattr(module, "hparams", {})
    thr, horizon = hp.get("val_threshold", 0.1), hp.get("val_rollout_seconds", float("inf"))
    held = f"≥ {horizon:g} s (never exceeded)" if seconds >= horizon - 1e-9 else f"{seconds:.2f} s"
    return f"validation rollouts within {thr:g} rad (or m) of the data: median {held}"


class FitSummary(L.Callback):
    """Prints, at the end of ``fit``, where the TensorBoard run and the checkpoints are and the last
    validation metrics, with the command that tests the last checkpoint."""

    def on_fit_end(self, trainer: L.Trainer, pl_module) -> None:
        log_dir = trainer.log_dir  # every rank: under DDP this is a collective (a broadcast)
        if not trainer.is_global_zero:
            return
        m = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("val/")}
        last = next((cb.path for cb in trainer.callbacks if isinstance(cb, LastCheckpoint) and cb.path), None)
        best = next((cb.best_model_path for cb in trainer.checkpoint_callbacks if getattr(cb, "best_model_path", "")),
                    None)
        path = lambda p: os.path.normpath(p) if p else p  # noqa: E731
        lines = [f"lnn-torch fit: {trainer.global_step} steps; TensorBoard run: {path(log_dir)}"]
        if last is not None:
            lines.append(f"  last checkpoint: {path(last)}")
        if best:
            lines.append(f"  best validation checkpoint: {path(best)}")
        if "val/acc_rel_err" in m:
            lines.append(f"  validation: acc. rel. L2 error {100 * m['val/acc_rel_err']:.2f} % pooled, "
                         f"{100 * m.get('val/acc_rel_err_traj_median', float('nan')):.2f} % per-trajectory median"
                         + (f"; {_divergence(pl_module, m['val/divergence_time'])}" if "val/divergence_time" in m
                            else ""))
        if last is not None:
            configs = " ".join(f"-c {c}" for c in getattr(self, "config_paths", [])) or "-c <this config>"
            lines.append(f"  test it: lnn-torch test {configs} --ckpt_path {path(last)}")
        print("\n".join(lines))
