"""Rigorous second-order automatic differentiation over boxes: interval jets in midpoint-radius form.

A :class:`Jet` of order ``k`` (0, 1 or 2) holds, for a function ``f`` of ``n`` variables ``z`` and a box ``Z``,
enclosures of ``f(z)`` (``v``), of its gradient (``g``, trailing axis n) and of its Hessian (``h``, trailing
axes n, n) that hold for EVERY ``z`` in ``Z``: forward-mode differentiation whose every operation is evaluated
in interval arithmetic encloses the pointwise chain rule, because each pointwise value lies in the operand's
interval. Arrays carry leading axes of their own (samples, vectors, matrices); the derivative axes are last.

Intervals are stored as midpoint and radius (:class:`MR`): ``<c, r> = [c - r, c + r]``. Every operation
computes the midpoint in floating point and a radius that covers (a) the operands' radii (the midpoint-radius
product of Rump, BIT 39 (1999): ``|a c| rb + ra (|bc| + rb)``), (b) the rounding error of the midpoint (``u |c|``
for one operation; ``gamma_n |a|^T |b|`` for an ``n``-term sum in any order, Higham sec. 3.1) and (c) the rounding
of the radius formula itself (a relative factor ``1 + (k + 2) 2u`` for ``k`` nonnegative operations, and an
absolute ``1e-300`` for underflow). The elementary functions ``sin`` and ``cos`` use numpy's, taken to be within
:data:`LIBM_ULPS` units in the last place (glibc's and numpy's SIMD double-precision sin/cos are documented within
4 ulp), and their Lipschitz constant 1.

The interval inverse of a matrix uses the preconditioned Neumann bound: with ``C ~ mid(M)^-1`` and
``E = I - C M``, ``||E||_inf <= beta < 1`` gives ``M^-1 = (I + E + R) C`` with ``|R_ij| <= beta^2 / (1 - beta)``
for every ``M`` in the interval matrix (the error of the floating-point ``C`` only enters through ``E``).
"""

from __future__ import annotations

import numpy as np

from h4bench.ident.numerics.fused import ONE, TINY, contract, contraction_views, extension
from h4bench.ident.numerics.interval import U, up

__all__ = ["LIBM_ULPS", "MR", "Jet", "SingularIntervalMatrix", "inverse"]

LIBM_ULPS = 4  # stated accuracy of numpy's float64 sin / cos [ulp]
_TINY = TINY
_ONE = ONE  # covers the rounding of a radius formula of up to 6 nonnegative operations


class SingularIntervalMatrix(ArithmeticError):
    """An interval matrix could not be proven regular (the preconditioned Neumann bound is >= 1)."""


def _gamma(n: int) -> float:
    return 2.0 * (n + 2) * U


