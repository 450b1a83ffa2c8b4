"""The recorder of a robot arm's datasets: an identification experiment, as one records a real arm.

Per trajectory, from its own random generator in this order: the payload (the scene's sampler), a
Fourier-series joint reference (``lnn_torch.robots.reference``: ``harmonics`` harmonics of
``base_frequency``, kept ``joint_margin`` rad inside the joint ranges, below ``velocity_fraction`` of
the joint velocity limits and, by the nominal inverse dynamics, below ``torque_fraction`` of the
torque limits), then the encoder noise ``N(0, encoder_noise^2)`` rad if any. The reference is tracked
by a computed-torque controller on the nominal description without payload knowledge, at the sample
rate 1/dt, its torques clipped to the limits and held over each sample interval, while MuJoCo
integrates the true arm with its RK4 in ``substeps`` steps per interval (``lnn_torch.robots.tracking``).

Recorded (``lnn_torch.systems.recording.Recording``): ``q`` as the encoders measure it, the true angles for the
energy, ``qd``, ``tau``, the engine's accelerations at the true states under the held torques, the work
of the torques and of the damper, the reference ``q_ref``; attributes ``recording`` (the experiment:
controller, gains, rates, reference, limits, noise, largest tracking error, share of clipped samples)
and ``robot`` (the description, its perturbation). Units: rad, rad/s, rad/s^2, N m, J, s.

With unmodelled effects (the scene's ``unmodelled``, ``lnn_torch.robots.unmodelled``) the engine's arm
carries them while the controller does not know them; the recorded ``tau`` is what the torque sensor
reads, the applied torque plus its offset ``o``, and the work is the scene's: of the recorded torques
(the applied ones' plus ``o . (q - q_0)``, exact for a constant ``o``) and of ``Q_diss`` (the damper's and
the friction's, less the same ``o . (q - q_0)``); attribute ``unmodelled`` records the effects, their
values per joint and the seed.
"""

from __future__ import annotations

import json

import numpy as np

from ..errors import GenerationError, InputError
from ..systems.recording import Recording
from .mujoco_arm import _mujoco
from .reference import sample_reference, within_torque
from .tracking import ComputedTorque, record_tracking

MAX_BANDWIDTH_DT = 0.5  # the controller's bandwidth times dt: beyond, the sampled loop is near instability
CONTROLLER = ("computed torque on the nominal description without payload: tau = clip(ID_nom(q_m, qd, qdd_ref + Kp "
              "(q_ref - q_m) + Kd (qd_ref - qd)), +-torque_limits), ID_nom = M v + bias + D qd; q_m the measured "
              "angles")


