"""The interval jets' fused arithmetic (ident/numerics/_mr.cpp through ident.numerics.fused) against its oracle, the
numpy formulas: the same bits for every operation of MR and for ein, on broadcast, strided and special operands,
and for the H4's interval jets end to end; ein's index-order sums against exact rationals (every point of the
operands' intervals, every tau of a Taylor model) and the spec forms it accepts and refuses."""

from __future__ import annotations

import shutil
import sys
from fractions import Fraction

import numpy as np
import pytest

from h4bench.ident.numerics import fused, jets
from h4bench.ident.numerics.jets import MR, ein

needs_mr = pytest.mark.skipif(fused.extension() is None, reason="the fused ufuncs are not built here")


@pytest.fixture
def pure(monkeypatch):
    """A function running ``f()`` with the numpy formulas (the extension switched off)."""

    def run(f):
        with monkeypatch.context() as m:
            m.setattr(jets, "extension", lambda: None)
            m.setattr(fused, "extension", lambda: None)
            return f()

    return run


def _bits(m: MR):
    parts = [np.ascontiguousarray(m.c), np.ascontiguousarray(np.broadcast_to(m.r, m.c.shape))]
    parts.append(b"" if m.a is None else np.ascontiguousarray(np.broadcast_to(m.a, m.c.shape)).tobytes())
    return [p if isinstance(p, bytes) else p.tobytes() for p in parts], m.c.shape


