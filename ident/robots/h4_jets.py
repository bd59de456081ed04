"""Rigorous enclosures of the H4's nacelle terms and their first and second derivatives over boxes of (q, qd).

The Mnac and Ibc columns of the weak form (:mod:`ident.robots.h4_certified`) need, on every sample step, the
per-step functions ``P(q, qd)`` and ``F(q, qd)`` with their gradients at the measured secant state and bounds of
their Hessians over the box that holds the measured and the true states of the step. This module computes them
by interval jets (:mod:`ident.numerics.jets`), so nothing is sampled:

* **the pose** ``x(q)`` (implicit: the loop closures ``G_i(x, q) = |B_i(q_i) - A_i(x)|^2 - l_i^2 = 0``) is
  enclosed over the box Q by the parametric Krawczyk test ``K(X) = x^ - C G(x^, Q) + (I - C G_x(X, Q)) (X - x^)
  subset int X`` (x^ the floating-point forward kinematics of the box's centre, ``C ~ G_x(x^)^-1``): then for
  every q in Q the loop closure has exactly one solution in X, and it lies in K(X). That solution is the
  nacelle pose of the assembly mode the forward kinematics found (an assumption of the whole weak form: the
  robot stays in the assembly mode the measured positions' forward kinematics gives);
* **its derivatives**: ``x_q = J = -G_x^-1 G_q = Jx^-1 diag(Jq)`` over (K(X), Q), and ``x_qq`` from the second
  derivative of ``G(x(q), q) = 0``: ``G_x x_ab + T_ab = 0`` where ``T`` is the Hessian of G computed with x's
  Hessian set to zero, so ``x_ab = (2 Jx)^-1 T_ab`` (``G_x = -2 Jx``);
* **P and F** (:func:`ident.robots.h4_certified.nacelle_terms`, the same formulas: xd = J qd, Jd from the
  derivatives of the loop-closure rows) evaluated in jet arithmetic with ``q``, ``qd`` the independent
  variables and ``x`` the jet above; one is rewritten in an equal form that the jets enclose more cheaply and a
  little more tightly: ``d(Jq_i)/dt = u . (B_i' x AB) + u . (PB x AB')`` with ``B_i' = (u x PB) qd_i`` as
  ``qd_i u . ((u x PB) x AB) + (u x PB) . AB'``, its first factor a function of q alone (4 variables, not 8).

Geometry constants are taken as the floating-point numbers of :class:`sim.H4Geometry` (the model), and their
products are enclosed like every other operation.
"""

from __future__ import annotations

import itertools

import numpy as np

from h4bench.ident.numerics.interval import U, up
from h4bench.ident.workers import shared_started
from h4bench.ident.numerics.jets import (MR, Jet, SingularIntervalMatrix, SplitJet, ein, inverse, jet_ein, jet_inverse,
                                        narrower, split_ein)

__all__ = ["KrawczykFailure", "POINT_CHUNK", "box_jets", "box_jets_started", "nacelle_jets", "point_jets",
           "point_jets_started", "pose_box"]

N_JOINTS = 4
_KRAWCZYK_TRIES = 6
CENTRED_ROUNDS = 2  # centred-form rounds for the pose's gradient over a box (_x_jet)
SPLIT = 2  # sub-boxes per joint of a box whose pose gradient is wide (_x_jet)
SPLIT_ABOVE = 0.05  # the relative width of the pose gradient above which a box is split (_x_jet)
#: steps per :func:`box_jets` chunk: the same bits for any chunk (each step's numbers are its own); on
#: ``certified --quick`` seed 0 at 914e5f9 the per-step stage took 7.7 s with 512 against 8.4 s with 128, and 10.6 s
#: against 14.8 s at 4096 counts per turn (numpy's per-call overhead spread over more steps)
BOX_CHUNK = 512
#: steps per :func:`point_jets` chunk (the same bits for any chunk)
POINT_CHUNK = 2048


class KrawczykFailure(ArithmeticError):
    """The nacelle pose could not be enclosed over a box of motor angles (too wide a box, or near a singular
    pose)."""


