"""The one compile-with-fallback wrapper (``lnn_torch.perf.CompiledFallback``) that the model's compiled
dynamics and the LightningModule's compiled training pass both use (no compiler runs here)."""

from __future__ import annotations

import pytest
import torch

from lnn_torch import LNNModule
from lnn_torch.perf import CompiledFallback, warn_compile_failure


class Own(Exception):
    """An error of the caller's own (passed through, not taken for a compilation failure)."""


def test_compiled_on_first_call_then_one_warned_fallback_to_eager():
    built, failures = [], []

    def compiler(fn, device):
        built.append(device)

        def compiled(x):
            if x < 0:
                raise RuntimeError("inductor failed\nsecond line")
            if x == 0:
                raise Own("the caller's own answer")
            return ("compiled", fn(x))

        return compiled

    wrapped = CompiledFallback(lambda x: 2 * x, "cpu", on_failure=failures.append, passthrough=(Own,),
                               compiler=compiler)
    assert built == [] and wrapped(3) == ("compiled", 6) and wrapped(4) == ("compiled", 8) and built == ["cpu"]
    with pytest.raises(Own):
        wrapped(0)
    assert not wrapped.failed and failures == []
    assert wrapped(-1) == -2  # failed: answered eagerly
    assert wrapped.failed and [str(e) for e in failures] == ["inductor failed\nsecond line"]
    assert wrapped(5) == 10 and len(failures) == 1 and built == ["cpu"]  # eager from now on, reported once
    # eager=False: the caller redoes its work eagerly itself
    quiet = CompiledFallback(lambda x: x, on_failure=failures.append, eager=False, compiler=compiler)
    assert quiet(-1) is None and quiet(2) is None and len(failures) == 2
    # a compiler that fails itself is a failure like any other
    broken = CompiledFallback(lambda x: x + 1, compiler=lambda fn, device: 1 / 0)
    assert broken(1) == 2 and broken.failed


def test_the_warning_names_what_failed_and_its_first_line():
    with pytest.warns(RuntimeWarning, match=r"^compiled rollout failed \(ValueError: bad\); continuing eagerly$"):
        warn_compile_failure("rollout", ValueError("bad\nmore"))
    with pytest.warns(RuntimeWarning, match=r"^compiled pass failed \(KeyError: \); continuing training eagerly$"):
        warn_compile_failure("pass", KeyError(), "continuing training eagerly")


def test_the_model_and_the_module_compile_through_it(monkeypatch):
    module = LNNModule(compile=True, val_rollouts=0, hidden_dims=[8])
    assert isinstance(module.training_pass.function(0, module.device), CompiledFallback)
    model = module.model.double().compile_dynamics()
    monkeypatch.setattr(torch, "compile", lambda fn, **kw: fn)  # a "compilation" that runs fn itself
    q = torch.tensor([[0.3, -0.2]], dtype=torch.float64)
    model.acceleration(q, q, torch.tensor([[1.0, 0.5, 1.2, 1.3]], dtype=torch.float64))
    assert isinstance(model._compiled["_acceleration_whole"], CompiledFallback)
