"""The H4's processed equation: the generic chain of :mod:`ident.processing.processing` bound to the H4 regressor.

:func:`build_equation` and :func:`raw_equation` take the H4's geometry and regressor structure (``"paper"`` or
``"extended"``) and pass :func:`ident.robots.h4.regressor` with its column names to the generic chain, which
imports no robot.
"""

from __future__ import annotations

from h4bench.ident.processing import processing
from h4bench.ident.processing.filtering import ProcessingSettings
from h4bench.ident.processing.processing import BLOCK_SAMPLES, Equation
from h4bench.ident.robots.h4 import parameter_names, regressor

__all__ = ["BLOCK_SAMPLES", "Equation", "build_equation", "raw_equation"]


def _regressor(geometry, structure: str):
    """``(q, qd, qdd) -> W (4n, p)``: the H4 regressor of ``geometry`` and ``structure`` (looked up at call time)."""
    return lambda q, qd, qdd: regressor(geometry, q, qd, qdd, structure=structure)


def raw_equation(geometry, q, tau, dt: float, settings: ProcessingSettings | None = None, structure: str = "paper"):
    """Steps 1-3 of the chain on an H4 log (:func:`ident.processing.processing.raw_equation`).

    geometry : the H4's :class:`sim.Geometry`; q (n, 4) [rad], tau (n, 4) [N m], dt [s]; structure : the
    regressor's columns (:func:`ident.robots.h4.parameter_names`). Returns (W (4n', p), y (4n',), keep (4n',)
    bool speed mask, samples (n',) original sample indices, (q, qd, qdd) estimated at those samples).
    """
    return processing.raw_equation(_regressor(geometry, structure), q, tau, dt, settings)


def build_equation(geometry, dataset, bound, settings: ProcessingSettings | None = None, prior=None,
                   structure: str = "paper", block_samples: int = BLOCK_SAMPLES, raw=None) -> Equation:
    """The processed equation of an H4 :class:`sim.Dataset` (:func:`ident.processing.processing.build_equation`).

    geometry : the H4's :class:`sim.Geometry`; structure : the regressor's columns (``"paper"``: 14,
    ``"extended"``); bound, settings, prior, block_samples, raw : as for the generic chain (bound [N m] per raw
    row, scalar, (4,) or (4n,); prior a Box or (lower, upper) of p entries; raw a :func:`raw_equation` result).
    """
    return processing.build_equation(_regressor(geometry, structure), parameter_names(structure), dataset, bound,
                                     settings, prior=prior, block_samples=block_samples, raw=raw)
