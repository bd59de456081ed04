"""The estimator benchmark's measuring functions on small data: every method timed against lstsq, the
guaranteed boxes enclose the truth and are no narrower than the exact hull, the cap skips a slow method."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from h4bench.ident.estimators import registry

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(BENCH))  # the script imports its sibling _setup
    try:
        spec = importlib.util.spec_from_file_location("bench_estimators", BENCH / "bench_estimators.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(BENCH))
    return module


@pytest.mark.parametrize("data", ["gauss", "h4"])
def test_every_method_is_timed_against_lstsq_and_the_guaranteed_ones_enclose(bench, data):
    names = ("hull", "cgsp", "contractor", "ols")
    ests = [registry.get(n) for n in names]
    row = bench.bench_size(800, data, ests, repeats=2, cap=60.0, skipped={}, last={})
    assert row["N"] == 800 and row["lstsq_s"] > 0
    assert set(row["methods"]) == set(names) | {bench.HULL_LPS}
    for name in names + (bench.HULL_LPS,):
        m = row["methods"][name]
        assert m["runs"] == 2 and m["seconds"] > 0 and m["ratio"] == pytest.approx(m["seconds"] / row["lstsq_s"])
    for name in ("hull", "cgsp", "contractor", bench.HULL_LPS):  # rigorous guaranteed: the truth is inside
        assert row["methods"][name]["encloses"], name
    for name in ("cgsp", "contractor"):  # outer boxes of the feasible set: never narrower than its hull
        assert row["methods"][name]["width_vs_hull"] >= 1.0 - 1e-9, name
    assert row["methods"][bench.HULL_LPS]["mean_width"] == pytest.approx(row["methods"]["hull"]["mean_width"],
                                                                          rel=1e-6)


def test_a_method_over_the_cap_is_skipped_and_said_so(bench):
    skipped, last = {}, {}
    ests = [registry.get("hull"), registry.get("contractor")]
    bench.bench_size(400, "gauss", ests, repeats=1, cap=1e-9, skipped=skipped, last=last)
    assert {"hull", "contractor"} <= set(skipped) and "cap" in skipped["contractor"]
    row = bench.bench_size(800, "gauss", ests, repeats=1, cap=1e-9, skipped=skipped, last=last)
    assert "hull" not in row["methods"] and "contractor" not in row["methods"]
