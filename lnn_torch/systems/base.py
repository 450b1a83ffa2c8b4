"""The scene interface: what every ground-truth mechanical system declares and computes.

A scene (system) states its degrees of freedom, which coordinates are angles, its physical
parameters with units, whether its kinetic energy is quadratic in the velocities, seeded samplers
for parameters and initial states, and closed-form batched physics in SI units. A scene may declare
generalised forces (``lnn_torch.mechanics.forces``): inputs (``input_matrix``: motor torques at actuated
joints) and joint friction (``friction_torque`` with the ``joint_map``); a conservative scene
declares neither and its accelerations take no ``tau``.

Shapes: ``q``, ``qd`` are ``(*batch, dof)``; ``params`` is ``(*batch, num_params)``. Every
function keeps the input dtype and device and also works on a single unbatched sample, so that it
can be differentiated with ``torch.func``.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError, check_tensors, values_readable
from ..mechanics.forces import check_inputs, dissipative_force, identity_or_none, input_force
from .excitation import validate as validate_excitation
from .recording import ClosedFormRecorder

GRAVITY = 9.81  # m/s^2, the one gravity constant of the project
PARAM_KINDS = ("positive", "nonnegative", "real")  # see ``System.param_kinds``


@dataclass(frozen=True)
class Range:
    """A closed interval ``[low, high]`` with ``low <= high`` (``low == high``: one value, a parameter held fixed)."""

    low: float
    high: float

    def __post_init__(self) -> None:
        lo, hi = float(self.low), float(self.high)
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise InputError(f"range [{lo}, {hi}] is not finite")
        if lo > hi:
            raise InputError(f"range [{lo}, {hi}] is inverted (low > high)")

    def sample(self, rng: np.random.Generator, size) -> np.ndarray:
        return rng.uniform(self.low, self.high, size=size)


def as_range(value, name: str) -> Range:
    """Accept a ``Range``, a pair ``(low, high)`` or a dict with ``low``/``high``."""
    if isinstance(value, Range):
        return value
    try:
        if isinstance(value, dict):
            return Range(float(value["low"]), float(value["high"]))
        low, high = value
        return Range(float(low), float(high))
    except InputError as err:
        raise InputError(f"{name}: {err}") from None
    except (TypeError, ValueError, KeyError):
        raise InputError(f"{name}: expected a pair (low, high), got {value!r}") from None


def param_extremes(params: torch.Tensor) -> tuple[list[float], list[float]] | None:
    """The smallest and largest value of each parameter of ``params (*batch, P)`` as two lists (one
    reduction; a NaN anywhere in a column is NaN in both), or None where there are no rows or parameters."""
    if params.numel() == 0:
        return None
    low, high = torch.stack(torch.aminmax(params.reshape(-1, params.shape[-1]), dim=0)).tolist()
    return low, high


def check_param_signs(params: torch.Tensor, kinds, names, where: str, lowest: list[float] | None = None) -> None:
    """Raise ``InputError`` naming the parameters that are not positive (kind ``positive``) or are
    negative (kind ``nonnegative``, e.g. friction coefficients); a parameter of kind ``real`` (a
    position, of either sign) may take any finite value. ``lowest``: each parameter's smallest value
    where the caller has it (``param_extremes``)."""
    kinds = list(kinds)
    unknown = sorted(set(kinds) - set(PARAM_KINDS))
    if unknown:
        raise InputError(f"{where}: unknown parameter kind(s) {unknown}; known: {', '.join(PARAM_KINDS)}")
    if not kinds or params.numel() == 0:  # a system without parameters (a measured one), or no rows
        return
    # one reduction: the smallest value of each parameter (NaN propagates and is refused too)
    if lowest is None:
        lowest = params.reshape(-1, len(kinds)).amin(0).tolist()
    bad_pos = [n for n, k, v in zip(names, kinds, lowest, strict=True) if k == "positive" and not v > 0]
    bad_neg = [n for n, k, v in zip(names, kinds, lowest, strict=True) if k == "nonnegative" and not v >= 0]
    if bad_pos:
        raise InputError(f"{where}: parameters must be positive; non-positive values in {bad_pos}")
    if bad_neg:
        raise InputError(f"{where}: friction coefficients must be >= 0; negative values in {bad_neg}")


class System(abc.ABC):
    """Base class of the ground-truth scenes.

    Subclasses set the class attributes and implement the closed-form physics. The sampler
    configuration is given to ``__init__`` and reported by ``config()`` so that a dataset file can
    record it and rebuild the same scene.

    Datasets: ``recorder(spec)`` hands the dataset generator (``lnn_torch.data.generate``) an object
    with one method, ``record(rngs, indices, advance=None) -> lnn_torch.systems.recording.Recording``. The
    generator alone seeds (one generator per trajectory, ``trajectory_rng(seed, index)``, each
    trajectory drawing from its own only, in a fixed order), and alone does the progress, the targets,
    the energy, the arrays, the split and every file attribute; the recorder returns the raw motion
    (``q`` as recorded, the true ``q`` where it differs, ``qd``, inputs, parameters, integrator steps,
    work, scene-specific arrays) and says how it recorded it. Default: the closed form integrated
    (``ClosedFormRecorder``); ``robot_arm``: a tracking experiment on the engine
    (``lnn_torch.robots.recording.TrackingRecorder``).
    """

    name: str = ""
    dof: int = 0
    angle_mask: tuple[bool, ...] = ()
    coord_names: tuple[str, ...] = ()
    param_names: tuple[str, ...] = ()
    param_units: tuple[str, ...] = ()
    quadratic_kinetic: bool = True
    conventions: str = ""
    gravity: float = GRAVITY
    speed_limit: float | None = None  # |qd| must stay below this (the relativistic particle's c = 1)
    # per parameter: "positive" (masses, lengths; normalised as logarithms), "nonnegative" (friction
    # coefficients, which may be zero) or "real" (any sign, e.g. a centre of mass; z-scored as it
    # is); empty means all positive
    param_kinds: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()  # one per input (motor torques), in N m
    coulomb_velocity: float = 0.05  # rad/s: the smoothing of Coulomb friction, tanh(rate / v)
    # fixed integrator steps per sample interval of the ground truth (stiff friction needs more)
    ground_truth_substeps: int = 1
    closed_form = True  # False for a measured system: no closed-form dynamics, energy or sampler
    # False for an engine-backed scene (``robot_arm``): its physics is exact but not torch-differentiable
    # (no autograd through it, no torch.func transforms), so the generic tests that differentiate a
    # Lagrangian leave it out
    differentiable = True

    @property
    def num_params(self) -> int:
        return len(self.param_names)

    @property
    def kinds(self) -> tuple[str, ...]:
        return self.param_kinds or ("positive",) * self.num_params

    # ------------------------------------------------------------------ generalised forces (optional)
    def angle_combinations(self) -> torch.Tensor | None:
        """Rows of coefficients over the coordinates: further angles whose sin/cos models read as
        features (e.g. a link's absolute angle ``q1 + q2`` in a chain measured in joint angles);
        None (default): the angle coordinates only."""
        return None

    def input_matrix(self) -> torch.Tensor | None:
        """``B (dof, num_inputs)``, float64: how the inputs enter the coordinates; None (default): no inputs."""
        return None

    @property
    def num_inputs(self) -> int:
        B = self.input_matrix()
        return 0 if B is None else int(B.shape[1])

    @property
    def input_units(self) -> tuple[str, ...]:
        """Each input's unit: ``N`` where its column of the input matrix acts only on lengths, ``N m`` where
        only on angles (or on nothing), ``N or N m`` where on both."""
        B = self.input_matrix()
        if B is None:
            return ()
        angle = torch.tensor(self.angle_mask, dtype=torch.bool)
        units = []
        for column in B.T:
            acts = column != 0
            on_angles, on_lengths = bool((acts & angle).any()), bool((acts & ~angle).any())
            units.append("N or N m" if on_angles and on_lengths else "N" if on_lengths else "N m")
        return tuple(units)

    def joint_map(self) -> torch.Tensor:
        """``D (num_joints, dof)``, float64: the joint rates ``D qd`` that friction acts on (default identity)."""
        return torch.eye(self.dof, dtype=torch.float64)

    def friction_torque(self, rates: torch.Tensor, params: torch.Tensor) -> torch.Tensor | None:
        """Friction torque per joint at joint rates ``(*batch, num_joints)``, N m (``lnn_torch.mechanics.forces``);
        None (default): no friction."""
        return None

    @property
    def has_friction(self) -> bool:
        return False

    @property
    def has_forces(self) -> bool:
        return self.num_inputs > 0 or self.has_friction

    def dissipative_force(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """``Q_diss = -D^T f(D qd)``, ``(*batch, dof)`` (zeros without friction)."""
        if not self.has_friction:
            return torch.zeros_like(qd)
        return dissipative_force(qd, self._force_maps()[1], lambda r: self.friction_torque(r, params))

    def _force_maps(self):
        """``(B, D)`` with None for identities, computed once (``lnn_torch.mechanics.forces``)."""
        if getattr(self, "_maps", None) is None:
            B = self.input_matrix()
            self._maps = (None if B is None else identity_or_none(B), identity_or_none(self.joint_map()))
        return self._maps

    def generalized_force(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor,
                          tau: torch.Tensor | None = None) -> torch.Tensor:
        """``Q = B tau + Q_diss``, ``(*batch, dof)`` in N m (or N)."""
        check_inputs(tau, self.num_inputs, q.shape[:-1])
        Q = self.dissipative_force(q, qd, params)
        return Q if tau is None else Q + input_force(tau, self._force_maps()[0])

    def default_excitation(self) -> dict:
        """The input signal a generated dataset uses when its spec names none (``lnn_torch.systems.excitation``)."""
        return {}

    def input_signal(self, excitation: dict) -> dict:
        """The excitation a dataset spec's ``excitation`` stands for, validated (the scene's default
        when empty; ``lnn_torch.systems.excitation``): what generation uses and the file records."""
        return validate_excitation(excitation or self.default_excitation(), self.num_inputs)

    # ------------------------------------------------------------------ data generation
    def recorder(self, spec):
        """The recorder of this scene's datasets for the specification ``spec`` (class docstring;
        ``lnn_torch.systems.recording``). Default: ``ClosedFormRecorder``, the closed form integrated by
        ``integrate_ground_truth``, inputs from the spec's excitation; a scene that records its data
        another way (an engine-backed arm tracking a reference) returns its own."""
        return ClosedFormRecorder(self, spec)

    @property
    def coord_units(self) -> tuple[str, ...]:
        return tuple("rad" if a else "m" for a in self.angle_mask)

    # ------------------------------------------------------------------ configuration
    @abc.abstractmethod
    def config(self) -> dict:
        """The sampler configuration (JSON-serialisable) that rebuilds this scene."""

    def describe(self) -> dict:
        """Everything a dataset file records about the scene."""
        return {
            "name": self.name,
            "dof": self.dof,
            "angle_mask": list(self.angle_mask),
            "coord_names": list(self.coord_names),
            "coord_units": list(self.coord_units),
            "param_names": list(self.param_names),
            "param_units": list(self.param_units),
            "quadratic_kinetic": self.quadratic_kinetic,
            "param_kinds": list(self.kinds),
            "gravity": self.gravity,
            "conventions": self.conventions,
            "config": self.config(),
            **self.describe_forces(),
        }

    def mismatch(self, recorded: dict) -> str | None:
        """What a dataset's recorded scene (its ``describe()``, the file's ``scene_json``) has that a model
        of this scene cannot take (the scene, coordinates, angles, parameters, inputs and their matrix),
        in words; None when a model of this scene can be evaluated on it."""
        mine = self.describe()
        if recorded.get("name") != mine["name"]:
            return f"scene '{recorded.get('name')}', not '{mine['name']}'"
        for key, what in (("dof", "coordinates"), ("angle_mask", "angle mask (which coordinates are angles)"),
                          ("param_names", "parameters"), ("input_names", "inputs")):
            if key not in recorded:  # an older file that does not record it
                continue
            theirs, ours = recorded.get(key), mine.get(key)
            if key in ("param_names", "input_names"):
                theirs, ours = len(theirs or []), len(ours or [])
            if theirs != ours:
                return f"{what} {recorded.get(key)}, where the model has {mine.get(key)}"
        B_file, B_model = recorded.get("input_matrix"), mine.get("input_matrix")
        if B_file is not None and B_model is not None and not torch.allclose(
                torch.tensor(B_file, dtype=torch.float64), torch.tensor(B_model, dtype=torch.float64)):
            return f"input matrix {B_file}, where the model has {B_model}"
        return None

    def describe_forces(self) -> dict:
        """The generalised forces a model of this scene needs: inputs and their matrix, friction and
        its joint map (empty for a conservative scene)."""
        out = {}
        if self.angle_combinations() is not None:
            out["angle_combinations"] = self.angle_combinations().tolist()
        if self.num_inputs:
            out.update(input_names=list(self.input_names), input_matrix=self.input_matrix().tolist())
        if self.has_friction:
            out.update(friction="joint", joint_map=self.joint_map().tolist(), coulomb_velocity=self.coulomb_velocity)
        return out

    # ------------------------------------------------------------------ samplers
    @abc.abstractmethod
    def sample_params(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` parameter vectors, float64 array ``(n, num_params)``."""

    @abc.abstractmethod
    def sample_state(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``n`` initial states ``(q0, qd0)``, each a float64 array ``(n, dof)``."""

    # ------------------------------------------------------------------ physics
    @abc.abstractmethod
    def potential(self, q: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Potential energy V in J, shape ``(*batch,)``."""

    def mass_matrix(self, q: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Mass matrix M in SI units, shape ``(*batch, dof, dof)`` (quadratic-T scenes only)."""
        raise NotImplementedError(f"scene '{self.name}' has no mass matrix: its kinetic energy is not quadratic")

    def kinetic(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Kinetic energy T in J, shape ``(*batch,)``. Default: ``1/2 qd^T M qd``."""
        M = self.mass_matrix(q, params)
        return 0.5 * torch.einsum("...i,...ij,...j->...", qd, M, qd)

    def lagrangian(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """L = T - V in J, shape ``(*batch,)``."""
        return self.kinetic(q, qd, params) - self.potential(q, params)

    def momentum(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Canonical momentum p = dL/dqd, shape ``(*batch, dof)``. Default: ``M qd``."""
        return torch.einsum("...ij,...j->...i", self.mass_matrix(q, params), qd)

    def energy(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Total energy E = p.qd - L in J, shape ``(*batch,)``. Default (quadratic T): T + V."""
        return self.kinetic(q, qd, params) + self.potential(q, params)

    @abc.abstractmethod
    def free_acceleration(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """Closed-form accelerations without generalised forces, shape ``(*batch, dof)``."""

    def acceleration(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor,
                     tau: torch.Tensor | None = None) -> torch.Tensor:
        """Accelerations qdd in rad/s^2 or m/s^2, shape ``(*batch, dof)``: ``M qdd = ... + B tau + Q_diss``.

        ``tau (*batch, num_inputs)``: the inputs of an actuated scene (required there; refused by an
        unactuated one).
        """
        if not self.has_forces:
            if tau is not None:
                raise InputError(f"{self.name}: tau given, but the scene has no inputs (it is not actuated)")
            return self.free_acceleration(q, qd, params)
        return self.forced_acceleration(q, qd, params, self.generalized_force(q, qd, params, tau))

    def forced_acceleration(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor,
                            force: torch.Tensor) -> torch.Tensor:
        """Accelerations under a given generalised force ``Q (*batch, dof)``: ``M qdd = ... + Q``."""
        qdd = self.free_acceleration(q, qd, params)
        return qdd + torch.linalg.solve(self.mass_matrix(q, params), force[..., None])[..., 0]

    def energy_scale(self, params: torch.Tensor) -> torch.Tensor:
        """The energy scale that drifts are divided by: V_max - V_min over q, shape ``(*batch,)``."""
        raise NotImplementedError

    # ------------------------------------------------------------------ cases and drawing (optional)
    def ood_cases(self) -> list[dict]:
        """Out-of-distribution test cases of this scene: ``[{"params": (P,), "q0": (dof,), "qd0": (dof,)}, ...]``
        (SI tuples). Reported by ``lnn-torch evaluate``; default none."""
        return []

    def regimes(self) -> dict:
        """The regimes of motion a user of this scene meets, each reported apart (``lnn-torch evaluate``'s
        ``regimes`` section): ``{name: sampler(rng, n) -> (q (n, dof), qd (n, dof), params (n, P))}``
        (numpy, SI). Default: the training distribution alone (``sample_state``, ``sample_params``)."""
        def within(rng, n):
            q, qd = self.sample_state(rng, n)
            return q, qd, self.sample_params(rng, n)

        return {"in distribution": within}

    def hard_parameter_cases(self) -> dict[str, tuple[float, ...]]:
        """Named extreme parameter vectors for the stability cases (``lnn_torch.evaluation.stability``), in
        addition to the generic ones every scene gets (parameters x10 and x0.1); default none."""
        return {}

    def scaled_params(self, params: torch.Tensor, k: float) -> tuple[torch.Tensor, str]:
        """The parameters of this scene ``k`` times larger, and a label, for the stability cases:
        every parameter times ``k`` (a valid system wherever the parameters are independent; a scene
        whose parameters constrain each other gives its similar system instead)."""
        return params * k, f"parameters x{k:g}"

    def scale_invariance(self) -> dict:
        """The parameters' direction that the motion cannot see, ``{param: exponent}`` (identification reports
        it as not identifiable, ``lnn_torch.identification.learned``); default none. A scene declares it where
        it holds: ``mass_scale`` gives the common one of a scene whose every mass is a parameter."""
        return {}

    def mass_scale(self) -> dict:
        """``scale_invariance`` of a scene whose every mass, inertia, stiffness and damping is one of its
        parameters: a Lagrangian (and a dissipation) times a constant has the same equations of motion, so
        without inputs to fix the scale, every parameter of mass dimension (units of kg or N) scaled alike
        changes no trajectory (a pendulum's one mass: any value). Empty with inputs (a known torque fixes the
        scale). A system with masses that are not parameters (a measured one: its learned arm) has no such
        direction."""
        if self.num_inputs:
            return {}
        return {p: 1.0 for p, unit in zip(self.param_names, self.param_units or (), strict=False)
                if _mass_dimension(unit)}

    def identifiable_quantities(self) -> dict:
        """Named log-linear combinations of the parameters that identification reports beside each
        parameter, ``{name: {param: coefficient}}`` (e.g. a mass ratio); default: each parameter of the scale
        the motion cannot see (``scale_invariance``) over the first, ``m2/m1``, ``k/m`` (where every one is a
        positive parameter, whose ratio identification reads in logarithms)."""
        members = list(self.scale_invariance())
        kinds = dict(zip(self.param_names, self.kinds, strict=False))
        if not all(kinds.get(p) == "positive" for p in members):
            return {}
        return {f"{p}/{members[0]}": {members[0]: -1.0, p: 1.0} for p in members[1:]}

    def linear_regressor(self, q, qd, qdd, tau=None):
        """Classical identification: the equations of motion written as ``Y phi = b``, linear in a
        vector ``phi`` of base parameters. Returns ``(Y (n, k), b (n,), quantities)`` with
        ``quantities(phi) -> (len(identifiable_quantities()),)`` in their order, for ``(T, dof)``
        inputs; None (default) where the scene offers none."""
        return None

    def positions(self, q: torch.Tensor, params: torch.Tensor) -> torch.Tensor | None:
        """Cartesian positions of the bodies for drawing, ``(*batch, num_bodies, 2)`` in m, linked as
        a chain from the origin (pendula); None (default) for scenes that are not drawn."""
        return None

    # ------------------------------------------------------------------ checks
    def check_params(self, params: torch.Tensor) -> None:
        """Raise ``InputError`` for non-finite, non-positive (or, for friction, negative) parameters."""
        check_tensors(params=params)
        if params.shape[-1:] != (self.num_params,):
            raise InputError(
                f"{self.name}: params must have shape (*batch, {self.num_params}) "
                f"({', '.join(self.param_names)}), got {tuple(params.shape)}"
            )
        if not values_readable():  # (vmap, jacrev: no single value to check)
            return
        extremes = param_extremes(params)  # one reduction: NaN and Inf show in the extremes
        if extremes is not None and not all(math.isfinite(v) for v in (*extremes[0], *extremes[1])):
            raise InputError(f"{self.name}: params contain NaN or Inf")
        check_param_signs(params, self.kinds, self.param_names, self.name, None if extremes is None else extremes[0])

    def check_state(self, q: torch.Tensor, qd: torch.Tensor | None = None) -> None:
        """Raise ``InputError`` for wrong shapes or non-finite states."""
        check_tensors(("q", "qd"), q=q, qd=qd)
        named = [(name, x) for name, x in (("q", q), ("qd", qd)) if x is not None]
        for name, x in named:
            if x.shape[-1:] != (self.dof,):
                raise InputError(f"{self.name}: {name} must have shape (*batch, {self.dof}), got {tuple(x.shape)}")
        # one sum is finite unless something is NaN or Inf (or the sum overflows): only then each is checked
        total = q.sum() if qd is None else q.sum() + qd.sum()
        if values_readable() and not math.isfinite(float(total.detach())):
            for name, x in named:
                if not torch.isfinite(x).all():
                    raise InputError(f"{self.name}: {name} contains NaN or Inf")
        if qd is not None and q.shape != qd.shape:
            raise InputError(f"{self.name}: q and qd shapes differ: {tuple(q.shape)} vs {tuple(qd.shape)}")

    def check_inputs(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor,
                     tau: torch.Tensor | None = None, inputs: str = "check") -> None:
        """``inputs``: ``"check"`` the inputs ``tau`` against the scene (shape, given iff actuated),
        or ``"skip"``."""
        self.check_state(q, qd)
        self.check_params(params)
        if params.shape[:-1] != q.shape[:-1]:
            raise InputError(
                f"{self.name}: batch shapes differ: q {tuple(q.shape)} vs params {tuple(params.shape)}"
            )
        if inputs == "check":
            check_inputs(tau, self.num_inputs, q.shape[:-1])
            if tau is not None and values_readable() and not torch.isfinite(tau).all():
                raise InputError(f"{self.name}: tau contains NaN or Inf")


def _mass_dimension(unit: str) -> bool:
    """Whether a unit (``kg``, ``N/m``, ``kg m^2``, ``N m s/rad``) has the dimension of mass."""
    tokens = unit.replace("/", " ").replace("^", " ").replace("*", " ").replace("·", " ").split()
    return "kg" in tokens or "N" in tokens
