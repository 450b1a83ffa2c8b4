"""Compilation (``torch.compile`` through ``lnn_torch.perf.compile_fn``): compiled dynamics and training
equal eager, when they compile by default, and the eager fallback when compilation fails."""

import pytest
import torch

from lnn_torch import LNNModule
from lnn_torch.mechanics.euler_lagrange import SingularHessianError
from lnn_torch.networks import build_model
from lnn_torch.networks.fused_aot import FusedPrograms
from lnn_torch.perf import compile_fn
from lnn_torch.systems import get_system

from .conftest import random_batch
from .helpers import make_dm, perturbed, quiet_trainer


def _stand_in_compilers(monkeypatch, tmp_path):
    """From here on, programs are built by stand-ins: the fused path's ``torch.export`` program run as exported
    (AOTInductor's packaging and loading replaced; the graph, its inputs and the program's key are the real
    ones, so a program reused where it should not be runs the old graph), kept in ``tmp_path``, and
    ``compile_fn`` dynamo without inductor (``backend="eager"``). What they check is which program each call
    takes and the plumbing around it. Inductor's code for those calls (a rollout's step with a gradient, the
    part-by-part path without one, a fit's pass) is not built here; the real compilations are the fused path
    without a gradient, the whole model with one, a rollout's step without one and the training pass."""
    import types

    import lnn_torch.networks.compiled as models
    from lnn_torch.networks import fused_aot

    def package(program, package_path, inductor_configs):
        torch.export.save(program, package_path)
        return package_path

    def load(path):
        module = torch.export.load(path).module()

        def run(inputs):
            out = module(*inputs)
            return [out] if isinstance(out, torch.Tensor) else list(out)

        return types.SimpleNamespace(loader=types.SimpleNamespace(run=run))

    monkeypatch.setattr(torch._inductor, "aoti_compile_and_package", package)
    monkeypatch.setattr(torch._inductor, "aoti_load_package", load)
    monkeypatch.setattr(fused_aot, "_package_dir", lambda: tmp_path / "stand_in_packages")
    monkeypatch.setattr(models, "compile_fn", lambda fn, device: torch.compile(fn, backend="eager", dynamic=False))


