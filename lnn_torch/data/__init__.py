"""Datasets: specification, generation, the HDF5 schema and (with Lightning) the DataModule."""

from ..errors import DatasetFileError, GenerationError
from .generate import generate_arrays, generate_dataset, sample_initial_conditions, simulate, split_indices
from .hdf5 import TrajectoryFile, read_dataset
from .spec import DatasetSpec
from .trajectories import Trajectories


def __getattr__(name):  # the DataModule needs Lightning: imported on first use
    if name == "TrajectoryDataModule":
        from .datamodule import TrajectoryDataModule

        return TrajectoryDataModule
    raise AttributeError(f"module 'lnn_torch.data' has no attribute '{name}'")

__all__ = ["DatasetSpec", "GenerationError", "generate_dataset", "generate_arrays", "simulate",
           "sample_initial_conditions", "split_indices", "read_dataset", "TrajectoryFile", "DatasetFileError",
           "Trajectories"]
