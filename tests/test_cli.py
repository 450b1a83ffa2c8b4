"""The command line and the shipped configs (``lnn_torch.cli``, ``lnn_torch.training.lightning_cli``): every
config instantiates and fits, fit/test/predict, the default root directory, a missing measured file."""

import glob
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from lnn_torch import LNNModule
from lnn_torch.training.datamodule import TrajectoryDataModule

from .helpers import ROOT, cli_in_process, run_cli, tiny_fit_args

CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


@pytest.mark.parametrize("config", CONFIGS, ids=[c.name for c in CONFIGS])
def test_every_shipped_config_instantiates(config, tmp_path):
    from lnn_torch.training.datamodule import TrajectoryDataModule as DM
    from lnn_torch.training.lightning_cli import LNNCLI, TRAINER_DEFAULTS

    args = ["-c", str(config)]
    if (ROOT / "configs" / "import" / config.name).exists():  # measured data: the scene comes from the file
        args.append(f"--data.path={_imported(config, tmp_path)}")
    cli = LNNCLI(LNNModule, DM, args=args, run=False, trainer_defaults=TRAINER_DEFAULTS)
    assert isinstance(cli.model, LNNModule) and isinstance(cli.datamodule, DM)
    assert cli.trainer.validate_loop.inference_mode is False and cli.trainer.predict_loop.inference_mode is False


@pytest.mark.slow
@pytest.mark.parametrize("config", CONFIGS, ids=[c.name for c in CONFIGS])
def test_every_shipped_config_fits_with_the_cli(config, tmp_path):
    """fast_dev_run of each config on a tiny dataset of its own scene (generated on the fly; the
    shipped recordings imported with their import config for a config of measured data). In this process
    (``main``): ``test_cli_fit_test_predict`` runs the command as a new process."""
    import yaml

    data = tmp_path / "d.h5"
    if (ROOT / "configs" / "import" / config.name).exists():
        data = _imported(config, tmp_path)
    # a config that starts from a shipped model keeps that model's widths (its weights must fit)
    starts_from = (yaml.safe_load(config.read_text()).get("model") or {}).get("init_from")
    narrow = [] if starts_from else ["--model.hidden_dims=[8,8]"]
    out = cli_in_process("fit", "-c", str(config), f"--data.path={data}", "--data.spec.num_trajectories=10",
               "--data.spec.duration=0.5", *narrow, "--model.val_rollout_seconds=0.1",
               "--trainer.fast_dev_run=true", "--trainer.enable_progress_bar=false",
               "--model.compile=false",  # one step: compiling it would only time inductor (tests/test_compile.py)
               cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]


