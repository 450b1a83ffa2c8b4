"""The potential part ``products`` (``lnn_torch.networks.parts.products``): its fast path against its
written-out reference and autograd, and its claim: a spatial arm's gravity with any point payload is in
its span exactly (MuJoCo's gravity torques of the shipped Panda fitted by least squares)."""

import numpy as np
import pytest
import torch

from lnn_torch.errors import InputError
from lnn_torch.mechanics.euler_lagrange import generic_acceleration
from lnn_torch.networks import reference
from lnn_torch.networks.registry import build_model
from lnn_torch.systems import get_system

from .helpers import random_batch


def _model(scene, hidden=(8, 8), **options):
    torch.manual_seed(0)
    model = build_model("film_lnn", get_system(scene), hidden_dims=hidden, **options).double()
    with torch.no_grad():  # away from the zero start, so that every coefficient matters
        for p in model.parameters():
            p.add_(0.1 * torch.randn_like(p))
    return model


@pytest.mark.parametrize("scene, options", [("double_pendulum", {}), ("chain_pendulum", {"film_hidden": 0}),
                                            ("robot_arm", {"skip": [0], "film_hidden": 0})])
def test_the_fast_path_is_the_written_out_series_and_its_gradient(scene, options, rng):
    """``V`` and ``dV/dq`` of the contraction equal every term written out and its autograd gradient
    (float64); a skipped joint gets no gradient; the part starts at zero."""
    fresh = build_model("film_lnn", get_system(scene), hidden_dims=(8, 8), potential={"products": options})
    model = _model(scene, potential={"products": options})
    part = model.potential["products"]
    system = get_system(scene)
    q, qd, params = random_batch(system, rng, 6)
    q_n, _, p_n = model.normalize(q, qd, params)
    term = part.potential(model._part_inputs(q_n, p_n, True), None, True)
    q_r = q_n.clone().requires_grad_(True)
    V_ref = part.reference_potential(q_r, p_n, None, None)
    (dV_ref,) = torch.autograd.grad(V_ref.sum(), q_r)
    assert V_ref.abs().max() > 1e-2
    torch.testing.assert_close(term.V, V_ref.detach(), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(term.dV_dq, dV_ref, rtol=1e-12, atol=1e-12)
    for j in options.get("skip", []):
        assert (term.dV_dq[:, j] == 0).all()
    f_n = fresh.normalize(q.float(), qd.float(), params.float())
    assert (fresh.potential["products"].potential(fresh._part_inputs(f_n[0], f_n[2], True), None, True).V == 0).all()
    # the model's accelerations with the part: the structured solve equals the generic Euler-Lagrange solve
    # of the readable Lagrangian (torch.func)
    force = None
    if system.num_inputs:
        force = model.force_norm(q_n, model.normalize(q, qd, params)[1], p_n,
                                 torch.randn(6, system.num_inputs, dtype=torch.float64))
    qd_n = model.normalize(q, qd, params)[1]
    fast = model.solve_norm(q_n, qd_n, p_n, force)
    generic = generic_acceleration(lambda a, b, c: reference.lagrangian(model, a, b, c), q_n, qd_n, p_n, force=force)
    assert (fast - generic).abs().max() <= 1e-10 * generic.abs().max()


def test_a_spatial_arms_gravity_with_any_payload_is_in_its_span():
    """The Panda's gravity torques (MuJoCo, the shipped description) with point payloads of any mass and
    centre of mass are ``-dV/dq`` of the series with coefficients linear in (1, m, m c): least squares
    over random configurations and payloads leaves 1e-9 of them. Without the payload terms, or without
    the products (single-joint harmonics), it cannot (the check can fail)."""
    from lnn_torch.robots.mujoco_arm import MujocoArm

    arm = MujocoArm("franka_panda")
    model = build_model("film_lnn", get_system("robot_arm"), hidden_dims=(8, 8),
                        potential={"products": {"skip": [0]}}).double()
    part = model.potential["products"]
    rng = np.random.default_rng(3)
    n = 900
    q = torch.tensor(arm.sample_q(rng, n))
    payload = torch.tensor(np.column_stack([rng.uniform(0, 3, n), rng.uniform(-0.05, 0.05, (n, 2)),
                                            rng.uniform(0, 0.1, n)]))
    g = arm.gravity(q, payload)  # dV/dq, N m
    u, du = part._factors(q)
    joints = u.shape[0]

    def outer(factors):  # (n, 3^joints): the products, the first joint's index slowest (as the part orders them)
        out = factors[0]
        for f in factors[1:]:
            out = (out[:, :, None] * f[:, None, :]).flatten(1)
        return out

    # dV/dq_j of every term: (n, joints, terms)
    basis = torch.stack([outer([du[j] if i == j else u[i] for i in range(joints)]) for j in range(joints)], 1)
    coef = torch.randn(part.num_terms, dtype=torch.float64)  # the ordering is the part's own
    torch.testing.assert_close(basis[:, 2] @ coef, part._contract(coef, [du[2] if i == 2 else u[i]
                                                                         for i in range(joints)]))
    weights = torch.cat([torch.ones(n, 1, dtype=torch.float64), payload[:, :1], payload[:, :1] * payload[:, 1:]], 1)

    def residual(columns):
        A = columns.reshape(n * joints, -1)
        A = A[:, A.norm(dim=0) > 0]  # the constant terms have no gradient
        b = g[:, part.joint_idx].reshape(-1)
        x = torch.linalg.lstsq(A, b[:, None], driver="gels").solution  # QR: the columns are independent
        return float((A @ x - b[:, None]).norm() / b.norm())

    exact = residual((basis[..., None] * weights[:, None, None, :]).flatten(2))
    massless = residual(basis)  # no payload terms
    single = torch.tensor([0] + [3**(joints - 1 - j) * i for j in range(joints) for i in (1, 2)])
    harmonics = residual((basis[:, :, single, None] * weights[:, None, None, :]).flatten(2))
    assert g.abs().max() > 10
    assert exact < 1e-9, exact
    assert massless > 1e-2 and harmonics > 1e-2, (massless, harmonics)


def test_bad_options_are_refused_in_one_line():
    system = get_system("robot_arm")
    with pytest.raises(InputError, match="skip \\[9\\] is not a joint index"):
        build_model("film_lnn", system, potential={"products": {"skip": [9]}})
    with pytest.raises(InputError, match="'products' over 9 joints"):
        build_model("film_lnn", get_system("chain_pendulum", num_links=9), potential={"products": {}})
    with pytest.raises(InputError, match="potential part 'products' takes no option 'links'"):
        build_model("film_lnn", system, potential={"products": {"links": 1}})
