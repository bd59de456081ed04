"""The house rules, checked on the source (DESIGN.md, "Imports run one way"):

- no import cycle among the project's modules (function-level imports count; the scenario registry's discovery
  of the kind modules counts as an import of each of them);
- no private name (``_x``) imported from another package;
- the packages import one way: scenarios -> trajectories -> ident -> sim (never backwards);
- no scenario kind imports another kind, and the runner reaches the kinds only through the registry.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sim", "ident", "trajectories", "scenarios")
ORDER = {"sim": 0, "ident": 1, "trajectories": 2, "scenarios": 3}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            parts = list(f.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> list[tuple[str, list[str]]]:
    """(imported module, imported names) for every import statement, at any depth."""
    tree = ast.parse(path.read_text())
    is_pkg = path.name == "__init__.py"
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(a.name, []) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                base = base[: len(base) - node.level + (1 if is_pkg else 0)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            found.append((module, [a.name for a in node.names]))
    return found


def _graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for name, path in MODULES.items():
        for module, names in _imports(name, path):
            targets = [f"{module}.{n}" for n in names if f"{module}.{n}" in MODULES]
            if module in MODULES and len(targets) < len(names) or not names:
                targets.append(module)
            graph[name] |= {t for t in targets if t in MODULES and t != name}
    kinds = [m for m in MODULES if m.startswith("scenarios.kinds.")]
    graph["scenarios.registry"] |= set(kinds) | {"scenarios.kinds"}  # discovery by importlib
    return graph


GRAPH = _graph()


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
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

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_the_graph_sees_the_known_edges():
    """The checker itself: edges that exist must be found (a graph that finds nothing would pass everything)."""
    assert "scenarios.registry" in GRAPH["scenarios.runner"]
    assert "scenarios.kinds.paper" in GRAPH["scenarios.registry"]
    assert "ident.processing.filtering" in GRAPH["ident.processing.processing"]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycle():
    assert _cycles(GRAPH) == []


def test_packages_import_one_way():
    backwards = [(m, t) for m, ts in GRAPH.items() for t in ts if ORDER[t.split(".")[0]] > ORDER[m.split(".")[0]]]
    assert backwards == []


def test_no_private_name_crosses_a_package():
    crossing = []
    for name, path in MODULES.items():
        for module, names in _imports(name, path):
            top = module.split(".")[0]
            if top in PACKAGES and top != name.split(".")[0]:
                crossing += [f"{name}: from {module} import {n}" for n in names
                             if n.startswith("_") and not n.startswith("__")]
            if top in PACKAGES and any(p.startswith("_") and not p.startswith("__") for p in module.split(".")[1:]) \
                    and top != name.split(".")[0]:
                crossing.append(f"{name}: import {module}")
    assert crossing == []


def test_kinds_are_rooms():
    kinds = [m for m in MODULES if m.startswith("scenarios.kinds.")]
    assert {"scenarios.kinds.paper", "scenarios.kinds.enclosure"} <= set(kinds)
    for k in kinds:
        others = {t for t in GRAPH[k] if t.startswith("scenarios.kinds") or t in ("scenarios.registry", "scenarios.runner")}
        assert others == set(), k
    runner_kinds = {t for t in GRAPH["scenarios.runner"] if t.startswith("scenarios.kinds")}
    assert runner_kinds == set()


@pytest.mark.parametrize("kind", sorted(m.rsplit(".", 1)[1] for m in MODULES if m.startswith("scenarios.kinds.")))
def test_every_kind_module_is_registered_with_a_description(kind):
    from scenarios import registry

    module = registry.get(kind)
    assert callable(module.run) and isinstance(module.DESCRIPTION, str) and module.DESCRIPTION
