"""Drive models of a robot's joints: the friction a joint's motor works against, as a function of the
joint's rate ``v`` (rad/s), one set of coefficients per joint, in SI (N m).

    f(v) = b v + c tanh(v / v_c) + o + s tanh(v / v_c) exp(-(v / v_s)^2) + d tanh(v / v_d)
           + phi1 [sigmoid(phi2 (v + phi3)) - sigmoid(phi2 phi3)]

Each term is a *form* a model may have (``DriveModel.forms``):

==========  ===========================================  =====================================================
form        coefficients                                 passive (``f(v) v >= 0``)?
==========  ===========================================  =====================================================
viscous     ``b`` (N m s/rad)                            yes for ``b >= 0``
coulomb     ``c`` (N m), smoothed over ``v_c``           yes for ``c >= 0``
offset      ``o`` (N m): an asymmetry, a torque sensor's  **no**: a constant torque, not a friction; it can
            offset or a gravity-compensation error         put energy in (it is reported as such)
stribeck    ``s`` (N m): breakaway above Coulomb, fading   yes for ``s >= 0`` (then ``c + s e^(...) >= 0``)
            over ``v_s``
saturating  ``d`` (N m): the Coulomb level moves from ``c``   yes for ``d >= -k c``, ``k = min(1, v_d / v_c)``
            to ``c + d`` over ``v_d`` (0.1 rad/s): rising  (``saturation_floor``): the law then stays
            (gear drives) or, for ``d < 0``, falling      above ``(c + d) tanh(v / v_d)`` (with ``c``'s
            (a breakaway, as Stribeck's)                  own sign: ``c >= 0``)
sigmoid     ``phi1`` (N m), ``phi2`` (s/rad), ``phi3``     yes for ``phi1, phi2 >= 0``: zero at rest and
            (rad/s): Gaz et al.'s form (Panda, 2019)       increasing, it opposes the motion; with ``phi3 != 0``
                                                           it is asymmetric
==========  ===========================================  =====================================================

``f`` is the torque the friction takes from the motor (it opposes the motion): ``tau = tau_rigid(q,
qd, qdd) + f(v)``; as a generalised force on the coordinates, ``Q_f = -D^T f(D qd)`` for joint rates
``D qd``. The linear forms enter least squares as columns (``columns``); the sigmoid is linear in
``phi1`` alone. Pure tensor functions: every shape is ``(..., n_j)`` per joint.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

FORMS = ("viscous", "coulomb", "offset", "stribeck", "saturating", "sigmoid")
LINEAR = ("viscous", "coulomb", "offset", "stribeck", "saturating")  # linear in their one coefficient
PASSIVE = {"viscous": True, "coulomb": True, "offset": False, "stribeck": True, "saturating": True, "sigmoid": True}
COEFFICIENTS = {"viscous": ("b",), "coulomb": ("c",), "offset": ("o",), "stribeck": ("s",), "saturating": ("d",),
                "sigmoid": ("phi1", "phi2", "phi3")}
# the steepest slope a friction law's smoothed step may take, relative to the Coulomb smoothing velocity:
# the sigmoid's phi2 <= SLOPE_LIMIT / v_c (2,500 s/rad at v_c = 0.02 rad/s; Gaz et al.'s Panda: 5-60 s/rad).
# A step sharper than the data's velocity resolution is not identifiable, and its gradients are spikes
SLOPE_LIMIT = 50.0
UNITS = {"b": "N m s/rad", "c": "N m", "o": "N m", "s": "N m", "d": "N m", "phi1": "N m", "phi2": "s/rad",
         "phi3": "rad/s"}


# the smoothing of Coulomb friction's sign, ``shape(v / v_c)``: tanh for the learned models and the
# scenes, arctan where an identified model was written with it (the real double pendulum's lab model)
COULOMB_SHAPES = {"tanh": torch.tanh, "arctan": torch.atan}


def coulomb_sign(v: torch.Tensor, coulomb_velocity: float, shape: str = "tanh") -> torch.Tensor:
    """The smoothed sign of the rates ``v (..., n_j)`` (rad/s or m/s): ``shape(v / v_c)``, dimensionless."""
    if shape not in COULOMB_SHAPES:
        raise _error(f"coulomb_shape must be one of {', '.join(COULOMB_SHAPES)}, got {shape!r}")
    return COULOMB_SHAPES[shape](v / coulomb_velocity)


def friction_torque(v: torch.Tensor, viscous, coulomb, coulomb_velocity: float, shape: str = "tanh") -> torch.Tensor:
    """The joint friction law, viscous plus smooth Coulomb: ``b v + c shape(v / v_c)`` at rates
    ``v (..., n_j)``, coefficients broadcasting to it (N m s/rad and N m; N s/m and N for a sliding
    joint), ``v_c`` in the rates' unit. Returns ``(..., n_j)`` in N m (N). Every model of the package
    computes its viscous and Coulomb friction here (``DriveModel.torque`` adds the further forms)."""
    return viscous * v + coulomb * coulomb_sign(v, coulomb_velocity, shape)


def _error(message: str) -> Exception:
    from ..errors import InputError

    return InputError(message)


@dataclass(frozen=True)
class DriveModel:
    """Which friction forms each joint has (module docstring) and their smoothing velocities.

    Args:
        forms: a subset of ``FORMS`` (a ``+``-joined string is read too: ``"viscous+coulomb+offset"``).
        coulomb_velocity: ``v_c``, rad/s: the smoothing of Coulomb (and Stribeck) friction's sign.
        stribeck_velocity: ``v_s``, rad/s: how fast the breakaway fades.
        saturation_velocity: ``v_d``, rad/s: over which saturating friction moves the Coulomb level.
    """

    forms: tuple[str, ...] = ("viscous", "coulomb")
    coulomb_velocity: float = 0.02
    stribeck_velocity: float = 0.1
    saturation_velocity: float = 0.1

    @classmethod
    def of(cls, value=None, **kw) -> DriveModel:
        if isinstance(value, DriveModel):
            return value
        if isinstance(value, dict):
            kw = {**value, **kw}
            value = kw.pop("forms", None)
        forms = cls.forms if value is None else tuple(value.split("+") if isinstance(value, str) else value)
        unknown = [f for f in forms if f not in FORMS]
        if unknown or not forms or len(set(forms)) != len(forms):
            raise _error(f"drive model: forms must be distinct names among {', '.join(FORMS)}, got {list(forms)}")
        model = cls(tuple(f for f in FORMS if f in forms), **kw)
        for key in ("coulomb_velocity", "stribeck_velocity", "saturation_velocity"):
            if not getattr(model, key) > 0:
                raise _error(f"drive model: {key} must be positive, got {getattr(model, key)}")
        return model

    @property
    def name(self) -> str:
        return "+".join(self.forms)

    def saturation_floor(self) -> float:
        """``k``: saturating friction's ``d`` is passive down to ``-k c`` (``c`` the Coulomb level; ``k = min(1,
        v_d / v_c)``, 0 without Coulomb friction): ``c tanh(v / v_c) + d tanh(v / v_d)`` then keeps the sign of
        ``v`` (``x tanh(v / x)`` grows with ``x``)."""
        return min(1.0, self.saturation_velocity / self.coulomb_velocity) if "coulomb" in self.forms else 0.0

    def with_forms(self, forms) -> DriveModel:
        """This drive model's smoothing velocities with other ``forms`` (as ``of`` reads them)."""
        return DriveModel.of(forms, coulomb_velocity=self.coulomb_velocity, stribeck_velocity=self.stribeck_velocity,
                             saturation_velocity=self.saturation_velocity)

    @property
    def passive(self) -> bool:
        """Whether every form is passive (with its coefficients' signs; ``offset`` is not)."""
        return all(PASSIVE[f] for f in self.forms)

    @property
    def linear_forms(self) -> tuple[str, ...]:
        return tuple(f for f in self.forms if f in LINEAR)

    def coefficient_names(self) -> list[str]:
        return [c for f in self.forms for c in COEFFICIENTS[f]]

    # ------------------------------------------------------------------ the torque
    def shape(self, form: str, v: torch.Tensor, phi2=None, phi3=None) -> torch.Tensor:
        """The torque of ``form`` per unit of its linear coefficient at rates ``v (..., n_j)``."""
        if form == "viscous":
            return v
        sign = coulomb_sign(v, self.coulomb_velocity)
        if form == "coulomb":
            return sign
        if form == "offset":
            return torch.ones_like(v)
        if form == "stribeck":
            return sign * torch.exp(-((v / self.stribeck_velocity) ** 2))
        if form == "saturating":
            return torch.tanh(v / self.saturation_velocity)
        if form == "sigmoid":
            return torch.sigmoid(phi2 * (v + phi3)) - torch.sigmoid(phi2 * phi3)
        raise _error(f"unknown friction form {form!r}")

    def columns(self, v: torch.Tensor) -> torch.Tensor:
        """``(..., n_j, k)``: the shapes of the linear forms (``linear_forms``, in order) at ``v``."""
        return torch.stack([self.shape(f, v) for f in self.linear_forms], -1)

    def torque(self, v: torch.Tensor, coefficients: dict) -> torch.Tensor:
        """``f(v) (..., n_j)``: the friction torque at joint rates ``v`` for ``coefficients``
        (``{name: (..., n_j)}``, SI; ``coefficient_names``)."""
        zero = torch.zeros((), dtype=v.dtype, device=v.device)
        out = friction_torque(v, coefficients["b"] if "viscous" in self.forms else zero,
                              coefficients["c"] if "coulomb" in self.forms else zero, self.coulomb_velocity)
        for form in self.forms:
            if form in ("viscous", "coulomb"):
                continue
            if form == "sigmoid":
                out = out + coefficients["phi1"] * self.shape(form, v, coefficients["phi2"], coefficients["phi3"])
            else:
                out = out + coefficients[COEFFICIENTS[form][0]] * self.shape(form, v)
        return out
