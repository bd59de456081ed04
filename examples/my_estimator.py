"""A plain user estimator for the workbench: the exact hull of the first half of the rows.

Dropping rows can only enlarge the feasible set, so the hull of ``{theta in prior : |y_k - W_k theta| <= b_k,
k < N/2}`` is an outer enclosure of the full set: a sound ``kind = "guaranteed"`` box, wider than the full hull
(``width_vs_hull >= 1``). Its rounding is the hull's (outward), so ``rigorous = True``. It shows the protocol:
a callable ``f(W, y, bound, prior, **context) -> ident.Box``; ``groups`` (the joint of each row) is accepted and
used only to report how many rows of each joint it kept.

Use it as ``examples.my_estimator:first_half_hull`` (from the repository's root), e.g.
``h4bench run paper --quick --methods hull,examples.my_estimator:first_half_hull``; run this file for a demo.
"""

from __future__ import annotations

import numpy as np

from h4bench import ident


def first_half_hull(W, y, bound, prior, groups=None):
    """The exact hull on rows ``0 .. N//2 - 1`` (at least one row).

    W (N, p), y (N,), bound (N,) > 0 in y's units, prior an ``ident.Box``, groups (N,) ints or None.
    Returns an ``ident.Box`` with ``info["rows"]`` and, with groups, ``info["rows_per_group"]``.
    """
    half = max(1, W.shape[0] // 2)
    box = ident.estimate(W[:half], y[:half], bound[:half], prior, method="hull")
    info = {"rows": half}
    if groups is not None:
        info["rows_per_group"] = np.bincount(np.asarray(groups[:half])).tolist()
    return ident.Box(box.lower, box.upper, box.names, info=info)


first_half_hull.kind = "guaranteed"
first_half_hull.rigorous = True
first_half_hull.description = "the exact hull of the first half of the rows (an outer box of the full set)"


if __name__ == "__main__":
    rng = np.random.default_rng(1)
    W = rng.normal(size=(400, 3))
    theta = np.array([0.5, -0.2, 1.0])
    y = W @ theta + rng.uniform(-0.1, 0.1, 400)
    prior = ident.Box(np.full(3, -5.0), np.full(3, 5.0))
    full = ident.estimate(W, y, 0.1, prior)
    half = first_half_hull(W, y, np.full(400, 0.1), prior)
    print("full hull width:", full.width, "\nfirst-half hull width:", half.width,
          "\nencloses the truth:", bool(half.contains(theta).all()))
