"""``lnn_torch.export.programs`` and ``lnn-torch export``: the exported programs equal the eager model (float64 to
1e-10, float32 to 1e-5) for the shipped double pendulum and an untrained actuated structured model
(forward and inverse dynamics, mass matrix, bias and gravity forces), saved programs load back and
take any batch, refusals come in one line; ONNX through onnxruntime where installed; the 7-joint arm's
grey box (every function as ``.pt2`` and AOTInductor packages, equal on arm states; the strided views of
its weights that AOTInductor's constant folding once read wrongly). One thread: about 17 s, 36 s with the
ONNX packages; the slow tests about 20 s for the double pendulum's AOTInductor package and several
minutes for the arm's six."""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from lnn_torch.cli import main
from lnn_torch.export import programs as ex
from lnn_torch.systems import get_system
from lnn_torch.training.checkpoints import load_model

from .helpers import perturbed, random_batch, random_inputs, save_checkpoint

ADP = get_system("actuated_double_pendulum")
TOL = {torch.float64: dict(rtol=1e-10, atol=1e-10), torch.float32: dict(rtol=1e-5, atol=1e-5)}


def assert_close_float32(out, ref, what: str):
    """A float32 program against the eager float32 model, within float32's round-off of the largest value: a
    compiled program sums and fuses in another order, and the arm's solves amplify round-off by the
    condition number of M (up to about 1e3 on arm states): AOTInductor's forward dynamics differs from eager
    by up to 2e-7 of the largest acceleration, as far from the float64 model as eager float32 is."""
    scale = float(ref.abs().max())
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5 * scale, msg=lambda m: f"{what}: {m}")


def untrained_module(variant="film_lnn", scene="actuated_double_pendulum", seed=0, hidden_dims=(16, 16), **options):
    """An ``LNNModule`` with small random (perturbed) networks and its normaliser fitted on the scene's
    distribution, inputs included: every path of the model matters."""
    from lnn_torch import LNNModule

    torch.manual_seed(seed)
    module = LNNModule(scene=scene, variant=variant, hidden_dims=None if hidden_dims is None else list(hidden_dims),
                       model_options=options or None)
    system = module.system
    rng = np.random.default_rng(seed)
    q, qd, params = random_batch(system, rng, 256)
    tau = random_inputs(system, rng, 256)
    stats = {"q": q, "qd": qd, "qdd": system.acceleration(q, qd, params, tau), "params": params,
             "params_points": params}
    if tau is not None:
        stats["tau"] = tau
    module.model.fit_normalizer(stats)
    perturbed(module.model, 0.1, seed)
    return module.eval()


@pytest.fixture(scope="module")
def models():
    return {"double_pendulum": load_model("pretrained:double_pendulum"), "actuated": untrained_module()}


def states(module, n, dtype, seed=1):
    """Random states, parameters, inputs and accelerations of the module's scene in ``dtype``."""
    system = module.system
    rng = np.random.default_rng(seed)
    q, qd, params = random_batch(system, rng, n)
    tau = random_inputs(system, rng, n)
    qdd = torch.tensor(rng.normal(0.0, 5.0, (n, system.dof)))
    cast = lambda x: None if x is None else x.to(dtype)  # noqa: E731
    return cast(q), cast(qd), cast(params), cast(tau), cast(qdd)


def eager(model, function, q, qd, params, tau, qdd):
    """``function`` by the model's own public methods (``model``: a ``DynamicsModel`` in the dtype): its SI
    rigid-body face."""
    if function == "forward_dynamics":
        return model.acceleration(q, qd, params, tau)
    if function == "inverse_dynamics":
        return model.inverse(q, qd, qdd, params)
    if function == "bias_force":
        return model.bias(q, qd, params)
    if function == "gravity_force":
        return model.gravity(q, params)
    if function == "friction_force":
        return model.friction(q, qd, params)
    return model.mass_matrix(q, params)


def arguments(function, q, qd, params, tau, qdd):
    return {"forward_dynamics": (q, qd, params) + (() if tau is None else (tau,)),
            "inverse_dynamics": (q, qd, qdd, params), "mass_matrix": (q, params), "bias_force": (q, qd, params),
            "gravity_force": (q, params), "friction_force": (q, qd, params)}[function]


