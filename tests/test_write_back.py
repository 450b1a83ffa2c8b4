"""The identified arm handed back as its robot description (``lnn_torch.export.description``, ``lnn-torch export
--format mjcf|urdf``): MuJoCo loaded from the written MJCF or URDF has the model's rigid-body dynamics (mass
matrix, bias, gravity, ``M qdd + bias``) to 1e-9 relative in float64 (measured: about 1e-14) for a grey box
perturbed away from its description, with and without a payload, with a tool and a removed hand, and for a
classical fit; what the format cannot express is listed (printed, in the file's comment, in the sidecar);
nothing else in the file changes; a model without a spatial part is refused in one line. Each comparison can
fail: the description itself is far from the model, and a wrong frame conversion is caught. About 15 s."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest
import torch

mujoco = pytest.importorskip("mujoco")

from lnn_torch.errors import InputError  # noqa: E402
from lnn_torch.export import description as wb  # noqa: E402
from lnn_torch.networks import build_model  # noqa: E402
from lnn_torch.networks.base import SceneInfo  # noqa: E402
from lnn_torch.robots.description import ArmDescription  # noqa: E402
from lnn_torch.robots.kinematics import read_chain  # noqa: E402
from lnn_torch.robots.mujoco_arm import MujocoArm  # noqa: E402
from lnn_torch.robots.shipped import DESCRIPTIONS  # noqa: E402

from .helpers import save_checkpoint  # noqa: E402

BOUND = 1e-9  # the bound (float64)
TOOL = [0.9, 0.01, -0.005, 0.04, 0.003, 0.004, 0.002, 0.0002, -0.0001, 0.00005]
PANDAS = {"panda": "franka_panda",
          "panda with a tool, hand removed": {"source": "franka_panda", "remove": ["hand"], "tool": TOOL}}
PAYLOAD = [1.3, 0.02, -0.01, 0.06]

TWO_LINK_URDF = """<?xml version="1.0"?>
<!-- a two-link arm -->
<robot name="two">
  <link name="base"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>
  </inertial></link>
  <link name="l1">
    <inertial><mass value="2"/><origin xyz="0.01 0 0.2" rpy="0.1 0.2 0.3"/>
      <inertia ixx="0.02" iyy="0.03" izz="0.015" ixy="0" ixz="0.001" iyz="0"/></inertial>
    <visual><geometry><cylinder radius="0.03" length="0.4"/></geometry></visual>
  </link>
  <link name="l2"><inertial><mass value="1.5"/><origin xyz="0.1 0 0.1"/>
    <inertia ixx="0.015" iyy="0.02" izz="0.015" ixy="0.001" ixz="0" iyz="0"/></inertial></link>
  <link name="tool0"><inertial><mass value="0.4"/><origin xyz="0.02 0.01 0.03" rpy="0.3 -0.2 0.5"/>
    <inertia ixx="0.002" iyy="0.0025" izz="0.001" ixy="0.0001" ixz="0" iyz="0"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.4" rpy="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="2"/>
    <dynamics damping="0.5" friction="0.2"/></joint>
  <joint name="flange" type="fixed"><parent link="l2"/><child link="tool0"/>
    <origin xyz="0.3 0 0" rpy="0 0.4 0"/></joint>
</robot>
"""


@pytest.fixture
def float64():
    old = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)  # the parts' raw parameters made in float64
    yield
    torch.set_default_dtype(old)


def _scene(description, dof=7):
    return SceneInfo.of({"name": "arm", "dof": dof, "angle_mask": [True] * dof,
                         "param_names": ["payload_mass", "payload_x", "payload_y", "payload_z"],
                         "param_kinds": ["nonnegative", "real", "real", "real"], "input_matrix": np.eye(dof).tolist(),
                         "friction": "joint", "joint_map": np.eye(dof).tolist(),
                         "config": {"description": description}})


def _grey_box(description, dof=7, seed=0, scale=0.05, **options):
    """A grey box of ``description`` (eps default: folded into the armature), its links, armature and
    friction moved away from the description's."""
    model = build_model("film_lnn", _scene(description, dof), kinetic={"spatial": {}}, potential={"spatial": {}},
                        **options).double()
    part = model.kinetic["spatial"]
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        part.raw[:, :4] += scale * torch.randn(part.raw[:, :4].shape, generator=g)
        part.raw[:, 4:] *= 1 + scale * torch.randn(part.raw[:, 4:].shape, generator=g)
        part.raw[:, 4:] += 0.1 * scale * torch.randn(part.raw[:, 4:].shape, generator=g)
        part.log_armature += 0.3 * torch.randn(dof, generator=g)
        forces = model.forces
        b = 0.2 + torch.rand(dof, generator=g)  # N m s/rad (units 1: normaliser not fitted)
        c = 0.1 + 0.5 * torch.rand(dof, generator=g)
        raw = torch.cat([b + torch.log(-torch.expm1(-b)), c + torch.log(-torch.expm1(-c))])
        forces.coefficient_net[-1].bias[: 2 * dof].copy_(raw)
    return model


