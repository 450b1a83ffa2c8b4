"""The robot description as the robot you have (``lnn_torch.robots.description``): bodies removed, a
tool carried, armature and damping as written, zero or given, a URDF's flange link, and refusals."""

import math

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")

from lnn_torch.errors import InputError  # noqa: E402
from lnn_torch.robots.description import ArmDescription  # noqa: E402
from lnn_torch.robots.mujoco_arm import MujocoArm  # noqa: E402

URDF = """<robot name="two">
  <link name="base"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>
  </inertial></link>
  <link name="l1"><inertial><mass value="2"/><origin xyz="0 0 0.2"/>
    <inertia ixx="0.02" iyy="0.03" izz="0.015" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l2"><inertial><mass value="1.5"/><origin xyz="0.1 0 0.1"/>
    <inertia ixx="0.015" iyy="0.02" izz="0.015" ixy="0.001" ixz="0" iyz="0"/></inertial></link>
  <link name="tool0"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.4"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="2"/></joint>
  <joint name="flange" type="fixed"><parent link="l2"/><child link="tool0"/><origin xyz="0.3 0 0"/></joint>
</robot>
"""


def states(arm, n=12, seed=0):
    rng = np.random.default_rng(seed)
    return arm.sample_q(rng, n), rng.normal(size=(n, arm.dof)), rng.normal(size=(n, arm.dof))