def assert_programs_equal_eager(module, state, dtype, functions=ex.FUNCTIONS):
    """Each function's ``torch.export`` program of ``module`` in ``dtype`` equals the eager model at
    ``state = (q, qd, params, tau, qdd)`` to ``TOL[dtype]``, finite."""
    model = copy.deepcopy(module.model).to(dtype)
    for function in functions:
        program = ex.export_program(ex.wrap(module, function, dtype)).module()
        with torch.no_grad():
            out = program(*arguments(function, *state))
            ref = eager(model, function, *state)
        torch.testing.assert_close(out, ref, **TOL[dtype], msg=f"{function} {dtype}")
        assert torch.isfinite(out).all()


def assert_onnx_equals_eager(ort, module, folder, functions, states_):
    """Each ``FUNCTION.onnx`` in ``folder`` (float64) run by ONNX Runtime on one thread equals the eager
    model at every state ``(q, qd, params, tau, qdd)`` of ``states_`` to ``TOL[float64]``."""
    model = copy.deepcopy(module.model).double()
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    for function in functions:
        session = ort.InferenceSession(str(folder / f"{function}.onnx"), options, providers=["CPUExecutionProvider"])
        names = [i.name for i in session.get_inputs()]
        for state in states_:
            args = arguments(function, *state)
            (out,) = session.run(None, {n: a.numpy() for n, a in zip(names, args, strict=True)})
            with torch.no_grad():
                ref = eager(model, function, *state)
            torch.testing.assert_close(torch.from_numpy(out), ref, **TOL[torch.float64], msg=function)


# ---------------------------------------------------------------------------- the programs
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("name", ["double_pendulum", "actuated"])
def test_exported_programs_equal_the_eager_model(models, name, dtype):
    module = models[name]
    model = copy.deepcopy(module.model).to(dtype)
    expected = {"double_pendulum": ("forward_dynamics", "mass_matrix"),
                "actuated": ("forward_dynamics", "inverse_dynamics", "mass_matrix", "bias_force", "gravity_force",
                             "friction_force")}[name]
    assert ex.available_functions(module) == expected
    q, qd, params, tau, qdd = states(module, 33, dtype)
    for function in expected:
        program = ex.export_program(ex.wrap(module, function, dtype)).module()
        args = arguments(function, q, qd, params, tau, qdd)
        with torch.no_grad():
            out, ref = program(*args), eager(model, function, q, qd, params, tau, qdd)
        assert out.dtype == dtype and out.shape == ref.shape
        torch.testing.assert_close(out, ref, **TOL[dtype], msg=f"{name} {function}")


def test_bias_gravity_and_friction_forces_are_what_the_mass_matrix_and_accelerations_give(models):
    """The one convention ``M qdd + n = B tau + Q_f`` (float64): ``n = Q_f - M a(q, qd, tau=0)`` (no friction
    in ``n``), ``g = n(q, 0)``, ``Q_f`` the learned joint friction ``-D^T (b r + c tanh(r / v))`` at the joint
    rates ``r = D qd`` (an independent formula of its coefficients), and ``B tau = M qdd + n - Q_f`` through
    the exported inverse dynamics."""
    module = models["actuated"]
    model = copy.deepcopy(module.model).double()
    q, qd, params, _, qdd = states(module, 33, torch.float64)
    zero_tau = torch.zeros(33, ADP.num_inputs, dtype=torch.float64)
    fns = {f: ex.export_program(ex.wrap(module, f, torch.float64)).module()
           for f in ("bias_force", "gravity_force", "friction_force", "inverse_dynamics")}
    with torch.no_grad():
        b, c = model.friction_coefficients(params)
        D = ADP.joint_map().double()
        rates = qd @ D.T
        Qf = -(b * rates + c * torch.tanh(rates / ADP.coulomb_velocity)) @ D
        torch.testing.assert_close(fns["friction_force"](q, qd, params), Qf, rtol=1e-9, atol=1e-12)
        assert (Qf.abs() > 1e-3).any() and ((Qf * qd).sum(-1) <= 0).all()  # friction matters here, and dissipates
        M = model.mass_matrix(q, params)
        n = Qf - (M @ model.acceleration(q, qd, params, zero_tau)[..., None])[..., 0]
        g = -(M @ model.acceleration(q, torch.zeros_like(qd), params, zero_tau)[..., None])[..., 0]
        torch.testing.assert_close(fns["bias_force"](q, qd, params), n, rtol=1e-9, atol=1e-10 * float(n.abs().max()))
        torch.testing.assert_close(fns["gravity_force"](q, params), g, rtol=1e-9, atol=1e-10 * float(g.abs().max()))
        tau = fns["inverse_dynamics"](q, qd, qdd, params)  # identity input matrix: B tau = tau
        Mqdd = (M @ qdd[..., None])[..., 0]
        torch.testing.assert_close(tau, Mqdd + n - Qf, rtol=1e-9, atol=1e-10 * float(tau.abs().max()))


