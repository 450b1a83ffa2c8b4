"""One loader for trained models: a checkpoint path written by ``lnn-torch fit`` or ``pretrained:<name>``
for a model shipped with the package (``lnn_torch/pretrained``)."""

from __future__ import annotations

from pathlib import Path

from .pretrained import HERE, available, info

PRETRAINED = "pretrained:"


def _resolve(source: str | Path) -> Path:
    source = str(source)
    if source.startswith(PRETRAINED):
        name = source[len(PRETRAINED):]
        path = HERE / f"{name}.ckpt"
        if not path.exists():
            raise KeyError(f"no pretrained model '{name}'; available: {', '.join(available()) or 'none'}")
        return path
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    return path


def load_model(source: str | Path, map_location="cpu"):
    """The ``LNNModule`` of a checkpoint path or ``pretrained:<name>``, in evaluation mode (SI units in
    and out): ``model.acceleration(q, qd, params)``, ``model.rollout(...)``."""
    from .module import LNNModule

    model = LNNModule.load_from_checkpoint(_resolve(source), map_location=map_location)
    model.eval()
    return model


def load_pretrained(name: str = "double_pendulum", map_location="cpu"):
    """The shipped ``LNNModule`` ``name`` in evaluation mode (SI units in and out).

    >>> model = load_pretrained("double_pendulum")
    >>> model.acceleration(q, qd, params)  # (B, 2), (B, 2), (B, 4) -> (B, 2)
    """
    return load_model(f"{PRETRAINED}{name}", map_location)


def data_hparams(source: str | Path) -> dict:
    """The DataModule hyper-parameters a checkpoint records (its data path and dataset ``spec``)."""
    import torch

    ckpt = torch.load(_resolve(source), map_location="cpu", weights_only=False)
    if "datamodule_hyper_parameters" in ckpt:
        return ckpt["datamodule_hyper_parameters"]
    if str(source).startswith(PRETRAINED):  # shipped models keep it in their card
        return info(str(source)[len(PRETRAINED):]).get("datamodule_hyper_parameters", {})
    return {}
