"""Parts of a structured Lagrangian and their registries.

A new kinetic or potential form is one class (a ``KineticPart`` or ``PotentialPart`` subclass, in its
own module here) plus one line in ``KINETIC_PARTS`` or ``POTENTIAL_PARTS``. The order of each
registry is the order in which a model builds, sums and concatenates its parts (it fixes the random
initialisation of a seed, so it is kept as it was).

A model names its parts in its options: ``kinetic: mlp``, ``kinetic: {chain: {links: [[1, 0], [1,
1]]}, mlp: {}}`` (a sum: the chain plus a Cholesky residual), ``potential: [harmonic, mlp]``;
``shared: true`` is the one part that gives both energies.
"""

from __future__ import annotations

import warnings

from ...errors import InputError
from .base import BuildContext, KineticPart, Part, PartInputs, PotentialPart, PotentialTerm, check_angles, part_options
from .chain import ChainGravity, RigidChain
from .cholesky import CholeskyMLP
from .harmonic import HarmonicSeries
from .potential_mlp import PotentialMLP
from .products import ProductSeries
from .shared import SharedMLP
from .spatial import SpatialChain, SpatialGravity

KINETIC_PARTS: dict[str, type[KineticPart]] = {"chain": RigidChain, "mlp": CholeskyMLP, "spatial": SpatialChain}
POTENTIAL_PARTS: dict[str, type[PotentialPart]] = {"mlp": PotentialMLP, "harmonic": HarmonicSeries,
                                                   "chain": ChainGravity, "spatial": SpatialGravity,
                                                   "products": ProductSeries}
SHARED_PART = SharedMLP  # both energies from one network

__all__ = ["KINETIC_PARTS", "POTENTIAL_PARTS", "SHARED_PART", "BuildContext", "Part", "KineticPart",
           "PotentialPart", "PartInputs", "PotentialTerm", "part_options", "parse_parts", "check_angles"]


def parse_parts(spec, role: str) -> dict[str, dict]:
    """A part specification -> ``{name: options}`` in the registry's order.

    ``spec``: a name (``"mlp"``), a list of names, or a dict of names to their options (None or ``{}``
    for none). The old sum strings (``"chain+mlp"``) still work, with a deprecation warning."""
    registry = KINETIC_PARTS if role == "kinetic" else POTENTIAL_PARTS
    if isinstance(spec, str):
        names = spec.split("+")
        if len(names) > 1:
            warnings.warn(f"{role}: {spec!r} is deprecated; name the parts as a dict, e.g. "
                          f"{role}: {{{', '.join(f'{n}: {{}}' for n in names)}}}", FutureWarning, stacklevel=4)
        spec = {n.strip(): {} for n in names}
    elif isinstance(spec, (list, tuple)):
        spec = {str(n): {} for n in spec}
    elif not isinstance(spec, dict):
        raise InputError(f"{role} must be a part name, a list of names or a dict of names to options, got {spec!r}")
    spec = {str(k): ({} if v is None else v) for k, v in spec.items()}
    if not spec:
        raise InputError(f"{role} names no part; known: {', '.join(registry)}")
    unknown = [n for n in spec if n not in registry]
    if unknown:
        raise InputError(f"unknown {role} part {', '.join(map(repr, unknown))}; known: {', '.join(registry)}")
    for name, opts in spec.items():
        if not isinstance(opts, dict):
            raise InputError(f"{role} part '{name}' takes a dict of options, got {opts!r}")
        known = [k for k in part_options(registry[name]) if k != "residual"]  # residual: set by the model
        bad = sorted(set(opts) - set(known))
        if bad:
            raise InputError(f"{role} part '{name}' takes no option {', '.join(map(repr, bad))}; its options: "
                             f"{', '.join(known) or 'none'}")
    return {n: dict(spec[n]) for n in registry if n in spec}
