"""lnn_torch: Lagrangian Neural Networks for mechanical systems, in PyTorch.

Public names: ``LNNModule`` (Lightning training shell), ``load_model`` (a checkpoint path or
``pretrained:<name>``), ``load_pretrained`` (shipped trained models), ``rollout`` (fixed-step
integration of any ``accel_fn``), ``get_system`` (ground-truth scenes), ``build_model`` (plain
``nn.Module`` variants), ``evaluate_model`` (the one evaluation pipeline), ``TrajectoryDataModule``
(HDF5 trajectories for Lightning).
"""

from ._version import __version__
from .mechanics.integrators import rollout
from .systems import get_system


def __getattr__(name):
    # Lightning and the networks are imported on first use, so that physics-only users stay light
    if name == "LNNModule":
        from .training.module import LNNModule

        return LNNModule
    if name == "build_model":
        from .networks import build_model

        return build_model
    if name == "load_pretrained":
        from .training.checkpoints import load_pretrained

        return load_pretrained
    if name == "load_model":
        from .training.checkpoints import load_model

        return load_model
    if name == "evaluate_model":
        from .evaluation import evaluate_model

        return evaluate_model
    if name == "TrajectoryDataModule":
        from .training.datamodule import TrajectoryDataModule

        return TrajectoryDataModule
    raise AttributeError(f"module 'lnn_torch' has no attribute '{name}'")


__all__ = ["__version__", "rollout", "get_system", "LNNModule", "build_model", "TrajectoryDataModule",
           "load_pretrained", "load_model", "evaluate_model"]
