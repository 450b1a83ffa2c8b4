"""A trained model's dynamics as standalone programs for a control loop (``lnn-torch export``).

Each exported function is a small ``nn.Module`` over one method of the model's SI rigid-body face
(``lnn_torch.networks.rigid_body``, which states the convention ``M(q) qdd + n(q, qd) = B tau +
Q_f(q, qd)``), with plain tensor arguments and SI units, the model's normaliser and the scene's
constants (input matrix, joint map, Coulomb smoothing velocity) baked in, and a dynamic batch dimension:

==================  =======================================  ==========================================
function            arguments -> result                      what
==================  =======================================  ==========================================
forward_dynamics    ``(q, qd, params[, tau]) -> qdd``        accelerations (``tau``: actuated scenes)
inverse_dynamics    ``(q, qd, qdd, params) -> tau``          the inputs: ``B tau = M qdd + n - Q_f``
mass_matrix         ``(q, params) -> M``                     the learned mass matrix ``(B, dof, dof)``
bias_force          ``(q, qd, params) -> n``                 Coriolis, centrifugal, gravity: no friction
gravity_force       ``(q, params) -> g``                     ``g(q) = n(q, 0)``
friction_force      ``(q, qd, params) -> Q_f``               the learned dissipative force
==================  =======================================  ==========================================

Shapes: ``q, qd, qdd (B, dof)``, ``params (B, P)``, ``tau (B, n_u)``. ``inverse_dynamics``,
``bias_force``, ``gravity_force`` and ``friction_force`` need a structured model (``film_lnn``,
``delan``) of a scene with inputs (``INVERSE_DYNAMICS``: the torques fix the scale of the learned
Lagrangian, so the forces are in N m), ``friction_force`` one that learns a dissipative force (a
scene with friction); ``mass_matrix`` a structured model (``MASS_MATRIX``; without inputs it is in
the model's own units, up to one positive factor per system). ``n = -M a_0`` holds the Coriolis,
centrifugal and gravity forces (``a_0``: the accelerations under no force at all); the learned friction
is ``Q_f`` (earlier versions' ``bias_force`` included it: ``n_old = n - Q_f``). Static
friction's holding torques (``dissipation: joint+stiction``) are not a force of the state: they are in
``forward_dynamics`` only, in none of ``n``, ``Q_f`` or ``inverse_dynamics``, as in the model's own
inverse dynamics.

Formats (``export_model``; ``lnn-torch export --format``):

* ``pt2``: ``torch.export.export`` with the batch a ``torch.export.Dim`` (1 to ``MAX_BATCH``), saved by
  ``torch.export.save`` (``torch.export.load(path).module()(q, qd, params)``). Only models whose
  functions make no autograd call can be exported: the structured models' hand-carried tangents and
  the direct MLP. The black-box ``lnn`` (velocity Hessians through ``torch.func``) and ``hnn``
  (gradients of its Hamiltonian) are refused (``InputError``, one line). The loaded program calls
  the same aten operators as the eager model from generated Python code: as fast as eager at large
  batches, slower at batch 1 (Python's cost per operator); it is the portable form.
* ``onnx``: ``torch.onnx.export(..., dynamo=True)`` of the same program (opset ``ONNX_OPSET``), where the
  optional packages ``onnx`` and ``onnxscript`` are installed (``pip install 'lnn-torch[export]'``,
  which adds ``onnxruntime`` to run them). Python scalars keep their float64 digits (``_onnx_translations``).
  An operator without an ONNX translation is refused in one line: static friction's holding torques
  (``dissipation: joint+stiction``) solve with ``linalg.solve``, so its forward dynamics has no ONNX form.
* ``aoti``: AOTInductor (``torch._inductor.aoti_compile_and_package``): the program compiled to a
  shared library in a ``NAME.aoti.pt2`` package, loaded by ``load_program`` (``AOTIProgram``). It needs
  a C++ compiler where it is exported (10-20 s per function on one thread for the double pendulum, about
  a minute for the 7-joint arm's grey box), and the package is bound to the torch version and CPU kind
  that compiled it; the fastest form at batch 1 (``results/export.md``). What the weights alone give is
  folded once at load (``AOTI_CONFIG``), strided views of the weights copied first
  (``contiguous_constant_views``: torch 2.13's folding reads them wrongly), and each package is called
  once against the eager model before it is kept (``check_aoti``).

What the programs do not do: check their inputs (shapes, NaN, parameter signs, a scene's valid
states) or warn about parameters beyond the model's trusted range; they condition on the nearest
trusted values as the model does (``describe`` records the range). Call the model
(``lnn_torch.load_model``) where such checks matter.
"""

