"""A hull's 2p LPs as two independent halves, the minima and the maxima, in two processes when there are two cores.

:func:`ident.estimators.hull.interval_hull` solves its 2p LPs one after the other on one HiGHS model. Here the
minima and the maxima are two hulls of their own (``interval_hull(..., lps=half)``: each its own model, working
set and warm start), merged: the lower endpoints of the first, the upper endpoints of the second. Every endpoint
is the same safe dual bound as ever, so the box is as rigorous; it differs from the one-model hull only within the
LPs' tolerances.

The split is a fixed part of the computation, not of the machine: :class:`HullSplit` runs the second half in a
worker process when it is given ``processes=2`` and in this process after the first otherwise, and both give the
same bits (each half is deterministic and sees the same inputs). The worker is the process-wide one of
:mod:`ident.workers` (``forkserver``: a clean process, no HiGHS threads forked), reused by every hull of a
refinement and by the certified path's other halves; an error in the block terminates it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from h4bench.ident.estimators.hull import COUNTERS, HullResult, HullWarm, interval_hull
from h4bench.ident.workers import shared_worker, stop_shared_worker

__all__ = ["HullSplit", "SplitWarm"]


@dataclass
class SplitWarm:
    """The warm starts of the two halves (either None)."""

    minima: HullWarm | None
    maxima: HullWarm | None


def _half(args):
    W, bl, bu, lo, hi, kwargs, lps = args
    return interval_hull(W, bl, bu, lo, hi, lps=lps, **kwargs)


class HullSplit:
    """Runs hulls as two halves (module docstring). ``processes``: 2 to run the maxima in a worker process, 1 to
    run both here; use as a context manager (the worker is shut down at its end)."""

    def __init__(self, processes: int = 1) -> None:
        if processes not in (1, 2):
            raise ValueError(f"processes must be 1 or 2, got {processes!r}")
        self.processes = processes
        self._pool = None

    def __enter__(self) -> HullSplit:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if self._pool is not None:
            if exc_type is not None:  # interrupted or failed: stop the worker's half now, not at its end
                stop_shared_worker(terminate=True)
            self._pool = None

    def _worker(self):
        if self._pool is None:
            self._pool = shared_worker()
        return self._pool

    def hull(self, W, bl, bu, lo, hi, *, warm: SplitWarm | None = None, **kwargs) -> HullResult:
        """:func:`ident.estimators.hull.interval_hull` of the same arguments, as two halves; ``warm`` a
        :class:`SplitWarm` (or None); the result's ``warm`` is the next one's."""
        p = np.asarray(lo).size
        warm = warm if isinstance(warm, SplitWarm) else SplitWarm(None, None)
        args_min = (W, bl, bu, lo, hi, {**kwargs, "warm": warm.minima}, list(range(p)))
        args_max = (W, bl, bu, lo, hi, {**kwargs, "warm": warm.maxima}, list(range(p, 2 * p)))
        if self.processes == 2:
            later = self._worker().submit(_half, args_max)
            a = _half(args_min)
            b = later.result()
        else:
            a = _half(args_min)
            b = _half(args_max)
        return merge(a, b, p)


def merge(a: HullResult, b: HullResult, p: int) -> HullResult:
    """The hull of the minima ``a`` and of the maxima ``b`` as one result: ``a``'s lower endpoints and LP
    solutions of the minima, ``b``'s upper endpoints and solutions of the maxima; the LP counters summed, the
    fallbacks and failures of both (LP indices as :func:`interval_hull` numbers them)."""
    status = "infeasible" if "infeasible" in (a.status, b.status) else "ok"
    info = {key: a.info.get(key, 0) + b.info.get(key, 0) for key in COUNTERS}
    info.update(working_rows=int(a.info.get("working_rows", 0) + b.info.get("working_rows", 0)),
                rounds=max(a.info.get("rounds", 0), b.info.get("rounds", 0)),
                lp_failures=sorted(set(a.info.get("lp_failures", [])) | set(b.info.get("lp_failures", []))),
                lp_fallback_endpoints=sorted(set(a.info.get("lp_fallback_endpoints", []))
                                             | set(b.info.get("lp_fallback_endpoints", []))),
                converged=bool(a.info.get("converged")) and bool(b.info.get("converged")),
                seconds=a.info.get("seconds", 0.0) + b.info.get("seconds", 0.0))
    for r in (a, b):
        if "lp_error" in r.info:
            info["lp_error"] = r.info["lp_error"]
    points = None
    if a.points is not None and b.points is not None:
        points = np.concatenate([a.points[:, :p], b.points[:, p:]], axis=1)
    return HullResult(lower=np.asarray(a.lower).copy(), upper=np.asarray(b.upper).copy(), status=status, info=info,
                      points=points, warm=SplitWarm(a.warm, b.warm))
