"""Opt-in compilation of a model's dynamics: ``compile_dynamics`` and what it runs (a mixin of
``DynamicsModel``, abstract: it compiles the host's own methods and builds nothing).

The host gives ``acceleration_norm``-like methods, ``rollout_conditioning(params)`` (the method and
what it needs from the parameters alone) and ``_acceleration_si(fn, q, qd, params_norm, *extra)``
(SI accelerations from a normalised method). Compiled functions go through
``lnn_torch.perf.CompiledFallback`` (``compile_fn``: static shapes, the C++ wrapper on the CPU) with
the eager fallback: a failure warns once and the model continues eagerly.
"""

from __future__ import annotations

import torch

from ..errors import InputError, SingularHessianError
from ..mechanics import integrators
from ..perf import CompiledFallback, compile_fn, warn_compile_failure


class CompiledDynamics:
    """``compile_dynamics`` and the compiled calls of a model (mixed into ``DynamicsModel``)."""

    _compile = "auto"  # "auto" (long rollouts compiled), True (always), False (never) or "failed"
    _compiled: dict | None = None  # compiled functions by name

    def compile_dynamics(self, enabled: bool | str = True):
        """Choose when ``acceleration``, and so ``rollout``, runs through ``torch.compile``.

        ``"auto"`` (the default): eagerly, except a rollout long enough to repay the compilation
        (``perf.AUTO_COMPILE_CALLS`` acceleration calls or more; the environment variable
        ``LNN_TORCH_COMPILE=0`` switches it off), whose integrator step is compiled whole (all its
        stages in one program). ``True``: accelerations and every rollout compiled. ``False``: never.

        Compiled on first use for each batch shape, dtype and grad mode (10-30 s each the first
        time; inductor caches compiled code on disk across processes, later compilations take a few
        seconds); the C++ wrapper on the CPU (``lnn_torch.perf.compile_fn``). On the CPU, accelerations
        and rollout steps without a gradient of a model with a fused path (``networks.fused``) run an
        AOTInductor program instead, called without dynamo's per-call overhead (``networks.fused_aot``;
        10-20 s to build, cached on disk alike). If compilation or a
        compiled call fails, a warning is issued once and the model continues eagerly. Returns the model.
        """
        if enabled not in (True, False, "auto"):
            raise ValueError(f"compile_dynamics takes True, False or 'auto', got {enabled!r}")
        self._compile, self._compiled = enabled, {}
        return self

    def _run(self, fn, *args):
        """``fn(*args)``, compiled after ``compile_dynamics(True)`` (with the eager fallback); inside a
        compiled rollout step it is part of that step's program."""
        if self._compile is not True or torch.compiler.is_compiling():
            return fn(*args)
        return self._compiled_fn(fn, args[0].device, "accelerations")(*args)

    def _compiled_fn(self, fn, device, what: str, eager: bool = True) -> CompiledFallback:
        """``fn`` compiled with the eager fallback (``perf.CompiledFallback`` over ``perf.compile_fn``),
        built on first use and kept by its name; the model's own errors (``InputError``, a singular
        Hessian) pass through, any other failure is ``_compile_failed``."""
        if self._compiled is None:
            self._compiled = {}
        compiled = self._compiled.get(fn.__name__)
        if compiled is None:
            compiled = self._compiled[fn.__name__] = CompiledFallback(
                fn, device, on_failure=lambda err: self._compile_failed(what, err),
                passthrough=(InputError, SingularHessianError), eager=eager, compiler=self._compiler_for(fn, device))
        return compiled

    def _compiler_for(self, fn, device):
        """What compiles ``fn`` for ``device``: ``compiler(fn, device) -> callable`` (``perf.compile_fn``; a model
        with a better program for one of its functions gives it here)."""
        return compile_fn

    def _compile_failed(self, what: str, err: Exception) -> None:
        """Warn once that compiled ``what`` failed and continue eagerly from now on."""
        warn_compile_failure(what, err, "continuing eagerly", stacklevel=7)
        self._compile, self._compiled = "failed", {}

    def _rollout_step(self, name: str, method: str, dt: float, q, qd, params_norm, cond: tuple, tau=None):
        """One integrator step in SI units from precomputed conditioning: a pure function of its tensors
        (``rollout`` compiles it whole: the four RK4 stages in one program)."""
        fn = getattr(self, name)
        extra = () if tau is None else (self.tau_norm(tau),)

        def accel(q_, qd_, _params):
            return self._acceleration_si(fn, q_, qd_, params_norm, *cond, *extra)

        return integrators.METHODS[method](accel, q, qd, params_norm, dt)

    def _compiled_rollout(self, q0, qd0, params, dt, num_steps, method, tau):
        """``rollout`` through the compiled ``_rollout_step`` (compiled once per batch shape, dtype, grad
        mode, method and step); None after a compilation failure (warned once; the caller continues
        eagerly)."""
        compiled = self._compiled_fn(self._rollout_step, q0.device, "rollout", eager=False)
        name, params_norm, cond = self.rollout_conditioning(params)
        qs, qds, q, qd = [q0], [qd0], q0, qd0
        for i in range(num_steps):
            out = compiled(name, method, float(dt), q, qd, params_norm, cond, None if tau is None else tau[:, i])
            if out is None:  # failed (warned): the whole rollout is redone eagerly
                return None
            q, qd = out
            qs.append(q)
            qds.append(qd)
        return torch.stack(qs, dim=1), torch.stack(qds, dim=1)

    def __getstate__(self):
        state = super().__getstate__()  # a copy of __dict__
        if "_compiled" in state:
            state["_compiled"] = {}  # compiled code is rebuilt on first use (copies, pickles)
        state.pop("_fusion_plan", None)  # the fused path's stacked weights (networks.fused): restacked on use
        state.pop("_fusion_view", None)
        return state
