"""The paper's estimator: preconditioned interval Gauss-Seidel (CGSP) on Rump's square augmented system.

Poignet, Ramdani & Vivas (CDC 2003, sec. 3) turn the over-determined ``W theta in [Y]`` (N x p) into the
square system of Rump (2002), with ``X = [theta; r]`` (p + N unknowns):

    A X = b,   A = [[W, -I_N], [0, W^T]],   b = [[Y]; 0],   [Y] = [y - bound, y + bound],

whose solutions are ``theta = W^+ Y`` (least squares) and ``r = W theta - Y`` for ``Y in [Y]``. Every theta
of the feasible set ``S = {theta in Q : |y - W theta| <= bound}`` is one of them (take ``Y = W theta``,
``r = 0``), so contracting the box ``[Q; r0]`` with the CSP gives an outer enclosure of ``S``. Algorithm
CGSP: precondition with ``C ~ mid(A)^-1`` (``[A'] = C A``, ``[b'] = C [b]``, computed rigorously) and
contract ``[X]`` with the interval Gauss-Seidel operator
``X_i <- X_i & ([b'_i] - sum_{j != i} [A'_ij] X_j) / [A'_ii]`` to a fixed point.

Block structure (used by :func:`cgsp`, never forming an (N+p) x (N+p) matrix). With ``G = W^T W`` and a
fixed float matrix ``Ginv ~ G^-1``, ``mid(A)^-1 = [[G^-1 W^T, G^-1], [W G^-1 W^T - I, W G^-1]]``; taking
``C`` equal to this expression with ``Ginv`` (exactly, as a real matrix),

    C A = [[Ginv G, 0], [W (Ginv G - I), I]]   exactly,

so only ``E = Ginv G`` (p x p) needs a rigorous enclosure, the theta rows do not involve r, and

    [b'_theta] = P [Y] with P = Ginv W^T (enclosed rigorously, p x N),
    [b'_r]     = (W P - I) [Y] subset W [b'_theta] - [Y]   (for each Y: W (P Y) - Y).

The r rows read ``r_k = b'_k - (W (E - I) theta)_k`` (unit diagonal), enclosed by
``r <- r & (W ([b'_theta] - [E - I] [theta]) - [Y])``. Time and memory are O(N p^2) and O(N p).

Stopping rule: sweeps (theta rows in order, then all r rows) are repeated until a sweep shrinks no
component's width by more than ``rtol`` times its previous width (or ``max_sweeps`` is reached; both
stops are sound, since every sweep only intersects with guaranteed enclosures). An empty intersection
proves ``S`` empty.

The paper's last two steps, ``[b] <- A0 [b'] & [b]`` and ``[A] <- A0 [A'] & [A]``, are omitted: [A] and
[b] are not contracted by CGS here (only X is), so they can only change through the inexactness of
``A0 C ~ I``, which would be a rounding artefact rather than a sound contraction.

A checked property (``tests/ident/test_cgsp.py``): for a point regressor the result is ``hull(W^+ [Y]) & Q`` up to rounding, whatever N is: the
width does not shrink like that of the exact hull of ``S`` (:mod:`ident.estimators.hull`).

:func:`cgsp_dense` is the small dense reference (forms A, inverts mid(A) numerically, Gauss-Seidel over all
N + p variables with endpoint interval products) used by the tests.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from h4bench.ident.numerics.interval import (
    div,
    dot_error,
    dot_rows,
    down,
    gram,
    intersect,
    matmul,
    mid_rad,
    mul,
    nonneg_upper,
    point_matmul,
    point_matvec,
    sub,
    sum_down,
    sum_up,
    up,
)

__all__ = ["CGSPResult", "cgsp", "cgsp_dense", "approximate_gram_inverse"]

_CHUNK = 8192


@dataclass
class CGSPResult:
    """theta box ``lower``/``upper`` (p,), residual box ``r_lower``/``r_upper`` (N,), ``empty`` if proven empty."""

    lower: np.ndarray
    upper: np.ndarray
    r_lower: np.ndarray
    r_upper: np.ndarray
    empty: bool
    info: dict = field(default_factory=dict)


def approximate_gram_inverse(G: np.ndarray) -> np.ndarray:
    """A float approximation of ``G^-1`` (column-equilibrated; pseudo-inverse if G is numerically singular).

    Any matrix is acceptable as a preconditioner (rigour does not depend on it), so a singular G gives a
    pseudo-inverse and a weak, but still sound, contraction.
    """
    d = np.sqrt(np.abs(np.diag(G)))
    d[d == 0.0] = 1.0
    Gs = G / d[:, None] / d[None, :]
    if np.linalg.cond(Gs) < 1e13:
        inv = np.linalg.inv(Gs)
    else:
        inv = np.linalg.pinv(Gs, rcond=1e-13, hermitian=True)
    return inv / d[:, None] / d[None, :]


def _gs_theta(Elo, Ehi, blo, bhi, tlo, thi) -> bool:
    """One Gauss-Seidel sweep over the theta rows, in place; returns False if a component became empty."""
    p = tlo.size
    for i in range(p):
        if Elo[i, i] <= 0.0 <= Ehi[i, i]:
            continue  # diagonal contains zero: no contraction (sound)
        plo, phi = mul(Elo[i], Ehi[i], tlo, thi)
        plo[i] = 0.0
        phi[i] = 0.0
        nlo, nhi = sub(blo[i], bhi[i], sum_down(plo), sum_up(phi))
        qlo, qhi = div(nlo, nhi, Elo[i, i], Ehi[i, i])
        tlo[i], thi[i] = max(tlo[i], float(qlo)), min(thi[i], float(qhi))
        if tlo[i] > thi[i]:
            return False
    return True


def _shrunk(old_w, new_w, rtol) -> bool:
    return bool(np.any(old_w - new_w > rtol * old_w))


def cgsp(
    W: np.ndarray,
    ylo: np.ndarray,
    yhi: np.ndarray,
    prior_lo: np.ndarray,
    prior_hi: np.ndarray,
    *,
    rtol: float = 1e-9,
    max_sweeps: int = 50,
) -> CGSPResult:
    """CGSP on Rump's system with the block structure (see module docstring).

    W : (N, p) float; ylo, yhi : (N,) the interval data ``[Y]`` (outward rounded by the caller);
    prior_lo, prior_hi : (p,) finite prior box Q. Returns a :class:`CGSPResult` whose theta box encloses
    ``{W^+ Y : Y in [Y]} & Q``, hence ``S``.
    """
    t0 = time.perf_counter()
    n, p = W.shape
    tlo = np.array(prior_lo, dtype=float)
    thi = np.array(prior_hi, dtype=float)

    # preconditioner pieces: Ginv (float), E = Ginv G enclosed, F = E - I
    Glo, Ghi = gram(W)
    Gmid = 0.5 * Glo + 0.5 * Ghi
    Ginv = approximate_gram_inverse(Gmid)
    Elo, Ehi = matmul(Ginv, Ginv, Glo, Ghi)
    eye = np.eye(p)
    Flo, Fhi = sub(Elo, Ehi, eye, eye)

    # [b'_theta] = P [Y] with P = Ginv W^T exactly. Pc = fl(Ginv W^T) block by block:
    #   P Y = Pc Y + (P - Pc) Y,  Pc Y in Pc yc +- |Pc| yr,  |P - Pc| <= gamma_p |Ginv| |W^T| + p eta,
    # so P [Y] subset Pc yc +- (|Pc| yr + gamma_p |Ginv| (|W^T| w) + p eta sum(w)), w = |yc| + yr.
    yc, yr = mid_rad(ylo, yhi)
    z = np.zeros(p)
    a_zc = np.zeros(p)  # |Pc| |yc|, for the float error of Pc yc
    a_zr = np.zeros(p)  # |Pc| yr
    for s in range(0, n, _CHUNK):
        e = min(n, s + _CHUNK)
        Pc = Ginv @ W[s:e].T
        z += Pc @ yc[s:e]
        np.abs(Pc, out=Pc)
        a_zc += Pc @ np.abs(yc[s:e])
        a_zr += Pc @ yr[s:e]
    w = up(np.abs(yc) + yr)
    t = np.zeros(p)
    for s in range(0, n, _CHUNK):
        t += np.abs(W[s : s + _CHUNK]).T @ w[s : s + _CHUNK]
    t = nonneg_upper(t, n)
    p_err = up(up(dot_error(nonneg_upper(np.abs(Ginv) @ t, p), p)) + up(1e-300 * sum_up(w)))
    rad = up(up(nonneg_upper(a_zr, n) + p_err) + dot_error(a_zc, n))
    zlo, zhi = down(z - rad), up(z + rad)

    # initial residual box r0 = W Q - [Y] (contains r = 0 for every theta in S)
    rlo = np.empty(n)
    rhi = np.empty(n)
    for s in range(0, n, _CHUNK):
        e = min(n, s + _CHUNK)
        wlo, whi = point_matvec(W[s:e], tlo, thi)
        rlo[s:e], rhi[s:e] = sub(wlo, whi, ylo[s:e], yhi[s:e])

    empty = False
    sweeps = 0
    while sweeps < max_sweeps:
        sweeps += 1
        tw = thi - tlo
        if not _gs_theta(Elo, Ehi, zlo, zhi, tlo, thi):
            empty = True
            break
        # r rows: r <- r & (W ([z] - [F] [theta]) - [Y])
        flo, fhi = matmul(Flo, Fhi, tlo, thi)
        vlo, vhi = sub(zlo, zhi, flo, fhi)
        rw = rhi - rlo
        for s in range(0, n, _CHUNK):
            e = min(n, s + _CHUNK)
            wlo, whi = point_matvec(W[s:e], vlo, vhi)
            qlo, qhi = sub(wlo, whi, ylo[s:e], yhi[s:e])
            rlo[s:e], rhi[s:e] = intersect(rlo[s:e], rhi[s:e], qlo, qhi)
        if np.any(rlo > rhi):
            empty = True
            break
        if not (_shrunk(tw, thi - tlo, rtol) or _shrunk(rw, rhi - rlo, rtol)):
            break
    info = {
        "sweeps": sweeps,
        "converged": sweeps < max_sweeps or empty,
        "diag_E": (Elo.diagonal().copy(), Ehi.diagonal().copy()),
        "seconds": time.perf_counter() - t0,
    }
    return CGSPResult(lower=tlo, upper=thi, r_lower=rlo, r_upper=rhi, empty=empty, info=info)


def cgsp_dense(
    W: np.ndarray,
    ylo: np.ndarray,
    yhi: np.ndarray,
    prior_lo: np.ndarray,
    prior_hi: np.ndarray,
    *,
    rtol: float = 1e-9,
    max_sweeps: int = 200,
) -> CGSPResult:
    """Dense reference CGSP: forms Rump's (N+p) x (N+p) matrix, ``C = inv(A)`` numerically, rigorous
    ``[A'] = C A`` and ``[b'] = C [b]``, and Gauss-Seidel over all N + p variables. For small N only
    (O((N+p)^3) time, O((N+p)^2) memory); same stopping rule as :func:`cgsp`.
    """
    t0 = time.perf_counter()
    n, p = W.shape
    m = n + p
    A = np.zeros((m, m))
    A[:n, :p] = W
    A[:n, p:] = -np.eye(n)
    A[n:, p:] = W.T
    try:
        C = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        C = np.linalg.pinv(A)
    Alo, Ahi = point_matmul(C, A)
    blo = np.concatenate([ylo, np.zeros(p)])
    bhi = np.concatenate([yhi, np.zeros(p)])
    bplo, bphi = point_matvec(C, blo, bhi)
    # X = [theta; r], r0 = W Q - [Y]
    wlo, whi = point_matvec(W, prior_lo, prior_hi)
    r0lo, r0hi = sub(wlo, whi, ylo, yhi)
    xlo = np.concatenate([np.asarray(prior_lo, float), r0lo])
    xhi = np.concatenate([np.asarray(prior_hi, float), r0hi])
    empty = False
    sweeps = 0
    while sweeps < max_sweeps and not empty:
        sweeps += 1
        old = xhi - xlo
        for i in range(m):
            if Alo[i, i] <= 0.0 <= Ahi[i, i]:
                continue
            rowlo = Alo[i].copy()
            rowhi = Ahi[i].copy()
            rowlo[i] = rowhi[i] = 0.0
            slo, shi = dot_rows(rowlo[None, :], rowhi[None, :], xlo, xhi)
            nlo, nhi = sub(bplo[i], bphi[i], slo[0], shi[0])
            qlo, qhi = div(nlo, nhi, Alo[i, i], Ahi[i, i])
            xlo[i] = max(xlo[i], float(qlo))
            xhi[i] = min(xhi[i], float(qhi))
            if xlo[i] > xhi[i]:
                empty = True
                break
        if not empty and not _shrunk(old, xhi - xlo, rtol):
            break
    info = {"sweeps": sweeps, "seconds": time.perf_counter() - t0}
    return CGSPResult(lower=xlo[:p], upper=xhi[:p], r_lower=xlo[p:], r_upper=xhi[p:], empty=empty, info=info)
