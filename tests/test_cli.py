"""The command line's conventions: ``lnn-torch list`` from the registries, ``--version``, one way to
name a model (``CHECKPOINT``: a path or ``pretrained:NAME``) with the old spellings still working,
help texts without doubled defaults."""

from __future__ import annotations

import pytest

from lnn_torch import __version__
from lnn_torch.cli import main
from lnn_torch.integrators import METHODS
from lnn_torch.networks import VARIANTS
from lnn_torch.networks.parts import KINETIC_PARTS, POTENTIAL_PARTS
from lnn_torch.pretrained import available
from lnn_torch.systems import SYSTEMS


def test_list_names_every_registered_scene_variant_part_model_and_integrator(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    for name in SYSTEMS:
        assert any(line.split()[:1] == [name] for line in lines), name
    for name in VARIANTS:
        assert any(line.split()[:1] == [name] for line in lines), name
    for role, registry in (("kinetic", KINETIC_PARTS), ("potential", POTENTIAL_PARTS)):
        for name in registry:
            assert any(line.split()[:2] == [role, name] for line in lines), (role, name)
    for name in available():
        assert f"pretrained:{name}" in out
    for name in METHODS:
        assert any(line.strip() == name for line in lines), name
    assert "dof 2: q = (theta1, theta2); params (m1, m2, l1, l2); no inputs" in out
    assert main(["list", "scenes"]) == 0 and "model variants" not in capsys.readouterr().out


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"lnn-torch {__version__}"


def test_generate_help_states_each_default_once(capsys):
    with pytest.raises(SystemExit):
        main(["generate", "--help"])
    out = capsys.readouterr().out
    assert "(default: None)" not in out and "(default: False)" not in out
    assert out.count("(default: 2000)") == 1  # --num-trajectories: the formatter adds it where the help has none
    assert "default: data/<scene>.h5" in out


@pytest.mark.parametrize("spelling", [["pretrained:double_pendulum"], [], ["--pretrained", "double_pendulum"],
                                      ["--checkpoint", "pretrained:double_pendulum", "--method", "rk4"]])
def test_simulate_takes_the_model_as_checkpoint_and_the_old_spellings(spelling, tmp_path, capsys):
    out = tmp_path / "sim.csv"
    args = ["simulate", *spelling, "--params", "1.0", "0.6", "1.2", "1.1", "--q0", "1.0", "-0.5", "--duration", "0.05",
            "--no-exact", "-o", str(out)]
    assert main(args) == 0
    assert out.exists() and out.with_suffix(".png").exists()
    err = capsys.readouterr().err
    assert ("deprecated" in err) == (any(s.startswith("--") for s in spelling))


def test_simulate_refuses_two_models(tmp_path, capsys):
    code = main(["simulate", "pretrained:double_pendulum", "--pretrained", "double_pendulum", "--params", "1", "1",
                 "1", "1", "--q0", "0", "0", "-o", str(tmp_path / "s.csv")])
    assert code == 2 and "give the model once" in capsys.readouterr().err