def test_control_and_export_take_the_same_face(models):
    """Control's plant of a structured model with friction and the exported programs agree on M, n, g and Q_f
    (they once disagreed: export's bias held the learned friction, the plant's did not)."""
    from lnn_torch.control import plant_of

    module = models["actuated"]
    model = copy.deepcopy(module.model).double()
    plant = plant_of(model)
    q, qd, params, tau, _ = states(module, 17, torch.float64, seed=5)
    programs = {f: ex.export_program(ex.wrap(module, f, torch.float64)).module()
                for f in ("mass_matrix", "bias_force", "gravity_force", "friction_force")}
    with torch.no_grad():
        pairs = {"mass_matrix": (plant.mass_matrix(q, params), programs["mass_matrix"](q, params)),
                 "bias_force": (plant.bias(q, qd, params), programs["bias_force"](q, qd, params)),
                 "gravity_force": (plant.gravity(q, params), programs["gravity_force"](q, params)),
                 "friction_force": (plant.friction(q, qd, params), programs["friction_force"](q, qd, params))}
        for name, (from_plant, from_program) in pairs.items():
            torch.testing.assert_close(from_plant, from_program, **TOL[torch.float64], msg=name)
        assert pairs["friction_force"][0].abs().max() > 1e-3  # the friction is there to disagree about
        # and both describe the plant's (the model's) motion: M qdd + n = B tau + Q_f
        qdd = plant.forward(q, qd, params, tau)
        lhs = (pairs["mass_matrix"][1] @ qdd[..., None])[..., 0] + pairs["bias_force"][1]
        torch.testing.assert_close(lhs, tau @ plant.input_matrix.T + pairs["friction_force"][1])


def test_saved_programs_load_back_and_take_any_batch(models, tmp_path):
    module = models["actuated"]
    files = ex.export_model(module, tmp_path, functions=["forward_dynamics", "inverse_dynamics"], dtype="float64",
                            source="test")
    assert [p.name for p in files] == ["forward_dynamics.pt2", "inverse_dynamics.pt2", "export.json"]
    model = copy.deepcopy(module.model).double()
    for function in ("forward_dynamics", "inverse_dynamics"):
        program = torch.export.load(tmp_path / f"{function}.pt2").module()
        for batch in (1, 5, 300):  # traced at 8
            q, qd, params, tau, qdd = states(module, batch, torch.float64, seed=batch)
            with torch.no_grad():
                out = program(*arguments(function, q, qd, params, tau, qdd))
                torch.testing.assert_close(out, eager(model, function, q, qd, params, tau, qdd), **TOL[torch.float64])
    meta = json.loads((tmp_path / "export.json").read_text())
    fwd = meta["functions"]["forward_dynamics"]
    assert [x["name"] for x in fwd["inputs"]] == ["q", "qd", "params", "tau"]
    assert fwd["inputs"][0] == {"name": "q", "shape": ["batch", 2], "dtype": "float64", "units": ["rad", "rad"],
                                "components": ["q1", "q2"], "description": "generalised coordinates"}
    assert fwd["inputs"][3]["components"] == ["tau1", "tau2"] and fwd["output"]["units"] == ["rad/s^2", "rad/s^2"]
    assert fwd["files"] == ["forward_dynamics.pt2"]
    assert meta["functions"]["inverse_dynamics"]["output"]["name"] == "tau"
    assert meta["scene"]["name"] == "actuated_double_pendulum" and "joint angles" in meta["scene"]["conventions"]
    from lnn_torch._version import __version__

    assert meta["lnn_torch_version"] == __version__ and meta["dtype"] == "float64"


