"""build_equation reusing a raw_equation's regressor rows (the campaign's one evaluation shared with the error
budget) gives exactly the equation it computes alone; a raw equation of other data or settings is not used."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from h4bench import sim
from h4bench.ident.robots import h4_equation as pr
from h4bench.ident.processing.filtering import ProcessingSettings
from tests.conftest import run_experiment


@pytest.fixture(scope="module")
def dataset(model, geometry):
    _, ds, _ = run_experiment(model, geometry, seconds=2.0, noise=sim.TorqueNoise(0.5), seed=4)
    return ds


def _same(a, b) -> None:
    for name in ("W", "y", "bound", "sample", "joint"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_reused_rows_give_the_same_equation(geometry, dataset, monkeypatch):
    settings = ProcessingSettings(dt=dataset.dt, position_cutoff_hz=50.0, decimation=2, numtaps=41, fir_cutoff=0.04,
                                  speed_threshold=0.5)
    alone = pr.build_equation(geometry, dataset, 1.5, settings, prior=(np.zeros(14), np.full(14, 2.0)))
    raw = pr.raw_equation(geometry, dataset.q, dataset.tau, dataset.dt, settings)
    other = pr.raw_equation(geometry, dataset.q, dataset.tau, dataset.dt,
                            dataclasses.replace(settings, position_cutoff_hz=30.0))
    calls = []
    real = pr.regressor
    monkeypatch.setattr(pr, "regressor", lambda *a, **k: calls.append(1) or real(*a, **k))
    shared = pr.build_equation(geometry, dataset, 1.5, settings, prior=(np.zeros(14), np.full(14, 2.0)), raw=raw)
    assert calls == []  # the raw rows were used
    _same(shared, alone)
    # a raw equation of other settings (another position filter) is not used: evaluated again, same result
    _same(pr.build_equation(geometry, dataset, 1.5, settings, prior=(np.zeros(14), np.full(14, 2.0)), raw=other),
          alone)
    assert calls == [1]
    # several blocks: a block's own derivatives differ at rounding level from the record's, so its rows are
    # evaluated again (a row is reused only where its inputs are equal bit for bit): the same equation
    blocks = pr.build_equation(geometry, dataset, 1.5, settings, block_samples=600)
    assert blocks.info["blocks"] > 1
    calls.clear()
    _same(pr.build_equation(geometry, dataset, 1.5, settings, block_samples=600, raw=raw), blocks)
    assert 1 <= len(calls) <= blocks.info["blocks"]


def test_the_generic_chain_uses_the_regressor_it_is_given(geometry, dataset):
    """The chain imports no robot: the regressor is an argument. Twice the H4's columns (exact in floating point,
    and the FIR is linear with power-of-two scaling exact) give twice its W, the same y and rows."""
    from h4bench.ident.processing import processing
    from h4bench.ident.robots import h4

    settings = ProcessingSettings(dt=dataset.dt, position_cutoff_hz=50.0, decimation=2, numtaps=41, fir_cutoff=0.04,
                                  speed_threshold=0.5)
    h4_eq = pr.build_equation(geometry, dataset, 1.5, settings)
    names = tuple(f"2{n}" for n in h4.parameter_names("paper"))
    doubled = processing.build_equation(lambda q, qd, qdd: 2.0 * h4.regressor(geometry, q, qd, qdd), names, dataset,
                                        1.5, settings)
    assert doubled.names == names
    assert np.array_equal(doubled.W, 2.0 * h4_eq.W)
    for name in ("y", "sample", "joint"):
        assert np.array_equal(getattr(doubled, name), getattr(h4_eq, name)), name
