"""The compiled fused path on the CPU as AOTInductor programs: what ``compile_dynamics(True)`` (and a long
rollout under ``"auto"``) runs where no gradient is recorded and a call has at most
``fused.COMPILED_MAX_ROWS`` rows, for a model with a fused path (``networks.fused``).

``torch.compile`` pays on every call dynamo's cache lookup and guards, AOTAutograd's runtime wrapper and
its program's Python entry: at batch 1 about 80 us an acceleration call of the default model, against
about 35 us for the same graph compiled ahead of time by AOTInductor and called through its runner with a
list of tensors (``benchmarks/speed_vs_original.py``, ``results/speed``).

``FusedPrograms`` takes ``perf.compile_fn``'s place for a model function (``CompiledDynamics._compiler_for``:
``StructuredLagrangian._fused_whole``, the accelerations, and ``_rollout_step``, one integrator step).
A call whose arguments hold the stacked weights (a ``fused.FusionPlan``) without a gradient runs an
AOTInductor program. Every registered model tensor the function reads is an input of its program (checked
when it is built): the stacked weights, the model's buffers and its parameters outside the stacked
networks (e.g. a learned friction), the latter two swapped in by ``torch.func.functional_call``. Weights
or buffers changed after compiling are so read on the next call without recompiling; tensors replaced by
others of another shape, stride or dtype take another program. A program's signature is what its graph
depends on: the arguments' structure, their tensors' shapes and dtypes, their other values (a step size, a
method name) and the model's structure that tracing reads as Python values (``_structure``: ``eps``, the
parts' tuples and the force residual, which ``residuals_off`` replaces, the drive model with its smoothing
velocities, the normaliser's ``exact``). Other
Python settings changed after compiling are not seen: ``compile_dynamics(True)`` again builds afresh.
Other calls (a gradient recorded, the networks part by part) go through ``perf.compile_fn``.

Packages are kept on disk in inductor's cache directory (``TORCHINDUCTOR_CACHE_DIR``), named by a hash of
the exported graph, its inputs' layout, its constants, the machine's architecture and vector
instructions and the optimisation level of the program's C++ wrapper (the tests build theirs at -O0): the
first compilation of a signature takes about 10-20 s, a later process loads it in 1-2 s.
"""

from __future__ import annotations

import dataclasses
import hashlib
import operator
import os
import platform
import tempfile
from pathlib import Path

import torch
from torch import nn

from ..perf import RECOMPILE_LIMIT, compile_fn, quiet_compilation
from .fused import FusionPlan, plan_sources

_AOTI_OPTIONS: dict = {}  # AOTInductor's defaults (no constants to fold: every model tensor is an input)
_CONSTANTS = (str, int, float, bool, type(None))


def _plan_layout(plan: FusionPlan) -> tuple[tuple[str, int | None], ...]:
    """The plan's tensor fields in order: ``(field, index)`` (index None for a tensor, else its place in a
    tuple of tensors)."""
    layout = []
    for field in dataclasses.fields(plan):
        value = getattr(plan, field.name)
        if isinstance(value, torch.Tensor):
            layout.append((field.name, None))
        elif isinstance(value, tuple) and value and all(isinstance(v, torch.Tensor) for v in value):
            layout.extend((field.name, i) for i in range(len(value)))
    return tuple(layout)


def _unflat_plan(template: FusionPlan, layout, tensors) -> FusionPlan:
    fields: dict = {}
    for (name, i), tensor in zip(layout, tensors, strict=True):
        if i is None:
            fields[name] = tensor
        else:
            fields.setdefault(name, []).append(tensor)
    return dataclasses.replace(template, **{k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()})


def _rebuild(spec, tensors, plan: tuple):
    """The arguments ``spec`` describes (``FusedPrograms._walk``), their tensors taken in order from the
    iterator ``tensors``; ``plan``: ``(template, layout)``."""
    kind = spec[0]
    if kind == "tensor":
        return next(tensors)
    if kind == "plan":
        template, layout = plan
        return _unflat_plan(template, layout, [next(tensors) for _ in layout])
    if kind == "tuple":
        return tuple(_rebuild(s, tensors, plan) for s in spec[1])
    return spec[-1]  # ("value", type name, value)


