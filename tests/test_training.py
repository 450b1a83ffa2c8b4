"""Training and use: DataModule chunks and splits, LNNModule, TensorBoard tags, checkpoints, CLI."""

import glob
import json
import re
import subprocess
import sys
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch

from lnn_torch import LNNModule, rollout
from lnn_torch.data import DatasetSpec, generate_dataset, read_dataset
from lnn_torch.data.datamodule import TrajectoryDataModule

ROOT = Path(__file__).resolve().parents[1]
SPEC = dict(scene="double_pendulum", num_trajectories=20, duration=2.0, dt=0.005, seed=5)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    path = tmp_path_factory.mktemp("data") / "dp.h5"
    generate_dataset(DatasetSpec(**SPEC), path)
    return path


def make_dm(path, **kw):
    args = dict(path=str(path), spec=SPEC, chunk_len=16, chunks_per_batch=4, steps_per_epoch=5, eval_stride=20)
    args.update(kw)
    return TrajectoryDataModule(**args)


def quiet_trainer(tmp_path, **kw):
    from lightning.pytorch.loggers import TensorBoardLogger

    args = dict(max_epochs=1, inference_mode=False, enable_progress_bar=False, enable_model_summary=False,
                logger=TensorBoardLogger(str(tmp_path), name="lightning_logs", default_hp_metric=False),
                log_every_n_steps=1, default_root_dir=str(tmp_path), accelerator="cpu", devices=1)
    args.update(kw)
    return L.Trainer(**args)


def test_chunks_are_contiguous_pieces_of_training_trajectories(dataset):
    dm = make_dm(dataset)
    dm.setup("fit")
    f = read_dataset(dataset)
    q_all = f.read("q")
    batch = next(iter(dm.train_dataloader()))
    assert batch["q"].shape == (4, 16, 2) and batch["params"].shape == (4, 16, 4)
    train = set(f.splits["train"].tolist())
    for c in range(4):
        chunk = batch["q"][c].double().numpy()
        hits = [(i, s) for i in range(len(q_all)) for s in range(q_all.shape[1] - 15)
                if np.allclose(q_all[i, s : s + 16], chunk, atol=1e-6)]
        assert hits and hits[0][0] in train


def test_chunk_sampling_is_seeded_per_epoch_and_worker_safe(dataset):
    a, b = make_dm(dataset), make_dm(dataset, num_workers=2, in_memory=False)
    for dm in (a, b):
        dm.setup("fit")
    first = [x["q"] for x in a.train_dataloader()]
    second = [x["q"] for x in b.train_dataloader()]
    for x, y in zip(first, second):
        torch.testing.assert_close(x, y)
    a.set_epoch(1)
    other = [x["q"] for x in a.train_dataloader()]
    assert not torch.equal(first[0], other[0])


def test_eval_sets_are_fixed_and_use_the_split(dataset):
    """Validation and test yield the whole split once (what evaluate_model consumes), the same at
    every epoch; predict yields every eval_stride-th point of each test trajectory."""
    dm = make_dm(dataset)
    dm.setup("validate")
    f = read_dataset(dataset)
    v1, v2 = list(dm.val_dataloader()), list(dm.val_dataloader())
    assert len(v1) == 1 and v1[0]["accel_stride"] == 20
    torch.testing.assert_close(v1[0]["trajectories"].q, v2[0]["trajectories"].q)
    assert v1[0]["trajectories"].index.tolist() == f.splits["val"].tolist()
    np.testing.assert_array_equal(v1[0]["trajectories"].q.numpy(), f.read("q")[np.sort(f.splits["val"])])
    (test,) = list(dm.test_dataloader())
    assert test["trajectories"].index.tolist() == f.splits["test"].tolist()
    assert torch.cat([x["trajectory"] for x in dm.predict_dataloader()]).tolist() == f.splits["test"].tolist()


def test_normalisation_comes_from_the_training_split_only(dataset):
    dm = make_dm(dataset)
    f = read_dataset(dataset)
    stats = dm.normalization_data()
    np.testing.assert_array_equal(stats["params"].numpy(), f.read("params")[f.splits["train"]])


def test_a_file_from_another_spec_is_used_with_a_warning(dataset):
    dm = make_dm(dataset, spec=dict(SPEC, num_trajectories=30))
    with pytest.warns(UserWarning, match="num_trajectories: file 20 vs config 30"):
        dm.setup("fit")


def test_missing_file_is_generated(tmp_path):
    dm = make_dm(tmp_path / "new.h5", spec=dict(SPEC, num_trajectories=10, duration=0.5))
    dm.setup("fit")
    assert (tmp_path / "new.h5").exists()


