"""One BLAS thread per campaign worker, except while a trajectory is designed.

A local campaign runs one worker process per core; each worker's OpenBLAS would otherwise start a thread per
core too, and on a busy machine its small products (the WLS fit, the LP scaling) spin threads against the other
workers': measured on 2 shared cores, WLS on a campaign run took 0.5-0.6 s with the default threads and 0.015 s
with one. A run's results do not depend on the thread count (a quick ``enclosure`` campaign's runs are the same
bit for bit with one thread and with the default), but a trajectory design does: its SLSQP iterates follow the
rounding of the threaded products, and a 3 s design with 1 and with 2 threads ends in different trajectories.
So the design runs with the thread counts the process started with (:func:`original_blas_threads`), as it
did before workers were limited; a design is then cached and shared (``trajectories.excitation``), under a key
that holds the thread counts it was computed with (:func:`h4bench.blas.blas_threads`): a design of other counts
is never reused.
"""

from __future__ import annotations

import contextlib

from h4bench.blas import openblas_libraries

__all__ = ["original_blas_threads", "single_blas_thread"]

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
