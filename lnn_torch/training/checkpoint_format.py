"""The checkpoint format, a leaf of the package: where a checkpoint path or ``pretrained:<name>`` (a
model shipped in ``lnn_torch/pretrained``) points, the stamp ``LNNModule`` writes (package version
and format), the checks that refuse what is not an lnn-torch checkpoint in one line, and the shims
that let ``LNNModule`` load checkpoints of earlier versions. It imports nothing above itself: the
loader, ``load_model``, lives in ``lnn_torch.training.checkpoints`` (also ``lnn_torch.load_model``)."""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

from ..errors import CheckpointError, UnknownNameError
from ..pretrained import HERE, available, info

PRETRAINED = "pretrained:"
# the checkpoint's entry of the compiled robot descriptions its model was built from
# (``robots.description.compiled_copies``)
DESCRIPTION_COPIES = "robot_descriptions"

# The layout of what ``LNNModule`` saves (``stamp``): raised when a change makes older code unable to
# read new checkpoints, so that such code refuses them in one line instead of failing inside.
CHECKPOINT_FORMAT = 3
# format 2: the double pendulum's models read the relative angle too (``DoublePendulum(relative_angle=True)``);
# a checkpoint of format 1 or unstamped was trained without it (``scene_config_of_old``)
# format 3: models with joint friction save their Coulomb smoothing (``LearnedForces.coulomb_velocity_si``; a
# classical start may choose another than the scene's); older weights load with the scene's

# ---------------------------------------------------------------------------- old checkpoints
# What ``LNNModule`` needs to load checkpoints saved by earlier versions with the weights they were
# trained with.

# options that older checkpoints record with these values for every variant; a variant that does not
# take one of them ignores it there (any other value of an option a variant does not take is an error)
_UNSET_IN_OLD_CHECKPOINTS = {"film_mode": "neuron", "potential_film": True, "eps": 1e-4, "lnn_init": False,
                             "hnn_coordinates": "canonical"}


# film_lnn's default widths before the cost-accuracy front moved them to (64, 64): a checkpoint that
# recorded no widths (hidden_dims None, saved before every checkpoint recorded its widths) has these
_OLD_DEFAULT_WIDTHS = {"film_lnn": [128, 128]}


def without_old_checkpoint_defaults(options: dict, known) -> dict:
    """``options`` of a model less those a variant (taking the options ``known``) does not take and
    that hold the value every older checkpoint recorded for them (``_UNSET_IN_OLD_CHECKPOINTS``); any
    other option stays, to be accepted or refused by the variant."""
    return {k: v for k, v in options.items()
            if k in known or k not in _UNSET_IN_OLD_CHECKPOINTS or v != _UNSET_IN_OLD_CHECKPOINTS[k]}


def record_widths(checkpoint: dict, model) -> None:
    """Write ``model``'s widths into the ``checkpoint``'s hyper-parameters where they were left to the
    variant's default (``hidden_dims`` None), so that a later change of the default cannot change
    what the checkpoint loads as."""
    hp = checkpoint.get("hyper_parameters")
    if hp is not None and hp.get("hidden_dims") is None and hasattr(model, "hidden_dims"):
        hp["hidden_dims"] = list(model.hidden_dims)


def old_default_widths(hparams) -> list | None:
    """The widths a checkpoint with these hyper-parameters was trained with where it recorded none
    (saved before ``record_widths``): its variant's old default (``_OLD_DEFAULT_WIDTHS``); None where
    it recorded its widths or its variant's default never changed."""
    old = _OLD_DEFAULT_WIDTHS.get(hparams["variant"])
    return old if hparams.get("hidden_dims") is None else None


def scene_config_of_old(checkpoint: dict, hparams) -> dict | None:
    """The scene configuration a checkpoint of an earlier format was trained with where it differs from
    what its hyper-parameters now build: a double pendulum saved before format 2 had no relative-angle
    feature (``relative_angle: false``). None where the checkpoint builds as it was trained."""
    fmt = int(checkpoint.get("lnn_torch", {}).get("format", 0))
    config = dict(hparams.get("scene_config") or {})
    if fmt >= 2 or hparams.get("scene", "double_pendulum") != "double_pendulum" or "relative_angle" in config:
        return None
    return {**config, "relative_angle": False}


def stamp(checkpoint: dict) -> None:
    """Record the package version and checkpoint format that wrote ``checkpoint``."""
    from .._version import __version__

    checkpoint["lnn_torch"] = {"version": __version__, "format": CHECKPOINT_FORMAT}


def check_stamp(checkpoint: dict, path: Path) -> None:
    """``CheckpointError`` where ``checkpoint`` is not a model of this package or was written in a
    newer format than this version reads (checkpoints from before the stamp pass)."""
    from .._version import __version__

    if not isinstance(checkpoint, dict):
        raise CheckpointError(f"checkpoint {path} is not an lnn-torch checkpoint (it holds a "
                              f"{type(checkpoint).__name__})")
    written = checkpoint.get("lnn_torch", {})
    if int(written.get("format", 0)) > CHECKPOINT_FORMAT:
        raise CheckpointError(f"checkpoint {path} was written by a newer version of lnn-torch "
                              f"({written.get('version', '?')}; this is {__version__}): upgrade lnn-torch to read it")
    if "variant" not in checkpoint.get("hyper_parameters", {}) or "state_dict" not in checkpoint:
        raise CheckpointError(f"checkpoint {path} is not an lnn-torch checkpoint (no model variant or weights: a "
                              "checkpoint of another program?)")


