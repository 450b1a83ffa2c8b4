"""Effects a robot description cannot write, with the truth known: the ``robot_arm`` scene option
``unmodelled`` (``scene_config: {unmodelled: {seed: 1, friction: {}, spring: {}, cogging: {},
sensor_offset: {}}}``: the effects named are on, each with its options, ``{}`` its defaults).

The engine (``lnn_torch.robots.mujoco_arm.MujocoArm``) stays the ground truth of the rigid body; the
effects are generalised forces added to it through its ``forces`` hook, at every stage of its
integration, each a closed form here. Per joint ``j``: ``q_j`` rad, ``v_j = qd_j`` rad/s, torques N m.

* ``friction`` (dissipative, ``f_j v_j >= 0``): Coulomb friction whose level grows with the joint's
  load, and a Stribeck breakaway,

      f_j = (c_j + l_j |g_j(q)|_s) tanh(v_j / v_c) + s_j tanh(v_j / v_c) exp(-(v_j / v_s)^2),

  ``g_j`` the joint's gravity torque on the true arm with its payload (``MujocoArm.gravity``),
  ``|x|_s = sqrt(x^2 + e^2) - e`` a smooth absolute value (``e = LOAD_SMOOTHING`` = 0.1 N m); ``f`` is the
  torque the motor works against (as ``lnn_torch.mechanics.friction``), the generalised force is ``-f``.
* ``spring`` (conservative): a nonlinear spring (a balancer, a cable's elasticity) on the joints
  ``joints``, rest angles ``r_j``: ``V = sum_j 1/2 k_j (q_j - r_j)^2 + 1/4 k3_j (q_j - r_j)^4``,
  ``Q_j = -k_j (q_j - r_j) - k3_j (q_j - r_j)^3``.
* ``cogging`` (conservative): a position-periodic motor torque, ``n_j`` cycles per revolution of the
  joint: ``Q_j = -a_j sin(n_j q_j + phi_j)``, ``V = -sum_j (a_j / n_j) cos(n_j q_j + phi_j)``.
* ``sensor_offset`` (a measurement, no force on the arm): the recorded torque is the applied one plus
  ``o_j``.

In the scene (whose inputs ``tau`` are the recorded torques) the truth is

    M(q) qdd + bias(q, qd) = tau - o - D qd - f(q, qd) + Q_spring(q) + Q_cogging(q),

its potential ``V_gravity + V_spring + V_cogging`` (the conservative effects are part of the truth's
Lagrangian, so its energy holds them) and its non-conservative force ``Q_diss = -D qd - f - o`` (the
offset's part is a constant torque: not passive). The recorded work (``work (N, T, 2)``) is that of the
recorded torques and of ``Q_diss``: ``E(t) - E(0) = W_tau + W_diss`` closes with these.

Options (a magnitude is one number for every joint or one per joint, N m; a value given per joint is
used as it is, one number or the default is a magnitude that each joint's value is drawn around,
seeded):

* ``friction: {coulomb, load, stribeck, coulomb_velocity, stribeck_velocity}``: ``c`` and ``s`` drawn as
  magnitude x U(0.5, 1.5), default 0.4 % of each joint's torque limit (0.35 N m on the Panda's joints
  1-4, 0.048 N m on 5-7); ``load`` ``l`` dimensionless, drawn likewise, default 0.02; ``v_c`` = 0.05
  rad/s, ``v_s`` = 0.2 rad/s.
* ``spring: {joints, stiffness, cubic, rest_spread}``: ``joints`` 0-based, default ``[0, 1]``; ``k`` N
  m/rad and ``k3`` N m/rad^3, default 0.25 % and 0.05 % of the torque limit per rad and per rad^3 (0.22
  and 0.044 on the Panda: 0.38 N m at 1.3 rad from rest); ``r_j`` the middle of the joint's range plus
  U(-spread, spread), spread 0.3 rad.
* ``cogging: {amplitude, cycles}``: ``a`` drawn as magnitude x U(0.5, 1.5), default 0.2 % of the torque
  limit (0.17 / 0.024 N m); ``n`` an integer, default 6; ``phi`` U(0, 2 pi).
* ``sensor_offset: {magnitude}``: ``o`` drawn as magnitude x U(-1, 1), default 0.3 % of the torque
  limit (up to 0.26 / 0.036 N m).

The Panda's recorded torques have a std of 0.5-0.6 N m (joint 7) to 16-25 N m (joint 2) per joint:
with the defaults each effect's torque RMS is a few percent of it (friction the largest, up to 12 % on
joints 1 and 4 through its load; all effects together 4-16 % per joint, measured on 20 trajectories).
Each effect draws from its own generator, ``SeedSequence(seed, spawn_key=(k,))`` with ``k`` its index in
``EFFECTS``, so that switching one effect on or off leaves the others' values unchanged.

Every function here takes numpy arrays or torch tensors (``(..., n)``) and answers in kind.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..errors import InputError

EFFECTS = ("friction", "spring", "cogging", "sensor_offset")
LOAD_SMOOTHING = 0.1  # N m: e of the smooth absolute value of the gravity load
# each effect's options and defaults; a default in TORQUE_FRACTION is that fraction of the joint's torque limit
OPTIONS = {
    "friction": {"coulomb": None, "load": 0.02, "stribeck": None, "coulomb_velocity": 0.05, "stribeck_velocity": 0.2},
    "spring": {"joints": (0, 1), "stiffness": None, "cubic": None, "rest_spread": 0.3},
    "cogging": {"amplitude": None, "cycles": 6},
    "sensor_offset": {"magnitude": None},
}
TORQUE_FRACTION = {("friction", "coulomb"): 0.004, ("friction", "stribeck"): 0.004, ("spring", "stiffness"): 0.0025,
                   ("spring", "cubic"): 0.0005, ("cogging", "amplitude"): 0.002, ("sensor_offset", "magnitude"): 0.003}
UNITS = {"c": "N m", "l": "1", "s": "N m", "v_c": "rad/s", "v_s": "rad/s", "k": "N m/rad", "k3": "N m/rad^3",
         "r": "rad", "a": "N m", "n": "cycles/rev", "phi": "rad", "o": "N m"}


def _xp(x):
    return torch if isinstance(x, torch.Tensor) else np


def _as(values: np.ndarray, like):
    """``values`` (float64 numpy) in ``like``'s kind, dtype and device."""
    if isinstance(like, torch.Tensor):
        return torch.as_tensor(values, dtype=like.dtype, device=like.device)
    return values


