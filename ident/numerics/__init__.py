"""Numerics shared by the estimators: outward-rounded interval arithmetic (:mod:`ident.numerics.interval`) and the
HiGHS linear-programming helpers (:mod:`ident.numerics.lp`)."""