class MR:
    """An interval array in midpoint-radius form, ``c +- r`` (``r >= 0``), optionally with a linear part in one
    shared symbol ``tau`` in [-1, 1]: ``c + a tau +- r`` (a first-order Taylor model: for every value of tau the
    quantity lies in ``[c + a tau - r, c + a tau + r]``). ``a`` is None for a plain interval. Operations on Taylor
    models keep the part linear in tau and bound the rest (``tau^2 = 1/2 + (tau^2 - 1/2)``, the second term in
    [-1/2, 1/2]; ``sin``/``cos`` by their second-order Taylor remainder), so a quantity that varies along tau
    (e.g. along one sample step's motion) is not widened by the dependency along it."""

    __slots__ = ("c", "a", "r")

    def __init__(self, c, r=None, a=None):
        self.c = np.asarray(c, dtype=float)
        self.r = np.zeros_like(self.c) if r is None else np.asarray(r, dtype=float)
        self.a = None if a is None else np.asarray(a, dtype=float)

    @classmethod
    def from_bounds(cls, lo, hi) -> MR:
        lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
        c = 0.5 * (lo + hi)
        return cls(c, up(np.maximum(hi - c, c - lo)))

    @staticmethod
    def stack(parts: list, axis: int = -1) -> MR:
        a = None
        if any(p.a is not None for p in parts):
            a = np.stack([np.zeros_like(p.c) if p.a is None else p.a for p in parts], axis=axis)
        return MR(np.stack([p.c for p in parts], axis=axis), np.stack([p.r for p in parts], axis=axis), a)

    @classmethod
    def zeros(cls, shape, like: MR | None = None) -> MR:
        """Exact zeros of ``shape``, a Taylor model if ``like`` is one."""
        return cls(np.zeros(shape), None, None if like is None or like.a is None else np.zeros(shape))

    def set(self, key, other: MR) -> None:
        """``self[key] = other`` in place (self must be a Taylor model if other is one)."""
        self.c[key], self.r[key] = other.c, other.r
        if other.a is not None:
            self.a[key] = other.a

    @property
    def shape(self) -> tuple:
        return self.c.shape

    def _spread(self) -> np.ndarray:
        """An upper bound of the distance from c to any value (``|a| + r``, before rounding)."""
        return self.r if self.a is None else np.abs(self.a) + self.r

    @property
    def lo(self) -> np.ndarray:
        return self.c - up(self._spread() * _ONE + U * np.abs(self.c) * 2 + _TINY)

    @property
    def hi(self) -> np.ndarray:
        return self.c + up(self._spread() * _ONE + U * np.abs(self.c) * 2 + _TINY)

    def mag(self) -> np.ndarray:
        """An upper bound of ``|x|`` over the interval (over every tau for a Taylor model)."""
        return up(up(np.abs(self.c) + self._spread()) * _ONE)

    def __getitem__(self, key) -> MR:
        return MR(self.c[key], self.r[key], None if self.a is None else self.a[key])

    def untied(self) -> MR:
        """The same enclosure without the tau-dependence: its range over every tau, ``c +- (|a| + r)``."""
        if self.a is None:
            return self
        return MR(self.c, (np.abs(self.a) + self.r) * _ONE + _TINY)

    def swap(self) -> MR:
        """The transpose of the last two axes."""
        return MR(np.swapaxes(self.c, -1, -2), np.swapaxes(self.r, -1, -2),
                  None if self.a is None else np.swapaxes(self.a, -1, -2))

    def __neg__(self) -> MR:
        return MR(-self.c, self.r, None if self.a is None else -self.a)

    def __add__(self, other) -> MR:
        o = _mr(other)
        ext = extension()
        if ext is not None:  # the same formulas in one pass (ident.numerics.fused)
            if self.a is None and o.a is None:
                return MR(*ext.add_plain(self.c, self.r, o.c, o.r))
            if self.a is not None and o.a is not None:
                c, a, r = ext.add_tm(self.c, self.a, self.r, o.c, o.a, o.r)
                return MR(c, r, a)
            a = _plus(self.a, o.a)
            return MR(*ext.add_tm1(self.c, self.r, o.c, o.r, a), a)
        c = self.c + o.c
        if self.a is None and o.a is None:
            return MR(c, (self.r + o.r + U * np.abs(c)) * _ONE + _TINY)
        a = _plus(self.a, o.a)
        return MR(c, (self.r + o.r + U * (np.abs(c) + np.abs(a))) * _ONE + _TINY, a)

    __radd__ = __add__

    def __sub__(self, other) -> MR:
        return self + (-_mr(other))

    def __rsub__(self, other) -> MR:
        return _mr(other) + (-self)

    def __mul__(self, other) -> MR:
        o = _mr(other)
        ext = extension()
        if ext is not None:  # the same formulas in one pass (ident.numerics.fused)
            return _fused_mul(ext, self, o)
        if o.a is None and not np.any(o.r):  # times an exact array (a constant): no radius of its own
            c = self.c * o.c
            a = None if self.a is None else self.a * o.c
            err = np.abs(c) if a is None else np.abs(c) + np.abs(a)
            return MR(c, (self.r * np.abs(o.c) + U * err) * _ONE + _TINY, a)
        if self.a is None and o.a is None:
            c = self.c * o.c
            r = np.abs(self.c) * o.r + self.r * (np.abs(o.c) + o.r) + U * np.abs(c)
            return MR(c, r * _ONE + _TINY)
        m1 = np.abs(self.c) if self.a is None else np.abs(self.c) + np.abs(self.a)
        m2 = np.abs(o.c) if o.a is None else np.abs(o.c) + np.abs(o.a)
        c = self.c * o.c
        if self.a is not None and o.a is not None:
            aa = self.a * o.a  # the tau^2 part: 1/2 into c, +-1/2 into r
            c = c + 0.5 * aa
            a = self.c * o.a + self.a * o.c
            extra = 0.5 * np.abs(aa)
        else:
            a = self.c * o.a if self.a is None else self.a * o.c
            extra = 0.0
        r = m1 * o.r + self.r * (m2 + o.r) + extra + 4 * U * m1 * m2
        return MR(c, r * _ONE + _TINY, a)

    __rmul__ = __mul__

    def _trig(self, f, df, sign) -> MR:
        c = f(self.c)
        err = 2 * LIBM_ULPS * U * np.abs(c)
        if self.a is None:  # Lipschitz 1
            return MR(c, (self.r + err) * _ONE + _TINY)
        d = df(self.c) * sign
        a = d * self.a
        # f(c + delta) = f(c) + f'(c) delta + R, |R| <= delta^2 / 2 with |delta| <= |a| + r
        spread = np.abs(self.a) + self.r
        r = np.abs(d) * self.r + 0.5 * spread * spread + err + 2 * LIBM_ULPS * U * np.abs(a) + U * np.abs(a)
        return MR(c, r * _ONE + _TINY, a)

    def sin(self) -> MR:
        return self._trig(np.sin, np.cos, 1.0)

    def cos(self) -> MR:
        return self._trig(np.cos, np.sin, -1.0)

    def contains(self, x) -> np.ndarray:
        return (self.lo <= x) & (x <= self.hi)


