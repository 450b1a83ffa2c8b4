"""lnn_torch: Lagrangian Neural Networks for mechanical systems, in PyTorch."""

__version__ = "0.1.0"

from .integrators import rollout  # noqa: E402
from .systems import get_system  # noqa: E402

__all__ = ["__version__", "rollout", "get_system"]
