"""The one estimator registry: the built-in box estimators, plugins by entry point, ``module:attribute`` or callable.

An estimator is a callable ``f(W, y, bound, prior, **context) -> ident.Box`` with ``W`` (N, p), ``y`` (N,),
``bound`` (N,) > 0 (the error model ``|y - W theta| <= bound`` row by row, in y's units) and ``prior`` a Box with
finite bounds. Raising :class:`~ident.InconsistentDataError` means "proven empty". The Box's ``info["set"]`` may
carry the set itself (``{"type": "ellipsoid", "center", "shape"}`` or ``{"type": "zonotope", "center",
"generators"}``).

**Its claims, stated once**, as attributes of the callable (set by the :func:`declare` decorator, or by hand):
``kind`` (``"guaranteed"``, the default: an outer enclosure of ``{theta in prior : |y - W theta| <= bound}``; or
``"statistical"``: a confidence box), ``level`` (a statistical box's confidence level in (0, 1)), ``rigorous``
(True only if every rounding is outward; default False), ``description`` (one line), ``citation`` and ``context``
(the context keywords it takes, e.g. ``("groups",)``). The registry reads them from the callable whichever way it
is resolved (a built-in name, ``module:attribute``, an entry point, the callable itself), so the claims are the
same on every path. Without a declared ``context`` the callable's signature decides: its named keyword parameters,
and :data:`CONTEXT_KEYWORDS` when it takes ``**kwargs``. :func:`call` passes an estimator only the context it takes.

**The door**: a plugin named by a string (an entry point, ``"module:attribute"``) is never imported nor run in this
process. :func:`get` imports it in a child process (its claims and source hash come back as data) and gives an
Estimator whose ``func`` is a :class:`~ident.estimators.door.Isolated`: every call of it, by whichever caller,
runs the plugin in a forked child (:mod:`ident.estimators.door`). The built-ins run in this process; a callable
passed as the method is the caller's own code (already imported there) and runs where it is called
(:func:`ident.estimators.isolation.call` contains it too).

Where an estimator comes from (:func:`get`): a built-in name (:data:`BUILTINS`: ``hull``, ``cgsp``, ...), the name of an
entry point of group :data:`ENTRY_POINT_GROUP` in an installed distribution (``[project.entry-points.
"h4bench.estimators"] name = "package.module:function"``), a ``"package.module:attribute"`` string, or the callable
itself. :func:`available` lists the built-ins and the entry points, and the entry points that fail to load as
broken (name, error) instead of raising. :func:`call` checks the inputs with the one validator
(:func:`~ident.estimators.checks.check_problem`, the same for built-ins and plugins), passes the accepted context and
checks the returned box.
"""

from __future__ import annotations

import functools
import importlib
import importlib.metadata
import inspect
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Callable, NamedTuple

import numpy as np

from h4bench.ident.box import Box
from h4bench.ident.errors import EstimatorError
from h4bench.ident.estimators import door
from h4bench.ident.estimators.checks import check_problem, real_array

__all__ = ["BUILTINS", "CLAIMS", "CONTEXT_KEYWORDS", "ENTRY_POINT_GROUP", "KINDS", "Available", "Estimator",
           "available", "call", "claims_table", "declare", "entry_point_names", "forget", "get", "register", "takes"]

ENTRY_POINT_GROUP = "h4bench.estimators"
KINDS = ("guaranteed", "statistical")
CONTEXT_KEYWORDS = ("groups", "instruments")  #: the public context, passed to a ``**kwargs`` estimator
#: context an estimator gets only when it declares it: ``regressor_radius`` ((N, p) >= 0: W is the interval matrix
#: ``[W - r, W + r]``, the derived interval equation of a certified error model; the ``certified`` estimator)
DECLARED_ONLY_CONTEXT = ("regressor_radius",)
CLAIMS = ("kind", "rigorous", "level", "description", "citation", "context")  #: the attributes that are claims


@dataclass(frozen=True)
class Estimator:
    """A resolved estimator: its name, the callable and what it claims.

    ``origin``: ``"built-in"``, ``"entry point <distribution>"``, ``"module:attribute"`` (the string it was loaded
    from) or ``"callable"``. The claims (``kind`` ... ``context``) are the callable's own (module docstring);
    ``context`` the keywords :func:`call` passes it.
    """

    name: str
    func: Callable | str
    kind: str = "guaranteed"
    rigorous: bool = False
    level: float | None = None
    description: str = ""
    citation: str = ""
    origin: str = "callable"
    context: tuple[str, ...] = ()

    def resolve(self) -> Callable:
        """The callable (imported on first use for a built-in given as ``"module:attribute"``; for a plugin named by
        a string, the :class:`~ident.estimators.door.Isolated` callable that runs it in a child process)."""
        return _load(self.func, self.name) if isinstance(self.func, str) else self.func


