"""ident.processing.errorspec: the error specification's checks and the per-sample position error bound."""

from __future__ import annotations

import numpy as np
import pytest

from h4bench.ident.processing.errorspec import ErrorSpec, ErrorSpecError


def _spec(**kw):
    base = dict(n_joints=4, sample_period=1e-3, torque_error=1.3, qd_max=15.0, qdd_max=600.0,
                position_resolution=2 * np.pi / 20000)
    base.update(kw)
    return ErrorSpec(**base)


def test_scalars_are_broadcast_per_joint_and_round_trip_through_a_table():
    spec = _spec(sources={"torque_error": "drive data sheet"})
    assert spec.torque_error.shape == (4,) and np.all(spec.qdd_max == 600.0)
    again = ErrorSpec.from_mapping({k: v for k, v in spec.to_dict().items() if k not in ("n_joints",)
                                    and v is not None}, 4)
    assert again.to_dict() == spec.to_dict()


def test_counts_per_turn_give_the_resolution(tmp_path):
    f = tmp_path / "spec.toml"
    f.write_text("[error_model]\nsample_period = 0.001\ncounts_per_turn = 20000\ntorque_error = [1, 1, 1, 2]\n"
                 "qd_max = 15\nqdd_max = 600\n[error_model.sources]\ntorque_error = 'assumed'\n")
    spec = ErrorSpec.from_toml(f, 4)
    assert spec.position_resolution == pytest.approx(np.full(4, 2 * np.pi / 20000), rel=1e-15)
    assert spec.torque_error.tolist() == [1, 1, 1, 2] and spec.sources == {"torque_error": "assumed"}
    q = np.random.default_rng(0).uniform(-3, 3, (50, 4))
    assert np.all(spec.position_error(q) == np.pi / 20000)


@pytest.mark.parametrize(("kw", "match"), [
    ({"torque_error": [1, 2]}, r"torque_error must be a scalar or have shape \(4,\), got \(2,\)"),
    ({"qd_max": -1.0}, "qd_max must be > 0, got"),
    ({"sample_period": 0.0}, "sample_period must be a finite number > 0"),
    ({"significant_digits": 5}, "exactly one of position_resolution"),
    ({"latency": 1e-3}, "needs torque_rate"),
    ({"torque_timing": "late"}, "torque_timing must be one of"),
    ({"sources": {"nope": "x"}}, "unknown entries"),
])
def test_bad_entries_are_named(kw, match):
    with pytest.raises(ErrorSpecError, match=match):
        _spec(**kw)


def test_a_table_with_unknown_or_missing_keys_is_refused():
    with pytest.raises(ErrorSpecError, match="unknown keys"):
        ErrorSpec.from_mapping({"sample_period": 1e-3, "allowance": 0.2}, 4)
    with pytest.raises(ErrorSpecError, match="missing"):
        ErrorSpec.from_mapping({"sample_period": 1e-3}, 4)


def test_significant_digits_bound_covers_the_written_values():
    """Oracle: Python's own formatting with 5 significant digits, read back; the bound holds for every value,
    decade boundaries and values rounded up into the next decade included."""
    rng = np.random.default_rng(1)
    true = np.concatenate([rng.uniform(-4, 4, (400, 2)), 10.0 ** rng.uniform(-6, 1, (400, 2)),
                           np.array([[0.999996, 9.99996], [-0.0999996, 1e-5]])])
    written = np.vectorize(lambda v: float(f"{v:.5g}"))(true)
    spec = ErrorSpec(n_joints=2, sample_period=2e-4, torque_error=1.0, qd_max=1.0, qdd_max=1.0,
                     significant_digits=5)
    bound = spec.position_error(written)
    assert np.all(np.abs(written - true) <= bound)
    assert np.max(np.abs(written - true) / bound) > 0.9  # not loose: some values use most of their half unit


def test_a_value_that_is_not_a_number_is_an_error_spec_error():
    with pytest.raises(ErrorSpecError, match=r"qdd_max must be a number or an array of shape \(4,\), got str"):
        _spec(qdd_max="fast")
    with pytest.raises(ErrorSpecError, match="latency must be a real number, got str"):
        _spec(latency="1 ms")


def test_significant_digits_decades_and_half_units_are_exact_at_every_power_of_ten():
    """Every exact power of ten written, and the largest 5-digit value below each, gets its own decade's half unit:
    at least the exact half unit (rational arithmetic), at most one ulp above it, whatever numpy's log10 and power
    round to on this CPU."""
    from fractions import Fraction

    exps = np.arange(-290, 291)
    at = np.array([float(f"1e{e}") for e in exps])
    below = np.array([float(f"9.9999e{e - 1}") for e in exps])
    spec = ErrorSpec(n_joints=2, sample_period=2e-4, torque_error=1.0, qd_max=1.0, qdd_max=1.0,
                     significant_digits=5)
    bound = spec.position_error(np.stack([at, below], axis=1))
    for k, e in enumerate(exps):
        for col, decade in ((0, int(e)), (1, int(e) - 1)):
            half = Fraction(1, 2) * Fraction(10) ** (decade - 4)
            got = float(bound[k, col])
            assert Fraction(got) >= half, (e, col)
            assert got <= np.nextafter(np.nextafter(float(half), np.inf), np.inf), (e, col)
