"""The command line's conventions: ``lnn-torch list`` from the registries, ``--version``, one way to
name a model (``CHECKPOINT``: a path or ``pretrained:NAME``) with the old spellings still working,
help texts without doubled defaults."""

from __future__ import annotations

from pathlib import Path

import pytest

from lnn_torch._version import __version__
from lnn_torch.cli import main
from lnn_torch.mechanics.integrators import METHODS
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


BAD_FILES = {"text": b"this is not a checkpoint\n", "empty": b""}


def _bad_file(tmp_path, kind: str, suffix: str, good: bytes | None = None) -> str:
    path = tmp_path / f"{kind}{suffix}"
    if kind in ("newer", "foreign"):  # a checkpoint from a future format, a PyTorch archive of another program
        import io

        import torch

        ckpt = torch.load(io.BytesIO(good), weights_only=False)
        ckpt = {**ckpt, "lnn_torch": {"version": "9.0", "format": 99}} if kind == "newer" else {"weights": [1.0]}
        torch.save(ckpt, path)
    else:
        path.write_bytes(good[: len(good) // 3] if kind == "truncated" else BAD_FILES[kind])
    return str(path)


@pytest.mark.parametrize("kind", ["text", "empty", "truncated", "newer", "foreign"])
@pytest.mark.parametrize("command", ["evaluate", "identify", "simulate", "export"])
def test_every_command_names_a_bad_checkpoint_in_one_line(command, kind, tmp_path, capsys):
    from lnn_torch.pretrained import HERE

    ckpt = _bad_file(tmp_path, kind, ".ckpt", (HERE / "double_pendulum.ckpt").read_bytes())
    extra = {"identify": ["recording.csv"], "simulate": ["--params", "1", "1", "1", "1", "--q0", "0", "0"]}
    assert main([command, ckpt, *extra.get(command, []), "-o" if command != "identify" else "--output-dir",
                 str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and ckpt in err, err
    assert {"text": "not an lnn-torch checkpoint", "empty": "empty file", "truncated": "truncated",
            "newer": "written by a newer version of lnn-torch (9.0",
            "foreign": "not an lnn-torch checkpoint"}[kind] in err


@pytest.mark.parametrize("kind", ["text", "empty", "truncated"])
def test_a_bad_dataset_is_named_in_one_line(kind, tmp_path, capsys):
    import h5py
    import numpy as np

    full = tmp_path / "full.h5"
    with h5py.File(full, "w") as f:
        f["x"] = np.zeros(20000)
    data = _bad_file(tmp_path, kind, ".h5", full.read_bytes())
    for command in (["evaluate", "pretrained:double_pendulum", "--data", data, "-o", str(tmp_path / "ev")],
                    ["identify", "pretrained:double_pendulum", data, "--output-dir", str(tmp_path / "id")],
                    ["fit", "--data.path", data, "--trainer.max_steps", "1", "--trainer.default_root_dir",
                     str(tmp_path / "runs")]):
        assert main(command) == 2
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert err.startswith(f"lnn-torch {command[0]}: error:") and data in err, err
        assert {"text": "not an HDF5 file", "empty": "an empty file", "truncated": "cannot read"}[kind] in err, err


@pytest.mark.parametrize("kind", ["text", "empty", "truncated"])
def test_a_bad_recording_is_named_in_one_line(kind, tmp_path, capsys):
    """identify's observation CSV and import's raw recording: a text file, an empty one and one cut
    mid-line are each named in one line."""
    import gzip
    from pathlib import Path

    import numpy as np

    import lnn_torch

    shipped = Path(lnn_torch.__file__).parent / "datasets" / "real_double_pendulum" / "recordings"
    config = Path(__file__).parents[1] / "configs" / "import" / "real_double_pendulum.yaml"
    t = np.arange(300) * 0.01
    observed = "t,theta1,theta2\n" + "".join(f"{a:.3f},{np.sin(a):.6f},{np.cos(a):.6f}\n" for a in t)
    recording = gzip.decompress(sorted(shipped.glob("*.csv.gz"))[0].read_bytes())[:20000]
    for command, good in ((["identify", "pretrained:double_pendulum"], observed.encode()),
                          (["import"], recording)):
        path = _bad_file(tmp_path, kind, ".csv", good)
        extra = (["--output-dir", str(tmp_path / "id")] if command[0] == "identify" else
                 ["--config", str(config), "-o", str(tmp_path / "r.h5")])
        assert main([*command, path, *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and path in err, err
        assert {"text": "no column", "empty": "the file is empty", "truncated": "line "}[kind] in err, err
    if kind == "truncated":  # a compressed recording cut short
        gz = tmp_path / "cut.csv.gz"
        gz.write_bytes(gzip.compress(recording)[:3000])
        assert main(["import", str(gz), "--config", str(config), "-o", str(tmp_path / "r.h5")]) == 2
        assert f"{gz}: truncated" in capsys.readouterr().err


@pytest.mark.parametrize("text, message", [("model: [\n", "not valid YAML (line 2"), ("", "empty file"),
                                           ("- 1\n- 2\n", "not a mapping of options")])
@pytest.mark.parametrize("command", ["fit", "import"])
def test_a_bad_config_is_named_in_one_line(command, text, message, tmp_path, capsys):
    config = tmp_path / "config.yaml"
    config.write_text(text)
    argv = (["fit", "-c", str(config)] if command == "fit" else
            ["import", str(tmp_path / "rec.csv"), "--config", str(config), "-o", str(tmp_path / "o.h5")])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(config) in err and message in err, err


def test_the_commands_silence_lightnings_advertisements_only(caplog):
    import logging

    from lnn_torch.training.lightning_cli import quiet_third_parties

    quiet_third_parties()
    logger = logging.getLogger("lightning.pytorch.utilities.rank_zero")
    with caplog.at_level(logging.INFO, logger="lightning.pytorch.utilities.rank_zero"):
        logger.info("💡 Tip: For seamless cloud logging and experiment tracking, try installing litlogger")
        logger.info("GPU available: False, used: False")
    saving = logging.getLogger("lightning.pytorch.trainer.connectors.checkpoint_connector")
    with caplog.at_level(logging.INFO, logger=saving.name):
        saving.info("`weights_only` was not set, defaulting to `False`.")
    assert [r.getMessage() for r in caplog.records] == ["GPU available: False, used: False"]


def test_a_system_without_parameters_fits_its_normaliser_without_warnings():
    import warnings

    import torch

    from lnn_torch.networks import Normalizer

    norm = Normalizer(2, 0, (True, True), (), 0, False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        norm.fit(torch.randn(50, 2), torch.randn(50, 2), torch.randn(50, 2), torch.zeros(5, 0))


def test_a_variant_lists_every_option_and_loss_term_it_cannot_use_at_once():
    """Switching the actuated scene's config to ``hnn``: its FiLM width and the torque term are refused
    in one message (they were refused one at a time)."""
    from lnn_torch import LNNModule
    from lnn_torch.errors import InputError

    with pytest.raises(InputError, match=r"variant 'hnn' cannot use: option 'film_hidden' .*; torque_weight 1 "):
        LNNModule(scene="actuated_double_pendulum", variant="hnn", hidden_dims=[8], torque_weight=1.0,
                  model_options={"film_hidden": 64})
    with pytest.raises(InputError, match=r"energy_weight 0.1 \(variant mlp has no energy"):
        LNNModule(variant="mlp", hidden_dims=[8], energy_weight=0.1)



def test_simulate_a_model_of_a_measured_system_without_parameters(tmp_path, capsys):
    out = tmp_path / "sim.csv"
    assert main(["simulate", "pretrained:real_double_pendulum", "--q0", "0.5", "0", "--duration", "0.2",
                 "--excitation", '{"kind": "none"}', "-o", str(out)]) == 0
    assert "no closed form" in capsys.readouterr().out
    header = [line for line in out.read_text().splitlines() if not line.startswith("#")][0]
    assert header.split(",")[:3] == ["t", "q1", "q2"] and "energy" not in header
    described = [line for line in out.read_text().splitlines() if line.startswith("# columns:")][0]
    assert "_exact" not in described and "energy" not in described  # (the comment names the columns there are)


def test_identify_keeps_one_report_folder_per_recording(tmp_path, monkeypatch, capsys):
    import numpy as np

    monkeypatch.chdir(tmp_path)
    t = np.arange(200) * 0.01
    for name, phase in (("a", 0.0), ("b", 0.3)):
        rows = "".join(f"{x:.3f},{0.5 * np.cos(3 * x + phase):.6f},{0.4 * np.sin(3 * x + phase):.6f}\n" for x in t)
        (tmp_path / f"{name}.csv").write_text("t,theta1,theta2\n" + rows)
        assert main(["identify", "pretrained:double_pendulum", f"{name}.csv", "--starts", "1", "--steps", "20"]) == 0
    assert (tmp_path / "identification" / "double_pendulum" / "a" / "report.md").exists()
    assert (tmp_path / "identification" / "double_pendulum" / "b" / "report.md").exists()
    # ... and per model: another model's report on the same recording goes elsewhere (it replaced this one's)
    assert main(["identify", "pretrained:double_pendulum_box", "a.csv", "--starts", "1", "--steps", "20"]) == 0
    assert (tmp_path / "identification" / "double_pendulum_box" / "a" / "report.md").exists()
    first = (tmp_path / "identification" / "double_pendulum" / "a" / "report.md").read_text()
    assert "double_pendulum_box" not in first
    from types import SimpleNamespace as NS

    from lnn_torch.commands.identify import _default_output
    run = tmp_path / "lightning_logs" / "version_3" / "checkpoints"
    assert _default_output(NS(checkpoint=str(run / "last.ckpt"), recording="data/arm.h5", split="test",
                              trajectory=0)) == run.parent / "identification" / "arm-test-0"
    assert _default_output(NS(checkpoint=str(run / "epoch2-err0.1.ckpt"), recording="x.csv", split="test",
                              trajectory=0)) == run.parent / "identification" / "epoch2-err0.1" / "x"
    # a checkpoint outside a run folder (downloaded, or kept in results/): here, by its name
    assert _default_output(NS(checkpoint=str(tmp_path / "results" / "model.ckpt"), recording="x.csv", split="test",
                              trajectory=0)) == Path("identification") / "model" / "x"


def test_plugins_are_imported_before_a_command_and_a_missing_one_is_named(tmp_path, monkeypatch, capsys):
    """LNN_TORCH_PLUGINS names modules (a scene of one's own) imported before any command, found in the working
    directory too; one that cannot be imported is refused in one line naming it."""
    import sys

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", list(sys.path))
    (tmp_path / "my_plugin_for_test.py").write_text("import pathlib\npathlib.Path('imported').write_text('yes')\n")
    monkeypatch.setenv("LNN_TORCH_PLUGINS", "my_plugin_for_test")
    assert main(["list"]) == 0 and (tmp_path / "imported").read_text() == "yes"
    monkeypatch.setenv("LNN_TORCH_PLUGINS", "json, not_a_module_here")
    assert main(["list"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("lnn-torch list: error: LNN_TORCH_PLUGINS: cannot import 'not_a_module_here' (ModuleNotFoundError: "
                   "No module named 'not_a_module_here')"), err



def test_out_of_range_run_settings_are_refused_in_one_line(tmp_path, monkeypatch, capsys):
    """A stride of 0 (a slice error after the model summary), validation every 0 epochs (a ZeroDivisionError
    traceback from Lightning) and a negative number of rollouts (accepted without a word) are refused by name."""
    import torch

    from lnn_torch.errors import InputError
    from lnn_torch.training import LNNModule
    from lnn_torch.training.datamodule import TrajectoryDataModule

    with pytest.raises(InputError, match=r"data\.eval_stride must be a whole number >= 1, got 0"):
        TrajectoryDataModule(path=str(tmp_path / "x.h5"), spec={}, eval_stride=0)
    with pytest.raises(InputError, match=r"val_rollouts must be a number of trajectories, 0 \(none\) or -1 \(all\), "
                                         r"got -3"):
        LNNModule(val_rollouts=-3)
    for dims in ([0], [], [64, -1], "64"):
        with pytest.raises(InputError, match=r"hidden_dims must be one or more positive widths"):
            LNNModule(hidden_dims=dims)
    model = LNNModule(hidden_dims=[8])
    with pytest.raises(InputError, match=r"q has no rows: an empty batch"):
        model.model.acceleration(torch.zeros(0, 2), torch.zeros(0, 2), torch.zeros(0, 4))
    assert main(["generate", "--scene", "measured", "-o", str(tmp_path / "m.h5")]) == 2
    assert "scene 'measured' is a recorded system: its data come from lnn-torch import" in capsys.readouterr().err
    monkeypatch.chdir(tmp_path)
    assert main(["fit", "--trainer.check_val_every_n_epoch", "0", "--data.path", "x.h5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("lnn-torch fit: error: --trainer.check_val_every_n_epoch must be a whole number >= 1 (or null), "
                   "got 0"), err


def test_evaluate_without_the_file_a_checkpoint_was_given_names_where_it_was(tmp_path, monkeypatch, capsys):
    """A model fitted on a file given by its path (no specification to generate it from), evaluated where that file
    is gone: the file, where it was when trained, and --data (it said "measured recordings" of a generated file)."""
    import torch

    from lnn_torch.training import LNNModule
    from lnn_torch.training.checkpoint_format import DATA_PATH

    from .helpers import save_checkpoint

    module = LNNModule(hidden_dims=[8])
    ckpt = save_checkpoint(module, tmp_path / "m.ckpt")
    raw = torch.load(ckpt, weights_only=False)
    raw["datamodule_hyper_parameters"], raw[DATA_PATH] = {"path": "data/small.h5"}, "/elsewhere/data/small.h5"
    torch.save(raw, ckpt)
    monkeypatch.chdir(tmp_path)
    assert main(["evaluate", ckpt]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("lnn-torch evaluate: error: the checkpoint's data file data/small.h5 (/elsewhere/data/small.h5 "
                   "where it was trained) is not there, and the checkpoint records no specification to generate it "
                   "from (the fit was given the file: an import, or one generated apart): pass --data"), err


def test_evaluate_computes_the_sections_asked_for(tmp_path, capsys):
    """--sections NAME: that section alone (a metric of one's own checked without the whole report's minutes); an
    unknown name is refused listing the sections."""
    import json

    from lnn_torch.data import DatasetSpec, generate_dataset
    from lnn_torch.training import LNNModule

    from .helpers import save_checkpoint

    data = generate_dataset(DatasetSpec(num_trajectories=8, duration=0.5, seed=2), tmp_path / "d.h5")
    ckpt = save_checkpoint(LNNModule(hidden_dims=[8]), tmp_path / "m.ckpt")
    assert main(["evaluate", ckpt, "--data", str(data), "--sections", "accelerations", "-o", str(tmp_path / "e")]) == 0
    metrics = json.loads((tmp_path / "e" / "metrics.json").read_text())
    assert "acc_rel_err" in metrics and "stability" not in metrics and "energy_drift" not in metrics, list(metrics)
    assert main(["evaluate", ckpt, "--data", str(data), "--sections", "accel"]) == 2
    assert "--sections: no section 'accel'; the sections: accelerations, rollouts" in capsys.readouterr().err


def test_a_resumed_fit_compares_model_options_as_the_module_rewrites_them():
    """The module leaves a force residual out of model_options where it is not learned (learn_residual): resuming
    with the same config compares the rest (a note, or a refusal, fired on the config's own residual)."""
    from lnn_torch.training.lightning_cli import _rewritten

    config = {"friction": "viscous", "residual_force": {"local": True}}
    assert _rewritten("model_options", config, {"friction": "viscous"})
    assert not _rewritten("model_options", config, {"friction": "coulomb"})
    assert not _rewritten("lr", 0.1, 0.01)



def test_identify_refuses_recordings_driven_by_inputs_a_model_has_none_of(tmp_path, capsys):
    """An actuated scene's file given to a model without inputs: one line (a traceback about the normaliser's
    input_rms before)."""
    from lnn_torch.data import DatasetSpec, generate_dataset

    path = generate_dataset(DatasetSpec(scene="actuated_double_pendulum", num_trajectories=2, duration=0.5, seed=1,
                                        split=[0.5, 0.0, 0.5]), tmp_path / "a.h5")
    assert main(["identify", "pretrained:double_pendulum", str(path), "-o", str(tmp_path / "id")]) == 2
    err = capsys.readouterr().err.strip()
    assert "recordings of scene 'actuated_double_pendulum' are driven by inputs (torques), which a model of " \
           "'double_pendulum' has none of" in err and "\n" not in err
