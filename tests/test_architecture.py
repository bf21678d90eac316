"""The layout stays legible: no import cycle among ``equipose`` modules, and imports flow one way through the layers.

Layers (``LAYERS``): core ← preprocess ← runtime; sources and models depend on core only; the torch side
(``equipose.train`` / ``equipose.export``) is reached only from ``equipose.commands`` and ``equipose.bench``, inside
functions. Every import statement counts, module-level and function-level.
"""
import ast
import functools
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE_DIRS = {"sdk": "equipose", "train": "equipose.train", "export": "equipose.export"}
TORCH_SIDE = ("equipose.train", "equipose.export")
# subpackage → the subpackages its modules may import (itself included). The root package ``equipose`` and
# ``equipose.errors`` (the public path of ``equipose.core.errors``) count as core: every import of an equipose module
# runs the root ``__init__`` first, so it must stay as light as the core (it loads only ``equipose.errors``).
# The runtime may use ``equipose.models`` (the registry of shipped files, itself core-only) to resolve model names.
LAYERS = {
    "equipose.core": {"equipose.core"},
    "equipose.preprocess": {"equipose.core", "equipose.preprocess"},
    "equipose.runtime": {"equipose.core", "equipose.preprocess", "equipose.models", "equipose.runtime"},
    "equipose.sources": {"equipose.core", "equipose.sources"},
    "equipose.models": {"equipose.core", "equipose.models"},
}
TORCH_SIDE_CALLERS = ("equipose.commands", "equipose.bench")      # may import the torch side, inside functions only


def _modules() -> dict:
    """{module name: (path, is_package)} for every .py file of the three package folders."""
    out = {}
    for folder, base in PACKAGE_DIRS.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT / folder).with_suffix("").parts
            is_pkg = parts[-1] == "__init__"
            name = ".".join((base,) + (parts[:-1] if is_pkg else parts))
            out[name] = (path, is_pkg)
    return out


def module_imports(name: str, source: str, modules, is_pkg: bool = False) -> list:
    """The ``equipose`` imports of one module's ``source``: [(imported module, line, inside a function?)].

    ``from pkg import name`` counts as importing ``pkg.name`` when that is a module (in ``modules``), else ``pkg``; an
    attribute (``from equipose.core.geometry import f``) counts as its module. Relative imports are resolved.
    "Inside a function" means nested in a ``def`` (it runs when called); everything else (top level, ``if`` / ``try``
    blocks, class bodies) runs at import time.
    """
    package = name if is_pkg else name.rpartition(".")[0]
    tree = ast.parse(source, name)
    in_function = set()
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            in_function.update(id(n) for n in ast.walk(fn) if n is not fn)
    out = []
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
        for t in targets:
            while t and t not in modules:                                       # attribute import → its module
                t = t.rpartition(".")[0]
            if t and t != name:
                out.append((t, node.lineno, id(node) in in_function))
    return out


@functools.lru_cache(maxsize=None)
def import_edges() -> tuple:
    """Every import of an ``equipose`` module in the three package folders: (importer, imported, line, in function?)."""
    modules = _modules()
    return tuple((name, *imp) for name, (path, is_pkg) in modules.items()
                 for imp in module_imports(name, path.read_text(), modules, is_pkg))


def import_graph() -> dict:
    """{module: set of equipose modules it imports}, from every import statement (function-level ones included)."""
    graph = {m: set() for m in _modules()}
    for src, dst, _, _ in import_edges():
        graph[src].add(dst)
    return graph


def subpackage(module: str) -> str:
    """The layer a module belongs to: ``equipose.runtime.session`` → ``equipose.runtime``; the root package and
    ``equipose.errors`` → ``equipose.core`` (see ``LAYERS``); other top-level modules (``equipose.cli``) → themselves."""
    if module in ("equipose", "equipose.errors"):
        return "equipose.core"
    parts = module.split(".")
    return ".".join(parts[:2]) if len(parts) > 1 else module


def _within(module: str, packages) -> bool:
    return any(module == p or module.startswith(p + ".") for p in packages)


