"""Lightning callbacks: what training does beside its steps.

``LNNModule.configure_callbacks`` adds the first five to every trainer that fits it (the module's
behaviour, whatever trainer a user builds); the CLI's trainer defaults add the others:

* ``SkipNonFiniteSteps``: a non-finite loss or gradient skips the optimiser step (counted in the
  module's ``skipped_steps`` and ``train/skipped_steps``); logs ``train/grad_norm`` and ``train/lr``;
* ``DivergenceWatch``: warns once when the training loss's running mean rises far above its lowest
  (a learning rate past the edge diverges to finite nonsense, which no skipped step shows);
* ``HParamsSummary``: the hyper-parameters in TensorBoard's HParams tab, with the metric keys;
* ``EvaluationFigures``: the figures of the validation's evaluation (``LNNModule.evaluation``) in
  TensorBoard, every ``figure_every_n_epochs`` validations and at the last;
* ``SelectOnValidation``: where the module names a ``selection_monitor`` (an arm grey box started from
  classical identification), the state the validation prefers, the start included, is the one the
  training ends with;
* ``LastCheckpoint``, ``PredictionWriter``, ``TestMetricsWriter``, ``FitSummary``: files and the
  closing summary of ``lnn-torch fit``/``test``/``predict``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import BasePredictionWriter, ModelCheckpoint
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_warn


class PredictionWriter(BasePredictionWriter):
    """Writes ``predict`` outputs (per test trajectory: q, qd, params, true and predicted qdd, the inputs tau of an
    actuated scene, ``valid``: the points of each recording, the rest padding) to an
    ``.npz`` file: ``output`` if given, else ``<log_dir>/predictions.npz``. Refuses to replace an
    existing file unless ``overwrite``."""

    def __init__(self, output: str | None = None, overwrite: bool = False) -> None:
        super().__init__(write_interval="epoch")
        self.output, self.overwrite = output, overwrite
        self.path: Path | None = None

    def write_on_epoch_end(self, trainer: L.Trainer, pl_module, predictions, batch_indices) -> None:
        if not predictions:
            return
        if isinstance(predictions[0], list):  # several dataloaders
            predictions = [p for group in predictions for p in group]
        arrays = {k: torch.cat([p[k] for p in predictions]).cpu().numpy() for k in predictions[0]}
        if trainer.world_size > 1:
            path = self._path(trainer).with_suffix(f".rank{trainer.global_rank}.npz")
        else:
            path = self._path(trainer)
        if path.exists() and not self.overwrite:
            raise FileExistsError(f"{path} exists; refusing to overwrite it (set overwrite: true on the "
                                  "PredictionWriter)")
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **arrays)
        self.path = path
        print(f"wrote {path} (predictions)")

    def _path(self, trainer) -> Path:
        if self.output:
            return Path(self.output)
        return Path(trainer.log_dir or ".") / "predictions.npz"


class TestMetricsWriter(L.Callback):
    """Writes the metrics of ``test`` to ``<log_dir>/test_metrics.json`` (as ``lnn-torch test`` prints them)."""

    def on_test_end(self, trainer: L.Trainer, pl_module) -> None:
        if not trainer.is_global_zero:
            return
        metrics = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("test/")}
        path = Path(trainer.log_dir or ".") / "test_metrics.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(metrics, indent=2) + "\n")
        print(f"wrote {path} (test metrics)")


class BestCheckpoint(ModelCheckpoint):
    """Lightning's ``ModelCheckpoint`` (the same state key: checkpoints of either resume with either) that keeps the
    best score of a resumed run: a resumed fit writes into a new run folder, where Lightning tracks the best afresh
    (its first checkpoint there became "the best" however much worse than the run's). Here the resumed run's best
    stays the best, its file where it is (never deleted from the other folder), until one saved here beats it."""

    @property
    def state_key(self) -> str:
        return f"ModelCheckpoint{self.state_key_args()!r}"

    def state_key_args(self) -> dict:
        return {"monitor": self.monitor, "mode": self.mode, "every_n_train_steps": self._every_n_train_steps,
                "every_n_epochs": self._every_n_epochs, "train_time_interval": self._train_time_interval}

    def load_state_dict(self, state_dict: dict) -> None:
        earlier = state_dict.get("dirpath", self.dirpath)
        path, score = state_dict.get("best_model_path"), state_dict.get("best_model_score")
        if earlier == self.dirpath or not path or score is None or not os.path.exists(path):
            super().load_state_dict(state_dict)
            return
        self.best_model_path, self.best_model_score = path, score
        self.best_k_models = {path: score}
        self.kth_best_model_path, self.kth_value = path, score
        self._carried = path

    def _remove_checkpoint(self, trainer: L.Trainer, filepath: str) -> None:
        if filepath == getattr(self, "_carried", None):  # (the resumed run's file, in its own folder: kept)
            return
        super()._remove_checkpoint(trainer, filepath)


class LastCheckpoint(L.Callback):
    """Writes ``last.ckpt`` beside the monitored checkpoints at the end of every training epoch: the
    final weights. (Lightning's ``save_last`` writes it only when the monitored metric improves, so
    there it would be the best, not the last, checkpoint.)"""

    def __init__(self, filename: str = "last.ckpt") -> None:
        self.filename = filename
        self.path: str | None = None

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module) -> None:
        if trainer.sanity_checking or trainer.fast_dev_run:
            return
        self._save(trainer)

    def on_exception(self, trainer: L.Trainer, pl_module, exception: BaseException) -> None:
        """Interrupted (Ctrl-C) while training: the state at the step reached is saved as ``last.ckpt`` (an epoch's
        steps since its last save were lost) and the line to resume it printed."""
        fitting = getattr(getattr(trainer, "state", None), "fn", None) == "fit"  # (in training or its validation)
        if not isinstance(exception, KeyboardInterrupt) or trainer.sanity_checking or trainer.fast_dev_run \
                or not fitting or not trainer.global_step:
            return
        self._save(trainer)
        if trainer.is_global_zero:
            print(f"\nlnn-torch fit: interrupted at step {trainer.global_step}; saved {os.path.normpath(self.path)} "
                  "(resume: the same command with --ckpt_path that file)", flush=True)

    def _save(self, trainer: L.Trainer) -> None:
        directory = getattr(trainer.checkpoint_callback, "dirpath", None) or os.path.join(
            trainer.log_dir or trainer.default_root_dir, "checkpoints")
        self.path = os.path.join(directory, self.filename)
        trainer.save_checkpoint(self.path)


def _divergence(module, seconds: float) -> str:
    """The validation rollouts' median time within the threshold, in words, ``≥ horizon`` when capped."""
    hp = getattr(module, "hparams", {})
    thr, horizon = hp.get("val_threshold", 0.1), hp.get("val_rollout_seconds", float("inf"))
    held = f"≥ {horizon:g} s (never exceeded)" if seconds >= horizon - 1e-9 else f"{seconds:.2f} s"
    return f"validation rollouts within {thr:g} rad (or m) of the data: median {held}"


def per_coordinate(metrics: dict, names) -> str | None:
    """The validation acceleration error of each coordinate, in words, for a system of three coordinates or
    more (an arm: the pooled figure can be one wrist joint of tiny inertia); None where the metrics lack one
    or the system has fewer."""
    keys = [f"val/acc_rel_err_{n}" for n in names or ()]
    if len(keys) < 3 or not all(k in metrics for k in keys):
        return None
    return "per coordinate " + ", ".join(f"{n} {100 * metrics[k]:.3g} %" for n, k in zip(names, keys, strict=True))


class FitSummary(L.Callback):
    """Prints, at the end of ``fit``, where the TensorBoard run and the checkpoints are and the last
    validation metrics, with the command that tests the last checkpoint."""

    def on_fit_end(self, trainer: L.Trainer, pl_module) -> None:
        log_dir = trainer.log_dir  # every rank: under DDP this is a collective (a broadcast)
        if not trainer.is_global_zero:
            return
        m = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("val/")}
        last = next((cb.path for cb in trainer.callbacks if isinstance(cb, LastCheckpoint) and cb.path), None)
        keeper = next((cb for cb in trainer.checkpoint_callbacks if getattr(cb, "best_model_path", "")), None)
        path = lambda p: os.path.normpath(p) if p else p  # noqa: E731
        lines = [f"lnn-torch fit: {trainer.global_step} steps; TensorBoard run: {path(log_dir)}"]
        if last is not None:
            lines.append(f"  last checkpoint: {path(last)}")
        selection = getattr(pl_module, "selection", None)
        # a best checkpoint kept by another scalar than the run's own choice (which the last one holds): not offered
        if keeper is not None and (selection is None or keeper.monitor == selection["monitor"]):
            best = getattr(keeper, "best_model_score", None)
            if selection is not None and best is not None and selection["value"] < float(best):
                # the kept state (e.g. the start) is no saved checkpoint of its own: the last one holds it
                lines.append(f"  best checkpoint of the steps trained: {path(keeper.best_model_path)} "
                             f"({keeper.monitor} {float(best):.4g}; the state the run keeps, in the last checkpoint, "
                             "is better)")
            elif selection is not None and best is not None and selection["value"] > float(best) * (1 + 1e-6):
                # the lowest pooled error is not the state kept (one worse on a validation recording of its own;
                # 1e-6: the float32 score of the same state)
                lines.append(f"  lowest validation error of the steps trained: {path(keeper.best_model_path)} "
                             f"({keeper.monitor} {float(best):.4g}; not the state the run keeps, in the last "
                             "checkpoint: below)")
            else:
                lines.append(f"  best validation checkpoint: {path(keeper.best_model_path)}")
        skipped = int(getattr(pl_module, "skipped_steps", 0) or 0)
        if skipped:
            never = "; the model never trained" if skipped >= trainer.global_step else ""
            lines.append(f"  warning: {skipped} of {trainer.global_step} steps skipped (a non-finite loss or gradient: "
                         f"the weights left as they were){never}")
        if selection is not None and selection["step"] != trainer.global_step:
            judged = len(selection.get("history", ())) > 1
            why = ("validation preferred it" if judged else "the only state validation judged (none ran after the "
                   "start: the steps since are not kept)")
            lines.append(f"  the run ends with the state at step {selection['step']} ({selection['monitor']} "
                         f"{selection['value']:.4g}): {why}" + (f"; the figures below are the last validation's (step "
                                                                f"{trainer.global_step}), not the kept state's"
                                                                if judged else ""))
        torque = None
        if "val/torque_rms" in m:
            units = set(getattr(getattr(pl_module, "system", None), "input_units", None) or ["N m"])
            unit = units.pop() if len(units) == 1 else "SI units"  # (a force on a length is in N)
            torque = (f"  validation: inverse-dynamics torque error {m['val/torque_rms']:.3g} {unit} RMS (mean over "
                      f"the inputs), {100 * m['val/torque_nrmse']:.2f} % normalised"
                      + (" (by the validation recordings' own torques, smaller than the error: they carry little "
                         "input, e.g. free swings)" if m["val/torque_nrmse"] > 1 else ""))
        # a model fitted to torques alone (an arm's identification): its torque error first, and its accelerations
        # (forward dynamics under the measured torques, which carry what no model of the state predicts) named so
        torques_only = torque is not None and getattr(pl_module, "hparams", {}).get("acceleration_weight", 1.0) == 0
        what = "acc. rel. L2 error" + (" (forward dynamics under the measured torques; not fitted: light links turn "
                                       "small torque errors into large accelerations)" if torques_only else "")
        if torques_only:
            lines.append(torque)
        if "val/acc_rel_err" in m:
            lines.append(f"  validation: {what} {100 * m['val/acc_rel_err']:.2f} % pooled, "
                         f"{100 * m.get('val/acc_rel_err_traj_median', float('nan')):.2f} % per-trajectory median"
                         + (f"; {_divergence(pl_module, m['val/divergence_time'])}" if "val/divergence_time" in m
                            else ""))
        coordinates = per_coordinate(m, getattr(getattr(pl_module, "system", None), "coord_names", None))
        if coordinates is not None:
            lines.append(f"  validation: {what} {coordinates}")
        if torque is not None and not torques_only:
            lines.append(torque)
        if not m and trainer.limit_val_batches != 0:
            epochs = trainer.check_val_every_n_epoch or 1
            every = epochs * max(trainer.num_training_batches, 1)
            advice = ("--trainer.check_val_every_n_epoch lower" if epochs > 1 else
                      "--data.steps_per_epoch lower (an epoch's steps)")
            lines.append(f"  validation: none ran in training (every {epochs} epoch{'s' if epochs != 1 else ''}, "
                         f"{every} steps; set {advice} for a shorter run)")
        if last is not None:
            dm = getattr(trainer, "datamodule", None)
            splits = getattr(getattr(dm, "file", None), "splits", None)
            # a command-line run (a Python one has no command to repeat) of data with a test split
            if hasattr(self, "config_paths") and (splits is None or len(splits.get("test", ())) > 0):
                configs = " ".join(f"-c {c}" for c in self.config_paths) or "-c <this config>"
                extra = "".join(f" {o}" for o in getattr(self, "data_options", []))
                lines.append(f"  test it: lnn-torch test {configs}{extra} --ckpt_path {path(last)}")
            data = getattr(getattr(trainer, "datamodule", None), "path", None)
            if torques_only and data is not None:  # an arm's identification: beside least squares, per joint
                lines.append(f"  beside classical least squares: lnn-torch identify {path(last)} {data}")
        print("\n".join(lines))


