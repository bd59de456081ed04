"""The H4's interval regressor: ``[W] = [Wc - D, Wc + D]`` from encoder errors, the filters and friction signs.

The estimator is :func:`ident.estimators.uncertain.uncertain_hull` (Oettli & Prager 1964, for any interval
regressor); this module builds ``[W]`` for the H4 chain of :mod:`ident.processing`.

**Where [W] comes from (the H4 chain of :mod:`ident.processing.processing`).** The estimated states
``s_est = P(q_meas)`` (Butterworth filtfilt + central differences, a linear operator P) differ from the true
ones by ``P(e) + (P(q) - s_true)``: the encoder error ``e`` (``|e| <= pi / counts``, rounding to the nearest
count) and the filter's distortion of the true motion. After the parallel filter h (applied to both sides):

    h * W(s_true) = h * W(s_est - P e) + h * [W(s_true) - W(P q)].

* **Encoder part (rigorous for the linear columns, first-order for the others).** ``|P_k e| <= ||P_k||_1 pi /
  counts`` row by row, with the row norms of the actual processing operator (:func:`encoder_radii`: the
  code's own filter applied to unit impulses, ends included). The regressor over the state box
  ``s_est ± r`` is enclosed by :func:`interval_regressor`: one-at-a-time central differences with steps equal
  to the radii, ``|f(s + r_j) - f(s - r_j)| / 2`` per coordinate, which is exact for the columns linear in the
  states (``Imot: qdd``, ``Fv: qd``); the Mnac and Ibc columns (``J^T (J qdd + Jdot qd - G)``) are linear in
  qdd (exact), quadratic in qd (the quadratic part is bounded exactly from second differences, the cross terms
  from mixed differences) and nonlinear in q (first- plus second-order one-at-a-time terms); the mixed q-qd,
  q-qdd and q-q terms are **not** bounded rigorously but covered by a stated margin ``second_order_margin``
  (default 10 %; measured on the H4 over random and corner states, the unmargined bound was exceeded by at most
  0.05 % at radii (2e-4 rad, 0.01 rad/s, 0.5 rad/s^2), 0.6 % at (2e-3, 0.2, 20), 5 % at (1e-2, 0.5, 50)). The
  state boxes hold the encoder part only: pointwise, the filters' distortion of the true motion is far larger
  (simulated: up to 80-300 rad/s^2 on qdd, closed-loop chatter and friction steps) than after the parallel
  filter, where it is handled (next items). The interval matrix
  then goes through the parallel filter as an interval: ``h * [Wc ± D] ⊆ [h * Wc ± |h| * D]`` (rigorous, with
  the filter's own floating-point error added to D) (:func:`filter_interval`).
* **Coulomb column.** ``sign(qd)`` is kept where the sign of the true speed over the sample is certain
  (``|qd_est| > r`` at the sample and at the next one, same sign; the friction of a sampled step acts with the
  end-of-step speed), else it becomes ``[-1, 1]`` (true of MuJoCo's friction box and of static friction): those
  rows need no speed-threshold exclusion.
* **Distortion part: an assumption.** ``h * [W(s_true) - W(P q)]`` is the low-pass's error on the true motion
  (the true accelerations carry closed-loop chatter and friction steps that no low-pass follows pointwise; the
  parallel filter removes most of it). It cannot be derived from the data. It is an input, ``distortion``
  (one bound per joint row and column of the filtered regressor, plus the raw speed distortion used for the
  sign test), measured by :func:`regressor_distortion` on a calibration simulation with the truth and
  multiplied by a safety factor. The claim "the interval regressor contains the true one" is exactly as
  good as this assumption; a scenario checks it against the truth of the run itself.

This module imports neither ``sim`` nor ``mujoco``: the regressor is passed in as a function.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.signal

from h4bench.ident.estimators.checks import check_finite, real_array
from h4bench.ident.numerics.interval import nonneg_upper, up
from h4bench.ident.processing.filtering import (
    ProcessingSettings,
    central_difference,
    default_edge_samples,
    derivatives,
    lowpass_position,
    parallel_filter,
    second_difference,
)

__all__ = [
    "H4_SIGN_COLUMNS",
    "Distortion",
    "IntervalEquation",
    "encoder_radii",
    "filter_interval",
    "interval_equation",
    "interval_regressor",
    "regressor_distortion",
]

H4_SIGN_COLUMNS = (10, 11, 12, 13)  # Fs1..Fs4 in ident.PARAMETER_NAMES order
N_JOINTS = 4


# ----------------------------------------------------------------------------------------------- checks
def _states(x, name: str, n: int | None = None) -> np.ndarray:
    a = real_array(x, name)
    if a.ndim != 2 or a.shape[1] != N_JOINTS or (n is not None and a.shape[0] != n):
        raise ValueError(f"{name} must have shape ({'n' if n is None else n}, {N_JOINTS}), got {a.shape}")
    check_finite(a, name)
    return a


def _radius(r, name: str, n: int) -> np.ndarray:
    a = real_array(r, name)
    try:
        a = np.broadcast_to(a, (n, N_JOINTS)).astype(float)
    except ValueError:
        raise ValueError(f"{name} must be a scalar, ({N_JOINTS},) or ({n}, {N_JOINTS}), got shape {a.shape}") from None
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"{name} must be finite and >= 0 (a radius), got min {float(np.min(a))!r}")
    return a


# ---------------------------------------------------------------------------------- encoder error radii
def encoder_radii(counts_per_turn: int, dt: float, cutoff_hz: float, order: int = 4, n: int | None = None) -> np.ndarray:
    """Rigorous radii ``(r_q, r_qd, r_qdd)`` [rad, rad/s, rad/s^2] of the encoder part of the state estimates.

    counts_per_turn : encoder counts per turn (error ``|e| <= pi / counts``, rounding to the nearest count);
    dt, cutoff_hz, order : the processing of :func:`ident.processing.filtering.derivatives`; n : the record's length in
    samples (default: long).

    The estimate is linear in the measured angles, ``s = P q_meas``, so the encoder part is ``P e`` and
    ``|(P e)_k| <= ||P_k||_1 max|e|``. The row norms are those of the code's own operator: the processing is
    applied to unit impulses (a probe of ``2 (trim + T) + 1`` samples, ``T`` the number of samples after which
    the Butterworth's impulse response has decayed below ``1e-16`` by its pole radius, ``trim`` the samples
    :func:`derivatives` marks invalid), and the largest row norm over the valid samples is taken; rows of a
    longer record equal the probe's up to those tails, covered by a ``1e-6`` relative margin (with the
    floating-point error of the probe, about 1e-13). Returns (3,) radii.
    """
    if isinstance(counts_per_turn, bool) or not isinstance(counts_per_turn, (int, np.integer)) or counts_per_turn < 1:
        raise ValueError(f"counts_per_turn must be an integer >= 1, got {counts_per_turn!r}")
    trim = default_edge_samples(dt, cutoff_hz) + 2
    sos = scipy.signal.butter(order, cutoff_hz, btype="low", output="sos", fs=1.0 / dt)
    rho = float(np.max(np.abs(scipy.signal.sos2zpk(sos)[1])))
    T = int(math.ceil(math.log(1e-16) / math.log(rho)))
    n_probe = 2 * (trim + T) + 1
    if n is not None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2 * trim + 1:
            raise ValueError(f"n must be an integer > 2 * trim = {2 * trim} (samples of the record), got {n!r}")
        n_probe = min(n_probe, int(n))
    sums = np.zeros((3, n_probe))
    eye = np.eye(n_probe)
    for s in range(0, n_probe, N_JOINTS):
        blk = eye[:, s: s + N_JOINTS]
        if blk.shape[1] < N_JOINTS:
            blk = np.hstack([blk, np.zeros((n_probe, N_JOINTS - blk.shape[1]))])
        qf = lowpass_position(blk, dt, cutoff_hz, order)
        for o, x in enumerate((qf, central_difference(qf, dt), second_difference(qf, dt))):
            sums[o] += np.abs(x).sum(axis=1)
    norms = sums[:, trim: n_probe - trim].max(axis=1)
    eps = up(np.pi / counts_per_turn)
    return up(up(norms * (1.0 + 1e-6)) * eps)


# ------------------------------------------------------------------------------------ interval regressor
def interval_regressor(regressor_fn, q, qd, qdd, r_q, r_qd, r_qdd, *, sign_columns=H4_SIGN_COLUMNS,
                       sign_radius=None, sign_next: bool = True, second_order_margin: float = 0.1):
    """Interval enclosure ``(Wc, D)`` of ``W(s)`` over the state boxes ``s ± r`` (module docstring).

    regressor_fn : callable ``(q, qd, qdd) -> W (4n, p)`` (rows ``4k + i``), e.g.
    ``lambda q, qd, qdd: ident.regressor(geometry, q, qd, qdd)``; q, qd, qdd : (n, 4) estimated states;
    r_q, r_qd, r_qdd : radii, scalar, (4,) or (n, 4) [rad, rad/s, rad/s^2]; sign_columns : the column of
    ``sign(qd_i)`` for each joint i (None: no Coulomb column); sign_radius : (n, 4) radius used to decide the
    sign of the true speed (default ``r_qd``); sign_next : the sign must also be certain at the next sample
    (sampled friction acts with the end-of-step speed; the last sample is then uncertain);
    second_order_margin : relative margin for the mixed second-order terms not bounded (default 0.1).

    Cost: 31 evaluations of ``regressor_fn``. Returns ``(Wc, D)``, both (4n, p); ``Wc`` is W at the estimates
    except the uncertain Coulomb entries (0, radius 1).
    """
    q, qd, qdd = (_states(x, name) for x, name in ((q, "q"), (qd, "qd"), (qdd, "qdd")))
    n = q.shape[0]
    if qd.shape[0] != n or qdd.shape[0] != n:
        raise ValueError(f"q, qd and qdd must have the same number of samples, got {n}, {qd.shape[0]}, {qdd.shape[0]}")
    radii = [_radius(r, name, n) for r, name in ((r_q, "r_q"), (r_qd, "r_qd"), (r_qdd, "r_qdd"))]
    if isinstance(second_order_margin, bool) or not isinstance(second_order_margin, (int, float)) or \
            not (math.isfinite(second_order_margin) and second_order_margin >= 0):
        raise ValueError(f"second_order_margin must be a finite number >= 0, got {second_order_margin!r}")
    states = [q, qd, qdd]
    W0 = np.asarray(regressor_fn(q, qd, qdd), dtype=float)
    if W0.ndim != 2 or W0.shape[0] != N_JOINTS * n:
        raise ValueError(f"regressor_fn must return shape ({N_JOINTS * n}, p), got {W0.shape}")
    p = W0.shape[1]

    def evaluate(o, j, step):
        s = [x.copy() for x in states]
        s[o][:, j] += step
        return np.asarray(regressor_fn(*s), dtype=float)

    D = np.zeros_like(W0)
    plus_qd = {}
    for o in range(3):
        for j in range(N_JOINTS):
            if not np.any(radii[o][:, j]):
                continue
            wp = evaluate(o, j, radii[o][:, j])
            wm = evaluate(o, j, -radii[o][:, j])
            D += 0.5 * np.abs(wp - wm) + 0.5 * np.abs(wp + wm - 2.0 * W0)
            if o == 1:
                plus_qd[j] = wp
    # exact quadratic cross terms in qd: f(+i,+k) - f(+i) - f(+k) + f0 = H_ik r_i r_k
    for i in range(N_JOINTS):
        for k in range(i + 1, N_JOINTS):
            if i not in plus_qd or k not in plus_qd:
                continue
            s = [x.copy() for x in states]
            s[1][:, i] += radii[1][:, i]
            s[1][:, k] += radii[1][:, k]
            wik = np.asarray(regressor_fn(*s), dtype=float)
            D += np.abs(wik - plus_qd[i] - plus_qd[k] + W0)
    # margin for the mixed terms; the float error of evaluating W (~1e-15 relative) is far below it
    D = up(D * (1.0 + second_order_margin) + 16.0 * 2.0**-53 * np.abs(W0))
    Wc = W0.copy()
    if sign_columns is not None:
        cols = tuple(int(c) for c in sign_columns)
        if len(cols) != N_JOINTS or any(not 0 <= c < p for c in cols):
            raise ValueError(f"sign_columns must give one column index in [0, {p}) per joint, got {sign_columns!r}")
        sr = radii[1] if sign_radius is None else _radius(sign_radius, "sign_radius", n)
        uncertain = np.abs(qd) <= sr
        if sign_next:
            nxt = np.ones_like(uncertain)
            nxt[:-1] = (np.abs(qd[1:]) <= sr[1:]) | (np.sign(qd[1:]) != np.sign(qd[:-1]))
            uncertain |= nxt
        rows = np.arange(n)
        for i, c in enumerate(cols):
            D[:, c] = 0.0
            r = N_JOINTS * rows + i
            Wc[r, c] = np.where(uncertain[:, i], 0.0, np.sign(qd[:, i]))
            D[r, c] = np.where(uncertain[:, i], 1.0, 0.0)
    return Wc, D


def filter_interval(Wc, D, y, bound, factor: int, taps):
    """The parallel filter of an interval equation: ``h * [Wc ± D] ⊆ [h * Wc ± (|h| * D + rounding)]``.

    Wc, D : (4n, p); y : (4n,); bound : scalar or (4n,); factor, taps : decimation and FIR as in
    :func:`ident.processing.filtering.parallel_filter` (which computes every filtered quantity and its rounding bound).
    Returns ``(Wc_f, D_f, y_f, bound_f, fe)`` with ``fe`` the :class:`~ident.processing.filtering.FilteredEquation` of the
    centre (sample_index, rows, ...). Rigorous: the radius adds the floating-point error bounds of ``h * Wc``
    and of ``|h| * D`` and is rounded up.
    """
    h = np.asarray(taps, dtype=float)
    fe = parallel_filter(Wc, y, bound, factor, taps=h)
    fd = parallel_filter(D, np.zeros(D.shape[0]), 0.0, factor, taps=np.abs(h))
    D_f = nonneg_upper(fd.W + fd.w_rounding + fe.w_rounding, 3)
    return fe.W, D_f, fe.y, fe.bound, fe


# ---------------------------------------------------------------------------- distortion (an assumption)
@dataclass(frozen=True)
class Distortion:
    """Assumed bounds on the filters' distortion of the TRUE motion (see the module docstring).

    regressor : (4, p) bound on ``|h * [W(s_true) - W(P q_true)]|`` per joint row and column of the filtered
    regressor (Coulomb columns: 0, they are handled by the sign test); qd : (4,) bound on the raw speed
    distortion ``|P_d q_true - qd_true|`` [rad/s] (widens the sign test); source : where the numbers come from.
    """

    regressor: np.ndarray
    qd: np.ndarray
    source: str = ""

    def scaled(self, factor: float) -> "Distortion":
        """The same bounds times a safety factor (rounded up)."""
        def scale(a):
            a = np.asarray(a, dtype=float)
            return np.where(a > 0, up(a * factor), 0.0)

        return Distortion(scale(self.regressor), scale(self.qd), f"{self.source} x {factor:g}")


def _processed_states(q, settings: ProcessingSettings):
    est = derivatives(q, settings.dt, settings.position_cutoff_hz, settings.butter_order,
                      timing=settings.torque_timing)
    v = est.valid
    return est.q[v], est.qd[v], est.qdd[v], np.arange(q.shape[0])[v]


def regressor_distortion(regressor_fn, q_true, qd_true, qdd_true, settings: ProcessingSettings,
                         sign_columns=H4_SIGN_COLUMNS) -> Distortion:
    """Measure the distortion of the processing on a record whose true states are known (a calibration
    simulation): the processing of the exact angles ``q_true`` (no encoder) against the true states.

    q_true, qd_true, qdd_true : (n, 4) true states at the samples; settings : the processing of the experiment.
    Returns the largest distortion per joint row and column after the parallel filter, and the largest raw
    speed distortion per joint. Reads a truth: for calibration only, never on the data being identified.
    """
    q_true, qd_true, qdd_true = (_states(x, name) for x, name in
                                 ((q_true, "q_true"), (qd_true, "qd_true"), (qdd_true, "qdd_true")))
    qf, qd, qdd, samples = _processed_states(q_true, settings)
    W_true = np.asarray(regressor_fn(q_true[samples], qd_true[samples], qdd_true[samples]), dtype=float)
    W_est = np.asarray(regressor_fn(qf, qd, qdd), dtype=float)
    diff = W_true - W_est
    if sign_columns is not None:
        diff[:, list(sign_columns)] = 0.0
    taps = settings.taps()
    if settings.decimation == 1 and taps.size == 1:
        filt = diff
    else:
        filt = parallel_filter(diff, np.zeros(diff.shape[0]), 0.0, settings.decimation, taps=taps).W
    p = diff.shape[1]
    reg = np.abs(filt).reshape(-1, N_JOINTS, p).max(axis=0)
    qd_dist = np.abs(qd - qd_true[samples]).max(axis=0)
    return Distortion(regressor=reg, qd=qd_dist, source="measured on a record with known true states")


# ----------------------------------------------------------------------------------------- the pipeline
@dataclass(frozen=True)
class IntervalEquation:
    """``y = W theta + e`` with ``W in [Wc - D, Wc + D]`` and ``|e| <= bound``: Wc, D (m, p); y, bound (m,);
    sample, joint (m,) the original sample and joint of each row; info: radii, counts, filter data."""

    Wc: np.ndarray
    D: np.ndarray
    y: np.ndarray
    bound: np.ndarray
    sample: np.ndarray
    joint: np.ndarray
    info: dict = field(default_factory=dict, compare=False)

    def __len__(self) -> int:
        return self.y.size


def interval_equation(regressor_fn, q_meas, tau, bound, settings: ProcessingSettings, *, counts_per_turn: int | None,
                      distortion: Distortion | None, sign_columns=H4_SIGN_COLUMNS, sign_band: float = 0.0,
                      second_order_margin: float = 0.1) -> IntervalEquation:
    """The processed equation of measured data with an interval regressor (module docstring).

    regressor_fn : ``(q, qd, qdd) -> W (4n, p)``; q_meas : (n, 4) measured (quantised) angles [rad];
    tau : (n, 4) measured torques [N m]; bound : scalar > 0, the claim on raw rows ``|tau - W(s_true) theta|``
    (noise and model mismatch only: the derivative errors are in the regressor now); settings : processing;
    counts_per_turn : the encoder's resolution (None: exact angles); distortion : the assumed distortion bounds (None: zero, i.e.
    the claim that the filters do not distort the true motion); sign_band : extra speed [rad/s] within which
    the friction law is not trusted (e.g. a simulator's friction smoothing band).

    Every raw sample in the valid range is kept (no speed threshold): uncertain signs become [-1, 1].
    """
    q_meas = _states(q_meas, "q_meas")
    tau = _states(tau, "tau", q_meas.shape[0])
    bound = float(bound)
    if not (math.isfinite(bound) and bound > 0):
        raise ValueError(f"bound must be a finite number > 0 [N m], got {bound!r}")
    if isinstance(sign_band, bool) or not isinstance(sign_band, (int, float)) or not (math.isfinite(sign_band) and sign_band >= 0):
        raise ValueError(f"sign_band must be a finite number >= 0 [rad/s], got {sign_band!r}")
    dt = settings.dt
    radii = np.zeros(3) if counts_per_turn is None else \
        encoder_radii(counts_per_turn, dt, settings.position_cutoff_hz, settings.butter_order, n=q_meas.shape[0])
    qf, qd, qdd, samples = _processed_states(q_meas, settings)
    dist_qd = np.zeros(N_JOINTS) if distortion is None else np.asarray(distortion.qd, dtype=float)
    sign_radius = up(up(radii[1] + dist_qd) + sign_band)[None, :] * np.ones((qf.shape[0], 1))
    Wc, D = interval_regressor(regressor_fn, qf, qd, qdd, radii[0], radii[1], radii[2], sign_columns=sign_columns,
                               sign_radius=sign_radius, second_order_margin=second_order_margin)
    y = tau[samples].reshape(-1)
    taps = settings.taps()
    info = {"encoder_radii": radii.tolist(), "counts_per_turn": counts_per_turn,
            "sign_uncertain_rows": int(np.count_nonzero(D[:, list(sign_columns)] == 1.0)) if sign_columns else 0,
            "raw_rows": int(y.size), "second_order_margin": second_order_margin,
            "distortion_source": None if distortion is None else distortion.source}
    if settings.decimation == 1 and taps.size == 1:
        Wf, Df, yf, bf = Wc, D, y, np.full(y.size, bound)
        sample, joint = np.repeat(samples, N_JOINTS), np.tile(np.arange(N_JOINTS), samples.size)
        info.update({"filtered": False, "l1_norm": 1.0})
    else:
        Wf, Df, yf, bf, fe = filter_interval(Wc, D, y, bound, settings.decimation, taps)
        sample = np.repeat(samples[fe.sample_index], N_JOINTS)
        joint = np.tile(np.arange(N_JOINTS), fe.sample_index.size)
        info.update({"filtered": True, "l1_norm": fe.l1_norm})
    if distortion is not None:
        reg = np.asarray(distortion.regressor, dtype=float)
        if reg.shape != (N_JOINTS, Wf.shape[1]):
            raise ValueError(f"distortion.regressor must have shape ({N_JOINTS}, {Wf.shape[1]}), got {reg.shape}")
        Df = up(Df + reg[joint])
    return IntervalEquation(Wc=Wf, D=Df, y=yf, bound=bf, sample=sample, joint=joint, info=info)