def _states(arm, n=8, seed=0):
    rng = np.random.default_rng(seed)
    q = torch.tensor(arm.sample_q(rng, n))
    return q, torch.tensor(rng.normal(size=q.shape)), torch.tensor(rng.normal(size=q.shape))


def _rel(a, b):
    return float((a - b).detach().abs().max() / b.detach().abs().max())


def _compare(model, arm, params, seed=0) -> dict:
    """The model's rigid-body face against MuJoCo's from the written file: relative errors."""
    q, qd, qdd = _states(arm, seed=seed)
    p = params.expand(len(q), -1)
    with torch.no_grad():
        M, n = model.mass_matrix(q, p), model.bias(q, qd, p)
        return {"mass_matrix": _rel(arm.mass_matrix(q), M), "bias": _rel(arm.bias(q, qd), n),
                "gravity": _rel(arm.gravity(q), model.gravity(q, p)),
                "inverse": _rel(arm.inverse(q, qd, qdd, damping=False), (M @ qdd[..., None])[..., 0] + n)}


@pytest.mark.parametrize("with_payload", [False, True])
@pytest.mark.parametrize("which", list(PANDAS))
def test_mujoco_from_the_written_mjcf_is_the_grey_box(tmp_path, float64, which, with_payload):
    description = PANDAS[which]
    model = _grey_box(description)
    payload = torch.tensor(PAYLOAD) if with_payload else torch.zeros(4)
    result = wb.write_description(model, tmp_path / "out" / "arm.xml", payload=PAYLOAD if with_payload else None)
    assert not [n for n in result.notes if "not a rigid body" in n]  # welded bodies kept as written
    arm = MujocoArm(str(result.path))
    errors = _compare(model, arm, payload[None])
    print(which, "payload" if with_payload else "no payload", errors)
    assert max(errors.values()) < BOUND, errors
    # the comparison can fail: the description itself is far from the model
    assert _rel(MujocoArm(description).mass_matrix(_states(arm)[0], payload[None]),
                model.mass_matrix(_states(arm)[0], payload[None].expand(8, -1))) > 1e-2
    # the joints: armature (eps folded in), viscous damping b, friction loss = Coulomb level c
    b, c = model.forces.coefficients(model.normalizer.params(payload[None]))
    torch.testing.assert_close(torch.as_tensor(arm.model.dof_damping), b[0], rtol=1e-15, atol=0)
    torch.testing.assert_close(torch.as_tensor(arm.model.dof_frictionloss), c[0], rtol=1e-15, atol=0)
    # with the joints' damping: the model's inverse dynamics less its smooth Coulomb friction
    q, qd, qdd = _states(arm, seed=1)
    p = payload[None].expand(len(q), -1)
    coulomb = c * torch.tanh(qd / model.forces.coulomb_velocity)
    assert _rel(arm.inverse(q, qd, qdd), model.inverse(q, qd, qdd, p) - coulomb) < BOUND
    # the written file is a description the project reads: a grey box of it alone is the model
    again = build_model("film_lnn", _scene(str(result.path)), kinetic={"spatial": {"learn": False}},
                        potential={"spatial": {}}, eps=0.0).double()
    rest = torch.zeros_like(p)
    assert _rel(again.mass_matrix(q, rest), model.mass_matrix(q, rest)) < BOUND
    assert _rel(again.gravity(q, rest), model.gravity(q, rest)) < BOUND
    record = json.loads(result.sidecar.read_text())
    assert record["payload"] == (PAYLOAD if with_payload else None)
    assert record["check"]["largest_relative_difference"] < BOUND


def test_the_payload_and_a_heavy_change_of_a_welded_link(tmp_path, float64):
    """A full payload (ten values, flange frame) is MuJoCo's own payload at the flange; a change the
    moving body cannot carry beside its welded hand puts the whole link in the moving body (noted)."""
    payload = [1.1, 0.03, -0.02, 0.05, 0.004, 0.006, 0.003, 0.0004, -0.0002, 0.0001]
    model = _grey_box("franka_panda", seed=3, scale=0.3)
    full = wb.write_description(model, tmp_path / "full.xml", payload=payload)
    light = wb.write_description(model, tmp_path / "light.xml", payload=payload[:4])
    assert any(n.startswith("link7:") and "hand" in n for n in light.notes), light.notes
    errors = _compare(model, MujocoArm(str(light.path)), torch.tensor(payload[:4])[None])
    print("heavy change", errors)
    assert max(errors.values()) < BOUND, errors
    # the payload's inertia (the model takes four values): as MuJoCo's own payload at the flange
    q = _states(MujocoArm("franka_panda"))[0]
    nominal = MujocoArm("franka_panda")
    extra = MujocoArm(str(full.path)).mass_matrix(q) - MujocoArm(str(light.path)).mass_matrix(q)
    expected = nominal.mass_matrix(q, torch.tensor([payload])) - nominal.mass_matrix(q, torch.tensor([payload[:4]]))
    assert _rel(extra, expected) < 1e-9 and expected.abs().max() > 1e-4


