"""Networks: FiLM, the Cholesky mass matrix, potentials, Lagrangian models and baselines (plain nn.Module)."""

from .layers import FiLM, TangentMLP
from .models import (VARIANTS, BlackBoxLagrangian, DirectMLP, DynamicsModel, HamiltonianNN, SceneInfo,
                     StructuredLagrangian, build_model)
from .normalization import Normalizer

__all__ = ["FiLM", "TangentMLP", "Normalizer", "SceneInfo", "DynamicsModel", "StructuredLagrangian",
           "BlackBoxLagrangian", "DirectMLP", "HamiltonianNN", "build_model", "VARIANTS"]
