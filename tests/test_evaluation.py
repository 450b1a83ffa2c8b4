"""The one evaluation pipeline (``lnn_torch.evaluation``): exact for the closed form, a wrong model measured
as wrong, registered sections, what validation logs. The registry: test_registry.py; the cases and
drawings scenes own: test_systems.py."""


import pytest
import torch

import lnn_torch
from lnn_torch.data import DatasetSpec, generate_dataset, read_dataset
from lnn_torch.evaluation import REPORT_SECTIONS, SECTIONS, evaluate_model, report_sections, section
from lnn_torch.systems import get_system
from lnn_torch.systems.ground_truth import ClosedForm, reference_rollout


@pytest.fixture(scope="module")
def trajectories(tmp_path_factory):
    path = generate_dataset(DatasetSpec(num_trajectories=20, duration=2.0, seed=4),
                            tmp_path_factory.mktemp("d") / "d.h5")
    return read_dataset(path).trajectories("train")


def test_a_non_finite_prediction_is_an_infinite_error():
    """A model whose predictions are NaN (every one, or some) must not score well: the totals are infinite, each
    trajectory holding one too, and the fraction of such points is counted; padding (NaN targets) is no point."""
    from lnn_torch.evaluation.metrics import acceleration_errors

    true = torch.randn(4, 10, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    true[3, 7:] = float("nan")  # a shorter recording's padding
    exact = acceleration_errors(true.clone(), true)
    assert exact["total"] == 0 and exact["per_trajectory_median"] == 0 and exact["non_finite_fraction"] == 0
    nan = acceleration_errors(torch.full_like(true, float("nan")), true)
    assert nan["total"] == nan["q0"] == nan["per_trajectory_median"] == float("inf")
    assert nan["non_finite_fraction"] == 1.0
    some = true.clone()
    some[0, 2, 1] = float("nan")
    one = acceleration_errors(some, true)
    assert one["total"] == float("inf") and one["per_trajectory_median"] == 0
    assert one["per_trajectory_p90"] == float("inf") and one["non_finite_fraction"] == pytest.approx(1 / 37)


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
    with pytest.raises(ValueError, match=r"^dt must be a positive step in s, got -0.01$"):  # (not "not multiples")
        evaluate_model(ClosedForm(system), system, trajectories, dt=-0.01)


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
    assert logged["val/rollout_horizon_s"] == pytest.approx(r["horizon_s"]) == pytest.approx(0.5)  # (their length)


# ---------------------------------------------------------------------------- registry
def test_the_report_order_is_the_registration_order():
    """The package registers its sections module by module (accelerations, rollouts, structure,
    horizons, cases, regimes): the report keeps its order, the regimes last."""
    assert report_sections() == REPORT_SECTIONS == (
        "accelerations", "rollouts", "energy", "predictability", "mass_matrix", "torques", "friction", "free_decay",
        "horizons", "ood", "stability", "regimes")
    assert tuple(SECTIONS)[: len(REPORT_SECTIONS)] == REPORT_SECTIONS


def test_the_evaluation_package_exports_only_its_own_names():
    """One name, one home: ``lnn_torch.evaluation`` exports what its modules define (the metrics, the
    report helpers, the sections' registry, the pipeline), no other package's names under a second path."""
    import inspect

    import lnn_torch.evaluation as evaluation

    for name in evaluation.__all__:
        value = getattr(evaluation, name)
        if inspect.isfunction(value) or inspect.isclass(value):
            assert value.__module__.startswith("lnn_torch.evaluation"), (name, value.__module__)
    assert not hasattr(evaluation, "ClosedForm")  # the scene's exact reference: lnn_torch.systems
    for name in ("DEFAULT_SECTIONS", "EvalContext", "SectionResult", "section_logs", "skip", "Trajectories"):
        assert hasattr(evaluation, name), name
    assert set(evaluation.__all__) <= set(dir(evaluation))


def test_importing_the_evaluation_loads_no_matplotlib():
    """The sections name their figures in ``lnn_torch.evaluation.plots``; matplotlib is imported only when a
    figure is drawn (physics-only users and training without a logger never load it)."""
    import subprocess
    import sys

    code = ("import sys, lnn_torch.evaluation, lnn_torch.evaluation.stability, lnn_torch.evaluation.plots; "
            "assert 'matplotlib' not in sys.modules, 'matplotlib imported'; "
            "from lnn_torch.evaluation.plots import plt; assert plt.get_backend().lower() == 'agg'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_evaluation_plots_and_stability_do_not_import_each_other_in_a_circle():
    """``plots``, ``stability``, ``metrics`` and ``report`` serve the evaluation's sections and import
    none of them, nor the package's ``__init__`` (the cycle evaluation <-> plots <-> stability is gone)."""
    import ast
    from pathlib import Path

    root = Path(lnn_torch.__file__).parent / "evaluation"
    sections = {"registry", "cases", "rollouts", "structure", "horizons", "accelerations", ""}
    for module in ("plots.py", "stability.py", "metrics.py", "report.py"):
        tree = ast.parse((root / module).read_text())
        imported = {node.module or "" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
        imported |= {a.name for node in ast.walk(tree) if isinstance(node, ast.Import) for a in node.names}
        assert not any("evaluation" in name for name in imported), (module, imported)
        assert not sections & {name.lstrip(".") for name in imported if name.startswith(".") and
                               not name.startswith("..")}, (module, imported)
        assert not ({"stability", "plots"} - {module[:-3]}) & {name.lstrip(".") for name in imported}, module


# ---------------------------------------------------------------------------- scenes own their cases


class _Measured:
    """A scene seen as measured recordings (no closed form), otherwise itself."""

    closed_form = False

    def __init__(self, system):
        self._system = system

    def __getattr__(self, name):
        return getattr(self._system, name)


def test_measured_rollouts_stop_once_every_one_has_diverged_with_the_same_numbers(trajectories):
    """For measured recordings the rollout runs in 1 s segments and stops once every trajectory has left the
    largest threshold: the same states as one long rollout up to there, the same divergence times; a model
    that stays close rolls out the whole horizon."""
    system = get_system("double_pendulum")

    class Pushed(ClosedForm):  # 50 rad/s^2 off: every rollout leaves 0.5 rad within 0.2 s
        def acceleration(self, q, qd, params, tau=None, check=False):
            return system.acceleration(q, qd, params) + 50.0

        def rollout(self, q0, qd0, params, dt, num_steps, method="rk4", tau=None):
            return lnn_torch.rollout(self.acceleration, q0, qd0, params, dt, num_steps, method)

    data = trajectories.head(6)
    for model, stops in ((Pushed(system), True), (ClosedForm(system), False)):
        whole = evaluate_model(model, system, data, horizon=2.0, sections=("rollouts",))
        measured = evaluate_model(model, _Measured(system), data, horizon=2.0, sections=("rollouts",))
        q_whole, q_measured = whole["_arrays"]["q_model"], measured["_arrays"]["q_model"]
        assert q_whole.shape == (6, 401, 2)
        assert q_measured.shape == ((6, 201, 2) if stops else (6, 401, 2))
        assert ("rollout_stopped_at_s" in measured) == stops
        torch.testing.assert_close(q_measured, q_whole[:, : q_measured.shape[1]], rtol=0, atol=0)
        for thr in (0.1, 0.5):
            key = f"divergence_time@{thr:g}"
            assert measured[key]["model"] == whole[key]["model"]
    assert measured["divergence_time@0.1"]["model"]["median"] == pytest.approx(2.0)  # the exact model stays
