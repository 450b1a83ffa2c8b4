"""LightningCLI wiring: the data's scene is linked to the model (from the dataset file when it exists,
so that imported recordings declare their measured system; else from the data spec); inference mode
is off (the Euler-Lagrange solves differentiate with respect to their inputs even in evaluation)."""

from __future__ import annotations

import logging
import sys

from lightning.pytorch.cli import LightningCLI

from .datamodule import TrajectoryDataModule
from .module import LNNModule


class LNNCLI(LightningCLI):
    def parse_arguments(self, parser, args) -> None:
        """LightningCLI's parse, the command line kept (``before_fit`` reads its ``--data`` options). The model
        configures its own optimiser and schedule: ``--optimizer`` and ``--lr_scheduler`` are refused saying so
        (Lightning's replaced the whole optimisation, or did nothing without ``--optimizer``)."""
        self.argv = list(sys.argv[1:] if args is None else args) if not isinstance(args, dict) else []
        asked = next((a.split("=", 1)[0] for a in self.argv if a.split("=", 1)[0].split(".", 1)[0] in
                      ("--optimizer", "--lr_scheduler")), None)
        if asked:
            from ..errors import InputError

            raise InputError(f"{asked}: {OWN_OPTIMISER}")
        super().parse_arguments(parser, args)

    def _parse_ckpt_path(self) -> None:
        """Lightning reads a ``--ckpt_path`` checkpoint's hyper-parameters over the model's settings, the command
        line's too. A setting of how the model is judged (``EVALUATION``) that the command line or a config file
        gives is taken from it; any other (the model, its data link, its training) stays the checkpoint's: one the
        command line sets to another value is refused in one line, one a config file gives otherwise (resuming a
        fit) is said in a note (both were ignored without a word)."""
        sub = self.config.get("subcommand")
        if sub and self.config[sub].get("ckpt_path") == "last":
            self.config[sub]["ckpt_path"] = _last_checkpoint(self.config[sub])
        given = [] if not sub else list(dict.fromkeys(
            arg[len("--model."):].split("=", 1)[0].split(".", 1)[0] for arg in self.argv
            if arg.startswith("--model.")))
        model = self.config[sub].get("model") if sub else None
        # and a config file's (-c): its settings of how the model is judged, and on a resumed fit every setting it
        # gives (a test reads the checkpoint's model whatever the config says: a config's other settings are left)
        files = _config_model_keys(self.config[sub].get("config") or []) if sub else set()
        typed = set(given)
        given += [k for k in files if k not in given and (sub == "fit" or k in EVALUATION)]
        asked = {k: model.get(k) for k in given} if model is not None else {}
        super()._parse_ckpt_path()
        if not asked:
            return
        model = self.config[sub]["model"]
        advice = (": to train on with other settings, start a new run from its weights (--model.init_from "
                  "CHECKPOINT)" if sub == "fit" else "")
        for key, value in asked.items():
            stored = model.get(key)
            if key in EVALUATION or value == stored:
                model[key] = value
                continue
            if key not in typed:  # a config file's: said, not refused (the module rewrites some settings it
                if not _rewritten(key, value, stored):  # gives, e.g. a residual left out of model_options)
                    print(f"note: model.{key} {value!r} (a config file's) differs from the checkpoint's {stored!r}: "
                          f"a --ckpt_path run keeps the checkpoint's{advice}", flush=True)
                continue
            from ..errors import InputError

            raise InputError(f"--model.{key} {value!r}: the checkpoint's model has {stored!r}, and a --ckpt_path "
                             f"checkpoint keeps its model and training settings (only {', '.join(EVALUATION)} may "
                             f"change){advice}")

    def init_parser(self, **kwargs):
        """Lightning's parser, whose errors are the one line that says what is wrong (with the option nearest a
        misspelt one) and the pointer to ``--help``, not the 90 lines of usage before them."""
        parser = super().init_parser(**kwargs)
        parser.print_usage = lambda file=None: None
        error = parser.error

        def with_suggestion(message, ex=None):
            return error(message + _nearest_option(parser, message), ex)

        parser.error = with_suggestion
        return parser

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data", "model.scene", apply_on="instantiate", compute_fn=lambda dm: dm.model_scene()[0])
        parser.link_arguments("data", "model.scene_config", apply_on="instantiate",
                              compute_fn=lambda dm: dm.model_scene()[1])
        parser.set_defaults({"trainer.logger": LOGGER, "trainer.callbacks": CALLBACKS})

    def before_instantiate_classes(self) -> None:
        """``--trainer.default_root_dir DIR`` moves the default TensorBoard logger (and so the
        checkpoints, which go under the logger's folder) to DIR, as Lightning's own default logger
        would; a logger given its own ``save_dir`` keeps it. A ``--ckpt_path`` checkpoint's compiled robot
        descriptions are registered first (the model is built before its weights load)."""
        config = self.config[self.subcommand] if self.subcommand else self.config
        register_description_copies(config.get("ckpt_path"))
        trainer = config.get("trainer")
        chosen = next((k for k in ("optimizer", "lr_scheduler") if config.get(k)), None)
        if chosen:  # (a config file's; the command line's is refused as it is parsed)
            from ..errors import InputError

            raise InputError(f"{chosen}: {OWN_OPTIMISER}")
        every = trainer.get("check_val_every_n_epoch") if trainer is not None else None
        if every is not None and (isinstance(every, bool) or not isinstance(every, int) or every < 1):
            from ..errors import InputError  # (Lightning divided by it, a ZeroDivisionError after the model summary)

            raise InputError(f"--trainer.check_val_every_n_epoch must be a whole number >= 1 (or null), got {every!r}")
        root = trainer.get("default_root_dir") if trainer is not None else None
        logger = trainer.get("logger") if trainer is not None else None
        if not root or logger is None or isinstance(logger, (bool, list)):
            return
        init = logger.get("init_args") if hasattr(logger, "get") else None
        if logger.get("class_path") == LOGGER["class_path"] and init is not None and init.get("save_dir") == ".":
            init["save_dir"] = str(root)

    def before_fit(self) -> None:
        """The fit's closing summary names the config files it was given and the data options the command line
        set beside them (``--data.path``, ...: its ``test`` command reads the same data); a resumed fit's model
        knows it is one (``LNNModule.resuming``)."""
        config = self.config[self.subcommand] if self.subcommand else self.config
        if config.get("ckpt_path") and hasattr(self.model, "resuming"):  # no classical start nor residual judging
            self.model.resuming = True
            _resumed_on(config.get("ckpt_path"), self.model, self.datamodule)
        paths = [str(getattr(p, "relative", p)) for p in (config.get("config") or [])]
        for cb in self.trainer.callbacks:
            if type(cb).__name__ == "FitSummary":
                cb.config_paths = paths
                cb.data_options = data_options(self.argv)