def layering_violations(edges, layers=LAYERS) -> list:
    """One line per import that breaks the layering (``LAYERS``, and the torch side only from ``TORCH_SIDE_CALLERS``
    inside functions), naming the importer, the line and the imported module."""
    bad = []
    for src, dst, line, in_function in edges:
        where = f"{src} (line {line}{', inside a function' if in_function else ''}) imports {dst}"
        if _within(src, TORCH_SIDE) or not _within(dst, TORCH_SIDE):
            layer = subpackage(src)
            allowed = layers.get(layer)
            if allowed is not None and subpackage(dst) not in allowed:
                bad.append(f"{where}: {layer} may import only {', '.join(sorted(allowed))}")
        elif not _within(src, TORCH_SIDE_CALLERS):
            bad.append(f"{where}: only {' and '.join(TORCH_SIDE_CALLERS)} may import the torch side")
        elif not in_function:
            bad.append(f"{where} at import time: import the torch side inside the function that needs it")
    return bad


def find_cycle(graph: dict):
    """One import cycle as a list of modules, or None (iterative DFS, three colours)."""
    colour = {m: 0 for m in graph}
    for start in graph:
        if colour[start]:
            continue
        stack = [(start, iter(sorted(graph[start])))]
        colour[start], path = 1, [start]
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                colour[node] = 2
                stack.pop()
                path.pop()
            elif colour.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            elif colour.get(nxt) == 0:
                colour[nxt] = 1
                path.append(nxt)
                stack.append((nxt, iter(sorted(graph[nxt]))))
    return None


def test_graph_sees_the_packages():
    g = import_graph()
    assert "equipose.runtime.estimator" in g and "equipose.preprocess" in g["equipose.runtime.estimator"]
    assert any(m.startswith("equipose.train.") for m in g) and any(m.startswith("equipose.export.") for m in g)


def test_cycle_finder_finds_a_planted_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " → ".join(cycle)


def test_layering_finder_names_a_planted_violation():
    edges = [("equipose.preprocess.crop", "equipose.core.errors", 3, False),
             ("equipose.sources.mcap", "equipose.preprocess.validate", 236, True),
             ("equipose.models", "equipose.runtime.session", 9, False),
             ("equipose.core.metadata", "equipose", 70, True),
             ("equipose.runtime.copies", "equipose.train.model", 5, True),
             ("equipose.commands.train", "equipose.train.trainer", 82, True),
             ("equipose.commands.eval", "equipose.export.onnx_export", 4, False),
             ("equipose.train.trainer", "equipose.runtime.estimator", 7, False)]
    assert layering_violations(edges) == [
        "equipose.sources.mcap (line 236, inside a function) imports equipose.preprocess.validate: equipose.sources "
        "may import only equipose.core, equipose.sources",
        "equipose.models (line 9) imports equipose.runtime.session: equipose.models may import only equipose.core, "
        "equipose.models",
        "equipose.runtime.copies (line 5, inside a function) imports equipose.train.model: only equipose.commands "
        "and equipose.bench may import the torch side",
        "equipose.commands.eval (line 4) imports equipose.export.onnx_export at import time: import the torch side "
        "inside the function that needs it"]


def test_imports_are_told_apart_by_where_they_run():
    modules = {"equipose", "equipose.core", "equipose.core.errors", "equipose.core.geometry", "equipose.runtime",
               "equipose.runtime.result", "equipose.train", "equipose.train.model"}
    source = ("import numpy as np\n"
              "import equipose.core.errors\n"
              "try:\n"
              "    from equipose.core import geometry\n"
              "except ImportError:\n"
              "    pass\n"
              "class A:\n"
              "    from ..runtime.result import PoseResult\n"
              "    def f(self):\n"
              "        from equipose.train.model import EquiPoseNet\n"
              "def g():\n"
              "    def h():\n"
              "        from equipose import __version__\n")
    assert sorted(module_imports("equipose.core.x", source, modules), key=lambda e: e[1]) == [
        ("equipose.core.errors", 2, False), ("equipose.core.geometry", 4, False),
        ("equipose.runtime.result", 8, False), ("equipose.train.model", 10, True), ("equipose", 13, True)]


def test_imports_flow_one_way():
    bad = layering_violations(import_edges())
    assert not bad, "imports against the layering (tests/test_architecture.py LAYERS):\n  " + "\n  ".join(bad)


def test_every_layer_exists():
    present = {subpackage(m) for m in _modules()}
    assert set(LAYERS) | set(TORCH_SIDE_CALLERS) <= present
