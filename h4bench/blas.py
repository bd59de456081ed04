"""The process's OpenBLAS builds, their kernels and thread counts (standard library only, nothing of the project's
own).

Nothing that selects an experiment depends on them: the designs compute without BLAS where a result chooses
something (:mod:`h4bench.portable`), so the design caches no longer key on them. They are recorded as information
(:func:`blas_info`, in a run's ``result.json`` under ``platform``), and :mod:`scenarios.threads` sets the counts
of a campaign's workers (speed only). The libraries are found in ``/proc/self/maps`` (Linux); elsewhere, or for
another BLAS, :func:`blas_threads` names what can decide the count instead (the core count and the thread
variables of the environment).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
from pathlib import Path

__all__ = ["blas_info", "blas_threads", "one_blas_thread", "openblas_libraries"]

_SETTERS = ("openblas_set_num_threads", "openblas_set_num_threads64_", "scipy_openblas_set_num_threads64_",
            "scipy_openblas_set_num_threads")
_GETTERS = ("openblas_get_num_threads", "openblas_get_num_threads64_", "scipy_openblas_get_num_threads64_",
            "scipy_openblas_get_num_threads")
_CORENAMES = ("openblas_get_corename", "openblas_get_corename64_", "scipy_openblas_get_corename64_",
              "scipy_openblas_get_corename")
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


def blas_info() -> list:
    """Each OpenBLAS loaded (load numpy and scipy.linalg first), JSON-ready and for information only:
    ``[{"library": file name, "kernel": the core name it runs (e.g. "Haswell"), "threads": n}, ...]``, or the
    :func:`blas_threads` fallback where none is found."""
    out = []
    for path, _, getter in openblas_libraries():
        kernel = None
        try:
            lib = ctypes.CDLL(path)
            fn = next((getattr(lib, n) for n in _CORENAMES if hasattr(lib, n)), None)
            if fn is not None:
                fn.restype = ctypes.c_char_p
                kernel = fn().decode(errors="replace")
        except OSError:
            pass
        out.append({"library": Path(path).name, "kernel": kernel, "threads": int(getter())})
    return out or [{"library": "unknown", "kernel": None, "threads": blas_threads()[0][1]}]


@contextlib.contextmanager
def one_blas_thread():
    """Within the block, every OpenBLAS loaded now (load the libraries whose calls matter first, e.g. by
    importing scipy.optimize) runs one thread; the counts it found are restored after it. For a step whose
    library code calls BLAS on a path we do not control (scipy's SLSQP): a threaded product splits its sums by
    thread, so one thread removes the thread count from the result (the kernel's own order remains)."""
    libs = openblas_libraries()
    saved = [(setter, int(getter())) for _, setter, getter in libs]
    for setter, _ in saved:
        setter(1)
    try:
        yield
    finally:
        for setter, n in saved:
            setter(n)
