"""The rigid-chain kinetic energy (``kinetic: chain``): closed forms, coordinate changes, the fast
factor and its tangents against torch.func on the plain positions, and the solve against the
generic Hessian solve."""

import math

import pytest
import torch

from lnn_torch.networks import build_model
from lnn_torch.systems import InputError, get_system
from lnn_torch.systems.measured import MeasuredSystem

from .conftest import random_batch
from .helpers import assert_fast_path_is_the_references

ABSOLUTE2, RELATIVE2 = [[1, 0], [0, 1]], [[1, 0], [1, 1]]


def inv_softplus(x: float) -> float:
    return math.log(math.expm1(x))


def set_chain(model, mass, along, across, length, const=None):
    """Sets a parameter-free chain's raw parameters from physical values (normalised units); ``const``:
    the lower-triangular factor of the constant part K (None: K = 0 to round-off)."""
    dof = model.chain.dof
    L = torch.zeros(dof, dof, dtype=torch.float64) if const is None else torch.as_tensor(const, dtype=torch.float64)
    rows, cols = torch.tril_indices(dof, dof)
    tri = [inv_softplus(max(float(L[r, c]), 1e-300)) if r == c else float(L[r, c])
           for r, c in zip(rows, cols, strict=True)]
    raw = [math.log(m) for m in mass] + list(along) + list(across) + list(length) + tri
    with torch.no_grad():
        model.chain.raw.copy_(torch.tensor(raw, dtype=model.chain.raw.dtype))
    return model


def chain_mass(model, q):
    """The chain's mass matrix ``F F^T`` (without the eps I of the model) at normalised angles ``q``."""
    F, _ = model.chain.factor_at(q, q.new_zeros(q.shape[0], 0), tangents=False)
    return F @ F.mT


def test_point_mass_chain_is_the_double_pendulums_mass_matrix():
    """Point masses at the ends of massless rods, in absolute angles: the closed form of ``double_pendulum``."""
    model = build_model("film_lnn", MeasuredSystem(2), kinetic="chain", links=ABSOLUTE2, potential="harmonic").double()
    m1, m2, l1, l2 = 0.7, 1.3, 0.9, 0.6
    set_chain(model, mass=(m1, m2), along=(l1, l2), across=(0.0, 0.0), length=(l1,))
    q = torch.randn(32, 2, dtype=torch.float64) * 2
    params = torch.tensor([m1, m2, l1, l2], dtype=torch.float64).expand(32, -1)
    expected = get_system("double_pendulum").mass_matrix(q, params)
    torch.testing.assert_close(chain_mass(model, q), expected, rtol=1e-12, atol=1e-12)


def test_chain_gravity_is_the_double_pendulums_potential():
    """``potential: chain``: g on the chain's own masses; point masses give ``double_pendulum``'s V (and,
    with a time scale tau, the normalised V is g tau^2 times the same sum: lengths in metres)."""
    model = build_model("film_lnn", MeasuredSystem(2), kinetic="chain", links=ABSOLUTE2, potential="chain").double()
    m1, m2, l1, l2 = 0.7, 1.3, 0.9, 0.6
    set_chain(model, mass=(m1, m2), along=(l1, l2), across=(0.0, 0.0), length=(l1,))
    q = torch.randn(32, 2, dtype=torch.float64) * 2
    params = torch.tensor([m1, m2, l1, l2], dtype=torch.float64).expand(32, -1)
    none = q.new_zeros(32, 0)
    expected = get_system("double_pendulum").potential(q, params)
    torch.testing.assert_close(model.potential_norm(q, none)[0], expected, rtol=1e-12, atol=1e-12)
    with torch.no_grad():
        model.normalizer.time_scale.fill_(0.3)
    V, dV = model.potential_norm(q, none, grad=True)
    torch.testing.assert_close(V, 0.09 * expected, rtol=1e-12, atol=1e-12)
    grad = torch.func.vmap(torch.func.grad(lambda x: get_system("double_pendulum").potential(x, params[0])))(q)
    torch.testing.assert_close(dV, 0.09 * grad, rtol=1e-12, atol=1e-12)


