"""The inertial columns of a serial arm's certified equation, vectorised: per-step local bounds batched over sample
steps, window sums for all windows at once (:mod:`ident.robots.serial_certified` derives the bounds; this module
evaluates them).

**Per step** j (``[t_j, t_j+1]``, mid-step position ``qh``, speed estimate ``vh``) the regressor is evaluated
at ``qh``, at ``qh + ETA e_k`` and at ``qh + ETA (e_a + e_b)`` with the arguments of the module docstring of
:mod:`ident.robots.serial_certified` (gravity, the speed estimate, unit speeds and accelerations: ``2 + 2 n + n (n -
1) / 2 + n (3 n + 2) + n (n + 1) (n + 2) / 2`` evaluations, each step once: at the corners ``qh + ETA (e_a + e_b)``
also gravity and the mass matrix's columns, for its derivatives): a batch of steps in one call of
:func:`ident.robots.chain.regressor` for a chain of revolute joints, pinocchio's one at a time otherwise. Only the
entries a chain can fill are kept (:func:`ident.robots.chain.live_entries`: ``5 n (n + 1)`` of the ``10 n^2``, the
others zero for every state). Every other operation runs on arrays of many steps at once, in the same arithmetic as
the per-step reference (:mod:`ident.robots.serial_reference`).

**Per window** the regressor at the window's scaled speed and acceleration (``u_w = -k'_w dq_w``: the Lagrangian
form's mass term) is not called again: ``Y(q, v, a) = g(q) + h(q, v) + M(q) a`` with ``h`` quadratic in v, so the
reference's call ``Y(qh_j, sqrt(K_w) vh_j, u_w)`` is
``g0_j + K_w (f0_j - g0_j) + sum_b Mc_j[b] u_w[b]`` from the step's ``g0 = Y(qh, 0, 0)``, ``f0 = Y(qh, vh, 0)``
and mass-matrix columns ``Mc[b] = Y(qh, 0, e_b) - g0`` (an identity of the exact functions). Its arithmetic adds
at most ``2 (n + 5) u`` of ``|g0| + K_w (|f0| + |g0|) + sum_b |Mc[b]| |u_w[b]|`` per (window, step) (``u =
2^-53``: the n-term product, the difference ``f0 - g0``, two products and two sums), returned as ``recon`` (an
upper bound, the sum's own rounding included) for the floating-point radius. Window sums are correlations of
per-step arrays with kernel weights (matrix-vector products over strided views of the step arrays, no copies);
the per-(window, step) arrays (the rebuilt regressor, the differences of kernel-weighted step arrays at two
steps: the speed estimates' exact gradients) are formed for a few windows at a time (``memory`` bounds them).

**Steps held**: the per-step arrays of the windows starting within about ``max(L, 256)`` steps, plus the
``L + 2`` steps the next windows share (moved, not evaluated again): ``8 (max(L, 256) + L) (18 + 3 n) 5 n (n + 1)``
bytes (:data:`_KEEP`), 48 MB for 6 joints and 70 MB for 7 at L = 400.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import as_strided

from h4bench.ident.numerics.interval import U, up
from h4bench.ident.processing.weakform import Kernel
from h4bench.ident.robots.chain import live_entries

__all__ = ["ETA", "PARTS", "PIN_REL", "StepGrid", "c2_terms", "hessian_quadratic", "inertial_family", "inertial_rows",
           "local_bounds", "mass_derivatives", "mass_hessian_bound", "mass_pairs", "q_remainder",
           "quadratic_speed_weights", "regressor_one", "robot_chain", "speed_linear", "step_displacements"]

ETA = 1e-4  # rad: forward-difference step of the local q-derivatives (its truncation is bounded in the radii)
PIN_REL = 1e-12  # stated allowance for pinocchio's floating-point error, relative to the magnitudes summed
# the inertial columns' radii by origin (``parts`` of the equation): M(q) along the step against its mid-step value
# (the term -k' M qd), f2 = g - dT/dq along the step against its value at the mid-step estimate, and the
# measurement through each (the mid-step position, and the exact gradient of sum_j k'_j M_j dq_j)
PARTS = ("mass_motion", "coriolis_motion", "mass_position", "coriolis_position", "gradient_position")
# per-step arrays of (n rows, 10 n columns) the window sums read, and the (n, n rows, 10 n columns) ones
_KEEP = ("g0", "fg", "af0", "ag0", "c2", "c2mag", "L_mot", "H_mot", "Gq", "H_pos", "Dloc", "Ecur", "Eknot",
         "Ediff", "Mc", "aMc", "Jv", "Jc", "aJc", "Jk", "Jf")


class StepGrid:
    """The log's per-step and per-sample estimates (vectorised over the whole log).

    q, e : (N, n) measured positions and their error bounds [rad]; dt [s]; qddm : (n,) stated |qdd| bound; m : the
    secant half-span [steps]. Per step (N - 1 rows): ``qbar`` mid-step position, ``ebar`` its error, ``dq`` the
    step, ``vh`` the speed secant over 2 m - 1 steps (NaN where it leaves the log), ``ev_pos`` its measurement
    error; per sample (N rows): ``w`` the centred secant over 2 m steps, ``ew_pos`` its measurement error;
    ``ev_mot_max``, ``ew_mot`` (n,) the secants' truncation bounds.
    """

    def __init__(self, q, e, dt, qddm, m):
        n = q.shape[1]
        N = q.shape[0]
        self.q, self.e, self.dt, self.qddm, self.m, self.n, self.N = q, e, dt, qddm, m, n, N
        self.S = (2 * m - 1) * dt
        self.qbar, self.ebar, self.dq = 0.5 * (q[:-1] + q[1:]), 0.5 * (e[:-1] + e[1:]), np.diff(q, axis=0)
        self.vh = np.full((N - 1, n), np.nan)
        js = np.arange(m - 1, N - m)
        self.vh[js] = (q[js + m] - q[js + 1 - m]) / self.S
        self.ev_pos = np.full((N - 1, n), np.inf)
        self.ev_pos[js] = (e[js + m] + e[js + 1 - m]) / self.S
        self.ev_mot_max = qddm * self.mot_max_factor(dt, m)  # max over the step of |qd(t) - qd_true secant|
        self.w = np.full((N, n), np.nan)
        ks = np.arange(m, N - m)
        self.w[ks] = (q[ks + m] - q[ks - m]) / (2 * m * dt)
        self.ew_mot = qddm * (m * dt / 2)
        self.ew_pos = np.full((N, n), np.inf)
        self.ew_pos[ks] = (e[ks + m] + e[ks - m]) / (2 * m * dt)

    @staticmethod
    def mot_max_factor(dt: float, m: int) -> float:
        """``c`` [s] with ``|qd(t) - vh*| <= qdd_max c`` for every t in a step, ``vh*`` the true secant over the
        ``2 m - 1`` steps centred on it (span ``S``): ``vh*`` is the mean of qd over the span, so ``|qd(t) - vh*|
        <= qdd_max mean_u |t - u| = qdd_max ((t - c)^2 + S^2 / 4) / S`` (c the span's centre, ``|t - c| <= dt / 2
        <= S / 2``), at most ``(dt^2 + S^2) / (4 S)`` (attained: qd = qdd_max |u - t_end|); rounded up."""
        S = (2 * m - 1) * dt
        return (dt * dt + S * S) / (4 * S) * (1 + 4 * U)

    @staticmethod
    def mot_ms_factor(dt: float, m: int) -> float:
        """``c2`` [s^2] with ``(1 / dt) int_step (qd(t) - vh*)^2 dt <= qdd_max^2 c2``: for m = 1 ``vh*`` is the
        step's mean speed, so this is the variance of qd over the step, ``1/2 E (qd(U) - qd(U'))^2 <= qdd_max^2
        dt^2 / 12`` (U, U' independent uniform on the step); for m > 1 Jensen's inequality over the span, ``E_t
        E_u (qd(t) - qd(u))^2 <= qdd_max^2 (dt^2 + S^2) / 12``; rounded up."""
        S = (2 * m - 1) * dt
        return (dt * dt / 12 if m == 1 else (dt * dt + S * S) / 12) * (1 + 4 * U)


def quadratic_speed_weights(kern: Kernel, m: int) -> np.ndarray:
    """(L,) per kernel step w the weight ``c_w`` of ``Gq = sum_ab |Gamma_ab| qdd_max_a qdd_max_b`` (per step) in
    the bound of the speed deviation's quadratic term ``int_step k (v - vh*)^T Gamma (v - vh*)`` (k >= 0 on
    the step): the smaller of ``K_w c^2`` (the pointwise bound of :meth:`StepGrid.mot_max_factor`, squared) and
    ``max(k_w, k_w+1) dt c2`` (Cauchy-Schwarz, ``int k |x_a| |x_b| <= max k sqrt(int x_a^2 int x_b^2)``, with the
    mean-square bound :meth:`StepGrid.mot_ms_factor`); rounded up. For m = 1 the second is about a third of the
    first inside the kernel; for m > 1 the first is the smaller."""
    dt, k = kern.h, kern.knots
    c = StepGrid.mot_max_factor(dt, m)
    point = kern.integrals * (c * c) * (1 + 4 * U)
    ms = np.maximum(k[:-1], k[1:]) * (dt * StepGrid.mot_ms_factor(dt, m)) * (1 + 4 * U)
    return np.minimum(point, ms)


def _regressor_calls(robot, qh, vh) -> dict:
    """The regressor evaluations of steps with mid positions qh (C, n) and speed estimates vh (C, n): each (C, ...)
    with the regressor's live entries last (F = 5 n (n + 1): :func:`ident.robots.chain.live_entries`, the others
    are zero); ``ha``, ``pair``, ``Mc``, ``Mk``, ``Vp``, ``Vm`` before subtracting. A chain of revolute joints goes
    through :func:`ident.robots.chain.regressor` (all of a batch's evaluations in one call), any other model through
    pinocchio one call at a time (:func:`_pinocchio_calls`)."""
    from h4bench.ident.robots.chain import regressor  # noqa: PLC0415

    ch = robot_chain(robot)
    if ch is None:
        live = live_entries(qh.shape[1])
        return {k: v.reshape(v.shape[:-2] + (-1,))[..., live] for k, v in _pinocchio_calls(robot, qh, vh).items()}
    C, n = qh.shape
    I = np.eye(n)
    pa, pb = np.triu_indices(n, 1)
    shifts = ETA * I
    qk = qh[:, None, :] + shifts[None]  # (C, k, n): qh + ETA e_k
    # (q, v, a) of each evaluation, evaluations at one position together (the chain shares their kinematics): g0,
    # f0, ha, pair, Mc at qh | per k: gk, fk, Mk (b), Vp (b), Vm (b) at qh + ETA e_k | fab
    Z1 = np.zeros((C, 1, n))
    at_qh = np.broadcast_to(qh[:, None], (C, 2 + 2 * n + pa.size, n))
    v_qh = np.concatenate([Z1, vh[:, None], np.broadcast_to(I, (C, n, n)),
                           np.broadcast_to(I[pa] + I[pb], (C, pa.size, n)), np.zeros((C, n, n))], axis=1)
    a_qh = np.concatenate([Z1, Z1, np.zeros((C, n + pa.size, n)), np.broadcast_to(I, (C, n, n))], axis=1)
    nk = 2 + 3 * n  # evaluations per shifted position
    at_k = np.broadcast_to(qk[:, :, None, :], (C, n, nk, n))
    vk = np.empty((C, n, nk, n))
    vk[:, :, 0] = 0.0
    vk[:, :, 1] = vh[:, None]
    vk[:, :, 2:2 + n] = 0.0
    vk[:, :, 2 + n:2 + 2 * n] = vh[:, None, None] + I  # row b: vh + e_b
    vk[:, :, 2 + 2 * n:] = vh[:, None, None] - I
    ak = np.zeros((C, n, nk, n))
    ak[:, :, 2:2 + n] = I
    # per corner qh + ETA (e_a + e_b), a <= b: f (vh, 0); at the corners of the mass pairs (1 <= a <= b) also
    # g (0, 0) and the mass-matrix columns (0, e_c): first the n corners (0, b), then the mass pairs' blocks
    ma, mb = mass_pairs(n)
    nf = 2 + n
    at_0 = qh[:, None, :] + (shifts[0] + shifts)[None]  # (C, b, n): the corners (0, b)
    at_f = np.broadcast_to((qh[:, None, :] + (shifts[ma] + shifts[mb])[None])[:, :, None], (C, ma.size, nf, n))
    vf = np.zeros((C, ma.size, nf, n))
    vf[:, :, 0] = vh[:, None]
    af = np.zeros((C, ma.size, nf, n))
    af[:, :, 2:] = I
    Q = np.concatenate([at_qh, at_k.reshape(C, n * nk, n), at_0, at_f.reshape(C, -1, n)], axis=1).reshape(-1, n)
    V = np.concatenate([v_qh, vk.reshape(C, n * nk, n), np.broadcast_to(vh[:, None], (C, n, n)),
                        vf.reshape(C, -1, n)], axis=1).reshape(-1, n)
    A = np.concatenate([a_qh, ak.reshape(C, n * nk, n), np.zeros((C, n, n)), af.reshape(C, -1, n)],
                       axis=1).reshape(-1, n)
    E = at_qh.shape[1] + n * nk + n + ma.size * nf
    sh = (5 * n * (n + 1),)
    Y = regressor(ch, Q, V, A, packed=True).reshape((C, E) + sh)
    h0 = at_qh.shape[1]
    Yk = Y[:, h0:h0 + n * nk].reshape((C, n, nk) + sh)  # views: the in-place differences of local_bounds work on them
    pair = np.zeros((C, n, n) + sh)
    pair[:, pa, pb] = Y[:, 2 + n:2 + n + pa.size]
    Y0 = Y[:, h0 + n * nk:h0 + n * nk + n]
    Yf = Y[:, h0 + n * nk + n:].reshape((C, ma.size, nf) + sh)
    fab = np.empty((C, n, n) + sh)
    fab[:, 0, :] = Y0
    fab[:, :, 0] = Y0
    fab[:, ma, mb] = Yf[:, :, 0]
    fab[:, mb, ma] = Yf[:, :, 0]
    return {"g0": Y[:, 0], "f0": Y[:, 1], "ha": Y[:, 2:2 + n], "pair": pair, "Mc": Y[:, 2 + n + pa.size:h0],
            "gk": Yk[:, :, 0], "fk": Yk[:, :, 1], "Mk": Yk[:, :, 2:2 + n], "Vp": Yk[:, :, 2 + n:2 + 2 * n],
            "Vm": Yk[:, :, 2 + 2 * n:], "fab": fab, "gab": Yf[:, :, 1], "Mab": Yf[:, :, 2:]}


def regressor_one(robot, q, v, a) -> np.ndarray:
    """One evaluation (n, 10 n) of the regressor :func:`_regressor_calls` uses (the chain's or pinocchio's)."""
    ch = robot_chain(robot)
    if ch is None:
        import pinocchio as pin  # noqa: PLC0415

        return pin.computeJointTorqueRegressor(robot.model, robot.data, q, v, a).copy()
    from h4bench.ident.robots.chain import regressor  # noqa: PLC0415

    return regressor(ch, np.asarray(q)[None], np.asarray(v)[None], np.asarray(a)[None])[0]


def robot_chain(robot):
    """The robot's :class:`ident.robots.chain.Chain` (kept on it), or None when it is not a chain of revolute
    joints."""
    from h4bench.ident.robots.chain import chain_of  # noqa: PLC0415

    if not hasattr(robot, "_chain_cache"):
        robot._chain_cache = chain_of(robot.model)
    return robot._chain_cache


def _pinocchio_calls(robot, qh, vh) -> dict:
    """The regressor evaluations of steps with mid positions qh (C, n) and speed estimates vh (C, n): each (C, ...)
    with the regressor's (n, 10 n) last; ``ha``, ``pair``, ``Mc``, ``Mk``, ``Vp``, ``Vm`` before subtracting."""
    import pinocchio as pin

    Y = pin.computeJointTorqueRegressor
    model, data = robot.model, robot.data
    C, n = qh.shape
    sh = (n, 10 * n)
    Z, I = np.zeros(n), np.eye(n)
    pairs = [(a, b, I[a] + I[b]) for a in range(n) for b in range(a + 1, n)]
    shifts = [ETA * I[k] for k in range(n)]
    out = {"g0": np.empty((C,) + sh), "f0": np.empty((C,) + sh), "ha": np.empty((C, n) + sh),
           "pair": np.zeros((C, n, n) + sh), "Mc": np.empty((C, n) + sh), "gk": np.empty((C, n) + sh),
           "fk": np.empty((C, n) + sh), "Mk": np.empty((C, n, n) + sh), "Vp": np.empty((C, n, n) + sh),
           "Vm": np.empty((C, n, n) + sh), "fab": np.empty((C, n, n) + sh),
           "gab": np.empty((C, n * (n - 1) // 2) + sh), "Mab": np.empty((C, n * (n - 1) // 2, n) + sh)}
    g0, f0, ha, pair, Mc, gk, fk, Mk, Vp, Vm, fab, gab, Mab = out.values()
    for c in range(C):
        qq, v = qh[c], vh[c]
        vp, vm = v + I, v - I  # rows b: v + e_b, v - e_b
        g0[c] = Y(model, data, qq, Z, Z)
        f0[c] = Y(model, data, qq, v, Z)
        for a in range(n):
            ha[c, a] = Y(model, data, qq, I[a], Z)
        for a, b, ab in pairs:
            pair[c, a, b] = Y(model, data, qq, ab, Z)
        for b in range(n):
            Mc[c, b] = Y(model, data, qq, Z, I[b])
        for k in range(n):
            qk = qq + shifts[k]
            gk[c, k] = Y(model, data, qk, Z, Z)
            fk[c, k] = Y(model, data, qk, v, Z)
            for b in range(n):
                Mk[c, k, b] = Y(model, data, qk, Z, I[b])
                Vp[c, k, b] = Y(model, data, qk, vp[b], Z)
                Vm[c, k, b] = Y(model, data, qk, vm[b], Z)
        for a in range(n):  # the corners of the q-Hessian's forward differences (a == b: qq + 2 ETA e_a)
            for b in range(a, n):
                qab = qq + (shifts[a] + shifts[b])
                fab[c, a, b] = Y(model, data, qab, v, Z)
                fab[c, b, a] = fab[c, a, b]
                if a == 0:  # M does not depend on the first joint (mass_pairs)
                    continue
                P = (a - 1) * (n - 1) - (a - 1) * (a - 2) // 2 + b - a  # the pair's index in mass_pairs(n)
                gab[c, P] = Y(model, data, qab, Z, Z)
                for d in range(n):
                    Mab[c, P, d] = Y(model, data, qab, Z, I[d])
    return out


def speed_linear(Jv, gam, gmag, vh, dq, e0, e1, qddm, dt):
    """The speed's first-order term of ``h`` over a step, integrated exactly (per step, arrays over C steps).

    On step j the Taylor expansion of ``h(q, v)`` at the speed estimate ``vh`` has the linear term ``Jv (v(t) -
    vh)`` (``Jv = dh/dv (qh, vh)``, constant over the step). The kernel is linear on the step, ``k(t) = k_mid +
    k' (t - t_mid)``, so ``int_step k v = K1 s_true + k' int (t - t_mid) (v(t) - v(t_mid))`` with ``s_true =
    (q_true(t_j+1) - q_true(t_j)) / dt`` the step's mean speed (exact) and the last integral within ``qdd_max dt^3
    / 12``. Hence
    ``int_step k Jv (v - vh) = K1 Jv (s - vh) - K1 Jv (delta_j+1 - delta_j) / dt + Jv k' eps`` with ``s`` the
    measured step speed (known: added to the row's centre, ``Jc``), the position errors ``delta`` (through the
    row's exact gradient: the caller's summation by parts) and ``|eps| <= qdd_max dt^3 / 12`` (``Jk``, times
    ``|k'|``). This replaces the bound ``K1 |Jv| qdd_max (dt / 4 + S / 4)`` of the speed estimate's truncation:
    about ``9 T / dt`` times smaller for a triangle kernel of length T.

    Jv (C, n, ...) and gam (C, n, n, ...) as computed; gmag (C, n, n, ...) the magnitudes pinocchio's values in each
    Christoffel entry sum (its error ``PIN_REL`` of them); vh, dq, e0, e1 (C, n): speed estimate, measured step,
    position-error bounds at the step's ends. Returns ``Jc`` (the centre term), ``aJc = |Jc|``, ``Jk`` (``sum_a
    |Jv_a| qdd_max_a dt^3 / 12``) and ``Jf``: the bound of the centre term's own error (the computed Jv is within
    ``2 PIN_REL sum_b gmag_ab |vh_b|`` and its float sum of the exact one; that error times ``|s - vh| + (e0 + e1) /
    dt`` covers the centre and the exact gradient's use of the computed Jv; ``4 (n + 2) u`` for the products and
    sums of the centre term).
    """
    C, n = vh.shape
    s = dq / dt
    dv = s - vh
    Jc = np.einsum("sa...,sa->s...", Jv, dv)
    aJv = np.abs(Jv)
    Jk = np.einsum("sa...,a->s...", aJv, qddm) * (dt**3 / 12 * (1 + 4 * U))
    eps = (2 * PIN_REL * np.einsum("sab...,sb->sa...", gmag, np.abs(vh))
           + 4 * (n + 2) * U * np.einsum("sab...,sb->sa...", np.abs(gam), np.abs(vh)))
    Jf = (np.einsum("sa...,sa->s...", eps, np.abs(dv) + (e0 + e1) / dt)
          + 4 * (n + 2) * U * np.einsum("sa...,sa->s...", aJv, np.abs(dv) + np.abs(s) + np.abs(vh)))
    return {"Jc": Jc, "aJc": np.abs(Jc), "Jk": Jk, "Jf": Jf}


def q_remainder(fab, fk, f0, qh, vh, ev_max, dq_max, geo):
    """Bound of the q-q second-order remainder of ``f = h + g`` over a step, per row entry: ``|f(q, v) - f(qh, v)
    - df/dq(qh, v) (q - qh)|`` for every ``|q - qh| <= dq_max`` and ``|v - vh| <= ev_max`` (per joint).

    fab (C, n, n, ...), fk (C, n, ...), f0 (C, ...): pinocchio's ``Y(qh + ETA (e_a + e_b), vh, 0)``,
    ``Y(qh + ETA e_a, vh, 0)``, ``Y(qh, vh, 0)``; qh, vh, ev_max, dq_max (C, n). Returns (C, ...).

    Taylor with Lagrange's remainder: ``1/2 sum_ab |d2f/dq_a dq_b (zeta, v)| dq_a dq_b``, zeta in the step's box.
    The second derivative there is bounded LOCALLY, per entry:

    * the forward difference ``H_ab = (f_ab - f_a - f_b + f_0) / ETA^2`` equals ``d2f/dq_a dq_b (xi, vh)`` at
      some xi of the rectangle ``[qh, qh + ETA (e_a + e_b)]`` (the mean-value theorem twice; a == b: the second
      difference over ``qh, qh + ETA e_a, qh + 2 ETA e_a``), up to: pinocchio's stated error ``PIN_REL`` of the
      four magnitudes and the float operations (``2 PIN_REL sum |f| / ETA^2``), the spacings' rounding (the
      corners' coordinates are rounded sums ``qh + ETA``: a relative ``1e-9`` of ``|H|`` for the mixed ones, whose
      rectangle stays exact, and ``3 sup|df/dq| ulp / ETA^2`` for the unequally spaced diagonal ones, ``ulp`` the
      spacing of the floats at ``|qh| + 4 ETA``);
    * from xi to zeta (``|zeta - xi| <= dq_max + 2 ETA`` per coordinate, two of them shifted): the third
      derivatives, ``<= 8 sup|f(., vh)| <= 8 (gamma (sum|vh|)^2 + g)`` (Bernstein, degree 2 in each angle: the
      module docstring of :mod:`ident.robots.serial_certified`), times ``sum dq_max + 4 ETA``;
    * from vh to v: ``h(q, v) - h(q, vh) = sum_ab Gamma_ab (v_a v_b - vh_a vh_b)`` and ``|d2 Gamma / dq2| <= 4
      gamma``: ``4 gamma (2 sum|vh| sum ev_max + (sum ev_max)^2)``.

    The global bound it replaces, ``4 (gamma (sum|v|)^2 + g)`` for every entry, is far above the local second
    derivatives (tests/ident/test_serial_remainder.py compares both with sampled remainders): the terms left
    global here multiply one more small factor (a step's displacement, or the speed estimate's error).
    """
    eta = ETA
    C, n = qh.shape
    ex = (slice(None),) + (None,) * (f0.ndim - 1)
    H = fab - fk[:, :, None] - fk[:, None, :]
    H += f0[:, None, None]
    mag = np.abs(fab) + np.abs(fk[:, :, None]) + np.abs(fk[:, None, :])
    mag += np.abs(f0)[:, None, None]
    np.abs(H, out=H)
    H *= (1.0 + 1e-9) / eta**2
    H += mag * (2.0 * PIN_REL / eta**2)
    del mag
    vs = np.sum(np.abs(vh), axis=1)
    dvs, dqs = np.sum(ev_max, axis=1), np.sum(dq_max, axis=1)
    sup = geo["gamma"] * vs**2 + geo["g"]  # sup over q of |f(., vh)| per unit parameter
    ulp = np.spacing(np.max(np.abs(qh), axis=1) + 4 * eta)
    glob = (8 * sup * (dqs + 4 * eta) + 3 * 2 * sup * ulp / eta**2
            + 4 * geo["gamma"] * (2 * vs * dvs + dvs * dvs))  # added to every |H_ab|
    rem = 0.5 * np.einsum("sab...,sa,sb->s...", H, dq_max, dq_max)
    rem += (0.5 * glob * dqs * dqs)[ex]
    return rem


def step_displacements(dq, e0, e1, ebar, qddm, dt):
    """The step's position excursions from its measured mid-step position ``qh`` (per step, arrays (C, n)): the
    kernel-weighted mean and the max over the step of ``|q(t) - qh|``, motion part and max with the error ``ebar``.

    The true step ``[t_j, t_j+1]``: ``q(t) = chord(t) + r(t)`` with the chord through the true end positions
    (slope ``s*``, ``|s*| <= (|dq| + e0 + e1) / dt``) and ``|r(t)| <= qdd_max (t - t_j) (t_j+1 - t) / 2``; the
    chord's middle is ``qh`` within ``ebar``. So ``|q(t) - qh| <= |t - t_mid| |s*| + |r(t)| + ebar``, whose mean
    under a weight linear on the step and >= 0 (a symmetric function's weighted mean is its plain mean) is ``|s*|
    dt / 4 + qdd_max dt^2 / 12`` (+ ebar: the position parts) and whose max is ``|s*| dt / 2 + qdd_max dt^2 / 8 +
    ebar``. Returns (dq_mean, dq_max), rounded up."""
    grow = 1 + 8 * U
    st = (np.abs(dq) + e0 + e1) * grow
    dq_mean = (st * 0.25 + qddm * (dt * dt / 12)) * grow
    dq_max = (st * 0.5 + qddm * (dt * dt / 8) + ebar) * grow
    return dq_mean, dq_max


def mass_pairs(n: int):
    """The pairs ``1 <= a <= k < n`` (0-based joints) where the mass matrix's second derivatives can be nonzero, in
    ``np.triu_indices(n - 1)`` order shifted by one: M does not depend on the first joint's angle (it turns the
    whole arm about an axis fixed in the base, a rigid rotation that leaves the kinetic energy unchanged), so every
    derivative of M in ``q_0`` is exactly 0."""
    fa, fb = np.triu_indices(n - 1)
    return fa + 1, fb + 1


def mass_derivatives(Mc, Mk, gk, Mab, gab, qh, geo):
    """The mass matrix's first and second q-derivatives at a step's mid position ``qh`` from the regressor at
    ``qh``, ``qh + ETA e_k`` and ``qh + ETA (e_a + e_k)`` (arrays over C steps, the entries last; the columns of M are
    ``Y(q, 0, e_b) - Y(q, 0, 0)``): Mc (C, b, ...) at qh (gravity subtracted); Mk (C, k, b, ...), gk (C, k, ...); Mab
    (C, P, b, ...), gab (C, P, ...) at the pairs of :func:`mass_pairs` (the others are 0).
    Returns ``(dM, eps, HB0)``, HB0 (C, P, b, ...) per pair (a, k):

    * ``dM[k, b] = (4 M(qh + ETA e_k) - 3 M(qh) - M(qh + 2 ETA e_k)) / (2 ETA)``, second-order accurate:
      ``|dM - dM_true| <= eps = ETA^2 / 3 * 8 M`` (its Taylor remainder, Bernstein's third derivative ``8 M``)
      ``+ 8 (PIN_REL + 16 u) (M + 2 g) / (2 ETA)`` (the regressor's stated error on the eight values, each of
      magnitude at most ``M + 2 g`` per unit parameter, and the formula's rounding) ``+ 8 M ulp / ETA`` (the
      positions ``qh + ETA e_k`` rounded: unequal spacings);
    * ``HB0[a, k, b] >= |d2 M_b / dq_a dq_k (xi)|`` at some xi of the rectangle ``[qh, qh + ETA (e_a + e_k)]`` (the
      mixed difference, the mean-value theorem twice, as :func:`q_remainder`'s), with the same allowances over
      ``ETA^2`` (``1e-9`` of it for the mixed spacings, ``3 sup|dM| ulp / ETA^2`` for the diagonal ones); at
      another point zeta add ``8 M |zeta - xi|_1`` (:func:`mass_hessian_bound`)."""
    eta, mbar = ETA, geo["M"]
    n = Mc.shape[1]
    fa, fb = mass_pairs(n)
    diag = np.flatnonzero(fa == fb)  # the pairs (k, k), k >= 1
    M1 = Mk - gk[:, :, None]
    dM = np.zeros_like(M1)  # dM / dq_0 = 0 exactly (mass_pairs)
    dM[:, 1:] = (4.0 * M1[:, 1:] - 3.0 * Mc[:, None] - (Mab[:, diag] - gab[:, diag, None])) / (2 * eta)
    ulp = np.spacing(np.max(np.abs(qh), axis=1) + 4 * eta).reshape((-1,) + (1,) * (Mk.ndim - 1))
    grow = 1 + 8 * U
    vmag = mbar + 2 * geo["g"]  # |Y(q, 0, e_b)| + |Y(q, 0, 0)| per unit parameter
    eps = ((eta * eta / 3) * 8 * mbar + (PIN_REL + 16 * U) * 8 * vmag / (2 * eta) + 8 * mbar * ulp / eta) * grow
    eps = eps * (np.arange(n) > 0).reshape((1, n) + (1,) * (Mk.ndim - 2))  # (C, k, 1, ...): exact for k = 0
    # per pair a <= k: M(qh + ETA (e_a + e_k)) - M(qh + ETA e_a) - M(qh + ETA e_k) + M(qh), as Mab - (gab + M1_a +
    # M1_k - Mc) in one buffer
    S = M1[:, fa]
    S += M1[:, fb]
    S -= Mc[:, None]
    S += gab[:, :, None]
    H = np.subtract(Mab, S, out=S)
    H = np.abs(H, out=H)
    H *= (1 + 1e-9) * grow / (eta * eta)
    H += (((PIN_REL + 16 * U) * 4 * vmag + 3 * 2 * mbar * ulp) * grow / (eta * eta))
    return dM, eps, H


def mass_hessian_bound(HB0, dq_max, mbar):
    """``HB`` (C, P, b, ...): ``|d2 M_b / dq_a dq_k|`` per pair a <= k anywhere in the step's box ``|q - qh| <=
    dq_max``: HB0 of :func:`mass_derivatives` plus ``8 M`` times the l1 distance from its rectangle, ``sum dq_max + 4
    ETA`` (in place)."""
    HB0 += (8 * mbar * (np.sum(dq_max, axis=1) + 4 * ETA) * (1 + 8 * U)).reshape((-1,) + (1,) * (HB0.ndim - 1))
    return HB0


def _pair_sum(HB, z):
    """``sum_b HB[:, P, b] z_b`` (C, P, ...), in index order."""
    ex = (None,) * (HB.ndim - 3)
    return np.sum(HB * z[(slice(None), None, slice(None)) + ex], axis=2)


def _pair_contract(tz, x, y):
    """``sum_ak t[a, k] x_a y_k`` with ``t`` symmetric in (a, k) given per pair of :func:`mass_pairs` (tz (C, P,
    ...); 0 on the others), in index order: the pair (a, k) stands for both orders."""
    fa, fb = mass_pairs(x.shape[1])
    coef = x[:, fa] * y[:, fb] + np.where(fa != fb, x[:, fb] * y[:, fa], 0.0)
    return np.sum(tz * coef[(slice(None), slice(None)) + (None,) * (tz.ndim - 2)], axis=1)


def hessian_quadratic(HB, x, w):
    """``sum_klb HB[k, l, b] x_k x_l w_b`` per step (HB (C, P, b, ...) per pair k <= l, x, w (C, n))."""
    return _pair_contract(_pair_sum(HB, w), x, x)


def c2_terms(HB, vmax, st, ebar, dq_max, qddm, mbar, dt):
    """The q-variation of ``c2 = Mdot(q, v) v = sum_ab dM_b/dq_a v_a v_b`` over a step against its value at the
    measured mid position qh (per step: HB (C, a, k, b, F) of :func:`mass_hessian_bound`, vmax (C, n) the step's speed
    bound, st (C, n) the true step speed's, ebar, dq_max (C, n) of :func:`step_displacements`). Returns ``(pos, mot,
    slope)``, each (C, F): per unit kernel weight, the parts of the mid position's error and of the motion, and per
    unit ``|k'|`` the chord's.

    ``c2(q(t), v) - c2(qh, v) = sum_k D_k(qh, v) (q - qh)_k + R``, ``D_k = dc2/dq_k = sum_ab d2 M_b/dq_a dq_k v_a
    v_b``: over the step's box ``|D_k| <= DB_k = sum_ab HB_akb vmax_a vmax_b`` (HB of :func:`mass_hessian_bound`),
    ``|dD_k / dv_a| <= DV_ka = sum_b (HB_akb + HB_bka) vmax_b``,
    and ``|R| <= 4 M (sum vmax)^2 (sum dq_max)^2`` (Bernstein: ``|d3 M| <= 8 M``). With ``q - qh = (t - t_mid) s* + r(t)
    + eps`` (:func:`step_displacements`): the mid position's error ``DB_k ebar_k`` (pos); the chord against the kernel
    ``D_k(qh, s*) s*_k int k (t - t_mid) = D_k s*_k k' dt^3 / 12`` (slope) plus ``(D_k(v(t)) - D_k(s*)) (t - t_mid)
    s*_k``, ``|v_a - s*_a| <= qdd_max_a ((t - t_mid)^2 + dt^2 / 4) / dt``, ``int k |t - t_mid| |v_a - s*_a| <= max k 3
    qdd_max_a dt^3 / 32 <= 2 K_w 3 qdd_max_a dt^2 / 32`` (k >= 0 linear on the step), the chord's remainder ``int k
    |D_k| |r_k| <= K_w DB_k qdd_max_k dt^2 / 12`` and R (mot)."""
    ex = (slice(None),) + (None,) * (HB.ndim - 3)  # (C,) over (C, entries)
    # every term is a sum_akb HB[a, k, b] x_a y_k z_b: the b-sums first (per pair a <= k), in index order
    cq = np.broadcast_to(qddm * (2 * 3 * dt * dt / 32), vmax.shape)
    tv, tc = _pair_sum(HB, vmax), _pair_sum(HB, cq)
    grow = 1 + 16 * U
    vmx = np.sum(vmax, axis=1)
    pos = _pair_contract(tv, vmax, ebar)  # sum_k DB_k ebar_k
    slope = _pair_contract(tv, vmax, st)
    mot = _pair_contract(tv, vmax, np.broadcast_to(qddm * (dt * dt / 12), vmax.shape))
    # sum_ka DV_ka st_k c_a, DV_ka = sum_b (HB[a, k, b] + HB[b, k, a]) vmax_b
    mot += _pair_contract(tv, cq, st) + _pair_contract(tc, vmax, st)
    mot += (4 * mbar * vmx * vmx * np.sum(dq_max, axis=1) ** 2)[ex]
    return pos * grow, mot * grow, slope * ((dt**3 / 12) * grow)


def _bound(d, c, mag, flt):
    """``|d| + c + flt (mag + |d| ETA)`` evaluated in that order, overwriting d (with ``mag + x`` as ``x + mag``:
    the same float)."""
    a = np.abs(d, out=d)
    t = a * ETA
    t += mag
    t *= flt
    a += c
    a += t
    return a


def local_bounds(robot, geo, grid: StepGrid, j0: int, j1: int) -> dict:
    """The local data and radii aggregates of steps ``j0 .. j1 - 1`` (the per-step bounds of
    :mod:`ident.robots.serial_certified`), each (C, F), (C, n, F) or (C, n, n, F) for C = j1 - j0 steps and the F
    live entries: ``g0``, ``f0``, ``Mc``, ``dlt``, ``c2`` (``Mdot(qh, vh) vh``), ``c2mag``, ``L_mot``, ``H_mot``,
    ``Gq``, ``H_pos``, ``Dloc``, ``Ecur``, ``Jv`` (``d f2 / dv``) and the speed-linear terms (the same arithmetic as
    the per-step reference, batched)."""
    J = np.arange(j0, j1)
    eta, dt, n = ETA, grid.dt, grid.n
    vh = grid.vh[J]
    p = _regressor_calls(robot, grid.qbar[J], vh)
    g0, f0 = p["g0"], p["f0"]
    C = J.size
    ha = p["ha"] - g0[:, None]
    gam = np.zeros((C, n, n) + g0.shape[1:])
    for a in range(n):
        gam[:, a, a] = ha[:, a]
        for b in range(a + 1, n):
            gam[:, a, b] = gam[:, b, a] = 0.5 * (p["pair"][:, a, b] - g0 - ha[:, a] - ha[:, b])
    Mc = p["Mc"] - g0[:, None]  # (s, b, i, c): column b of M per unit parameter
    Jh = 2 * np.einsum("sabf,sb->saf", gam, vh)  # dh/dv, exact: h is quadratic in v
    mag = np.abs(f0) + np.abs(g0)
    Jq = (p["fk"] - f0[:, None]) / eta
    # the mass matrix's derivatives: dM second-order accurate (its error eps), the second derivatives' bounds HB0
    dM, eps, HB0 = mass_derivatives(Mc, p["Mk"], p["gk"], p["Mab"], p["gab"], grid.qbar[J], geo)
    dJv = p["Vp"]  # (s, k, a, i, c): (0.5 (Vp - Vm) - Jh) / eta, only |dJv| is read
    dJv -= p["Vm"]
    dJv *= 0.5
    dJv -= Jh[:, None]
    dJv /= eta
    flt = 4 * PIN_REL / eta
    # the Lagrangian form's velocity term c2 = Mdot v = sum_kb dM[k, b] v_k v_b (a quadratic form in v whose matrix
    # is the symmetric part Gc of dM), and f2 = g + h - c2 (= g - dT/dq): its matrix gam - Gc, its speed gradient
    Gc = 0.5 * (dM + np.swapaxes(dM, 1, 2))
    gam2 = gam - Gc
    Jv = 2 * np.einsum("sabf,sb->saf", gam2, vh)
    c2 = np.einsum("sabf,sa,sb->sf", Gc, vh, vh)
    avh = np.abs(vh)
    c2mag = np.einsum("sabf,sa,sb->sf", np.abs(Gc), avh, avh)
    epsG = 0.5 * (eps + np.swapaxes(eps, 1, 2))  # dM's error, hence Gc's (symmetrised)
    # bounds on the true derivatives (forward-difference truncation by Bernstein, pinocchio's float error)
    vs = np.sum(avh, axis=1)
    c4 = (slice(None), None, None)  # (C,) over (C, n, F)
    JqB = np.abs(Jq) + (eta / 2 * 4 * (geo["gamma"] * vs**2 + geo["g"]))[c4] + flt * (mag[:, None] + np.abs(Jq) * eta)
    dMB = np.abs(dM) + eps  # |dM_true| at qh
    dJvB = _bound(dJv, (4 * eta * geo["gamma"] * (vs + 1))[c4 + (None,)], 2 * mag[:, None, None], flt)
    # speeds and position boxes of the step (true motion)
    ebar = grid.ebar[J]
    ev_max = grid.ev_mot_max + grid.ev_pos[J]
    vmax = avh + ev_max  # bound on |v(t)| over the step
    qddm = grid.qddm
    e0, e1 = grid.e[J], grid.e[J + 1]
    dq_mean, dq_max = step_displacements(grid.dq[J], e0, e1, ebar, qddm, dt)
    rem_qq = q_remainder(p["fab"], p["fk"], f0, grid.qbar[J], vh, ev_max, dq_max, geo)
    aY = np.abs(p["ha"])
    gmag = np.abs(p["pair"])  # filled for a < b only: symmetric
    gmag += np.swapaxes(gmag, 1, 2).copy()
    gmag += aY[:, :, None] + aY[:, None, :]
    gmag += 3 * np.abs(g0)[:, None, None]
    absGc = np.abs(Gc)
    lin = speed_linear(Jv, np.abs(gam) + absGc, gmag, vh, grid.dq[J], e0, e1, qddm, dt)
    lin["Jf"] += 4 * (n + 2) * U * c2mag  # c2's own products and sums
    del p, Jq, dJv, aY, gmag, dM
    c3 = (slice(None), None)  # (C,) over (C, F)
    mbar = geo["M"]
    # -k' int_step M(q) qd against -k' M(qh) dq: the path's deviation from the mid-step value, to first order with
    # dM (at the true mid-chord: + 4 M ebar) against the chord's antisymmetry, second order by Bernstein
    st = (np.abs(grid.dq[J]) + e0 + e1) / dt * (1 + 4 * U)  # bound on the true step speed |s*|
    P1 = (np.einsum("sk,b->skb", st, qddm * (3 * dt**3 / 32))
          + np.einsum("k,sb->skb", qddm * (dt**3 / 12), st + qddm * (dt / 2)))
    dqx = st * (dt / 2) + qddm * (dt * dt / 8)
    HB = mass_hessian_bound(HB0, dq_max, mbar)
    del HB0
    L_mot = np.einsum("skbf,skb->sf", dMB, P1) + (4 * mbar * np.sum(ebar, axis=1) * np.sum(P1, axis=(1, 2)))[c3]
    L_mot += 0.5 * hessian_quadratic(HB, dqx, st * dt + qddm * (dt * dt / 3))
    # f2(q(t), qd(t)) against f2(qh, vh): g + h with the local first order in q, the q-q remainder (local Hessian),
    # the q-v cross term; c2's q-variation by Bernstein (|dc2/dq_k| <= 4 M (sum|v|)^2); dM's forward-difference
    # error in c2 over the step's speeds; the v-quadratic part exactly (Gq, Q_pos: matrix gam - Gc)
    absG2 = np.abs(gam2)
    mot = grid.ev_mot_max
    Gq = np.einsum("sabf,a,b->sf", absG2, qddm, qddm)  # the quadratic speed term's, per kernel weight (window sums)
    dvs, dqs = np.sum(ev_max, axis=1), np.sum(dq_max, axis=1)
    c2p, c2m, c2k = c2_terms(HB, vmax, st, ebar, dq_max, qddm, mbar, dt)
    del HB
    rem = (rem_qq + np.einsum("skaf,sk,sa->sf", dJvB, dq_max, ev_max) + (2 * geo["gamma"] * dvs * dvs * dqs)[c3]
           + c2m)
    Cfd = np.einsum("sabf,sa,sb->sf", epsG, vmax, vmax)
    H_mot = np.einsum("skf,sk->sf", JqB, dq_mean) + rem + Cfd  # Jv (v - vh): speed_linear; Gq: the rows
    # Q_all - Q_mm without the cancellation: ev_max = mot + ev_pos, so the difference is a sum of non-negative
    # products (|G| mot ev_pos twice and |G| ev_pos ev_pos)
    pos = grid.ev_pos[J]
    Q_pos = (np.einsum("sabf,a,sb->sf", absG2, mot, pos) + np.einsum("sabf,sa,b->sf", absG2, pos, mot)
             + np.einsum("sabf,sa,sb->sf", absG2, pos, pos))
    H_pos = np.einsum("skf,sk->sf", JqB, ebar) + Q_pos + c2p
    dlt = np.einsum("skbf,sk->sbf", dMB, ebar) + (2 * mbar * np.sum(ebar, axis=1) ** 2)[c4]
    L_mot += c2k  # c2's q-variation along the chord against the kernel's slope, |k'| too
    return {"g0": g0, "f0": f0, "Mc": Mc, "dlt": dlt, "c2": c2, "c2mag": c2mag, "L_mot": L_mot, "H_mot": H_mot,
            "Gq": Gq, "H_pos": H_pos, "Dloc": np.einsum("sbf,sb->sf", dlt, np.abs(grid.dq[J]) + e0 + e1),
            "Ecur": np.einsum("sbf,sb->sf", np.abs(Mc), e0), "Jv": Jv, **lin}


def _sample_terms(grid: StepGrid, j0: int, cur: dict, Mc_prev) -> dict:
    """The sample-instant aggregates of samples j0 .. j0 + C - 1 (between steps j - 1 and j): ``Eknot``,
    ``Ediff``; Mc_prev : the mass-matrix columns of steps j0 - 1 .. j0 + C - 2."""
    J = np.arange(j0, j0 + cur["Mc"].shape[0])
    e = grid.e[J]
    return {"Eknot": np.einsum("sbf,sb->sf", np.abs(Mc_prev), e),
            "Ediff": np.einsum("sbf,sb->sf", np.abs(Mc_prev - cur["Mc"]), e)}


class _StepBuffer:
    """The per-step arrays (:data:`_KEEP`) of the consecutive steps ``b0 .. b0 + size - 1``, (steps, F) or (steps,
    n, F) with F = 5 n (n + 1) live entries; :meth:`advance` drops the steps before a new first one and evaluates
    the missing ones, ``batch`` steps per regressor batch."""

    def __init__(self, robot, geo, grid: StepGrid, capacity: int, batch: int = 32):
        self.robot, self.geo, self.grid, self.batch = robot, geo, grid, batch
        n = grid.n
        F = live_entries(n).size
        self.arr = {k: np.empty((capacity, n, F) if k in ("Mc", "aMc", "Jv") else (capacity, F)) for k in _KEEP}
        self.b0, self.size = 0, 0

    def advance(self, first: int, end: int) -> None:
        """Hold steps ``first .. end - 1`` (first >= the held first step, end - first <= capacity)."""
        keep = max(0, self.b0 + self.size - first) if self.size else 0
        if keep and first > self.b0:
            src = first - self.b0
            for a in self.arr.values():
                a[:keep] = a[src: src + keep]
        self.b0, self.size = first, keep
        for j0 in range(first + keep, end, self.batch):
            j1 = min(end, j0 + self.batch)
            cur = local_bounds(self.robot, self.geo, self.grid, j0, j1)
            C = j1 - j0
            Mc = cur["Mc"]
            held = j0 - self.b0
            if held:
                Mc_prev = np.concatenate([self.arr["Mc"][held - 1: held].reshape((1,) + Mc.shape[1:]), Mc[:-1]])
            else:  # no step before: the first step's sample terms are never read
                Mc_prev = np.concatenate([np.full_like(Mc[:1], np.nan), Mc[:-1]])
            cur.update(_sample_terms(self.grid, j0, {"Mc": Mc}, Mc_prev))
            cur.update(fg=cur["f0"] - cur["g0"], af0=np.abs(cur["f0"]), ag0=np.abs(cur["g0"]), aMc=np.abs(Mc))
            for key, a in self.arr.items():
                a[held: held + C] = cur[key].reshape((C,) + a.shape[1:])
            self.size = held + C


def _view(arr, first, count: int, stride: int, length: int):
    """(count, length, ...) read-only view with ``[r, l] = arr[first + r stride + l]`` (no copy)."""
    st = arr.strides
    need = first + (count - 1) * stride + length
    if first < 0 or need > arr.shape[0]:
        raise IndexError(f"window view [{first}, {need}) outside the {arr.shape[0]} held rows")
    return as_strided(arr[first:], shape=(count, length) + arr.shape[1:], strides=(stride * st[0],) + st,
                      writeable=False)


def _shift_diff_sum(T, ew, d: int):
    """``sum_o sum_a |G[o, a, :]| ew[o, a]`` per window for ``G[o] = [o >= d] T[o - d] - [o < L] T[o]``
    (o < L + d) and T (R, L, n, F), ew (R, L + d, n): the reference's ``|G|`` entry by entry (the same
    differences). Returns (R, F)."""
    L = T.shape[1]

    def contract(absg, e):
        return np.einsum("roa,roaf->rf", e, absg)

    lo = min(d, L)
    out = contract(np.abs(T[:, :lo]), ew[:, :lo])  # G = -T[o]
    if d < L:  # G = T[o - d] - T[o]
        mid = np.subtract(T[:, :L - d], T[:, d:])
        out += contract(np.abs(mid, out=mid), ew[:, d:L])
    hi = max(L, d)
    return out + contract(np.abs(T[:, hi - d:]), ew[:, hi:])  # G = T[o - d]


def _weights(kern: Kernel) -> dict:
    k = kern.knots
    kp = np.diff(k) / kern.h  # (L,) slopes [1/s^2]
    return {"k": k, "K1": kern.integrals, "kp": kp, "akp": np.abs(kp),
            "dkp": np.abs(np.diff(np.concatenate([[0.0], kp, [0.0]])))}  # |k'_{j-1} - k'_j| at sample j


def _correlations(buf: _StepBuffer, grid: StepGrid, wt: dict, starts, stride: int) -> dict:
    """The window sums of per-step arrays with kernel weights (BLAS over strided views), windows ``starts``
    (all held by ``buf``), and the per-(window, step) accelerations ``u`` (R, L, n). Returns (R, F) arrays."""
    K1, akp, dkp = wt["K1"], wt["akp"], wt["dkp"]
    L = K1.size
    R, s0 = starts.size, int(starts[0])
    rel = s0 - buf.b0

    def V(key, off=0, length=L):
        return _view(buf.arr[key], rel + off, R, stride, length)

    # the mass term of the Lagrangian form, -k'_w M_w dq_w: the regressor's acceleration argument
    u = -wt["kp"][:, None] * _view(grid.dq, s0, R, stride, L)
    out = {"mass_motion": akp @ V("L_mot"),
           "coriolis_motion": K1 @ V("H_mot") + akp @ V("Jk") + wt["cq"] @ V("Gq"),
           "mass_position": akp @ V("Dloc"), "coriolis_position": K1 @ V("H_pos"),
           # measurement through the exact gradient of sum_j k'_j M_j dq_j (sample jj of the window)
           "gradient_position": dkp[0] * V("Ecur", 0, 1)[:, 0] + dkp[1:L] @ V("Eknot", 1, L - 1)
           + akp[1:L] @ V("Ediff", 1, L - 1) + dkp[L] * V("Eknot", L, 1)[:, 0],
           "gK": (K1 - 1.0) @ V("g0") + K1 @ V("Jc") - K1 @ V("c2"),
           "mag": np.abs(K1 - 1.0) @ V("ag0") + K1 @ V("aJc") + K1 @ V("c2mag"), "Jf": K1 @ V("Jf"),
           "rsum": (1.0 + K1) @ V("ag0") + K1 @ V("af0")}
    return out, u


def _pair_terms(buf: _StepBuffer, grid: StepGrid, wt: dict, starts, stride: int, u) -> dict:
    """The per-(window, step) terms of windows ``starts``: the regressor at the window's scaled speed and
    acceleration (its window sum ``Wi``, the sum of its magnitudes ``mag``, the reconstruction's magnitudes
    ``rsum``) and the speed estimates' gradient term (``cG``). Returns (R, F) arrays; u : (R, L, n) the windows'
    accelerations."""
    K1 = wt["K1"]
    L = K1.size
    R, rel = starts.size, int(starts[0]) - buf.b0
    dt = grid.dt
    A = buf.arr

    def V(key, off=0, length=L):
        return _view(A[key], rel + off, R, stride, length)

    # Y(qh_j, sqrt(K_w) vh_j, u_w) = g0_j + K_w (f0_j - g0_j) + sum_b Mc_j[b] u_w[b]
    Y = V("g0") + K1[:, None] * V("fg")
    Y += np.matmul(u[:, :, None, :], V("Mc"))[:, :, 0]
    out = {"Wi": Y.sum(axis=1), "mag": np.abs(Y, out=Y).sum(axis=1)}
    out["rsum"] = np.einsum("rlb,rlbf->rf", np.abs(u), V("aMc"))
    # the speed's linear term at the true step speeds (speed_linear): sum_j K1_j Jv_j (delta_{j+1} - delta_j) / dt,
    # summed by parts
    out["cG"] = _shift_diff_sum(K1[:, None, None] * V("Jv"), _view(grid.e, int(starts[0]), R, stride, L + 1), 1) / dt
    return out


def inertial_rows(robot, geo, q, e, spec, m: int, kern: Kernel, starts, progress=None, *, memory: int = 2**27):
    """The inertial columns' window sums of the certified equation, all windows at once.

    robot : :class:`ident.robots.serial.SerialRobot`; geo : :func:`ident.robots.serial_certified.geometry_bounds`;
    q, e : (N, n) measured positions and their error bounds [rad]; spec : the log's ``ErrorSpec``; m : secant
    half-span [steps]; kern : the window kernel (L steps); starts : (R,) first sample of each window (equally
    spaced, ``m <= starts``, ``starts + L + m < N``); progress : callable(done, total) or None; memory : bytes for
    the per-(window, step) temporaries (a few windows at a time).

    Returns ``(Wi, mag, recon, parts)``: Wi (R, n, 10 n) the window sums of the regressor [N m per unit
    parameter], mag (R, n, 10 n) the magnitudes it sums (``sum |Y| + |K - 1| |g0|``, the floating-point radius'
    base), recon (R, n, 10 n) the bound of the regressor reconstruction's rounding (module docstring), parts
    {name: (R, n, 10 n)} the radii of :data:`PARTS` (before outward rounding). Each is 0 at the entries a chain
    cannot fill (:func:`ident.robots.chain.live_entries`: joint j's row in a body's columns before j), where the
    regressor is zero for every state; the per-step stage evaluates the live entries only.
    """
    return inertial_family(robot, geo, q, e, spec, m, [(kern, starts)], progress, memory=memory)[0]


class _KernelRows:
    """One kernel's windows and output arrays in :func:`inertial_family`."""

    def __init__(self, kern: Kernel, starts, n: int, m: int, memory: int):
        self.starts = np.asarray(starts, dtype=np.int64)
        self.L, self.R = kern.steps, self.starts.size
        if self.R == 0:
            raise ValueError("starts must hold at least one window")
        self.stride = int(self.starts[1] - self.starts[0]) if self.R > 1 else 1
        if self.R > 1 and (self.stride < 1 or np.any(np.diff(self.starts) != self.stride)):
            raise ValueError("starts must be equally spaced and increasing")
        F = live_entries(n).size
        self.wt = dict(_weights(kern), cq=quadratic_speed_weights(kern, m))
        self.rc = max(1, int(memory // (8 * 4 * n * F * (self.L + 2 * m + 2))))  # windows per batch of pair terms
        # module docstring; the sum's rounding
        self.c_rec = 2 * (n + 5) * U * (1 + 2 * (self.L * (n + 3) + 2) * U) * (1 + 4 * U)
        self.out = {name: np.empty((self.R, F)) for name in ("Wi", "mag", "recon") + PARTS}
        self.done = 0  # windows computed

    def compute(self, buf: _StepBuffer, grid: StepGrid, upto: int) -> None:
        """The windows ``done .. upto - 1`` (their steps held by ``buf``)."""
        out, L = self.out, self.L
        for r0 in range(self.done, upto, self.rc):
            sub = self.starts[r0: min(upto, r0 + self.rc)]
            cor, u = _correlations(buf, grid, self.wt, sub, self.stride)
            pair = _pair_terms(buf, grid, self.wt, sub, self.stride, u)
            rows = slice(r0, r0 + sub.size)
            out["Wi"][rows] = pair["Wi"] + cor["gK"]
            out["mag"][rows] = pair["mag"] + cor["mag"]
            out["recon"][rows] = up(up((pair["rsum"] + cor["rsum"]) * self.c_rec)
                                    + up(cor["Jf"] * (1 + 2 * (L + 2) * U)))
            for name in PARTS:
                out[name][rows] = cor[name]
            out["coriolis_position"][rows] += pair["cG"]
        self.done = upto

    def result(self, n: int):
        live = live_entries(n)

        def full(a):  # the structural zeros back in
            out = np.zeros((self.R, n * 10 * n))
            out[:, live] = a
            return out.reshape(self.R, n, 10 * n)

        o = self.out
        return full(o["Wi"]), full(o["mag"]), full(o["recon"]), {k: full(o[k]) for k in PARTS}


def inertial_family(robot, geo, q, e, spec, m: int, kernels, progress=None, *, memory: int = 2**27) -> list:
    """:func:`inertial_rows` of several kernels in one pass over the log: ``kernels`` a list of ``(kern, starts)``;
    returns one ``(Wi, mag, recon, parts)`` per kernel, in order.

    Every step's pinocchio stage (:func:`local_bounds`, most of the time) is evaluated once for all the kernels:
    the log is walked in blocks of about ``max(L_max, 256)`` window starts, and each block's windows of every
    kernel read the same held steps. The steps a window reads, and each window's arithmetic, are those of the
    kernel alone: the same bits (tests/ident/test_serial_certified.py)."""
    grid = StepGrid(q, e, spec.sample_period, spec.qdd_max, m)
    n = grid.n
    rows = [_KernelRows(kern, starts, n, m, memory) for kern, starts in kernels]
    L_max = max(k.L for k in rows)
    span = max(L_max, 256)  # window starts per block
    buf = _StepBuffer(robot, geo, grid, span + L_max + 2)
    total = sum(k.R for k in rows)
    while True:
        todo = [k for k in rows if k.done < k.R]
        if not todo:
            break
        first = min(int(k.starts[k.done]) for k in todo)
        upto = [int(np.searchsorted(k.starts, first + span, side="left")) for k in todo]
        end = max(int(k.starts[u - 1]) + k.L + 1 for k, u in zip(todo, upto) if u > k.done)
        buf.advance(first - 1, end)
        for k, u in zip(todo, upto):
            if u > k.done:
                k.compute(buf, grid, u)
        if progress is not None:
            progress(sum(k.done for k in rows), total)
    return [k.result(n) for k in rows]