def _cross(a: Jet, b) -> Jet:
    """Cross product over the last value axis (3) of a jet and a jet or float array."""
    return Jet.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                      a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]])


def _const(geometry):
    """The geometry's derived constants as intervals: L_i e_i, L_i f_i (f = u x e) and u x e itself."""
    e = MR(geometry.arm_dir)
    u = MR(geometry.motor_axis)
    f = MR.stack([u[:, 1] * e[:, 2] - u[:, 2] * e[:, 1], u[:, 2] * e[:, 0] - u[:, 0] * e[:, 2],
                  u[:, 0] * e[:, 1] - u[:, 1] * e[:, 0]])
    L = MR(geometry.arm_length[:, None])
    return L * e, L * f


def _closures(geometry, q: Jet, x: Jet) -> Jet:
    """The loop closures G (..., 4) alone (the operations of :func:`_loop`'s, the same values)."""
    ab = _ab(geometry, q, x)[0]
    l = MR(geometry.forearm_length)
    return jet_ein("...ik,...ik->...i", ab, ab) - l * l


def _ab(geometry, q: Jet, x: Jet):
    """AB = B - A (..., 4, 3), DC (..., 4, 3) and B (..., 4, 3) as jets."""
    Le, Lf = _const(geometry)
    b = geometry.bar_offset
    th = x[..., 3]
    c, s = th.cos()[..., None], th.sin()[..., None]  # (..., 1)
    dc = Jet.stack([c * b[:, 0] - s * b[:, 1], s * b[:, 0] + c * b[:, 1],
                    Jet.constant(np.broadcast_to(b[:, 2], c.shape[:-1] + (N_JOINTS,)), like=c)])
    A = dc + x[..., None, :3] + geometry.attach_offset
    B = q.cos()[..., None] * Le + q.sin()[..., None] * Lf + geometry.motor_pos
    return B - A, dc, B


def _loop(geometry, q: Jet, x: Jet):
    """The loop-closure quantities of eqs. 11-12 as jets: AB, PB, DC (..., 4, 3), Jx (..., 4, 4), Jq (..., 4),
    u x PB (..., 4, 3) and the closures G (..., 4)."""
    ab, dc, B = _ab(geometry, q, x)
    pb = B - geometry.motor_pos
    jx = Jet.stack([ab[..., 0], ab[..., 1], ab[..., 2], dc[..., 0] * ab[..., 1] - dc[..., 1] * ab[..., 0]])
    ucross = _cross_const_left(geometry.motor_axis, pb)  # u x PB
    jq = jet_ein("...ik,...ik->...i", ucross, ab)  # u . (PB x AB) = (u x PB) . AB
    l = MR(geometry.forearm_length)
    G = jet_ein("...ik,...ik->...i", ab, ab) - l * l
    return ab, pb, dc, jx, jq, ucross, G


def _cross_const_left(u: np.ndarray, b: Jet) -> Jet:
    """u x b for a constant (4, 3) array u and a jet b (..., 4, 3)."""
    return Jet.stack([b[..., 2] * u[:, 1] - b[..., 1] * u[:, 2], b[..., 0] * u[:, 2] - b[..., 2] * u[:, 0],
                      b[..., 1] * u[:, 0] - b[..., 0] * u[:, 1]])