def test_mujoco_from_the_written_urdf_is_the_grey_box(tmp_path, float64):
    """A URDF (a welded flange link with its own rotated inertial) written back as URDF, read by MuJoCo:
    the model's rigid body once the armature the sidecar lists is set (URDF has no armature)."""
    source = tmp_path / "two.urdf"
    source.write_text(TWO_LINK_URDF)
    description = {"source": str(source), "flange": "tool0"}
    model = _grey_box(description, dof=2, seed=1)
    result = wb.write_description(model, tmp_path / "out" / "two_identified.urdf", payload=PAYLOAD)
    assert result.format == "urdf" and result.unexpressed[0].startswith("armature")
    assert not [n for n in result.notes if "not a rigid body" in n]
    arm = MujocoArm(str(result.path))
    # read back with the flange it was built with: the payload body written there is the payload's place
    again = MujocoArm({"source": str(result.path), "flange": "tool0"})
    assert again.model.body_parentid[again.payload_id] == arm.model.body_parentid[arm.payload_id]
    armature = json.loads(result.sidecar.read_text())["not_expressed"][0]["values"]
    q = _states(arm)[0]
    without = _rel(arm.mass_matrix(q), model.mass_matrix(q, torch.tensor([PAYLOAD]).expand(8, -1)))
    arm.model.dof_armature[:] = [armature[n] for n in ("j1", "j2")]
    errors = _compare(model, arm, torch.tensor(PAYLOAD)[None])
    again.model.dof_armature[:] = arm.model.dof_armature
    torch.testing.assert_close(again.mass_matrix(q), arm.mass_matrix(q), rtol=0, atol=0)
    print("urdf", errors, "without the armature", without)
    assert max(errors.values()) < BOUND, errors
    assert without > 1e-5  # the armature matters: listed, not dropped
    b, c = model.forces.coefficients(model.normalizer.params(torch.tensor([PAYLOAD])))
    torch.testing.assert_close(torch.as_tensor(arm.model.dof_damping), b[0], rtol=1e-15, atol=0)
    torch.testing.assert_close(torch.as_tensor(arm.model.dof_frictionloss), c[0], rtol=1e-15, atol=0)
    # the rest of the URDF as written: every element but the inertials and the joints' dynamics
    written = wb._parse(result.path.read_text())
    original = wb._parse(TWO_LINK_URDF)

    def rest(root):
        return [(el.tag, dict(el.attrib)) for el in root.iter() if el.tag not in
                ("inertial", "origin", "mass", "inertia", "dynamics") and not callable(el.tag)]

    added = [("link", {"name": "payload"}), ("joint", {"name": "payload_joint", "type": "fixed"}),
             ("parent", {"link": "tool0"}), ("child", {"link": "payload"})]
    assert rest(written) == rest(original) + added
    joint_origins = lambda root: [dict(j.find("origin").attrib) for j in root.iter("joint")  # noqa: E731
                                  if j.find("origin") is not None]
    assert joint_origins(written) == joint_origins(original)
    assert result.path.read_text().startswith('<?xml version="1.0"?>\n<!-- a two-link arm -->\n<robot name="two">')
    # as MJCF: MuJoCo's own conversion of the URDF write-back with the armature set, the model's rigid body as it is
    mjcf = wb.write_description(model, tmp_path / "out" / "two_identified.xml", "mjcf", payload=PAYLOAD)
    assert mjcf.format == "mjcf" and not [u for u in mjcf.unexpressed if u.startswith("armature")]
    converted = MujocoArm(str(mjcf.path))
    errors = _compare(model, converted, torch.tensor(PAYLOAD)[None])
    print("urdf as mjcf", errors)
    assert max(errors.values()) < BOUND, errors
    assert json.loads(mjcf.sidecar.read_text())["format"] == "mjcf"
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["two_identified.urdf", "two_identified.urdf.json",
                                                                    "two_identified.xml", "two_identified.xml.json"]
    assert not [n for n in mjcf.notes if "elements are not in the MJCF" in n]
    # a URDF's elements MuJoCo does not read (a transmission, Gazebo's tags): the URDF write-back keeps them, the
    # MJCF says it has not
    extra = ('  <transmission name="t1"><type>transmission_interface/SimpleTransmission</type>'
             '<joint name="j1"/></transmission>\n  <gazebo reference="l1"><material>Gazebo/Grey</material></gazebo>\n'
             '  <gazebo/>\n</robot>')
    source.write_text(TWO_LINK_URDF.replace("</robot>", extra))
    kept = wb.write_description(model, tmp_path / "more" / "two.urdf", payload=PAYLOAD)
    assert "<transmission name=\"t1\">" in kept.path.read_text() and "Gazebo/Grey" in kept.path.read_text()
    mjcf = wb.write_description(model, tmp_path / "more" / "two.xml", "mjcf", payload=PAYLOAD)
    assert "the URDF's <gazebo> (2), <transmission> (1) elements are not in the MJCF" in " ".join(mjcf.notes)