def _fused_mul(ext, x: MR, o: MR) -> MR:
    """:meth:`MR.__mul__` by the fused ufuncs (the same cases, formulas and bits)."""
    if o.a is None and not np.any(o.r):
        if x.a is None:
            return MR(*ext.mul_const(x.c, x.r, o.c))
        c, a, r = ext.mul_const_tm(x.c, x.a, x.r, o.c)
    elif x.a is None and o.a is None:
        return MR(*ext.mul_plain(x.c, x.r, o.c, o.r))
    elif x.a is not None and o.a is not None:
        c, a, r = ext.mul_tm(x.c, x.a, x.r, o.c, o.a, o.r)
    elif o.a is None:
        c, a, r = ext.mul_tm_left(x.c, x.a, x.r, o.c, o.r)
    else:
        c, a, r = ext.mul_tm_right(x.c, x.r, o.c, o.a, o.r)
    return MR(c, r, a)


def _plus(a, b):
    if a is None:
        return b
    return a if b is None else a + b


def _mr(x) -> MR:
    return x if isinstance(x, MR) else MR(x)


def _terms(spec: str, a_shape: tuple, b_shape: tuple) -> int:
    """The number of terms each output element of ``einsum(spec, a, b)`` sums (contracted index sizes)."""
    ins, out = spec.split("->")
    sa, sb = ins.split(",")
    sizes = {}
    for s, shape in ((sa, a_shape), (sb, b_shape)):
        letters = s.replace("...", "")
        for letter, size in zip(letters, shape[len(shape) - len(letters):]):
            sizes[letter] = size
    n = 1
    for letter, size in sizes.items():
        if letter not in out:
            n *= size
    return n


