"""What a part of a structured Lagrangian is, and what it is given.

A structured model (``lnn_torch.networks.structured``) is ``L = 1/2 qd^T M(q, theta) qd - V(q, theta)``
with ``M = F F^T + eps I``. Its *kinetic parts* each give a block of columns of the factor ``F``
(``M`` is the sum of their ``F_i F_i^T``); its *potential parts* each give a term of ``V``. A part
owns its parameters and says which of them are physical coefficients (exempt from weight decay),
gives a readable reference of what it computes (the tests compare the fast path with it in float64)
and, where it has one, a report in SI units.

Every part sees one ``PartInputs`` per evaluation: the normalised state and parameters, the input
features ``phi`` and their tangents, and a cache for what several parts share (the rigid chain's
geometry is computed once for its mass matrix and its gravity). A part that conditions on the
parameters once per rollout or training chunk (FiLM) computes that in ``condition``; the model
passes the result back at every evaluation.

Construction has two phases, so that a seed gives the initialisation (and the parameter order) of
earlier releases whatever parts are combined: ``__init__`` builds each part's own network (kinetic
parts first, then potential parts), then ``build_conditioning`` builds each part's conditioning
network (FiLM, a coefficient network of the parameters), in the same order. The conditioning is the
model variant's concern (FiLM for ``film_lnn``, none for ``delan``, which concatenates): the model
owns these networks (``model.conditioning_nets``), the part uses its own through ``conditioning_net``.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import nn

from ...errors import InputError
from ..layers import FiLM
from ..normalization import trusted


@dataclass(frozen=True)
class BuildContext:
    """What a part needs to know to build itself: the scene's sizes, the model's conditioning and its
    default options (each part's own options override them), and the model's feature maps."""

    scene_name: str
    dof: int
    num_params: int
    num_features: int
    all_angles: bool
    angle_mask: tuple[bool, ...]
    conditioning: str  # "film": FiLM on the parameters; "concat": the parameters as inputs (DeLaN)
    defaults: dict
    sel_angle: torch.Tensor  # (dof, n_feature_angles): the feature angles G q, as G^T
    linear_idx: tuple[int, ...]  # the non-angle coordinates
    kinetic_parts: dict = field(default_factory=dict)  # the kinetic parts built so far, by name
    robot_description: str | None = None  # the scene's robot description (``robot_arm``), for the spatial parts

    @property
    def film(self) -> bool:
        return self.conditioning == "film" and self.num_params > 0


@dataclass
class PartInputs:
    """One evaluation's inputs: ``q_norm (B, dof)``, ``params_norm (B, P)``, features ``phi (B, F)``,
    their tangents ``dphi (dof, B, F)`` (None when no tangents are asked), ``sin_cos`` of the feature
    angles, ``tangents``: whether ``d F / d q`` and ``dV/dq`` are asked, and the model's
    ``features_vjp`` and ``gravity`` (``g`` in normalised units)."""

    q_norm: torch.Tensor
    params_norm: torch.Tensor
    phi: torch.Tensor
    dphi: torch.Tensor | None
    sin_cos: tuple
    tangents: bool
    gravity: Callable[[torch.dtype], torch.Tensor]
    cache: dict = field(default_factory=dict)

    def shared(self, key, compute: Callable):
        """``compute()``, once per evaluation for ``key`` (what several parts use)."""
        if key not in self.cache:
            self.cache[key] = compute()
        return self.cache[key]


@dataclass
class PotentialTerm:
    """A potential part's ``V (B,)`` and its gradient, as a feature gradient ``dV_dphi (B, F)`` (pulled
    back to the coordinates once for all parts) and/or a coordinate gradient ``dV_dq (B, dof)``."""

    V: torch.Tensor
    dV_dphi: torch.Tensor | None = None
    dV_dq: torch.Tensor | None = None


class Part(nn.Module):
    """Abstract: a part of a structured Lagrangian (never instantiated itself)."""

    name = ""  # the registry name
    needs_angles = False  # refused for scenes with non-angle coordinates
    film_conditioned = False  # its conditioning network is a FiLM (``condition``: once per rollout or chunk)

    def build_conditioning(self, ctx: BuildContext) -> nn.Module | None:
        """The second phase of construction: the part's conditioning network (registered by the model
        under ``conditioning_nets``), or None."""
        return None

    def attach_normalizer(self, normalizer: nn.Module) -> None:
        self._normalizer_ref = (normalizer,)  # a reference: the model owns it

    @property
    def normalizer(self) -> nn.Module:
        """The model's ``Normalizer`` (its time, force and parameter scales), for parts in SI units."""
        return self._normalizer_ref[0]

    def attach_conditioning(self, net: nn.Module | None) -> None:
        self._conditioning_ref = (net,)  # a reference: the model owns the network

    @property
    def conditioning_net(self) -> nn.Module | None:
        return getattr(self, "_conditioning_ref", (None,))[0]

    @property
    def has_film(self) -> bool:
        return self.film_conditioned and self.conditioning_net is not None

    def condition(self, params_norm: torch.Tensor, chunks: int | None = None):
        """What the part derives from the parameters alone (FiLM pairs), or None."""
        return None

    def coefficient_parameters(self) -> list[nn.Parameter]:
        """The part's physical coefficients (exempt from weight decay)."""
        return []

    def regularization(self) -> torch.Tensor | None:
        """A term the training loss adds for this part (a prior on its physical parameters), or None."""
        return None

    def si_report(self, scales: dict, params_norm: torch.Tensor) -> dict | None:
        """The part's identified quantities in SI units, where it has any (``scales``: the normaliser's
        ``time`` and ``force`` scales; ``StructuredLagrangian.chain_si`` says when they apply)."""
        return None


