"""Declared capabilities and self-presenting evaluation sections: every report section over every
variant and every kind of scene (conservative, actuated with friction, measured) gives values or a
stated reason, never an error; the SI accessors agree with the normalised quantities; a new metric
is one function and one registration."""

import math

import pytest
import torch

from lnn_torch.commands.evaluate import write_report
from lnn_torch.data import DatasetSpec, Trajectories, generate_arrays
from lnn_torch.evaluation import (
    SECTIONS,
    SectionResult,
    evaluate_model,
    report_sections,
    section,
    section_figures,
    section_logs,
    skip,
)
from lnn_torch.networks import MODELS, VARIANTS, build_model
from lnn_torch.networks.capabilities import (
    CAPABILITIES,
    ENERGY,
    FORCES,
    FRICTION,
    INVERSE_DYNAMICS,
    MASS_MATRIX,
    NAN_ON_SINGULAR,
    STATIC_FRICTION,
)
from lnn_torch.systems import InputError, get_system

KINDS = ("conservative", "actuated", "measured")
# tiny: 0.1 s rollouts, 4-step hard cases, two horizons
OPTIONS = dict(horizon=0.1, stability_seconds=0.02, long_horizon_steps=5, horizons=(0.05, 0.1), start_every=0.1)


@pytest.fixture(scope="module")
def scenes():
    """kind -> (system, Trajectories): 3 trajectories of 0.3 s each. The measured kind is the
    actuated arm's data as an imported recording gives it: a system without parameters or closed
    form, recordings of different lengths (NaN padding)."""
    out = {}
    for kind, name in (("conservative", "double_pendulum"), ("actuated", "actuated_double_pendulum")):
        a = generate_arrays(DatasetSpec(scene=name, num_trajectories=3, duration=0.3, seed=3))
        t = {k: torch.as_tensor(a[k], dtype=torch.float64) for k in ("q", "qd", "qdd", "params", "tau") if k in a}
        dt = float(a["t"][1] - a["t"][0])
        out[kind] = get_system(name), Trajectories(t["q"], t["qd"], t["params"], dt, t["qdd"], tau=t.get("tau"))
    _, act = out["actuated"]
    q, qd, qdd, tau = (x.clone() for x in (act.q, act.qd, act.qdd, act.tau))
    lengths = torch.tensor([61, 51, 41])
    for i, n in enumerate(lengths):
        for x in (q, qd, qdd, tau):
            x[i, n:] = float("nan")
    measured = get_system("measured", dof=2, input_names=["tau1", "tau2"], angle_combinations=[[1, 1]])
    out["measured"] = measured, Trajectories(q, qd, torch.zeros(3, 0, dtype=torch.float64), act.dt, qdd, tau=tau,
                                             lengths=lengths)
    return out


def tiny_model(variant, system, data):
    """An untrained model (8 x 8) with its normaliser fitted to ``data``."""
    torch.manual_seed(0)
    model = build_model(variant, system, hidden_dims=(8, 8))
    n = int(data.num_points if data.lengths is None else data.lengths.min())
    flat = lambda x: x[:, :n].reshape(-1, x.shape[-1])  # noqa: E731
    stats = {"q": flat(data.q), "qd": flat(data.qd), "qdd": flat(data.qdd), "params": data.params,
             "params_points": data.params[:, None].expand(-1, n, -1).flatten(0, 1)}
    if data.tau is not None:
        stats["tau"] = flat(data.tau)
    model.fit_normalizer(stats)
    return model


# ---------------------------------------------------------------------------- declarations
EXPECTED = {  # (variant, kind) -> capabilities; hnn cannot be built for a measured system
    ("film_lnn", "conservative"): {ENERGY, MASS_MATRIX}, ("delan", "conservative"): {ENERGY, MASS_MATRIX},
    ("lnn", "conservative"): {ENERGY, NAN_ON_SINGULAR}, ("mlp", "conservative"): set(), ("hnn", "conservative"): set(),
    ("film_lnn", "actuated"): {ENERGY, MASS_MATRIX, INVERSE_DYNAMICS, FRICTION, FORCES},
    ("delan", "actuated"): {ENERGY, MASS_MATRIX, INVERSE_DYNAMICS, FRICTION, FORCES},
    ("lnn", "actuated"): {ENERGY, FRICTION, NAN_ON_SINGULAR, FORCES}, ("mlp", "actuated"): set(),
    ("hnn", "actuated"): {FRICTION, FORCES},
    ("film_lnn", "measured"): {ENERGY, MASS_MATRIX, INVERSE_DYNAMICS, FRICTION, FORCES},  # a measured arm has friction
    ("delan", "measured"): {ENERGY, MASS_MATRIX, INVERSE_DYNAMICS, FRICTION, FORCES},
    ("lnn", "measured"): {ENERGY, FRICTION, NAN_ON_SINGULAR, FORCES}, ("mlp", "measured"): set(),
}
# the flags that ``provides`` replaced: (flag, capability) -> the classes that have it
FLAGS = {("has_energy", ENERGY): {"film_lnn", "delan", "lnn"},
         ("uses_forces", FORCES): {"film_lnn", "delan", "lnn", "hnn"},
         ("static_friction", STATIC_FRICTION): {"film_lnn", "delan"}}


