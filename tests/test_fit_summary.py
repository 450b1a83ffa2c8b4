"""The end-of-fit summary (``lnn_torch.training.callbacks.FitSummary``): on a system of three coordinates or more it
names each coordinate's validation acceleration error, so that a pooled figure one wrist joint dominates
is read as what it is."""

from types import SimpleNamespace

import torch

from lnn_torch.training.callbacks import FitSummary, per_coordinate


def metrics(names, values, pooled=19.47):
    return {"val/acc_rel_err": pooled, "val/acc_rel_err_traj_median": pooled,
            **{f"val/acc_rel_err_{n}": v for n, v in zip(names, values, strict=True)}}


def stand_in_trainer(metrics: dict, step: int = 5, checkpoints=()) -> SimpleNamespace:
    """What ``FitSummary`` reads of a trainer: its run folder, step, checkpoint callbacks and last metrics."""
    return SimpleNamespace(log_dir="runs/x", is_global_zero=True, global_step=step, callbacks=[],
                           checkpoint_callbacks=list(checkpoints), limit_val_batches=1.0,
                           callback_metrics={k: torch.tensor(v) for k, v in metrics.items()})


def test_per_coordinate_names_each_coordinate_of_an_arm_and_nothing_for_fewer_than_three():
    names = [f"joint{j}" for j in range(1, 8)]
    line = per_coordinate(metrics(names, [0.02, 0.01, 0.03, 0.02, 0.05, 30.1, 0.04]), names)
    assert line == ("per coordinate joint1 2 %, joint2 1 %, joint3 3 %, joint4 2 %, joint5 5 %, joint6 3.01e+03 %, "
                    "joint7 4 %")
    assert per_coordinate(metrics(["q1", "q2"], [0.01, 0.02]), ["q1", "q2"]) is None
    assert per_coordinate(metrics(names[:6], [0.1] * 6), names) is None  # one missing: nothing half-said
    assert per_coordinate({}, None) is None


def test_the_fit_summary_prints_the_per_coordinate_line(capsys):
    names = ["joint1", "joint2", "joint3"]
    trainer = stand_in_trainer(metrics(names, [0.02, 0.5, 12.0]))
    module = SimpleNamespace(system=SimpleNamespace(coord_names=names), hparams={})
    FitSummary().on_fit_end(trainer, module)
    out = capsys.readouterr().out
    assert "validation: acc. rel. L2 error 1947.00 % pooled" in out
    assert "validation: acc. rel. L2 error per coordinate joint1 2 %, joint2 50 %, joint3 1.2e+03 %" in out


def test_a_model_fitted_to_torques_alone_leads_with_its_torque_error(capsys):
    """An arm identified on torques (acceleration_weight 0): the torque error comes first and the accelerations
    (forward dynamics under the measured torques, never fitted) are named as such; a model fitted to
    accelerations keeps its acceleration line first."""
    names = ["joint1", "joint2", "joint3"]
    values = {**metrics(names, [0.02, 0.5, 12.0]), "val/torque_rms": 0.25, "val/torque_nrmse": 0.15}
    trainer = stand_in_trainer(values)
    out = {}
    for weight in (0.0, 1.0):
        module = SimpleNamespace(system=SimpleNamespace(coord_names=names), hparams={"acceleration_weight": weight})
        FitSummary().on_fit_end(trainer, module)
        out[weight] = [line.strip() for line in capsys.readouterr().out.splitlines() if "validation:" in line]
    assert out[0.0][0] == ("validation: inverse-dynamics torque error 0.25 N m RMS (mean over the inputs), "
                           "15.00 % normalised")
    assert out[0.0][1].startswith("validation: acc. rel. L2 error (forward dynamics under the measured torques; not "
                                  "fitted: light links turn small torque errors into large accelerations) 1947.00 % "
                                  "pooled")
    assert out[1.0][0].startswith("validation: acc. rel. L2 error 1947.00 % pooled")
    assert out[1.0][-1].startswith("validation: inverse-dynamics torque error")
    # with a last checkpoint and the dataset, the torque-fitted model's summary says how to put least squares beside it
    from lnn_torch.training.callbacks import LastCheckpoint

    last = LastCheckpoint()
    last.path = "runs/x/checkpoints/last.ckpt"
    trainer.callbacks, trainer.datamodule = [last], SimpleNamespace(path="data/arm.h5")
    for weight, hinted in ((0.0, True), (1.0, False)):
        module = SimpleNamespace(system=SimpleNamespace(coord_names=names), hparams={"acceleration_weight": weight})
        FitSummary().on_fit_end(trainer, module)
        hint = "beside classical least squares: lnn-torch identify runs/x/checkpoints/last.ckpt data/arm.h5"
        assert (hint in capsys.readouterr().out) == hinted


