"""Estimators on any ``(W, y, bound, prior)``: the exact hull, CGSP, WLS, outlier-robust and online hulls, the
uncertain-regressor hull, and :func:`estimate` that dispatches among them (import the modules directly).
:func:`check_estimator` (:mod:`ident.estimators.conformance`, imported on first use) checks any estimator."""

__all__ = ["check_estimator"]


def __getattr__(name: str):
    if name == "check_estimator":
        from h4bench.ident.estimators.conformance import check_estimator

        return check_estimator
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