class KineticPart(Part):
    """Abstract: a block of columns ``F_i (B, dof, r_i)`` of the mass-matrix factor."""

    def factor(self, inputs: PartInputs, cond) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``F_i (B, dof, r_i)`` and, with ``inputs.tangents``, ``d F_i / d q_k (dof, B, dof, r_i)``."""
        raise NotImplementedError

    def reference_factor(self, q_norm: torch.Tensor, params_norm: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        """``F_i`` by the plain formulas (``phi``: the plain features of ``q_norm``)."""
        raise NotImplementedError


class PotentialPart(Part):
    """Abstract: a term of the potential."""

    def potential(self, inputs: PartInputs, cond, grad: bool) -> PotentialTerm:
        raise NotImplementedError

    def reference_potential(self, q_norm: torch.Tensor, params_norm: torch.Tensor, phi: torch.Tensor,
                            gravity: torch.Tensor) -> torch.Tensor:
        """``V_i (B,)`` by the plain formulas."""
        raise NotImplementedError


class FiLMConditioned:
    """Abstract mixin of the parts whose MLP ``self.net`` (widths ``hidden_dims``) a FiLM network of the
    parameters modulates (``film_lnn``; ``use_film`` False or concatenated conditioning: none)."""

    film_conditioned = True
    use_film = True

    @property
    def film(self):
        """The FiLM network of this part's MLP (owned by the model), or None."""
        return self.conditioning_net

    def build_conditioning(self, ctx: BuildContext):
        if ctx.film and self.use_film:
            return FiLM(ctx.num_params, list(self.hidden_dims), self.film_mode, self.film_hidden)
        return None

    def condition(self, params_norm, chunks=None):
        return film_of(self.film, self.net, params_norm, chunks)


def film_of(film_net, net, params_norm: torch.Tensor, chunks: int | None):
    """The FiLM pairs of ``film_net`` for ``net`` (None without FiLM): per row ``(B, H)``, or per chunk
    ``(C, 1, H)`` when the batch is ``chunks`` runs of rows that share their parameters."""
    if film_net is None:
        return None
    if chunks is None:
        return film_net(trusted(params_norm), net.sigmoid_form)
    cond = trusted(params_norm).view(chunks, -1, params_norm.shape[-1])[:, 0]
    return [(g[:, None], b[:, None]) for g, b in film_net(cond, net.sigmoid_form)]


def part_options(cls: type[Part]) -> dict:
    """A part class's own options with their defaults (its ``__init__`` after ``self, ctx``)."""
    params = list(inspect.signature(cls.__init__).parameters.values())[2:]
    return {p.name: p.default for p in params if p.kind is p.KEYWORD_ONLY or p.kind is p.POSITIONAL_OR_KEYWORD}


def option(ctx: BuildContext, value, name: str):
    """A part's option: its own value, else the model's default."""
    return ctx.defaults[name] if value is None else value


def check_angles(part: type[Part], ctx: BuildContext, role: str) -> None:
    if part.needs_angles and not ctx.all_angles:
        raise InputError(f"{role} part '{part.name}' needs angle coordinates only; scene '{ctx.scene_name}' has "
                         f"angle mask {list(ctx.angle_mask)}")