def test_a_run_that_chose_its_state_by_another_scalar_does_not_offer_the_best_checkpoint(capsys):
    """A grey box whose state validation chose by its torque error (``SelectOnValidation``) while the best
    checkpoint is kept by the acceleration error: the summary offers the last checkpoint (the run's choice) only."""
    checkpoint = SimpleNamespace(best_model_path="runs/x/checkpoints/epoch1-err6.2.ckpt", monitor="val/acc_rel_err")
    trainer = stand_in_trainer({"val/torque_rms": 0.25, "val/torque_nrmse": 0.15}, 500, [checkpoint])
    selection = {"step": 0, "monitor": "val/torque_rms", "value": 0.2469, "history": [[0, 0.2469], [500, 0.25]]}
    module = SimpleNamespace(system=SimpleNamespace(coord_names=None), hparams={}, selection=selection)
    FitSummary().on_fit_end(trainer, module)
    out = capsys.readouterr().out
    assert "best validation checkpoint" not in out  # kept by another scalar: easy to take for the run's choice
    assert "the run ends with the state at step 0 (val/torque_rms 0.2469): validation preferred it" in out
    # a run too short for a validation after the start: the start is kept, and the summary does not call it a choice
    trainer.callback_metrics, trainer.num_training_batches, trainer.check_val_every_n_epoch = {}, 100, 5
    module.selection = {**selection, "history": [[0, 0.2469]]}
    FitSummary().on_fit_end(trainer, module)
    out = capsys.readouterr().out
    assert "the run ends with the state at step 0 (val/torque_rms 0.2469): the only state validation judged" in out
    assert "validation preferred" not in out and "validation: none ran in training (every 5 epochs, 500 steps" in out
    assert "set --trainer.check_val_every_n_epoch lower" in out
    trainer.check_val_every_n_epoch = 1  # every epoch already: the epoch's length is what to shorten
    FitSummary().on_fit_end(trainer, module)
    assert ("validation: none ran in training (every 1 epoch, 100 steps; set --data.steps_per_epoch lower (an "
            "epoch's steps) for a shorter run)") in capsys.readouterr().out
    trainer.callback_metrics = {"val/torque_rms": torch.tensor(0.25), "val/torque_nrmse": torch.tensor(0.15)}
    module.selection = None
    FitSummary().on_fit_end(trainer, module)
    assert "best validation checkpoint: runs/x/checkpoints/epoch1-err6.2.ckpt" in capsys.readouterr().out


def summary_of(trainer, module, capsys) -> str:
    """What ``FitSummary`` prints at the end of a fit of ``trainer`` and ``module``."""
    FitSummary().on_fit_end(trainer, module)
    return capsys.readouterr().out


def test_a_best_checkpoint_worse_than_the_kept_state_is_not_called_the_best(capsys):
    """Validation kept the start (step 0, 0.1333), which no checkpoint of its own holds, while the best checkpoint
    saved by the same scalar after it is worse (0.1334): the summary says the kept state, in the last checkpoint, is
    better, and that the figures it prints are the last validation's, not the kept state's."""
    checkpoint = SimpleNamespace(best_model_path="runs/x/checkpoints/epoch3-torque_rms0.1334.ckpt",
                                 monitor="val/torque_rms", best_model_score=torch.tensor(0.1334))
    trainer = stand_in_trainer({"val/torque_rms": 0.1336, "val/torque_nrmse": 0.15}, 1500, [checkpoint])
    selection = {"step": 0, "monitor": "val/torque_rms", "value": 0.1333, "history": [[0, 0.1333], [1500, 0.1336]]}
    module = SimpleNamespace(system=SimpleNamespace(coord_names=None), hparams={}, selection=selection)
    FitSummary().on_fit_end(trainer, module)
    out = capsys.readouterr().out
    assert "best validation checkpoint" not in out
    assert ("best checkpoint of the steps trained: runs/x/checkpoints/epoch3-torque_rms0.1334.ckpt (val/torque_rms "
            "0.1334; the state the run keeps, in the last checkpoint, is better)") in out
    assert "the figures below are the last validation's (step 1500), not the kept state's" in out
    assert "15.00 % normalised\n" in out
    trainer.callback_metrics["val/torque_nrmse"] = torch.tensor(7.9)  # a free swing's noise as the scale
    FitSummary().on_fit_end(trainer, module)
    assert ("790.00 % normalised (by the validation recordings' own torques, smaller than the error: they carry "
            "little input, e.g. free swings)") in capsys.readouterr().out
    selection.update(step=1000, value=0.1334)  # the best checkpoint is the kept state: called so
    FitSummary().on_fit_end(trainer, module)
    assert "best validation checkpoint: runs/x/checkpoints/epoch3-torque_rms0.1334.ckpt" in capsys.readouterr().out
    # the start kept though worse pooled (a later state was worse on one validation recording): the best checkpoint
    # is not called the best, nor the state kept
    selection.update(step=0, value=0.1391)
    out = summary_of(trainer, module, capsys)
    assert "best validation checkpoint" not in out
    assert ("lowest validation error of the steps trained: runs/x/checkpoints/epoch3-torque_rms0.1334.ckpt "
            "(val/torque_rms 0.1334; not the state the run keeps, in the last checkpoint: below)") in out
    assert "the run ends with the state at step 0 (val/torque_rms 0.1391)" in out


