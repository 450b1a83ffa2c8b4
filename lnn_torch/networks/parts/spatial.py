"""The mass matrix and gravity of a spatial serial arm read from its robot description (grey box).

Kinetic part ``spatial``: ``M(q) = sum_i tr(dT_i J_i dT_i^T) + diag(armature)`` (``lnn_torch.robots.kinematics``:
the poses ``T_i`` of the description's moving bodies, each body's pseudo-inertia ``J_i``), given to the
structured solve as the factor ``F`` with its closed-form derivative; potential part ``spatial``:
gravity on the same masses. The inertial parameters start at the description's values and are learned
(``learn: false`` keeps them: the description alone), always physically consistent: each ``J_i = U_i
U_i^T`` with ``U_i`` upper triangular, its diagonal ``exp`` of a learned value (the log-Cholesky
parameterisation of the pseudo-inertia: positive mass, inertia positive definite and within the
triangle inequality, for every value of the raw parameters); the armature (rotor inertia) is ``exp`` of
a learned value, starting at the description's (at least ``ARMATURE_START`` kg m^2: a description without
rotors, armature 0, learns it from there). With ``learn: false`` every value is the description's exactly
(armature 0 included).

The scene's parameters are the payload at the flange, ``(mass, cx, cy, cz)`` (kg, m, flange frame) or
with its inertia about its centre of mass ``(Ixx, Iyy, Izz, Ixy, Ixz, Iyz)`` (kg m^2): the part adds the
payload's pseudo-inertia to the last body's, so the model is conditioned on the payload exactly (one
model for every payload). The parameters are SI; the part's output is scaled to the model's normalised
units (``M_norm = force_scale / time_scale^2 M``, ``V_norm = force_scale V``).
"""

from __future__ import annotations

import torch
from torch import nn

from ...errors import InputError
from ...robots import kinematics as K
from ...robots.description import ArmDescription
from .base import BuildContext, KineticPart, PartInputs, PotentialPart, PotentialTerm

ARMATURE_START = 1e-4  # kg m^2: where a learned armature starts if the description's is smaller (or 0)


def _load_chain(description) -> K.SerialChain:
    from ...robots.mujoco_arm import load_description

    return K.read_chain(load_description(description))


