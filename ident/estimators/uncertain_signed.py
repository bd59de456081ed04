"""The Oettli-Prager hull for a prior of any signs (:func:`signed_uncertain_hull`).

:func:`ident.estimators.uncertain.uncertain_hull` needs ``theta >= 0`` (its polytope form); a robot's base
parameters (first moments, offsets, products of inertia) have both signs. The chord of ``|theta_j|`` over the
prior interval (an upper bound, exact for one-signed intervals) makes the set a polytope containing the exact
Oettli-Prager set, in uncertain_hull's form after a shift and sign changes (docstring below).
"""

from __future__ import annotations

import numpy as np

from h4bench.ident.box import Box
from h4bench.ident.estimators.hull import COUNTERS
from h4bench.ident.estimators.uncertain import uncertain_hull_rows
from h4bench.ident.numerics.interval import down, point_matvec, up
from h4bench.portable import exp, log
from h4bench.portable import matmul as pmatmul

__all__ = ["COARSE_GROUPS", "coarse_step", "signed_uncertain_hull"]

#: each round's hull LPs start from the previous round's working set and bases (False: from their own first rows)
WARM_ROWS = True
#: the first refinement rounds use about this many row groups (kernel windows), at least (:func:`coarse_step`); the
#: per-round widths and seconds on fewer and on all rows: benchmarks/bench_serial_certified.py prints them
COARSE_GROUPS = 256
#: HiGHS options of every round's hull LPs: the dual simplex. Each round starts from the previous round's bases
#: with a new right-hand side and radius (the last box's chords). On the logs of benchmarks/bench_serial_certified.py
#: (hull alone, 2 processes, at 396da6f + the portable base) the dual simplex took 19.0 s against 22.2 s of the
#: primal one (UR5) and 40.5 s against 40.6 s (Panda: 6 of its runs stopped at the iteration limit and were re-run
#: cold, 0 of the primal's); one process at 007d532, 28.7 against 33.2 s and 53.4 against 65.6 s. The same boxes.
#: The point hulls keep the primal simplex, faster there (1.8 s against 3.2 s for the Panda's tuned hull)
SIGNED_SIMPLEX = {"simplex_strategy": 1}
#: per-run budgets of the rounds' LP models: a warm-started run that has not converged in 1000 iterations is cut and
#: run again cold (:class:`~ident.numerics.lp.LPModel`). On the Panda's hull (one process, at b05321f) the cold
#: re-runs took 249-355 iterations, while 6 warm runs stalled at the 20 000-iteration limit (12.9 s) and 10 others
#: took 2 221-15 272 (6.5 s) of the 2 230 optimal runs (median 29 iterations, 99th percentile 982)
SIGNED_BUDGET = {"warm_iteration_limit": 1000}


def coarse_step(n_groups: int) -> int:
    """The thinning of the first rounds for ``n_groups`` row groups: the largest power of two ``<= n_groups /
    COARSE_GROUPS`` (1: no thinning)."""
    step = 1
    while 2 * step * COARSE_GROUPS <= n_groups:
        step *= 2
    return step


def signed_uncertain_hull(Wc, D, y, bound, prior, *, refine: int = 1, rtol: float = 0.0, coarse: int = 1,
                          coarse_rtol: float = 0.1, groups=None, processes: int | None = None, progress=None):
    """Oettli-Prager hull (:func:`ident.estimators.uncertain.uncertain_hull`) for a prior of any signs.

    The exact set ``{theta in Q : |y - Wc theta| <= bound + D |theta|}`` is not convex when a parameter's
    interval contains 0; ``|theta_j|`` is replaced by its chord over ``[lo_j, hi_j]`` (an upper bound, exact
    when the interval has one sign), which makes the set a polytope containing the exact one. Columns with
    ``|hi_j| < |lo_j|`` are negated first so every chord slope ``s_j`` is in [0, 1]; with ``theta = lo + phi``,
    ``phi >= 0``, the system is Oettli-Prager's on ``phi`` with radius ``D diag(s)``, torques ``y - Wc lo``
    (enclosed, its radius added to the bound) and bound ``bound + D |lo|``: uncertain_hull's form. Slopes and
    products are rounded up, so the set can only grow. Up to ``refine`` times, the box found becomes the prior
    (the truth lies in it), which shortens the chords; it stops earlier when the geometric mean of the widths
    shrank by less than ``rtol`` (relative) in the last round. Returns an :class:`ident.Box` with
    ``info['refinements']`` (the rounds done), the last round's hull statistics, and the LP counters
    (``lp_solves``, ``lp_iterations``, ``lp_limit_hits``, ``lp_retries``, ``lp_fallbacks``) summed and
    ``lp_fallback_parameters`` gathered over all rounds (an endpoint that fell back in an earlier round is still
    a valid bound: each round's box encloses the set, and the next round's prior is that box). Each round's hull
    LPs start from the previous round's working set and each LP's basis there (the same stacked rows over a
    smaller box: the optima move little; a start that steers the LPs only).

    coarse > 1: the first rounds use the rows of every ``coarse``-th group only (``groups``: one label per row,
    integers (m,) or rows of integers (m, k), e.g. each row's window ``[first, last]`` sample so that all joints of
    a window stay together, groups in the labels' sorted order; default each row its own group; fewer rows:
    a larger set, so each such round's
    box still encloses the exact one; it is only wider); when a round shrinks the widths' geometric mean by less
    than ``coarse_rtol``, the next rounds use twice as many groups (every ``coarse // 2``-th, ...), and with all
    rows the rounds go on until ``rtol``. The last round allowed by ``refine`` always uses all rows. The early
    rounds, on a wide box, cost the most LP iterations: on fewer rows they cost a fraction of that.
    ``info['coarse_rounds']`` counts the rounds on fewer rows.

    processes : None, every round's 2p LPs on one HiGHS model; 1 or 2, as two halves (the minima and the maxima,
    :mod:`ident.estimators.hull_split`), in two processes with 2: the same box with 1 or 2. progress :
    callable(rounds done, most rounds) after each round, or None.
    """
    if processes is None:
        return _signed_hull(Wc, D, y, bound, prior, refine, rtol, coarse, coarse_rtol, groups, None, progress)
    from h4bench.ident.estimators.hull_split import HullSplit

    with HullSplit(int(processes)) as split:
        return _signed_hull(Wc, D, y, bound, prior, refine, rtol, coarse, coarse_rtol, groups, split, progress)