@pytest.mark.slow
def test_cli_fit_test_predict(dataset, tmp_path):
    """fit, test and predict: the first fit as a new process (the entry point a shell runs), the rest in
    this process (``main``)."""
    common = ["-c", str(ROOT / "configs" / "quickstart.yaml"), f"--data.path={dataset}",
              "--data.spec.num_trajectories=20", "--data.spec.duration=2.0", "--data.spec.seed=5",
              "--model.hidden_dims=[16,16]", "--model.val_rollout_seconds=0.5", "--trainer.enable_progress_bar=false"]
    out = run_cli("fit", *common, "--trainer.fast_dev_run=true", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    out = cli_in_process("fit", *common, "--trainer.max_epochs=1", "--data.steps_per_epoch=3",
               "--trainer.check_val_every_n_epoch=1", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    ckpts = sorted(glob.glob(str(tmp_path / "lightning_logs" / "version_0" / "checkpoints" / "*.ckpt")))
    assert ckpts
    # last.ckpt holds the final weights (Lightning's save_last would follow only improvements)
    last = torch.load(tmp_path / "lightning_logs" / "version_0" / "checkpoints" / "last.ckpt", weights_only=False)
    assert last["global_step"] == 3
    # the end-of-fit summary: where the run and the checkpoint are, and the validation error
    assert "TensorBoard run: lightning_logs/version_0" in out.stdout and "last.ckpt" in out.stdout
    # ... and a test command that reads the same data (the command line's --data options beside the config)
    assert f"test it: lnn-torch test -c {ROOT / 'configs' / 'quickstart.yaml'} --data.path={dataset} " \
           "--data.spec.num_trajectories=20 --data.spec.duration=2.0 --data.spec.seed=5 --data.steps_per_epoch=3 " \
           "--ckpt_path" in out.stdout, out.stdout[-800:]
    assert re.search(r"validation rollouts within 0\.1 rad \(or m\) of the data: median (≥ [\d.]+ s \(never "
                     r"exceeded\)|[\d.]+ s)", out.stdout), out.stdout[-600:]
    assert re.search(r"validation: acc\. rel\. L2 error [0-9.]+ % pooled, [0-9.]+ % per-trajectory median", out.stdout)
    out = cli_in_process("test", *common, f"--ckpt_path={ckpts[0]}", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "test/acc_rel_err" in out.stdout
    written = glob.glob(str(tmp_path / "lightning_logs" / "*" / "test_metrics.json"))
    assert written and "test/acc_rel_err" in json.loads(Path(written[0]).read_text())
    # a --ckpt_path command line sets how the model is judged (Lightning read the checkpoint's over it), and is
    # refused a model or training setting other than the checkpoint's (ignored without a word before)
    out = cli_in_process("test", *common, f"--ckpt_path={ckpts[0]}", "--model.test_rollouts=1",
                         "--trainer.default_root_dir=judged", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "test_rollouts: 1\n" in next((tmp_path / "judged").rglob("config.yaml")).read_text()
    # ... and so does a config file (-c) that sets one (its value was replaced by the checkpoint's)
    (tmp_path / "judge.yaml").write_text("model:\n  test_rollouts: 2\n")
    out = cli_in_process("test", *common, "-c", str(tmp_path / "judge.yaml"), f"--ckpt_path={ckpts[0]}",
                         "--trainer.default_root_dir=judged_by_file", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "test_rollouts: 2\n" in next((tmp_path / "judged_by_file").rglob("config.yaml")).read_text()
    for command in ("test", "fit"):
        out = cli_in_process(command, *common, f"--ckpt_path={ckpts[0]}", "--model.lr=0.5", cwd=tmp_path)
        assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr[-2000:]
        assert f"lnn-torch {command}: error: --model.lr 0.5: the checkpoint's model has 0.01, and a --ckpt_path " \
               "checkpoint keeps its model and training settings (only val_rollouts, " in out.stderr, out.stderr
        assert ("start a new run from its weights (--model.init_from CHECKPOINT)" in out.stderr) == (command == "fit")
    out = cli_in_process("predict", *common, f"--ckpt_path={ckpts[0]}", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    files = glob.glob(str(tmp_path / "lightning_logs" / "*" / "predictions.npz"))
    assert files
    pred = np.load(files[0])
    assert pred["qdd_pred"].shape == pred["qdd_true"].shape and pred["qdd_pred"].shape[-1] == 2
    # a run shorter than its validation interval says so, instead of printing no validation at all
    out = cli_in_process("fit", *common, "--trainer.max_epochs=1", "--data.steps_per_epoch=3",
                         "--trainer.check_val_every_n_epoch=4", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "validation: none ran in training (every 4 epochs, 12 steps" in out.stdout, out.stdout[-600:]


@pytest.mark.slow
def test_last_checkpoint_names_the_best_checkpoint_that_exists(dataset, tmp_path):
    """last.ckpt's record of the best checkpoint is the one on disk (it was written before the epoch's best was, and
    named a file the top-1 rule had deleted: a resumed run printed that path and compared against its score)."""
    out = cli_in_process("fit", *tiny_fit_args(dataset, "--data.spec.seed=5", "--model.hidden_dims=[8,8]",
                                               "--model.val_rollout_seconds=0.2", "--trainer.max_epochs=3",
                                               "--data.steps_per_epoch=2", "--trainer.check_val_every_n_epoch=1",
                                               "--model.compile=false"), cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    folder = tmp_path / "lightning_logs" / "version_0" / "checkpoints"
    last = torch.load(folder / "last.ckpt", weights_only=False)
    (state,) = [v for k, v in last["callbacks"].items() if k.startswith("ModelCheckpoint")]
    assert (tmp_path / state["best_model_path"]).exists(), (state["best_model_path"], sorted(folder.iterdir()))
    assert sorted(p.name for p in folder.iterdir()) == sorted(["last.ckpt", Path(state["best_model_path"]).name])


@pytest.mark.slow
def test_a_resumed_fit_keeps_its_best_and_its_settings(dataset, tmp_path):
    """Resuming (a new run folder): the resumed run's best checkpoint stays the best, its file kept, until one saved
    here beats it (Lightning tracked it afresh there: a worse checkpoint became "the best"); ``--ckpt_path last``
    finds the newest run's last.ckpt (Lightning looked for its own and started afresh); a config file's other
    training setting is refused as the command line's is (it was ignored)."""
    args = tiny_fit_args(dataset, "--data.spec.seed=5", "--model.hidden_dims=[8,8]", "--model.val_rollout_seconds=0.2",
                         "--data.steps_per_epoch=2", "--trainer.check_val_every_n_epoch=1", "--model.compile=false")
    out = cli_in_process("fit", *args, "--trainer.max_epochs=1", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    first = tmp_path / "lightning_logs" / "version_0" / "checkpoints"
    last = torch.load(first / "last.ckpt", weights_only=False)
    (key,) = [k for k in last["callbacks"] if k.startswith("ModelCheckpoint")]
    earlier = Path(last["callbacks"][key]["best_model_path"])
    last["callbacks"][key]["best_model_score"] = torch.tensor(1e-6)  # a best no later state can beat
    torch.save(last, first / "last.ckpt")
    out = cli_in_process("fit", *args, "--trainer.max_epochs=3", "--ckpt_path", "last", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert f"--ckpt_path last: {Path('lightning_logs') / 'version_0' / 'checkpoints' / 'last.ckpt'}" in out.stdout
    assert f"best validation checkpoint: {os.path.normpath(earlier)}" in out.stdout, out.stdout[-1500:]
    assert (tmp_path / earlier).exists()
    second = tmp_path / "lightning_logs" / "version_1" / "checkpoints"
    assert sorted(p.name for p in second.iterdir()) == ["last.ckpt"]
    resumed = torch.load(second / "last.ckpt", weights_only=False)
    assert resumed["global_step"] == 6 and float(resumed["callbacks"][key]["best_model_score"]) == pytest.approx(1e-6)
    (tmp_path / "faster.yaml").write_text("model:\n  lr: 0.05\n")  # a config file's other setting: said
    out = cli_in_process("fit", *args, "-c", "faster.yaml", "--trainer.max_epochs=4", "--ckpt_path", "last",
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert ("note: model.lr 0.05 (a config file's) differs from the checkpoint's 0.01: a --ckpt_path run keeps the "
            "checkpoint's: to train on with other settings, start a new run from its weights") in out.stdout
    second = tmp_path / "lightning_logs" / "version_2" / "checkpoints"
    out = cli_in_process("fit", *args, "--ckpt_path", "last", "--trainer.default_root_dir=elsewhere", cwd=tmp_path)
    assert out.returncode == 2 and "--ckpt_path last: no last.ckpt in elsewhere/lightning_logs/*/checkpoints" \
        in out.stderr
    # on another scene's data: one line (the model built for those data could not take the weights: a size list)
    from lnn_torch.data import DatasetSpec, generate_dataset

    other = generate_dataset(DatasetSpec(scene="pendulum", num_trajectories=6, duration=0.5, seed=1), tmp_path / "p.h5")
    out = cli_in_process("fit", "--data.path", str(other), "--trainer.max_steps=2", "--ckpt_path",
                         str(second / "last.ckpt"), cwd=tmp_path)
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr[-2000:]
    assert "a model of scene 'double_pendulum', and the data (" in out.stderr and "hold 'pendulum'" in out.stderr


@pytest.mark.slow
def test_a_resumed_fit_logs_what_the_uninterrupted_one_logs(dataset, tmp_path):
    """20 steps, then from last.ckpt to 40: at each step written the resumed run logs the learning rate a run of 40
    steps logs there (the same schedule at the same step; keyed on global_step, which Lightning's own step counter
    runs one ahead of after a resume, every training value was written 10 steps late and some steps not at all)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    args = tiny_fit_args(dataset, "--data.spec.seed=5", "--model.hidden_dims=[8,8]", "--model.val_rollout_seconds=0.2",
                         "--data.steps_per_epoch=20", "--trainer.check_val_every_n_epoch=1", "--model.compile=false",
                         "--trainer.log_every_n_steps=5")

    def scalars(folder, tag="train/loss"):
        events = EventAccumulator(str(folder)).Reload()
        return {e.step: e.value for e in events.Scalars(tag)}

    assert cli_in_process("fit", *args, "--trainer.max_epochs=2", "--trainer.default_root_dir=whole",
                          cwd=tmp_path).returncode == 0
    assert cli_in_process("fit", *args, "--trainer.max_epochs=1", "--trainer.default_root_dir=parts",
                          cwd=tmp_path).returncode == 0
    out = cli_in_process("fit", *args, "--trainer.max_epochs=2", "--trainer.default_root_dir=parts",
                         "--ckpt_path", "last", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    whole = scalars(tmp_path / "whole" / "lightning_logs" / "version_0", "train/lr")
    second = scalars(tmp_path / "parts" / "lightning_logs" / "version_1", "train/lr")
    assert sorted(whole) == [4, 9, 14, 19, 24, 29, 34, 39] and sorted(second) == [24, 29, 34, 39], (whole, second)
    assert len(set(second.values())) == 4  # (the cosine moves between the steps written)
    for step, value in second.items():
        assert value == pytest.approx(whole[step], rel=1e-6), (step, value, whole[step])


@pytest.mark.slow
def test_mixed_precision_trains_and_the_optimiser_options_are_refused(dataset, tmp_path):
    """bf16-mixed (16-mixed on a CPU) with the default gradient clipping trains (the fused AdamW refused clipping
    gradients it unscales itself); Lightning's --optimizer and --lr_scheduler are refused saying what to set (they
    replaced the model's whole optimisation, or did nothing without --optimizer)."""
    args = tiny_fit_args(dataset, "--data.spec.seed=5", "--model.hidden_dims=[8,8]", "--model.val_rollout_seconds=0.2",
                         "--data.steps_per_epoch=2", "--trainer.max_epochs=1", "--model.compile=false")
    out = cli_in_process("fit", *args, "--trainer.precision=bf16-mixed", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "lnn-torch fit: 2 steps" in out.stdout
    # a run folder's config.yaml (optimizer: null, as Lightning writes it) is read; a config's own optimiser refused
    (tmp_path / "null.yaml").write_text("optimizer: null\nlr_scheduler: null\n")
    assert cli_in_process("fit", *args, "-c", "null.yaml", cwd=tmp_path).returncode == 0
    (tmp_path / "sgd.yaml").write_text("optimizer:\n  class_path: torch.optim.SGD\n  init_args:\n    lr: 0.1\n")
    out = cli_in_process("fit", *args, "-c", "sgd.yaml", cwd=tmp_path)
    assert out.returncode == 2 and "optimizer: the model configures its own optimiser (AdamW" in out.stderr
    for option in (["--optimizer", "SGD", "--optimizer.lr", "0.01"], ["--lr_scheduler=StepLR"]):
        out = cli_in_process("fit", *args, *option, cwd=tmp_path)
        assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr[-2000:]
        assert f"{option[0].split('=')[0]}: the model configures its own optimiser (AdamW" in out.stderr
        assert "set --model.lr, --model.lr_min, --model.weight_decay" in out.stderr


@pytest.mark.slow
def test_default_root_dir_holds_logs_and_checkpoints(dataset, tmp_path):
    """--trainer.default_root_dir DIR moves the default TensorBoard run and the checkpoints to DIR
    (the logger's save_dir is no longer fixed to the working directory)."""
    common = ["-c", str(ROOT / "configs" / "quickstart.yaml"), f"--data.path={dataset}",
              "--data.spec.num_trajectories=20", "--data.spec.duration=2.0", "--data.spec.seed=5",
              "--model.hidden_dims=[8,8]", "--model.val_rollout_seconds=0.2", "--trainer.enable_progress_bar=false",
              "--trainer.max_epochs=1", "--data.steps_per_epoch=2", f"--trainer.default_root_dir={tmp_path / 'runs'}"]
    out = cli_in_process("fit", *common, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert glob.glob(str(tmp_path / "runs" / "lightning_logs" / "version_0" / "events.*"))
    assert glob.glob(str(tmp_path / "runs" / "lightning_logs" / "version_0" / "checkpoints" / "last.ckpt"))
    assert not (tmp_path / "lightning_logs").exists()
    # an explicit save_dir still wins
    out = cli_in_process("fit", *common, f"--trainer.logger.init_args.save_dir={tmp_path / 'mine'}", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert glob.glob(str(tmp_path / "mine" / "lightning_logs" / "version_0" / "events.*"))


@pytest.mark.slow
def test_a_measured_config_without_its_imported_file_says_to_import_it(tmp_path):
    """Fitting the real-pendulum config before importing its recordings names the missing file and the
    import command (it used to fall back to generating a simulated double pendulum and then refuse the
    torque loss with an unrelated message); a spec'd dataset still generates."""
    out = cli_in_process("fit", "-c", str(ROOT / "configs" / "real_double_pendulum.yaml"),
               f"--data.path={tmp_path / 'absent.h5'}", "--trainer.fast_dev_run=true", cwd=tmp_path)
    assert out.returncode != 0
    assert "absent.h5 not found" in out.stderr and "lnn-torch import" in out.stderr, out.stderr[-2000:]
    assert not (tmp_path / "absent.h5").exists()
    with pytest.raises(FileNotFoundError, match="import them first"):
        TrajectoryDataModule(path=str(tmp_path / "absent.h5"), targets="savgol")
    assert TrajectoryDataModule(path=str(tmp_path / "sim.h5"), spec=dict(num_trajectories=4, duration=0.2),
                                targets="savgol").model_scene()[0] == "double_pendulum"


def test_a_misspelt_option_is_two_lines_with_the_nearest_one(tmp_path):
    """A misspelt option, on the command line or in a config file: the error, with the option meant, and the
    pointer to --help (Lightning's parser printed 90 lines of usage first)."""
    (tmp_path / "typo.yaml").write_text("model:\n  hiden_dims: [8, 8]\n")
    for extra, expected in ((["--model.hiden_dims=[8,8]"], "error: unrecognized arguments: --model.hiden_dims=[8,8] "
                                                            "(did you mean --model.hidden_dims?)"),
                            (["-c", str(tmp_path / "typo.yaml")], "error: Subcommand 'fit' does not accept option "
                                                                  "'model.hiden_dims' (did you mean "
                                                                  "--model.hidden_dims?)")):
        out = cli_in_process("fit", "-c", str(ROOT / "configs" / "quickstart.yaml"), *extra, cwd=tmp_path)
        assert out.returncode == 2
        tip, error = out.stderr.strip().splitlines()  # (the program's name is the process's: lnn-torch in a shell)
        assert tip.startswith("tip: For details of accepted options run: ") and tip.endswith(" fit --help")
        assert error == expected, out.stderr[-2000:]


@pytest.mark.skipif(torch.cuda.is_available(), reason="a machine with CUDA takes the GPU")
def test_a_gpu_asked_for_on_a_machine_without_one_is_one_line(tmp_path):
    """``--trainer.accelerator gpu`` without CUDA: Lightning's MisconfigurationException was a traceback."""
    out = cli_in_process("fit", "-c", str(ROOT / "configs" / "quickstart.yaml"), "--trainer.accelerator=gpu",
                         f"--data.path={tmp_path / 'd.h5'}", "--data.spec.num_trajectories=4", cwd=tmp_path)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == ["lnn-torch fit: error: the trainer cannot be set up as asked: No "
                                               "supported gpu backend found! (this machine has no CUDA device: "
                                               "--trainer.accelerator cpu, or leave it out)"], out.stderr[-2000:]


@pytest.mark.parametrize("argv", [["import", "run.csv"], ["simulate", "--params", "1"], ["export"],
                                  ["evaluate", "x.ckpt", "--horizon", "soon"]])
def test_a_commands_bad_arguments_are_one_line_with_the_pointer_to_help(argv, tmp_path):
    """The commands that are not Lightning's: argparse printed the whole usage first (27 lines for import)."""
    out = cli_in_process(*argv, cwd=tmp_path)
    assert out.returncode == 2
    (line,) = out.stderr.strip().splitlines()
    assert line.startswith(f"lnn-torch {argv[0]}: error: ") and line.endswith(f"(options: lnn-torch {argv[0]} --help)")


def _imported(config: Path, tmp_path: Path) -> Path:
    """The dataset of a config of measured data, imported with its import config: the shipped recordings
    where the package ships them; otherwise (a recording that stays outside the package, such as the real
    Panda's) smooth stand-ins with the columns and the time span the import config names."""
    import yaml

    importer = ROOT / "configs" / "import" / config.name
    recordings = sorted((ROOT / "lnn_torch" / "datasets" / config.stem / "recordings").glob("*.csv.gz"))
    if not recordings:
        spec = yaml.safe_load(importer.read_text())
        names = sorted({w.split("[")[0] for part in spec["split"].values() for w in part})
        ends = [float(w.split(":")[1].rstrip("]")) for part in spec["split"].values() for w in part if ":" in w]
        end = max(ends, default=5.0)  # recordings named whole: 5 s each
        t = np.arange(0.0, end + 0.5, spec.get("dt", 0.01))
        dof = len(spec["coordinates"])
        k = np.arange(1, dof + 1)[None]
        q = 0.3 * np.sin(0.7 * k * t[:, None]) - np.where(k == 4, 1.5, 0.0)
        dq = 0.21 * k * np.cos(0.7 * k * t[:, None])
        tau = 5.0 * np.cos(0.5 * k * t[:, None])
        header = [spec["time"], *spec["coordinates"], *spec["velocities"], *spec["inputs"]]
        for name in names:
            recordings.append(tmp_path / f"{name}.csv")
            np.savetxt(recordings[-1], np.column_stack([t, q, dq, tau]), delimiter=",", header=",".join(header),
                       comments="")
    data = tmp_path / "d.h5"
    out = cli_in_process("import", *map(str, recordings), "--config", str(importer), "-o", str(data), cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    return data