from __future__ import annotations

import copy
import json
import math
import platform
import warnings
from pathlib import Path

import torch
from torch import nn

from ..errors import InputError
from ..mechanics.euler_lagrange import unrolled_solves
from ..networks.capabilities import FORCES, INVERSE_DYNAMICS, MASS_MATRIX
from ..perf import quiet_compilation

FUNCTIONS = ("forward_dynamics", "inverse_dynamics", "mass_matrix", "bias_force", "gravity_force", "friction_force")
FORMATS = ("pt2", "onnx", "aoti")
SUFFIXES = {"pt2": "pt2", "onnx": "onnx", "aoti": "aoti.pt2"}
DTYPES = {"float32": torch.float32, "float64": torch.float64}
ONNX_OPSET = 18
ONNX_PACKAGES = ("onnx", "onnxscript")  # needed to write ONNX; onnxruntime runs it
MAX_BATCH = 1 << 24  # the largest batch an exported program takes

# what each function needs of the model, beyond accelerations (the forces need inputs: they fix the scale)
_NEEDS = {"inverse_dynamics": (INVERSE_DYNAMICS,), "mass_matrix": (MASS_MATRIX,), "bias_force": (INVERSE_DYNAMICS,),
          "gravity_force": (INVERSE_DYNAMICS,), "friction_force": (INVERSE_DYNAMICS, FORCES)}
# variants whose accelerations need autograd: torch.export (2.13) fails inside their torch.func transforms
_AUTOGRAD = {"lnn": "its accelerations solve the Euler-Lagrange equations through torch.func velocity Hessians",
             "hnn": "its vector field is the torch.func gradient of its Hamiltonian"}


# ---------------------------------------------------------------------------- the functions
class _Function(nn.Module):
    """A copy of a dynamics model (frozen, evaluation mode) behind one plain tensor function: one method
    of the model's SI rigid-body face (``lnn_torch.networks.rigid_body``), unchecked."""

    name = ""
    arguments: tuple[str, ...] = ()
    result = ""

    def __init__(self, model) -> None:
        super().__init__()
        self.model = model


class ForwardDynamics(_Function):
    """``(q, qd, params[, tau]) -> qdd``: the model's accelerations (``tau`` for an actuated scene;
    ``forward``)."""

    name, result = "forward_dynamics", "qdd"

    def __init__(self, model) -> None:
        super().__init__(model)
        self.arguments = ("q", "qd", "params") + (("tau",) if model.scene.num_inputs else ())

    def forward(self, q, qd, params, tau=None):
        return self.model.forward(q, qd, params, tau, check=False)


class InverseDynamics(_Function):
    """``(q, qd, qdd, params) -> tau``: the inputs that make the model accelerate by ``qdd``
    (``inverse``, with the input matrix's pseudo-inverse a constant of the program)."""

    name, arguments, result = "inverse_dynamics", ("q", "qd", "qdd", "params"), "tau"

    def __init__(self, model) -> None:
        super().__init__(model)
        forces = model.forces
        if not forces.identity_inputs:  # LearnedForces.solve_inputs with the pseudo-inverse computed once, here
            pinv = torch.linalg.pinv(forces.current_input_matrix().detach())
            self.register_buffer("input_pinv", pinv.mT.contiguous())

    def forward(self, q, qd, qdd, params):
        input_force = self.model.input_force(q, qd, qdd, params)  # B tau
        if self.model.forces.identity_inputs:
            return input_force
        return input_force @ self.input_pinv.to(input_force.dtype)


class MassMatrix(_Function):
    """``(q, params) -> M (B, dof, dof)``: the learned mass matrix in SI velocities (``mass_matrix``)."""

    name, arguments, result = "mass_matrix", ("q", "params"), "M"

    def forward(self, q, params):
        return self.model.mass_matrix(q, params)


class BiasForce(_Function):
    """``(q, qd, params) -> n``: ``M qdd + n = B tau + Q_f``: Coriolis, centrifugal and gravity forces, no
    friction (``bias``)."""

    name, arguments, result = "bias_force", ("q", "qd", "params"), "n"

    def forward(self, q, qd, params):
        return self.model.bias(q, qd, params)


class GravityForce(_Function):
    """``(q, params) -> g``: the bias force at rest, ``n(q, 0)`` (gravity and the learned potential;
    ``gravity``)."""

    name, arguments, result = "gravity_force", ("q", "params"), "g"

    def forward(self, q, params):
        return self.model.gravity(q, params)


