"""Controllers on a ``Plant`` (``lnn_torch.control.plant``): the same code runs on a learned model's
plant and on the truth's. Each controller is a callable ``u = controller(t, q, qd)`` over a batch of
states (float64, SI), built for fixed conditioning parameters ``params (B, P)``.

* ``lqr_gain``: infinite-horizon LQR about an equilibrium, continuous or discrete at a control period
  (zero-order hold), on the plant's exact linearisation;
* ``LQR``: ``u = u_eq - K (x - x_eq)`` with angle errors wrapped to (-pi, pi];
* ``ComputedTorque``: model feed-forward plus PD on a reference trajectory,
  ``u = B^+ (M (qdd_ref + Kp e + Kd e') + n - Q_f)``.
"""

from __future__ import annotations

import copy

import numpy as np
import torch

from ..errors import InputError
from ..mechanics.angles import wrap_angles as wrap
from ..mechanics.integrators import held, semi_implicit_euler_step
from .plant import Plant


def equilibrium_input(plant: Plant, q_eq: torch.Tensor, params: torch.Tensor | None = None,
                      tol: float = 0.02) -> torch.Tensor:
    """The constant input that holds ``q_eq (B, n)`` at rest (least squares); ``InputError`` where the
    inputs cannot: the unbalanced force, along directions no input acts on, exceeds ``tol`` times the
    plant's gravity scale (its gravity force with every angle a quarter turn from ``q_eq``). The
    tolerance admits a learned model's upright, balanced to a fraction of a percent."""
    zero = torch.zeros_like(q_eq)
    u, res = plant.solve_inputs(q_eq, zero, zero, params)
    turned = q_eq + (torch.pi / 2) * torch.tensor(plant.angle_mask, dtype=q_eq.dtype)
    scale = plant.gravity(turned, params).norm(dim=-1).clamp_min(1e-12)
    bad = res > tol * scale
    if bad.any():
        i = int(bad.nonzero()[0])
        raise InputError(f"{plant.name}: the inputs cannot hold q = {q_eq[i].tolist()} at rest (unbalanced force "
                         f"{float(res[i]):.3g}, {100 * float(res[i] / scale[i]):.2g} % of the gravity scale, along "
                         "directions no input acts on): not an equilibrium of this actuation")
    return u


def lqr_gain(A: torch.Tensor, B: torch.Tensor, Q, R, dt: float | None = None) -> torch.Tensor:
    """LQR gains ``K (batch, m, 2n)`` for ``x' = A x + B u`` (batched ``(batch, 2n, 2n)``, ``(batch, 2n, m)``)
    minimising ``int x^T Q x + u^T R u``; with ``dt``, the discrete-time problem of the zero-order-hold
    discretisation at that control period (what a digital controller at ``1/dt`` Hz runs).
    Raises ``InputError`` where no stabilising solution exists (an uncontrollable linearisation)."""
    import scipy.linalg

    A_np, B_np = A.detach().double().cpu().numpy(), B.detach().double().cpu().numpy()
    n2, m = A_np.shape[-1], B_np.shape[-1]
    Q, R = _weights(Q, n2, "Q"), _weights(R, m, "R")
    gains = []
    for a, b in zip(A_np, B_np, strict=True):
        try:
            if dt is None:
                P = scipy.linalg.solve_continuous_are(a, b, Q, R)
                K = np.linalg.solve(R, b.T @ P)
            else:
                block = np.zeros((n2 + m, n2 + m))
                block[:n2, :n2], block[:n2, n2:] = a, b
                E = scipy.linalg.expm(block * dt)
                Ad, Bd = E[:n2, :n2], E[:n2, n2:]
                P = scipy.linalg.solve_discrete_are(Ad, Bd, Q, R)
                K = np.linalg.solve(R + Bd.T @ P @ Bd, Bd.T @ P @ Ad)
        except (np.linalg.LinAlgError, ValueError) as err:
            raise InputError(f"LQR: no stabilising solution for this linearisation ({err}); is the equilibrium "
                             "controllable with these inputs?") from None
        gains.append(K)
    return torch.tensor(np.stack(gains), dtype=torch.float64)


