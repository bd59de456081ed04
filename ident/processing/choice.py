"""The certified equation's processing chosen from the specification: the kernel length that minimises the rows'
relative radius.

Every radius of a certified row is a known function of the processing: the encoder terms fall with the kernel's
length (the slope's total variation scales as ``1 / T^2``, the summed-by-parts speed terms as ``1 / T``), the
motion terms (within-step variation, speed estimates, second-order remainders) stay about constant, the Coulomb
sign term grows with the share of windows that hold a reversal, and the torque term is the stated bound times
``integral |k| = 1``. A longer kernel also averages the motion out of the rows (their signal ``|Wc| theta``
falls once the kernel is as long as the motion's fastest components). The rule weighs the two by evaluating the
robot's own certified equation, for each candidate length, on the same evenly spread sample of windows, and
scoring it by the median over those rows of the **relative row radius**

    rho(L) = (bound + D |theta|) / (|Wc| |theta|),     |theta| = the prior's largest magnitudes,

the size of the row's uncertainty against its signal at the worst parameters the prior allows (a row whose
radius is a small fraction of its signal narrows the set; the Oettli-Prager set's width grows with it). The
chosen length is the candidate of least score (the shorter one on a tie). It reads only the specification, the
measured positions (through the equation's regressor side and radii) and the prior: never the torques, never a
truth. Explicit settings (a spec file's ``[certified]`` table) win over the rule.

Too-short kernels are refused by :func:`minimum_kernel_steps`: a kernel shorter than the stated minimum
(``MIN_KERNEL_SECONDS``, and never fewer than ``MIN_KERNEL_STEPS`` steps) leaves the encoder terms at their
largest, and a log must give more rows than parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["KernelChoice", "MIN_KERNEL_STEPS", "candidate_lengths", "choose_kernel", "minimum_kernel_steps",
           "relative_radius", "sample_starts"]

MIN_KERNEL_STEPS = 10  # a kernel of fewer sample steps is refused (its slope's variation is ~ 16 / (L h)^2)
SAMPLE_WINDOWS = 24  # windows per candidate in the score's sample


@dataclass(frozen=True)
class KernelChoice:
    """steps : the chosen kernel length [sample steps]; scores : {steps: median relative row radius};
    rule : a one-line statement of the rule, for result.json; sampled_windows : windows per candidate."""

    steps: int
    scores: dict = field(default_factory=dict)
    rule: str = ""
    sampled_windows: int = 0

    def to_dict(self) -> dict:
        return {"steps": int(self.steps), "scores": {str(k): float(v) for k, v in self.scores.items()},
                "rule": self.rule, "sampled_windows": int(self.sampled_windows)}


def candidate_lengths(n_samples: int, dt: float, *, shortest_s: float = 0.04, longest_s: float = 0.8,
                      even: bool = True) -> list[int]:
    """Kernel lengths [steps] on a geometric grid (factor ~1.6) from ``shortest_s`` to ``longest_s`` [s], each at
    most a tenth of the log (so that the rows are many and spread) and at least :data:`MIN_KERNEL_STEPS`; even
    when ``even`` (a triangle's apex on a sample)."""
    hi = max(MIN_KERNEL_STEPS, min(int(round(longest_s / dt)), (n_samples - 1) // 10))
    lo = max(MIN_KERNEL_STEPS, min(int(round(shortest_s / dt)), hi))
    out, L = [], float(lo)
    while L <= hi * (1 + 1e-9):
        k = int(round(L))
        k += (k % 2) if even else 0
        if not out or k > out[-1]:
            out.append(k)
        L *= 1.6
    return out


def sample_starts(n_samples: int, steps: int, count: int = SAMPLE_WINDOWS, margin: int = 0) -> np.ndarray:
    """``count`` window starts spread evenly over the log for a kernel of ``steps`` steps (``margin`` samples kept
    free at both ends, e.g. a speed secant's half-span)."""
    last = n_samples - 1 - steps - margin
    if last < margin:
        return np.zeros(0, dtype=np.int64)
    return np.unique(np.linspace(margin, last, count).round().astype(np.int64))


def relative_radius(Wc, D, bound, theta_abs) -> np.ndarray:
    """(m,) the relative row radius ``(bound + D |theta|) / (|Wc| |theta|)`` (inf where a row has no signal)."""
    t = np.abs(np.asarray(theta_abs, dtype=float))
    signal = np.abs(np.asarray(Wc, dtype=float)) @ t
    radius = np.asarray(bound, dtype=float) + np.asarray(D, dtype=float) @ t
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(signal > 0, radius / signal, np.inf)


def choose_kernel(evaluate, candidates, theta_abs, progress=None) -> KernelChoice:
    """The candidate kernel length of least median relative row radius (module docstring).

    evaluate : ``f(steps) -> (Wc, D, bound)`` the certified equation's rows for a kernel of ``steps`` steps on the
    rule's window sample (the caller keeps the sample the same for every candidate); candidates : lengths
    [steps]; theta_abs : (p,) the prior's largest magnitudes; progress : callable(done, total) or None.
    """
    candidates = [int(c) for c in candidates]
    if not candidates:
        raise ValueError("candidates must hold at least one kernel length, got none")
    scores = {}
    for i, L in enumerate(candidates):
        Wc, D, bound = evaluate(L)
        rho = relative_radius(Wc, D, bound, theta_abs)
        scores[L] = float(np.median(rho)) if rho.size else math.inf
        if progress is not None:
            progress(i + 1, len(candidates))
    best = min(candidates, key=lambda L: (scores[L], L))
    rule = ("kernel length of least median relative row radius (bound + D|theta|) / (|Wc||theta|) at the prior's "
            "largest |theta|, over the candidates, on the same sample of windows")
    return KernelChoice(steps=best, scores=scores, rule=rule, sampled_windows=SAMPLE_WINDOWS)


def minimum_kernel_steps(dt: float, min_seconds: float = 0.0) -> int:
    """The shortest kernel accepted [steps]: :data:`MIN_KERNEL_STEPS`, or ``min_seconds`` of samples if longer."""
    return max(MIN_KERNEL_STEPS, int(math.ceil(min_seconds / dt - 1e-9)))