# ---------------------------------------------------------------------------- the module's own callbacks
def writes_logs(trainer) -> bool:
    """Whether the logger writes this training step's per-step values (every ``log_every_n_steps``
    optimiser steps, and at the last): a ``log`` call costs a fraction of a millisecond, several per
    step, so per-step values are logged only on the steps that are written. True outside a trainer."""
    if trainer is None:
        return True
    connector = getattr(trainer, "_logger_connector", None)  # Lightning's own decision (its step counter runs one
    if connector is not None and hasattr(connector, "should_update_logs"):  # ahead of global_step after a resume:
        return bool(connector.should_update_logs)  # keyed on global_step, every value was logged 10 steps late)
    return (trainer.global_step + 1) % max(trainer.log_every_n_steps, 1) == 0 or trainer.should_stop


class SkipNonFiniteSteps(L.Callback):
    """A non-finite loss or gradient skips the optimiser step: the gradients are dropped, so AdamW
    leaves the weights untouched, and the module's ``skipped_steps`` counts it; under DDP every rank
    skips together. Logs ``train/grad_norm`` (of the steps taken), ``train/skipped_steps`` and
    ``train/lr`` on the steps the logger writes."""

    def __init__(self) -> None:
        self.bad_loss = False

    def on_before_backward(self, trainer, pl_module, loss) -> None:
        self.bad_loss = not bool(torch.isfinite(loss))

    def on_before_optimizer_step(self, trainer, pl_module, optimizer) -> None:
        grads = [p.grad for p in pl_module.parameters() if p.grad is not None]
        # one norm over all gradients: non-finite if some entry is NaN or Inf (or it overflows)
        norm = torch.linalg.vector_norm(torch.stack(torch._foreach_norm(grads))) if grads else torch.zeros(())
        flag = torch.tensor(float(self.bad_loss or not bool(torch.isfinite(norm))), device=pl_module.device)
        if trainer.world_size > 1:
            flag = trainer.strategy.reduce(flag, reduce_op="max")
        skip = flag.item() > 0
        if skip:
            pl_module.skipped_steps += 1
            for p in pl_module.parameters():
                p.grad = None
        if not writes_logs(trainer):
            return
        if not skip:
            pl_module.log("train/grad_norm", norm, on_step=True, on_epoch=False)
        pl_module.log("train/skipped_steps", pl_module.skipped_steps.float(), on_step=True, on_epoch=False)
        pl_module.log("train/lr", optimizer.param_groups[0]["lr"], on_step=True, on_epoch=False)


