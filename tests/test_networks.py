"""The networks (``lnn_torch.networks``: structured FiLM/DeLaN, black-box LNN, MLP; layers, registry):
fast structured path vs torch.func references, SPD mass matrices, batch independence, gradcheck,
shapes and error messages. The solves themselves: test_dynamics.py; the HNN: test_hamiltonian.py;
compilation: test_compile.py."""


import pytest
import torch

from lnn_torch.mechanics.euler_lagrange import generic_acceleration
from lnn_torch.networks import VARIANTS, FiLM, SceneInfo, build_model, reference
from lnn_torch.networks.layers import ACTIVATIONS, TangentMLP
from lnn_torch.systems import InputError, get_system

from .conftest import QUADRATIC, QUADRATIC_IDS, SCENE_IDS, SCENES, random_batch, random_inputs
from .helpers import assert_fast_path_is_the_references, normalized_batch, perturbed


@pytest.mark.parametrize("scene, config", QUADRATIC, ids=QUADRATIC_IDS)
@pytest.mark.parametrize("variant", ["film_lnn", "delan"])
@pytest.mark.parametrize("activation, shared", [(a, False) for a in ACTIVATIONS] + [("tanh", True), ("softplus", True)])
def test_structured_fast_path_equals_generic_solve(scene, config, variant, activation, shared, rng):
    """The fast structured solve (hand tangents, hand reverse pass, unrolled Cholesky, sigmoid-form
    layers; two networks or one shared) equals the readable model (``networks.reference``: plain
    formulas, torch's activations) solved two independent ways: torch.func jvp/vjp + LAPACK Cholesky,
    and the generic Hessian solve."""
    system = get_system(scene, **config)
    model = perturbed(build_model(variant, system, hidden_dims=(32, 32), activation=activation,
                                  shared=shared).double())
    qn, qdn, pn = normalized_batch(model, system, rng)
    assert_fast_path_is_the_references(model, system, qn, qdn, pn)
    # the model's own Lagrangian (fast networks) is the reference one
    L = torch.func.vmap(model.lagrangian_norm)(qn, qdn, pn)
    torch.testing.assert_close(L, torch.func.vmap(lambda a, b, c: reference.lagrangian(model, a, b, c))(qn, qdn, pn),
                               rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("shared", [False, True])
def test_structured_energy_is_legendre_transform(shared, rng):
    system = get_system("double_pendulum")
    model = perturbed(build_model("film_lnn", system, hidden_dims=(32, 32), shared=shared).double())
    qn, qdn, pn = normalized_batch(model, system, rng, 16)
    H, T, V = model.energy_norm(qn, qdn, pn)
    L = torch.func.vmap(model.lagrangian_norm)(qn, qdn, pn)
    p = torch.func.vmap(torch.func.grad(model.lagrangian_norm, argnums=1))(qn, qdn, pn)
    torch.testing.assert_close(H, (p * qdn).sum(-1) - L, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(T - V, L, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("shared", [False, True])
def test_potential_gradient_matches_autograd(shared, rng):
    system = get_system("double_pendulum")
    model = perturbed(build_model("film_lnn", system, hidden_dims=(32, 32), shared=shared).double())
    qn, _, pn = normalized_batch(model, system, rng, 16)
    qn = qn.clone().requires_grad_(True)
    V, dV = model.potential_norm(qn, pn, grad=True)
    (auto,) = torch.autograd.grad(V.sum(), qn)
    torch.testing.assert_close(dV, auto, rtol=1e-12, atol=1e-12)


def fitted(model, system, rng, n=256):
    """``model`` with its normaliser fitted on the scene's (widened) distribution, inputs included: with
    inputs the force scale is not 1, so the SI face's units matter."""
    q, qd, params = random_batch(system, rng, n)
    tau = random_inputs(system, rng, n)
    stats = {"q": q, "qd": qd, "qdd": system.acceleration(q, qd, params, tau), "params": params,
             "params_points": params, **({"tau": tau} if tau is not None else {})}
    model.fit_normalizer(stats)
    return model


@pytest.mark.parametrize("scene, variant, shared", [("actuated_double_pendulum", "film_lnn", False),
                                                    ("actuated_double_pendulum", "delan", True),
                                                    ("double_pendulum", "film_lnn", False),
                                                    ("mass_spring", "delan", False)])
def test_the_si_face_is_its_lagrangian_by_torch_func(scene, variant, shared, rng):
    """The SI rigid-body face (``networks.rigid_body``) against the model's own SI Lagrangian ``L = H - 2 V``
    (``energy``, its potential at rest) differentiated by torch.func through the normalisation:
    ``M = d2L/dqd2``, ``n = (d/dq dL/dqd) qd - dL/dq``, ``g = -dL/dq`` at rest (in J and N m with inputs,
    else the model's units); and ``M qdd + n = B tau + Q_f`` at the model's accelerations,
    ``inverse`` their inverse, ``Q_f`` dissipative."""
    system = get_system(scene)
    model = fitted(perturbed(build_model(variant, system, hidden_dims=(16, 16), shared=shared).double()), system,
                   rng)
    q, qd, params = random_batch(system, rng, 12)
    zero = torch.zeros_like(qd)

    def lagrangian(q_, qd_):  # (B,): T - V = H - 2 V, V = H at rest
        return model.energy(q_, qd_, params) - 2 * model.energy(q_, torch.zeros_like(qd_), params)

    def momentum(q_, qd_):
        return torch.func.grad(lambda v: lagrangian(q_, v).sum())(qd_)

    dof = system.dof
    M_ref = torch.stack([torch.func.jvp(lambda v: momentum(q, v), (qd,), (zero + torch.eye(dof, dtype=q.dtype)[k],))[1]
                         for k in range(dof)], -1)
    dL_dq = torch.func.grad(lambda x: lagrangian(x, qd).sum())(q)
    n_ref = torch.func.jvp(lambda x: momentum(x, qd), (q,), (qd,))[1] - dL_dq
    g_ref = -torch.func.grad(lambda x: lagrangian(x, zero).sum())(q)
    with torch.no_grad():
        M, n, g = model.mass_matrix(q, params), model.bias(q, qd, params), model.gravity(q, params)
        for got, ref in ((M, M_ref), (n, n_ref), (g, g_ref)):
            torch.testing.assert_close(got, ref, rtol=1e-9, atol=1e-10 * float(ref.abs().max()))
        torch.testing.assert_close(model.bias(q, zero, params), g, rtol=1e-9, atol=1e-12 * float(g.abs().max()))
        tau = random_inputs(system, rng, 12)
        if tau is None:  # a conservative scene: no forces, no friction, no inverse dynamics
            assert model.forces is None and model.missing("forces") and model.missing("inverse_dynamics")
            with pytest.raises(InputError, match="has no generalised forces"):
                model.friction(q, qd, params)
            tau, Qf, B = torch.zeros(12, 0, dtype=q.dtype), torch.zeros_like(q), torch.zeros(dof, 0, dtype=q.dtype)
            qdd = model.forward(q, qd, params)
        else:
            Qf, B = model.friction(q, qd, params), system.input_matrix().double()
            assert ((Qf * qd).sum(-1) <= 0).all() and Qf.abs().max() > 0
            qdd = model.forward(q, qd, params, tau)
            torch.testing.assert_close(model.inverse(q, qd, qdd, params), tau, rtol=1e-9, atol=1e-9)
            torch.testing.assert_close(model.input_force(q, qd, qdd, params), tau @ B.T, rtol=1e-9, atol=1e-9)
        torch.testing.assert_close(qdd, model.acceleration(q, qd, params, tau if tau.shape[1] else None),
                                   rtol=0, atol=0)
        torch.testing.assert_close((M @ qdd[..., None])[..., 0] + n, tau @ B.T + Qf, rtol=1e-9,
                                   atol=1e-10 * float(n.abs().max()))


@pytest.mark.parametrize("variant", ["film_lnn", "delan"])
def test_mass_matrix_spd_with_min_eigenvalue_eps(variant, rng):
    system = get_system("double_pendulum")
    model = perturbed(build_model(variant, system).double(), scale=0.5)
    q, qd, params = random_batch(system, rng, 256)
    model.normalizer.fit(q, qd, system.acceleration(q, qd, params), params)
    cases = {
        "random": (q, params),
        "huge angles": (q + 1e3 * torch.sign(torch.randn_like(q)), params),
        "params 100x above": (q, params * 100),
        "params 100x below": (q, params / 100),
    }
    for name, (qq, pp) in cases.items():
        q_n, _, p_n = model.normalize(qq, qq, pp)
        M = model.mass_matrix_norm(q_n, p_n)  # normalised units: eps is its floor
        torch.testing.assert_close(M, M.mT, rtol=0, atol=0)
        eig = torch.linalg.eigvalsh(M)
        assert torch.isfinite(eig).all(), name
        assert eig.min() >= model.eps * (1 - 1e-9), name
    # huge velocities: the accelerations stay finite
    a = model.acceleration(q, qd * 1e3, params)
    assert torch.isfinite(a).all()


@pytest.mark.parametrize("variant", VARIANTS)
def test_batch_independence_and_per_sample_loop(variant, rng):
    system = get_system("double_pendulum")
    model = perturbed(build_model(variant, system, hidden_dims=(16, 16)).double())
    q, qd, params = random_batch(system, rng, 8)
    batch = model.acceleration(q, qd, params)
    loop = torch.cat([model.acceleration(q[i : i + 1], qd[i : i + 1], params[i : i + 1]) for i in range(8)])
    torch.testing.assert_close(batch, loop, rtol=1e-12, atol=1e-12)
    # changing one sample leaves the others untouched
    q2 = q.clone()
    q2[3] += 0.5
    other = model.acceleration(q2, qd, params)
    torch.testing.assert_close(torch.cat([other[:3], other[4:]]), torch.cat([batch[:3], batch[4:]]), rtol=0, atol=0)
    assert (other[3] - batch[3]).abs().max() > 0


@pytest.mark.parametrize("variant", ["film_lnn", "mlp"])
def test_vmap_equals_loop(variant, rng):
    system = get_system("double_pendulum")
    model = perturbed(build_model(variant, system, hidden_dims=(16, 16)).double())
    q, qd, params = random_batch(system, rng, 6)
    single = lambda a, b, c: model.acceleration(a[None], b[None], c[None], check=False)[0]  # noqa: E731
    vm = torch.func.vmap(single)(q, qd, params)
    loop = torch.stack([single(q[i], qd[i], params[i]) for i in range(6)])
    torch.testing.assert_close(vm, loop, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("shared", [False, True])
def test_gradcheck_through_structured_solve(shared, rng):
    system = get_system("double_pendulum")
    model = perturbed(build_model("film_lnn", system, hidden_dims=(4, 4), shared=shared).double())
    qn, qdn, pn = (x[:3].clone().requires_grad_(True) for x in normalized_batch(model, system, rng, 3))
    assert torch.autograd.gradcheck(lambda a, b: model.acceleration_norm(a, b, pn), (qn, qdn))
    # and with respect to network weights (what training differentiates)
    q, qd, params = (x[:3] for x in random_batch(system, rng, 3))
    names = (("kinetic.shared.net.hidden.1.weight", "kinetic.shared.net.out.weight",
              "conditioning_nets.kinetic_shared.net.2.weight")
             if shared else ("kinetic.mlp.net.hidden.1.weight", "potential.mlp.net.hidden.0.weight",
                             "conditioning_nets.kinetic_mlp.net.2.weight"))
    weights = tuple(dict(model.named_parameters())[n].detach().clone().requires_grad_(True) for n in names)

    def accel(*ws):
        return torch.func.functional_call(model, dict(zip(names, ws, strict=True)), (q, qd, params))

    assert torch.autograd.gradcheck(accel, weights)


@pytest.mark.parametrize("variant", VARIANTS)
def test_differentiable_for_training_and_no_grad(variant, rng):
    system = get_system("double_pendulum")
    model = perturbed(build_model(variant, system, hidden_dims=(16, 16)))
    q, qd, params = (x.float() for x in random_batch(system, rng, 32))
    loss = model.acceleration(q, qd, params).pow(2).mean()
    loss.backward()
    grads = [p.grad for p in model.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(g).all() for g in grads)
    assert sum(g.abs().sum() for g in grads) > 0
    with torch.no_grad():
        a = model.acceleration(q, qd, params)
    assert not a.requires_grad and torch.isfinite(a).all()


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_shapes_dtype_device_preserved(variant, dtype, rng):
    system = get_system("double_pendulum")
    model = build_model(variant, system, hidden_dims=(16, 16)).to(dtype)
    q, qd, params = (x.to(dtype) for x in random_batch(system, rng, 5))
    a = model.acceleration(q, qd, params)
    assert a.shape == (5, 2) and a.dtype == dtype and a.device == q.device


@pytest.mark.parametrize("variant", VARIANTS)
def test_bad_input_raises_clear_errors(variant, rng):
    system = get_system("double_pendulum")
    model = build_model(variant, system, hidden_dims=(8,)).double()
    q, qd, params = random_batch(system, rng, 4)
    with pytest.raises(InputError, match=r"params must have shape \(4, 4\)"):
        model.acceleration(q, qd, params[:, :3])
    with pytest.raises(InputError, match="qd must have the shape of q"):
        model.acceleration(q, qd[:3], params)
    with pytest.raises(InputError, match=r"q must have shape \(batch, 2\)"):
        model.acceleration(q[:, :1], qd[:, :1], params)
    nan_q = q.clone()
    nan_q[1, 0] = float("nan")
    with pytest.raises(InputError, match="q contains NaN"):
        model.acceleration(nan_q, qd, params)
    inf_qd = qd.clone()
    inf_qd[2, 1] = -float("inf")
    with pytest.raises(InputError, match="qd contains NaN or Inf"):
        model.acceleration(q, inf_qd, params)
    nan_params = params.clone()
    nan_params[0, 3] = float("nan")
    with pytest.raises(InputError, match="params contains NaN"):
        model.acceleration(q, qd, nan_params)
    with pytest.raises(InputError, match="positive"):
        model.acceleration(q, qd, -params)
    zero_m2 = params.clone()
    zero_m2[3, 1] = 0.0
    with pytest.raises(InputError, match=r"non-positive values in \['m2'\]"):  # named by the scene's name
        model.acceleration(q, qd, zero_m2)
    # finite values whose sum overflows are not refused (the one-sum check falls back to each tensor)
    huge = torch.full_like(qd, 1e308)
    model.check_inputs(q, huge, params)


def test_film_identity_init_and_modes():
    cond = torch.randn(7, 4)
    for mode, size in (("neuron", 32), ("layer", 1)):
        film = FiLM(4, [32, 32], mode=mode)
        out = film(cond)
        assert len(out) == 2
        for g, b in out:
            assert g.shape == (7, size) and b.shape == (7, size)
            torch.testing.assert_close(g, torch.ones_like(g))
            torch.testing.assert_close(b, torch.zeros_like(b))
    with pytest.raises(ValueError, match="FiLM mode"):
        FiLM(4, [8], mode="channel")


def test_film_parameters_change_the_mass_matrix(rng):
    """The parameters reach M only through FiLM in film_lnn: a perturbed FiLM makes M depend on them."""
    system = get_system("double_pendulum")
    model = build_model("film_lnn", system, hidden_dims=(16, 16)).double()
    q, _, params = random_batch(system, rng, 4)
    M1 = model.mass_matrix(q, params)
    torch.testing.assert_close(M1, model.mass_matrix(q, params * 2))  # identity FiLM: no dependence yet
    perturbed(model)
    assert (model.mass_matrix(q, params) - model.mass_matrix(q, params * 2)).abs().max() > 1e-6


def test_structured_model_refuses_non_quadratic_kinetic_energy():
    scene = SceneInfo("relativistic_particle", 1, (False,), 1, quadratic_kinetic=False)
    with pytest.raises(InputError, match="not quadratic"):
        build_model("film_lnn", scene)
    build_model("lnn", scene)  # the black-box Lagrangian accepts it


def test_unknown_variant():
    with pytest.raises(InputError, match="unknown model variant 'hnnn'"):
        build_model("hnnn", get_system("pendulum"))


def test_lnn_init_scheme():
    """sigma = c / sqrt(n) with c = 2.2 (first), 0.58 i (hidden i), n (output); pooled over 20
    seeded draws so that the output layer's 100 weights become 2000 samples (std error ~1.6 %)."""
    torch.manual_seed(0)
    samples = [[] for _ in range(4)]
    for _ in range(20):
        mlp = TangentMLP(8, [100, 100, 100], 1)
        mlp.lnn_init()
        for i, layer in enumerate([*mlp.hidden, mlp.out]):
            samples[i].append(layer.weight.flatten())
    expected = [2.2 / 10, 0.58 / 10, 1.16 / 10, 100 / 10]
    for s, e in zip(samples, expected, strict=True):
        assert abs(torch.cat(s).std().item() - e) / e < 0.05


@pytest.mark.parametrize("scene, config", SCENES, ids=SCENE_IDS)
@pytest.mark.parametrize("variant", VARIANTS)
def test_every_variant_is_built_from_the_scene(scene, config, variant, rng):
    """Inputs (sin/cos only for angles), FiLM width, Cholesky size and solve path come from the scene."""
    system = get_system(scene, **config)
    if variant in ("film_lnn", "delan") and not system.quadratic_kinetic:
        with pytest.raises(InputError, match="not quadratic.*use variant 'lnn'"):
            build_model(variant, system)
        return
    # the untrained black-box Lagrangian's velocity Hessian is indefinite; on the forced scene one of
    # these random states is singular, so its generic solve is regularised there
    extra = {"hessian_reg": 1e-3} if variant == "lnn" and system.has_forces else {}
    model = perturbed(build_model(variant, system, hidden_dims=(16, 16), **extra).double())
    n_angles = sum(system.angle_mask)
    combos = system.angle_combinations()
    n_combos = 0 if combos is None else combos.shape[0]  # e.g. a joint-angle chain's absolute link angles
    assert model.num_features == 2 * (n_angles + n_combos) + (system.dof - n_angles)
    if variant == "film_lnn":
        assert model.kinetic["mlp"].film.net[0].in_features == system.num_params
        assert model.kinetic["mlp"].net.out.out_features == system.dof * (system.dof + 1) // 2
        assert model.kinetic["mlp"].net.hidden[0].in_features == model.num_features  # parameters only through FiLM
    if variant == "delan":
        assert model.kinetic["mlp"].net.hidden[0].in_features == model.num_features + system.num_params
    q, qd, params = random_batch(system, rng, 7)
    tau = random_inputs(system, rng, 7)
    if variant == "hnn" and system.has_forces:  # the velocity-coordinate HNN has no force port
        with pytest.raises(InputError, match="no port for generalised forces"):
            build_model(variant, system, hnn_coordinates="velocity")
    model.fit_normalizer({"q": q, "qd": qd, "qdd": system.acceleration(q, qd, params, tau), "params": params,
                          "params_points": params, "tau": tau})
    # only a scene with forces builds them (a conservative scene: none, no extra parameter)
    assert (getattr(model, "forces", None) is not None) == (system.has_forces and variant != "mlp")
    a = model.acceleration(q, qd, params, tau)
    assert a.shape == (7, system.dof) and torch.isfinite(a).all()
    held = None if tau is None else tau[:3, None].expand(-1, 4, -1)
    qs, qds = model.rollout(q[:3], qd[:3], params[:3], 0.001, 4, tau=held)
    assert qs.shape == (3, 5, system.dof) and torch.isfinite(qs).all() and torch.isfinite(qds).all()


@pytest.mark.parametrize("activation", ACTIVATIONS)
@pytest.mark.parametrize("with_film", [False, True, "quadratic"])
@pytest.mark.parametrize("B", [5, 9])
def test_tangent_mlp_equals_a_plain_mlp(activation, with_film, B):
    """TangentMLP (tanh layers run in sigmoid form, FiLM pairs mapped to (2 gamma, beta - gamma))
    is the plain MLP ``h = gamma act(W h + b) + beta`` of ``networks.reference`` (torch's own
    activations, FiLM's plain formula): outputs in float64, tangents against torch.func.jvp, input
    gradients against autograd. Batches of 5 and 9 rows: the products with few output columns take
    their transposed form (``_kernels.mm_t``) only when the batch has more rows than outputs.
    ``quadratic``: FiLM without a hidden layer (``film_hidden=0``)."""
    torch.manual_seed(0)
    net = TangentMLP(6, [24, 24], 3, activation).double()
    film_net = FiLM(4, [24, 24], film_hidden=0 if with_film == "quadratic" else 16).double()
    with torch.no_grad():
        for p in film_net.parameters():
            p.add_(0.3 * torch.randn_like(p))
    x, cond = torch.randn(B, 6, dtype=torch.float64), torch.randn(B, 4, dtype=torch.float64)
    pairs = reference.film_pairs(film_net, cond) if with_film else None

    def plain(x):
        return reference.mlp(net, x, pairs)

    if with_film:  # the plain FiLM is not the identity here, and differs from the sigmoid-form pairs
        assert (pairs[0][0] - 1).abs().max() > 0.1
    film = film_net(cond, net.sigmoid_form) if with_film else None
    dx = torch.randn(2, B, 4, dtype=torch.float64)
    y, dy = net(x, dx, film)
    torch.testing.assert_close(y, plain(x), rtol=0, atol=1e-12)
    torch.testing.assert_close(net(x, None, film)[0], plain(x), rtol=0, atol=1e-12)
    for k in range(2):
        ref = torch.func.jvp(plain, (x,), (torch.cat([dx[k], torch.zeros(B, 2, dtype=torch.float64)], -1),))[1]
        torch.testing.assert_close(dy[k], ref, rtol=0, atol=1e-12)
    scalar = TangentMLP(6, [24, 24], 1, activation, out_bias=False).double()
    scalar.hidden, scalar.out.weight = net.hidden, torch.nn.Parameter(net.out.weight[:1].clone())
    value, grad = scalar.value_and_input_grad(x, film, num_grad_inputs=4)
    xr = x.clone().requires_grad_(True)
    ref = (plain(xr)[:, 0] - net.out.bias[0])
    (ref_grad,) = torch.autograd.grad(ref.sum(), xr)
    torch.testing.assert_close(value, ref.detach(), rtol=0, atol=1e-12)
    torch.testing.assert_close(grad, ref_grad[:, :4], rtol=0, atol=1e-12)


def test_film_without_a_hidden_layer_is_quadratic_in_the_parameters():
    """``film_hidden=0``: every gamma and beta is a quadratic polynomial of the parameters (third
    differences along any line vanish, second differences do not); with a hidden layer they are not;
    a negative width is refused."""
    torch.manual_seed(1)
    c, d = torch.randn(6, 3, dtype=torch.float64), torch.randn(6, 3, dtype=torch.float64)
    for hidden, quadratic in ((0, True), (16, False)):
        film = FiLM(3, [8, 5], film_hidden=hidden).double()
        with torch.no_grad():
            for p in film.parameters():
                p.copy_(torch.randn_like(p))
        at = [torch.cat([torch.cat(pair, -1) for pair in film(c + k * d)], -1) for k in (-1, 0, 1, 2)]
        third = at[3] - 3 * at[2] + 3 * at[1] - at[0]
        second = at[2] - 2 * at[1] + at[0]
        assert second.abs().max() > 1e-2
        assert (third.abs().max() < 1e-11) == quadratic, float(third.abs().max())
    with pytest.raises(ValueError, match="film_hidden"):
        FiLM(3, [8], film_hidden=-1)


@pytest.mark.parametrize("config", [{}, {"film_mode": "layer"}, {"potential_film": False}, {"shared": True},
                                    {"film_hidden": 0}])
def test_chunk_conditioning_equals_per_row_conditioning(config, rng):
    """Training chunks share their parameters: FiLM once per chunk (``chunks=C``) gives the per-row
    result, values and parameter gradients (float64); parameters that vary inside a chunk are not
    what chunks means (the result then differs); a batch that does not split evenly is refused."""
    system = get_system("double_pendulum")
    model = perturbed(build_model("film_lnn", system, hidden_dims=(16, 16), **config).double())
    assert model.chunk_conditioning
    C, L = 3, 8
    q, qd, params = random_batch(system, rng, C * L)
    params = params[::L].repeat_interleave(L, 0)
    qdd = system.acceleration(q, qd, params)
    results = []
    for chunks in (None, C):
        for energy in (False, True):
            model.zero_grad()
            out = model.training_terms(q, qd, qdd, params, energy=energy, chunks=chunks)
            sum(o.sum() for o in out.values()).backward()
            results.append((out, [p.grad.clone() for p in model.parameters() if p.grad is not None]))
    for (o0, g0), (o1, g1) in zip(results[:2], results[2:], strict=True):
        assert o0.keys() == o1.keys()
        for key in o0:
            torch.testing.assert_close(o1[key], o0[key], rtol=1e-12, atol=1e-12)
        assert len(g0) == len(g1)
        for a, b in zip(g0, g1, strict=True):
            torch.testing.assert_close(b, a, rtol=1e-10, atol=1e-12)
    mixed = params.clone()
    mixed[1] *= 1.5  # a parameter change inside the first chunk: per-chunk FiLM no longer applies
    assert (model.training_terms(q, qd, qdd, mixed)["pred"]
            - model.training_terms(q, qd, qdd, mixed, chunks=C)["pred"]).abs().max() > 1e-8
    with pytest.raises(InputError, match="chunks"):
        model.training_terms(q, qd, qdd, params, energy=True, chunks=5)


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_variant_takes_the_chunk_structure(variant, rng):
    """``training_terms(..., chunks=C)`` is accepted by every variant (used or not) and changes nothing."""
    system = get_system("double_pendulum")
    model = perturbed(build_model(variant, system, hidden_dims=(16, 16)).double())
    q, qd, params = random_batch(system, rng, 8)
    params = params[:1].expand(8, -1)
    qdd = system.acceleration(q, qd, params)
    a, b = model.training_terms(q, qd, qdd, params), model.training_terms(q, qd, qdd, params, chunks=2)
    assert a.keys() == b.keys()
    for key in a:
        torch.testing.assert_close(b[key], a[key], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("variant, kw", [("film_lnn", {}), ("film_lnn", {"potential_film": False}), ("delan", {}),
                                         ("film_lnn", {"shared": True})])
def test_rollout_conditions_once(variant, kw, rng):
    """A rollout computes FiLM once (acceleration_fn) and equals, to the bit, integrating
    model.acceleration, which computes it at every stage; other parameters are refused."""
    from lnn_torch.mechanics import integrators

    system = get_system("double_pendulum")
    model = perturbed(build_model(variant, system, hidden_dims=(16, 16), **kw).double())
    q, qd, params = random_batch(system, rng, 6)
    reference = integrators.rollout(lambda a, b, p: model.acceleration(a, b, p, check=False), q, qd, params, 0.01, 5)
    for got, want in zip(model.rollout(q, qd, params, 0.01, 5), reference, strict=True):
        torch.testing.assert_close(got, want, rtol=0, atol=0)
    accel = model.acceleration_fn(params)
    torch.testing.assert_close(accel(q, qd, params), model.acceleration(q, qd, params), rtol=0, atol=0)
    if model._has_film:
        with pytest.raises(InputError, match="other parameters"):
            accel(q, qd, params.clone())


@pytest.mark.parametrize("variant", ["film_lnn", "delan"])
def test_mass_invariance_keeps_the_solve_exact(variant, rng):
    """A mass matrix independent of the base joint (``mass_invariant``) still solves exactly as the
    readable references, and the mass matrix does not change when the whole arm turns about its base
    joint (it does without the option)."""
    system = get_system("actuated_double_pendulum")
    for invariant in ([0], None):
        model = perturbed(build_model(variant, system, hidden_dims=(32, 32), mass_invariant=invariant).double())
        qn, qdn, pn = normalized_batch(model, system, rng, 16)
        force = model.force_norm(qn, qdn, pn, torch.randn(qn.shape[0], system.num_inputs, dtype=torch.float64))
        fast = model.solve_norm(qn, qdn, pn, force)
        generic = generic_acceleration(lambda a, b, c, m=model: reference.lagrangian(m, a, b, c), qn, qdn, pn,
                                       force=force)
        assert (fast - generic).abs().max() <= 1e-10 * generic.abs().max()
        turned = qn + torch.tensor([1.3, 0.0], dtype=torch.float64)
        same = torch.allclose(model.mass_matrix_norm(turned, pn), model.mass_matrix_norm(qn, pn), rtol=0, atol=1e-14)
        assert same == (invariant is not None)


def test_mass_invariant_refuses_bad_coordinates():
    system = get_system("actuated_double_pendulum")
    with pytest.raises(InputError, match="mass_invariant"):
        build_model("film_lnn", system, mass_invariant=[2])
    with pytest.raises(InputError, match="no feature"):
        build_model("film_lnn", system, mass_invariant=[0, 1])
    with pytest.raises(InputError, match="shared .* cannot be combined with mass_invariant"):
        build_model("film_lnn", system, mass_invariant=[0], shared=True)


@pytest.mark.parametrize("variant", ["film_lnn", "delan"])
@pytest.mark.parametrize("scene", ["double_pendulum", "actuated_double_pendulum", "measured"])
@pytest.mark.parametrize("potential", ["harmonic", "harmonic+mlp"])
def test_harmonic_potential_solves_exactly(variant, scene, potential, rng):
    """``potential='harmonic'``: the fast solve (hand-written dV/dq) equals the generic torch.func
    solve of the readable Lagrangian (float64; with parameters, and with none for a measured system),
    and dV/dq equals a central difference of V."""
    from lnn_torch.systems.measured import MeasuredSystem

    if scene == "measured":
        system = MeasuredSystem(2, input_names=("tau1", "tau2"), angle_combinations=[[1, 1]])
        q = torch.randn(16, 2, dtype=torch.float64)
        qd, params = torch.randn(16, 2, dtype=torch.float64), torch.zeros(16, 0, dtype=torch.float64)
    else:
        system = get_system(scene)
        q, qd, params = random_batch(system, rng, 16)
    model = perturbed(build_model(variant, system, hidden_dims=(16, 16), potential=potential).double(), scale=0.3)
    assert (model.part("potential", "mlp") is None) == (potential == "harmonic")
    qn, qdn, pn = model.normalize(q, qd, params)
    force = None
    if system.num_inputs:
        force = model.force_norm(qn, qdn, pn, torch.randn(qn.shape[0], system.num_inputs, dtype=torch.float64))
    fast = model.solve_norm(qn, qdn, pn, force)
    generic = generic_acceleration(lambda a, b, c: reference.lagrangian(model, a, b, c), qn, qdn, pn, force=force)
    assert (fast - generic).abs().max() <= 1e-10 * generic.abs().max()
    V, dV = model.potential_norm(qn, pn, grad=True)
    torch.testing.assert_close(V, reference.potential(model, qn, pn), rtol=1e-12, atol=1e-12)
    h = 1e-5  # central difference: truncation ~h^2 (third derivative), rounding ~1e-16 / h: both below the tolerance
    for k in range(system.dof):
        e = torch.zeros(system.dof, dtype=torch.float64)
        e[k] = h
        fd = (model.potential_norm(qn + e, pn)[0] - model.potential_norm(qn - e, pn)[0]) / (2 * h)
        torch.testing.assert_close(dV[:, k], fd, rtol=1e-7, atol=1e-9)


def test_harmonic_potential_spans_the_rigid_arm_potential(rng):
    """The form is exact for rigid links under gravity: for fixed parameters of the actuated double
    pendulum (joint-relative q2, angle combination q1 + q2), the closed-form potential minus its
    constant is a least-squares combination of the model's features to round-off; a potential with a
    second harmonic (cos 2 q1) is not (so the check can fail)."""
    system = get_system("actuated_double_pendulum")
    model = build_model("film_lnn", system, hidden_dims=(8, 8), potential="harmonic").double()
    q, _, params = random_batch(system, rng, 200)
    params = params[:1].expand(200, -1)
    phi, _ = model.features(q)
    for target, fits in ((system.potential(q, params), True), (torch.cos(2 * q[:, 0]), False)):
        A = torch.cat([phi, torch.ones(200, 1, dtype=torch.float64)], -1)
        coef = torch.linalg.lstsq(A, target[:, None]).solution
        residual = (A @ coef)[:, 0] - target
        assert (residual.abs().max() <= 1e-10 * target.abs().max()) == fits


def test_harmonic_potential_is_refused_where_it_cannot_hold():
    with pytest.raises(InputError, match="harmonic"):
        build_model("film_lnn", get_system("mass_spring"), potential="harmonic")
    with pytest.raises(InputError, match="harmonic"):
        build_model("film_lnn", get_system("double_pendulum"), potential="harmonic", shared=True)
    with pytest.raises(InputError, match="unknown potential part 'fourier'"):
        build_model("film_lnn", get_system("double_pendulum"), potential="fourier")


@pytest.mark.parametrize("potential", ["mlp", "harmonic+mlp"])
def test_networks_are_built_in_a_fixed_order(potential):
    """The order in which the structured model creates its networks is the order in which they draw
    from the random generator: changing it changes every seed's initialisation (and every result
    measured from a seed). The forces (built by the base class), the kinetic network, the potential
    network, then their FiLM networks (then the harmonic series' coefficient network): checked by
    drawing the same networks from the same seed in that order."""
    from lnn_torch.networks import FiLM, TangentMLP

    system = get_system("actuated_double_pendulum")
    torch.manual_seed(3)
    model = build_model("film_lnn", system, potential=potential)
    torch.manual_seed(3)
    forces = build_model("film_lnn", system).forces  # draws exactly what the base class draws
    torch.manual_seed(3)
    forces_again = type(forces)(model.scene, model.num_features)
    F, P, H = model.num_features, system.num_params, [64, 64]
    kinetic, potential_net = TangentMLP(F, H, 3), TangentMLP(F + P, H, 1, out_bias=False)
    films = FiLM(P, H), FiLM(P, H)
    expected = {"forces": forces_again, "kinetic.mlp.net": kinetic, "potential.mlp.net": potential_net,
                "conditioning_nets.kinetic_mlp": films[0], "conditioning_nets.potential_mlp": films[1]}
    modules = dict(model.named_modules())
    for name, net in expected.items():
        for (n, a), (_, b) in zip(modules[name].named_parameters(), net.named_parameters(), strict=True):
            assert torch.equal(a, b), f"{name}.{n}"
    assert torch.equal(forces.coefficient_net[0].weight, forces_again.coefficient_net[0].weight)
    # and the parameters come in that order too (gradient clipping sums their norms in this order)
    order = [p for net in expected.values() for p in net.parameters()]
    assert [tuple(p.shape) for p in model.parameters()][:len(order)] == [tuple(p.shape) for p in order]
    assert all(torch.equal(a, b) for a, b in zip(model.parameters(), order, strict=False))  # the first ones
