"""The design cache within a process: a checked entry is recalled while its file is unchanged, an entry holding
the arrays that passed the checks at design time (its content hash) is not checked again, anything else is."""

from __future__ import annotations

import numpy as np
import pytest

from h4bench import trajectories as tj
from h4bench.trajectories import excitation as tx
from tests.trajectories.test_bounded import PAPER_PROCESSING


def test_recall_and_content_hash(geometry, tmp_path, monkeypatch):
    monkeypatch.setenv("H4BENCH_CACHE", str(tmp_path))
    monkeypatch.setattr(tx, "_MEMORY", {})
    kw = dict(processing=PAPER_PROCESSING, max_iter=2)
    s0 = tx.cache_stats()
    first = tj.design_excitation(geometry, 3.0, seed=4, **kw)
    assert tx.cache_stats()["computed"] == s0["computed"] + 1
    assert first.parameters["cache"]["content"] == tx.content_hash(first)
    checks = []
    real = tx.check_trajectory
    monkeypatch.setattr(tx, "check_trajectory", lambda *a, **k: checks.append(1) or real(*a, **k))
    disk = tj.design_excitation(geometry, 3.0, seed=4, **kw)
    assert checks == [] and disk.equals(first)  # the stored content hash matched: no second check
    again = tj.design_excitation(geometry, 3.0, seed=4, **kw)
    s1 = tx.cache_stats()
    assert again is disk and s1["memory"] >= 1 and s1["disk"] >= s0["disk"] + 1
    with pytest.raises(ValueError):
        again.q[0, 0] = 1.0  # shared by the calls: read-only
    path = next((tmp_path / "trajectories").glob("*.npz"))
    # arrays changed under the same metadata (hash kept): the hash does not match, the full check runs
    q = first.q.copy()
    q[100, 0] += 1e-9
    tj.Trajectory(t=first.t, x=first.x, q=q, qd=first.qd, qdd=first.qdd, kind=first.kind,
                  parameters=first.parameters, checks=first.checks).save(path)
    got = tj.design_excitation(geometry, 3.0, seed=4, **kw)
    assert checks == [1] and np.array_equal(got.q, q)  # a changed file is loaded again, then checked
    # an entry written without the hash (an older one) is checked too
    params = dict(first.parameters, cache={k: v for k, v in first.parameters["cache"].items() if k != "content"})
    tj.Trajectory(t=first.t, x=first.x, q=first.q, qd=first.qd, qdd=first.qdd, kind=first.kind, parameters=params,
                  checks=first.checks).save(path)
    tj.design_excitation(geometry, 3.0, seed=4, **kw)
    assert checks == [1, 1]
