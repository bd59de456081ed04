"""One BLAS thread per campaign worker.

A local campaign runs one worker process per core; each worker's OpenBLAS would otherwise start a thread per
core too, and on a busy machine its small products (the WLS fit, the LP scaling) spin threads against the other
workers': measured on 2 shared cores, WLS on a campaign run took 0.5-0.6 s with the default threads and 0.015 s
with one. Dask's nanny does the same for its workers (``OPENBLAS_NUM_THREADS=1``). Every matrix product still
computes each entry in one thread, in the same order.
"""

from __future__ import annotations

import ctypes
import os

__all__ = ["single_blas_thread"]

_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_SETTERS = ("openblas_set_num_threads", "openblas_set_num_threads64_", "scipy_openblas_set_num_threads64_",
            "scipy_openblas_set_num_threads")


def single_blas_thread() -> list[str]:
    """Limit this process's BLAS to one thread: the environment for libraries loaded from now on, and the
    OpenBLAS builds already loaded (found in ``/proc/self/maps``, Linux) through their own setter.

    Returns the paths of the loaded libraries that were set (empty where none is found: nothing else changes).
    """
    for var in _VARIABLES:
        os.environ[var] = "1"
    done = []
    try:
        with open("/proc/self/maps") as f:
            paths = {line.split()[-1] for line in f if "openblas" in line.rsplit("/", 1)[-1].lower()}
    except OSError:
        return done
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in _SETTERS:
            setter = getattr(lib, name, None)
            if setter is not None:
                setter.argtypes = [ctypes.c_int]
                setter(1)
                done.append(path)
                break
    return done
