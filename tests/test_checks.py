"""h4bench.checks: the argument checks sim and ident share (messages name the argument, expected and actual)."""

from __future__ import annotations

import numpy as np
import pytest

from h4bench.checks import per_joint, vector


def test_vector_and_per_joint_convert_and_broadcast():
    assert vector([1, 2, 3], "v", 3).dtype == float
    assert per_joint(2, "k", 6).tolist() == [2.0] * 6
    assert per_joint([0, 1], "k", 2, allow_zero=True).tolist() == [0.0, 1.0]


@pytest.mark.parametrize(("call", "error", "match"), [
    (lambda: vector(1.0, "v", 3), ValueError, r"v must have shape \(3,\), got \(\)"),
    (lambda: vector("abc", "v", 3), TypeError, r"v must be an array of shape \(3,\), got str"),
    (lambda: vector([1, np.nan, 2], "v", 3), ValueError, "v must be finite"),
    (lambda: per_joint([1, 2], "k", 4), ValueError, r"k must be a scalar or have shape \(4,\), got \(2,\)"),
    (lambda: per_joint(None, "k", 4), TypeError, r"k must be a number or an array of shape \(4,\), got NoneType"),
    (lambda: per_joint([1, 0], "k", 2), ValueError, "k must be > 0"),
    (lambda: per_joint([1, -1], "k", 2, allow_zero=True), ValueError, "k must be >= 0"),
])
def test_bad_values_are_named(call, error, match):
    with pytest.raises(error, match=match):
        call()
