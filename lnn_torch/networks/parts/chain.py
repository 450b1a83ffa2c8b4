"""The kinetic energy of a planar chain of rigid links on parallel revolute joints (grey box).

Any such arm, whatever its masses, centres of mass, inertias and motors, has

    T = 1/2 sum_i m_i |v_i|^2 + 1/2 qd^T K qd

with ``v_i`` the velocity of link i's centre of mass and ``K`` a CONSTANT positive semi-definite
matrix in the coordinates: a link's rotation about its centre of mass (inertia ``I_i``, angular
rate ``G_i qd``) adds ``I_i G_i^T G_i``, and a motor rotor, whose rate is a fixed combination of the
coordinate rates whatever its gear ratio and carrier link, adds a constant term of the same kind.
With ``phi = G q`` the absolute link angles (``G``: the ``links`` option, e.g. ``[[1, 0], [1, 1]]``
for joint-relative angles), ``e(phi) = (sin phi, -cos phi)`` the direction of a link hanging at
``phi`` from the downward vertical and ``n(phi) = (cos phi, sin phi) = de/dphi``, link i's centre
of mass is at

    p_i = sum_{k < i} l_k e(phi_k) + a_i e(phi_i) + b_i n(phi_i)

(``l_k`` the joint-to-joint length of link k, ``(a_i, b_i)`` the centre of mass along and across
link i). ``M = F F^T`` with the rectangular factor ``F = [sqrt(m_i) dp_i/dq | L_K]`` (dof, 2 n + dof),
``K = L_K L_K^T`` (``L_K`` lower-triangular, positive diagonal): positive definite by construction.
It enters ``lnn_torch.mechanics.euler_lagrange.structured_acceleration_from_factor`` as a Cholesky factor would:
that solve needs ``M = F F^T`` and ``dF/dq``, not a triangular F. Few parameters (4 per link less
one length, 3 with ``across: false``, plus ``dof (dof + 1) / 2``), all learned: constants for a
measured system, or the output of a small network of the scene's parameters. This is the mass matrix
of the lab's physical model family, so it cannot bend where the data never went; ``kinetic:
chain+mlp`` adds the Cholesky MLP as a residual.

Parts here: ``RigidChain`` (kinetic ``chain``) and ``ChainGravity`` (potential ``chain``: gravity on
the chain's own masses and centres of mass).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ...errors import InputError
from ..normalization import trusted
from .base import BuildContext, KineticPart, PartInputs, PotentialPart, PotentialTerm, option

_SOFTPLUS_THIRD = math.log(math.expm1(0.3))


class RigidChain(KineticPart):
    """``chain``: mass-matrix factor of a planar rigid chain ``F (B, dof, r)`` and ``dF/dq_k (dof, B,
    dof, r)``, ``r = 2 n + dof``.

    Options:
        links: ``(n, dof)``: each link's absolute angle (from the downward vertical) as coefficients
            over the coordinates: ``[[1, 0], [0, 1]]`` for the double pendulum's absolute angles,
            ``[[1, 0], [1, 1]]`` for joint-relative angles.
        film_hidden: width of the network of the scene's parameters (when there are any; None: the
            model's default).
        across: whether a link's centre of mass may lie off the line from its joint to the next
            (``b_i`` learned; False: ``b_i = 0``, the lab model's form, the centre of mass on the link's
            line, which also takes a phase out of each link's gravity).
    """

    name = "chain"
    needs_angles = True

    def __init__(self, ctx: BuildContext, links=None, film_hidden=None, across: bool = True) -> None:
        super().__init__()
        if not isinstance(across, bool):
            raise InputError(f"kinetic part 'chain': across must be true or false, got {across!r}")
        self.across = across
        if links is None:
            raise InputError("kinetic part 'chain' needs links (each link's absolute angle over the coordinates), "
                             "e.g. kinetic: {chain: {links: [[1, 0], [1, 1]]}}")
        num_params, hidden = ctx.num_params, option(ctx, film_hidden, "film_hidden")
        try:
            G = torch.tensor(links, dtype=torch.float32)
        except (TypeError, ValueError):
            raise InputError(f"links must be rows of coordinate coefficients, got {links!r}") from None
        if G.ndim != 2 or G.shape[0] < 1:
            raise InputError(f"links must be a non-empty list of rows, got {links!r}")
        self.num_links, self.dof = G.shape
        self.register_buffer("link_map", G, persistent=False)
        n, dof = self.num_links, self.dof
        rows, cols = torch.tril_indices(dof, dof)
        self.register_buffer("const_rows", rows, persistent=False)
        self.register_buffer("const_cols", cols, persistent=False)
        # raw parameters: log mass, centre of mass along and across (n each), lengths (n - 1), and the
        # constant factor L_K's lower triangle (row-major; softplus on its diagonal). Masses are scale
        # parameters: Adam moves a log-mass by a fraction of itself per step, so a mass can reach the
        # O(100) of normalised units that metre-sized lengths need (potential: chain) within a run.
        const = torch.where(rows == cols, torch.full((len(rows),), _SOFTPLUS_THIRD), torch.zeros(len(rows)))
        init = torch.cat([torch.zeros(n), torch.full((n,), 0.5), torch.zeros(n), torch.ones(n - 1),
                          const])
        self.num_raw = init.numel()
        if num_params:
            self.net = nn.Sequential(nn.Linear(num_params, hidden), nn.Tanh(), nn.Linear(hidden, self.num_raw))
            nn.init.zeros_(self.net[-1].weight)
            with torch.no_grad():
                self.net[-1].bias.copy_(init)
            self.raw = None
        else:
            self.net = None
            self.raw = nn.Parameter(init)
        self.num_columns = 2 * n + dof
        if dof != ctx.dof:
            raise InputError(f"links must be rows of {ctx.dof} coefficients (one per coordinate), got {links!r}")

    def coefficient_parameters(self):
        # the chain's constants: its raw vector, or the output bias of its network of the parameters
        return [self.raw] if self.net is None else [self.net[-1].bias]

    def _geometry(self, inputs: PartInputs):
        return inputs.shared(self, lambda: self.geometry(inputs.q_norm, inputs.params_norm))

    def factor(self, inputs: PartInputs, cond):
        return self.factor_at(inputs.q_norm, inputs.params_norm, inputs.tangents, self._geometry(inputs))

    def reference_factor(self, q_norm, params_norm, phi):
        """``F`` with ``F F^T = sum_i m_i J_i^T J_i + K``, ``J_i = dp_i/dq`` by torch.func on the written-out
        centres of mass (``positions``)."""
        p = self.parameters_of(params_norm)

        def one(q1, p1):
            return self.positions(q1[None], p1[None])[0].flatten()  # (2 n,)

        J = torch.func.vmap(torch.func.jacrev(one))(q_norm, params_norm.expand(q_norm.shape[0], -1))  # (B, 2n, dof)
        B = q_norm.shape[0]
        mass = p["mass"].expand(B, -1).repeat_interleave(2, -1)  # (B, 2n): x and y of each link
        return torch.cat([(mass.sqrt()[..., None] * J).mT, p["const"].expand(B, -1, -1)], -1)

    def positions(self, q_norm: torch.Tensor, params_norm: torch.Tensor) -> torch.Tensor:
        """The centres of mass ``(B, n, 2)``, written out: joint k + 1 is at ``sum_{j <= k} l_j (sin phi_j,
        -cos phi_j)``, link i's centre of mass ``a_i`` along and ``b_i`` across its own direction from
        joint i (the readable reference of ``factor`` and ``gravity``)."""
        p = self.parameters_of(params_norm)
        phi = q_norm @ self.link_map.to(q_norm.dtype).T
        out, joint = [], q_norm.new_zeros(*q_norm.shape[:-1], 2)
        for i in range(self.num_links):
            s, c = torch.sin(phi[..., i]), torch.cos(phi[..., i])
            along, across = p["along"][..., i], p["across"][..., i]
            out.append(joint + torch.stack([along * s + across * c, -along * c + across * s], -1))
            if i < self.num_links - 1:
                joint = joint + p["length"][..., i, None] * torch.stack([s, -c], -1)
        return torch.stack(out, -2)

    def si_report(self, scales: dict, params_norm: torch.Tensor) -> dict:
        """The chain in SI: ``mass`` (kg), centre of mass ``along`` and ``across`` each link and
        joint-to-joint ``length`` (m), and ``constant`` ``K`` (kg m^2), detached. ``scales``: ``time``
        (s) and ``force`` (the normaliser's force scale); valid where gravity on the chain pins its
        lengths to metres and the inputs fix the mass scale (``StructuredLagrangian.chain_si``)."""
        with torch.no_grad():
            p = self.parameters_of(params_norm)
            scale = scales["time"] ** 2 / scales["force"]
            out = {"mass": p["mass"] * scale, "along": p["along"], "across": p["across"], "length": p["length"],
                   "constant": p["const"] @ p["const"].mT * scale}
        return {k: v.detach() for k, v in out.items()}  # a parameter passed through as it is stays detached too

    def parameters_of(self, params_norm: torch.Tensor) -> dict[str, torch.Tensor]:
        """The chain's parameters in normalised units, each ``(B, .)`` or ``(1, .)`` (no scene parameters):
        ``mass (n) >= 0``, centre of mass ``along, across (n)``, ``length (n - 1)``, and ``const``: the
        factor ``L_K (dof, dof)`` of the constant part ``K = L_K L_K^T``."""
        raw = self.raw.to(params_norm.dtype)[None] if self.net is None else self.net(trusted(params_norm))
        n, dof = self.num_links, self.dof
        mass, along, across, length, tri = raw.split([n, n, n, n - 1, len(self.const_rows)], -1)
        diag = (self.const_rows == self.const_cols).to(tri.device)
        tri = torch.where(diag, F.softplus(tri), tri)
        const = tri.new_zeros(tri.shape[0], dof * dof).index_copy(-1, self.const_rows * dof + self.const_cols, tri)
        if not self.across:
            across = torch.zeros_like(across)
        return {"mass": mass.exp(), "along": along, "across": across, "length": length,
                "const": const.view(-1, dof, dof)}

    def _coefficients(self, p: dict, batch: int):
        """``C[i, k]``: the coefficient of ``n(phi_k)`` in ``dp_i/dphi_k`` along the link (``l_k`` below
        the diagonal, ``a_i`` on it), ``S[i, k]``: that of ``-e(phi_k)`` (``b_i`` on the diagonal)."""
        n = self.num_links
        lengths = torch.cat([p["length"], p["length"].new_zeros(p["length"].shape[0], 1)], -1)  # (., n)
        below = torch.tril(torch.ones(n, n, dtype=lengths.dtype, device=lengths.device), -1)  # k < i
        C = below * lengths[:, None, :] + torch.diag_embed(p["along"])
        S = torch.diag_embed(p["across"])
        return C.expand(batch, n, n), S.expand(batch, n, n)

    def geometry(self, q_norm: torch.Tensor, params_norm: torch.Tensor) -> tuple:
        """What ``factor`` and ``gravity`` share, computed once per state batch: the parameters,
        ``C`` and ``S`` (``_coefficients``) and ``sin, cos`` of the absolute link angles ``(B, n)``."""
        p = self.parameters_of(params_norm)
        C, S = self._coefficients(p, q_norm.shape[0])
        phi = q_norm @ self.link_map.to(q_norm.dtype).T  # (B, n)
        return p, C, S, torch.sin(phi), torch.cos(phi)

    def factor_at(self, q_norm: torch.Tensor, params_norm: torch.Tensor, tangents: bool = True, geometry=None):
        """``F (B, dof, 2 n + dof)`` and, with ``tangents``, ``dF/dq_k (dof, B, dof, 2 n + dof)``
        (``geometry``: this state's ``geometry(q_norm, params_norm)`` where already computed)."""
        B, dtype = q_norm.shape[0], q_norm.dtype
        G = self.link_map.to(dtype)
        p, C, S, sin, cos = geometry or self.geometry(q_norm, params_norm)
        e = torch.stack([sin, -cos], -1)  # (B, n, 2)
        nrm = torch.stack([cos, sin], -1)  # de/dphi
        # dp_i/dphi_k = C_ik n_k - S_ik e_k;  dp_i/dq_j = sum_k (.) G_kj   -> (B, n, 2, dof)
        dp_dphi = C[..., None] * nrm[:, None] - S[..., None] * e[:, None]  # (B, i, k, 2)
        jac = torch.einsum("bikx,kj->bixj", dp_dphi, G)
        root_m = p["mass"].sqrt().expand(B, -1)  # (B, n)
        linear = (root_m[..., None, None] * jac).reshape(B, 2 * self.num_links, self.dof).mT  # (B, dof, 2n)
        Fq = torch.cat([linear, p["const"].expand(B, -1, -1)], -1)
        if not tangents:
            return Fq, None
        # d/dphi_k (dp_i/dphi_k) = -C_ik e_k - S_ik n_k (the only non-zero phi-derivative)
        d2 = -(C[..., None] * e[:, None] + S[..., None] * nrm[:, None])  # (B, i, k, 2)
        djac = torch.einsum("bikx,km,kj->mbixj", d2, G, G)  # (dof_m, B, n, 2, dof_j)
        dlinear = (root_m[None, ..., None, None] * djac).reshape(self.dof, B, 2 * self.num_links, self.dof).mT
        dF = torch.cat([dlinear, Fq.new_zeros(self.dof, B, self.dof, Fq.shape[-1] - 2 * self.num_links)], -1)
        return Fq, dF

    def gravity(self, q_norm: torch.Tensor, params_norm: torch.Tensor, g: torch.Tensor, grad: bool = True,
                geometry=None):
        """``V = g sum_i m_i y_i`` (``y`` the height of each centre of mass; the angles hang from the
        downward vertical) ``(B,)`` and, with ``grad``, ``dV/dq (B, dof)``. With ``w_k = sum_i m_i C_ik``
        and ``s_k = sum_i m_i S_ik``: ``V = g sum_k (s_k sin phi_k - w_k cos phi_k)`` (``geometry``: as
        for ``factor``)."""
        B = q_norm.shape[0]
        p, C, S, sin, cos = geometry or self.geometry(q_norm, params_norm)
        mass = p["mass"].expand(B, -1)[..., None]  # (B, n, 1)
        w, s = (mass * C).sum(-2), (mass * S).sum(-2)  # (B, n): over the links i whose position phi_k moves
        V = g * (s * sin - w * cos).sum(-1)
        if not grad:
            return V, None
        return V, (g * (s * cos + w * sin)) @ self.link_map.to(q_norm.dtype)



class ChainGravity(PotentialPart):
    """``chain``: gravity ``g = 9.81 m/s^2`` on the rigid chain's own masses and centres of mass, pointing
    along the angles' downward vertical (needs the kinetic part ``chain``). It has no parameter of its
    own and pins the chain's lengths to metres (``V_norm / M_norm = tau^2 V / M``)."""

    name = "chain"
    needs_angles = True

    def __init__(self, ctx: BuildContext) -> None:
        super().__init__()
        chain = ctx.kinetic_parts.get("chain")
        if chain is None:
            raise InputError("potential part 'chain' is the gravity of the rigid chain's masses: it needs the "
                             "kinetic part 'chain'")
        self._chain = (chain,)  # a reference, not a submodule: the kinetic part owns the chain's parameters

    @property
    def chain(self) -> RigidChain:
        return self._chain[0]

    def potential(self, inputs: PartInputs, cond, grad: bool) -> PotentialTerm:
        geometry = self.chain._geometry(inputs)
        V, dV = self.chain.gravity(inputs.q_norm, inputs.params_norm, inputs.gravity(inputs.q_norm.dtype), grad,
                                   geometry)
        return PotentialTerm(V, dV_dq=dV)

    def reference_potential(self, q_norm, params_norm, phi, gravity):
        heights = self.chain.positions(q_norm, params_norm)[..., 1]
        return gravity * (self.chain.parameters_of(params_norm)["mass"] * heights).sum(-1)