def test_a_urdf_whose_meshes_are_not_there_is_written_back_with_them(tmp_path, float64):
    """A URDF as a ROS package ships it (collision meshes named ``package://...``, not there): the grey box
    is built from its inertials, the file written back keeps every mesh reference as written (its notes say so and
    how to read it here), and MuJoCo from it (the meshes left out again, with the warning) is the model's rigid
    body."""
    mesh = '<collision><geometry><mesh filename="package://two/meshes/{}.stl"/></geometry></collision>'
    text = TWO_LINK_URDF.replace('<link name="l1">', '<link name="l1">' + mesh.format("l1"))
    text = text.replace('<link name="l2">', '<link name="l2">' + mesh.format("l2"))
    source = tmp_path / "two.urdf"
    source.write_text(text)
    with pytest.warns(UserWarning, match=r"2 mesh file\(s\) not found"):
        model = _grey_box({"source": str(source), "flange": "tool0"}, dof=2, seed=2)
    result = wb.write_description(model, tmp_path / "out" / "two_identified.urdf")
    written = result.path.read_text()
    assert written.count('<mesh filename="package://two/meshes/') == 2 and source.read_text() == text
    assert 'name="payload"' not in written  # no payload given: nothing added to the robot as described
    assert any("2 mesh file(s)" in n and "load_description" in n for n in result.notes), result.notes  # said so
    with pytest.warns(UserWarning, match=r"2 mesh file\(s\) not found"):
        arm = MujocoArm(str(result.path))
    arm.model.dof_armature[:] = [json.loads(result.sidecar.read_text())["not_expressed"][0]["values"][n]
                                 for n in ("j1", "j2")]
    errors = _compare(model, arm, torch.zeros(1, 4))
    assert max(errors.values()) < BOUND, errors


def test_an_arm_model_written_back_is_its_inverse_less_friction(tmp_path, float64):
    """A classical fit with every link's parameters (perturbed, physically consistent), viscous, Coulomb
    and offset friction: MuJoCo from the written MJCF is its rigid body, and with the joints' damping its
    inverse dynamics less the smooth Coulomb friction and the offset, which are listed."""
    from lnn_torch.identification import ArmModel
    from lnn_torch.mechanics import DriveModel
    from lnn_torch.robots import kinematics as K
    from lnn_torch.robots.regressor import parameter_vector

    chain = K.read_chain(ArmDescription.of("franka_panda").compile())
    g = torch.Generator().manual_seed(5)
    U = K.reverse_cholesky(chain.J)
    U = U * (1 + 0.05 * torch.randn(U.shape, generator=g)).triu()
    armature = chain.armature * (1 + 0.2 * torch.rand(7, generator=g))
    b = 0.5 + torch.rand(7, generator=g)
    pi = parameter_vector(U @ U.mT, armature, b).numpy()
    coefficients = {"b": b.numpy(), "c": (0.2 + torch.rand(7, generator=g)).numpy(),
                    "o": (0.1 * torch.randn(7, generator=g)).numpy()}
    fit = ArmModel(chain, DriveModel.of("viscous+coulomb+offset"), "physically consistent", coefficients, pi=pi)
    with pytest.raises(InputError, match="pass description="):
        wb.write_description(fit, tmp_path / "x.xml")
    result = wb.write_description(fit, tmp_path / "fit.xml", description="franka_panda")
    terms = [line.split(":")[0] for line in result.unexpressed]
    assert terms == ["Coulomb smoothing", "friction offset"]
    arm = MujocoArm(str(result.path))
    q, qd, qdd = _states(arm, seed=2)
    rigid = fit.inverse(q, qd, qdd) + fit.friction(q, qd)  # its inverse less its friction (viscous included)
    errors = {"inverse": _rel(arm.inverse(q, qd, qdd, damping=False), rigid),
              "mass_matrix": _rel(arm.mass_matrix(q), fit.mass_matrix(q)),
              "damped": _rel(arm.inverse(q, qd, qdd), fit.inverse(q, qd, qdd) - fit.drive.torque(
                  qd, {"c": torch.as_tensor(coefficients["c"]), "o": torch.as_tensor(coefficients["o"]),
                       "b": torch.zeros(1)}))}
    print("arm model", errors)
    assert max(errors.values()) < BOUND, errors
    assert _rel(MujocoArm("franka_panda").inverse(q, qd, qdd, damping=False), rigid) > 1e-3
    least = ArmModel(chain, DriveModel.of("viscous"), "least squares", {}, base={"rank": 3}, beta=np.zeros(3))
    with pytest.raises(InputError, match="consistent_fit") as err:
        wb.write_description(least, tmp_path / "y.xml", description="franka_panda")
    assert "\n" not in str(err.value)


