"""How a dataset's trajectories are recorded: what a scene's recorder hands the dataset generator.

A scene gives the generator a recorder for a dataset specification (``System.recorder(spec)``). The
generator (``lnn_torch.data.generate``) seeds it, one random generator per trajectory
(``trajectory_rng(seed, index)``), and does everything else: progress, targets, energy, arrays, the
split and the file attributes. A recorder has one method,

    record(rngs, indices, advance=None) -> Recording

``rngs``: the trajectories' generators, ``indices``: their indices in the specification (for
messages), ``advance(n)``: called as ``n`` sample intervals of trajectories are done (progress;
``len(rngs) * (num_points - 1)`` in all). Each trajectory draws its random quantities from its own
generator only, in a fixed order, so that it depends on ``(seed, index)`` alone and any subset of a
dataset records the same trajectories as the full one.

Recorders: ``ClosedFormRecorder`` (here) integrates a closed-form scene's Lagrangian
(``lnn_torch.systems.ground_truth``); the robot arm's tracking experiment is
``lnn_torch.robots.recording.TrackingRecorder``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from .excitation import sample
from .ground_truth import integrate_ground_truth


@dataclass
class Recording:
    """The raw motion of ``N`` trajectories of ``T`` samples, float64 numpy arrays, and how it was
    recorded (what the file attributes say).

    Attributes:
        q: ``(N, T, dof)`` the coordinates as recorded (measured angles where there is encoder noise).
        qd: ``(N, T, dof)`` velocities (rad/s or m/s).
        params: ``(N, num_params)`` the physical parameters (SI).
        steps: ``(N,)`` int64: the integrator steps each trajectory took.
        integrator: the file attribute ``integrator``: the method that integrated the motion.
        method: how the motion was integrated and checked, in words (attribute ``tolerances``).
        check: the accuracy check, in words (energy drift or power-balance residual).
        tau: ``(N, T, num_inputs)`` the inputs (N m), input ``k`` acting on ``[t_k, t_{k+1})``; None
            for a scene without inputs.
        work: ``(N, T, 2)`` the work since ``t_0`` of the inputs and of friction (J); None for a
            conservative scene.
        q_true: ``(N, T, dof)`` the true coordinates where ``q`` is measured (the energy's); None: ``q``.
        qdd: ``(N, T, dof)`` accelerations the recorder measured along the motion (an engine's at the
            true states under the held inputs); None: the generator takes the scene's closed form.
        arrays: scene-specific arrays ``(N, ...)`` written as they are (e.g. a reference ``q_ref``).
        tolerances: the settings of the accuracy check (entries of attribute ``tolerances``).
        attrs: further file attributes (JSON strings), e.g. the experiment of a recorded arm.
    """

    q: np.ndarray
    qd: np.ndarray
    params: np.ndarray
    steps: np.ndarray
    integrator: str
    method: str
    check: str
    tau: np.ndarray | None = None
    work: np.ndarray | None = None
    q_true: np.ndarray | None = None
    qdd: np.ndarray | None = None
    arrays: dict = field(default_factory=dict)
    tolerances: dict = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)


def sample_conditions(system, rngs, t: np.ndarray, excitation: dict | None = None):
    """Each trajectory's parameters and initial state, drawn from its own generator in that order
    (then, given an ``excitation`` (``lnn_torch.systems.excitation``), its input signal on the sample times
    ``t (T,)``): float64 arrays ``params (N, num_params)``, ``q0 (N, dof)``, ``qd0 (N, dof)`` (and
    ``tau (N, T, num_inputs)``)."""
    params, q0, qd0, tau = [], [], [], []
    for rng in rngs:
        params.append(system.sample_params(rng, 1)[0])
        q, qd = system.sample_state(rng, 1)
        q0.append(q[0])
        qd0.append(qd[0])
        if excitation is not None:
            tau.append(sample(excitation, rng, t, system.num_inputs))
    out = (np.array(params), np.array(q0), np.array(qd0))
    if excitation is None:
        return out
    return (*out, np.array(tau).reshape(len(q0), len(t), system.num_inputs))


class ClosedFormRecorder:
    """The recorder of a closed-form scene: per trajectory its parameters, initial state and (with
    inputs) input signal from the spec's excitation (``sample_conditions``), then all trajectories
    integrated together in float64 (``integrate_ground_truth``: the spec's fixed-step method, adaptive
    DOP853 for those that fail the energy or power-balance check).

    Args:
        system: the scene (``lnn_torch.systems.System``).
        spec: the dataset specification (``lnn_torch.data.DatasetSpec``): ``dt``, ``num_points``,
            ``integrator``, ``substeps``, ``energy_tol``, ``adaptive_tol``, ``excitation``.
    """

    def __init__(self, system, spec) -> None:
        self.system = system
        self.dt, self.num_points = float(spec.dt), int(spec.num_points)
        self.integrator, self.substeps = spec.integrator, int(spec.substeps)
        self.energy_tol, self.adaptive_tol = spec.energy_tol, spec.adaptive_tol
        self.excitation = system.input_signal(spec.excitation) if system.num_inputs else None

    def record(self, rngs, indices, advance=None) -> Recording:
        """The trajectories of ``rngs`` (module docstring); raises ``GenerationError`` naming the
        ``indices`` of those that fail the accuracy check even with the tightest adaptive steps."""
        system, n = self.system, len(rngs)
        t = np.arange(self.num_points) * self.dt
        sampled = sample_conditions(system, rngs, t, self.excitation)
        params, q0, qd0 = (torch.from_numpy(a) for a in sampled[:3])
        tau = torch.from_numpy(sampled[3]) if self.excitation is not None else None
        system.check_params(params)
        system.check_state(q0, qd0)
        with torch.no_grad():
            q, qd, steps, work = integrate_ground_truth(
                system, q0, qd0, params, self.dt, self.num_points - 1, self.integrator, self.substeps,
                self.energy_tol, self.adaptive_tol, callback=None if advance is None else (lambda i: advance(n)),
                indices=indices, tau=None if tau is None else tau[:, :-1], return_work=True)
        check = "power-balance residual |E(t) - E(0) - W(t)|" if system.has_forces else "energy drift"
        method = (f"fixed-step {self.integrator}, h = dt / substeps = {self.dt / self.substeps:g} s; trajectories "
                  f"whose relative {check} exceeds {self.energy_tol:g} of the energy scale are integrated again "
                  f"with adaptive DOP853 steps (rtol = atol = {self.adaptive_tol:g}; ten, then a hundred times "
                  "tighter for those that still exceed it)")
        return Recording(q=q.numpy(), qd=qd.numpy(), params=params.numpy(), steps=steps.numpy(),
                         integrator=self.integrator, method=method, check=check,
                         tau=None if tau is None else tau.numpy(), work=work.numpy() if system.has_forces else None,
                         tolerances={"energy_tol": self.energy_tol, "adaptive_tol": self.adaptive_tol})