def pose_box(geometry, Q: MR, x_hat: np.ndarray) -> MR:
    """An enclosure (S, 4) of the nacelle poses x(q) for every q in the boxes Q (S, 4) [rad], by the parametric
    Krawczyk test around x_hat (S, 4), the forward kinematics of Q's centres (module docstring).

    Raises :class:`KrawczykFailure` naming the first step whose box could not be verified."""
    x_hat = np.asarray(x_hat, dtype=float)
    S = x_hat.shape[0]
    centre = _loop(geometry, Jet(MR(Q.c)), Jet(MR(x_hat)))
    jx_c, jq_c = centre[3].v.c, centre[4].v.c
    C = -0.5 * np.linalg.inv(jx_c)  # ~ G_x^-1 (G_x = -2 Jx)
    J0 = np.linalg.solve(jx_c, np.eye(N_JOINTS)[None] * jq_c[:, None, :])
    # the guess x~ (a Taylor model in tau when Q is one: the linearisation along Q's linear part)
    x_t = MR(x_hat) if Q.a is None else MR(x_hat, None, np.einsum("sij,sj->si", J0, Q.a))
    resid = _closures(geometry, Jet(Q), Jet(x_t)).v  # G(x~, Q)
    base = x_t - ein("...ij,...j->...i", C, resid)
    off = np.abs(base.c - x_t.c) + base.r + (0 if base.a is None else np.abs(base.a - x_t.a))
    # first guess: twice the linearisation's reach over Q's radius plus twice the Newton correction, and a floor
    rad = 2.0 * np.einsum("sij,sj->si", np.abs(J0), Q.r) + 2.0 * off + 1e-12
    inside = np.zeros(S, dtype=bool)
    for _ in range(_KRAWCZYK_TRIES):
        X = MR(x_t.c, rad, x_t.a)
        jx = _loop(geometry, Jet(Q), Jet(X))[3].v
        M = MR(np.eye(N_JOINTS)) - ein("...ij,...jk->...ik", C, jx * -2.0)
        K = base + ein("...ij,...j->...i", M, MR(np.zeros_like(rad), rad))
        with np.errstate(all="ignore"):
            reach = up(up(np.abs(K.c - x_t.c) + K.r + (0 if K.a is None else np.abs(K.a - x_t.a))) * 1.0001)
            inside = np.all(reach < rad, axis=1)
        if inside.all():
            return K
        if not (np.all(np.isfinite(reach)) and np.all(rad < 1.0)):  # diverging: no verification possible
            break
        rad = np.where(inside[:, None], rad, up(1.5 * np.maximum(reach, rad)))
    bad = np.flatnonzero(~inside)
    raise KrawczykFailure(
        f"the nacelle pose could not be enclosed over the motor-angle boxes of {bad.size} of {S} steps (first: "
        f"step {int(bad[0])}, box half-widths {Q.r[bad[0]].tolist()} rad): too wide a box or a pose near a "
        "singularity")


def _x_jet(geometry, Q: MR, X: MR, order: int, x_hat=None, centred: int = 0, split: int = 0):
    """The pose as a jet in q (4 variables): value X, gradient J, Hessian x_qq; and the enclosure of Jx^-1 over
    (X, Q) it used. Returns (jet, jx_inv).

    centred : rounds of the centred form ``J(Q) in J(q^) + x_qq(Q) (Q - q^)`` (q^ = Q's centre, x_hat its pose),
    each followed by x_qq from the narrower J: the plain interval J over a box is widened by the conditioning of
    Jx, the centred one only by x_qq times the box's radius.
    split : on the boxes whose plain J is wider than :data:`SPLIT_ABOVE` (relative), J and Jx^-1 are also
    enclosed as the hull of their enclosures over ``split``^4 sub-boxes of Q's radius (:func:`_split_inverse`):
    without it a wide box's J makes x_qq wide, and the centred form (J from x_qq) cannot recover."""
    n = N_JOINTS
    _, _, _, jx, jq, _, _ = _loop(geometry, Jet(Q), Jet(X))
    jx_inv = inverse(jx.v)
    g = jx_inv * jq.v[..., None, :]  # J (S, 4, 4): x's gradient in q
    if order < 2:
        return Jet(X, g), jx_inv
    if split > 1 and x_hat is not None:
        jx_inv, g = _narrow_by_split(geometry, Q, x_hat, jx_inv, g, split)
    qj = Jet.variables(Q, n, 0, 2)

    def hessian(grad):  # T: the Hessian of G(x(q), q) without x's own; x_qq = (2 Jx)^-1 T = 0.5 Jx^-1 T
        T = _closures(geometry, qj, Jet(X, grad, MR(np.zeros(X.shape + (n, n))))).h
        return ein("...ij,...jYZ->...iYZ", jx_inv, T) * 0.5

    xqq = hessian(g)
    if centred:
        q_hat = MR(Q.c)
        J_hat = _x_jet(geometry, q_hat, pose_box(geometry, q_hat, x_hat), 1)[0].g
        dQ = MR(np.zeros_like(Q.c), Q.r, Q.a)  # Q - q^
        for _ in range(centred):  # mean value: x_qq at a point between q^ and q, over every tau (untied)
            g = narrower(g, J_hat + ein("...ijk,...k->...ij", xqq.untied(), dQ))
            xqq = narrower(xqq, hessian(g))
    return Jet(X, g, xqq), jx_inv


