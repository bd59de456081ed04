"""The certified equation's processing from the specification: every kernel of a family at once, no single pick.

Every radius of a certified row is a known function of the kernel: the encoder terms fall with its length ``T``
(the slope's total variation scales as ``1 / T^2``, the summed-by-parts speed terms as ``1 / T``), the motion
terms (within-step variation, speed estimates, second-order remainders) stay about constant, the Coulomb sign
term follows the share of windows that hold a reversal, and the torque term is the stated bound times
``integral |k| = 1``. Which length gives the narrowest box depends on more than the radii, though: a longer
kernel averages the motion out of the rows (the columns' contrasts, e.g. Coulomb against viscous friction, fade)
and its neighbouring rows say nearly the same thing. Scores built on the radii alone (the median relative row
radius, or a least-squares covariance of the rows scaled by their radii) do not rank the lengths as their boxes
do (``benchmarks/certified_kernels.py`` prints each length's box beside the family's).

No pick is needed. For the same log and specification, **every** kernel gives a true interval equation (each
radius is derived from the specification for that kernel), so the true parameters satisfy all of them at once:
the rows of a whole family of kernels stacked are one interval equation whose Oettli-Prager set is the
intersection of the single kernels' sets, and its hull is at most as wide as the best single kernel's, whichever
that is. The family (:func:`kernel_family`) is a geometric grid of lengths (factor ~1.6) from ``SHORTEST_S`` to
``LONGEST_S`` (at most a tenth of the log), each with a row stride that grows with its length (a kernel's
neighbouring rows overlap by ``1 - stride / L``: ``stride = max(stride, L // STRIDE_DIVISOR)`` keeps the long
kernels' rows few). It reads only the log's length, its sample period and the stated stride: never the torques,
never a truth. Explicit settings (a spec file's ``[certified]`` ``kernel_steps``) give one kernel instead.

Too-short kernels are refused: under :data:`MIN_KERNEL_STEPS` steps the encoder terms (``~ e / T^2``) leave
the rows uninformative.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = ["KernelFamily", "LONGEST_S", "MIN_KERNEL_STEPS", "SHORTEST_S", "STRIDE_DIVISOR", "check_kernel_steps",
           "kernel_family", "stack_equations", "stack_family"]

# The shortest kernel [sample steps]. The encoder error enters every acceleration column through the kernel's slope
# (summation by parts): about 8 pi e / (L h)^2 per unit parameter for a Hann kernel of L steps, and the nacelle
# columns' through their gradients likewise. Measured with `identify --spec` on the first 1.5 s of the `certified
# --quick` log (seed 0, 20 000 counts, prior [0, 2]): kernels of 7, 14, 20 and 30 steps left all 14 of the H4's
# parameters at the prior, 50 steps 12, 100 steps 10; on the whole 4 s log 40 steps gives a box 1.09x the tuned
# hull's (benchmarks/certified_kernels.py). Shorter kernels are refused.
MIN_KERNEL_STEPS = 40
SHORTEST_S = 0.04  # [s] the family's shortest kernel
LONGEST_S = 0.8  # [s] the family's longest kernel (and at most a tenth of the log)
FACTOR = 1.6  # ratio of consecutive lengths
STRIDE_DIVISOR = 16  # a kernel of L steps takes rows every max(stride, L // STRIDE_DIVISOR) samples


@dataclass(frozen=True)
class KernelFamily:
    """steps : kernel lengths [sample steps], increasing; strides : the row stride of each [samples]; seconds :
    the grid's (shortest, longest) length [s]; factor : its ratio."""

    steps: tuple[int, ...]
    strides: tuple[int, ...]
    seconds: tuple[float, float] = (SHORTEST_S, LONGEST_S)
    factor: float = FACTOR
    stride_rule: str = f"max(stride, L // {STRIDE_DIVISOR})"

    def to_dict(self) -> dict:
        return {"steps": list(self.steps), "strides": list(self.strides),
                "rule": f"every kernel of a geometric grid (factor {self.factor:g}) from {self.seconds[0]:g} s to "
                        f"{self.seconds[1]:g} s (at most a tenth of the log), rows stacked; stride "
                        f"{self.stride_rule}"}