def test_what_mujoco_cannot_express_is_listed(tmp_path, float64):
    """Every friction form beyond viscous and a hard Coulomb level, Rayleigh damping, a force residual and
    learned input gains: listed with their values in the result, the sidecar and the file's comment; the
    rigid body is still written exactly."""
    model = _grey_box("franka_panda", friction="viscous+coulomb+offset+stribeck+sigmoid", dissipation="joint+rayleigh",
                      residual_force={}, learn_input_matrix="gains")
    # a residual at its start (its output layer zero) is nothing left out: said so, not listed
    zero = wb.write_description(model, tmp_path / "zero.xml")
    assert "force residual" not in [line.split(":")[0] for line in zero.unexpressed]
    assert any("force residual is zero" in n for n in zero.notes), zero.notes
    assert not [n for n in zero.notes if "depend on the payload" in n]  # (its coefficients do not, yet)
    with torch.no_grad():
        model.forces.residual.output_layer[1].fill_(0.01)  # ... a learned one is
        model.forces.coefficient_net[-1].weight.fill_(0.01)  # and coefficients that depend on the payload are said
    result = wb.write_description(model, tmp_path / "arm.xml")
    assert any("depend on the payload: written at no payload" in n for n in result.notes), result.notes
    terms = [line.split(":")[0] for line in result.unexpressed]
    assert terms == ["Coulomb smoothing", "friction offset", "Stribeck friction", "sigmoid friction",
                     "Rayleigh damping", "force residual", "input gains"], terms
    record = json.loads(result.sidecar.read_text())
    listed = {u["term"]: u for u in record["not_expressed"]}
    coef = model.forces.drive_coefficients(model.normalizer.params(torch.zeros(1, 4)))
    for key, term in (("o", "friction offset"), ("s", "Stribeck friction"), ("phi2", "sigmoid friction")):
        assert list(listed[term]["values"][key].values()) == pytest.approx(coef[key][0].tolist(), rel=1e-15)
    # the residual's torque at rest, which the written arm lacks (a residual that took up gravity: a trial's 0.59 N m
    # on a joint whose written gravity was then worse than the description's): per joint, against the model's own
    at_rest = listed["force residual"]["values"]
    gen = np.random.default_rng(0)
    ranges = MujocoArm("franka_panda").joint_range.numpy()
    q = torch.as_tensor(gen.uniform(ranges[:, 0], ranges[:, 1], (512, 7)), dtype=model.dtype)
    own = model.residual_force(q, torch.zeros_like(q), torch.zeros(512, 4, dtype=model.dtype))
    assert at_rest == pytest.approx(own.double().pow(2).mean(0).sqrt().tolist(), rel=1e-6)
    assert min(at_rest) > 0 and "At rest over the joints' ranges it is up to" in listed["force residual"]["why"]
    text = result.path.read_text()
    comment = re.search(r"<!-- lnn_torch write-back.*?-->", text, re.S).group(0)
    for term in terms:
        assert term in comment
    assert "--" not in comment[4:-3]
    errors = _compare(model, MujocoArm(str(result.path)), torch.zeros(1, 4))
    assert max(errors.values()) < BOUND, errors
    # URDF: the armature too
    source = tmp_path / "two.urdf"
    source.write_text(TWO_LINK_URDF)
    two = _grey_box({"source": str(source), "flange": "tool0"}, dof=2, friction="viscous")
    result = wb.write_description(two, tmp_path / "two_out.urdf")
    assert [line.split(":")[0] for line in result.unexpressed] == ["armature"]
    assert any("friction loss is left as written" in n for n in result.notes)
    assert MujocoArm(str(result.path)).model.dof_frictionloss.tolist() == [0.0, 0.2]  # as written


