"""``LNNModule``: a thin LightningModule over a dynamics model (``lnn_torch.networks``).

Loss = Huber on normalised accelerations + ``energy_weight`` x the scale-invariant variance of the
model's own Hamiltonian over each contiguous chunk (``lnn_torch.losses.energy_variance``; with
generalised forces, of ``H - W`` with ``W`` the work of the model's own forces along the chunk: a
power-balance residual) + ``torque_weight`` x Huber on the inputs the model's inverse dynamics
predict (structured models of actuated scenes). With ``loss="trajectory"`` (trajectory matching, for
data without accelerations) the acceleration term is replaced by short differentiable rollouts of
each chunk from its first state, driven by its inputs, compared with its positions (multiple
shooting: every chunk is one shooting window; none crosses a trajectory's end).
The losses are pure functions of the model's training terms (``lnn_torch.losses.training_loss``,
``trajectory_loss``, ``shooting_residuals``); the compiled training pass runs through
``lnn_torch.perf.CompiledFallback``; the shims for older checkpoints are in ``lnn_torch.checkpoints``.
A non-finite loss or gradient skips the optimiser step (counted in ``train/skipped_steps``).
Validation and test call ``lnn_torch.evaluation.evaluate_model`` (relative L2 acceleration error,
rollouts of some trajectories with their true-energy drift and divergence time) and log its result.
"""

from __future__ import annotations

import math

import lightning as L
import torch
from torch.utils.tensorboard.summary import hparams as hparams_summary

from .checkpoint_format import (
    PRETRAINED,
    READ_ERRORS,
    old_default_widths,
    read_checkpoint,
    record_widths,
    resolve,
    stamp,
    unreadable,
    without_old_checkpoint_defaults,
)
from .evaluation import DEFAULT_SECTIONS, evaluate_model, section_figures, section_logs
from .losses import shooting_residuals, training_loss, trajectory_loss
from .networks import build_model
from .errors import InputError
from .networks.calls import counting_failures, model_accelerations
from .networks.capabilities import ENERGY, INVERSE_DYNAMICS
from .networks.registry import model_class, unknown_options
from .networks import model_options as model_options_of
from .perf import CompiledFallback, adamw, compile_pays_training, configure_cpu, warn_compile_failure
from .systems import get_system


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


def refuse_conflicts(variant: str, system, options: dict, energy_weight: float = 0.0, torque_weight: float = 0.0) -> None:
    """Every option and loss term that ``variant`` cannot use on ``system``, in ONE ``InputError`` (a user
    switching variants sees the whole list at once, not one refusal per attempt)."""
    cls = model_class(variant)
    problems = [f"option {k!r} (not an option of {variant})" for k in unknown_options(variant, options)]
    if torque_weight > 0 and not (INVERSE_DYNAMICS in cls.provides and system.num_inputs):
        problems.append(f"torque_weight {torque_weight:g} (needs inverse dynamics: film_lnn or delan on a scene with "
                        f"inputs; scene '{system.name}' has {system.num_inputs})")
    if energy_weight > 0 and ENERGY not in cls.provides:
        problems.append(f"energy_weight {energy_weight:g} (variant {variant} has no energy of its own)")
    if (energy_weight > 0 or torque_weight > 0) and options.get("dissipation") == "joint+stiction":
        problems.append("energy_weight/torque_weight with dissipation 'joint+stiction' (static friction's holding "
                        "torque is not a force of the state)")
    if problems:
        raise InputError(f"variant '{variant}' cannot use: {'; '.join(problems)}. "
                         f"Its options: {', '.join(model_options_of(variant))}")