def check_kernel_steps(steps, name: str = "kernel_steps") -> int:
    """``steps`` as an int, or a ValueError naming ``name`` when it is not an integer >= :data:`MIN_KERNEL_STEPS`."""
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)):
        raise ValueError(f"{name} must be an integer number of sample steps, got {steps!r}")
    if steps < MIN_KERNEL_STEPS:
        raise ValueError(f"{name} must be >= {MIN_KERNEL_STEPS} sample steps, got {steps}: the encoder error enters "
                         f"the acceleration columns through the kernel's slope, about 8 pi e / ({name} h)^2 per unit "
                         f"parameter, and kernels shorter than {MIN_KERNEL_STEPS} steps leave every parameter at its "
                         "prior")
    return int(steps)


def kernel_family(n_samples: int, dt: float, stride: int = 1, *, even: bool = False, shortest_s: float = SHORTEST_S,
                  longest_s: float = LONGEST_S, factor: float = FACTOR) -> KernelFamily:
    """The kernel family of a log of ``n_samples`` samples every ``dt`` [s] (module docstring): lengths from
    ``shortest_s`` to ``longest_s`` [s] (at most a tenth of the log, at least :data:`MIN_KERNEL_STEPS` steps) on a
    geometric grid of ratio ``factor``; ``even``: even lengths only (a triangle's apex on a sample); ``stride`` :
    the stated row stride [samples] of the shortest; a kernel of L steps takes rows every ``max(stride, L //
    STRIDE_DIVISOR)`` samples."""
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise ValueError(f"stride must be an integer >= 1, got {stride!r}")
    if not (0 < shortest_s <= longest_s and factor > 1):
        raise ValueError(f"need 0 < shortest_s <= longest_s and factor > 1, got {shortest_s!r}, {longest_s!r}, "
                         f"{factor!r}")
    hi = max(MIN_KERNEL_STEPS, min(int(round(longest_s / dt)), (n_samples - 1) // 10))
    lo = max(MIN_KERNEL_STEPS, min(int(round(shortest_s / dt)), hi))
    steps: list[int] = []
    L = float(lo)
    while L <= hi * (1 + 1e-9):
        k = int(round(L))
        k += (k % 2) if even else 0
        if not steps or k > steps[-1]:
            steps.append(k)
        L *= factor
    return KernelFamily(steps=tuple(steps), strides=tuple(max(stride, k // STRIDE_DIVISOR) for k in steps),
                        seconds=(float(shortest_s), float(longest_s)), factor=float(factor))


def stack_equations(eqs: list, info: dict):
    """One interval equation of the rows of several of the same dataclass (each true on its own, so all are at
    once): every array field and every array in a dict field (``terms``, ``parts``) stacked along the rows, the
    other fields from the first, ``info`` replaced by ``info``."""
    first = eqs[0]
    out = {}
    for f in dataclasses.fields(first):
        v = getattr(first, f.name)
        if f.name == "info":
            out[f.name] = info
        elif isinstance(v, np.ndarray):
            out[f.name] = np.concatenate([getattr(e, f.name) for e in eqs], axis=0)
        elif isinstance(v, dict) and all(isinstance(x, np.ndarray) for x in v.values()):
            out[f.name] = {k: np.concatenate([getattr(e, f.name)[k] for e in eqs], axis=0) for k in v}
        else:
            out[f.name] = v
    return type(first)(**out)


def stack_family(eqs: list, family: KernelFamily, **info):
    """The equations of a family's kernels (one each, in the family's order) as one (:func:`stack_equations`):
    ``info`` from the first equation's with ``rows`` and ``windows`` summed, ``kernels`` the family's
    (:meth:`KernelFamily.to_dict`) and the given entries (what no longer holds for the whole, e.g. one kernel's
    length, set to None). One kernel: that equation, with ``kernels`` added. Both robot kinds' paths use it."""
    if len(eqs) == 1:
        eqs[0].info["kernels"] = family.to_dict()
        return eqs[0]
    merged = dict(eqs[0].info, rows=sum(e.info["rows"] for e in eqs), windows=sum(e.info["windows"] for e in eqs),
                  kernels=family.to_dict(), **info)
    return stack_equations(eqs, merged)