def test_nothing_else_in_the_file_changes(tmp_path, float64):
    """The shipped Panda written back: every line but the inertials and the joints' (and the comment
    at the top) as written; compiled, the same geometry, joints, limits, geoms and actuators."""
    model = _grey_box("franka_panda")
    result = wb.write_description(model, tmp_path / "arm.xml")
    original = DESCRIPTIONS["franka_panda"].read_text()
    written = result.path.read_text()
    comment = re.compile(r"\n\s*<!-- lnn_torch write-back.*?-->", re.S)
    assert len(comment.findall(written)) == 1

    def lines(text):
        return [line.replace('"/>', '" />') for line in comment.sub("", text).splitlines()
                if "<inertial" not in line and "<joint " not in line]

    assert lines(written) == lines(original)
    a, b = (mujoco.MjSpec.from_file(str(p)).compile() for p in (DESCRIPTIONS["franka_panda"], result.path))
    for key in ("body_pos", "body_quat", "body_parentid", "jnt_range", "jnt_axis", "jnt_pos", "jnt_limited",
                "geom_size", "geom_type", "actuator_gear", "actuator_trnid", "actuator_gainprm", "actuator_biasprm",
                "actuator_ctrlrange", "actuator_forcerange", "opt.gravity", "opt.timestep"):
        x, y = (np.asarray(_field(m, key)) for m in (a, b))
        assert np.array_equal(x, y), key
    assert (a.ngeom, a.nu, a.nbody, a.njnt) == (b.ngeom, b.nu, b.nbody, b.njnt)
    assert not np.allclose(a.body_mass, b.body_mass)
    # written twice over itself: the same file (nothing accumulates)
    again = wb.write_description(model, tmp_path / "arm.xml")
    assert again.path.read_text() == written


def _field(obj, name):
    for part in name.split("."):
        obj = getattr(obj, part)
    return obj


ARM_MJCF = """<mujoco model="a">
  <include file="defaults.xml"/>
  <compiler angle="degree"/>
  <worldbody>
    <body name="b1"><joint name="j1" axis="0 0 1"/><geom type="capsule" size="0.05" fromto="0 0 0 0.3 0 0"/>
      <body name="b2" pos="0.3 0 0" euler="0 30 0"><joint name="j2" axis="0 1 0" damping="0.2"/>
        <geom type="box" size="0.1 0.02 0.02" pos="0.1 0 0"/>
        <site name="tcp" pos="0.25 0 0" euler="90 0 0"/>
        <body name="hand" pos="0.2 0 0"><geom type="sphere" size="0.04"/>
          <body name="finger"><joint name="jf" type="slide" axis="1 0 0" range="0 0.04"/>
            <geom type="sphere" size="0.01"/></body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="j1"/><motor joint="j2"/><position name="grip" joint="jf"/></actuator>
  <sensor><jointpos joint="jf"/><jointpos joint="j2"/></sensor>
  <contact><exclude body1="b2" body2="hand"/></contact>
</mujoco>
"""


def test_an_mjcf_as_the_robot_is_written_as_compiled(tmp_path, float64):
    """An MJCF whose inertias come from its geoms, with an include, a hand carrying an actuated finger that
    the robot lacks (``remove``), a flange at a site given in degrees and a tool, written into another
    folder: the hand, its actuator, sensor and contact exclusion are gone, the include still found, the
    payload and tool at the site's frame, and MuJoCo from it is the grey box."""
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "defaults.xml").write_text('<mujoco><default><geom rgba="1 0 0 1"/></default></mujoco>\n')
    (tmp_path / "src" / "arm.xml").write_text(ARM_MJCF)
    description = {"source": str(tmp_path / "src" / "arm.xml"), "remove": ["hand"], "flange": "tcp",
                   "tool": [0.3, 0.01, 0.0, 0.02]}
    model = _grey_box(description, dof=2, seed=4)
    result = wb.write_description(model, tmp_path / "out" / "arm.xml", payload=PAYLOAD)
    arm = MujocoArm(str(result.path))
    errors = _compare(model, arm, torch.tensor(PAYLOAD)[None])
    print("mjcf as the robot", errors)
    assert max(errors.values()) < BOUND, errors
    assert (arm.model.nu, arm.model.nsensor, arm.model.nexclude) == (2, 1, 0)
    assert '<include file="../src/defaults.xml"/>' in result.path.read_text()  # closed as the file closes them
    assert "hand" not in arm.body_names and {"payload", "tool"} <= set(arm.body_names)
    assert any(n.startswith("the bodies the model's description removes (hand)") for n in result.notes), result.notes
    assert not [n for n in result.notes if "do not determine" in n]
    # a model started from a classical fit whose recordings left values to its prior: the export says which
    model.classical_start = {"held_by_prior": [f"joint{j}.{k}" for j in (1, 2) for k in ("Ixx", "Iyy", "armature")]}
    held = wb.write_description(model, tmp_path / "out" / "held.xml", payload=PAYLOAD)
    assert ("the training recordings do not determine 6 of the values written (joint1.Ixx, joint1.Iyy, "
            "joint1.armature, joint2.Ixx, joint2.Iyy, joint2.armature): the fit's prior towards the description holds "
            "them") in " ".join(held.notes), held.notes