class LNNModule(L.LightningModule):
    """Train a Lagrangian (or baseline) model of a scene.

    Args:
        scene: scene name (``lnn_torch.systems``); linked to the data's scene by the CLI.
        scene_config: scene sampler configuration (only structural options matter to the model).
        variant: a model variant (``lnn_torch.networks.VARIANTS``): ``film_lnn`` (default), ``delan``,
            ``lnn``, ``mlp``, ``hnn``.
        hidden_dims, activation, film_mode, potential_film, eps, lnn_init, hessian_reg,
            hnn_coordinates: model options; None (default) takes the variant's own default
            (``lnn_torch.networks.model_options(variant)``), and an option the variant does not take
            is an error. ``activation``: ``tanh``, ``softplus``, ``sigmoid``, ``isru`` (softplus for
            ``lnn``, as in the LNN paper; tanh otherwise). ``film_mode``: ``neuron`` (per-neuron FiLM)
            or ``layer`` (per-layer scalars, the reference design). ``potential_film``: FiLM on the
            potential network too. ``eps``: ``M = chol chol^T + eps I``. ``lnn_init``: the LNN
            paper's initialisation (``lnn``). ``hessian_reg``: regularisation of the black-box LNN's
            velocity Hessian (``lnn``; 0 raises on singular Hessians). ``hnn_coordinates``:
            ``canonical`` (p = dL/dqd from the scene) or ``velocity`` (the non-canonical (q, qd) of
            the LNN paper's counter-example).
        model_options: further options of the variant (a dict), for variants with options of their own.
        lr, lr_min: AdamW learning rate, cosine-annealed to ``lr_min`` over the run.
        weight_decay: AdamW weight decay of the network weights (physical coefficients are exempt:
            ``DynamicsModel.coefficient_parameters``).
        huber_delta: Huber threshold (normalised units).
        energy_weight: weight of the energy-conservation (power-balance, with forces) term (0 disables it).
        torque_weight: weight of the inverse-dynamics term: Huber on the inputs (motor torques) that
            the model's inverse dynamics give for the data's accelerations, normalised by their rms
            (structured models of actuated scenes; 0 disables it).
        loss: ``acceleration`` (default: Huber on accelerations) or ``trajectory`` (trajectory
            matching: each training chunk of ``L`` points is rolled out ``L - 1`` steps of the data's
            step from its first state with ``trajectory_integrator``, and the position error at
            every point, divided by ``(L - 1)^2 dt^2 / 2`` in normalised units, enters a Huber loss;
            no acceleration target is used).
        trajectory_integrator: the integrator of the training rollouts (``rk4``, ``leapfrog``, ...).
        trajectory_velocity_weight: weight of the velocity error of the training rollouts (the data's
            velocities: measured or estimated), divided by ``(L - 1) dt``.
        val_rollouts: validation trajectories rolled out each validation epoch.
        val_rollout_seconds: the horizon of validation and test rollouts (s).
        test_rollouts: test trajectories rolled out by ``test`` (-1: all of the test split).
        val_threshold: coordinate error (rad or m) that defines the divergence time.
        figure_every_n_epochs: log the evaluation's figures at every n-th validation (1, the default:
            every one; the last validation of a run always; 0: never).
        compile: run the training pass through ``torch.compile`` (``lnn_torch.perf.compile_fn``):
            ``"auto"`` (default) when the run is planned for at least
            ``lnn_torch.perf.AUTO_COMPILE_TRAIN_STEPS`` optimiser steps (the measured break-even of the
            compilation, ``results/compile_rule.md``; ``LNN_TORCH_COMPILE=0`` switches it off), ``True``
            always, ``False`` never. If compilation or the compiled backward fails, training warns
            once and continues eagerly. Validation and test use the model's own rule for rollouts
            (``model.compile_dynamics``).

    The learning rate follows a cosine from ``lr`` to ``lr_min`` that ends with the run: at the
    trainer's step budget or, when ``max_time`` is set, its time budget, whichever comes first.
    """

    def __init__(self, scene: str = "double_pendulum", scene_config: dict | None = None, variant: str = "film_lnn",
                 hidden_dims: list[int] | None = None, activation: str | None = None, film_mode: str | None = None,
                 potential_film: bool | None = None, eps: float | None = None, lnn_init: bool | None = None,
                 hessian_reg: float | None = None, hnn_coordinates: str | None = None,
                 model_options: dict | None = None, lr: float = 3e-3,
                 lr_min: float = 3e-5, weight_decay: float = 0.0, huber_delta: float = 1.0, energy_weight: float = 0.0,
                 torque_weight: float = 0.0, loss: str = "acceleration", trajectory_integrator: str = "rk4",
                 trajectory_velocity_weight: float = 0.0,
                 val_rollouts: int = 4, val_rollout_seconds: float = 5.0, test_rollouts: int = -1,
                 val_threshold: float = 0.1, figure_every_n_epochs: int = 1, compile: bool | str = "auto") -> None:
        super().__init__()
        self.save_hyperparameters(logger=False)
        self.system = get_system(scene, **(scene_config or {}))
        options = dict(hidden_dims=hidden_dims, activation=activation, film_mode=film_mode,
                       potential_film=potential_film, eps=eps, lnn_init=lnn_init, hessian_reg=hessian_reg,
                       hnn_coordinates=hnn_coordinates, **(model_options or {}))
        options = without_old_checkpoint_defaults(options, model_options_of(variant))
        refuse_conflicts(variant, self.system, options, energy_weight=energy_weight, torque_weight=torque_weight)
        self.model = build_model(variant, self.system, **options)
        self._model_options = options
        if loss not in ("acceleration", "trajectory"):
            raise ValueError(f"loss must be 'acceleration' or 'trajectory', got '{loss}'")
        if compile not in (True, False, "auto"):
            raise ValueError(f"compile must be true, false or 'auto', got {compile!r}")
        self.data_dt = None  # the sampling interval of the training data (the power-balance term integrates over it)
        self.register_buffer("normalizer_fitted", torch.tensor(False))
        self.register_buffer("skipped_steps", torch.tensor(0, dtype=torch.long))
        self._skip_this_step = False
        self._compiled = None  # the compiled training pass, once built; False after a fallback
        self._auto_compile = None  # compile="auto": the decision, made at the first training step
        self._last_batch = None

    # ------------------------------------------------------------------ checkpoints
    def on_save_checkpoint(self, checkpoint: dict) -> None:
        """Record the model's widths even where they were left to the variant's default, so that a
        later change of the default cannot change what a checkpoint loads as; and the package version
        and checkpoint format that wrote it (``checkpoints.stamp``)."""
        record_widths(checkpoint, self.model)
        stamp(checkpoint)

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        """A checkpoint without recorded widths predates ``on_save_checkpoint``: it was trained with the
        variant's old default widths, which the model is rebuilt with before its weights load."""
        old = old_default_widths(self.hparams)
        if old is not None:
            self.hparams.hidden_dims = list(old)
            self.model = build_model(self.hparams.variant, self.system, **{**self._model_options, "hidden_dims": old})

    # ------------------------------------------------------------------ public physics
    def acceleration(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor,
                     tau: torch.Tensor | None = None) -> torch.Tensor:
        """Accelerations in SI units: ``(B, dof), (B, dof), (B, P)[, tau (B, n_u)] -> (B, dof)`` (dtype and
        device of ``q``). ``tau``: the inputs of an actuated scene (N m; required there).

        Inputs are checked against the model and the scene (e.g. |qd| < c for the relativistic particle).
        """
        self.model.check_inputs(q, qd, params, tau)
        self.system.check_inputs(q, qd, params, tau)
        return self.model.acceleration(q, qd, params, tau, check=False)

    forward = acceleration

    def rollout(self, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4", tau=None):
        """Integrate the learned dynamics: returns ``(q, qd)`` each ``(B, num_steps + 1, dof)``.
        ``tau (B, num_steps, n_u)``: inputs of an actuated scene, held over each step."""
        self.system.check_inputs(q0, qd0, params, None if tau is None else tau[:, 0])
        return self.model.rollout(q0, qd0, params, dt, num_steps, method, tau=tau)

    def inverse_dynamics(self, q, qd, qdd, params) -> torch.Tensor:
        """The inputs ``tau (B, n_u)`` (N m) that produce the accelerations ``qdd`` (structured models
        of actuated scenes)."""
        self.system.check_inputs(q, qd, params, inputs="skip")
        return self.model.inverse_dynamics(q, qd, qdd, params)

    def identify(self, t, q, qd=None, tau=None, qdd=None, **options):
        """The physical parameters that make this model best explain ONE observed trajectory (SI:
        ``t (T,)``, ``q (T, dof)``, optional ``qd``, ``tau``, ``qdd``), with uncertainties and the
        directions the observation cannot determine: ``lnn_torch.identification.identify``."""
        from .identification import identify

        return identify(self.model, self.system, t, q, qd, tau, qdd, **options)

    # ------------------------------------------------------------------ set-up
    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if dm is not None and hasattr(dm, "scene"):
            data_scene = dm.scene
            if data_scene["name"] != self.system.name or data_scene["dof"] != self.system.dof:
                raise ValueError(f"the model is for scene '{self.system.name}' but the data hold "
                                 f"'{data_scene['name']}' (set model.scene, or let the CLI link it)")
        if not bool(self.normalizer_fitted):
            if dm is None or not hasattr(dm, "normalization_data"):
                raise RuntimeError("the normaliser is not fitted and no TrajectoryDataModule provides data")
            self.model.fit_normalizer(dm.normalization_data())
            self.normalizer_fitted.fill_(True)
        if dm is not None and hasattr(dm, "dt"):
            self.data_dt = dm.dt

    def on_fit_start(self) -> None:
        from lightning.pytorch.loggers import TensorBoardLogger

        configure_cpu()  # flush denormals, keep freed tensors in the heap (lnn_torch.perf)

        for logger in self.loggers:
            if isinstance(logger, TensorBoardLogger):
                # hyper-parameters with the metric keys, so the HParams tab shows the real metrics; the
                # keys are declared in the HParams summary only (Lightning's log_hyperparams(params,
                # metrics) would also write each key as a NaN scalar at step 0)
                logger.log_hyperparams(dict(self.hparams))
                energy = "val/power_balance" if self.system.has_forces else "val/energy_drift"
                metrics = {"val/acc_rel_err": math.nan, energy: math.nan, "val/divergence_time": math.nan}
                writer = logger.experiment._get_file_writer()
                if writer is None:  # the logger's stand-in on ranks other than the first writes nothing
                    continue
                for summary in hparams_summary(_plain_hparams(dict(self.hparams)), metrics):
                    writer.add_summary(summary)

    def on_train_epoch_start(self) -> None:
        dm = getattr(self.trainer, "datamodule", None)
        if dm is not None and hasattr(dm, "set_epoch"):
            dm.set_epoch(self.current_epoch)

    def configure_optimizers(self):
        params = list(self.parameters())
        if self.hparams.weight_decay:  # the network weights decay, the physical coefficients do not
            coefficients = {id(p) for p in self.model.coefficient_parameters()}
            groups = [{"params": [p for p in params if id(p) not in coefficients]},
                      {"params": [p for p in params if id(p) in coefficients], "weight_decay": 0.0}]
            params = [g for g in groups if g["params"]]
        opt = adamw(params, lr=self.hparams.lr, weight_decay=self.hparams.weight_decay)
        floor = self.hparams.lr_min / self.hparams.lr
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda step: floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * self._progress(step))))
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    def _progress(self, step: int) -> float:
        """Fraction of the training budget used: steps, or wall time under ``max_time``."""
        if self._trainer is None:
            return 0.0
        total = self.trainer.estimated_stepping_batches
        progress = step / total if total and math.isfinite(total) else 0.0
        from lightning.pytorch.callbacks import Timer

        for cb in self.trainer.callbacks:
            if isinstance(cb, Timer) and cb.time_remaining("train") is not None:
                elapsed = cb.time_elapsed("train")
                duration = elapsed + cb.time_remaining("train")
                progress = max(progress, elapsed / duration if duration > 0 else 1.0)
        return min(progress, 1.0)

    # ------------------------------------------------------------------ training
    def _with_energy(self) -> bool:
        return self.hparams.energy_weight > 0 and self.model.has_energy

    def _training_pass(self, q, qd, qdd, params, tau=None, chunks=None):
        """Eager training pass on flat SI tensors: the dict of ``training_terms``. ``chunks``: the
        rows are that many trajectory chunks, each with one parameter vector."""
        return self.model.training_terms(q, qd, qdd, params, tau=tau, energy=self._with_energy(), chunks=chunks,
                                         torque=self.hparams.get("torque_weight", 0) > 0)

    def _compile_training(self) -> bool:
        """Whether training runs its pass compiled: ``compile``, or under ``"auto"`` whether the run's
        planned steps (the trainer's ``estimated_stepping_batches``) repay the compilation."""
        choice = self.hparams.get("compile", False)
        if choice != "auto":
            return bool(choice)
        if self._auto_compile is None:
            steps = self.trainer.estimated_stepping_batches if self._trainer is not None else 0
            self._auto_compile = compile_pays_training(steps)
        return self._auto_compile

    def _pass_fn(self):
        if self._compiled is False or not self._compile_training():
            return self._training_pass
        if self._compiled is None:
            self._compiled = CompiledFallback(self._training_pass, self.device, on_failure=self._compile_failed)
        return self._compiled

    def _trajectory_loss(self, batch) -> tuple[torch.Tensor, dict]:
        """Multiple shooting: each chunk rolled out from its first state, driven by its inputs,
        against its positions (and velocities); errors in normalised units divided by the window's
        ``(k dt)^2 / 2`` (positions) and ``k dt`` (velocities), ``k = L - 1`` steps."""
        q, qd = batch["q"], batch["qd"]
        if q.shape[1] < 2:
            raise ValueError("trajectory matching needs chunks of at least 2 points (data.chunk_len >= 2)")
        tau = batch["tau"][:, :-1] if "tau" in batch else None
        norm = self.model.normalizer
        velocity_weight = self.hparams.trajectory_velocity_weight
        with counting_failures(self.model):  # residuals in normalised coordinates and time
            err, err_v = shooting_residuals(self.model, q[:, 0], qd[:, 0], batch["params"][:, 0], self.data_dt or 1.0,
                                            q, self.hparams.trajectory_integrator, tau=tau,
                                            qd_windows=qd if velocity_weight > 0 else None,
                                            scale=norm.coord_scale.to(q.dtype), time_scale=float(norm.time_scale))
        return trajectory_loss(err, err_v, huber_delta=self.hparams.huber_delta, velocity_weight=velocity_weight)

    def _training_loss(self, batch, pass_fn):
        """``(loss, parts)``: the total loss and its logged parts (``huber``, ``energy_var``, ``torque``,
        or ``trajectory`` for trajectory matching)."""
        if self.hparams.get("loss", "acceleration") == "trajectory":
            return self._trajectory_loss(batch)
        C, L, _ = batch["q"].shape  # (chunks, chunk length, dof)
        flat = [batch[k].reshape(C * L, -1) for k in ("q", "qd", "qdd", "params")]
        tau = batch["tau"].reshape(C * L, -1) if "tau" in batch else None
        # chunks of one trajectory share their parameters: the model then conditions once per chunk
        params = batch["params"]
        shared = params.shape[1] == 1 or bool((params == params[:, :1]).all())
        out = pass_fn(*flat, tau, C if shared else None)
        # the power balance integrates the forces' power over the data's step, in normalised time
        dt_norm = (self.data_dt or 1.0) / float(self.model.normalizer.time_scale) if "power" in out else 1.0
        return training_loss(out, C, L, huber_delta=self.hparams.huber_delta, energy_weight=self.hparams.energy_weight,
                             torque_weight=self.hparams.get("torque_weight", 0), dt=dt_norm)

    def _compile_failed(self, err: Exception) -> None:
        """The compiled training pass failed (compiling it, a compiled call or its backward): warn once
        and train eagerly from now on."""
        warn_compile_failure("training pass", err, "continuing training eagerly", stacklevel=1)
        self._compiled = False

    def training_step(self, batch, batch_idx):
        self._last_batch = batch
        # a compilation failure of the pass falls back to the eager pass inside it (CompiledFallback)
        loss, parts = self._training_loss(batch, self._pass_fn())
        if self._writes_logs():
            if len(parts) > 1:  # one curve per term; a loss of one term is train/loss itself
                for name, value in parts.items():
                    self.log(f"train/{name}", value.detach(), on_step=True, on_epoch=False)
            self.log("train/loss", loss.detach(), on_step=True, on_epoch=False, prog_bar=True)
        self._skip_this_step = not bool(torch.isfinite(loss))
        if self._skip_this_step:
            # keep the graph (DDP needs every rank to run backward) but contribute nothing
            loss = sum(p.sum() for p in self.parameters()) * 0.0
        return loss

    def backward(self, loss, *args, **kwargs) -> None:
        try:
            super().backward(loss, *args, **kwargs)
        except Exception as err:  # the compiled backward failed: redo this step eagerly
            if not self._compiled or self._last_batch is None:
                raise
            self._compiled.fail(err)  # warned once (_compile_failed); eager from now on
            self.zero_grad(set_to_none=True)
            loss, _ = self._training_loss(self._last_batch, self._training_pass)
            if not torch.isfinite(loss):
                loss = sum(p.sum() for p in self.parameters()) * 0.0
            super().backward(loss, *args, **kwargs)

    def on_before_optimizer_step(self, optimizer) -> None:
        grads = [p.grad for p in self.parameters() if p.grad is not None]
        # one norm over all gradients: non-finite if some gradient entry is NaN or Inf (or it overflows)
        norm = torch.linalg.vector_norm(torch.stack(torch._foreach_norm(grads))) if grads else torch.zeros(())
        bad = self._skip_this_step or not bool(torch.isfinite(norm))
        flag = torch.tensor(float(bad), device=self.device)
        if self.trainer.world_size > 1:  # every rank skips together
            flag = self.trainer.strategy.reduce(flag, reduce_op="max")
        skip = flag.item() > 0
        if skip:
            self.skipped_steps += 1
            for p in self.parameters():
                p.grad = None  # AdamW leaves parameters without gradients untouched
        if not self._writes_logs():
            return
        if not skip:
            self.log("train/grad_norm", norm, on_step=True, on_epoch=False)
        self.log("train/skipped_steps", self.skipped_steps.float(), on_step=True, on_epoch=False)
        self.log("train/lr", optimizer.param_groups[0]["lr"], on_step=True, on_epoch=False)

    def _writes_logs(self) -> bool:
        """Whether the logger writes this step's per-step values (every ``log_every_n_steps`` steps):
        a ``self.log`` call costs a fraction of a millisecond, several per step, so per-step values
        are logged only on the steps that are written (always outside a trainer's fit loop)."""
        connector = getattr(self._trainer, "_logger_connector", None) if self._trainer is not None else None
        try:
            return bool(connector.should_update_logs) if connector is not None else True
        except Exception:  # noqa: BLE001 - a Lightning version without this property: log every step
            return True

    # ------------------------------------------------------------------ evaluation
    def _evaluate(self, batch: dict, prefix: str) -> None:
        """``evaluate_model`` on a whole split (the DataModule's one evaluation item), logged as
        ``{prefix}/...``: the scalars its sections present (``SectionResult.logs``) and, every
        ``figure_every_n_epochs`` validation epochs, their figures. Every rank evaluates the same
        data (identical results)."""
        data = batch["trajectories"]
        n = self.hparams.val_rollouts if prefix == "val" else self.hparams.get("test_rollouts", -1)
        thr = self.hparams.val_threshold
        if not self.system.closed_form:  # measured recordings: open-loop horizons from many start points
            result = evaluate_model(self.model, self.system, data, sections=("accelerations", "horizons"),
                                    thresholds=(thr,), accel_stride=int(batch["accel_stride"]),
                                    horizons=(0.1, 0.5, self.hparams.val_rollout_seconds))
        else:
            result = evaluate_model(self.model, self.system, data,
                                    sections=DEFAULT_SECTIONS if n != 0 else ("accelerations",),
                                    horizon=self.hparams.val_rollout_seconds, thresholds=(thr,),
                                    accel_stride=int(batch["accel_stride"]), num_rollouts=n if n > 0 else None)
        for name, value in section_logs(result).items():
            self.log(f"{prefix}/{name}", float(value), batch_size=1, sync_dist=True, prog_bar=name == "acc_rel_err")
        if prefix == "val" and self.system.closed_form and n != 0 and self._figures_now():
            self._log_figures(result, prefix)

    def _figures_now(self) -> bool:
        """Whether this validation logs figures: every ``figure_every_n_epochs``-th one and the run's
        last (not the sanity check before training, nor on other ranks than the first)."""
        every, trainer = self.hparams.figure_every_n_epochs, self.trainer
        if not every or trainer.sanity_checking or not trainer.is_global_zero:
            return False
        self._validations = getattr(self, "_validations", 0) + 1
        last = ((trainer.max_epochs not in (None, -1) and self.current_epoch + 1 >= trainer.max_epochs)
                or (trainer.max_steps not in (None, -1) and self.global_step >= trainer.max_steps))
        return self._validations % every == 0 or last

    def validation_step(self, batch, batch_idx):
        self._evaluate(batch, "val")

    def test_step(self, batch, batch_idx):
        self._evaluate(batch, "test")

    def _log_figures(self, result: dict, prefix: str = "val") -> None:
        """Every figure the evaluated sections present, as ``{prefix}/{name}`` in TensorBoard."""
        from lightning.pytorch.loggers import TensorBoardLogger

        loggers = [lg for lg in self.loggers if isinstance(lg, TensorBoardLogger)]
        if not loggers:
            return
        import matplotlib.pyplot as plt

        # the step Lightning logs this validation's scalars at: the last training step's index
        step = max(self.global_step - 1, 0)
        for tag, build in section_figures(result, tags=True, case=f"{prefix} split, step {step}").items():
            fig = build(result)
            if fig is None:
                continue
            for lg in loggers:
                lg.experiment.add_figure(f"{prefix}/{tag}", fig, global_step=step, close=False)
            plt.close(fig)

    # ------------------------------------------------------------------ prediction
    def predict_step(self, batch, batch_idx):
        pred = model_accelerations(self.model, batch["q"], batch["qd"], batch["params"][:, 0])
        return {"trajectory": batch["trajectory"], "q": batch["q"], "qd": batch["qd"], "params": batch["params"][:, 0],
                "qdd_true": batch["qdd"], "qdd_pred": pred}


def load_model(source, map_location="cpu") -> LNNModule:
    """The ``LNNModule`` of a checkpoint path or ``pretrained:<name>``, in evaluation mode (SI units in
    and out): ``model.acceleration(q, qd, params)``, ``model.rollout(...)``. A file that is not an
    lnn-torch checkpoint is refused in one line (``CheckpointError``)."""
    path = resolve(source)
    read_checkpoint(path)
    try:
        model = LNNModule.load_from_checkpoint(path, map_location=map_location)
    except InputError:
        raise
    except READ_ERRORS as err:
        raise unreadable(path, err) from None
    model.eval()
    return model


def load_pretrained(name: str = "double_pendulum", map_location="cpu") -> LNNModule:
    """The shipped ``LNNModule`` ``name`` in evaluation mode (SI units in and out).

    >>> model = load_pretrained("double_pendulum")
    >>> model.acceleration(q, qd, params)  # (B, 2), (B, 2), (B, 4) -> (B, 2)
    """
    return load_model(f"{PRETRAINED}{name}", map_location)
