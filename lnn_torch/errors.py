"""The library's exceptions, in one module that imports nothing of the package (any module may raise them).

* ``InputError`` (a ``ValueError``): malformed physical input or options: shapes, NaN, non-positive
  parameters, an option a variant cannot use;
* ``SingularHessianError`` (a ``RuntimeError``): the velocity Hessian of a Lagrangian is singular, so
  its accelerations are undefined (``lnn_torch.mechanics.euler_lagrange``);
* ``DatasetFileError`` (a ``ValueError``): a dataset file is missing, not HDF5, incomplete or malformed;
* ``GenerationError`` (a ``RuntimeError``): ground truth could not be integrated to the requested accuracy;
* ``CheckpointError`` (an ``InputError``): a file is not a readable lnn-torch checkpoint.

Each is also importable where it was first defined (``lnn_torch.systems.base.InputError``,
``lnn_torch.mechanics.euler_lagrange.SingularHessianError``, ``lnn_torch.data.DatasetFileError``,
``lnn_torch.systems.ground_truth.GenerationError``).
"""


class InputError(ValueError):
    """Raised for malformed physical input (shapes, NaN, non-positive parameters)."""


class UntrustedParameterWarning(UserWarning):
    """Parameters given to a model lie beyond its trusted range (``Normalizer.TRUST`` standard
    deviations of its training parameters): the model conditions on the nearest trusted values."""


class SingularHessianError(RuntimeError):
    """The velocity Hessian d2L/dqd2 of a Lagrangian is singular: accelerations are undefined."""


class DatasetFileError(ValueError):
    """A dataset file is missing, not HDF5, incomplete or malformed."""


class GenerationError(RuntimeError):
    """Ground truth could not be integrated to the requested accuracy."""


class CheckpointError(InputError):
    """A file that is not a readable lnn-torch checkpoint (one line naming the file and what it is not)."""


__all__ = ["InputError", "SingularHessianError", "DatasetFileError", "GenerationError"]
