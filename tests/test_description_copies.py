"""A checkpoint of a model built from a robot description file carries the compiled description: loaded
where the file is gone it gives the same model (with a warning), refused in one line where it carries no
copy, and a warning names a file that is there but is another arm than the one the model was trained on."""

import shutil
import warnings

import lightning as L
import pytest
import torch

pytest.importorskip("mujoco")

from lnn_torch.errors import InputError  # noqa: E402
from lnn_torch.robots import DESCRIPTIONS  # noqa: E402
from lnn_torch.robots.description import ArmDescription, compiled_copies, descriptions_in  # noqa: E402
from lnn_torch.training import checkpoint_format as ckpt  # noqa: E402
from lnn_torch.training.checkpoints import load_model  # noqa: E402
from lnn_torch.training.module import LNNModule  # noqa: E402

GREY_BOX = {"kinetic": {"spatial": {}}, "potential": {"spatial": {}}}


def grey_box_checkpoint(folder, out):
    """A grey box of the robot-arm scene on a copy of the shipped Panda in ``folder``, saved to ``out`` as
    Lightning saves it (hyper-parameters, weights, the module's own entries); returns the module."""
    folder.mkdir()
    xml = folder / "my_panda.xml"
    shutil.copy(DESCRIPTIONS["franka_panda"], xml)
    module = LNNModule(scene="robot_arm", scene_config={"description": str(xml)}, model_options=GREY_BOX, eps=0.0)
    checkpoint = {"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams),
                  "pytorch-lightning_version": L.__version__}
    module.on_save_checkpoint(checkpoint)
    torch.save(checkpoint, out)
    return module, xml


