"""Every estimator judged side by side: one place that runs a scenario's methods and builds their result entries.

:func:`run_methods` runs each method (a registry name, an entry point, ``"module:attribute"`` or a callable)
on ``|y - W theta| <= bound``, theta in the prior, and never lets one method cost the others: a method that
cannot be loaded, raises, or returns something that is not a box (wrong shape, NaN, lower > upper) is
``"failed"`` with a message naming it; :class:`~ident.InconsistentDataError` is ``"inconsistent"`` (proven
empty). The exact hull is always computed as the reference when any other method runs (stored as the
reference, not as a method, when ``"hull"`` is not in the list).

:func:`judge` turns the outcomes into the per-method entries of ``result.json``: ``kind``, ``rigorous``,
``level``, ``origin``, ``status``, ``lower``, ``upper``, ``width``, ``enclosed`` / ``all_enclosed`` (when a truth
is known, else null), ``width_vs_hull`` (its width over the hull's, per parameter), ``unsound`` and
``narrower_than_hull`` (guaranteed methods), ``seconds``.

The narrower-than-hull check (:class:`HullReference`). The hull box H = [h_lo, h_hi] is the smallest box
enclosing the feasible set S (its endpoints rigorous outer bounds). Its 2p LP solutions (the points attaining
the endpoints, computed in floating point) are proven in S by :func:`ident.estimators.proof.proven_points`
(outward-rounded residuals, ``max_k |y_k - W_k x| / b_k <= 1``, and x in the prior; a point that fails is pulled
towards a verified point of S along the segment, or dropped): the same proof as ``h4bench check-estimator``. The proven points are in S, so per
coordinate j the inner endpoints ``in_lo_j = min x_j``, ``in_hi_j = max x_j`` over them lie in the exact hull, and
the hull's tolerance is ``tol_lo_j = in_lo_j - h_lo_j``, ``tol_hi_j = h_hi_j - in_hi_j`` (how far the exact hull
may lie inside H). A guaranteed box B is **unsound** when in some coordinate ``B_lo_j > h_lo_j + tol_lo_j`` or
``B_hi_j < h_hi_j - tol_hi_j``: it then excludes a point proven to lie in S (so it is not an outer enclosure, a
proof). Where no point is proven (S empty within the LP tolerance, or thinner than the rounding: the
``enclosure-critical`` campaign), the tolerance falls back to :data:`HULL_RTOL` relative to the hull's
endpoints, ``tol_j = HULL_RTOL * max(|h_lo_j|, |h_hi_j|)`` (``hull_tolerance`` in the entry: its ``source``,
"proven points" or "relative HULL_RTOL", and the tolerances per coordinate, ``lower`` and ``upper``):
a box narrower than that is flagged, but without a proof. A method that says "proven empty" while a point of S
is proven is unsound in every coordinate. A statistical box claims no enclosure: it is never unsound.
"""

from __future__ import annotations

import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from h4bench import ident
from h4bench.ident.estimators import isolation, registry
from h4bench.ident.estimators.proof import proven_points

__all__ = ["HULL_RTOL", "HullReference", "Outcome", "clopper_pearson", "describe_estimators", "hull_reference",
           "judge", "parse_methods", "run_method", "run_methods", "summarise_methods"]

#: relative tolerance (of the hull's endpoint magnitudes) of the narrower-than-hull check where no hull point is
#: proven feasible. Nothing can be proven there, so this is a stated heuristic: 100 times the hull LPs' feasibility
#: tolerance (1e-9 on the rows scaled by their bound; the unproven LP points violate them by up to a few 1e-10),
#: so that the looseness of the LP optimum alone never flags a sound box. On ``enclosure-critical`` the hull's
#: widths are about 1e-13 of the endpoints, far below it: the check is silent there and the truth check decides.
HULL_RTOL = 1e-7


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
    that fail to load included, so that each run reports them as failed). Duplicates are dropped. No entry point
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
        if item == "all":
            out += known
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


