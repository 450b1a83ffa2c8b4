"""A tool (payload) that an arm's recordings carry at the flange, and what is known of it (``Tool``): its
row as the models read it (``ROW``: mass kg, centre of mass m in the flange frame, and for ten values the
inertia kg m^2 about the centre of mass), each entry known or to identify
(``lnn_torch.identification.payload.identify_tools``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError

ROW = ("mass", "x", "y", "z", "ixx", "iyy", "izz", "ixy", "ixz", "iyz")  # a payload row's entries (SI)
FIELDS = {"mass": slice(0, 1), "com": slice(1, 4), "inertia": slice(4, 10)}  # what a declaration may give
UNITS = ("kg", "m", "m", "m", "kg m^2", "kg m^2", "kg m^2", "kg m^2", "kg m^2", "kg m^2")


@dataclass(frozen=True)
class Tool:
    """A tool (payload) some recordings carry at the flange, and what is known of it.

    ``width``: 4 (a point mass: mass, centre of mass in the flange frame) or 10 (and its inertia about
    the centre of mass: ixx, iyy, izz, ixy, ixz, iyz); ``known``: the known entries' values by index of
    the row (``ROW``), the rest to identify."""

    name: str
    width: int
    known: dict

    @classmethod
    def declared(cls, name: str, value, width: int) -> Tool:
        """From an import declaration: a list (every value known, ``width`` long), or a mapping of what is
        known (``mass`` kg, ``com`` [3] m, ``inertia`` [6] kg m^2 about the centre of mass; ``{}``:
        nothing)."""
        if not isinstance(value, dict):
            values = [float(v) for v in value]
            if len(values) != width:
                raise InputError(f"import: tool {name!r} gives {len(values)} values; the payloads have {width}")
            return cls(name, width, dict(enumerate(values)))
        unknown = sorted(set(value) - set(FIELDS))
        if unknown:
            raise InputError(f"import: tool {name!r}: {', '.join(unknown)} is not a payload field (mass, com, "
                             "inertia)")
        if "inertia" in value and width != 10:
            raise InputError(f"import: tool {name!r} declares an inertia, but the payloads are point masses "
                             "(4 values)")
        known = {}
        for field_name, span in FIELDS.items():
            if field_name not in value or span.start >= width:
                continue
            values = np.atleast_1d(np.asarray(value[field_name], dtype=np.float64))
            size = span.stop - span.start
            if values.shape != (size,) or not np.isfinite(values).all():
                raise InputError(f"import: tool {name!r}: {field_name} needs {size} finite value(s), got "
                                 f"{value[field_name]!r}")
            known.update({span.start + k: float(v) for k, v in enumerate(values)})
        if 0 in known and known[0] <= 0:
            raise InputError(f"import: tool {name!r}: mass must be positive, got {known[0]}")
        return cls(name, width, known)

    @property
    def unknown(self) -> list[int]:
        """The row's indices to identify."""
        return [k for k in range(self.width) if k not in self.known]

    def row(self, theta: torch.Tensor) -> torch.Tensor:
        """The payload row ``(width,)`` with the unknown entries ``theta (len(unknown),)``."""
        base = torch.tensor([self.known.get(k, 0.0) for k in range(self.width)], dtype=theta.dtype)
        return base.index_put((torch.tensor(self.unknown, dtype=torch.long),), theta) if self.unknown else base

    def known_row(self) -> np.ndarray:
        """The row with what is known (zeros where unknown)."""
        return np.array([self.known.get(k, 0.0) for k in range(self.width)])

    def describe(self) -> str:
        if not self.unknown:
            return "known"
        if not self.known:
            return "nothing known"
        return "known: " + ", ".join(f for f, s in FIELDS.items() if all(k in self.known for k in
                                                                         range(s.start, min(s.stop, self.width)))
                                     and s.start < self.width)
