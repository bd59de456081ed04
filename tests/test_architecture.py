"""The house rules, checked on the source (imports run one way; what runs is checked in ``tests/test_imports.py``):

- no import cycle among the project's modules (function-level imports count; the scenario registry's discovery
  of the kind modules counts as an import of each of them);
- no private name (``_x``) imported from another package, nor from a module of another sub-package
  (``ident.estimators`` from ``ident.numerics``, ``scenarios.kinds`` from ``scenarios``, ...);
- the packages import one way: scenarios -> trajectories -> ident -> sim (never backwards);
- the layers of ident: ``ident.estimators`` and ``ident.numerics`` import neither ``ident.robots``,
  ``ident.processing``, ``sim``, ``mujoco`` nor plotting; ``ident.processing`` imports no robot; only
  ``ident.robots`` imports ``sim``;
- no scenario kind imports another kind, and the runner reaches the kinds only through the registry.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import h4bench

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = h4bench.SUBPACKAGES
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


def _short(module: str) -> str:
    """``h4bench.ident.box`` -> ``ident.box``: the modules are named here by their folder in the checkout."""
    return module[len("h4bench."):] if module.startswith("h4bench.") else module


def _imports(name: str, path: Path) -> list[tuple[str, list[str]]]:
    """(imported module, imported names) for every import statement, at any depth; ``from h4bench import
    ident`` counts as ``import ident``."""
    tree = ast.parse(path.read_text())
    is_pkg = path.name == "__init__.py"
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(_short(a.name), []) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                base = base[: len(base) - node.level + (1 if is_pkg else 0)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            if module == "h4bench":
                found += [(a.name, []) for a in node.names]
            else:
                found.append((_short(module), [a.name for a in node.names]))
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


def _external(name: str, path: Path) -> set[str]:
    """Top-level names of every module imported by ``name`` (the project's and third-party ones)."""
    return {module.split(".")[0] for module, _ in _imports(name, path) if module}


def _layer_violations(layer: str, forbidden_project: tuple[str, ...], forbidden_external: tuple[str, ...]):
    out = []
    for name, path in MODULES.items():
        if name != layer and not name.startswith(layer + "."):
            continue
        out += [f"{name} -> {t}" for t in sorted(GRAPH[name]) if t.startswith(forbidden_project)]
        out += [f"{name} -> {e}" for e in sorted(_external(name, path) & set(forbidden_external))]
    return out


PLOTTING = ("matplotlib", "rerun")


@pytest.mark.parametrize("layer", ["ident.estimators", "ident.numerics"])
def test_estimators_and_numerics_import_no_robot_processing_simulator_or_plotting(layer):
    found = _layer_violations(layer, ("ident.robots", "ident.processing", "sim"), ("sim", "mujoco", *PLOTTING))
    assert sorted(found) == []


def test_processing_imports_no_robot_and_only_robots_import_sim():
    found = _layer_violations("ident.processing", ("ident.robots", "sim"), ("sim", "mujoco", *PLOTTING))
    for name, path in MODULES.items():
        if name.startswith("ident") and not name.startswith("ident.robots") and "sim" in _external(name, path):
            found.append(f"{name} -> sim")
    assert sorted(found) == []


def test_the_equation_builder_takes_the_regressor():
    """The generic chain imports no robot (it was the last crossing, processing -> the H4 regressor); the H4's
    binding lives on the robot side and imports the chain, not the other way round."""
    assert not any(t.startswith("ident.robots") for t in GRAPH["ident.processing.processing"])
    assert "ident.processing.processing" in GRAPH["ident.robots.h4_equation"]
    assert "ident.robots.h4" in GRAPH["ident.robots.h4_equation"]


def _subpackage_graph() -> dict[str, set[str]]:
    """The import graph between sub-packages (``ident.processing``, ``ident.robots``, ...)."""
    out: dict[str, set[str]] = {}
    for name, targets in GRAPH.items():
        out.setdefault(_subpackage(name), set()).update(_subpackage(t) for t in targets)
    return {a: {b for b in bs if b != a and b in out} for a, bs in out.items()}


def test_processing_and_robots_form_no_cycle():
    """``ident.robots`` uses the processing chain; the chain never imports a robot, so the two sub-packages form no
    cycle (module by module there was none: processing.processing -> robots.h4 -> ..., robots.h4_interval ->
    processing.filtering)."""
    sub = _subpackage_graph()
    assert "ident.processing" in sub["ident.robots"]
    assert [c for c in _cycles(sub) if {"ident.processing", "ident.robots"} & set(c)] == []


def test_scenarios_import_no_numerics():
    """Rigorous residual and coverage checks live in ``ident`` (``ident.estimators.residuals``): a scenario
    calls them and does no interval arithmetic itself."""
    found = [f"{m} -> {t}" for m, ts in GRAPH.items() if m.startswith("scenarios") for t in sorted(ts)
             if t == "ident.numerics" or t.startswith("ident.numerics.")]
    assert found == []


def test_the_layer_check_sees_a_crossing():
    """The checker itself: the robot layer does import sim (lazily), and a crossing there must be found."""
    assert any(v.startswith("ident.robots.h4 -> sim") for v in _layer_violations("ident.robots", ("sim",), ()))


def _subpackage(name: str) -> str:
    path = MODULES[name]
    return name if path.name == "__init__.py" else name.rpartition(".")[0]


def test_no_private_name_crosses_a_subpackage():
    crossing = []
    for name, path in MODULES.items():
        for module, names in _imports(name, path):
            if module in MODULES and _subpackage(module) != _subpackage(name):
                crossing += [f"{name}: from {module} import {n}" for n in names
                             if n.startswith("_") and not n.startswith("__")]
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
    from h4bench.scenarios import registry

    module = registry.get(kind)
    assert callable(module.run) and isinstance(module.DESCRIPTION, str) and module.DESCRIPTION


def test_every_file_imports_the_packages_under_h4bench():
    """Run from the checkout, ``import ident`` would still find the folder (the current directory is on the path),
    so an import left in the old top-level form would pass here and fail when installed: none may remain."""
    old = set(h4bench.SUBPACKAGES)
    found = []
    for path in sorted(ROOT.rglob("*.py")):
        if any(part.startswith(".") or part in ("build", "venv") for part in path.relative_to(ROOT).parts):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                [node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level else [])
            found += [f"{path.relative_to(ROOT)}:{node.lineno} {n}" for n in names if n.split(".")[0] in old]
    assert found == []


@pytest.mark.parametrize("module, allowed", [
    # imported by sim and ident alike: nothing of the project's own
    ("checks", {"__future__", "numpy"}),
    # the BLAS-free linear algebra of every layer (sim's kinematics, ident's products, the designs)
    ("portable", {"__future__", "numpy"}),
    # read by the designs, scenarios.threads and the platform record: the standard library only
    ("blas", {"__future__", "contextlib", "ctypes", "os", "pathlib"}),
    # the content hashes and platform of a run: numpy, scipy's version, the BLAS probe
    ("fingerprint", {"__future__", "hashlib", "platform", "numpy", "scipy", "scipy.linalg", "h4bench.blas"}),
])
def test_the_shared_helpers_sit_below_every_layer(module, allowed):
    """The modules of ``h4bench/`` itself are imported by every layer, so they import none of them."""
    tree = ast.parse((ROOT / "h4bench" / f"{module}.py").read_text())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert imported <= allowed, imported - allowed