def _resumed_on(ckpt_path, model, datamodule) -> None:
    """A resumed fit on data of another scene than its checkpoint's model is refused in one line (the model built
    for the data could not take the checkpoint's weights: a list of size mismatches); on another file of the same
    scene a note says which."""
    from pathlib import Path

    from ..errors import InputError
    from .checkpoint_format import DATA_PATH, read_checkpoint

    if not Path(str(ckpt_path)).is_file():
        return
    ckpt = read_checkpoint(ckpt_path)
    theirs, ours = ckpt.get("hyper_parameters", {}), model.hparams
    dof = lambda h: (h.get("scene_config") or {}).get("dof")  # noqa: E731  (a measured system's coordinates)
    if theirs.get("scene") != ours.get("scene") or dof(theirs) != dof(ours):
        raise InputError(f"--ckpt_path {ckpt_path}: a model of scene '{theirs.get('scene')}'"
                         + (f" of {dof(theirs)} coordinates" if theirs.get("scene") == ours.get("scene") else "")
                         + f", and the data ({getattr(datamodule, 'path', '?')}) hold '{ours.get('scene')}': resume on "
                         "its own data, or start a new run from its weights (--model.init_from) where they fit")
    trained = ckpt.get(DATA_PATH)
    here = getattr(datamodule, "path", None)
    if trained and here is not None and Path(here).resolve() != Path(trained):
        print(f"note: resuming on {here}; the checkpoint was trained on {trained}", flush=True)


def _rewritten(key: str, given, stored) -> bool:
    """Whether the checkpoint's ``stored`` value of model setting ``key`` is the config's ``given`` as the module
    rewrites it when it builds the model: a force residual left out of ``model_options`` (``learn_residual``)."""
    if key != "model_options" or not isinstance(given, dict) or not isinstance(stored, dict):
        return False
    return {k: v for k, v in given.items() if k != "residual_force"} == \
        {k: v for k, v in stored.items() if k != "residual_force"}


def _config_model_keys(paths) -> set[str]:
    """The model settings (``model: {key: ...}``) the config files ``paths`` (``-c``) give."""
    from pathlib import Path

    import yaml

    keys = set()
    for path in paths:
        try:
            text = yaml.safe_load(Path(str(getattr(path, "absolute", path))).read_text()) or {}
        except (OSError, yaml.YAMLError):
            continue
        model = text.get("model") if isinstance(text, dict) else None
        if isinstance(model, dict):
            keys |= set((model.get("init_args") if isinstance(model.get("init_args"), dict) else model).keys())
    return keys - {"class_path", "init_args"}