class SpatialChain(KineticPart):
    """``spatial``: the mass-matrix factor of the arm of a robot description (module docstring).

    Options:
        description: a shipped description (``franka_panda``), an MJCF or URDF path, or the description
            as the robot it is (``lnn_torch.robots.description.ArmDescription``: ``{source, flange, remove,
            tool, armature, damping}``); None: the scene's own.
        learn: learn the inertial parameters and armature (True) or keep the description's (False).
        prior: the weight of a prior towards the description (learned parts only): the training loss adds
            ``prior`` times the sum over links of the LogDet divergence of each learned pseudo-inertia from
            the description's, ``tr(J0^-1 J) - log det(J0^-1 J) - 4`` (zero at the description, invariant
            to the units; the geometry-aware pull where the data cannot tell a link's inertia). 0: none.
    """

    name = "spatial"
    needs_angles = True

    def __init__(self, ctx: BuildContext, description=None, learn: bool = True, prior: float = 0.0) -> None:
        super().__init__()
        description = description or ctx.robot_description
        if description is None:
            raise InputError("kinetic part 'spatial' needs a robot description: kinetic: {spatial: {description: "
                             "franka_panda}} (or a scene that has one, e.g. robot_arm)")
        self.description = ArmDescription.of(description)
        chain = _load_chain(self.description)
        if chain.dof != ctx.dof:
            raise InputError(f"robot description {description} has {chain.dof} joints; scene '{ctx.scene_name}' has "
                             f"{ctx.dof} coordinates")
        if ctx.num_params not in (0, 4, 10):
            raise InputError(f"kinetic part 'spatial' reads the scene's parameters as a payload (mass, cx, cy, cz"
                             f"[, six inertias]); scene '{ctx.scene_name}' has {ctx.num_params}")
        if ctx.num_params and chain.flange is None:
            raise InputError(f"robot description {description} has no body 'payload' for the scene's payload")
        self.num_links, self.dof, self.payload = chain.dof, chain.dof, bool(ctx.num_params)
        self.takes_params_exactly = self.payload  # the payload is a rigid body on the last link, at any value
        self.learn = bool(learn)
        self.prior = float(prior)
        if not (self.prior >= 0):
            raise InputError(f"kinetic part 'spatial': prior must be >= 0, got {prior!r}")
        # the description's geometry, exact: float64 constants (not buffers, which a float32 model would
        # round), cast once per dtype and device
        self._constants = {"X": chain.X, "axis": chain.axis, "anchor": chain.anchor, "qpos0": chain.qpos0,
                           "flange": chain.flange if chain.flange is not None else torch.eye(4, dtype=torch.float64),
                           "gravity": chain.gravity, "nominal_J": chain.J, "nominal_U": K.reverse_cholesky(chain.J),
                           "damping": chain.damping}
        self._cast = {}
        # in the default dtype (a float64 test builds the description's values exactly)
        raw = K.log_cholesky(chain.J).to(torch.get_default_dtype())
        if self.learn:
            self.raw = nn.Parameter(raw)  # (n, 10): log of U's diagonal, then its six upper entries
            self.log_armature = nn.Parameter(chain.armature.clamp_min(ARMATURE_START).log().to(raw.dtype))
        else:  # the description alone, exactly: nothing learned, nothing to save
            self._fixed = {"raw": raw.double(), "armature": chain.armature.clone()}
        self.joint_names = chain.joint_names
        self.num_columns = 6 * self.num_links + self.dof

    def const(self, name: str, like: torch.Tensor) -> torch.Tensor:
        """A constant of the description in ``like``'s dtype and device."""
        key = (name, like.dtype, like.device)
        if key not in self._cast:
            self._cast[key] = self._constants[name].to(dtype=like.dtype, device=like.device)
        return self._cast[key]

    def _raw(self, name: str, dtype) -> torch.Tensor:
        if self.learn:
            return getattr(self, name).to(dtype)
        return self._fixed[name].to(dtype=dtype, device=self.normalizer.time_scale.device)

    def description_damping(self) -> torch.Tensor:
        """The description's viscous joint damping ``(n,)`` in N m s/rad (where a model's friction starts)."""
        return self._constants["damping"].clone()

    def coefficient_parameters(self):
        return [self.raw, self.log_armature] if self.learn else []

    def regularization(self) -> torch.Tensor | None:
        """``prior`` times the LogDet divergence of the learned links from the anchor (option ``prior``):
        the description's, or the start ``start_at`` set with ``anchor=True``."""
        if not (self.learn and self.prior):
            return None
        U = self.link_U(self.raw.dtype)
        U0 = self.const("anchor_U" if "anchor_U" in self._constants else "nominal_U", U)  # J0 = U0 U0^T
        # J0^-1 J = U0^-T U0^-1 U U^T: with W = U0^-1 U, tr(J0^-1 J) = |W|^2 and log det(J0^-1 J) = 2 log |det W|
        W = torch.linalg.solve_triangular(U0, U, upper=True)
        logdet = 2 * torch.log(torch.diagonal(W, dim1=-2, dim2=-1).abs()).sum(-1)
        return self.prior * (W.pow(2).sum((-2, -1)) - logdet - 4).sum()

    @torch.no_grad()
    def start_at(self, J: torch.Tensor, armature: torch.Tensor, anchor: bool = True) -> None:
        """Start the learned links at the pseudo-inertias ``J (n, 4, 4)`` (positive definite: a physically
        consistent fit's) and the armature ``(n,)`` kg m^2 (at least 1e-8: a learned value is ``exp`` of
        one); ``anchor``: the prior then pulls towards this start instead of the description
        (``anchor_J`` reads it back, e.g. to keep it in a checkpoint)."""
        if not self.learn:
            raise InputError("kinetic part 'spatial' with learn: false keeps the description: nothing to start")
        self.raw.copy_(K.log_cholesky(torch.as_tensor(J, dtype=torch.float64)).to(self.raw.dtype))
        self.log_armature.copy_(torch.as_tensor(armature, dtype=torch.float64).clamp_min(1e-8).log()
                                .to(self.log_armature.dtype))
        if anchor:
            self.anchor_at(J)

    def anchor_at(self, J: torch.Tensor | None) -> None:
        """The pseudo-inertias ``J (n, 4, 4)`` the prior pulls towards (None: the description's)."""
        self._constants.pop("anchor_U", None)
        self._cast = {}
        if J is not None:
            self._constants["anchor_U"] = K.reverse_cholesky(torch.as_tensor(J, dtype=torch.float64))

    def anchor_J(self) -> torch.Tensor | None:
        """The start the prior pulls towards (``start_at``), None where it pulls towards the description."""
        U = self._constants.get("anchor_U")
        return None if U is None else U @ U.mT

    # ------------------------------------------------------------------ the inertial parameters
    def link_U(self, dtype) -> torch.Tensor:
        """``U (n, 4, 4)``: each link's factor ``J_i = U_i U_i^T``."""
        return K.log_cholesky_factor(self._raw("raw", dtype))

    def link_J(self, dtype=torch.float64) -> torch.Tensor:
        U = self.link_U(dtype)
        return U @ U.mT

    def armature(self, dtype=torch.float64) -> torch.Tensor:
        """The joints' armature ``(n,)``, kg m^2."""
        if self.learn:
            return self.log_armature.to(dtype).exp()
        return self._fixed["armature"].to(dtype=dtype, device=self.normalizer.time_scale.device)

    def payload_si(self, params_norm: torch.Tensor) -> torch.Tensor | None:
        """The payload in SI ``(B, P)`` from the normalised parameters (None without one)."""
        if not self.payload:
            return None
        return self.normalizer.params_to_phys(params_norm)

    def scales(self, dtype) -> tuple[torch.Tensor, torch.Tensor]:
        """``(sqrt(force_scale) / time_scale, force_scale)``: SI factor and potential to normalised units."""
        norm = self.normalizer
        force = norm.force_scale.to(dtype) if hasattr(norm, "force_scale") else torch.ones((), dtype=dtype)
        return force.sqrt() / norm.time_scale.to(dtype), force

    def body_inertia(self, params_norm: torch.Tensor, dtype) -> tuple[torch.Tensor, torch.Tensor]:
        """``(J, L)``: the links' pseudo-inertias ``(B or 1, n, 4, 4)``, the payload's added to the last
        link's, and the factors of their spatial inertias ``(B or 1, n, 6, 6)`` (``kinematics.inertia_factor``:
        the links' once, the last link's per row where a payload is added)."""
        U = self.link_U(dtype)[None]
        J = U @ U.mT
        L = K.inertia_factor(J)
        payload = self.payload_si(params_norm)
        if payload is None:
            return J, L
        last = J[:, -1] + K.payload_at_flange(self.const("flange", payload.to(dtype)), payload.to(dtype))  # (B, 4, 4)
        B = payload.shape[0]
        J = torch.cat([J.expand(B, -1, -1, -1)[:, :-1], last[:, None]], 1)
        L = torch.cat([L.expand(B, -1, -1, -1)[:, :-1], K.inertia_factor(last)[:, None]], 1)
        return J, L

    def _kinematic_chain(self, like: torch.Tensor):
        c = {k: self.const(k, like) for k in ("X", "axis", "anchor", "qpos0")}
        return K.SerialChain(c["X"], c["axis"], c["anchor"], c["qpos0"], None, None, None, None, None, self.joint_names)

    def geometry(self, q_norm: torch.Tensor, params_norm: torch.Tensor):
        """``(T, S, J, L)``: poses and twists (``kinematics.poses_and_twists``) and the bodies' inertia."""
        T, S = K.poses_and_twists(self._kinematic_chain(q_norm), q_norm)
        J, L = self.body_inertia(params_norm, q_norm.dtype)
        return T, S, J, L

    def _geometry(self, inputs: PartInputs):
        return inputs.shared(self, lambda: self.geometry(inputs.q_norm, inputs.params_norm))

    # ------------------------------------------------------------------ the factor
    def factor(self, inputs: PartInputs, cond):
        T, S, _, L = self._geometry(inputs)
        dtype, B = inputs.q_norm.dtype, inputs.q_norm.shape[0]
        F, dF = K.factor(T, S, L, inputs.tangents)
        root_a = torch.diag_embed(self.armature(dtype).sqrt()).expand(B, -1, -1)
        scale, _ = self.scales(dtype)
        F = torch.cat([F, root_a], -1) * scale
        if dF is not None:
            dF = torch.cat([dF, dF.new_zeros(self.dof, B, self.dof, self.dof)], -1) * scale
        return F, dF

    def reference_factor(self, q_norm, params_norm, phi):
        """A factor written out from the bodies' centre-of-mass velocities and angular velocities: ``F =
        [sqrt(m_i) Jv_i^T | Jw_i^T R_i L_i | sqrt(armature)]`` (``Jv_i``, ``Jw_i`` by autograd of the
        poses, ``L_i L_i^T`` the inertia about the centre of mass), in normalised units."""
        dtype = q_norm.dtype
        J, _ = self.body_inertia(params_norm, dtype)
        B = q_norm.shape[0]
        mass, com, inertia = K.mass_properties(J.expand(B, -1, -1, -1))
        L = torch.linalg.cholesky(inertia)
        chain = self._kinematic_chain(q_norm)

        def pose(q1):
            return K.poses_and_twists(chain, q1[None])[0][0]  # (n, 4, 4)

        cols = []
        for b in range(B):
            Tb = pose(q_norm[b])
            dT = torch.func.jacfwd(pose)(q_norm[b])  # (n, 4, 4, dof)
            for i in range(self.num_links):
                c_h = torch.cat([com[b, i], com[b, i].new_ones(1)])
                Jv = torch.einsum("xyk,y->xk", dT[i, :3], c_h)  # (3, dof)
                Jw = torch.stack([K.vee(dT[i, :3, :3, k] @ Tb[i, :3, :3].T) for k in range(self.dof)], -1)
                cols.append((b, torch.cat([mass[b, i].sqrt() * Jv.T, Jw.T @ Tb[i, :3, :3] @ L[b, i]], -1)))
        F = torch.stack([torch.cat([c for bb, c in cols if bb == b], -1) for b in range(B)])
        F = torch.cat([F, torch.diag_embed(self.armature(dtype).sqrt()).expand(B, -1, -1)], -1)
        return F * self.scales(dtype)[0]

    def gravity(self, inputs: PartInputs, grad: bool):
        T, S, J, _ = self._geometry(inputs)
        V, dV = K.gravity_potential(T, S, J, self.const("gravity", T), grad)
        _, force = self.scales(T.dtype)
        return V * force, None if dV is None else dV * force

    # ------------------------------------------------------------------ report
    def si_report(self, scales=None, params_norm=None) -> dict:
        """The learned links in SI (detached): ``mass (n)`` kg, centre of mass ``com (n, 3)`` m and inertia
        about it ``inertia (n, 3, 3)`` kg m^2 in each body's frame (welded bodies folded in), ``armature
        (n)`` kg m^2; and ``pseudo_inertia (n, 4, 4)``."""
        with torch.no_grad():
            J = self.link_J(torch.float64)
            mass, com, inertia = K.mass_properties(J)
            return {"mass": mass, "com": com, "inertia": inertia, "armature": self.armature(torch.float64),
                    "pseudo_inertia": J}


