"""The one evaluation pipeline, the model registry and the scene-owned cases."""

import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch

import lnn_torch
from lnn_torch.data import DatasetSpec, Trajectories, generate_dataset, read_dataset
from lnn_torch.evaluation import SECTIONS, ClosedForm, evaluate_model, section
from lnn_torch.ground_truth import reference_rollout
from lnn_torch.networks import MODELS, VARIANTS, build_model, model_options
from lnn_torch.systems import InputError, get_system

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def trajectories(tmp_path_factory):
    path = generate_dataset(DatasetSpec(num_trajectories=20, duration=2.0, seed=4), tmp_path_factory.mktemp("d") / "d.h5")
    return read_dataset(path).trajectories("train")


def test_closed_form_through_the_pipeline_is_exact(trajectories):
    """The scene's own dynamics through evaluate_model: zero acceleration error, no divergence over
    the horizon, energy drift at the integrator's level; a coarser and a finer step than the data's
    are compared on the data's grid."""
    system = get_system("double_pendulum")
    for dt, drift_bound in ((0.005, 1e-6), (0.01, 1e-5), (0.001, 1e-8)):
        r = evaluate_model(ClosedForm(system), system, trajectories, integrator="rk4", dt=dt, horizon=1.0)
        assert r["acc_rel_err"]["total"] == 0 and r["acc_rel_err"]["non_finite_fraction"] == 0
        assert r["divergence_time@0.1"]["model"]["q25"] == pytest.approx(1.0)
        assert r["energy_drift"]["max"] < drift_bound, (dt, r["energy_drift"])  # measured 1e-8 / 2e-7 / 3e-12
        assert r["_arrays"]["q_model"].shape == (len(trajectories), 201 if dt < 0.01 else 101, 2)
        assert r["horizon_s"] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="not multiples"):
        evaluate_model(ClosedForm(system), system, trajectories, dt=0.0075)


def test_a_wrong_model_is_measured_as_wrong(trajectories):
    """A model with the lengths 10 % off has a clear acceleration error and diverges."""
    system = get_system("double_pendulum")

    class Off(ClosedForm):
        def acceleration(self, q, qd, params, tau=None, check=False):
            return system.acceleration(q, qd, params * torch.tensor([1.0, 1.0, 1.1, 1.1], dtype=params.dtype))

        def rollout(self, q0, qd0, params, dt, num_steps, method="rk4", tau=None):
            return lnn_torch.rollout(self.acceleration, q0, qd0, params, dt, num_steps, method)

    r = evaluate_model(Off(system), system, trajectories, horizon=2.0, sections=("accelerations", "rollouts"))
    assert 0.03 < r["acc_rel_err"]["total"] < 0.2
    assert r["divergence_time@0.1"]["model"]["median"] < 2.0


def test_predictability_uses_the_exact_reference(trajectories):
    system = get_system("double_pendulum")
    r = evaluate_model(ClosedForm(system), system, trajectories.head(4), sections=("rollouts", "predictability"),
                       horizon=2.0, perturbation=1e-6)
    assert r["divergence_time@0.1"]["exact_perturbed"]["median"] == pytest.approx(2.0)  # 1e-6 off stays close
    q, _ = reference_rollout(system, trajectories.q[:4, 0], trajectories.qd[:4, 0], trajectories.params[:4], 0.005, 400)
    torch.testing.assert_close(q, trajectories.q[:4], rtol=0, atol=1e-8)  # the same ground truth as the data


def test_a_new_metric_is_one_function_and_one_line(trajectories):
    system = get_system("double_pendulum")

    @section("max_speed")
    def max_speed(ctx):
        return {"max_speed": float(ctx.rollouts()["qd"].abs().max())}

    try:
        r = evaluate_model(ClosedForm(system), system, trajectories, sections=("rollouts", "max_speed"), horizon=0.5)
        assert r["max_speed"] == pytest.approx(float(trajectories.qd[:, :101].abs().max()), rel=1e-6)
    finally:
        SECTIONS.pop("max_speed")
    with pytest.raises(ValueError, match="unknown evaluation sections"):
        evaluate_model(ClosedForm(system), system, trajectories, sections=("max_speed",))


def test_validation_logs_what_evaluate_model_computes(tmp_path):
    """The LightningModule's validation is evaluate_model on the val split: the same numbers."""
    import lightning as L

    from lnn_torch import LNNModule, TrajectoryDataModule

    spec = dict(num_trajectories=12, duration=1.0, seed=2)
    dm = TrajectoryDataModule(path=str(tmp_path / "d.h5"), spec=spec, chunk_len=8, chunks_per_batch=4,
                              steps_per_epoch=3, eval_stride=5)
    model = LNNModule(hidden_dims=[8, 8], val_rollouts=1, val_rollout_seconds=0.5, val_threshold=0.2)
    trainer = L.Trainer(max_epochs=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, inference_mode=False, num_sanity_val_steps=0)
    trainer.fit(model, dm)
    logged = trainer.validate(model, dm, verbose=False)[0]
    r = evaluate_model(model.model, model.system, dm.trajectories("val"), horizon=0.5, thresholds=(0.2,),
                       accel_stride=5, num_rollouts=1)
    assert logged["val/acc_rel_err"] == pytest.approx(r["acc_rel_err"]["total"], rel=1e-6)
    assert logged["val/acc_rel_err_theta2"] == pytest.approx(r["acc_rel_err"]["theta2"], rel=1e-6)
    assert logged["val/energy_drift"] == pytest.approx(r["energy_drift"]["mean"], rel=1e-6)
    assert logged["val/divergence_time"] == pytest.approx(r["divergence_time@0.2"]["model"]["median"], rel=1e-6)