@dataclass
class HullReference:
    """The exact hull as the reference of the narrower-than-hull check (module docstring).

    lower, upper : (p,) the hull box; inner_lower, inner_upper : (p,) the proven inner endpoints (NaN where no
    point is proven); tol_lower, tol_upper : (p,) the tolerances; proven : number of proven points;
    source : "proven points" or "relative HULL_RTOL" (the fallback).
    """

    lower: np.ndarray
    upper: np.ndarray
    inner_lower: np.ndarray
    inner_upper: np.ndarray
    tol_lower: np.ndarray
    tol_upper: np.ndarray
    proven: int
    source: str
    seconds: float = 0.0
    points: np.ndarray | None = field(default=None, repr=False)

    def narrower(self, lower, upper) -> np.ndarray:
        """(p,) bool: coordinates where [lower, upper] is narrower than the hull beyond its tolerance."""
        return (np.asarray(lower) > self.lower + self.tol_lower) | (np.asarray(upper) < self.upper - self.tol_upper)

    def tolerance(self) -> dict:
        """The check's tolerance per coordinate, as written in a guaranteed method's entry (``hull_tolerance``)."""
        return {"source": self.source, "lower": self.tol_lower.tolist(), "upper": self.tol_upper.tolist(),
                **({"rtol": HULL_RTOL} if self.source != "proven points" else {})}

    def describe(self) -> dict:
        return {"lower": self.lower.tolist(), "upper": self.upper.tolist(), "source": self.source,
                "proven_points": self.proven, "rtol": HULL_RTOL,
                "tolerance_lower": self.tol_lower.tolist(), "tolerance_upper": self.tol_upper.tolist(),
                "seconds": self.seconds}


def hull_reference(W, y, bound, prior, hull: ident.Box) -> HullReference:
    """The reference of the check from the hull box and its LP points (``hull.info["points"]``, (p, 2p)).

    W (N, p), y (N,), bound scalar or (N,), prior a Box; see the module docstring for the proof and the fallback.
    """
    t0 = time.perf_counter()
    W = np.asarray(W, dtype=float)
    y = np.asarray(y, dtype=float)
    b = np.broadcast_to(np.asarray(bound, dtype=float), y.shape)
    lo, hi = np.asarray(prior.lower, float), np.asarray(prior.upper, float)
    h_lo, h_hi = np.asarray(hull.lower, float), np.asarray(hull.upper, float)
    proven = proven_points(W, y, b, lo, hi, hull.info.get("points"))
    rel = HULL_RTOL * np.maximum(np.abs(h_lo), np.abs(h_hi))
    if proven.shape[1]:
        in_lo, in_hi = proven.min(axis=1), proven.max(axis=1)
        tol_lo, tol_hi = np.maximum(in_lo - h_lo, 0.0), np.maximum(h_hi - in_hi, 0.0)
        source = "proven points"
    else:
        in_lo = in_hi = np.full(len(h_lo), np.nan)
        tol_lo = tol_hi = rel
        source = "relative HULL_RTOL"
    return HullReference(h_lo, h_hi, in_lo, in_hi, tol_lo, tol_hi, int(proven.shape[1]), source,
                         time.perf_counter() - t0, proven)


def _info(box: ident.Box) -> dict:
    return {k: v for k, v in box.info.items() if isinstance(v, (int, float, str, bool, list)) and k != "points"}


def judge(outcomes: dict, reference: HullReference | None, truth=None, names=None) -> dict:
    """The result entries of the methods (module docstring), by name.

    outcomes : from :func:`run_methods`; reference : :func:`hull_reference` of the hull (None when the hull did
    not give a box: no width_vs_hull, no check); truth : (p,) true parameters or None (real data).
    """
    truth = None if truth is None else np.asarray(truth, dtype=float)
    out = {}
    for name, o in outcomes.items():
        est = o.estimator
        e = {"kind": est.kind if est else None, "rigorous": est.rigorous if est else None,
             "level": est.level if est else None, "origin": est.origin if est else None,
             "status": o.status, "seconds": o.seconds}
        guaranteed = est is not None and est.kind == "guaranteed"
        if o.status == "ok":
            box = o.box
            e.update(lower=box.lower.tolist(), upper=box.upper.tolist(), width=box.width.tolist())
            if truth is not None:
                enc = box.contains(truth)
                e.update(enclosed=enc.tolist(), all_enclosed=bool(enc.all()))
            else:
                e.update(enclosed=None, all_enclosed=None)
            if reference is not None:
                hw = reference.upper - reference.lower
                with np.errstate(divide="ignore", invalid="ignore"):
                    ratio = np.where(hw > 0, box.width / np.where(hw > 0, hw, 1.0), np.where(box.width > 0, np.inf, 1.0))
                e["width_vs_hull"] = [float(v) if np.isfinite(v) else None for v in ratio]
                if guaranteed:
                    bad = reference.narrower(box.lower, box.upper)
                    nm = list(names or box.names)
                    e["narrower_than_hull"] = [nm[j] for j in np.flatnonzero(bad)]
                    e["unsound"] = bool(bad.any())
                    e["hull_tolerance"] = reference.tolerance()
            e["info"] = _info(box)
        else:
            e["message"] = o.message
            if truth is not None:
                e.update(enclosed=None, all_enclosed=False)
            if guaranteed and o.status == "inconsistent" and reference is not None and reference.proven:
                e["unsound"] = True  # claims "empty" while a point of S is proven
                e["narrower_than_hull"] = list(names or [])
                e["hull_tolerance"] = reference.tolerance()
        if guaranteed and "unsound" not in e:  # no box (failed), or no reference: not judged (null), never "sound"
            e["unsound"] = None if reference is None or o.status == "failed" else False
            e.setdefault("narrower_than_hull", [])
        out[name] = e
    return out


