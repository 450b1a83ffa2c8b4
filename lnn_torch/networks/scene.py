"""What a model needs to know about a scene (``SceneInfo``): its coordinates, parameters and
generalised forces, from a ``System``, its ``describe()`` dict or a ``SceneInfo``."""

from __future__ import annotations

import json
from dataclasses import dataclass


@dataclass(frozen=True)
class SceneInfo:
    """What a model needs to know about a scene: its coordinates, parameters and generalised forces
    (``input_matrix`` (dof, n_u) of the inputs; joint ``friction`` on the rates ``joint_map @ qd``,
    ``lnn_torch.mechanics.forces``). A conservative scene has neither, and a model of it builds none."""

    name: str
    dof: int
    angle_mask: tuple[bool, ...]
    num_params: int
    quadratic_kinetic: bool = True
    param_kinds: tuple[str, ...] = ()  # "positive" / "nonnegative" per parameter; empty: all positive
    input_matrix: tuple[tuple[float, ...], ...] | None = None
    friction: bool = False
    joint_map: tuple[tuple[float, ...], ...] | None = None
    coulomb_velocity: float = 0.05
    # further angles (rows: coefficients over the coordinates) whose sin/cos are features, e.g. the
    # absolute angle q1 + q2 of a link in a chain measured in joint angles
    angle_combinations: tuple[tuple[float, ...], ...] | None = None
    param_names: tuple[str, ...] = ()  # for messages; empty: params[i]
    param_units: tuple[str, ...] = ()
    # a robot arm's description (its scene config's ``description``): a name, a path, or the JSON of an
    # ``ArmDescription`` (hashable, as the rest)
    robot_description: str | None = None

    @property
    def num_inputs(self) -> int:
        return 0 if self.input_matrix is None else len(self.input_matrix[0])

    @property
    def has_forces(self) -> bool:
        return self.num_inputs > 0 or self.friction

    @property
    def kinds(self) -> tuple[str, ...]:
        return self.param_kinds or ("positive",) * self.num_params

    @classmethod
    def of(cls, scene) -> SceneInfo:
        """From a ``System``, a ``System.describe()`` dict or a ``SceneInfo``."""
        if isinstance(scene, SceneInfo):
            return scene
        d = scene if isinstance(scene, dict) else scene.describe()
        as_tuple = lambda m: None if m is None else tuple(tuple(float(x) for x in row) for row in m)  # noqa: E731
        return cls(d["name"], int(d["dof"]), tuple(bool(a) for a in d["angle_mask"]), len(d["param_names"]),
                   bool(d.get("quadratic_kinetic", True)), tuple(d.get("param_kinds", ())),
                   as_tuple(d.get("input_matrix")), d.get("friction") is not None,
                   as_tuple(d.get("joint_map")), float(d.get("coulomb_velocity", 0.05)),
                   as_tuple(d.get("angle_combinations")), tuple(d.get("param_names", ())),
                   tuple(d.get("param_units", ())), _description((d.get("config") or {}).get("description")))


def _description(value) -> str | None:
    """A scene's robot description as text: a name or path as it is, a dict as its JSON."""
    if value is None or isinstance(value, str):
        return value
    return json.dumps(value, sort_keys=True)
