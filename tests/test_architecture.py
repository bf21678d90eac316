"""The layout stays legible: no import cycle among ``equipose`` modules, no module over 300 lines."""
import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE_DIRS = {"sdk": "equipose", "train": "equipose.train", "export": "equipose.export"}
MAX_LINES = 300


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


def import_graph() -> dict:
    """{module: set of equipose modules it imports}, from every import statement (function-level ones included)."""
    modules = _modules()
    graph = {}
    for name, (path, is_pkg) in modules.items():
        package = name if is_pkg else name.rpartition(".")[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
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
                while t and t not in modules:                                   # attribute import → its module
                    t = t.rpartition(".")[0]
                if t and t != name:
                    deps.add(t)
        graph[name] = deps
    return graph


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
    assert "equipose.train.model" in g and "equipose.export.onnx_export" in g


def test_cycle_finder_finds_a_planted_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " → ".join(cycle)


def test_runtime_does_not_import_the_torch_side():
    g = import_graph()
    bad = {m: sorted(d for d in deps if d.startswith(("equipose.train", "equipose.export")))
           for m, deps in g.items() if m.startswith(("equipose.runtime", "equipose.preprocess", "equipose.core",
                                                        "equipose.sources", "equipose.eval"))}
    assert not {m: d for m, d in bad.items() if d}


def test_no_module_over_300_lines():
    long = {str(p.relative_to(ROOT)): n for p, _ in _modules().values()
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines: {long}"
