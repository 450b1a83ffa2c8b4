"""Closed-loop simulation of a controller on a (true) plant, as a digital controller runs on
hardware: the controller sees the state every control period (optionally with sensor noise and a
delay of whole periods), its output is clipped to the torque limits and held constant over the
period (zero-order hold) while the plant moves (RK4 substeps). Batched over episodes.
"""

from __future__ import annotations

import torch

from ..errors import InputError
from .plant import Plant


def closed_loop(plant: Plant, controller, q0: torch.Tensor, qd0: torch.Tensor, params: torch.Tensor | None,
                duration: float, control_dt: float, substeps: int = 4, torque_limit=None,
                noise_std: tuple[float, float] | None = None, delay: int = 0, seed: int = 0) -> dict:
    """Run ``controller(t, q, qd) -> u`` (``(B, m)``) on ``plant`` from ``q0, qd0 (B, n)``.

    ``torque_limit``: ``(m,)`` bounds (N m) on ``|u|`` (None: none); ``noise_std``: standard deviations
    of the measured angles (rad) and velocities (rad/s), seeded; ``delay``: control periods between
    measurement and actuation (the first ``delay`` periods apply zeros).

    Returns ``t (T,)``, ``q``, ``qd`` ``(B, T, n)`` of the true plant at the control instants and ``u
    (B, T - 1, m)``, the inputs applied over each period.
    """
    B, n, m = q0.shape[0], plant.dof, plant.num_inputs
    if q0.shape != (B, n) or qd0.shape != (B, n):
        raise InputError(f"closed loop: q0 and qd0 must have shape (episodes, {n}), got {tuple(q0.shape)} and "
                         f"{tuple(qd0.shape)}")
    if not control_dt > 0 or not duration > 0 or substeps < 1 or delay < 0:
        raise InputError("closed loop: control_dt and duration must be positive, substeps >= 1 and delay >= 0")
    limit = None
    if torque_limit is not None:
        limit = torch.as_tensor(torque_limit, dtype=torch.float64).reshape(-1)
        if limit.shape != (m,) or (limit <= 0).any():
            raise InputError(f"closed loop: torque_limit needs {m} positive values (one per input: "
                             f"{', '.join(plant.input_names)}), got {torch.as_tensor(torque_limit).tolist()}")
    gen = torch.Generator().manual_seed(int(seed))
    steps = int(round(duration / control_dt))
    q, qd = q0.double(), qd0.double()
    qs, qds, us = [q], [qd], []
    pending = [torch.zeros(B, m, dtype=torch.float64)] * delay
    for k in range(steps):
        q_m, qd_m = q, qd
        if noise_std is not None:
            q_m = q + noise_std[0] * torch.randn(q.shape, generator=gen, dtype=q.dtype)
            qd_m = qd + noise_std[1] * torch.randn(qd.shape, generator=gen, dtype=qd.dtype)
        with torch.no_grad():
            u = controller(k * control_dt, q_m, qd_m).detach().double()
        if limit is not None:
            u = torch.maximum(torch.minimum(u, limit), -limit)
        pending.append(u)
        u = pending.pop(0)
        with torch.no_grad():
            q, qd = plant.step(q, qd, params, u, control_dt, substeps)
        qs.append(q), qds.append(qd), us.append(u)
    t = torch.arange(steps + 1, dtype=torch.float64) * control_dt
    return {"t": t, "q": torch.stack(qs, 1), "qd": torch.stack(qds, 1), "u": torch.stack(us, 1)}