def read_checkpoint(source: str | Path) -> dict:
    """The checked contents of a checkpoint path or ``pretrained:<name>`` (``torch.load``)."""
    import torch

    path = resolve(source)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except READ_ERRORS as err:
        raise unreadable(path, err) from None
    check_stamp(ckpt, path)
    return ckpt


def check_checkpoint_file(path: Path) -> Path:
    """``path`` if it can be an lnn-torch checkpoint (a non-empty PyTorch zip archive), else
    ``CheckpointError`` naming the file and what it is not."""
    if path.is_dir():
        raise CheckpointError(f"checkpoint {path} is a folder, not a checkpoint file")
    if path.stat().st_size == 0:
        raise CheckpointError(f"checkpoint {path} is an empty file")
    if not zipfile.is_zipfile(path):
        raise CheckpointError(f"checkpoint {path} is not an lnn-torch checkpoint (not a PyTorch archive: another kind "
                              "of file, or a truncated one)")
    return path


def resolve(source: str | Path) -> Path:
    source = str(source)
    if source.startswith(PRETRAINED):
        name = source[len(PRETRAINED):]
        path = HERE / f"{name}.ckpt"
        if not path.exists():
            raise UnknownNameError(f"no pretrained model '{name}'; available: {', '.join(available()) or 'none'}")
        return path
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    return check_checkpoint_file(path)


def unreadable(path: Path, err: Exception) -> CheckpointError:
    text = str(err).splitlines()[0][:160] if str(err) else ""
    return CheckpointError(f"checkpoint {path} is not an lnn-torch checkpoint ({type(err).__name__}: {text})")


# what reading a damaged or foreign archive raises (torch.load, Lightning, the module's own arguments)
READ_ERRORS = (KeyError, RuntimeError, EOFError, pickle.UnpicklingError, zipfile.BadZipFile, ModuleNotFoundError)


def output_dir(checkpoint: str, given: str | None, kind: str) -> Path:
    """Where a command writes what it makes of ``checkpoint``: ``given``, else ``<kind>/<name>`` for
    ``pretrained:<name>``, else ``<kind>`` beside the run's ``checkpoints`` folder."""
    if given:
        return Path(given)
    if str(checkpoint).startswith(PRETRAINED):
        return Path(kind) / str(checkpoint)[len(PRETRAINED):]
    return Path(checkpoint).parent.parent / kind


DATA_PATH = "data_path_resolved"  # the data file's absolute path when the checkpoint was saved


def data_hparams(source: str | Path) -> dict:
    """The DataModule hyper-parameters a checkpoint records (its data path and dataset ``spec``); a data path
    relative to the folder the fit ran in, not found from here, is the absolute one the checkpoint records."""
    ckpt = read_checkpoint(source)
    if "datamodule_hyper_parameters" in ckpt:
        hparams = dict(ckpt["datamodule_hyper_parameters"])
        given, resolved = hparams.get("path"), ckpt.get(DATA_PATH)
        if given and resolved and not Path(given).exists() and Path(resolved).exists():
            hparams["path"] = resolved
        return hparams
    if str(source).startswith(PRETRAINED):  # shipped models keep it in their card
        return info(str(source)[len(PRETRAINED):]).get("datamodule_hyper_parameters", {})
    return {}


RESIDUAL = "model.forces.residual."  # the force residual's weights in an LNNModule's state


def load_start_weights(module, source: str | Path) -> bool:
    """Start ``module`` (an ``LNNModule`` about to train) from the weights and normaliser of the
    checkpoint ``source`` (a path or ``pretrained:<name>``) of a model of the same variant and shape
    (widths, options, degrees of freedom and parameters; the scene may differ: a simulated arm's model
    fine-tuned on the real arm's recordings): fine-tuning on new data, or a warm restart of the
    schedule. The optimiser, the learning-rate schedule and the step count start afresh. The one
    difference allowed: ``module`` has a force residual (``residual_force``) and the checkpoint none
    (a residual beside a fitted model); the residual then starts as built, at zero, and True is
    returned (its units still to be fitted from the data). Anything else is refused in one line."""
    checkpoint = read_checkpoint(source)
    theirs = checkpoint["hyper_parameters"]
    if theirs.get("variant") != module.hparams.get("variant"):
        raise CheckpointError(f"init_from {source}: its variant is {theirs.get('variant')!r}, this run's is "
                              f"{module.hparams.get('variant')!r}")
    state = {**checkpoint["state_dict"], "skipped_steps": module.skipped_steps}  # this run's own count
    own = module.state_dict()
    fresh = any(k.startswith(RESIDUAL) for k in own) and not any(k.startswith(RESIDUAL) for k in state)
    if fresh:  # their options less the residual must be this run's (the strict load below checks the shapes)
        state.update({k: v for k, v in own.items() if k.startswith(RESIDUAL)})
    try:
        module.load_state_dict(state)
    except RuntimeError as err:  # a missing, unexpected or other-shaped tensor: other widths, options or dof
        detail = " ".join(line.strip() for line in str(err).splitlines()[1:])[:200]
        old = scene_config_of_old(checkpoint, theirs)
        if old is not None and old != dict(module.hparams.get("scene_config") or {}):
            detail = ("it was trained without the relative-angle feature (checkpoint format 1); train with "
                      "--data.spec.scene_config '{relative_angle: false}' (or that scene_config in the config) to "
                      "start from it")
        raise CheckpointError(f"init_from {source}: its weights do not fit this model (other widths, model "
                              f"options or degrees of freedom): {detail}") from None
    return fresh
