"""The spatial arm parts (``kinetic: spatial``, ``potential: spatial``) against an established rigid-body
engine and independent references: MuJoCo's mass matrix, bias forces and accelerations of the shipped
Panda with and without a payload (float64, 1e-9 relative), the readable reference (autograd Jacobians of
the centres of mass and rotations) and the generic Hessian solve, the planar chain part as its special
case, and physical consistency for every value of the raw parameters."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

mujoco = pytest.importorskip("mujoco")

from lnn_torch.errors import InputError  # noqa: E402
from lnn_torch.mechanics.euler_lagrange import structured_acceleration_from_factor  # noqa: E402
from lnn_torch.networks import build_model  # noqa: E402
from lnn_torch.networks.base import SceneInfo  # noqa: E402
from lnn_torch.robots import kinematics  # noqa: E402
from lnn_torch.robots.mujoco_arm import MujocoArm  # noqa: E402

from .helpers import assert_fast_path_is_the_references  # noqa: E402

ARM = SceneInfo.of({"name": "robot_arm", "dof": 7, "angle_mask": [True] * 7,
                    "param_names": ["payload_mass", "payload_x", "payload_y", "payload_z"],
                    "param_kinds": ["nonnegative", "real", "real", "real"], "input_matrix": np.eye(7).tolist(),
                    "friction": "joint", "joint_map": np.eye(7).tolist(), "config": {"description": "franka_panda"}})


@pytest.fixture(scope="module")
def arm():
    return MujocoArm("franka_panda")


@pytest.fixture
def float64():
    old = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)  # the part's raw parameters exactly the description's
    yield
    torch.set_default_dtype(old)


def _batch(arm, n=8, seed=0):
    rng = np.random.default_rng(seed)
    q = torch.tensor(arm.sample_q(rng, n))
    qd, qdd, tau = (torch.tensor(rng.normal(size=(n, 7))) for _ in range(3))
    payload = torch.tensor(np.c_[rng.uniform(0, 3, n), rng.uniform(-0.05, 0.05, (n, 2)), rng.uniform(0, 0.1, n)])
    return q, qd, qdd, tau, payload


def _grey_box(**kw):
    return build_model("film_lnn", ARM, kinetic={"spatial": kw}, potential={"spatial": {}}, eps=0.0)


def _rel(a, b):
    return float((a - b).detach().abs().max() / b.abs().max())


@pytest.mark.parametrize("with_payload", [False, True])
def test_mass_matrix_bias_and_gravity_are_the_engines(arm, float64, with_payload):
    model = _grey_box().double()
    q, qd, _, _, payload = _batch(arm)
    if not with_payload:
        payload = torch.zeros_like(payload)
    pn = model.normalizer.params(payload)
    F, dF = model.cholesky(q, pn, tangents=True)
    M = F @ F.mT
    assert _rel(M, arm.mass_matrix(q, payload)) < 1e-9
    _, dV = model.potential_norm(q, pn, grad=True)
    assert _rel(dV, arm.gravity(q, payload)) < 1e-9
    free = structured_acceleration_from_factor(F, dF, qd, dV, 0.0)
    bias = -(M @ free[..., None])[..., 0]  # Coriolis, centrifugal and gravity
    assert _rel(bias, arm.bias(q, qd, payload)) < 1e-9
    coriolis = bias - dV
    assert _rel(coriolis, arm.bias(q, qd, payload) - arm.gravity(q, payload)) < 1e-9


def test_with_the_true_parameters_the_grey_box_has_the_engines_accelerations_and_torques(arm, float64):
    """The description's inertia, armature and viscous damping as the learned friction: forward and
    inverse dynamics equal MuJoCo's (the payload a scene parameter per state)."""
    model = _grey_box().double()
    forces = model.forces
    with torch.no_grad():  # friction b = damping (softplus^-1 of b / unit), Coulomb c ~ 0
        b = torch.as_tensor(arm.damping) / forces.units[0]
        forces.coefficient_net[-1].bias.copy_(torch.cat([b + torch.log(-torch.expm1(-b)), torch.full((7,), -60.0)]))
    q, qd, qdd, tau, payload = _batch(arm, seed=1)
    assert _rel(model.acceleration(q, qd, payload, tau), arm.forward(q, qd, tau, payload)) < 1e-9
    assert _rel(model.inverse(q, qd, qdd, payload), arm.inverse(q, qd, qdd, payload)) < 1e-9


