"""Networks (plain ``nn.Module``): FiLM, tangent-carrying MLPs, the normaliser, the model variants and
their registry.

Where things live: ``base`` (normalisation glue, checks, rollouts, capabilities), ``features`` (the
angle features), ``rigid_body`` (the SI rigid-body face and its convention), ``forces`` (the learned
generalised forces), ``compiled`` (opt-in compilation), ``scene`` (``SceneInfo``), ``structured``
(``film_lnn``, ``delan``: the structured Lagrangian of its ``parts``), ``blackbox`` (``lnn``), ``direct``
(``mlp``), ``hamiltonian`` (``hnn``), ``registry`` (name -> class, ``build_model``), ``layers`` (FiLM,
TangentMLP), ``reference`` (the plain formulas the fast paths are tested against), ``fused`` (inference of
``film_lnn``'s default composition as one stacked network; ``fusable`` says where it applies), ``_kernels``
(private CPU-oriented forms).
"""

from .base import DynamicsModel
from .blackbox import BlackBoxLagrangian
from .calls import counting_failures, model_accelerations, model_rollout
from .capabilities import ENERGY, INVERSE_DYNAMICS, capabilities_of, missing
from .direct import DirectMLP
from .fused import fusable
from .hamiltonian import HamiltonianNN
from .layers import FiLM, TangentMLP
from .normalization import Normalizer
from .registry import MODELS, VARIANTS, build_model, model_options
from .scene import SceneInfo
from .shares import torque_shares
from .structured import DeLaN, FiLMLagrangian, StructuredLagrangian

__all__ = ["FiLM", "TangentMLP", "Normalizer", "SceneInfo", "DynamicsModel", "StructuredLagrangian", "FiLMLagrangian",
           "DeLaN", "BlackBoxLagrangian", "DirectMLP", "HamiltonianNN", "MODELS", "VARIANTS", "build_model",
           "model_options", "counting_failures", "model_accelerations", "model_rollout", "capabilities_of",
           "missing", "ENERGY", "INVERSE_DYNAMICS", "torque_shares", "fusable"]