def _weights(W, k: int, name: str) -> np.ndarray:
    """A weight matrix ``(k, k)`` from a scalar (times the identity), a diagonal or a matrix: finite, symmetric,
    positive semi-definite (``Q``) or positive definite (``R``), else refused naming it."""
    try:
        W = np.asarray(W, dtype=np.float64)
    except (ValueError, TypeError):
        raise InputError(f"LQR: {name} must be a scalar, {k} diagonal entries or a ({k}, {k}) matrix of numbers, "
                         f"got {W!r}") from None
    W = W * np.eye(k) if W.ndim == 0 else (np.diag(W) if W.ndim == 1 else W)
    if W.shape != (k, k):
        raise InputError(f"LQR: {name} must be a scalar, {k} diagonal entries or a ({k}, {k}) matrix, got shape "
                         f"{W.shape}")
    if not np.isfinite(W).all() or not np.allclose(W, W.T, rtol=1e-9, atol=0.0):
        raise InputError(f"LQR: {name} must be finite and symmetric")
    low = float(np.linalg.eigvalsh(W).min())
    scale = float(np.abs(W).max()) or 1.0
    if name == "R" and not low > 1e-12 * scale:
        raise InputError(f"LQR: R must be positive definite (its smallest eigenvalue is {low:.3g})")
    if name == "Q" and low < -1e-12 * scale:
        raise InputError(f"LQR: Q must be positive semi-definite (its smallest eigenvalue is {low:.3g})")
    return W


class LQR:
    """``u = u_eq - K (x - x_eq)`` about the equilibrium ``(q_eq, 0, u_eq)`` of ``plant``, one gain per
    parameter set: designed on the linearisation of the plant's rigid body (``lqr_gain``; friction, not
    differentiable at rest, acts on the loop as a disturbance)."""

    def __init__(self, plant: Plant, q_eq: torch.Tensor, params: torch.Tensor | None = None, Q=1.0, R=1.0,
                 dt: float | None = None) -> None:
        self.q_eq, self.angle_mask = q_eq, plant.angle_mask
        self.u_eq = equilibrium_input(plant, q_eq, params)
        # the rigid body's linearisation: friction has no useful derivative at rest (Plant.linearize)
        A, B = plant.linearize(q_eq, torch.zeros_like(q_eq), self.u_eq, params, friction=False)
        self.K = lqr_gain(A, B, Q, R, dt)

    def repeat_interleave(self, k: int) -> LQR:
        """The same controller for ``k`` episodes of each design (one row per episode)."""
        out = copy.copy(self)
        out.q_eq, out.u_eq, out.K = (x.repeat_interleave(k, 0) for x in (self.q_eq, self.u_eq, self.K))
        return out

    def __call__(self, t, q, qd) -> torch.Tensor:
        x = torch.cat([wrap(q - self.q_eq, self.angle_mask), qd], -1)
        return self.u_eq - torch.einsum("bmj,bj->bm", self.K, x)


class ComputedTorque:
    """Model feed-forward + PD on a reference ``ref(t) -> (q, qd, qdd)`` (each ``(B, n)``):
    ``u = B^+ (M (qdd_ref + Kp e + Kd e') + n - Q_f)``; exact tracking on a perfect model of a fully
    actuated plant (the error then obeys ``e'' + Kd e' + Kp e = 0``)."""

    def __init__(self, plant: Plant, ref, params: torch.Tensor | None = None, kp=100.0, kd=20.0) -> None:
        self.plant, self.ref, self.params, self.kp, self.kd = plant, ref, params, kp, kd

    def __call__(self, t, q, qd) -> torch.Tensor:
        q_r, qd_r, qdd_r = self.ref(t)
        e = wrap(q_r - q, self.plant.angle_mask)
        return self.plant.inverse(q, qd, qdd_r + self.kp * e + self.kd * (qd_r - qd), self.params)


def min_jerk(q_start: torch.Tensor, q_goal: torch.Tensor, seconds: float):
    """A minimum-jerk (quintic) reference from rest at ``q_start`` to rest at ``q_goal`` (each ``(B, n)``)
    in ``seconds``: ``ref(t) -> (q, qd, qdd)``, holding the goal afterwards."""
    delta = q_goal - q_start

    def ref(t: float):
        s = min(max(t / seconds, 0.0), 1.0)
        pos = 10 * s**3 - 15 * s**4 + 6 * s**5
        vel = (30 * s**2 - 60 * s**3 + 30 * s**4) / seconds
        acc = (60 * s - 180 * s**2 + 120 * s**3) / seconds**2
        return q_start + pos * delta, vel * delta, acc * delta

    return ref


