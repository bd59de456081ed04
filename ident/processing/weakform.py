"""The weak form of the dynamic equation on sampled data: one kernel on both sides, radii from an ErrorSpec only.

Each processed row applies one kernel ``k(t)`` to both sides of ``tau = W(q, qd, qdd) theta + e``. The kernel
is supported on ``L`` sample steps ``[t_j0, t_j0+L]``, linear between sample instants (knots at the samples)
and zero at both ends, so with ``s_w`` its slope on step ``w`` and ``K_w`` its integral over that step:

* torques held over each step (``torque_timing = "hold"``): ``integral k tau = sum_w K_w tau_w`` exactly, and the
  torque error enters as at most ``torque_error * sum |K_w|``;
* a column of the form ``dP/dt + F`` with ``P = P(q, qd)``, ``F = F(q, qd)`` (inertial terms in Lagrangian
  form: ``P = dT/dqd``; the Imot column is ``P = qd_i``, the viscous one ``F = qd_i``) becomes, by parts,
  ``-integral k' P + integral k F = sum_w (-s_w integral_w P + integral_w k F)``: no acceleration anywhere;
* on each step ``P`` and ``F`` are evaluated at the secant state ``(q_m, v) = ((q_j + q_j+1) / 2,
  (q_j+1 - q_j) / h)`` of the measured positions. The TRUE motion on the step differs from the secant line by
  at most ``|q(t) - q_m| <= qd_max h / 2`` and ``|qd(t) - v| <= qdd_max h / 2``, ``integral_w (qd - v) = 0``
  exactly and ``|integral_w (q - q_m)| <= qdd_max h^3 / 12`` (the chord remainder), so the truncation radius
  needs only the stated ``qd_max`` and ``qdd_max`` (no bound on the jerk, which does not exist for held torques);
* the encoder error enters through the exact gradient of the row functional with respect to the measured
  positions (for the Imot column: summation by parts, ``sum_u |s_u - s_u-1| e_u``), plus a second-order term.

This module holds the kernel, the row windows and the generic, robot-independent parts (torque side, the
columns ``qd_i`` of ``P`` or ``F`` and the Coulomb sign columns, the nonlinear-column functional with its
gradient and remainders); a robot module supplies its configuration-dependent ``P`` and ``F``
(:mod:`ident.robots.h4_certified`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from h4bench.ident.numerics.interval import dot_error, down, up

__all__ = ["KERNEL_SHAPES", "Kernel", "NonlinearSteps", "RowWindows", "coulomb_columns", "make_kernel",
           "nonlinear_columns", "nonlinear_rows", "nonlinear_steps",
           "imot_columns", "row_check", "row_windows", "torque_rows", "torque_side_terms", "viscous_columns"]

KERNEL_SHAPES = ("hann", "triangle")


@dataclass(frozen=True)
class Kernel:
    """A kernel linear between sample instants: ``knots`` (L + 1,) its values at the window's sample instants
    [1/s] (zero at both ends), ``h`` the sample period [s]."""

    knots: np.ndarray
    h: float

    @property
    def steps(self) -> int:
        return self.knots.size - 1

    @property
    def integrals(self) -> np.ndarray:
        """(L,) ``K_w`` = integral of k over step w (trapezoid, exact for a linear piece) [-]."""
        return 0.5 * self.h * (self.knots[:-1] + self.knots[1:])

    @property
    def slopes(self) -> np.ndarray:
        """(L,) ``s_w`` = k' on step w [1/s^2]."""
        return np.diff(self.knots) / self.h

    @property
    def mids(self) -> np.ndarray:
        """(L,) k at the middle of step w [1/s]."""
        return 0.5 * (self.knots[:-1] + self.knots[1:])

    @property
    def l1(self) -> float:
        """Upper bound of ``integral |k|`` (the knots are >= 0, so it is ``sum K_w``, rounded up)."""
        return float(up(np.sum(self.integrals) * (1 + 4 * self.steps * 2.0**-53)))


