"""The certified path's second process: one worker, started at first use and kept for the calls that follow.

The certified stage splits its work in two halves where two cores are there (``processes=2``): the H4's interval
jets and kernel rows (:mod:`ident.robots.h4_certified`), a serial arm's windows
(:mod:`ident.robots.serial_certified`), a hull's minima and maxima (:mod:`ident.estimators.hull_split`). Each half
is the same computation in either process, so the bits do not depend on where it ran. Starting a ``forkserver``
worker costs about as much as a quick run's whole certified equation (1.3-1.7 s on a 2-core machine: a clean
process imports the package again), and one run used to start three or more (its equation, its hull, its
certificate's equation; the TX40 study five). :func:`worker` hands every caller of this process the same one.

:func:`shared_map` shares a list of independent pieces between this process and the worker without assuming the
worker is ready: the worker takes pieces from the end of the list, this process from the start, and this process
also does every piece the worker has not begun by the time it gets there, so a worker still starting (or slower)
delays nothing. Every piece is computed by the same function on the same arguments wherever it runs, so the
results are the same bits as computed in one process.

An error or an interrupt in a caller's block terminates the worker (its pending half is dropped, not finished in
the background) and the next call starts a new one. The worker is shut down at the interpreter's exit.
"""

from __future__ import annotations

import atexit
import concurrent.futures
import contextlib
import multiprocessing
import threading

__all__ = ["prewarm", "shared_map", "shared_started", "shared_worker", "stop_shared_worker", "worker"]

#: what the fork server imports before it forks a worker (:func:`shared_worker`)
PRELOAD = ("__main__", "h4bench.ident.robots.h4_certified", "h4bench.ident.robots.serial_certified",
           "h4bench.ident.estimators.hull_split")
_POOL: concurrent.futures.ProcessPoolExecutor | None = None
_LOCK = threading.Lock()


def shared_worker() -> concurrent.futures.ProcessPoolExecutor:
    """The process-wide executor of one ``forkserver`` worker (a clean process, no threads forked), started now if
    none is running (or the last one broke)."""
    global _POOL
    with _LOCK:
        if _POOL is None or getattr(_POOL, "_broken", False):
            ctx = multiprocessing.get_context("forkserver")
            # the modules the halves run, imported once by the fork server (when this process starts it), so that a
            # worker forked from it starts in milliseconds instead of importing them again (about 1.5 s)
            ctx.set_forkserver_preload(list(PRELOAD))
            _POOL = concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=ctx)
        return _POOL


def prewarm(processes: int) -> None:
    """With ``processes=2``, start the shared worker (and the fork server, which imports :data:`PRELOAD` once: about
    2 s) in a background thread now, so that it is ready when the certified stage needs it; a caller does this
    before work of its own (a simulation, the tuned estimators). Nothing for 1."""
    if processes != 2:
        return

    def start():
        try:
            shared_worker().submit(int).result()
        except Exception:  # noqa: BLE001  (a failed start shows again, with its error, at the first real use)
            pass

    threading.Thread(target=start, name="h4bench-worker-prewarm", daemon=True).start()


def stop_shared_worker(terminate: bool = False) -> None:
    """Shut the shared worker down (``terminate``: at once, dropping its work); the next call starts another."""
    global _POOL
    with _LOCK:
        pool, _POOL = _POOL, None
    if pool is None:
        return
    if terminate:
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            proc.terminate()
    pool.shutdown(wait=not terminate, cancel_futures=True)


# shut down before the interpreter tears its modules down (else the executor's own finaliser may run without them)
atexit.register(stop_shared_worker)


@contextlib.contextmanager
def worker(processes: int):
    """None for ``processes=1``; the shared worker's executor for 2 (:func:`shared_worker`). An exception in the
    block (KeyboardInterrupt included) terminates the worker before it propagates."""
    if processes not in (1, 2):
        raise ValueError(f"processes must be 1 or 2, got {processes!r}")
    if processes == 1:
        yield None
        return
    pool = shared_worker()
    try:
        yield pool
    except BaseException:
        stop_shared_worker(terminate=True)
        raise


def shared_started(pool, fn, args_list):
    """:func:`shared_map` begun: the worker's pieces are submitted now; the returned function computes this
    process's and returns the list of results in order."""
    n = len(args_list)
    if pool is None or n < 2:
        return lambda: [fn(*args) for args in args_list]
    futures = {k: pool.submit(fn, *args_list[k]) for k in range(n - 1, n // 2 - 1, -1)}

    def finish() -> list:
        out: list = [None] * n
        done = [False] * n
        for k in range(n):
            if k not in futures or futures[k].cancel():
                out[k], done[k] = fn(*args_list[k]), True
        for k, f in futures.items():
            if not done[k]:
                out[k] = f.result()
        return out

    return finish


def shared_map(pool, fn, args_list) -> list:
    """``[fn(*args) for args in args_list]``; with ``pool`` (an executor of one worker) the later half of the pieces
    is submitted to it, the last first, and this process computes the others in order, then, in order, each
    submitted piece the worker has not begun (cancelled there); the worker's results are collected at the end."""
    return shared_started(pool, fn, args_list)()
