"""Every exception and warning class of :mod:`ident` (re-exported by the package and by the modules that raise
them)."""

from __future__ import annotations

__all__ = ["EstimatorError", "InconsistentDataError", "LPError", "LPFallbackWarning", "OutlierBudgetError", "ProcessingError",
           "UnidentifiableError"]


class InconsistentDataError(ValueError):
    """The data contradict the error bound: no theta in the prior satisfies ``|y - W theta| <= bound``.

    ``min_bound`` is the smallest scalar bound that makes the data consistent with the prior (rounded up,
    so ``bound = min_bound`` is guaranteed consistent); ``bound`` the bound that was given (scalar or the
    largest per-row value); ``scale_lower`` a proven lower bound of the factor by which the given bound(s)
    must be multiplied to become consistent (``> 1``).
    """

    def __init__(self, message: str, *, min_bound: float, bound: float, scale_lower: float) -> None:
        super().__init__(message)
        self.min_bound = float(min_bound)
        self.bound = float(bound)
        self.scale_lower = float(scale_lower)


class UnidentifiableError(ValueError):
    """The data do not determine some parameters (rank-deficient regressor); ``names`` lists them."""

    def __init__(self, message: str, *, names: tuple[str, ...]) -> None:
        super().__init__(message)
        self.names = tuple(names)


class OutlierBudgetError(InconsistentDataError):
    """More than ``q`` rows contradict the bound: the q-relaxed set ``S_q`` is proven empty.

    ``q`` is the budget given; ``certain_rows`` the rows proven to be outliers when the proof was found;
    ``min_bound`` is the plain smallest consistent scalar bound (all rows kept), an upper bound of the
    smallest bound that would make the q-relaxed problem consistent.
    """

    def __init__(self, message: str, *, q: int, certain_rows=(), min_bound: float, bound: float) -> None:
        super().__init__(message, min_bound=min_bound, bound=bound, scale_lower=1.0)
        self.q = int(q)
        self.certain_rows = tuple(int(k) for k in certain_rows)


class ProcessingError(ValueError):
    """The data cannot give an equation: too short a log, or no row free of slow samples."""


class LPError(RuntimeError):
    """HiGHS rejected a call or could not solve a linear program (the message names the call and status)."""


class LPFallbackWarning(RuntimeWarning):
    """An LP could not be solved; a coarser rigorous bound (or the prior) was used for some endpoints."""


class EstimatorError(ValueError):
    """An estimator could not be found or loaded, or returned something that is not a valid box for the prior
    (the message names the estimator and what was wrong)."""