def states(n=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    draw = lambda: torch.randn(n, 7, generator=g, dtype=torch.float64)  # noqa: E731
    q, qd, tau = 0.5 * draw(), draw(), 5 * draw()
    payload = torch.rand(n, 4, generator=g, dtype=torch.float64)  # mass 0-2 kg, centre of mass within 0.1 m
    payload = payload * torch.tensor([2.0, 0.2, 0.2, 0.2]) - torch.tensor([0.0, 0.1, 0.1, 0.1])
    return q, qd, payload.double(), tau


def test_the_checkpoint_carries_each_description_file_once_and_no_shipped_one(tmp_path):
    module, xml = grey_box_checkpoint(tmp_path / "arm", tmp_path / "model.ckpt")
    saved = torch.load(tmp_path / "model.ckpt", weights_only=False)
    assert list(saved[ckpt.DESCRIPTION_COPIES]) == [ArmDescription.of(str(xml)).to_json()]
    assert descriptions_in({"a": {"description": str(xml)}, "b": [{"description": {"source": str(xml)}}]}) == [
        ArmDescription.of(str(xml))]
    assert compiled_copies({"scene_config": {"description": "franka_panda"}}) == {}


def test_a_checkpoint_whose_description_file_is_gone_loads_the_same_model_from_its_copy(tmp_path):
    module, xml = grey_box_checkpoint(tmp_path / "arm", tmp_path / "model.ckpt")
    q, qd, p, tau = states()
    module.double().eval()
    with torch.no_grad():
        before = module.acceleration(q, qd, p, tau)
    shutil.rmtree(tmp_path / "arm")
    with pytest.warns(UserWarning, match="no such file; using the compiled copy checkpoint .*model.ckpt carries"):
        loaded = load_model(str(tmp_path / "model.ckpt")).double()
    with torch.no_grad():
        after = loaded.acceleration(q, qd, p, tau)
    torch.testing.assert_close(after, before, rtol=1e-12, atol=1e-12)


def test_a_checkpoint_without_the_copy_and_without_the_file_is_refused_in_one_line(tmp_path):
    grey_box_checkpoint(tmp_path / "arm2", tmp_path / "old.ckpt")
    saved = torch.load(tmp_path / "old.ckpt", weights_only=False)
    del saved[ckpt.DESCRIPTION_COPIES]  # as checkpoints written before the copies
    torch.save(saved, tmp_path / "old.ckpt")
    shutil.rmtree(tmp_path / "arm2")
    with pytest.raises(InputError, match="my_panda.xml: no such file") as err:
        load_model(str(tmp_path / "old.ckpt"))
    assert "\n" not in str(err.value)


def test_a_description_file_that_changed_since_training_is_named_in_a_warning(tmp_path):
    module, xml = grey_box_checkpoint(tmp_path / "arm3", tmp_path / "model.ckpt")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the file as it was: no warning
        load_model(str(tmp_path / "model.ckpt"))
    text = xml.read_text()
    assert text.count('mass="') > 2
    start = text.index('mass="') + len('mass="')
    end = text.index('"', start)
    xml.write_text(text[:start] + str(float(text[start:end]) * 1.5) + text[end:])  # one link 50 % heavier
    with pytest.warns(UserWarning, match="my_panda.xml is not the arm checkpoint .* was trained with"):
        load_model(str(tmp_path / "model.ckpt"))


def test_the_copy_is_refused_in_one_line_under_another_mujoco_version(tmp_path, monkeypatch):
    grey_box_checkpoint(tmp_path / "arm4", tmp_path / "model.ckpt")
    saved = torch.load(tmp_path / "model.ckpt", weights_only=False)
    for copy in saved[ckpt.DESCRIPTION_COPIES].values():
        copy["mujoco"] = "0.0.1"
    torch.save(saved, tmp_path / "model.ckpt")
    shutil.rmtree(tmp_path / "arm4")
    with pytest.raises(InputError, match=r"compiled by MuJoCo 0\.0\.1 .*install mujoco==0\.0\.1"):
        load_model(str(tmp_path / "model.ckpt"))


def test_a_dataset_whose_description_file_is_gone_still_builds_its_models(tmp_path):
    """Recordings imported with a description file carry its compiled copy: with the file gone, the
    file's scene still builds the grey box (what ``fit`` does), with the same mass matrix."""
    from lnn_torch.data import read_dataset
    from lnn_torch.data.importer import ImportSpec, import_recordings

    from .test_measured_arm import record

    folder = tmp_path / "arm5"
    folder.mkdir()
    xml = folder / "my_panda.xml"
    shutil.copy(DESCRIPTIONS["franka_panda"], xml)
    robot = {"source": str(xml), "remove": ["hand"], "armature": "zero", "damping": "zero"}
    csv = record(tmp_path / "arm.csv", seconds=0.5, robot=robot)
    spec = ImportSpec(time="time", coordinates=[f"q{j}" for j in range(1, 8)], inputs=[f"tau{j}" for j in range(1, 8)],
                      velocities=[f"dq{j}" for j in range(1, 8)], robot=robot, friction=True, label="my_panda",
                      split={"train": ["arm[0.0:0.3]"], "val": ["arm[0.3:0.4]"], "test": ["arm[0.4:0.5]"]})
    path = import_recordings([csv], tmp_path / "arm.h5", spec)
    scene = read_dataset(path).scene
    module = LNNModule(scene="measured", scene_config=scene["config"], model_options=GREY_BOX, eps=0.0).double()
    q = 0.3 * torch.randn(8, 7, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    before = module.model.mass_matrix(q, torch.zeros(8, 0, dtype=torch.float64))
    shutil.rmtree(folder)
    with pytest.warns(UserWarning, match="no such file; using the compiled copy dataset file .*arm.h5 carries"):
        scene = read_dataset(path).scene
        module = LNNModule(scene="measured", scene_config=scene["config"], model_options=GREY_BOX, eps=0.0).double()
    after = module.model.mass_matrix(q, torch.zeros(8, 0, dtype=torch.float64))
    torch.testing.assert_close(after, before, rtol=1e-12, atol=1e-12)


def test_a_joint_offset_changed_in_the_file_is_named_too(tmp_path):
    """Not only masses: a joint's reference angle (the grey box's joint offset) makes another arm."""
    module, xml = grey_box_checkpoint(tmp_path / "arm6", tmp_path / "model.ckpt")
    text = xml.read_text()
    assert text.count('<joint name="joint1"') == 1
    xml.write_text(text.replace('<joint name="joint1"', '<joint name="joint1" ref="0.3"'))
    with pytest.warns(UserWarning, match="is not the arm checkpoint"):
        load_model(str(tmp_path / "model.ckpt"))


def test_the_copy_is_the_arm_the_model_was_built_from_and_warns_once(tmp_path):
    """The file deleted between building the model and saving it: the checkpoint still carries the arm
    it was built from; loading it twice warns once."""
    folder = tmp_path / "arm7"
    folder.mkdir()
    xml = folder / "my_panda.xml"
    shutil.copy(DESCRIPTIONS["franka_panda"], xml)
    module = LNNModule(scene="robot_arm", scene_config={"description": str(xml)}, model_options=GREY_BOX, eps=0.0)
    shutil.rmtree(folder)
    checkpoint = {"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams),
                  "pytorch-lightning_version": L.__version__}
    module.on_save_checkpoint(checkpoint)
    torch.save(checkpoint, tmp_path / "model.ckpt")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_model(str(tmp_path / "model.ckpt"))
        load_model(str(tmp_path / "model.ckpt"))
    assert sum("using the compiled copy" in str(w.message) for w in caught) == 1


def test_a_ckpt_path_of_the_cli_registers_its_copies_before_the_model_is_built(tmp_path):
    from lnn_torch.training.lightning_cli import register_description_copies

    module, xml = grey_box_checkpoint(tmp_path / "arm8", tmp_path / "model.ckpt")
    shutil.rmtree(tmp_path / "arm8")
    register_description_copies(str(tmp_path / "model.ckpt"))
    with pytest.warns(UserWarning, match="using the compiled copy"):
        LNNModule(**module.hparams)


def test_a_malformed_copy_is_refused_in_one_line(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs a failed load to MUJOCO_LOG.TXT in the working folder
    grey_box_checkpoint(tmp_path / "arm9", tmp_path / "model.ckpt")
    saved = torch.load(tmp_path / "model.ckpt", weights_only=False)
    for copy in saved[ckpt.DESCRIPTION_COPIES].values():
        copy["mjb"] = copy["mjb"][:100]
    torch.save(saved, tmp_path / "model.ckpt")
    shutil.rmtree(tmp_path / "arm9")
    with pytest.raises(InputError, match="compiled robot description checkpoint .* carries cannot be read") as err:
        load_model(str(tmp_path / "model.ckpt"))
    assert "\n" not in str(err.value)
    saved[ckpt.DESCRIPTION_COPIES] = {"x": 1}
    torch.save(saved, tmp_path / "model.ckpt")
    with pytest.raises(InputError, match="compiled robot descriptions are malformed"):
        load_model(str(tmp_path / "model.ckpt"))