class FrictionForce(_Function):
    """``(q, qd, params) -> Q_f``: the learned dissipative generalised force (``friction``)."""

    name, arguments, result = "friction_force", ("q", "qd", "params"), "Q_f"

    def forward(self, q, qd, params):
        return self.model.friction(q, qd, params)


_CLASSES = {cls.name: cls for cls in (ForwardDynamics, InverseDynamics, MassMatrix, BiasForce, GravityForce,
                                       FrictionForce)}


def _dynamics_model(model):
    """The ``DynamicsModel`` of an ``LNNModule`` (or the model itself)."""
    return getattr(model, "model", model)


def refusal(model, function: str = "forward_dynamics") -> str | None:
    """Why ``function`` of ``model`` (an ``LNNModule`` or a ``DynamicsModel``) cannot be exported (one
    sentence), or None if it can."""
    m = _dynamics_model(model)
    if function not in _CLASSES:
        return f"unknown function '{function}' (choose from {', '.join(FUNCTIONS)})"
    if m.variant in _AUTOGRAD:
        return (f"variant '{m.variant}' cannot be exported: {_AUTOGRAD[m.variant]}, autograd that torch.export "
                "does not trace (export a structured model: film_lnn, delan)")
    needed = _NEEDS.get(function, ())
    reason = m.missing(*needed) if needed else None
    if reason is None and function == "friction_force" and not m.forces.dissipative:
        reason = "it learns no dissipative force (the scene has no friction)"
    if reason is not None:
        return f"{function} is not available for this model: {reason}"
    return None


def available_functions(model) -> tuple[str, ...]:
    """The functions of ``model`` that can be exported, in ``FUNCTIONS`` order."""
    return tuple(f for f in FUNCTIONS if refusal(model, f) is None)


def wrap(model, function: str = "forward_dynamics", dtype: torch.dtype | None = None) -> _Function:
    """``function`` of ``model`` (an ``LNNModule`` or a ``DynamicsModel``) as a small ``nn.Module`` over a
    frozen copy of the model in ``dtype`` (default: the model's own), in evaluation mode. ``InputError``
    (one line) for what cannot be exported."""
    reason = refusal(model, function)
    if reason is not None:
        raise InputError(reason)
    m = copy.deepcopy(_dynamics_model(model))
    m.compile_dynamics(False)
    if dtype is not None:
        m = m.to(dtype)
    m.eval().requires_grad_(False)
    return _CLASSES[function](m).eval()


