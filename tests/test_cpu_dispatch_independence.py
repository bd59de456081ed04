"""Same seed, same numbers whichever SIMD code numpy picks for this CPU: the short paper experiment of
``test_blas_independence`` (design, controller, feed-forward, simulation, hull box, a serial arm's base and prior, the
signed uncertain hull) and a short H4 certified equation, in fresh processes with ``NPY_DISABLE_CPU_FEATURES``
switching off none, all but the lowest and all of numpy's run-time dispatch targets (``__cpu_dispatch__``: AVX2 and
AVX-512 code on x86-64), each with its own empty design cache.

numpy picks its ufunc loops by CPU at run time; ``np.arccos``, ``np.exp``, ``np.log``, ``np.tanh``, ``np.power``,
``np.arctan2``, complex products and absolute values, and the order of ties in ``np.argpartition`` and the default
``np.argsort`` change with it. Before h4bench computed them portably (:mod:`h4bench.portable`), switching off the
AVX-512 code changed the trajectory design, the controller and so every simulated log, and switching off AVX2 the
hull's working set.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from tests.test_blas_independence import CHILD, run_child


H4_CHILD = """
import hashlib, json
import numpy as np
from h4bench.ident.robots.h4_certified import Processing, certified_equation
from h4bench.scenarios.certificate import simulated_error_spec
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.registry import load_spec
spec = load_spec("certified", quick=True)
spec["trajectory"]["duration"] = 3.0
spec["estimators"]["methods"] = ["hull"]
run = run_experiment(spec, 0)
es = simulated_error_spec(spec, run.reference, run.dataset.dt, run.noise_bound, run.dataset.tau, model=run.model)
eq = certified_equation(run.geometry, run.dataset.q[:600], run.dataset.tau[:600], es, Processing(kernel_steps=64))
h = hashlib.sha256()
for a in (eq.Wc, eq.D, eq.y, eq.bound, eq.motion.HP, eq.motion.HF):
    h.update(np.ascontiguousarray(a).tobytes())
# a log written with 6 significant digits: each value's decade and half unit (numpy's log10 and power differ by CPU)
from h4bench.ident.processing.errorspec import ErrorSpec
digits = ErrorSpec(n_joints=4, sample_period=1e-3, torque_error=1.0, qd_max=1.0, qdd_max=1.0, significant_digits=6)
written = np.vectorize(lambda v: float(f"{v:.6g}"))(np.concatenate([run.dataset.q, 10.0 ** np.arange(-8, 8.0)[:, None]
                                                                     * np.ones(4)]))
h.update(digits.position_error(written).tobytes())
print(json.dumps({"certified": h.hexdigest(), "hashes": run.content_hashes}))
"""


def _targets() -> list[str]:
    from numpy._core._multiarray_umath import __cpu_dispatch__  # noqa: PLC0415

    return list(__cpu_dispatch__)


def _child(code: str, disabled: list[str], cache: Path) -> dict:
    return run_child(code, dict(os.environ, H4BENCH_CACHE=str(cache), NPY_DISABLE_CPU_FEATURES=" ".join(disabled)))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    targets = _targets()
    if not targets:
        pytest.skip("this numpy dispatches no SIMD code at run time")
    settings = [(), tuple(targets[1:]), tuple(targets)]  # none, all but the lowest (AVX2 left on x86-64), all
    root = tmp_path_factory.mktemp("dispatch")
    jobs = [(code, s) for s in settings for code in (CHILD, H4_CHILD)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        out = list(pool.map(lambda j: _child(j[0], list(j[1]), root / f"{jobs.index(j)}"), jobs))
    return {(j[1], "paper" if j[0] is CHILD else "h4"): r for j, r in zip(jobs, out)}


def test_the_experiment_and_its_boxes_are_the_same_bits_under_every_dispatch(runs):
    first = runs[((), "paper")]
    assert set(first["hashes"]) == {"trajectory", "controller", "feedforward", "dataset"}
    for (setting, kind), r in runs.items():
        if kind != "paper":
            continue
        assert r["hashes"] == first["hashes"], (setting, r["hashes"], first["hashes"])
        for key in ("lower", "upper", "uncertain", "serial"):
            assert r[key] == first[key], (setting, key)


def test_the_h4_certified_equation_is_the_same_bits_under_every_dispatch(runs):
    first = runs[((), "h4")]
    for (setting, kind), r in runs.items():
        if kind == "h4":
            assert r == first, setting


def test_the_portable_functions_track_numpys_within_a_few_ulp():
    """The oracle here is numpy's own (within 4 ulp of the true values by its documentation); the portable ones are
    compared at random and at special arguments."""
    from h4bench import portable  # noqa: PLC0415

    rng = np.random.default_rng(11)

    def ulps(a, b):
        return float(np.max(np.abs(a - b) / np.spacing(np.maximum(np.abs(b), 1e-300))))

    x = np.concatenate([rng.uniform(-1, 1, 50000), rng.normal(size=2000) * 1e3, [0.0, 1.0, -1.0, 1e-300]])
    y = rng.normal(size=x.size) * np.exp(rng.uniform(-5, 5, x.size))
    assert ulps(portable.atan2(y, x), np.arctan2(y, x)) <= 4
    assert np.array_equal(portable.atan2([0.0, -0.0, 0.0, -0.0, 1.0, -1.0], [0.0, 0.0, -0.0, -0.0, 0.0, 0.0]),
                          np.arctan2([0.0, -0.0, 0.0, -0.0, 1.0, -1.0], [0.0, 0.0, -0.0, -0.0, 0.0, 0.0]))
    u = np.concatenate([rng.uniform(-1, 1, 50000), [-1.0, 0.0, 1.0]])
    assert ulps(portable.arccos(u), np.arccos(u)) <= 4
    assert ulps(portable.arcsin(u[np.abs(u) > 1e-3]), np.arcsin(u[np.abs(u) > 1e-3])) <= 4
    z = np.concatenate([rng.uniform(-700, 700, 50000), rng.uniform(-1, 1, 50000)])
    assert ulps(portable.exp(z), np.exp(z)) <= 4
    assert np.array_equal(portable.exp([np.inf, -np.inf, 0.0, 800.0, -800.0]), [np.inf, 0.0, 1.0, np.inf, 0.0])
    w = np.exp(rng.uniform(-700, 700, 50000))
    assert ulps(portable.log(w), np.log(w)) <= 4
    assert np.array_equal(portable.log([0.0, 1.0, np.inf]), [-np.inf, 0.0, np.inf]) and np.isnan(portable.log(-1.0))
    t = rng.uniform(-30, 30, 50000)
    assert np.max(np.abs(portable.tanh(t) - np.tanh(t))) <= 4 * 2.0**-53
    v = np.exp(rng.uniform(-60, 60, 50000))
    assert np.array_equal(portable.nearest_power_of_two(v), np.rint(np.log2(v)).astype(np.int64))


def test_smallest_and_largest_break_ties_by_index():
    from h4bench import portable  # noqa: PLC0415

    x = np.array([3.0, 1.0, 2.0, 1.0, 3.0, 1.0])
    assert portable.smallest(x, 2).tolist() == [1, 3]
    assert portable.largest(x, 3).tolist() == [0, 4, 2]
    assert portable.smallest(x, 10).tolist() == [1, 3, 5, 2, 0, 4]
    assert portable.largest(x, 0).size == 0
