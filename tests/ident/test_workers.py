"""The shared worker process (ident.workers): pieces shared with it give the results of one process, in order; a
busy or late worker delays nothing (this process takes what it has not begun); an error stops it."""

import os
import time

import pytest

from h4bench.ident import workers


def _square_and_pid(x):
    return x * x, os.getpid()


def _sleep(s):
    time.sleep(s)
    return os.getpid()


@pytest.mark.parametrize("n", [0, 1, 2, 5, 8])
def test_shared_map_gives_the_plain_results_in_order(n):
    args = [(k,) for k in range(n)]
    with workers.worker(2) as pool:
        got = workers.shared_map(pool, _square_and_pid, args)
    assert [g[0] for g in got] == [k * k for k in range(n)]
    with workers.worker(1) as none:
        assert none is None and workers.shared_map(none, _square_and_pid, args) == [(k * k, os.getpid())
                                                                                    for k in range(n)]


def test_a_busy_worker_leaves_its_pieces_to_this_process():
    with workers.worker(2) as pool:
        busy = pool.submit(_sleep, 3.0)  # the worker is taken: the pieces submitted after it are not begun
        got = workers.shared_map(pool, _square_and_pid, [(k,) for k in range(8)])
        assert [g[0] for g in got] == [k * k for k in range(8)]
        # at most the pieces the executor had already moved to the worker's call queue (max_workers + 1 = 2 behind
        # the running sleep) are computed there
        assert sum(pid != os.getpid() for _, pid in got) <= 2
        worker_pid = busy.result()
    # an idle worker does its share: the last pieces of a long list (which of them depends on timing)
    with workers.worker(2) as pool:
        got = workers.shared_map(pool, _sleep, [(0.2,)] * 10)
    assert worker_pid in got and os.getpid() in got


def test_an_error_in_the_block_terminates_the_worker_and_a_new_one_starts():
    with pytest.raises(RuntimeError, match="stop"):
        with workers.worker(2) as pool:
            first = pool.submit(os.getpid).result()
            raise RuntimeError("stop")
    with workers.worker(2) as pool:
        second = pool.submit(os.getpid).result()
    assert first != second
    with pytest.raises(ValueError, match="processes must be 1 or 2, got 3"):
        with workers.worker(3):
            pass
