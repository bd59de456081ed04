"""The registry's ``certified`` estimator: the Oettli-Prager hull of an interval regressor.

A certified error model (:mod:`ident.processing.errorspec`, the derived interval equations of
:mod:`ident.robots.h4_certified` and :mod:`ident.robots.serial_certified`) gives each processed row an interval
regressor ``[W - r, W + r]`` and a bound; this estimator takes ``r`` as the context keyword ``regressor_radius``.
"""

from __future__ import annotations

import numpy as np

from h4bench.ident.box import Box
from h4bench.ident.estimators.registry import declare
from h4bench.ident.estimators.uncertain import uncertain_hull
from h4bench.ident.estimators.uncertain_signed import signed_uncertain_hull

__all__ = ["certified"]


@declare(kind="guaranteed", rigorous=True, context=("regressor_radius",),
         description="the Oettli-Prager hull of an interval regressor [W - r, W + r] (context key regressor_radius)",
         citation="W. Oettli, W. Prager, Compatibility of approximate solution of linear equations with given error "
                  "bounds for coefficients and right-hand sides, Numer. Math. 6:405-409, 1964")
def certified(W, y, bound, prior, regressor_radius=None) -> Box:
    """The registry's ``certified`` estimator: :func:`uncertain_hull` on the interval equation
    ``y in [W - regressor_radius, W + regressor_radius] theta + [-bound, bound]``.

    regressor_radius : (N, p) >= 0, the radius of each regressor entry (e.g. the derived interval equation of
    :mod:`ident.robots.h4_certified`), passed by the registry as a context keyword; required. A prior with
    negative lower bounds goes to :func:`ident.estimators.uncertain_signed.signed_uncertain_hull` (the chord of
    ``|theta|``, refined up to 3 times).
    """
    if regressor_radius is None:
        raise ValueError("certified needs regressor_radius, the (N, p) radius of the interval regressor (a context "
                         "keyword of ident.estimators.registry.call), got None")
    if np.all(np.asarray(prior.lower) >= 0):
        return uncertain_hull(W, regressor_radius, y, bound, prior)
    # a prior of both signs: the chord relaxation of |theta| (a polytope containing the Oettli-Prager set)
    return signed_uncertain_hull(W, regressor_radius, y, bound, prior, refine=3, rtol=0.02)

