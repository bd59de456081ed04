"""Zonotope outer bound of the feasible set by sequential strip intersection, with order reduction.

Alamo, Bravo & Camacho, "Guaranteed state estimation by zonotopes", Automatica 41(6):1035-1043, 2005;
Bravo, Alamo & Camacho, "Bounded error identification of systems with time-varying parameters",
IEEE TAC 51(7):1144-1150, 2006. A zonotope ``Z = <c, G> = {c + G xi : |xi|_inf <= 1}`` (G : (p, m)) and a strip
``S = {theta : |y - w^T theta| <= b}`` give, for every ``lambda`` in R^p,

    Z ∩ S  ⊆  Z(lambda) = < c + lambda (y - w^T c), [(I - lambda w^T) G, b lambda] >

(Alamo et al. 2005, property 2). ``lambda`` minimises the F-radius ``|G(lambda)|_F^2``, in closed form
``lambda = G G^T w / (w^T G G^T w + b^2)`` (Alamo et al. 2005, sec. 4). Before the update the strip is narrowed
to its intersection with the zonotope's own range of ``w^T theta`` (``w^T c +- |G^T w|_1``), which leaves
``Z ∩ S`` unchanged; a row whose strip contains that range does not cut and is skipped, a row whose strip
misses it proves the set empty.

Order reduction (Girard, HSCC 2005; Combastel, IFAC 2003): when the zonotope reaches ``(order + 1) p``
generators (one per cutting row is added), the ``(order - 1) p`` generators with the largest ``|g|_1 - |g|_inf``
are kept and the others replaced by their interval hull (``p`` axis-aligned generators), leaving ``order p``
(default ``order = 3``: 42 for p = 14, at most 56 between reductions). The reduced zonotope contains the
original. Reducing in batches of ``p`` rows matters: reducing after every row (boxing the newest generator
each time) made the F-radius grow geometrically on random data (to 1e6 within 200 rows, p = 14), while
batches of p rows stay bounded.

:func:`parallelotope` is the ``p``-generator special case of Chisci, Garulli & Zappa, "Recursive state
bounding by parallelotopes", Automatica 32(7):1049-1055, 1996: with the strip narrowed as above, each
candidate ``lambda = g_j / (w^T g_j)`` of the same family removes generator ``j``'s component along ``w``
and replaces ``g_j`` by ``b g_j / (w^T g_j)``; this is the parallelotope bounded by the strip and the other
``p - 1`` face pairs, of volume ``|det G| b / |w^T g_j|``. The minimum-volume candidate (``j`` maximising
``|w^T g_j|``) is taken when it is smaller than the current parallelotope, otherwise the row is skipped.
No order reduction is needed (p generators throughout).

Measured on random data (W Gaussian, N = 20 000, p = 14, bound 0.1, prior truth +- 1): the median width
over the exact hull's is about 2100 for the F-radius zonotope (order 3, 0.5 s) and about 710 for the
parallelotope (0.1 s); both are shipped as references. Neither is rigorous in floating point (the updates
are rounded to nearest): ``rigorous = False``. The box is the interval hull ``c +- |G| 1`` intersected with
the prior. As a cheap safeguard each strip is widened by ``8 (p + 2) u`` times the magnitudes involved
(``|y_k| + b_k + |w_k| |c| + |G^T w_k|_1``, ``u = 2^-53``): without it the parallelotope reported 186 of 200
consistent critical-bound cases (``b_k = |y_k - w_k theta_true|`` rounded up, p = 2..4, N = 40) as inconsistent
and lost the truth in 4 others.
"""

from __future__ import annotations

import numpy as np

from h4bench.portable import largest
from h4bench.ident import Box
from h4bench.ident.estimators.registry import declare
from h4bench.ident.estimators._common import SKIP_SLACK, RowScan, check_inputs, inconsistent, set_box

__all__ = ["parallelotope", "zonotope", "zonotope_at"]


def _pad(p: int) -> float:
    """Relative widening of each strip, ``8 (p + 2) u``: a safeguard against rounding, not a proof."""
    return 8.0 * (p + 2) * 2.0**-53


