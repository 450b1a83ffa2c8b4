"""The dataset specification: everything that determines a generated dataset file."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field

from ..errors import InputError
from ..mechanics.integrators import METHODS
from ..systems import System, get_system

_SCENE = "_scene"  # the instance attribute holding ((scene, scene_config as JSON), the built scene)


@dataclass
class DatasetSpec:
    """What to generate. Every field is recorded in the file (attribute ``spec``, JSON).

    Attributes:
        scene: scene name (see ``lnn_torch.systems.SYSTEMS``).
        scene_config: sampler configuration of the scene (ranges; see the scene's ``__init__``).
        num_trajectories: number of trajectories.
        duration: length of each trajectory in s.
        dt: sampling interval in s (``round(duration / dt) + 1`` points per trajectory).
        seed: master seed; trajectory ``i`` uses the seed sequence ``(seed, i)``.
        split: train/val/test fractions by trajectory.
        integrator: fixed-step method of ``lnn_torch.mechanics.integrators`` used for ground truth.
        substeps: fixed integrator steps per sampling interval (first pass); None: the scene's
            ``ground_truth_substeps``.
        energy_tol: a trajectory whose energy drifts (with inputs or friction: whose power balance
            is violated) by more than this fraction of the scene's energy scale in the fixed-step
            pass is integrated again with adaptive DOP853 steps (per trajectory, ``rtol = atol =
            adaptive_tol``); if it still fails, generation fails with an error naming the trajectories.
        adaptive_tol: tolerances of the adaptive pass.
        targets: ``"analytic"`` (the scene's closed-form accelerations, default) or
            ``"finite_difference"`` (second-order central differences of qd, as for measured data).
        excitation: the input signals of an actuated scene (``lnn_torch.systems.excitation``); empty: the
            scene's ``default_excitation()``. Refused for a scene without inputs, and by a scene whose
            inputs come from its own recording (``robot_arm``: a tracking controller's torques).

    The scene is built once (``system``, cached outside the fields: equality, ``asdict``,
    ``to_json``, pickling and copies see the fields only), and again only if ``scene`` or
    ``scene_config`` change.
    """

    scene: str = "double_pendulum"
    scene_config: dict = field(default_factory=dict)
    num_trajectories: int = 2000
    duration: float = 20.0
    dt: float = 0.005
    seed: int = 0
    split: tuple[float, float, float] = (0.8, 0.1, 0.1)
    integrator: str = "rk8"
    substeps: int | None = None
    energy_tol: float = 1e-10
    adaptive_tol: float = 1e-11
    targets: str = "analytic"
    excitation: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.scene_config = dict(self.scene_config or {})
        self.excitation = dict(self.excitation or {})
        if self.substeps is None:
            self.substeps = getattr(self.system, "ground_truth_substeps", 1)
        try:  # values from command lines and YAML may arrive as strings
            self.num_trajectories, self.seed = int(self.num_trajectories), int(self.seed)
            self.substeps = int(self.substeps)
            self.duration, self.dt = float(self.duration), float(self.dt)
            self.energy_tol, self.adaptive_tol = float(self.energy_tol), float(self.adaptive_tol)
            self.split = tuple(float(x) for x in self.split)
        except (TypeError, ValueError) as err:
            raise InputError(f"dataset spec: {err}") from None
        self.validate()

    @property
    def num_points(self) -> int:
        return int(round(self.duration / self.dt)) + 1

    @property
    def system(self) -> System:
        """The scene of this specification, built on first use and kept (a robot arm's description is
        loaded once per dataset); built again only where ``scene`` or ``scene_config`` changed."""
        key = (self.scene, json.dumps(self.scene_config, sort_keys=True, default=repr))
        cached = self.__dict__.get(_SCENE)
        if cached is None or cached[0] != key:
            cached = self.__dict__[_SCENE] = (key, get_system(self.scene, **self.scene_config))
        return cached[1]

    def build_system(self) -> System:
        """A new instance of the scene (``system`` is the specification's own, built once)."""
        return get_system(self.scene, **self.scene_config)

    def __getstate__(self) -> dict:  # pickles and copies carry the fields, not the built scene
        return {k: v for k, v in self.__dict__.items() if k != _SCENE}

    def validate(self) -> None:
        system = self.system  # unknown scene / bad ranges raise InputError
        if not system.closed_form:
            raise InputError(f"scene '{self.scene}' has no closed form and cannot be generated: import its recordings "
                             "(lnn-torch import) and point data.path at the file")
        if int(self.num_trajectories) < 1:
            raise InputError(f"num_trajectories must be >= 1, got {self.num_trajectories}")
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise InputError(f"dt must be positive, got {self.dt}")
        if not (math.isfinite(self.duration) and self.duration >= self.dt):
            raise InputError(f"duration must be >= dt, got duration={self.duration}, dt={self.dt}")
        if abs(self.duration / self.dt - round(self.duration / self.dt)) > 1e-6:
            raise InputError(f"duration {self.duration} is not a whole number of steps of dt={self.dt}")
        if len(self.split) != 3 or any(x < 0 for x in self.split) or abs(sum(self.split) - 1) > 1e-9:
            raise InputError(f"split must be three non-negative fractions summing to 1, got {self.split}")
        if self.split[0] == 0:
            raise InputError("split: the training fraction must be positive")
        n = int(self.num_trajectories)
        if n - int(round(self.split[1] * n)) - int(round(self.split[2] * n)) < 1:  # (as split_indices rounds them)
            raise InputError(f"split {list(self.split)} of {n} trajectories leaves none for training (the validation "
                             "and test shares round up to all of them): more trajectories, or a larger training share")
        if int(self.substeps) < 1:
            raise InputError(f"substeps must be >= 1, got {self.substeps}")
        for name in ("energy_tol", "adaptive_tol"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"{name} must be positive, got {value}")
        if self.targets not in ("analytic", "finite_difference"):
            raise InputError(f"targets must be 'analytic' or 'finite_difference', got '{self.targets}'")
        if self.integrator not in METHODS:
            raise InputError(f"unknown integrator '{self.integrator}'; known: {', '.join(METHODS)}")
        self.input_signal()  # a malformed excitation, or one for a scene without inputs, raises InputError

    def input_signal(self) -> dict:
        """The excitation of the inputs (the scene's default when the spec names none), validated."""
        return self.system.input_signal(self.excitation)

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> DatasetSpec:
        return cls(**json.loads(text))