def ein(spec: str, a, b) -> MR:
    """``einsum(spec, a, b)`` of two interval (or float) arrays or Taylor models, enclosed: the terms summed in
    index order (:func:`ident.numerics.fused.contract`; the bound holds for any order)."""
    a, b = _mr(a), _mr(b)
    n = _terms(spec, a.shape, b.shape)
    g = _gamma(n)
    if a.a is None and b.a is None:
        (ac, ar), (bc, br) = contraction_views(spec, [a.c, a.r], [b.c, b.r])
        return MR(*contract((ac, ar), (bc, br), g, taylor=False))
    zero = np.zeros(())
    a1 = np.broadcast_to(zero, a.c.shape) if a.a is None else a.a
    a2 = np.broadcast_to(zero, b.c.shape) if b.a is None else b.a
    va, vb = contraction_views(spec, [a.c, a1, a.r], [b.c, a2, b.r])
    c, lin, r = contract(tuple(va), tuple(vb), g, taylor=True)
    return MR(c, r, lin)


def inverse(m: MR) -> MR:
    """An enclosure of ``M^-1`` for every M in the interval matrices ``m`` (..., k, k) (module docstring).

    Raises :class:`SingularIntervalMatrix` naming how many matrices could not be proven regular."""
    k = m.shape[-1]
    try:
        C = np.linalg.inv(m.c)
    except np.linalg.LinAlgError:  # a singular midpoint: any C is valid, the test below then refuses it
        C = np.linalg.pinv(m.c)
    eye = np.eye(k)
    E = MR(eye) - ein("...ij,...jk->...ik", C, m)
    beta = up(np.max(np.sum(E.mag(), axis=-1), axis=-1) * _ONE)
    bad = ~(beta < 0.75)
    if np.any(bad):
        raise SingularIntervalMatrix(
            f"{int(bad.sum())} interval matrices could not be proven regular (preconditioned Neumann bound "
            f"||I - C M|| = {float(np.max(beta)):.3g} >= 0.75): the box is too wide or near a singular pose")
    rho = up(up(beta * beta) / (1.0 - beta) * _ONE)  # 1 - beta: one rounding, covered by _ONE
    ic = eye + E.c
    inner = MR(ic, (E.r + U * np.abs(ic) + rho[..., None, None]) * _ONE + _TINY, E.a)
    return ein("...ij,...jk->...ik", inner, C)


class _Differences:
    """``a - b`` as ``a + (-b)`` for a class with ``__add__`` and ``__neg__``."""

    __slots__ = ()

    def __sub__(self, other):
        return self + (-other)

    def __rsub__(self, other):
        return (-self) + other


