"""Trained models shipped inside the package: where they lie and what their cards say. The loader is
``lnn_torch.load_pretrained(name)`` (``lnn_torch.training.checkpoints``, which reads this package; this package
imports nothing of ``lnn_torch``).

Each model is a slim Lightning checkpoint (weights, normalisation buffers and hyper-parameters; no
optimizer state) written by ``scripts/export_pretrained.py``, with a JSON file beside it recording
the command that trained it and its measured test metrics.
"""

from __future__ import annotations

import json
from pathlib import Path

HERE = Path(__file__).resolve().parent


def available() -> list[str]:
    """Names of the shipped models."""
    return sorted(p.stem for p in HERE.glob("*.ckpt"))


def info(name: str) -> dict:
    """How the shipped model ``name`` was trained and what it measured (its JSON card)."""
    path = HERE / f"{name}.json"
    if not path.exists():
        raise KeyError(f"no pretrained model '{name}'; available: {', '.join(available()) or 'none'}")
    return json.loads(path.read_text())