class DivergenceWatch(L.Callback):
    """Warns once when training diverges without a non-finite value: a learning rate past the model's
    edge can carry the weights to a finite state of ~100 % error (``results/quickstart_ablation.md``:
    the quickstart at 2e-2), which no skipped step reveals. The training loss's running mean (over about
    ``window`` steps) is watched from step ``window`` on; when it rises ``factor`` times above the lowest
    it reached, the warning names the step, both values and what to do."""

    def __init__(self, factor: float = 100.0, window: int = 50) -> None:
        self.factor, self.window = float(factor), int(window)
        self.mean = self.best = None
        self.best_step, self.steps, self.warned = 0, 0, False

    def on_before_backward(self, trainer, pl_module, loss) -> None:
        value = float(loss.detach())
        if self.warned or not math.isfinite(value):
            return
        self.steps += 1
        rate = 1.0 / min(self.steps, self.window)
        self.mean = value if self.mean is None else self.mean + rate * (value - self.mean)
        if self.steps < self.window:
            return
        if self.best is None or self.mean < self.best:
            self.best, self.best_step = self.mean, self.steps
        elif self.mean > self.factor * self.best:
            self.warned = True
            step = getattr(trainer, "global_step", self.steps)
            lr = dict(getattr(pl_module, "hparams", {})).get("lr")
            since = self.steps - self.best_step
            rank_zero_warn(f"training diverged at step {step}: the training loss's running mean {self.mean:.3g} is "
                           f"{self.mean / self.best:.0f} times its lowest ({self.best:.3g}, {since} steps earlier); "
                           f"lower the learning rate (model.lr{f', now {lr:g}' if lr else ''})",
                           category=RuntimeWarning)


