"""The scene interface: what every ground-truth mechanical system declares and computes.

A scene (system) states its degrees of freedom, which coordinates are angles, its physical
parameters with units, whether its kinetic energy is quadratic in the velocities, seeded samplers
for parameters and initial states, and closed-form batched physics in SI units.

Shapes: ``q``, ``qd`` are ``(*batch, dof)``; ``params`` is ``(*batch, num_params)``. Every
function keeps the input dtype and device and also works on a single unbatched sample, so that it
can be differentiated with ``torch.func``.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import numpy as np
import torch

GRAVITY = 9.81  # m/s^2, the one gravity constant of the project


class InputError(ValueError):
    """Raised for malformed physical input (shapes, NaN, non-positive parameters)."""


@dataclass(frozen=True)
class Range:
    """A closed interval ``[low, high]`` with ``low < high``."""

    low: float
    high: float

    def __post_init__(self) -> None:
        lo, hi = float(self.low), float(self.high)
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise InputError(f"range [{lo}, {hi}] is not finite")
        if lo > hi:
            raise InputError(f"range [{lo}, {hi}] is inverted (low > high)")
        if lo == hi:
            raise InputError(f"range [{lo}, {hi}] is empty (low == high)")

    def sample(self, rng: np.random.Generator, size) -> np.ndarray:
        return rng.uniform(self.low, self.high, size=size)


def as_range(value, name: str) -> Range:
    """Accept a ``Range``, a pair ``(low, high)`` or a dict with ``low``/``high``."""
    if isinstance(value, Range):
        return value
    try:
        if isinstance(value, dict):
            return Range(float(value["low"]), float(value["high"]))
        low, high = value
        return Range(float(low), float(high))
    except InputError as err:
        raise InputError(f"{name}: {err}") from None
    except (TypeError, ValueError, KeyError):
        raise InputError(f"{name}: expected a pair (low, high), got {value!r}") from None


class System(abc.ABC):
    """Base class of the ground-truth scenes.

    Subclasses set the class attributes and implement the closed-form physics. The sampler
    configuration is given to ``__init__`` and reported by ``config()`` so that a dataset file can
    record it and rebuild the same scene.
    """

    name: str = ""
    dof: int = 0
    angle_mask: tuple[bool, ...] = ()
    coord_names: tuple[str, ...] = ()
    param_names: tuple[str, ...] = ()
    param_units: tuple[str, ...] = ()
    quadratic_kinetic: bool = True
    conventions: str = ""
    gravity: float = GRAVITY
    speed_limit: float | None = None  # |qd| must stay below this (the relativistic particle's c = 1)

    @property
    def num_params(self) -> int:
        return len(self.param_names)

    @property
    def coord_units(self) -> tuple[str, ...]:
        return tuple("rad" if a else "m" for a in self.angle_mask)

    # ------------------------------------------------------------------ configuration
    @abc.abstractmethod
    def config(self) -> dict:
        """The sampler configuration (JSON-serialisable) that rebuilds this scene."""

    def describe(self) -> dict:
        """Everything a dataset file records about the scene."""
        return {
            "name": self.name,
            "dof": self.dof,
            "angle_mask": list(self.angle_mask),
            "coord_names": list(self.coord_names),
            "coord_units": list(self.coord_units),
            "param_names": list(self.param_names),
            "param_units": list(self.param_units),
            "quadratic_kinetic": self.quadratic_kinetic,
            "gravity": self.gravity,
            "conventions": self.conventions,
            "config": self.config(),
        }

    # ------------------------------------------------------------------ samplers
    @abc.abstractmethod
    def sample_params(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` parameter vectors, float64 array ``(n, num_params)``."""

    @abc.abstractmethod
    def sample_state(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``n`` initial states ``(q0, qd0)``, each a float64 array ``(n, dof)``."""

    # ------------------------------------------------------------------ physics
    @abc.abstractmethod
    def potential(self, q: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Potential energy V in J, shape ``(*batch,)``."""

    def mass_matrix(self, q: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Mass matrix M in SI units, shape ``(*batch, dof, dof)`` (quadratic-T scenes only)."""
        raise NotImplementedError(f"scene '{self.name}' has no mass matrix: its kinetic energy is not quadratic")

    def kinetic(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Kinetic energy T in J, shape ``(*batch,)``. Default: ``1/2 qd^T M qd``."""
        M = self.mass_matrix(q, params)
        return 0.5 * torch.einsum("...i,...ij,...j->...", qd, M, qd)

    def lagrangian(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """L = T - V in J, shape ``(*batch,)``."""
        return self.kinetic(q, qd, params) - self.potential(q, params)

    def momentum(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Canonical momentum p = dL/dqd, shape ``(*batch, dof)``. Default: ``M qd``."""
        return torch.einsum("...ij,...j->...i", self.mass_matrix(q, params), qd)

    def energy(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Total energy E = p.qd - L in J, shape ``(*batch,)``. Default (quadratic T): T + V."""
        return self.kinetic(q, qd, params) + self.potential(q, params)

    @abc.abstractmethod
    def acceleration(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Closed-form accelerations qdd, shape ``(*batch, dof)``, in rad/s^2 or m/s^2."""

    def energy_scale(self, params: torch.Tensor) -> torch.Tensor:
        """The energy scale that drifts are divided by: V_max - V_min over q, shape ``(*batch,)``."""
        raise NotImplementedError

    # ------------------------------------------------------------------ cases and drawing (optional)
    def ood_cases(self) -> list[dict]:
        """Out-of-distribution test cases of this scene: ``[{"params": (P,), "q0": (dof,), "qd0": (dof,)}, ...]``
        (SI tuples). Reported by ``lnn-torch evaluate``; default none."""
        return []

    def hard_parameter_cases(self) -> dict[str, tuple[float, ...]]:
        """Named extreme parameter vectors for the stability cases (``lnn_torch.stability``), in
        addition to the generic ones every scene gets (parameters x10 and x0.1); default none."""
        return {}

    def positions(self, q: torch.Tensor, params: torch.Tensor) -> torch.Tensor | None:
        """Cartesian positions of the bodies for drawing, ``(*batch, num_bodies, 2)`` in m, linked as
        a chain from the origin (pendula); None (default) for scenes that are not drawn."""
        return None

    # ------------------------------------------------------------------ checks
    def check_params(self, params: torch.Tensor) -> None:
        """Raise ``InputError`` for non-finite or non-positive parameters."""
        if params.shape[-1:] != (self.num_params,):
            raise InputError(
                f"{self.name}: params must have shape (*batch, {self.num_params}) "
                f"({', '.join(self.param_names)}), got {tuple(params.shape)}"
            )
        if not torch.isfinite(params).all():
            raise InputError(f"{self.name}: params contain NaN or Inf")
        if (params <= 0).any():
            bad = [n for i, n in enumerate(self.param_names) if (params[..., i] <= 0).any()]
            raise InputError(f"{self.name}: parameters must be positive; non-positive values in {bad}")

    def check_state(self, q: torch.Tensor, qd: torch.Tensor | None = None) -> None:
        """Raise ``InputError`` for wrong shapes or non-finite states."""
        for name, x in (("q", q), ("qd", qd)):
            if x is None:
                continue
            if x.shape[-1:] != (self.dof,):
                raise InputError(f"{self.name}: {name} must have shape (*batch, {self.dof}), got {tuple(x.shape)}")
            if not torch.isfinite(x).all():
                raise InputError(f"{self.name}: {name} contains NaN or Inf")
        if qd is not None and q.shape != qd.shape:
            raise InputError(f"{self.name}: q and qd shapes differ: {tuple(q.shape)} vs {tuple(qd.shape)}")

    def check_inputs(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> None:
        self.check_state(q, qd)
        self.check_params(params)
        if params.shape[:-1] != q.shape[:-1]:
            raise InputError(
                f"{self.name}: batch shapes differ: q {tuple(q.shape)} vs params {tuple(params.shape)}"
            )
