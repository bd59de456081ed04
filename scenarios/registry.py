"""The registry of scenario kinds: one module per kind in :mod:`scenarios.kinds`, found by its file name.

A kind module defines ``DESCRIPTION`` (one line) and ``run(spec, seed, out, progress) -> dict``, which writes the
kind's files into ``out`` (a temporary folder the runner swaps into place when the run succeeds) and returns the
result (the common keys of ``docs/results.md``: ``scenario``, ``parameters``, ``true``, ``bound``,
``methods.<name>`` ...); ``docs/scenarios.md`` says how to add a kind.
A kind that fills its folder itself, resumably (a campaign), sets ``RESUMABLE = True``; its ``run`` then gets
the final folder and the runner's options (``only``, ``fresh``). A kind may declare ``SPEC_DEFAULTS``, a table of
spec sections of its own merged over :data:`scenarios.spec.DEFAULTS`.

Kind modules import neither each other nor this registry; the runner imports only this registry.
"""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType

_PACKAGE = "h4bench.scenarios.kinds"


def kinds() -> dict[str, ModuleType]:
    """Every kind: ``{name: module}`` (name = module name, e.g. ``prior_bound``)."""
    package = importlib.import_module(_PACKAGE)
    found = {}
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{_PACKAGE}.{info.name}")
        if not callable(getattr(module, "run", None)):
            raise TypeError(f"scenario kind module {module.__name__} must define run(spec, seed, out, progress)")
        found[info.name] = module
    return found


def names() -> tuple[str, ...]:
    return tuple(kinds())


def get(name: str) -> ModuleType:
    """The module of kind ``name`` (``-`` and ``_`` alike); KeyError names the known kinds."""
    found = kinds()
    key = name.replace("-", "_")
    if key not in found:
        raise KeyError(f"kind must be one of {tuple(found)}, got {name!r}")
    return found[key]


def spec_defaults() -> dict:
    """The spec sections the kinds declare (``SPEC_DEFAULTS``), merged."""
    out: dict = {}
    for module in kinds().values():
        out.update(getattr(module, "SPEC_DEFAULTS", {}))
    return out


def load_spec(name_or_path, quick: bool = False) -> dict:
    """A scenario spec with its kind checked against the registry and the kinds' own sections known."""
    from h4bench.scenarios.spec import load_spec as _load

    return _load(name_or_path, quick=quick, kinds=names(), extra_defaults=spec_defaults())