def _plain_hparams(hparams: dict, prefix: str = "") -> dict:
    """Hyper-parameters as TensorBoard's HParams plugin takes them: nested dicts flattened to ``a/b``,
    values other than numbers, strings and booleans as their text."""
    out = {}
    for key, value in hparams.items():
        if isinstance(value, dict):
            out.update(_plain_hparams(value, f"{prefix}{key}/"))
        else:
            out[prefix + key] = value if isinstance(value, (bool, int, float, str)) else str(value)
    return out


class HParamsSummary(L.Callback):
    """At the start of ``fit``, the module's hyper-parameters in every TensorBoard logger, with the keys
    of the validation metrics, so that the HParams tab shows the real metrics (declared in the HParams
    summary only: Lightning's ``log_hyperparams(params, metrics)`` would also write each key as a NaN
    scalar at step 0)."""

    def on_fit_start(self, trainer, pl_module) -> None:
        from torch.utils.tensorboard.summary import hparams as hparams_summary

        energy = "val/power_balance" if pl_module.system.has_forces else "val/energy_drift"
        metrics = {"val/acc_rel_err": math.nan, energy: math.nan, "val/divergence_time": math.nan}
        for logger in trainer.loggers:
            if not isinstance(logger, TensorBoardLogger):
                continue
            logger.log_hyperparams(dict(pl_module.hparams))
            writer = logger.experiment._get_file_writer()
            if writer is None:  # the logger's stand-in on ranks other than the first writes nothing
                continue
            for summary in hparams_summary(_plain_hparams(dict(pl_module.hparams)), metrics):
                writer.add_summary(summary)