class _Method(nn.Module):
    """A model function as a module's forward (``functional_call`` swaps in the model's tensors)."""

    def __init__(self, model, name: str) -> None:
        super().__init__()
        self.model, self.name = model, name

    def forward(self, *args):
        return getattr(self.model, self.name)(*args)


class _Flat(nn.Module):
    """What is exported: the function of flat tensor inputs (the arguments' tensors, the plan's among them,
    then the model's other tensors), nothing of the model held as a constant; it returns a tensor or a tuple."""

    def __init__(self, model, name: str, spec, plan: tuple, other_names) -> None:
        super().__init__()
        object.__setattr__(self, "_method", _Method(model, name))  # not a submodule: its tensors are not exported
        self.spec, self.plan, self.other_names = spec, plan, other_names

    def forward(self, *inputs):
        tensors = iter(inputs)
        args = _rebuild(self.spec, tensors, self.plan)
        others = {f"model.{n}": t for n, t in zip(self.other_names, tensors, strict=True)}
        out = torch.func.functional_call(self._method, others, args, strict=False)
        return out if isinstance(out, torch.Tensor) else tuple(out)


def _package_dir() -> Path:
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    return Path(cache_dir()) / "lnn_torch_aoti"


@dataclasses.dataclass
class _Program:
    """One signature's compiled program: its runner's ``run(list of tensors)``, whether the function returns
    one tensor, and the model's other tensors it reads (``sources``: where each lives; ``tensors``: those
    seen last, ``layout``: their shapes, strides and dtypes when it was built)."""

    run: object
    single: bool
    sources: tuple
    tensors: list
    layout: tuple


def _other_sources(model) -> tuple[tuple, tuple]:
    """The model's tensors a program reads besides the plan: every buffer, and every parameter that the plan
    was not stacked from (friction, a residual force): ``((dict, name), ...)`` where each lives (read there on
    every call) and their dotted names."""
    stacked = {id(d) for d, _ in plan_sources(model)}
    sources, names = [], []
    for prefix, module in model.named_modules():
        for kind in ("_buffers", "_parameters"):
            tensors = getattr(module, kind)
            if kind == "_parameters" and id(tensors) in stacked:
                continue
            for name, tensor in tensors.items():
                if tensor is not None:
                    sources.append((tensors, name))
                    names.append(f"{prefix}.{name}" if prefix else name)
    return tuple(sources), tuple(names)


def _layout(tensors) -> tuple:
    return tuple((t.shape, t.stride(), t.dtype) for t in tensors)


def _structure(model) -> tuple:
    """What of the model's structure tracing reads as Python values and a call can change: ``eps``, the
    parts' tuples (``residuals_off`` replaces them), the force residual (``residuals_off("force")`` drops it),
    the drive model's smoothing velocities (weights loaded, ``set_coulomb_velocity``), whether the normaliser takes the
    parameters exactly."""
    forces = getattr(model, "forces", None)
    return (model.eps, id(model._kinetic_parts), id(model._potential_parts),
            None if forces is None else id(forces.residual), getattr(forces, "drive", None),
            model.normalizer.exact)


