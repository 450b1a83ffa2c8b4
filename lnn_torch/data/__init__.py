"""Datasets: specification, generation, the HDF5 schema (the only writer of dataset files), the import of
recorded tables and derivative estimation. The Lightning DataModule over them is
``lnn_torch.training.TrajectoryDataModule``."""

from ..errors import DatasetFileError, GenerationError
from .generate import generate_arrays, generate_dataset, sample_initial_conditions, simulate, split_indices
from .hdf5 import TrajectoryFile, read_dataset
from .spec import DatasetSpec
from .trajectories import Trajectories

__all__ = ["DatasetSpec", "GenerationError", "generate_dataset", "generate_arrays", "simulate",
           "sample_initial_conditions", "split_indices", "read_dataset", "TrajectoryFile", "DatasetFileError",
           "Trajectories"]
