"""Datasets: specification, generation, the HDF5 schema (the only writer of dataset files), the import of
recorded tables and derivative estimation. The Lightning DataModule over them is
``lnn_torch.training.TrajectoryDataModule``."""

from ..errors import DatasetFileError, GenerationError
from .export_csv import export_recordings
from .generate import generate_arrays, generate_dataset, sample_initial_conditions, split_indices
from .hdf5 import (
    OPTIONAL_ARRAYS,
    TrajectoryFile,
    check_writable,
    copy_dataset,
    read_arrays,
    read_dataset,
    write_dataset,
)
from .spec import DatasetSpec
from .trajectories import Trajectories, points

__all__ = ["DatasetSpec", "GenerationError", "generate_dataset", "generate_arrays",
           "sample_initial_conditions", "split_indices", "read_dataset", "TrajectoryFile", "DatasetFileError",
           "Trajectories", "points", "copy_dataset", "read_arrays", "write_dataset", "check_writable",
           "OPTIONAL_ARRAYS", "export_recordings"]