def test_three_link_point_masses_are_the_chain_pendulums_mass_matrix():
    system = get_system("chain_pendulum", num_links=3)
    model = build_model("film_lnn", MeasuredSystem(3), kinetic="chain", links=torch.eye(3).tolist(),
                        potential="harmonic").double()
    m, l = (0.5, 1.1, 0.8), (0.7, 0.9, 0.4)
    set_chain(model, mass=m, along=l, across=(0.0,) * 3, length=l[:2])
    q = torch.randn(16, 3, dtype=torch.float64)
    expected = system.mass_matrix(q, torch.tensor(m + l, dtype=torch.float64).expand(16, -1))
    torch.testing.assert_close(chain_mass(model, q), expected, rtol=1e-12, atol=1e-12)


def test_joint_angles_are_a_change_of_coordinates_of_absolute_angles():
    """The same arm (centres of mass off the link axes) in joint-relative angles: ``M_rel = G^T M_abs G``
    with ``phi = G q``; the constant part adds ``K = L_K L_K^T`` (link inertias, motor rotors)."""
    values = dict(mass=(0.8, 0.5), along=(0.3, 0.25), across=(0.05, -0.04), length=(0.6,))
    absolute = set_chain(build_model("film_lnn", MeasuredSystem(2), kinetic="chain", links=ABSOLUTE2).double(),
                         **values)
    L_K = [[0.2, 0.0], [-0.1, 0.15]]
    relative = set_chain(build_model("film_lnn", MeasuredSystem(2, input_names=["tau1", "tau2"]), kinetic="chain",
                                     links=RELATIVE2).double(), **values, const=L_K)
    q = torch.randn(16, 2, dtype=torch.float64)
    G, L_K = torch.tensor(RELATIVE2, dtype=torch.float64), torch.tensor(L_K, dtype=torch.float64)
    expected = G.T @ chain_mass(absolute, q @ G.T) @ G + L_K @ L_K.T
    torch.testing.assert_close(chain_mass(relative, q), expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("scene, config, links", [
    ("double_pendulum", {}, ABSOLUTE2),  # parameters: the chain's from a network of them
    ("actuated_double_pendulum", {}, RELATIVE2),  # inputs (rotor inertias), friction, joint angles
    ("chain_pendulum", {"num_links": 3}, torch.eye(3).tolist()),
    ("pendulum", {}, [[1]]),
])
@pytest.mark.parametrize("kinetic", ["chain", "chain+mlp"])
@pytest.mark.parametrize("potential", ["harmonic", "mlp", "chain", "chain+harmonic"])
def test_chain_fast_path_equals_generic_solve(scene, config, links, kinetic, potential, rng):
    """The hand-derived factor and tangents solve as the plain positions differentiated by torch.func
    (``RigidChain.reference_factor``) and as the generic Hessian solve of the reference Lagrangian."""
    system = get_system(scene, **config)
    model = build_model("film_lnn", system, hidden_dims=(16, 16), kinetic=kinetic, links=links,
                        potential=potential).double()
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=gen, dtype=p.dtype))
    q, qd, params = random_batch(system, rng, 32)
    qn, qdn, pn = model.normalize(q, qd, params)
    assert_fast_path_is_the_references(model, system, qn, qdn, pn)
    # the factor's tangents: a central difference of the factor itself
    F, dF = model.cholesky(qn, pn, tangents=True)
    h = 1e-6
    for k in range(system.dof):
        e = torch.zeros_like(qn)
        e[:, k] = h
        fd = (model.cholesky(qn + e, pn)[0] - model.cholesky(qn - e, pn)[0]) / (2 * h)
        torch.testing.assert_close(dF[k], fd, rtol=1e-7, atol=1e-7)


def test_a_chain_builds_no_kinetic_network():
    model = build_model("film_lnn", get_system("double_pendulum"), kinetic="chain", links=ABSOLUTE2)
    assert model.chain.num_columns == 6  # x and y of two links, and the constant 2 x 2 factor
    assert list(model.kinetic) == ["chain"]  # no Cholesky network, no FiLM
    assert sum(p.numel() for p in model.chain.parameters()) == 4 * 16 + 16 + 17 * (4 * 2 - 1 + 3)