def make_kernel(steps: int, h: float, shape: str = "hann") -> Kernel:
    """A kernel of ``steps`` sample steps (``steps + 1`` knots, both ends 0), unit integral.

    shape : ``"hann"`` (``1 - cos(2 pi u / L)``: smooth, its slope's total variation ~ 4 pi / L^2 per unit
    integral, which scales the encoder radius as ``1 / L^2``) or ``"triangle"`` (a hat).
    """
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 2:
        raise ValueError(f"steps must be an integer >= 2 (the kernel's length in sample steps), got {steps!r}")
    if not (np.isfinite(h) and h > 0):
        raise ValueError(f"h must be a finite sample period > 0 [s], got {h!r}")
    if shape not in KERNEL_SHAPES:
        raise ValueError(f"shape must be one of {KERNEL_SHAPES}, got {shape!r}")
    u = np.arange(steps + 1) / steps
    k = 1.0 - np.cos(2 * np.pi * u) if shape == "hann" else 1.0 - np.abs(2 * u - 1)
    k[0] = k[-1] = 0.0
    k = k / (h * np.sum(0.5 * (k[:-1] + k[1:])))
    return Kernel(knots=k, h=float(h))


@dataclass(frozen=True)
class RowWindows:
    """Row windows on a record of n samples: window r covers samples ``start[r] .. start[r] + L``."""

    start: np.ndarray
    steps: int

    @property
    def centre(self) -> np.ndarray:
        """(R,) the sample each row stands for (the window's middle)."""
        return self.start + self.steps // 2

    def gather(self, per_step: np.ndarray) -> np.ndarray:
        """(S, ...) per-step array -> (R, L, ...) the steps of each window."""
        idx = self.start[:, None] + np.arange(self.steps)[None, :]
        return per_step[idx]

    def gather_knots(self, per_sample: np.ndarray) -> np.ndarray:
        """(n, ...) per-sample array -> (R, L + 1, ...) the samples of each window."""
        idx = self.start[:, None] + np.arange(self.steps + 1)[None, :]
        return per_sample[idx]


def row_windows(n_samples: int, steps: int, stride: int) -> RowWindows:
    """Windows of ``steps`` steps every ``stride`` samples, all inside the record (no edge trimming needed:
    the kernel is zero at both ends of its support)."""
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or stride < 1:
        raise ValueError(f"stride must be an integer >= 1, got {stride!r}")
    if n_samples < steps + 1:
        raise ValueError(f"the log must have at least {steps + 1} samples for a kernel of {steps} steps, "
                         f"got {n_samples}")
    return RowWindows(start=np.arange(0, n_samples - steps, stride, dtype=np.int64), steps=int(steps))


def torque_rows(tau: np.ndarray, windows: RowWindows, kernel: Kernel, timing: str = "hold"):
    """The torque side ``y`` (R, n_j) [N m] of each row, its floating-point error bound (R, n_j) and an upper bound
    of ``sum |c|`` of the torque weights (the factor of the torque error bound).

    timing : ``"hold"`` (torque k held over step k: ``y = sum_w K_w tau_w``, exact) or ``"sample"`` (tau_k the
    torque at instant k: ``y`` is the exact integral of k times the linear interpolation of the samples, weights
    ``c_u = h (k_u-1 / 6 + k_u / 3) + h (k_u / 3 + k_u+1 / 6)``; the applied torque's deviation from the
    interpolation of its own samples is at most ``2 rho min(t, h - t)`` on a step for ``|d tau / dt| <= rho``,
    whose integral against the step's linear k is ``rho h / 2 K_w``: the caller adds ``rho h / 2`` times the
    returned factor).
    """
    tau = np.asarray(tau, dtype=float)
    if timing == "hold":
        K = kernel.integrals
        taus = windows.gather(tau[:-1])  # held torque of each step
        y = np.einsum("w,rwj->rj", K, taus)
        return y, dot_error(np.einsum("w,rwj->rj", np.abs(K), np.abs(taus)), kernel.steps), kernel.l1
    if timing != "sample":
        raise ValueError(f"timing must be 'hold' or 'sample', got {timing!r}")
    k, h = kernel.knots, kernel.h
    c = np.zeros(k.size)
    c[:-1] += h * (k[:-1] / 3 + k[1:] / 6)
    c[1:] += h * (k[:-1] / 6 + k[1:] / 3)
    taus = windows.gather_knots(tau)  # (R, L + 1, n_j)
    y = np.einsum("u,ruj->rj", c, taus)
    fp = dot_error(np.einsum("u,ruj->rj", np.abs(c), np.abs(taus)), kernel.steps + 1)
    # c's own rounding (4 operations per weight) is absorbed by the factor's relative margin
    return y, fp, float(up(np.sum(np.abs(c)) * (1 + (8 * kernel.steps + 32) * 2.0**-53)))


