"""The package's import graph (read from the source with ``ast``, imports inside functions included):
no cycles, and no import from a lower layer to a higher one. The layers are declared here and
described in docs/design.md ("Layers"); every module of the package must be placed in one."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "lnn_torch"

# lowest first; a module may import its own layer and the layers below it. A package's name places the
# package and its submodules (the most specific name wins: a package may span two layers).
LAYERS = [
    ("foundations", ["_version", "errors", "perf", "pretrained"]),
    ("mechanics", ["mechanics"]),
    ("scene signals", ["systems.excitation", "systems.ground_truth", "systems.recording"]),
    ("robots", ["robots"]),
    ("systems", ["systems"]),
    ("networks", ["networks"]),
    ("data", ["data"]),
    ("evaluation", ["evaluation"]),
    ("objectives", ["training.losses"]),
    ("identification", ["identification"]),
    ("recorded import", ["data.importer", "data.import_tools"]),
    ("control", ["control"]),
    ("export", ["export"]),
    ("training", ["training"]),
    ("interface", ["lnn_torch", "commands", "cli"]),
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
            if lazy_table(node):  # a package's names imported on first use: {name: ".module"}
                node = ast.ImportFrom(module=None, names=[ast.alias(v.value[1:]) for v in node.value.values], level=1)
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


def lazy_table(node) -> bool:
    """Whether ``node`` is a package's ``_LAZY = {name: ".module", ...}`` (names imported on first use)."""
    return (isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == ["_LAZY"]
            and isinstance(node.value, ast.Dict))


def climbs(mods: dict[str, Path]) -> list[str]:
    """Imports of a name (not a submodule) from a package above the importing module: the package's
    ``__init__`` is then imported for that name (``from .. import __version__``), an edge the layer
    order cannot place."""
    out = []
    for name, path in mods.items():
        base = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            b = base
            for _ in range(max(node.level - 1, 0)):
                b = b.rpartition(".")[0]
            mod = (f"{b}.{node.module}" if node.module else b) if node.level else node.module
            if mod in mods and mod != name and name.startswith(mod + "."):
                out += [f"{name}: from {mod} import {a.name}" for a in node.names if f"{mod}.{a.name}" not in mods]
    return out


def layer_of(name: str) -> int:
    short = "lnn_torch" if name == "lnn_torch" else name.removeprefix("lnn_torch.")
    best = None
    for level, (_, names) in enumerate(LAYERS):
        for pattern in names:
            exact = pattern == short
            wild = pattern != "lnn_torch" and short.startswith(pattern + ".")
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
    assert "lnn_torch.training.module" in edges["lnn_torch.training.checkpoints"]
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


def test_no_module_imports_a_name_from_a_package_above_it(tmp_path):
    found = climbs(modules())
    assert not found, "names imported from a package's __init__ above the module:\n" + "\n".join(found)
    pkg = tmp_path / "lnn_torch"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("x = 1\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "leaf.py").write_text("from .. import x\nfrom . import other\n")
    (pkg / "sub" / "other.py").write_text("")
    mods = {"lnn_torch": pkg / "__init__.py", "lnn_torch.sub": pkg / "sub" / "__init__.py",
            "lnn_torch.sub.leaf": pkg / "sub" / "leaf.py", "lnn_torch.sub.other": pkg / "sub" / "other.py"}
    assert climbs(mods) == ["lnn_torch.sub.leaf: from lnn_torch import x"]


def test_the_layers_are_the_package_list():
    """The layer list is as short as the tree: the root holds only the entry points, and each layer
    names packages (a package may span two layers where its lower modules serve another package)."""
    root = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert root == ["__init__.py", "_version.py", "cli.py", "errors.py", "perf.py"], root
    assert sum(len(names) for _, names in LAYERS) <= 25


@pytest.mark.parametrize("name, layer", [("lnn_torch.networks.parts.spatial", "networks"),
                                         ("lnn_torch.training.datamodule", "training"), ("lnn_torch.data", "data"),
                                         ("lnn_torch.training.losses", "objectives"),
                                         ("lnn_torch.systems.recording", "scene signals"),
                                         ("lnn_torch.training.checkpoint_format", "training")])
def test_layer_lookup(name, layer):
    assert LAYERS[layer_of(name)][0] == layer