def _signed_hull(Wc, D, y, bound, prior, refine, rtol, coarse, coarse_rtol, groups, split, progress):
    Wc, D = np.asarray(Wc, dtype=float), np.asarray(D, dtype=float)
    lo, hi = np.asarray(prior.lower, dtype=float), np.asarray(prior.upper, dtype=float)
    names = prior.names
    box, warm = None, None
    m_rows = Wc.shape[0]
    bound_all = np.broadcast_to(np.asarray(bound, dtype=float), (m_rows,))
    y_all, Wc_all, D_all = np.asarray(y, dtype=float), Wc, D
    step, coarse_rounds = max(1, int(coarse)), 0  # rows used: those of every step-th group
    if groups is None:
        group = np.arange(m_rows)
    else:
        g = np.asarray(groups)
        if g.shape[:1] != (m_rows,) or g.ndim > 2:
            raise ValueError(f"groups must hold one label (an integer or a row of integers) per row ({m_rows}), got "
                             f"shape {g.shape}")
        group = np.unique(g, axis=0, return_inverse=True)[1].ravel()
    sel = np.flatnonzero(group % step == 0)
    for it in range(int(refine) + 1):
        if step > 1 and it == int(refine):  # the last round allowed: all rows
            step = 1
        new_sel = np.flatnonzero(group % step == 0) if step > 1 else np.arange(m_rows)
        if new_sel.size > sel.size:  # more rows than the last round: a cold start (the last round's working set
            # and bases, moved to the new rows, made the LPs slower: benchmarks/bench_serial_certified.py prints each
            # round's simplex iterations; on its UR5 log the first rounds on half and on all of the windows took
            # 169 041 + 221 058 with them at 58b3069, 84 482 + 136 010 cold at 6fc8ab8)
            warm = None
        sel = new_sel
        if step > 1:
            Wc, D, y, bound = Wc_all[sel], D_all[sel], y_all[sel], bound_all[sel]
            coarse_rounds += 1
        else:
            Wc, D, y, bound = Wc_all, D_all, y_all, bound_all
        flip = np.abs(hi) < np.abs(lo)
        sg = np.where(flip, -1.0, 1.0)
        W1, lo1, hi1 = Wc * sg, np.where(flip, -hi, lo), np.where(flip, -lo, hi)  # exact: sign changes only
        width = up(hi1 - lo1)
        slope = np.where(width > 0, up((np.abs(hi1) - np.abs(lo1)) / np.where(width > 0, down(hi1 - lo1), 1.0)),
                         0.0)
        slope = np.clip(slope, 0.0, 1.0)
        D1 = up(D * slope)
        plo, phi_ = point_matvec(W1, lo1, lo1)  # enclosure of Wc lo
        y2lo, y2hi = np.nextafter(y - phi_, -np.inf), np.nextafter(y - plo, np.inf)
        y2 = 0.5 * y2lo + 0.5 * y2hi
        extra = up(up(y2hi - y2lo) + up(pmatmul(D, np.abs(lo1))) * (1 + 4 * Wc.shape[1] * 2.0**-53))
        b2 = up(np.asarray(bound, dtype=float) + extra)
        sub, warm = uncertain_hull_rows(W1, D1, y2, b2, Box(np.zeros_like(lo1), width, names=names),
                                        warm=warm if WARM_ROWS else None, split=split, lp_options=SIGNED_SIMPLEX,
                                        lp_budget=SIGNED_BUDGET)
        lo_f = np.nextafter(lo1 + sub.lower, -np.inf)
        hi_f = np.nextafter(lo1 + sub.upper, np.inf)
        new_lo = np.maximum(lo, np.where(flip, -hi_f, lo_f))
        new_hi = np.minimum(hi, np.where(flip, -lo_f, hi_f))
        info = {**sub.info, "refinements": it, "coarse_rounds": coarse_rounds}
        if box is not None:  # the LP work and the fallbacks of every round are counted
            for key in COUNTERS:
                info[key] += box.info[key]
            info["lp_fallback_parameters"] = sorted(set(info["lp_fallback_parameters"])
                                                    | set(box.info["lp_fallback_parameters"]))
        box = Box(new_lo, new_hi, names=names, info=info)
        w_old, w_new = hi - lo, new_hi - new_lo
        pos = (w_old > 0) & (w_new > 0)
        shrink = 1.0 - float(exp(np.mean(log(w_new[pos] / w_old[pos])))) if np.any(pos) else 0.0
        lo, hi = new_lo, new_hi
        if progress is not None:
            progress(it + 1, int(refine) + 1)
        if step > 1:
            if shrink < coarse_rtol:  # twice the groups from the next round
                step //= 2
            continue
        if it > 0 and shrink < rtol:
            break
    return box