def _operand(rng, shape, taylor, radius=True, special=False):
    c = rng.normal(size=shape) * 10.0 ** rng.integers(-6, 6, size=shape)
    if special:  # zeros of both signs, exact integers, tiny and huge magnitudes
        flat = c.reshape(-1)
        picks = rng.integers(0, flat.size, size=max(1, flat.size // 3))
        flat[picks] = rng.choice([0.0, -0.0, 1.0, -3.0, 1e-300, -1e100, 2.0**-1060], size=picks.size)
    r = rng.uniform(0, 1e-3, size=shape) * np.abs(c) if radius else None
    a = rng.normal(size=shape) * 1e-2 if taylor else None
    return MR(c, r, a)


_SHAPES = [((6, 4, 3), (6, 4, 3)), ((6, 4, 3), (4, 3)), ((6, 1, 3), (1, 5, 3)), ((3,), (7, 2, 3)), ((), (4, 2))]


@needs_mr
@pytest.mark.parametrize("special", [False, True])
def test_every_elementwise_operation_gives_the_numpy_formulas_bits(pure, special):
    rng = np.random.default_rng(11)
    cases = 0
    for sa, sb in _SHAPES:
        for ta in (False, True):
            for tb in (False, True):
                for rb in (True, False):  # a constant (no radius, not a Taylor model) takes its own formula
                    a = _operand(rng, sa, ta, special=special)
                    b = _operand(rng, sb, tb, radius=rb, special=special)
                    for name, op in (("+", lambda: a + b), ("*", lambda: a * b), ("r*", lambda: b * a),
                                     ("-", lambda: a - b)):
                        assert _bits(op()) == _bits(pure(op)), (name, sa, sb, ta, tb, rb)
                        cases += 1
    # strided operands (transposed views): the loops' general path
    a, b = _operand(rng, (5, 7), True), _operand(rng, (7, 5), True)
    t = MR(a.c.T, a.r.T, a.a.T)
    assert _bits(t * b) == _bits(pure(lambda: t * b)) and _bits(t + b) == _bits(pure(lambda: t + b))
    assert cases == 4 * len(_SHAPES) * 8


_SPECS = [("...ij,...jk->...ik", (3, 4, 4), (3, 4, 4)), ("...ik,...ik->...i", (5, 4, 3), (5, 4, 3)),
          ("...ijY,...jkZ->...ikYZ", (2, 4, 4, 3), (2, 4, 4, 2)), ("...ai,a->...i", (6, 3, 4), (3,)),
          ("...ik,ik->...i", (6, 4, 3), (4, 3)), ("...ij,...j->...i", (4, 4), (2, 3, 4)),
          ("...iY,...Z->...iYZ", (3, 2, 4), (3, 5)), ("...ijk,...jk->...i", (2, 3, 4, 5), (2, 4, 5))]


@needs_mr
@pytest.mark.parametrize("spec, sa, sb", _SPECS)
def test_ein_gives_the_numpy_formulas_bits(pure, spec, sa, sb):
    rng = np.random.default_rng(12)
    for ta, tb in ((False, False), (True, False), (False, True), (True, True)):
        a, b = _operand(rng, sa, ta, special=True), _operand(rng, sb, tb)
        assert _bits(ein(spec, a, b)) == _bits(pure(lambda: ein(spec, a, b))), (ta, tb)


def _exact_einsum(spec, a, b):
    """einsum in exact rationals over object arrays of Fractions (numpy's einsum on objects sums exactly)."""
    fa = np.vectorize(Fraction, otypes=[object])(a)
    fb = np.vectorize(Fraction, otypes=[object])(b)
    return np.einsum(spec, fa, fb)


@pytest.mark.parametrize("spec, sa, sb", _SPECS)
def test_ein_encloses_the_exact_sums_at_every_point_and_tau(spec, sa, sb):
    """The enclosure holds for sampled points of both operands' intervals and of tau, in exact arithmetic; the
    midpoint is numpy's einsum to rounding (the same sum in another order)."""
    rng = np.random.default_rng(13)
    a, b = _operand(rng, sa, True), _operand(rng, sb, False)
    out = ein(spec, a, b)
    scale = np.einsum(spec, np.abs(a.c) + np.abs(a.a), np.abs(b.c))
    assert np.all(np.abs(out.c + 0.0 - np.einsum(spec, a.c, b.c)) <= 1e-14 * scale + 1e-300)
    lo_hi = []
    for tau in (-1.0, -0.25, 1.0):
        mid = out.c + out.a * tau
        lo_hi.append((tau, mid, out.r))
        for _ in range(3):
            pa = a.c + a.a * tau + rng.uniform(-1, 1, sa) * a.r
            pb = b.c + rng.uniform(-1, 1, sb) * b.r
            exact = _exact_einsum(spec, pa, pb)
            # |exact - (c + lin tau)| <= r, in rationals (c + lin tau itself is not a float)
            diff = np.vectorize(lambda e, c, l, t=tau: abs(e - Fraction(c) - Fraction(l) * Fraction(t)),
                                otypes=[object])(exact, out.c, out.a)
            assert np.all(np.vectorize(lambda d, r: d <= Fraction(r), otypes=[bool])(diff, out.r))


def test_ein_refuses_specs_it_cannot_contract_in_index_order():
    a = MR(np.ones((2, 3)))
    for spec in ("...ij,...kl->...i", "ij,jk->...ik...", "...ii,...i->...i"):
        with pytest.raises(ValueError, match="ein"):
            ein(spec, a, a)


@needs_mr
def test_the_h4_interval_jets_give_the_same_bits_with_and_without_the_extension(pure, geometry):
    """box_jets end to end (Krawczyk, the split inverse, the split jets; plain boxes and Taylor models)."""
    from h4bench.ident.robots.h4_jets import box_jets
    from h4bench.sim.kinematics import forward_kinematics
    from tests.ident.test_jets import _poses

    q, v = _poses(geometry, 12, 14)
    pose = forward_kinematics(geometry, q)
    for Q in (MR(q, np.full(q.shape, 2e-4)), MR(q, np.full(q.shape, 2e-4), v * 5e-4)):
        V = MR(v, np.full(v.shape, 0.5))
        fast = box_jets(geometry, Q, V, pose, chunk=5)
        slow = pure(lambda Q=Q, V=V: box_jets(geometry, Q, V, pose, chunk=5))
        assert fast[4].all()
        for f, s in zip(fast, slow):
            np.testing.assert_array_equal(f, s)
            assert f.tobytes() == s.tobytes()


@pytest.mark.skipif(shutil.which("c++") is None or not sys.platform.startswith("linux"), reason="no C++ compiler")
def test_the_fused_ufuncs_are_built_where_a_compiler_is(monkeypatch):
    """An install on a machine with a C++ compiler builds the extension (its build is optional: a failure would
    otherwise pass unseen, every certified run then taking the slower numpy formulas)."""
    monkeypatch.delenv("H4BENCH_PURE_PYTHON", raising=False)
    fused.extension.cache_clear()
    try:
        assert fused.extension() is not None, "h4bench.ident.numerics._mr was not built: see the install's output"
    finally:
        fused.extension.cache_clear()