def test_each_class_declares_what_it_provides_and_the_scene_narrows_it(scenes):
    for name, cls in MODELS.items():
        assert cls.provides <= set(CAPABILITIES), name
        assert (ENERGY in cls.provides) == cls.has_energy, name  # the energy regulariser's flag agrees
        for (flag, capability), having in FLAGS.items():  # the old flags: read-only, derived from provides
            assert getattr(cls, flag) == (capability in cls.provides) == (name in having), (name, flag)
    for (variant, kind), expected in EXPECTED.items():
        system, data = scenes[kind]
        assert tiny_model(variant, system, data).capabilities == expected, (variant, kind)
    with pytest.raises(NotImplementedError, match="no mass matrix"):  # no momentum map: it cannot be fitted,
        tiny_model("hnn", *scenes["measured"])  # so there is no hnn of a measured system to evaluate
    system = get_system("actuated_double_pendulum")
    stiction = build_model("film_lnn", system, hidden_dims=(8,), dissipation="joint+stiction")
    assert STATIC_FRICTION in stiction.capabilities
    plain = build_model("film_lnn", system, hidden_dims=(8,))
    assert plain.missing(STATIC_FRICTION) == "the model has no static friction (dissipation 'joint+stiction')"
    conservative = build_model("delan", get_system("double_pendulum"), hidden_dims=(8,))
    assert conservative.missing(INVERSE_DYNAMICS, ENERGY) == ("scene 'double_pendulum' has no inputs (inverse "
                                                              "dynamics needs them)")
    hnn = build_model("hnn", system, hidden_dims=(8,))
    assert hnn.missing(ENERGY, FRICTION) == "variant 'hnn' does not provide energy"
    assert plain.missing(ENERGY) is None
    assert plain.has_energy and plain.uses_forces and plain.static_friction
    with pytest.raises(AttributeError, match="read-only"):
        plain.has_energy = False
    assert conservative.missing(FORCES) == "scene 'double_pendulum' has no generalised forces (inputs or friction)"
    assert build_model("mlp", system, hidden_dims=(8,)).forces is None  # the inputs are its features


def test_si_accessors_agree_with_the_normalised_quantities(scenes):
    """energy is H / force_scale (J) with inputs; mass_matrix is the matrix of energy's kinetic
    energy in SI velocities; friction in N m; an accessor the model does not provide names why."""
    system, data = scenes["actuated"]
    model = tiny_model("film_lnn", system, data).double()
    q, qd, p = data.q[:, ::7].reshape(-1, 2), data.qd[:, ::7].reshape(-1, 2), data.params[:, None].expand(-1, 9, -1)
    p = p.reshape(-1, p.shape[-1])
    with torch.no_grad():
        H_n, T_n, _ = model.energy_norm(*model.normalize(q, qd, p))
        fs = float(model.normalizer.force_scale)
        assert fs != 1.0
        torch.testing.assert_close(model.energy(q, qd, p), H_n / fs, rtol=1e-12, atol=0)
        M = model.mass_matrix(q, p)
        torch.testing.assert_close(0.5 * torch.einsum("bi,bij,bj->b", qd, M, qd), T_n / fs, rtol=1e-10, atol=1e-14)
        rates = qd @ system.joint_map().T
        torch.testing.assert_close(model.friction_torque(rates, p),
                                   model.forces.friction_torque(rates, model.normalizer.params(p)))
        b, c = model.friction_coefficients(p)
        assert b.shape == c.shape == (len(p), 2) and (b >= 0).all() and (c >= 0).all()
    mlp = tiny_model("mlp", system, data)
    for call in (lambda: mlp.energy(q, qd, p), lambda: mlp.mass_matrix(q, p),
                 lambda: mlp.friction_torque(rates, p)):
        with pytest.raises(InputError, match="variant 'mlp' does not provide"):
            call()


def test_undefined_accelerations_are_nan_only_within_the_context():
    from lnn_torch.mechanics.euler_lagrange import SingularHessianError

    model = build_model("lnn", get_system("double_pendulum"), hidden_dims=(8,)).double()
    with torch.no_grad():
        model.net.out.weight.zero_()  # L = 0: a singular velocity Hessian everywhere
    q = torch.zeros(2, 2, dtype=torch.float64)
    p = torch.ones(2, 4, dtype=torch.float64)
    with pytest.raises(AttributeError):
        model.raise_on_singular = False  # not a flag to set: a context
    with pytest.raises(SingularHessianError):
        model.acceleration(q, q, p)
    with model.nan_on_singular():
        with model.nan_on_singular():
            assert not model.raise_on_singular
        assert torch.isnan(model.acceleration(q, q, p)).all()
    assert model.raise_on_singular