def test_the_hand_removed_and_carried_back_as_a_tool_is_the_arm_as_written():
    """Removing the Panda's hand and carrying the same rigid body as a tool (its mass, centre of mass
    and inertia written in the flange frame: the hand's frame is turned by the description's quaternion,
    about -45 deg about the flange's z) gives the description's own dynamics; without the tool the
    hand's 0.73 kg is gone."""
    shipped = MujocoArm("franka_panda")
    w, z = np.array([0.9238795, -0.3826834]) / math.hypot(0.9238795, 0.3826834)  # as written, normalised
    c, s = w * w - z * z, 2 * w * z
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    com = R @ np.array([-0.01, 0, 0.03])
    inertia = R @ np.diag([0.001, 0.0025, 0.0017]) @ R.T
    tool = [0.73, *com, inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
    carried = MujocoArm({"source": "franka_panda", "remove": ["hand"], "tool": tool})
    bare = MujocoArm({"source": "franka_panda", "remove": ["hand"]})
    q, qd, qdd = states(shipped)
    torch.testing.assert_close(carried.mass_matrix(q), shipped.mass_matrix(q), rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(carried.inverse(q, qd, qdd), shipped.inverse(q, qd, qdd), rtol=1e-12, atol=1e-12)
    assert float((shipped.gravity(q) - bare.gravity(q)).abs().max()) > 0.5
    assert sum(bare.model.body_mass) == pytest.approx(sum(shipped.model.body_mass) - 0.73, abs=1e-12)


def test_armature_and_damping_as_written_zero_or_given():
    written = MujocoArm("franka_panda")
    zero = MujocoArm({"source": "franka_panda", "armature": "zero", "damping": "zero"})
    given = MujocoArm({"source": "franka_panda", "armature": [0.2] * 7, "damping": [0.5] * 7})
    assert written.armature.tolist() == [0.1] * 7 and written.damping.tolist() == [1.0] * 7
    assert zero.armature.tolist() == [0.0] * 7 and zero.damping.tolist() == [0.0] * 7
    assert given.armature.tolist() == [0.2] * 7 and given.damping.tolist() == [0.5] * 7
    q, qd, _ = states(written)
    # M differs by the armature on its diagonal exactly; the passive force is -damping qd
    diff = written.mass_matrix(q) - zero.mass_matrix(q)
    torch.testing.assert_close(diff, 0.1 * torch.eye(7, dtype=torch.float64).expand_as(diff), rtol=0, atol=1e-14)
    torch.testing.assert_close(given.friction(q, qd), -0.5 * torch.as_tensor(qd), rtol=0, atol=0)


def test_a_urdf_keeps_its_flange_link_and_takes_payloads_there(tmp_path):
    path = tmp_path / "two.urdf"
    path.write_text(URDF)
    arm = MujocoArm({"source": str(path), "flange": "tool0"})
    assert arm.joint_names == ("j1", "j2") and arm.body_names[arm.model.body_parentid[arm.payload_id]] == "tool0"
    # 2 kg at the flange, 0.3 m along l2's x: holding it at q = 0 takes m g x at joint 2 (axis y)
    held = arm.gravity(np.zeros((1, 2)), [2.0, 0, 0, 0]) - arm.gravity(np.zeros((1, 2)))
    torch.testing.assert_close(held, torch.tensor([[0.0, -2.0 * 9.81 * 0.3]], dtype=torch.float64), rtol=0,
                               atol=1e-12)
    assert path.read_text() == URDF  # never edited


MJCF_SITE = """<mujoco><compiler angle="degree"/><worldbody>
  <body name="l1" pos="0 0 0.1"><joint name="j1" axis="0 0 1"/>
    <inertial pos="0 0 0.1" mass="1" diaginertia="0.01 0.01 0.01"/>
    <body name="l2" pos="0 0 0.3"><joint name="j2" axis="1 0 0"/>
      <inertial pos="0 0.1 0" mass="1" diaginertia="0.01 0.01 0.01"/>
      <site name="flange" pos="0 0.2 0.05" {orientation}/></body></body></worldbody></mujoco>
"""


@pytest.mark.parametrize("orientation", ['euler="30 0 0"', 'axisangle="1 0 0 30"', 'zaxis="0 -0.5 0.8660254037844386"'])
def test_a_site_flange_keeps_its_orientation_however_it_is_written(tmp_path, orientation):
    """A payload's centre of mass is in the flange's frame: a site rotated by euler, axisangle or zaxis is
    the same frame as the site written as a quaternion (30 degrees about x)."""
    half = math.radians(15)
    quat = f'quat="{math.cos(half)} {math.sin(half)} 0 0"'
    arms = {}
    for key, text in (("quat", quat), ("other", orientation)):
        path = tmp_path / f"{key}.xml"
        path.write_text(MJCF_SITE.format(orientation=text))
        arms[key] = MujocoArm({"source": str(path), "flange": "flange"})
    q = np.array([[0.3, -0.7], [1.1, 0.4]])
    payload = [1.5, 0.02, 0.08, -0.03]
    tau = {k: a.gravity(q, payload) for k, a in arms.items()}
    assert (tau["quat"] - arms["quat"].gravity(q)).abs().max() > 0.1  # the payload counts
    torch.testing.assert_close(tau["other"], tau["quat"], rtol=0, atol=1e-12)


def test_descriptions_round_trip_and_bad_ones_are_refused_in_one_line():
    d = ArmDescription.of({"source": "franka_panda", "remove": "hand", "armature": "zero", "tool": [1, 0, 0, 0.1]})
    assert ArmDescription.of(d.to_json()) == d and ArmDescription.of(d.to_dict()) == d
    assert ArmDescription.of("franka_panda").as_written and not d.as_written
    assert ArmDescription.of("franka_panda").config() == "franka_panda"
    assert str(d) == "franka_panda (remove=['hand'], tool=[1.0, 0.0, 0.0, 0.1], armature=zero)"
    for bad, match in (({"source": "franka_panda", "remove": ["hands"]}, "no body 'hands' to remove"),
                       ({"source": "franka_panda", "armature": [1, 2]}, "armature has 2 values for 7 joints"),
                       ({"source": "franka_panda", "armature": "learn"}, "armature must be 'as_written', 'zero'"),
                       ({"source": "franka_panda", "tool": [1, 0]}, "tool must be"),
                       ({"source": "franka_panda", "flange": "link7"}, "has a body 'payload' and a flange"),
                       ({"sourse": "franka_panda"}, "unknown key")):
        with pytest.raises(InputError, match=match):
            ArmDescription.of(bad).compile()


def test_an_unexpanded_xacro_is_refused_with_how_to_expand_it(tmp_path):
    """A ROS description as its package keeps it (xacro macros): MuJoCo cannot read it, and the one-line error
    says to expand it first, without suggesting a command that overwrites it; a plain bad URDF gets no hint."""
    xacro = ('<robot name="r" xmlns:xacro="http://ros.org/wiki/xacro"><xacro:property name="pi" value="3.14159"/>'
             '<link name="base"/><link name="l1"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" '
             'izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link><joint name="j1" type="revolute"><parent '
             'link="base"/><child link="l1"/><axis xyz="0 0 1"/><limit lower="${-pi}" upper="${pi}" effort="1" '
             'velocity="1"/></joint></robot>')
    for name, expanded in (("arm.urdf.xacro", "arm.urdf"), ("arm.urdf", "arm_expanded.urdf")):
        (tmp_path / name).write_text(xacro)
        with pytest.raises(InputError, match=rf"xacro file .*expand it first, e.g. xacro {name} > {expanded}$"):
            ArmDescription.of(str(tmp_path / name)).compile()
    (tmp_path / "bad.urdf").write_text(xacro.replace("${-pi}", "low").replace("${pi}", "1").replace("xacro:", "x"))
    with pytest.raises(InputError) as err:
        ArmDescription.of(str(tmp_path / "bad.urdf")).compile()
    assert "xacro file" not in str(err.value)


def test_a_continuous_joint_turns_all_the_way_round(tmp_path):
    path = tmp_path / "continuous.urdf"
    path.write_text(URDF.replace('type="revolute"><parent link="l1"/>', 'type="continuous"><parent link="l1"/>')
                    .replace('<limit lower="-2" upper="2" effort="10" velocity="2"/>', ''))
    arm = MujocoArm({"source": str(path), "flange": "tool0"})
    torch.testing.assert_close(arm.joint_range, torch.tensor([[-3.0, 3.0], [-math.pi, math.pi]], dtype=torch.float64))
    q = arm.sample_q(np.random.default_rng(0), 200)
    assert q[:, 1].min() < -2.5 and q[:, 1].max() > 2.5


def test_an_import_config_names_its_description_relative_to_itself(tmp_path, monkeypatch):
    """``robot: {source: two.urdf}`` in an import config beside the URDF, imported from another folder:
    the dataset records the file's absolute path, so the data (and models trained on it) find it from
    anywhere."""
    import json

    from lnn_torch.cli import main
    from lnn_torch.data import read_dataset

    arm_dir = tmp_path / "my_arm"
    arm_dir.mkdir()
    (arm_dir / "two.urdf").write_text(URDF)
    t = np.arange(60) * 0.01
    rows = ["time,j1,j2,tau1,tau2"] + [f"{x},{0.1 * np.sin(x)},{0.2 * np.cos(x)},0.5,0.1" for x in t]
    (arm_dir / "run.csv").write_text("\n".join(rows) + "\n")
    (arm_dir / "import.yaml").write_text(
        "coordinates: [j1, j2]\ninputs: [tau1, tau2]\nrobot: {source: two.urdf, flange: tool0}\n"
        "split: {train: [run]}\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert main(["import", str(arm_dir / "run.csv"), "--config", str(arm_dir / "import.yaml"), "-o", "arm.h5"]) == 0
    robot = json.loads(read_dataset(elsewhere / "arm.h5").attrs["scene_json"])["config"]["description"]
    assert robot["source"] == str((arm_dir / "two.urdf").resolve())
    with pytest.raises(InputError, match="no such file, and not a shipped one"):
        MujocoArm({"source": "missing.urdf"})


def _with_meshes(text: str) -> str:
    """``URDF`` as a ROS package ships it: every link's collision and visual geometry a mesh named
    ``package://...`` (which MuJoCo cannot open)."""
    for link in ("base", "l1", "l2"):
        text = text.replace(f'<link name="{link}">', f'<link name="{link}"><visual><geometry><mesh filename='
                            f'"package://two_description/meshes/visual/{link}.dae"/></geometry></visual><collision>'
                            f'<geometry><mesh filename="package://two_description/meshes/collision/{link}.stl"/>'
                            '</geometry></collision>')
    return text


def test_a_description_whose_meshes_are_not_there_is_its_inertials(tmp_path):
    """A URDF from a ROS package (meshes as ``package://``, not there) loads with a warning naming the
    files left out, and is the same arm as the URDF without any geometry: the dynamics come from the
    inertials as written; the file is never edited. A mesh that is there stays."""
    bare, meshed = tmp_path / "bare.urdf", tmp_path / "meshed.urdf"
    bare.write_text(URDF)
    meshed.write_text(_with_meshes(URDF))
    with pytest.warns(UserWarning, match=r"3 mesh file\(s\) not found \(package://two_description/meshes/collision/"
                                         r"base.stl.*their geoms are left out"):
        arm = MujocoArm({"source": str(meshed), "flange": "tool0"})
    reference = MujocoArm({"source": str(bare), "flange": "tool0"})
    q, qd, qdd = states(reference)
    torch.testing.assert_close(arm.mass_matrix(q), reference.mass_matrix(q), rtol=1e-14, atol=0)
    torch.testing.assert_close(arm.inverse(q, qd, qdd), reference.inverse(q, qd, qdd), rtol=1e-14, atol=0)
    assert arm.model.ngeom == 0 and meshed.read_text() == _with_meshes(URDF)
    # a mesh that is there is kept: a tetrahedron as the collision mesh of l1 (MuJoCo reads OBJ)
    (tmp_path / "l1.obj").write_text("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    meshed.write_text(_with_meshes(URDF).replace("package://two_description/meshes/collision/l1.stl", "l1.obj"))
    with pytest.warns(UserWarning, match=r"2 mesh file\(s\) not found"):
        kept = MujocoArm({"source": str(meshed), "flange": "tool0"})
    assert kept.model.ngeom == 1
    torch.testing.assert_close(kept.mass_matrix(q), reference.mass_matrix(q), rtol=1e-14, atol=0)


def test_a_moving_body_whose_inertia_comes_from_a_missing_mesh_is_refused(tmp_path):
    """MuJoCo computes the inertia of a body without an inertial from its geoms: with the mesh gone that
    body cannot be modelled, and the error names it and the file; a body that does not move (welded to
    the world) loses its mesh silently."""
    text = """<mujoco><compiler meshdir="assets"/><asset><mesh name="base" file="base.stl"/>
      <mesh name="l1" file="l1.stl"/></asset><worldbody><body name="base"><geom type="mesh" mesh="base"/>
      <body name="l1"><joint name="j1" axis="0 0 1"/><geom type="mesh" mesh="l1"/>{inertial}</body></body>
      </worldbody></mujoco>"""
    path = tmp_path / "arm.xml"
    path.write_text(text.format(inertial=""))
    with pytest.raises(InputError, match=r"body 'l1' takes its inertia from mesh 'l1.stl', which is not there "
                                         r"\(it has no inertial written\)"):
        ArmDescription.of(str(path)).compile()
    path.write_text(text.format(inertial='<inertial pos="0 0.1 0" mass="2" diaginertia="0.01 0.02 0.02"/>'))
    with pytest.warns(UserWarning, match=r"2 mesh file\(s\) not found \(assets/base.stl, assets/l1.stl\)|"
                                         r"2 mesh file\(s\) not found \(base.stl, l1.stl\)"):
        model = ArmDescription.of(str(path)).compile()
    assert model.ngeom == 0 and model.body_mass[2] == 2.0


@pytest.mark.parametrize("payload, accepted", [('<body name="payload"/>', True),
                                               ('<body name="payload" euler="0 90 0"/>', False),
                                               ('<body name="payload"><joint name="loose"/></body>', False),
                                               ('<body name="payload"><body name="more"/></body>', False)])
def test_a_payload_body_at_the_named_flange_is_used_and_any_other_refused(tmp_path, payload, accepted):
    """A description with a ``payload`` body (one ``lnn-torch export`` wrote) read with a named flange: used where
    it is welded at that flange with nothing hanging from it, its orientation however written; else refused."""
    text = f"""<mujoco><worldbody><body name="l1"><joint name="j1" axis="0 0 1"/>
      <inertial pos="0 0 0.1" mass="1" diaginertia="0.01 0.01 0.01"/>
      <body name="l2" pos="0 0 0.3"><joint name="j2" axis="1 0 0"/>
        <inertial pos="0 0.1 0" mass="1" diaginertia="0.01 0.01 0.01"/>{payload}</body></body></worldbody></mujoco>"""
    path = tmp_path / "arm.xml"
    path.write_text(text)
    description = ArmDescription.of({"source": str(path), "flange": "l2"})
    if accepted:
        model = description.compile()
        assert model.nbody == 4  # world, l1, l2 and the payload written there: none added
    else:
        with pytest.raises(InputError, match="has a body 'payload' and a flange 'l2'"):
            description.compile()


def test_a_description_found_in_neither_folder_is_refused_naming_both(tmp_path, monkeypatch):
    from lnn_torch.commands.import_recordings import resolved_robot

    monkeypatch.chdir(tmp_path)
    (tmp_path / "configs").mkdir()
    with pytest.raises(InputError, match=r"robot description \.\./arm\.urdf: no such file beside the import config "
                                         rf"\({tmp_path}/arm\.urdf\) or from the working folder \({tmp_path.parent}/arm"
                                         r"\.urdf\), and not a shipped one \(franka_panda"):
        resolved_robot({"source": "../arm.urdf"}, tmp_path / "configs")
    (tmp_path / "arm.urdf").write_text(URDF)
    assert resolved_robot({"source": "../arm.urdf"}, tmp_path / "configs")["source"] == str(tmp_path / "arm.urdf")
    assert resolved_robot("franka_panda", tmp_path) == "franka_panda"