class Jet(_Differences):
    """Value ``v`` (..., ), gradient ``g`` (..., n) and Hessian ``h`` (..., n, n) enclosures (:class:`MR`) over a
    box; ``order`` 0, 1 or 2 says which are tracked (the others are None)."""

    __slots__ = ("v", "g", "h")

    def __init__(self, v: MR, g: MR | None = None, h: MR | None = None):
        self.v, self.g, self.h = v, g, h

    @property
    def order(self) -> int:
        return 0 if self.g is None else (1 if self.h is None else 2)

    @property
    def shape(self) -> tuple:
        return self.v.shape

    @classmethod
    def variables(cls, box: MR, n: int, first: int, order: int) -> Jet:
        """Independent variables ``z_first .. z_first + m - 1`` (box (..., m)) among n, as a jet of ``order``."""
        m = box.shape[-1]
        if order == 0:
            return cls(box)
        seed = np.zeros(box.shape + (n,))
        seed[..., np.arange(m), first + np.arange(m)] = 1.0
        h = MR(np.zeros(box.shape + (n, n))) if order == 2 else None
        return cls(box, MR(seed), h)

    @classmethod
    def constant(cls, value, like: Jet) -> Jet:
        """A constant (float or MR array) as a jet of ``like``'s order and variable count."""
        v = _mr(value)
        if like.order == 0:
            return cls(v)
        n = like.g.shape[-1]
        g = MR(np.zeros(v.shape + (n,)))
        h = MR(np.zeros(v.shape + (n, n))) if like.order == 2 else None
        return cls(v, g, h)

    def pad(self, n: int) -> Jet:
        """The same jet in n >= m variables: the first m are this jet's, the others absent (zero derivatives)."""
        if self.g is None:
            return self
        m = self.g.shape[-1]
        g = MR.zeros(self.v.shape + (n,), like=self.g)
        g.set((Ellipsis, slice(0, m)), self.g)
        if self.h is None:
            return Jet(self.v, g)
        h = MR.zeros(self.v.shape + (n, n), like=self.h)
        h.set((Ellipsis, slice(0, m), slice(0, m)), self.h)
        return Jet(self.v, g, h)

    def __getitem__(self, key) -> Jet:
        key = key if isinstance(key, tuple) else (key,)
        full = slice(None)
        return Jet(self.v[key], None if self.g is None else self.g[key + (full,)],
                   None if self.h is None else self.h[key + (full, full)])

    def __neg__(self) -> Jet:
        return Jet(-self.v, None if self.g is None else -self.g, None if self.h is None else -self.h)

    def __add__(self, other) -> Jet:
        if not isinstance(other, Jet):
            return Jet(self.v + other, self.g, self.h)
        return Jet(self.v + other.v, None if self.g is None else self.g + other.g,
                   None if self.h is None else self.h + other.h)

    __radd__ = __add__

    def __mul__(self, other) -> Jet:
        """Elementwise product (numpy broadcasting of the value axes) with a jet, MR or float array."""
        if not isinstance(other, Jet):
            o = _mr(other)
            return Jet(self.v * o, None if self.g is None else self.g * o[..., None],
                       None if self.h is None else self.h * o[..., None, None])
        a, b = self, other
        v = a.v * b.v
        if a.g is None:
            return Jet(v)
        g = a.g * b.v[..., None] + b.g * a.v[..., None]
        if a.h is None:
            return Jet(v, g)
        cross = a.g[..., :, None] * b.g[..., None, :]
        h = a.h * b.v[..., None, None] + b.h * a.v[..., None, None] + cross + _transpose(cross)
        return Jet(v, g, h)

    __rmul__ = __mul__

    def sin(self) -> Jet:
        s = self.v.sin()
        if self.g is None:
            return Jet(s)
        c = self.v.cos()
        g = self.g * c[..., None]
        if self.h is None:
            return Jet(s, g)
        gg = self.g[..., :, None] * self.g[..., None, :]
        return Jet(s, g, self.h * c[..., None, None] - gg * s[..., None, None])

    def cos(self) -> Jet:
        c = self.v.cos()
        if self.g is None:
            return Jet(c)
        s = self.v.sin()
        g = -(self.g * s[..., None])
        if self.h is None:
            return Jet(c, g)
        gg = self.g[..., :, None] * self.g[..., None, :]
        return Jet(c, g, -(self.h * s[..., None, None]) - gg * c[..., None, None])

    @staticmethod
    def stack(jets: list, axis: int = -1) -> Jet:
        """Stack jets of one order along a new LAST value axis (``axis`` must be -1)."""
        if axis != -1:
            raise ValueError(f"axis must be -1 (a new last value axis), got {axis}")
        order = jets[0].order
        return Jet(MR.stack([j.v for j in jets], -1), MR.stack([j.g for j in jets], -2) if order >= 1 else None,
                   MR.stack([j.h for j in jets], -3) if order == 2 else None)


def _transpose(m: MR) -> MR:
    return m.swap()


def jet_ein(spec: str, a, b) -> Jet:
    """``einsum(spec, a, b)`` for jets (or a jet and a constant float / MR array); spec over the value axes with
    a leading ``...`` (e.g. ``"...ij,...j->...i"``), lower-case letters only."""
    if not isinstance(a, Jet):
        return _const_ein(spec, a, b, left=True)
    if not isinstance(b, Jet):
        return _const_ein(spec, b, a, left=False)
    ins, out = spec.split("->")
    sa, sb = ins.split(",")
    v = ein(spec, a.v, b.v)
    if a.g is None:
        return Jet(v)
    g = ein(f"{sa}Y,{sb}->{out}Y", a.g, b.v) + ein(f"{sa},{sb}Y->{out}Y", a.v, b.g)
    if a.h is None:
        return Jet(v, g)
    cross = ein(f"{sa}Y,{sb}Z->{out}YZ", a.g, b.g)
    h = (ein(f"{sa}YZ,{sb}->{out}YZ", a.h, b.v) + ein(f"{sa},{sb}YZ->{out}YZ", a.v, b.h) + cross
         + _transpose(cross))
    return Jet(v, g, h)


