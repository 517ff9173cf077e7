"""The package layout is the architecture: layered subpackages, imports only downward.

Reads every module of ``sqfit`` and ``sqsim`` as text (nothing is imported), collects its imports,
lazy ones inside functions included, and checks the rules of the README's "Development" section:

- every module sits in a layer, and imports only from its own layer or lower ones
  (``sqfit``: base < kernels/geometry < formats < views < fitting < metrics/limit/recording/testing < graph < cli;
  every ``sqsim`` layer above every ``sqfit`` one: world < imaging < data < reports < runs < cli);
- no two modules import each other, directly or through a loop;
- no module takes a private name (``_x``) from another;
- at most ``MAX_TOP_MODULES`` modules directly under ``sqfit/``.
"""

from __future__ import annotations

import ast
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("sqfit", "sqsim")
MAX_TOP_MODULES = 10

#: module-name prefix -> layer; the longest matching prefix wins.
LAYERS = {
    "sqfit": 0, "sqfit.constants": 0, "sqfit._checks": 0,
    "sqfit.geometry": 1, "sqfit.kernels": 1,
    "sqfit.formats": 2,
    "sqfit.views": 3,
    "sqfit.fitting": 4,
    "sqfit.metrics": 5, "sqfit.limit": 5, "sqfit.recording": 5, "sqfit.testing": 5,
    "sqfit.graph": 6,
    "sqfit.cli": 7,
    "sqsim": 10,
    "sqsim.world": 11,
    "sqsim.imaging": 12,
    "sqsim.data": 13,
    "sqsim.reports": 14,
    "sqsim.runs": 15,
    "sqsim.demo": 16, "sqsim.cli": 16,
}
#: The package face of sqfit re-exports from below it and is imported by its users, so it takes the
#: layer above what it faces, not that of the package root (sqsim's face only holds its version).
FACES = {"sqfit": 8}


def _module_name(path):
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules():
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            found[_module_name(path)] = path
    return found


MODULES = _modules()


def _resolve(importer, node):
    """Absolute module names an ``import`` / ``from ... import`` node refers to, with the names taken."""
    if isinstance(node, ast.Import):
        return [(alias.name, None) for alias in node.names]
    if node.level:
        package = importer if MODULES[importer].name == "__init__.py" else importer.rpartition(".")[0]
        base = package.split(".")[:len(package.split(".")) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module
    out = []
    for alias in node.names:
        sub = f"{target}.{alias.name}"
        out.append((sub, None) if sub in MODULES else (target, alias.name))
    return out


def _imports():
    edges = {}
    for name, path in MODULES.items():
        found = []
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for target, taken in _resolve(name, node):
                    if target.split(".")[0] in PACKAGES:
                        found.append((target, taken, node.lineno))
        edges[name] = found
    return edges


EDGES = _imports()


def layer(module):
    if module in FACES:
        return FACES[module]
    best = max((p for p in LAYERS if module == p or module.startswith(p + ".")), key=len)
    return LAYERS[best]


def test_every_import_resolves_to_a_module():
    missing = [f"{m}:{line} imports {t}" for m, found in EDGES.items() for t, _, line in found
               if t not in MODULES]
    assert not missing, "\n".join(missing)


def test_imports_only_go_down_the_layers():
    upward = [f"{m}:{line} (layer {layer(m)}) imports {t} (layer {layer(t)})"
              for m, found in EDGES.items() for t, _, line in found
              if t in MODULES and layer(t) > layer(m)]
    assert not upward, "\n".join(upward)


def test_sqfit_never_imports_sqsim():
    assert not [m for m, found in EDGES.items() if m.startswith("sqfit")
                for t, _, _ in found if t.startswith("sqsim")]


def find_cycles(graph):
    """Loops of a directed graph ``{node: set of nodes}``, each as ``"a -> b -> a"``."""
    state, cycles = {}, []

    def visit(node, stack):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                cycles.append(" -> ".join(stack[stack.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [])
    return cycles


def test_no_import_cycles():
    graph = {m: {t for t, _, _ in found if t in MODULES and t != m and t not in FACES}
             for m, found in EDGES.items()}
    cycles = find_cycles(graph)
    assert not cycles, "\n".join(cycles)


def test_no_private_name_crosses_a_module():
    private = [f"{m}:{line} takes {taken} from {t}" for m, found in EDGES.items()
               for t, taken, line in found
               if taken and taken.startswith("_") and not taken.startswith("__") and t != m]
    assert not private, "\n".join(private)


def test_few_modules_directly_under_sqfit():
    top = sorted(p.name for p in (ROOT / "sqfit").glob("*.py"))
    assert len(top) <= MAX_TOP_MODULES, top


def test_every_module_has_a_layer_of_its_own():
    # a new subpackage or top-level module must be placed in LAYERS, not fall back to its root's layer
    unplaced = [m for m in MODULES if m not in FACES and m not in ("sqfit", "sqsim")
                and max((p for p in LAYERS if m == p or m.startswith(p + ".")), key=len) in PACKAGES]
    assert not unplaced, unplaced


def test_the_checks_catch_a_violation():
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a -> b -> c -> a"]
    assert find_cycles({"a": {"b"}, "b": set()}) == []
    assert layer("sqfit.geometry.camera") < layer("sqfit.views.rays") < layer("sqfit.fitting.pipeline") \
        < layer("sqfit.graph.solve") < layer("sqfit.cli.fit") < layer("sqsim.world.scene") < layer("sqsim.runs.slam")
