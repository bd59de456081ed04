"""The process's OpenBLAS builds and their thread counts (standard library only, nothing of the project's own).

An optimised design (a trajectory's SLSQP iterates, a controller's root finding) follows the rounding of threaded
BLAS products, so a cached design holds only for the thread counts it was computed with: the design caches put
:func:`blas_threads` in their keys (``trajectories.excitation``, ``sim.design_cache``), and
:mod:`scenarios.threads` sets the counts of a campaign's workers. The libraries are found in
``/proc/self/maps`` (Linux); elsewhere, or for another BLAS, :func:`blas_threads` names what can decide the count
instead (the core count and the thread variables of the environment).
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

__all__ = ["blas_threads", "openblas_libraries"]

_SETTERS = ("openblas_set_num_threads", "openblas_set_num_threads64_", "scipy_openblas_set_num_threads64_",
            "scipy_openblas_set_num_threads")
_GETTERS = ("openblas_get_num_threads", "openblas_get_num_threads64_", "scipy_openblas_get_num_threads64_",
            "scipy_openblas_get_num_threads")
_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_HANDLES: dict = {}  # path -> (setter, getter) or None: a library is opened once per process


def openblas_libraries() -> list:
    """(path, setter, getter) of every OpenBLAS build loaded in this process (``/proc/self/maps``, Linux), sorted
    by path; empty where none is found."""
    try:
        with open("/proc/self/maps") as f:
            paths = {line.split()[-1] for line in f if "openblas" in line.rsplit("/", 1)[-1].lower()}
    except OSError:
        return []
    out = []
    for path in sorted(paths):
        if path not in _HANDLES:
            try:
                lib = ctypes.CDLL(path)
            except OSError:
                _HANDLES[path] = None
                continue
            setter = next((getattr(lib, n) for n in _SETTERS if hasattr(lib, n)), None)
            getter = next((getattr(lib, n) for n in _GETTERS if hasattr(lib, n)), None)
            if setter is not None and getter is not None:
                setter.argtypes, getter.restype = [ctypes.c_int], ctypes.c_int
                _HANDLES[path] = (setter, getter)
            else:
                _HANDLES[path] = None
        if _HANDLES[path] is not None:
            out.append((path, *_HANDLES[path]))
    return out


def blas_threads() -> list:
    """What decides the BLAS thread counts now, JSON-ready: ``[[library file name, threads], ...]`` for every
    OpenBLAS loaded (load numpy and scipy.linalg first), or, when none is found,
    ``[["unknown", os.cpu_count(), {variable: value}]]`` with the environment's thread variables."""
    found = [[Path(path).name, int(getter())] for path, _, getter in openblas_libraries()]
    if found:
        return found
    return [["unknown", os.cpu_count(), {k: os.environ[k] for k in _ENV if k in os.environ}]]