@pytest.mark.slow
def test_compiled_dynamics_equal_eager(rng, monkeypatch, tmp_path):
    """compile_dynamics(): accelerations through the fused path's AOTInductor program (batch 1, no gradient)
    and through torch.compile (C++ wrapper; with autograd, batch 5) equal the eager ones; weights changed in
    place are read without recompiling; the compiled code is dropped by copies. Then, with stand-in compilers
    (``_stand_in_compilers``): a rollout's step takes a program of its own without a gradient and
    torch.compile with one; above ``COMPILED_MAX_ROWS`` rows the part-by-part path is compiled."""
    import copy

    system = get_system("double_pendulum")
    model = perturbed(build_model("film_lnn", system, hidden_dims=(16, 16)))
    q, qd, params = (x.float() for x in random_batch(system, rng, 5))
    eager_accel = model.acceleration(q, qd, params)
    eager_q, eager_qd = model.rollout(q, qd, params, 0.01, 3)
    fresh = copy.deepcopy(model)
    model.compile_dynamics()
    with torch.no_grad():
        torch.testing.assert_close(model.acceleration(q[:1], qd[:1], params[:1]), eager_accel[:1], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(model.acceleration(q, qd, params), eager_accel, rtol=1e-5, atol=1e-5)  # autograd
    # without a gradient the fused path is compiled (its stacked weights the program's inputs), with one the parts
    assert model._compile is True and set(model._compiled) == {"_fused_whole", "_acceleration_whole"}
    assert copy.deepcopy(model)._compiled == {}  # no fallback happened above; copies recompile
    # on the CPU the fused path is an AOTInductor program (fused_aot), one per input signature
    programs = model._compiled["_fused_whole"].compiled
    assert isinstance(programs, FusedPrograms) and len(programs.programs) == 1
    # weights and buffers changed in place after compilation: the compiled inference uses the new ones, not
    # recompiled (every tensor is the program's input)
    other = copy.deepcopy(model).compile_dynamics(False)
    with torch.no_grad():
        for m in (model, other):
            for p in m.parameters():
                p.mul_(1.05)
            m.normalizer.accel_rms.mul_(2.0)
        changed = model.acceleration(q[:1], qd[:1], params[:1])
        assert len(programs.programs) == 1 and model._compiled["_fused_whole"].compiled is programs
        torch.testing.assert_close(changed, other.acceleration(q[:1], qd[:1], params[:1]), rtol=1e-5, atol=1e-5)
        assert (changed - eager_accel[:1]).abs().max() > 1e-3
    _stand_in_compilers(monkeypatch, tmp_path)
    # a rollout's step without a gradient: a program of its own; with one, its step through torch.compile
    fresh.compile_dynamics()
    with torch.no_grad():
        q_c, qd_c = fresh.rollout(q, qd, params, 0.01, 3)
    torch.testing.assert_close(q_c, eager_q, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(qd_c, eager_qd, rtol=1e-5, atol=1e-5)
    steps = fresh._compiled["_rollout_step"].compiled
    assert isinstance(steps, FusedPrograms) and len(steps.programs) == 1 and steps.dynamo is None
    q_g, qd_g = fresh.rollout(q, qd, params, 0.01, 2)
    assert steps.dynamo is not None and q_g.requires_grad
    torch.testing.assert_close(q_g, eager_q[:, :3], rtol=1e-5, atol=1e-5)
    with torch.no_grad():
        from lnn_torch.networks import fused

        monkeypatch.setattr(fused, "COMPILED_MAX_ROWS", 4)  # batch 5 is above it: the parts, compiled
        wide = copy.deepcopy(model).compile_dynamics(True)
        torch.testing.assert_close(wide.acceleration(q, qd, params), other.acceleration(q, qd, params),
                                   rtol=1e-5, atol=1e-5)
        assert set(wide._compiled) == {"_acceleration_whole"}
    # several compiled models per process: dynamo's per-code cache allows them (8 entries by default)
    from lnn_torch.perf import RECOMPILE_LIMIT

    assert torch._dynamo.config.recompile_limit >= RECOMPILE_LIMIT >= 32
    model.compile_dynamics(False)
    torch.testing.assert_close(model.acceleration(q, qd, params), other.acceleration(q, qd, params), rtol=0, atol=0)


@pytest.mark.slow
def test_compiled_fused_program_float64_with_inputs(rng, monkeypatch, tmp_path):
    """The fused path's AOTInductor program (``fused_aot.FusedPrograms``) of a float64 model of an actuated
    scene equals the eager fused path to rounding, inputs included, and so does a rollout's step with inputs;
    a non-contiguous state is read as its values; parameters changed in place are read without recompiling.
    Then, with stand-in compilers (``_stand_in_compilers``): another batch shape is another program, a cast of
    the model another; a force residual dropped by ``residuals_off`` is dropped by the program too, and a new
    Coulomb smoothing is read (other programs: the model's structure is in its key)."""
    import copy

    system = get_system("actuated_double_pendulum")
    model = perturbed(build_model("film_lnn", system, hidden_dims=(16, 16), residual_force={"hidden": [8]})).double()
    with torch.no_grad():
        for p in model.forces.residual.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=torch.Generator().manual_seed(1), dtype=p.dtype))
    q, qd, params = random_batch(system, rng, 3)
    tau = torch.randn(3, system.num_inputs, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    compiled = copy.deepcopy(model).compile_dynamics(True)
    with torch.no_grad():
        expected = model.acceleration(q, qd, params, tau)
        torch.testing.assert_close(compiled.acceleration(q, qd, params, tau), expected, rtol=1e-10, atol=1e-10)
        both = torch.stack([q, q], -1)[..., 0]  # a strided view: the program reads its values
        assert not both.is_contiguous()
        torch.testing.assert_close(compiled.acceleration(both, qd, params, tau), expected, rtol=1e-10, atol=1e-10)
        programs = compiled._compiled["_fused_whole"].compiled
        assert isinstance(programs, FusedPrograms) and len(programs.programs) == 1
        # a rollout's step under inputs: one program of its own, the eager rollout's result
        taus = tau[:, None].expand(-1, 3, -1)
        for a, b in zip(compiled.rollout(q, qd, params, 0.001, 3, tau=taus),
                        model.rollout(q, qd, params, 0.001, 3, tau=taus), strict=True):
            torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-10)
        assert len(compiled._compiled["_rollout_step"].compiled.programs) == 1
        # every parameter changed in place, the learned friction's too (not part of the stacked weights): read
        # on the next call, nothing recompiled
        for m in (model, compiled):
            for p in m.parameters():
                p.mul_(1.05)
        changed = model.acceleration(q, qd, params, tau)
        assert (changed - expected).abs().max() > 1e-3
        torch.testing.assert_close(compiled.acceleration(q, qd, params, tau), changed, rtol=1e-10, atol=1e-10)
        assert len(programs.programs) == 1
        expected = changed
        _stand_in_compilers(monkeypatch, tmp_path)
        torch.testing.assert_close(compiled.acceleration(q[:1], qd[:1], params[:1], tau[:1]), expected[:1],
                                   rtol=1e-10, atol=1e-10)
        assert len(programs.programs) == 2
        with model.residuals_off("force"):
            without = model.acceleration(q, qd, params, tau)
        assert (without - expected).abs().max() > 1e-3
        with compiled.residuals_off("force"):
            torch.testing.assert_close(compiled.acceleration(q, qd, params, tau), without, rtol=1e-10, atol=1e-10)
        torch.testing.assert_close(compiled.acceleration(q, qd, params, tau), expected, rtol=1e-10, atol=1e-10)
        assert len(programs.programs) == 3
        # the Coulomb smoothing changed (a classical start's choice, or weights loaded): another program, the
        # eager value
        for m in (model, compiled):
            m.forces.set_coulomb_velocity(2.0)  # over the states' speeds: the friction moves
        smoothed = model.acceleration(q, qd, params, tau)
        assert (smoothed - expected).abs().max() > 1e-3
        torch.testing.assert_close(compiled.acceleration(q, qd, params, tau), smoothed, rtol=1e-10, atol=1e-10)
        assert len(programs.programs) == 4
        expected = smoothed
        compiled.float()
        torch.testing.assert_close(compiled.acceleration(q, qd, params, tau), expected, rtol=1e-4, atol=1e-4)
        assert len(programs.programs) == 5 and compiled._compile is True


