"""lnn_torch: Lagrangian Neural Networks for mechanical systems, in PyTorch.

The public face, one name per task (each package's ``__init__`` is the second tier):

* models: ``load_model`` (a checkpoint path or ``pretrained:<name>``), ``load_pretrained``,
  ``build_model`` (plain ``nn.Module`` variants), ``LNNModule`` (the Lightning training shell);
* scenes and data: ``get_system``, ``rollout`` (fixed-step integration of any ``accel_fn``),
  ``generate_dataset``, ``import_recordings`` with its ``ImportSpec``, ``read_dataset``,
  ``TrajectoryDataModule``;
* use: ``evaluate_model`` (the one evaluation pipeline), ``identify`` (a learned model's physical
  parameters), ``fit_classical`` (classical least squares on a robot arm), ``plant_of`` (the plant
  view for control), ``export_model`` (standalone programs);
* the exceptions (``InputError``, ``CheckpointError``, ...).

Names other than ``get_system`` and ``rollout`` are imported on first use, so that physics-only
users stay light (no Lightning).
"""

from importlib import import_module

from ._version import __version__
from .errors import (
    CheckpointError,
    DatasetFileError,
    GenerationError,
    InputError,
    PoorFitWarning,
    SingularHessianError,
    UntrustedParameterWarning,
)
from .mechanics.integrators import rollout
from .systems import get_system

_LAZY = {"LNNModule": ".training.module", "TrajectoryDataModule": ".training.datamodule",
         "load_model": ".training.checkpoints", "load_pretrained": ".training.checkpoints",
         "build_model": ".networks.registry", "evaluate_model": ".evaluation", "identify": ".identification.learned",
         "fit_classical": ".identification.arm_comparison", "plant_of": ".control.plant",
         "export_model": ".export.programs", "generate_dataset": ".data.generate",
         "import_recordings": ".data.importer", "ImportSpec": ".data.importer", "read_dataset": ".data.hdf5"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module 'lnn_torch' has no attribute '{name}'")


__all__ = ["__version__", "rollout", "get_system", "InputError", "CheckpointError", "DatasetFileError",
           "GenerationError", "SingularHessianError", "UntrustedParameterWarning", "PoorFitWarning", *_LAZY]
