"""Structured Lagrangians ``L = 1/2 qd^T M(q, theta) qd - V(q, theta)`` built from parts (variants
``film_lnn`` and ``delan``).

``M = F F^T + eps I`` with ``F = [F_1 | F_2 | ...]`` the columns of the model's kinetic parts and ``V``
the sum of its potential parts (``lnn_torch.networks.parts``): the Cholesky MLP, the rigid planar
chain, a sum of the two; the potential MLP, the harmonic or product series, the chain's gravity, sums; or one
shared network for both. ``film_lnn`` conditions the networks on the parameters by FiLM; ``delan``
(Deep Lagrangian Networks, Lutter et al.) concatenates the parameters to the inputs: the same
composition with other conditioning.

``residual_force`` adds a learned generalised force ``Q_r(q, qd, theta)`` beside the parts and the
learned friction (``lnn_torch.networks.residual_force``): starting at zero, regularised, not passive; in
the forward and inverse dynamics (``M qdd + n = B tau + Q_f + Q_r``, ``lnn_torch.networks.rigid_body``)
and in the power of the model's forces. ``lnn_torch.networks.shares`` reports how much of the torque it
and the residual parts carry.

The solve needs no Hessian: the parts carry forward-mode tangents by hand (``d F / d q_k``), the
potential parts give ``dV/dq`` (a hand-written reverse pass for the MLP), and ``M qdd = dT/dq - dV/dq
- Mdot qd`` is solved by Cholesky (``lnn_torch.mechanics.euler_lagrange.structured_acceleration_from_factor``). The
plain formulas this computes are each part's reference (``lnn_torch.networks.reference`` assembles
them); tests compare the two, and the generic Hessian solve, in float64.
"""

from __future__ import annotations

import contextlib
import inspect
import warnings

import torch
from torch import nn

from ..errors import InputError
from ..mechanics.euler_lagrange import structured_acceleration_from_factor
from ..systems.base import GRAVITY
from . import fused as _fused
from .base import DynamicsModel
from .capabilities import ENERGY, FORCES, FRICTION, INVERSE_DYNAMICS, MASS_MATRIX, STATIC_FRICTION
from .fused import compiled_view, fused_films, fused_solve, fusion_plan
from .fused_aot import FusedPrograms
from .parts import KINETIC_PARTS, POTENTIAL_PARTS, SHARED_PART, BuildContext, PartInputs, check_angles, parse_parts
from .parts import part_options as _part_options
from .residual_force import ResidualForce

# the options of ``residual_force`` (``ResidualForce``) and their defaults
RESIDUAL_FORCE_OPTIONS = {"hidden": [32, 32], "weight": 1e-3, "activation": "tanh", "film_hidden": 16,
                          "harmonics": 1, "local": False}
# options of the model that are defaults for its parts (a part's own options override them)
_PART_DEFAULTS = ("hidden_dims", "activation", "film_mode", "film_hidden", "diag_shift", "potential_film")

# state-dict prefixes of the models before parts: loaded into the parts that replaced them
_OLD_NAMES = (("kinetic_net.", "kinetic.mlp.net."), ("kinetic_film.", "conditioning_nets.kinetic_mlp."),
              ("potential_net.", "potential.mlp.net."), ("potential_film.", "conditioning_nets.potential_mlp."),
              ("potential_coef_net.", "conditioning_nets.potential_harmonic."),
              ("potential_coef", "potential.harmonic.coef"), ("chain.", "kinetic.chain."),
              ("trunk_film.", "conditioning_nets.kinetic_shared."), ("trunk.", "kinetic.shared.net."))


