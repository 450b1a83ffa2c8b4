"""The library's exceptions, in one module that imports nothing of the package (any module may raise them).

* ``InputError`` (a ``ValueError``): malformed physical input or options: shapes, NaN, non-positive
  parameters, an option a variant cannot use;
* ``SingularHessianError`` (a ``RuntimeError``): the velocity Hessian of a Lagrangian is singular, so
  its accelerations are undefined (``lnn_torch.mechanics.euler_lagrange``);
* ``DatasetFileError`` (a ``ValueError``): a dataset file is missing, not HDF5, incomplete or malformed;
* ``GenerationError`` (a ``RuntimeError``): ground truth could not be integrated to the requested accuracy;
* ``CheckpointError`` (an ``InputError``): a file is not a readable lnn-torch checkpoint;
* ``UnknownNameError`` (an ``InputError`` and a ``KeyError``): a name none of those known (a pretrained model).

``check_tensors`` refuses, by name, an argument that is not a torch tensor or (for states) not floating point;
``values_readable`` says where the checks of values cannot run (under ``torch.func`` transforms);
``is_number`` and ``as_number`` are the settings' checks of a number (a bool is none; a number written as text is
one).

Each is also importable where it was first defined (``lnn_torch.systems.base.InputError``,
``lnn_torch.mechanics.euler_lagrange.SingularHessianError``, ``lnn_torch.data.DatasetFileError``,
``lnn_torch.systems.ground_truth.GenerationError``).
"""


class InputError(ValueError):
    """Raised for malformed physical input (shapes, NaN, non-positive parameters)."""


def check_tensors(floating=(), **named) -> None:
    """``InputError`` naming the first of ``named`` (``name=value``; None skipped) that is not a torch tensor (a
    numpy array, a list), or, for the names in ``floating``, not floating point (an integer tensor's results would
    be truncated)."""
    import torch

    for name, x in named.items():
        if x is None:
            continue
        if not isinstance(x, torch.Tensor):
            raise InputError(f"{name} must be a torch.Tensor, got {type(x).__name__} (torch.as_tensor({name}, "
                             "dtype=torch.float64) converts it)")
        if name in floating and not x.is_floating_point():
            raise InputError(f"{name} must be floating point, got {x.dtype} (e.g. torch.tensor([[1.0, 0.0]]), not "
                             "[[1, 0]]: integers would truncate the results)")


def values_readable() -> bool:
    """Whether the values of tensors can be read (for the checks of NaN, signs and ranges): not under a
    ``torch.func`` transform (``vmap``, ``grad``, ``jacrev``: their tensors hold no single value). Under
    ``torch.compile`` the checks run (a graph break). The checks of shapes and types hold everywhere."""
    from torch._C._functorch import peek_interpreter_stack

    return peek_interpreter_stack() is None


def is_number(x, finite: bool = False) -> bool:
    """Whether a setting's value ``x`` is a real number: an int or a float, not a bool (which Python counts as an
    int); ``finite``: and finite."""
    import math

    return isinstance(x, (int, float)) and not isinstance(x, bool) and (not finite or math.isfinite(x))


def as_number(x):
    """``x``, or the number a text ``x`` holds (a quoted ``'0.01'`` in a config): ``float(x)`` where it reads."""
    if isinstance(x, str):
        try:
            return float(x)
        except ValueError:
            pass
    return x


class UnknownNameError(InputError, KeyError):
    """A name among none of those known (a pretrained model): an ``InputError`` in one line, and a ``KeyError``
    for code that looks names up (its message without ``KeyError``'s quotes)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class UntrustedParameterWarning(UserWarning):
    """Parameters given to a model lie beyond the range it was trained on (``Normalizer.EXTRAPOLATION``
    standard deviations of its training parameters: its answers there are extrapolation); beyond its
    trusted range (``Normalizer.TRUST``) the model conditions on the nearest trusted values."""


class PoorFitWarning(UserWarning):
    """An identification's model explains little of the observation (its residual near or beyond the observed
    accelerations' own size): the observation is likely not the model's scene, or in other units, or barely moves;
    the estimates and their uncertainties then describe nothing."""


class SingularHessianError(RuntimeError):
    """The velocity Hessian d2L/dqd2 of a Lagrangian is singular: accelerations are undefined."""


class DatasetFileError(ValueError):
    """A dataset file is missing, not HDF5, incomplete or malformed."""


class GenerationError(RuntimeError):
    """Ground truth could not be integrated to the requested accuracy."""


class CheckpointError(InputError):
    """A file that is not a readable lnn-torch checkpoint (one line naming the file and what it is not)."""


__all__ = ["InputError", "SingularHessianError", "DatasetFileError", "GenerationError"]
