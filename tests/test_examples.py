"""The examples run: ``examples/python_api.py`` (the Python API, cell by cell) and ``examples/own_arm/run.py`` (a
UR5 log certified under a specification written from data sheets), on short inputs; the full-length arm is slow.

Oracles: the simulated truth (the H4's true parameters; the arm's true base parameters from pinocchio's inertias),
which the examples read only to count what their boxes enclose.
"""

from __future__ import annotations

import importlib.util
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(f"example_{path.stem}", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_python_api_example(tmp_path):
    from h4bench import ident, sim

    assert tuple(sim.TRUE_PARAMETER_ORDER) == tuple(ident.PARAMETER_NAMES)  # the example compares them by index
    out = _load(ROOT / "examples" / "python_api.py").main(["--seconds", "3", "--out", str(tmp_path)])
    assert out["enclosed"] == out["parameters"] == 14
    assert out["polygon_vertices"] >= 3
    assert (tmp_path / "projection.png").stat().st_size > 1000


def test_the_arm_spec_is_the_logs_truth():
    """The hand-written spec.toml states what the simulated log's generator guarantees: its encoder, its torque
    error bound, and motion / torque-rate bounds at least the generator's own (analytic motion bounds; the rate
    from a fine sampling of the smooth torque, which arm_log reports with a margin of 1.5)."""
    pytest.importorskip("pinocchio")
    run = _load(ROOT / "examples" / "own_arm" / "run.py")
    urdf = run.ur5_urdf()
    import numpy as np

    from h4bench.ident.robots.serial import SerialRobot
    from h4bench.scenarios.arm_log import arm_log

    em = tomllib.loads((ROOT / "examples" / "own_arm" / "spec.toml").read_text())["error_model"]
    for seconds in (2.5, 12.0):
        log = arm_log(SerialRobot(urdf), seconds=seconds, counts=2**17, torque_error=0.8, speed=1.5, seed=0)
        assert em["counts_per_turn"] == log.counts and em["sample_period"] == log.dt
        assert em["torque_error"] >= log.torque_error
        assert np.all(np.asarray(em["torque_rate"]) >= log.torque_rate)
        assert np.all(em["qd_max"] >= log.qd_max - 1e-12) and np.all(em["qdd_max"] >= log.qdd_max)


def _own_arm(tmp_path, seconds: float) -> dict:
    pytest.importorskip("pinocchio")
    run = _load(ROOT / "examples" / "own_arm" / "run.py")
    return run.main(["--seconds", str(seconds), "--out", str(tmp_path)])


def test_own_arm_example_short_log(tmp_path):
    """A 2.5 s log: the certified box holds every true base parameter and the stated bounds are not contradicted;
    the box is wide (most widths near the prior's), as docs/own-arm.md says for a short log."""
    read = _own_arm(tmp_path, 2.5)
    assert read["status"] == "ok" and read["contradicted"] == []
    assert read["enclosed"] == read["base_parameters"]
    assert 0 < read["width_over_prior_median"] <= 1.0
    assert read["dominant"] in read["shares"]


@pytest.mark.slow
def test_own_arm_example_full_log(tmp_path):
    """The example's default 12 s log: every true base parameter enclosed, narrower than the short log's box."""
    read = _own_arm(tmp_path, 12.0)
    assert read["status"] == "ok" and read["contradicted"] == []
    assert read["enclosed"] == read["base_parameters"]
    assert read["narrowed"] > 0
