"""Fixed-step integrators for second-order systems ``qdd = accel_fn(q, qd, params)`` and for
first-order systems ``ydot = vector_field_fn(y, params)`` (e.g. Hamiltonian networks in (q, p)).

Entry points: ``rollout`` (second order) and ``rollout_first_order``, each picking a method by name.
Every step function has ``order`` and ``stages`` (acceleration calls per step) attributes.

* ``rk4``: classical Runge-Kutta, order 4 (first and second order systems).
* ``rk8``: the 12-stage, 8th-order Dormand-Prince tableau (the one DOP853 uses) as a fixed step;
  used to generate ground truth (first and second order systems).
* ``semi_implicit_euler``: kick then drift (symplectic Euler for velocity-independent forces), order 1.
* ``leapfrog``: kick-drift-kick (velocity Verlet) with the velocity in the second kick taken from an
  explicit half-step estimate; symplectic and order 2 for velocity-independent forces.

Explicit Runge-Kutta methods are one function, ``explicit_rk_step``, driven by a Butcher tableau; a
second-order system is integrated as the first-order system ``y = (q, qd)``. Pure tensor functions;
shapes ``(*batch, dof)``.

Inputs (``tau``, e.g. motor torques) are held constant over each output interval (zero-order hold,
as a digital controller applies them): output step ``k`` integrates from ``t_k`` to ``t_{k+1}`` with
``tau[:, k]``, passed to ``accel_fn(q, qd, params, tau_k)`` at every stage and substep.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

AccelFn = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]
VectorFieldFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]

_RK4_TABLEAU = ([[], [0.5], [0.0, 0.5], [0.0, 0.0, 1.0]], [1 / 6, 1 / 3, 1 / 3, 1 / 6])


def _dop853_tableau():
    # The coefficients are read from scipy's DOP853 implementation (not re-typed here).
    from scipy.integrate._ivp import dop853_coefficients as dc

    s = dc.N_STAGES
    return [dc.A[i, :i].tolist() for i in range(s)], dc.B.tolist()


def _dop853_error_weights():
    """The embedded 5th- and 3rd-order error weights of DOP853 (13 stages, the last one FSAL)."""
    from scipy.integrate._ivp import dop853_coefficients as dc

    return dc.E5.tolist(), dc.E3.tolist()


_TABLEAUX = {"rk4": lambda: _RK4_TABLEAU, "rk8": _dop853_tableau}
_COEFFICIENTS: dict = {}


def _coefficients(name: str, dtype, device):
    """The tableau of ``name`` as tensors: each stage's row ``(1, i)`` and the weights ``(1, s)``."""
    key = (name, dtype, device)
    if key not in _COEFFICIENTS:
        A, B = _TABLEAUX[name]()
        _COEFFICIENTS[key] = ([torch.tensor([row], dtype=dtype, device=device) for row in A],
                              torch.tensor([B], dtype=dtype, device=device))
    return _COEFFICIENTS[key]


def explicit_rk_step(name: str, fn: VectorFieldFn, y: torch.Tensor, params: torch.Tensor, dt: float) -> torch.Tensor:
    """One step of the explicit Runge-Kutta method ``name`` (``rk4`` or ``rk8``) for ``ydot = fn(y, params)``.

    The stages are written into one buffer ``(s, *y.shape)``; each stage's state and the step are one
    matrix product with the tableau's row (few ops per stage, which matters for small batches)."""
    A, B = _coefficients(name, y.dtype, y.device)
    stages = y.new_empty((len(A), *y.shape))
    flat, y_row = stages.view(len(A), -1), y.reshape(1, -1)
    for i, a in enumerate(A):
        yi = y if i == 0 else torch.addmm(y_row, a, flat[:i], alpha=dt).view(y.shape)
        stages[i] = fn(yi, params)
    return torch.addmm(y_row, B, flat, alpha=dt).view(y.shape)


def _second_order_rk(name: str, order: int, stages: int):
    def step(accel_fn: AccelFn, q, qd, params, dt):
        dof = q.shape[-1]

        def fn(y, params_):  # y = (q, qd) -> (qd, qdd)
            return torch.cat([y[..., dof:], accel_fn(y[..., :dof], y[..., dof:], params_)], dim=-1)

        y = explicit_rk_step(name, fn, torch.cat([q, qd], dim=-1), params, dt)
        return y[..., :dof], y[..., dof:]

    step.order, step.stages = order, stages
    step.__name__ = f"{name}_step"
    return step