class Available(NamedTuple):
    """What :func:`available` found: the usable estimators and the broken entry points ``(name, error)``."""

    estimators: tuple[Estimator, ...]
    broken: tuple[tuple[str, str], ...]


class _Builtins(Mapping):
    """The built-in estimators by name: ``"module:attribute"`` strings imported on first look-up (so that importing
    the registry imports no estimator module), their claims read from the callable."""

    def __init__(self) -> None:
        self._specs: dict[str, Callable | str] = {}
        self._resolved: dict[str, Estimator] = {}

    def add(self, name: str, func: Callable | str) -> None:
        self._specs[name] = func

    def __getitem__(self, name: str) -> Estimator:
        if name not in self._resolved:
            func = self._specs[name]
            self._resolved[name] = _from_callable(_load(func, name) if isinstance(func, str) else func, name,
                                                  "built-in")
        return self._resolved[name]

    def __contains__(self, name) -> bool:
        """Whether ``name`` is a built-in, without importing its module (``Mapping``'s default would look it up)."""
        return name in self._specs

    def __iter__(self):
        return iter(self._specs)

    def __len__(self) -> int:
        return len(self._specs)


BUILTINS: Mapping[str, Estimator] = _Builtins()


def _check_claims(name: str, kind, level, rigorous) -> None:
    if kind not in KINDS:
        raise EstimatorError(f"estimator {name!r}: kind must be one of {KINDS}, got {kind!r}")
    if kind == "statistical":
        if isinstance(level, bool) or not isinstance(level, (int, float)) or not 0.0 < level < 1.0:
            raise EstimatorError(f"estimator {name!r}: a statistical box needs a level in (0, 1), got {level!r}")
    elif level is not None:
        raise EstimatorError(f"estimator {name!r}: level is for statistical boxes only, got {level!r}")
    if not isinstance(rigorous, bool):
        raise EstimatorError(f"estimator {name!r}: rigorous must be True or False, got {rigorous!r}")


def declare(*, kind: str = "guaranteed", rigorous: bool = False, level: float | None = None, description: str = "",
            citation: str = "", context=None):
    """Decorator stating an estimator's claims once, as the attributes the registry reads (module docstring).

    kind : ``"guaranteed"`` or ``"statistical"``; rigorous : True only if every rounding is outward; level : a
    statistical box's confidence level in (0, 1) (None for guaranteed); description : one line; citation : the
    paper; context : the context keywords the estimator takes (a tuple of names; None: its signature decides).
    Raises EstimatorError for claims that do not fit (checked again when the registry reads them).
    """
    def mark(func: Callable) -> Callable:
        name = getattr(func, "__name__", type(func).__name__)
        _check_claims(name, kind, level, rigorous)
        func.kind, func.rigorous, func.level = kind, rigorous, None if level is None else float(level)
        func.description, func.citation = description, citation
        if context is not None:
            func.context = tuple(context)
        _context_of(func, name)  # a declared keyword the signature does not take is an error now, not at a call
        return func

    return mark


def register(name: str, func: Callable | str) -> None:
    """Register a built-in estimator under ``name`` (``func`` a callable or a ``"module:attribute"`` string, imported
    on first use). Its claims are the callable's own attributes (:func:`declare`), read when it is first looked up.

    Raises ValueError if the name is taken or not a non-empty string without ``':'``.
    """
    if not isinstance(name, str) or not name or ":" in name:
        raise ValueError(f"name must be a non-empty string without ':', got {name!r}")
    if name in BUILTINS:
        raise ValueError(f"estimator {name!r} is already registered")
    BUILTINS.add(name, func)


def _load(spec: str, name: str) -> Callable:
    """Import ``"package.module:attribute"`` (the attribute may be dotted); EstimatorError naming it otherwise."""
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise EstimatorError(f"estimator {name!r}: {spec!r} is not of the form 'package.module:attribute'")
    try:
        obj = importlib.import_module(module_name)
    except Exception as exc:
        raise EstimatorError(f"estimator {name!r}: cannot import {module_name!r} ({type(exc).__name__}: {exc})") \
            from exc
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise EstimatorError(f"estimator {name!r}: module {module_name!r} has no attribute {attr!r}") from None
    if not callable(obj):
        raise EstimatorError(f"estimator {name!r}: {spec!r} is a {type(obj).__name__}, not a callable")
    return obj