def _last_checkpoint(config) -> str:
    """``--ckpt_path last``: the newest run's ``last.ckpt`` (``callbacks.LastCheckpoint``) under the run folders
    of the default logger (``<default_root_dir or save_dir>/<name>/<version>/checkpoints``); Lightning looks for
    its own ``save_last`` file, which these runs do not write, and started afresh without a word."""
    from pathlib import Path

    from ..errors import InputError

    trainer = config.get("trainer") or {}
    logger = trainer.get("logger")
    init = (logger.get("init_args") if hasattr(logger, "get") else None) or {}
    root = Path(init.get("save_dir") or ".")
    if str(root) == "." and trainer.get("default_root_dir"):
        root = Path(trainer.get("default_root_dir"))
    runs = root / (init.get("name") or "lightning_logs")
    found = [p for p in runs.glob("*/checkpoints/last.ckpt")]  # (version_N, or a logger's own version name)
    if not found:
        raise InputError(f"--ckpt_path last: no last.ckpt in {runs}/*/checkpoints (a fit writes one at the end "
                         "of every epoch, and when interrupted): give the checkpoint's path")
    latest = max(found, key=lambda p: p.stat().st_mtime)  # (the run written last)
    print(f"--ckpt_path last: {latest}", flush=True)
    return str(latest)


OWN_OPTIMISER = ("the model configures its own optimiser (AdamW, a cosine schedule per step from model.lr to "
                 "model.lr_min, no weight decay on physical coefficients): set --model.lr, --model.lr_min, "
                 "--model.weight_decay")

# the model's settings of how it is judged (validation and test rollouts, the threshold of the time within it, figures,
# compilation): a --ckpt_path command line may set them (every other setting is the checkpoint's)
EVALUATION = ("val_rollouts", "val_rollout_seconds", "test_rollouts", "val_threshold", "figure_every_n_epochs",
              "compile")
TRAINER_DEFAULTS = {"inference_mode": False, "gradient_clip_val": 1.0}
LOGGER = {"class_path": "lightning.pytorch.loggers.TensorBoardLogger",
          "init_args": {"save_dir": ".", "name": "lightning_logs", "default_hp_metric": False}}
CALLBACKS = [
    {"class_path": "lnn_torch.training.callbacks.BestCheckpoint",
     # saved when validation ends, so before LastCheckpoint's last.ckpt at the epoch's end (Lightning runs
     # checkpoint callbacks after the others: at the epoch's end last.ckpt held the best checkpoint before this one)
     "init_args": {"monitor": "val/acc_rel_err", "mode": "min", "save_on_train_epoch_end": False,
                   "filename": "epoch{epoch}-err{val/acc_rel_err:.4f}", "auto_insert_metric_name": False}},
    {"class_path": "lnn_torch.training.callbacks.LastCheckpoint"},
    {"class_path": "lnn_torch.training.callbacks.PredictionWriter"},
    {"class_path": "lnn_torch.training.callbacks.TestMetricsWriter"},
    {"class_path": "lnn_torch.training.callbacks.FitSummary"},
]


def _instantiate(spec: dict):
    """An object from a LightningCLI ``{"class_path": ..., "init_args": {...}}`` dict."""
    import importlib

    module, _, name = spec["class_path"].rpartition(".")
    return getattr(importlib.import_module(module), name)(**spec.get("init_args", {}))


def make_trainer(**overrides):
    """A ``lightning.Trainer`` as ``lnn-torch fit`` builds it: the CLI's trainer defaults
    (``TRAINER_DEFAULTS``: gradient clipping at 1.0, inference mode off), its TensorBoard logger and its
    callbacks (best and last checkpoints, prediction and test-metric writers, the fit summary), with
    ``overrides`` (any ``Trainer`` argument: ``max_steps``, ``logger=False``, ``callbacks=[...]``,
    ``enable_progress_bar``...) taking precedence. Scripts and studies train through it, so that a
    study's model is trained as a user's is. Lightning's notes that the command line leaves out are left out
    here too (``quiet_third_parties``)."""
    import lightning as L

    quiet_third_parties()  # as the command line: no advertisements, no note at every checkpoint written
    kwargs = {**TRAINER_DEFAULTS, "logger": None, "callbacks": None, **overrides}
    if kwargs["logger"] is None:  # under default_root_dir where one is given, as the command line puts it
        root = kwargs.get("default_root_dir")
        kwargs["logger"] = _instantiate(LOGGER if root is None else
                                        {**LOGGER, "init_args": {**LOGGER["init_args"], "save_dir": str(root)}})
    if kwargs["callbacks"] is None:
        kwargs["callbacks"] = [_instantiate(spec) for spec in CALLBACKS]
    return L.Trainer(**kwargs)


