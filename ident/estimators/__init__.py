"""Estimators on any ``(W, y, bound, prior)``: the exact hull, CGSP, WLS, outlier-robust and online hulls, the
uncertain-regressor hull, and :func:`estimate` that dispatches among them (import the modules directly)."""
