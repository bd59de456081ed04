"""The registry of scenario kinds: one module per kind in :mod:`scenarios.kinds`, found by its file name.

A kind module defines ``DESCRIPTION`` (one line) and ``run(spec, seed, out, progress) -> dict``, which writes the
kind's files into ``out`` (a temporary folder the runner swaps into place when the run succeeds) and returns the
result (the common keys of ``docs/results.md``: ``scenario``, ``parameters``, ``true``, ``bound``,
``methods.<name>`` ...); ``docs/scenarios.md`` says how to add a kind.
A kind that fills its folder itself, resumably (a campaign), sets ``RESUMABLE = True``; its ``run`` then gets
the final folder and the runner's options (``only``, ``fresh``). A kind may declare ``SPEC_DEFAULTS``, a table of
spec sections of its own merged over :data:`scenarios.spec.DEFAULTS`.

Kind modules import neither each other nor this registry; the runner imports only this registry.

Lazy discovery: :func:`names` lists the kinds from the package's files without importing any kind, and
:func:`get` imports only the kind asked for, so a command pays for the imports of its own kind alone.
:func:`spec_defaults` reads each kind's ``SPEC_DEFAULTS`` from its source when it is a literal
(``ast.literal_eval``) and imports the kind only when it is not (a table built from another module's).
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import pkgutil
from pathlib import Path
from types import ModuleType

_PACKAGE = "h4bench.scenarios.kinds"


def _folder() -> list[str]:
    """The kinds package's folder(s), found without importing it."""
    spec = importlib.util.find_spec(_PACKAGE)
    if spec is None or not spec.submodule_search_locations:  # pragma: no cover - a broken installation
        raise ImportError(f"the scenario kinds package {_PACKAGE} is not installed")
    return list(spec.submodule_search_locations)


def names() -> tuple[str, ...]:
    """Every kind's name (= module name, e.g. ``prior_bound``), sorted; no kind module is imported."""
    return tuple(sorted(info.name for info in pkgutil.iter_modules(_folder()) if not info.name.startswith("_")))


def _load(name: str) -> ModuleType:
    module = importlib.import_module(f"{_PACKAGE}.{name}")
    if not callable(getattr(module, "run", None)):
        raise TypeError(f"scenario kind module {module.__name__} must define run(spec, seed, out, progress)")
    return module


def kinds() -> dict[str, ModuleType]:
    """Every kind: ``{name: module}`` (imports every kind module; :func:`names` does not)."""
    return {name: _load(name) for name in names()}


def get(name: str) -> ModuleType:
    """The module of kind ``name`` (``-`` and ``_`` alike), importing it alone; KeyError names the known kinds."""
    found = names()
    key = name.replace("-", "_") if isinstance(name, str) else name
    if key not in found:
        raise KeyError(f"kind must be one of {found}, got {name!r}")
    return _load(key)


def _literal_defaults(name: str):
    """The kind's ``SPEC_DEFAULTS`` read from its source: a dict, ``{}`` when the module assigns none, or None when
    the assignment is not a literal (the module must then be imported)."""
    path = next((Path(folder) / f"{name}.py" for folder in _folder() if (Path(folder) / f"{name}.py").is_file()),
                None)
    if path is None:  # not a plain source file (a package, a compiled module): ask the module itself
        return None
    for node in ast.parse(path.read_text(), filename=str(path)).body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) \
            else []
        if any(isinstance(t, ast.Name) and t.id == "SPEC_DEFAULTS" for t in targets):
            try:
                value = ast.literal_eval(node.value)
            except ValueError:
                return None
            return value if isinstance(value, dict) else None
    return {}


def spec_defaults() -> dict:
    """The spec sections the kinds declare (``SPEC_DEFAULTS``), merged in name order; a kind module is imported
    only when its table is not a literal."""
    out: dict = {}
    for name in names():
        found = _literal_defaults(name)
        out.update(found if found is not None else getattr(_load(name), "SPEC_DEFAULTS", {}))
    return out


def load_spec(name_or_path, quick: bool = False) -> dict:
    """A scenario spec with its kind checked against the registry and the kinds' own sections known."""
    from h4bench.scenarios.spec import load_spec as _load_spec

    return _load_spec(name_or_path, quick=quick, kinds=names(), extra_defaults=spec_defaults())
