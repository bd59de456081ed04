"""Running a scenario's methods (the first room of :mod:`scenarios.judging`).

:func:`run_methods` runs each method (a registry name, an entry point, ``"module:attribute"`` or a callable)
on ``|y - W theta| <= bound``, theta in the prior, and never lets one method cost the others: a method that
cannot be loaded, raises, or returns something that is not a box (wrong shape, NaN, lower > upper) is
``"failed"`` with a message naming it; :class:`~ident.InconsistentDataError` is ``"inconsistent"`` (proven
empty). The exact hull is always computed as the reference when any other method runs (stored as the
reference, not as a method, when ``"hull"`` is not in the list).
"""

from __future__ import annotations

import time
import traceback
from dataclasses import dataclass, field

from h4bench import ident
from h4bench.ident.estimators import isolation, registry

__all__ = ["Outcome", "describe_estimators", "parse_methods", "run_method", "run_methods"]


@dataclass
class Outcome:
    """What one method did: ``status`` "ok" (``box``), "inconsistent" (proven empty) or "failed" (``message``)."""

    name: str
    estimator: registry.Estimator | None
    status: str
    box: ident.Box | None = None
    message: str | None = None
    seconds: float = 0.0
    error: Exception | None = field(default=None, repr=False)  # the exception of an "inconsistent" / "failed"


def run_method(method, W, y, bound, prior, context: dict | None = None, timeout: float | None = None) -> Outcome:
    """Run one method (anything :func:`ident.estimators.registry.get` resolves) and catch everything it does.

    A plugin runs in a child process of its own (:mod:`ident.estimators.isolation`: it cannot change the inputs
    the other methods see, end this process, write to standard output or run past ``timeout`` seconds).
    Returns an :class:`Outcome`; never raises for a method's own failure (the message names the method).
    """
    name = method if isinstance(method, str) else getattr(method, "__name__", repr(method))
    t0 = time.perf_counter()
    try:
        est = isolation.resolve(method).estimator
    except Exception as exc:  # noqa: BLE001 - a plugin that cannot be loaded is reported, not raised
        text = str(exc) if repr(name) in str(exc) else f"estimator {name!r}: {exc}"
        return Outcome(name, None, "failed", message=text, seconds=time.perf_counter() - t0, error=exc)
    try:
        box = isolation.call(method, W, y, bound, prior, timeout=timeout, **(context or {}))
    except ident.InconsistentDataError as exc:
        return Outcome(name, est, "inconsistent", message=str(exc), seconds=time.perf_counter() - t0, error=exc)
    except ident.EstimatorError as exc:
        return Outcome(name, est, "failed", message=str(exc), seconds=time.perf_counter() - t0, error=exc)
    except Exception as exc:  # noqa: BLE001 - a built-in that raises costs only its own entry
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return Outcome(name, est, "failed", message=f"estimator {name!r} ({est.origin}) raised "
                       f"{type(exc).__name__}: {exc} (at {where.filename}:{where.lineno})",
                       seconds=time.perf_counter() - t0, error=exc)
    return Outcome(name, est, "ok", box=box, seconds=time.perf_counter() - t0)


def run_methods(methods, W, y, bound, prior, context: dict | None = None,
                timeout: float | None = None) -> tuple[dict, Outcome | None]:
    """Run every method of ``methods`` (a list) and the exact hull as reference; ``timeout`` [s] per method.

    Returns (outcomes by name in the list's order, the hull's outcome: the method ``"hull"``'s own if listed,
    else computed once more as the reference; None when the list is empty or only "hull").
    """
    outcomes = {}
    for method in methods:
        o = run_method(method, W, y, bound, prior, context, timeout)
        outcomes[o.name] = o
    if "hull" in outcomes:
        return outcomes, outcomes["hull"]
    if not outcomes:
        return outcomes, None
    return outcomes, run_method("hull", W, y, bound, prior, timeout=timeout)


def parse_methods(text) -> list[str]:
    """The method list of ``--methods a,b,c``: names (a built-in, an entry point of group ``h4bench.estimators``)
    or ``package.module:attribute``; ``all`` = every registered one (the built-ins and every entry point, those
    that fail to load included, so that each run reports them as failed) except the built-ins that need the
    derived interval regressor (``certified``: a derived error model adds it with what it needs). Duplicates are dropped. No entry point
    is loaded here; a ``module:attribute`` is resolved in a child process
    (:func:`ident.estimators.isolation.resolve`: its import code never runs in this process).

    Raises ValueError naming the argument for an empty list, a name nothing provides, or a ``module:attribute``
    that cannot be resolved (malformed, no such module or attribute, fails or exits at import, bad claims).
    """
    if not isinstance(text, str):
        raise TypeError(f"methods must be a comma-separated string, got {type(text).__name__}")
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise ValueError(f"methods must name at least one estimator (e.g. hull,cgsp or all), got {text!r}")
    usable, problems = registry.entry_point_names()
    known = [*registry.BUILTINS, *usable, *(n for n, _ in problems if n not in registry.BUILTINS)]
    out = []
    for item in items:
        if item == "all":  # the built-ins that need the derived interval regressor run only with it (certify)
            out += [n for n in known if not (n in registry.BUILTINS and any(
                registry.takes(n, k) for k in registry.DECLARED_ONLY_CONTEXT))]
        elif item in known:
            out.append(item)
        elif ":" in item:
            try:
                isolation.resolve(item)
            except ident.EstimatorError as exc:
                raise ValueError(f"methods: {item!r} cannot be resolved: {exc}") from None
            out.append(item)
        else:
            raise ValueError(f"methods: {item!r} is neither a registered estimator ({', '.join(known)}), 'all' nor "
                             "'package.module:attribute'")
    return list(dict.fromkeys(out))


def describe_estimators() -> dict:
    """Every estimator the registry knows (``h4bench estimators``): ``estimators`` a list of {name, kind,
    rigorous, level, origin, description, citation} and ``broken`` a list of {name, error}."""
    found = isolation.available()
    return {"estimators": [{"name": e.name, "kind": e.kind, "rigorous": e.rigorous, "level": e.level,
                            "origin": e.origin, "description": e.description, "citation": e.citation}
                           for e in found.estimators],
            "broken": [{"name": n, "error": err} for n, err in found.broken]}