def _keywords(func: Callable) -> tuple[tuple[str, ...], bool]:
    """The named keyword parameters of ``func`` after its four positional ones, and whether it takes ``**kwargs``."""
    try:
        params = list(inspect.signature(func).parameters.values())
    except (TypeError, ValueError):  # no signature (some builtins): no context
        return (), False
    named = tuple(p.name for p in params[4:] if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD,
                                                            inspect.Parameter.KEYWORD_ONLY))
    return named, any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params)


def _context_of(func: Callable, name: str) -> tuple[str, ...]:
    """The context keywords ``func`` takes: its declared ``context`` (each one a keyword its signature accepts),
    else its named keyword parameters plus :data:`CONTEXT_KEYWORDS` when it takes ``**kwargs``."""
    named, var = _keywords(func)
    declared = getattr(func, "context", None)
    if declared is None:
        return tuple(dict.fromkeys((*named, *(CONTEXT_KEYWORDS if var else ()))))
    if isinstance(declared, str) or not all(isinstance(k, str) for k in declared):
        raise EstimatorError(f"estimator {name!r}: context must be a tuple of keyword names, got {declared!r}")
    missing = [k for k in declared if k not in named and not var]
    if missing:
        raise EstimatorError(f"estimator {name!r} declares the context {missing} that its signature does not take")
    return tuple(declared)


def _from_callable(func: Callable, name: str, origin: str) -> Estimator:
    """The Estimator of ``func`` with the claims read from its attributes (the one place that reads them)."""
    kind = getattr(func, "kind", "guaranteed")
    level = getattr(func, "level", None)
    rigorous = getattr(func, "rigorous", False)
    _check_claims(name, kind, level, rigorous)
    return Estimator(name, func, kind, rigorous, None if level is None else float(level),
                     str(getattr(func, "description", "") or ""), str(getattr(func, "citation", "") or ""), origin,
                     _context_of(func, name))


def _entry_points() -> list:
    return list(importlib.metadata.entry_points(group=ENTRY_POINT_GROUP))


def _from_entry_point(ep) -> Estimator:
    dist = getattr(ep, "dist", None)
    origin = f"entry point {dist.name if dist is not None else '?'}"
    try:
        func = ep.load()
    except Exception as exc:
        raise EstimatorError(f"estimator {ep.name!r} ({origin}, {ep.value}): cannot load "
                             f"({type(exc).__name__}: {exc})") from exc
    if not callable(func):
        raise EstimatorError(f"estimator {ep.name!r} ({origin}, {ep.value}) is a {type(func).__name__}, "
                             "not a callable")
    return _from_callable(func, ep.name, origin)


def _unusable(name: str) -> str | None:
    """Why an entry-point name cannot be a method name (None if it can)."""
    if not name or name != name.strip() or any(c.isspace() for c in name):
        return "not a usable method name (empty or with white space)"
    if "," in name or ":" in name:
        return "not a usable method name (',' separates methods and ':' marks 'module:attribute')"
    if name == "all":
        return "not a usable method name ('all' means every registered estimator)"
    return None


def entry_point_names() -> tuple[list[str], list[tuple[str, str]]]:
    """The entry points of group :data:`ENTRY_POINT_GROUP`, none loaded: (the usable names, in order; the
    unusable ones as ``(name, reason)``: a built-in's name, a name two distributions give, a name with ``,`` or
    ``:`` or white space, ``all``)."""
    by_name: dict[str, list] = {}
    for ep in _entry_points():
        by_name.setdefault(ep.name, []).append(ep)
    usable, problems = [], []
    for name, eps in by_name.items():
        dists = sorted({f"{getattr(ep.dist, 'name', '?')} ({ep.value})" for ep in eps})
        if name in BUILTINS:
            problems.append((name, f"the name of a built-in estimator ({', '.join(ep.value for ep in eps)} not loaded)"))
        elif len(dists) > 1 or len(eps) > 1:
            problems.append((name, f"given by {len(eps)} entry points ({', '.join(dists)}): ambiguous, none loaded"))
        elif _unusable(name):
            problems.append((name, f"{_unusable(name)}; {eps[0].value} not loaded"))
        else:
            usable.append(name)
    return usable, problems


def available() -> Available:
    """The built-ins and the entry points of group :data:`ENTRY_POINT_GROUP`, each entry point loaded in a child
    process of its own (:func:`get`: its import code never runs here); those that fail to load (raise, exit or
    crash at import), whose name is a built-in's, is given twice or is unusable (:func:`entry_point_names`) are
    listed in ``broken`` with the reason instead of raising."""
    found = list(BUILTINS.values())
    usable, broken = entry_point_names()
    for name in usable:
        try:
            found.append(get(name))
        except EstimatorError as exc:
            broken.append((name, str(exc)))
    return Available(tuple(found), tuple(broken))