def test_a_wrong_frame_conversion_is_caught(tmp_path, float64, monkeypatch):
    """The written file is compiled and compared before it is kept: an inertia written about the body's
    origin instead of its centre of mass, in axes turned a quarter turn (a frame's rotation missed), or
    the welded hand's pose rotated the wrong way (its rotation transposed) is refused in one line;
    written anyway, MuJoCo from it is far from the model."""
    model = _grey_box("franka_panda")
    right, pose = wb.inertial_of, wb._transform
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

    def about_origin(J):
        m, c, I = right(J)
        return m, c, I + m * (c @ c * np.eye(3) - np.outer(c, c))

    def turned(J):
        m, c, I = right(J)
        return m, turn @ c, turn @ I @ turn.T

    def transposed(pos, quat):
        T = pose(pos, quat)
        T[:3, :3] = T[:3, :3].T
        return T

    for name, wrong in (("inertial_of", about_origin), ("inertial_of", turned), ("_transform", transposed)):
        path = tmp_path / f"{wrong.__name__}.xml"
        with monkeypatch.context() as patch:
            patch.setattr(wb, name, wrong)
            with pytest.raises(InputError, match="does not give the identified arm") as err:
                wb.write_description(model, path)
            assert "\n" not in str(err.value) and not path.exists()
            result = wb.write_description(model, path, check=False)
        errors = _compare(model, MujocoArm(str(result.path)), torch.zeros(1, 4))
        print(wrong.__name__, errors)
        assert errors["mass_matrix"] > 1e-3, (wrong.__name__, errors)


def test_a_model_without_a_spatial_part_is_refused_in_one_line(tmp_path, capsys):
    from lnn_torch import LNNModule
    from lnn_torch.cli import main

    torch.manual_seed(0)

    plain = LNNModule(scene="robot_arm", variant="film_lnn", hidden_dims=[8, 8])
    with pytest.raises(InputError, match="write-back needs a grey box built from a robot description") as err:
        wb.write_description(plain, tmp_path / "arm.xml")
    assert "\n" not in str(err.value)
    ckpt = save_checkpoint(plain, tmp_path / "plain.ckpt")
    assert main(["export", ckpt, "--format", "mjcf", "-o", str(tmp_path / "arm.xml")]) == 2
    out = capsys.readouterr()
    assert out.err.strip().count("\n") == 0 and "write-back needs a grey box" in out.err
    assert not (tmp_path / "arm.xml").exists()