class StructuredLagrangian(DynamicsModel):
    """Abstract: the structured Lagrangian of its parts; ``FiLMLagrangian`` and ``DeLaN`` fix the
    conditioning (``conditioning``).

    Args:
        scene: a ``System``, its ``describe()`` dict or a ``SceneInfo``.
        kinetic: the kinetic parts: ``mlp`` (default: the Cholesky factor from an MLP), ``chain`` (the
            mass matrix of a planar chain of rigid links on revolute joints: masses, centres of mass,
            link lengths and a constant inertia matrix for the links' rotations and any motor rotors;
            constants without parameters, else from a small network of them), or a sum: ``{chain:
            {links: ...}, mlp: {}}`` (the chain plus the Cholesky MLP as a residual, which starts
            near zero). A name, a list of names or a dict of names to their options
            (``lnn_torch.networks.parts``).
        potential: the potential parts: ``mlp`` (default), ``harmonic`` (``V = sum_k c_k(theta)
            phi_k(q)``, linear in the first-harmonic features of the angles: the exact form of a rigid
            chain's gravity), ``products`` (linear in the products of the joints' ``(1, cos, sin)``: the
            exact form of a spatial serial arm's gravity with a payload; option ``skip``, e.g. ``[0]`` for
            a vertical first axis), ``chain`` (gravity ``g = 9.81 m/s^2`` on the rigid chain's own masses: no
            parameter of its own, it pins the chain's lengths to metres; needs the kinetic part
            ``chain``), or a sum (``[harmonic, mlp]``, ``[chain, harmonic]``: beside the chain's
            gravity the harmonic series is a residual that decays under weight decay).
        shared: ONE network (the part ``shared``) whose outputs are both the Cholesky entries and the
            potential, as Deep Lagrangian Networks share their hidden layers (about half the work of
            two networks; ``results/cost_accuracy/README.md``). Default False.
        hidden_dims, activation, film_mode, film_hidden, diag_shift, potential_film: defaults of the
            network parts (each part's own options override them): hidden widths (default 64 x 64 for
            ``film_lnn``: the knee of the cost-accuracy front), ``tanh``/``softplus``/``sigmoid``/
            ``isru``, FiLM per ``neuron`` or per ``layer``, the FiLM networks' width (0: no hidden layer,
            FiLM quadratic in the parameters; ``lnn_torch.networks.layers.FiLM``), the shift of the
            Cholesky diagonal's softplus, FiLM on the potential MLP too.
        eps: ``M = F F^T + eps I``.
        mass_invariant: the Cholesky MLP's ``mass_invariant`` (coordinates the mass matrix does not
            depend on, e.g. ``[0]`` for a serial arm in joint angles).
        links: the rigid chain's ``links`` (deprecated here: give it as the part's option).
        learn_input_matrix, dissipation: the generalised forces of a scene with inputs or friction
            (``lnn_torch.networks.forces``; ignored for a conservative scene, which builds none).
        friction: the drive model's friction forms per joint (``lnn_torch.mechanics.friction``): ``viscous+coulomb``
            (default), or any ``+``-joined subset of viscous, coulomb, offset, stribeck, saturating, sigmoid.
        residual_force: None (default: none) or the options of a force residual ``Q_r`` (``true`` or ``{}``:
            the defaults): ``hidden`` widths ([32, 32]), ``weight`` of its L2 penalty (1e-3), ``activation``
            (tanh), ``film_hidden`` (16), ``harmonics`` (1: sin/cos of the angles; K: of k times them, k <=
            K), ``local`` (false; true: a network per coordinate of its own angle and velocity); FiLM on the
            parameters for ``film_lnn``, the parameters as inputs for ``delan`` and ``local``
            (``lnn_torch.networks.residual_force``). Needs a scene with forces.

    Options given with a value other than their default that no part of the model takes: the
    part-specific ones (``mass_invariant``, ``links``) are refused, all in one line; the defaults of
    network parts the model does not have (``hidden_dims``, ...) are named in one warning.
    """

    conditioning = ""  # "film" or "concat": fixed by the concrete variants
    # inference of the default composition through ``fused`` (False: part by part, as under a gradient)
    fuse_inference = True
    provides = frozenset({ENERGY, MASS_MATRIX, INVERSE_DYNAMICS, FRICTION, STATIC_FRICTION, FORCES})

    def __init__(self, scene, *, hidden_dims, activation, film_mode, potential_film, film_hidden, eps, diag_shift,
                 learn_input_matrix, dissipation, shared, mass_invariant, potential, kinetic, links,
                 friction, residual_force=None) -> None:
        super().__init__(scene, learn_input_matrix, dissipation, friction)
        if not self.scene.quadratic_kinetic:
            raise InputError(
                f"scene '{self.scene.name}' has a kinetic energy that is not quadratic in the velocities; "
                "the structured model (T = 1/2 qd^T M qd) cannot represent it: use variant 'lnn'"
            )
        given = dict(hidden_dims=tuple(hidden_dims), activation=activation, film_mode=film_mode,
                     potential_film=potential_film, film_hidden=film_hidden, diag_shift=diag_shift,
                     mass_invariant=mass_invariant, links=links)
        self.hidden_dims = tuple(hidden_dims)
        self.eps = float(eps)
        self.shared = bool(shared)
        ctx = BuildContext(self.scene.name, self.scene.dof, self.scene.num_params, self.num_features,
                           self.all_angles, self.scene.angle_mask, self.conditioning,
                           {k: given[k] for k in _PART_DEFAULTS}, self.angle_features.sel_angle,
                           tuple(self.angle_features.linear_idx.tolist()),
                           robot_description=self.scene.robot_description)
        kinetic_spec, potential_spec = self._part_specs(kinetic, potential, given)
        # phase 1: each part's own network (kinetic parts first); phase 2: their conditioning networks
        self.kinetic, self.potential = nn.ModuleDict(), nn.ModuleDict()
        if self.shared:
            check_angles(SHARED_PART, ctx, "shared")
            self.kinetic["shared"] = SHARED_PART(ctx, **kinetic_spec.get("shared", {}))
        else:
            kin_residual = len(kinetic_spec) > 1
            for name, opts in kinetic_spec.items():
                cls = KINETIC_PARTS[name]
                check_angles(cls, ctx, "kinetic")
                extra = {"residual": True} if kin_residual and name == "mlp" else {}
                self.kinetic[name] = ctx.kinetic_parts[name] = cls(ctx, **opts, **extra)
            for name, opts in potential_spec.items():
                cls = POTENTIAL_PARTS[name]
                check_angles(cls, ctx, "potential")
                extra = {"residual": True} if ((name == "harmonic" and "chain" in potential_spec)
                                               or (name == "mlp" and "spatial" in potential_spec)) else {}
                self.potential[name] = cls(ctx, **opts, **extra)
        # the parts in their roles, as plain tuples (the ModuleDicts own them): iterated at every call
        self._parts = (*self.kinetic.values(), *self.potential.values())
        for part in self._parts:
            part.attach_normalizer(self.normalizer)
            if getattr(part, "takes_params_exactly", False):  # e.g. the spatial arm's payload: never clamped
                self.normalizer.mark_exact()
        self._kinetic_parts = tuple(self.kinetic.values())
        self._potential_parts = self._kinetic_parts if self.shared else tuple(self.potential.values())
        self._num_kinetic = 0 if self.shared else len(self._kinetic_parts)
        self.conditioning_nets = nn.ModuleDict()  # the parts' conditioning networks (FiLM, coefficient networks)
        for role, parts in (("kinetic", self.kinetic), ("potential", self.potential)):
            for name, part in parts.items():
                net = part.build_conditioning(ctx)
                part.attach_conditioning(net)
                if net is not None:
                    self.conditioning_nets[f"{role}_{name}"] = net
        self.chunk_conditioning = ctx.film
        self.register_load_state_dict_pre_hook(_load_old_names)
        # the force residual last: a seed gives every network above as without it
        if residual_force is not None and residual_force is not False:
            self._build_residual_force(residual_force)

    def _build_residual_force(self, options) -> None:
        opts = {} if options is True else options
        if not isinstance(opts, dict):
            raise InputError(f"residual_force takes a dict of options ({', '.join(RESIDUAL_FORCE_OPTIONS)}) or true, "
                             f"got {options!r}")
        bad = sorted(set(opts) - set(RESIDUAL_FORCE_OPTIONS))
        if bad:
            raise InputError(f"residual_force takes no option {', '.join(map(repr, bad))}; its options: "
                             f"{', '.join(RESIDUAL_FORCE_OPTIONS)}")
        if self.forces is None:
            raise InputError(f"residual_force needs a scene with generalised forces (inputs or friction); scene "
                             f"'{self.scene.name}' has none")
        opts = {**RESIDUAL_FORCE_OPTIONS, **opts}
        self.forces.attach_residual(ResidualForce(self.num_features, self.scene.dof, self.scene.num_params,
                                                  "film" if self.conditioning == "film" else "concat", **opts,
                                                  num_angles=int(self.angle_features.sel_angle.shape[1]),
                                                  angle_idx=self.angle_features.angle_idx.tolist(),
                                                  linear_idx=self.angle_features.linear_idx.tolist()))

    def _part_specs(self, kinetic, potential, given: dict) -> tuple[dict, dict]:
        """``{name: options}`` of the kinetic and the potential parts, with the model-level options that
        only some parts take given to them; every option (or part) the model cannot use, in one refusal."""
        defaults = {k: v.default for k, v in inspect.signature(type(self).__init__).parameters.items()}
        changed = {k for k, v in given.items() if k in defaults and _differs(v, defaults[k])}
        if self.shared:
            kinetic_spec, potential_spec = {"shared": {}}, {}
            conflicts = [f"{role} {spec!r}" for role, spec in (("kinetic", kinetic), ("potential", potential))
                         if spec != "mlp"]
            conflicts += [k for k in ("mass_invariant", "links", "potential_film") if k in changed]
            if conflicts:
                raise InputError(f"shared (one network for both energies) cannot be combined with "
                                 f"{', '.join(conflicts)}")
            return kinetic_spec, potential_spec
        kinetic_spec, potential_spec = parse_parts(kinetic, "kinetic"), parse_parts(potential, "potential")
        if given["links"] is not None and "chain" in kinetic_spec:
            warnings.warn("the model option links is deprecated; give it to the chain part, e.g. "
                          "kinetic: {chain: {links: [[1, 0], [1, 1]]}}", FutureWarning, stacklevel=4)
            kinetic_spec["chain"].setdefault("links", given["links"])
        if given["mass_invariant"] is not None and "mlp" in kinetic_spec:
            kinetic_spec["mlp"].setdefault("mass_invariant", given["mass_invariant"])
        parts = [KINETIC_PARTS[n] for n in kinetic_spec] + [POTENTIAL_PARTS[n] for n in potential_spec]
        taken = set().union(*(_part_options(cls) for cls in parts))
        unused = sorted(k for k in changed if k not in taken)
        what = f"model variant '{self.variant}' with kinetic {list(kinetic_spec)} and potential {list(potential_spec)}"
        refused = [k for k in unused if k not in _PART_DEFAULTS]  # options that select a part's structure
        if refused:
            raise InputError(f"{what} takes no option {', '.join(refused)} (no part uses it)")
        if unused:  # defaults of network parts it does not have
            warnings.warn(f"{what} has no network part: ignored {', '.join(unused)}", UserWarning, stacklevel=4)
        return kinetic_spec, potential_spec

    def part(self, role: str, name: str):
        """The model's ``role`` (``kinetic``/``potential``) part ``name``, or None."""
        if self.shared:
            return self.kinetic["shared"] if name == "shared" else None
        parts = self.kinetic if role == "kinetic" else self.potential
        return parts[name] if name in parts else None

    @property
    def chain(self):
        """The rigid-chain kinetic part, or None."""
        return self.part("kinetic", "chain")

    @property
    def has_si_chain(self) -> bool:
        """Whether ``chain_si`` applies: the rigid chain with its own gravity as the only potential, and inputs."""
        return (self.chain is not None and list(self.potential) == ["chain"] and self.forces is not None
                and self.forces.num_inputs > 0)

    def chain_si(self, params: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """The rigid chain's identified parameters in SI: ``mass`` (kg), centre of mass ``along`` and
        ``across`` each link and joint-to-joint ``length`` (m), and ``constant`` ``K`` (kg m^2: link
        inertias about their centres of mass, motor rotors), for the scene's parameters ``params``
        ``(B, P)`` (None for a measured system). Needs the kinetic part ``chain`` and gravity on it as
        the only potential part (it pins the lengths to metres; a harmonic series beside it can carry
        gravity itself) and a scene with inputs (the torques fix the mass scale, ``M_SI = M_norm tau^2
        / force_scale``)."""
        if not self.has_si_chain:
            raise InputError("SI chain parameters need kinetic 'chain', potential 'chain' and a scene with inputs "
                             "(without gravity alone only products of masses and lengths are identified)")
        norm = self.normalizer
        if params is None:
            params = torch.zeros(1, self.scene.num_params, device=norm.time_scale.device)
        scales = {"time": norm.time_scale, "force": norm.force_scale}
        return self.chain.si_report(scales, norm.params(params.to(self.dtype)))

    def fit_normalizer(self, stats: dict) -> None:
        """As ``DynamicsModel.fit_normalizer``; a model with the spatial arm part then starts its joint
        friction at the description's viscous damping (and a small Coulomb level); a force residual takes
        its units from the data (each coordinate's rms input force and normalised velocity)."""
        super().fit_normalizer(stats)
        self.fit_residual(stats)
        spatial = self.part("kinetic", "spatial")
        if spatial is not None and self.forces is not None and self.forces.friction and \
                self.forces.num_joints == spatial.dof:
            self.forces.start_at(spatial.description_damping())

    def fit_residual(self, stats: dict) -> None:
        """The force residual's units from the data ``stats`` (as ``fit_normalizer``): each coordinate's rms
        input force and normalised velocity (with the normaliser as it is). Nothing without a residual."""
        residual = None if self.forces is None else self.forces.residual
        if residual is None:
            return
        tau, B = stats.get("tau"), self.scene.input_matrix
        force_rms = None
        if tau is not None and B is not None:
            force = tau.double().reshape(-1, tau.shape[-1]) @ torch.tensor(B, dtype=torch.float64).T
            force_rms = force.pow(2).mean(0).sqrt()
        qd_norm = self.normalizer.state(stats["q"].double().reshape(-1, self.scene.dof),
                                        stats["qd"].double().reshape(-1, self.scene.dof))[1]
        residual.fit(force_rms, qd_norm.pow(2).mean(0).sqrt())

    def regularization(self) -> torch.Tensor | None:
        """The sum of the parts' priors (``Part.regularization``) and the force residual's penalty
        (``ResidualForce.regularization``), or None where there is none."""
        terms = [part.regularization() for part in self._parts]
        if self.forces is not None and self.forces.residual is not None:
            terms.append(self.forces.residual.regularization())
        terms = [t for t in terms if t is not None]
        return sum(terms) if terms else None

    # ------------------------------------------------------------------ residuals
    def residual_names(self) -> tuple[str, ...]:
        """The model's residuals beside its physics: ``force`` (the force residual), ``kinetic`` (the
        Cholesky MLP beside another kinetic part), ``potential`` (the potential MLP beside the arm's gravity,
        or the harmonic series beside the chain's): what ``residuals_off`` can switch off."""
        names = []
        if self.forces is not None and self.forces.residual is not None:
            names.append("force")
        if not self.shared and any(getattr(self.kinetic[n], "residual", False) for n in self.kinetic):
            names.append("kinetic")
        if not self.shared and any(getattr(self.potential[n], "residual", False) for n in self.potential):
            names.append("potential")
        return tuple(names)

    @contextlib.contextmanager
    def residuals_off(self, *which: str):
        """Within the block the model is without the residuals ``which`` (``residual_names``; none given:
        all): every call (forward and inverse dynamics, energies) runs as if they were not there (the
        force residual's output is dropped, the residual parts are left out of the sums). For measuring
        their share (``lnn_torch.networks.shares``); the weights are untouched."""
        names = self.residual_names()
        which = names if not which else which
        unknown = [w for w in which if w not in names]
        if unknown:
            raise InputError(f"the model has no residual {', '.join(map(repr, unknown))}; it has: "
                             f"{', '.join(names) or 'none'}")
        saved = (self._parts, self._kinetic_parts, self._potential_parts, self._num_kinetic,
                 None if self.forces is None else self.forces.residual)
        kinetic = tuple(p for p in self.kinetic.values() if not ("kinetic" in which and getattr(p, "residual", False)))
        potential = tuple(p for p in self.potential.values() if not ("potential" in which and
                                                                      getattr(p, "residual", False)))
        try:
            if "kinetic" in which or "potential" in which:
                self._kinetic_parts, self._potential_parts = kinetic, potential
                self._parts, self._num_kinetic = (*kinetic, *potential), len(kinetic)
            if "force" in which:
                self.forces.residual = None
            yield self
        finally:
            self._parts, self._kinetic_parts, self._potential_parts, self._num_kinetic = saved[:4]
            if self.forces is not None:
                self.forces.residual = saved[4]

    # ------------------------------------------------------------------ generalised forces
    def force_norm(self, q_norm, qd_norm, params_norm, tau_norm=None):
        """As ``DynamicsModel.force_norm``, with the features the force residual reads."""
        if self.forces is None or not self.forces.needs_features:
            return super().force_norm(q_norm, qd_norm, params_norm, tau_norm)
        return self.forces.force_norm(qd_norm, params_norm, tau_norm, self.features(q_norm)[0])

    def coefficient_parameters(self):
        """As ``DynamicsModel.coefficient_parameters``, plus each part's own (the chain's constants, a
        harmonic series that is not a residual, a Cholesky residual's output bias)."""
        params = super().coefficient_parameters()
        for part in self._parts:
            params += part.coefficient_parameters()
        return params

    # ------------------------------------------------------------------ conditioning
    def films(self, params_norm: torch.Tensor, chunks: int | None = None) -> tuple:
        """Each part's conditioning (its FiLM pairs, or None) for these parameters: per row ``(B, H)``,
        or per chunk ``(C, 1, H)`` when the batch is ``chunks`` runs of rows that share their
        parameters (one FiLM evaluation per chunk)."""
        return tuple(part.condition(params_norm, chunks) for part in self._parts)

    # ------------------------------------------------------------------ the parts
    def _part_inputs(self, q_norm, params_norm, tangents: bool) -> PartInputs:
        phi, dphi, sin_cos = self._features(q_norm, tangents)
        return PartInputs(q_norm, params_norm, phi, dphi, sin_cos, tangents, self.gravity_constant_norm)

    def _factor(self, inputs: PartInputs, conds):
        """The mass-matrix factor ``(B, dof, r)`` and its tangents ``(dof, B, dof, r)`` (None without
        ``inputs.tangents``): the kinetic parts' columns side by side."""
        # conds: every part's conditioning, the kinetic parts' first
        out = [part.factor(inputs, cond) for part, cond in zip(self._kinetic_parts, conds, strict=False)]
        if len(out) == 1:
            return out[0]
        F = torch.cat([f for f, _ in out], -1)
        return F, (None if out[0][1] is None else torch.cat([d for _, d in out], -1))

    def _potential(self, inputs: PartInputs, conds, grad: bool):
        """``V (B,)`` and, with ``grad``, ``dV/dq (B, dof)``: the sum of the potential parts, their
        feature gradients pulled back through the features once."""
        V = g_phi = dV = None
        for part, cond in zip(self._potential_parts, conds[self._num_kinetic:], strict=True):
            term = part.potential(inputs, cond, grad)
            V = term.V if V is None else V + term.V
            if term.dV_dphi is not None:
                g_phi = term.dV_dphi if g_phi is None else g_phi + term.dV_dphi
            if term.dV_dq is not None:
                dV = term.dV_dq if dV is None else dV + term.dV_dq
        if not grad:
            return V, None
        if g_phi is not None:
            pulled = self.features_vjp(inputs.q_norm, g_phi.expand_as(inputs.phi), inputs.sin_cos)
            dV = pulled if dV is None else pulled + dV
        return V, dV

    def _terms(self, q_norm, params_norm, conds, tangents: bool = True):
        """``(phi, F, dF, V, dV)`` from one pass of each part: mass-matrix factor ``(B, dof, r)``,
        ``d F / d q_k`` ``(dof, B, dof, r)``, potential ``(B,)`` and ``dV/dq`` ``(B, dof)`` (the
        derivatives None without ``tangents``)."""
        inputs = self._part_inputs(q_norm, params_norm, tangents)
        chol, dchol = self._factor(inputs, conds)
        V, dV = self._potential(inputs, conds, tangents)
        return inputs.phi, chol, dchol, V, dV

    def cholesky(self, q_norm, params_norm, tangents: bool = False):
        """Mass-matrix factor ``(B, dof, r)`` and, if asked, ``d F / d q_k`` ``(dof, B, dof, r)``."""
        return self._factor(self._part_inputs(q_norm, params_norm, tangents), self.films(params_norm))

    def _mass_from(self, chol):
        """``M = F F^T + eps I`` ``(B, dof, dof)`` (``chol``: any factor ``(B, dof, r)``)."""
        eye = torch.eye(self.scene.dof, dtype=chol.dtype, device=chol.device)
        return torch.baddbmm(eye * self.eps, chol, chol.mT)

    def mass_matrix_norm(self, q_norm, params_norm):
        return self._mass_from(self.cholesky(q_norm, params_norm)[0])

    def potential_norm(self, q_norm, params_norm, grad: bool = False):
        """Potential ``(B,)`` and, if asked, ``dV/dq`` ``(B, dof)``."""
        inputs = self._part_inputs(q_norm, params_norm, grad and self.shared)  # the shared net's tangents
        return self._potential(inputs, self.films(params_norm), grad)

    def gravity_constant_norm(self, dtype=torch.float32) -> torch.Tensor:
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
        plan = self._fusion_plan_for(q_norm.dtype)
        if plan is not None:  # inference of the default composition: one stacked network (``fused``)
            return fused_solve(self, plan, q_norm, qd_norm, params_norm, force=force_norm)
        return self._solve(q_norm, qd_norm, params_norm, self.films(params_norm), energy=False, force=force_norm)

    def _fusion_plan_for(self, dtype: torch.dtype | None):
        """The stacked weights of ``fused`` where they apply to this call: ``fuse_inference`` on, no
        gradient recorded, not compiling or exporting (compiled code takes the plan as an input:
        ``_inference_call``), inputs of ``dtype`` the model's (None: inputs cast to the model's); else None."""
        if (not self.fuse_inference or torch.is_grad_enabled() or torch.compiler.is_compiling()
                or torch.compiler.is_exporting() or torch.jit.is_tracing()):
            return None
        plan = fusion_plan(self)
        return plan if plan is not None and (dtype is None or plan.weights[0].dtype == dtype) else None

    def _inference_call(self, q, qd, params, tau=None) -> tuple:
        """Compiled, the fused path where it applies (``_compiled_plan``), its stacked weights the compiled
        program's inputs (``_fused_whole``); else ``DynamicsModel._inference_call``."""
        plan = self._compiled_plan(q.shape[0]) if self._compile is True else None
        if plan is not None:
            return self._fused_whole, q, qd, params, tau, plan
        return super()._inference_call(q, qd, params, tau)

    def _compiled_plan(self, rows: int):
        """The stacked weights as compiled code takes them (``fused.compiled_view``) where a compiled call of
        ``rows`` rows runs the fused path: no gradient (``_fusion_plan_for``) and at most
        ``fused.COMPILED_MAX_ROWS`` rows, above which the part-by-part program is the faster; else None."""
        # the compiled call casts its inputs to the model's dtype (that of the plan, stacked from its weights)
        plan = self._fusion_plan_for(None) if rows <= _fused.COMPILED_MAX_ROWS else None
        return None if plan is None else compiled_view(self, plan)

    def _compiler_for(self, fn, device):
        """On the CPU, the accelerations and a rollout's step run the fused path's AOTInductor programs where
        they take it (``fused_aot.FusedPrograms``: no dynamo on the call; other calls through ``torch.compile``);
        else ``CompiledDynamics._compiler_for``."""
        compiler = super()._compiler_for(fn, device)
        if fn.__name__ in ("_fused_whole", "_rollout_step") and torch.device(device).type == "cpu":
            return lambda fn_, device_: FusedPrograms(self, fn_, device_, compiler)
        return compiler

    def _fused_whole(self, q, qd, params, tau, plan):
        """``_acceleration_whole`` through the fused path with the stacked weights ``plan`` given."""
        extra = () if tau is None else (self.tau_norm(tau),)
        params_norm = self.normalizer.params(params.to(self.dtype))
        return self._acceleration_si(self._fused_acceleration_norm, q, qd, params_norm, plan,
                                     fused_films(plan, params_norm), *extra)

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

    def _fused_acceleration_norm(self, q_norm, qd_norm, params_norm, plan, films, tau_norm=None):
        return self.forced_acceleration_norm(lambda f: fused_solve(self, plan, q_norm, qd_norm, params_norm, films, f),
                                             q_norm, qd_norm, params_norm, tau_norm)

    @property
    def _has_film(self) -> bool:
        return any(part.has_film for part in self._parts)

    def rollout_conditioning(self, params: torch.Tensor):
        if not self._has_film:
            return super().rollout_conditioning(params)
        params_norm = self.normalizer.params(params.to(self.dtype))
        plan = self._compiled_plan(params.shape[0])  # the fused path, its weights the program's inputs
        if plan is not None:
            return "_fused_acceleration_norm", params_norm, (plan, fused_films(plan, params_norm))
        return "_acceleration_norm_films", params_norm, (self.films(params_norm),)

    def acceleration_fn(self, params: torch.Tensor):
        """As ``DynamicsModel.acceleration_fn``, with both networks' FiLM computed once, not at
        every call (an RK4 step makes four)."""
        if not self._has_film:
            return super().acceleration_fn(params)
        params_norm = self.normalizer.params(params.to(self.dtype))
        plan = None if self._compile is True else self._fusion_plan_for(params_norm.dtype)
        fused = None if plan is None else fused_films(plan, params_norm)
        films = None

        def accel(q, qd, params_, tau=None):
            nonlocal films
            if params_ is not params:
                raise InputError("acceleration_fn(params) was called with other parameters than its own")
            extra = () if tau is None else (self.tau_norm(tau),)
            if fused is not None and self._fusion_plan_for(params_norm.dtype) is plan:  # the same weights, no gradient
                return self._acceleration_si(self._fused_acceleration_norm, q, qd, params_norm, plan, fused, *extra)
            films = self.films(params_norm) if films is None else films
            return self._acceleration_si(self._acceleration_norm_films, q, qd, params_norm, films, *extra)

        return accel

    # ------------------------------------------------------------------ the rigid-body face (``rigid_body``)
    def bias_norm(self, q_norm, qd_norm, params_norm):
        """``n = -M a_0`` ``(B, dof)`` (normalised): Coriolis, centrifugal and gravity forces, with ``a_0``
        the accelerations under no generalised force (``RigidBodyFace.bias``)."""
        _, chol, dchol, _, dV = self._terms(q_norm, params_norm, self.films(params_norm))
        free = structured_acceleration_from_factor(chol, dchol, qd_norm, dV, self.eps)  # M free = rhs
        return -torch.bmm(self._mass_from(chol), free[..., None])[..., 0]

    def gravity_norm(self, q_norm, params_norm):
        """``g = n(q, 0) = dV/dq`` ``(B, dof)`` (normalised; ``RigidBodyFace.gravity``)."""
        return self.potential_norm(q_norm, params_norm, grad=True)[1]

    def inverse_dynamics_norm(self, q_norm, qd_norm, qdd_norm, params_norm, chunks: int | None = None):
        """The input force ``B tau`` in SI ``(B, dof)`` that makes the model accelerate by ``qdd_norm``:
        ``M qdd + n - Q_f - Q_r`` with ``n = -M a_0`` (Deep Lagrangian Networks' inverse model;
        ``RigidBodyFace.input_force``; ``Q_r`` the force residual, if any)."""
        if self.forces is None or not self.forces.num_inputs:
            raise InputError(f"inverse dynamics needs a scene with inputs; scene '{self.scene.name}' has none")
        phi, chol, dchol, _, dV = self._terms(q_norm, params_norm, self.films(params_norm, chunks))
        M = self._mass_from(chol)
        free = structured_acceleration_from_factor(chol, dchol, qd_norm, dV, self.eps)  # M free = rhs
        phi_f = phi if self.forces.needs_features else None
        q_state = self.forces.state_force_at(qd_norm, params_norm, phi_f)
        return self.normalizer.force_to_phys(torch.bmm(M, (qdd_norm - free)[..., None])[..., 0]) - q_state

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


def _differs(value, default) -> bool:
    if isinstance(value, (list, tuple)) and isinstance(default, (list, tuple)):
        return list(value) != list(default)
    return value != default


def _load_old_names(module, state_dict, prefix, *args) -> None:
    """Load a state dict saved before parts (``kinetic_net.*``, ``trunk.*``, ...) into the parts."""
    for key in [k for k in state_dict if k.startswith(prefix)]:
        rest = key[len(prefix):]
        for old, new in _OLD_NAMES:
            if rest.startswith(old) and not rest.startswith(new):
                state_dict[prefix + new + rest[len(old):]] = state_dict.pop(key)
                break


class FiLMLagrangian(StructuredLagrangian):
    """``film_lnn``: the structured Lagrangian with its networks conditioned on the parameters by FiLM
    (a ``(gamma, beta)`` pair per hidden neuron, or per layer with ``film_mode: layer``; the potential
    MLP too unless ``potential_film`` is off). Options: ``StructuredLagrangian``."""

    variant = "film_lnn"
    conditioning = "film"

    def __init__(self, scene, hidden_dims=(64, 64), activation: str = "tanh", film_mode: str = "neuron",
                 potential_film: bool = True, film_hidden: int = 16, eps: float = 1e-4, diag_shift: float = 1e-3,
                 learn_input_matrix: bool = False, dissipation: str = "joint", shared: bool = False,
                 mass_invariant: list[int] | None = None, potential="mlp", kinetic="mlp",
                 links: list[list[float]] | None = None, friction: str = "viscous+coulomb",
                 residual_force: dict | None = None) -> None:
        super().__init__(scene, hidden_dims=hidden_dims, activation=activation, film_mode=film_mode,
                         potential_film=potential_film, film_hidden=film_hidden, eps=eps, diag_shift=diag_shift,
                         learn_input_matrix=learn_input_matrix, dissipation=dissipation, shared=shared,
                         mass_invariant=mass_invariant, potential=potential, kinetic=kinetic, links=links,
                         friction=friction, residual_force=residual_force)


class DeLaN(StructuredLagrangian):
    """``delan`` (Deep Lagrangian Networks, Lutter et al.): the structured Lagrangian with the
    parameters concatenated to the inputs of its networks instead of FiLM. Options:
    ``StructuredLagrangian``."""

    variant = "delan"
    conditioning = "concat"

    def __init__(self, scene, hidden_dims=(128, 128), activation: str = "tanh", eps: float = 1e-4,
                 diag_shift: float = 1e-3, learn_input_matrix: bool = False, dissipation: str = "joint",
                 shared: bool = False, mass_invariant: list[int] | None = None, potential="mlp", kinetic="mlp",
                 links: list[list[float]] | None = None, friction: str = "viscous+coulomb",
                 residual_force: dict | None = None) -> None:
        super().__init__(scene, hidden_dims=hidden_dims, activation=activation, film_mode="neuron",
                         potential_film=True, film_hidden=16, eps=eps, diag_shift=diag_shift,
                         learn_input_matrix=learn_input_matrix, dissipation=dissipation, shared=shared,
                         mass_invariant=mass_invariant, potential=potential, kinetic=kinetic, links=links,
                         friction=friction, residual_force=residual_force)