def get(method) -> Estimator:
    """Resolve ``method``: a built-in name, an entry-point name, ``"package.module:attribute"`` or a callable.

    A built-in or a callable is returned as it is; a plugin named by a string is imported in a child process
    (remembered per process; :func:`forget`) and returned with ``func`` the
    :class:`~ident.estimators.door.Isolated` callable that runs it in a child process at every call.
    Raises TypeError for anything else than a string or a callable, EstimatorError (a ValueError) for a name
    that nothing provides or a plugin that cannot be loaded (the message names it and says why).
    """
    if isinstance(method, Estimator):
        return method
    if callable(method):
        return _from_callable(method, getattr(method, "__name__", type(method).__name__), "callable")
    if not isinstance(method, str):
        raise TypeError(f"method must be a string, one of {tuple(BUILTINS)}, an entry point of "
                        f"{ENTRY_POINT_GROUP!r} or 'package.module:attribute', or a callable, "
                        f"got {type(method).__name__}")
    if method in BUILTINS:
        return BUILTINS[method]
    if ":" not in method:
        usable, problems = entry_point_names()
        if method in dict(problems):
            raise EstimatorError(f"estimator {method!r}: {dict(problems)[method]}")
        if method not in usable:
            raise EstimatorError(f"method must be one of {tuple(BUILTINS)} (or an entry point of "
                                 f"{ENTRY_POINT_GROUP!r}, 'package.module:attribute' or a callable), got {method!r}")
    if method not in _PLUGINS:
        est, source = door.resolve_in_child(method, _describe_here)
        _PLUGINS[method] = replace(est, func=door.Isolated(est.name, est.origin, functools.partial(_call_here, method),
                                                           source=source))
    return _PLUGINS[method]


_PLUGINS: dict[str, Estimator] = {}


def forget() -> None:
    """Forget the plugins resolved in this process (e.g. after a plugin's file changed)."""
    _PLUGINS.clear()


def _get_here(method: str) -> Estimator:
    """A plugin named by ``method`` imported in *this* process: for a door's child only (:func:`_describe_here`,
    :func:`_call_here`)."""
    if ":" in method:
        return _from_callable(_load(method, method), method, method)
    return _from_entry_point(next(ep for ep in _entry_points() if ep.name == method))


def _describe_here(method: str) -> tuple[Estimator, dict]:
    """In a door's child: the plugin's Estimator (``func`` the method string) and the provenance of its code
    (``{"module", "sha256"}``, for an entry point also ``"distribution"`` and ``"version"``)."""
    est = _get_here(method)
    if ":" in method:
        source = door.module_source(method.partition(":")[0])
    else:
        ep = next(ep for ep in _entry_points() if ep.name == method)
        source = {**door.module_source(ep.value.partition(":")[0]), "distribution": getattr(ep.dist, "name", None),
                  "version": getattr(ep.dist, "version", None)}
    return replace(est, func=method), source


def _call_here(method: str, W, y, b, prior, **context) -> Box:
    """In a door's child: run the plugin named by ``method`` on checked inputs and check its box (so that only plain
    data comes back)."""
    est = _get_here(method)
    return _check_result(est, est.resolve()(W, y, b, prior, **context), W.shape[1], prior.names)


def _check_context(context: dict, n: int, p: int) -> dict:
    out = dict(context)
    if out.get("groups") is not None:
        g = np.asarray(out["groups"])
        if g.shape != (n,) or g.dtype.kind not in "iu":
            raise ValueError(f"groups must be an integer array of shape ({n},), got {g.dtype} {g.shape}")
        out["groups"] = g
    if out.get("instruments") is not None:
        z = real_array(out["instruments"], "instruments")
        if z.shape != (n, p):
            raise ValueError(f"instruments must have shape ({n}, {p}) like W, got {z.shape}")
        out["instruments"] = z
    if out.get("regressor_radius") is not None:
        d = real_array(out["regressor_radius"], "regressor_radius")
        if d.shape != (n, p) or not np.all(d >= 0):
            raise ValueError(f"regressor_radius must have shape ({n}, {p}) like W with entries >= 0, got {d.shape}")
        out["regressor_radius"] = d
    return out


