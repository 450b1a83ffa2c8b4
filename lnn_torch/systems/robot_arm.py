"""A 7-joint robot arm from its robot description (the Franka Emika Panda shipped in
``lnn_torch/robots``), carrying an unknown payload: its physics from the MuJoCo engine, its datasets
recorded as an identification experiment records a real arm.

Conventions (also in ``conventions``, written into every dataset file):

* ``q = (joint1, ..., joint7)``: the joint angles as the description defines them (rad): each joint
  turns about its own z axis (right-handed), ``q = 0`` is the description's zero configuration, which
  lies outside joint 4's range ``[-3.0718, -0.0698]`` rad for the Panda; ``qd`` rad/s.
* ``params = (payload_mass, payload_x, payload_y, payload_z)``: a point mass (kg) rigidly attached at
  the flange (link 7, 0.107 m along its z axis), its position in the flange frame (m). Declared
  limits: mass in ``[0, 10]`` kg, ``|x|, |y|, |z| <= 0.25`` m (``check_params`` refuses others).
* inputs ``tau``: the motor torque at each joint (N m, input matrix the identity); joint friction: the
  description's viscous joint damping ``D`` (N m s/rad; the perturbed arm's own): ``Q_diss = -D qd``.
* gravity 9.81 m/s^2 along -z of the world (the fixed base's frame).

Physics, all from the engine (``lnn_torch.robots.mujoco_arm.MujocoArm``; none written here):
``M(q) qdd + bias(q, qd) = tau - D qd`` with the rotors' armature in ``M``; the potential is MuJoCo's
``-sum_i m_i g . x_i`` over the bodies (payload included); ``T = 1/2 qd^T M qd``. No joint-limit or
contact forces: the smooth dynamics everywhere. It is not torch-differentiable (``differentiable =
False``): tensors go to the engine and come back in the input's dtype and device.

``perturbation=seed``: the arm is not its description (masses, centres of mass, inertias, armature and
damping perturbed, seeded; ``MujocoArm``); the payload stays the parameter.

``unmodelled={seed, friction, spring, cogging, sensor_offset}``: physics the description cannot write,
seeded (``lnn_torch.robots.unmodelled``: Stribeck and load-dependent Coulomb friction, a nonlinear
spring, motor cogging, a torque-sensor offset), added to the engine's arm as generalised forces. The
inputs ``tau`` are then the RECORDED torques (applied + the sensor's offset ``o``) and the truth is
``M qdd + bias = tau - o - D qd - f(q, qd) + Q_spring(q) + Q_cogging(q)``: the conservative effects are
in ``potential`` (so in the energy), the rest in ``dissipative_force`` (``-D qd - f - o``; the offset's
part is not passive) and so in the recorded work. The controller does not know them.

Data (``recorder``: ``lnn_torch.robots.recording.TrackingRecorder``, used by ``lnn-torch generate`` and
``generate_dataset``): per trajectory (seeded by ``(spec.seed, index)``: the payload first, then the
reference, then the encoder noise) a Fourier-series joint reference tracked by a computed-torque
controller on the nominal description without payload knowledge, at the sample rate 1/dt, its torques
clipped to the limits and held over each sample interval; the engine integrates with RK4 at dt /
substeps. Recorded: ``q`` as the encoders measure it (plus N(0, encoder_noise^2) rad), ``qd``, ``tau``,
``qdd`` (the engine's at the true state and the held torque, or finite differences of ``qd``), the true
energy and the work of the torques and of the damper, and the reference ``q_ref``.
The spec's ``excitation`` must stay empty: the inputs are the controller's (options above, in the
scene configuration); the file records them as the excitation.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..errors import InputError
from ..robots import DESCRIPTIONS, LIMITS
from ..robots.mujoco_arm import MujocoArm
from ..robots.recording import TrackingRecorder
from ..robots.unmodelled import UnmodelledEffects
from .base import System, as_range

PARAM_NAMES = ("payload_mass", "payload_x", "payload_y", "payload_z")
MASS_LIMIT = (0.0, 10.0)  # kg: the payloads check_params accepts
OFFSET_LIMIT = 0.25  # m: |x|, |y|, |z| of the payload in the flange frame
SCALE_SAMPLES = 256  # configurations (seed 0) over which energy_scale takes the potential's range


class RobotArm(System):
    """The robot arm scene (module docstring). Configuration:

    Args:
        description: a shipped description (``franka_panda``) or an MJCF file (a serial arm of hinge
            joints with a body ``payload`` at its flange).
        payload_mass, payload_x, payload_y, payload_z: sampling ranges (kg, m, m, m), inside the limits.
        perturbation: None (the description as written) or the seed of a perturbed arm.
        base_frequency: the reference's base frequency f0 (Hz); harmonics: its number of harmonics.
        velocity_fraction, torque_fraction: the reference's share of the velocity and torque limits.
        joint_margin: how far (rad) the reference stays inside each joint range.
        bandwidth: the controller's bandwidth w (rad/s): ``Kp = w^2``, ``Kd = 2 w``.
        encoder_noise: standard deviation (rad) of the noise on the recorded (and fed back) angles.
        velocity_limits, torque_limits: per joint (rad/s, N m); None: the shipped description's
            datasheet values (``lnn_torch.robots.LIMITS``; required for another description).
        unmodelled: None (the engine's arm alone) or the effects a description cannot write
            (``lnn_torch.robots.unmodelled``): ``{seed: int, friction: {...}, spring: {...}, cogging:
            {...}, sensor_offset: {...}}``, the effects named on (``{}``: their defaults).
    """

    name = "robot_arm"
    dof = 7
    angle_mask = (True,) * 7
    coord_names = tuple(f"joint{i}" for i in range(1, 8))
    param_names = PARAM_NAMES
    param_units = ("kg", "m", "m", "m")
    param_kinds = ("nonnegative", "real", "real", "real")
    quadratic_kinetic = True
    differentiable = False
    ground_truth_substeps = 4  # RK4 steps of the engine per sample interval (1.25 ms at dt = 5 ms)

    def __init__(self, description="franka_panda", payload_mass=(0.0, 3.0), payload_x=(-0.05, 0.05),
                 payload_y=(-0.05, 0.05), payload_z=(0.0, 0.1), perturbation: int | None = None,
                 base_frequency: float = 0.2, harmonics: int = 5, velocity_fraction: float = 0.5,
                 torque_fraction: float = 0.6, joint_margin: float = 0.2, bandwidth: float = 20.0,
                 encoder_noise: float = 0.0, velocity_limits=None, torque_limits=None, unmodelled=None) -> None:
        self.description = str(description)
        integer = isinstance(perturbation, (int, np.integer)) and not isinstance(perturbation, bool)
        if perturbation is not None and not integer:
            raise InputError(f"robot_arm: perturbation must be None or an integer seed, got {perturbation!r}")
        self.perturbation = None if perturbation is None else int(perturbation)
        self.arm = MujocoArm(self.description, perturbation=self.perturbation)
        if not torch.allclose(self.arm.gravity_vector, torch.tensor([0.0, 0.0, -self.gravity], dtype=torch.float64)):
            raise InputError(f"robot_arm: description {self.description} has gravity "
                             f"{self.arm.gravity_vector.tolist()} "
                             f"m/s^2; the project's is (0, 0, -{self.gravity}) (leave the description's <option "
                             "gravity> out)")
        self._nominal = None
        self.ranges = {name: as_range(value, name) for name, value in
                       zip(PARAM_NAMES, (payload_mass, payload_x, payload_y, payload_z), strict=True)}
        for name, r in self.ranges.items():
            low, high = MASS_LIMIT if name == "payload_mass" else (-OFFSET_LIMIT, OFFSET_LIMIT)
            if r.low < low or r.high > high:
                raise InputError(f"robot_arm: {name} range [{r.low}, {r.high}] leaves the limits [{low}, {high}]")
        options = {"base_frequency": base_frequency, "velocity_fraction": velocity_fraction,
                   "torque_fraction": torque_fraction, "bandwidth": bandwidth}
        for key, value in options.items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(f"robot_arm: {key} must be a positive number, got {value!r}")
        for key in ("velocity_fraction", "torque_fraction"):
            if options[key] > 1:
                raise InputError(f"robot_arm: {key} must be in (0, 1], got {options[key]}")
        if not (isinstance(harmonics, int) and harmonics >= 1):
            raise InputError(f"robot_arm: harmonics must be an integer >= 1, got {harmonics!r}")
        for key, value in (("joint_margin", joint_margin), ("encoder_noise", encoder_noise)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise InputError(f"robot_arm: {key} must be a number >= 0, got {value!r}")
        self.base_frequency, self.harmonics = float(base_frequency), int(harmonics)
        self.velocity_fraction, self.torque_fraction = float(velocity_fraction), float(torque_fraction)
        self.joint_margin, self.bandwidth = float(joint_margin), float(bandwidth)
        self.encoder_noise = float(encoder_noise)
        known = LIMITS.get(self.description, {}) if self.description in DESCRIPTIONS else {}
        self.velocity_limits = self._limits(velocity_limits, known.get("velocity"), "velocity_limits", "rad/s")
        self.torque_limits = self._limits(torque_limits, known.get("torque"), "torque_limits", "N m")
        self.dof = self.arm.dof
        self.angle_mask = (True,) * self.dof
        self.coord_names = self.arm.joint_names
        self.input_names = tuple(f"tau_{j}" for j in self.arm.joint_names)
        self.unmodelled = None
        if unmodelled is not None:
            self.unmodelled = UnmodelledEffects.of(unmodelled, self.arm.joint_range.numpy(), self.torque_limits,
                                                   self.arm.joint_names)
            if self.unmodelled.acts_on_the_arm:
                self.arm.forces = self.unmodelled.engine_forces
        self.conventions = self._conventions()
        self._scale_q = None

    def _limits(self, given, known, key: str, unit: str):
        """Per-joint limits as a tuple, or None where neither given nor known."""
        value = known if given is None else given
        if value is None:
            return None
        try:
            value = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            raise InputError(f"robot_arm: {key} must be {self.arm.dof} numbers ({unit}), got {given!r}") from None
        if len(value) != self.arm.dof or not all(math.isfinite(v) and v > 0 for v in value):
            raise InputError(f"robot_arm: {key} must be {self.arm.dof} positive numbers ({unit}), got {given!r}")
        return value

    def _conventions(self) -> str:
        joints = list(zip(self.arm.joint_names, self.arm.joint_range.tolist(), strict=True))
        ranges = ", ".join(f"{n} [{lo:.4f}, {hi:.4f}]" for n, (lo, hi) in joints)
        outside = [n for n, (lo, hi) in joints if not lo <= 0 <= hi]
        zero = (f"q = 0 is its zero configuration (outside the range of {', '.join(outside)})" if outside
                else "q = 0 is its zero configuration")
        arm = f"description {self.description}" + ("" if self.perturbation is None
                                                     else f", perturbed with seed {self.perturbation}")
        m = self.arm.model
        axes = ("each joint turning about its own z axis (right-handed)" if np.allclose(m.jnt_axis, [0, 0, 1])
                else "each joint turning about the axis its description gives (right-handed)")
        flange = m.body_pos[self.arm.payload_id].tolist()
        parent = self.arm.body_names[m.body_parentid[self.arm.payload_id]]
        noise = (f"q as measured: true angles + N(0, {self.encoder_noise:g}^2) rad encoder noise"
                 if self.encoder_noise else "q the true angles (no encoder noise)")
        effects = ""
        if self.unmodelled is not None:
            effects = (f"; unmodelled effects (seed {self.unmodelled.seed}): {', '.join(self.unmodelled.names)} "
                       "(lnn_torch.robots.unmodelled; values in attribute unmodelled): tau are the recorded torques "
                       "(applied + sensor offset o), M qdd + bias = tau - o - D qd - f(q, qd) + Q_spring(q) + "
                       "Q_cogging(q); the potential holds V_spring + V_cogging, Q_diss = -D qd - f - o")
        return (
            f"q = ({', '.join(self.arm.joint_names)}): the joint angles of the robot {arm} (MJCF), rad, {axes}; "
            f"{zero}; joint ranges (rad): {ranges}; qd rad/s; "
            "params = (payload_mass, payload_x, payload_y, payload_z): kg, m, m, m: a point mass rigidly attached at "
            f"the flange, its position in the flange frame (the frame of {parent} moved by {flange} m); limits: mass "
            "[0, 10] kg, |x|, |y|, |z| <= 0.25 m; inputs "
            "tau = motor torques at the joints, N m (input matrix the identity); friction = the arm's viscous joint "
            "damping D (N m s/rad), Q_diss = -D qd; rotor armature in M; gravity 9.81 m/s^2 along -z of the world; "
            "dynamics, potential (-sum m_i g . x_i) and mass matrix from MuJoCo, no joint-limit or contact forces. "
            "Recorded: a Fourier-series joint reference tracked by a computed-torque controller on the nominal "
            "description without the payload, at the sample rate, torques clipped to the limits and held over each "
            f"sample interval (zero-order hold); {noise}; qd, qdd, energy and work of the true motion{effects}"
        )

    @property
    def nominal(self):
        """The arm as its description gives it, without payload: the controller's model (its own
        engine instance, so that the controller and the simulated arm never load each other's payload)."""
        if self._nominal is None:
            self._nominal = MujocoArm(self.description)
        return self._nominal

    def config(self) -> dict:
        return {"description": self.description, "perturbation": self.perturbation,
                **{name: [r.low, r.high] for name, r in self.ranges.items()},
                "base_frequency": self.base_frequency, "harmonics": self.harmonics,
                "velocity_fraction": self.velocity_fraction, "torque_fraction": self.torque_fraction,
                "joint_margin": self.joint_margin, "bandwidth": self.bandwidth, "encoder_noise": self.encoder_noise,
                "velocity_limits": None if self.velocity_limits is None else list(self.velocity_limits),
                "torque_limits": None if self.torque_limits is None else list(self.torque_limits),
                **({} if self.unmodelled is None else {"unmodelled": self.unmodelled.config()})}

    # ------------------------------------------------------------------ checks
    def check_params(self, params: torch.Tensor) -> None:
        """Also refuses a payload outside the declared limits (mass in [0, 10] kg, |x|, |y|, |z| <=
        0.25 m), naming the parameter and the value."""
        if params.shape[-1:] == (self.num_params,) and params.numel() and torch.isfinite(params).all():
            flat = params.detach().reshape(-1, self.num_params).double()
            for j, name in enumerate(PARAM_NAMES):
                low, high = MASS_LIMIT if j == 0 else (-OFFSET_LIMIT, OFFSET_LIMIT)
                column = flat[:, j]
                bad = (column < low) | (column > high)
                if bad.any():
                    value = float(column[bad][0])
                    raise InputError(f"{self.name}: {name} = {value:g} {self.param_units[j]} is outside its limits "
                                     f"[{low:g}, {high:g}] {self.param_units[j]}")
        super().check_params(params)


    # ------------------------------------------------------------------ samplers
    def sample_params(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Payloads uniform over the configured ranges: ``(n, 4)``, drawn parameter by parameter."""
        return np.stack([self.ranges[name].sample(rng, n) for name in PARAM_NAMES], axis=-1)

    def sample_state(self, rng: np.random.Generator, n: int):
        """``q`` uniform within the joint ranges 0.1 rad inside each end, ``qd ~ U(-0.3, 0.3)`` rad/s."""
        return self.arm.sample_q(rng, n, margin=0.1), rng.uniform(-0.3, 0.3, (n, self.dof))

    # ------------------------------------------------------------------ generalised forces
    def input_matrix(self):
        return torch.eye(self.dof, dtype=torch.float64)

    @property
    def has_friction(self) -> bool:
        return True

    def friction_torque(self, rates, params):
        """The joint damper ``D r`` (N m), ``D`` the engine model's (perturbed) damping per joint; with the
        unmodelled friction, plus its torque at no gravity load (its load part depends on ``q``:
        ``dissipative_force``)."""
        torque = self.arm.damping.to(rates.dtype).to(rates.device) * rates
        if self.unmodelled is not None:
            torque = torque + self.unmodelled.friction(rates)
        return torque

    def gravity_load(self, q, params):
        """The joints' gravity torques ``(*batch, dof)`` N m on the true arm with its payload (the engine's
        ``bias(q, 0)``): the load of the unmodelled friction."""
        return self._engine(lambda q_, p_: self.arm.gravity(q_, p_), q, params)

    def dissipative_force(self, q, qd, params):
        """``Q_diss (*batch, dof)`` N m: ``-D qd``; with the unmodelled effects ``-D qd - f(q, qd) - o`` (the
        module docstring; the sensor offset's ``-o`` is not passive)."""
        if self.unmodelled is None:
            return super().dissipative_force(q, qd, params)
        effects = self.unmodelled
        load = self.gravity_load(q, params) if effects.needs_load else None
        damper = self.arm.damping.to(qd.dtype).to(qd.device) * qd
        return -damper - effects.friction(qd, load) - effects.offset(qd)

    def effect_torques(self, q, qd, params) -> dict:
        """Each unmodelled effect's share of the recorded torques, ``{name: (*batch, dof)}`` N m
        (``UnmodelledEffects.torques``): the recorded torques are the engine's inverse dynamics of the arm
        (damper on, effects off) plus their sum. Empty without the option."""
        if self.unmodelled is None:
            return {}
        load = self.gravity_load(q, params) if self.unmodelled.needs_load else None
        return self.unmodelled.torques(q, qd, load)

    # ------------------------------------------------------------------ physics (the engine's)
    def _engine(self, fn, q, *arrays):
        """Run ``fn`` on ``(B, .)`` float64 arrays of the flattened batch; the result in ``q``'s batch,
        dtype and device."""
        batch = q.shape[:-1]
        flat = [None if x is None else x.detach().reshape(-1, x.shape[-1]).double().cpu() for x in (q, *arrays)]
        out = fn(*flat)
        return out.reshape(*batch, *out.shape[1:]).to(dtype=q.dtype, device=q.device)

    def acceleration(self, q, qd, params, tau=None):
        """``qdd (*batch, dof)``: ``M qdd = tau - bias - D qd`` (the engine's forward dynamics, damper on);
        with the unmodelled effects, theirs too (``tau`` the recorded torques, the sensor offset taken off)."""
        self.check_inputs(q, qd, params, tau)
        if self.unmodelled is not None:
            tau = tau - self.unmodelled.offset(tau)
        return self._engine(lambda q_, qd_, p_, tau_: self.arm.forward(q_, qd_, tau_, p_), q, qd, params, tau)

    def forced_acceleration(self, q, qd, params, force):
        """``qdd (*batch, dof)`` under a generalised force ``Q (*batch, dof)`` and no other: ``M qdd =
        Q - bias`` (the engine with its damper off; with the unmodelled effects ``+ Q_spring + Q_cogging``,
        the conservative ones, as gravity is in ``bias``), so that ``acceleration(tau) ==
        forced_acceleration(generalized_force(tau))``."""
        self.check_inputs(q, qd, params, inputs="skip")
        if force.shape != q.shape:
            raise InputError(f"{self.name}: force must have the shape of q {tuple(q.shape)}, got {tuple(force.shape)}")
        if self.unmodelled is not None:
            force = force + self.unmodelled.conservative_force(q.detach().double()).to(force.dtype)
        return self._engine(lambda q_, qd_, p_, f_: self.arm.forward(q_, qd_, f_, p_, damping=False),
                            q, qd, params, force)

    def free_acceleration(self, q, qd, params):
        """``qdd`` without any generalised force (no torques, no damping)."""
        return self.forced_acceleration(q, qd, params, torch.zeros_like(q))

    def _finite_rows(self, fn, q, params, tail: tuple):
        """``fn(q, params)`` where every coordinate of ``q`` is finite, NaN elsewhere: the energy of a
        diverged model rollout is undefined, as a closed-form scene's NaN arithmetic makes it (the
        engine itself takes finite states only); shapes and parameters are checked as always."""
        ok = torch.isfinite(q).all(-1)
        if ok.all():
            return fn(q, params)
        self.check_state(torch.where(ok[..., None], q, torch.zeros_like(q)))
        params = params.expand(*q.shape[:-1], params.shape[-1])
        out = torch.full((*q.shape[:-1], *tail), float("nan"), dtype=q.dtype, device=q.device)
        if ok.any():
            out[ok] = fn(q[ok], params[ok])
        return out

    def mass_matrix(self, q, params):
        """``M (*batch, dof, dof)`` in kg m^2, armature included (NaN where ``q`` is not finite)."""
        def engine(q_, p_):
            self.check_inputs(q_, None, p_, inputs="skip")
            return self._engine(lambda a, b: self.arm.mass_matrix(a, b), q_, p_)

        return self._finite_rows(engine, q, params, (self.dof, self.dof))

    def potential(self, q, params):
        """``V (*batch,)`` in J: MuJoCo's ``-sum_i m_i g . x_i`` (payload included; the fixed base adds a
        constant; NaN where ``q`` is not finite); with the unmodelled effects plus ``V_spring + V_cogging``."""
        def engine(q_, p_):
            self.check_inputs(q_, None, p_, inputs="skip")
            V = self._engine(lambda a, b: self.arm.potential(a, b)[:, None], q_, p_)[..., 0]
            if self.unmodelled is not None:
                V = V + self.unmodelled.potential(q_.detach().double()).to(V.dtype)
            return V

        return self._finite_rows(engine, q, params, ())

    def energy_scale(self, params):
        """``V_max - V_min`` over a fixed sample of ``SCALE_SAMPLES`` configurations (seed 0, within the
        joint ranges) for each payload: ``(*batch,)`` J."""
        if self._scale_q is None:
            self._scale_q = self.arm.sample_q(np.random.default_rng(0), SCALE_SAMPLES)
        rows = params.detach().reshape(-1, self.num_params).double().cpu()
        unique, inverse = torch.unique(rows, dim=0, return_inverse=True)
        scale = torch.stack([_span(self.arm.potential(self._scale_q, p.numpy())) for p in unique])
        return scale[inverse].reshape(params.shape[:-1]).to(dtype=params.dtype, device=params.device)

    # ------------------------------------------------------------------ cases
    def ood_cases(self):
        """A payload heavier and farther out than the sampled ones, the arm starting at rest in the
        middle of its joint ranges (inputs off: it falls, damped)."""
        middle = tuple(self.arm.joint_range.mean(1).tolist())
        rest = (0.0,) * self.dof
        return [{"params": (4.5, 0.0, 0.0, 0.15), "q0": middle, "qd0": rest},
                {"params": (4.5, 0.1, -0.1, 0.05), "q0": middle, "qd0": rest}]

    def hard_parameter_cases(self):
        return {"no payload": (0.0, 0.0, 0.0, 0.0), "10 kg at 0.25 m": (MASS_LIMIT[1], 0.0, 0.0, OFFSET_LIMIT)}

    def scaled_params(self, params, k):
        """The payload's mass times ``k`` (at most the 10 kg limit), its position kept: every parameter
        times ``k`` would put the payload outside the flange's reach of the limits."""
        scaled = params.clone()
        scaled[..., 0] = (params[..., 0] * k).clamp(*MASS_LIMIT)
        return scaled, f"payload mass x{k:g} (at most {MASS_LIMIT[1]:g} kg)"

    # ------------------------------------------------------------------ classical identification
    def identifiable_quantities(self) -> dict:
        """The payload's mass and position, each its own quantity (what least squares reports)."""
        return {name: {name: 1.0} for name in PARAM_NAMES}

    def linear_regressor(self, q, qd, qdd, tau=None):
        """Classical payload identification on the engine: the torques the payload adds, ``tau -
        tau_arm(q, qd, qdd)`` (the engine's inverse dynamics of the arm without payload, damping
        included), are linear in its ten inertial parameters ``(m, m c, I_o)``
        (``MujocoArm.payload_regressor``); the quantities are ``m`` and ``c = (m c) / m``."""
        if tau is None:
            return None
        Y = self.arm.payload_regressor(q, qd, qdd).reshape(-1, 10)
        b = (torch.as_tensor(tau, dtype=torch.float64) - self.arm.inverse(q, qd, qdd)).reshape(-1)

        def quantities(phi):
            return torch.cat([phi[:1], phi[1:4] / phi[0]])

        return Y, b, quantities

    # ------------------------------------------------------------------ data
    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """The velocity (rad/s) and torque (N m) limits per joint ``(dof,)`` each, for data generation."""
        if self.velocity_limits is None or self.torque_limits is None:
            raise InputError(f"{self.name}: description {self.description} has no known joint velocity and torque "
                             "limits: give velocity_limits and torque_limits in the scene configuration")
        return np.array(self.velocity_limits), np.array(self.torque_limits)

    def input_signal(self, excitation: dict) -> dict:
        """The inputs are a tracking controller's torques, set by the scene configuration: a spec's
        ``excitation`` must be empty; what the file records as the excitation is the controller's recipe."""
        if excitation:
            raise InputError(f"{self.name}: the inputs are the torques of a computed-torque controller tracking a "
                             "Fourier-series joint reference (scene_config: base_frequency, harmonics, "
                             "velocity_fraction, torque_fraction, joint_margin, bandwidth); leave the spec's "
                             f"excitation empty, got {excitation!r}")
        return {"kind": "computed_torque_tracking", "reference": "fourier_series",
                "base_frequency": self.base_frequency, "harmonics": self.harmonics,
                "velocity_fraction": self.velocity_fraction, "torque_fraction": self.torque_fraction,
                "joint_margin": self.joint_margin, "bandwidth": self.bandwidth}

    def recorder(self, spec) -> TrackingRecorder:
        """The tracking experiment that records this arm's datasets (module docstring;
        ``lnn_torch.robots.recording``): this scene's arm and nominal model, loaded once."""
        return TrackingRecorder(self, spec)


def _span(values: torch.Tensor) -> torch.Tensor:
    """``max - min`` of a 1-D tensor."""
    return values.max() - values.min()