def rk4_step(accel_fn: AccelFn, q, qd, params, dt):
    """Classical RK4 written out for ``qdd = accel_fn(q, qd, params)`` (fewer ops per stage than the
    tableau form, which matters for small batches; a test checks it against ``explicit_rk_step``)."""
    h = 0.5 * dt
    a1 = accel_fn(q, qd, params)
    v2 = torch.add(qd, a1, alpha=h)
    a2 = accel_fn(torch.add(q, qd, alpha=h), v2, params)
    v3 = torch.add(qd, a2, alpha=h)
    a3 = accel_fn(torch.add(q, v2, alpha=h), v3, params)
    v4 = torch.add(qd, a3, alpha=dt)
    a4 = accel_fn(torch.add(q, v3, alpha=dt), v4, params)
    q_new = torch.add(q, qd + 2 * (v2 + v3) + v4, alpha=dt / 6)
    qd_new = torch.add(qd, a1 + 2 * (a2 + a3) + a4, alpha=dt / 6)
    return q_new, qd_new


rk4_step.order, rk4_step.stages = 4, 4
rk8_step = _second_order_rk("rk8", 8, 12)  # the 12-stage Dormand-Prince tableau


def semi_implicit_euler_step(accel_fn: AccelFn, q, qd, params, dt):
    qd_new = qd + dt * accel_fn(q, qd, params)
    return q + dt * qd_new, qd_new


semi_implicit_euler_step.order, semi_implicit_euler_step.stages = 1, 1


def leapfrog_step(accel_fn: AccelFn, q, qd, params, dt):
    a0 = accel_fn(q, qd, params)
    qd_half = qd + 0.5 * dt * a0
    q_new = q + dt * qd_half
    # second kick: the acceleration is evaluated at an explicit estimate of the end velocity
    qd_guess = qd_half + 0.5 * dt * a0
    qd_new = qd_half + 0.5 * dt * accel_fn(q_new, qd_guess, params)
    return q_new, qd_new


leapfrog_step.order, leapfrog_step.stages = 2, 2

METHODS = {
    "rk4": rk4_step,
    "rk8": rk8_step,
    "semi_implicit_euler": semi_implicit_euler_step,
    "leapfrog": leapfrog_step,
}
FIRST_ORDER_METHODS = {"rk4": 4, "rk8": 8}  # name -> order


def check_rollout(q0, qd0, params, dt: float, num_steps: int, method: str, substeps: int = 1, tau=None):
    """The arguments of ``rollout`` checked (``ValueError`` naming the problem); returns the step function."""
    try:
        step = METHODS[method]
    except KeyError:
        raise ValueError(f"unknown integrator '{method}'; known: {', '.join(METHODS)}") from None
    if q0.shape != qd0.shape or q0.ndim != 2:
        raise ValueError(f"q0 and qd0 must both be (batch, dof), got {tuple(q0.shape)} and {tuple(qd0.shape)}")
    if params.ndim != 2 or params.shape[0] != q0.shape[0]:
        raise ValueError(f"params must be (batch, num_params) with batch {q0.shape[0]}, got {tuple(params.shape)}")
    if not dt > 0 or num_steps < 0 or substeps < 1:
        raise ValueError(f"need dt > 0, num_steps >= 0, substeps >= 1; got {dt}, {num_steps}, {substeps}")
    if tau is not None and (tau.ndim != 3 or tau.shape[:2] != (q0.shape[0], num_steps)):
        raise ValueError(f"tau must be (batch, num_steps, num_inputs) = ({q0.shape[0]}, {num_steps}, n_u), "
                         f"got {tuple(tau.shape)}")
    return step


