"""The plant view of a dynamics model: what a controller needs, the same for a learned model, a
scene's closed form and an identified rigid-body model, so a controller designed on one runs
unchanged on another.

Every plant is a rigid mechanical system ``M(q) qdd + n(q, qd) = B u + Q_f(q, qd)`` in SI units,
batched over states and (conditioning) parameters:

* ``mass_matrix(q, params)`` ``M (B, n, n)``;
* ``bias(q, qd, params)`` ``n``: Coriolis/centrifugal and gravity forces, ``gravity(q, params)`` its
  part at rest; ``friction(q, qd, params)`` ``Q_f`` (dissipative, zero without friction);
* ``forward(q, qd, params, u)`` accelerations under the inputs ``u (B, m)`` (N m), ``inverse(q, qd,
  qdd, params)`` the inputs that give ``qdd`` (least squares where ``m < n``);
* ``linearize(q, qd, u, params)`` ``(A, B)`` of ``x' = (qd, qdd)`` about a state and input, exact
  (forward-mode derivatives of ``forward``);
* ``energy(q, qd, params)`` where the source has one.

A learned model's plant wraps the model's SI rigid-body face (``lnn_torch.networks.rigid_body``, where
the convention is stated: ``n`` without friction or inputs, ``Q_f`` the learned dissipation, static
friction's holding torques in the accelerations only); a scene's plant its closed form.

Inputs act through ``B`` (``input_matrix``): an actuated scene's own; for a scene without inputs,
torques at its joints (``actuation``: all joints by default, or a mask such as ``(True, False)`` for
a pendubot) acting as generalised forces ``joint_map^T u``. A model learned without inputs knows its
Lagrangian only up to a scale (``cL`` moves alike): ``torque_scale`` is that scale (model units per
N m), 1 where training with inputs fixed it; ``calibrate_torque_scale`` estimates it from a recording
with known torques.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from ..errors import InputError
from ..identification.two_link import RigidArmModel
from ..mechanics.integrators import held, rk4_step
from ..networks.base import DynamicsModel
from ..networks.capabilities import FORCES, MASS_MATRIX, capabilities_of
from ..robots.mujoco_arm import MujocoArm
from ..systems.base import System


@dataclass
class Plant:
    """A rigid mechanical system behind the controller interface (see the module docstring).

    Build one with ``plant_of(source)``; the callables take and return float64 SI tensors.
    """

    name: str
    dof: int
    num_params: int
    input_matrix: torch.Tensor  # (n, m): generalised force B u
    angle_mask: tuple[bool, ...]
    accel_fn: Callable  # (q, qd, params, u | None) -> qdd; u None: inputs off
    mass_fn: Callable  # (q, params) -> M
    friction_fn: Callable | None = None  # (q, qd, params) -> Q_f
    energy_fn: Callable | None = None  # (q, qd, params) -> E
    torque_scale: float | torch.Tensor = 1.0  # model units per N m (one, or one per state of the batch)
    input_names: tuple[str, ...] = field(default_factory=tuple)
    bias_fn: Callable | None = None  # (q, qd, params) -> n (no friction, no inputs); None: Q_f - M a_free
    gravity_fn: Callable | None = None  # (q, params) -> n(q, 0); None: bias at qd = 0

    @property
    def num_inputs(self) -> int:
        return int(self.input_matrix.shape[1])

    # ------------------------------------------------------------------ checks
    def _check(self, q, qd=None, params=None, u=None):
        n, B = self.dof, q.shape[0] if q.ndim == 2 else None
        if q.ndim != 2 or q.shape[1] != n:
            raise InputError(f"{self.name}: q must have shape (batch, {n}), got {tuple(q.shape)}")
        if qd is not None and qd.shape != q.shape:
            raise InputError(f"{self.name}: qd must have the shape of q {tuple(q.shape)}, got {tuple(qd.shape)}")
        if params is not None and params.shape != (B, self.num_params):
            raise InputError(f"{self.name}: params must have shape ({B}, {self.num_params}), got {tuple(params.shape)}")
        if u is not None and u.shape != (B, self.num_inputs):
            raise InputError(f"{self.name}: u must have shape ({B}, {self.num_inputs}) (inputs: "
                             f"{', '.join(self.input_names) or self.num_inputs}), got {tuple(u.shape)}")

    def _params(self, q, params):
        return torch.zeros(q.shape[0], 0, dtype=q.dtype) if params is None else params

    # ------------------------------------------------------------------ the rigid-body terms
    def mass_matrix(self, q, params=None) -> torch.Tensor:
        params = self._params(q, params)
        self._check(q, params=params)
        return self.mass_fn(q, params)

    def friction(self, q, qd, params=None) -> torch.Tensor:
        """The dissipative generalised force ``Q_f`` (zero without friction)."""
        params = self._params(q, params)
        return torch.zeros_like(qd) if self.friction_fn is None else self.friction_fn(q, qd, params)

    def bias(self, q, qd, params=None) -> torch.Tensor:
        """``n(q, qd)``: Coriolis, centrifugal and gravity forces (``M qdd + n = B u + Q_f``)."""
        params = self._params(q, params)
        self._check(q, qd, params)
        if self.bias_fn is not None:
            return self.bias_fn(q, qd, params)
        free = self.accel_fn(q, qd, params, None)
        M = self.mass_fn(q, params)
        return self.friction(q, qd, params) - torch.einsum("bij,bj->bi", M, free)

    def gravity(self, q, params=None) -> torch.Tensor:
        """The gravity forces ``n(q, 0)`` (what holding the system still at ``q`` takes)."""
        if self.gravity_fn is None:
            return self.bias(q, torch.zeros_like(q), params)
        params = self._params(q, params)
        self._check(q, params=params)
        return self.gravity_fn(q, params)

    # ------------------------------------------------------------------ dynamics
    def forward(self, q, qd, params=None, u=None) -> torch.Tensor:
        """Accelerations ``(B, n)`` under the inputs ``u (B, m)`` (None: off)."""
        params = self._params(q, params)
        self._check(q, qd, params, u)
        return self.accel_fn(q, qd, params, u)

    def inverse(self, q, qd, qdd, params=None) -> torch.Tensor:
        """The inputs ``u (B, m)`` that give ``qdd``: ``B u = M qdd + n - Q_f``, least squares where
        there are fewer inputs than coordinates (``residual`` tells how far from exact)."""
        return self.solve_inputs(q, qd, qdd, params)[0]

    def residual(self, q, qd, qdd, params=None) -> torch.Tensor:
        """``|B u - (M qdd + n - Q_f)|`` per state of the least-squares ``inverse``: 0 where ``qdd`` is
        reachable with the inputs (always, fully actuated)."""
        return self.solve_inputs(q, qd, qdd, params)[1]

    def solve_inputs(self, q, qd, qdd, params=None) -> tuple[torch.Tensor, torch.Tensor]:
        """``(inverse, residual)`` from one least-squares solve."""
        params = self._params(q, params)
        self._check(q, qd, params)
        M = self.mass_fn(q, params)
        needed = torch.einsum("bij,bj->bi", M, qdd) + self.bias(q, qd, params) - self.friction(q, qd, params)
        B = self.input_matrix.to(q.dtype)
        u = torch.linalg.lstsq(B.expand(q.shape[0], -1, -1), needed[..., None]).solution[..., 0]
        return u, (needed - u @ B.T).norm(dim=-1)

    def energy(self, q, qd, params=None) -> torch.Tensor:
        if self.energy_fn is None:
            raise InputError(f"{self.name} has no energy of its own")
        params = self._params(q, params)
        self._check(q, qd, params)
        return self.energy_fn(q, qd, params)

    def rigid_forward(self, q, qd, params=None, u=None) -> torch.Tensor:
        """Accelerations of the rigid body alone, friction left out: ``M^-1 (B u - n)``."""
        params = self._params(q, params)
        force = -self.bias(q, qd, params)
        if u is not None:
            force = force + u @ self.input_matrix.T.to(u.dtype)
        return torch.linalg.solve(self.mass_fn(q, params), force[..., None])[..., 0]

    def linearize(self, q, qd, u=None, params=None, friction: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """``(A (B, 2n, 2n), B (B, 2n, m))`` of ``x' = f(x, u)``, ``x = (q, qd)``, about the given states
        and inputs (zeros for None), by forward-mode differentiation of ``forward`` (``friction=False``:
        of ``rigid_forward``; friction has no useful derivative at rest: Coulomb friction is a step and
        static friction holds a joint against small inputs, which would read as no input at all)."""
        params = self._params(q, params)
        u = torch.zeros(q.shape[0], self.num_inputs, dtype=q.dtype) if u is None else u
        self._check(q, qd, params, u)
        n, m = self.dof, self.num_inputs
        fn = self.accel_fn if friction else (lambda q_, qd_, p_, u_: self.rigid_forward(q_, qd_, p_, u_))

        def f(x, v):  # the batch: (B, 2n), (B, m) -> (B, 2n); samples are independent
            return torch.cat([x[:, n:], fn(x[:, :n], x[:, n:], params, v if m else None)], -1)

        x = torch.cat([q, qd], -1)
        columns = []  # one forward-mode derivative per state and input direction, for the whole batch
        for j in range(2 * n + m):
            dx, du = torch.zeros_like(x), torch.zeros_like(u)
            (dx if j < 2 * n else du)[:, j if j < 2 * n else j - 2 * n] = 1.0
            columns.append(torch.func.jvp(f, (x, u), (dx, du))[1])
        jac = torch.stack(columns, -1)  # (B, 2n, 2n + m)
        return jac[..., :2 * n], jac[..., 2 * n:]

    def step(self, q, qd, params, u, dt: float, substeps: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
        """``dt`` of motion under the input ``u`` held constant (zero-order hold), RK4 in ``substeps``."""
        params = self._params(q, params)
        accel = held(self.accel_fn, u)
        for _ in range(substeps):
            q, qd = rk4_step(accel, q, qd, params, dt / substeps)
        return q, qd


# ---------------------------------------------------------------------------- building plants
def _joint_inputs(joint_map: torch.Tensor, actuation) -> torch.Tensor:
    """``B = D^T S``: torques at the joints (rates ``D qd``) selected by ``actuation`` (None / "full":
    all; a mask of booleans; or an explicit ``(n, m)`` matrix)."""
    D = joint_map.to(torch.float64)
    if actuation is None or (isinstance(actuation, str) and actuation == "full"):
        return D.T.clone()
    a = torch.as_tensor(actuation)
    if a.dtype == torch.bool or (a.ndim == 1 and set(a.tolist()) <= {0, 1}):
        mask = a.bool()
        if mask.shape != (D.shape[0],) or not mask.any():
            raise InputError(f"actuation mask must have {D.shape[0]} entries (one per joint) with at least one "
                             f"actuated, got {a.tolist()}")
        return D.T[:, mask].clone()
    if a.ndim != 2 or a.shape[0] != D.shape[1]:
        raise InputError(f"an actuation matrix must have shape ({D.shape[1]}, m), got {tuple(a.shape)}")
    return a.to(torch.float64)


def plant_of(source, actuation=None, torque_scale: float | None = None) -> Plant:
    """The plant view of ``source``: a scene (``lnn_torch.systems``), a trained model (``LNNModule``
    or its network; it must provide a mass matrix: the structured variants), an identified
    rigid-body model (``lnn_torch.identification.two_link.RigidArmModel``) or a robot description's arm through
    MuJoCo (``lnn_torch.robots.mujoco_arm.MujocoArm``: its parameters the payload at the flange).

    ``actuation``: for a source without inputs of its own, which joints carry a motor (see
    ``_joint_inputs``); refused for one with inputs (those are its own). ``torque_scale``: for a
    learned model without inputs of its own, model units per N m (see the module docstring)."""
    if isinstance(source, System):
        return _system_plant(source, actuation)
    if isinstance(source, RigidArmModel):
        if actuation is not None:
            raise InputError("the identified arm model is actuated at both joints; actuation is its own")
        return Plant(source.variant, 2, 0, torch.eye(2, dtype=torch.float64), (True, True),
                     lambda q, qd, p, u: source.acceleration(q, qd, None, u),
                     lambda q, p: source.mass_matrix(q), source.friction, source.energy, 1.0, ("tau1", "tau2"))
    if isinstance(source, MujocoArm):
        if actuation is not None:
            raise InputError("a robot description's arm is actuated at every joint; actuation is its own")
        return _arm_plant(source)
    network = getattr(source, "model", source)
    if isinstance(network, DynamicsModel):
        return _model_plant(network, actuation, torque_scale)
    raise InputError(f"no plant view of {type(source).__name__}: give a scene, a trained structured model, an "
                     "identified rigid-body model or a robot description's arm (MujocoArm)")


def _system_plant(system, actuation) -> Plant:
    if not system.closed_form or not system.quadratic_kinetic:
        raise InputError(f"scene '{system.name}' has no closed-form rigid-body dynamics (M(q), forces): no plant")
    own = system.num_inputs > 0
    if own and actuation is not None:
        raise InputError(f"scene '{system.name}' has inputs of its own ({', '.join(system.input_names)}); "
                         "choose them in its configuration (actuated=...), not with actuation")
    B = system.input_matrix() if own else _joint_inputs(system.joint_map(), actuation)

    def accel(q, qd, p, u):
        if own:
            return system.acceleration(q, qd, p, u if u is not None else torch.zeros(q.shape[0], B.shape[1],
                                                                                       dtype=q.dtype))
        force = system.dissipative_force(q, qd, p)
        if u is not None:
            force = force + u @ B.T.to(u.dtype)
        return system.forced_acceleration(q, qd, p, force)

    def rigid_bias(q, qd, p):
        return -torch.einsum("bij,bj->bi", system.mass_matrix(q, p), system.free_acceleration(q, qd, p))

    names = tuple(system.input_names) if own else tuple(f"tau{i + 1}" for i in range(B.shape[1]))
    return Plant(system.name, system.dof, system.num_params, B, tuple(system.angle_mask), accel, system.mass_matrix,
                 system.dissipative_force if system.has_friction else None, system.energy, 1.0, names, rigid_bias)


def _arm_plant(arm: MujocoArm) -> Plant:
    """A robot description's arm through MuJoCo (``MujocoArm``): a motor at every joint, the parameters
    ``(B, 4)`` the payload at the flange (mass, centre of mass; zeros: none), the description's viscous
    joint damping as its friction (none where it is zero) and its armature in ``M``."""
    dof = arm.dof

    def torques(q, u):
        return torch.zeros(q.shape[0], dof, dtype=q.dtype) if u is None else u

    def accel(q, qd, p, u):
        return arm.forward(q, qd, torques(q, u), payload=p)

    def energy(q, qd, p):
        kinetic = 0.5 * torch.einsum("bi,bij,bj->b", qd, arm.mass_matrix(q, p), qd)
        return kinetic + arm.potential(q, p)

    friction = (lambda q, qd, p: arm.friction(q, qd)) if bool((arm.damping != 0).any()) else None
    names = tuple(f"tau_{j}" for j in arm.joint_names)
    return Plant(f"{arm.description} (MuJoCo)", dof, 4, torch.eye(dof, dtype=torch.float64), (True,) * dof, accel,
                 lambda q, p: arm.mass_matrix(q, p), friction, energy, 1.0, names,
                 lambda q, qd, p: arm.bias(q, qd, p), lambda q, p: arm.gravity(q, p))


def _model_plant(network, actuation, torque_scale) -> Plant:
    """A learned model's plant: its SI rigid-body face (``lnn_torch.networks.rigid_body``: ``mass_matrix``,
    ``bias``, ``friction``, ``forward``, ``energy``), in N m per ``torque_scale``."""
    capabilities = capabilities_of(network)
    if MASS_MATRIX not in capabilities:
        raise InputError(f"variant '{network.variant}' has no mass matrix M(q): a controller needs one (train a "
                         "structured variant: film_lnn or delan)")
    scene = network.scene
    own = scene.num_inputs > 0
    if own and actuation is not None:
        raise InputError(f"the model's scene '{scene.name}' has inputs of its own; actuation is its own")
    if own and torque_scale not in (None, 1.0):
        raise InputError("the model was trained with inputs: its torque scale is fixed (1)")
    dtype = torch.float64
    D = torch.tensor(scene.joint_map, dtype=dtype) if scene.joint_map is not None else torch.eye(scene.dof, dtype=dtype)
    B = torch.tensor(scene.input_matrix, dtype=dtype) if own else _joint_inputs(D, actuation)
    scale = torch.as_tensor(1.0 if torque_scale is None else torque_scale, dtype=dtype)
    if scale.ndim > 1 or (scale <= 0).any():
        raise InputError(f"torque_scale must be positive: one value, or one per state of the batch, "
                         f"got {scale.tolist()}")

    def per_state(x):  # x (B, ...) in model units -> N m (divided by the scale: one, or one per state)
        return x / scale.reshape(-1, *([1] * (x.ndim - 1))) if scale.ndim else x / scale

    def mass(q, p):
        return per_state(network.mass_matrix(q, p))

    def accel(q, qd, p, u):
        if own:
            tau = u if u is not None else torch.zeros(q.shape[0], B.shape[1], dtype=q.dtype)
            return network.forward(q, qd, p, tau, check=False)
        free = network.forward(q, qd, p, check=False)
        if u is None:
            return free
        return free + torch.linalg.solve(mass(q, p), (u @ B.T.to(u.dtype))[..., None])[..., 0]

    friction = None
    if FORCES in capabilities:
        def friction(q, qd, p):
            return per_state(network.friction(q, qd, p))

    def energy(q, qd, p):
        return per_state(network.energy(q, qd, p))

    def bias(q, qd, p):
        return per_state(network.bias(q, qd, p))

    def gravity(q, p):
        return per_state(network.gravity(q, p))

    names = tuple(f"tau{i + 1}" for i in range(B.shape[1]))
    return Plant(f"{network.variant} ({scene.name})", scene.dof, scene.num_params, B, tuple(scene.angle_mask), accel,
                 mass, friction, energy, scale, names, bias, gravity)


def calibrate_torque_scale(plant: Plant, q, qd, qdd, u, params=None):
    """The scale ``c`` (model units per N m) that makes the plant's Lagrangian explain a recording with
    known inputs: least squares of ``M_model (qdd - a_free) = c B u`` over the samples (``plant`` built
    with ``torque_scale=1``). ``(N, n)`` samples give one float; ``(S, T, n)`` recordings of ``S``
    systems (``params (S, P)``) give one scale per system ``(S,)``."""
    if q.ndim == 3:
        S, T, n = q.shape
        p = plant._params(q[:, 0], params)[:, None].expand(-1, T, -1).reshape(S * T, -1)
        flat = [x.reshape(S * T, -1) for x in (q, qd, qdd, u)]
        lhs, rhs = _calibration_terms(plant, *flat, p)
        return ((lhs * rhs).reshape(S, -1).sum(-1) / (rhs * rhs).reshape(S, -1).sum(-1)).detach()
    lhs, rhs = _calibration_terms(plant, q, qd, qdd, u, plant._params(q, params))
    return float((lhs * rhs).sum() / (rhs * rhs).sum())


def _calibration_terms(plant: Plant, q, qd, qdd, u, params):
    M = plant.mass_fn(q, params)
    lhs = torch.einsum("bij,bj->bi", M, qdd - plant.accel_fn(q, qd, params, None))
    return lhs, u @ plant.input_matrix.T.to(u.dtype)


def calibrate_on(true_plant: Plant, model_plant: Plant, params: torch.Tensor | None, seconds: float = 1.0,
                 seed: int = 0, dt: float = 0.005):
    """Per-system torque scales of ``model_plant`` (built with scale 1) from ``seconds`` of
    ``true_plant`` driven by random torques (standard normal, N m, held ``dt``) from random angles at
    rest: the recording a user makes of each system, with its exact accelerations. ``params (S, P)``
    (None: one system). Returns ``(S,)``."""
    S = 1 if params is None else params.shape[0]
    n, m = true_plant.dof, true_plant.num_inputs
    gen = torch.Generator().manual_seed(int(seed))
    q = torch.pi * (2 * torch.rand(S, n, generator=gen, dtype=torch.float64) - 1)
    qd = torch.zeros(S, n, dtype=torch.float64)
    rec = {"q": [], "qd": [], "qdd": [], "u": []}
    for _ in range(int(round(seconds / dt))):
        u = torch.randn(S, m, generator=gen, dtype=torch.float64)
        rec["q"].append(q), rec["qd"].append(qd), rec["u"].append(u)
        rec["qdd"].append(true_plant.forward(q, qd, params, u))
        q, qd = true_plant.step(q, qd, params, u, dt, 2)
    arrays = {k: torch.stack(v, 1) for k, v in rec.items()}
    return calibrate_torque_scale(model_plant, arrays["q"], arrays["qd"], arrays["qdd"], arrays["u"], params)
