"""The package's import graph (read from the source with ``ast``, imports inside functions included):
no cycles, and no import from a lower layer to a higher one. The layers are declared here and
described in docs/design.md ("Layers"); every module of the package must be placed in one."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "lnn_torch"

# lowest first; a module may import its own layer and the layers below it. A name ending in ".*"
# places a package's submodules (the most specific name wins).
LAYERS = [
    ("foundations", ["errors", "perf", "config_files", "pretrained", "checkpoint_format", "integrators", "dynamics",
                     "forces", "drives", "velocity_feedback", "excitation", "metrics", "report", "data.trajectories",
                     "data.derivatives",
                     "networks.normalization", "networks._kernels"]),
    ("physics", ["robots", "robots.*", "systems", "systems.*", "ground_truth", "recording", "identified"]),
    ("models", ["networks", "networks.*"]),
    ("data", ["data.spec", "data.generate", "data.hdf5", "data.importer", "data.export_csv", "data.cache"]),
    ("use", ["losses", "optim", "training_pass", "evaluation", "evaluation.*", "plots", "stability", "identification",
             "arm_identification", "control", "control.*", "export"]),
    ("training", ["module", "callbacks", "checkpoints", "data.datamodule", "lightning_cli"]),
    ("interface", ["lnn_torch", "data", "commands", "commands.*", "cli"]),
]


def modules() -> dict[str, Path]:
    """``lnn_torch.x.y`` -> its file, every module and package of the package."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def imports(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Each module's imports of package modules (the deepest module a dotted name resolves to), at any
    depth of its code; a module's import of its own parent package's ``__init__`` is not counted (the
    package importing its submodules is)."""
    def resolve(name):
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    edges = {}
    for name, path in mods.items():
        base = name if path.name == "__init__.py" else name.rpartition(".")[0]
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                b = base
                for _ in range(max(node.level - 1, 0)):
                    b = b.rpartition(".")[0]
                mod = (f"{b}.{node.module}" if node.module else b) if node.level else node.module
                targets = [f"{mod}.{a.name}" for a in node.names] + [mod]
            else:
                continue
            for t in targets:
                if t == "lnn_torch" or t.startswith("lnn_torch."):
                    r = resolve(t)
                    if r and r != name and not name.startswith(r + "."):
                        found.add(r)
        edges[name] = found
    return edges


def layer_of(name: str) -> int:
    short = "lnn_torch" if name == "lnn_torch" else name.removeprefix("lnn_torch.")
    best = None
    for level, (_, names) in enumerate(LAYERS):
        for pattern in names:
            exact = pattern == short
            wild = pattern.endswith(".*") and short.startswith(pattern[:-1])
            if exact or wild:
                rank = (2 if exact else 1, len(pattern))
                if best is None or rank > best[0]:
                    best = (rank, level)
    if best is None:
        raise KeyError(f"{name} is in no layer: place it in tests/test_import_graph.py LAYERS and docs/design.md")
    return best[1]


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in edges:
        if v not in index:
            visit(v)
    return out


def test_the_graph_reader_sees_imports_at_every_depth(tmp_path):
    """The reader must see an import inside a function and resolve relative names (else the two tests
    below could pass on a graph with cycles)."""
    edges = imports(modules())
    assert "lnn_torch.errors" in edges["lnn_torch.systems.base"]  # module level, relative
    assert "lnn_torch.module" in edges["lnn_torch.checkpoints"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycles():
    found = cycles(imports(modules()))
    assert not found, "import cycles: " + "; ".join(" -> ".join(c) for c in found)


def test_every_module_is_in_a_layer_and_imports_only_its_own_and_lower_layers():
    mods = modules()
    upward = []
    for name, targets in imports(mods).items():
        for target in sorted(targets):
            if layer_of(target) > layer_of(name):
                upward.append(f"{name} ({LAYERS[layer_of(name)][0]}) imports {target} ({LAYERS[layer_of(target)][0]})")
    assert not upward, "imports against the layer order:\n" + "\n".join(upward)


@pytest.mark.parametrize("name, layer", [("lnn_torch.networks.parts.spatial", "models"),
                                         ("lnn_torch.data.datamodule", "training"), ("lnn_torch.data", "interface"),
                                         ("lnn_torch.checkpoint_format", "foundations")])
def test_layer_lookup(name, layer):
    assert LAYERS[layer_of(name)][0] == layer