def example_inputs(fn: _Function, batch: int = 8, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """Arguments of ``fn`` for tracing: random states near rest and the normaliser's mean parameters
    (the values do not matter to the program, only shapes and dtype)."""
    m = fn.model
    dtype, dof = m.dtype, m.scene.dof
    gen = torch.Generator().manual_seed(seed)
    norm = m.normalizer
    with torch.no_grad():
        params = norm.params_to_phys(torch.zeros(m.scene.num_params, dtype=torch.float64)).to(dtype)
    shapes = {"q": dof, "qd": dof, "qdd": dof, "tau": m.scene.num_inputs}
    args = []
    for name in fn.arguments:
        if name == "params":
            args.append(params.expand(batch, -1).clone())
        else:
            args.append(torch.randn(batch, shapes[name], generator=gen, dtype=torch.float64).to(dtype))
    return tuple(args)


def dynamic_shapes(fn: _Function) -> dict:
    """The batch (dimension 0 of every argument) as one ``torch.export.Dim`` from 1 to ``MAX_BATCH``."""
    batch = torch.export.Dim("batch", min=1, max=MAX_BATCH)
    return {name: {0: batch} for name in fn.arguments}


def export_program(fn: _Function, batch: int = 8) -> torch.export.ExportedProgram:
    """``fn`` through ``torch.export.export`` with a dynamic batch, after one eager call (which fills the
    model's caches of constants, e.g. the spatial part's geometry in its dtype: filled while tracing,
    torch.export would warn that they were assigned during export). A failure to trace is an
    ``InputError`` naming the variant and the first line of torch's reason."""
    args = example_inputs(fn, batch)
    try:
        # Cholesky solves as elementwise operators (ONNX has none); einsum's contraction order not chosen by
        # opt_einsum (installed beside jax, e.g.), whose choice for the example's batch fixed the batch to it
        with torch.no_grad(), unrolled_solves(), torch.backends.opt_einsum.flags(enabled=False):
            fn(*args)
            return torch.export.export(fn, args, dynamic_shapes=dynamic_shapes(fn), strict=False)
    except Exception as err:  # noqa: BLE001 (torch.export raises many kinds)
        first = (str(err).strip().splitlines() or [type(err).__name__])[0][:200]
        raise InputError(f"{fn.name} of variant '{fn.model.variant}' could not be exported by torch.export "
                         f"({type(err).__name__}: {first})") from err


def missing_onnx_packages() -> list[str]:
    """The optional packages that writing ONNX needs and this environment lacks."""
    import importlib.util

    return [p for p in ONNX_PACKAGES if importlib.util.find_spec(p) is None]


def _onnx_translations() -> dict:
    """ONNX translations that replace the exporter's own: ``aten.scalar_tensor`` of a Python number as a
    constant of the graph's dtype. The exporter's translation (onnxscript 0.7) makes a float32 constant
    and casts it, so every Python scalar of a float64 program (``eps``, the Coulomb velocity, ...) lost
    its digits beyond float32's, about 1e-8 relative error in float64 ONNX programs."""
    import numpy as np
    import onnx_ir as ir
    from onnxscript import opset18 as op

    def scalar_tensor(s, dtype=ir.DataType.FLOAT, layout: str = "", device: str = "", pin_memory: bool = False):
        dtype = ir.DataType(dtype)
        if isinstance(s, (bool, int, float)):
            return op.Constant(value=ir.tensor(np.asarray(s, dtype=dtype.numpy())))
        return op.Cast(s, to=dtype)

    return {torch.ops.aten.scalar_tensor.default: scalar_tensor}


def _reason(err: BaseException) -> str:
    """The line of a conversion failure that says what failed: the operator without an ONNX translation
    where that is it, else the first line of the innermost error."""
    import re

    seen = err
    while seen is not None:
        found = re.search(r"No ONNX function found for <OpOverload\(op='([\w.]+)', overload='(\w+)'\)>", str(seen))
        if found:
            return f"no ONNX translation of the operator {found.group(1)}.{found.group(2)}"
        if seen.__cause__ is None:
            break
        seen = seen.__cause__
    first = (str(seen).strip().splitlines() or [type(seen).__name__])[0][:200]
    return f"{type(seen).__name__}: {first}"


def onnx_requirement() -> str | None:
    """One line naming the optional packages that writing ONNX needs where they are missing, else None."""
    missing = missing_onnx_packages()
    if not missing:
        return None
    return (f"ONNX export needs the optional package(s) {' and '.join(missing)}: "
            "pip install 'lnn-torch[export]' (or: pip install onnx onnxscript onnxruntime)")


def _valid_onnx(onnx_program) -> bool:
    """Whether ``onnx.checker`` accepts the program's graph. The exporter's optimiser (onnxscript 0.7) can drop the
    bounds of a clamp of a clamped value, leaving Clip nodes that read values nothing produces (the models clamp
    their normalised parameters where each network reads them): such a program is written unoptimised (ONNX
    Runtime optimises a graph when it loads it)."""
    import onnx

    try:
        onnx.checker.check_model(onnx_program.model_proto)
    except onnx.checker.ValidationError:
        return False
    return True


def to_onnx(program: torch.export.ExportedProgram, fn: _Function):
    """The exported program as an ``ONNXProgram`` (``torch.onnx.export(..., dynamo=True)``, opset
    ``ONNX_OPSET``; ``.save(path)`` writes it), its inputs named as ``fn``'s arguments and its output
    as ``fn``'s result. ``InputError`` (one line) where ``onnx``/``onnxscript`` are missing or an
    operator has no ONNX translation (e.g. ``linalg.solve`` of static friction's holding torques)."""
    requirement = onnx_requirement()
    if requirement:
        raise InputError(requirement)
    import logging
    import warnings

    quiet = [logging.getLogger(n) for n in ("torch.onnx", "onnxscript", "onnx_ir")]
    levels = [log.level for log in quiet]
    try:
        for log in quiet:
            log.setLevel(logging.ERROR)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for optimize in (True, False):
                onnx_program = torch.onnx.export(program, (), input_names=list(fn.arguments),
                                                 output_names=[fn.result], opset_version=ONNX_OPSET, dynamo=True,
                                                 verbose=False, custom_translation_table=_onnx_translations(),
                                                 optimize=optimize)
                if _valid_onnx(onnx_program):
                    return onnx_program
            raise ValueError("the ONNX graph the exporter wrote is not valid (onnx.checker)")
    except Exception as err:  # noqa: BLE001
        raise InputError(f"{fn.name} of variant '{fn.model.variant}' could not be converted to ONNX "
                         f"({_reason(err)})") from err
    finally:
        for log, level in zip(quiet, levels, strict=True):
            log.setLevel(level)


def export_onnx(program: torch.export.ExportedProgram, fn: _Function, path: str | Path) -> Path:
    """``to_onnx`` saved to ``path`` (its batch dimension named ``batch``)."""
    path = Path(path)
    to_onnx(program, fn).save(str(path))
    _batch_named(path)
    return path


def _batch_named(path: Path) -> None:
    """The saved ONNX graph's batch dimension named ``batch`` (the exporter names it after its symbol, ``s49``),
    in its inputs, output and every intermediate value, in place."""
    import onnx

    model = onnx.load(str(path))
    symbol = model.graph.input[0].type.tensor_type.shape.dim[0].dim_param
    if not symbol or symbol == "batch":
        return
    for value in [*model.graph.input, *model.graph.output, *model.graph.value_info]:
        for dim in value.type.tensor_type.shape.dim:
            if dim.dim_param == symbol:
                dim.dim_param = "batch"
    onnx.save(model, str(path))


# what is computed from the weights alone (FiLM's maps of its output layers, transposes) folded once when
# the package loads, not at every call: batch-1 inverse dynamics 75 -> 55 us (results/export.md)
AOTI_CONFIG = {"aot_inductor.use_runtime_constant_folding": True}
# the self-check of a compiled package against the eager function (``check_aoti``): far looser than the
# two agree to (1e-7 in float32, 1e-13 in float64 on the arm's grey box), far tighter than a wrong kernel
AOTI_CHECK_TOLERANCE = {torch.float32: 1e-3, torch.float64: 1e-8}


class AOTIProgram:
    """A loaded AOTInductor package called with positional tensors: ``torch._inductor.aoti_load_package``'s
    model less its per-call parsing of the argument structure (about 20 us of a batch-1 call). The package
    itself checks nothing (a float64 input gave NaN or 1e37): where ``export.json`` lies beside it, each call's
    inputs are checked against its entry first (their number, dtype, 2-D shapes with the listed widths, one batch
    size, contiguity; a few microseconds), a mismatch refused in one line (``InputError``); ``check=False``
    leaves that out."""

    def __init__(self, path: str | Path, check: bool = True) -> None:
        path = Path(path)
        self.package = torch._inductor.aoti_load_package(str(path))
        self.loader = self.package.loader
        self.inputs = None
        meta = path.parent / "export.json"
        name = path.name[: -len(".aoti.pt2")] if path.name.endswith(".aoti.pt2") else None
        if check and name and meta.exists():
            entry = json.loads(meta.read_text()).get("functions", {}).get(name)
            if entry is not None:
                self.inputs = [(x["name"], getattr(torch, x["dtype"]), int(x["shape"][1])) for x in entry["inputs"]]

    def __call__(self, *args: torch.Tensor) -> torch.Tensor:
        if self.inputs is not None:
            self._check(args)
        return self.loader.run(list(args))[0]

    def _check(self, args) -> None:
        if len(args) != len(self.inputs):
            raise InputError(f"takes {len(self.inputs)} inputs ({', '.join(n for n, _, _ in self.inputs)}), got "
                             f"{len(args)}")
        batch = None
        for x, (name, dtype, width) in zip(args, self.inputs, strict=True):
            if not isinstance(x, torch.Tensor) or x.dtype != dtype or x.ndim != 2 or x.shape[1] != width:
                got = f"{x.dtype} of shape {tuple(x.shape)}" if isinstance(x, torch.Tensor) else type(x).__name__
                raise InputError(f"{name} must be a {str(dtype).replace('torch.', '')} tensor of shape (batch, "
                                 f"{width}), got {got}")
            batch = x.shape[0] if batch is None else batch
            if x.shape[0] != batch or not 1 <= batch <= MAX_BATCH:
                raise InputError(f"{name} has batch {x.shape[0]}: every input needs the same batch, 1 to "
                                 f"{MAX_BATCH}")
            if not x.is_contiguous():
                raise InputError(f"{name} must be contiguous (x.contiguous())")


def _constant_nodes(program: torch.export.ExportedProgram) -> set:
    """The nodes of ``program``'s graph computed from its weights, buffers and lifted constants alone (what
    AOTInductor's runtime constant folding may fold; creation ops without inputs excluded, as there)."""
    signature = program.graph_signature
    names = (set(signature.inputs_to_parameters) | set(signature.inputs_to_buffers)
             | set(signature.inputs_to_lifted_tensor_constants))
    constant = set()
    for node in program.graph.nodes:
        if node.op == "placeholder":
            if node.name in names:
                constant.add(node)
        elif node.op == "call_function" and node.all_input_nodes and all(i in constant for i in node.all_input_nodes):
            constant.add(node)
    return constant


def contiguous_constant_views(program: torch.export.ExportedProgram) -> int:
    """Give every strided view of the weights that the rest of ``program`` reads a contiguous copy of its
    own, in place; returns how many. AOTInductor's runtime constant folding (``AOTI_CONFIG``; torch 2.13)
    materialises such a view (e.g. the columns ``raw[:, 4:]`` of a weight: strides ``(10, 1)``) with a
    contiguous clone, while the compiled kernels that read it keep the view's strides: they read the
    wrong entries, past its end from some row on (the arm's grey box: wrong link inertias, then
    "linalg.cholesky: ... not positive-definite"; the ``.pt2`` program and eager are right). A copy
    computed from the view is a buffer of its own, contiguous in the folded constants and in the kernels."""
    graph = program.graph
    constant = _constant_nodes(program)
    count = 0
    for node in [n for n in graph.nodes if n in constant]:
        val = node.meta.get("val")
        readers = [u for u in node.users if u not in constant]
        if not isinstance(val, torch.Tensor) or val.is_contiguous() or not readers:
            continue
        with graph.inserting_after(node):
            copy_ = graph.call_function(torch.ops.aten.clone.default, (node,),
                                        {"memory_format": torch.contiguous_format})
        with val.fake_mode:
            copy_.meta["val"] = val.clone(memory_format=torch.contiguous_format)
        for user in readers:
            user.replace_input_with(node, copy_)
        count += 1
    if count:
        graph.lint()
        program.graph_module.recompile()
    return count


def check_aoti(path: str | Path, fn: _Function, batch: int = 8) -> float:
    """The largest difference between the package at ``path`` and the eager ``fn`` on ``example_inputs``
    (seeded states near rest), relative to the largest entry of the eager result; ``InputError`` (one
    line) where the package fails or exceeds ``AOTI_CHECK_TOLERANCE`` (a wrong compilation)."""
    args = example_inputs(fn, batch, seed=1)
    try:
        with torch.no_grad():
            expected, got = fn(*args), AOTIProgram(path)(*args)
        error = float((got - expected).abs().max() / expected.abs().max().clamp_min(1e-30))
    except Exception as err:  # noqa: BLE001 (the compiled library raises RuntimeError of any kind)
        raise InputError(f"{fn.name}: the AOTInductor package fails on its first call ({_reason(err)})") from err
    if not error <= AOTI_CHECK_TOLERANCE.get(expected.dtype, 1e-3):
        raise InputError(f"{fn.name}: the AOTInductor package disagrees with the model (largest difference "
                         f"{error:.2g} of the largest value); the .pt2 program is the reference")
    return error


def compile_aoti(program: torch.export.ExportedProgram, fn: _Function, path: str | Path, check: bool = True) -> Path:
    """The exported program compiled ahead of time by AOTInductor into a package at ``path``
    (``torch._inductor.aoti_compile_and_package``; load it with ``load_program``), its strided views of
    the weights copied first (``contiguous_constant_views``, on a copy: ``program`` is unchanged), and with
    ``check`` called once against the eager ``fn`` (``check_aoti``; a package that fails it is removed).
    Needs a C++ compiler here; ``InputError`` (one line) where the compilation or the check fails."""
    path = Path(path)
    try:
        with quiet_compilation():
            program = copy.deepcopy(program)
            contiguous_constant_views(program)
            path = Path(torch._inductor.aoti_compile_and_package(program, package_path=str(path),
                                                                 inductor_configs=dict(AOTI_CONFIG)))
    except Exception as err:  # noqa: BLE001
        raise InputError(f"{fn.name} could not be compiled by AOTInductor ({_reason(err)})") from err
    if check:
        try:
            check_aoti(path, fn)
        except InputError:
            path.unlink(missing_ok=True)
            raise
    return path


# ---------------------------------------------------------------------------- the description
def _units(system, model) -> dict:
    coord = list(system.coord_units)
    force = ["N m" if u == "rad" else "N" for u in coord]
    return {"q": coord, "qd": [f"{u}/s" for u in coord], "qdd": [f"{u}/s^2" for u in coord],
            "params": list(system.param_units), "tau": list(system.input_units), "force": force}


def describe_function(fn: _Function, system) -> dict:
    """Inputs and output of an exported function: names, shapes (``batch`` dynamic), dtype, units."""
    m = fn.model
    dof, units = m.scene.dof, _units(system, m)
    dtype = str(m.dtype).replace("torch.", "")
    names = {"q": list(system.coord_names), "qd": [f"{n}_dot" for n in system.coord_names],
             "qdd": [f"{n}_ddot" for n in system.coord_names], "params": list(system.param_names),
             "tau": list(system.input_names)}
    text = {"q": "generalised coordinates", "qd": "their velocities", "qdd": "their accelerations",
            "params": "physical parameters of the system (the model conditions on them)",
            "tau": "inputs (motor torques)"}
    inputs = [{"name": a, "shape": ["batch", len(names[a])], "dtype": dtype, "units": units[a],
               "components": names[a], "description": text[a]} for a in fn.arguments]
    scaled = bool(m.scene.num_inputs)
    matrix_units = ("SI: M[i][j] in (force unit i) s^2 / (coordinate unit j), e.g. kg m^2 between angles" if scaled
                    else "the model's own units: without inputs the learned Lagrangian's scale is free "
                         "(M up to one positive factor per system)")
    outputs = {
        "forward_dynamics": ("qdd", ["batch", dof], units["qdd"], "accelerations"),
        "inverse_dynamics": ("tau", ["batch", system.num_inputs], units["tau"],
                             "the inputs that give the accelerations qdd: B tau = M qdd + n - Q_f (least squares "
                             "through the input matrix where there are fewer inputs than coordinates); static "
                             "friction's holding torques excluded"),
        "mass_matrix": ("M", ["batch", dof, dof], matrix_units,
                        "the learned mass matrix (symmetric positive definite)"),
        "bias_force": ("n", ["batch", dof], units["force"],
                       "M qdd + n(q, qd) = B tau + Q_f(q, qd): Coriolis, centrifugal and gravity forces, no friction "
                       "(n = -M a_0, a_0 the accelerations under no force at all)"),
        "gravity_force": ("g", ["batch", dof], units["force"], "n(q, 0): the forces at rest (gravity, the learned "
                                                                  "potential)"),
        "friction_force": ("Q_f", ["batch", dof], units["force"],
                           "M qdd + n(q, qd) = B tau + Q_f(q, qd): the learned dissipative generalised force (joint "
                           "friction through the joint map, learned damping; qd . Q_f <= 0); static friction's "
                           "holding torques excluded"),
    }[fn.name]
    return {"inputs": inputs, "output": {"name": outputs[0], "shape": outputs[1], "dtype": dtype,
                                         "units": outputs[2], "description": outputs[3]}}


def _bounds(values: torch.Tensor, kinds, floor: float | None = None) -> list:
    """Trusted-range bounds for JSON: None where unbounded (a parameter taken exactly), a lower bound of
    a nonnegative parameter at least ``floor``."""
    out = []
    for v, kind in zip(values.tolist(), kinds, strict=True):
        if not math.isfinite(v):
            out.append(None)
        else:
            out.append(max(v, floor) if floor is not None and kind in ("nonnegative", "positive") else v)
    return out


def describe(module, functions: dict, source: str = "", files: dict | None = None) -> dict:
    """What ``lnn-torch export`` writes beside the programs: each function's inputs and output, the scene's
    conventions, the model, the trusted parameter range and the versions that wrote them. ``functions``:
    ``{name: wrapped function}``; ``files``: ``{name: [file names]}``."""
    from .._version import __version__

    system = module.system
    m = _dynamics_model(module)
    low, high = m.normalizer.trusted_range()
    out = {
        "lnn_torch_version": __version__, "torch_version": torch.__version__, "python": platform.python_version(),
        "checkpoint": source, "variant": m.variant,
        "scene": {"name": system.name, "dof": system.dof, "conventions": system.conventions,
                  "coord_names": list(system.coord_names), "coord_units": list(system.coord_units),
                  "param_names": list(system.param_names), "param_units": list(system.param_units),
                  "input_names": list(system.input_names),
                  "input_matrix": None if not system.num_inputs else system.input_matrix().tolist()},
        "trusted_params": {"low": _bounds(low, system.kinds, 0.0), "high": _bounds(high, system.kinds),
                           "note": "beyond this range the model conditions on the nearest trusted values; the "
                                   "programs do not warn (null: a parameter taken exactly, at any value)"},
        "batch": {"min": 1, "max": MAX_BATCH},
        "notes": "the programs check no values (NaN, parameter signs, valid states): lnn_torch.load_model checks "
                 "them. Each takes its inputs in the order listed, as 2-D arrays (batch, n) of the dtype listed.",
        "loading": {
            "pt2": "torch.export.load(path).module()(*inputs): shapes and dtype checked",
            "aoti.pt2": "torch._inductor.aoti_load_package(path)(*inputs) (C++: torch::inductor::"
                        "AOTIModelPackageLoader): checks nothing, a wrong dtype or shape gives wrong numbers, not an "
                        "error; lnn_torch.export.programs.AOTIProgram(path) checks them against this file beside it",
            "onnx": "onnxruntime.InferenceSession(path).run(None, {name: array, ...}) with contiguous arrays of the "
                    "dtype listed; the batch dimension is named batch",
        },
        "functions": {},
    }
    for name, fn in functions.items():
        out["functions"][name] = {**describe_function(fn, system), "files": list((files or {}).get(name, []))}
    return out


# ---------------------------------------------------------------------------- all of it
def output_name(function: str, fmt: str) -> str:
    """The file of ``function`` in format ``fmt``: ``NAME.pt2``, ``NAME.onnx``, ``NAME.aoti.pt2``."""
    return f"{function}.{SUFFIXES[fmt]}"


def export_model(module, output_dir: str | Path, functions=None, formats=("pt2",), dtype=None, source: str = "",
                 overwrite: bool = False) -> list[Path]:
    """Export ``functions`` (default: every one ``module`` has) of an ``LNNModule`` to ``output_dir``: a
    file per function and format (``output_name``) and ``export.json`` (``describe``). ``dtype``:
    ``torch.float32``/``float64`` or its name (default: the model's own). Every refusal (a function
    the model lacks, a variant that needs autograd, ONNX without its packages or an operator without
    an ONNX translation, files that exist without ``overwrite``) comes before anything is written
    (AOTInductor compiles last). Returns the paths written."""
    if isinstance(dtype, str):
        if dtype not in DTYPES:
            raise InputError(f"dtype must be one of {', '.join(DTYPES)}, got '{dtype}'")
        dtype = DTYPES[dtype]
    formats = tuple(dict.fromkeys(formats))
    unknown = [f for f in formats if f not in FORMATS]
    if unknown or not formats:
        raise InputError(f"format must be among {', '.join(FORMATS)}, got {', '.join(unknown) or 'none'}")
    chosen = functions is not None  # (every function by default: one ONNX cannot express is left out of ONNX)
    if functions is None:
        reason = refusal(module)
        if reason is not None:
            raise InputError(reason)
        functions = available_functions(module)
    functions = tuple(dict.fromkeys(functions))
    for name in functions:
        reason = refusal(module, name)
        if reason is not None:
            raise InputError(reason)
    if "onnx" in formats and onnx_requirement():
        raise InputError(onnx_requirement())
    output_dir = Path(output_dir)
    targets = [output_dir / output_name(n, f) for n in functions for f in formats] + [output_dir / "export.json"]
    existing = [str(p) for p in targets if p.exists()]
    if existing and not overwrite:
        raise FileExistsError(f"{', '.join(existing)} exist; refusing to overwrite (pass --overwrite)")
    wrapped, programs, onnx_programs, not_onnx = {}, {}, {}, {}
    for name in functions:  # everything that can fail, before a file is written
        fn = wrapped[name] = wrap(module, name, dtype)
        programs[name] = export_program(fn)
        if "onnx" in formats:
            try:
                onnx_programs[name] = to_onnx(programs[name], fn)
            except InputError as err:
                if chosen:
                    raise
                not_onnx[name] = str(err)
    if not_onnx and len(not_onnx) == len(functions):
        raise InputError(next(iter(not_onnx.values())))
    output_dir.mkdir(parents=True, exist_ok=True)
    files, written = {name: [] for name in functions}, []
    for fmt in formats:
        for name in functions:
            if fmt == "onnx" and name in not_onnx:
                continue
            path = output_dir / output_name(name, fmt)
            if fmt == "pt2":
                with warnings.catch_warnings():  # torch's note on weights that share storage: they are on the CPU
                    warnings.filterwarnings("ignore", message="No complete tensor found in the group")
                    torch.export.save(programs[name], path)
            elif fmt == "onnx":
                onnx_programs[name].save(str(path))
                _batch_named(path)
            else:
                compile_aoti(programs[name], wrapped[name], path)
            files[name].append(path.name)
            written.append(path)
    meta = describe(module, wrapped, source, files)
    meta["dtype"] = str(next(iter(wrapped.values())).model.dtype).replace("torch.", "")
    if not_onnx:
        meta["not_in_onnx"] = not_onnx
    meta_path = output_dir / "export.json"
    meta_path.write_text(json.dumps(meta, indent=2) + "\n")
    return [*written, meta_path]


def load_program(path: str | Path):
    """A saved program as a callable of the function's arguments: ``NAME.aoti.pt2`` as an ``AOTIProgram``,
    another ``.pt2`` through ``torch.export.load(path).module()``."""
    path = str(path)
    if path.endswith(".aoti.pt2"):
        return AOTIProgram(path)
    return torch.export.load(path).module()
