"""From measured data to the bounded-error equation ``y = W theta + e``, ``|e| <= bound`` row by row.

The paper's chain (section 4.1), each step in :mod:`ident.processing.filtering`:

1. zero-phase Butterworth low-pass on the measured q, central differences for qd and qdd; the samples at
   both ends (filter transients) are dropped;
2. the regressor ``W(q, qd, qdd)`` (paper eqs. 14-18 for the H4) and ``y = tau`` (the measured torques);
3. rows whose joint speed is under the threshold are marked: ``sign(qd)`` is unreliable there;
4. parallel filtering: the same FIR on y and every column of W, joint by joint, then decimation; the bound is
   propagated (``|h| * b``) with the floating-point error of the filter, and an output row is kept only if its
   whole window is free of marked rows.

``bound`` is the caller's claim about the raw rows: the torque error (noise) bound plus an allowance for the
derivative estimation and the model's mismatch. It is propagated, never guessed.

The chain is generic: the robot's regressor is an argument (``regressor(q, qd, qdd) -> (4n, p)``, row ``4k + i``
= sample k, joint i) with its column names; the H4's binding is :mod:`ident.robots.h4_equation`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from h4bench.ident.errors import ProcessingError
from h4bench.ident.processing.filtering import (N_JOINTS, ProcessingSettings, default_edge_samples, derivatives,
                                        exclude_low_speed, parallel_filter)


@dataclass(frozen=True)
class Equation:
    """``y = W theta + e`` with ``|e| <= bound``: W (m, p), y (m,), bound (m,) [N m]; ``sample`` (m,) the
    original sample index each row stands for, ``joint`` (m,) its joint (0..3); ``names`` the columns."""

    W: np.ndarray
    y: np.ndarray
    bound: np.ndarray
    sample: np.ndarray
    joint: np.ndarray
    names: tuple[str, ...]
    info: dict = field(default_factory=dict, compare=False)

    def __len__(self) -> int:
        return self.y.size


def _prior_abs_max(prior, p: int) -> np.ndarray | None:
    if prior is None:
        return None
    lower, upper = (prior.lower, prior.upper) if hasattr(prior, "lower") else prior
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    if lower.shape != (p,) or upper.shape != (p,):
        raise ValueError(f"prior must have {p} lower and upper bounds, got shapes {lower.shape}, {upper.shape}")
    return np.maximum(np.abs(lower), np.abs(upper))


def raw_equation(regressor, q, tau, dt: float, settings: ProcessingSettings | None = None):
    """Steps 1-3: the unfiltered equation on the samples free of edge effects.

    regressor : callable ``(q, qd, qdd) -> W`` with q, qd, qdd (n, 4) [rad, rad/s, rad/s^2] and W (4n, p), row
    ``4k + i`` = sample k, joint i (e.g. the H4's, bound by :func:`ident.robots.h4_equation.raw_equation`).

    Returns (W (4n', p), y (4n',), keep (4n',) bool speed mask, samples (n',) original sample indices,
    (q, qd, qdd) estimated at those samples).
    """
    settings = settings or ProcessingSettings(dt=dt)
    est = derivatives(q, dt, settings.position_cutoff_hz, settings.butter_order, timing=settings.torque_timing)
    v = est.valid
    qf, qd, qdd = est.q[v], est.qd[v], est.qdd[v]
    samples = np.arange(q.shape[0])[v]
    w = regressor(qf, qd, qdd)
    y = np.asarray(tau, dtype=float)[v].reshape(-1)
    keep = exclude_low_speed(qd, settings.speed_threshold)
    return w, y, keep, samples, (qf, qd, qdd)



BLOCK_SAMPLES = 100_000  # samples per processing block: ~45 MB of raw regressor; logs up to this size are one block


def _row_bounds(bound, n: int) -> np.ndarray:
    """bound -> (4,) per joint or (4n,) per raw row; validated (finite, > 0)."""
    b = np.asarray(bound, dtype=float) if not isinstance(bound, (str, bytes)) else None
    if b is None or b.dtype.kind not in "fiu":
        raise TypeError(f"bound must be a number or an array of numbers [N m], got {type(bound).__name__}")
    if b.ndim == 0:
        b = np.full(N_JOINTS, float(b))
    if b.shape not in ((N_JOINTS,), (N_JOINTS * n,)):
        raise ValueError(f"bound must be a scalar, one value per joint ({N_JOINTS},) or one per raw row "
                         f"({N_JOINTS * n},) [N m], got shape {b.shape}")
    bad = ~(np.isfinite(b) & (b > 0))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        where = f"joint {k + 1}" if b.size == N_JOINTS else f"raw row {k} (sample {k // N_JOINTS}, joint {k % N_JOINTS + 1})"
        raise ValueError(f"bound must be finite and > 0 [N m] everywhere, got {b[k]!r} at {where}")
    return b


def _bounds_of(b: np.ndarray, start: int, stop: int) -> np.ndarray:
    """Raw-row bounds of samples start..stop-1 (rows 4*start .. 4*stop-1)."""
    if b.size == N_JOINTS:
        return np.tile(b, stop - start)
    return b[N_JOINTS * start: N_JOINTS * stop]


def _too_slow(kept_raw: int, total_raw: int, threshold: float) -> ProcessingError:
    if kept_raw == 0:
        return ProcessingError(
            f"no sample of the log moves faster than the speed threshold {threshold:g} rad/s "
            f"(processing.speed_threshold) on any joint: the robot must move during the log (a static log "
            f"cannot identify the parameters)")
    return ProcessingError(
        f"no filter window is free of samples slower than the speed threshold {threshold:g} rad/s "
        f"(processing.speed_threshold): only {kept_raw} of {total_raw} raw rows move fast enough, never over "
        f"a whole window; the robot must move continuously during the log")


def select_rows(w, y, bound, qd, settings: ProcessingSettings, taps, theta_abs_max=None):
    """The rows of a record (or block) that the identification keeps, as :func:`build_equation` selects them.

    w (4n, p) raw regressor rows (row 4k + i = sample k, joint i), y (4n,), bound a scalar or (4n,) [N m], qd (n, 4)
    joint speeds [rad/s], taps the parallel filter's (``settings.taps()``). The low-speed exclusion
    (``exclude_low_speed``); unless ``settings.decimation == 1`` with one tap, the parallel filter and decimation
    (``parallel_filter``, with ``theta_abs_max`` to fold W's rounding into the bound) and the exclusion propagated over
    each output's window (``propagate_mask``). Returns ``(fe, rows, keep)``: the filter's result (None unfiltered),
    the kept rows (indices into ``fe.W`` or ``w``) and the raw rows' mask (4n,).
    """
    keep = exclude_low_speed(qd, settings.speed_threshold)
    if settings.decimation == 1 and np.size(taps) == 1:
        return None, np.flatnonzero(keep), keep
    fe = parallel_filter(w, y, bound, settings.decimation, taps=taps, theta_abs_max=theta_abs_max)
    return fe, np.flatnonzero(fe.propagate_mask(keep)), keep


def _reused_rows(raw, a: int, b: int, q, qd, qdd, p: int):
    """The regressor rows of samples a..b-1 from ``raw`` (a :func:`raw_equation` result), or None unless ``raw``
    holds those samples evaluated at exactly these (q, qd, qdd) (bit for bit) with p columns."""
    if raw is None:
        return None
    w, _, _, samples, (rq, rqd, rqdd) = raw
    if w.ndim != 2 or w.shape[1] != p or samples.size == 0 or w.shape[0] != N_JOINTS * samples.size:
        return None
    i0 = a - int(samples[0])
    i1 = i0 + (b - a)
    if i0 < 0 or i1 > samples.size or int(samples[i1 - 1]) != b - 1:
        return None
    if not (np.array_equal(rq[i0:i1], q) and np.array_equal(rqd[i0:i1], qd) and np.array_equal(rqdd[i0:i1], qdd)):
        return None
    return w[N_JOINTS * i0:N_JOINTS * i1]


def build_equation(regressor, names, dataset, bound, settings: ProcessingSettings | None = None, prior=None,
                   block_samples: int = BLOCK_SAMPLES, raw=None) -> Equation:
    """The processed equation of a :class:`sim.Dataset` (t, q, tau) under a raw-row bound [N m].

    regressor : callable ``(q, qd, qdd) -> W`` with q, qd, qdd (n, 4) and W (4n, p) (as for :func:`raw_equation`);
    names : the p column names (the H4's binding: :func:`ident.robots.h4_equation.build_equation`).

    bound : the claim ``|tau_measured - W_true theta| <= bound`` on every raw row (noise plus the allowance
    for derivative and model errors) [N m]: a scalar, one value per joint (4,), or one per raw row (4n,)
    (row ``4k + i`` = sample k, joint i); prior : Box or (lower, upper), used to fold the floating-point error
    of filtering W into the bound (needed for rigour; omitted = not folded, flagged in ``info``).
    settings.decimation == 1 with numtaps == 1 skips the parallel filter.

    Blocks. The record is processed in time blocks of about ``block_samples`` samples, so the peak memory is
    the processed equation plus one block's temporaries (a log of at most ``block_samples`` samples is one
    block, processed exactly as the whole record). A block is a run of consecutive decimated outputs; it
    reads the samples their FIR windows cover plus ``margin = 4 * default_edge_samples + 2`` samples on each
    side (clipped to the record), filters and differentiates them as a record, and discards the margins, so
    every block edge is trimmed like (and further than) the record's edges. Consequences, each measured in
    tests/scenarios/test_identify.py: the rows, samples, joints and y are those of the whole-record
    processing (y bit for bit: the FIR sums the same terms in the same order); W differs only at the rounding
    level of the position filter and the second difference (a block edge's Butterworth transient has decayed
    by about exp(-28) after the margin): on the paper's trajectory tiled to 30 s in blocks of 1000 samples,
    ``max |dW|`` per column <= 5e-12 of the column's largest entry, ``max |dW theta|`` = 1.4e-9 N m over the prior
    [0, 2]^14 against a 1.5 N m bound, and the sign(qd) columns identical. That difference is a derivative-
    estimation error, which the raw bound's allowance covers as it covers the whole record's; the propagated
    bound is computed rigorously for each block's own W, y and raw bounds. Only a row whose joint speed lies
    within ~1e-12 of the speed threshold could be classed differently.
    raw : optional, :func:`raw_equation` of the same log (e.g. computed for an error budget): its regressor rows
    are reused where the block's filtered q, qd and qdd equal those it was evaluated at, bit for bit (a log of
    one block processed with the same settings), instead of evaluating the regressor again. The regressor works
    row by row, so the rows are the ones it would give here (numpy's batched linear algebra may round a batch
    of a single sample differently, by an ulp; never a block of a real log).
    Raises ProcessingError (a ValueError) if the log is too short or no row moves fast enough.
    """
    dt = dataset.dt
    settings = settings or ProcessingSettings(dt=dt)
    if abs(settings.dt - dt) > 1e-9:
        raise ValueError(f"settings.dt must match the dataset's sample period {dt:g} s, got {settings.dt:g}")
    if isinstance(block_samples, bool) or not isinstance(block_samples, (int, np.integer)) or block_samples < 1:
        raise ValueError(f"block_samples must be an integer >= 1, got {block_samples!r}")
    n = len(dataset)
    b_raw = _row_bounds(bound, n)
    names = tuple(names)
    t_abs = _prior_abs_max(prior, len(names))
    taps = settings.taps()
    L = taps.size
    factor = settings.decimation
    edge = default_edge_samples(dt, settings.position_cutoff_hz)
    trim = edge + 2  # as derivatives(): the record's edges
    if n - 2 * trim < max(L, 1) or n < 4:
        raise ProcessingError(
            f"the log must have at least {2 * trim + L} samples (2 x {trim} trimmed at the ends for the position "
            f"filter and differences, plus {L} for the parallel filter's window), got {n}")
    filtered = not (factor == 1 and L == 1)
    scalar = b_raw.size == N_JOINTS and np.all(b_raw == b_raw[0])
    m = (n - 2 * trim - L) // factor + 1  # decimated outputs of the whole record
    per_block = max(1, block_samples // factor)
    margin = 4 * edge + 2
    q, tau = dataset.q, dataset.tau
    # W is filled in place (no concatenation copy): at most 4m rows, or 4 per valid sample unfiltered
    W_all = np.empty((N_JOINTS * (m if filtered else n - 2 * trim), len(names)))
    r = 0
    ys, bs, ss, js = [], [], [], []
    l1 = 1.0
    w_incl = True
    kept_raw = 0
    for k0 in range(0, m, per_block):
        k1 = min(m, k0 + per_block)
        a, b = trim + k0 * factor, trim + (k1 - 1) * factor + L  # samples whose rows the block's outputs use
        c0, c1 = (0, n) if (k0 == 0 and k1 == m) else (max(0, a - margin), min(n, b + margin))
        est = derivatives(q[c0:c1], dt, settings.position_cutoff_hz, settings.butter_order, trim=0,
                          timing=settings.torque_timing)
        sl = slice(a - c0, b - c0)
        qd = est.qd[sl]
        w = _reused_rows(raw, a, b, est.q[sl], qd, est.qdd[sl], len(names))
        if w is None:
            w = regressor(est.q[sl], qd, est.qdd[sl])
        y = np.asarray(tau[a:b], dtype=float).reshape(-1)
        rb = _bounds_of(b_raw, a, b)
        fe, rows, keep = select_rows(w, y, float(rb[0]) if scalar else rb, qd, settings, taps, t_abs)
        own = (trim + k1 * factor if k1 < m else b) - a  # samples not shared with the next block
        kept_raw += int(keep[:N_JOINTS * own].sum())
        if fe is None:
            W_all[r:r + rows.size] = w[rows]
            r += rows.size
            ys.append(y[rows]); bs.append(rb[rows])
            ss.append(a + rows // N_JOINTS); js.append(rows % N_JOINTS)
            continue
        del w
        W_all[r:r + rows.size] = fe.W[rows]
        r += rows.size
        ys.append(fe.y[rows]); bs.append(fe.bound[rows])
        ss.append(a + fe.sample_index[rows // N_JOINTS]); js.append(rows % N_JOINTS)
        l1, w_incl = fe.l1_norm, fe.w_rounding_included
        del fe
    rows_kept = r
    if rows_kept == 0:
        raise _too_slow(kept_raw, N_JOINTS * (n - 2 * trim), settings.speed_threshold)
    W = W_all[:r].copy() if r < W_all.shape[0] // 2 else W_all[:r]  # compact if over half is slack
    del W_all
    info = {"l1_norm": l1, "rows_raw": N_JOINTS * (n - 2 * trim), "rows_kept": rows_kept, "filtered": filtered,
            "blocks": len(ys), "block_samples": per_block * factor, "block_margin": margin}
    if filtered:
        info.update({"rows_filtered": N_JOINTS * m, "w_rounding_included": w_incl,
                     "raw_bound": float(b_raw[0]) if scalar else {"min": float(b_raw.min()), "max": float(b_raw.max())}})
    return Equation(W, np.concatenate(ys), np.concatenate(bs), np.concatenate(ss), np.concatenate(js), names, info)