def test_compiled_dynamics_fall_back_once(monkeypatch, rng):
    """A failing compiled call warns once and the model continues eagerly with the eager result;
    the model's own errors (singular Hessian) pass through and are not taken for a compile failure."""
    import lnn_torch.networks.compiled as models

    def broken(fn, device):
        def run(*args):
            raise RuntimeError("inductor: C++ compile failed")
        return run

    monkeypatch.setattr(models, "compile_fn", broken)
    system = get_system("double_pendulum")
    model = perturbed(build_model("film_lnn", system, hidden_dims=(8,)).double())
    q, qd, params = random_batch(system, rng, 4)
    expected = model.acceleration(q, qd, params)
    model.compile_dynamics()
    with pytest.warns(RuntimeWarning, match="C\\+\\+ compile failed.*continuing eagerly"):
        torch.testing.assert_close(model.acceleration(q, qd, params), expected, rtol=0, atol=0)
    assert model._compile == "failed"
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        torch.testing.assert_close(model.acceleration(q, qd, params), expected, rtol=0, atol=0)

    def singular(fn, device):
        def run(*args):
            raise SingularHessianError("the velocity Hessian d2L/dqd2 is singular")
        return run

    monkeypatch.setattr(models, "compile_fn", singular)
    model.compile_dynamics()
    with pytest.raises(SingularHessianError):
        model.acceleration(q, qd, params)
    assert model._compile is True


def test_fused_program_failure_falls_back_once(monkeypatch, rng):
    """The fused path's AOTInductor program failing to build (no C++ compiler, an export error) warns once
    and the model continues with the eager fused path's result."""
    from lnn_torch.networks import fused_aot

    def broken(self, *args):
        raise RuntimeError("AOTInductor: C++ compile failed")

    monkeypatch.setattr(fused_aot.FusedPrograms, "_compile", broken)
    system = get_system("double_pendulum")
    model = perturbed(build_model("film_lnn", system, hidden_dims=(8, 8)))
    q, qd, params = (x.float() for x in random_batch(system, rng, 2))
    with torch.no_grad():
        expected = model.acceleration(q, qd, params)
        model.compile_dynamics(True)
        with pytest.warns(RuntimeWarning, match="C\\+\\+ compile failed.*continuing eagerly"):
            torch.testing.assert_close(model.acceleration(q, qd, params), expected, rtol=0, atol=0)
    assert model._compile == "failed"