# ---------------------------------------------------------------------------- registry
def test_registry_maps_every_variant_and_each_class_declares_its_defaults():
    assert set(VARIANTS) == set(MODELS) == {"film_lnn", "delan", "lnn", "mlp", "hnn"}
    for name, cls in MODELS.items():
        assert cls.variant == name
        assert "hidden_dims" in model_options(name) and "activation" in model_options(name)
    assert model_options("lnn")["activation"] == "softplus" and model_options("film_lnn")["activation"] == "tanh"
    system = get_system("pendulum")
    assert build_model("film_lnn", system, film_mode="layer").kinetic["mlp"].film.mode == "layer"
    with pytest.raises(InputError, match="model variant 'mlp' takes no option 'film_mode'"):
        build_model("mlp", system, film_mode="layer")
    with pytest.raises(InputError, match="unknown model variant 'hnnn'"):
        build_model("hnnn", system)


def test_module_refuses_an_option_its_variant_does_not_take_but_loads_old_checkpoints():
    from lnn_torch import LNNModule

    with pytest.raises(InputError, match="takes no option 'hnn_coordinates'"):
        LNNModule(variant="mlp", hnn_coordinates="velocity", hidden_dims=[8])
    # older checkpoints record every option with its old default for every variant: still loads
    old = dict(variant="mlp", hidden_dims=[8], film_mode="neuron", potential_film=True, eps=1e-4, lnn_init=False,
               hnn_coordinates="canonical")
    assert LNNModule(**old).model.variant == "mlp"


def test_shared_network_option_travels_with_the_module_hyperparameters():
    from lnn_torch import LNNModule

    module = LNNModule(hidden_dims=[8, 8], model_options={"shared": True})
    assert module.model.shared and list(module.model.kinetic) == ["shared"] and module.model.kinetic["shared"].film
    rebuilt = LNNModule(**module.hparams)
    rebuilt.load_state_dict(module.state_dict())  # same parameters, same names
    assert rebuilt.model.shared
    assert not LNNModule(hidden_dims=[8, 8]).model.shared  # off by default


# ---------------------------------------------------------------------------- scenes own their cases
def test_generic_modules_name_no_scene():
    """Evaluation, stability and plots take cases, drawings and time steps from the scene and the
    data: no scene names, and no fixed dof or time step in them."""
    for module in ("evaluation.py", "stability.py", "plots.py", "metrics.py", "commands/evaluate.py"):
        text = (ROOT / "lnn_torch" / module).read_text()
        for name in ("double_pendulum", "chain_pendulum", "mass_spring", "relativistic", "OOD_CASES",
                     "reshape(-1, 2)", "m2/m1"):
            assert name not in text, (module, name)
        assert not re.search(r"\bdt = 0\.005\b", text), module


def test_scenes_own_their_cases():
    dp, chain = get_system("double_pendulum"), get_system("chain_pendulum", num_links=4)
    assert len(dp.ood_cases()) == 4 and chain.ood_cases() == []
    assert set(dp.hard_parameter_cases()) == {"m2/m1 = 1e-3", "m2/m1 = 1e3", "l2/l1 = 0.1", "l2/l1 = 10"}
    from lnn_torch.stability import hard_cases

    names = {c.name for c in hard_cases(chain, num=2)}
    assert "parameters x10" in names and not any("m2/m1" in n for n in names)
    assert get_system("mass_spring").positions(torch.zeros(1, 1), torch.ones(1, 2)) is None


def test_chain_pendulum_is_drawn_with_all_its_links():
    from lnn_torch.plots import frames_figure

    chain = get_system("chain_pendulum", num_links=4)
    rng = np.random.default_rng(0)
    params = torch.tensor(chain.sample_params(rng, 1))[0]
    q = torch.tensor(rng.uniform(-1, 1, (10, 4)))
    fig = frames_figure(chain, q, q + 0.1, params, 0.01, num_frames=3)
    lines = fig.axes[0].get_lines()
    assert len(lines) == 2 and all(len(line.get_xdata()) == 5 for line in lines)  # origin + 4 bodies
    xy = chain.positions(q[:1], params[None])[0]
    np.testing.assert_allclose(lines[0].get_xdata()[1:], xy[:, 0].numpy())
    assert frames_figure(get_system("mass_spring"), q[:, :1], q[:, :1], torch.ones(2), 0.01) is None


def test_trajectories_container_checks_its_shapes():
    q = torch.zeros(2, 5, 2)
    with pytest.raises(ValueError, match="shapes differ"):
        Trajectories(q, torch.zeros(2, 4, 2), torch.ones(2, 4), 0.01)
    with pytest.raises(ValueError, match="params must be"):
        Trajectories(q, q, torch.ones(3, 4), 0.01)
    t = Trajectories(q, q, torch.ones(2, 4), 0.01, index=torch.tensor([3, 7]))
    assert len(t.head(1)) == 1 and t.to(torch.float32).index.dtype == torch.long and math.isclose(t.dt, 0.01)