class UnmodelledEffects:
    """The effects of the module docstring with their drawn per-joint values (float64 numpy ``(n,)``).

    Build with ``UnmodelledEffects.of(config, joint_range, torque_limits, joint_names)``; ``config()``
    gives back what rebuilds it, ``report()`` what a dataset file records.
    """

    def __init__(self, seed: int, options: dict, values: dict, joint_names) -> None:
        self.seed, self.options, self.values = int(seed), options, values
        self.joint_names = tuple(joint_names)
        self.dof = len(self.joint_names)
        self._needs_load = "friction" in values and bool(np.any(values["friction"]["l"]))
        self._hook = _HookConstants.of(values, self.dof)

    # ------------------------------------------------------------------ construction
    @classmethod
    def of(cls, config, joint_range, torque_limits, joint_names) -> UnmodelledEffects:
        """From the scene option: ``{seed: int, <effect>: {options} | true, ...}`` (module docstring);
        ``joint_range (n, 2)`` rad, ``torque_limits (n,)`` N m (None: every magnitude must be given)."""
        if not isinstance(config, dict):
            raise InputError(f"robot_arm: unmodelled must be a dict of effects ({', '.join(EFFECTS)}) and a seed, "
                             f"got {config!r}")
        config = dict(config)
        seed = config.pop("seed", 0)
        if not (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0):
            raise InputError(f"robot_arm: unmodelled seed must be an integer >= 0, got {seed!r}")
        unknown = sorted(set(config) - set(EFFECTS))
        if unknown:
            raise InputError(f"robot_arm: unmodelled has no effect {', '.join(map(repr, unknown))}; known: "
                             f"{', '.join(EFFECTS)} (and seed)")
        options = {}
        for name in EFFECTS:
            given = config.get(name)
            if given is None or given is False:
                continue
            given = {} if given is True else given
            if not isinstance(given, dict):
                raise InputError(f"robot_arm: unmodelled {name} takes a dict of options (or true), got {given!r}")
            bad = sorted(set(given) - set(OPTIONS[name]))
            if bad:
                raise InputError(f"robot_arm: unmodelled {name} takes no option {', '.join(map(repr, bad))}; its "
                                 f"options: {', '.join(OPTIONS[name])}")
            options[name] = {k: _plain(v) for k, v in given.items()}
        if not options:
            raise InputError(f"robot_arm: unmodelled names no effect; choose among {', '.join(EFFECTS)}")
        joint_range = np.asarray(joint_range, dtype=np.float64)
        n = len(joint_range)
        limits = None if torque_limits is None else np.asarray(torque_limits, dtype=np.float64)
        values = {}
        for k, name in enumerate(EFFECTS):
            if name in options:
                rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(k,)))
                opts = {**OPTIONS[name], **options[name]}
                values[name] = _DRAW[name](rng, opts, _Magnitudes(name, opts, n, limits), joint_range)
        return cls(int(seed), options, values, joint_names)

    def config(self) -> dict:
        """What rebuilds the effects (with the scene's joint ranges and torque limits): the seed and each
        effect's options as given."""
        return {"seed": self.seed, **{name: dict(opts) for name, opts in self.options.items()}}

    def report(self) -> dict:
        """What a dataset file records (attribute ``unmodelled``): the seed, the options and, per effect,
        each coefficient per joint with its unit, and the formulas (the module docstring)."""
        effects = {}
        for name, vals in self.values.items():
            effects[name] = {key: {"unit": UNITS[key], "per_joint": dict(zip(self.joint_names, np.broadcast_to(
                value, (self.dof,)).tolist(), strict=True))} for key, value in vals.items() if key in UNITS}
            if name == "spring":
                effects[name]["joints"] = [self.joint_names[j] for j in np.flatnonzero(vals["on"])]
        return {"seed": self.seed, "options": self.config(), "effects": effects, "formulas": FORMULAS}

    # ------------------------------------------------------------------ which
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.values)

    @property
    def acts_on_the_arm(self) -> bool:
        """Whether any effect is a force (all but the sensor offset)."""
        return any(name != "sensor_offset" for name in self.values)

    @property
    def needs_load(self) -> bool:
        """Whether the friction depends on the gravity load (``l != 0`` somewhere)."""
        return self._needs_load

    # ------------------------------------------------------------------ the closed forms
    def friction(self, qd, load=None):
        """``f (..., n)`` N m, the torque the motors work against (module docstring) at rates ``qd`` and
        gravity loads ``load`` (``(..., n)`` N m; None: no load); zeros without the friction effect."""
        xp = _xp(qd)
        if "friction" not in self.values:
            return qd * 0
        p = self.values["friction"]
        sign = xp.tanh(qd / p["v_c"])
        level = _as(p["c"], qd)
        if load is not None:
            level = level + _as(p["l"], qd) * (xp.sqrt(load * load + LOAD_SMOOTHING**2) - LOAD_SMOOTHING)
        return level * sign + _as(p["s"], qd) * sign * xp.exp(-((qd / p["v_s"]) ** 2))

    def _spring_terms(self, q):
        p = self.values["spring"]
        d = (q - _as(p["r"], q)) * _as(p["on"], q)
        return d, _as(p["k"], q), _as(p["k3"], q)

    def spring_force(self, q):
        """``Q_spring (..., n)`` N m (zeros on the other joints and without the effect)."""
        if "spring" not in self.values:
            return q * 0
        d, k, k3 = self._spring_terms(q)
        return -k * d - k3 * d**3

    def cogging_force(self, q):
        """``Q_cogging (..., n)`` N m (zeros without the effect)."""
        if "cogging" not in self.values:
            return q * 0
        p = self.values["cogging"]
        return -_as(p["a"], q) * _xp(q).sin(_as(p["n"], q) * q + _as(p["phi"], q))

    def conservative_force(self, q):
        """``Q_spring + Q_cogging (..., n)`` N m: ``-dV/dq`` of ``potential``."""
        return self.spring_force(q) + self.cogging_force(q)

    def potential(self, q):
        """``V_spring + V_cogging (...,)`` J (0 without either)."""
        V = q[..., 0] * 0
        if "spring" in self.values:
            d, k, k3 = self._spring_terms(q)
            V = V + (0.5 * k * d**2 + 0.25 * k3 * d**4).sum(-1)
        if "cogging" in self.values:
            p = self.values["cogging"]
            n = _as(p["n"], q)
            V = V - (_as(p["a"], q) / n * _xp(q).cos(n * q + _as(p["phi"], q))).sum(-1)
        return V

    def offset(self, like):
        """``o (n,)`` N m in ``like``'s kind (zeros without the sensor offset)."""
        o = self.values["sensor_offset"]["o"] if "sensor_offset" in self.values else np.zeros(self.dof)
        return _as(o, like)

    def torques(self, q, qd, load=None) -> dict:
        """Each effect's share of the recorded torque, ``{name: (..., n)}`` N m: what the recorded
        torques hold beyond the description's rigid body and damper (``tau_rec = ID_engine(q, qd, qdd) +
        sum``): ``friction`` ``f``, ``spring`` ``-Q_spring``, ``cogging`` ``-Q_cogging``, ``sensor_offset``
        ``o``."""
        out = {}
        for name in self.values:
            if name == "friction":
                out[name] = self.friction(qd, load)
            elif name == "spring":
                out[name] = -self.spring_force(q)
            elif name == "cogging":
                out[name] = -self.cogging_force(q)
            else:
                out[name] = self.offset(q) + q * 0
        return out

    # ------------------------------------------------------------------ the engine's hook
    def engine_forces(self, arm, data):
        """``MujocoArm``'s ``forces`` hook: ``(Q_c, Q_d)`` ``(n,)`` at the state in ``data`` (kinematics
        done): the conservative effects and the friction ``-f`` (its load from ``gravity_from_kinematics``)."""
        q, qd = data.qpos, data.qvel
        load = arm.gravity_from_kinematics(data) if self._needs_load else None
        return self._hook(q, qd, load)


