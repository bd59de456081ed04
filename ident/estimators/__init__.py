"""Estimators on any ``(W, y, bound, prior)``: the exact hull, CGSP, WLS, outlier-robust and online hulls, the
uncertain-regressor hull, and :func:`estimate` that dispatches among them (import the modules directly).
:func:`check_estimator` (:mod:`ident.estimators.conformance`, imported on first use) checks any estimator; the
public names :class:`SupportLP` (support functions of the feasible set) and :func:`min_consistent_scale` are also
imported on first use."""

__all__ = ["SupportLP", "check_estimator", "min_consistent_scale"]

#: public names, imported on first use (PEP 562): name -> module
_LAZY = {"check_estimator": "conformance", "min_consistent_scale": "estimate", "SupportLP": "support"}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib import import_module

    return getattr(import_module(f"{__name__}.{module}"), name)
