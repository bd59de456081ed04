"""From measured data to the bounded-error equation ``y = W theta + e``, ``|e| <= bound`` row by row.

The paper's chain (section 4.1), each step in :mod:`ident.filtering`:

1. zero-phase Butterworth low-pass on the measured q, central differences for qd and qdd; the samples at
   both ends (filter transients) are dropped;
2. the regressor ``W(q, qd, qdd)`` (paper eqs. 14-18) and ``y = tau`` (the measured torques);
3. rows whose joint speed is under the threshold are marked: ``sign(qd)`` is unreliable there;
4. parallel filtering: the same FIR on y and every column of W, joint by joint, then decimation; the bound is
   propagated (``|h| * b``) with the floating-point error of the filter, and an output row is kept only if its
   whole window is free of marked rows.

``bound`` is the caller's claim about the raw rows: the torque error (noise) bound plus an allowance for the
derivative estimation and the model's mismatch. It is propagated, never guessed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ident.filtering import ProcessingSettings, derivatives, exclude_low_speed, parallel_filter
from ident.regressor import parameter_names, regressor


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


def raw_equation(geometry, q, tau, dt: float, settings: ProcessingSettings | None = None, structure: str = "paper"):
    """Steps 1-3: the unfiltered equation on the samples free of edge effects.

    Returns (W (4n', p), y (4n',), keep (4n',) bool speed mask, samples (n',) original sample indices,
    (q, qd, qdd) estimated at those samples).
    """
    settings = settings or ProcessingSettings(dt=dt)
    est = derivatives(q, dt, settings.position_cutoff_hz, settings.butter_order)
    v = est.valid
    qf, qd, qdd = est.q[v], est.qd[v], est.qdd[v]
    samples = np.arange(q.shape[0])[v]
    w = regressor(geometry, qf, qd, qdd, structure=structure)
    y = np.asarray(tau, dtype=float)[v].reshape(-1)
    keep = exclude_low_speed(qd, settings.speed_threshold)
    return w, y, keep, samples, (qf, qd, qdd)


def build_equation(geometry, dataset, bound, settings: ProcessingSettings | None = None, prior=None,
                   structure: str = "paper") -> Equation:
    """The processed equation of a :class:`sim.Dataset` (t, q, tau) under a raw-row bound [N m].

    bound : scalar, the claim ``|tau_measured - W_true theta| <= bound`` on every raw row (noise plus the
    allowance for derivative and model errors); prior : Box or (lower, upper), used to fold the
    floating-point error of filtering W into the bound (needed for rigour; omitted = not folded, flagged in
    ``info``). settings.decimation == 1 with numtaps == 1 skips the parallel filter.
    """
    bound = float(bound)
    if not (np.isfinite(bound) and bound > 0):
        raise ValueError(f"bound must be a finite number > 0 [N m], got {bound!r}")
    dt = dataset.dt
    settings = settings or ProcessingSettings(dt=dt)
    if abs(settings.dt - dt) > 1e-9:
        raise ValueError(f"settings.dt must match the dataset's sample period {dt:g} s, got {settings.dt:g}")
    names = parameter_names(structure)
    w, y, keep, samples, _ = raw_equation(geometry, dataset.q, dataset.tau, dt, settings, structure)
    t_abs = _prior_abs_max(prior, len(names))
    taps = settings.taps()
    if settings.decimation == 1 and taps.size == 1:
        rows = np.flatnonzero(keep)
        return Equation(w[rows], y[rows], np.full(rows.size, bound), samples[rows // 4], rows % 4, names,
                        {"l1_norm": 1.0, "rows_raw": keep.size, "rows_kept": rows.size, "filtered": False})
    fe = parallel_filter(w, y, bound, settings.decimation, taps=taps, theta_abs_max=t_abs)
    mask = fe.propagate_mask(keep)
    rows = np.flatnonzero(mask)
    return Equation(
        fe.W[rows], fe.y[rows], fe.bound[rows], samples[fe.sample_index[rows // 4]], rows % 4, names,
        {"l1_norm": fe.l1_norm, "rows_raw": keep.size, "rows_filtered": fe.y.size, "rows_kept": rows.size,
         "filtered": True, "w_rounding_included": fe.w_rounding_included, "raw_bound": bound},
    )