class TrackingRecorder:
    """The experiment of the module docstring for one dataset specification.

    Args:
        scene: the ``robot_arm`` scene (``lnn_torch.systems.robot_arm.RobotArm``): its true arm
            (``arm``), the controller's model (``nominal``), the payload sampler (``sample_params``),
            ``joint_limits()`` and the experiment's settings (``base_frequency``, ``harmonics``,
            ``velocity_fraction``, ``torque_fraction``, ``joint_margin``, ``bandwidth``,
            ``encoder_noise``).
        spec: the dataset specification (``lnn_torch.data.DatasetSpec``): ``dt``, ``num_points``,
            ``substeps``, ``targets``.

    Raises ``InputError`` where the scene has no joint limits or its controller is too fast for ``dt``.
    """

    def __init__(self, scene, spec) -> None:
        self.scene = scene
        self.velocity, self.torque = scene.joint_limits()
        self.dt, self.substeps, self.targets = float(spec.dt), int(spec.substeps), spec.targets
        if scene.bandwidth * self.dt > MAX_BANDWIDTH_DT:
            raise InputError(f"{scene.name}: the controller's bandwidth {scene.bandwidth:g} rad/s is too high for its "
                             f"sample interval dt = {self.dt:g} s (bandwidth x dt must be <= {MAX_BANDWIDTH_DT}): "
                             "lower bandwidth or dt")
        self.t = np.arange(spec.num_points) * self.dt
        self.controller = ComputedTorque.with_bandwidth(scene.nominal, scene.bandwidth, self.torque)

    def _nominal_inverse(self, q, qd, qdd):
        return self.scene.nominal.inverse(q, qd, qdd).numpy()

    def record(self, rngs, indices, advance=None) -> Recording:
        """The experiments of ``rngs`` (``lnn_torch.systems.recording``); raises ``GenerationError`` naming the
        first trajectory (of ``indices``) whose arm left its joint ranges."""
        scene, t = self.scene, self.t
        low, high = scene.arm.joint_range.numpy().T
        rows, params = [], []
        for i, rng in zip(indices, rngs, strict=True):
            payload = scene.sample_params(rng, 1)[0]
            reference = sample_reference(rng, low, high, scene.velocity_fraction * self.velocity,
                                         scene.base_frequency, scene.harmonics, scene.joint_margin)
            reference, _ = within_torque(reference, t, self._nominal_inverse, scene.torque_fraction * self.torque)
            noise = rng.normal(0.0, scene.encoder_noise, (len(t), scene.dof)) if scene.encoder_noise else None
            rec = record_tracking(scene.arm, payload, self.controller, reference, t, self.substeps, noise)
            if scene.unmodelled is not None:
                self._read_by_the_sensor(rec, scene.unmodelled.offset(rec["tau"]))
            outside = ~((rec["q"] >= low) & (rec["q"] <= high)).all(0) | ~np.isfinite(rec["q"]).all(0)
            if outside.any():
                j = int(np.flatnonzero(outside)[0])
                error = float(np.abs(rec["q"] - rec["q_ref"]).max())
                raise GenerationError(f"{scene.name}: trajectory {i} leaves the range of {scene.coord_names[j]} "
                                      f"(tracking error up to {error:.3g} rad): lower velocity_fraction or raise "
                                      "joint_margin or bandwidth")
            rows.append(rec)
            params.append(payload)
            if advance is not None:
                advance(len(t) - 1)
        stack = {k: np.stack([r[k] for r in rows]) for k in rows[0]}
        method = (f"MuJoCo {_mujoco().__version__} RK4 (mj_RungeKutta), h = dt / substeps = "
                  f"{self.dt / self.substeps:g} s, joint limits and contacts off; the spec's integrator, energy_tol "
                  "and adaptive_tol do not apply")
        check = ("power-balance residual |E(t) - E(0) - W(t)| over the energy scale, at the true states; W the work "
                 "of the torques and of the damper, by the corrected trapezoidal rule per RK4 step")
        attrs = {}
        if scene.unmodelled is not None:
            if scene.unmodelled.acts_on_the_arm:
                method = (f"classical RK4 over MuJoCo {_mujoco().__version__}'s forward dynamics (mj_forward) with the "
                          f"unmodelled effects' forces at every stage, h = dt / substeps = {self.dt / self.substeps:g} "
                          "s, joint limits and contacts off; the spec's integrator, energy_tol and adaptive_tol do not "
                          "apply")
            check = ("power-balance residual |E(t) - E(0) - W(t)| over the energy scale, at the true states; E with "
                     "the effects' potential (spring, cogging), W the work of the recorded torques and of Q_diss "
                     "(damper, unmodelled friction, sensor offset), the torques' and Q_diss's by the RK4 stages")
            attrs["unmodelled"] = json.dumps(scene.unmodelled.report())
        return Recording(
            q=stack["q_measured"], qd=stack["qd"], params=np.array(params),
            steps=np.full(len(rows), (len(t) - 1) * self.substeps, dtype=np.int64),
            integrator="mujoco_rk4", method=method, check=check, tau=stack["tau"], work=stack["work"],
            q_true=stack["q"], qdd=stack["qdd"], arrays={"q_ref": stack["q_ref"]},
            attrs={"recording": json.dumps(self._experiment(stack, method)), "robot": json.dumps(self._robot()),
                   **attrs})

    @staticmethod
    def _read_by_the_sensor(rec: dict, offset: np.ndarray) -> None:
        """The recorded torques as the sensor reads them, ``tau + o``, and the work in the scene's terms:
        ``o . (q - q_0)`` moved from the friction's column to the torques' (in place)."""
        if not offset.any():
            return
        moved = (rec["q"] - rec["q"][:1]) @ offset
        rec["tau"] = rec["tau"] + offset
        rec["work"] = rec["work"] + np.stack([moved, -moved], -1)

    def _experiment(self, stack: dict, method: str) -> dict:
        """What attribute ``recording`` says: the controller, its rates, the reference, the limits, the
        noise, what each array is, the largest tracking error and the share of clipped samples."""
        scene = self.scene
        offset = np.zeros(scene.dof) if scene.unmodelled is None else scene.unmodelled.offset(np.zeros(scene.dof))
        clipped = np.isclose(np.abs(stack["tau"] - offset), self.torque, rtol=0, atol=1e-12).any(-1)
        tau = ("as the torque sensor reads it: commanded = applied, plus the sensor's offset (attribute unmodelled)"
               if offset.any() else "commanded = applied")
        return {
            "controller": CONTROLLER,
            "kp": scene.bandwidth**2, "kd": 2 * scene.bandwidth, "bandwidth_rad_s": scene.bandwidth,
            "control_rate_hz": 1 / self.dt, "hold": "zero-order: tau_k on [t_k, t_k+1)",
            "integration": method, "substeps": self.substeps,
            "reference": {"kind": "fourier_series", "base_frequency_hz": scene.base_frequency,
                          "harmonics": scene.harmonics, "joint_margin_rad": scene.joint_margin,
                          "velocity_fraction": scene.velocity_fraction, "torque_fraction": scene.torque_fraction},
            "limits": {"velocity_rad_s": list(scene.velocity_limits), "torque_n_m": list(scene.torque_limits)},
            "encoder_noise_rad": scene.encoder_noise,
            "recorded": f"q: measured (true + encoder noise); qd: true; tau: {tau}; qdd: "
                        + ("the engine's at the true state and tau" if self.targets == "analytic"
                           else "central differences of qd") + "; energy, work: true; q_ref: the reference",
            "max_tracking_error_rad": float(np.abs(stack["q_measured"] - stack["q_ref"]).max()),
            "clipped_sample_fraction": float(clipped.mean()),
        }

    def _robot(self) -> dict:
        """What attribute ``robot`` says: the description, its file, the engine's version, the perturbation."""
        arm = self.scene.arm
        return {"description": self.scene.description, "path": str(arm.path), "mujoco_version": _mujoco().__version__,
                "perturbation": arm.perturbation_report()}