class FusedPrograms:
    """``fn`` (a method of ``model``) compiled in ``perf.compile_fn``'s place: calls with the stacked weights
    among the arguments and no gradient run AOTInductor programs, one per signature (at most
    ``perf.RECOMPILE_LIMIT``; further signatures take the other path); other calls run ``compiler(fn,
    device)`` (default ``perf.compile_fn``). Called as ``fn`` is; ``CompiledFallback`` runs the model eagerly
    if compiling or a call fails. Settings of the model other than those of ``_structure`` changed after
    compiling are not seen: call ``compile_dynamics(True)`` again."""

    def __init__(self, model, fn, device, compiler=None) -> None:
        self.model, self.fn, self.device = model, fn, torch.device(device)
        self.compiler = compiler or compile_fn  # for the calls that are not the fused path's
        self.programs: dict = {}
        self.dynamo = None  # compiler(fn, device), built on the first such call
        self.layout = None  # the plan's tensor fields in order (the same for every stacking of a model)
        self._view: tuple = (None, [], ())  # the last plan seen, its tensors in order, their shapes and dtypes

    def _walk(self, x, tensors: list):
        """``x``'s signature (its structure, tensors' shapes and dtypes, other values and their types), its
        tensors appended to ``tensors``; a plan's as ``layout`` orders them (flattened once per stacking)."""
        if isinstance(x, torch.Tensor):
            tensors.append(x.contiguous())
            return ("tensor", x.shape, x.dtype)
        if isinstance(x, FusionPlan):
            if x is not self._view[0]:  # the compiled view is cached per stacking
                if self.layout is None:
                    self.layout = _plan_layout(x)
                flat = [getattr(x, n) if i is None else getattr(x, n)[i] for n, i in self.layout]
                self._view = (x, flat, _layout(flat))  # one assignment: a concurrent call sees old or new
            _, flat, shapes = self._view
            tensors.extend(flat)
            return ("plan", shapes)
        if isinstance(x, tuple):
            return ("tuple", tuple(self._walk(v, tensors) for v in x))
        if isinstance(x, _CONSTANTS):
            return ("value", type(x).__name__, x)
        raise TypeError(f"an argument of type {type(x).__name__} cannot be a compiled program's")

    def _fallback(self, *args):
        if self.dynamo is None:
            self.dynamo = self.compiler(self.fn, self.device)
        return self.dynamo(*args)

    def __call__(self, *args):
        plan = next((a for a in args if isinstance(a, FusionPlan)), None)
        if plan is None:
            plan = next((v for a in args if isinstance(a, tuple) for v in a if isinstance(v, FusionPlan)), None)
        if plan is None or torch.is_grad_enabled() or plan.weights[0].device.type != "cpu":  # e.g. moved to a GPU
            return self._fallback(*args)
        tensors: list = []
        key = (("tuple", tuple(self._walk(a, tensors) for a in args)), _structure(self.model))
        program = self.programs.get(key)
        if program is not None:
            others = [d[name] for d, name in program.sources]
            if not all(map(operator.is_, others, program.tensors)):  # a tensor replaced (cast, moved)
                if _layout(others) != program.layout:  # another layout: another program
                    key = (*key, _layout(others))
                    program = self.programs.get(key)
                else:
                    program.tensors = others
        if program is None:
            if len(self.programs) >= RECOMPILE_LIMIT:
                return self._fallback(*args)
            program = self.programs[key] = self._compile(key[0], plan, tensors)
            others = program.tensors
        out = program.run(tensors + others)
        return out[0] if program.single else tuple(out)

    def _compile(self, spec, plan: FusionPlan, tensors) -> _Program:
        """Export, compile (or load the cached package of the same graph) and load one signature's program."""
        sources, names = _other_sources(self.model)
        others = [d[name] for d, name in sources]
        inputs = tensors + others
        flat = _Flat(self.model, self.fn.__name__, spec, (plan, self.layout), names)
        with torch.no_grad(), quiet_compilation():
            program = torch.export.export(flat, tuple(inputs), strict=False)
            # a model tensor baked into the program would go stale: every registered one must be an input
            kinds = {s.kind.name for s in program.graph_signature.input_specs} - {"USER_INPUT", "CONSTANT_TENSOR"}
            own = {t.untyped_storage().data_ptr() for t in (*self.model.parameters(), *self.model.buffers())}
            if kinds or any(c.untyped_storage().data_ptr() in own for c in program.constants.values()):
                raise RuntimeError("the fused program reads model tensors that are not its inputs")
            # the graph, its inputs' layout, its constants (e.g. a cached 1.0), the machine it is built for and how
            digest = hashlib.sha256()
            digest.update("\n".join([torch.__version__, platform.machine(), torch.backends.cpu.get_cpu_capability(),
                                     repr(sorted(_AOTI_OPTIONS.items())),
                                     torch._inductor.config.aot_inductor.compile_wrapper_opt_level,
                                     str(program.graph),
                                     repr(_layout(inputs))]).encode())
            for name, value in sorted(program.constants.items()):
                digest.update(name.encode() + repr(value.tolist()).encode())
            path = _package_dir() / f"{digest.hexdigest()[:32]}.pt2"
            if not path.exists():
                path.parent.mkdir(parents=True, exist_ok=True)
                with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
                    built = torch._inductor.aoti_compile_and_package(
                        program, package_path=str(Path(tmp) / path.name), inductor_configs=dict(_AOTI_OPTIONS))
                    os.replace(built, path)  # whole or absent: another process may load it meanwhile
            runner = torch._inductor.aoti_load_package(str(path)).loader
        return _Program(runner.run, program.call_spec.out_spec.is_leaf(), sources, others, _layout(others))
