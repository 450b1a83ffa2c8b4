"""Training (``LNNModule`` under Lightning): logged values, TensorBoard tags, checkpoints, skipped
non-finite steps, DDP, learning what an HNN on (q, qd) cannot. The data: test_datamodule.py; the
command line and configs: test_cli.py; compiled training: test_compile.py."""

import glob
import warnings
from pathlib import Path
from types import SimpleNamespace

import lightning as L
import numpy as np
import pytest
import torch

from lnn_torch import LNNModule
from lnn_torch.data import DatasetSpec, generate_dataset
from lnn_torch.training.datamodule import TrajectoryDataModule

from .helpers import ROOT, make_dm, quiet_trainer, random_batch, run_cli


def _fit(dataset, tmp_path, **model_kw):
    model = LNNModule(val_rollouts=2, val_rollout_seconds=0.5, hidden_dims=[32, 32], figure_every_n_epochs=1,
                      **model_kw)
    trainer = quiet_trainer(tmp_path, max_epochs=2)
    trainer.fit(model, make_dm(dataset))
    return model, trainer


def test_per_step_values_are_logged_on_the_written_steps_with_that_steps_values(dataset, tmp_path):
    """Per-step training values are logged only on the steps the logger writes (every
    log_every_n_steps): the written steps are those multiples, and each written value is that step's
    own (the learning rate of the step, which changes every step)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    model = LNNModule(val_rollouts=0, hidden_dims=[16, 16], lr=1e-3, lr_min=1e-5, compile=False)
    seen = []

    class Record(L.Callback):
        def on_before_optimizer_step(self, trainer, pl_module, optimizer):
            seen.append(optimizer.param_groups[0]["lr"])

    trainer = quiet_trainer(tmp_path, max_epochs=-1, max_steps=12, log_every_n_steps=4, limit_val_batches=0,
                            callbacks=[Record()])
    trainer.fit(model, make_dm(dataset))
    events = glob.glob(str(tmp_path / "lightning_logs" / "version_0" / "events.*"))
    acc = EventAccumulator(str(Path(events[0]).parent), size_guidance={"scalars": 0})
    acc.Reload()
    lr = acc.Scalars("train/lr")
    assert [e.step for e in lr] == [3, 7, 11]
    np.testing.assert_allclose([e.value for e in lr], [seen[3], seen[7], seen[11]], rtol=1e-6)
    assert [e.step for e in acc.Scalars("train/loss")] == [3, 7, 11]
    assert len(set(seen)) == 12  # the learning rate differs at every step: the test can tell steps apart


def test_a_single_term_loss_logs_one_curve_and_figures_come_at_the_last_validation(dataset, tmp_path):
    """Without the energy term the loss is the Huber term alone: one curve (train/loss), not two equal
    ones; with figures every 2nd validation of 3, the last validation logs them too."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    model = LNNModule(val_rollouts=1, val_rollout_seconds=0.2, hidden_dims=[8, 8], figure_every_n_epochs=2,
                      compile=False)
    trainer = quiet_trainer(tmp_path, max_epochs=3, limit_train_batches=2, log_every_n_steps=1)
    trainer.fit(model, make_dm(dataset))
    events = glob.glob(str(tmp_path / "lightning_logs" / "version_0" / "events.*"))
    acc = EventAccumulator(str(Path(events[0]).parent), size_guidance={"images": 0, "scalars": 0})
    acc.Reload()
    assert "train/loss" in acc.Tags()["scalars"] and "train/huber" not in acc.Tags()["scalars"]
    val_steps = [e.step for e in acc.Scalars("val/acc_rel_err")]
    assert len(val_steps) == 3
    assert [e.step for e in acc.Images("val/trajectory")] == [val_steps[1], val_steps[2]]