class _HookConstants:
    """The closed forms of ``UnmodelledEffects`` for ONE state in plain numpy, every effect's constants
    as ``(n,)`` arrays (zeros where it is off): the engine's hook runs at every RK4 stage, where the
    general functions' checks and conversions would cost more than the engine. The tests compare the
    two."""

    @classmethod
    def of(cls, values: dict, n: int) -> _HookConstants:
        self = cls()
        zero, one = np.zeros(n), np.ones(n)
        fr = values.get("friction", {"c": zero, "l": zero, "s": zero, "v_c": 1.0, "v_s": 1.0})
        self.friction = "friction" in values
        self.c, self.l, self.s, self.v_c, self.v_s = fr["c"], fr["l"], fr["s"], fr["v_c"], fr["v_s"]
        sp = values.get("spring", {"on": zero, "k": zero, "k3": zero, "r": zero})
        self.spring = "spring" in values
        self.on, self.k, self.k3, self.r = sp["on"], sp["k"], sp["k3"], sp["r"]
        cg = values.get("cogging", {"a": zero, "n": one, "phi": zero})
        self.cogging = "cogging" in values
        self.a, self.n, self.phi = cg["a"], cg["n"], cg["phi"]
        return self

    def __call__(self, q: np.ndarray, qd: np.ndarray, load: np.ndarray | None):
        conservative = np.zeros_like(q)
        if self.spring:
            d = (q - self.r) * self.on
            conservative -= (self.k + self.k3 * d * d) * d
        if self.cogging:
            conservative -= self.a * np.sin(self.n * q + self.phi)
        if not self.friction:
            return conservative, np.zeros_like(qd)
        level = self.c if load is None else self.c + self.l * (np.sqrt(load * load + LOAD_SMOOTHING**2)
                                                                - LOAD_SMOOTHING)
        return conservative, -np.tanh(qd / self.v_c) * (level + self.s * np.exp(-((qd / self.v_s) ** 2)))


