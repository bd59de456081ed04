"""A deliberately UNSOUND estimator: the exact hull shrunk inward, to show that the workbench catches it.

Each side of the exact hull (``ident.estimate(..., method="hull")``) moves inward by :data:`FRACTION` of the
hull's width, so the box claims to enclose the feasible set while it cuts 2 x 10 % of it off in every
coordinate. It declares itself ``kind = "guaranteed"`` (it claims an outer enclosure) and ``rigorous = False``.
The scenarios flag it: its box excludes points of the feasible set proven by the hull's own LP solutions (the
narrower-than-hull check, ``unsound: true``: every run of ``h4bench run enclosure --quick --methods
hull,examples.shrunk_hull:estimate``) and, when the truth lies in a cut-off slice, it misses the truth (in
``enclosure-critical``, where no hull point can be proven: every quick run, 78 % of 200 runs).

:func:`rounded_inward` is the other kind of defect, the one ``enclosure-critical`` exists for: a box that is
right but for its last digits (each endpoint moved inward by :data:`RELATIVE` of its magnitude, about 4500 units
in the last place: what an endpoint computed in plain floating point instead of a safe bound can lose). In an
ordinary run the hull's LP points, proven feasible with outward rounding, lie closer to the hull's edges than that,
so the narrower-than-hull check proves it unsound (4 of 4 quick runs); in a critical run no point can be proven,
but the feasible set itself is about 1e-13 of the values wide, and the box misses the truth.

Use them as ``examples.shrunk_hull:estimate`` and ``examples.shrunk_hull:rounded_inward`` (from the repository's
root) wherever a method name is accepted; run this file to see one verdict on a small synthetic problem.
"""

from __future__ import annotations

import numpy as np

from h4bench import ident

FRACTION = 0.10  #: each side moves inward by this fraction of the hull's width


def estimate(W, y, bound, prior):
    """The hull of ``{theta in prior : |y - W theta| <= bound}`` shrunk by :data:`FRACTION` of its width per side.

    W (N, p), y (N,), bound (N,) > 0 in y's units, prior an ``ident.Box``; returns an ``ident.Box`` (p,).
    Raises ``ident.InconsistentDataError`` where the hull proves the set empty.
    """
    hull = ident.estimate(W, y, bound, prior, method="hull")
    cut = FRACTION * hull.width
    return ident.Box(hull.lower + cut, hull.upper - cut, hull.names, info={"shrunk_by": FRACTION})


estimate.kind = "guaranteed"
estimate.rigorous = False
estimate.description = f"UNSOUND on purpose: the exact hull shrunk by {FRACTION:.0%} of its width per side"


RELATIVE = 1e-12  #: rounded_inward: each endpoint moves inward by this fraction of its magnitude


def rounded_inward(W, y, bound, prior):
    """The exact hull with each endpoint moved inward by :data:`RELATIVE` of its magnitude (never past the
    midpoint: a box whose width is below that collapses to its midpoint).

    W (N, p), y (N,), bound (N,) > 0 in y's units, prior an ``ident.Box``; returns an ``ident.Box`` (p,).
    """
    hull = ident.estimate(W, y, bound, prior, method="hull")
    mid = hull.mid
    lower = np.minimum(hull.lower + RELATIVE * np.abs(hull.lower), mid)
    upper = np.maximum(hull.upper - RELATIVE * np.abs(hull.upper), mid)
    return ident.Box(lower, upper, hull.names, info={"moved_inward_relative": RELATIVE})


rounded_inward.kind = "guaranteed"
rounded_inward.rigorous = False
rounded_inward.description = (f"UNSOUND on purpose: the exact hull's endpoints moved inward by {RELATIVE:g} of their "
                              "magnitude (a rounding-scale defect)")


def _demo() -> dict:
    """The hull and the shrunk box judged on a random strip problem (truth known)."""
    from h4bench.scenarios import judging

    rng = np.random.default_rng(0)
    W = rng.normal(size=(200, 3))
    theta = np.array([0.5, -0.2, 1.0])
    y = W @ theta + rng.uniform(-0.1, 0.1, 200)
    bound = np.full(200, 0.1)
    prior = ident.Box(np.full(3, -5.0), np.full(3, 5.0))
    outcomes, hull = judging.run_methods(["hull", estimate], W, y, bound, prior)
    ref = judging.hull_reference(W, y, bound, prior, hull.box)
    return judging.judge(outcomes, ref, theta)


if __name__ == "__main__":
    for name, m in _demo().items():
        print(f"{name}: unsound={m['unsound']} narrower_than_hull={m['narrower_than_hull']} "
              f"encloses the truth={m['all_enclosed']}")