def clopper_pearson(k: int, n: int, alpha: float = 0.05) -> tuple[float, float]:
    """Exact (Clopper-Pearson) two-sided ``1 - alpha`` interval of a binomial proportion ``k / n``:
    ``beta.ppf(alpha/2, k, n-k+1)``, ``beta.ppf(1-alpha/2, k+1, n-k)``, with 0 and 1 at the ends."""
    from scipy.stats import beta

    if n <= 0:
        return (0.0, 1.0)
    lo = 0.0 if k == 0 else float(beta.ppf(alpha / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - alpha / 2, k + 1, n - k))
    return (lo, hi)


def summarise_methods(runs: list[dict]) -> dict:
    """Per method over a campaign's runs (each a result with ``methods`` entries of :func:`judge`): the claims,
    ``runs``, ``misses`` (runs whose box does not enclose the truth), ``failed_runs`` (seeds of runs without a box:
    failed or proven empty), ``unsound_runs``, ``flagged_runs`` (runs with a miss or an unsound verdict),
    ``coverage`` (runs whose box encloses the truth / runs: a run
    without a box does not cover) with
    ``coverage_ci`` (Clopper-Pearson 95 %), ``width_vs_hull_median`` per parameter, median ``seconds``, and the
    earlier keys (``miss_seeds``, ``relative_width_median`` ...)."""
    first = runs[0]
    p = len(first["true"])
    names = list(dict.fromkeys(n for r in runs for n in r["methods"]))
    methods = {}
    for name in names:
        entries = [(r, r["methods"][name]) for r in runs if name in r["methods"]]
        ok = [(r, m) for r, m in entries if m.get("status") == "ok"]
        claims = next((m for _, m in entries if m.get("kind") is not None), entries[0][1])
        enclosed = np.array([m["enclosed"] for _, m in ok]) if ok else np.zeros((0, p), bool)
        misses = [r["seed"] for r, m in ok if not m["all_enclosed"]]
        covered = [r["seed"] for r, m in ok if not m["all_enclosed"] and r["bound_covers_residual"]]
        rel_w = np.array([np.asarray(m["width"]) / np.abs(np.asarray(r["true"])) for r, m in ok])
        wvh = np.array([[np.nan if v is None else v for v in m["width_vs_hull"]] for _, m in ok
                        if m.get("width_vs_hull")], dtype=float)
        n = len(entries)
        k = len(ok) - len(misses)
        unsound = [r["seed"] for r, m in entries if m.get("unsound")]
        failed = [r["seed"] for r, m in entries if m.get("status") != "ok"]
        messages = sorted({m.get("message", "") for _, m in entries if m.get("status") == "failed"})
        with np.errstate(all="ignore"):
            wvh_med = np.nanmedian(wvh, axis=0).tolist() if len(wvh) else []
        methods[name] = {
            "kind": claims.get("kind"), "rigorous": claims.get("rigorous"), "level": claims.get("level"),
            "origin": claims.get("origin"), "status": "ok" if ok else "failed",
            "lower": ok[0][1]["lower"] if ok else None, "upper": ok[0][1]["upper"] if ok else None,
            "enclosed": enclosed.all(axis=0).tolist() if len(ok) else [],
            "all_enclosed": bool(len(ok) == n and enclosed.all()),
            "runs": n, "misses": len(misses), "miss_seeds": misses,
            "misses_with_bound_covering_residual": covered, "failed_runs": failed,
            "failure_messages": messages[:5],
            "unsound_runs": len(unsound), "unsound_seeds": unsound,
            "flagged_runs": len({*misses, *unsound}),
            "coverage": k / n if n else None, "coverage_ci": list(clopper_pearson(k, n)),
            "width_vs_hull_median": [None if not np.isfinite(v) else float(v) for v in wvh_med],
            "relative_width_median": np.median(rel_w, axis=0).tolist() if len(ok) else [],
            "relative_width_p90": np.percentile(rel_w, 90, axis=0).tolist() if len(ok) else [],
            "seconds": float(np.median([m["seconds"] for _, m in entries if m.get("seconds") is not None])),
        }
    return methods