FORMULAS = {
    "friction": "f_j = (c_j + l_j (sqrt(g_j^2 + e^2) - e)) tanh(v_j / v_c) + s_j tanh(v_j / v_c) exp(-(v_j / v_s)^2), "
                "g_j the joint's gravity torque (payload included), e = 0.1 N m, v_j = qd_j; generalised force -f "
                "(dissipative)",
    "spring": "Q_j = -k_j (q_j - r_j) - k3_j (q_j - r_j)^3 on the joints listed, V = sum 1/2 k (q - r)^2 + 1/4 k3 "
              "(q - r)^4 (conservative: in the scene's potential)",
    "cogging": "Q_j = -a_j sin(n_j q_j + phi_j), V = -sum (a_j / n_j) cos(n_j q_j + phi_j) (conservative: in the "
               "scene's potential)",
    "sensor_offset": "tau_recorded = tau_applied + o (no force on the arm; in the scene's terms a constant force -o on "
                     "the recorded torques, not passive, in Q_diss and its work)",
}


def _plain(value):
    """An option as JSON has it (a tuple or an array as a list)."""
    if isinstance(value, (tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


class _Magnitudes:
    """An effect's option values per joint: ``(values (n,), drawn)``, ``drawn`` False for a value given
    per joint (used as it is)."""

    def __init__(self, effect: str, opts: dict, n: int, limits) -> None:
        self.effect, self.opts, self.n, self.limits = effect, opts, n, limits

    def __call__(self, key: str, positive: bool = True) -> tuple[np.ndarray, bool]:
        value = self.opts[key]
        where = f"robot_arm: unmodelled {self.effect} {key}"
        if value is None:
            if self.limits is None:
                raise InputError(f"{where}: the default is a fraction of the torque limits, which the description has "
                                 "none of: give it in N m (or torque_limits in the scene configuration)")
            return TORQUE_FRACTION[self.effect, key] * self.limits, True
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{where} must be a number or {self.n} numbers, got {value!r}") from None
        if array.ndim > 1 or (array.ndim == 1 and len(array) != self.n) or not np.isfinite(array).all() \
                or (array < 0).any() or (positive and not (array > 0).any()):
            raise InputError(f"{where} must be a number >= 0 or {self.n} such numbers, got {value!r}")
        return np.broadcast_to(array, (self.n,)).copy(), array.ndim == 0


def _drawn(rng, values: np.ndarray, drawn: bool, low: float = 0.5, high: float = 1.5) -> np.ndarray:
    """``values`` times a seeded factor per joint where they are a magnitude, else as given."""
    factor = rng.uniform(low, high, len(values))  # drawn either way: the draws' order never depends on the options
    return values * factor if drawn else values


def _velocity(opts: dict, key: str) -> float:
    value = opts[key]
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise InputError(f"robot_arm: unmodelled friction {key} must be a positive number (rad/s), got {value!r}")
    return float(value)


def _draw_friction(rng, opts, magnitude, joint_range) -> dict:
    c, l, s = magnitude("coulomb"), magnitude("load", positive=False), magnitude("stribeck", positive=False)
    return {"c": _drawn(rng, *c), "l": _drawn(rng, *l), "s": _drawn(rng, *s),
            "v_c": _velocity(opts, "coulomb_velocity"), "v_s": _velocity(opts, "stribeck_velocity")}


def _draw_spring(rng, opts, magnitude, joint_range) -> dict:
    n = len(joint_range)
    joints = opts["joints"]
    if not (isinstance(joints, (list, tuple)) and joints and all(isinstance(j, int) and 0 <= j < n for j in joints)
            and len(set(joints)) == len(joints)):
        raise InputError(f"robot_arm: unmodelled spring joints must be distinct joint indices in [0, {n}), got "
                         f"{joints!r}")
    spread = opts["rest_spread"]
    if not (isinstance(spread, (int, float)) and math.isfinite(spread) and spread >= 0):
        raise InputError(f"robot_arm: unmodelled spring rest_spread must be a number >= 0 (rad), got {spread!r}")
    on = np.zeros(n)
    on[list(joints)] = 1.0
    rest = joint_range.mean(1) + rng.uniform(-spread, spread, n)
    return {"on": on, "k": magnitude("stiffness", positive=False)[0] * on,
            "k3": magnitude("cubic", positive=False)[0] * on, "r": rest * on}


def _draw_cogging(rng, opts, magnitude, joint_range) -> dict:
    n = len(joint_range)
    cycles = np.broadcast_to(np.asarray(opts["cycles"]), (n,)) if np.ndim(opts["cycles"]) in (0, 1) else None
    if cycles is None or cycles.shape != (n,) or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                                         and v >= 1 for v in cycles.tolist()):
        raise InputError(f"robot_arm: unmodelled cogging cycles must be an integer >= 1 or {n} of them, got "
                         f"{opts['cycles']!r}")
    a = _drawn(rng, *magnitude("amplitude"))
    return {"a": a, "n": cycles.astype(np.float64), "phi": rng.uniform(0, 2 * math.pi, n)}


def _draw_offset(rng, opts, magnitude, joint_range) -> dict:
    return {"o": _drawn(rng, *magnitude("magnitude"), low=-1.0, high=1.0)}


_DRAW = {"friction": _draw_friction, "spring": _draw_spring, "cogging": _draw_cogging, "sensor_offset": _draw_offset}
