"""The interval jets' arithmetic (:class:`ident.numerics.jets.MR` and :func:`ident.numerics.jets.ein`) in one
pass per operation: fused numpy ufuncs from ``ident/numerics/_mr.cpp`` when the extension is built, the numpy
formulas otherwise. Both give the same bits (the compiled loops evaluate the numpy formulas operation for operation
on IEEE doubles, without fused multiply-add; ``tests/ident/test_fused_mr.py``), so a result does not depend on
whether the extension was built: only the speed does. ``H4BENCH_PURE_PYTHON=1`` in the environment (read at the
first operation of a process) forces the numpy formulas, as it forces the simulator's Python loop.

The contractions sum their terms in index order, k = 0 .. n - 1, in both paths (:func:`contract`); numpy's einsum
is not used for them, so its choice of summation order (which may follow the CPU) cannot reach a result.
"""

from __future__ import annotations

import functools
import os

import numpy as np

from h4bench.ident.numerics.interval import U

__all__ = ["ONE", "TINY", "contract", "contraction_views", "extension"]

LAYOUT_VERSION = 2
ONE = 1.0 + 16 * U  # covers the rounding of a radius formula of up to 6 nonnegative operations
TINY = 1e-300  # an absolute allowance for underflow in every radius


@functools.cache
def extension():
    """The built ``_mr`` extension, or None (not built, another layout, other constants, or
    ``H4BENCH_PURE_PYTHON`` set)."""
    if os.environ.get("H4BENCH_PURE_PYTHON"):
        return None
    try:
        from h4bench.ident.numerics import _mr  # noqa: PLC0415
    except ImportError:
        return None
    if (_mr.LAYOUT_VERSION, _mr.U, _mr.ONE, _mr.TINY) != (LAYOUT_VERSION, U, ONE, TINY):
        return None
    return _mr


@functools.lru_cache(maxsize=None)
def _plan(spec: str, nda: int, ndb: int):
    """For ``einsum(spec, a, b)`` with a.ndim = nda, b.ndim = ndb: per operand the axis permutation, the size-1
    axes to insert, and the number of contracted axes (moved last, to be merged into one)."""
    ins, out = spec.split("->")
    sa, sb = ins.split(",")
    la, lb, lo = (s.replace("...", "") for s in (sa, sb, out))
    for s, letters in ((sa, la), (sb, lb), (out, lo)):
        bad_ellipsis = s.count("...") > 1 or ("..." in s and not s.startswith("..."))
        if len(set(letters)) != len(letters) or (letters and not letters.isalpha()) or bad_ellipsis:
            raise ValueError(f"ein: unsupported spec {spec!r} (a leading '...' and distinct letters only)")
    contracted = [x for x in la if x not in lo]
    if sorted(contracted) != sorted(x for x in lb if x not in lo) or any(x not in la + lb for x in lo):
        raise ValueError(f"ein: spec {spec!r} must contract letters present in both operands only")

    def one(letters: str, nd: int):
        lead = nd - len(letters)
        if lead < 0:
            raise ValueError(f"ein: spec {spec!r} names more axes than an operand's {nd}")
        perm = (tuple(range(lead)) + tuple(lead + letters.index(x) for x in lo if x in letters)
                + tuple(lead + letters.index(x) for x in contracted))
        expand = tuple(lead + i for i, x in enumerate(lo) if x not in letters)
        return perm, expand

    return one(la, nda), one(lb, ndb), len(contracted)


def contraction_views(spec: str, a_parts: list, b_parts: list):
    """Views of the operands' arrays (each of a_parts the shape of a, of b_parts the shape of b) with the output's
    axes first (size 1 where the operand lacks one) and the contracted axes merged into one last axis (size 1 if
    nothing is contracted), so that the contraction is a sum over the last axis of their broadcast products."""
    (pa, ea), (pb, eb), nc = _plan(spec, a_parts[0].ndim, b_parts[0].ndim)

    def view(x, perm, expand):
        x = np.expand_dims(np.transpose(x, perm), expand) if expand else np.transpose(x, perm)
        if nc == 0:
            return x[..., None]
        return x if nc == 1 else x.reshape(x.shape[:x.ndim - nc] + (-1,))

    return [view(x, pa, ea) for x in a_parts], [view(x, pb, eb) for x in b_parts]


def contract(a: tuple, b: tuple, g: float, taylor: bool):
    """The enclosed sums over the last axis (views from :func:`contraction_views`), in index order.

    Plain (``taylor`` False): a = (ac, ar), b = (bc, br); returns (c, r) with ``c = sum ac bc`` and
    ``r = (sum |ac| (br + g |bc|) + sum ar (|bc| + br)) (1 + 3 g) + 1e-300``.
    Taylor models: a = (ac, aa, ar), b = (bc, ba, br); returns (c, lin, r) with ``c = sum ac bc + sum aa ba / 2``,
    ``lin = sum ac ba + sum aa bc`` and ``r = (sum m1 (br + 2 g m2) + sum ar (m2 + br) + sum |aa| |ba| / 2)
    (1 + 4 g) + 1e-300`` (m1 = |ac| + |aa|, m2 = |bc| + |ba|). g: the rounding factor of n-term sums
    (:func:`ident.numerics.jets.ein`). Each operand's own factors (``|ac|``, ``br + g |bc|``, m1, ...) are formed
    once, before the sums, by the same expressions in both paths."""
    g = np.float64(g)
    if not taylor:
        (ac, ar), (bc, br) = a, b
        abc = np.abs(bc)
        parts = (ac, np.abs(ac), ar), (bc, br + g * abc, abc + br)
    else:
        (ac, aa, ar), (bc, ba, br) = a, b
        absaa, absba = np.abs(aa), np.abs(ba)
        m2 = np.abs(bc) + absba
        parts = (ac, aa, ar, np.abs(ac) + absaa, absaa), (bc, ba, br + 2 * g * m2, m2 + br, absba)
    ext = extension()
    if ext is not None:
        return (ext.contract_tm if taylor else ext.contract_plain)(*parts[0], *parts[1], g)
    return _contract_numpy(parts[0], parts[1], g, taylor)


def _contract_numpy(a, b, g, taylor):
    n = np.broadcast_shapes(*(x.shape[-1:] for x in a + b))[0]
    if not taylor:
        for j in range(n):
            (x, xa, xr), (y, p1, p2) = ([m[..., j] for m in a], [m[..., j] for m in b])
            t, t1, t2 = x * y, xa * p1, xr * p2
            c, r1, r2 = (t, t1, t2) if j == 0 else (c + t, r1 + t1, r2 + t2)
        return c, (r1 + r2) * (1.0 + 3 * g) + TINY
    for j in range(n):
        (x, xa, xr, m1, axa), (y, ya, q1, q2, aya) = ([m[..., j] for m in a], [m[..., j] for m in b])
        terms = (x * y, xa * ya, x * ya, xa * y, m1 * q1, xr * q2, axa * aya)
        sums = terms if j == 0 else tuple(s + t for s, t in zip(sums, terms))
    cc, aa2, l1, l2, r1, r2, r3 = sums
    return cc + 0.5 * aa2, l1 + l2, ((r1 + r2) + 0.5 * r3) * (1.0 + 4 * g) + TINY
