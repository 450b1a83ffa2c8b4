"""How an identification experiment records an arm: a joint reference tracked by a computed-torque
controller running at the sample rate, on the arm as MuJoCo simulates it.

At each sample time ``t_k = k dt`` the controller reads the measured joint angles ``q_m = q_k + noise``
(encoder noise, if any) and the velocities ``qd_k`` and commands

    tau_k = clip(ID_nom(q_m, qd_k, qdd_ref_k + Kp (q_ref_k - q_m) + Kd (qd_ref_k - qd_k)), -tau_max, tau_max)

``ID_nom`` the inverse dynamics ``M v + bias + D qd`` of the NOMINAL description without payload (the
controller knows neither the payload nor a perturbation of the arm), ``Kp = w^2``, ``Kd = 2 w``
(critically damped error dynamics of bandwidth ``w`` rad/s where the model is right). ``tau_k`` is held
on ``[t_k, t_{k+1})`` (zero-order hold) while the engine integrates the true arm with its RK4 in
``substeps`` steps (``MujocoArm.hold``): replaying the recorded torques open loop reproduces the motion.
Units: rad, rad/s, rad/s^2, N m, J, s; arrays ``(T, n)`` float64 numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mujoco_arm import MujocoArm
from .reference import FourierReference


@dataclass(frozen=True)
class ComputedTorque:
    """The controller of the module docstring: ``nominal`` the arm it believes in (its own payload, the
    description's, is used), gains ``kp`` (1/s^2) and ``kd`` (1/s), ``torque_limit (n,)`` N m."""

    nominal: MujocoArm
    kp: float
    kd: float
    torque_limit: np.ndarray

    @classmethod
    def with_bandwidth(cls, nominal: MujocoArm, bandwidth: float, torque_limit) -> ComputedTorque:
        """Critically damped gains of bandwidth ``w`` rad/s: ``Kp = w^2``, ``Kd = 2 w``."""
        return cls(nominal, bandwidth**2, 2 * bandwidth, np.asarray(torque_limit, dtype=np.float64))

    def __call__(self, q_m, qd, q_ref, qd_ref, qdd_ref) -> np.ndarray:
        """The commanded torques ``(n,)`` from the measured state and the reference at one sample, ``(n,)`` each."""
        v = qdd_ref + self.kp * (q_ref - q_m) + self.kd * (qd_ref - qd)
        tau = self.nominal.inverse(q_m[None], qd[None], v[None])[0].numpy()
        return np.clip(tau, -self.torque_limit, self.torque_limit)


def record_tracking(arm: MujocoArm, payload, controller: ComputedTorque, reference: FourierReference,
                    t: np.ndarray, substeps: int, noise: np.ndarray | None = None) -> dict:
    """One recorded experiment from the reference's start state ``(q_ref(0), qd_ref(0))``.

    ``arm``: the true arm (perturbed or not) carrying ``payload`` ``(4,)`` or ``(10,)``; ``t (T,)`` the
    uniform sample times (s); ``noise (T, n)``: encoder noise added to the angles the controller reads
    (and the recording keeps), None for none.

    Returns float64 arrays: ``q`` (true angles), ``q_measured`` (``q + noise``), ``qd``, ``qdd`` (the
    engine's acceleration at ``(q_k, qd_k, tau_k)``), ``tau`` (the torque held on ``[t_k, t_{k+1})``; the
    last one the controller's next command), ``q_ref`` ``(T, n)`` each and ``work (T, 2)``: the work since
    ``t_0`` of the torques and of the joint damper (J).
    """
    q_ref, qd_ref, qdd_ref = reference.evaluate(t)
    T, n = q_ref.shape
    dt = float(t[1] - t[0]) if T > 1 else 0.0
    noise = np.zeros((T, n)) if noise is None else np.asarray(noise, dtype=np.float64)
    out = {k: np.zeros((T, n)) for k in ("q", "qd", "qdd", "tau")}
    work = np.zeros((T, 2))
    arm.start(q_ref[0], qd_ref[0], payload)
    for k in range(T):
        q, qd = arm.state()
        tau = controller(q + noise[k], qd, q_ref[k], qd_ref[k], qdd_ref[k])
        out["q"][k], out["qd"][k], out["tau"][k] = q, qd, tau
        if k + 1 < T:
            out["qdd"][k], w = arm.hold(tau, dt, substeps)
            work[k + 1] = work[k] + w
        else:  # the last sample: its acceleration only (the engine's, as in hold)
            out["qdd"][k] = arm.forward(q[None], qd[None], tau[None], payload)[0].numpy()
    return {**out, "q_measured": out["q"] + noise, "q_ref": q_ref, "work": work}