class EvaluationFigures(L.Callback):
    """The figures of each validation's evaluation (``pl_module.evaluation``: an ``evaluate_model``
    result, or None where the validation has none to show) as ``val/<tag>`` in every TensorBoard
    logger, at the step of that validation's scalars: every ``figure_every_n_epochs``-th validation
    (the module's hyper-parameter; 0: never) and the run's last; never the sanity check, never on
    ranks other than the first."""

    def __init__(self) -> None:
        self.validations = 0

    def on_validation_epoch_end(self, trainer, pl_module) -> None:
        result, pl_module.evaluation = pl_module.evaluation, None
        every = pl_module.hparams.get("figure_every_n_epochs", 1)
        if result is None or not every or trainer.sanity_checking or not trainer.is_global_zero:
            return
        self.validations += 1
        last = ((trainer.max_epochs not in (None, -1) and trainer.current_epoch + 1 >= trainer.max_epochs)
                or (trainer.max_steps not in (None, -1) and trainer.global_step >= trainer.max_steps))
        loggers = [lg for lg in trainer.loggers if isinstance(lg, TensorBoardLogger)]
        if loggers and (self.validations % every == 0 or last):
            _log_figures(loggers, result, max(trainer.global_step - 1, 0))


def _log_figures(loggers, result: dict, step: int) -> None:
    import matplotlib.pyplot as plt

    from ..evaluation.plots import section_figures

    for tag, build in section_figures(result, tags=True, case=f"val split, step {step}").items():
        fig = build(result)
        if fig is None:
            continue
        for lg in loggers:
            lg.experiment.add_figure(f"val/{tag}", fig, global_step=step, close=False)
        plt.close(fig)


def best_checkpoint_on(trainer, monitor: str) -> None:
    """The CLI's best-checkpoint callback (on the acceleration error) keeps the best state on ``monitor`` instead
    (what ``SelectOnValidation`` judges: a model trained on torques alone has no acceleration error worth a file
    name); a resumed run's module calls it before the callbacks' state is loaded, which is keyed by it."""
    for cb in trainer.checkpoint_callbacks:
        if isinstance(cb, ModelCheckpoint) and cb.monitor == "val/acc_rel_err" and cb.mode == "min":
            cb.monitor = monitor
            cb.filename = f"epoch{{epoch}}-{monitor.rpartition('/')[2]}{{{monitor}:.4f}}"


