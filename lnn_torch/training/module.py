"""``LNNModule``: a thin LightningModule over a dynamics model (``lnn_torch.networks``): the steps, the
optimiser and the schedule. The losses are pure functions (``lnn_torch.training.losses``: one batch is one call
of ``acceleration_batch_loss`` or ``trajectory_batch_loss``); skipping non-finite steps, TensorBoard's
HParams and figures are callbacks (``lnn_torch.training.callbacks``, added by ``configure_callbacks``);
validation and test are ``lnn_torch.evaluation.evaluate_split`` on a whole split, its scalars logged.
``lnn_torch.training.checkpoints.load_model`` reads a checkpoint into it.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import lightning as L
import torch

from ..errors import InputError, check_tensors, values_readable
from ..evaluation import evaluate_split, section_logs
from ..identification.learned import identify
from ..networks import build_model, registry
from ..networks.calls import model_accelerations
from ..networks.capabilities import ENERGY
from ..perf import configure_cpu
from ..robots.description import compiled_copies
from ..systems import get_system
from . import checkpoint_format as ckpt
from .callbacks import (
    DivergenceWatch,
    EvaluationFigures,
    HParamsSummary,
    SelectOnValidation,
    SkipNonFiniteSteps,
    best_checkpoint_on,
    writes_logs,
)
from .losses import acceleration_batch_loss, trajectory_batch_loss
from .optim import configure_optimizer, freeze_all_but, training_progress
from .training_pass import TrainingPass


class LNNModule(L.LightningModule):
    """Train a Lagrangian (or baseline) model of a scene.

    Args:
        scene: scene name (``lnn_torch.systems``); linked to the data's scene by the CLI.
        scene_config: scene configuration (only structural options matter to the model).
        variant: ``film_lnn`` (default), ``delan``, ``lnn``, ``mlp`` or ``hnn`` (``lnn-torch list``).
        hidden_dims, activation, film_mode, potential_film, eps, lnn_init, hessian_reg, hnn_coordinates:
            model options (``docs/design.md``); None takes the variant's default
            (``lnn_torch.networks.model_options``); an option the variant does not take is an error.
            ``activation``: tanh, softplus (the default of ``lnn``), sigmoid, isru; ``film_mode``:
            ``neuron`` or ``layer`` (the reference design's per-layer scalars); ``eps``: ``M = chol
            chol^T + eps I``; ``hessian_reg``: regularisation of ``lnn``'s velocity Hessian (0 raises on
            singular Hessians); ``hnn_coordinates``: ``canonical`` (p = dL/dqd) or ``velocity``.
        model_options: further options of the variant (a dict): parts, dissipation, ...
        lr, lr_min, weight_decay: AdamW learning rate, cosine-annealed to ``lr_min`` over the run
            (``lnn_torch.training.optim``); weight decay of the network weights (physical coefficients are exempt).
        huber_delta: Huber threshold (normalised units).
        energy_weight: weight of the energy-conservation (with forces: power-balance) term; 0: off.
        acceleration_weight: weight of the acceleration term (0: torques alone, with ``torque_weight``).
        torque_weight: weight of the inverse-dynamics term, Huber on the inputs the model needs for the
            data's accelerations over their rms (structured models of actuated scenes); 0: off.
        loss: ``acceleration`` (Huber on accelerations) or ``trajectory`` (multiple shooting: each chunk
            of ``L`` points rolled out ``L - 1`` steps from its first state with
            ``trajectory_integrator``; position errors over ``(L - 1)^2 dt^2 / 2``; no accelerations).
        trajectory_integrator, trajectory_velocity_weight: their integrator (``rk4``, ...) and the weight of
            their velocity error, over ``(L - 1) dt``.
        val_rollouts, val_rollout_seconds, val_threshold: validation trajectories rolled out at each
            validation; the horizon of validation and test rollouts (s); the coordinate error (rad or m)
            that defines the divergence time. test_rollouts: those of ``test`` (-1: all).
        figure_every_n_epochs: log figures at every n-th validation and the last (0: never).
        compile: compile the training pass (``perf.compile_fn``): ``"auto"`` (default) when the run plans
            at least ``perf.AUTO_COMPILE_TRAIN_STEPS`` steps (``results/compile_rule.md``; ``LNN_TORCH_COMPILE=0``:
            never), ``True`` always, ``False`` never; a failure warns once and training goes on eagerly.
        init_from: a checkpoint or ``pretrained:<name>`` of a model of the same variant and shape whose
            weights and normaliser start the run (fine-tuning, warm restarts; the schedule starts afresh);
            or of the same model without this run's force residual, which then starts at zero beside it.
        train_only: ``"residual_force"``: only the force residual trains, the rest stays as ``init_from``
            gave it (a residual beside a fitted grey box that cannot move its physics); None: all.
        classical_start: start an arm grey box (the learned spatial part with joint friction, trained on
            torques) from classical identification of the training recordings
            (``identification.classical_start``: the physically consistent least-squares fit, its prior
            chosen on the validation recordings; the refinement's prior then pulls towards it) and end
            the training with the state the validation torque error prefers, that start included
            (``callbacks.SelectOnValidation``): the model is never worse than the classical fit on
            validation. ``"auto"`` (default): for every such model on a fresh run; True: required (an
            error where the model or data cannot); False: the description is the start, the last
            state the end.
        learn_residual: whether a fresh run learns the force residual its ``model_options`` ask for
            (``residual_force``): ``"auto"`` (default) only where validation can judge it, i.e. where there
            is a validation split and it holds recordings of its own (on windows of the training recordings a
            force of the state fits the one trajectory on both sides of the split); True: always; False: never. A
            residual not learned is left out of the model and its checkpoint, and the fit says why.
        residual_min_steps: the fewest training steps of a run whose force residual is learned: a residual
            beside a classical start needs more steps than the start's refinement alone (``trainer.max_steps``,
            which a run without a residual keeps, as one that plans more steps); None: ``trainer.max_steps``.
    """

    def __init__(self, scene: str = "double_pendulum", scene_config: dict | None = None, variant: str = "film_lnn",
                 hidden_dims: list[int] | None = None, activation: str | None = None, film_mode: str | None = None,
                 potential_film: bool | None = None, eps: float | None = None, lnn_init: bool | None = None,
                 hessian_reg: float | None = None, hnn_coordinates: str | None = None,
                 model_options: dict | None = None, lr: float = 3e-3, lr_min: float = 3e-5, weight_decay: float = 0.0,
                 huber_delta: float = 1.0, energy_weight: float = 0.0, torque_weight: float = 0.0,
                 acceleration_weight: float = 1.0, loss: str = "acceleration", trajectory_integrator: str = "rk4",
                 trajectory_velocity_weight: float = 0.0,
                 val_rollouts: int = 4, val_rollout_seconds: float = 5.0, test_rollouts: int = -1,
                 val_threshold: float = 0.1, figure_every_n_epochs: int = 1, compile: bool | str = "auto",
                 init_from: str | None = None, train_only: str | None = None,
                 classical_start: bool | str = "auto", learn_residual: bool | str = "auto",
                 residual_min_steps: int | None = None) -> None:
        super().__init__()
        self.save_hyperparameters(logger=False)
        self.system = get_system(scene, **(scene_config or {}))
        options = dict(hidden_dims=hidden_dims, activation=activation, film_mode=film_mode,
                       potential_film=potential_film, eps=eps, lnn_init=lnn_init, hessian_reg=hessian_reg,
                       hnn_coordinates=hnn_coordinates, **(model_options or {}))
        options = ckpt.without_old_checkpoint_defaults(options, registry.model_options(variant))
        registry.refuse_conflicts(variant, self.system, options, energy_weight, torque_weight, acceleration_weight)
        self.model = build_model(variant, self.system, **options)
        self._model_options = options
        freeze_all_but(self.model, train_only, init_from)
        if loss not in ("acceleration", "trajectory"):
            raise ValueError(f"loss must be 'acceleration' or 'trajectory', got '{loss}'")
        self.data_dt = None  # the sampling interval of the training data (the power-balance term integrates over it)
        self.register_buffer("normalizer_fitted", torch.tensor(False))
        self.register_buffer("skipped_steps", torch.tensor(0, dtype=torch.long))  # callbacks.SkipNonFiniteSteps
        self.training_pass = TrainingPass(self.training_terms, compile)  # compiled where it pays
        self._last_batch = self.evaluation = None  # the step's batch; the last validation's result (its figures)
        # a resumed run (set by the CLI before ``fit`` with ``--ckpt_path``; ``trainer.fit(module, ckpt_path=...)``
        # from Python: set it first): no classical start nor residual judging, the checkpoint's state stands (where
        # unset, both run and the checkpoint overrides them); the step limit a learned residual raised (``_at_least``)
        self.resuming, self._raised_steps = False, None
        self._description_copies = None  # what checkpoints carry of the robot description files (on_save_checkpoint)
        for name, value in (("val_rollouts", val_rollouts), ("test_rollouts", test_rollouts)):
            if isinstance(value, bool) or not isinstance(value, int) or value < -1:
                raise InputError(f"{name} must be a number of trajectories, 0 (none) or -1 (all), got {value!r}")
        if classical_start not in (True, False, "auto"):
            raise InputError(f"classical_start must be true, false or auto, got {classical_start!r}")
        if learn_residual not in (True, False, "auto"):
            raise InputError(f"learn_residual must be true, false or auto, got {learn_residual!r}")
        if residual_min_steps is not None and (isinstance(residual_min_steps, bool)
                                               or not isinstance(residual_min_steps, int) or residual_min_steps < 1):
            raise InputError(f"residual_min_steps must be a positive number of steps or null, "
                             f"got {residual_min_steps!r}")
        # the classical fit the run started from (classical_start) and the state validation chose
        # (callbacks.SelectOnValidation); both travel in the checkpoint
        self.classical_start = self.selection = None

    # ------------------------------------------------------------------ checkpoints
    def on_save_checkpoint(self, checkpoint: dict) -> None:
        """The model's widths even where left to the variant's default, the data file's absolute path, the
        compiled robot descriptions it was built from (``robots.description.compiled_copies``) and the package's
        stamp."""
        ckpt.record_widths(checkpoint, self.model)
        dm = getattr(self._trainer, "datamodule", None) if self._trainer is not None else None
        if getattr(dm, "path", None):  # where the data were (a relative path holds only from the fit's folder)
            checkpoint[ckpt.DATA_PATH] = str(Path(dm.path).resolve())
        if self._description_copies is None:
            try:
                self._description_copies = compiled_copies({"scene_config": self.hparams.get("scene_config"),
                                                            "model_options": self.hparams.get("model_options")})
            except InputError as err:  # a description file gone since the model was built in another process
                warnings.warn(f"the checkpoint carries no copy of its robot description: {err}", stacklevel=2)
                self._description_copies = {}
        if self._description_copies:
            checkpoint[ckpt.DESCRIPTION_COPIES] = self._description_copies
        if self.classical_start is not None:
            spatial = self.model.part("kinetic", "spatial")
            checkpoint["classical_start"] = {**self.classical_start, "anchor_J": spatial.anchor_J()}
        if self.selection is not None:
            checkpoint["selection"] = self.selection
        if self._raised_steps is not None:
            checkpoint["raised_max_steps"] = self._raised_steps
        ckpt.stamp(checkpoint)

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        """A checkpoint of an earlier format is built as it was trained: the variant's old default widths
        where it recorded none, the scene's features of then (``checkpoint_format.scene_config_of_old``); a
        resumed run takes the checkpoint's force residual (or its absence) and the step limit a learned residual
        raised."""
        theirs = checkpoint.get("hyper_parameters") or self.hparams  # (a resumed run: the module is this run's)
        old = ckpt.old_default_widths(theirs)
        widths = old if old is not None else theirs.get("hidden_dims")
        if widths is not None and list(widths) == list(getattr(self.model, "hidden_dims", widths)):
            widths = None  # built so already
        scene_config = ckpt.scene_config_of_old(checkpoint, self.hparams)
        if scene_config is not None:
            self.hparams.scene_config = scene_config
            self.system = get_system(self.hparams.scene, **scene_config)
        rebuild = widths is not None or scene_config is not None
        if widths is not None:
            self.hparams.hidden_dims = list(widths)
            self._model_options = {**self._model_options, "hidden_dims": list(widths)}
        # a resumed run whose setup judged the force residual otherwise than the checkpoint's run: the checkpoint's
        stored = checkpoint.get("hyper_parameters", {}).get("model_options") or {}
        residual = any(k.startswith(ckpt.RESIDUAL) for k in checkpoint.get("state_dict", {}))
        if residual != (getattr(getattr(self.model, "forces", None), "residual", None) is not None) \
                and residual == ("residual_force" in stored):
            self._set_residual_option(stored["residual_force"] if residual else None)
            rebuild = True
        if rebuild:
            self.model = build_model(self.hparams.variant, self.system, **self._model_options)
            freeze_all_but(self.model, self.hparams.get("train_only"), self.hparams.get("init_from"))
        if (checkpoint.get("raised_max_steps") and self._trainer is not None
                and self.trainer.state.fn == "fit"):  # a resumed run with a learned residual (not a test)
            self._at_least(int(checkpoint["raised_max_steps"]), "a resumed run with its force residual",
                           getattr(self.trainer, "datamodule", None))
        start = checkpoint.get("classical_start")
        if start is not None:  # the refinement's prior pulls towards the start (a resumed run goes on so)
            self.classical_start = {k: v for k, v in start.items() if k != "anchor_J"}
            self.model.part("kinetic", "spatial").anchor_at(start.get("anchor_J"))
        self.selection = checkpoint.get("selection")
        if self._trainer is not None and self.selection_monitor:  # a resumed run: before its callbacks' state loads
            best_checkpoint_on(self.trainer, self.selection_monitor)

    # ------------------------------------------------------------------ public physics
    def acceleration(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor,
                     tau: torch.Tensor | None = None) -> torch.Tensor:
        """Accelerations in SI units, checked inputs: ``(B, dof), (B, dof), (B, P)[, tau (B, n_u)] -> (B, dof)``
        (dtype and device of ``q``); ``tau``: the inputs of an actuated scene (N m; required there)."""
        self.model.check_inputs(q, qd, params, tau)
        self.system.check_inputs(q, qd, params, tau)
        return self.model.acceleration(q, qd, params, tau, check=False)

    forward = acceleration

    def compile_dynamics(self, enabled: bool | str = True) -> LNNModule:
        """When ``acceleration`` and ``rollout`` run through ``torch.compile`` (the network's
        ``compile_dynamics``: ``True``, ``False`` or ``"auto"``, the default). Returns this module."""
        self.model.compile_dynamics(enabled)
        return self

    def rollout(self, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4", tau=None):
        """Integrate the learned dynamics: returns ``(q, qd)`` each ``(B, num_steps + 1, dof)``.
        ``tau (B, num_steps, n_u)``: inputs of an actuated scene, held over each step. A trajectory that becomes
        non-finite is warned of (``RuntimeWarning``)."""
        check_tensors(("q0", "qd0", "tau"), q0=q0, qd0=qd0, params=params, tau=tau)
        num_steps = self.model.check_rollout_inputs(q0, num_steps, tau)
        self.system.check_inputs(q0, qd0, params, None if tau is None else tau[:, 0])
        q, qd = self.model.rollout(q0, qd0, params, dt, num_steps, method, tau=tau)
        if not values_readable():  # (under a torch.func transform: no values to judge)
            return q, qd
        bad = ~(torch.isfinite(q).all(-1) & torch.isfinite(qd).all(-1))  # (B, num_steps + 1)
        if bad.any():
            first = int(bad.any(0).nonzero()[0, 0])
            warnings.warn(f"rollout: {int(bad.any(1).sum())} of {len(q)} trajectories became non-finite (the first "
                          f"at step {first}, t = {first * dt:g} s): their states left what the model was trained on, "
                          "or dt is too large for them", RuntimeWarning, stacklevel=2)
        return q, qd

    def inverse(self, q, qd, qdd, params) -> torch.Tensor:
        """The inputs ``tau (B, n_u)`` (N m) that produce the accelerations ``qdd`` (structured models
        of actuated scenes)."""
        self.system.check_inputs(q, qd, params, inputs="skip")
        return self.model.inverse(q, qd, qdd, params)

    # the model's SI rigid-body face (``lnn_torch.networks.rigid_body`` states the convention), checked inputs
    def mass_matrix(self, q, params) -> torch.Tensor:
        """``M (B, dof, dof)`` in SI."""
        self.system.check_inputs(q, q, params, inputs="skip")
        return self.model.mass_matrix(q, params)

    def bias(self, q, qd, params) -> torch.Tensor:
        """``n (B, dof)``: Coriolis, centrifugal and gravity forces in SI (no friction, no inputs)."""
        self.system.check_inputs(q, qd, params, inputs="skip")
        return self.model.bias(q, qd, params)

    def gravity(self, q, params) -> torch.Tensor:
        """``g = n(q, 0) (B, dof)`` in SI."""
        self.system.check_inputs(q, q, params, inputs="skip")
        return self.model.gravity(q, params)

    def friction(self, q, qd, params) -> torch.Tensor:
        """``Q_f (B, dof)``: the learned dissipative generalised force in SI."""
        self.system.check_inputs(q, qd, params, inputs="skip")
        return self.model.friction(q, qd, params)

    def energy(self, q, qd, params) -> torch.Tensor:
        """``H = T + V (B,)``: the model's own energy (J where it was trained with torques, else its own units)."""
        self.system.check_inputs(q, qd, params, inputs="skip")
        return self.model.energy(q, qd, params)

    def residual_force(self, q, qd, params) -> torch.Tensor:
        """``Q_r (B, dof)``: the learned force residual in SI (zero without one; a scene without generalised
        forces has none to add to: InputError, as ``friction``)."""
        self.system.check_inputs(q, qd, params, inputs="skip")
        return self.model.residual_force(q, qd, params)

    def identify(self, t, q, qd=None, tau=None, qdd=None, **options):
        """The parameters that best explain ONE observed trajectory: ``lnn_torch.identification.learned.identify``."""
        return identify(self.model, self.system, t, q, qd, tau, qdd, **options)

    # ------------------------------------------------------------------ set-up
    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        scene = getattr(dm, "scene", None)
        if scene is not None and (scene["name"] != self.system.name or scene["dof"] != self.system.dof):
            raise ValueError(f"the model is for scene '{self.system.name}' but the data hold '{scene['name']}' "
                             "(set model.scene, or let the CLI link it)")
        # a resumed run loads its own state after this (the CLI says so beforehand: ``resuming``), and
        # ``on_load_checkpoint`` gives the model the checkpoint's residual and steps
        fresh = stage == "fit" and not self.resuming
        if not bool(self.normalizer_fitted) and self.hparams.get("init_from"):
            added = ckpt.load_start_weights(self, self.hparams.init_from)
            if added:
                self.model.fit_residual(dm.normalization_data())  # a new residual: its units from this data
            if fresh:
                self._judge_residual(dm, trained=not added)
        if not bool(self.normalizer_fitted):
            if dm is None or not hasattr(dm, "normalization_data"):
                raise RuntimeError("the normaliser is not fitted and no TrajectoryDataModule provides data")
            self.model.fit_normalizer(dm.normalization_data())
            self.normalizer_fitted.fill_(True)
            if fresh:
                self._start_from_classical(dm)
                self._judge_residual(dm)
        self.data_dt = dm.dt if hasattr(dm, "dt") else self.data_dt

    def _set_residual_option(self, options) -> None:
        """The model options (the module's and its saved hyper-parameters) with ``residual_force: options``, or
        without a force residual (None)."""
        def set_in(held: dict) -> dict:
            others = {k: v for k, v in held.items() if k != "residual_force"}
            return others if options is None else {**others, "residual_force": options}

        self._model_options = set_in(self._model_options)
        self.hparams["model_options"] = set_in(self.hparams.get("model_options") or {})

    def _judge_residual(self, dm, trained: bool = False) -> None:
        """``learn_residual`` (the class docstring): with ``"auto"`` a force residual is learned only where
        validation can judge it. Where the validation windows come from the training recordings (one exciting
        trajectory split in time), a force of the state fits that trajectory on both sides of the split (the UR10
        bag: validation took a local residual, the held-out error rose 22 %), so the model is built without it
        (its checkpoint as a model without ``residual_force``), and a line says so; so too without a validation
        split. ``"auto"`` keeps a residual ``init_from`` brought (``trained``: judged when it was trained) or one
        trained alone on purpose (``train_only: residual_force``). A residual that is learned trains at least
        ``residual_min_steps`` steps (``_at_least``)."""
        forces = getattr(self.model, "forces", None)
        if getattr(forces, "residual", None) is None:
            return
        wanted = self.hparams.get("learn_residual", "auto")
        shared = dm.shared_recordings("train", "val") if hasattr(dm, "shared_recordings") else []
        judged = not hasattr(dm, "split_names") or "val" in dm.split_names()
        chosen = wanted is True or trained or self.hparams.get("train_only") == "residual_force"
        if wanted is False or (not chosen and (shared or not judged)):
            forces.residual = None
            self._set_residual_option(None)
            why = ("model.learn_residual is false" if wanted is False else
                   "the data have no validation split to judge it (validate on recordings of their own to learn "
                   "it, or set model.learn_residual true)" if not judged else
                   f"the validation windows come from the training recordings ({', '.join(shared)}), where "
                   "validation cannot tell a force of the state from one of the trajectory (validate on recordings "
                   "of their own to learn it, or set model.learn_residual true)")
            print(f"force residual: left out: {why}", flush=True)
            return
        unjudged = bool(shared) or not judged
        why = ("model.learn_residual is true" if wanted is True and unjudged else "init_from brought it" if trained
               else "trained alone (train_only)" if unjudged
               else "the validation recordings are recordings of their own")
        self._at_least(self.hparams.get("residual_min_steps"), f"force residual: learned ({why})", dm)

    def _at_least(self, steps: int | None, what: str, dm=None) -> None:
        """Raise the trainer's step limit (and an epoch limit that would end the run first) to ``steps``, saying so
        with ``what``; nothing where the run plans that many already or trains without a step limit."""
        if steps is None or self._trainer is None:
            return
        loop = self.trainer.fit_loop
        per_epoch = (getattr(dm, "hparams", None) or {}).get("steps_per_epoch")  # a TrajectoryDataModule's
        planned = loop.epoch_loop.max_steps if loop.epoch_loop.max_steps != -1 else float("inf")
        if loop.max_epochs not in (None, -1) and per_epoch:
            planned = min(planned, loop.max_epochs * per_epoch)
        if steps <= planned:  # (a run without a step limit trains as long as it is let)
            return
        loop.epoch_loop.max_steps = int(steps)
        if loop.max_epochs not in (None, -1) and per_epoch and loop.max_epochs * per_epoch < steps:
            loop.max_epochs = -(-int(steps) // int(per_epoch))
        self._raised_steps = int(steps)
        timer = any(type(cb).__name__ == "Timer" for cb in self.trainer.callbacks)
        print(f"{what}: {steps} steps (model.residual_min_steps) instead of {int(planned)}"
              + (" (a max_time may end it first)" if timer else ""), flush=True)

    def _start_from_classical(self, dm) -> None:
        """``classical_start`` (the class docstring): the fit written into the model, reported in a line."""
        from ..data.import_tools import ordinal
        from ..identification.classical_start import STRIDE, can_start, start_from_classical

        wanted = self.hparams.get("classical_start", "auto")
        if wanted is False or self.hparams.get("init_from"):
            return
        reason = can_start(self.model)
        if reason is None and not (self.hparams.get("torque_weight", 0) > 0 and self.system.num_inputs):
            reason = "the model is not trained on torques (torque_weight 0 or a scene without inputs)"
        if reason is None and "train" not in dm.split_names():
            reason = "the data have no training split"
        if reason is not None:
            if wanted is True:
                raise InputError(f"classical_start: {reason}")
            return
        val = dm.trajectories("val") if "val" in dm.split_names() else None
        train = dm.trajectories("train")
        points = sum(train.valid_lengths())
        every = "every sample" if STRIDE == 1 else f"every {ordinal(STRIDE)} sample"
        print(f"classical start: least squares on {every} of {points} training samples"
              + (", its settings chosen on the validation split" if val is not None else "")
              + " (seconds to minutes for long recordings) ...", flush=True)
        with warnings.catch_warnings(record=True) as caught:  # each candidate fit warns of poor excitation: once
            warnings.simplefilter("always")
            self.classical_start = start_from_classical(self.model, self.system, train, val)
        _warn_once_of_excitation(caught)
        s = self.classical_start
        scores = s["validation_rms_mean"]
        chosen = "" if scores is None else (f", chosen on validation ({scores[format(s['prior'], 'g')]:.4g} N m there, "
                                            f"on {every})")
        form = s.get("form", s["drive"])
        form = form if form == s["drive"] else f"{form}, the form validation chose among {s['drive']} and its terms"
        method = s.get("method", "physically consistent")
        smoothing = s.get("smoothing_selection")
        if smoothing:
            configured = "" if s["coulomb_velocity"] != self.system.coulomb_velocity else ", as configured"
            smoothing = (f"; Coulomb smoothing {s['coulomb_velocity']:g} rad/s, chosen on validation among "
                         f"{', '.join(format(v, 'g') for v in smoothing)}{configured}")
        saturation = s.get("saturation_selection") if "saturating" in s.get("form", "") else None
        if saturation:
            saturation = (f"; saturating friction over {s['saturation_velocity']:g} rad/s, chosen on validation among "
                          f"{', '.join(format(v, 'g') for v in saturation)}")
        print(f"classical start: the {method} least-squares fit ({form}; prior {s['prior']:g}"
              f"{chosen}{smoothing or ''}{saturation or ''}; {s['fit_seconds']:.1f} s)")

    @property
    def selection_monitor(self) -> str | None:
        """The validation scalar ``callbacks.SelectOnValidation`` chooses the final state by (None: the last
        state is the end): the torque error, where the run started from a classical fit and has validation
        recordings (without them nothing judges the states)."""
        start = self.classical_start
        return "val/torque_rms" if start is not None and start.get("validation_rms_mean") is not None else None

    def validation_value(self, name: str) -> float:
        """A validation scalar (``val/<name>`` as validation logs it) of the current state, evaluated on
        the DataModule's validation split outside the validation loop (only the section it needs)."""
        from ..evaluation import evaluate_model

        dm = self.trainer.datamodule
        key = name.removeprefix("val/")
        sections = {"torque_rms": ("torques",), "torque_nrmse": ("torques",)}.get(key, ("accelerations",))
        result = evaluate_model(self.model, self.system, dm.trajectories("val"), sections=sections,
                                accel_stride=int(dm.hparams.eval_stride))
        return float(section_logs(result)[key])

    def validation_per_recording(self) -> list[float]:
        """Each validation entry's mean joint-torque RMS error (N m; every ``eval_stride``-th point) of the current
        state, as ``identify`` reports each recording: what ``callbacks.SelectOnValidation`` holds every state to
        against the start, entry by entry."""
        from ..data import points
        from ..identification.arm_comparison import model_torque, torque_errors

        dm = self.trainer.datamodule
        data, stride, torque = dm.trajectories("val"), int(dm.hparams.eval_stride), model_torque(self.model)
        out = []
        for j in range(len(data)):
            q, qd, qdd, tau, params = (x.to(self.device) for x in points(data.entry(j), stride))
            out.append(torque_errors(torque(q, qd, qdd, params), tau, range(tau.shape[1]))["rms_mean"])
        return out

    def configure_callbacks(self):
        return [SkipNonFiniteSteps(), DivergenceWatch(), HParamsSummary(), EvaluationFigures(), SelectOnValidation()]

    def on_fit_start(self) -> None:
        configure_cpu()  # flush denormals, keep freed tensors in the heap (lnn_torch.perf)

    def on_train_epoch_start(self) -> None:
        if hasattr(dm := getattr(self.trainer, "datamodule", None), "set_epoch"):
            dm.set_epoch(self.current_epoch)

    def configure_optimizers(self):
        hp = self.hparams
        trained = [p for p in self.parameters() if p.requires_grad]  # all but what train_only freezes
        precision = str(getattr(self._trainer, "precision", "32-true")) if self._trainer is not None else "32-true"
        return configure_optimizer(trained, self.model.coefficient_parameters(), lr=hp.lr, lr_min=hp.lr_min,
                                   weight_decay=hp.weight_decay, progress=lambda s: training_progress(self._trainer, s),
                                   fused="mixed" not in precision)  # (mixed precision clips unscaled gradients)

    # ------------------------------------------------------------------ training
    def training_terms(self, q, qd, qdd, params, tau=None, chunks=None) -> dict:
        """The eager training pass on flat SI tensors (``DynamicsModel.training_terms``; ``chunks``: as there)."""
        energy = self.hparams.energy_weight > 0 and ENERGY in self.model.capabilities
        return self.model.training_terms(q, qd, qdd, params, tau=tau, energy=energy, chunks=chunks,
                                         torque=self.hparams.get("torque_weight", 0) > 0)

    def batch_loss(self, batch: dict, pass_fn=None) -> tuple[torch.Tensor, dict]:
        """``(loss, parts)`` of one batch (``losses.acceleration_batch_loss`` or, for ``loss:
        trajectory``, ``losses.trajectory_batch_loss``) with this module's settings; ``pass_fn``:
        the training pass (default ``training_terms``, eager)."""
        hp = self.hparams
        if hp.get("loss", "acceleration") == "trajectory":
            return trajectory_batch_loss(self.model, batch, dt=self.data_dt, integrator=hp.trajectory_integrator,
                                         huber_delta=hp.huber_delta, velocity_weight=hp.trajectory_velocity_weight)
        return acceleration_batch_loss(self.model, batch, pass_fn or self.training_terms, huber_delta=hp.huber_delta,
                                       energy_weight=hp.energy_weight, torque_weight=hp.get("torque_weight", 0),
                                       dt=self.data_dt, acceleration_weight=hp.get("acceleration_weight", 1.0))

    def training_step(self, batch, batch_idx):
        self._last_batch = batch  # a failed compiled backward redoes it eagerly (``backward``)
        steps = self.trainer.estimated_stepping_batches if self._trainer is not None else 0
        pass_fn = self.training_pass.function(steps, self.device, _time_limit(self._trainer))
        loss, parts = self.batch_loss(batch, pass_fn)
        if writes_logs(self._trainer):
            if len(parts) > 1:  # one curve per term; a loss of one term is train/loss itself
                for name, value in parts.items():
                    self.log(f"train/{name}", value.detach(), on_step=True, on_epoch=False)
            self.log("train/loss", loss.detach(), on_step=True, on_epoch=False, prog_bar=True)
        return loss

    def backward(self, loss, *args, **kwargs) -> None:
        try:
            super().backward(loss, *args, **kwargs)
        except Exception as err:  # the compiled backward failed: warn once, redo this step eagerly
            if self._last_batch is None or not self.training_pass.backward_failed(err):
                raise
            self.zero_grad(set_to_none=True)
            super().backward(self.batch_loss(self._last_batch)[0], *args, **kwargs)

    # ------------------------------------------------------------------ evaluation
    def _evaluate(self, batch: dict, prefix: str) -> None:
        """``evaluation.evaluate_split`` of the split (the DataModule's one item), its scalars logged as
        ``{prefix}/...``; a validation's result with rollouts kept in ``evaluation`` for its figures
        (``callbacks.EvaluationFigures``). Every rank evaluates the same data (identical results)."""
        hp = self.hparams
        n = hp.val_rollouts if prefix == "val" else hp.get("test_rollouts", -1)
        result = evaluate_split(self.model, self.system, batch["trajectories"], num_rollouts=n,
                                seconds=hp.val_rollout_seconds, threshold=hp.val_threshold,
                                accel_stride=int(batch["accel_stride"]))
        for name, value in section_logs(result).items():
            self.log(f"{prefix}/{name}", float(value), batch_size=1, sync_dist=True, prog_bar=name == "acc_rel_err")
        if n != 0 and "horizon_s" in result and self.system.closed_form:  # a simulated scene's rollouts' length,
            # which their metrics depend on (evaluate's default is the whole trajectory: its energy drift and time
            # within the threshold differ from a test's); a measured one's run from many starts over their own
            self.log(f"{prefix}/rollout_horizon_s", float(result["horizon_s"]), batch_size=1, sync_dist=True)
        self.evaluation = result if prefix == "val" and self.system.closed_form and n != 0 else None

    def validation_step(self, batch, batch_idx):
        self._evaluate(batch, "val")

    def test_step(self, batch, batch_idx):
        self._evaluate(batch, "test")

    def predict_step(self, batch, batch_idx):
        """The model's accelerations at the test points under their recorded inputs (``tau`` of an actuated scene:
        they were left out), with ``valid`` marking the points of each recording (the rest pads shorter ones)."""
        tau = batch.get("tau") if self.system.num_inputs else None
        pred = model_accelerations(self.model, batch["q"], batch["qd"], batch["params"][:, 0], tau)
        out = {"trajectory": batch["trajectory"], "q": batch["q"], "qd": batch["qd"], "params": batch["params"][:, 0],
               "qdd_true": batch["qdd"], "qdd_pred": pred, "valid": torch.isfinite(batch["q"]).all(-1)}
        return out if tau is None else {**out, "tau": tau}


def _warn_once_of_excitation(caught) -> None:
    """Re-issue ``caught`` warnings, those of the classical start's candidate fits on poor excitation (one each, the
    condition numbers of their regressors) as one: the range of condition numbers and how many fits warned."""
    import re

    from ..errors import UntrustedParameterWarning

    poor = [w for w in caught if issubclass(w.category, UntrustedParameterWarning) and "excite the model poorly"
            in str(w.message)]
    seen = set()
    for w in caught:  # the others once each (every candidate fit raises the same), as Python's default filter shows
        key = (w.category, str(w.message))
        if w not in poor and key not in seen:
            seen.add(key)
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, module=__name__)
    if poor:
        found = [float(m.group(1)) for w in poor
                 if (m := re.search(r"condition number (inf|[0-9.e+-]+)", str(w.message)))]
        finite = [f for f in found if f < float("inf")]
        if not finite:
            numbers = "infinite: a regressor column is zero, e.g. a joint that never moves"
        else:
            numbers = f"{min(finite):.3g}" if len(set(finite)) == 1 else f"{min(finite):.3g} to {max(finite):.3g}"
            numbers += ", infinite in some" if len(finite) < len(found) else ""
        warnings.warn(f"classical start: the training recordings excite the model poorly (condition number {numbers} "
                      f"of the scaled regressor in {len(poor)} of its candidate fits): the base parameters are "
                      "uncertain; record a more exciting trajectory (lnn-torch identify lists what they determine)",
                      UntrustedParameterWarning, stacklevel=3)


def _time_limit(trainer) -> float | None:
    """The seconds a run may train (``--trainer.max_time``: Lightning's ``Timer``), or None."""
    from lightning.pytorch.callbacks import Timer

    timer = next((cb for cb in getattr(trainer, "callbacks", None) or () if isinstance(cb, Timer)), None)
    duration = getattr(timer, "_duration", None)
    return None if duration is None else float(duration)
