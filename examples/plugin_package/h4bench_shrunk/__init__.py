"""An installable h4bench estimator plugin: the exact hull shrunk by 10 % of its width per side (UNSOUND on
purpose, to be caught by the workbench's narrower-than-hull check and the enclosure campaigns)."""

from __future__ import annotations

from h4bench import ident

FRACTION = 0.10


def estimate(W, y, bound, prior):
    """The hull of ``{theta in prior : |y - W theta| <= bound}`` shrunk inward by FRACTION of its width per side.

    W (N, p), y (N,), bound (N,) > 0, prior an ``ident.Box``; returns an ``ident.Box``."""
    hull = ident.estimate(W, y, bound, prior, method="hull")
    cut = FRACTION * hull.width
    return ident.Box(hull.lower + cut, hull.upper - cut, hull.names)


estimate.kind = "guaranteed"
estimate.rigorous = False
estimate.description = "UNSOUND on purpose: the exact hull shrunk by 10 % of its width per side"
