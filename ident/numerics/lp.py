"""The one place where HiGHS models are made: silent from the start, every call's status checked.

* **No solver output on stdout.** HiGHS writes its banner ("Running HiGHS x.y.z ...") from C to file
  descriptor 1 inside the constructor of the *first* ``highspy.Highs()`` of a process (measured with highspy
  1.16: once per process, at construction, before any option can be set; later constructions print
  nothing, and ``output_flag = False`` silences every solve). :func:`new_highs` therefore constructs the
  first model of the process with file descriptor 1 pointed at ``os.devnull`` (Python's and C's stdout
  buffers flushed before and after), under a lock, so that two threads never interleave the redirection;
  a thread that writes to file descriptor 1 during that single construction (microseconds) loses that
  write. Every later model is constructed without any redirection.
* **Every status is checked.** ``addVars``/``addRows``/``changeColsCost``/``setOptionValue`` return a
  ``HighsStatus``; an error (e.g. ``addRows`` rejects a whole block when an entry is ``>= 1e15`` in
  magnitude, leaving the model without those rows) raises :class:`LPError`. Callers turn it into a rigorous
  fallback (a coarser safe bound or the prior), never into a tighter box.
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading

import highspy
import numpy as np

from ident.errors import LPError, LPFallbackWarning

__all__ = ["LARGE_ENTRY", "LPError", "LPFallbackWarning", "add_dense_rows", "check", "new_highs"]

LARGE_ENTRY = 1e15  # HiGHS's default large_matrix_value: addRows rejects a block holding an entry this large
_ERROR = highspy.HighsStatus.kError
_lock = threading.Lock()
_first_done = False




def check(status, what: str) -> None:
    """Raise :class:`LPError` if a HiGHS call returned ``kError`` (warnings are accepted)."""
    if status == _ERROR:
        raise LPError(f"HiGHS rejected {what} (status {status})")


def _flush_c_stdout() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library handle on this platform: nothing buffered to flush
        pass


def _construct_silently() -> highspy.Highs:
    """``highspy.Highs()`` with file descriptor 1 sent to ``os.devnull`` around the constructor."""
    if sys.stdout is not None:
        try:
            sys.stdout.flush()
        except (OSError, ValueError):
            pass
    _flush_c_stdout()
    try:
        saved = os.dup(1)
    except OSError:  # no file descriptor 1: nothing can reach stdout
        return highspy.Highs()
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        try:
            h = highspy.Highs()
        finally:
            _flush_c_stdout()
            os.dup2(saved, 1)
    finally:
        os.close(saved)
        os.close(devnull)
    return h


def new_highs(tolerance: float | None = None, **options) -> highspy.Highs:
    """A silent ``highspy.Highs`` (no banner, ``output_flag`` off) with the given options set and checked.

    tolerance : primal and dual feasibility tolerance (None: HiGHS's defaults); options : further HiGHS
    options by name (e.g. ``presolve="off"``, ``simplex_strategy=4``).
    """
    global _first_done
    with _lock:
        if not _first_done:
            h = _construct_silently()
            _first_done = True
        else:
            h = highspy.Highs()
    h.silent()
    check(h.setOptionValue("output_flag", False), "option output_flag")
    if tolerance is not None:
        options = {"primal_feasibility_tolerance": float(tolerance), "dual_feasibility_tolerance": float(tolerance),
                   **options}
    for name, value in options.items():
        check(h.setOptionValue(name, value), f"option {name}={value!r}")
    return h


def add_dense_rows(h: highspy.Highs, A: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
    """Append the dense rows ``lo <= A x <= hi`` to ``h``; :class:`LPError` if HiGHS rejects them.

    A : (m, n); lo, hi : (m,) (may hold -inf / +inf). Rows with an entry of magnitude ``>= LARGE_ENTRY`` or a
    non-finite entry are rejected here first (HiGHS would drop the whole block).
    """
    A = np.ascontiguousarray(A, dtype=float)
    m, n = A.shape
    if m == 0:
        return
    amax = np.max(np.abs(A)) if A.size else 0.0
    if not np.isfinite(amax) or amax >= LARGE_ENTRY:
        raise LPError(f"rows with a matrix entry of magnitude {amax:.3g} (HiGHS accepts < {LARGE_ENTRY:.0e})")
    starts = np.arange(m, dtype=np.int32) * n
    index = np.tile(np.arange(n, dtype=np.int32), m)
    check(h.addRows(m, np.asarray(lo, float), np.asarray(hi, float), m * n, starts, index, A.ravel()), f"addRows ({m} rows)")
