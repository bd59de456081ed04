"""Warm starts of the hull LPs (:class:`ident.estimators.hull.HullWarm`) and the full check pool.

Oracles: scipy's linprog on all rows (the exact hull of the same polytope, its optima moved to verified points of
the set); the former path of the same code on the same inputs (``POOL_ENTRIES = 0``, ``WARM_ROWS = False``: the
pool of the 4000 nearest rows and every refinement round from its own first rows, as at 7b00d11); HiGHS's own
iteration count for a restored basis.
"""

from __future__ import annotations

import numpy as np
import pytest

from h4bench import ident
from h4bench.ident.estimators import hull as hull_module
from h4bench.ident.estimators import hull_warm
from h4bench.ident.estimators import uncertain_signed
from h4bench.ident.estimators.hull import HullWarm, interval_hull, strip_bounds
from h4bench.ident.estimators.uncertain_signed import signed_uncertain_hull
from h4bench.ident.numerics import lp
from h4bench.ident.numerics.lp import LPModel
from tests.ident.test_hull import linprog_endpoints, make_problem, verified_feasible_point
from tests.ident.test_uncertain import _op_problem

# seeds of make_problem with more rows than ALL_ROWS_UP_TO (below it every row is in the model from the start)
SEEDS = [s for s in range(60) if make_problem(s)["W"].shape[0] > hull_module.ALL_ROWS_UP_TO][:8]


def _hull(P, lo, hi, **kw):
    bl, bu = strip_bounds(P["y"], P["b"])
    return interval_hull(P["W"], bl, bu, lo, hi, center=P["theta"], **kw)


def _assert_outer_and_tight(res, P, lo, hi):
    """The box holds verified points of S next to linprog's optima (exact comparison) and is within 1e-9 of them."""
    Q = dict(P, lo=lo, hi=hi)
    lp_lo, lp_hi, points = linprog_endpoints(P["W"], P["y"], P["b"], lo, hi)
    for i in range(lo.size):
        z_min, z_max = verified_feasible_point(points[0, i], Q), verified_feasible_point(points[1, i], Q)
        assert res.lower[i] <= z_min[i] and z_max[i] <= res.upper[i]
    scale = np.maximum(np.maximum(np.abs(lp_lo), np.abs(lp_hi)), lp_hi - lp_lo) + 1e-300
    assert np.all(np.abs(res.lower - lp_lo) <= 1e-9 * scale + 1e-12 * (hi - lo))
    assert np.all(np.abs(res.upper - lp_hi) <= 1e-9 * scale + 1e-12 * (hi - lo))


@pytest.mark.parametrize("seed", SEEDS)
def test_warm_started_hull_over_a_smaller_box_matches_linprog(seed):
    """A hull over the prior, then over a box around its result (as a refinement round) warm-started from it."""
    P = make_problem(seed)
    first = _hull(P, P["lo"], P["hi"])
    assert first.status == "ok" and first.warm is not None
    assert sum(b is not None for b in first.warm.bases) == 2 * P["W"].shape[1]
    # a smaller box that still holds the true theta (the set shrinks: optima move)
    lo = np.maximum(P["lo"], np.minimum(P["theta"], first.lower + 0.2 * (first.upper - first.lower)))
    hi = np.minimum(P["hi"], np.maximum(P["theta"], first.upper - 0.2 * (first.upper - first.lower)))
    warm = _hull(P, lo, hi, warm=first.warm)
    cold = _hull(P, lo, hi)
    tight, bases = hull_warm.tight_rows(first.warm)
    assert tight.size and np.all(np.isin(tight, first.warm.rows))
    for b, full in zip(bases, first.warm.bases):  # a dropped row is basic in every basis: the bases stay square
        assert sum(st == lp.BASIC for st in b[1]) + sum(st == lp.BASIC for st in b[0]) == len(b[1])
        assert len(full[1]) - len(b[1]) == sum(st == lp.BASIC for st in full[1]) - sum(st == lp.BASIC for st in b[1])
    assert np.array_equal(warm.warm.rows[:tight.size], tight)  # the warm start's tight rows, in order, came first
    _assert_outer_and_tight(warm, P, lo, hi)
    _assert_outer_and_tight(cold, P, lo, hi)


def test_unusable_warm_starts_are_ignored():
    """Rows out of range, repeated rows, a wrong number of bases, or nonsense basis statuses: the box is still
    linprog's hull (a warm start steers the LPs only)."""
    P = make_problem(SEEDS[0])
    n, p = P["W"].shape
    first = _hull(P, P["lo"], P["hi"])
    good = first.warm
    bad = [HullWarm(rows=np.array([0, n]), bases=good.bases), HullWarm(rows=np.array([3, 3, 4]), bases=good.bases),
           HullWarm(rows=good.rows, bases=good.bases[:-1]),
           HullWarm(rows=np.zeros(0, dtype=np.int64), bases=good.bases)]
    assert not any(hull_warm.usable(w, n, 2 * p, hull_module.ALL_ROWS_UP_TO) for w in bad)
    assert hull_warm.usable(good, n, 2 * p, hull_module.ALL_ROWS_UP_TO)
    basic = [(list(c), [type(c[0]).kBasic] * len(r)) for c, r in (b for b in good.bases)]  # n + m basic: invalid
    for warm in bad + [HullWarm(rows=good.rows, bases=basic)]:
        _assert_outer_and_tight(_hull(P, P["lo"], P["hi"], warm=warm), P, P["lo"], P["hi"])


