"""One BLAS thread per campaign worker (speed only: no result depends on the count).

A local campaign runs one worker process per core; each worker's OpenBLAS would otherwise start a thread per
core too, and on a busy machine its small products (the WLS fit, the LP scaling) spin threads against the other
workers': measured on 2 shared cores, WLS on a campaign run took 0.5-0.6 s with the default threads and 0.015 s
with one. Nothing that selects an experiment depends on the thread count or the BLAS kernel (the trajectory
and controller designs compute without BLAS, :mod:`h4bench.portable`), so a design made under one count is the
one any other would make, and the design caches do not key on it. :func:`original_blas_threads` restores the
counts the process started with inside a block (e.g. to time a threaded step).
"""

from __future__ import annotations

import contextlib

from h4bench.blas import openblas_libraries

__all__ = ["hull_processes", "original_blas_threads", "single_blas_thread"]

#: library path -> (setter, thread count found by :func:`single_blas_thread`)
_ORIGINAL: dict = {}


def single_blas_thread() -> list[str]:
    """Limit this process's OpenBLAS builds (numpy's and scipy's, both loaded first) to one thread each,
    remembering their counts for :func:`original_blas_threads`. Returns the paths of the libraries set (empty
    where none is found: nothing else changes)."""
    import numpy  # noqa: F401  (their BLAS loaded now, so that all are set)
    import scipy.linalg  # noqa: F401

    done = []
    for path, setter, getter in openblas_libraries():
        _ORIGINAL.setdefault(path, (setter, int(getter())))
        setter(1)
        done.append(path)
    return done


@contextlib.contextmanager
def original_blas_threads():
    """Within the block, the thread counts :func:`single_blas_thread` found (no change if it was not called);
    one thread again after it."""
    for setter, n in _ORIGINAL.values():
        setter(n)
    try:
        yield
    finally:
        for setter, _ in _ORIGINAL.values():
            setter(1)


def hull_processes() -> int:
    """The processes of the certified path's two halves: a signed hull's minima and maxima
    (:mod:`ident.estimators.hull_split`), the two halves of a serial certified equation's windows
    (:func:`ident.robots.serial_certified.certified_family`, the TX40 study's identification and held-out
    equations) and of the H4's interval jets (:func:`ident.robots.h4_certified.certified_steps`); speed only: 1 and
    2 give the same box. ``H4BENCH_HULL_PROCESSES`` (1 or 2) if set, else 2 when this process may use 2 cores or
    more. A campaign's workers (one per core already) set it to 1 unless it is set; a daemonic process (e.g. a Dask
    worker's), which may not start processes of its own, gets 1."""
    import multiprocessing
    import os

    env = os.environ.get("H4BENCH_HULL_PROCESSES")
    if env is not None:
        if env not in ("1", "2"):
            raise ValueError(f"H4BENCH_HULL_PROCESSES must be 1 or 2, got {env!r}")
        return int(env)
    if multiprocessing.current_process().daemon:
        return 1
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return 2 if cores >= 2 else 1
