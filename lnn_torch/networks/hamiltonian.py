"""Hamiltonian neural network (Greydanus et al.), the baseline the LNN paper compares with."""

from __future__ import annotations

import torch

from ..errors import InputError
from ..mechanics import integrators
from .base import DynamicsModel
from .capabilities import FORCES, FRICTION
from .layers import TangentMLP


class HamiltonianNN(DynamicsModel):
    """Hamiltonian neural network (Greydanus et al.): an MLP ``H(q, m, theta)`` with the flow
    ``qdot = dH/dm``, ``mdot = -dH/dq`` fitted to the data.

    ``hnn_coordinates="canonical"``: ``m`` is the canonical momentum ``p = dL/dqd``, computed from the
    scene's momentum map (so the model needs the scene, not only its description).
    ``hnn_coordinates="velocity"``: ``m = qd``, i.e. the HNN is fed non-canonical ``(q, qd)``; it can then
    only represent dynamics whose accelerations do not depend on ``qd`` in a way a Hamiltonian flow
    in ``(q, qd)`` can express (it fails on the relativistic particle, the LNN paper's point).

    Normalisation keeps ``(q_norm, m_norm)`` canonical: ``m_norm = p * coord_scale / c`` with one
    momentum scale ``c`` and one time scale, so ``H_norm = (tau / c) H``.

    With generalised forces (inputs, friction) it is a port-Hamiltonian model: ``pdot = -dH/dq + Q``
    with ``Q = B tau + Q_diss(qdot)`` from ``LearnedForces`` at the model's velocity ``qdot = dH/dp``
    (``m_dot_norm = (tau c^-1 coord_scale) Q`` in its units); canonical coordinates only.
    """

    variant = "hnn"

    def __init__(self, scene, hidden_dims=(128, 128), activation: str = "tanh", hnn_coordinates: str = "canonical",
                 learn_input_matrix: bool = False, dissipation: str = "joint") -> None:
        super().__init__(scene, learn_input_matrix, dissipation)
        coordinates = hnn_coordinates
        if coordinates not in ("canonical", "velocity"):
            raise ValueError(f"hnn coordinates must be 'canonical' or 'velocity', got '{coordinates}'")
        if coordinates == "velocity" and self.scene.has_forces:
            raise InputError("an HNN in (q, qd) coordinates has no port for generalised forces (inputs, friction): "
                             "use hnn_coordinates='canonical'")
        self.coordinates = coordinates
        self._momentum_fn = None
        if coordinates == "canonical":
            self._momentum_fn = getattr(scene, "momentum", None)
            if self._momentum_fn is None:
                raise InputError("the canonical HNN needs the scene's momentum map p = dL/dqd: build it from a "
                                 "System (lnn_torch.systems), or use hnn_coordinates='velocity'")
        dof, P, F = self.scene.dof, self.scene.num_params, self.num_features
        self.net = TangentMLP(F + dof + P, list(hidden_dims), 1, activation, out_bias=False)

    # ------------------------------------------------------------------ coordinates
    def momentum_norm(self, q, qd, params):
        """The model's second coordinate ``m_norm`` of SI states ``(B, dof)``."""
        if self.coordinates == "velocity":
            return self.normalizer.state(q, qd)[1]
        return self.normalizer.momentum_to_norm(self._momentum_fn(q, qd, params))

    def _momentum_and_rate_norm(self, q, qd, qdd, params):
        """``m_norm`` and its time derivative ``d m_norm / d t_norm`` along the data (SI inputs)."""
        if self.coordinates == "velocity":
            return self.normalizer.state(q, qd)[1], self.normalizer.accel_to_norm(qdd)
        p, pdot = torch.func.jvp(lambda a, b: self._momentum_fn(a, b, params), (q, qd), (qd, qdd))
        tau = self.normalizer.time_scale.to(q.dtype)
        return self.normalizer.momentum_to_norm(p), self.normalizer.momentum_to_norm(pdot) * tau

    def fit_normalizer(self, stats: dict) -> None:
        super().fit_normalizer(stats)
        q, qd, qdd = (stats[k].double() for k in ("q", "qd", "qdd"))
        if self.coordinates == "canonical":
            if "params_points" not in stats:
                raise ValueError("the canonical HNN needs per-point parameters ('params_points') to fit its "
                                 "momentum scale")
            pp = stats["params_points"].double()
            p = self._momentum_fn(q, qd, pp) * self.normalizer.coord_scale.double()
            self.normalizer.momentum_scale.copy_(p.pow(2).mean().sqrt().clamp_min(1e-12))
        else:
            pp = None
        with torch.no_grad():
            m, mdot = self._momentum_and_rate_norm(q, qd, qdd, pp)
            qd_n = self.normalizer.state(q, qd)[1]
        rms = torch.cat([qd_n, mdot], -1).pow(2).mean(0).sqrt().clamp_min(1e-6)
        self.normalizer.vector_field_rms.copy_(rms)

    # ------------------------------------------------------------------ the flow
    def hamiltonian_and_grads(self, q_n, m_n, params_n):
        """``H (B,)``, ``dH/dq_norm (B, dof)``, ``dH/dm_norm (B, dof)`` (hand-written reverse pass)."""
        F = self.num_features
        phi, _, sin_cos = self._features(q_n, False)
        x = torch.cat([phi, m_n, params_n], -1)
        H, g = self.net.value_and_input_grad(x, None, num_grad_inputs=F + self.scene.dof)
        return H, self.features_vjp(q_n, g[:, :F], sin_cos), g[:, F:]

    def vector_field_norm(self, q_n, m_n, params_n, tau_norm=None):
        """``(dq_norm/dt_norm, dm_norm/dt_norm) = (dH/dm, -dH/dq + Q_m)`` with ``Q_m`` the generalised
        force in the model's momentum units (models with forces)."""
        _, dH_dq, dH_dm = self.hamiltonian_and_grads(q_n, m_n, params_n)
        dm = -dH_dq
        if self.forces is not None:
            norm = self.normalizer
            scale, t_scale = norm.coord_scale.to(q_n.dtype), norm.time_scale.to(q_n.dtype)
            tau = None if tau_norm is None else tau_norm * norm.input_rms.to(q_n.dtype)
            Q = self.forces.force(dH_dm * (scale / t_scale), params_n, tau)
            dm = dm + Q * (t_scale * scale / norm.momentum_scale.to(q_n.dtype))
        return dH_dm, dm

    def energy_norm(self, q_n, qd_n, params_n):
        raise NotImplementedError("the HNN's Hamiltonian is a function of (q, m): use hamiltonian_and_grads")

    def training_terms(self, q, qd, qdd, params, tau=None, energy: bool = False, chunks: int | None = None,
                       torque: bool = False) -> dict:
        """The flow ``(dq, dm)`` against the data's ``(qd, d m / dt)`` (normalised)."""
        if torque:
            raise InputError("the HNN has no inverse-dynamics (torque) loss")
        q_n, qd_n, p_n = self.normalize(q, qd, params)
        m_n, mdot_n = self._momentum_and_rate_norm(q, qd, qdd, params)
        tau_n = None if tau is None else tau / self.normalizer.input_rms.to(tau.dtype)
        dq, dm = self.vector_field_norm(q_n, m_n, p_n, tau_n)
        return {"pred": torch.cat([dq, dm], -1), "target": torch.cat([qd_n, mdot_n], -1),
                "rms": self.normalizer.vector_field_rms.to(q.dtype)}

    def acceleration_norm(self, q_n, qd_n, params_n, tau_norm=None):
        """Accelerations of the model's flow at ``(q, qd)``.

        ``velocity``: ``qdd = -dH/dq`` at ``m = qd``. ``canonical``: ``m`` from the momentum map,
        then ``qdd = d/dt (dH/dm) = H_mq qdot + H_mm mdot`` along the flow (a jvp).
        """
        if self.coordinates == "velocity":
            return self.vector_field_norm(q_n, qd_n, params_n)[1]
        q, qd = self.normalizer.state_to_phys(q_n, qd_n)
        params = self.normalizer.params_to_phys(params_n)
        m_n = self.normalizer.momentum_to_norm(self._momentum_fn(q, qd, params))
        flow = self.vector_field_norm(q_n, m_n, params_n, tau_norm)
        _, qdd_n = torch.func.jvp(lambda a, b: self.hamiltonian_and_grads(a, b, params_n)[2], (q_n, m_n), flow)
        return qdd_n

    def rollout(self, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4", tau=None):
        """Integrate the model's own flow in ``(q, m)`` (RK methods; inputs ``tau (B, num_steps, n_u)``
        held over each step); ``qd`` of the result is the model's velocity ``dH/dp`` (canonical) or
        the state ``m = qd`` (velocity coordinates)."""
        num_steps = self.check_rollout_inputs(q0, num_steps, tau)
        self.check_inputs(q0, qd0, params, None if tau is None else tau[:, 0])
        dof = self.scene.dof
        q_n, _, p_n = self.normalize(q0, qd0, params)
        m_n = self.momentum_norm(q0, qd0, params)

        dtype = self.dtype

        def field(y, pn, tau_k=None):  # the state keeps the input dtype; the network runs in its own
            y, pn = y.to(dtype), pn.to(dtype)
            tau_n = None if tau_k is None else self.tau_norm(tau_k)
            return torch.cat(self.vector_field_norm(y[:, :dof], y[:, dof:], pn, tau_n), -1).to(q0.dtype)

        t_scale = float(self.normalizer.time_scale)
        y = integrators.rollout_first_order(field, torch.cat([q_n, m_n], -1), p_n, dt / t_scale, num_steps, method,
                                            tau=tau)
        qs_n, ms_n = y[..., :dof], y[..., dof:]  # (B, T, dof)
        if self.coordinates == "canonical":
            B, T = qs_n.shape[:2]
            flat = lambda x: x.flatten(0, 1)  # noqa: E731
            qds_n = self.vector_field_norm(flat(qs_n).to(dtype), flat(ms_n).to(dtype),
                                           flat(p_n[:, None].expand(-1, T, -1)).to(dtype))[0]
            qds_n = qds_n.reshape(B, T, dof).to(q0.dtype)
        else:
            qds_n = ms_n
        return self.normalizer.state_to_phys(qs_n, qds_n)

    # learned forces and friction through its port; no energy of (q, qd) (its H is a function of (q, p):
    # conserved by construction, no T/V split), no mass matrix, no static friction (its own flow: the
    # holding torques are not solved for)
    provides = frozenset({FRICTION, FORCES})
