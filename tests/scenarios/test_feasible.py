"""The paper kind's feasible set and held-out prediction (quick size) against independent oracles.

Oracles: the truth (feasible whenever the bound covers the oracle residual, so inside every polygon and every
envelope), the hull's intervals (the polygons' axis extents), scipy's linprog on the same LPs (the envelope on a
sample of rows), and the interval evaluation over the hull box (never narrower than the polytope's envelope).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import linprog

from h4bench.scenarios import spec as specs
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.feasible import drawn_methods, parse_pairs
from h4bench.scenarios.kinds import paper


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("feasible")
    spec = specs.load_spec("paper", quick=True)
    run_ = run_experiment(spec, 0)
    feas = paper.feasible_set(run_, out)
    arrays = {}
    pred = paper.held_out_prediction(run_, 0 + spec["prediction"]["seed_offset"], out, arrays=arrays)
    return run_, feas, pred, arrays, out


def test_polygons_contain_the_truth_and_span_the_hull(quick):
    run_, feas, _, _, out = quick
    assert (out / "feasible_set.png").stat().st_size > 10_000
    hull = run_.boxes["hull"]
    names = list(run_.equation.names)
    r = np.abs(run_.residual)
    assert np.all(r <= run_.equation.bound)  # the truth is feasible in this run, so it lies in every projection
    assert len(feas["pairs"]) == 3 and feas["lp_failures"] == 0
    json.dumps(feas)  # plain JSON
    for pj in feas["pairs"]:
        i, j = (names.index(n) for n in pj["parameters"])
        v = np.asarray(pj["vertices"])
        assert pj["directions"] >= 32 and pj["area"] > 0 and pj["truth_inside"]
        for col, k in ((0, i), (1, j)):
            tol = 1e-7 * (hull.upper[k] - hull.lower[k])
            assert v[:, col].min() == pytest.approx(hull.lower[k], abs=tol)
            assert v[:, col].max() == pytest.approx(hull.upper[k], abs=tol)
        assert pj["gap"] < 1e-2 and pj["inner_area"] <= pj["area"]
    assert set(drawn_methods(run_.spec["estimators"]["methods"])) <= set(feas["methods_drawn"]) | set(
        feas["methods_skipped"])


def test_prediction_covers_and_equals_linprog(quick):
    run_, _, pred, arrays, out = quick
    assert (out / "prediction.png").stat().st_size > 10_000
    assert pred["rows"] == arrays["W"].shape[0] > 0 and pred["seed"] == 100
    if pred["bound_covers_residual"]:
        assert pred["coverage"] == 1.0 and pred["truth_in_envelope"] == 1.0  # the guarantee
    lo_p, hi_p = arrays["polytope"]
    lo_b, hi_b = arrays["box"]
    assert np.all(lo_b <= lo_p) and np.all(hi_p <= hi_b)
    assert pred["envelope_width_median"]["polytope"] < pred["envelope_width_median"]["box"]
    eq, hull = run_.equation, run_.boxes["hull"]
    A = np.vstack([eq.W, -eq.W])
    rhs = np.concatenate([eq.y + eq.bound, eq.bound - eq.y])
    bounds = list(zip(hull.lower, hull.upper))
    for k in np.linspace(0, pred["rows"] - 1, 5).astype(int):
        w = arrays["W"][k]
        res_lo = linprog(w, A_ub=A, b_ub=rhs, bounds=bounds, method="highs")
        res_hi = linprog(-w, A_ub=A, b_ub=rhs, bounds=bounds, method="highs")
        assert res_lo.status == 0 and res_hi.status == 0
        scale = np.abs(w) @ (hull.upper - hull.lower)
        assert lo_p[k] <= res_lo.fun + 1e-9 * scale and hi_p[k] >= -res_hi.fun - 1e-9 * scale  # outer
        assert lo_p[k] == pytest.approx(res_lo.fun, abs=1e-6 * scale)  # and tight
        assert hi_p[k] == pytest.approx(-res_hi.fun, abs=1e-6 * scale)


def test_parse_pairs_and_spec_checks(tmp_path):
    names = ["Fv1", "Fs1", "Mnac"]
    assert parse_pairs("Fv1:Fs1, Mnac:Fv1", names) == [(0, 1), (2, 0)]
    for bad, what in (("Fv1", "NAME:NAME"), ("Fv1:Fv1", "different"), ("Fv1:Xx", "unknown parameter 'Xx'"),
                      ("", "at least one")):
        with pytest.raises(ValueError, match=what):
            parse_pairs(bad, names)
    for table, line, what in (("feasible", "directions = 10", "feasible.directions"),
                              ("feasible", "pairs = ['Fv1-Fs1']", "feasible.pairs"),
                              ("prediction", "joint = 5", "prediction.joint")):
        path = tmp_path / f"{what}.toml"
        path.write_text(f"kind = 'paper'\n[{table}]\n{line}\n")
        with pytest.raises(specs.ScenarioError, match=what):
            specs.load_spec(path)


def _identify(csv, out, *args):
    from typer.testing import CliRunner

    from h4bench.scenarios.cli import app

    return CliRunner().invoke(app, ["identify", str(csv), "--bound", "1.5", "--out", str(out), *map(str, args)])


@pytest.fixture(scope="module")
def log_csv(quick, tmp_path_factory):
    ds = quick[0].dataset
    path = tmp_path_factory.mktemp("log") / "log.csv"
    np.savetxt(path, np.column_stack([ds.t, ds.q, ds.tau]), delimiter=",", header="t,q1,q2,q3,q4,tau1,tau2,tau3,tau4",
               comments="", fmt="%.17g")
    return path


def test_identify_pairs_draws_the_projections(log_csv, tmp_path):
    res = _identify(log_csv, tmp_path / "a", "--pairs", "Fv1:Fs1,Imot1:Mnac")
    assert res.exit_code == 0, res.output
    result = json.loads((tmp_path / "a" / "result.json").read_text())
    assert (tmp_path / "a" / "feasible_set.png").stat().st_size > 10_000
    pairs = result["feasible_set"]["pairs"]
    assert [p["parameters"] for p in pairs] == [["Fv1", "Fs1"], ["Imot1", "Mnac"]]
    hull, names = result["methods"]["hull"], result["parameters"]
    for pj in pairs:
        v = np.asarray(pj["vertices"])
        for col, name in enumerate(pj["parameters"]):
            k = names.index(name)
            tol = 1e-7 * (hull["upper"][k] - hull["lower"][k])
            assert v[:, col].min() == pytest.approx(hull["lower"][k], abs=tol)
            assert v[:, col].max() == pytest.approx(hull["upper"][k], abs=tol)
    res = _identify(log_csv, tmp_path / "b", "--pairs", "auto", "--method", "cgsp")
    assert res.exit_code == 0, res.output
    result = json.loads((tmp_path / "b" / "result.json").read_text())
    assert len(result["feasible_set"]["pairs"]) == 3 and result["feasible_set"]["selection"].startswith("most")


def test_identify_bad_pairs_is_one_error_line(log_csv, tmp_path):
    res = _identify(log_csv, tmp_path / "c", "--pairs", "Fv1:Xx")
    assert res.exit_code == 2
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: --pairs") and "'Xx'" in lines[0], res.output


def test_replay_polygons_shrink_as_data_arrive(quick, tmp_path):
    from h4bench.scenarios.replay import box_history, write_replay
    from tests.scenarios.test_replay import read_rrd

    run_, feas, _, _, _ = quick
    run_.feasible = feas
    history = box_history(run_, methods=("hull",), points=3)
    content = read_rrd(write_replay(run_, tmp_path / "replay.rrd", history=history))
    ok = history["methods"]["hull"]["ok"]
    names = list(run_.equation.names)
    hull = run_.boxes["hull"]
    for pj in feas["pairs"]:
        a, b = pj["parameters"]
        i, j = names.index(a), names.index(b)
        entry = content[f"/feasible/{a}_{b}/polygon"]
        np.testing.assert_allclose(entry["t"], history["time"][ok], atol=1e-9)  # the box history's k
        lo = hull.lower[[i, j]]
        w = hull.upper[[i, j]] - lo
        truth = (run_.theta_true[[i, j]] - lo) / w
        areas = []
        for row in entry["LineStrips2D:strips"]:
            v = np.asarray(row[0], dtype=float)[:-1]  # closed strip: the first vertex repeated
            e = np.roll(v, -1, axis=0) - v
            cross = e[:, 0] * (truth[1] - v[:, 1]) - e[:, 1] * (truth[0] - v[:, 0])
            assert np.all(cross >= -1e-6)  # the truth (feasible for every prefix of the rows) inside each polygon
            areas.append(0.5 * np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
        assert areas[-1] < areas[0]  # more data, a smaller set
        # the last polygon spans the final hull box: the unit square of the replay's plane
        last = np.asarray(entry["LineStrips2D:strips"][-1][0], dtype=float)
        np.testing.assert_allclose([last.min(axis=0), last.max(axis=0)], [[0, 0], [1, 1]], atol=1e-6)
        assert f"/feasible/{a}_{b}/hull" in content and f"/feasible/{a}_{b}/true" in content
