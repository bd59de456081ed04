"""``check_estimator``: a conformance check for estimator authors, like scikit-learn's ``check_estimator``.

:func:`check_estimator` resolves an estimator (a registry name, ``"package.module:attribute"``, an entry point or the
callable, :func:`ident.estimators.registry.get`), runs it through the one call path
(:func:`~ident.estimators.registry.call`) on the generated problems of :func:`problems` and reports per check:

- ``claims``: its stated claims fit (kind ``guaranteed`` or ``statistical``, a statistical level in (0, 1), a
  declared context its signature takes); read once, before any problem.
- ``box``: it returns a Box of the prior's shape, finite, with ``lower <= upper`` (a ``(lower, upper)`` pair is
  made a Box by the registry), or raises :class:`~ident.InconsistentDataError`. Any other exception fails, except a
  ``ValueError`` (reported as "refused") on the problem with fewer rows than parameters, which any estimator may
  refuse (the guaranteed built-ins all accept it), and from a statistical estimator on any problem (its
  assumptions may need more rows, e.g. per-group degrees of freedom). A guaranteed estimator's problem always has
  an answer: it may not refuse one with N >= p.
- ``outer`` (guaranteed estimators; a statistical box claims a confidence level, not an enclosure, and is judged on
  its claims only): the exact hull's LP solutions (``ident.estimate(..., method="hull")``) are proven in the
  feasible set with outward rounding (:func:`ident.estimators.proof.proven_points`); the box must contain every
  proven point. A box that excludes one is not an outer enclosure, and the point is the **proof**: the check
  fails naming the parameter, the box's interval and the point. An estimator that says "proven empty" while a
  point is proven fails the same way. This is the narrower-than-hull check of the scenarios, with the hull's
  tolerance taken from the proven points. Where no point can be proven (the problem is empty), the check passes
  with the note "nothing proven".
- ``empty`` (the problem whose set is proven empty by the hull): raising InconsistentDataError or returning any box
  is accepted (a box is an outer enclosure of the empty set); anything else fails.
- ``inputs``: the arrays it was given (W, y, bound, the context arrays) are unchanged afterwards.
- ``time``: its seconds on each problem beside the exact hull's (reported, never judged).

The problems (:func:`problems`, seeded): ``random`` (Gaussian W, per-row bounds), ``h4-like`` (the H4's column
structure: 4 joints, per-joint inertia, viscous and Coulomb columns, two dense coupled columns with gravity, column
scales over four decades; generated, no simulator), ``tiny`` (the bound 1 + 1e-6 times the smallest consistent one:
a set about 1e-6 of the data's scale), ``wide`` (few rows, a large bound: the set reaches the prior's faces),
``bad-scaling`` (every other row in units 1e8 times larger: the same set), ``fewer-rows`` (N = 2 < p = 5) and
``empty`` (duplicated rows whose measurements differ by three bounds).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from h4bench.ident.box import Box
from h4bench.ident.errors import EstimatorError, InconsistentDataError
from h4bench.ident.estimators import isolation, registry
from h4bench.ident.estimators.door import InputsChanged
from h4bench.ident.estimators.estimate import estimate, min_consistent_bound
from h4bench.ident.estimators.proof import excluded_point, proven_points

__all__ = ["CheckResult", "ConformanceReport", "Problem", "check_estimator", "problems"]

PASS, FAIL, SKIP = "pass", "fail", "skip"


@dataclass(frozen=True)
class Problem:
    """A generated bounded-error problem: W (N, p), y (N,), bound (N,) > 0, prior a Box, the context (``groups``
    (N,) ints, ``instruments`` (N, p), ``regressor_radius`` (N, p) zeros: the point regressor as an interval one, so
    that an interval-regressor estimator's feasible set is the same set), and whether its feasible set is empty by
    construction."""

    name: str
    description: str
    W: np.ndarray
    y: np.ndarray
    bound: np.ndarray
    prior: Box
    context: dict = field(default_factory=dict)
    empty: bool = False


@dataclass(frozen=True)
class CheckResult:
    """One check on one problem: ``status`` ``"pass"``, ``"fail"`` or ``"skip"``, a one-line ``detail`` and, for
    a failed ``outer`` check, the ``proof`` (``parameter``, ``point`` (p,), ``box`` [lower, upper] of that
    parameter)."""

    check: str
    problem: str
    status: str
    detail: str = ""
    proof: dict | None = None
    seconds: float | None = None

    def to_dict(self) -> dict:
        return {"check": self.check, "problem": self.problem, "status": self.status, "detail": self.detail,
                "proof": self.proof, "seconds": self.seconds}


@dataclass
class ConformanceReport:
    """What :func:`check_estimator` found: the estimator's name, origin and claims, and the results per check."""

    name: str
    origin: str
    claims: dict
    results: list[CheckResult]

    @property
    def passed(self) -> bool:
        """True when no check failed."""
        return not self.failures

    @property
    def failures(self) -> list[CheckResult]:
        return [r for r in self.results if r.status == FAIL]

    def to_dict(self) -> dict:
        return {"name": self.name, "origin": self.origin, "claims": self.claims, "passed": self.passed,
                "results": [r.to_dict() for r in self.results]}

    def table(self) -> str:
        """A plain-text table: one line per problem and check, then the failures with their proofs."""
        lines = [f"estimator {self.name} ({self.origin}): " + ", ".join(f"{k}={v}" for k, v in self.claims.items()
                                                                        if k in ("kind", "rigorous", "level")),
                 f"{'problem':12s} {'check':7s} {'status':6s} detail"]
        for r in self.results:
            lines.append(f"{r.problem:12s} {r.check:7s} {r.status.upper():6s} {r.detail}")
        for r in self.failures:
            lines.append(f"FAILED {r.check} on {r.problem}: {r.detail}")
            if r.proof:
                lines.append(f"  proof point (proven feasible, outward rounding): {r.proof['point']}")
        lines.append("PASSED" if self.passed else f"FAILED: {len(self.failures)} check(s)")
        return "\n".join(lines)


# --------------------------------------------------------------------------------------------------- problems
def _problem(name, description, W, y, bound, prior, groups=None, empty=False) -> Problem:
    W = np.ascontiguousarray(W, dtype=float)
    groups = np.arange(W.shape[0], dtype=np.int64) % 4 if groups is None else np.asarray(groups, dtype=np.int64)
    context = {"groups": groups, "instruments": W.copy(), "regressor_radius": np.zeros_like(W)}
    return Problem(name, description, W, np.asarray(y, dtype=float), np.broadcast_to(
        np.asarray(bound, dtype=float), (W.shape[0],)).copy(), prior, context, empty)


def _random(rng, n: int, p: int, noise: float = 0.1):
    W = rng.standard_normal((n, p))
    theta = rng.uniform(1.0, 10.0, p) * rng.choice((-1.0, 1.0), p)
    b = rng.uniform(0.5, 1.0, n) * noise
    y = W @ theta + rng.uniform(-1.0, 1.0, n) * b
    return W, y, b, Box(theta - 1.0, theta + 1.0), theta


def _h4_like(rng, samples: int = 40):
    """The H4 model's column structure (rows sample k, joint i -> 4 k + i), generated from smooth joint motions."""
    t = np.linspace(0.0, 2.0, samples)[:, None]
    w = rng.uniform(2.0, 6.0, 4)
    a = rng.uniform(0.3, 0.8, 4)
    phase = rng.uniform(0.0, 2 * np.pi, 4)
    q = a * np.sin(w * t + phase)
    qd = a * w * np.cos(w * t + phase)
    qdd = -a * w**2 * np.sin(w * t + phase)
    eye = np.eye(4)
    nacelle = 0.1 * (qdd.sum(axis=1, keepdims=True) * 0.05 + 9.81)  # vertical motion with gravity
    turn = 0.05 * (qdd * np.array([1.0, -1.0, 1.0, -1.0])).sum(axis=1, keepdims=True)
    blocks = [qdd[:, :, None] * eye,                                   # Imot_i: qdd_i on row i
              (0.2 * np.cos(q) * nacelle)[:, :, None],                # Mnac: every row
              (np.sin(q + np.arange(4)) * turn)[:, :, None],          # Ibc: every row
              qd[:, :, None] * eye,                                    # Fv_i: qd_i on row i
              np.sign(qd)[:, :, None] * eye]                           # Fs_i: sign(qd_i) on row i
    W = np.concatenate(blocks, axis=2).reshape(4 * samples, 14)
    theta = np.r_[np.full(4, 0.012), 1.0, 0.003, np.full(4, 0.1), np.full(4, 1.0)] * rng.uniform(0.7, 1.3, 14)
    b = np.full(4 * samples, 0.05)
    y = W @ theta + rng.uniform(-1.0, 1.0, W.shape[0]) * b
    half = np.maximum(0.5 * np.abs(theta), 1e-3)
    return W, y, b, Box(theta - half, theta + half), np.tile(np.arange(4), samples)


def problems(seed: int = 0) -> list[Problem]:
    """The generated problems of the check (module docstring), reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    out = []
    W, y, b, prior, _ = _random(rng, 80, 4)
    out.append(_problem("random", "Gaussian W (80, 4), per-row bounds, the truth inside", W, y, b, prior))
    W, y, b, prior, joint = _h4_like(rng)
    out.append(_problem("h4-like", "the H4's 14-column structure on 4 joints x 40 samples", W, y, b, prior, joint))
    W, y, _, prior, _ = _random(rng, 60, 3)
    t = min_consistent_bound(W, y, prior)
    out.append(_problem("tiny", "bound (1 + 1e-6) x the smallest consistent one: a tiny set", W, y,
                        t * (1.0 + 1e-6), prior))
    W, y, _, prior, _ = _random(rng, 6, 4)
    out.append(_problem("wide", "6 rows, a bound of 1.5: the set reaches the prior's faces", W, y, 1.5, prior))
    W, y, b, prior, _ = _random(rng, 60, 3)
    scale = np.where(np.arange(60) % 2, 1e8, 1.0)
    out.append(_problem("bad-scaling", "every other row in units 1e8 times larger (the same set)", W * scale[:, None],
                        y * scale, b * scale, prior))
    W, y, b, prior, _ = _random(rng, 2, 5)
    out.append(_problem("fewer-rows", "N = 2 rows for p = 5 parameters", W, y, b, prior))
    W, y, b, prior, _ = _random(rng, 30, 3)
    out.append(_problem("empty", "duplicated rows whose measurements differ by three bounds: proven empty",
                        np.vstack([W, W]), np.r_[y, y + 3.0 * b], np.r_[b, b], prior, empty=True))
    return out


# ----------------------------------------------------------------------------------------------------- checks
def _copies(problem: Problem) -> list[tuple[str, np.ndarray, np.ndarray]]:
    arrays = {"W": problem.W, "y": problem.y, "bound": problem.bound, "prior.lower": problem.prior.lower,
              "prior.upper": problem.prior.upper, **{f"context {k}": v for k, v in problem.context.items()}}
    return [(k, v, np.array(v, copy=True)) for k, v in arrays.items()]


def _reference(problem: Problem) -> tuple[np.ndarray, float, str]:
    """The proven points (p, k) of the problem's feasible set from the exact hull, its seconds, and a note."""
    t0 = time.perf_counter()
    try:
        hull = estimate(problem.W, problem.y, problem.bound, problem.prior, method="hull")
    except InconsistentDataError:
        return np.zeros((len(problem.prior.lower), 0)), time.perf_counter() - t0, "the hull proves it empty"
    seconds = time.perf_counter() - t0
    pts = proven_points(problem.W, problem.y, problem.bound, np.asarray(problem.prior.lower, float),
                        np.asarray(problem.prior.upper, float), hull.info.get("points"))
    return pts, seconds, f"{pts.shape[1]} hull points proven"


def _proof(est, problem: Problem, j: int, x: np.ndarray, lower=None, upper=None) -> tuple[str, dict]:
    name = problem.prior.names[j]
    point = [float(v) for v in x]
    if lower is None:
        return (f"{est.name} says the set is proven empty, but the point {point} is proven in it",
                {"parameter": name, "point": point, "box": None})
    return (f"the box excludes a point proven feasible: {name} = {float(x[j])!r} outside "
            f"[{float(lower[j])!r}, {float(upper[j])!r}]",
            {"parameter": name, "point": point, "box": [float(lower[j]), float(upper[j])]})


def _check_problem(est, problem: Problem) -> list[CheckResult]:
    guaranteed = est.kind == "guaranteed"
    proven, hull_seconds, note = _reference(problem)
    if problem.empty and proven.shape[1]:
        raise RuntimeError(f"problem {problem.name!r}: the generated empty set has proven points")  # a bug of ours
    before = _copies(problem)
    t0 = time.perf_counter()
    box, error = None, None
    try:
        box = registry.call(est, problem.W, problem.y, problem.bound, problem.prior, **problem.context)
    except Exception as exc:  # noqa: BLE001 - every outcome is reported
        error = exc
    seconds = time.perf_counter() - t0
    out = []
    n, p = problem.W.shape
    name = problem.name
    # box
    if isinstance(error, InconsistentDataError):
        out.append(CheckResult("box", name, PASS, "raises InconsistentDataError (proven empty)", seconds=seconds))
    elif isinstance(error, EstimatorError) or (error is not None and not (
            isinstance(error, ValueError) and (n < p or not guaranteed))):
        out.append(CheckResult("box", name, FAIL, f"{type(error).__name__}: {error}", seconds=seconds))
    elif error is not None:
        why = "N < p" if n < p else "the problem (a statistical estimator's assumptions)"
        out.append(CheckResult("box", name, PASS, f"refused {why}: {type(error).__name__}: {error}",
                               seconds=seconds))
    else:
        out.append(CheckResult("box", name, PASS, f"a Box of {p} parameters", seconds=seconds))
    # outer
    if problem.empty:
        ok = box is not None or isinstance(error, InconsistentDataError)
        out.append(CheckResult("empty", name, PASS if ok else FAIL,
                               "raises InconsistentDataError" if isinstance(error, InconsistentDataError) else
                               "returns a box (an outer box of the empty set)" if box is not None else
                               f"{type(error).__name__}: {error}"))
    elif not guaranteed:
        out.append(CheckResult("outer", name, SKIP, f"{est.kind} (level {est.level}): judged on its claims only"))
    elif box is not None or isinstance(error, InconsistentDataError):
        hit = excluded_point(box.lower, box.upper, proven) if box is not None else \
            ((0, proven[:, 0]) if proven.shape[1] else None)
        if hit is None:
            out.append(CheckResult("outer", name, PASS, f"contains every proven point ({note})" if proven.shape[1]
                                   else f"nothing proven ({note})"))
        else:
            detail, proof = _proof(est, problem, *hit, *((box.lower, box.upper) if box is not None else ()))
            out.append(CheckResult("outer", name, FAIL, detail, proof))
    # inputs
    changed = [k for k, arr, copy in before if not np.array_equal(arr, copy)]
    if isinstance(error, InputsChanged):  # a plugin changed them in its child process (ours are untouched)
        changed += [f"{k} (in its process)" for k in error.inputs]
    out.append(CheckResult("inputs", name, FAIL if changed else PASS,
                           f"changed {changed}" if changed else "unchanged"))
    out.append(CheckResult("time", name, PASS, f"{seconds:.3g} s (the exact hull: {hull_seconds:.3g} s)",
                           seconds=seconds))
    return out


def check_estimator(method, *, seed: int = 0, timeout: float | None = None) -> ConformanceReport:
    """Run the conformance checks (module docstring) on ``method``.

    Parameters
    ----------
    method : a registry name, an entry-point name, ``"package.module:attribute"`` or a callable
        ``f(W, y, bound, prior, **context) -> ident.Box``.
    seed : the seed of the generated problems.
    timeout : seconds per problem (None: no limit); with a limit the estimator runs in a child process (a plugin
        named by a string always does: :mod:`ident.estimators.door`), killed past it (that problem's ``box``
        check fails: timeout).

    Returns
    -------
    ConformanceReport
        ``passed``, ``failures``, ``results`` (one :class:`CheckResult` per check and problem), ``table()``.
        An estimator that cannot be resolved, or whose claims do not fit, gives a report with one failed
        ``claims`` check.
    """
    try:
        est = registry.get(method)
    except (EstimatorError, TypeError) as exc:
        name = method if isinstance(method, str) else getattr(method, "__name__", repr(method))
        return ConformanceReport(str(name), "?", {}, [CheckResult("claims", "-", FAIL, str(exc))])
    if timeout is not None:
        est = isolation.contained(est, timeout)
    claims = {"kind": est.kind, "rigorous": est.rigorous, "level": est.level, "context": list(est.context),
              "description": est.description, "citation": est.citation}
    results = [CheckResult("claims", "-", PASS, f"{est.kind}" + (f", level {est.level:g}" if est.level else "")
                           + f", rigorous={est.rigorous}, context {list(est.context)}")]
    for problem in problems(seed):
        results.extend(_check_problem(est, problem))
    return ConformanceReport(est.name, est.origin, claims, results)