def rollout(
    accel_fn: AccelFn,
    q0: torch.Tensor,
    qd0: torch.Tensor,
    params: torch.Tensor,
    dt: float,
    num_steps: int,
    method: str = "rk4",
    substeps: int = 1,
    callback: Callable[[int], None] | None = None,
    tau: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Integrate a batch of trajectories with a fixed step.

    Args:
        accel_fn: ``(q, qd, params) -> qdd`` on ``(B, dof)``, ``(B, dof)``, ``(B, P)``, SI units.
        q0, qd0: initial state ``(B, dof)``; params: ``(B, P)``.
        dt: output interval in s; each output step takes ``substeps`` integrator steps of ``dt/substeps``.
        num_steps: number of output steps.
        method: a key of ``METHODS``.
        callback: called with the output step index after each step (progress bars).
        tau: inputs ``(B, num_steps, n_u)``, held over each output interval (zero-order hold);
            ``accel_fn`` then takes them as a fourth argument, ``(q, qd, params, tau_k)``.

    Returns:
        ``(q, qd)`` each of shape ``(B, num_steps + 1, dof)``, starting with the initial state.
    """
    step = check_rollout(q0, qd0, params, dt, num_steps, method, substeps, tau)
    h = dt / substeps
    qs, qds = [q0], [qd0]
    q, qd = q0, qd0
    for i in range(num_steps):
        fn = accel_fn if tau is None else held(accel_fn, tau[:, i])
        for _ in range(substeps):
            q, qd = step(fn, q, qd, params, h)
        qs.append(q)
        qds.append(qd)
        if callback is not None:
            callback(i)
    return torch.stack(qs, dim=1), torch.stack(qds, dim=1)


def held(fn: Callable, tau_k: torch.Tensor) -> Callable:
    """``fn`` with the inputs ``tau_k (B, n_u)`` held as its last argument: ``(*args) -> fn(*args, tau_k)``
    (an ``accel_fn(q, qd, params)`` or a ``vector_field_fn(y, params)``)."""
    def with_inputs(*args):
        return fn(*args, tau_k)
    return with_inputs


def rollout_first_order(
    vector_field_fn: VectorFieldFn,
    y0: torch.Tensor,
    params: torch.Tensor,
    dt: float,
    num_steps: int,
    method: str = "rk4",
    substeps: int = 1,
    tau: torch.Tensor | None = None,
    callback: Callable[[int], None] | None = None,
) -> torch.Tensor:
    """Integrate ``ydot = vector_field_fn(y, params)`` with a fixed step.

    Args:
        vector_field_fn: ``(y (B, n), params (B, P)) -> (B, n)`` (with ``tau``: ``(y, params, tau_k)``).
        y0: ``(B, n)``; params: ``(B, P)``; dt: output interval; num_steps: number of output steps.
        method: ``rk4`` or ``rk8`` (the symplectic methods need a second-order system).
        substeps: integrator steps of ``dt / substeps`` per output step.
        tau: inputs ``(B, num_steps, n_u)`` held over each output interval (zero-order hold).

    Returns:
        ``y`` of shape ``(B, num_steps + 1, n)``, starting with ``y0``.
    """
    if method not in FIRST_ORDER_METHODS:
        raise ValueError(f"integrator '{method}' is not available for first-order systems; "
                         f"known: {', '.join(FIRST_ORDER_METHODS)}")
    if y0.ndim != 2 or params.ndim != 2 or params.shape[0] != y0.shape[0]:
        raise ValueError(f"y0 must be (batch, n) and params (batch, P), "
                         f"got {tuple(y0.shape)} and {tuple(params.shape)}")
    if not dt > 0 or num_steps < 0 or substeps < 1:
        raise ValueError(f"need dt > 0, num_steps >= 0 and substeps >= 1; got {dt}, {num_steps}, {substeps}")
    ys, y = [y0], y0
    for i in range(num_steps):
        fn = vector_field_fn if tau is None else held(vector_field_fn, tau[:, i])
        for _ in range(substeps):
            y = explicit_rk_step(method, fn, y, params, dt / substeps)
        ys.append(y)
        if callback is not None:
            callback(i)
    return torch.stack(ys, dim=1)


def rollout_adaptive(
    vector_field_fn: VectorFieldFn,
    y0: torch.Tensor,
    params: torch.Tensor,
    dt: float,
    num_steps: int,
    rtol: float = 1e-11,
    atol: float = 1e-11,
    max_iterations: int = 10_000_000,
    tau: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Integrate ``ydot = vector_field_fn(y, params)`` with adaptive DOP853 steps, per trajectory.

    Every trajectory has its own step size, controlled by the embedded error estimate of the
    Dormand-Prince 8(5,3) pair (Hairer, Norsett & Wanner); trajectories advance in lockstep (one
    attempted step each per iteration, only those not yet finished are evaluated), and steps are
    clipped to land exactly on the output times ``k dt``. Meant for ground truth on stiff or fast
    trajectories (the light first mass of a double pendulum whipping round).

    Args:
        y0: ``(B, n)``; params ``(B, P)``; dt: output interval; num_steps: number of outputs after y0.
        rtol, atol: tolerances of the error norm (scaled per component as in scipy's DOP853).
        tau: inputs ``(B, num_steps, n_u)`` held over each output interval (``vector_field_fn`` then
            takes ``(y, params, tau_k)``); steps never cross an output time, so each sees one input.

    Returns:
        ``y (B, num_steps + 1, n)`` and the accepted steps per trajectory ``(B,)``. A trajectory
        whose step size collapses (below 1e-12 dt) or turns non-finite is NaN from there on.
    """
    rows_A, row_B = _coefficients("rk8", y0.dtype, y0.device)
    A, Bw = [a[0] for a in rows_A], row_B[0]
    E5, E3 = (torch.tensor(w, dtype=y0.dtype, device=y0.device) for w in _dop853_error_weights())
    safety, min_factor, max_factor, exponent = 0.9, 0.2, 10.0, -1.0 / 8.0
    B, n = y0.shape
    out = y0.new_full((B, num_steps + 1, n), float("nan"))
    out[:, 0] = y0
    def evaluate(y, prm, rows):
        """The vector field at ``y`` for trajectories ``rows[0]`` in their intervals ``rows[1]``."""
        return vector_field_fn(y, prm) if tau is None else vector_field_fn(y, prm, tau[rows[0], rows[1]])

    all_rows = (torch.arange(y0.shape[0], device=y0.device),
                torch.zeros(y0.shape[0], dtype=torch.long, device=y0.device))
    y, f = y0.clone(), evaluate(y0, params, all_rows)
    t = torch.zeros(B, dtype=torch.float64, device=y0.device)
    h = torch.full((B,), float(dt), dtype=torch.float64, device=y0.device)
    k = torch.ones(B, dtype=torch.long, device=y0.device)  # index of the next output
    rejected = torch.zeros(B, dtype=torch.bool, device=y0.device)
    accepted_steps = torch.zeros(B, dtype=torch.long, device=y0.device)
    for _ in range(max_iterations):
        idx = torch.nonzero(k <= num_steps)[:, 0]
        if idx.numel() == 0:
            break
        ya, fa, pa = y[idx], f[idx], params[idx]
        rows = (idx, k[idx] - 1)  # the interval each trajectory is in: its held input
        if tau is not None:  # the stored derivative may belong to the previous interval's input
            fa = evaluate(ya, pa, rows)
        target = k[idx].to(torch.float64) * dt
        h_try = torch.minimum(h[idx], target - t[idx])  # (b,)
        hc = h_try.to(y0.dtype)[:, None]
        ks = [fa]
        for a in A[1:]:
            ks.append(evaluate(ya + hc * torch.tensordot(a, torch.stack(ks), dims=1), pa, rows))
        y_new = ya + hc * torch.tensordot(Bw, torch.stack(ks), dims=1)
        f_new = evaluate(y_new, pa, rows)
        K = torch.stack(ks + [f_new])  # (13, b, n)
        scale = atol + rtol * torch.maximum(ya.abs(), y_new.abs())
        e5 = (torch.tensordot(E5, K, dims=1) / scale).square().sum(-1)
        e3 = (torch.tensordot(E3, K, dims=1) / scale).square().sum(-1)
        denom = e5 + 0.01 * e3
        err = torch.where(denom > 0, h_try.abs() * e5 / torch.sqrt(denom * n).clamp_min(1e-300), torch.zeros_like(e5))
        ok = (err < 1) & torch.isfinite(err) & torch.isfinite(y_new).all(-1)
        factor = torch.where(err > 0, safety * err.clamp_min(1e-300) ** exponent, torch.full_like(err, max_factor))
        factor = factor.clamp(min_factor, max_factor)
        factor = torch.where(ok & rejected[idx], factor.clamp(max=1.0), factor)  # no growth right after a rejection
        factor = torch.where(torch.isfinite(err), factor, torch.full_like(err, min_factor))
        acc = idx[ok]
        t_new = t[idx] + h_try
        reached = ok & (t_new >= target - 1e-9 * dt)
        y[acc], f[acc] = y_new[ok], f_new[ok]
        t[acc] = torch.where(reached[ok], target[ok], t_new[ok])
        accepted_steps[acc] += 1
        hit = idx[reached]
        out[hit, k[hit]] = y[hit]
        k[hit] += 1
        h[idx] = torch.clamp(h_try * factor, max=float(dt))
        rejected[idx] = ~ok
        dead = idx[(h[idx] < 1e-12 * dt)]
        if dead.numel():  # the step size collapsed: give up on these trajectories (NaN from here)
            k[dead] = num_steps + 1
    else:
        raise RuntimeError(f"rollout_adaptive: more than {max_iterations} iterations")
    return out, accepted_steps