def test_long_rollouts_compile_by_default_short_ones_and_switched_off_ones_never(monkeypatch, rng):
    """The default compilation mode ("auto") compiles the integrator step of a rollout whose work reaches
    perf.AUTO_COMPILE_CALLS acceleration calls (RK4: 4 a step), and nothing else: not a shorter rollout,
    not a direct acceleration call, not after compile_dynamics(False) or with LNN_TORCH_COMPILE=0. A
    compilation failure warns once and the rollout continues eagerly with the eager result."""
    import lnn_torch.networks.compiled as models
    import lnn_torch.perf as perf

    compiled = []

    def recording(fn, device):
        def run(*args):
            compiled.append(fn.__name__)
            return fn(*args)
        return run

    monkeypatch.setattr(models, "compile_fn", recording)
    monkeypatch.setattr(perf, "AUTO_COMPILE_CALLS", 40)
    system = get_system("double_pendulum")
    model = perturbed(build_model("film_lnn", system, hidden_dims=(8,)).double())
    q, qd, params = random_batch(system, rng, 3)
    assert model._compile == "auto"
    short = model.rollout(q, qd, params, 0.01, 9)  # 36 calls
    model.acceleration(q, qd, params)
    assert compiled == []
    long = model.rollout(q, qd, params, 0.01, 10)  # 40 calls: one compiled step function, called 10 times
    assert compiled == ["_rollout_step"] * 10
    torch.testing.assert_close(long[0][:, :10], short[0], rtol=0, atol=0)  # the step path = the eager path
    compiled.clear()
    model.acceleration(q, qd, params)  # after the rollout: eager again
    monkeypatch.setenv("LNN_TORCH_COMPILE", "0")
    model.rollout(q, qd, params, 0.01, 10)
    monkeypatch.delenv("LNN_TORCH_COMPILE")
    model.compile_dynamics(False)
    model.rollout(q, qd, params, 0.01, 10)
    assert compiled == []
    with pytest.raises(ValueError, match="compile_dynamics takes"):
        model.compile_dynamics("sometimes")
    # a model without a fused path (no FiLM on the potential) compiles its rollout step through compile_fn,
    # with a gradient or without
    layer = perturbed(build_model("film_lnn", system, hidden_dims=(8,), potential_film=False).double())
    expected = layer.rollout(q, qd, params, 0.01, 2)
    layer.compile_dynamics(True)
    with torch.no_grad():
        torch.testing.assert_close(layer.rollout(q, qd, params, 0.01, 2), expected, rtol=0, atol=0)
    assert compiled.count("_rollout_step") == 2 and layer._compile is True

    def broken(fn, device):
        def run(*args):
            raise RuntimeError("inductor: C++ compile failed")
        return run

    monkeypatch.setattr(models, "compile_fn", broken)
    model.compile_dynamics("auto")
    with pytest.warns(RuntimeWarning, match="compiled rollout failed.*continuing eagerly"):
        torch.testing.assert_close(model.rollout(q, qd, params, 0.01, 10), long, rtol=0, atol=0)
    assert model._compile == "failed"


