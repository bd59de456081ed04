"""The signed Oettli-Prager hull's first rounds on fewer rows (``coarse``, ``groups``).

Oracle: random points of the exact Oettli-Prager set (``|y - Wc theta| <= b + D |theta|``, checked directly) must
lie in every box; the rounds' row counts are read from the rounds themselves.
"""

from __future__ import annotations

import numpy as np
import pytest

from h4bench import ident
from h4bench.ident.estimators import uncertain_signed
from h4bench.ident.estimators.uncertain_signed import COARSE_GROUPS, coarse_step, signed_uncertain_hull


def _problem(windows=400, per=3, p=4, seed=2):
    rng = np.random.default_rng(seed)
    m = windows * per
    Wc = rng.normal(size=(m, p))
    D = 0.03 * np.abs(rng.normal(size=(m, p)))
    theta0 = np.array([1.0, -0.5, 0.2, -2.0])[:p]
    y = Wc @ theta0 + rng.uniform(-0.3, 0.3, m)
    window = np.repeat(np.stack([np.arange(windows) * 10, np.arange(windows) * 10 + 40], axis=1), per, axis=0)
    return Wc, D, y, np.full(m, 0.3), theta0, window, rng


def test_coarse_step_is_the_largest_power_of_two_within_the_groups():
    assert [coarse_step(n) for n in (1, COARSE_GROUPS, 2 * COARSE_GROUPS - 1, 2 * COARSE_GROUPS,
                                     4 * COARSE_GROUPS + 5, 9 * COARSE_GROUPS)] == [1, 1, 1, 2, 4, 8]


def test_coarse_rounds_keep_whole_windows_end_on_all_rows_and_enclose_the_set(monkeypatch):
    Wc, D, y, b, theta0, window, rng = _problem()
    prior = ident.Box(np.full(4, -5.0), np.full(4, 5.0))
    rows_seen = []
    real = uncertain_signed.uncertain_hull_rows

    def spy(W1, *args, **kwargs):
        rows_seen.append(W1.shape[0])
        return real(W1, *args, **kwargs)

    monkeypatch.setattr(uncertain_signed, "uncertain_hull_rows", spy)
    plain = signed_uncertain_hull(Wc, D, y, b, prior, refine=6, rtol=0.02)
    rows_seen.clear()
    box = signed_uncertain_hull(Wc, D, y, b, prior, refine=6, rtol=0.02, coarse=4, groups=window)
    m = Wc.shape[0]
    assert box.info["coarse_rounds"] >= 1
    assert rows_seen[0] == m // 4 and all(r % 3 == 0 for r in rows_seen)  # whole windows of 3 rows
    assert rows_seen[-1] == m and rows_seen == sorted(rows_seen)
    pts = rng.uniform(plain.lower, plain.upper, (40000, 4))  # the set fills a part of its hull
    feasible = np.all(np.abs(y[None] - pts @ Wc.T) <= b + np.abs(pts) @ D.T, axis=1)
    assert feasible.sum() > 20
    for bx in (plain, box):
        assert np.all(bx.contains(theta0)) and all(np.all(bx.contains(t)) for t in pts[feasible])
    # both end on all rows: the same set's hull, reached through other chords (within a few % of each other)
    assert np.allclose(box.upper - box.lower, plain.upper - plain.lower, rtol=0.05)


def test_the_last_round_allowed_uses_all_rows(monkeypatch):
    Wc, D, y, b, theta0, window, _ = _problem(seed=4)
    rows_seen = []
    real = uncertain_signed.uncertain_hull_rows
    monkeypatch.setattr(uncertain_signed, "uncertain_hull_rows",
                        lambda W1, *a, **k: (rows_seen.append(W1.shape[0]), real(W1, *a, **k))[1])
    box = signed_uncertain_hull(Wc, D, y, b, ident.Box(np.full(4, -5.0), np.full(4, 5.0)), refine=1, coarse=8,
                                groups=window, coarse_rtol=0.0)
    assert rows_seen == [Wc.shape[0] // 8, Wc.shape[0]] and box.info["coarse_rounds"] == 1
    assert np.all(box.contains(theta0))


def test_groups_of_another_length_are_refused():
    Wc, D, y, b, _, window, _ = _problem(windows=20)
    with pytest.raises(ValueError, match="groups must hold one label"):
        signed_uncertain_hull(Wc, D, y, b, ident.Box(np.full(4, -5.0), np.full(4, 5.0)), coarse=2,
                              groups=window[:-1])
