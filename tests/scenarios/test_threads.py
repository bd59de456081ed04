"""scenarios.threads.hull_processes: the environment's choice, and 1 in a daemonic process (which may not start
processes of its own, e.g. a Dask worker's)."""

import multiprocessing

import pytest

from h4bench.scenarios.threads import hull_processes


def _in_child(queue):
    queue.put(hull_processes())


def test_the_environment_decides(monkeypatch):
    for value in ("1", "2"):
        monkeypatch.setenv("H4BENCH_HULL_PROCESSES", value)
        assert hull_processes() == int(value)
    monkeypatch.setenv("H4BENCH_HULL_PROCESSES", "3")
    with pytest.raises(ValueError, match="H4BENCH_HULL_PROCESSES must be 1 or 2, got '3'"):
        hull_processes()


@pytest.mark.parametrize("daemon", [True, False])
def test_a_daemonic_process_gets_one(monkeypatch, daemon):
    monkeypatch.delenv("H4BENCH_HULL_PROCESSES", raising=False)
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1}, raising=False)  # 2 cores, whatever the machine
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    child = ctx.Process(target=_in_child, args=(queue,), daemon=daemon)
    child.start()
    got = queue.get(timeout=60)
    child.join(timeout=60)
    assert got == (1 if daemon else 2)