class SpatialGravity(PotentialPart):
    """``spatial``: gravity (the description's vector; MuJoCo's default 9.81 m/s^2 down world z) on the masses
    of the kinetic part ``spatial`` and the payload; no parameter of its own."""

    name = "spatial"
    needs_angles = True

    def __init__(self, ctx: BuildContext) -> None:
        super().__init__()
        chain = ctx.kinetic_parts.get("spatial")
        if chain is None:
            raise InputError("potential part 'spatial' is the gravity of the arm's masses: it needs the kinetic part "
                             "'spatial'")
        self._chain = (chain,)

    @property
    def chain(self) -> SpatialChain:
        return self._chain[0]

    def potential(self, inputs: PartInputs, cond, grad: bool) -> PotentialTerm:
        V, dV = self.chain.gravity(inputs, grad)
        return PotentialTerm(V, dV_dq=dV)

    def reference_potential(self, q_norm, params_norm, phi, gravity):
        """``V = -sum_i m_i g . c_i`` from the bodies' centres of mass (``T_i`` applied to each)."""
        chain = self.chain
        dtype = q_norm.dtype
        T, _ = K.poses_and_twists(chain._kinematic_chain(q_norm), q_norm)
        J, _ = chain.body_inertia(params_norm, dtype)
        mass, com, _ = K.mass_properties(J.expand(q_norm.shape[0], -1, -1, -1))
        com = torch.cat([com, mass.new_ones(*mass.shape, 1)], -1)
        world = (T @ com[..., None])[..., :3, 0]
        return -(mass * (world @ chain.const("gravity", q_norm))).sum(-1) * chain.scales(dtype)[1]