def torque_side_terms(spec, l1: float) -> dict:
    """The torque side's bound of every row of one kernel, by origin, per joint (n_j,) [N m], each rounded up:
    ``torque`` the stated torque error ``torque_error l1``; ``timing`` the applied torque's change over the
    ``latency`` and, for sample-instant torques, its deviation from the samples' interpolation (``torque_rate
    (latency + h / 2) l1``, :func:`torque_rows`; 0 without a ``torque_rate``, where the spec's own check allows no
    latency); ``model`` the stated ``model_error l1``. spec : an :class:`~ident.processing.errorspec.ErrorSpec`; l1
    : the rounded-up ``sum |c|`` that :func:`torque_rows` returns."""
    nj = spec.n_joints
    rate = np.zeros(nj) if spec.torque_rate is None else np.asarray(spec.torque_rate, dtype=float)
    span = spec.latency + (spec.sample_period / 2 if spec.torque_timing == "sample" else 0.0)

    def product(a, b):  # a b >= 0 rounded up; exactly 0 where a factor is 0 (no stray tiny radius in reports)
        a = np.asarray(a, dtype=float) * np.ones(nj)
        return np.where((a == 0) | (b == 0), 0.0, up(a * b))

    return {"torque": product(spec.torque_error, l1),
            "timing": product(product(rate, float(up(span)) if span else 0.0), l1),
            "model": product(spec.model_error, l1)}


def row_check(actual, radius) -> dict:
    """A certificate's check of derived radii against actual errors (a simulation's truth), elementwise:
    ``violations`` (``|actual| > radius``), ``min_margin`` (the smallest ``radius - |actual|``), ``max_actual``,
    ``max_radius`` and ``max_actual_over_radius``; JSON-ready. Both robot kinds' certificates use it."""
    actual, radius = np.abs(np.asarray(actual, dtype=float)), np.asarray(radius, dtype=float)
    margin = radius - actual
    return {"violations": int(np.sum(margin < 0)), "min_margin": float(margin.min()),
            "max_actual": float(actual.max()), "max_radius": float(radius.max()),
            "max_actual_over_radius": float(np.max(actual / np.maximum(radius, 1e-300)))}


