"""The documentation in ``docs/`` against the code: the ``result.json`` schema of ``docs/results.md`` against a
real quick paper run (both ways), the estimator registry's claims, and a repository that stands alone (no file
points to design notes outside it)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = ("design.md", "conventions.md", "results.md", "estimators.md", "scenarios.md")

_ROW = re.compile(r"^\|\s*`([^`]+)`")


def documented(section_title: str) -> dict[str, str]:
    """``{key path: type cell}`` of every table row in the section of docs/results.md whose ``## `` heading
    starts with ``section_title`` (its ``###`` subsections included)."""
    text = (DOCS / "results.md").read_text()
    parts = re.split(r"^## ", text, flags=re.M)
    section = [p for p in parts if p.startswith(section_title)]
    assert len(section) == 1, f"one section {section_title!r} in docs/results.md, found {len(section)}"
    rows = {}
    for line in section[0].splitlines():
        m = _ROW.match(line)
        if m:
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))]  # a pipe in a cell is \|
            rows[m.group(1)] = cells[1]
    return rows


def key_paths(result: dict, opaque: set[str]) -> set[str]:
    """Every key path of a result (the notation of docs/results.md: ``methods.<method>``, ``[]`` for the elements of
    a list of objects, ``<parameter>`` for a table keyed by parameter name), not entering ``opaque`` paths."""
    names = set(result.get("parameters") or ())
    found: set[str] = set()

    def walk(x, path: str) -> None:
        if path in opaque:
            return
        if isinstance(x, dict):
            keyed = path.rsplit(".", 1)[-1] == "methods"
            by_parameter = bool(x) and set(x) <= names
            for k, v in x.items():
                sub = "<method>" if keyed else ("<parameter>" if by_parameter else k)
                q = f"{path}.{sub}" if path else sub
                found.add(q)
                walk(v, q)
        elif isinstance(x, list) and x and all(isinstance(e, dict) for e in x):
            for e in x:
                walk(e, path + "[]")

    walk(result, "")
    return found


def test_key_paths_notation():
    """The path notation on a hand-made result (the expected set written out by hand)."""
    r = {"parameters": ["a", "b"], "methods": {"hull": {"status": "ok", "info": {"x": 1}}, "cgsp": {"status": "ok"}},
         "sweep": [{"bound": 1.0}, {"bound": 2.0, "extra": True}], "per": {"a": 1.0, "b": 2.0}}
    assert key_paths(r, {"methods.<method>.info"}) == {
        "parameters", "methods", "methods.<method>", "methods.<method>.status", "methods.<method>.info", "sweep",
        "sweep[].bound", "sweep[].extra", "per", "per.<parameter>"}


@pytest.fixture(scope="module")
def paper_result(paper_quick_cli):
    import json

    out, _ = paper_quick_cli
    return json.loads((out / "result.json").read_text())


def test_paper_schema_matches_a_quick_run(paper_result):
    """Every key of a quick paper run's result.json is documented in the paper section of docs/results.md, and
    every key documented there without a condition ``(if ...)`` is in the run."""
    doc = documented("Common keys")
    opaque = {k for k, t in doc.items() if "free-form" in t}
    run = key_paths(paper_result, opaque)
    undocumented = sorted(run - set(doc))
    assert not undocumented, f"keys of the paper result not in docs/results.md: {undocumented}"
    required = {k for k, t in doc.items() if "(if" not in t}
    missing = sorted(required - run)
    assert not missing, f"keys documented in docs/results.md but not in a quick paper run: {missing}"


def _tracked_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
        files = [ROOT / f for f in out.decode().split("\0") if f]
    except (OSError, subprocess.CalledProcessError):  # not a git checkout: every file but caches and runs
        files = [f for f in ROOT.rglob("*") if f.is_file()
                 and not {".git", "runs", "__pycache__", ".venv"} & set(f.relative_to(ROOT).parts)]
    return [f for f in files if f.suffix in {".py", ".md", ".toml", ".txt", ".cfg", ".yml", ".yaml", ".xml"}]


def test_the_repository_stands_alone():
    """No file of the project cites design notes that are not in it (the names are built here so that this
    test does not cite them itself)."""
    outside = ["DESIGN" + ".md", "NOTES" + ".md", "../" + "shared", "/work/" + "shared"]
    hits = []
    for f in _tracked_files():
        if not f.is_file():
            continue
        text = f.read_text(errors="replace")
        hits += [f"{f.relative_to(ROOT)}: {s}" for s in outside if s in text]
    assert not hits, hits


def test_the_pages_exist_and_the_readme_points_to_them():
    readme = (ROOT / "README.md").read_text()
    for page in PAGES:
        assert (DOCS / page).is_file(), page
        assert f"docs/{page}" in readme, f"README.md does not point to docs/{page}"


def test_every_registered_estimator_states_its_claims():
    """Each built-in of the estimator registry has a kind, a one-line description and a citation, a statistical
    one its level, and docs/estimators.md names it."""
    from h4bench.ident.estimators import registry

    page = (DOCS / "estimators.md").read_text()
    assert registry.BUILTINS
    for name, est in registry.BUILTINS.items():
        assert est.kind in registry.KINDS, name
        assert est.description and "\n" not in est.description, name
        assert est.citation, name
        assert (est.level is not None) == (est.kind == "statistical"), name
        assert f"`{name}`" in page, f"docs/estimators.md does not name the estimator {name!r}"


def test_the_estimators_table_is_the_registrys():
    """docs/estimators.md holds the table generated from the functions' claims (registry.claims_table), verbatim."""
    from h4bench.ident.estimators import registry

    table = registry.claims_table()
    assert table.count("\n") == len(registry.BUILTINS) + 1
    assert table in (DOCS / "estimators.md").read_text(), "regenerate the table: registry.claims_table()"


PUBLIC = ("h4bench.ident", "h4bench.sim", "h4bench.trajectories", "h4bench.scenarios.export", "h4bench.scenarios.arm_log")


def public_objects():
    """``(qualified name, object)`` of every function and class in the ``__all__`` of the documented packages
    (the API reference of the site, docs/api/*.md), and of every public method those classes define."""
    import importlib
    import inspect

    for package in PUBLIC:
        mod = importlib.import_module(package)
        for name in mod.__all__:
            obj = getattr(mod, name)
            if not (inspect.isclass(obj) or inspect.isfunction(obj)):
                continue
            yield f"{package}.{name}", obj
            if inspect.isclass(obj):
                for attr, member in vars(obj).items():
                    if not attr.startswith("_") and inspect.isfunction(member):
                        yield f"{package}.{name}.{attr}", member


def test_every_public_function_has_a_docstring():
    names = [name for name, _ in public_objects()]
    assert len(names) > 100  # the four packages' public names and their methods
    missing = [name for name, obj in public_objects() if not (obj.__doc__ or "").strip()]
    assert not missing, f"public functions and classes without a docstring: {missing}"


def test_the_docstring_check_can_fail(monkeypatch):
    """The check above sees a public function whose docstring is removed."""
    from h4bench.ident import box

    monkeypatch.setattr(box.Box.to_dict, "__doc__", None)
    assert "h4bench.ident.Box.to_dict" in [name for name, obj in public_objects() if not (obj.__doc__ or "").strip()]