def _fit(dataset, tmp_path, **model_kw):
    model = LNNModule(val_rollouts=2, val_rollout_seconds=0.5, hidden_dims=[32, 32], figure_every_n_epochs=1, **model_kw)
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


def test_rollout_function_methods_and_no_grad():
    from lnn_torch.systems import get_system

    system = get_system("pendulum")
    params = torch.tensor([[1.0, 1.0]], dtype=torch.float64)
    q0 = torch.tensor([[0.1]], dtype=torch.float64)
    qd0 = torch.zeros_like(q0)
    exact_period = 2 * np.pi / np.sqrt(9.81)
    for method in ("rk4", "leapfrog", "semi_implicit_euler", "rk8"):
        with torch.no_grad():
            q, qd = rollout(system.acceleration, q0, qd0, params, 0.001, 1000, method=method)
        assert q.shape == (1, 1001, 1) and not q.requires_grad
        assert abs(q[0, -1, 0].item() - 0.1 * np.cos(2 * np.pi / exact_period)) < 5e-3
    with pytest.raises(ValueError, match="unknown integrator 'euler2'"):
        rollout(system.acceleration, q0, qd0, params, 0.01, 1, method="euler2")


def test_written_out_rk4_equals_the_tableau_form():
    from lnn_torch.integrators import explicit_rk_step, rk4_step
    from lnn_torch.systems import get_system

    system = get_system("double_pendulum")
    rng = np.random.default_rng(0)
    params = torch.tensor(system.sample_params(rng, 16))
    q, qd = (torch.tensor(x) for x in system.sample_state(rng, 16))
    q1, qd1 = rk4_step(system.acceleration, q, qd, params, 0.01)
    y = explicit_rk_step("rk4", lambda y, p: torch.cat([y[:, 2:], system.acceleration(y[:, :2], y[:, 2:], p)], -1),
                         torch.cat([q, qd], -1), params, 0.01)
    torch.testing.assert_close(torch.cat([q1, qd1], -1), y, rtol=0, atol=1e-14)


@pytest.mark.parametrize("method, order", [("rk4", 4), ("leapfrog", 2), ("semi_implicit_euler", 1), ("rk8", 8)])
def test_integrator_convergence_orders(method, order):
    """Halving dt divides the global error by 2^order (harmonic oscillator, exact solution)."""
    from lnn_torch.systems import get_system

    system = get_system("mass_spring")
    params = torch.tensor([[1.0, 4.0]], dtype=torch.float64)  # omega = 2
    q0, qd0 = torch.tensor([[1.0]], dtype=torch.float64), torch.tensor([[0.0]], dtype=torch.float64)
    errs = []
    base = {1: 0.01, 2: 0.02, 4: 0.05, 8: 0.2}[order]
    for dt in (base, base / 2):
        n = int(round(2.0 / dt))
        q, _ = rollout(system.acceleration, q0, qd0, params, dt, n, method=method)
        errs.append(abs(q[0, -1, 0].item() - np.cos(2 * 2.0)))
    measured = np.log2(errs[0] / errs[1])
    assert abs(measured - order) < 0.35, measured


CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


@pytest.mark.parametrize("config", CONFIGS, ids=[c.name for c in CONFIGS])
def test_every_shipped_config_instantiates(config, tmp_path):
    from lnn_torch.data.datamodule import TrajectoryDataModule as DM
    from lnn_torch.lightning_cli import LNNCLI, TRAINER_DEFAULTS

    args = ["-c", str(config)]
    importer = ROOT / "configs" / "import" / config.name
    if importer.exists():  # a config of measured data: its scene comes from the imported file
        data = tmp_path / "d.h5"
        recordings = sorted((ROOT / "lnn_torch" / "datasets" / config.stem / "recordings").glob("*.csv.gz"))
        out = _cli("import", *map(str, recordings), "--config", str(importer), "-o", str(data), cwd=tmp_path)
        assert out.returncode == 0, out.stderr[-3000:]
        args.append(f"--data.path={data}")
    cli = LNNCLI(LNNModule, DM, args=args, run=False, trainer_defaults=TRAINER_DEFAULTS)
    assert isinstance(cli.model, LNNModule) and isinstance(cli.datamodule, DM)
    assert cli.trainer.validate_loop.inference_mode is False and cli.trainer.predict_loop.inference_mode is False