def test_chain_mass_matrix_is_positive_definite_and_the_residual_starts_small(rng):
    model = build_model("film_lnn", MeasuredSystem(2, input_names=["a", "b"]), kinetic="chain+mlp", links=RELATIVE2,
                        mass_invariant=[0]).double()
    q = torch.randn(256, 2, dtype=torch.float64) * 3
    p = q.new_zeros(256, 0)
    M = model.mass_matrix_norm(q, p)
    assert torch.linalg.eigvalsh(M).min() > 0
    F, _ = model.cholesky(q, p)
    residual = F[..., model.chain.num_columns:]
    assert residual.abs().max() < 0.03 * F[..., :model.chain.num_columns].abs().max()


def test_chain_refusals():
    dp = get_system("double_pendulum")
    with pytest.raises(InputError, match="needs links"):
        build_model("film_lnn", dp, kinetic="chain")
    with pytest.raises(InputError, match="rows of 2 coefficients"):
        build_model("film_lnn", dp, kinetic="chain", links=[[1, 0, 0]])
    with pytest.raises(InputError, match="cannot be combined with kinetic 'chain'"):
        build_model("film_lnn", dp, kinetic="chain", links=ABSOLUTE2, shared=True)
    with pytest.raises(InputError, match="angle mask"):
        build_model("film_lnn", get_system("mass_spring"), kinetic="chain", links=[[1]])
    with pytest.raises(InputError, match="unknown kinetic part 'rigid'"):
        build_model("film_lnn", dp, kinetic="rigid")
    with pytest.raises(InputError, match="needs the kinetic part 'chain'"):
        build_model("film_lnn", dp, potential="chain")


def test_weight_decay_spares_the_physical_coefficients():
    """AdamW's decay pulls towards zero: on the chain's masses and lengths, the potential's and the
    friction's coefficients it would bias the physics, so only the network weights decay."""
    from lnn_torch.training.module import LNNModule

    config = MeasuredSystem(2, input_names=["a", "b"], angle_combinations=[[1, 1]]).config()
    module = LNNModule(scene="measured", scene_config=config,
                       variant="film_lnn", hidden_dims=[8, 8], weight_decay=0.1,
                       model_options={"kinetic": "chain+mlp", "links": RELATIVE2, "potential": "harmonic+mlp"})
    opt = module.configure_optimizers()["optimizer"]
    decayed, spared = opt.param_groups
    names = {id(p): n for n, p in module.model.named_parameters()}
    assert sorted(names[id(p)] for p in spared["params"]) == ["forces.coefficients_raw", "kinetic.chain.raw",
                                                              "kinetic.mlp.net.out.bias", "potential.harmonic.coef"]
    assert spared["weight_decay"] == 0.0 and decayed["weight_decay"] == 0.1
    assert any(names[id(p)].startswith("kinetic.mlp.net") for p in decayed["params"])


def test_si_chain_parameters_undo_the_normalisation():
    """``M_norm = force_scale M_SI / tau^2`` (angles unscaled): the SI masses and K come back from the
    normalised ones, the lengths (pinned to metres by g tau^2) as they are."""
    scene = MeasuredSystem(2, input_names=["tau1", "tau2"], angle_combinations=[[1, 1]])
    model = build_model("film_lnn", scene, kinetic="chain", links=RELATIVE2, potential="chain").double()
    tau, fs = 0.17, 2.9
    with torch.no_grad():
        model.normalizer.time_scale.fill_(tau)
        model.normalizer.force_scale.fill_(fs)
    masses = (0.64, 0.56)
    set_chain(model, mass=[m * fs / tau**2 for m in masses], along=(0.2, 0.32), across=(0.0, 0.01), length=(0.2,),
              const=[[0.1, 0.0], [0.02, 0.05]])
    si = model.chain_si()
    torch.testing.assert_close(si["mass"][0], torch.tensor(masses, dtype=torch.float64))
    torch.testing.assert_close(si["length"][0], torch.tensor([0.2], dtype=torch.float64))
    L = torch.tensor([[0.1, 0.0], [0.02, 0.05]], dtype=torch.float64)
    torch.testing.assert_close(si["constant"][0], L @ L.T * tau**2 / fs)
    # the model's SI mass matrix is that chain's
    q = torch.randn(8, 2, dtype=torch.float64)
    m1, m2 = masses
    c = torch.cos(q[:, 1])
    M11 = m1 * 0.2**2 + m2 * (0.2**2 + 0.32**2 + 0.01**2) + 2 * m2 * 0.2 * (0.32 * c - 0.01 * torch.sin(q[:, 1]))
    M_si = chain_mass(model, q) * tau**2 / fs
    K = L @ L.T * tau**2 / fs
    torch.testing.assert_close(M_si[:, 0, 0] - K[0, 0], M11)
    with pytest.raises(InputError, match="SI chain parameters need"):
        build_model("film_lnn", scene, kinetic="chain", links=RELATIVE2, potential="chain+harmonic").chain_si()


