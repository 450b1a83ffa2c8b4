"""Datasets: specification, generation, the HDF5 schema and (with Lightning) the DataModule."""

from .generate import GenerationError, generate_dataset, sample_initial_conditions, simulate, split_indices
from .hdf5 import DatasetFileError, TrajectoryFile, read_dataset
from .spec import DatasetSpec

__all__ = ["DatasetSpec", "GenerationError", "generate_dataset", "simulate", "sample_initial_conditions", "split_indices",
           "read_dataset", "TrajectoryFile", "DatasetFileError"]