@pytest.mark.slow
def test_compiled_training_matches_eager(dataset, tmp_path, monkeypatch):
    """compile=True: on one training batch (the supported size: chunks_per_batch x chunk_len, 4 x 16
    here; evaluation stays eager) the compiled pass gives the eager loss and gradients; and a short
    fit runs its pass through ``compile_fn`` without falling back. The pass is compiled as training compiles it
    (``perf.compile_fn``: static shapes, inductor's C++ wrapper), which also compiles it in about half
    the time of plain ``torch.compile``'s Python wrapper."""
    dm = make_dm(dataset)
    dm.setup("fit")
    batch = {k: v.double() for k, v in dm.train_set[0].items()}  # float64: an equality, not a float32 race
    model = LNNModule(val_rollouts=0, hidden_dims=[16, 16], energy_weight=0.1)
    model.model.fit_normalizer(dm.normalization_data())
    model = model.double()
    results = []
    for pass_fn in (model.training_terms, compile_fn(model.training_terms)):
        model.zero_grad()
        loss, _ = model.batch_loss(batch, pass_fn)
        loss.backward()
        results.append((loss.detach(), [p.grad.clone() for p in model.parameters()]))
    (l0, g0), (l1, g1) = results
    torch.testing.assert_close(l1, l0, rtol=1e-12, atol=0)
    for a, b in zip(g0, g1, strict=True):
        # only the summation order differs between the two graphs (in float32 that alone reached
        # 1e-6 of the largest entry, and 5x relative on near-zero entries)
        torch.testing.assert_close(b, a, rtol=1e-9, atol=1e-12 * max(float(a.abs().max()), 1e-3))
    # a fit with compile=True runs its pass through compile_fn, without falling back (dynamo without inductor here:
    # the compiled pass's numbers are those above)
    from lnn_torch import perf

    compiled = []

    def stand_in(fn, device):
        compiled.append(fn.__name__)
        return torch.compile(fn, backend="eager", dynamic=False)

    monkeypatch.setattr(perf, "compile_fn", stand_in)
    model = LNNModule(compile=True, val_rollouts=0, hidden_dims=[16, 16])
    trainer = quiet_trainer(tmp_path, max_epochs=1, limit_val_batches=0, logger=False, enable_checkpointing=False)
    trainer.fit(model, make_dm(dataset, steps_per_epoch=3))
    assert compiled == ["training_terms"]
    assert model.training_pass.compiled not in (None, False) and trainer.global_step == 3


def test_training_compiles_by_default_only_runs_long_enough_to_repay_it(dataset, tmp_path, monkeypatch):
    """compile="auto" (the default): a run planned for fewer than AUTO_COMPILE_TRAIN_STEPS steps
    trains eagerly; one planned for at least that many compiles its pass, unless limited to less time than
    AUTO_COMPILE_MIN_SECONDS; LNN_TORCH_COMPILE=0 and compile=False never compile."""
    from lnn_torch import perf

    built = []

    def recording_compile(fn, **kw):
        built.append(fn)
        return fn  # the eager pass under a recorded "compilation": the decision is what is tested

    monkeypatch.setattr(torch, "compile", recording_compile)
    monkeypatch.setattr(perf, "AUTO_COMPILE_TRAIN_STEPS", 4)

    def fit(steps, max_time=None, **kw):
        model = LNNModule(val_rollouts=0, hidden_dims=[8], **kw)
        trainer = quiet_trainer(tmp_path, max_steps=steps, limit_val_batches=0, logger=False,
                                enable_checkpointing=False, max_time=max_time)
        trainer.fit(model, make_dm(dataset, steps_per_epoch=steps))
        return model

    assert LNNModule(hidden_dims=[8]).hparams.compile == "auto"
    assert fit(3).training_pass.compiled is None and not built  # 3 < 4 planned steps: eager
    assert fit(4).training_pass.compiled is not None and len(built) == 1  # 4 planned steps: compiled
    assert fit(6, compile=False).training_pass.compiled is None and len(built) == 1
    # a run limited to less time than compiling repays (--trainer.max_time 20 s: the compilation took it all)
    assert fit(6, max_time="00:00:00:20").training_pass.compiled is None and len(built) == 1
    assert fit(6, max_time="00:01:00:00").training_pass.compiled is not None and len(built) == 2
    monkeypatch.setenv("LNN_TORCH_COMPILE", "0")
    assert fit(6).training_pass.compiled is None and len(built) == 2
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
    assert model.training_pass.compiled is False and trainer.global_step == 3
    assert all(torch.isfinite(p).all() for p in model.parameters())


def test_what_load_model_returns_takes_compile_dynamics_as_the_readme_calls_it():
    """``lnn_torch.load_model(...).compile_dynamics(True)`` as the README writes it (it raised AttributeError: the
    method was the network's only): the module's network is switched, the module returned."""
    from lnn_torch import load_model

    module = load_model("pretrained:double_pendulum")
    assert module.compile_dynamics(False) is module and module.model._compile is False
    assert module.compile_dynamics("auto").model._compile == "auto"
