"""Training and checkpoints: the LightningModule (``module``), its losses (``losses``, pure
functions), optimiser (``optim``), compiled pass (``training_pass``) and callbacks (``callbacks``),
the DataModule (``datamodule``), the CLI wiring (``lightning_cli``), and checkpoints (``checkpoints``:
``load_model``; ``checkpoint_format``: the stamp and checks).

Imported on first use: Lightning loads only when a name of it is asked for."""

from importlib import import_module

_LAZY = {"LNNModule": ".module", "TrajectoryDataModule": ".datamodule", "load_model": ".checkpoints",
         "load_pretrained": ".checkpoints", "data_hparams": ".checkpoint_format", "output_dir": ".checkpoint_format",
         "read_checkpoint": ".checkpoint_format", "run_cli": ".lightning_cli", "make_trainer": ".lightning_cli",
         "LNNCLI": ".lightning_cli", "TRAINER_DEFAULTS": ".lightning_cli", "TrainingPass": ".training_pass",
         "acceleration_loss": ".losses", "energy_variance": ".losses"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = sorted(_LAZY)
