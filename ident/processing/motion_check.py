"""What the measured positions prove about the true motion: lower bounds of ``max |qd|`` and ``max |qdd|`` per
joint, against the stated ``qd_max``, ``qdd_max`` of an :class:`~ident.processing.errorspec.ErrorSpec`.

The true positions ``q(t)`` are sampled every ``h`` (``spec.sample_period``) and measured within ``e_k``
(``ErrorSpec.position_error``, or the caller's bound). For every span of ``m`` sample steps:

* the secant ``(q_{k+m} - q_k) / (m h)`` of the TRUE positions is the mean of ``qd`` over the span, so
  ``max |qd| >= |secant_meas| - (e_k + e_{k+m}) / (m h)``;
* the second difference ``(q_{k+2m} - 2 q_{k+m} + q_k) / (m h)^2`` of the TRUE positions is a weighted mean of
  ``qdd`` over the two spans (triangle weights of unit sum; ``qdd`` may jump, as under a held torque step), so
  ``max |qdd| >= |d2_meas| - (e_k + 2 e_{k+m} + e_{k+2m}) / (m h)^2``.

Short spans see the peaks but amplify the position error; long spans average it away but smooth the peaks: the
check takes, per joint, the best lower bound over every span ``m = 1 .. max_span`` and every sample. Each bound is
rounded downward step by step (:func:`ident.numerics.interval.down`), so it is a proof in floating point: a
stated bound below it is contradicted by the data. (The only facts used are the sample period, the position error
bound and that q is the integral of qd and qd of qdd; the stated bounds themselves are not used.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from h4bench.ident.numerics.interval import U, down, up

__all__ = ["MAX_SPAN", "SpecCheck", "check_motion_bounds", "floor_digits"]

MAX_SPAN = 400  # the longest span tried [sample steps] (capped by the log's length)


def floor_digits(x: float, digits: int = 4) -> float:
    """``x >= 0`` rounded DOWN to ``digits`` significant digits (a proven lower bound printed without overstating
    it); ``x`` itself when it is 0 or not finite."""
    if not (math.isfinite(x) and x > 0):
        return x
    scale = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    out = math.floor(x / scale) * scale
    while out > x:  # the division or the product rounded up
        out = float(np.nextafter(out, 0.0))
    return out


@dataclass(frozen=True)
class SpecCheck:
    """Proven lower bounds of the true motion's max |qd|, max |qdd| per joint, against the stated bounds.

    qd_lower, qdd_lower : (n,) [rad/s, rad/s^2] what the positions prove (0: nothing); qd_max, qdd_max : (n,) the
    stated bounds; qd_span, qdd_span : (n,) the span [sample steps] of each best bound; qd_sample, qdd_sample :
    (n,) the first sample of that span."""

    qd_lower: np.ndarray
    qdd_lower: np.ndarray
    qd_max: np.ndarray
    qdd_max: np.ndarray
    qd_span: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    qdd_span: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    qd_sample: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    qdd_sample: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    @property
    def contradictions(self) -> list[dict]:
        """Every stated bound below its proven lower bound: ``entry``, ``joint`` (1-based), ``stated``,
        ``proven_lower``, ``unit``, ``span`` [steps] and ``sample`` where it is proven."""
        out = []
        for entry, lower, stated, unit, span, sample in (
                ("qd_max", self.qd_lower, self.qd_max, "rad/s", self.qd_span, self.qd_sample),
                ("qdd_max", self.qdd_lower, self.qdd_max, "rad/s^2", self.qdd_span, self.qdd_sample)):
            for i in np.flatnonzero(lower > stated):
                out.append({"entry": entry, "joint": int(i + 1), "stated": float(stated[i]),
                            "proven_lower": float(lower[i]), "unit": unit,
                            "span": int(span[i]) if span.size else None,
                            "sample": int(sample[i]) if sample.size else None})
        return out

    @property
    def contradicted(self) -> list[str]:
        """One sentence per contradicted entry: ``qdd_max of joint 2 = 10 rad/s^2 is contradicted by the data: the
        positions prove max |qdd| >= 431.2 rad/s^2`` (the proven value rounded down)."""
        return [f"{c['entry']} of joint {c['joint']} = {c['stated']:.6g} {c['unit']} is contradicted by the data: "
                f"the positions prove max |{c['entry'][:-4]}| >= {floor_digits(c['proven_lower']):.6g} {c['unit']}"
                + (f" (over {c['span']} sample step{'s' if c['span'] != 1 else ''} from sample {c['sample']})"
                   if c["span"] is not None else "")
                for c in self.contradictions]

    def to_dict(self) -> dict:
        return {"qd_lower": self.qd_lower.tolist(), "qdd_lower": self.qdd_lower.tolist(),
                "qd_max": self.qd_max.tolist(), "qdd_max": self.qdd_max.tolist(),
                "qd_span": self.qd_span.tolist(), "qdd_span": self.qdd_span.tolist(),
                "contradicted": self.contradicted, "contradictions": self.contradictions,
                "method": "every span of 1..max_span sample steps: secants (qd) and second differences (qdd) "
                          "minus the position error's effect, rounded down"}


def _secant_lower(q, e, m: int, T_up: float):
    """(N - m, n) lower bounds of max|qd| from the secants over m steps; T_up >= m h."""
    d = np.abs(q[m:] - q[:-m])  # |fl(qb - qa)| <= (1 + u) |qb - qa|: down() gives a lower bound
    num = down(down(d) - up(e[m:] + e[:-m]))
    return down(num / T_up)


def _second_lower(q, e, m: int, T2_up: float):
    """(N - 2m, n) lower bounds of max|qdd| from the second differences over m steps; T2_up >= (m h)^2."""
    qa, qb, qc = q[:-2 * m], q[m:-m], q[2 * m:]
    s = qa + qc
    t = s - 2.0 * qb  # two roundings, each within u of its result (2 qb is exact)
    err = up(up(2.0 * U * (np.abs(s) + np.abs(t))) * (1.0 + 4.0 * U))
    ee = up(up(e[:-2 * m] + e[2 * m:]) + 2.0 * e[m:-m])
    num = down(down(down(np.abs(t)) - err) - ee)
    return down(num / T2_up)


def _best(lower_of, n_spans: int, shape_n: int):
    best = np.zeros(shape_n)
    span = np.zeros(shape_n, dtype=int)
    sample = np.zeros(shape_n, dtype=int)
    for m in range(1, n_spans + 1):
        lo = lower_of(m)
        if lo.size == 0:
            break
        k = np.argmax(lo, axis=0)
        val = lo[k, np.arange(shape_n)]
        better = val > best
        best[better], span[better], sample[better] = val[better], m, k[better]
    return best, span, sample


def check_motion_bounds(q, spec, position_error=None, max_span: int = MAX_SPAN) -> SpecCheck:
    """The lower bounds of the TRUE max |qd| and max |qdd| per joint that the measured positions prove (module
    docstring), against ``spec.qd_max``, ``spec.qdd_max``.

    q : (N, n) measured positions [rad] (for the H4: the motor angles, on which its spec's bounds are stated);
    spec : :class:`~ident.processing.errorspec.ErrorSpec` of n joints; position_error : (N, n) bound on
    ``|q_meas - q_true|`` [rad], default ``spec.position_error(q)``; max_span : the longest span [steps].
    """
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != spec.n_joints:
        raise ValueError(f"q must have shape (N, {spec.n_joints}), got {q.shape}")
    e = spec.position_error(q) if position_error is None else np.asarray(position_error, dtype=float)
    if e.shape != q.shape or not np.all(np.isfinite(e)) or np.any(e < 0):
        raise ValueError(f"position_error must be finite, >= 0, of shape {q.shape}, got shape {e.shape}")
    if isinstance(max_span, bool) or not isinstance(max_span, (int, np.integer)) or max_span < 1:
        raise ValueError(f"max_span must be an integer >= 1, got {max_span!r}")
    h, n, N = float(spec.sample_period), q.shape[1], q.shape[0]

    def T(m):  # upper bound of m h
        return float(up(m * h))

    qd = _best(lambda m: _secant_lower(q, e, m, T(m)), min(max_span, N - 1), n)
    qdd = _best(lambda m: _second_lower(q, e, m, float(up(T(m) * T(m)))), min(max_span, (N - 1) // 2), n)
    return SpecCheck(qd_lower=qd[0], qdd_lower=qdd[0], qd_max=np.asarray(spec.qd_max, dtype=float).copy(),
                     qdd_max=np.asarray(spec.qdd_max, dtype=float).copy(), qd_span=qd[1], qdd_span=qdd[1],
                     qd_sample=qd[2], qdd_sample=qdd[2])