class SwingUp:
    """Swing-up and balance of a fully actuated arm: computed-torque tracking of a minimum-jerk path
    from the start to the target (``seconds`` long), then LQR about the target once the state is within
    ``catch`` rad (angles) and ``catch`` rad/s of it, for good. Both parts are designed on ``plant``."""

    def __init__(self, plant: Plant, q_start: torch.Tensor, q_goal: torch.Tensor, params: torch.Tensor | None = None,
                 seconds: float = 2.0, kp=60.0, kd=16.0, Q=(10, 10, 1, 1), R=0.1, dt: float | None = None,
                 catch: float = 0.1) -> None:
        if plant.num_inputs < plant.dof:
            raise InputError(f"{plant.name}: this swing-up tracks a path by computed torque and needs every joint "
                             f"actuated ({plant.num_inputs} inputs for {plant.dof} coordinates)")
        self.track = ComputedTorque(plant, min_jerk(q_start, q_goal, seconds), params, kp, kd)
        self.lqr = LQR(plant, q_goal, params, Q, R, dt)
        self.q_goal, self.angle_mask, self.catch = q_goal, plant.angle_mask, catch
        self.caught = torch.zeros(q_goal.shape[0], dtype=torch.bool)

    def __call__(self, t, q, qd) -> torch.Tensor:
        near = (wrap(q - self.q_goal, self.angle_mask).abs().amax(-1) < self.catch) & (qd.abs().amax(-1) < self.catch)
        self.caught |= near
        return torch.where(self.caught[:, None], self.lqr(t, q, qd), self.track(t, q, qd))


class MPPI:
    """Model-predictive path integral control (Williams et al.): at every call, ``samples`` input
    sequences of ``horizon`` control periods, perturbed about the current plan, are rolled out on
    ``plant`` in one batch (semi-implicit Euler at the control period, inputs clipped to
    ``torque_limit``); the plan becomes their average weighted by ``exp(-cost / temperature)`` and its
    first input is applied. Cost per step: ``Q``-weighted squared state error to ``(q_goal, 0)``
    (angles wrapped) plus ``R`` times the squared inputs; ``terminal`` times the state cost at the end.
    One plan per episode (``q_goal (B, n)``); seeded."""

    def __init__(self, plant: Plant, q_goal: torch.Tensor, params: torch.Tensor | None = None, samples: int = 1000,
                 horizon: int = 50, dt: float = 0.02, noise: float = 1.0, temperature: float = 1.0,
                 Q=(10, 10, 1, 1), R: float = 0.01, terminal: float = 10.0, torque_limit=None,
                 seed: int = 0) -> None:
        B, m = q_goal.shape[0], plant.num_inputs
        self.plant, self.q_goal, self.params = plant, q_goal, params
        self.K, self.H, self.dt, self.noise, self.lam = samples, horizon, dt, noise, temperature
        self.Q = torch.as_tensor(Q, dtype=torch.float64)
        if self.Q.shape != (2 * plant.dof,):
            raise InputError(f"MPPI: Q needs {2 * plant.dof} diagonal weights, got {self.Q.tolist()}")
        self.R, self.terminal = float(R), float(terminal)
        self.limit = None if torque_limit is None else torch.as_tensor(torque_limit, dtype=torch.float64)
        if self.limit is not None and self.limit.shape != (m,):
            raise InputError(f"MPPI: torque_limit needs {m} values, got {self.limit.tolist()}")
        self.plan = torch.zeros(B, horizon, m, dtype=torch.float64)
        self.gen = torch.Generator().manual_seed(int(seed))
        self._p = None if params is None else params.repeat_interleave(samples, 0)

    def _clip(self, u):
        return u if self.limit is None else torch.maximum(torch.minimum(u, self.limit), -self.limit)

    def __call__(self, t, q, qd) -> torch.Tensor:
        B, K, H = q.shape[0], self.K, self.H
        eps = self.noise * torch.randn(B, K, H, self.plan.shape[-1], generator=self.gen, dtype=torch.float64)
        u = self._clip(self.plan[:, None] + eps)  # (B, K, H, m)
        qs, qds = q.repeat_interleave(K, 0), qd.repeat_interleave(K, 0)
        goal = self.q_goal.repeat_interleave(K, 0)
        flat_u = u.reshape(B * K, H, -1)
        cost = torch.zeros(B * K, dtype=torch.float64)
        with torch.no_grad():
            for k in range(H):
                params = self.plant._params(qs, self._p)
                qs, qds = semi_implicit_euler_step(held(self.plant.accel_fn, flat_u[:, k]), qs, qds, params, self.dt)
                x = torch.cat([wrap(qs - goal, self.plant.angle_mask), qds], -1)
                step = (x.pow(2) * self.Q).sum(-1) + self.R * flat_u[:, k].pow(2).sum(-1)
                cost = cost + torch.nan_to_num(step, nan=1e12, posinf=1e12) * (self.terminal if k == H - 1 else 1.0)
        cost = cost.reshape(B, K)
        w = torch.softmax(-(cost - cost.min(1, keepdim=True).values) / self.lam, dim=1)  # (B, K)
        self.plan = torch.einsum("bk,bkhm->bhm", w, u)
        first = self.plan[:, 0].clone()
        self.plan = torch.cat([self.plan[:, 1:], self.plan[:, -1:]], 1)  # shift for the next call
        return first