def _const_ein(spec, const, jet: Jet, left: bool) -> Jet:
    ins, out = spec.split("->")
    sa, sb = ins.split(",")

    def one(suffix, part):
        return (ein(f"{sa},{sb}{suffix}->{out}{suffix}", const, part) if left
                else ein(f"{sa}{suffix},{sb}->{out}{suffix}", part, const))

    return Jet(one("", jet.v), None if jet.g is None else one("Y", jet.g),
               None if jet.h is None else one("YZ", jet.h))


def jet_inverse(m: Jet, centre=None, rounds: int = 2, start: MR | None = None) -> Jet:
    """The jet of ``M^-1`` for a jet of square matrices (..., k, k): ``Y = M^-1``, ``Y_a = -Y M_a Y``,
    ``Y_ab = -(T_a Y_b + T_b Y_a) - Y M_ab Y`` with ``T_a = Y M_a``.

    centre : None, or (Y0, dz): an enclosure Y0 (..., k, k) of the inverse at the box's centre z0 and dz (..., n)
    an enclosure of ``z - z0`` over the box; then Y is narrowed ``rounds`` times by the centred form
    ``Y0 + Y_z dz`` (the plain interval inverse over a box is widened by the conditioning of M).
    start : None, or another enclosure of M^-1 over the box (e.g. the hull over sub-boxes); the narrower is used."""
    y = inverse(m.v) if start is None else _tighter(inverse(m.v), start)
    if m.g is None:
        return Jet(y)

    def grad(y):
        t = ein("...ij,...jkY->...ikY", y, m.g)
        return t, -ein("...ikY,...kl->...ilY", t, y)

    t, g = grad(y)
    if centre is not None:
        y0, dz = centre
        for _ in range(rounds):
            # mean value: Y(z) = Y0 + Y_z(xi) (z - z0), xi between z0 and z (on another slice of tau than z for a
            # Taylor model: Y_z enters with its range over every tau, z - z0 with its own tau)
            y = _tighter(y, y0 + ein("...ilY,...Y->...il", g.untied(), dz))
            t, g = grad(y)
    if m.h is None:
        return Jet(y, g)
    cross = ein("...ikY,...klZ->...ilYZ", t, g)
    ymh = ein("...ij,...jkYZ->...ikYZ", y, m.h)
    h = -(cross + _transpose(cross)) - ein("...ikYZ,...kl->...ilYZ", ymh, y)
    return Jet(y, g, h)


def _tighter(m1: MR, m2: MR) -> MR:
    """Elementwise the narrower of two enclosures of the same quantity (each element of either is valid)."""
    a1 = np.zeros_like(m1.c) if m1.a is None else m1.a
    a2 = np.zeros_like(m2.c) if m2.a is None else m2.a
    first = np.abs(a1) + m1.r <= np.abs(a2) + m2.r
    a = None if m1.a is None and m2.a is None else np.where(first, a1, a2)
    return MR(np.where(first, m1.c, m2.c), np.where(first, m1.r, m2.r), a)