@pytest.mark.parametrize("config", CONFIGS, ids=[c.name for c in CONFIGS])
def test_every_shipped_config_fits_with_the_cli(config, tmp_path):
    """fast_dev_run of each config on a tiny dataset of its own scene (generated on the fly; the
    shipped recordings imported with their import config for a config of measured data)."""
    data = tmp_path / "d.h5"
    importer = ROOT / "configs" / "import" / config.name
    if importer.exists():
        recordings = sorted((ROOT / "lnn_torch" / "datasets" / config.stem / "recordings").glob("*.csv.gz"))
        out = _cli("import", *map(str, recordings), "--config", str(importer), "-o", str(data), cwd=tmp_path)
        assert out.returncode == 0, out.stderr[-3000:]
    out = _cli("fit", "-c", str(config), f"--data.path={data}", "--data.spec.num_trajectories=10",
               "--data.spec.duration=0.5", "--model.hidden_dims=[8,8]", "--model.val_rollout_seconds=0.1",
               "--trainer.fast_dev_run=true", "--trainer.enable_progress_bar=false", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "lnn_torch.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


def test_cli_fit_test_predict(dataset, tmp_path):
    common = ["-c", str(ROOT / "configs" / "quickstart.yaml"), f"--data.path={dataset}",
              "--data.spec.num_trajectories=20", "--data.spec.duration=2.0", "--data.spec.seed=5",
              "--model.hidden_dims=[16,16]", "--model.val_rollout_seconds=0.5", "--trainer.enable_progress_bar=false"]
    out = _cli("fit", *common, "--trainer.fast_dev_run=true", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    out = _cli("fit", *common, "--trainer.max_epochs=1", "--data.steps_per_epoch=3",
               "--trainer.check_val_every_n_epoch=1", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    ckpts = sorted(glob.glob(str(tmp_path / "lightning_logs" / "version_0" / "checkpoints" / "*.ckpt")))
    assert ckpts
    # last.ckpt holds the final weights (Lightning's save_last would follow only improvements)
    last = torch.load(tmp_path / "lightning_logs" / "version_0" / "checkpoints" / "last.ckpt", weights_only=False)
    assert last["global_step"] == 3
    # the end-of-fit summary: where the run and the checkpoint are, and the validation error
    assert "TensorBoard run: lightning_logs/version_0" in out.stdout and "last.ckpt" in out.stdout
    assert re.search(r"validation: acc\. rel\. L2 error [0-9.]+ % pooled, [0-9.]+ % per-trajectory median", out.stdout)
    out = _cli("test", *common, f"--ckpt_path={ckpts[0]}", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "test/acc_rel_err" in out.stdout
    written = glob.glob(str(tmp_path / "lightning_logs" / "*" / "test_metrics.json"))
    assert written and "test/acc_rel_err" in json.loads(Path(written[0]).read_text())
    out = _cli("predict", *common, f"--ckpt_path={ckpts[0]}", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    files = glob.glob(str(tmp_path / "lightning_logs" / "*" / "predictions.npz"))
    assert files
    pred = np.load(files[0])
    assert pred["qdd_pred"].shape == pred["qdd_true"].shape and pred["qdd_pred"].shape[-1] == 2


def test_default_root_dir_holds_logs_and_checkpoints(dataset, tmp_path):
    """--trainer.default_root_dir DIR moves the default TensorBoard run and the checkpoints to DIR
    (the logger's save_dir is no longer fixed to the working directory)."""
    common = ["-c", str(ROOT / "configs" / "quickstart.yaml"), f"--data.path={dataset}",
              "--data.spec.num_trajectories=20", "--data.spec.duration=2.0", "--data.spec.seed=5",
              "--model.hidden_dims=[8,8]", "--model.val_rollout_seconds=0.2", "--trainer.enable_progress_bar=false",
              "--trainer.max_epochs=1", "--data.steps_per_epoch=2", f"--trainer.default_root_dir={tmp_path / 'runs'}"]
    out = _cli("fit", *common, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert glob.glob(str(tmp_path / "runs" / "lightning_logs" / "version_0" / "events.*"))
    assert glob.glob(str(tmp_path / "runs" / "lightning_logs" / "version_0" / "checkpoints" / "last.ckpt"))
    assert not (tmp_path / "lightning_logs").exists()
    # an explicit save_dir still wins
    out = _cli("fit", *common, f"--trainer.logger.init_args.save_dir={tmp_path / 'mine'}", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert glob.glob(str(tmp_path / "mine" / "lightning_logs" / "version_0" / "events.*"))


def test_ddp_two_cpu_processes(dataset, tmp_path):
    """Lightning's own DDP strategy: two CPU processes, one writer of logs and checkpoints."""
    common = ["-c", str(ROOT / "configs" / "quickstart.yaml"), f"--data.path={dataset}",
              "--data.spec.num_trajectories=20", "--data.spec.duration=2.0", "--data.spec.seed=5",
              "--model.hidden_dims=[16,16]", "--model.val_rollout_seconds=0.5", "--trainer.enable_progress_bar=false",
              "--trainer.max_epochs=1", "--data.steps_per_epoch=4", "--trainer.strategy=ddp", "--trainer.devices=2",
              "--trainer.accelerator=cpu"]
    out = _cli("fit", *common, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    versions = glob.glob(str(tmp_path / "lightning_logs" / "version_*"))
    assert len(versions) == 1
    assert len(glob.glob(versions[0] + "/events.*")) == 1
    assert glob.glob(versions[0] + "/checkpoints/last.ckpt")


def test_distributed_chunk_sampling_is_rank_aware(dataset):
    """Under DDP, Lightning's DistributedSampler splits the epoch's batches between ranks (each
    item of the training set is a whole batch of chunks)."""
    from torch.utils.data.distributed import DistributedSampler

    dm = make_dm(dataset, steps_per_epoch=6)
    dm.setup("fit")
    ranks = [list(DistributedSampler(dm.train_set, num_replicas=2, rank=r, shuffle=False)) for r in (0, 1)]
    assert set(ranks[0]).isdisjoint(ranks[1]) and len(ranks[0]) + len(ranks[1]) == len(dm.train_set)
    batches = [[dm.train_set[i]["q"] for i in r] for r in ranks]
    for b0 in batches[0]:
        assert all(not torch.equal(b0, b1) for b1 in batches[1])


def test_learning_rate_ten_times_too_high_stays_finite(dataset, tmp_path):
    """lr = 3e-2 (10x the default): gradient clipping and the non-finite skip keep the weights finite."""
    model = LNNModule(lr=3e-2, lr_min=3e-4, val_rollouts=0, hidden_dims=[32, 32], energy_weight=0.1)
    trainer = quiet_trainer(tmp_path, max_epochs=4, limit_val_batches=0, gradient_clip_val=1.0)
    trainer.fit(model, make_dm(dataset, steps_per_epoch=25))
    assert trainer.global_step == 100
    assert all(torch.isfinite(p).all() for p in model.parameters())
    q = torch.tensor([[0.3, -0.2]])
    assert torch.isfinite(model.acceleration(q, q, torch.tensor([[1.0, 0.5, 1.2, 1.3]]))).all()


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
        return model._training_pass(*args)

    loss_shared, _ = model._training_loss(batch, spy)
    mixed = dict(batch, params=batch["params"].clone())
    mixed["params"][0, 1:] *= 1.1
    model._training_loss(mixed, spy)
    C = batch["q"].shape[0]
    assert seen == [C, None]
    loss_rows, _ = model._training_loss(batch, lambda *a: model._training_pass(*a[:-1], None))
    torch.testing.assert_close(loss_shared, loss_rows, rtol=1e-5, atol=0)


def test_compiled_training_matches_eager(dataset, tmp_path):
    """compile=True: on one training batch (the supported size: chunks_per_batch x chunk_len, 4 x 16
    here; evaluation stays eager) the compiled pass gives the eager loss and gradients; and a short
    fit runs compiled without falling back."""
    dm = make_dm(dataset)
    dm.setup("fit")
    batch = {k: v.double() for k, v in dm.train_set[0].items()}  # float64: an equality, not a float32 race
    model = LNNModule(val_rollouts=0, hidden_dims=[16, 16], energy_weight=0.1)
    model.model.fit_normalizer(dm.normalization_data())
    model = model.double()
    results = []
    for pass_fn in (model._training_pass, torch.compile(model._training_pass, dynamic=False)):
        model.zero_grad()
        loss, _ = model._training_loss(batch, pass_fn)
        loss.backward()
        results.append((loss.detach(), [p.grad.clone() for p in model.parameters()]))
    (l0, g0), (l1, g1) = results
    torch.testing.assert_close(l1, l0, rtol=1e-12, atol=0)
    for a, b in zip(g0, g1):
        # only the summation order differs between the two graphs (in float32 that alone reached
        # 1e-6 of the largest entry, and 5x relative on near-zero entries)
        torch.testing.assert_close(b, a, rtol=1e-9, atol=1e-12 * max(float(a.abs().max()), 1e-3))
    model = LNNModule(compile=True, val_rollouts=0, hidden_dims=[16, 16])
    trainer = quiet_trainer(tmp_path, max_epochs=1, limit_val_batches=0, logger=False, enable_checkpointing=False)
    trainer.fit(model, make_dm(dataset, steps_per_epoch=3))
    assert model._compiled not in (None, False) and trainer.global_step == 3


def test_training_compiles_by_default_only_runs_long_enough_to_repay_it(dataset, tmp_path, monkeypatch):
    """compile="auto" (the default): a run planned for fewer than AUTO_COMPILE_TRAIN_STEPS steps
    trains eagerly; one planned for at least that many compiles its pass; LNN_TORCH_COMPILE=0 and
    compile=False never compile."""
    from lnn_torch import perf

    built = []

    def recording_compile(fn, **kw):
        built.append(fn)
        return fn  # the eager pass under a recorded "compilation": the decision is what is tested

    monkeypatch.setattr(torch, "compile", recording_compile)
    monkeypatch.setattr(perf, "AUTO_COMPILE_TRAIN_STEPS", 4)

    def fit(steps, **kw):
        model = LNNModule(val_rollouts=0, hidden_dims=[8], **kw)
        trainer = quiet_trainer(tmp_path, max_steps=steps, limit_val_batches=0, logger=False,
                                enable_checkpointing=False)
        trainer.fit(model, make_dm(dataset, steps_per_epoch=steps))
        return model

    assert LNNModule(hidden_dims=[8]).hparams.compile == "auto"
    assert fit(3)._compiled is None and not built  # 3 < 4 planned steps: eager
    assert fit(4)._compiled is not None and len(built) == 1  # 4 planned steps: compiled
    assert fit(6, compile=False)._compiled is None and len(built) == 1
    monkeypatch.setenv("LNN_TORCH_COMPILE", "0")
    assert fit(6)._compiled is None and len(built) == 1
    with pytest.raises(ValueError, match="compile must be true, false or 'auto'"):
        LNNModule(compile="sometimes")


@pytest.mark.parametrize("where", ["forward", "backward"])
def test_compile_failure_falls_back_to_eager(where, dataset, tmp_path, monkeypatch):
    class Boom(torch.autograd.Function):
        @staticmethod
        def forward(ctx, x):
            return x.clone()

        @staticmethod
        def backward(ctx, g):
            raise RuntimeError("compiled backward failed")

    def fake_compile(fn, **kw):
        def compiled(*args):
            if where == "forward":
                raise RuntimeError("compilation failed")
            out = fn(*args)
            return {**out, "pred": Boom.apply(out["pred"])}

        return compiled

    monkeypatch.setattr(torch, "compile", fake_compile)
    model = LNNModule(compile=True, val_rollouts=0, hidden_dims=[8])
    trainer = quiet_trainer(tmp_path, max_epochs=1, limit_val_batches=0, logger=False)
    with pytest.warns(RuntimeWarning, match="continuing training eagerly"):
        trainer.fit(model, make_dm(dataset, steps_per_epoch=3))
    assert model._compiled is False and trainer.global_step == 3
    assert all(torch.isfinite(p).all() for p in model.parameters())


def test_lnn_learns_the_relativistic_particle_where_an_hnn_on_q_qd_fails(tmp_path):
    """The LNN paper's point: with (q, qd) inputs an HNN cannot represent the relativistic particle
    (qdd depends on qd, but a Hamiltonian flow in (q, qd) with qdot = qd cannot), while the LNN
    and an HNN given canonical momenta learn it. Judged on rollouts of 8 held-out trajectories:
    the median over trajectories of the max position error over 5 s (c = 1 units)."""
    from lnn_torch.evaluation import counting_failures

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

    from lnn_torch.callbacks import LastCheckpoint

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


def test_a_measured_config_without_its_imported_file_says_to_import_it(tmp_path):
    """Fitting the real-pendulum config before importing its recordings names the missing file and the
    import command (it used to fall back to generating a simulated double pendulum and then refuse the
    torque loss with an unrelated message); a spec'd dataset still generates."""
    out = _cli("fit", "-c", str(ROOT / "configs" / "real_double_pendulum.yaml"),
               f"--data.path={tmp_path / 'absent.h5'}", "--trainer.fast_dev_run=true", cwd=tmp_path)
    assert out.returncode != 0
    assert "absent.h5 not found" in out.stderr and "lnn-torch import" in out.stderr, out.stderr[-2000:]
    assert not (tmp_path / "absent.h5").exists()
    with pytest.raises(FileNotFoundError, match="import them first"):
        TrajectoryDataModule(path=str(tmp_path / "absent.h5"), targets="savgol")
    assert TrajectoryDataModule(path=str(tmp_path / "sim.h5"), spec=dict(num_trajectories=4, duration=0.2),
                                targets="savgol").model_scene()[0] == "double_pendulum"
