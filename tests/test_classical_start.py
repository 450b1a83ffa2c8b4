"""An arm grey box started from classical identification and floored by validation
(``lnn_torch.identification.classical_start``, ``LNNModule(classical_start=...)``,
``training.callbacks.SelectOnValidation``), on a recording of the Panda simulated by MuJoCo (its
description without the hand, armature and damping zero, as the real robot was logged): the started
model's inverse dynamics is the physically consistent fit's exactly (float64); the consistent fit's prior
is the one with the lowest validation error of those it tried; a training run whose gradient steps only
make validation worse ends with the start, its checkpoint saying so; without the classical start the
model starts at the description."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")
pytestmark = pytest.mark.slow  # a recording, its import and a short fit: about 30 s

from lnn_torch.data.importer import ImportSpec, import_recordings  # noqa: E402
from lnn_torch.data.trajectories import points  # noqa: E402
from lnn_torch.identification.classical_start import start_from_classical  # noqa: E402
from lnn_torch.training import LNNModule, TrajectoryDataModule  # noqa: E402
from lnn_torch.training.checkpoints import load_model  # noqa: E402

from .helpers import ROOT, cli_in_process  # noqa: E402
from .test_measured_arm import ROBOT, record  # noqa: E402

OPTIONS = {"kinetic": {"spatial": {"prior": 1.0e-4}}, "potential": {"spatial": {}},
           "friction": "viscous+coulomb+offset"}


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    root = tmp_path_factory.mktemp("classical_start")
    csv = record(root / "arm.csv", seconds=3.0)
    spec = ImportSpec(time="time", coordinates=[f"q{j}" for j in range(1, 8)],
                      velocities=[f"dq{j}" for j in range(1, 8)], inputs=[f"tau{j}" for j in range(1, 8)],
                      coord_names=[f"joint{j}" for j in range(1, 8)], robot=ROBOT, friction=True,
                      coulomb_velocity=0.02, label="synthetic_panda", torque_delay="off",
                      split={"train": ["arm[0.1:2.0]"], "val": ["arm[2.0:2.5]"], "test": ["arm[2.5:2.9]"]})
    return root, import_recordings([csv], root / "arm.h5", spec)


def test_the_started_model_is_the_consistent_fit_and_its_prior_was_chosen_on_validation(recording):
    _, path = recording
    dm = TrajectoryDataModule(path=str(path), targets="finite_difference")
    scene, config = dm.model_scene()
    module = LNNModule(scene=scene, scene_config=config, model_options=OPTIONS, torque_weight=1.0,
                       acceleration_weight=0.0, eps=0.0)
    model = module.model.double()
    model.fit_normalizer(dm.normalization_data())
    priors = (1e-4, 1e-2, 1.0, 100.0)
    report = start_from_classical(model, module.system, dm.trajectories("train"), dm.trajectories("val"),
                                  priors=priors)
    search, scores = report["prior_search"], report["validation_rms_mean"]
    # every prior given, and beyond the strongest or weakest where validation preferred it (classical_arm.EXTEND)
    given = {f"{p:g}" for p in priors}
    assert given <= set(search) and all(not min(priors) <= float(k) <= max(priors) for k in set(search) - given)
    assert report["prior"] == min((float(k) for k in scores), key=lambda k: scores[f"{k:g}"])
    # the friction form: the drive's terms and every form less one of them, the best on validation kept
    forms = report["form_selection"]
    assert set(forms) == {"viscous+coulomb+offset", "coulomb+offset", "viscous+offset", "viscous+coulomb"}
    # a term of the drive is dropped only where that validates better by more than FORM_MARGIN
    from lnn_torch.identification.classical_start import FORM_MARGIN

    better = {k: v for k, v in forms.items() if v < (1 - FORM_MARGIN) * forms["viscous+coulomb+offset"]}
    assert report["form"] == (min(better, key=better.get) if better else "viscous+coulomb+offset")
    # the rows' weighting: as recorded or per joint as weighted least squares, the better on validation
    weightings = report["weighting_selection"]
    assert set(weightings) == {"physically consistent", "weighted physically consistent"}
    assert report["method"] == min(weightings, key=weightings.get)
    # the fit again, as the start made it: the model's torques are its torques (to the 1e-6 of their unit at
    # which a friction coefficient the fit puts at zero starts)
    from lnn_torch.identification.arm_comparison import fit_classical

    full = report["form"] == "viscous+coulomb+offset"
    fits = fit_classical(module.system, dm.trajectories("train"), drive=report["form"],
                         methods=("least squares", "weighted least squares", report["method"]),
                         val=dm.trajectories("val"), prior=priors if full else report["prior"])
    fit = fits[f"{report['method']} + {report['form']}"]
    q, qd, qdd, tau, params = points(dm.trajectories("test"))
    with torch.no_grad():
        ours = model.inverse(q, qd, qdd, params)
    theirs = fit.inverse(q, qd, qdd, params)
    assert (ours - theirs).abs().max() <= 1e-5 * theirs.abs().max(), float((ours - theirs).abs().max())
    # the data are the engine's rigid body: the fit explains the held-out torques to a small fraction
    assert float((theirs - tau).pow(2).mean().sqrt() / tau.std()) < 0.05
    # the refinement's prior pulls towards the start: zero there
    assert float(model.part("kinetic", "spatial").regularization()) < 1e-6


def test_a_run_whose_steps_only_hurt_validation_ends_with_the_classical_start(recording):
    root, path = recording
    # a learning rate far too large: every step leaves the classical optimum
    out = cli_in_process("fit", "-c", str(ROOT / "configs" / "real_panda.yaml"), "--data.path", str(path),
                         "--trainer.max_steps", "20", "--data.steps_per_epoch", "10",
                         "--trainer.check_val_every_n_epoch", "1", "--model.lr", "0.3",
                         "--trainer.enable_progress_bar", "false", "--data.targets", "finite_difference",
                         "--model.val_rollout_seconds", "0.1", cwd=root)
    assert out.returncode == 0, out.stderr[-3000:]
    announced = (r"classical start: least squares on every 2nd sample of \d+ training samples, its settings chosen "
                 r"on the validation split")
    assert re.search(announced + r" .*\.\.\.\nclassical start: the (weighted )?physically consistent least-squares fit",
                     out.stdout)
    assert "selected on validation: the state at step 0 of 20" in out.stdout, out.stdout[-2000:]
    (ckpt,) = root.glob("lightning_logs/version_*/checkpoints/last.ckpt")
    saved = torch.load(ckpt, map_location="cpu", weights_only=False)
    assert saved["selection"]["step"] == 0 and len(saved["selection"]["history"]) == 3
    # the best checkpoint beside it is the best on what the selection judges (the torques), not on accelerations
    best = [p.name for p in ckpt.parent.glob("epoch*.ckpt")]
    assert best and all("-torque_rms" in name for name in best), best
    history = dict(saved["selection"]["history"])
    assert history[0] < min(history[10], history[20])
    module = load_model(str(ckpt))
    assert module.classical_start["prior"] > 0
    assert module.model.part("kinetic", "spatial").anchor_J() is not None
    # the checkpoint's torques are the start's: the fit of the training split with the chosen prior
    dm = TrajectoryDataModule(path=str(path), targets="finite_difference")
    q, qd, qdd, tau, params = points(dm.trajectories("val"))
    with torch.no_grad():
        error = (module.model.inverse(*(x.float() for x in (q, qd, qdd, params))).double() - tau)
    rms = float(error.pow(2).mean(0).sqrt().mean())
    np.testing.assert_allclose(rms, history[0], rtol=2e-2)


def test_without_the_classical_start_the_grey_box_starts_at_the_description(recording):
    _, path = recording
    dm = TrajectoryDataModule(path=str(path), targets="finite_difference")
    scene, config = dm.model_scene()
    module = LNNModule(scene=scene, scene_config=config, model_options=OPTIONS, torque_weight=1.0,
                       acceleration_weight=0.0, eps=0.0, classical_start=False)
    spatial = module.model.part("kinetic", "spatial")
    before = spatial.link_J().clone()
    module._start_from_classical(dm)
    assert module.classical_start is None and module.selection_monitor is None
    assert torch.equal(spatial.link_J(), before) and spatial.anchor_J() is None
    with pytest.raises(Exception, match="classical_start must be"):
        LNNModule(scene=scene, scene_config=config, model_options=OPTIONS, classical_start="sometimes")


def started(root, name: str, friction, options) -> tuple:
    """``(module, report, scene, config, datamodule)``: a 6 s recording of the arm whose drives have the
    friction torque ``friction(qd)`` (training 0.1-3.5 s, validation 3.5-5.9 s; the configured smoothing 20
    mrad/s), a model with ``options`` and its classical start."""
    csv = record(root / f"{name}.csv", seconds=6.0, friction=friction)
    spec = ImportSpec(time="time", coordinates=[f"q{j}" for j in range(1, 8)],
                      velocities=[f"dq{j}" for j in range(1, 8)], inputs=[f"tau{j}" for j in range(1, 8)],
                      coord_names=[f"joint{j}" for j in range(1, 8)], robot=ROBOT, friction=True,
                      coulomb_velocity=0.02, label="synthetic_panda", torque_delay="off",
                      split={"train": [f"{name}[0.1:3.5]"], "val": [f"{name}[3.5:5.9]"]})
    dm = TrajectoryDataModule(path=str(import_recordings([csv], root / f"{name}.h5", spec)),
                              targets="finite_difference")
    scene, config = dm.model_scene()
    module = LNNModule(scene=scene, scene_config=config, model_options=options, torque_weight=1.0,
                       acceleration_weight=0.0, eps=0.0)
    module.model.double().fit_normalizer(dm.normalization_data())
    report = start_from_classical(module.model, module.system, dm.trajectories("train"), dm.trajectories("val"))
    return module, report, scene, config, dm


def test_the_coulomb_smoothing_is_chosen_on_validation_and_travels_with_the_weights(tmp_path):
    """Drives whose Coulomb friction turns over within 4 mrad/s, recorded with the configured 20 mrad/s: the
    start takes the smoothing that validates best beyond chance (5 mrad/s of COULOMB_VELOCITIES), writes it
    into the model, and a model built from the scene's 20 mrad/s that loads the weights (a checkpoint's
    state, as ``lnn-torch test --ckpt_path`` loads it) has it too; the configured one, where the data have
    it, is kept."""
    from lnn_torch.identification.classical_start import COULOMB_VELOCITIES

    level = np.array([2.0, 2.5, 1.5, 1.5, 0.8, 0.6, 0.4])
    runs = {true: started(tmp_path, f"arm{true}", lambda qd, v=true: level * np.tanh(qd / v), OPTIONS)[:4]
            for true in (0.004, 0.02)}
    module, report, scene, config = runs[0.004]
    errors = report["smoothing_selection"]
    assert set(errors) == set(COULOMB_VELOCITIES) and min(errors, key=errors.get) == 0.005, errors
    assert report["coulomb_velocity"] == 0.005 and module.model.forces.drive.coulomb_velocity == 0.005
    rebuilt = LNNModule(scene=scene, scene_config=config, model_options=OPTIONS, torque_weight=1.0,
                        acceleration_weight=0.0, eps=0.0)
    assert rebuilt.model.forces.coulomb_velocity == 0.02  # the scene's, until the weights come
    rebuilt.load_state_dict(module.state_dict())
    assert rebuilt.model.forces.drive.coulomb_velocity == 0.005 and rebuilt.model.forces.stick_velocity == 0.0125
    older = {k: v for k, v in module.state_dict().items() if not k.endswith("coulomb_velocity_si")}
    rebuilt = LNNModule(scene=scene, scene_config=config, model_options=OPTIONS, torque_weight=1.0,
                        acceleration_weight=0.0, eps=0.0)
    rebuilt.load_state_dict(older)  # saved before the smoothing travelled: strict, and the scene's stands
    assert rebuilt.model.forces.coulomb_velocity == 0.02
    module, report, *_ = runs[0.02]
    assert report["coulomb_velocity"] == 0.02 and module.model.forces.coulomb_velocity == 0.02, report


def test_saturating_friction_is_kept_only_where_validation_asks_for_it_and_its_velocity_travels(tmp_path):
    """Drives whose friction rises over 0.2 rad/s beside the Coulomb step (gear drives, as the UR10 bag's), and
    drives without it, fitted with ``viscous+coulomb+offset+saturating``: where the data have it, the start keeps
    the saturating term (its form validates better than the form without it by more than FORM_MARGIN), at the
    velocity and Coulomb smoothing that validate best together (the drives' own: 0.2 rad/s and 20 mrad/s), and
    the model's friction law then follows the drives' over the recorded rates; the velocity is written into the
    model and
    a model built with the configured 0.1 rad/s that loads the weights has it; where the data lack it, the start
    drops the term, its coefficient at its floor."""
    from lnn_torch.identification.classical_start import FORM_MARGIN, SATURATION_VELOCITIES

    options = {**OPTIONS, "friction": "viscous+coulomb+offset+saturating"}
    level, rising = np.array([2.0, 2.5, 1.5, 1.5, 0.8, 0.6, 0.4]), np.array([3.0, 4.0, 2.0, 2.0, 1.0, 0.8, 0.5])
    laws = {"gears": lambda qd: level * np.tanh(qd / 0.02) + rising * np.tanh(qd / 0.2),
            "plain": lambda qd: level * np.tanh(qd / 0.02),
            # a term at 0.1 rad/s beside a Coulomb step smoothed over 0.05: least squares cannot tell it from a
            # Coulomb step over 0.1 beside a term at 0.05 (the same model); the start takes the saturating term
            # above the smoothing, every run (round-off took either)
            "swapped": lambda qd: level * np.tanh(qd / 0.05) + rising * np.tanh(qd / 0.1)}
    runs = {name: started(tmp_path, name, friction, options) for name, friction in laws.items()}
    module, report, scene, config, dm = runs["gears"]
    forms, errors = report["form_selection"], report["saturation_selection"]
    assert report["form"] == "viscous+coulomb+offset+saturating", report
    assert forms[report["form"]] < (1 - FORM_MARGIN) * forms["viscous+coulomb+offset"], forms
    assert set(errors) == set(SATURATION_VELOCITIES) and report["saturation_velocity"] == min(errors, key=errors.get)
    assert (report["coulomb_velocity"], report["saturation_velocity"]) == (0.02, 0.2), (report, errors)
    forces = module.model.forces
    assert forces.drive.saturation_velocity == report["saturation_velocity"]
    qd = points(dm.trajectories("val"), 2)[1].double()
    truth = torch.as_tensor(laws["gears"](qd.numpy()))
    law = forces.drive.torque(qd, forces.drive_coefficients(torch.zeros(1, 0, dtype=torch.float64)))
    assert (law - truth).pow(2).mean().sqrt() < 0.1 * truth.pow(2).mean().sqrt()
    for velocity in (report["saturation_velocity"], 0.2, 0.5):  # whatever validation chose: it travels
        forces.set_saturation_velocity(velocity)
        rebuilt = LNNModule(scene=scene, scene_config=config, model_options=options, torque_weight=1.0,
                            acceleration_weight=0.0, eps=0.0)
        assert rebuilt.model.forces.drive.saturation_velocity == 0.1  # the configured one, until the weights come
        rebuilt.load_state_dict(module.state_dict())
        assert rebuilt.model.forces.drive.saturation_velocity == velocity
    swapped = runs["swapped"][1]
    assert "saturating" in swapped["form"], swapped
    assert (swapped["coulomb_velocity"], swapped["saturation_velocity"]) == (0.05, 0.1), swapped
    module, report, scene, config, dm = runs["plain"]
    assert report["form"] == "viscous+coulomb+offset", report
    forces = module.model.forces
    d = forces.drive_coefficients(torch.zeros(1, 0, dtype=torch.float64))["d"]
    assert float(d.abs().max()) < 1e-5 * float(forces.units[1]) + 1e-12, d
    # the term left out stays out: the model's drive is the chosen form, and whatever gradient steps did to the
    # term's coefficient, it adds no torque (and so gets no gradient); a model built with the configured form
    # that loads the weights is the chosen form too
    assert forces.drive.forms == ("viscous", "coulomb", "offset") and report["drive"] == options["friction"]
    q, qd, qdd, tau, params = (x.double() for x in points(dm.trajectories("val"), 4))
    before = module.model.inverse(q, qd, qdd, params).detach()
    with torch.no_grad():
        forces.coefficients_raw[-7:] += 5.0  # saturating friction's d, the last block
    assert torch.equal(module.model.inverse(q, qd, qdd, params).detach(), before)
    rebuilt = LNNModule(scene=scene, scene_config=config, model_options=options, torque_weight=1.0,
                        acceleration_weight=0.0, eps=0.0)
    assert rebuilt.model.forces.drive.forms == ("viscous", "coulomb", "offset", "saturating")
    rebuilt.load_state_dict(module.state_dict())
    assert rebuilt.model.forces.drive.forms == ("viscous", "coulomb", "offset")
    # where the start keeps every configured term, so does the model
    assert runs["gears"][0].model.forces.drive.forms == ("viscous", "coulomb", "offset", "saturating")


def test_the_classical_fits_standard_errors_are_cluster_robust_over_the_blocks_given(recording):
    """``fit_classical(block=...)`` reaches the least-squares fits' covariance (``identify`` passes the filtered
    residuals' correlation time, as the tools' at import): over blocks the standard errors are wider than
    over single samples on data whose errors are correlated in time (the targets' finite differences)."""
    from lnn_torch.identification.arm_comparison import fit_classical

    _, path = recording
    dm = TrajectoryDataModule(path=str(path), targets={"method": "butterworth", "cutoff": 10.0, "order": 4,
                                                      "use_measured_velocity": True})
    scene, config = dm.model_scene()
    module = LNNModule(scene=scene, scene_config=config, model_options=OPTIONS, torque_weight=1.0,
                       acceleration_weight=0.0, eps=0.0)
    std = {}
    for block in (1, 25):
        fit = next(iter(fit_classical(module.system, dm.trajectories("train"), methods=("least squares",),
                                      block=block).values()))
        u = fit.info["uncertainty"]
        assert u["block_samples"] == block
        std[block] = torch.as_tensor(u["std"])
    assert float(torch.median(std[25] / std[1])) > 1.2, torch.median(std[25] / std[1])


def test_selection_takes_no_state_worse_than_the_start_on_a_validation_recording(capsys):
    """``SelectOnValidation``: a state better over all validation recordings but worse than the start on one of
    them is left out (and said so); a state better pooled and no worse on any is taken."""
    from types import SimpleNamespace

    from lnn_torch.training.callbacks import SelectOnValidation

    class Module:  # the module's face the callback reads: a state, each validation recording's error
        selection_monitor = "val/torque_rms"

        def __init__(self):
            self.weight, self.each, self.selection = torch.zeros(1), [1.0, 1.0], None

        def state_dict(self):
            return {"weight": self.weight}

        def load_state_dict(self, state):
            self.weight = state["weight"].clone()

        def validation_per_recording(self):
            return list(self.each)

        def validation_value(self, monitor):
            return sum(self.each) / len(self.each)

    module, select = Module(), SelectOnValidation()
    trainer = SimpleNamespace(global_step=0, sanity_checking=False, callback_metrics={}, is_global_zero=True,
                              callbacks=[])
    select.on_train_start(trainer, module)
    for step, each in ((10, [0.5, 1.1]), (20, [0.9, 0.95]), (30, [0.4, 1.01])):  # pooled 0.8, 0.925, 0.705
        module.weight, module.each, trainer.global_step = torch.full((1,), float(step)), each, step
        trainer.callback_metrics = {"val/torque_rms": torch.tensor(sum(each) / 2)}
        select.on_validation_end(trainer, module)
    select.on_train_end(trainer, module)
    assert module.selection["step"] == 20 and float(module.weight) == 20.0
    assert module.selection["left_out"] == [10, 30]
    assert "left out, better over all but worse than the start on a validation recording: steps 10, 30" in \
        capsys.readouterr().out
    # a resumed run goes on judging against the first run's start and best (its callback state travels)
    resumed = SelectOnValidation()
    resumed.load_state_dict(select.state_dict())
    module.each = [0.2, 1.0]  # the resumed state, better than the first start everywhere: no new start
    resumed.on_train_start(trainer, module)
    for step, each in ((40, [0.3, 1.05]), (50, [0.85, 0.9])):
        module.weight, module.each, trainer.global_step = torch.full((1,), float(step)), each, step
        trainer.callback_metrics = {"val/torque_rms": torch.tensor(sum(each) / 2)}
        resumed.on_validation_end(trainer, module)
    resumed.on_train_end(trainer, module)
    assert module.selection["step"] == 50 and module.selection["left_out"] == [10, 30, 40]


def test_a_choice_is_taken_only_where_it_validates_better_beyond_chance():
    """``classical_start._beyond_chance`` (the Coulomb smoothing's test): a gain that holds over the validation
    window's blocks passes, the same mean gain from one burst or from noise does not, and nor does a window too
    short to form the blocks."""
    from lnn_torch.identification.classical_start import CHANCE_BLOCKS, _beyond_chance

    rng = np.random.default_rng(0)
    default = torch.as_tensor(rng.uniform(0.5, 1.5, (400, 3)))
    assert _beyond_chance(default, 0.97 * default)  # 3 % lower everywhere
    assert not _beyond_chance(default, default)
    assert not _beyond_chance(default, 1.03 * default)  # worse
    burst = default.clone()
    burst[:20] *= 0.4  # the same 3 % mean gain, all of it in one block
    assert not _beyond_chance(default, burst)
    noisy = default * torch.as_tensor(rng.normal(1.0, 0.5, (400, 3)))  # lower or higher at random
    assert not _beyond_chance(default, noisy)
    short = default[: 2 * CHANCE_BLOCKS - 1]
    assert not _beyond_chance(short, 0.5 * short)


def test_the_classical_starts_warnings_of_poor_excitation_are_one():
    """Each candidate fit of the classical start warns of a poorly excited regressor (its own condition number):
    the fit says it once, with their range and count; other warnings pass as they were."""
    import warnings

    from lnn_torch.errors import UntrustedParameterWarning
    from lnn_torch.training.module import _warn_once_of_excitation

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for number in (1.07e3, 2.5e5, 1.5e7):
            warnings.warn(f"classical identification: the recordings excite the model poorly (condition number "
                          f"{number:.3g} of the scaled regressor, above 1000)", UntrustedParameterWarning,
                          stacklevel=1)
            warnings.warn("something else", UserWarning, stacklevel=1)  # (the same from every candidate fit)
    with warnings.catch_warnings(record=True) as again:
        warnings.simplefilter("always")
        _warn_once_of_excitation(caught)
    messages = [str(w.message) for w in again]
    assert len(messages) == 2 and "something else" in messages, messages
    poor = [m for m in messages if "excite" in m]
    assert poor == ["classical start: the training recordings excite the model poorly (condition number 1.07e+03 to "
                    "1.5e+07 of the scaled regressor in 3 of its candidate fits): the base parameters are uncertain; "
                    "record a more exciting trajectory (lnn-torch identify lists what they determine)"], poor
    # a zero regressor column (a joint that never moves) has an infinite condition number: said, not a crash
    for numbers, said in (((float("inf"),) * 2, "condition number infinite: a regressor column is zero"),
                          ((float("inf"), 2e3), "condition number 2e+03, infinite in some of the scaled")):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for number in numbers:
                warnings.warn(f"classical identification: the recordings excite the model poorly (condition number "
                              f"{number:.3g} of the scaled regressor, above 1000)", UntrustedParameterWarning,
                              stacklevel=1)
        with warnings.catch_warnings(record=True) as again:
            warnings.simplefilter("always")
            _warn_once_of_excitation(caught)
        assert len(again) == 1 and said in str(again[0].message), str(again[0].message)