class SplitJet(_Differences):
    """A jet in two groups of variables ``z = (y, w)`` (m and k of them) whose derivative blocks that are exactly
    zero are neither stored nor computed (None): the value ``v`` (...), the gradient blocks ``gy`` (..., m) and
    ``gw`` (..., k), and for ``order`` 2 the Hessian blocks ``hyy`` (..., m, m), ``hyw`` (..., m, k) (``d^2 /
    dy_a dw_b``; the block ``hwy`` is its transpose) and ``hww`` (..., k, k).

    The operations are :class:`Jet`'s (the same product rule, each product and sum enclosed by :class:`MR` and
    :func:`ein`), term by term over the blocks, skipping the terms with a zero factor: a function of y alone times
    one linear in w has no ``hww`` block, and its ``hyw`` block is one product and one cross term instead of the
    four of a dense Hessian. Skipping an exact zero never narrows an enclosure wrongly (the term is zero for every
    point of the box). :meth:`to_jet` gives the dense :class:`Jet` in the n = m + k variables (y first)."""

    __slots__ = ("v", "gy", "gw", "hyy", "hyw", "hww", "m", "k", "order")

    def __init__(self, v: MR, m: int, k: int, order: int, gy=None, gw=None, hyy=None, hyw=None, hww=None):
        if order not in (1, 2):
            raise ValueError(f"order must be 1 or 2, got {order!r}")
        self.v, self.m, self.k, self.order = _mr(v), int(m), int(k), order
        self.gy, self.gw = gy, gw
        self.hyy, self.hyw, self.hww = (hyy, hyw, hww) if order == 2 else (None, None, None)

    @classmethod
    def from_jet(cls, jet: Jet, k: int) -> SplitJet:
        """A :class:`Jet` of order 1 or 2 in m variables as a function of y alone (k more variables w)."""
        return cls(jet.v, jet.g.shape[-1], k, jet.order, gy=jet.g, hyy=jet.h)

    @classmethod
    def w_variables(cls, box: MR, m: int, order: int) -> SplitJet:
        """The variables w (box (..., k)) themselves."""
        k = box.shape[-1]
        seed = np.zeros(box.shape + (k,))
        seed[..., np.arange(k), np.arange(k)] = 1.0
        return cls(box, m, k, order, gw=MR(seed))

    def _like(self, v, gy=None, gw=None, hyy=None, hyw=None, hww=None) -> SplitJet:
        return SplitJet(v, self.m, self.k, self.order, gy, gw, hyy, hyw, hww)

    def _blocks(self):
        return (self.gy, self.gw, self.hyy, self.hyw, self.hww)

    @property
    def shape(self) -> tuple:
        return self.v.shape

    def __getitem__(self, key) -> SplitJet:
        key = key if isinstance(key, tuple) else (key,)
        full = slice(None)
        parts = [None if b is None else b[key + (full,) * n] for b, n in zip(self._blocks(), (1, 1, 2, 2, 2))]
        return self._like(self.v[key], *parts)

    def __neg__(self) -> SplitJet:
        return self._like(-self.v, *(None if b is None else -b for b in self._blocks()))

    def __add__(self, other) -> SplitJet:
        if not isinstance(other, SplitJet):
            return self._like(self.v + other, *self._blocks())
        return self._like(self.v + other.v, *(_sum([a, b]) for a, b in zip(self._blocks(), other._blocks())))

    __radd__ = __add__

    def _as_jet(self, other) -> SplitJet:
        return other if isinstance(other, SplitJet) else self._like(_mr(other))

    def __mul__(self, other) -> SplitJet:
        """Elementwise product (numpy broadcasting of the value axes) with a split jet, MR or float array."""
        return _bilinear(self, self._as_jet(other), _mul_axes)

    __rmul__ = __mul__

    @staticmethod
    def stack(jets: list) -> SplitJet:
        """Stack split jets of one order and variable split along a new LAST value axis (a block that is zero in
        some and not in others is stored with exact zeros in those)."""
        first = jets[0]
        out = []
        for i, n in enumerate((1, 1, 2, 2, 2)):
            parts = [j._blocks()[i] for j in jets]
            if all(p is None for p in parts):
                out.append(None)
                continue
            dims = [(first.m,), (first.k,), (first.m, first.m), (first.m, first.k), (first.k, first.k)][i]
            parts = [MR(np.zeros(j.v.shape + dims)) if p is None else p for j, p in zip(jets, parts)]
            out.append(MR.stack(parts, -1 - n))
        return first._like(MR.stack([j.v for j in jets], -1), *out)

    def to_jet(self) -> Jet:
        """The dense :class:`Jet` in the m + k variables (y first); zero blocks as exact zeros."""
        shape = self.v.shape

        def block(b, dims):
            return MR(np.zeros(shape + dims)) if b is None else b

        g = _concat([block(self.gy, (self.m,)), block(self.gw, (self.k,))], -1)
        if self.order == 1:
            return Jet(self.v, g)
        hyw = block(self.hyw, (self.m, self.k))
        top = _concat([block(self.hyy, (self.m, self.m)), hyw], -1)
        bottom = _concat([hyw.swap(), block(self.hww, (self.k, self.k))], -1)
        return Jet(self.v, g, _concat([top, bottom], -2))


