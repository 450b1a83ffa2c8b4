"""Structured Lagrangians ``L = 1/2 qd^T M(q, theta) qd - V(q, theta)`` (variants ``film_lnn`` and ``delan``).

``M = chol chol^T + eps I`` with ``chol`` lower-triangular (softplus + shift on its diagonal), from a
kinetic MLP; ``V`` from a potential MLP. ``film_lnn`` conditions both networks on the parameters by
FiLM; ``delan`` (Deep Lagrangian Networks, Lutter et al.) concatenates the parameters to the inputs.
Grey-box options for real arms: ``kinetic: chain`` (the mass matrix of a planar rigid chain,
``lnn_torch.networks.chain``, a rectangular factor ``F`` with ``M = F F^T + eps I``) and
``potential: harmonic`` (gravity's first-harmonic series), each optionally plus its MLP.

The solve needs no Hessian: the kinetic MLP carries forward-mode tangents along each coordinate by
hand (``d chol / d q_k``), the potential MLP has a hand-written reverse pass (``dV/dq``), and
``M qdd = dT/dq - dV/dq - Mdot qd`` is solved by Cholesky
(``lnn_torch.dynamics.structured_acceleration_from_factor``). The plain formulas this computes are
``lnn_torch.networks.reference``; tests compare the two, and the generic Hessian solve, in float64.
"""

from __future__ import annotations

import torch
from torch import nn

from ..dynamics import structured_acceleration_from_factor
from ..errors import InputError
from ..systems.base import GRAVITY
from ._kernels import one
from .base import DynamicsModel
from .layers import FiLM, TangentMLP


# The harmonic potential's coefficients are stored divided by this gain: Adam moves a parameter by
# about the learning rate per step, and gravity-sized coefficients in the normalised units of a forced
# system are O(10) (on the real double pendulum a gain of 1 reached about 60 % of the lab model's
# gravity torques in 6,000 steps; 10, 30 and 100 fitted alike).
HARMONIC_GAIN = 10.0