def _reduce(G: np.ndarray, keep: int) -> np.ndarray:
    """Girard's reduction: keep the ``keep`` largest generators by ``|g|_1 - |g|_inf``, box the rest."""
    A = np.abs(G)
    score = A.sum(axis=0) - A.max(axis=0)
    idx = largest(score, keep)
    rest = np.ones(G.shape[1], dtype=bool)
    rest[idx] = False
    return np.concatenate([G[:, idx], np.diag(A[:, rest].sum(axis=1))], axis=1)


def _cut(w, c, G, yk, bk, rel):
    """One strip against the set ``c + G xi``: ``G^T w`` (m,), ``w . c``, the set's half-range along w and the
    strip's part ``[slo, shi]`` inside that range, the strip widened by a rounding safeguard (not a proof)."""
    Gw = G.T @ w
    wc = float(w @ c)
    r = float(np.abs(Gw).sum())
    pad = rel * (abs(yk) + bk + float(np.abs(w) @ np.abs(c)) + r)
    return Gw, wc, r, max(yk - bk - pad, wc - r), min(yk + bk + pad, wc + r)


def _parallelotope_skips(Wb, yb, bb, c, G, rel) -> np.ndarray:
    """(B,) bool: rows of the block ``Wb`` that :func:`parallelotope`'s row step certainly skips against the set
    ``c + G xi`` (``bk >= max_j |w^T g_j|``, the strip meeting the set), from block products (one matrix product
    instead of B): each test holds with a margin of :data:`SKIP_SLACK` times the magnitudes, far above the
    difference between the block's rounding and the row step's (:class:`RowScan`)."""
    GW = Wb @ G  # (B, p): G^T w per row
    wc = Wb @ c
    r = np.abs(GW).sum(axis=1)
    aW = np.abs(Wb)
    scale = np.abs(yb) + bb + aW @ np.abs(c) + (aW @ np.abs(G)).sum(axis=1)
    pad = rel * (np.abs(yb) + bb + aW @ np.abs(c) + r)
    slo = np.maximum(yb - bb - pad, wc - r)
    shi = np.minimum(yb + bb + pad, wc + r)
    margin = SKIP_SLACK * scale
    return (shi - slo >= margin) & (0.5 * (shi - slo) - np.abs(GW).max(axis=1) >= margin)


def _start(lo, hi, p):
    """The prior box as a zonotope (centre, p generators) and the strips' rounding safeguard."""
    return 0.5 * (lo + hi), np.diag(0.5 * (hi - lo)), _pad(p), 0


def _zonotope_box(method, c, G, lo, hi, names, W, y, b, prior, **info):
    return set_box(method, c, np.abs(G).sum(axis=1), lo, hi, names, W, y, b, prior,
                   {"type": "zonotope", "center": c.tolist(), "generators": G.tolist()}, **info)


def _misses(what: str, k: int, W, y, b, prior):
    return inconsistent(f"the {what} misses the strip of row {k}: the data appear inconsistent with the prior and "
                        "the bound", W, y, b, prior)


def _zonotope(W, y, bound, prior, order: int) -> Box:
    W, y, b, lo, hi, names = check_inputs(W, y, bound, prior)
    N, p = W.shape
    if int(order) != order or order < 1:
        raise ValueError(f"order must be an integer >= 1, got {order!r}")
    order = int(order)
    c, G, rel, cuts = _start(lo, hi, p)
    cap, keep = (order + 1) * p - 1, (order - 1) * p
    for k in range(N):
        w = W[k]
        Gw, wc, r, slo, shi = _cut(w, c, G, y[k], b[k], rel)
        if slo > shi:
            raise _misses("zonotope", k, W, y, b, prior)
        if slo <= wc - r and shi >= wc + r:
            continue  # the strip contains the zonotope's range: no cut
        yk = 0.5 * (slo + shi)
        bk = 0.5 * (shi - slo)
        GGw = G @ Gw  # G G^T w
        den = float(w @ GGw) + bk * bk
        if not den > 0.0:
            continue
        lam = GGw / den
        c = c + lam * (yk - wc)
        G = np.concatenate([G - np.outer(lam, Gw), (bk * lam)[:, None]], axis=1)
        cuts += 1
        if G.shape[1] > cap:
            G = _reduce(G, keep)
    return _zonotope_box('zonotope', c, G, lo, hi, names, W, y, b, prior, order=order, cuts=cuts)