class _DropLightningTips(logging.Filter):
    """Lightning's advertisements for its cloud services ("Tip: ... try installing litlogger") and its
    note at every checkpoint written ("`weights_only` was not set"): nothing a user of this command can
    act on."""

    NOISE = ("💡 Tip:", "`weights_only` was not set")

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        return not any(text in message for text in self.NOISE)


def quiet_third_parties() -> None:
    """Silence what the user cannot act on, in the package's own commands only: Lightning's tips and
    its use of a torch pytree API that torch deprecated (warned at every fit)."""
    import warnings

    for name in ("lightning.pytorch.utilities.rank_zero", "lightning.pytorch.trainer.connectors.checkpoint_connector"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, _DropLightningTips) for f in logger.filters):
            logger.addFilter(_DropLightningTips())
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\)` is deprecated",
                            module=r"lightning\.pytorch\.utilities\._pytree")
    # `lnn-torch test --ckpt_path` starts a new run folder: Lightning's note that the checkpoint
    # folder changed is about resuming, which testing does not do
    warnings.filterwarnings("ignore", message=r"The dirpath has changed from")
    # a compiled solve without a native kernel runs through a fallback: correct, nothing to act on
    logging.getLogger("torch._inductor.ir").setLevel(logging.ERROR)


def _nearest_option(parser, message: str) -> str:
    """``" (did you mean --model.hidden_dims?)"`` for the first option of ``message`` (an unrecognised
    ``--model.hiden_dims`` on the command line, or ``'model.hiden_dims'`` from a config file) that is close to one
    the command (``message``'s subcommand, else ``parser``) takes; empty where none is."""
    import difflib
    import re

    match = re.search(r"--([\w.]+)|option '([\w.]+)'", message)
    if match is None:
        return ""
    wanted = match.group(1) or match.group(2)
    sub = re.search(r"Subcommand '(\w+)'", message)
    target = parser
    if sub is not None:
        target = next((p for a in parser._actions for name, p in (getattr(a, "choices", None) or {}).items()
                       if name == sub.group(1) and hasattr(p, "_option_string_actions")), parser)
    known = [o[2:] for o in getattr(target, "_option_string_actions", {}) if o.startswith("--")]
    close = difflib.get_close_matches(wanted, known, n=1, cutoff=0.8)
    return f" (did you mean --{close[0]}?)" if close else ""


def data_options(argv: list[str]) -> list[str]:
    """The ``--data`` and ``--data.*`` options of a command line (a data config file, single settings) and its
    ``--trainer.default_root_dir`` (a test's run then goes beside the fit's), each as one ``--NAME=VALUE``
    (quoted for a shell where needed)."""
    import shlex

    out = []
    for i, arg in enumerate(argv):
        if not (arg.startswith("--data.") or arg == "--data" or arg.startswith("--data=")
                or arg.split("=", 1)[0] == "--trainer.default_root_dir"):
            continue
        if "=" in arg:
            name, value = arg.split("=", 1)
        elif i + 1 < len(argv) and not argv[i + 1].startswith("--"):
            name, value = arg, argv[i + 1]
        else:
            continue
        out.append(f"{name}={shlex.quote(value)}")
    return out


def run_cli(argv: list[str]) -> LNNCLI:
    quiet_third_parties()
    # from the console script argv is sys.argv[1:]: let LightningCLI read it itself (given both, it warns)
    args = None if argv == sys.argv[1:] else argv
    return LNNCLI(LNNModule, TrajectoryDataModule, args=args, trainer_defaults=TRAINER_DEFAULTS,
                  save_config_kwargs={"overwrite": True}, seed_everything_default=0)


def register_description_copies(ckpt_path) -> None:
    """The compiled robot descriptions a checkpoint given as ``--ckpt_path`` carries, for the model the CLI
    builds before loading its weights (``robots.description.register_copies``); ``best`` and other names
    Lightning resolves itself are left to it (``last`` is resolved before: ``_last_checkpoint``)."""
    from pathlib import Path

    if ckpt_path and Path(str(ckpt_path)).is_file():
        from .checkpoints import read_with_descriptions

        read_with_descriptions(ckpt_path)