@pytest.mark.filterwarnings("ignore:model variant 'film_lnn' with kinetic")
def test_the_export_command_writes_the_grey_box_back(tmp_path, capsys):
    """``lnn-torch export CKPT --format mjcf -o FILE --payload ...`` on a trained-looking grey box checkpoint
    (float32 weights): the file, the listing printed, MuJoCo from it equal to the model in float64."""
    from lnn_torch import LNNModule
    from lnn_torch.cli import main

    module = LNNModule(scene="robot_arm", variant="film_lnn", hidden_dims=None,
                       model_options={"kinetic": {"spatial": {}}, "potential": {"spatial": {}}})
    part = module.model.kinetic["spatial"]
    with torch.no_grad():
        part.raw.mul_(1 + 0.03 * torch.randn(part.raw.shape, generator=torch.Generator().manual_seed(2)))
    ckpt = save_checkpoint(module, tmp_path / "grey.ckpt")
    out = tmp_path / "panda_identified.xml"
    assert main(["export", ckpt, "--format", "mjcf", "-o", str(out), "--payload", *map(str, PAYLOAD)]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed and "not expressed in MJCF" in printed and "Coulomb smoothing" in printed
    model = module.model.double()
    errors = _compare(model, MujocoArm(str(out)), torch.tensor([PAYLOAD], dtype=torch.float64))
    with capsys.disabled():
        print("command", errors)
    assert max(errors.values()) < BOUND, errors
    assert main(["export", ckpt, "--format", "mjcf", "-o", str(out)]) == 2  # exists: --overwrite replaces it
    assert "exists" in capsys.readouterr().err
    assert main(["export", ckpt, "--format", "urdf", "-o", str(tmp_path)]) == 2
    assert "write it back as mjcf" in capsys.readouterr().err


SITE_MJCF = """<mujoco><worldbody><body name="l1"><joint name="j1" axis="0 0 1"/>
  <inertial pos="0.02 0 0.1" mass="1.2" fullinertia="0.01 0.012 0.008 0.001 0 0"/>
  <body name="l2" pos="0 0 0.3"><joint name="j2" axis="1 0 0"/>
    <inertial pos="0 0.1 0.01" mass="0.9" diaginertia="0.01 0.011 0.009"/>
    <site name="flange" pos="0.3 0 0.05" euler="0.4 0 0"/></body></body></worldbody></mujoco>
"""


@pytest.mark.parametrize("named", [True, False])
def test_a_file_written_without_a_payload_keeps_its_flange(tmp_path, float64, named):
    """No payload given: where the file read alone would put the payload elsewhere (a site flange), the massless
    payload body is written there and reading it alone finds the flange; where the flange is the chain's last
    body's origin, nothing is added."""
    source = tmp_path / "arm.xml"
    site = '<site name="flange" pos="0.3 0 0.05" euler="0.4 0 0"/>'
    source.write_text(SITE_MJCF if named else SITE_MJCF.replace(site, ""))
    description = {"source": str(source), "flange": "flange"} if named else str(source)
    model = _grey_box(description, dof=2, seed=3)
    result = wb.write_description(model, tmp_path / "out.xml")
    assert ('name="payload"' in result.path.read_text()) is named
    alone = MujocoArm(str(result.path))
    q = torch.tensor([[0.3, -0.4], [1.0, 0.5]])
    load = torch.tensor([[1.5, 0.02, -0.01, 0.04]])
    reference = MujocoArm(description)
    held = alone.gravity(q, load) - alone.gravity(q)  # the load's own torques: where it hangs
    torch.testing.assert_close(held, reference.gravity(q, load) - reference.gravity(q), rtol=1e-12, atol=1e-12)


def test_what_the_data_left_as_described_is_written_as_the_description_has_it(tmp_path, monkeypatch):
    """A float32 grey box gives a value the data never moved as the description's to float32 round-off
    (3.6999999 for a mass of 3.7): such values are the description's, so a link left as described keeps its
    inertial element as written (a rotated one too), a link of which one second moment moved keeps the text of
    every value that did not (mass, centre of mass, the unchanged inertia entries), the file closes its elements
    and declares its namespaces as the source does, and the written chain is the identified one (the write-back's
    own check). The rule can fail: a link moved by more than round-off is written anew."""
    text = TWO_LINK_URDF.replace('<robot name="two">', '<robot name="two" xmlns:xacro="http://ros.org/wiki/xacro">')
    source = tmp_path / "two.urdf"
    source.write_text(text)
    description = {"source": str(source), "flange": "tool0"}
    model = build_model("film_lnn", _scene(description, 2), kinetic={"spatial": {}}, potential={"spatial": {}}).float()
    described = read_chain(ArmDescription.of(description).compile()).J.numpy()
    ident = wb.identified_arm(model)
    assert 0 < np.abs(ident.J - described).max() < 1e-6  # the model's own: the description's to float32 round-off
    noise = 1e-8 * np.random.default_rng(0).standard_normal(described.shape)
    J = described * (1 + noise + noise.transpose(0, 2, 1))  # round-off everywhere
    J[1, 2, 2] += 1e-3  # l2's second moment along z: its ixx and iyy move, nothing else
    monkeypatch.setattr(wb, "identified_arm", lambda *a, **k: dataclasses.replace(ident, J=J))
    result = wb.write_description(model, tmp_path / "out" / "two_identified.urdf")
    written = result.path.read_text()
    assert any("within the model's round-off" in n for n in result.notes), result.notes
    inertials = lambda t: re.findall(r"<inertial>.*?</inertial>", t, re.S)  # noqa: E731
    before, after = inertials(text), inertials(written)
    assert after[1] == before[1]  # l1: rotated inertial, as written
    l2 = wb._parse(written).find("link[@name='l2']/inertial")
    inertia = l2.find("inertia").attrib
    assert (l2.find("mass").get("value"), l2.find("origin").get("xyz")) == ("1.5", "0.1 0 0.1")
    assert {k: inertia[k] for k in ("izz", "ixy", "ixz", "iyz")} == {"izz": "0.015", "ixy": "0.001", "ixz": "0",
                                                                      "iyz": "0"}
    assert inertia["ixx"] != "0.015" and inertia["iyy"] != "0.02"  # moved
    assert '<robot name="two" xmlns:xacro="http://ros.org/wiki/xacro">' in written and " />" not in written
    # l1 moved by more than round-off: written anew
    J[0, 3, 3] *= 1 + 1e-5
    moved = wb.write_description(model, tmp_path / "out" / "moved.urdf")
    assert inertials(moved.path.read_text())[1] != before[1]
