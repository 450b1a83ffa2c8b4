"""A measured system: a real machine known only through its recordings.

It has fixed, unknown physics: no parameter vector (models of it have no FiLM: there is nothing to
condition on), no closed form (its held-out recordings are the reference), and it is declared by
what a model needs to know (``lnn-torch import`` writes the declaration into the dataset file):

* ``dof``, which coordinates are angles (``angle_mask``), their names, and the angle convention in
  words (``conventions``: e.g. joint-relative angles of a robot);
* ``angle_combinations``: further angles whose sin/cos are features (the absolute angle ``q1 + q2``
  of a link of a chain measured in joint angles);
* inputs: their names and the input matrix ``B (dof, n_u)`` (motor torques at joints: columns of the
  identity);
* dissipation: joint friction (``friction``) on the joint rates ``joint_map @ qd`` with the Coulomb
  smoothing velocity ``coulomb_velocity``; the coefficients are learned;
* known parameters per recording (``param_names``, ``param_units``, ``param_kinds``): e.g. the payload a
  robot arm carried in each recording (mass, centre of mass, inertia in the flange frame), stored in
  the dataset beside each recording, so that a model conditions on them as on a simulated scene's;
* ``description``: for a robot arm, its robot description as the robot it is
  (``lnn_torch.robots.description.ArmDescription``: source, flange, bodies removed, tool, armature,
  damping), which a grey-box model reads; the coordinates are then its joints, in its order.
"""

from __future__ import annotations

import math

import torch

from ..errors import InputError
from .base import PARAM_KINDS, System


class MeasuredSystem(System):
    name = "measured"
    quadratic_kinetic = True
    closed_form = False

    def __init__(self, dof: int, angle_mask=None, coord_names=None, input_names=(), input_matrix=None,
                 friction: bool = True, joint_map=None, coulomb_velocity: float = 0.02, angle_combinations=None,
                 conventions: str = "", label: str = "measured", param_names=(), param_units=None, param_kinds=None,
                 description=None) -> None:
        try:
            dof = int(dof)
        except (TypeError, ValueError):
            raise InputError(f"measured system: dof must be an integer, got {dof!r}") from None
        if dof < 1:
            raise InputError(f"measured system: dof must be >= 1, got {dof}")
        self.dof = dof
        self.angle_mask = tuple(bool(a) for a in (angle_mask if angle_mask is not None else [True] * dof))
        self.coord_names = tuple(coord_names or [f"q{i + 1}" for i in range(dof)])
        if len(self.angle_mask) != dof or len(self.coord_names) != dof:
            raise InputError(f"measured system: angle_mask and coord_names need {dof} entries each")
        self.input_names = tuple(input_names or ())
        n_u = len(self.input_names)
        B = (torch.eye(dof, dtype=torch.float64)[:, :n_u] if input_matrix is None
             else torch.tensor(input_matrix, dtype=torch.float64))
        if n_u and B.shape != (dof, n_u):
            raise InputError(f"measured system: input_matrix must be ({dof}, {n_u}), got {tuple(B.shape)}")
        self._B = B if n_u else None
        self.friction = bool(friction)
        D = torch.eye(dof, dtype=torch.float64) if joint_map is None else torch.tensor(joint_map, dtype=torch.float64)
        if D.ndim != 2 or D.shape[1] != dof:
            raise InputError(f"measured system: joint_map must have {dof} columns, got {tuple(D.shape)}")
        self._D = D
        if not (math.isfinite(coulomb_velocity) and coulomb_velocity > 0):
            raise InputError(f"measured system: coulomb_velocity must be positive, got {coulomb_velocity}")
        self.coulomb_velocity = float(coulomb_velocity)
        self._combos = None if not angle_combinations else torch.tensor(angle_combinations, dtype=torch.float64)
        if self._combos is not None and (self._combos.ndim != 2 or self._combos.shape[1] != dof):
            raise InputError(f"measured system: angle_combinations must be rows of {dof} coefficients")
        self.conventions = conventions or "measured coordinates (no convention declared)"
        self.label = label
        self.param_names = tuple(str(n) for n in (param_names or ()))
        P = len(self.param_names)
        self.param_units = tuple(param_units) if param_units is not None else ("",) * P
        kinds = tuple(param_kinds) if param_kinds is not None else ("real",) * P
        if len(self.param_units) != P or len(kinds) != P:
            raise InputError(f"measured system: param_units and param_kinds need {P} entries (one per parameter)")
        bad = [k for k in kinds if k not in PARAM_KINDS]
        if bad:
            raise InputError(f"measured system: param_kinds must be among {', '.join(PARAM_KINDS)}, got {bad[0]!r}")
        self.param_kinds = kinds
        self.description = description

    def config(self) -> dict:
        return {"dof": self.dof, "angle_mask": list(self.angle_mask), "coord_names": list(self.coord_names),
                "input_names": list(self.input_names),
                "input_matrix": None if self._B is None else self._B.tolist(), "friction": self.friction,
                "joint_map": self._D.tolist(), "coulomb_velocity": self.coulomb_velocity,
                "angle_combinations": None if self._combos is None else self._combos.tolist(),
                "conventions": self.conventions, "label": self.label, "param_names": list(self.param_names),
                "param_units": list(self.param_units), "param_kinds": list(self.param_kinds),
                "description": self.description}

    # ------------------------------------------------------------------ declared forces
    def angle_combinations(self):
        return self._combos

    def input_matrix(self):
        return self._B

    def joint_map(self):
        return self._D

    @property
    def has_friction(self) -> bool:
        return self.friction

    # ------------------------------------------------------------------ no closed form
    def _none(self, what: str):
        raise NotImplementedError(f"measured system '{self.label}' has no closed-form {what}: its recordings are "
                                  "the reference")

    def sample_params(self, rng, n):
        self._none("sampler (import recordings instead of generating data)")

    def sample_state(self, rng, n):
        self._none("sampler (import recordings instead of generating data)")

    def potential(self, q, params):
        self._none("potential")

    def free_acceleration(self, q, qd, params):
        self._none("dynamics")

    def friction_torque(self, rates, params):
        self._none("friction")

    def energy(self, q, qd, params):
        self._none("energy")

    def energy_scale(self, params):
        self._none("energy scale")
