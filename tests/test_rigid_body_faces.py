"""One rigid-body vocabulary: every object that holds a rigid body -- the learned network, the
LightningModule, the plant view of each, MuJoCo's arm and the classical identified model -- answers
``mass_matrix(q, params)``, ``bias(q, qd, params)`` and ``gravity(q, params)`` in SI (``params``: the
payload at the flange), and on the shipped arm, built from its description alone, they agree to
round-off in float64. Friction ``Q_f`` is compared where each face holds the description's damping."""

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")

from lnn_torch.control import plant_of  # noqa: E402
from lnn_torch.identification.arm_comparison import description_model  # noqa: E402
from lnn_torch.training import LNNModule  # noqa: E402

FACES = ("network", "module", "network plant", "mujoco", "mujoco plant", "classical")


@pytest.fixture(scope="module")
def faces():
    before = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)  # the network's constants made in float64 (as test_spatial_part)
    try:
            module = LNNModule(scene="robot_arm", variant="film_lnn", eps=0.0,
                           model_options={"kinetic": {"spatial": {"learn": False}}, "potential": {"spatial": {}}},
                           compile=False).double().eval()
    finally:
        torch.set_default_dtype(before)
    arm = module.system.arm
    return {"network": module.model, "module": module, "network plant": plant_of(module), "mujoco": arm,
            "mujoco plant": plant_of(arm), "classical": description_model(module.system)}


@pytest.fixture(scope="module")
def states(faces):
    arm = faces["mujoco"]
    rng = np.random.default_rng(0)
    q = torch.tensor(arm.sample_q(rng, 5))
    qd = torch.tensor(rng.normal(size=q.shape))
    payload = torch.tensor([[1.5, 0.02, -0.01, 0.06], [0.0, 0.0, 0.0, 0.0], [2.5, -0.03, 0.04, 0.02],
                            [0.7, 0.0, 0.0, 0.1], [3.0, 0.05, 0.05, 0.0]], dtype=torch.float64)
    return q, qd, payload


def _rel(a, b):
    return float((a - b).abs().max() / b.abs().max())


@pytest.mark.parametrize("quantity", ["mass_matrix", "bias", "gravity"])
def test_every_face_gives_the_same_rigid_body_in_si(faces, states, quantity):
    q, qd, payload = states
    args = {"mass_matrix": (q, payload), "bias": (q, qd, payload), "gravity": (q, payload)}[quantity]
    with torch.no_grad():
        values = {name: getattr(face, quantity)(*args) for name, face in faces.items()}
    reference = values["mujoco"]
    assert reference.abs().max() > 0.1  # newton metres (or kg m^2) of a real arm, not zeros
    for name in FACES:
        assert values[name].dtype == torch.float64, name
        assert _rel(values[name], reference) < 1e-12, (name, quantity, _rel(values[name], reference))


def test_the_faces_agree_on_the_descriptions_damping_and_inverse_dynamics(faces, states):
    q, qd, payload = states
    qdd = torch.randn(q.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    arm, classical = faces["mujoco"], faces["classical"]
    assert arm.damping.abs().max() > 0  # the shipped Panda's joints are damped
    for face in (faces["mujoco plant"], classical):
        assert _rel(face.friction(q, qd, payload), arm.friction(q, qd, payload)) < 1e-12
    assert _rel(classical.inverse(q, qd, qdd, payload), arm.inverse(q, qd, qdd, payload)) < 1e-12
    # M qdd + n - Q_f is the inverse dynamics on every face that holds friction
    for face in (arm, classical):
        M = face.mass_matrix(q, payload)
        rebuilt = (M @ qdd[..., None])[..., 0] + face.bias(q, qd, payload) - face.friction(q, qd, payload)
        assert _rel(rebuilt, face.inverse(q, qd, qdd, payload)) < 1e-12


def test_the_module_has_the_networks_whole_face_residual_included(faces, states):
    """Every quantity of the convention (``lnn_torch.networks.rigid_body``) on the module as on its network: the
    force residual too (zero without one), with the module's checked inputs."""
    from lnn_torch.errors import InputError

    q, qd, payload = states
    module, network = faces["module"], faces["network"]
    with torch.no_grad():
        for name, args in (("friction", (q, qd, payload)), ("residual_force", (q, qd, payload)),
                           ("energy", (q, qd, payload))):
            torch.testing.assert_close(getattr(module, name)(*args), getattr(network, name)(*args), rtol=0, atol=0)
        assert module.residual_force(q, qd, payload).abs().max() == 0  # (no residual in this model)
    with pytest.raises(InputError, match="params"):
        module.residual_force(q, qd, payload[:, :3])


def test_a_wrong_face_is_seen():
    """The comparison can fail: a classical model of a heavier arm differs by far more than the bound."""
    from lnn_torch.identification import ArmModel
    from lnn_torch.identification.classical_arm import description_parameters
    from lnn_torch.mechanics import DriveModel
    from lnn_torch.systems import get_system

    system = get_system("robot_arm")
    honest = description_model(system)
    heavy = ArmModel(honest.chain, DriveModel.of("viscous"), "heavier", honest.friction_coefficients,
                     pi=1.01 * description_parameters(honest.chain).numpy())
    q = torch.tensor(system.arm.sample_q(np.random.default_rng(2), 3))
    assert _rel(heavy.gravity(q), honest.gravity(q)) > 1e-3