def _spread_ratio(m: MR) -> np.ndarray:
    """(S,) the largest distance from the centre over the largest |centre| of each (S, k, k) matrix."""
    return np.max(m._spread(), axis=(-1, -2)) / np.maximum(np.max(np.abs(m.c), axis=(-1, -2)), 1e-300)


def _narrow_by_split(geometry, Q: MR, x_hat, jx_inv: MR, g: MR, split: int):
    """(jx_inv, g) narrowed on the boxes where g is wide (:func:`_x_jet`); unchanged where a sub-box fails."""
    wide = np.flatnonzero(_spread_ratio(g) > SPLIT_ABOVE)
    if wide.size == 0:
        return jx_inv, g
    try:
        inv_s, g_s = _split_inverse(geometry, Q[wide], x_hat[wide], split)
    except (KrawczykFailure, SingularIntervalMatrix):
        return jx_inv, g
    out = []
    for whole, part in ((jx_inv, inv_s), (g, g_s)):
        best = narrower(whole[wide], part)
        a = None if whole.a is None and best.a is None else (
            np.zeros_like(whole.c) if whole.a is None else whole.a.copy())
        m = MR(whole.c.copy(), whole.r.copy(), a)
        m.c[wide], m.r[wide] = best.c, best.r
        if a is not None:
            m.a[wide] = 0.0 if best.a is None else best.a
        out.append(m)
    return tuple(out)


def _split_inverse(geometry, Q: MR, x_hat, split: int):
    """Enclosures of Jx^-1 and J = Jx^-1 diag(Jq) (S, 4, 4) over the boxes Q (S, 4) (a Taylor model in tau or
    not) as the hull over ``split``^4 sub-boxes, each ``Q.c + d +- r_k`` (same tau part) with d on a grid of
    Q's radius and r_k covering its share of the radius and the rounding of ``Q.c + d``: every q of Q lies in a
    sub-box, where the pose box, Jx^-1 and J are enclosed as in :func:`_x_jet` (a plain interval of the range
    over every tau). Raises what :func:`pose_box` or :func:`inverse` raise."""
    c0 = _loop(geometry, Jet(MR(Q.c)), Jet(MR(x_hat)))
    J0 = np.linalg.solve(c0[3].v.c, np.eye(N_JOINTS)[None] * c0[4].v.c[:, None, :])  # to start each sub-pose
    grid = (2.0 * np.arange(split) + 1.0) / split - 1.0
    lo = hi = None
    for o in itertools.product(grid, repeat=N_JOINTS):
        d = np.asarray(o) * Q.r
        ck = Q.c + d
        rk = (Q.r / split + 2 * U * (np.abs(ck) + np.abs(d) + Q.r)) * (1 + 8 * U) + 1e-300
        Qk = MR(ck, rk, Q.a)
        Xk = pose_box(geometry, Qk, x_hat + np.einsum("sij,sj->si", J0, d))
        _, _, _, jx, jq, _, _ = _loop(geometry, Jet(Qk), Jet(Xk))
        inv_k = inverse(jx.v)
        g_k = inv_k * jq.v[..., None, :]
        parts = [(m.lo, m.hi) for m in (inv_k, g_k)]
        lo = [p[0] for p in parts] if lo is None else [np.minimum(a, p[0]) for a, p in zip(lo, parts)]
        hi = [p[1] for p in parts] if hi is None else [np.maximum(a, p[1]) for a, p in zip(hi, parts)]
    return tuple(MR.from_bounds(a, b) for a, b in zip(lo, hi))


