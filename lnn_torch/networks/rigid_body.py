"""The one SI rigid-body face of a model, as Pinocchio's ``crba`` / ``nonLinearEffects`` /
``computeGeneralizedGravity`` / ``rnea`` / ``aba``: what control (``lnn_torch.control.plant_of``) and
export (``lnn_torch.export.programs``) take from a model, instead of deriving it again.

THE CONVENTION (stated here once): a model with a mass matrix (``MASS_MATRIX``: the structured
Lagrangians) is, in SI units, the rigid mechanical system

    M(q) qdd + n(q, qd) = B tau + Q_f(q, qd) + Q_r(q, qd)

* ``mass_matrix(q, params)``: ``M (B, dof, dof)``, symmetric positive definite (``crba``);
* ``bias(q, qd, params)``: ``n``, the learned Lagrangian's Coriolis, centrifugal and gravity forces
  (``nonLinearEffects``): NO friction and NO inputs, ``n = -M a_0`` with ``a_0`` the accelerations
  under no generalised force at all;
* ``gravity(q, params)``: ``g = n(q, 0) = dV/dq`` (``computeGeneralizedGravity``);
* ``friction(q, qd, params)``: ``Q_f``, the learned dissipative generalised force (``FORCES``): joint
  friction at the joint rates ``D qd`` mapped back through the joint map, ``-D^T f(D qd)``, and a
  learned Rayleigh damping ``-R qd`` where the model has one; ``qd . Q_f <= 0``;
* ``residual_force(q, qd, params)``: ``Q_r``, the learned force residual (the structured models'
  option ``residual_force``, ``lnn_torch.networks.residual_force``; zero without it): a generalised force
  of the state for what the model's physics cannot write, NOT passive (so not in ``Q_f``, whose
  ``qd . Q_f <= 0`` stays true); its power is counted with the model's other forces;
* ``inverse(q, qd, qdd, params)``: the inputs ``tau (B, n_u)`` with ``B tau = M qdd + n -
  Q_f - Q_r`` (least squares through ``B`` where there are fewer inputs than coordinates;
  ``INVERSE_DYNAMICS``; ``input_force`` gives ``B tau`` itself);
* ``forward(q, qd, params, tau)``: the accelerations ``M^-1 (B tau + Q_f + Q_r - n)``: the
  model's ``acceleration`` (``aba``).

Static friction (``dissipation: joint+stiction``) is not a force of the state: its holding torques are
what holding a slow joint at rest takes against everything else acting at that instant
(``lnn_torch.mechanics.forces.holding_torque``). They are in ``forward`` (the model's accelerations
and rollouts) and in none of ``n``, ``Q_f`` or the inverse dynamics, which gives the inputs without
holding (as the training's torque loss compares them).

Units: where the scene has inputs, its torques fix the learned Lagrangian's scale: ``M`` in J s^2 per
unit^2 (kg m^2 between angles), forces in N m (N for a linear coordinate), energy in J. Without
inputs the scale is free (``cL`` moves alike): ``M``, ``n``, ``g``, ``Q_f`` and the energy are in the
model's own units, up to one positive factor per system (``lnn_torch.control.calibrate_torque_scale``
estimates it from a recording with known torques).

Shapes: ``q, qd, qdd (B, dof)``, ``params (B, P)``, ``tau (B, n_u)``; results in ``q``'s dtype (the
networks run in their own). The methods check the capability and, with ``check`` where they take it,
the inputs; without checks they read no Python number from a tensor, so ``torch.export`` traces them
as they are (``lnn_torch.export.programs`` does).
"""

from __future__ import annotations

import torch

from .capabilities import ENERGY, FORCES, FRICTION, INVERSE_DYNAMICS, MASS_MATRIX


