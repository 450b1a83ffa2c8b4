"""What a model can give beyond accelerations and rollouts, and how a caller asks.

A model class declares its capabilities in ``provides``; a model's ``capabilities`` keeps those its
scene allows (``DynamicsModel.capabilities``). Evaluation, control, export and training ask only
these, never ``hasattr``. Any object with ``acceleration`` and ``rollout`` (a scene's closed form, an
identified model) is a model too; one that declares nothing provides accelerations and rollouts only.
"""

from __future__ import annotations

ENERGY = "energy"  # its own energy H = T + V: ``energy(q, qd, params)``
# the rigid-body face (``lnn_torch.networks.rigid_body``): ``mass_matrix``, ``bias``, ``gravity``
# (and ``mass_matrix(q, params)``, normalised)
MASS_MATRIX = "mass_matrix"
# ``inverse(q, qd, qdd, params)`` (alias ``inverse_dynamics``), ``input_force``: needs inputs
INVERSE_DYNAMICS = "inverse_dynamics"
FRICTION = "friction"  # learned joint friction: ``friction_torque``, ``friction_coefficients``; needs friction
STATIC_FRICTION = "static_friction"  # holding torques at rest (``dissipation: joint+stiction``)
NAN_ON_SINGULAR = "nan_on_singular"  # accelerations can be undefined; NaN there within ``nan_on_singular()``
# the scene's generalised forces (inputs B tau, dissipation Q_f) apart from the model's own dynamics
# (``lnn_torch.networks.forces.LearnedForces``): ``friction``; needs a scene with inputs or friction
FORCES = "forces"
CAPABILITIES = (ENERGY, MASS_MATRIX, INVERSE_DYNAMICS, FRICTION, STATIC_FRICTION, NAN_ON_SINGULAR, FORCES)


def capabilities_of(model) -> frozenset:
    """A model's declared capabilities (``DynamicsModel.capabilities``); an object that declares none
    gives accelerations and rollouts only."""
    return frozenset(getattr(model, "capabilities", frozenset()))


def missing(model, needs) -> str | None:
    """Why ``model`` cannot give the capabilities ``needs`` (a sentence), or None if it can. A model
    that explains itself (``DynamicsModel.missing``: what its scene rules out) is asked."""
    lacking = [c for c in needs if c not in capabilities_of(model)]
    if not lacking:
        return None
    explain = getattr(model, "missing", None)
    if callable(explain):
        return explain(*lacking)
    return f"variant '{getattr(model, 'variant', type(model).__name__)}' does not provide {', '.join(lacking)}"
