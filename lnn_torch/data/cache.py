"""The user's cache of generated evaluation splits: what ``lnn-torch evaluate`` builds when a
checkpoint's dataset file is not there (a shipped model, a checkpoint copied from elsewhere).

Only the split asked for is generated (``generate_dataset(..., splits=(split,))``), seeded as in the
full file, once per specification, into ``$LNN_TORCH_CACHE`` (default ``$XDG_CACHE_HOME/lnn_torch``,
else ``~/.cache/lnn_torch``) under ``datasets/``; the name carries a digest of the specification, so
a different specification never reads a stale file. Delete the folder to free the space.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from .generate import generate_dataset, split_indices
from .spec import DatasetSpec


def cache_dir() -> Path:
    """``$LNN_TORCH_CACHE``, else ``$XDG_CACHE_HOME/lnn_torch``, else ``~/.cache/lnn_torch``."""
    if os.environ.get("LNN_TORCH_CACHE"):
        return Path(os.environ["LNN_TORCH_CACHE"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base).expanduser() / "lnn_torch"


def split_path(spec: DatasetSpec, split: str) -> Path:
    """Where the cached ``split`` of ``spec`` lives."""
    digest = hashlib.sha256(spec.to_json().encode()).hexdigest()[:12]
    return cache_dir() / "datasets" / f"{spec.scene}-{split}-{digest}.h5"


def cached_split(spec: DatasetSpec, split: str, progress: bool = False) -> Path:
    """The file holding ``split`` of ``spec`` (its trajectories only), generated into the cache the
    first time (saying where and how many) and read from there afterwards."""
    path = split_path(spec, split)
    if not path.exists():
        n = len(split_indices(spec)[split])
        print(f"generating the {split} split ({n} of {spec.num_trajectories} trajectories of {spec.scene}, seed "
              f"{spec.seed}) into the cache: {path}")
        generate_dataset(spec, path, progress=progress, splits=(split,))
    return path
