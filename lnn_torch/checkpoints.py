"""Trained models from their checkpoints, for users: ``load_model(path | "pretrained:<name>")``,
``load_pretrained(name)``, ``data_hparams`` (the data a checkpoint was trained on) and ``output_dir``.

The loader lives with ``LNNModule`` (``lnn_torch.module``); the format itself (stamp, checks, shims
for older checkpoints) in ``lnn_torch.checkpoint_format``, a leaf. This module gathers them.
"""

from __future__ import annotations

from .checkpoint_format import (  # noqa: F401 - the names this module has always given
    CHECKPOINT_FORMAT,
    PRETRAINED,
    check_checkpoint_file,
    check_stamp,
    data_hparams,
    output_dir,
    read_checkpoint,
    stamp,
)
from .module import load_model, load_pretrained  # noqa: F401

__all__ = ["load_model", "load_pretrained", "data_hparams", "output_dir", "read_checkpoint", "PRETRAINED"]