class SelectOnValidation(L.Callback):
    """Ends the training with the state the validation prefers, the state before the first step included
    (evaluated when training starts: a model started from a classical fit keeps it unless a refined
    state does better on validation, so it is never worse there). Active where the module names a
    ``selection_monitor`` (a logged validation scalar, lower is better, e.g. ``val/torque_rms``, and
    ``validation_value(monitor)`` evaluates it outside the validation loop). Where the module also gives
    each validation entry's error (``validation_per_recording``), a state is taken only where it is no
    worse than the start on any of them: a state better pooled but worse on one recording (a residual that
    helps the logs without a tool and costs the one with it) is left out, and said so. States between the
    last validation and the end are not kept (nothing judged them). At the end the module holds the chosen
    state, its ``selection`` says which, and ``last.ckpt`` is written again with it."""

    def __init__(self) -> None:
        self.best = self.state = self.step = self.start = None
        self.history: list[tuple[int, float]] = []
        self.left_out: list[int] = []
        self.restored = False

    def state_dict(self) -> dict:
        """What a resumed run needs to go on judging as the first did: the start's errors, the best state so far
        (its weights too), the history."""
        if self.best is None:
            return {}
        return {"best": self.best, "step": self.step, "start": self.start, "history": list(self.history),
                "left_out": list(self.left_out), "state": self.state}

    def load_state_dict(self, state_dict: dict) -> None:
        if state_dict:
            self.best, self.step, self.start = state_dict["best"], state_dict["step"], state_dict["start"]
            self.history = [tuple(h) for h in state_dict["history"]]
            self.left_out, self.state = list(state_dict["left_out"]), state_dict["state"]
            self.restored = True

    def on_fit_start(self, trainer, pl_module) -> None:
        monitor = getattr(pl_module, "selection_monitor", None)
        if monitor:
            best_checkpoint_on(trainer, monitor)

    def on_train_start(self, trainer, pl_module) -> None:
        if self.restored:  # a resumed run: the start and the best so far are the first run's
            self.restored = False
            return
        self.best = self.state = self.step = self.start = None
        self.history, self.left_out = [], []
        monitor = getattr(pl_module, "selection_monitor", None)
        if monitor:
            self._offer(pl_module.validation_value(monitor), trainer.global_step, pl_module)

    def on_validation_end(self, trainer, pl_module) -> None:
        monitor = getattr(pl_module, "selection_monitor", None)
        if not monitor or trainer.sanity_checking or monitor not in trainer.callback_metrics:
            return
        self._offer(float(trainer.callback_metrics[monitor]), trainer.global_step, pl_module)

    def _offer(self, value: float, step: int, module) -> None:
        self.history.append((int(step), float(value)))
        if not math.isfinite(value) or (self.best is not None and value >= self.best):
            return
        each = module.validation_per_recording() if hasattr(module, "validation_per_recording") else None
        if self.best is None:  # the first state offered: the start, which every later one is held to
            self.start = each
        worse = each is not None and self.start is not None and any(
            not e <= s for e, s in zip(each, self.start, strict=True) if math.isfinite(s))  # (a NaN e: worse)
        if worse:
            self.left_out.append(int(step))
            return
        self.best, self.step = float(value), int(step)
        self.state = {k: v.detach().clone() for k, v in module.state_dict().items()}

    def on_train_end(self, trainer, pl_module) -> None:
        monitor = getattr(pl_module, "selection_monitor", None)
        if not monitor or self.state is None:
            return
        pl_module.load_state_dict(self.state)
        pl_module.selection = {"monitor": monitor, "step": self.step, "value": self.best,
                               "history": [list(h) for h in self.history], "left_out": list(self.left_out)}
        if trainer.is_global_zero:
            start = self.history[0][1]
            print(f"selected on validation: the state at step {self.step} of {trainer.global_step} ({monitor} "
                  f"{self.best:.4g}; at the start {start:.4g})"
                  + (f"; left out, better over all but worse than the start on a validation recording: step"
                     f"{'s' if len(self.left_out) > 1 else ''} {', '.join(map(str, self.left_out))}"
                     if self.left_out else ""))
        for cb in trainer.callbacks:
            if isinstance(cb, LastCheckpoint) and cb.path:
                trainer.save_checkpoint(cb.path)
