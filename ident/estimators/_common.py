"""Shared argument checks of the reference estimators (the estimator protocol's inputs).

Every reference estimator takes ``W`` (N, p), ``y`` (N,), ``bound`` (N,) or a scalar (the error model
``|y - W theta| <= bound`` row by row, in y's units) and ``prior`` (an :class:`ident.Box` or a ``(lower, upper)``
pair with finite bounds), checked by :func:`~ident.estimators.checks.check_problem` (``check_inputs``).
"""

from __future__ import annotations

import numpy as np

from h4bench.ident.estimators.checks import check_problem
from h4bench.ident.numerics import interval as ia  # noqa: F401  (re-exported for the contractor)


check_inputs = check_problem  # the one validator of the protocol's inputs (ident.estimators.checks)


def check_groups(groups, N: int) -> np.ndarray:
    """``groups`` as an (N,) int array (one group when None)."""
    if groups is None:
        return np.zeros(N, dtype=int)
    g = np.asarray(groups)
    if g.shape != (N,) or g.dtype.kind not in "iu":
        raise ValueError(f"groups must be an (N,) = ({N},) integer array, got shape {g.shape} dtype {g.dtype}")
    return g.astype(int)


def clip_to_prior(lower, upper, lo, hi):
    """Intersect a box with the prior; an empty intersection is returned as ``None``."""
    lower = np.maximum(np.asarray(lower, dtype=float), lo)
    upper = np.minimum(np.asarray(upper, dtype=float), hi)
    if np.any(lower > upper):
        return None
    return lower, upper


def set_box(method: str, c, rad, lo, hi, names, W, y, b, prior, set_info: dict, **info):
    """The final box of a set estimator: the set's hull ``c +- rad`` intersected with the prior, its set in
    ``info["set"]``; an empty intersection (only through rounding: the set meets the prior by construction) is an
    inconsistency naming ``method``."""
    from h4bench.ident import Box

    clipped = clip_to_prior(c - rad, c + rad, lo, hi)
    if clipped is None:
        raise inconsistent(f"the {method} does not meet the prior", W, y, b, prior)
    return Box(clipped[0], clipped[1], names, info={"method": method, **info, "set": set_info})


def inconsistent(message: str, W, y, b, prior):
    """An ``ident.InconsistentDataError`` for data proven (or found) inconsistent with the prior.

    ``min_bound`` is ``ident.min_consistent_bound`` of the data (zero rows appended when N < p, which does not
    change it); ``scale_lower`` is 1 (the emptiness is the only proof, not its size).
    """
    from h4bench.ident import InconsistentDataError, min_consistent_bound

    N, p = W.shape
    if N < p:
        W = np.vstack([W, np.zeros((p - N, p))])
        y = np.concatenate([y, np.zeros(p - N)])
    mb = float(min_consistent_bound(W, y, prior))
    return InconsistentDataError(f"{message}; the smallest consistent scalar bound is about {mb:.6g}",
                                 min_bound=mb, bound=float(np.max(b)), scale_lower=1.0)



#: Relative slack of :class:`RowScan`'s tests: far above the a-priori error of a p-term product computed in
#: another order (``2 (p + 2) u``, about 4e-15 for p = 14) and of the few roundings after it.
SKIP_SLACK = 1e-10


class RowScan:
    """The rows ``0 .. N-1`` a sequential set estimator must visit, in order, leaving out rows a batched test
    proves it would skip (rows that leave its set unchanged).

    ``provably_skipped(k, end)`` -> (end - k,) bool, from the estimator's current set: True only where the row's
    exact step, as the estimator computes it row by row, is certain to leave the set unchanged (the batched
    products differ from the row-by-row ones in the last bits only, so the tests keep a margin of
    :data:`SKIP_SLACK` times the magnitudes involved). After a visited row that changed the set the caller sets
    ``scan.changed = True``: the following rows are then tested against the new set. Every row left out is one
    the estimator would skip and a skipped row changes nothing, so the result is the row-by-row one bit for bit.
    Blocks start at ``first`` rows and double, up to ``largest``, while no row changes the set.
    """

    def __init__(self, N: int, provably_skipped, first: int = 32, largest: int = 4096):
        self.N, self.test, self.first, self.largest = int(N), provably_skipped, int(first), int(largest)
        self.changed = False

    def __iter__(self):
        k, size = 0, self.first
        while k < self.N:
            end = min(self.N, k + size)
            restart = None
            for row in np.flatnonzero(~self.test(k, end)) + k:
                self.changed = False
                yield int(row)
                if self.changed:
                    restart = int(row) + 1
                    break
            if restart is None:
                k, size = end, min(2 * size, self.largest)
            else:
                k, size = restart, self.first