class RigidBodyFace:
    """The SI face of ``DynamicsModel`` (a mixin: the model's capabilities, normaliser and forces are
    its host's). A model with ``MASS_MATRIX`` gives ``mass_matrix_norm``, ``bias_norm`` and
    ``gravity_norm``; with ``INVERSE_DYNAMICS``, ``inverse_dynamics_norm``."""

    # ------------------------------------------------------------------ what a structured model gives
    def mass_matrix_norm(self, q_norm, params_norm) -> torch.Tensor:
        """``M (B, dof, dof)`` in normalised units."""
        raise NotImplementedError(f"variant '{self.variant}' has no mass matrix")

    def bias_norm(self, q_norm, qd_norm, params_norm) -> torch.Tensor:
        """``n (B, dof)`` in normalised Euler-Lagrange units (no friction, no inputs)."""
        raise NotImplementedError(f"variant '{self.variant}' has no bias force")

    def gravity_norm(self, q_norm, params_norm) -> torch.Tensor:
        """``g = n(q, 0) = dV/dq (B, dof)`` in normalised Euler-Lagrange units."""
        raise NotImplementedError(f"variant '{self.variant}' has no gravity force")

    def inverse_dynamics_norm(self, q_norm, qd_norm, qdd_norm, params_norm, chunks: int | None = None):
        """The input force ``B tau = M qdd + n - Q_f`` in SI ``(B, dof)`` at a normalised state."""
        raise NotImplementedError(f"variant '{self.variant}' has no inverse dynamics")

    # ------------------------------------------------------------------ units
    def _si_inputs(self, *tensors):
        """The tensors in the model's dtype (the networks run in it; the SI accessors return the
        dtype they were given)."""
        return tuple(x.to(self.dtype) for x in tensors)

    def _joules(self, value: torch.Tensor) -> torch.Tensor:
        """An energy-like quantity of the normalised Lagrangian in J where the scene's inputs fix the
        Lagrangian's scale (``L_SI = L_norm / force_scale``); without inputs the scale is free (``cL``
        has the same motion) and it stays in the model's own units. A tensor operation (traceable)."""
        if not self.scene.num_inputs:
            return value
        return value / self.normalizer.force_scale.to(value.dtype)

    def _force_si(self, force_norm: torch.Tensor) -> torch.Tensor:
        """A normalised generalised force ``(B, dof)`` in SI (``Normalizer.force_to_phys``) where the
        inputs fix the scale, else in the model's own units (the rule of ``_joules``)."""
        if self.scene.num_inputs:
            return self.normalizer.force_to_phys(force_norm)
        return force_norm / self.normalizer.coord_scale.to(force_norm.dtype)

    # ------------------------------------------------------------------ the face
    def mass_matrix(self, q: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """``M (B, dof, dof)`` of ``energy``'s kinetic energy in SI velocities (``D M_norm D``,
        ``D = diag(time_scale / coord_scale)``; units: the module docstring). ``MASS_MATRIX``."""
        self._require(MASS_MATRIX)
        q_n, _, p_n = self.normalize(*self._si_inputs(q, q, params))
        M_n = self.mass_matrix_norm(q_n, p_n).to(q.dtype)
        norm = self.normalizer
        D = norm.time_scale.to(q.dtype) / norm.coord_scale.to(q.dtype)
        return self._joules(D[:, None] * M_n * D[None, :])

    def bias(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """``n (B, dof)``: Coriolis, centrifugal and gravity forces, no friction, no inputs (the module
        docstring's convention). ``MASS_MATRIX``."""
        self._require(MASS_MATRIX)
        q_n, qd_n, p_n = self.normalize(*self._si_inputs(q, qd, params))
        return self._force_si(self.bias_norm(q_n, qd_n, p_n).to(q.dtype))

    def gravity(self, q: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """``g = n(q, 0) (B, dof)``: the forces that holding the system still at ``q`` takes (``dV/dq``).
        ``MASS_MATRIX``."""
        self._require(MASS_MATRIX)
        q_n, _, p_n = self.normalize(*self._si_inputs(q, q, params))
        return self._force_si(self.gravity_norm(q_n, p_n).to(q.dtype))

    def friction(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """``Q_f (B, dof)``: the learned dissipative generalised force (joint friction through the joint
        map, Rayleigh damping; zero for a model whose forces are inputs alone). ``FORCES``."""
        self._require(FORCES)
        q_n, qd_n, p_n = self.normalize(*self._si_inputs(q, qd, params))
        phi = self.features(q_n)[0] if self.forces.rayleigh is not None else None
        return self.forces.dissipative_force_at(qd_n, p_n, phi).to(q.dtype)

    def residual_force(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """``Q_r (B, dof)``: the learned force residual (N m; zeros for a model without one; not passive:
        the module docstring). ``FORCES``."""
        self._require(FORCES)
        q_n, qd_n, p_n = self.normalize(*self._si_inputs(q, qd, params))
        if self.forces.residual is None:
            return torch.zeros_like(qd)
        return self.forces.residual_force_at(qd_n, p_n, self.features(q_n)[0]).to(q.dtype)

    def input_force(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor,
                       params: torch.Tensor) -> torch.Tensor:
        """``B tau = M qdd + n - Q_f - Q_r (B, dof)``: the generalised force of the inputs that makes the
        model accelerate by ``qdd`` (SI). ``INVERSE_DYNAMICS``."""
        return self._input_force(q, qd, qdd, params).to(q.dtype)

    def _input_force(self, q, qd, qdd, params) -> torch.Tensor:
        self._require(INVERSE_DYNAMICS)
        q_n, qd_n, p_n = self.normalize(*self._si_inputs(q, qd, params))
        return self.inverse_dynamics_norm(q_n, qd_n, self.normalizer.accel_to_norm(qdd.to(self.dtype)), p_n)

    def inverse(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor, params: torch.Tensor,
                            check: bool = True) -> torch.Tensor:
        """The inputs ``tau (B, n_u)`` in N m that make the model accelerate by ``qdd`` (SI): ``B tau = M
        qdd + n - Q_f - Q_r`` solved through the input matrix (least squares where fewer inputs than
        coordinates; static friction's holding torques excluded). ``check``: the shapes, NaN and
        parameter signs of the inputs first. ``INVERSE_DYNAMICS``."""
        if check:
            self.check_inputs(q, qd, params, inputs=False)
        force = self._input_force(q, qd, qdd, params)  # (first: a scene without inputs is said, not an AttributeError)
        return self.forces.solve_inputs(force).to(q.dtype)

    def forward(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor,
                            tau: torch.Tensor | None = None, check: bool = True) -> torch.Tensor:
        """The accelerations ``(B, dof)`` under the inputs ``tau (B, n_u)`` (None for a scene without),
        static friction included: the model's ``acceleration``."""
        return self.acceleration(q, qd, params, tau, check=check)

    # ------------------------------------------------------------------ energy and friction coefficients
    def energy(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """The model's own energy ``H = T + V`` at SI states ``(B, dof), (B, dof), (B, P) -> (B,)`` (``q``'s
        dtype): in J for a scene with inputs, else in the model's units (see ``_joules``). ``ENERGY``."""
        self._require(ENERGY)
        q_n, qd_n, p_n = self.normalize(*self._si_inputs(q, qd, params))
        return self._joules(self.energy_norm(q_n, qd_n, p_n)[0].to(q.dtype))

    def friction_torque(self, rates: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """The learned joint friction torque (N m) at joint rates ``rates (..., n_j)`` (the scene's
        ``joint_map @ qd``) for parameters ``params (..., P)``; ``rates``' dtype. ``FRICTION``."""
        self._require(FRICTION)
        r, p = self._si_inputs(rates, params)
        return self.forces.friction_torque(r, self.normalizer.params(p)).to(rates.dtype)

    def friction_coefficients(self, params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The learned viscous (N m s/rad) and Coulomb (N m) coefficients per joint ``(B, n_j)`` each,
        in ``params``' dtype. ``FRICTION``."""
        self._require(FRICTION)
        b, c = self.forces.coefficients(self.normalizer.params(params.to(self.dtype)))
        return b.to(params.dtype), c.to(params.dtype)