def test_a_payload_beyond_the_training_range_is_taken_exactly(arm, float64):
    """The payload is a rigid body on the last link, not a network's input: trained on 0-2 kg, the grey
    box's torques at 9 and 30 kg are still the engine's (no clamp to the networks' trusted range, no
    warning), and the trusted range says so."""
    model = _grey_box().double()
    q, qd, qdd, _, payload = _batch(arm, n=6, seed=3)
    train = payload.clone()
    train[:, 0] = torch.linspace(0.0, 2.0, 6)
    model.fit_normalizer({"q": q, "qd": qd, "qdd": qdd, "params": train})
    heavy = payload.clone()
    heavy[:3, 0], heavy[3:, 0] = 9.0, 30.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tau = model.gravity(q, heavy)
    assert _rel(tau, arm.gravity(q, heavy)) < 1e-9
    low, high = model.normalizer.trusted_range()
    assert torch.isinf(low).all() and torch.isinf(high).all()
    # the networks beside it (here the friction coefficients' network) still read the trusted range
    with torch.no_grad():
        model.forces.coefficient_net[-1].weight.normal_(0.0, 0.5)
    far = heavy.clone()
    far[:, 0] = 300.0
    pn_heavy, pn_far = model.normalizer.params(heavy[3:]), model.normalizer.params(far[3:])
    torch.testing.assert_close(model.forces.coefficients(pn_heavy)[0], model.forces.coefficients(pn_far)[0])
    assert not torch.allclose(model.gravity(q[3:], heavy[3:]), model.gravity(q[3:], far[3:]))


@pytest.mark.parametrize("residual", [False, True])
def test_the_fast_path_is_the_reference_and_the_generic_solve(arm, residual):
    """Away from the description (random raw inertial parameters), with or without the neural residual
    parts: the hand-carried tangents give the accelerations of the readable reference's Lagrangian by
    the generic Hessian solve."""
    kinetic, potential = {"spatial": {}}, {"spatial": {}}
    if residual:
        kinetic["mlp"], potential["mlp"] = {}, {}
    sizes = {"hidden_dims": (8, 8)} if residual else {}
    model = build_model("film_lnn", ARM, kinetic=kinetic, potential=potential, **sizes).double()
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.2 * torch.randn(p.shape, dtype=p.dtype, generator=gen))
    q, qd, _, _, payload = _batch(arm, n=4, seed=2)
    assert_fast_path_is_the_references(model, ARM, *model.normalize(q, qd, payload))


def test_every_raw_value_is_a_physically_consistent_arm():
    """Masses positive, inertias about the centres of mass positive definite and within the triangle
    inequality, armature positive — for any raw parameters."""
    model = _grey_box()
    part = model.kinetic["spatial"]
    with torch.no_grad():
        part.raw.copy_(3 * torch.randn(part.raw.shape, generator=torch.Generator().manual_seed(1)))
        part.log_armature.copy_(-5 * torch.rand(7))
    report = part.si_report()
    assert (report["mass"] > 0).all() and (report["armature"] > 0).all()
    eig = torch.linalg.eigvalsh(report["inertia"])  # ascending principal moments
    assert (eig > 0).all()
    assert (eig[:, 0] + eig[:, 1] >= eig[:, 2] * (1 - 1e-9)).all()