def test_si_inverse_dynamics_of_a_point_mass_chain_is_the_closed_form():
    """End to end through the normalisation (time scale, force scale, g tau^2): a chain set from SI
    point masses in absolute angles returns the torques ``M(q) qdd + dV/dq`` of ``double_pendulum``'s
    closed form (at zero velocity: no Coriolis term, no friction)."""
    scene = MeasuredSystem(2, input_names=["tau1", "tau2"])
    model = build_model("film_lnn", scene, kinetic="chain", links=ABSOLUTE2, potential="chain").double()
    tau, fs = 0.21, 3.7
    with torch.no_grad():
        model.normalizer.time_scale.fill_(tau)
        model.normalizer.force_scale.fill_(fs)
    m1, m2, l1, l2 = 0.6, 0.45, 0.3, 0.25
    set_chain(model, mass=(m1 * fs / tau**2, m2 * fs / tau**2), along=(l1, l2), across=(0.0, 0.0), length=(l1,))
    q, qdd = torch.randn(16, 2, dtype=torch.float64), torch.randn(16, 2, dtype=torch.float64)
    params = torch.tensor([m1, m2, l1, l2], dtype=torch.float64).expand(16, -1)
    dp = get_system("double_pendulum")
    gravity = torch.func.vmap(torch.func.grad(lambda x: dp.potential(x, params[0])))(q)
    eps_si = model.eps * tau**2 / fs  # the model's M = F F^T + eps I (eps in normalised units)
    expected = (dp.mass_matrix(q, params) @ qdd[..., None])[..., 0] + eps_si * qdd + gravity
    got = model.inverse(q, torch.zeros_like(q), qdd, q.new_zeros(16, 0))
    torch.testing.assert_close(got, expected, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(model.chain_si()["mass"][0], torch.tensor([m1, m2], dtype=torch.float64))


def test_the_si_face_of_a_point_mass_chain_is_the_double_pendulums_plant():
    """The SI rigid-body face of a chain set from SI point masses in absolute angles, through the
    normalisation (time scale, force scale, g tau^2), is ``plant_of(double_pendulum)`` (its closed form):
    M up to the model's eps I, the bias n at nonzero velocities (Coriolis, centrifugal, gravity) with the
    model's learned friction kept out of it, g = n(q, 0), and the inverse dynamics B tau = M qdd + n - Q_f."""
    from lnn_torch.control import plant_of

    scene = MeasuredSystem(2, input_names=["tau1", "tau2"])
    model = build_model("film_lnn", scene, kinetic={"chain": {"links": ABSOLUTE2}}, potential="chain").double()
    tau, fs = 0.21, 3.7
    with torch.no_grad():
        model.normalizer.time_scale.fill_(tau)
        model.normalizer.force_scale.fill_(fs)
    m1, m2, l1, l2 = 0.6, 0.45, 0.3, 0.25
    set_chain(model, mass=(m1 * fs / tau**2, m2 * fs / tau**2), along=(l1, l2), across=(0.0, 0.0), length=(l1,))
    gen = torch.Generator().manual_seed(3)
    q, qd, qdd = (torch.randn(16, 2, generator=gen, dtype=torch.float64) for _ in range(3))
    params, none = torch.tensor([m1, m2, l1, l2], dtype=torch.float64).expand(16, -1), q.new_zeros(16, 0)
    plant = plant_of(get_system("double_pendulum"))
    eps_si = model.eps * tau**2 / fs  # the model's M = F F^T + eps I (eps in normalised units)
    with torch.no_grad():
        M, n, Qf = model.mass_matrix(q, none), model.bias(q, qd, none), model.friction(q, qd, none)
        torch.testing.assert_close(M, plant.mass_matrix(q, params) + eps_si * torch.eye(2, dtype=torch.float64))
        torch.testing.assert_close(n, plant.bias(q, qd, params), rtol=1e-10, atol=1e-12)
        torch.testing.assert_close(model.gravity(q, none), plant.gravity(q, params), rtol=1e-10, atol=1e-12)
        assert Qf.abs().max() > 1e-3 and ((Qf * qd).sum(-1) < 0).all()  # learned friction: in Q_f, not in n
        expected = (plant.mass_matrix(q, params) @ qdd[..., None])[..., 0] + eps_si * qdd + plant.bias(q, qd, params)
        torch.testing.assert_close(model.inverse(q, qd, qdd, none), expected - Qf, rtol=1e-10, atol=1e-12)


def test_the_residuals_decay_and_the_chain_constants_do_not():
    from lnn_torch.training.module import LNNModule

    scene = MeasuredSystem(2, input_names=["a", "b"], angle_combinations=[[1, 1]]).config()
    module = LNNModule(scene="measured", scene_config=scene, variant="film_lnn", hidden_dims=[8, 8], weight_decay=0.1,
                       model_options={"kinetic": "chain+mlp", "links": RELATIVE2, "potential": "chain+harmonic"})
    decayed, spared = module.configure_optimizers()["optimizer"].param_groups
    names = {id(p): n for n, p in module.model.named_parameters()}
    assert sorted(names[id(p)] for p in spared["params"]) == ["forces.coefficients_raw", "kinetic.chain.raw",
                                                              "kinetic.mlp.net.out.bias"]
    assert "potential.harmonic.coef" in {names[id(p)] for p in decayed["params"]}  # the harmonic residual decays
    # a scene with parameters: the chain's constants are its network's output bias, spared too
    dp = build_model("film_lnn", get_system("double_pendulum"), kinetic="chain", links=ABSOLUTE2)
    assert any(p is dp.chain.net[-1].bias for p in dp.coefficient_parameters())
    with pytest.raises(InputError, match="takes no option mass_invariant"):
        build_model("film_lnn", get_system("double_pendulum"), kinetic="chain", links=ABSOLUTE2, mass_invariant=[0])


def test_across_false_keeps_each_centre_of_mass_on_its_links_line():
    """``across: false`` (the lab model's form): whatever its raw across values, the chain is the one whose
    centres of mass lie on the links' lines; with ``across`` learned, the same raw values move them off."""
    def chain(across_option):
        options = {"links": ABSOLUTE2} if across_option is None else {"links": ABSOLUTE2, "across": across_option}
        return build_model("film_lnn", MeasuredSystem(2), kinetic={"chain": options}, potential="chain").double()

    on_line = set_chain(chain(False), mass=(0.7, 1.3), along=(0.4, 0.3), across=(0.05, -0.1), length=(0.9,))
    reference = set_chain(chain(None), mass=(0.7, 1.3), along=(0.4, 0.3), across=(0.0, 0.0), length=(0.9,))
    off_line = set_chain(chain(True), mass=(0.7, 1.3), along=(0.4, 0.3), across=(0.05, -0.1), length=(0.9,))
    q = torch.randn(32, 2, dtype=torch.float64) * 2
    none = q.new_zeros(32, 0)
    torch.testing.assert_close(chain_mass(on_line, q), chain_mass(reference, q), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(on_line.potential_norm(q, none)[0], reference.potential_norm(q, none)[0],
                               rtol=1e-12, atol=1e-12)
    assert (chain_mass(off_line, q) - chain_mass(reference, q)).abs().max() > 1e-3
    hanging = torch.zeros(1, 2, dtype=torch.float64)  # at rest straight down: no gravity torque on the line
    assert on_line.potential_norm(hanging, none[:1], grad=True)[1].abs().max() < 1e-12
    assert off_line.potential_norm(hanging, none[:1], grad=True)[1].abs().max() > 1e-3


def test_across_must_be_a_boolean():
    with pytest.raises(InputError, match="across must be true or false, got 'false'"):
        build_model("film_lnn", MeasuredSystem(2), kinetic={"chain": {"links": ABSOLUTE2, "across": "false"}},
                    potential="chain")
