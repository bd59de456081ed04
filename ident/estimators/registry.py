"""The one estimator registry: the built-in box estimators, plugins by entry point, ``module:attribute`` or callable.

An estimator is a callable ``f(W, y, bound, prior, **context) -> ident.Box`` with ``W`` (N, p), ``y`` (N,),
``bound`` (N,) > 0 (the error model ``|y - W theta| <= bound`` row by row, in y's units) and ``prior`` a Box with
finite bounds. Optional context keywords, passed only when the callable's signature accepts them (a named
parameter or ``**kwargs``): ``groups`` ((N,) ints: which joint/output each row belongs to) and ``instruments``
((N, p) floats, row-aligned with W) and ``regressor_radius`` ((N, p) floats >= 0: W is an interval matrix
``[W - r, W + r]``; the ``certified`` estimator needs it). Optional attributes of the callable: ``kind`` (``"guaranteed"``, the default:
an outer enclosure of ``{theta in prior : |y - W theta| <= bound}``; or ``"statistical"``: a confidence box),
``level`` (a statistical box's confidence level in (0, 1)), ``rigorous`` (True only if every rounding is outward;
default False for plugins), ``description`` (one line) and ``citation``. Raising
:class:`~ident.InconsistentDataError` means "proven empty". The Box's ``info["set"]`` may carry the set itself
(``{"type": "ellipsoid", "center", "shape"}`` or ``{"type": "zonotope", "center", "generators"}``).

Where an estimator comes from (:func:`get`): a built-in name (:data:`BUILTINS`: ``hull``, ``cgsp``), the name of an
entry point of group :data:`ENTRY_POINT_GROUP` in an installed distribution (``[project.entry-points.
"h4bench.estimators"] name = "package.module:function"``), a ``"package.module:attribute"`` string, or the callable
itself. :func:`available` lists the built-ins and the entry points, and the entry points that fail to load as
broken (name, error) instead of raising. :func:`call` passes the accepted context and checks the returned box.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import inspect
from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from h4bench.ident.box import Box
from h4bench.ident.errors import EstimatorError
from h4bench.ident.estimators.checks import check_bound, check_prior, check_W_y, real_array

__all__ = ["BUILTINS", "CONTEXT_KEYWORDS", "ENTRY_POINT_GROUP", "KINDS", "Available", "Estimator", "available",
           "call", "get", "register"]

ENTRY_POINT_GROUP = "h4bench.estimators"
KINDS = ("guaranteed", "statistical")
CONTEXT_KEYWORDS = ("groups", "instruments", "regressor_radius")


@dataclass(frozen=True)
class Estimator:
    """A resolved estimator: its name, the callable and what it claims.

    ``origin``: ``"built-in"``, ``"entry point <distribution>"``, ``"module:attribute"`` (the string it was loaded
    from) or ``"callable"``. ``func`` of a built-in may be a ``"module:attribute"`` string until first use
    (:meth:`resolve`), so that the registry imports no estimator module.
    """

    name: str
    func: Callable | str
    kind: str = "guaranteed"
    rigorous: bool = False
    level: float | None = None
    description: str = ""
    citation: str = ""
    origin: str = "callable"

    def resolve(self) -> Callable:
        """The callable (imported on first use for a built-in given as ``"module:attribute"``)."""
        return _load(self.func, self.name) if isinstance(self.func, str) else self.func


class Available(NamedTuple):
    """What :func:`available` found: the usable estimators and the broken entry points ``(name, error)``."""

    estimators: tuple[Estimator, ...]
    broken: tuple[tuple[str, str], ...]


BUILTINS: dict[str, Estimator] = {}


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


def register(name: str, func: Callable | str, *, kind: str = "guaranteed", rigorous: bool = False,
             level: float | None = None, description: str = "", citation: str = "") -> Estimator:
    """Register a built-in estimator under ``name`` (``func`` a callable or a ``"module:attribute"`` string).

    Raises ValueError if the name is taken or not an identifier-like string, EstimatorError for claims that do not
    fit (unknown kind, a statistical box without a level in (0, 1)).
    """
    if not isinstance(name, str) or not name or ":" in name:
        raise ValueError(f"name must be a non-empty string without ':', got {name!r}")
    if name in BUILTINS:
        raise ValueError(f"estimator {name!r} is already registered")
    _check_claims(name, kind, level, rigorous)
    est = Estimator(name, func, kind, rigorous, None if level is None else float(level), description, citation,
                    "built-in")
    BUILTINS[name] = est
    return est


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


def _from_callable(func: Callable, name: str, origin: str) -> Estimator:
    kind = getattr(func, "kind", "guaranteed")
    level = getattr(func, "level", None)
    rigorous = getattr(func, "rigorous", False)
    _check_claims(name, kind, level, rigorous)
    return Estimator(name, func, kind, rigorous, None if level is None else float(level),
                     str(getattr(func, "description", "") or ""), str(getattr(func, "citation", "") or ""), origin)


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


def available() -> Available:
    """The built-ins and the entry points of group :data:`ENTRY_POINT_GROUP`; those that fail to load (or whose
    name is a built-in's) are listed in ``broken`` with the reason instead of raising."""
    found, broken = list(BUILTINS.values()), []
    for ep in _entry_points():
        if ep.name in BUILTINS:
            broken.append((ep.name, f"the name of a built-in estimator ({ep.value} not loaded)"))
            continue
        try:
            found.append(_from_entry_point(ep))
        except EstimatorError as exc:
            broken.append((ep.name, str(exc)))
    return Available(tuple(found), tuple(broken))


def get(method) -> Estimator:
    """Resolve ``method``: a built-in name, an entry-point name, ``"package.module:attribute"`` or a callable.

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
    if ":" in method:
        return _from_callable(_load(method, method), method, method)
    for ep in _entry_points():
        if ep.name == method:
            return _from_entry_point(ep)
    raise EstimatorError(f"method must be one of {tuple(BUILTINS)} (or an entry point of {ENTRY_POINT_GROUP!r}, "
                         f"'package.module:attribute' or a callable), got {method!r}")


def _accepted(func: Callable, context: dict) -> dict:
    try:
        params = inspect.signature(func).parameters.values()
    except (TypeError, ValueError):  # no signature (some builtins): pass no context
        return {}
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
        return dict(context)
    named = {p.name for p in params if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD,
                                                   inspect.Parameter.KEYWORD_ONLY)}
    return {k: v for k, v in context.items() if k in named}


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


def call(est, W, y, bound, prior, **context) -> Box:
    """Run an estimator (anything :func:`get` resolves) and check its box.

    W (N, p), y (N,), bound (a scalar or (N,) > 0), prior a Box or a (lower, upper) pair; context: keywords
    passed only if the callable accepts them (``groups``, ``instruments``, a built-in's ``check_consistency``).
    A built-in receives the arguments as given (it checks them itself, with the same messages); a plugin
    receives them checked and converted (float arrays, bound (N,), prior a Box with the prior's names).
    Returns the Box (a plugin may also return a ``(lower, upper)`` pair: it becomes a Box with the prior's names);
    EstimatorError naming the estimator if it is not a box of the prior's shape, finite, with lower <= upper.
    """
    est = get(est)
    func = est.resolve()
    if est.origin == "built-in":
        box = func(W, y, bound, prior, **_accepted(func, context))
        return _check_result(est, box, np.shape(W)[1])
    W, y = check_W_y(W, y)
    b, _ = check_bound(bound, W.shape[0])
    lo, hi, names = check_prior(prior, W.shape[1])
    context = _check_context(context, *W.shape)
    box = func(W, y, b, Box(lo, hi, names), **_accepted(func, context))
    return _check_result(est, box, W.shape[1], names)


register("hull", "h4bench.ident.estimators.estimate:hull_estimator", kind="guaranteed", rigorous=True,
         description="the exact interval hull of the feasible set: 2p linear programs with safe dual bounds",
         citation="Neumaier & Shcherbina, Math. Program. 99 (2004): safe bounds in linear programming")
register("cgsp", "h4bench.ident.estimators.estimate:cgsp_estimator", kind="guaranteed", rigorous=True,
         description="the paper's preconditioned interval Gauss-Seidel on Rump's system (an outer box)",
         citation="Poignet, Ramdani & Vivas (CDC 2003, sec. 3); Rump (2002)")

# the reference estimators of the bounded-error literature and the statistical references (their modules carry
# the same claims as attributes; tests/ident/estimators/test_protocol.py checks the two agree)
register("ellipsoid", "h4bench.ident.estimators.ellipsoid:ellipsoid", kind="guaranteed", rigorous=False,
         description="optimal bounding ellipsoid: recursive minimum-volume strip updates (not rigorous in fp)",
         citation="Fogel & Huang, Automatica 18(2):229-238, 1982")
register("zonotope", "h4bench.ident.estimators.zonotope:zonotope", kind="guaranteed", rigorous=False,
         description="zonotope by sequential strip intersection (F-radius), order reduction to 3 p generators "
                     "(not rigorous in fp)",
         citation="Alamo, Bravo & Camacho, Automatica 41(6):1035-1043, 2005; Bravo, Alamo & Camacho, IEEE TAC "
                  "51(7):1144-1150, 2006")
register("parallelotope", "h4bench.ident.estimators.zonotope:parallelotope", kind="guaranteed", rigorous=False,
         description="minimum-volume parallelotope by sequential strip intersection (not rigorous in fp)",
         citation="Chisci, Garulli & Zappa, Automatica 32(7):1049-1055, 1996")
register("contractor", "h4bench.ident.estimators.contractor:contractor", kind="guaranteed", rigorous=True,
         description="forward-backward interval contractor on the strips, Jacobi sweeps to a fixed point",
         citation="Jaulin, Kieffer, Didrit & Walter, Applied Interval Analysis, Springer 2001, ch. 4")
register("ols", "h4bench.ident.estimators.statistical:ols", kind="statistical", rigorous=False, level=0.95,
         description="least squares, 95 % Bonferroni confidence box (Gaussian homoscedastic errors)",
         citation="ordinary least squares; Bonferroni simultaneous t intervals")
register("wls", "h4bench.ident.estimators.statistical:wls", kind="statistical", rigorous=False, level=0.95,
         description="Gautier's per-joint weighted least squares, 95 % Bonferroni confidence box",
         citation="Gautier & Poignet, Control Engineering Practice 9(12):1361-1372, 2001")
register("iv", "h4bench.ident.estimators.statistical:iv", kind="statistical", rigorous=False, level=0.95,
         description="instrumental variables (IDIM-IV), 95 % Bonferroni confidence box (asymptotic)",
         citation="Janot, Vandanjon & Gautier, IEEE TCST 22(1):132-145, 2014")
register("certified", "h4bench.ident.estimators.uncertain:certified", kind="guaranteed", rigorous=True,
         description="the Oettli-Prager hull of an interval regressor [W - r, W + r] (context key regressor_radius)",
         citation="Oettli & Prager, Numer. Math. 6 (1964)")
