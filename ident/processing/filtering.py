"""Data processing for identification, with the torque-error bound carried through every filter.

The processing follows Gautier's practice as used in the paper (Poignet, Ramdani & Vivas, CDC 2003, sec. 4.1;
Poignet & Gautier 2001; BIRDy):

1. :func:`lowpass_position`: zero-phase Butterworth low-pass (forward and backward) on the measured joint
   positions ``q``.
2. :func:`central_difference` / :func:`derivatives`: ``qd`` and ``qdd`` by central differences of the filtered
   ``q`` (together a zero-phase band-pass "derivative filter").
3. Build ``W(q, qd, qdd)`` and ``y = tau`` elsewhere (``ident.regressor``), then :func:`parallel_filter`: the same
   FIR low-pass on ``y`` and on every column of ``W``, joint by joint, followed by decimation.
4. :func:`exclude_low_speed`: drop rows where ``|qd|`` is too small for ``sign(qd)`` (Coulomb friction) to be
   trusted.

Bounded-error contract. The torque equation is ``y = W theta + e`` with ``|e_r| <= b_r`` row by row. Steps 1-2
act on ``q`` only, i.e. *inside* ``W``: their effect (derivative-estimation error) is part of ``e`` and must be
covered by the bound the caller assumes; nothing here can propagate it. Step 3 is linear and applied
identically to both sides, so ``h * y = (h * W) theta + h * e`` holds exactly for ANY taps ``h`` (pass-band droop
or aliasing do not bias the equation) and ``|h * e| <= |h| * b`` (``<= ||h||_1 max b``) is the propagated
bound, tight for the worst-case noise ``e = b sign(h)`` reversed in time. Note that for a filter with unit DC
gain ``||h||_1 >= |sum h| = 1``: parallel filtering never shrinks a worst-case bound; it buys fewer rows and
rejects high-frequency content at the price of a factor ``||h||_1`` (1.71 for the default 20*factor+1 tap
Hamming design, about 1.06 for 4*factor+1 taps, exactly 1 for non-negative taps).
:func:`parallel_filter` also bounds the floating-point error of computing ``h * y`` and ``h * W`` (Higham's
``gamma_n |h| * |y|``), so its returned bound is rigorous for the computed ``W_f``, ``y_f``.

Any number of joints ``nj`` (the H4 has 4, a serial arm 6): every function works column by column (joint by
joint), so the result for one joint does not depend on the others. Stacking convention: sample ``k``, joint
``i`` -> row ``nj*k + i`` of ``W`` and ``y`` (``4*k + i`` for the H4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.signal

from h4bench.ident.validation import as_float_array, check_finite, positive, positive_int

N_JOINTS = 4  # the default chain's joint count (the H4's); every function takes `joints` for other robots

__all__ = [
    "DEFAULT_TORQUE_TIMING",
    "TORQUE_TIMINGS",
    "Derivatives",
    "FilteredEquation",
    "ProcessingSettings",
    "central_difference",
    "decimation_fir",
    "default_edge_samples",
    "derivatives",
    "exclude_low_speed",
    "lowpass_position",
    "parallel_filter",
    "second_difference",
    "torque_timing",
]

_U = 2.0**-53  # unit round-off of binary64, round to nearest
_TINY = 1e-300  # absolute slack for underflow: >= L * 2**-1074 for any realistic tap count L


# ----------------------------------------------------------------------------------------------- validation


def _joint_columns(x, name: str = "q") -> np.ndarray:
    """A finite float array of shape (n, nj), nj >= 1: one row per sample, one column per joint."""
    arr = as_float_array(x, name)
    if arr.ndim != 2 or arr.shape[1] < 1:
        raise ValueError(f"{name} must have shape (n, n_joints), one column per joint, got {arr.shape}")
    check_finite(arr, name)
    return arr


def _cutoff(cutoff_hz, dt: float, name: str = "cutoff_hz") -> float:
    cutoff_hz = positive(cutoff_hz, name)
    nyquist = 0.5 / dt
    if cutoff_hz >= nyquist:
        raise ValueError(f"{name} must be below the Nyquist frequency 1/(2 dt) = {nyquist:g} Hz, got {cutoff_hz:g}")
    return cutoff_hz


# ------------------------------------------------------------------------------------ positions, derivatives


def default_edge_samples(dt: float, cutoff_hz: float) -> int:
    """Samples at each end affected by the Butterworth transient: ``ceil(3 / (cutoff_hz dt))``.

    A 4th-order Butterworth's impulse response envelope decays with time constant ``1/(2 pi fc sin(pi/8))``
    ~ ``0.42/fc``; after ``3/fc`` it is below 1e-3 of its peak. Used both as the padding length of
    :func:`lowpass_position` and (+2 for the difference stencils) as the trimmed edge of :func:`derivatives`.
    """
    dt = positive(dt, "dt")
    cutoff_hz = positive(cutoff_hz, "cutoff_hz")
    return int(math.ceil(3.0 / (cutoff_hz * dt)))


def lowpass_position(q, dt: float, cutoff_hz: float, order: int = 4, padlen: int | None = None) -> np.ndarray:
    """Zero-phase Butterworth low-pass of each joint's position (``scipy.signal.sosfiltfilt``).

    q : (n, nj) joint angles [rad]; dt : sample period [s]; cutoff_hz : -3 dB frequency of ONE pass [Hz]
    (forward-backward squares the magnitude: the combined gain at ``cutoff_hz`` is 1/2, -6 dB, and the
    effective order is ``2*order``); order : Butterworth order of one pass.

    Padding: odd extension (``padtype="odd"``: the signal is reflected through its end point, which continues
    its value and slope, so a smooth trajectory sees no step) of ``padlen`` samples at each end, by default
    :func:`default_edge_samples` (about three time constants of the filter), clipped to ``n - 1``. Samples
    within that distance of either end still carry some transient; :func:`derivatives` marks them invalid.

    Returns (n, nj) filtered positions [rad].
    """
    q = _joint_columns(q)
    dt = positive(dt, "dt")
    cutoff_hz = _cutoff(cutoff_hz, dt)
    order = positive_int(order, "order")
    n = q.shape[0]
    if n < 2:
        raise ValueError(f"q must have at least 2 samples to be filtered, got {n}")
    if padlen is None:
        padlen = min(default_edge_samples(dt, cutoff_hz), n - 1)
    else:
        padlen = positive_int(padlen, "padlen", minimum=0)
        if padlen >= n:
            raise ValueError(f"padlen must be < n = {n} (number of samples in q), got {padlen}")
    sos = scipy.signal.butter(order, cutoff_hz, btype="low", output="sos", fs=1.0 / dt)
    return scipy.signal.sosfiltfilt(sos, q, axis=0, padtype="odd", padlen=padlen)


def central_difference(x, dt: float) -> np.ndarray:
    """First derivative along axis 0 by central differences, second-order accurate.

    x : (n, ...) samples, n >= 3; dt : sample period [s]. Interior: ``(x[k+1] - x[k-1]) / (2 dt)``, error
    ``dt^2/6 x'''``. The two end samples use the one-sided second-order formulas of ``numpy.gradient``
    (``edge_order=2``), so every output is O(dt^2) accurate, but the ends are noisier; callers usually drop
    them (see :func:`derivatives`). Returns an array of the same shape [x's unit / s].
    """
    x = as_float_array(x, "x")
    dt = positive(dt, "dt")
    if x.ndim == 0 or x.shape[0] < 3:
        raise ValueError(f"x must have at least 3 samples along axis 0, got shape {x.shape}")
    return np.gradient(x, dt, axis=0, edge_order=2)


def second_difference(x, dt: float) -> np.ndarray:
    """Second derivative along axis 0 by the 3-point central difference, second-order accurate.

    x : (n, ...) samples, n >= 4; dt : sample period [s]. Interior: ``(x[k+1] - 2 x[k] + x[k-1]) / dt^2``,
    error ``dt^2/12 x''''`` (a quarter of that of a central difference applied twice, whose stencil spans
    5 samples). Ends: one-sided ``(2 x0 - 5 x1 + 4 x2 - x3) / dt^2`` (second-order). Returns the same shape
    [x's unit / s^2].
    """
    x = as_float_array(x, "x")
    dt = positive(dt, "dt")
    if x.ndim == 0 or x.shape[0] < 4:
        raise ValueError(f"x must have at least 4 samples along axis 0, got shape {x.shape}")
    out = np.empty_like(x)
    out[1:-1] = (x[2:] - 2.0 * x[1:-1] + x[:-2]) / dt**2
    out[0] = (2.0 * x[0] - 5.0 * x[1] + 4.0 * x[2] - x[3]) / dt**2
    out[-1] = (2.0 * x[-1] - 5.0 * x[-2] + 4.0 * x[-3] - x[-4]) / dt**2
    return out


class Derivatives(NamedTuple):
    """Filtered joint positions and their derivatives; ``valid`` selects samples free of edge effects.

    q : (n, nj) [rad]; qd : (n, nj) [rad/s]; qdd : (n, nj) [rad/s^2]; valid : slice over axis 0.
    Typical use: ``q, qd, qdd, valid = derivatives(...)`` then ``q[valid]``, ``qd[valid]``, ...
    """

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    valid: slice


def derivatives(q, dt: float, cutoff_hz: float, order: int = 4, trim: int | None = None,
                timing: str = "hold") -> Derivatives:
    """Zero-phase low-pass of ``q`` then ``qd``, ``qdd`` by central differences of the filtered positions.

    q : (n, nj) measured joint angles [rad]; dt : sample period [s]; cutoff_hz, order : Butterworth settings of
    :func:`lowpass_position`; trim : samples to mark invalid at each end, default
    ``default_edge_samples(dt, cutoff_hz) + 2`` (filter transient + the one-sided difference stencils).

    timing : the instant the torque sample ``k`` stands for (:data:`TORQUE_TIMINGS`); default
    :data:`DEFAULT_TORQUE_TIMING` = ``"hold"``, the one default of the library, the scenario specs and
    ``h4bench identify`` (the simulator's torques, like a joint controller's logged commands, are held):

    - ``"sample"``: the instant ``t_k`` (a torque measured at the sampling instant; the paper's convention):
      ``q[k]``, ``(q[k+1] - q[k-1]) / (2 dt)``, ``(q[k+1] - 2 q[k] + q[k-1]) / dt^2``;
    - ``"hold"``: the step ``[t_k, t_k + dt)`` over which a zero-order-hold command is applied (a logged
      motor command, as the simulator's and a joint controller's): the dynamics hold at every instant of the
      step with the same torque, so the regressor is evaluated at mid-step ``t_k + dt/2`` with
      ``(q[k] + q[k+1]) / 2``, ``(q[k+1] - q[k]) / dt`` and the mean of the second differences at ``k`` and
      ``k+1``. With ``"sample"`` on held torques, the acceleration is late by half a step
      (``dt/2 x jerk``: about 10 rad/s^2 at 3 Hz and 700 rad/s^2, over 0.25 N m on the H4 after filtering).

    All arrays keep length n (end samples use one-sided second-order differences) and ``valid =
    slice(trim, n - trim)`` says which samples to keep. Raises ValueError if nothing would remain.
    """
    q = _joint_columns(q)
    dt = positive(dt, "dt")
    cutoff_hz = _cutoff(cutoff_hz, dt)
    n = q.shape[0]
    if trim is None:
        trim = default_edge_samples(dt, cutoff_hz) + 2
    else:
        trim = positive_int(trim, "trim", minimum=0)
    if n < 4 or n - 2 * trim < 1:
        raise ValueError(f"q must have more than 2*trim = {2 * trim} samples (and at least 4), got {n}")
    timing = torque_timing(timing)
    qf = lowpass_position(q, dt, cutoff_hz, order)
    qdd = second_difference(qf, dt)
    if timing == "sample":
        return Derivatives(qf, central_difference(qf, dt), qdd, slice(trim, n - trim))
    # mid-step values; the last sample has no step after it inside the record: it keeps its own (it lies
    # in the trimmed edge, as the one-sided ends of the "sample" stencils do)
    qm, qdm, qddm = qf.copy(), central_difference(qf, dt), qdd.copy()
    qm[:-1] = 0.5 * (qf[:-1] + qf[1:])
    qdm[:-1] = (qf[1:] - qf[:-1]) / dt
    qddm[:-1] = 0.5 * (qdd[:-1] + qdd[1:])
    return Derivatives(qm, qdm, qddm, slice(trim, n - trim))


TORQUE_TIMINGS = ("sample", "hold")
#: The one default torque timing (:func:`derivatives`, :class:`ProcessingSettings`, :func:`ident.robots.serial.process`,
#: the scenario specs): a logged torque is a command held over its sample period. Pass ``"sample"`` for torques
#: measured at the sampling instants.
DEFAULT_TORQUE_TIMING = "hold"


def torque_timing(timing) -> str:
    """Validated ``timing`` of :func:`derivatives` (``"sample"`` or ``"hold"``)."""
    if timing not in TORQUE_TIMINGS:
        raise ValueError(f"torque_timing must be one of {', '.join(map(repr, TORQUE_TIMINGS))} "
                         f"(the instant a torque sample stands for), got {timing!r}")
    return timing


# ------------------------------------------------------------------------------------------ parallel filter


def decimation_fir(factor: int, numtaps: int | None = None, cutoff: float = 0.8, window="hamming") -> np.ndarray:
    """Linear-phase FIR low-pass for decimation by ``factor`` (``scipy.signal.firwin``), unit DC gain.

    factor : decimation factor >= 1; numtaps : odd tap count, default ``20*factor + 1`` (as
    ``scipy.signal.decimate``); cutoff : -6 dB frequency relative to the DECIMATED Nyquist frequency
    ``fs/(2 factor)`` (Gautier uses 0.8), in (0, 1]; window : any ``firwin`` window.
    Returns (numtaps,) taps. An odd count makes the delay an integer, ``(numtaps - 1)/2`` samples.
    """
    factor = positive_int(factor, "factor")
    if numtaps is None:
        numtaps = 20 * factor + 1
    numtaps = positive_int(numtaps, "numtaps")
    if numtaps % 2 == 0:
        raise ValueError(f"numtaps must be odd (integer delay), got {numtaps}")
    if isinstance(cutoff, bool) or not isinstance(cutoff, (int, float, np.integer, np.floating)):
        raise TypeError(f"cutoff must be a real number, got {type(cutoff).__name__}")
    if not 0.0 < cutoff <= 1.0:
        raise ValueError(f"cutoff must be in (0, 1] (fraction of the decimated Nyquist frequency), got {cutoff}")
    if numtaps == 1:
        return np.ones(1)
    return scipy.signal.firwin(numtaps, cutoff / factor, window=window)


@dataclass(frozen=True)
class FilteredEquation:
    """Result of :func:`parallel_filter`: ``y = W theta + e`` with ``|e| <= bound`` row by row.

    W : (nj m, p) filtered, decimated regressor; y : (nj m,) filtered torques [N m];
    bound : (nj m,) rigorous bound [N m] on ``|y - W theta_true|`` given the input bound; it includes the
    rounding error of computing ``W`` only if ``w_rounding_included`` (``theta_abs_max`` was given), else add
    ``w_rounding @ theta_abs_max`` yourself (:meth:`total_bound` does it rigorously);
    w_rounding : (nj m, p) elementwise bound on ``|W - h * W_exact|`` (floating-point error of the filter);
    sample_index : (m,) index of the original sample at the centre of each output's window (tap
    ``(L-1)//2``: for symmetric taps the time the output represents); output row ``nj*k + i`` is joint i of
    ``sample_index[k]``; window_start : (m,) first original sample in each window (the window is
    ``window_start[k] .. window_start[k] + L - 1``); taps : (L,) the filter h; factor : decimation factor;
    l1_norm : ``||h||_1`` (the scalar-bound amplification); joints : nj, the joints per sample.
    """

    W: np.ndarray
    y: np.ndarray
    bound: np.ndarray
    w_rounding: np.ndarray
    w_rounding_included: bool
    sample_index: np.ndarray
    window_start: np.ndarray
    taps: np.ndarray
    factor: int
    l1_norm: float
    joints: int = N_JOINTS

    @property
    def rows(self) -> np.ndarray:
        """(m, nj) original row indices ``nj*sample_index[k] + i`` that each output row stands for."""
        return self.joints * self.sample_index[:, None] + np.arange(self.joints)

    def total_bound(self, theta_abs_max) -> np.ndarray:
        """(nj m,) rigorous bound ``bound + w_rounding @ theta_abs_max``, rounded up.

        theta_abs_max : (p,) max ``|theta_j|`` over the prior box. If the W rounding is already included,
        returns ``bound`` unchanged.
        """
        if self.w_rounding_included:
            return self.bound
        t = _theta_abs_max(theta_abs_max, self.W.shape[1])
        return _round_up(self.bound + self.w_rounding @ t, self.W.shape[1] + 2)

    def propagate_mask(self, row_mask) -> np.ndarray:
        """(nj m,) bool: output row kept iff every input row of the same joint in its window is kept.

        row_mask : (nj n,) bool over the ORIGINAL rows (e.g. from :func:`exclude_low_speed`), True = keep.
        Use this to exclude rows after filtering without breaking the time contiguity the filter needs.
        (Alternatively, keep all rows and enlarge their bound where the model is unreliable, e.g.
        ``b + 2 Fs_max`` where ``sign(qd)`` is uncertain; that propagates exactly.)
        """
        row_mask = np.asarray(row_mask)
        nj = self.joints
        if row_mask.dtype != bool or row_mask.ndim != 1 or row_mask.size % nj:
            raise ValueError(f"row_mask must be a 1-D bool array of length {nj}n, got dtype {row_mask.dtype}, "
                             f"shape {row_mask.shape}")
        n = row_mask.size // nj
        L = self.taps.size
        if self.window_start.size and self.window_start[-1] + L > n:
            raise ValueError(f"row_mask covers {n} samples, fewer than the filtered data used "
                             f"({self.window_start[-1] + L})")
        bad = np.concatenate([np.zeros((1, nj)), np.cumsum(~row_mask.reshape(n, nj), axis=0)])
        counts = bad[self.window_start + L] - bad[self.window_start]
        return (counts == 0).reshape(-1)


def _theta_abs_max(theta_abs_max, p: int) -> np.ndarray:
    t = as_float_array(theta_abs_max, "theta_abs_max")
    if t.shape != (p,):
        raise ValueError(f"theta_abs_max must have shape ({p},), got {t.shape}")
    check_finite(t, "theta_abs_max")
    if np.any(t < 0):
        raise ValueError("theta_abs_max must be >= 0 (max |theta_j| over the prior box)")
    return t


def _gamma(n: int) -> float:
    """Higham's gamma_n = n u / (1 - n u) for recursive sums of n products in round-to-nearest."""
    return n * _U / (1.0 - n * _U)


def _round_up(x: np.ndarray, n_ops: int) -> np.ndarray:
    """Upper bound of a sum of ``n_ops`` non-negative fp terms computed in round-to-nearest.

    A fp sum of non-negative terms is >= (1 - gamma_n) times the exact one; multiply by 1 + 2 gamma_n
    (>= 1/(1 - gamma_n)), add the underflow slack and step one ulp up for the multiplication's own rounding.
    """
    return np.nextafter(x * (1.0 + 2.0 * _gamma(n_ops + 2)) + _TINY, np.inf)


def _fir_valid_decimated(x: np.ndarray, taps: np.ndarray, starts: np.ndarray, factor: int) -> np.ndarray:
    """out[k] = sum_j taps[j] * x[starts[k] + L - 1 - j] along axis 0 ('valid' convolution, decimated).

    Recursive summation in tap order, so |fl(out) - out| <= gamma_L (|taps| * |x|) for every entry.
    The loop is over taps, not samples.
    """
    L = taps.size
    m = starts.size
    out = np.zeros((m,) + x.shape[1:])
    first = int(starts[0]) if m else 0
    for j in range(L):
        off = first + L - 1 - j
        out += taps[j] * x[off: off + (m - 1) * factor + 1: factor]
    return out


def parallel_filter(W, y, bound, factor: int, numtaps: int | None = None, *, cutoff: float = 0.8,
                    taps=None, theta_abs_max=None, joints: int = N_JOINTS) -> FilteredEquation:
    """Parallel filtering of ``y = W theta + e``: the same FIR per joint on ``y`` and every column of ``W``.

    W : (nj n, p) regressor, rows stacked ``nj*k + i`` (sample k, joint i); y : (nj n,) measured torques [N m];
    bound : scalar or (nj n,) bound on ``|e|`` [N m]; factor : integer decimation factor;
    numtaps, cutoff : FIR design (:func:`decimation_fir`), ignored if ``taps`` (any (L,) finite array) is given;
    theta_abs_max : optional (p,) max ``|theta_j|`` over the prior box, to fold the rounding error of ``h * W``
    (which enters the equation as ``|dW| |theta|``) into the returned bound; joints : nj >= 1, the joints per
    sample (default 4, the H4).

    The FIR runs along time for each joint separately (rows i, i+nj, i+2nj, ...), never across the interleaved
    stacking, in 'valid' mode: output k uses samples ``window_start[k] .. window_start[k] + L - 1`` only, with
    ``window_start[k] = k * factor``, so no padding enters and the bound is exact:

        y_f = W_f theta + h * e,   |h * e| <= |h| * b   (<= ||h||_1 max b).

    Rigour: the outputs are computed by plain recursive sums over the taps, whose error obeys
    ``|fl(h * y) - h * y| <= gamma_L |h| * |y|`` (Higham, Accuracy and Stability, 2002, sec. 3.1); the returned
    ``bound`` adds that term, and ``w_rounding = gamma_L |h| * |W|`` (inflated for its own rounding) bounds
    ``|fl(h * W) - h * W|``. All sums of non-negative terms are rounded up (:func:`_round_up`).
    Returns a :class:`FilteredEquation` with m = ``(n - L) // factor + 1`` output samples.
    """
    nj = positive_int(joints, "joints")
    factor = positive_int(factor, "factor")
    W = as_float_array(W, "W")
    y = as_float_array(y, "y")
    if W.ndim != 2:
        raise ValueError(f"W must have shape ({nj}n, p), got {W.shape}")
    rows, p = W.shape
    if rows == 0 or rows % nj:
        raise ValueError(f"W must have {nj}n rows ({nj} joints per sample), got {rows}")
    if y.shape != (rows,):
        raise ValueError(f"y must have shape ({rows},) to match W, got {y.shape}")
    check_finite(W, "W")
    check_finite(y, "y")
    b = as_float_array(bound, "bound")
    if b.ndim == 0:
        b = np.full(rows, float(b))
    elif b.shape != (rows,):
        raise ValueError(f"bound must be a scalar or have shape ({rows},), got {b.shape}")
    check_finite(b, "bound")
    if np.any(b < 0):
        raise ValueError("bound must be >= 0")
    if taps is None:
        h = decimation_fir(factor, numtaps, cutoff)
    else:
        h = as_float_array(taps, "taps")
        if h.ndim != 1 or h.size == 0:
            raise ValueError(f"taps must be a non-empty 1-D array, got shape {h.shape}")
        check_finite(h, "taps")
    t_max = None if theta_abs_max is None else _theta_abs_max(theta_abs_max, p)

    n = rows // nj
    L = h.size
    if n < L:
        raise ValueError(f"W and y must hold at least as many samples as taps ({L}), got {n} samples")
    m = (n - L) // factor + 1
    starts = np.arange(m) * factor
    habs = np.abs(h)

    Y = y.reshape(n, nj)
    W3 = W.reshape(n, nj, p)
    y_f = _fir_valid_decimated(Y, h, starts, factor).reshape(-1)
    W_f = _fir_valid_decimated(W3, h, starts, factor).reshape(-1, p)
    hb = _fir_valid_decimated(b.reshape(n, nj), habs, starts, factor).reshape(-1)
    hy = _fir_valid_decimated(np.abs(Y), habs, starts, factor).reshape(-1)
    hw = _fir_valid_decimated(np.abs(W3), habs, starts, factor).reshape(-1, p)

    g = 2.0 * _gamma(L)  # >= gamma_L / (1 - gamma_L): covers the fp error of computing |h|*|.| itself
    w_rounding = _round_up(g * hw, L)
    total = hb + g * hy
    if t_max is not None:
        total = total + w_rounding @ t_max
    bound_f = _round_up(total, L + p + 3)
    l1 = float(np.nextafter(habs.sum() * (1.0 + 2.0 * _gamma(L)), np.inf))
    return FilteredEquation(W=W_f, y=y_f, bound=bound_f, w_rounding=w_rounding,
                            w_rounding_included=t_max is not None, sample_index=starts + (L - 1) // 2,
                            window_start=starts, taps=h, factor=factor, l1_norm=l1, joints=nj)


# ----------------------------------------------------------------------------------------- low-speed rows


def exclude_low_speed(qd, threshold, whole_samples: bool = False) -> np.ndarray:
    """Row mask (True = keep) dropping rows whose joint speed is below ``threshold``.

    qd : (n, nj) joint velocities [rad/s]; threshold : scalar or (nj,) per joint [rad/s], >= 0; a row
    ``nj*k + i`` is kept iff ``|qd[k, i]| >= threshold[i]``. whole_samples : if True, drop all nj rows of a
    sample as soon as one joint is slow (keeps samples complete, e.g. for per-sample diagnostics).
    Returns a (nj n,) bool array aligned with the ``nj*k + i`` stacking.
    """
    qd = _joint_columns(qd, "qd")
    nj = qd.shape[1]
    thr = as_float_array(threshold, "threshold")
    if thr.ndim == 0:
        thr = np.full(nj, float(thr))
    elif thr.shape != (nj,):
        raise ValueError(f"threshold must be a scalar or have shape ({nj},), got {thr.shape}")
    if not np.all(np.isfinite(thr)) or np.any(thr < 0):
        raise ValueError(f"threshold must be finite and >= 0, got {thr}")
    keep = np.abs(qd) >= thr
    if whole_samples:
        keep = np.repeat(keep.all(axis=1, keepdims=True), nj, axis=1)
    return keep.reshape(-1)


# ------------------------------------------------------------------------------------------------ settings


@dataclass(frozen=True)
class ProcessingSettings:
    """Settings of the processing chain, with defaults for 1 kHz data whose useful motion is below ~10 Hz.

    dt = 1e-3 s: the paper's 1000 Hz sampling.
    position_cutoff_hz = 50 Hz (one pass; -6 dB after forward-backward), order = 4: Gautier's rule puts the
    Butterworth cut-off at >= 5 times the motion band so the filter does not distort it (the combined gain
    at 10 Hz is 1 - 2.6e-6), while the 8th-order roll-off removes encoder quantisation before the double
    differentiation (noise in qdd grows like f^2).
    decimation = 10: 100 Hz output, Nyquist 50 Hz, still 5 times the motion band; the regressor rows stay
    plentiful (1000 per joint and 10 s) while consecutive rows are less redundant.
    fir_cutoff = 0.8 of the decimated Nyquist (40 Hz): the usual choice (Gautier), pass-band flat to 1e-4 at
    10 Hz. numtaps = None -> 20*decimation + 1 (Hamming), alias rejection about -52 dB but ``||h||_1`` = 1.71,
    which multiplies the guaranteed bound; 4*decimation + 1 taps give ``||h||_1`` = 1.06 with -11 dB alias
    rejection (aliasing does not bias the filtered equation, it only mixes high-frequency content in).
    speed_threshold = 0.05 rad/s: MuJoCo's friction law is exact above ~0.005 rad/s, and a sign change
    within one step needs ``|qd| < |qdd| dt`` (~0.05 rad/s at 50 rad/s^2); rows below are excluded.
    torque_timing = "hold" (:data:`DEFAULT_TORQUE_TIMING`, the specs' default too): the torque sample ``k`` is
    a zero-order-hold command held over ``[t_k, t_k + dt)`` (the regressor at mid-step, see :func:`derivatives`),
    as the simulator's torques; ``"sample"``: it stands for the instant ``t_k`` (a torque measured there).
    """

    dt: float = 1e-3
    position_cutoff_hz: float = 50.0
    butter_order: int = 4
    decimation: int = 10
    fir_cutoff: float = 0.8
    numtaps: int | None = None
    speed_threshold: float = 0.05
    torque_timing: str = DEFAULT_TORQUE_TIMING

    def __post_init__(self) -> None:
        dt = positive(self.dt, "dt")
        torque_timing(self.torque_timing)
        _cutoff(self.position_cutoff_hz, dt, "position_cutoff_hz")
        positive_int(self.butter_order, "butter_order")
        positive_int(self.decimation, "decimation")
        if isinstance(self.speed_threshold, bool) or not isinstance(self.speed_threshold, (int, float)):
            raise TypeError(f"speed_threshold must be a real number, got {type(self.speed_threshold).__name__}")
        if not (math.isfinite(self.speed_threshold) and self.speed_threshold >= 0):
            raise ValueError(f"speed_threshold must be finite and >= 0, got {self.speed_threshold}")
        self.taps()  # validates numtaps and fir_cutoff

    def taps(self) -> np.ndarray:
        """(L,) the parallel filter's FIR taps (:func:`decimation_fir`)."""
        return decimation_fir(self.decimation, self.numtaps, self.fir_cutoff)