class StructuredLagrangian(DynamicsModel):
    """``film_lnn``: FiLM-conditioned Cholesky mass matrix and potential.

    Args:
        scene: a ``System``, its ``describe()`` dict or a ``SceneInfo``.
        hidden_dims: hidden widths of the kinetic and the potential MLP (default 64 x 64: the knee of the
            cost-accuracy front, ``results/cost_accuracy/README.md``; 128 x 128 before).
        activation: ``tanh`` (default), ``softplus``, ``sigmoid`` or ``isru``.
        film_mode: ``neuron`` (a (gamma, beta) pair per hidden neuron) or ``layer`` (one scalar pair
            per layer, the reference design).
        potential_film: FiLM on the potential network too (else it reads the parameters as inputs).
        film_hidden: hidden width of each FiLM network.
        eps: ``M = chol chol^T + eps I``.
        diag_shift: added to the softplus of the Cholesky diagonal.
        learn_input_matrix, dissipation: the generalised forces of a scene with inputs or friction
            (``lnn_torch.networks.forces``; ignored for a conservative scene, which builds none).
        mass_invariant: coordinates (indices) that the mass matrix does not depend on: the kinetic
            network then reads only the features that do not involve them (e.g. ``[0]`` for a serial
            arm in joint angles, whose kinetic energy is unchanged by turning the whole arm about its
            base joint). None (default): every coordinate. Needs the two networks (not ``shared``).
        shared: ONE network (``trunk``, with one FiLM) whose outputs are both the Cholesky entries and
            the potential, as Deep Lagrangian Networks share their hidden layers: a single pass with
            forward tangents gives ``chol``, ``d chol / dq``, ``V`` and ``dV/dq`` (about half the work
            of two networks; ``results/cost_accuracy/README.md``). Its input is the features and the
            parameters. Default False: a kinetic and a potential network.
        potential: ``mlp`` (default: the potential MLP), ``harmonic``: ``V = sum_k c_k(theta) phi_k(q)``,
            linear in the first-harmonic features ``sin, cos`` of the angles and the scene's angle
            combinations, its coefficients constant (no parameters) or from a small network of the
            parameters. This is the exact form of the gravitational potential of any chain of rigid
            links on revolute joints in a uniform field (each centre of mass's height is a sum of
            ``l cos`` and ``l sin`` of absolute link angles, which the angle combinations supply for
            joint-relative angles); unlike an MLP it cannot bend where the data never went; or
            ``harmonic+mlp``: that series plus the potential MLP. The harmonic forms need angle
            coordinates only, and the two networks (not ``shared``). ``chain`` (with a chain kinetic
            energy): gravity ``g = 9.81 m/s^2`` on the chain's own masses and centres of mass, pointing
            along the angles' downward vertical: no parameter of its own, and it pins the chain's
            lengths to metres; ``chain+harmonic``: that plus the harmonic series as a residual (forces
            of springs, cables or a tilted base that gravity on the links does not explain; it decays
            under weight decay, but it can carry gravity itself, so the lengths are no longer pinned).
        kinetic: ``mlp`` (default: the Cholesky factor from the kinetic MLP), ``chain``: the mass matrix
            of a planar chain of rigid links on revolute joints (``lnn_torch.networks.chain``: masses,
            centres of mass, link lengths and a constant inertia matrix for the links' rotations and
            any motor rotors; constants without parameters, else from a small network of them), or ``chain+mlp``: that plus the
            Cholesky MLP's ``chol chol^T`` as a residual (which starts near zero). The chain forms need
            angle coordinates only, ``links``, and the two networks (not ``shared``).
        links: for the chain forms: each link's absolute angle (from the downward vertical) as a row of
            coefficients over the coordinates: ``[[1, 0], [0, 1]]`` for the double pendulum's absolute
            angles, ``[[1, 0], [1, 1]]`` for joint-relative angles.
    """

    variant = "film_lnn"
    conditioning = "film"

    def __init__(self, scene, hidden_dims=(64, 64), activation: str = "tanh", film_mode: str = "neuron",
                 potential_film: bool = True, film_hidden: int = 16, eps: float = 1e-4, diag_shift: float = 1e-3,
                 learn_input_matrix: bool = False, dissipation: str = "joint", shared: bool = False,
                 mass_invariant: list[int] | None = None, potential: str = "mlp", kinetic: str = "mlp",
                 links: list[list[float]] | None = None) -> None:
        super().__init__(scene, learn_input_matrix, dissipation)
        if not self.scene.quadratic_kinetic:
            raise InputError(
                f"scene '{self.scene.name}' has a kinetic energy that is not quadratic in the velocities; "
                "the structured model (T = 1/2 qd^T M qd) cannot represent it: use variant 'lnn'"
            )
        dof, P, F = self.scene.dof, self.scene.num_params, self.num_features
        hidden_dims = list(hidden_dims)
        self.hidden_dims = tuple(hidden_dims)
        self.eps, self.diag_shift = float(eps), float(diag_shift)
        self.num_chol = dof * (dof + 1) // 2
        film = self.conditioning == "film" and P > 0
        self.shared = bool(shared)
        if self.shared and mass_invariant is not None:
            raise InputError("mass_invariant needs a kinetic network of its own: it cannot be combined with shared")
        self.mass_invariant = self._kinetic_features(mass_invariant)
        if potential not in ("mlp", "harmonic", "harmonic+mlp", "chain", "chain+harmonic"):
            raise InputError(f"potential must be 'mlp', 'harmonic', 'harmonic+mlp', 'chain' or 'chain+harmonic', "
                             f"got {potential!r}")
        if potential.startswith("chain") and kinetic == "mlp":
            raise InputError("potential 'chain' is the gravity of the rigid chain's masses: it needs kinetic 'chain' "
                             "or 'chain+mlp'")
        self.chain_gravity = potential.startswith("chain")
        self.harmonic = "harmonic" in potential
        if self.harmonic and (self.shared or not self.all_angles):
            raise InputError(f"potential {potential!r} needs angle coordinates only and the two networks (not shared); "
                             f"scene '{self.scene.name}' has angle mask {list(self.scene.angle_mask)}"
                             + (", shared is set" if self.shared else ""))
        self.potential_coef = self.potential_coef_net = None
        if kinetic not in ("mlp", "chain", "chain+mlp"):
            raise InputError(f"kinetic must be 'mlp', 'chain' or 'chain+mlp', got {kinetic!r}")
        self.kinetic = kinetic
        self.chain = None
        if kinetic == "chain" and mass_invariant is not None:
            raise InputError("mass_invariant selects the kinetic network's inputs; kinetic 'chain' has no kinetic "
                             "network (its mass matrix never depends on the base angle): drop mass_invariant")
        if kinetic != "mlp":
            if self.shared or not self.all_angles or links is None:
                raise InputError(f"kinetic {kinetic!r} needs angle coordinates only, the two networks (not shared) "
                                 "and links (each link's absolute angle over the coordinates); scene "
                                 f"'{self.scene.name}' has angle mask {list(self.scene.angle_mask)}"
                                 + (", shared is set" if self.shared else "") + ("" if links else ", links not given"))
            from .chain import RigidChainKinetic

            self.chain = RigidChainKinetic(links, P, film_hidden)
            if self.chain.dof != dof:
                raise InputError(f"links must be rows of {dof} coefficients (one per coordinate), got {links!r}")
        if self.shared:  # one network: outputs [Cholesky entries | V]
            self.trunk = TangentMLP(F + P, hidden_dims, self.num_chol + 1, activation)
            self.trunk_film = FiLM(P, hidden_dims, film_mode, film_hidden) if film else None
            self.kinetic_net = self.potential_net = self.kinetic_film = self.potential_film = None
        else:
            Fk = F if self.kinetic_index is None else len(self.kinetic_index)  # the kinetic network's features
            # (the construction order fixes the random initialisation of a seed: kept as it was)
            self.kinetic_net = (TangentMLP(Fk if film else Fk + P, hidden_dims, self.num_chol, activation)
                                if kinetic != "chain" else None)
            mlp_potential = potential in ("mlp", "harmonic+mlp")
            self.potential_net = TangentMLP(F + P, hidden_dims, 1, activation, out_bias=False) if mlp_potential else None
            self.kinetic_film = FiLM(P, hidden_dims, film_mode, film_hidden) if (film and self.kinetic_net is not None) else None
            self.potential_film = (FiLM(P, hidden_dims, film_mode, film_hidden)
                                   if (film and potential_film and mlp_potential) else None)
            if self.harmonic:  # V (+)= c(theta) . phi(q)
                if P:
                    self.potential_coef_net = nn.Sequential(nn.Linear(P, film_hidden), nn.Tanh(),
                                                            nn.Linear(film_hidden, F))
                else:
                    self.potential_coef = nn.Parameter(torch.zeros(F))
            self.trunk = self.trunk_film = None
        # scatter of the Cholesky entries (diagonal first) into a row-major lower-triangular matrix;
        # folded into the kinetic network's output layer, which so outputs the dof^2 matrix directly
        # (the shared network's last output, V, passes through)
        rows, cols = torch.tril_indices(dof, dof)
        order = torch.cat([torch.nonzero(rows == cols)[:, 0], torch.nonzero(rows != cols)[:, 0]])
        n_out = self.num_chol + self.shared
        scatter = torch.zeros(n_out, dof * dof + self.shared)
        scatter[torch.arange(self.num_chol), rows[order] * dof + cols[order]] = 1.0
        if self.shared:
            scatter[-1, -1] = 1.0
        self.register_buffer("chol_scatter", scatter, persistent=False)
        self.register_buffer("chol_diag", torch.eye(dof, dtype=torch.bool).flatten(), persistent=False)
        self.chunk_conditioning = film
        if kinetic == "chain+mlp":  # the Cholesky MLP is a residual: it starts at chol ~ 0.02 I
            with torch.no_grad():
                self.kinetic_net.out.weight.zero_()
                self.kinetic_net.out.bias.zero_()
                self.kinetic_net.out.bias[:dof] = -4.0

    def _kinetic_features(self, invariant) -> list[int] | None:
        """Registers ``kinetic_index``: the features the kinetic network reads when the mass matrix
        does not depend on the coordinates ``invariant`` (None: all features, nothing registered)."""
        if invariant is None:
            self.kinetic_index = None
            return None
        dof = self.scene.dof
        invariant = sorted({int(i) for i in invariant})
        if any(not 0 <= i < dof for i in invariant):
            raise InputError(f"mass_invariant must list coordinate indices in [0, {dof}), got {invariant}")
        G = self.sel_angle.T  # (n_angles, dof): the feature angles in terms of q
        na = G.shape[0]
        angles = [i for i in range(na) if not G[i, invariant].any()]
        linear = [k for k, j in enumerate(self.linear_idx.tolist()) if j not in invariant]
        index = angles + [na + i for i in angles] + [2 * na + k for k in linear]
        if not index:
            raise InputError(f"mass_invariant {invariant} leaves the kinetic network no feature to read")
        self.register_buffer("kinetic_index", torch.tensor(index, dtype=torch.long), persistent=False)
        return invariant

    def chain_si(self, params: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """The rigid chain's identified parameters in SI: ``mass`` (kg), centre of mass ``along`` and
        ``across`` each link and joint-to-joint ``length`` (m), and ``constant`` ``K`` (kg m^2: link
        inertias about their centres of mass, motor rotors), for the scene's parameters ``params``
        ``(B, P)`` (None for a measured system). Needs ``potential: chain`` (gravity alone pins the
        lengths to metres; beside the harmonic series, which can carry gravity itself, it does not) and a
        scene with inputs (the torques fix the mass scale,
        ``M_SI = M_norm tau^2 / force_scale``)."""
        if (self.chain is None or not self.chain_gravity or self.harmonic or self.forces is None
                or not self.forces.num_inputs):
            raise InputError("SI chain parameters need kinetic 'chain', potential 'chain' and a scene with inputs "
                             "(without gravity alone only products of masses and lengths are identified)")
        norm = self.normalizer
        if params is None:
            params = torch.zeros(1, self.scene.num_params, device=norm.time_scale.device)
        with torch.no_grad():
            p = self.chain.parameters_of(norm.params(params.to(self.dtype)))
            scale = norm.time_scale ** 2 / norm.force_scale
            out = {"mass": p["mass"] * scale, "along": p["along"], "across": p["across"], "length": p["length"],
                   "constant": p["const"] @ p["const"].mT * scale}
        return {k: v.detach() for k, v in out.items()}  # a parameter passed through as it is stays detached too

    def coefficient_parameters(self):
        """As ``DynamicsModel.coefficient_parameters``, plus the chain's constants where a network of
        the scene's parameters gives them (its output bias) and the Cholesky residual's output bias
        (``chain+mlp``: decay towards 0 would grow a diagonal that starts at softplus(-4)); but the
        harmonic series beside the chain's own gravity (``potential: chain+harmonic``) is a residual,
        and decays like a network's weights."""
        params = super().coefficient_parameters()
        if self.chain_gravity and self.potential_coef is not None:
            params = [p for p in params if p is not self.potential_coef]
        if self.chain is not None and self.chain.net is not None:  # the chain's constants for a scene's parameters
            params.append(self.chain.net[-1].bias)
        if self.kinetic == "chain+mlp":  # the residual's bias (its diagonal starts at -4): decay would grow it
            params.append(self.kinetic_net.out.bias)
        return params

    # ------------------------------------------------------------------ conditioning
    def films(self, params_norm: torch.Tensor, chunks: int | None = None):
        """The FiLM pairs ``(kinetic, potential)`` for these parameters (None for a network without
        FiLM): per row ``(B, H)``, or per chunk ``(C, 1, H)`` when the batch is ``chunks`` runs of
        rows that share their parameters (one FiLM evaluation per chunk)."""
        if self.shared:
            return self._film(self.trunk_film, self.trunk, params_norm, chunks), None
        return (self._film(self.kinetic_film, self.kinetic_net, params_norm, chunks),
                self._film(self.potential_film, self.potential_net, params_norm, chunks))

    @staticmethod
    def _film(film_net, net, params_norm, chunks):
        if film_net is None:
            return None
        if chunks is None:
            return film_net(params_norm, net.sigmoid_form)
        cond = params_norm.view(chunks, -1, params_norm.shape[-1])[:, 0]
        return [(g[:, None], b[:, None]) for g, b in film_net(cond, net.sigmoid_form)]

    def _inputs(self, phi, params_norm):
        """The kinetic network's input: the features, plus the parameters where FiLM does not carry them."""
        return phi if self.kinetic_film is not None else torch.cat([phi, params_norm], -1)

    # ------------------------------------------------------------------ the networks
    def _terms(self, q_norm, params_norm, films, tangents: bool = True):
        """``(phi, chol, dchol, V, dV)`` from one pass of each network (of the one shared network):
        mass-matrix factor ``(B, dof, r)`` (``r = dof``: the Cholesky factor; see ``_cholesky``),
        ``d chol / d q_k`` ``(dof, B, dof, r)``, potential ``(B,)``
        and ``dV/dq`` ``(B, dof)`` (the derivatives None without ``tangents``)."""
        phi, dphi, sin_cos = self._features(q_norm, tangents)
        if not self.shared:
            geo = None if self.chain is None else self.chain.geometry(q_norm, params_norm)  # shared by M and V
            chol, dchol = self._cholesky(q_norm, phi, dphi, params_norm, films[0], geo)
            V, dV = self._potential(q_norm, phi, sin_cos, params_norm, films[1], grad=tangents, chain_geometry=geo)
            return phi, chol, dchol, V, dV
        n = self.scene.dof ** 2
        y, dy = self.trunk(torch.cat([phi, params_norm], -1), dphi, films[0], out_map=self.chol_scatter.to(phi.dtype))
        chol, dchol = self._chol_from(y[:, :n], None if dy is None else dy[..., :n])
        return phi, chol, dchol, y[:, n], (None if dy is None else dy[..., n].mT)

    def cholesky(self, q_norm, params_norm, tangents: bool = False):
        """Mass-matrix factor ``(B, dof, r)`` and, if asked, ``d chol / d q_k`` ``(dof, B, dof, r)``
        (``r = dof``, the Cholesky factor, unless ``kinetic`` is a chain form: see ``_cholesky``)."""
        if not self.shared:
            phi, dphi = self.features(q_norm, tangents)
            return self._cholesky(q_norm, phi, dphi, params_norm, self.films(params_norm)[0])
        _, chol, dchol, _, _ = self._terms(q_norm, params_norm, self.films(params_norm), tangents)
        return chol, dchol

    def _cholesky(self, q_norm, phi, dphi, params_norm, film, chain_geometry=None):
        """The mass matrix's factor ``(B, dof, r)`` (``M = F F^T + eps I``; square lower-triangular for
        the kinetic MLP, rectangular for the rigid chain, the two side by side for ``chain+mlp``) and
        its tangents ``(dof, B, dof, r)`` (None without ``dphi``)."""
        if self.chain is not None:
            Fc, dFc = self.chain.factor(q_norm, params_norm, tangents=dphi is not None, geometry=chain_geometry)
            if self.kinetic_net is None:
                return Fc, dFc
            chol, dchol = self._mlp_cholesky(phi, dphi, params_norm, film)
            return torch.cat([Fc, chol], -1), (None if dchol is None else torch.cat([dFc, dchol], -1))
        return self._mlp_cholesky(phi, dphi, params_norm, film)

    def _mlp_cholesky(self, phi, dphi, params_norm, film):
        S = self.chol_scatter.to(phi.dtype)  # (n_chol, dof^2)
        if self.kinetic_index is not None:  # only the features the mass matrix depends on
            phi = phi[..., self.kinetic_index]
            dphi = None if dphi is None else dphi[..., self.kinetic_index]
        # (B, dof^2), (K, B, dof^2); 0 above the diagonal
        raw, draw = self.kinetic_net(self._inputs(phi, params_norm), dphi, film, out_map=S)
        return self._chol_from(raw, draw)

    def _chol_from(self, raw, draw):
        """The factor and its tangents from the network's ``(B, dof^2)`` outputs (0 above the diagonal)
        and their tangents ``(K, B, dof^2)``."""
        dof, B = self.scene.dof, raw.shape[0]
        # positive diagonal: softplus + shift (computed on every entry, kept on the diagonal)
        chol = torch.where(self.chol_diag, nn.functional.softplus(raw) + self.diag_shift, raw).view(B, dof, dof)
        if draw is None:
            return chol, None
        dchol = draw * torch.where(self.chol_diag, torch.sigmoid(raw), one(raw))  # d softplus = sigmoid
        return chol, dchol.reshape(-1, B, dof, dof)

    def _mass_from(self, chol):
        """``M = chol chol^T + eps I`` ``(B, dof, dof)`` (``chol``: any factor ``(B, dof, r)``)."""
        eye = torch.eye(self.scene.dof, dtype=chol.dtype, device=chol.device)
        return torch.baddbmm(eye * self.eps, chol, chol.mT)

    def mass_matrix_norm(self, q_norm, params_norm):
        return self._mass_from(self.cholesky(q_norm, params_norm)[0])

    def mass_matrix(self, q, params):
        """The learned mass matrix in normalised units, ``(B, dof, dof)`` (physical M up to a scale per system)."""
        q_norm, _, params_norm = self.normalize(q, q, params)
        return self.mass_matrix_norm(q_norm, params_norm)

    def potential_norm(self, q_norm, params_norm, grad: bool = False):
        """Potential ``(B,)`` and, if asked, ``dV/dq`` ``(B, dof)`` (hand-written reverse pass, or the
        shared network's tangents)."""
        if self.shared:
            _, _, _, V, dV = self._terms(q_norm, params_norm, self.films(params_norm), grad)
            return V, dV
        phi, _, sin_cos = self._features(q_norm, False)
        return self._potential(q_norm, phi, sin_cos, params_norm, self.films(params_norm)[1], grad)

    def harmonic_coefficients(self, params_norm: torch.Tensor) -> torch.Tensor:
        """The harmonic potential's coefficients ``(B, F)`` (or ``(F,)`` without parameters)."""
        if self.potential_coef is not None:
            return HARMONIC_GAIN * self.potential_coef.to(params_norm.dtype)
        return HARMONIC_GAIN * self.potential_coef_net(params_norm)

    def _potential(self, q_norm, phi, sin_cos, params_norm, film, grad: bool, chain_geometry=None):
        V, dV_dphi = 0.0, 0.0
        if self.potential_net is not None:
            x = torch.cat([phi, params_norm], -1)
            if not grad:
                V = self.potential_net(x, None, film)[0][..., 0]
            else:
                V, dV_dphi = self.potential_net.value_and_input_grad(x, film, num_grad_inputs=self.num_features)
        if self.harmonic:  # plus c(theta) . phi(q)
            c = self.harmonic_coefficients(params_norm)
            V = V + (phi * c).sum(-1)
            dV_dphi = dV_dphi + c
        on_features = self.potential_net is not None or self.harmonic
        dV = self.features_vjp(q_norm, dV_dphi.expand_as(phi), sin_cos) if grad and on_features else None
        if self.chain_gravity:  # plus gravity on the chain's masses
            Vg, dVg = self.chain.gravity(q_norm, params_norm, self.gravity_norm(q_norm.dtype), grad, chain_geometry)
            V = V + Vg
            dV = dVg if dV is None else dV + dVg
        return V, dV

    def gravity_norm(self, dtype=torch.float32) -> torch.Tensor:
        """``g`` in normalised units, ``g tau^2`` (angles are not scaled): with it the chain's lengths are
        in metres (``V_norm / M_norm = tau^2 V / M`` whatever the force scale)."""
        return GRAVITY * self.normalizer.time_scale.to(dtype) ** 2

    # ------------------------------------------------------------------ the solve
    def _solve(self, q_norm, qd_norm, params_norm, films, energy: bool, force=None):
        """Accelerations (and, with ``energy``, ``H, T, V``) from ONE pass of each network, under
        the normalised generalised force ``force`` (None: none)."""
        _, chol, dchol, V, dV = self._terms(q_norm, params_norm, films)
        if not energy:
            return structured_acceleration_from_factor(chol, dchol, qd_norm, dV, self.eps, force=force)
        qdd, T = structured_acceleration_from_factor(chol, dchol, qd_norm, dV, self.eps, return_kinetic=True,
                                                     force=force)
        return qdd, T + V, T, V

    def solve_norm(self, q_norm, qd_norm, params_norm, force_norm=None):
        return self._solve(q_norm, qd_norm, params_norm, self.films(params_norm), energy=False, force=force_norm)

    def acceleration_and_energy_norm(self, q_norm, qd_norm, params_norm, chunks: int | None = None, force_norm=None):
        """Accelerations and the model's own ``H = T + V``, ``T``, ``V`` from ONE pass of each network
        (``chunks``: FiLM once per chunk, see ``DynamicsModel.acceleration_and_energy_norm``)."""
        B = q_norm.shape[0]
        if chunks is not None and (chunks < 1 or B % chunks):
            raise InputError(f"a batch of {B} rows cannot be split into {chunks} chunks of equal length")
        return self._solve(q_norm, qd_norm, params_norm, self.films(params_norm, chunks), energy=True, force=force_norm)

    def _acceleration_norm_films(self, q_norm, qd_norm, params_norm, films, tau_norm=None):
        return self.forced_acceleration_norm(lambda f: self._solve(q_norm, qd_norm, params_norm, films, False, f),
                                             q_norm, qd_norm, params_norm, tau_norm)

    @property
    def _has_film(self) -> bool:
        return any(f is not None for f in (self.kinetic_film, self.potential_film, self.trunk_film))

    def rollout_conditioning(self, params: torch.Tensor):
        if not self._has_film:
            return super().rollout_conditioning(params)
        params_norm = self.normalizer.params(params.to(self.dtype))
        return "_acceleration_norm_films", params_norm, (self.films(params_norm),)

    def acceleration_fn(self, params: torch.Tensor):
        """As ``DynamicsModel.acceleration_fn``, with both networks' FiLM computed once, not at
        every call (an RK4 step makes four)."""
        if not self._has_film:
            return super().acceleration_fn(params)
        params_norm = self.normalizer.params(params.to(self.dtype))
        films = self.films(params_norm)

        def accel(q, qd, params_, tau=None):
            if params_ is not params:
                raise InputError("acceleration_fn(params) was called with other parameters than its own")
            extra = () if tau is None else (self.tau_norm(tau),)
            return self._acceleration_si(self._acceleration_norm_films, q, qd, params_norm, films, *extra)

        return accel

    # ------------------------------------------------------------------ inverse dynamics
    def inverse_dynamics_norm(self, q_norm, qd_norm, qdd_norm, params_norm, chunks: int | None = None):
        """The input force ``B tau`` in SI ``(B, dof)`` that makes the model accelerate by ``qdd_norm``:
        ``M qdd - (dT/dq - dV/dq - Mdot qd) - Q_diss`` (Deep Lagrangian Networks' inverse model)."""
        if self.forces is None or not self.forces.num_inputs:
            raise InputError(f"inverse dynamics needs a scene with inputs; scene '{self.scene.name}' has none")
        phi, chol, dchol, _, dV = self._terms(q_norm, params_norm, self.films(params_norm, chunks))
        M = self._mass_from(chol)
        free = structured_acceleration_from_factor(chol, dchol, qd_norm, dV, self.eps)  # M free = rhs
        norm = self.normalizer
        qd = qd_norm * (norm.coord_scale.to(qd_norm.dtype) / norm.time_scale.to(qd_norm.dtype))
        phi_f = phi if self.forces.rayleigh is not None else None
        q_diss = self.forces.dissipative_force(qd, params_norm, phi_f, qd_norm)
        return norm.force_to_phys(torch.bmm(M, (qdd_norm - free)[..., None])[..., 0]) - q_diss

    def inverse_dynamics(self, q, qd, qdd, params) -> torch.Tensor:
        """The inputs ``tau (B, n_u)`` in N m that make the model accelerate by ``qdd`` (SI): the input
        force solved through the input matrix (least squares where fewer inputs than coordinates)."""
        self.check_inputs(q, qd, params, inputs=False)
        dtype = self.dtype
        q_n, qd_n, p_n = self.normalize(q.to(dtype), qd.to(dtype), params.to(dtype))
        Btau = self.inverse_dynamics_norm(q_n, qd_n, self.normalizer.accel_to_norm(qdd.to(dtype)), p_n)
        return self.forces.solve_inputs(Btau).to(q.dtype)

    # ------------------------------------------------------------------ energies
    def _mass_and_potential(self, q_norm, params_norm):
        _, chol, _, V, _ = self._terms(q_norm, params_norm, self.films(params_norm), tangents=False)
        return self._mass_from(chol), V

    def energy_norm(self, q_norm, qd_norm, params_norm):
        M, V = self._mass_and_potential(q_norm, params_norm)
        T = 0.5 * torch.einsum("bi,bij,bj->b", qd_norm, M, qd_norm)
        return T + V, T, V

    def lagrangian_norm(self, q_norm, qd_norm, params_norm):
        """Scalar Lagrangian of ONE sample ``(dof,), (dof,), (P,) -> ()`` (for torch.func references)."""
        M, V = self._mass_and_potential(q_norm[None], params_norm[None])
        return 0.5 * qd_norm @ M[0] @ qd_norm - V[0]


class DeLaN(StructuredLagrangian):
    """``delan`` (Deep Lagrangian Networks, Lutter et al.): the structured Lagrangian with the
    parameters concatenated to the inputs of both networks instead of FiLM."""

    variant = "delan"
    conditioning = "concat"

    def __init__(self, scene, hidden_dims=(128, 128), activation: str = "tanh", eps: float = 1e-4,
                 diag_shift: float = 1e-3, learn_input_matrix: bool = False, dissipation: str = "joint",
                 shared: bool = False, mass_invariant: list[int] | None = None, potential: str = "mlp") -> None:
        super().__init__(scene, hidden_dims, activation, eps=eps, diag_shift=diag_shift,
                         learn_input_matrix=learn_input_matrix, dissipation=dissipation, shared=shared,
                         mass_invariant=mass_invariant, potential=potential)
