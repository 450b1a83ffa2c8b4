"""Time acceleration evaluation and one training step for every model variant and solve path.

Medians after warm-up, one thread by default, default network sizes (2 hidden layers of 128),
float32 and float64. Accelerations are timed on states whose parameters differ from row to row. A
training step is forward + backward + AdamW on ONE 512-point chunk with the energy term (Huber +
0.1 x energy variance over the chunk), with the fused AdamW that training uses; as in training, the
chunk's points share one parameter vector (one trajectory), so FiLM runs once per chunk on the fast
path (``--per-row-params``: every point its own parameters, FiLM per point).
Every row also gives the ratio to the scene's closed-form acceleration timed in the same run. For
the structured variants, a last row times the matrix products of one acceleration call alone (same
shapes and weights): the floor that the rest of the call (activations, FiLM, solve, dispatch) adds to.

    python benchmarks/benchmark_dynamics.py              # full table (a few minutes)
    python benchmarks/benchmark_dynamics.py --quick      # fewer repeats, no batch 8192, no compile
"""

from __future__ import annotations

import argparse
import os
import statistics
from pathlib import Path

# compile in this process: inductor's pool of compile workers would otherwise compete for the
# cores while the rows are timed (before torch is imported)
os.environ.setdefault("TORCHINDUCTOR_COMPILE_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from timing import HelpFormatter, add_output_file, in_turn, machine_header, median_ms, median_ratio, wrote  # noqa: E402

from lnn_torch.evaluation import table_header, table_row  # noqa: E402
from lnn_torch.mechanics import generic_acceleration, structured_acceleration  # noqa: E402
from lnn_torch.networks import ENERGY, build_model, capabilities_of  # noqa: E402
from lnn_torch.perf import adamw, compile_fn, configure_cpu  # noqa: E402
from lnn_torch.systems import get_system  # noqa: E402
from lnn_torch.training import acceleration_loss, energy_variance  # noqa: E402

# the output width up to which a product is computed as ``(W @ x.T).T``, as the networks' fast path does
# for products with few output columns (``lnn_torch.networks``; measured in results/benchmark_dynamics.md)
SKINNY = 8


def mm_t(x: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``x @ weight.T`` the way the networks compute it: ``(weight @ x.T).T`` for few outputs."""
    if weight.shape[0] <= SKINNY < x.shape[0]:
        return torch.mm(weight, x.t()).t()
    return torch.mm(x, weight.t())


def affine(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """``x @ weight.T + bias`` as one fused ``addmm`` (an ``mm`` without a bias), as the networks' layers
    compute it."""
    return torch.mm(x, weight.t()) if bias is None else torch.addmm(bias, x, weight.t())


def paths(model, variant, compile_fast: bool, chunks):
    """Solve paths of a model: name -> (accel_norm(q_n, qd_n, p_n), train_pass, needs_grad).

    ``train_pass`` returns ``(qdd, H, T, V)`` (or ``(qdd,)`` for models without an energy);
    ``chunks`` as in ``DynamicsModel.acceleration_and_energy_norm``."""
    if ENERGY in capabilities_of(model):
        fused = lambda q, qd, p: model.acceleration_and_energy_norm(q, qd, p, chunks)  # noqa: E731
    else:
        fused = lambda q, qd, p: (model.acceleration_norm(q, qd, p),)  # noqa: E731
    out = {}
    if variant in ("film_lnn", "delan"):
        out["structured (hand tangents)"] = (model.acceleration_norm, fused, False)
        if compile_fast:
            out["structured (hand tangents, torch.compile)"] = (
                compile_fn(model.acceleration_norm), compile_fn(fused), False)

        def func_ref(q, qd, p):
            return structured_acceleration(lambda q1, p1: model.cholesky(q1[None], p1[None])[0][0],
                                           lambda q1, p1: model.potential_norm(q1[None], p1[None])[0][0],
                                           q, qd, p, eps=model.eps)

        def with_energy(fn):
            return lambda q, qd, p: (fn(q, qd, p), *model.energy_norm(q, qd, p))

        out["structured (torch.func jvp/vjp)"] = (func_ref, with_energy(func_ref), True)
        generic = lambda q, qd, p: generic_acceleration(model.lagrangian_norm, q, qd, p, check=False)  # noqa: E731
        out["generic (torch.func hessian)"] = (generic, with_energy(generic), True)
    elif variant == "lnn":
        out["generic (torch.func hessian)"] = (model.acceleration_norm, fused, True)
    else:
        out["direct"] = (model.acceleration_norm, fused, False)
        if compile_fast:
            out["direct (torch.compile)"] = (compile_fn(model.acceleration_norm), compile_fn(fused), False)
    return out


def matmul_floor(model, batch: int, dtype):
    """The matrix products of ONE structured acceleration call of ``model`` (film_lnn or delan) at
    ``batch`` states, alone: the same shapes, kinds and weights as the model's call, on random
    inputs. The rest of a call (activations, FiLM, the solve, dispatch) comes on top of this."""
    gen = torch.Generator().manual_seed(0)

    def rand(*shape):
        return torch.randn(*shape, generator=gen, dtype=dtype)

    K = model.scene.dof  # tangents of the kinetic network
    kinetic, potential = model.kinetic["mlp"], model.potential["mlp"]
    nets = [(kinetic.net, kinetic.film, False), (potential.net, potential.film, True)]
    inputs = [(rand(batch, net.hidden[0].in_features), rand(K * batch, model.num_features),
               None if film is None else rand(batch, film.net[0].in_features)) for net, film, _ in nets]

    def products():
        for (net, film, reverse), (x, dx, cond) in zip(nets, inputs, strict=True):
            if film is not None:
                first, _, last = film.net
                affine(affine(cond, first.weight, first.bias), last.weight, last.bias)
            h, dh = x, dx
            for i, layer in enumerate(net.hidden):
                h = affine(h, layer.weight, layer.bias)
                if not reverse:
                    dh = torch.mm(dh, (layer.weight[:, : dh.shape[-1]] if i == 0 else layer.weight).t())
            affine(h, net.out.weight, net.out.bias)
            if reverse:  # the hand-written reverse pass to the features
                for i in range(len(net.hidden) - 1, -1, -1):
                    W = net.hidden[i].weight
                    h = mm_t(h, (W[:, : model.num_features] if i == 0 else W).t())
            else:
                mm_t(dh, net.out.weight)

    return products


def forced_row(variant: str, dtype, batches, repeats: int, closed: dict, conservative) -> str:
    """The same structured solve on the actuated scene (inputs at both joints, joint friction): the
    cost of the generalised forces (``lnn_torch.networks.forces``), same network sizes. Timed in
    turn with the conservative model's solve (``conservative(b)``) over 5 rounds; the last column is
    the median per-round ratio forced / conservative."""
    scene = get_system("actuated_double_pendulum")
    rng = np.random.default_rng(1)
    n = max(batches)
    params = torch.tensor(scene.sample_params(rng, n)).to(dtype)
    q, qd = (torch.tensor(x).to(dtype) for x in scene.sample_state(rng, n))
    tau = torch.tensor(rng.uniform(-1, 1, (n, 2))).to(dtype)
    torch.manual_seed(0)
    model = build_model(variant, scene, hidden_dims=(128, 128)).to(dtype)
    model.fit_normalizer({"q": q, "qd": qd, "qdd": scene.acceleration(q, qd, params, tau), "params": params,
                          "params_points": params, "tau": tau})
    qn, qdn, pn = model.normalize(q, qd, params)
    tau_n = model.tau_norm(tau)
    cells, ratios = [], []
    for b in batches:
        def forced(b=b):
            with torch.no_grad():
                model.acceleration_norm(qn[:b], qdn[:b], pn[:b], tau_n[:b])

        ms = in_turn({"forced": forced, "conservative": conservative(b)}, 5, lambda fn: median_ms(fn, repeats))
        cells.append(statistics.median(ms["forced"]))
        ratios.append(median_ratio(ms["forced"], ms["conservative"]))
    return table_row([variant, "structured, actuated scene (inputs + joint friction)", str(dtype)[6:],
                      *(f"{c:.3f}" for c in cells), "-", f"{cells[1] / closed[512]:.0f} (x"
                      + ", x".join(f"{r:.2f}" for r in ratios) + " the conservative solve, in turn)"])


def closed_form(system, q, qd, params, b: int):
    """One call of the scene's closed-form accelerations on the first ``b`` states."""
    return lambda: system.acceleration(q[:b], qd[:b], params[:b])


def variant_rows(variant: str, system, states: tuple, closed: dict, batches, repeats: int, compile_fast: bool,
                 per_row_params: bool, row) -> None:
    """The rows of one model variant at the states' dtype (``row(text)`` for each): every solve path,
    and for the structured variants their matrix products alone and the actuated scene."""
    qq, qqd, pp = states
    dtype = qq.dtype
    torch._dynamo.reset()  # fresh compile caches per model: no recompile limit across rows
    torch.manual_seed(0)
    model = build_model(variant, system, hidden_dims=(128, 128)).to(dtype)
    model.normalizer.fit(qq, qqd, system.acceleration(qq, qqd, pp), pp)
    qn, qdn, pn = model.normalize(qq, qqd, pp)
    target = model.normalizer.accel_to_norm(system.acceleration(qq, qqd, pp))
    opt = adamw(model.parameters(), lr=1e-5)  # as in training
    # the training chunk: one trajectory's parameters on all 512 points (or per point)
    p_chunk = pn[:512] if per_row_params else pn[:1].expand(512, -1)
    chunks = None if per_row_params else 1
    for name, (fn, train_pass, grad) in paths(model, variant, compile_fast, chunks).items():
        cells = []
        for b in batches:
            if b > 512 and grad:  # the torch.func paths take seconds there
                cells.append("-")
                continue

            def ev(b=b, fn=fn, grad=grad):
                with torch.set_grad_enabled(grad):
                    fn(qn[:b], qdn[:b], pn[:b])

            cells.append(f"{median_ms(ev, repeats):.3f}")

        def step(train_pass=train_pass):
            opt.zero_grad()
            pred, *energies = train_pass(qn[:512], qdn[:512], p_chunk)
            loss = acceleration_loss(pred, target[:512], model.normalizer.accel_rms.to(dtype))
            if energies:
                H, T, V = (x.reshape(1, 512) for x in energies)
                loss = loss + 0.1 * energy_variance(H, T, V)
            loss.backward()
            opt.step()

        st = median_ms(step, max(5, repeats // 2))
        ratio = float(cells[1]) / closed[512]
        row(table_row([variant, name, str(dtype)[6:], *cells, f"{st:.2f}", f"{ratio:.0f}"]))
    if variant in ("film_lnn", "delan"):
        with torch.no_grad():
            cells = [median_ms(matmul_floor(model, b, dtype), repeats) for b in batches]
        row(table_row([variant, "its matrix products alone", str(dtype)[6:], *(f"{c:.3f}" for c in cells), "-",
                       f"{cells[1] / closed[512]:.0f}"]))

        def conservative(b):
            def call():
                with torch.no_grad():
                    model.acceleration_norm(qn[:b], qdn[:b], pn[:b])
            return call

        row(forced_row(variant, dtype, batches, repeats, closed, conservative))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--repeats", type=int, default=30, help="timed calls per median")
    ap.add_argument("--quick", action="store_true", help="7 repeats, batches 1 and 512, no torch.compile rows")
    ap.add_argument("--no-compile", action="store_true", help="skip the torch.compile rows")
    ap.add_argument("--variants", nargs="*", default=["film_lnn", "delan", "lnn", "mlp"], help="model variants")
    ap.add_argument("--per-row-params", action="store_true",
                    help="training step on a chunk whose points all have different parameters")
    add_output_file(ap, None, "also write the table (with the machine header) to this Markdown file")
    args = ap.parse_args()
    configure_cpu(args.threads)
    repeats = 7 if args.quick else args.repeats
    batches = (1, 512) if args.quick else (1, 512, 8192)
    compile_fast = not (args.quick or args.no_compile)
    system = get_system("double_pendulum")
    rng = np.random.default_rng(0)
    n = max(batches)
    params = torch.tensor(system.sample_params(rng, n))
    q, qd = (torch.tensor(x) for x in system.sample_state(rng, n))
    lines = []

    def row(text: str) -> None:  # printed as it comes (a full run takes minutes), kept for --output
        lines.append(text)
        print(text, flush=True)

    row(f"{machine_header()}; medians of {repeats} after warm-up")
    for line in table_header(["variant", "path", "dtype", *(f"accel B={b} (ms)" for b in batches),
                              "train step, 512-pt chunk (ms)", "accel B=512 / closed form"]):
        row(line)
    for dtype in (torch.float32, torch.float64):
        qq, qqd, pp = q.to(dtype), qd.to(dtype), params.to(dtype)
        closed = {b: median_ms(closed_form(system, qq, qqd, pp, b), repeats) for b in batches}
        row(table_row(["closed form", "analytic", str(dtype)[6:], *(f"{closed[b]:.3f}" for b in batches), "-", 1]))
        for variant in args.variants:
            variant_rows(variant, system, (qq, qqd, pp), closed, batches, repeats, compile_fast, args.per_row_params,
                         row)
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        Path(args.output).write_text("\n".join(lines) + "\n")
        wrote(args.output)


if __name__ == "__main__":
    main()