def test_restored_basis_needs_no_iteration():
    """LPModel.basis_status / set_basis_status: LP a's optimal basis, restored after LP b, solves LP a at once; a
    basis of fewer rows is completed with basic rows."""
    rng = np.random.default_rng(5)
    p, m = 6, 80
    A = rng.standard_normal((m, p))
    model = LPModel(-np.ones(p), np.ones(p), center=np.zeros(p))
    model.add_rows(A[:40], -np.ones(40), np.ones(40))
    ca, cb = rng.standard_normal(p), rng.standard_normal(p)
    sa = model.solve(ca)
    basis = model.basis_status()
    model.solve(cb)
    model.add_rows(A[40:], -np.ones(40), np.ones(40))  # more rows than the saved basis: they enter basic
    assert model.set_basis_status(*basis)
    again = model.solve(ca)
    redo = LPModel(-np.ones(p), np.ones(p), center=np.zeros(p))
    redo.add_rows(A, -np.ones(m), np.ones(m))
    exact = redo.solve(ca)
    assert again.status == "optimal" and abs(ca @ again.x - ca @ exact.x) <= 1e-9 * (1 + abs(ca @ exact.x))
    if np.all(np.abs(A[40:] @ sa.x) < 1 - 1e-9):  # the new rows do not cut LP a's optimum: nothing to do
        assert again.iterations == 0
    assert not model.set_basis_status(basis[0][:-1], basis[1])  # wrong number of columns: refused


@pytest.mark.parametrize("seed", [3, 11])
def test_signed_hull_warm_rounds_give_the_former_box(seed, monkeypatch):
    """The signed hull with warm-started rounds and the full pool against the former path on the same inputs:
    equal within the LP tolerance (1e-7 of each width), neither narrower nor wider beyond it."""
    Wc, D, y, theta = _op_problem(400, 4, seed=seed)
    prior = ident.Box(-3 * np.ones(4), 3 * np.ones(4), names=("a", "b", "c", "d"))
    new = signed_uncertain_hull(Wc, D, y, 0.5, prior, refine=3)
    monkeypatch.setattr(hull_module, "POOL_ENTRIES", 0)
    monkeypatch.setattr(uncertain_signed, "WARM_ROWS", False)
    old = signed_uncertain_hull(Wc, D, y, 0.5, prior, refine=3)
    tol = 1e-7 * np.maximum(old.upper - old.lower, 1e-300)
    assert np.all(np.abs(new.lower - old.lower) <= tol) and np.all(np.abs(new.upper - old.upper) <= tol)
    assert new.contains(theta).all() and new.info["refinements"] == old.info["refinements"]


@pytest.mark.slow  # about a minute on a loaded 2-core machine: two identify runs with 3 refinement rounds each
def test_identify_spec_gives_the_former_box(tmp_path, monkeypatch):
    """End to end: ``identify --urdf --spec`` on a short synthetic TX40 log (tests/ident/test_serial_certified.py's,
    with 3 refinement rounds) gives the former path's box within the LP tolerance, and both hold the truth."""
    from h4bench.ident.robots import tx40
    from h4bench.scenarios.identify_serial_certified import identify_urdf_spec
    from tests.ident.test_serial_certified import DT, _log, spec_toml

    robot = tx40.robot()
    _, theta, q, tau, spec = _log(robot, T=1.2)
    csv, toml = tmp_path / "log.csv", tmp_path / "spec.toml"
    head = "t," + ",".join(f"q{i + 1}" for i in range(6)) + "," + ",".join(f"tau{i + 1}" for i in range(6))
    np.savetxt(csv, np.column_stack([np.arange(q.shape[0]) * DT, q, tau]), delimiter=",", header=head, comments="",
               fmt="%.17g")
    toml.write_text(spec_toml(spec, kernel_steps=80, stride=40, refine=3))
    truth = robot.base(200, 0).from_standard(theta)

    def run(name):
        r = identify_urdf_spec(csv, tx40.urdf_path(), toml, coupled_wrist=(4, 5), out=tmp_path / name)
        m = r["methods"]["certified"]
        assert m["status"] == "ok" and m["info"]["lp_fallbacks"] == 0
        return np.asarray(m["lower"]), np.asarray(m["upper"]), m["info"]

    lo, hi, info = run("new")
    assert info["refinements"] >= 1 and np.all((lo <= truth) & (truth <= hi))
    monkeypatch.setattr(hull_module, "POOL_ENTRIES", 0)
    monkeypatch.setattr(uncertain_signed, "WARM_ROWS", False)
    lo0, hi0, info0 = run("former")
    tol = 1e-7 * np.maximum(hi0 - lo0, 1e-300)
    assert info0["refinements"] == info["refinements"]
    assert np.all(np.abs(lo - lo0) <= tol) and np.all(np.abs(hi - hi0) <= tol)
