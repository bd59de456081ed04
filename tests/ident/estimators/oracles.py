"""Independent oracles for the reference estimators: random bounded-error problems, the exact hull by 2p
linear programs (scipy.optimize.linprog, HiGHS) and random feasible points (LP vertices with random costs,
hit-and-run from the Chebyshev centre)."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
from scipy.optimize import linprog

from h4bench.ident import Box


def problem(rng, p: int, N: int, *, noise: float = 0.1, prior_halfwidth: float = 1.0, per_row: bool = True):
    """A random feasible problem: W (N, p) Gaussian, truth theta (p,), bounds b (N,), errors uniform in
    [-b, b], prior = truth +- halfwidth * U(0.5, 1.5) (shifted by up to half its width, so the truth is
    not the centre)."""
    W = rng.normal(size=(N, p))
    theta = rng.normal(size=p)
    b = noise * (rng.uniform(0.5, 1.5, N) if per_row else np.ones(N))
    y = W @ theta + rng.uniform(-1.0, 1.0, N) * b
    hw = prior_halfwidth * rng.uniform(0.5, 1.5, p)
    shift = rng.uniform(-0.5, 0.5, p) * hw
    prior = Box(theta + shift - hw, theta + shift + hw)
    return W, y, b, prior, theta


def _polytope(W, y, b):
    A = np.vstack([W, -W])
    rhs = np.concatenate([y + b, -(y - b)])
    return A, rhs


def exact_hull(W, y, b, prior):
    """(lower, upper) of the feasible polytope {theta in prior : |y - W theta| <= b}, 2p LPs."""
    A, rhs = _polytope(W, y, b)
    bounds = list(zip(prior.lower, prior.upper))
    p = W.shape[1]
    lo, hi = np.empty(p), np.empty(p)
    for j in range(p):
        e = np.zeros(p)
        e[j] = 1.0
        for sign, out in ((1.0, lo), (-1.0, hi)):
            res = linprog(sign * e, A_ub=A, b_ub=rhs, bounds=bounds, method="highs")
            assert res.status == 0, res.message
            out[j] = res.x[j]
    return lo, hi


def feasible_points(rng, W, y, b, prior, *, vertices: int = 20, walk: int = 200):
    """Points of the feasible polytope: LP vertices for random costs and a hit-and-run walk started at the
    Chebyshev centre (each returned point satisfies the constraints up to the LP tolerance)."""
    A, rhs = _polytope(W, y, b)
    p = W.shape[1]
    A = np.vstack([A, np.eye(p), -np.eye(p)])
    rhs = np.concatenate([rhs, prior.upper, -prior.lower])
    pts = []
    for _ in range(vertices):
        res = linprog(rng.normal(size=p), A_ub=A, b_ub=rhs, bounds=[(None, None)] * p, method="highs")
        assert res.status == 0, res.message
        pts.append(res.x)
    # Chebyshev centre: max r s.t. A x + |A_i| r <= rhs
    norms = np.linalg.norm(A, axis=1)
    res = linprog(np.r_[np.zeros(p), -1.0], A_ub=np.c_[A, norms], b_ub=rhs,
                  bounds=[(None, None)] * p + [(0, None)], method="highs")
    assert res.status == 0 and res.x[-1] > 0, res.message
    x = res.x[:p]
    for _ in range(walk):
        d = rng.normal(size=p)
        d /= np.linalg.norm(d)
        Ad = A @ d
        slack = rhs - A @ x
        with np.errstate(divide="ignore"):
            t = slack / Ad
        tmax = np.min(t[Ad > 0]) if np.any(Ad > 0) else 0.0
        tmin = np.max(t[Ad < 0]) if np.any(Ad < 0) else 0.0
        x = x + rng.uniform(tmin, tmax) * d
        pts.append(x.copy())
    return np.array(pts)


def box_contains(box, lo, hi, rel: float = 1e-9):
    """True when the box contains [lo, hi] up to ``rel`` times the prior-scale of each coordinate."""
    scale = rel * np.maximum(np.abs(lo) + np.abs(hi), 1.0)
    return bool(np.all(box.lower <= lo + scale) and np.all(box.upper >= hi - scale))


def encloses_exact_hull(box, W, y, b, prior) -> bool:
    """Whether ``box`` contains the exact hull of the feasible set (:func:`exact_hull`, 2p scipy LPs)."""
    return box_contains(box, *exact_hull(W, y, b, prior))


def critical_case(rng, p: int, N: int):
    """Bounds equal to the exact residual at the truth, rounded up to the next float: the truth is feasible,
    on the boundary of every strip."""
    W = rng.uniform(-1.0, 1.0, (N, p)) / 3.0
    theta = rng.normal(size=p) / 7.0
    y = W @ theta + rng.normal(size=N) * 1e-3
    b = np.empty(N)
    tq = [Fraction(float(v)) for v in theta]
    for k in range(N):
        r = abs(Fraction(float(y[k])) - sum(Fraction(float(W[k, j])) * tq[j] for j in range(p)))
        f = float(r)
        b[k] = f if Fraction(f) >= r else np.nextafter(f, np.inf)
    return W, y, b, theta