def _secant(q: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    return 0.5 * (q[:-1] + q[1:]), np.diff(q, axis=0) / h


def imot_columns(q, e, windows: RowWindows, kernel: Kernel):
    """The ``P = qd_i`` column of joint i (an Imot-like column): centre ``-sum_w s_w (q_w+1 - q_w)`` (exact in the
    true positions), measurement radius ``sum_u |s_u - s_u-1| e_u`` (summation by parts), truncation 0.

    q : (n, n_j) measured positions [rad]; e : (n, n_j) position error bounds [rad]. Returns (value, meas,
    trunc), each (R, n_j) [rad/s^2 integrated against k: rad/s^2]."""
    s = kernel.slopes
    dq = windows.gather(np.diff(q, axis=0))
    value = -np.einsum("w,rwj->rj", s, dq)
    ds = np.abs(np.diff(np.concatenate([[0.0], s, [0.0]])))  # (L + 1,) |s_u - s_u-1|
    meas = np.einsum("u,ruj->rj", ds, windows.gather_knots(e))
    meas = meas + dot_error(np.einsum("w,rwj->rj", np.abs(s), np.abs(dq)), kernel.steps)
    return value, meas, np.zeros_like(value)


def viscous_columns(q, e, windows: RowWindows, kernel: Kernel, qdd_max):
    """The ``F = qd_i`` column: centre ``sum_w K_w v_w`` (v the secant speed), measurement radius
    ``sum_u |K_u-1 - K_u| e_u / h``, truncation ``sum_w |s_w| qdd_max h^3 / 12`` (k linear on the step:
    ``integral_w k qd - K_w v = s_w integral (t - t_mid)(qd - qd(t_mid))``). Returns (value, meas, trunc)
    (R, n_j) [rad/s]."""
    h = kernel.h
    K, s = kernel.integrals, kernel.slopes
    v = windows.gather(np.diff(q, axis=0) / h)
    value = np.einsum("w,rwj->rj", K, v)
    dK = np.abs(np.diff(np.concatenate([[0.0], K, [0.0]]))) / h
    meas = np.einsum("u,ruj->rj", dK, windows.gather_knots(e))
    meas = meas + dot_error(np.einsum("w,rwj->rj", np.abs(K), np.abs(v)), kernel.steps)
    trunc = np.broadcast_to(np.sum(np.abs(s)) * h**3 / 12.0 * np.asarray(qdd_max, dtype=float), value.shape)
    return value, meas, up(np.array(trunc))


def coulomb_columns(q, e, windows: RowWindows, kernel: Kernel, qdd_max, band=0.0):
    """The ``F = sign(qd_i)`` column: on a step where the true speed's lower bound ``|v| - (e_j + e_j+1) / h -
    qdd_max h / 2`` exceeds ``band`` (the speed below which the friction is only known to lie in ``[-Fs, Fs]``,
    ``ErrorSpec.friction_band``; 0: ideal Coulomb friction, where excluding 0 suffices) the friction is
    ``Fs sign(v)``; elsewhere ``F`` is any value in [-1, 1] (the friction of a joint at, through or near rest),
    weighted by ``K_w``. Returns (value, radius, uncertain_steps) with value, radius (R, n_j) [-] and
    uncertain_steps (S, n_j) bool."""
    h = kernel.h
    v = np.diff(q, axis=0) / h
    encoder, motion = up(up(e[:-1] + e[1:]) / h), up(0.5 * np.asarray(qdd_max, dtype=float) * h)
    margin = up(up(encoder + motion) + np.asarray(band, dtype=float))
    certain = down(down(np.abs(v))) > margin  # v = fl(fl(q_j+1 - q_j) / h): two roundings
    sign = np.where(certain, np.sign(v), 0.0)
    K = kernel.integrals
    value = np.einsum("w,rwj->rj", K, windows.gather(sign))
    radius = np.einsum("w,rwj->rj", np.abs(K), windows.gather((~certain).astype(float)))
    radius = up(radius + dot_error(np.full_like(radius, np.sum(np.abs(K))), kernel.steps))
    return value, radius, ~certain


def nonlinear_steps(evaluate, q, e, h: float, qd_max, qdd_max, curvature, encoder=None) -> "NonlinearSteps":
    """The per-step stage of columns ``dP/dt + F`` with configuration-dependent ``P(q, qd)``, ``F(q, qd)`` (n_out
    outputs, nc columns): everything that does not depend on the kernel, computed once per log; the rows of any
    kernel and windows follow from it (:func:`nonlinear_rows`), so that several kernels cost one evaluation.

    evaluate : ``f(q_m (S, n_j), v (S, n_j)) -> (P, F)``, each a first-order :class:`~ident.numerics.jets.Jet`
    of value shape (S, n_out, nc) in the 2 n_j variables (q, qd): rigorous enclosures of the values and the
    gradients at the measured secant states (e.g. :func:`ident.robots.h4_jets.nacelle_jets`).
    q, e : (n, n_j) measured positions and their error bounds [rad]; qd_max, qdd_max (n_j,) stated motion bounds;
    curvature : (MP, MF), each (n_out, nc, 2 n_j, 2 n_j) or per step (S, n_out, nc, 2 n_j, 2 n_j): bounds of
    ``|d^2 P / dx_a dx_b|``, ``|d^2 F / ...|`` over ``x = (q, qd)`` over each step's motion (the H4's: interval jets
    over each step's motion tube, :func:`ident.robots.h4_jets.box_jets`, or the sampled fallback): used by the
    truncation's second-order remainder.
    encoder : (MP, MF, GP, GF) per step, or None (then ``curvature`` serves here too): bounds over each step's
    ENCODER box (the measured secant state +- the position error's effect ``(e_m, e_v)``) of the second
    derivatives (S, n_out, nc, 2 n_j, 2 n_j) and of the gradients (S, n_out, nc, 2 n_j) of P and F, e.g. the
    magnitudes of interval jets over those boxes (:func:`ident.robots.h4_jets.box_jets`): used by the encoder's
    second-order term and to carry the gradients from the measured to the true secant state.

    h : the sample period [s]. Returns a :class:`NonlinearSteps` (the rows' meaning: :func:`nonlinear_rows`).
    """
    qm, v = _secant(q, h)
    S, nj = qm.shape
    Pj, Fj = evaluate(qm, v)
    P, F = Pj.v.c, Fj.v.c
    n_out, nc = P.shape[1:]
    Pq, Pv, Fq, Fv = Pj.g.c[..., :nj], Pj.g.c[..., nj:], Fj.g.c[..., :nj], Fj.g.c[..., nj:]
    Pq_r, Pv_r, Fq_r, Fv_r = Pj.g.r[..., :nj], Pj.g.r[..., nj:], Fj.g.r[..., :nj], Fj.g.r[..., nj:]
    MP, MF = (np.broadcast_to(np.asarray(m, dtype=float), (S, n_out, nc, 2 * nj, 2 * nj)) for m in curvature)
    MPe, MFe, GPe, GFe = (MP, MF, None, None) if encoder is None else encoder
    qdd_max = np.asarray(qdd_max, dtype=float)
    # gradients at the measured secant state, widened to cover the true one (|q_m error| <= e_m, |v error| <= e_v)
    em, ev = 0.5 * (e[:-1] + e[1:]), (e[:-1] + e[1:]) / h
    eps = np.concatenate([em, ev], axis=1)  # (S, 2 n_j)
    # the true speed on each step: |qd| <= |v_measured| + e_v + qdd_max h / 2, and never above the stated qd_max
    qd_step = np.minimum(np.abs(v) + ev + qdd_max * h / 2, np.asarray(qd_max, dtype=float))  # (S, n_j)
    # second-order remainder of one step, |R(t)| <= 1/2 sum_ab M_ab |dx_a(t)| |dx_b(t)| with dx = x(t) - x_m,
    # tau = t - t_mid in [-h/2, h/2]: dq(t) = v* tau + rho(t) with |v*| <= w (the true secant speed) and |rho| <=
    # qdd_max (h^2/4 - tau^2) / 2 (chord remainder), so |dq_a| <= w_a |tau| + c_a (h^2/4 - tau^2), c = qdd_max / 2,
    # and integral |dq_a dq_b| <= w_a w_b h^3/12 + (w_a c_b + c_a w_b) h^4/32 + c_a c_b h^5/30; sigma = qd - v* has
    # zero mean on the step and |sigma'| <= qdd_max, so (Poincare-Wirtinger, constant (h / pi)^2) integral
    # sigma_a^2 <= (qdd_a h / pi)^2 h, and Cauchy-Schwarz bounds the mixed integrals: I_ab >= integral |dx_a dx_b|,
    # the integral of |R| over the step <= 1/2 sum M_ab I_ab. Its supremum uses |dq| <= qd_step h / 2 and
    # |sigma| <= qdd_max h / 2 (d_sup).
    w = np.minimum(np.abs(v) + ev, np.asarray(qd_max, dtype=float))  # (S, n_j) the true secant speed's bound
    c = np.broadcast_to(qdd_max / 2, (S, nj))
    Iqq = (w[:, :, None] * w[:, None, :] * h**3 / 12
           + (w[:, :, None] * c[:, None, :] + c[:, :, None] * w[:, None, :]) * h**4 / 32
           + c[:, :, None] * c[:, None, :] * h**5 / 30)
    sq = np.sqrt(np.diagonal(Iqq, axis1=1, axis2=2))  # (S, n_j) sqrt(integral dq_a^2)
    sv = np.broadcast_to(qdd_max * h / np.pi * np.sqrt(h), (S, nj))  # sqrt(integral sigma_a^2)
    I = np.empty((S, 2 * nj, 2 * nj))
    I[:, :nj, :nj] = Iqq
    I[:, :nj, nj:] = sq[:, :, None] * sv[:, None, :]
    I[:, nj:, :nj] = np.swapaxes(I[:, :nj, nj:], 1, 2)
    I[:, nj:, nj:] = sv[:, :, None] * sv[:, None, :]
    I = up(I * (1 + 64 * 2.0**-53))
    d_sup = np.concatenate([qd_step * h / 2, np.broadcast_to(qdd_max * h / 2, (S, nj))], axis=1)
    QP = 0.5 * np.einsum("sicab,sab->sic", MP, I)  # (S, n_out, nc): integral of |R_P| over the step
    QF = 0.5 * np.einsum("sicab,sab->sic", MF, I)
    QF_sup = 0.5 * np.einsum("sicab,sa,sb->sic", MF, d_sup, d_sup)
    # the gradients at the TRUE secant state: the measured one's plus the encoder box's second derivatives times
    # eps, or the gradient's bound over the encoder box, whichever is smaller (both hold)
    gP = np.einsum("sicab,sb->sica", MPe, eps)  # (S, n_out, nc, 2 n_j)
    gF = np.einsum("sicab,sb->sica", MFe, eps)
    aPq = np.abs(Pq) + Pq_r + gP[..., :nj]
    aFq = np.abs(Fq) + Fq_r + gF[..., :nj]
    aFv = np.abs(Fv) + Fv_r + gF[..., nj:]
    if GPe is not None:
        aPq, aFq, aFv = np.minimum(aPq, GPe[..., :nj]), np.minimum(aFq, GFe[..., :nj]), np.minimum(aFv, GFe[..., nj:])
    # per-step truncation pieces (S, n_out, nc): coefficient of |s_w| and of |k_mid,w|
    # (the slope part of k weights R_F by |tau| <= h / 2: integral |tau R_F| <= min(sup |R_F| h^2 / 4, h / 2 QF))
    t_s = (np.einsum("sica,a->sic", aPq, qdd_max) * h**3 / 12 + QP
           + np.einsum("sica,sa->sic", aFq, qd_step) * h**3 / 12 + np.einsum("sica,a->sic", aFq, qdd_max) * h**4 / 32
           + np.einsum("sica,a->sic", aFv, qdd_max) * h**3 / 8 + np.minimum(QF_sup * h**2 / 4, QF * h / 2))
    t_k = np.einsum("sica,a->sic", aFq, qdd_max) * h**3 / 12 + QF
    # encoder second-order: 1/2 eps^T M eps per step
    s2P = 0.5 * np.einsum("sicab,sa,sb->sic", MPe, eps, eps)
    s2F = 0.5 * np.einsum("sicab,sa,sb->sic", MFe, eps, eps)
    # derivative of step j's term with respect to q_j (A) and q_j+1 (B), per unit weight
    dPa, dPb = 0.5 * Pq - Pv / h, 0.5 * Pq + Pv / h
    dFa, dFb = 0.5 * Fq - Fv / h, 0.5 * Fq + Fv / h
    # the enclosures' radii: of the values (per step) and of the gradients (per step and variable)
    rPa, rFa = 0.5 * Pq_r + Pv_r / h, 0.5 * Fq_r + Fv_r / h  # the same for A and B
    mPa, mFa = 0.5 * np.abs(Pq) + np.abs(Pv) / h, 0.5 * np.abs(Fq) + np.abs(Fv) / h  # magnitudes for rounding
    return NonlinearSteps(h=float(h), e=np.asarray(e, dtype=float), P=P, F=F, P_r=Pj.v.r, F_r=Fj.v.r, dPa=dPa,
                          dPb=dPb, dFa=dFa, dFb=dFb, rPa=rPa, rFa=rFa, mPa=mPa, mFa=mFa, t_s=t_s, t_k=t_k, s2P=s2P,
                          s2F=s2F)


@dataclass(frozen=True)
class NonlinearSteps:
    """Per sample step j (S steps; arrays (S, n_out, nc) or (S, n_out, nc, n_j)) what the rows of
    :func:`nonlinear_rows` sum: the values ``P``, ``F`` and their enclosures' radii, the row functional's
    derivatives with respect to ``q_j`` (``dPa``, ``dFa``) and ``q_j+1`` (``dPb``, ``dFb``) per unit weight, their
    radii (``rPa``, ``rFa``) and magnitudes for rounding (``mPa``, ``mFa``), the truncation pieces per unit
    ``|s_w|`` (``t_s``) and ``|k_mid,w|`` (``t_k``), the encoder's second-order pieces (``s2P``, ``s2F``); ``e``
    (n, n_j) the position error bounds [rad], ``h`` the sample period [s]."""

    h: float
    e: np.ndarray
    P: np.ndarray
    F: np.ndarray
    P_r: np.ndarray
    F_r: np.ndarray
    dPa: np.ndarray
    dPb: np.ndarray
    dFa: np.ndarray
    dFb: np.ndarray
    rPa: np.ndarray
    rFa: np.ndarray
    mPa: np.ndarray
    mFa: np.ndarray
    t_s: np.ndarray
    t_k: np.ndarray
    s2P: np.ndarray
    s2F: np.ndarray


#: the window steps per chunk of :func:`nonlinear_rows` (rows per chunk ``max(1, ROW_CHUNK_STEPS // L)``): each
#: row's numbers are its own, so any chunk gives the same bits; the H4's full-size rows (7 kernels, 10 s log) took
#: 1.2 s with 1024-2048 steps per chunk against 2.5-3.0 s with 512 rows (arrays of up to 100 MB out of cache)
ROW_CHUNK_STEPS = 1536


def nonlinear_rows(st: NonlinearSteps, windows: RowWindows, kernel: Kernel, chunk: int | None = None):
    """The rows of the nonlinear columns for a kernel and row windows, from their per-step stage.

    Returns (value, meas, trunc, second), each (R, n_out, nc): the centre; the first-order encoder radius
    ``sum_u |dPhi / dq_u| e_u`` (the gradient of the row functional, enclosed) plus the enclosures' own radii; the
    truncation radius (chord remainder, linear terms exactly integrated, second-order remainder over the step's
    motion box); the encoder's second-order term. The second-order part of ``trunc`` rests on ``curvature``;
    ``second`` and the gradients' transfer to the true state rest on ``encoder`` (:func:`nonlinear_steps`).
    chunk : rows per chunk (default ``max(1, ROW_CHUNK_STEPS // L)``; the same bits for any).
    """
    if abs(kernel.h - st.h) > 1e-12 * st.h:
        raise ValueError(f"kernel.h must be the steps' sample period {st.h!r} s, got {kernel.h!r}")
    h, e = st.h, st.e
    P, F, dPa, dPb, dFa, dFb = st.P, st.F, st.dPa, st.dPb, st.dFa, st.dFb
    rPa, rFa, mPa, mFa, t_s, t_k, s2P, s2F = st.rPa, st.rFa, st.mPa, st.mFa, st.t_s, st.t_k, st.s2P, st.s2F
    n_out, nc = P.shape[1:]
    s, K, km = kernel.slopes, kernel.integrals, kernel.mids
    R = windows.start.size
    L = kernel.steps
    chunk = max(1, ROW_CHUNK_STEPS // L) if chunk is None else int(chunk)
    # per-step weights broadcast over (r, w, i, c, a): elementwise products, the bits of einsum("w,rwica->rwica")
    s5, K5 = s[None, :, None, None, None], K[None, :, None, None, None]
    as5, aK5 = np.abs(s)[None, :, None, None, None], np.abs(K)[None, :, None, None, None]
    value = np.empty((R, n_out, nc))
    meas, trunc, second = np.empty_like(value), np.empty_like(value), np.empty_like(value)
    for r0 in range(0, R, chunk):
        sub = RowWindows(windows.start[r0:r0 + chunk], L)
        gPw, gFw = sub.gather(P), sub.gather(F)
        value[r0:r0 + chunk] = -h * np.einsum("w,rwic->ric", s, gPw) + np.einsum("w,rwic->ric", K, gFw)
        fp = dot_error(h * np.einsum("w,rwic->ric", np.abs(s), np.abs(gPw))
                       + np.einsum("w,rwic->ric", np.abs(K), np.abs(gFw)), 2 * L)
        fp = fp + (h * np.einsum("w,rwic->ric", np.abs(s), sub.gather(st.P_r))
                   + np.einsum("w,rwic->ric", np.abs(K), sub.gather(st.F_r))) * (1 + 4 * L * 2.0**-53)
        # the row functional's gradient in each sample's position: step u's derivative in its first sample (A)
        # plus step u-1's in its second (B), and likewise the radii and the magnitudes for the float error
        A = -h * (s5 * sub.gather(dPa)) + K5 * sub.gather(dFa)
        B = -h * (s5 * sub.gather(dPb)) + K5 * sub.gather(dFb)
        gr = h * (as5 * sub.gather(rPa)) + aK5 * sub.gather(rFa)
        sl = h * (as5 * sub.gather(mPa)) + aK5 * sub.gather(mFa)
        bound_g = np.empty((A.shape[0], L + 1) + A.shape[2:])
        bound_g[:, 0] = np.abs(A[:, 0]) + gr[:, 0] + 32 * 2.0**-53 * sl[:, 0]
        bound_g[:, 1:L] = (np.abs(A[:, 1:] + B[:, :-1]) + (gr[:, 1:] + gr[:, :-1])
                           + 32 * 2.0**-53 * (sl[:, 1:] + sl[:, :-1]))
        bound_g[:, L] = np.abs(B[:, -1]) + gr[:, -1] + 32 * 2.0**-53 * sl[:, -1]
        ew = sub.gather_knots(e)  # (r, L + 1, n_j)
        meas[r0:r0 + chunk] = up(np.einsum("ruica,rua->ric", bound_g, ew) * (1 + 4 * L * 2.0**-53) + fp)
        trunc[r0:r0 + chunk] = (np.einsum("w,rwic->ric", np.abs(s), sub.gather(t_s))
                                + np.einsum("w,rwic->ric", np.abs(km), sub.gather(t_k)))
        second[r0:r0 + chunk] = (h * np.einsum("w,rwic->ric", np.abs(s), sub.gather(s2P))
                                 + np.einsum("w,rwic->ric", np.abs(K), sub.gather(s2F)))
    # the float sums above add at most (4 L + 256) u relative error (nonnegative terms)
    grow = 1.0 + (4 * L + 256) * 2.0**-53
    return value, meas, up(trunc * grow), up(second * grow)


def nonlinear_columns(evaluate, q, e, windows: RowWindows, kernel: Kernel, qd_max, qdd_max, curvature,
                      encoder=None, chunk: int | None = None):
    """:func:`nonlinear_steps` then :func:`nonlinear_rows` for one kernel (the arguments of both)."""
    steps = nonlinear_steps(evaluate, q, e, kernel.h, qd_max, qdd_max, curvature, encoder=encoder)
    return nonlinear_rows(steps, windows, kernel, chunk=chunk)
