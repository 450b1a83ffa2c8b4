"""Trained models from their checkpoints, for users: ``load_model(path | "pretrained:<name>")`` and
``load_pretrained(name)``.

The loader is here; the format itself (stamp, checks, shims for older checkpoints) lives in
``lnn_torch.training.checkpoint_format``, a leaf, and the module it loads in ``lnn_torch.training.module``.
"""

from __future__ import annotations

from ..errors import InputError
from . import checkpoint_format as ckpt
from .module import LNNModule

__all__ = ["load_model", "load_pretrained", "read_with_descriptions"]


def load_model(source, map_location="cpu") -> LNNModule:
    """The ``LNNModule`` of a checkpoint path or ``pretrained:<name>``, in evaluation mode (SI units in
    and out): ``model.acceleration(q, qd, params)``, ``model.rollout(...)``. A file that is not an
    lnn-torch checkpoint is refused in one line (``CheckpointError``)."""
    path = ckpt.resolve(source)
    read_with_descriptions(path)
    _check_map_location(map_location)
    try:
        model = LNNModule.load_from_checkpoint(path, map_location=map_location)
    except InputError:
        raise
    except ckpt.READ_ERRORS as err:
        raise ckpt.unreadable(path, err) from None
    model.eval()
    return model


def _check_map_location(map_location) -> None:
    """``InputError`` in one line for a device this machine lacks or cannot hold a model on (a CUDA device without
    CUDA, ``meta``: torch's error read as "not an lnn-torch checkpoint")."""
    import torch

    if callable(map_location) or isinstance(map_location, dict) or map_location is None:
        return
    try:
        device = torch.device(map_location)
    except (RuntimeError, TypeError) as err:
        raise InputError(f"map_location {map_location!r} is not a device ({err})") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"map_location {map_location!r}: this machine has no CUDA device (torch.cuda.is_available() "
                         "is False); load on 'cpu'")
    if device.type == "meta":
        raise InputError("map_location 'meta': a model needs its weights; load on 'cpu' or a GPU")


def read_with_descriptions(source) -> dict:
    """The checked contents of a checkpoint path or ``pretrained:<name>`` (``read_checkpoint``), the
    compiled robot descriptions it carries registered (``robots.description.register_copies``): a model
    built from its settings afterwards finds them where their files are gone."""
    path = ckpt.resolve(source)
    checkpoint = ckpt.read_checkpoint(path)
    copies = checkpoint.get(ckpt.DESCRIPTION_COPIES)
    if copies:
        from ..robots.description import register_copies

        register_copies(copies, f"checkpoint {path}")
    return checkpoint


def load_pretrained(name: str = "double_pendulum", map_location="cpu") -> LNNModule:
    """The shipped ``LNNModule`` ``name`` in evaluation mode (SI units in and out)."""
    return load_model(f"{ckpt.PRETRAINED}{name}", map_location)
