"""The training pass a module's steps call: its eager function, compiled where that pays, with the
eager fallback (``perf.CompiledFallback``): a failure to compile, of a compiled call or of its
backward warns once and training continues eagerly."""

from __future__ import annotations

from ..perf import CompiledFallback, compile_pays_training, warn_compile_failure


class TrainingPass:
    """``fn`` (the eager pass), compiled when ``compile`` is True or, under ``"auto"``, when the run's
    planned optimiser steps repay it (``perf.compile_pays_training``, decided at the first step).

    ``compiled``: None until built, then the ``CompiledFallback``; False after a failure (eager from
    then on). ``auto``: ``"auto"``'s decision once made."""

    def __init__(self, fn, compile: bool | str = "auto") -> None:
        if compile not in (True, False, "auto"):
            raise ValueError(f"compile must be true, false or 'auto', got {compile!r}")
        self.fn, self.choice = fn, compile
        self.compiled = self.auto = None

    def function(self, planned_steps: float, device, seconds: float | None = None):
        """The function to call this step: compiled (built on first use for ``device``) or ``fn`` (``seconds``:
        the run's time limit, if any)."""
        if self.choice == "auto" and self.auto is None:
            self.auto = compile_pays_training(planned_steps, seconds)
        if self.compiled is False or not (self.auto if self.choice == "auto" else self.choice):
            return self.fn
        if self.compiled is None:
            self.compiled = CompiledFallback(self.fn, device, on_failure=self._failed)
        return self.compiled

    def _failed(self, err: Exception) -> None:
        warn_compile_failure("training pass", err, "continuing training eagerly", stacklevel=1)
        self.compiled = False

    def backward_failed(self, err: Exception) -> bool:
        """The backward of this step failed: if it ran through the compiled pass, record the failure
        (warned once; eager from now on) and return True (the caller redoes the step eagerly); else False."""
        if not self.compiled:
            return False
        self.compiled.fail(err)
        return True