def nacelle_jets(geometry, Q: MR, V: MR, x_hat: np.ndarray, order: int = 2):
    """P and F (each a :class:`Jet` of value shape (S, 4, 2): joint, column Mnac / Ibc) over the boxes Q (S, 4)
    [rad] of motor angles and V (S, 4) [rad/s] of motor speeds, as functions of the 8 variables (q, qd);
    x_hat (S, 4) the floating-point forward kinematics of Q's centres. ``order`` 1 (gradients) or 2 (Hessians).
    """
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    X = pose_box(geometry, Q, x_hat)
    # everything that depends on q alone in the 4 variables q (a quarter of the Hessian entries), then padded
    x, jx_inv = _x_jet(geometry, Q, X, order, x_hat=x_hat, centred=CENTRED_ROUNDS if order == 2 else 0,
                       split=SPLIT if order == 2 else 0)
    q = Jet.variables(Q, N_JOINTS, 0, order)
    ab, pb, dc, jx, jq, ucross, _ = _loop(geometry, q, x)
    centre = None
    if order == 2:  # the centred form for Jx^-1 over the box (jet_inverse)
        q_hat = MR(Q.c)
        jx_hat = _loop(geometry, Jet(q_hat), Jet(pose_box(geometry, q_hat, x_hat)))[3].v
        centre = (inverse(jx_hat), MR(np.zeros_like(Q.c), Q.r, Q.a))
    jinv = jet_inverse(jx, centre, start=jx_inv)
    J = jinv * jq[..., None, :]
    # d(Jq_i)/dt = u . (B_i' x AB) + u . (PB x AB') with B_i' = (u x PB) qd_i: the first term is qd_i times the
    # function of q alone u . ((u x PB) x AB), computed here in the 4 variables q
    su = jet_ein("...ik,ik->...i", _cross(ucross, ab), geometry.motor_axis)
    # from here on, functions of (q, qd) as split jets: the q-only ones have no qd blocks, the ones linear in qd no
    # qd-qd block, and those exact zeros are skipped (jets.SplitJet)
    ab, dc, ucross, jinv, J, su = (SplitJet.from_jet(j, N_JOINTS) for j in (ab, dc, ucross, jinv, J, su))
    qd = SplitJet.w_variables(V, N_JOINTS, order)
    xd = split_ein("...ij,...j->...i", J, qd)
    bd = ucross * qd[..., None]  # B_i's velocity
    ezdc = SplitJet.stack([-dc[..., 1], dc[..., 0], SplitJet(MR(np.zeros(dc.shape[:-1])), N_JOINTS, N_JOINTS, order)])
    dcd = ezdc * xd[..., 3][..., None, None]
    abd = bd - xd[..., None, :3] - dcd
    jxd = SplitJet.stack([abd[..., 0], abd[..., 1], abd[..., 2],
                          dcd[..., 0] * ab[..., 1] + dc[..., 0] * abd[..., 1] - dcd[..., 1] * ab[..., 0]
                          - dc[..., 1] * abd[..., 0]])
    jqd = su * qd + split_ein("...ik,...ik->...i", ucross, abd)  # u . (PB x AB') = (u x PB) . AB
    rhs = jqd[..., :, None] * np.eye(N_JOINTS) - split_ein("...ij,...jk->...ik", jxd, J)
    jd = split_ein("...ij,...jk->...ik", jinv, rhs)
    P = SplitJet.stack([split_ein("...ai,...a->...i", J[..., :3, :], xd[..., :3]), J[..., 3, :] * xd[..., 3:4]])
    F = SplitJet.stack([-split_ein("...ai,...a->...i", jd[..., :3, :], xd[..., :3])
                        - split_ein("...ai,a->...i", J[..., :3, :], geometry.gravity),
                        -(jd[..., 3, :] * xd[..., 3:4])])
    return P.to_jet(), F.to_jet()


def point_jets(geometry, qm: np.ndarray, v: np.ndarray, x_hat: np.ndarray, chunk: int | None = None):
    """First-order jets of P and F at the points (qm, v) (S, 4) (rigorous values and gradients; x_hat (S, 4) the
    forward kinematics of qm), computed in chunks of ``chunk`` steps (default :data:`POINT_CHUNK`) and joined."""
    chunk = POINT_CHUNK if chunk is None else int(chunk)
    parts = [nacelle_jets(geometry, MR(qm[i:i + chunk]), MR(v[i:i + chunk]), x_hat[i:i + chunk], order=1)
             for i in range(0, qm.shape[0], chunk)]
    return tuple(_join_jets([p[k] for p in parts]) for k in (0, 1))