# ---------------------------------------------------------------------------- every section, every model, every scene
@pytest.mark.parametrize("kind", KINDS)
def test_every_report_section_gives_values_or_a_reason(kind, scenes, tmp_path):
    """Every report section for every variant that can model the scene: values, or a stated skip;
    the report lists both (the known crash before: the hnn's free decay on a scene with friction)."""
    system, data = scenes[kind]
    sections = report_sections()
    assert set(sections) >= {"accelerations", "rollouts", "energy", "predictability", "mass_matrix", "torques",
                             "friction", "free_decay", "horizons", "ood", "stability", "regimes"}
    for variant in VARIANTS:
        if (variant, kind) not in EXPECTED:
            continue
        model = tiny_model(variant, system, data)
        result = evaluate_model(model, system, data, sections=sections, **OPTIONS)
        presented, skipped = result["_sections"], result.get("skipped", {})
        assert set(presented) | set(skipped) == set(sections) and not set(presented) & set(skipped), variant
        for name, why in skipped.items():
            assert isinstance(why, str) and len(why) > 10, (variant, name, why)
        for name, s in presented.items():
            assert s.values and (s.rows or s.blocks), (variant, name)
        assert {"accelerations", "rollouts", "horizons"} <= set(presented), (variant, skipped)
        caps = model.capabilities
        assert ("mass_matrix" in presented) == (MASS_MATRIX in caps and system.closed_form), variant
        assert ("torques" in presented) == (INVERSE_DYNAMICS in caps), variant
        assert ("free_decay" in presented) == ({ENERGY, FRICTION} <= caps and system.closed_form), variant
        assert ("energy" in presented) == system.closed_form, variant
        if variant == "hnn" and kind == "actuated":
            assert skipped["free_decay"] == "variant 'hnn' does not provide energy"
        if kind == "measured":
            assert "no closed form" in skipped["stability"]
        if "torques" in presented:
            assert math.isfinite(result["torque_nrmse"]["mean"])  # at the valid points of the recordings
        if variant not in ("film_lnn", "hnn", "mlp"):
            continue  # the report is the same loop for every model: written (with its PNGs) for three
        report = write_report({"data": kind, **result}, tmp_path / variant)
        text = (tmp_path / variant / "report.md").read_text()
        assert "Skipped sections:" in text or not skipped
        for name, why in skipped.items():
            assert f"* {name}: {why}" in text
        for s in presented.values():
            assert all(row in text for row in s.rows)
        assert {p.name for p in report[2:]} <= set(section_figures(result)), variant
    logs = section_logs(result)
    assert "acc_rel_err" in logs and "divergence_time" in logs


# ---------------------------------------------------------------------------- one function, one registration
def test_a_new_metric_presents_itself_in_the_report_figures_and_logs(scenes, tmp_path):
    """A new section is one function and its @section line: its values reach metrics.json, its
    rows report.md, its figure a PNG and its scalar the training logs; a plain dict works too (its
    scalars become rows), and a model without what it ``needs`` skips it with the reason."""
    system, data = scenes["conservative"]

    def speed_figure(result):
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots()
        ax.plot(result["_arrays"]["qd_model"][0, :, 0])
        return fig

    @section("max_speed", report=False)
    def max_speed(ctx):
        if not ctx.system.closed_form:
            return skip("needs a closed form")
        v = float(ctx.rollouts()["qd"].abs().max())
        return SectionResult({"max_speed": v}, rows=[f"| max speed (rad/s) | {v:.3f} |"],
                             figures={"max_speed.png": speed_figure}, logs={"max_speed": v})

    @section("plain", needs=(MASS_MATRIX,), report=False)
    def plain(ctx):
        return {"plain": {"one": 1.0}}

    try:
        model = tiny_model("mlp", system, data)
        r = evaluate_model(model, system, data, sections=("rollouts", "max_speed", "plain"), horizon=0.2)
        assert section_logs(r)["max_speed"] == r["max_speed"] > 0
        assert r["skipped"] == {"plain": "variant 'mlp' does not provide mass_matrix"}
        files = write_report(r, tmp_path)
        text = (tmp_path / "report.md").read_text()
        assert "| max speed (rad/s) |" in text and "* plain: variant 'mlp' does not provide mass_matrix" in text
        assert (tmp_path / "max_speed.png") in files
        r = evaluate_model(tiny_model("delan", system, data), system, data, sections=("plain",))
        assert r["plain"] == {"one": 1.0} and r["_sections"]["plain"].rows == ["| plain (one) | 1 |"]
        assert "max_speed" not in report_sections()  # report=False: on demand only
    finally:
        SECTIONS.pop("max_speed")
        SECTIONS.pop("plain")
