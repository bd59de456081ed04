"""Bounded torque-error models: the error between the torque a drive applies and the torque the robot logs.

The simulator commands ``tau_cmd`` (4,) at each sample k, the motors apply ``tau_cmd + e_k`` and the robot logs
``tau_log`` (the current reference, possibly quantised). The identification assumes ``|applied - logged| <= b``
row by row (Poignet, Ramdani & Vivas, CDC 2003, eq. 21). :class:`TorqueError` builds ``e`` as a sum of
components, each with its own rigorous bound, and states ``b`` = the sum of the bounds:

=====================  ===========================================================  ==========================
component              error at sample k, joint i [N m]                              bound [N m]
=====================  ===========================================================  ==========================
:class:`Uniform`       i.i.d. uniform in [-b, b] (white)                             b
:class:`Square`        b sign(sin(2 pi f t + phi_i)) (the worst case for a filter)   b
:class:`Sine`          b sin(2 pi f t + phi_i)                                       b
:class:`Samples`       given values (n, 4)                                           given (checked)
:class:`Drift`         slow signal: band-limited (< cutoff_hz) random, scaled to     b
                       peak b per joint; or a thermal exponential
:class:`Ripple`        sum_h a_h sin(n_h q_i + phi_hi) (cogging / torque ripple of   sum_h a_h
                       the motor angle q, per-joint random phases)
:class:`GainError`     g_i tau_cmd_i (torque-constant error), |g_i| <= g              g torque_limit
:class:`LogQuantisation`  logged = round(tau_cmd / lsb) lsb (not in e: in the log)  lsb / 2
=====================  ===========================================================  ==========================

Rigour. Precomputed components are clipped to their bounds; ``a sin(.)`` and ``g_i tau`` never exceed ``a`` and
``g torque_limit`` after rounding (rounding is monotone); the stream adds the errors in the order in which
:attr:`TorqueError.bound` adds the bounds, so ``|at(...)| <= bound`` holds for the computed floats, and the last
addition (the half-LSB) is rounded up: the bound holds for the exact ``|tau_cmd + e - logged|``. The simulator's
own rounding of ``tau_cmd + e`` (an ulp of 15 N m, 1.8e-15 N m) is left to the scenario's allowance; clipping
the applied torque at the actuator range (which holds ``tau_cmd``) never moves it away from ``tau_cmd``.

Spec table (:meth:`TorqueError.from_spec`; a TOML table maps to the same dict). Every key is optional; a number
is shorthand for the table with that amplitude and default settings::

    uniform = 0.2                                    # N m
    square = {amplitude = 0.3, frequency_hz = 5.0}   # or a number (5 Hz)
    sine = {amplitude = 0.3, frequency_hz = 5.0}     # or a number (5 Hz)
    drift = {amplitude = 0.25, kind = "band", cutoff_hz = 0.2}   # or kind = "thermal", time_constant = 30.0
    ripple = {orders = [1, 11, 66], amplitudes = [0.125, 0.0625, 0.0625]}  # or amplitude = total, split equally
    gain = {max = 0.02, mode = "worst"}             # or a number (worst case); mode "random": g_i ~ U[-g, g]
    quantisation_lsb = 0.0078125                     # N m
    torque_limit = 15.0                              # N m (gain bound and quantiser range)

Components are realised in the fixed order uniform, square, sine, drift, ripple, gain whatever the order of the
keys, so a seed reproduces a realisation. :func:`realistic_drive` is a documented mix with total bound 1.0 N m;
the table ``{preset = "realistic_drive", bound = 1.0}`` (optionally with torque_limit, quantisation_lsb) builds it.

Modules: :mod:`sim.noise.components` (the components and their bounds), :mod:`sim.noise.stream` (the stream
protocol, :class:`ErrorStream`), :mod:`sim.noise.model` (the sum :class:`TorqueError`, the spec table,
:func:`realistic_drive`), :mod:`sim.noise.shapes` (:class:`TorqueNoise`, the one-shape noise of a scenario's
``noise.shape``, realised by the components). Every public name is importable from here.
"""

from h4bench.sim.noise.components import (
    DRIFT_KINDS,
    GAIN_MODES,
    TORQUE_LIMIT,
    Drift,
    GainError,
    LogQuantisation,
    NoiseModelError,
    Ripple,
    Samples,
    Sine,
    Square,
    Uniform,
)
from h4bench.sim.noise.model import LOG_LSB, REALISTIC_DRIVE_SHARES, RIPPLE_ORDERS, RIPPLE_WEIGHTS, TorqueError, realistic_drive
from h4bench.sim.noise.shapes import NOISE_SHAPES, PrecomputedTorqueError, TorqueNoise
from h4bench.sim.noise.stream import ErrorStream

__all__ = [
    "DRIFT_KINDS",
    "GAIN_MODES",
    "LOG_LSB",
    "NOISE_SHAPES",
    "REALISTIC_DRIVE_SHARES",
    "RIPPLE_ORDERS",
    "RIPPLE_WEIGHTS",
    "TORQUE_LIMIT",
    "Drift",
    "ErrorStream",
    "GainError",
    "LogQuantisation",
    "NoiseModelError",
    "PrecomputedTorqueError",
    "Ripple",
    "Samples",
    "Sine",
    "Square",
    "TorqueError",
    "TorqueNoise",
    "Uniform",
    "realistic_drive",
]