def _check_result(est: Estimator, box, p: int, names: tuple[str, ...] | None = None) -> Box:
    """The returned Box (or, from a plugin, a ``(lower, upper)`` pair, made a Box with the prior's names),
    checked: p parameters, finite, lower <= upper; EstimatorError naming the estimator otherwise."""
    def bad(what: str) -> EstimatorError:
        return EstimatorError(f"estimator {est.name!r} ({est.origin}) returned {what}")

    if isinstance(box, Box):
        lower, upper = box.lower, box.upper
    elif names is not None and isinstance(box, (tuple, list)) and len(box) == 2:
        try:
            lower, upper = (np.asarray(v, dtype=float) for v in box)
        except (TypeError, ValueError):
            raise bad("a (lower, upper) pair that is not numeric") from None
    else:
        raise bad(f"a {type(box).__name__}, not an ident.Box")
    if lower.shape != (p,) or upper.shape != (p,):
        raise bad(f"a box of shape {lower.shape} / {upper.shape} for a prior of {p} parameters")
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
        raise bad(f"a box with non-finite bounds ({int(np.sum(~np.isfinite(lower)) + np.sum(~np.isfinite(upper)))}"
                  " NaN or inf endpoints)")
    if np.any(lower > upper):
        raise bad(f"a box with lower > upper for parameter(s) {np.flatnonzero(lower > upper).tolist()}")
    return box if isinstance(box, Box) else Box(lower, upper, names)


def claims_table() -> str:
    """The built-ins' claims as the Markdown table of ``docs/estimators.md`` (a test checks the page holds it)."""
    rows = ["| name | kind | rigorous | context | what it is | citation |", "|---|---|---|---|---|---|"]
    for est in BUILTINS.values():
        kind = est.kind if est.level is None else f"{est.kind}, {est.level:g}"
        context = ", ".join(f"`{k}`" for k in est.context) or "-"
        rows.append(f"| `{est.name}` | {kind} | {'yes' if est.rigorous else 'no'} | {context} | {est.description} "
                    f"| {est.citation} |")
    return "\n".join(rows)


def takes(method, keyword: str) -> bool:
    """Whether ``method`` (anything :func:`get` resolves) takes the context ``keyword`` (:attr:`Estimator.context`);
    False for a method that cannot be resolved (running it reports why)."""
    try:
        return keyword in get(method).context
    except (TypeError, ValueError):
        return False


def call(est, W, y, bound, prior, **context) -> Box:
    """Run an estimator (anything :func:`get` resolves) on checked inputs and check its box.

    W (N, p), y (N,), bound (a scalar or (N,) > 0), prior a Box or a (lower, upper) pair: checked by the one
    validator, :func:`~ident.estimators.checks.check_problem` (N >= 1, also N < p), the same for every estimator;
    the estimator receives them converted (float arrays, bound (N,), prior a Box with the prior's names).
    context : keywords, each passed only to an estimator that takes it (:attr:`Estimator.context`): ``groups``,
    ``instruments``, a built-in's ``check_consistency``, ...; ``groups`` and ``instruments`` are checked.
    Returns the Box (an estimator may also return a ``(lower, upper)`` pair: it becomes a Box with the prior's
    names); EstimatorError naming the estimator if it is not a box of the prior's shape, finite, with lower <= upper.
    A plugin named by a string runs in a child process (:func:`get` gives it as an
    :class:`~ident.estimators.door.Isolated`): what it raised, an exit, a crash or a change of its inputs comes back
    as an EstimatorError naming it.
    """
    est = get(est)
    func = est.resolve()
    W, y, b, lo, hi, names = check_problem(W, y, bound, prior)
    context = _check_context({k: v for k, v in context.items() if k in est.context}, *W.shape)
    box = func(W, y, b, Box(lo, hi, names), **context)
    return _check_result(est, box, W.shape[1], names)


# The built-ins: each module states its claims on the function (``declare``); the registry only names them.
register("hull", "h4bench.ident.estimators.estimate:hull_estimator")
register("cgsp", "h4bench.ident.estimators.estimate:cgsp_estimator")
register("ellipsoid", "h4bench.ident.estimators.ellipsoid:ellipsoid")
register("zonotope", "h4bench.ident.estimators.zonotope:zonotope")
register("parallelotope", "h4bench.ident.estimators.zonotope:parallelotope")
register("contractor", "h4bench.ident.estimators.contractor:contractor")
register("ols", "h4bench.ident.estimators.statistical:ols")
register("wls", "h4bench.ident.estimators.statistical:wls")
register("iv", "h4bench.ident.estimators.statistical:iv")
register("certified", "h4bench.ident.estimators.certified:certified")