def _g(v) -> str:
    return "-" if v is None else f"{v:.3g}"


def judged_table(methods: dict, campaign: bool = False) -> str:
    """The side-by-side table (markdown): one row per method. ``campaign``: coverage [CI], level, unsound runs,
    median width vs hull (median over the parameters of the per-parameter medians), median seconds; else the
    status, enclosed, unsound (narrower_than_hull), width vs hull (median, max over the parameters), seconds."""
    if campaign:
        lines = ["| method | kind | rigorous | coverage [95 % CI] | level | misses | unsound runs | "
                 "median width vs hull | median s |", "|---|---|---|---|---:|---:|---:|---:|---:|"]
        for name, m in methods.items():
            w = [v for v in m.get("width_vs_hull_median") or [] if v is not None]
            ci = m.get("coverage_ci") or [None, None]
            cov = "-" if m.get("coverage") is None else f"{m['coverage']:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]"
            lines.append(f"| {name} | {m.get('kind')} | {m.get('rigorous')} | {cov} | {_g(m.get('level'))} | "
                         f"{m['misses']} | {m.get('unsound_runs', '-')} | {_g(float(np.median(w)) if w else None)} | "
                         f"{_g(m.get('seconds'))} |")
        return "\n".join(lines)
    lines = ["| method | kind | rigorous | status | encloses truth | unsound (narrower than hull) | "
             "width vs hull median / min | seconds |", "|---|---|---|---|---|---|---:|---:|"]
    for name, m in methods.items():
        w = [v for v in m.get("width_vs_hull") or [] if v is not None]
        wtxt = f"{np.median(w):.3g} / {min(w):.3g}" if w else "-"
        uns = "-" if m.get("unsound") is None else (
            f"**yes** {', '.join(m['narrower_than_hull'])}" if m["unsound"] else "no")
        enc = "-" if m.get("all_enclosed") is None or m.get("status") != "ok" else (
            "yes" if m["all_enclosed"] else "**no**")
        lines.append(f"| {name} | {m.get('kind')} | {m.get('rigorous')} | {m['status']} | {enc} | {uns} | {wtxt} | "
                     f"{_g(m.get('seconds'))} |")
    return "\n".join(lines)


def plot_coverage(methods: dict, path) -> None:
    """``coverage.png``: per method its coverage with the Clopper-Pearson interval against the median (over the
    parameters) of its median width vs hull, log x; a statistical method's stated level as a marker."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    colours = plt.get_cmap("tab20").colors
    for i, (name, m) in enumerate(methods.items()):
        w = [v for v in m.get("width_vs_hull_median") or [] if v is not None and v > 0]
        if not w or m.get("coverage") is None:
            continue
        x = float(np.median(w))
        lo, hi = m["coverage_ci"]
        c = m["coverage"]
        ax.errorbar([x], [c], yerr=[[c - lo], [hi - c]], fmt="o" if m.get("kind") == "guaranteed" else "s",
                    capsize=4, color=colours[(2 * i) % 20 if i < 10 else (2 * i + 1) % 20],
                    label=f"{name} ({m.get('kind')})")
        if m.get("level") is not None:
            ax.plot([x], [m["level"]], "k_", markersize=14)
    ax.set_xscale("log")
    ax.set_xlabel("median width / exact hull width (median over parameters)")
    ax.set_ylabel("coverage (runs enclosing the truth), 95 % CI")
    ax.set_ylim(-0.05, 1.05)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("coverage against width (black bar: a statistical method's stated level)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