def test_the_printed_test_command_keeps_the_fits_data_and_run_folder():
    from lnn_torch.training.lightning_cli import data_options

    argv = ["-c", "configs/real_panda.yaml", "--data.path", "data/my arm.h5", "--trainer.default_root_dir=runs/fit",
            "--trainer.max_steps", "10"]
    assert data_options(argv) == ["--data.path='data/my arm.h5'", "--trainer.default_root_dir=runs/fit"]


def test_skipped_steps_are_said_and_a_run_that_never_trained_too(capsys):
    """Steps skipped for a non-finite loss or gradient (``callbacks.SkipNonFiniteSteps``) are counted in the summary;
    all of them: the model never trained (NaN in the data made every step so, and validation scored it 0 %)."""
    trainer = stand_in_trainer({"val/acc_rel_err": 0.1}, 150)
    module = SimpleNamespace(system=SimpleNamespace(coord_names=None), hparams={}, skipped_steps=torch.tensor(150))
    FitSummary().on_fit_end(trainer, module)
    assert ("warning: 150 of 150 steps skipped (a non-finite loss or gradient: the weights left as they were); the "
            "model never trained") in capsys.readouterr().out
    module.skipped_steps = torch.tensor(3)
    FitSummary().on_fit_end(trainer, module)
    out = capsys.readouterr().out
    assert "warning: 3 of 150 steps skipped" in out and "never trained" not in out
    module.skipped_steps = torch.tensor(0)
    FitSummary().on_fit_end(trainer, module)
    assert "skipped" not in capsys.readouterr().out


def test_an_interrupted_fit_saves_the_step_reached_and_says_how_to_resume(tmp_path, capsys):
    """Ctrl-C while training: last.ckpt holds the step reached (an epoch's steps since the last save were lost) and
    the line says where it is; not during the sanity check, nor for another exception, nor before any step."""
    from lnn_torch.training.callbacks import LastCheckpoint

    saved = []
    trainer = SimpleNamespace(sanity_checking=False, fast_dev_run=False, state=SimpleNamespace(fn="fit"),
                              global_step=37, is_global_zero=True, save_checkpoint=saved.append,
                              checkpoint_callback=SimpleNamespace(dirpath=str(tmp_path / "ck")))
    callback = LastCheckpoint()
    callback.on_exception(trainer, None, KeyboardInterrupt())
    assert saved == [str(tmp_path / "ck" / "last.ckpt")]
    assert (f"lnn-torch fit: interrupted at step 37; saved {tmp_path / 'ck' / 'last.ckpt'} (resume: the same command "
            "with --ckpt_path that file)") in capsys.readouterr().out
    for exception, changes in ((ValueError("x"), {}), (KeyboardInterrupt(), {"sanity_checking": True}),
                               (KeyboardInterrupt(), {"global_step": 0})):
        callback.on_exception(SimpleNamespace(**{**vars(trainer), **changes}), None, exception)
    assert len(saved) == 1


def test_the_clis_best_checkpoint_follows_the_monitor_a_run_selects_by():
    """The CLI's best-checkpoint callback (``BestCheckpoint``, a ModelCheckpoint) switches to the scalar a run selects
    its state by (an arm's torques): a test of the exact class missed the subclass, and the files kept the
    acceleration error's name."""
    from lnn_torch.training.callbacks import BestCheckpoint, best_checkpoint_on
    from lnn_torch.training.lightning_cli import CALLBACKS

    callback = BestCheckpoint(**CALLBACKS[0]["init_args"])
    assert CALLBACKS[0]["class_path"].endswith("BestCheckpoint") and callback.monitor == "val/acc_rel_err"
    best_checkpoint_on(SimpleNamespace(checkpoint_callbacks=[callback]), "val/torque_rms")
    assert callback.monitor == "val/torque_rms" and "torque_rms" in callback.filename
    assert callback.state_key.startswith("ModelCheckpoint{'monitor': 'val/torque_rms'")  # (Lightning's own key)