def test_the_description_alone_learns_nothing():
    model = _grey_box(learn=False)
    assert not list(model.kinetic["spatial"].parameters())
    report = model.kinetic["spatial"].si_report()
    chain = kinematics.read_chain(MujocoArm().model)
    torch.testing.assert_close(report["pseudo_inertia"], chain.J)


PLANAR = """<mujoco><compiler angle="radian"/><option gravity="0 0 -9.81"/><worldbody>
  <body name="l1"><joint name="j1" axis="0 -1 0" armature="{a1}"/>
    <inertial mass="{m1}" pos="{b1} 0 {a1_}" diaginertia="0.04 {i1} 0.03"/>
    <body name="l2" pos="0 0 -{l1}"><joint name="j2" axis="0 -1 0" armature="{a2}"/>
      <inertial mass="{m2}" pos="{b2} 0 {a2_}" diaginertia="0.015 {i2} 0.01"/></body></body>
</worldbody></mujoco>"""


def test_the_planar_chain_is_the_special_case(tmp_path, float64, rng):
    """A planar two-link arm written as a robot description: the spatial part's mass matrix and gravity
    equal the planar chain part's with the same masses, centres of mass, length, link inertias and rotor
    inertias (joint-relative angles from the downward vertical)."""
    v = dict(m1=1.3, m2=0.7, a1=0.21, b1=0.03, a2=0.17, b2=-0.02, l1=0.4, i1=0.05, i2=0.02, r1=0.011, r2=0.007)
    path = tmp_path / "planar.xml"
    path.write_text(PLANAR.format(a1=v["r1"], a2=v["r2"], m1=v["m1"], m2=v["m2"], b1=v["b1"], b2=v["b2"],
                                  a1_=-v["a1"], a2_=-v["a2"], l1=v["l1"], i1=v["i1"], i2=v["i2"]))
    scene = {"name": "planar_arm", "dof": 2, "angle_mask": [True, True], "param_names": [], "config": {}}
    spatial = build_model("film_lnn", scene, kinetic={"spatial": {"description": str(path)}},
                          potential={"spatial": {}}, eps=0.0).double()
    chain = build_model("film_lnn", scene, kinetic={"chain": {"links": [[1, 0], [1, 1]]}}, potential="chain",
                        eps=0.0).double()
    K = torch.tensor([[v["i1"] + v["i2"] + v["r1"], v["i2"]], [v["i2"], v["i2"] + v["r2"]]])
    L = torch.linalg.cholesky(K)
    softplus_inv = lambda x: x + torch.log(-torch.expm1(-x))  # noqa: E731
    with torch.no_grad():
        chain.kinetic["chain"].raw.copy_(torch.tensor([
            np.log(v["m1"]), np.log(v["m2"]), v["a1"], v["a2"], v["b1"], v["b2"], v["l1"],
            float(softplus_inv(L[0, 0])), float(L[1, 0]), float(softplus_inv(L[1, 1]))]))
    q = torch.tensor(rng.uniform(-3, 3, (16, 2)))
    p = torch.zeros(16, 0)
    torch.testing.assert_close(spatial.mass_matrix_norm(q, p), chain.mass_matrix_norm(q, p), rtol=1e-12, atol=1e-12)
    (Vs, dVs), (Vc, dVc) = spatial.potential_norm(q, p, grad=True), chain.potential_norm(q, p, grad=True)
    torch.testing.assert_close(dVs, dVc, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(Vs - Vs[0], Vc - Vc[0], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("body, message", [
    ('<body name="l1"><joint type="slide" axis="1 0 0"/><inertial mass="1" pos="0 0 0" diaginertia="1 1 1"/></body>',
     "not a hinge"),
    ('<body name="l1"><joint axis="1 0 0"/><inertial mass="1" pos="0 0 0" diaginertia="1 1 1"/>'
     '<body name="a"><joint axis="1 0 0"/><inertial mass="1" pos="0 0 0" diaginertia="1 1 1"/></body>'
     '<body name="b"><joint axis="1 0 0"/><inertial mass="1" pos="0 0 0" diaginertia="1 1 1"/></body></body>',
     "branches"),
])
def test_unsupported_descriptions_are_refused_in_one_line(tmp_path, body, message):
    path = tmp_path / "arm.xml"
    path.write_text(f"<mujoco><worldbody>{body}</worldbody></mujoco>")
    model = mujoco.MjModel.from_xml_path(str(path))
    with pytest.raises(InputError, match=message) as err:
        kinematics.read_chain(model)
    assert "\n" not in str(err.value)


def test_bad_part_options_are_refused_in_one_line(tmp_path):
    scene = {"name": "planar_arm", "dof": 3, "angle_mask": [True] * 3, "param_names": [], "config": {}}
    with pytest.raises(InputError, match="needs a robot description"):
        build_model("film_lnn", scene, kinetic="spatial")
    with pytest.raises(InputError, match="has 7 joints"):
        build_model("film_lnn", scene, kinetic={"spatial": {"description": "franka_panda"}})
    with pytest.raises(InputError, match="needs the kinetic part 'spatial'"):
        build_model("film_lnn", ARM, potential="spatial")


def test_identification_with_the_exact_part_recovers_the_payload(arm, float64):
    """Noise-free engine data (states with the engine's accelerations under the recorded torques) and
    the grey box with the description's parameters and damping: ``identify`` recovers the payload's
    mass and centre of mass to 1e-6."""
    from lnn_torch.identification.learned import identify
    from lnn_torch.systems import get_system

    system = get_system("robot_arm")
    model = _grey_box().double()
    rng = np.random.default_rng(7)
    params = torch.tensor(system.sample_params(rng, 64))
    model.fit_normalizer({"q": torch.zeros(1, 7), "qd": torch.zeros(1, 7), "qdd": torch.ones(1, 7), "params": params})
    forces = model.forces
    with torch.no_grad():
        b = torch.as_tensor(arm.damping) / forces.units[0]
        forces.coefficient_net[-1].bias.copy_(torch.cat([b + torch.log(-torch.expm1(-b)), torch.full((7,), -60.0)]))
    truth = torch.tensor([1.7, 0.02, -0.03, 0.06])
    n = 200
    q = torch.tensor(arm.sample_q(rng, n))
    qd, tau = torch.tensor(rng.normal(size=(n, 7))), torch.tensor(rng.normal(scale=5.0, size=(n, 7)))
    qdd = arm.forward(q, qd, tau, truth)
    found = identify(model, system, np.arange(n) * 0.01, q.numpy(), qd.numpy(), tau.numpy(), qdd.numpy(), starts=2)
    estimate = torch.tensor([found.params[name] for name in system.param_names])
    assert (estimate - truth).abs().max() < 1e-6, estimate - truth


def test_the_grey_box_starts_its_friction_at_the_descriptions_damping(arm):
    """After the normaliser is fitted (the force units set), the joint friction of a model with the
    spatial part is the description's viscous damping with a negligible Coulomb level."""
    model = _grey_box()
    q, qd, qdd, tau, payload = _batch(arm, n=64)
    model.fit_normalizer({"q": q, "qd": qd, "qdd": qdd, "params": payload, "tau": 20 * tau})
    b, c = model.forces.coefficients(model.normalizer.params(payload[:1].float()))
    torch.testing.assert_close(b[0].double(), arm.damping, rtol=1e-5, atol=0)
    assert (c < 1e-3 * 20).all()


TWO_LINK_URDF = """<robot name="two">
  <link name="base"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>
  </inertial></link>
  <link name="l1"><inertial><mass value="2"/><origin xyz="0.01 0 0.2"/>
    <inertia ixx="0.02" iyy="0.03" izz="0.015" ixy="0" ixz="0.001" iyz="0"/></inertial></link>
  <link name="l2"><inertial><mass value="1.5"/><origin xyz="0.1 0 0.1"/>
    <inertia ixx="0.015" iyy="0.02" izz="0.015" ixy="0.001" ixz="0" iyz="0"/></inertial></link>
  <link name="tool0"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.4" rpy="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="2"/></joint>
  <joint name="flange" type="fixed"><parent link="l2"/><child link="tool0"/><origin xyz="0.3 0 0"/></joint>
</robot>
"""


@pytest.mark.parametrize("which", ["urdf", "panda without hand, armature and damping zero", "panda with a tool"])
@pytest.mark.parametrize("with_payload", [False, True])
def test_any_description_alone_is_the_engine_through_the_si_face(tmp_path, float64, which, with_payload):
    """``learn: false`` on a description that is not the shipped one as written (a URDF without rotors,
    the Panda with its hand removed and armature 0, the Panda carrying a tool): the model's SI rigid-body
    face (mass matrix, bias, gravity) equals MuJoCo's to 1e-12 relative, with and without a payload."""
    if which == "urdf":
        path = tmp_path / "two.urdf"
        path.write_text(TWO_LINK_URDF)
        description = {"source": str(path), "flange": "tool0"}
    elif which.startswith("panda without"):
        description = {"source": "franka_panda", "remove": ["hand"], "armature": "zero", "damping": "zero"}
    else:
        description = {"source": "franka_panda", "tool": [0.9, 0.01, 0.0, 0.04, 0.003, 0.004, 0.002, 0, 0, 0]}
    engine = MujocoArm(description)
    n = engine.dof
    scene = SceneInfo.of({"name": "arm", "dof": n, "angle_mask": [True] * n,
                          "param_names": ["payload_mass", "payload_x", "payload_y", "payload_z"],
                          "param_kinds": ["nonnegative", "real", "real", "real"], "input_matrix": np.eye(n).tolist(),
                          "config": {"description": description}})
    model = build_model("film_lnn", scene, kinetic={"spatial": {"learn": False}}, potential={"spatial": {}},
                        eps=0.0).double()
    rng = np.random.default_rng(3)
    q = torch.tensor(engine.sample_q(rng, 6))
    qd = torch.tensor(rng.normal(size=(6, n)))
    payload = torch.tensor([[1.2, 0.02, -0.01, 0.05]] * 6) if with_payload else torch.zeros(6, 4)
    assert _rel(model.mass_matrix(q, payload), engine.mass_matrix(q, payload)) < 1e-12
    assert _rel(model.bias(q, qd, payload), engine.bias(q, qd, payload)) < 1e-12
    assert _rel(model.gravity(q, payload), engine.gravity(q, payload)) < 1e-12
    if "armature and damping zero" in which:
        assert float(model.kinetic["spatial"].armature().abs().max()) == 0.0


def test_the_prior_is_the_logdet_divergence_from_the_description(float64):
    """``prior`` adds ``w sum_i [tr(J0^-1 J) - log det(J0^-1 J) - 4]``: zero at the description, positive
    away from it, the written-out formula at any raw value; without ``prior`` no term."""
    model = _grey_box(prior=0.3).double()
    part = model.kinetic["spatial"]
    assert float(model.regularization()) == pytest.approx(0.0, abs=1e-10)
    with torch.no_grad():
        part.raw.add_(0.1 * torch.randn_like(part.raw, generator=torch.Generator().manual_seed(0)))
    J, J0 = part.link_J(), part.const("nominal_J", part.raw)
    A = torch.linalg.solve(J0, J)
    expected = 0.3 * (A.diagonal(dim1=-2, dim2=-1).sum(-1) - torch.logdet(A) - 4).sum()
    assert float(model.regularization()) == pytest.approx(float(expected), rel=1e-10) and float(expected) > 0
    assert _grey_box().regularization() is None