def _join_jets(items) -> Jet:
    """First-order jets of consecutive steps as one."""
    def join(ms):
        return MR(np.concatenate([m.c for m in ms]), np.concatenate([m.r for m in ms]))

    return Jet(join([j.v for j in items]), join([j.g for j in items]))


def point_jets_started(geometry, qm: np.ndarray, v: np.ndarray, x_hat: np.ndarray, pool=None):
    """:func:`point_jets` begun, as :func:`box_jets_started` begins :func:`box_jets`: with ``pool`` its chunks are
    shared with the worker (:func:`ident.workers.shared_started`); the returned function computes this process's
    and joins (the same chunks, the same bits)."""
    chunk = POINT_CHUNK
    pieces = [(geometry, qm[i:i + chunk], v[i:i + chunk], x_hat[i:i + chunk], chunk)
              for i in range(0, qm.shape[0], chunk)]
    started = shared_started(pool, point_jets, pieces)
    return lambda: tuple(_join_jets(list(parts)) for parts in zip(*started()))


def box_jets(geometry, Q: MR, V: MR, x_hat: np.ndarray, chunk: int | None = None):
    """Bounds over the boxes Q, V (S, 4) of |gradient| and |Hessian| of P and F (second-order jets in chunks of
    ``chunk`` steps, default :data:`BOX_CHUNK`).

    Q may be a Taylor model in tau (a tube along each step's motion, :class:`~ident.numerics.jets.MR`).
    Returns (GP, HP, GF, HF, proven): GP, GF (S, 4, 2, 8) and HP, HF (S, 4, 2, 8, 8) magnitudes over the whole
    box (every tau), and a (S,) bool mask of the steps whose boxes were verified (the bounds of the others are NaN:
    the caller must not use them; a pose test or an interval inverse failed there, e.g. near a singular pose or
    for too wide a box)."""
    chunk = BOX_CHUNK if chunk is None else int(chunk)
    S = Q.shape[0]
    out = [np.full((S, 4, 2, 8), np.nan), np.full((S, 4, 2, 8, 8), np.nan), np.full((S, 4, 2, 8), np.nan),
           np.full((S, 4, 2, 8, 8), np.nan)]
    proven = np.zeros(S, dtype=bool)
    todo = [(i, min(i + chunk, S)) for i in range(0, S, chunk)]
    while todo:
        a, b = todo.pop()
        try:
            P, F = nacelle_jets(geometry, Q[a:b], V[a:b], x_hat[a:b], order=2)
        except (KrawczykFailure, SingularIntervalMatrix):
            if b - a > 1:  # find the steps that fail by bisection
                m = (a + b) // 2
                todo += [(a, m), (m, b)]
            continue
        for k, m in enumerate((P.g, P.h, F.g, F.h)):
            out[k][a:b] = m.mag()
        proven[a:b] = True
    return (*out, proven)


def box_jets_started(geometry, Q: MR, V: MR, x_hat: np.ndarray, pool=None):
    """:func:`box_jets` begun: with ``pool`` (an executor of another process) its chunks are shared with it, the
    later ones submitted now (:func:`ident.workers.shared_started`: this process also takes those the worker has
    not begun when it gets there); the returned function computes this process's and joins, the same bits as
    :func:`box_jets` (every chunk holds the same steps). Without a pool, or with one chunk, the returned function
    computes it all."""
    chunk = BOX_CHUNK
    S = Q.shape[0]
    if pool is None or S <= chunk:
        return lambda: box_jets(geometry, Q, V, x_hat, chunk)
    pieces = [(geometry, Q[i:i + chunk], V[i:i + chunk], x_hat[i:i + chunk], chunk) for i in range(0, S, chunk)]
    started = shared_started(pool, box_jets, pieces)
    return lambda: tuple(np.concatenate(parts) for parts in zip(*started()))