def test_fit_logs_tensorboard_tags_and_checkpoint_round_trip(dataset, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    model, trainer = _fit(dataset, tmp_path, energy_weight=0.1)
    events = glob.glob(str(tmp_path / "lightning_logs" / "version_0" / "events.*"))
    assert events
    acc = EventAccumulator(str(Path(events[0]).parent), size_guidance={"images": 0, "scalars": 0})
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    for tag in ("train/loss", "train/huber", "train/energy_var", "val/acc_rel_err", "val/acc_rel_err_theta1",
                "val/acc_rel_err_traj_median",
                "val/acc_rel_err_theta2", "val/energy_drift", "val/divergence_time", "train/lr",
                "train/skipped_steps"):
        assert tag in tags, tag
    assert {"val/trajectory", "val/energy"} <= set(acc.Tags()["images"])
    # figures at every validation, the last one included, at the step of its scalars
    val_steps = [e.step for e in acc.Scalars("val/acc_rel_err")]
    assert len(val_steps) == 2 and [e.step for e in acc.Images("val/trajectory")] == val_steps
    assert "hp_metric" not in tags
    # the HParams plugin data (hyper-parameters logged with the metric keys)
    plugin = acc.PluginTagToContent("hparams")
    assert plugin, "no hparams summary"

    ckpt = tmp_path / "model.ckpt"
    trainer.save_checkpoint(ckpt)
    loaded = LNNModule.load_from_checkpoint(ckpt)
    assert bool(loaded.normalizer_fitted)
    torch.testing.assert_close(loaded.model.normalizer.time_scale, model.model.normalizer.time_scale)
    q = torch.tensor([[0.3, -0.2], [1.0, 0.5]])
    qd = torch.tensor([[0.1, 0.2], [-0.5, 0.3]])
    params = torch.tensor([[1.0, 0.5, 1.2, 1.3], [1.5, 1.0, 1.0, 1.0]])
    with torch.no_grad():
        a1, a2 = model.acceleration(q, qd, params), loaded.acceleration(q, qd, params)
        qs, qds = loaded.rollout(q, qd, params, 0.01, 10)
    torch.testing.assert_close(a1, a2)
    assert qs.shape == (2, 11, 2) and torch.isfinite(qs).all()
    # the data path as given (here absolute) and, resolved, the file the fit read: a relative path that does not
    # hold from another folder is read from there
    from lnn_torch.training.checkpoint_format import data_hparams

    assert data_hparams(ckpt)["path"] == str(dataset)
    raw = torch.load(ckpt, weights_only=False)
    assert raw["data_path_resolved"] == str(Path(dataset).resolve())
    raw["datamodule_hyper_parameters"]["path"] = "data/not_from_here.h5"  # as a fit in another folder named it
    torch.save(raw, tmp_path / "moved.ckpt")
    assert data_hparams(tmp_path / "moved.ckpt")["path"] == str(Path(dataset).resolve())


def test_non_finite_loss_skips_the_step(dataset, tmp_path):
    model = LNNModule(val_rollouts=0, hidden_dims=[16])
    dm = make_dm(dataset)
    dm.setup("fit")

    class Poisoned(torch.utils.data.Dataset):
        def __init__(self, base):
            self.base = base

        def __len__(self):
            return len(self.base)

        def __getitem__(self, i):
            item = self.base[i]
            item["qdd"] = item["qdd"] * float("nan")
            return item

    dm.train_set = Poisoned(dm.train_set)
    dm.setup = lambda stage=None: None
    model.model.normalizer.fit(*(dm.normalization_data()[k] for k in ("q", "qd", "qdd", "params")))
    model.normalizer_fitted.fill_(True)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    trainer = quiet_trainer(tmp_path, max_epochs=1, limit_val_batches=0)
    trainer.fit(model, dm)
    assert int(model.skipped_steps) == 5
    for k, v in model.state_dict().items():
        if k != "skipped_steps":
            torch.testing.assert_close(v, before[k], msg=k)


@pytest.mark.slow
def test_ddp_two_cpu_processes(dataset, tmp_path):
    """Lightning's own DDP strategy: two CPU processes, one writer of logs and checkpoints."""
    common = ["-c", str(ROOT / "configs" / "quickstart.yaml"), f"--data.path={dataset}",
              "--data.spec.num_trajectories=20", "--data.spec.duration=2.0", "--data.spec.seed=5",
              "--model.hidden_dims=[16,16]", "--model.val_rollout_seconds=0.5", "--trainer.enable_progress_bar=false",
              "--trainer.max_epochs=1", "--data.steps_per_epoch=4", "--trainer.strategy=ddp", "--trainer.devices=2",
              "--trainer.accelerator=cpu"]
    out = run_cli("fit", *common, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    versions = glob.glob(str(tmp_path / "lightning_logs" / "version_*"))
    assert len(versions) == 1
    assert len(glob.glob(versions[0] + "/events.*")) == 1
    assert glob.glob(versions[0] + "/checkpoints/last.ckpt")


def test_learning_rate_ten_times_too_high_stays_finite(dataset, tmp_path):
    """lr = 3e-2 (10x the default): gradient clipping and the non-finite skip keep the weights finite."""
    model = LNNModule(lr=3e-2, lr_min=3e-4, val_rollouts=0, hidden_dims=[32, 32], energy_weight=0.1)
    trainer = quiet_trainer(tmp_path, max_epochs=4, limit_val_batches=0, gradient_clip_val=1.0)
    trainer.fit(model, make_dm(dataset, steps_per_epoch=25))
    assert trainer.global_step == 100
    assert all(torch.isfinite(p).all() for p in model.parameters())
    q = torch.tensor([[0.3, -0.2]])
    assert torch.isfinite(model.acceleration(q, q, torch.tensor([[1.0, 0.5, 1.2, 1.3]]))).all()


def _watch(losses):
    """The warnings ``DivergenceWatch`` gives on a sequence of training losses."""
    from lnn_torch.training.callbacks import DivergenceWatch

    watch, trainer = DivergenceWatch(), SimpleNamespace(global_step=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for step, loss in enumerate(losses):
            trainer.global_step = step
            watch.on_before_backward(trainer, SimpleNamespace(hparams={"lr": 0.02}), torch.tensor(loss))
    return [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]


def test_a_finite_divergence_is_warned_once_and_a_noisy_descent_is_not():
    """A loss that falls to 1e-3 and then climbs to ~1 (a learning rate past the edge: finite, ~100 %
    error) warns once, naming the step and the learning rate; a noisy descent with spikes tenfold above
    its trend, or a loss that plateaus, does not."""
    rng = np.random.default_rng(0)
    steps = np.arange(3000)
    descent = 10.0 ** (-3 * np.minimum(steps, 1000) / 1000)  # 1 -> 1e-3 over 1000 steps, then flat
    diverged = np.where(steps < 1500, descent, 1.0) * np.exp(rng.normal(0, 0.3, steps.size))
    caught = _watch(diverged)
    assert len(caught) == 1 and "training diverged at step 15" in caught[0] and "model.lr, now 0.02" in caught[0]
    spiky = descent * np.exp(rng.normal(0, 0.5, steps.size)) * np.where(rng.random(steps.size) < 0.01, 10.0, 1.0)
    assert _watch(spiky) == []
    assert _watch(np.full(3000, 0.5)) == []


def test_training_conditions_once_per_chunk(dataset):
    """Datamodule batches are chunks of one trajectory each: the training pass is told so (FiLM once
    per chunk); a batch whose parameters vary inside a chunk is passed per row."""
    dm = make_dm(dataset)
    dm.setup("fit")
    batch = dm.train_set[0]
    model = LNNModule(val_rollouts=0, hidden_dims=[16, 16])
    model.model.fit_normalizer(dm.normalization_data())
    seen = []

    def spy(*args):
        seen.append(args[-1])
        return model.training_terms(*args)

    loss_shared, _ = model.batch_loss(batch, spy)
    mixed = dict(batch, params=batch["params"].clone())
    mixed["params"][0, 1:] *= 1.1
    model.batch_loss(mixed, spy)
    C = batch["q"].shape[0]
    assert seen == [C, None]
    loss_rows, _ = model.batch_loss(batch, lambda *a: model.training_terms(*a[:-1], None))
    torch.testing.assert_close(loss_shared, loss_rows, rtol=1e-5, atol=0)


@pytest.mark.slow
def test_lnn_learns_the_relativistic_particle_where_an_hnn_on_q_qd_fails(tmp_path):
    """The LNN paper's point: with (q, qd) inputs an HNN cannot represent the relativistic particle
    (qdd depends on qd, but a Hamiltonian flow in (q, qd) with qdot = qd cannot), while the LNN
    and an HNN given canonical momenta learn it. Judged on rollouts of 8 held-out trajectories:
    the median over trajectories of the max position error over 5 s (c = 1 units)."""
    from lnn_torch.networks import counting_failures

    spec = dict(scene="relativistic_particle", num_trajectories=80, duration=5.0, dt=0.01, seed=2)
    path = tmp_path / "rel.h5"
    generate_dataset(DatasetSpec(**spec), path)
    errors = {}
    for name, steps, kw in (("lnn", 1200, dict(variant="lnn", lr=1e-2)),
                            ("hnn canonical", 1200, dict(variant="hnn")),
                            ("hnn velocity", 1200, dict(variant="hnn", hnn_coordinates="velocity"))):
        torch.manual_seed(0)
        model = LNNModule(scene="relativistic_particle", hidden_dims=[32, 32], val_rollouts=0, **kw)
        dm = TrajectoryDataModule(path=str(path), spec=spec, chunk_len=8, chunks_per_batch=32, steps_per_epoch=steps)
        trainer = quiet_trainer(tmp_path, max_epochs=1, limit_val_batches=0, logger=False, enable_checkpointing=False)
        trainer.fit(model, dm)
        data = dm.trajectories("test")
        with counting_failures(model.model), torch.no_grad():
            q, _ = model.rollout(data.q[:, 0], data.qd[:, 0], data.params, data.dt, data.num_points - 1)
        errors[name] = float((q - data.q).abs().amax((1, 2)).median())
    print("relativistic particle, median max position error over 5 s:", errors)
    # measured (medians of 8, 1200 steps each): lnn 0.029, hnn canonical 0.012, hnn velocity 0.162
    assert errors["lnn"] < 0.06 and errors["hnn canonical"] < 0.06, errors
    assert errors["hnn velocity"] > 3 * max(errors["lnn"], errors["hnn canonical"]), errors


def test_last_checkpoint_holds_the_final_weights_when_validation_stops_improving(dataset, tmp_path):
    """Lightning's save_last writes last.ckpt only when the monitored metric improves; the project's
    LastCheckpoint writes it at every epoch's end. Monitored here: a metric that never improves."""
    from lightning.pytorch.callbacks import ModelCheckpoint

    from lnn_torch.training.callbacks import LastCheckpoint

    model = LNNModule(hidden_dims=[8, 8], val_rollouts=0)
    monitored = ModelCheckpoint(monitor="val/acc_non_finite", mode="min")
    trainer = quiet_trainer(tmp_path, max_epochs=2, callbacks=[monitored, LastCheckpoint()])
    trainer.fit(model, make_dm(dataset, steps_per_epoch=2))
    assert Path(monitored.best_model_path).name.startswith("epoch=0")  # never improved after the first
    last = torch.load(Path(monitored.dirpath) / "last.ckpt", weights_only=False)
    assert last["global_step"] == 4 and last["epoch"] == 1


def test_checkpoints_record_their_widths_and_old_ones_load_with_the_old_default(dataset, tmp_path):
    """A checkpoint of a model built with the default widths records them (64 x 64 now), so a later
    change of the default cannot change what it loads as; a checkpoint that recorded none (saved before)
    loads with the old default, 128 x 128, with its own weights."""
    trainer = quiet_trainer(tmp_path, max_epochs=1, logger=False, enable_checkpointing=False, limit_val_batches=0)
    model = LNNModule(val_rollouts=0)
    trainer.fit(model, make_dm(dataset, steps_per_epoch=1))
    trainer.save_checkpoint(tmp_path / "new.ckpt")
    ckpt = torch.load(tmp_path / "new.ckpt", weights_only=False)
    assert ckpt["hyper_parameters"]["hidden_dims"] == [64, 64]
    assert LNNModule.load_from_checkpoint(tmp_path / "new.ckpt").model.hidden_dims == (64, 64)
    from lnn_torch._version import __version__
    from lnn_torch.training.checkpoint_format import CHECKPOINT_FORMAT

    # what a newer-version check reads
    assert ckpt["lnn_torch"] == {"version": __version__, "format": CHECKPOINT_FORMAT}

    old = LNNModule(hidden_dims=[128, 128], val_rollouts=0)
    trainer = quiet_trainer(tmp_path, max_epochs=1, logger=False, enable_checkpointing=False, limit_val_batches=0)
    trainer.fit(old, make_dm(dataset, steps_per_epoch=1))
    trainer.save_checkpoint(tmp_path / "old.ckpt")
    ckpt = torch.load(tmp_path / "old.ckpt", weights_only=False)
    ckpt["hyper_parameters"]["hidden_dims"] = None  # as the checkpoints of LNNModule() recorded it before
    torch.save(ckpt, tmp_path / "old.ckpt")
    loaded = LNNModule.load_from_checkpoint(tmp_path / "old.ckpt")
    assert loaded.model.hidden_dims == (128, 128)
    q, qd, params = torch.zeros(3, 2) + 0.3, torch.ones(3, 2), torch.tensor([[1.0, 0.6, 1.2, 1.1]]).expand(3, -1)
    with torch.no_grad():
        torch.testing.assert_close(loaded.acceleration(q, qd, params), old.acceleration(q, qd, params))


def test_a_double_pendulum_checkpoint_of_format_1_loads_without_the_relative_angle(dataset, tmp_path):
    """Checkpoints of format 2 on read sin/cos of theta1 - theta2 too (6 features); one of format 1 (or
    unstamped) was trained on the absolute angles alone (4) and loads so, with its own weights, recording
    ``relative_angle: false`` from then on."""
    new = LNNModule(val_rollouts=0, hidden_dims=[16, 16], compile=False)
    assert new.model.angle_features.num_features == 6
    old = LNNModule(val_rollouts=0, hidden_dims=[16, 16], compile=False, scene_config={"relative_angle": False})
    assert old.model.angle_features.num_features == 4
    trainer = quiet_trainer(tmp_path, max_steps=2, logger=False, enable_checkpointing=False, limit_val_batches=0)
    trainer.fit(old, make_dm(dataset))
    trainer.save_checkpoint(tmp_path / "old.ckpt")
    ckpt = torch.load(tmp_path / "old.ckpt", weights_only=False)
    ckpt["hyper_parameters"]["scene_config"] = None  # as LNNModule() recorded it before format 2
    q, qd, params = torch.zeros(3, 2) + 0.3, torch.ones(3, 2), torch.tensor([[1.0, 0.6, 1.2, 1.1]]).expand(3, -1)
    for stamp in ({"version": "0.1.0", "format": 1}, None):
        if stamp is None:
            ckpt.pop("lnn_torch")
        else:
            ckpt["lnn_torch"] = stamp
        torch.save(ckpt, tmp_path / "old.ckpt")
        loaded = LNNModule.load_from_checkpoint(tmp_path / "old.ckpt")
        assert loaded.model.angle_features.num_features == 4
        assert loaded.hparams.scene_config == {"relative_angle": False}
        with torch.no_grad():
            torch.testing.assert_close(loaded.acceleration(q, qd, params), old.acceleration(q, qd, params))
    ckpt["lnn_torch"] = {"version": "0.1.0", "format": 2}  # the same file as format 2 holds other weights
    torch.save(ckpt, tmp_path / "old.ckpt")
    with pytest.raises(RuntimeError, match="size mismatch"):
        LNNModule.load_from_checkpoint(tmp_path / "old.ckpt")
    # starting a run with the relative angle from it is refused with the setting that fits named
    ckpt["lnn_torch"] = {"version": "0.1.0", "format": 1}
    torch.save(ckpt, tmp_path / "old.ckpt")
    from lnn_torch.errors import CheckpointError
    from lnn_torch.training.checkpoint_format import load_start_weights

    with pytest.raises(CheckpointError, match="without the relative-angle feature.*relative_angle: false"):
        load_start_weights(LNNModule(val_rollouts=0, hidden_dims=[16, 16], compile=False), tmp_path / "old.ckpt")
    load_start_weights(old, tmp_path / "old.ckpt")  # the model without it takes its weights


def test_init_from_starts_a_run_from_a_checkpoints_weights_and_normaliser_with_a_fresh_schedule(dataset, tmp_path):
    """``init_from``: the weights and normaliser of a checkpoint start the run (its normaliser altered
    here so that a refit on the data would differ), the learning rate starts at ``lr`` again and the
    weights then train; a checkpoint of other widths or another variant is refused in one line."""
    from lnn_torch.errors import CheckpointError

    first = LNNModule(val_rollouts=0, hidden_dims=[16, 16], compile=False)
    trainer = quiet_trainer(tmp_path / "a", max_steps=3, logger=False, enable_checkpointing=False, limit_val_batches=0)
    trainer.fit(first, make_dm(dataset))
    first.model.normalizer.time_scale.mul_(2.0)
    trainer.save_checkpoint(tmp_path / "first.ckpt")
    start, lrs = {}, []

    class Record(L.Callback):
        def on_train_start(self, trainer, pl_module):
            start.update({k: v.clone() for k, v in pl_module.state_dict().items()})

        def on_before_optimizer_step(self, trainer, pl_module, optimizer):
            lrs.append(optimizer.param_groups[0]["lr"])

    second = LNNModule(val_rollouts=0, hidden_dims=[16, 16], compile=False, lr=1e-3,
                       init_from=str(tmp_path / "first.ckpt"))
    trainer = quiet_trainer(tmp_path / "b", max_steps=3, logger=False, enable_checkpointing=False, limit_val_batches=0,
                            callbacks=[Record()])
    trainer.fit(second, make_dm(dataset))
    for name, value in first.state_dict().items():
        if name != "skipped_steps":
            torch.testing.assert_close(start[name], value, msg=name)
    assert lrs[0] == pytest.approx(1e-3) and trainer.global_step == 3
    torch.testing.assert_close(second.model.normalizer.time_scale, first.model.normalizer.time_scale)
    moved = [n for n, p in second.named_parameters() if not torch.equal(p, first.state_dict()[n])]
    assert moved  # and it trained from there
    for kw, match in (({"hidden_dims": [8, 8]}, "weights do not fit this model"),
                      ({"hidden_dims": [16, 16], "variant": "delan"},
                       "its variant is 'film_lnn', this run's is 'delan'")):
        other = LNNModule(val_rollouts=0, compile=False, init_from=str(tmp_path / "first.ckpt"), **kw)
        trainer = quiet_trainer(tmp_path / "c", max_steps=1, logger=False, enable_checkpointing=False,
                                limit_val_batches=0)
        with pytest.raises(CheckpointError, match=match):
            trainer.fit(other, make_dm(dataset))


def test_a_residual_beside_a_fitted_model_trains_alone_from_zero(tmp_path):
    """``init_from`` a model without a force residual into the same model with one, ``train_only:
    residual_force``: the run starts as the fitted model (the residual at zero, its units fitted from
    the data), only the residual trains, and every other weight and the normaliser stay as they were;
    ``train_only`` without a residual, of an unknown part or without ``init_from`` is refused in one line."""
    from lnn_torch.errors import InputError

    path, spec = tmp_path / "adp.h5", dict(scene="actuated_double_pendulum", num_trajectories=6, duration=1.0, seed=4)
    generate_dataset(DatasetSpec(**spec), path)
    scene = dict(scene="actuated_double_pendulum", val_rollouts=0, hidden_dims=[16, 16], compile=False)
    first = LNNModule(**scene)
    trainer = quiet_trainer(tmp_path / "a", max_steps=3, logger=False, enable_checkpointing=False, limit_val_batches=0)
    trainer.fit(first, make_dm(path, spec=spec))
    trainer.save_checkpoint(tmp_path / "grey.ckpt")
    start = {}

    class Record(L.Callback):
        def on_train_start(self, trainer, pl_module):
            q, qd, p = random_batch(pl_module.system, np.random.default_rng(0), 5, torch.float32)
            tau = torch.randn(5, 2)
            with torch.no_grad():
                start["same"] = torch.equal(pl_module.acceleration(q, qd, p, tau), first.acceleration(q, qd, p, tau))
            start["unit"] = pl_module.model.forces.residual.unit.clone()

    second = LNNModule(**scene, model_options={"residual_force": {"hidden": [8]}}, lr=1e-2,
                       init_from=str(tmp_path / "grey.ckpt"), train_only="residual_force")
    trainer = quiet_trainer(tmp_path / "b", max_steps=5, logger=False, enable_checkpointing=False, limit_val_batches=0,
                            callbacks=[Record()])
    trainer.fit(second, make_dm(path, spec=spec))
    assert start["same"] and not torch.equal(start["unit"], torch.ones(2))  # at zero, in the data's units
    theirs = first.state_dict()
    for name, value in second.state_dict().items():
        if name.startswith("model.forces.residual."):
            continue
        if name != "skipped_steps":
            assert torch.equal(value, theirs[name]), name
    out = second.model.forces.residual.output_layer[0]
    assert out.abs().max() > 0  # the residual trained
    grey = str(tmp_path / "grey.ckpt")
    with pytest.raises(InputError, match="train_only residual_force: the model has no residual_force"):
        LNNModule(**scene, train_only="residual_force", init_from=grey)
    with pytest.raises(InputError, match="train_only must be one of residual_force"):
        LNNModule(**scene, model_options={"residual_force": {}}, train_only="kinetic", init_from=grey)
    with pytest.raises(InputError, match="train_only residual_force needs init_from"):
        LNNModule(**scene, model_options={"residual_force": {}}, train_only="residual_force")