# ---------------------------------------------------------------------------- the command
def test_export_command_writes_the_programs_and_their_description(models, tmp_path, capsys):
    ckpt = save_checkpoint(models["actuated"], tmp_path / "actuated.ckpt")
    out = tmp_path / "out"
    assert main(["export", ckpt, "-o", str(out), "--functions", "inverse_dynamics", "bias_force"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("inverse_dynamics  (q[batch, 2], qd[batch, 2], qdd[batch, 2], params[batch, 11]) "
                               "-> tau[batch, 2]  float32")
    assert lines[-1] == f"wrote {out / 'inverse_dynamics.pt2'}, {out / 'bias_force.pt2'}, {out / 'export.json'}"
    # the same again refuses to overwrite, in one line
    assert main(["export", ckpt, "-o", str(out), "--functions", "inverse_dynamics"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--overwrite" in err


@pytest.mark.parametrize("case", ["inverse_of_conservative", "lnn", "hnn", "onnx_missing"])
def test_what_cannot_be_exported_is_refused_in_one_line(case, tmp_path, capsys, monkeypatch):
    argv = ["export", "pretrained:double_pendulum", "-o", str(tmp_path / "out")]
    if case == "inverse_of_conservative":
        argv += ["--functions", "inverse_dynamics"]
        expected = "inverse_dynamics is not available for this model: scene 'double_pendulum' has no inputs"
    elif case == "onnx_missing":
        monkeypatch.setattr(ex, "missing_onnx_packages", lambda: ["onnxscript"])
        argv += ["--format", "pt2", "onnx"]
        expected = "ONNX export needs the optional package(s) onnxscript: pip install 'lnn-torch[export]'"
    else:
        module = untrained_module(case, scene="double_pendulum")
        argv[1] = save_checkpoint(module, tmp_path / f"{case}.ckpt")
        expected = f"variant '{case}' cannot be exported: "
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("lnn-torch export: error: ") and expected in err, err
    assert not (tmp_path / "out").exists()  # nothing written


# ---------------------------------------------------------------------------- ONNX, AOTInductor
def test_onnx_programs_equal_the_eager_model_through_onnxruntime(models, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    pytest.importorskip("onnxscript")
    module = models["actuated"]
    functions = ["forward_dynamics", "inverse_dynamics", "mass_matrix"]
    ex.export_model(module, tmp_path, functions=functions, formats=["onnx"], dtype="float64")
    assert_onnx_equals_eager(ort, module, tmp_path, functions,
                             [states(module, batch, torch.float64, seed=batch) for batch in (1, 50)])


def test_an_operator_without_onnx_translation_is_refused_in_one_line(tmp_path):
    """Static friction's holding torques solve with ``linalg.solve``, which ONNX cannot express."""
    pytest.importorskip("onnxscript")
    module = untrained_module(dissipation="joint+stiction")
    with pytest.raises(ex.InputError, match=r"^forward_dynamics of variant 'film_lnn' could not be converted to "
                                            r"ONNX \(no ONNX translation of the operator aten._linalg_solve_ex"):
        ex.export_model(module, tmp_path, functions=["forward_dynamics"], formats=["onnx"])
    assert not list(tmp_path.iterdir())


def test_the_real_pendulums_chain_model_exports_every_function_and_onnx_what_it_can(tmp_path, capsys):
    """The README's control model (a planar chain part, static friction): every function as a program that takes
    any batch (with opt_einsum installed, as beside jax, its three-operand einsum fixed the batch to the traced 8
    and the export failed); by default ONNX gets every function it can express, the forward dynamics (static
    friction's linalg.solve) left out and said so, the batch dimension named batch."""
    module = load_model("pretrained:real_double_pendulum")
    formats = ["pt2", "onnx"] if not ex.missing_onnx_packages() else ["pt2"]
    assert main(["export", "pretrained:real_double_pendulum", "-o", str(tmp_path), "--format", *formats]) == 0
    out = capsys.readouterr().out
    functions = ex.available_functions(module)
    assert len(functions) == 6
    model = copy.deepcopy(module.model)
    for function in functions:
        program = torch.export.load(tmp_path / f"{function}.pt2").module()
        for batch in (1, 13):
            g = torch.Generator().manual_seed(batch)
            q, qd, tau, qdd = (torch.randn(batch, 2, generator=g) for _ in range(4))
            params = torch.zeros(batch, 0)
            with torch.no_grad():
                torch.testing.assert_close(program(*arguments(function, q, qd, params, tau, qdd)),
                                           eager(model, function, q, qd, params, tau, qdd), **TOL[torch.float32])
    if "onnx" not in formats:
        return
    import onnx

    meta = json.loads((tmp_path / "export.json").read_text())
    assert list(meta["not_in_onnx"]) == ["forward_dynamics"] and "aten._linalg_solve_ex" in \
        meta["not_in_onnx"]["forward_dynamics"]
    assert "note: forward_dynamics left out of ONNX (the other formats have it): " in out
    assert sorted(p.name for p in tmp_path.glob("*.onnx")) == sorted(f"{f}.onnx" for f in functions[1:])
    graph = onnx.load(str(tmp_path / "inverse_dynamics.onnx")).graph
    assert {d.dim_param for v in [*graph.input, *graph.output] for d in v.type.tensor_type.shape.dim[:1]} == {"batch"}
    assert set(meta["loading"]) == {"pt2", "aoti.pt2", "onnx"}


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("g++") is None and shutil.which("clang++") is None, reason="no C++ compiler")
def test_aoti_package_equals_the_eager_model(models, tmp_path):
    """AOTInductor (about 20 s: a C++ compilation)."""
    module = models["double_pendulum"]
    files = ex.export_model(module, tmp_path, functions=["forward_dynamics"], formats=["aoti"], dtype="float64")
    assert files[0].name == "forward_dynamics.aoti.pt2"
    program = ex.load_program(files[0])
    model = copy.deepcopy(module.model).double()
    for batch in (1, 64):
        q, qd, params, tau, qdd = states(module, batch, torch.float64, seed=batch)
        with torch.no_grad():
            torch.testing.assert_close(program(q, qd, params), model.acceleration(q, qd, params), **TOL[torch.float64])
    # the package checks nothing (float32 inputs gave garbage): AOTIProgram checks them against export.json
    for args, message in (((q.float(), qd, params), r"^q must be a float64 tensor of shape \(batch, 2\), got "
                                                     r"torch.float32 of shape \(64, 2\)$"),
                          ((q, qd[:3], params), r"^qd has batch 3: every input needs the same batch"),
                          ((q, qd), r"^takes 3 inputs \(q, qd, params\), got 2$"),
                          ((q.mT.contiguous().mT, qd, params), r"^q must be contiguous")):
        with pytest.raises(ex.InputError, match=message):
            program(*args)


# ---------------------------------------------------------------------------- the arm's grey box
ARM_PARTS = {"kinetic": {"spatial": {}}, "potential": {"spatial": {}}}


@pytest.fixture(scope="module")
def arm_grey_box():
    """The 7-joint arm's grey box (the description's rigid body, every link's inertia learned), its
    inertias, armature and friction perturbed away from the description's, normaliser fitted."""
    pytest.importorskip("mujoco")
    return untrained_module(scene="robot_arm", hidden_dims=None, **ARM_PARTS)


def arm_states(module, n, dtype, seed=1):
    """States of the arm within its joint ranges (0.1 rad inside each end), velocities up to 1.5 rad/s,
    payloads from the scene's ranges, torques up to 20 N m and accelerations N(0, 3) rad/s^2."""
    system = module.system
    rng = np.random.default_rng(seed)
    q = torch.tensor(system.arm.sample_q(rng, n, margin=0.1))
    qd = torch.tensor(rng.uniform(-1.5, 1.5, (n, system.dof)))
    params = torch.tensor(system.sample_params(rng, n))
    tau = torch.tensor(rng.uniform(-20.0, 20.0, (n, system.num_inputs)))
    qdd = torch.tensor(rng.normal(0.0, 3.0, (n, system.dof)))
    return tuple(x.to(dtype) for x in (q, qd, params, tau, qdd))


def test_strided_views_of_the_arms_weights_get_contiguous_copies_for_aoti(arm_grey_box):
    """The grey box reads its log-Cholesky factors' off-diagonal entries as the columns ``raw[:, 4:]`` of one
    weight: AOTInductor's runtime constant folding reads such a strided view wrongly (the arm's package
    once failed its first call: "linalg.cholesky: ... not positive-definite"). The copies compute the same."""
    fn = ex.wrap(arm_grey_box, "mass_matrix")
    program = ex.export_program(fn)

    def strided_reads(program):  # strided views of the weights that the rest of the program reads
        constant = ex._constant_nodes(program)
        return [n.name for n in constant if isinstance(n.meta.get("val"), torch.Tensor)
                and not n.meta["val"].is_contiguous() and any(u not in constant for u in n.users)]

    copied = copy.deepcopy(program)
    before = strided_reads(program)
    assert any(name.startswith("slice") for name in before), before  # raw[:, 4:]
    assert ex.contiguous_constant_views(copied) == len(before)
    assert strided_reads(copied) == [] and strided_reads(program) == before  # the original is left as it was
    q, _, params, _, _ = arm_states(arm_grey_box, 9, torch.float32)
    with torch.no_grad():
        torch.testing.assert_close(copied.module()(q, params), program.module()(q, params), rtol=0, atol=0)
        torch.testing.assert_close(copied.module()(q, params), fn(q, params))  # (its factors entry by entry)


@pytest.mark.parametrize("fault", ["fails", "disagrees"])
def test_a_package_that_fails_or_disagrees_with_the_model_is_refused_and_removed(models, tmp_path, monkeypatch,
                                                                                 fault):
    """``compile_aoti`` calls each package once against the eager function before keeping it."""
    def fake_compile(program, package_path, inductor_configs):
        Path(package_path).write_bytes(b"package")
        return package_path

    class FakeProgram:
        def __init__(self, path):
            pass

        def __call__(self, *args):
            if fault == "fails":
                raise RuntimeError("linalg.cholesky: (Batch element 4): The factorization could not be completed "
                                   "because the input is not positive-definite")
            return fn(*args) * 1.01

    monkeypatch.setattr(torch._inductor, "aoti_compile_and_package", fake_compile)
    monkeypatch.setattr(ex, "AOTIProgram", FakeProgram)
    fn = ex.wrap(models["actuated"], "mass_matrix")
    path = tmp_path / "mass_matrix.aoti.pt2"
    expected = "fails on its first call" if fault == "fails" else "disagrees with the model"
    with pytest.raises(ex.InputError, match=f"^mass_matrix: the AOTInductor package {expected}") as err:
        ex.compile_aoti(ex.export_program(fn), fn, path)
    assert len(str(err.value).splitlines()) == 1 and not path.exists()


@pytest.mark.slow
def test_the_arm_grey_box_programs_equal_the_eager_model(arm_grey_box):
    """Every function of the arm's grey box as a ``torch.export`` program on arm states, in float64 to 1e-10
    (the model's own float32: the AOTInductor test)."""
    module = arm_grey_box
    assert ex.available_functions(module) == ex.FUNCTIONS
    assert_programs_equal_eager(module, arm_states(module, 17, torch.float64), torch.float64)


def test_the_inputs_units_follow_what_each_input_moves():
    """A cart's force (on a length) is in N, a motor's torque (on an angle) in N m, an input on both says
    so; the export's description and an imported file's read them from the system (``input_units``)."""
    from lnn_torch.systems.measured import MeasuredSystem

    system = MeasuredSystem(2, angle_mask=(False, True), input_names=("force", "torque", "both"),
                            input_matrix=[[1.0, 0.0, 1.0], [0.0, 1.0, 1.0]])
    assert system.input_units == ("N", "N m", "N or N m")
    assert ex._units(system, None)["tau"] == ["N", "N m", "N or N m"]
    assert MeasuredSystem(2).input_units == ()