def zonotope_at(order: int):
    """The :func:`zonotope` estimator with at most ``order * p`` generators (order >= 1)."""
    if int(order) != order or order < 1:
        raise ValueError(f"order must be an integer >= 1, got {order!r}")

    def estimator(W, y, bound, prior) -> Box:
        return _zonotope(W, y, bound, prior, int(order))

    estimator.__name__ = f"zonotope_order{int(order)}"
    estimator.__doc__ = zonotope.__doc__
    return declare(kind=zonotope.kind, rigorous=zonotope.rigorous, context=(), citation=zonotope.citation,
                   description=zonotope.description.replace("to 3 p", f"to {int(order)} p"))(estimator)


@declare(kind="guaranteed", rigorous=False, context=(),
         description="zonotope by sequential strip intersection (F-radius), order reduction to 3 p generators "
                     "(not rigorous in fp)",
         citation="T. Alamo, J. M. Bravo, E. F. Camacho, Guaranteed state estimation by zonotopes, Automatica "
                  "41(6):1035-1043, 2005; J. M. Bravo, T. Alamo, E. F. Camacho, IEEE TAC 51(7):1144-1150, 2006")
def zonotope(W, y, bound, prior, *, order: int = 3) -> Box:
    """Zonotope outer bound by sequential strip intersection (Alamo, Bravo & Camacho 2005).

    Parameters
    ----------
    W : (N, p) regressor; y : (N,) observations; bound : (N,) or scalar > 0, the error bound of each row
        in y's units; prior : ident.Box with finite bounds (the first zonotope).
    order : at most ``order * p`` generators are kept (Girard's reduction), default 3.

    Returns
    -------
    ident.Box
        The zonotope's interval hull intersected with the prior; ``info["set"]`` the zonotope
        (``{"type": "zonotope", "center": (p,), "generators": (p, m)}``).

    Raises
    ------
    ident.InconsistentDataError
        when a strip misses the zonotope (the feasible set is then empty, up to rounding).
    """
    return _zonotope(W, y, bound, prior, order)




@declare(kind="guaranteed", rigorous=False, context=(),
         description="minimum-volume parallelotope by sequential strip intersection (not rigorous in fp)",
         citation="L. Chisci, A. Garulli, G. Zappa, Recursive state bounding by parallelotopes, Automatica "
                  "32(7):1049-1055, 1996")
def parallelotope(W, y, bound, prior) -> Box:
    """Minimum-volume parallelotope by sequential strip intersection (Chisci, Garulli & Zappa 1996).

    Parameters
    ----------
    W : (N, p) regressor; y : (N,) observations; bound : (N,) or scalar > 0, the error bound of each row
        in y's units; prior : ident.Box with finite bounds (the first parallelotope).

    Returns
    -------
    ident.Box
        The parallelotope's interval hull intersected with the prior; ``info["set"]`` the parallelotope as a
        zonotope with p generators (``{"type": "zonotope", "center": (p,), "generators": (p, p)}``).

    Raises
    ------
    ident.InconsistentDataError
        when a strip misses the parallelotope (the feasible set is then empty, up to rounding).
    """
    W, y, b, lo, hi, names = check_inputs(W, y, bound, prior)
    N, p = W.shape
    c, G, rel, cuts = _start(lo, hi, p)
    state = {"c": c, "G": G}
    scan = RowScan(N, lambda k, end: _parallelotope_skips(W[k:end], y[k:end], b[k:end], state["c"], state["G"],
                                                          rel))
    for k in scan:
        w = W[k]
        Gw, wc, r, slo, shi = _cut(w, c, G, y[k], b[k], rel)
        if slo > shi:
            raise _misses("parallelotope", k, W, y, b, prior)
        bk = 0.5 * (shi - slo)
        j = int(np.argmax(np.abs(Gw)))
        if not bk < abs(Gw[j]):
            continue  # no candidate has a smaller volume (includes the rows that do not cut)
        lam = G[:, j] / Gw[j]
        c = c + lam * (0.5 * (slo + shi) - wc)
        G = G - np.outer(lam, Gw)
        G[:, j] = bk * lam
        cuts += 1
        state["c"], state["G"] = c, G
        scan.changed = True
    return _zonotope_box('parallelotope', c, G, lo, hi, names, W, y, b, prior, cuts=cuts)