def _concat(parts: list, axis: int) -> MR:
    a = None
    if any(p.a is not None for p in parts):
        a = np.concatenate([np.zeros_like(p.c) if p.a is None else p.a for p in parts], axis=axis)
    return MR(np.concatenate([p.c for p in parts], axis=axis), np.concatenate([p.r for p in parts], axis=axis), a)


def _sum(terms: list):
    """The enclosed sum of the terms that are not None (None if all are: an exact zero)."""
    out = None
    for t in terms:
        if t is not None:
            out = t if out is None else out + t
    return out


def _mul_axes(x: MR, y: MR, sx: str, sy: str, so: str) -> MR:
    """The elementwise product of x with derivative axes sx and y with sy (trailing, letters of so), broadcast to
    the derivative axes so."""
    return _expand(x, sx, so) * _expand(y, sy, so)


def _expand(x: MR, have: str, want: str) -> MR:
    if have == want:
        return x
    key = (Ellipsis,) + tuple(slice(None) if letter in have else None for letter in want)
    return x[key]


def _bilinear(a: SplitJet, b: SplitJet, op) -> SplitJet:
    """The product rule over the blocks for a bilinear ``op(x, y, sx, sy, so)`` (an elementwise product or an
    einsum over the value axes; sx, sy, so the derivative axes of x, y and the result), zero factors skipped."""

    def term(x, y, sx, sy, so):
        return None if x is None or y is None else op(x, y, sx, sy, so)

    v = op(a.v, b.v, "", "", "")
    gy = _sum([term(a.gy, b.v, "Y", "", "Y"), term(a.v, b.gy, "", "Y", "Y")])
    gw = _sum([term(a.gw, b.v, "Y", "", "Y"), term(a.v, b.gw, "", "Y", "Y")])
    if a.order < 2:
        return a._like(v, gy, gw)

    def square(ha, hb, ga, gb):  # a Hessian block of one group: h_a b + a h_b + g_a g_b^T + g_b g_a^T
        cross = term(ga, gb, "Y", "Z", "YZ")
        return _sum([term(ha, b.v, "YZ", "", "YZ"), term(a.v, hb, "", "YZ", "YZ"), cross,
                     None if cross is None else cross.swap()])

    hyy = square(a.hyy, b.hyy, a.gy, b.gy)
    hww = square(a.hww, b.hww, a.gw, b.gw)
    hyw = _sum([term(a.hyw, b.v, "YZ", "", "YZ"), term(a.v, b.hyw, "", "YZ", "YZ"), term(a.gy, b.gw, "Y", "Z", "YZ"),
                term(a.gw, b.gy, "Z", "Y", "YZ")])
    return a._like(v, gy, gw, hyy, hyw, hww)


def split_ein(spec: str, a, b) -> SplitJet:
    """``einsum(spec, a, b)`` for split jets (or a split jet and a constant float / MR array) as :func:`jet_ein`."""
    ins, out = spec.split("->")
    sa, sb = ins.split(",")

    def op(x, y, sx, sy, so):
        return ein(f"{sa}{sx},{sb}{sy}->{out}{so}", x, y)

    like = a if isinstance(a, SplitJet) else b
    return _bilinear(like._as_jet(a), like._as_jet(b), op)


__all__ += ["jet_ein", "jet_inverse", "ein", "narrower", "SplitJet", "split_ein"]
narrower = _tighter
