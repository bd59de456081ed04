"""Design of the H4's joint controllers with python-control (the 1 kHz law itself is :mod:`sim.controller`).

The paper's data come from the robot tracking exciting trajectories under "closed-loop joint PI control"
(Poignet, Ramdani & Vivas, CDC 2003, sec. 4.1). Each axis, seen from its motor, is modelled as

    G(s) = q(s) / tau(s) = 1 / (J s^2 + Fv s)

with J the axis inertia seen by the motor [kg m^2] and Fv the viscous friction [N m s/rad]. A PI acting on the
position error alone is stable only if ``Fv Kp > J Ki`` (Routh on ``J s^3 + Fv s^2 + Kp s + Ki``), i.e. only
for a sluggish integral with the small, poorly known Fv. Structure chosen here: **position P + velocity PI
cascade**

    qd_cmd = Kp (q_ref - q) + qd_ref                 (outer loop, velocity feed-forward)
    tau    = Kv (qd_cmd - qd) + Ki integral(qd_cmd - qd) + tau_ff,   saturated at +-tau_max

rather than a PID with a filtered D, because (1) the velocity is an input anyway (the encoder difference the
caller already filters, or the simulator's), so no derivative of the noisy position error is taken inside the
law; (2) the integrator acts on the velocity error, which removes constant disturbances (gravity share,
Coulomb friction) with zero steady-state position error; (3) it is the usual drive structure, and the
integrator state can be limited (anti-windup) without upsetting the position loop. Unsaturated, it is a
PID on the error with derivative on ``qd_ref - qd``.

Design rule (one axis, per-axis J and Fv): the loop ``L = (Kv + Ki/s)(Kp + V(s)) G(s)``, with ``V(s) =
s/(tau_v s + 1)`` the velocity estimate, has two zeros, placed together at ``z = Kp = Ki/Kv`` (which puts the
position loop near a quarter of the velocity loop, the classic cascade ratio); z sets the phase at the
crossover ``w_c`` to ``-180 + PM`` plus an allowance ``w_c dt/2`` for the zero-order hold of the 1 kHz
sampling, Kv sets ``|L(j w_c)| = 1``, and ``w_c`` is adjusted so that the -3 dB bandwidth of the tracking
transfer ``T = L / (1 + L)`` equals the requested one. The discrete loop (plant with zero-order hold,
``ct.c2d(., dt, 'zoh')``; PI and velocity filter by Tustin, ``ct.c2d(., dt, 'tustin')``, exactly the
difference equations of :class:`JointController` and :class:`VelocityFilter`) is then re-checked: margins,
bandwidth, step information (``ct.step_info``) and poles (``ct.poles``) are reported for both. The margins
come from the directly evaluated frequency response (:func:`_margins`): ``ct.stability_margins`` listed
spurious crossovers for some sampled type-2 loops; the tests compare both where python-control is reliable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from h4bench.portable import atan2, exp, log
from h4bench.sim.controller import TAU_MAX_DEFAULT, JointController
from h4bench.sim.validation import N_JOINTS, axis_array, positive, real

# python-control (and the matplotlib it loads) is imported inside the functions that build or analyse transfer
# functions, so that importing sim or this module costs neither

__all__ = ["ControllerDesign", "LoopReport", "design_joint_controller"]


# ------------------------------------------------------------------------------------------- transfer fns


def _tf_parts(sys) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(sys.num[0][0], dtype=float), np.asarray(sys.den[0][0], dtype=float)


def _axis_systems(J: float, Fv: float, kp: float, kv: float, ki: float, tau_v: float | None,
                  dt: float | None) -> dict:
    """Loop, tracking and set-point transfer functions of one axis, continuous (dt None) or discrete.

    Built from polynomials (no spurious uncancelled poles): L = C_I (Kp G + G_v), where G_v is the transfer
    from torque to the velocity the law sees (V G with the filter, the exact velocity without).
    """
    import control as ct  # noqa: PLC0415
    plant = ct.tf([1.0], [J, Fv, 0.0])
    plant_v = ct.tf([1.0], [J, Fv])  # torque -> exact velocity
    pi = ct.tf([kv, ki], [1.0, 0.0])
    vfilt = None if tau_v is None else ct.tf([1.0, 0.0], [tau_v, 1.0])
    if dt is not None:
        plant = ct.c2d(plant, dt, "zoh")
        plant_v = ct.c2d(plant_v, dt, "zoh")
        pi = ct.c2d(pi, dt, "tustin")
        vfilt = None if vfilt is None else ct.c2d(vfilt, dt, "tustin")
    gn, gd = _tf_parts(plant)  # gd = (x - 1)(x - a) [discrete] or J s^2 + Fv s
    if vfilt is None:
        vn, vd = _tf_parts(plant_v)
        # G_v = vn / vd with vd a factor of gd: gd = vd * r
        r, rem = np.polydiv(gd, vd)
        if np.max(np.abs(rem)) > 1e-9 * np.max(np.abs(gd)):
            raise RuntimeError("internal: velocity plant denominator does not divide the position plant's")
        outer_num = np.polyadd(kp * gn, np.polymul(vn, r))
        outer_den = gd
    else:
        fn, fd = _tf_parts(vfilt)
        outer_num = np.polyadd(kp * np.polymul(gn, fd), np.polymul(fn, gn))
        outer_den = np.polymul(gd, fd)
    cn, cd = _tf_parts(pi)
    kw = {} if dt is None else {"dt": dt}
    loop_num = np.polymul(cn, outer_num)
    loop_den = np.polymul(cd, outer_den)
    char = np.polyadd(loop_den, loop_num)
    sp_num = kp * np.polymul(cn, gn if vfilt is None else np.polymul(gn, _tf_parts(vfilt)[1]))
    return {
        "loop": ct.tf(loop_num, loop_den, **kw),
        "tracking": ct.tf(loop_num, char, **kw),
        "setpoint": ct.tf(sp_num, char, **kw),
        "char": char,
    }


def _polyval_complex(c, xr, xi):
    """(real, imaginary) parts of the polynomial c (real coefficients, highest power first) at xr + j xi, by
    Horner's rule in real arithmetic: numpy's complex products run FMA code on some CPUs (other last bits)."""
    pr, pi = np.full_like(xr, c[0]), np.zeros_like(xr)
    for a in c[1:]:
        pr, pi = pr * xr - pi * xi + a, pr * xi + pi * xr
    return pr, pi


def _frequency_response(sys, w) -> np.ndarray:
    """Complex response of a SISO transfer function at w [rad/s] (discrete: at z = exp(j w dt)), the same bits on
    any CPU (real arithmetic, :func:`_polyval_complex`; sin and cos, whose numpy code is the same everywhere)."""
    num, den = _tf_parts(sys)
    w = np.asarray(w, dtype=float)
    if sys.dt in (0, None):
        xr, xi = np.zeros_like(w), w
    else:
        xr, xi = np.cos(w * sys.dt), np.sin(w * sys.dt)
    nr, ni = _polyval_complex(num, xr, xi)
    dr, di = _polyval_complex(den, xr, xi)
    q = dr * dr + di * di
    out = np.empty(w.shape, dtype=complex)
    out.real, out.imag = (nr * dr + ni * di) / q, (ni * dr - nr * di) / q
    return out


def _magnitude(z) -> np.ndarray:
    """|z| by hypot of the parts (numpy's complex absolute value differs in its last bits between CPUs)."""
    z = np.asarray(z)
    return np.hypot(z.real, z.imag)


def _log_grid(w_lo: float, w_hi: float, n: int) -> np.ndarray:
    """``n`` frequencies from w_lo to w_hi, equally spaced on a log scale (:func:`h4bench.portable.exp` and
    :func:`~h4bench.portable.log`: ``np.logspace``'s powers differ in their last bits between CPUs)."""
    return exp(np.linspace(float(log(w_lo)), float(log(w_hi)), n))


def _bandwidth(sys, w_max: float) -> float:
    """First angular frequency where |sys| drops below 1/sqrt(2) (DC gain 1 assumed) [rad/s]; nan if none."""
    w = _log_grid(w_max * 1e-9, w_max, 4000)
    g = _magnitude(_frequency_response(sys, w))
    below = np.flatnonzero(g < 1.0 / math.sqrt(2.0))
    if below.size == 0 or below[0] == 0:
        return float("nan")
    i = below[0]
    return brentq(lambda x: float(_magnitude(_frequency_response(sys, x))) - 1.0 / math.sqrt(2.0), w[i - 1], w[i])


def _angle(z) -> np.ndarray:
    """The argument of z [rad] (:func:`h4bench.portable.atan2`; ``np.angle`` differs between CPUs)."""
    z = np.asarray(z)
    return atan2(z.imag, z.real)


def _margins(loop, w_lo: float, w_hi: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All gain and phase crossovers of a loop on [w_lo, w_hi]: (w_gc, pm_deg, gm).

    ``ct.stability_margins`` reported spurious crossovers for the sampled type-2 loops (double pole at
    z = 1, ill-conditioned polynomial method; and 'frd' fallback with wrapped phase), so the crossings are
    bracketed on a dense logarithmic grid of the directly evaluated response and refined by ``brentq``:
    gain crossovers where ``|L| = 1`` (pm = 180 + angle L, wrapped into (-180, 180]), phase crossovers where
    L crosses the negative real axis (gm = 1/|L|).
    """
    w = _log_grid(w_lo, w_hi, 20000)
    resp = _frequency_response(loop, w)
    logmag = log(_magnitude(resp))
    wgc = [brentq(lambda x: float(log(_magnitude(_frequency_response(loop, x)))), w[k], w[k + 1], xtol=1e-12)
           for k in np.flatnonzero(np.sign(logmag[:-1]) * np.sign(logmag[1:]) < 0)]
    pm = [(math.degrees(float(_angle(_frequency_response(loop, x)))) + 360.0) % 360.0 - 180.0 for x in wgc]
    im = resp.imag
    negative = (resp.real[:-1] < 0) & (resp.real[1:] < 0)
    cross = np.flatnonzero((np.sign(im[:-1]) * np.sign(im[1:]) < 0) & negative)
    wpc = [brentq(lambda x: float(_frequency_response(loop, x).imag), w[k], w[k + 1], xtol=1e-12)
           for k in cross]
    gm = [1.0 / float(_magnitude(_frequency_response(loop, x))) for x in wpc]
    if loop.dt not in (0, None):  # at the Nyquist frequency (z = -1) a sampled loop is real
        num, den = _tf_parts(loop)
        end = np.polyval(num, -1.0) / np.polyval(den, -1.0)
        if end < 0:
            gm.append(-1.0 / end)
    return np.array(wgc), np.array(pm), np.array(gm)


# ----------------------------------------------------------------------------------------------- reports


@dataclass(frozen=True)
class LoopReport:
    """Analysis of one axis's closed loop (continuous or discrete).

    bandwidth_hz : -3 dB bandwidth of the tracking transfer ``T = L/(1+L)`` (reference with its velocity
    feed-forward) [Hz]; crossover_hz : gain crossover of L [Hz]; phase_margin_deg [deg];
    gain_margin : upper gain margin (factor by which the loop gain may grow; inf if the phase never crosses
    -180 deg above the crossover); lower_gain_margin : factor by which it may shrink (the type-2 loop is
    conditionally stable; 0 if none); rise_time, settling_time [s], overshoot_pct [%] : ``ct.step_info`` of
    the set-point step (``qd_ref = 0``); poles : closed-loop poles (s-plane [1/s] or z-plane);
    stable : all poles in the open left half plane / unit disc.
    """

    bandwidth_hz: float
    crossover_hz: float
    phase_margin_deg: float
    gain_margin: float
    lower_gain_margin: float
    rise_time: float
    settling_time: float
    overshoot_pct: float
    poles: np.ndarray
    stable: bool


def _analyse(systems: dict, dt: float | None, w_lo: float, w_max: float) -> LoopReport:
    import control as ct  # noqa: PLC0415

    wgcs, pms, gms = _margins(systems["loop"], w_lo, w_max)
    upper = [g for g in gms if g > 1.0]
    lower = [g for g in gms if g < 1.0]
    if pms.size:
        i = int(np.argmin(np.abs(pms)))  # the crossover closest to -180 deg
        pm, wgc = float(pms[i]), float(wgcs[i])
    else:
        pm, wgc = float("nan"), float("nan")
    poles = np.asarray(ct.poles(systems["tracking"]))
    stable = bool(np.all(_magnitude(poles) < 1.0)) if dt is not None else bool(np.all(poles.real < 0.0))
    rise = settle = over = float("nan")
    if stable:
        # horizon: 12 time constants of the slowest pole (ct's automatic one can be too short for it)
        decay = -poles.real if dt is None else -log(_magnitude(poles)) / dt
        t_end = 12.0 / max(float(decay.min()), 1e-9)
        if dt is None:
            timepts = np.linspace(0.0, t_end, 20001)
        else:
            timepts = np.arange(0.0, min(t_end, 2e5 * dt) + dt / 2, dt)
        try:
            info = ct.step_info(systems["setpoint"], timepts=timepts)
            rise, settle, over = float(info["RiseTime"]), float(info["SettlingTime"]), float(info["Overshoot"])
        except (IndexError, ValueError):  # response never reaches 90 % within the horizon: leave nan
            pass
    return LoopReport(
        bandwidth_hz=_bandwidth(systems["tracking"], w_max) / (2 * math.pi),
        crossover_hz=wgc / (2 * math.pi),
        phase_margin_deg=pm,
        gain_margin=float(min(upper)) if upper else float("inf"),
        lower_gain_margin=float(max(lower)) if lower else 0.0,
        rise_time=rise,
        settling_time=settle,
        overshoot_pct=over,
        poles=poles,
        stable=stable,
    )


@dataclass(frozen=True)
class ControllerDesign:
    """Gains and analysis of the four joint controllers (see the module docstring for the structure).

    J : (4,) axis inertia seen by the motor [kg m^2]; Fv : (4,) viscous friction [N m s/rad];
    kp : (4,) position gain [1/s]; kv : (4,) velocity gain [N m s/rad]; ki : (4,) velocity-integral gain
    [N m/rad]; dt : sample period [s]; velocity_filter_hz : cut-off of the velocity estimate assumed in the
    design (None: exact velocity); bandwidth_hz, phase_margin_deg : the requested values;
    continuous, discrete : per-axis :class:`LoopReport` of the continuous design and of the sampled loop.
    """

    J: np.ndarray
    Fv: np.ndarray
    kp: np.ndarray
    kv: np.ndarray
    ki: np.ndarray
    dt: float
    velocity_filter_hz: float | None
    bandwidth_hz: float
    phase_margin_deg: float
    continuous: tuple[LoopReport, ...]
    discrete: tuple[LoopReport, ...]

    @property
    def tau_v(self) -> float | None:
        """Time constant of the velocity filter [s], ``1/(2 pi velocity_filter_hz)``."""
        return None if self.velocity_filter_hz is None else 1.0 / (2 * math.pi * self.velocity_filter_hz)

    def systems(self, axis: int, discrete: bool = False) -> dict:
        """python-control models of one axis: ``loop`` L, ``tracking`` L/(1+L), ``setpoint`` (qd_ref = 0)
        transfer functions and ``char``, the closed-loop characteristic polynomial coefficients."""
        if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)) or not 0 <= axis < N_JOINTS:
            raise ValueError(f"axis must be an integer in 0..{N_JOINTS - 1}, got {axis!r}")
        return _axis_systems(self.J[axis], self.Fv[axis], self.kp[axis], self.kv[axis], self.ki[axis],
                             self.tau_v, self.dt if discrete else None)

    def controller(self, tau_max=TAU_MAX_DEFAULT, inertia_ff="design") -> JointController:
        """A :class:`JointController` with these gains; ``inertia_ff="design"`` uses J for ``qdd_ref``."""
        ff = self.J if isinstance(inertia_ff, str) and inertia_ff == "design" else inertia_ff
        return JointController(self.kp, self.kv, self.ki, dt=self.dt, tau_max=tau_max, inertia_ff=ff)

    def report(self) -> str:
        """Human-readable multi-line summary of gains, margins, bandwidths, step responses and poles."""
        vf = ("exact velocity" if self.velocity_filter_hz is None
              else f"velocity filter {self.velocity_filter_hz:g} Hz")
        lines = [
            "Joint control: position P + velocity PI cascade",
            "  tau = Kv e_v + Ki int(e_v) + ff,  e_v = Kp (q_ref - q) + qd_ref - qd",
            f"  requested: tracking bandwidth {self.bandwidth_hz:g} Hz, phase margin "
            f"{self.phase_margin_deg:g} deg (sampled loop); {1.0 / self.dt:g} Hz sample-and-hold; {vf}",
            "  bw: -3 dB of L/(1+L) (tracking with qd_ref); step: set-point step (qd_ref = 0); "
            "GM: up / down factor in dB",
        ]
        for i in range(N_JOINTS):
            lines.append(f"axis {i + 1}: J {self.J[i]:.4g} kg m^2, Fv {self.Fv[i]:.4g} N m s/rad -> "
                         f"Kp {self.kp[i]:.4g} 1/s, Kv {self.kv[i]:.4g} N m s/rad, Ki {self.ki[i]:.4g} N m/rad")
            for name, rep in (("continuous", self.continuous[i]), ("sampled   ", self.discrete[i])):
                gm = "inf" if math.isinf(rep.gain_margin) else f"{20 * math.log10(rep.gain_margin):.1f}"
                gl = "none" if rep.lower_gain_margin == 0 else f"{20 * math.log10(rep.lower_gain_margin):.1f}"
                pole = (f"max|z| {np.abs(rep.poles).max():.4f}" if name.startswith("sampled")
                        else f"max Re {rep.poles.real.max():.1f} 1/s")
                lines.append(
                    f"  {name}: bw {rep.bandwidth_hz:.2f} Hz, crossover {rep.crossover_hz:.2f} Hz, "
                    f"PM {rep.phase_margin_deg:.1f} deg, GM {gm} / {gl} dB; "
                    f"step: rise {1e3 * rep.rise_time:.1f} ms, "
                    f"overshoot {rep.overshoot_pct:.1f} %, settling {1e3 * rep.settling_time:.0f} ms; "
                    f"poles {pole}" + ("" if rep.stable else "  UNSTABLE"))
        return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ design


def _phase(w: float, z: float, J: float, Fv: float, tau_v: float | None) -> float:
    """Unwrapped phase [rad] of L(j w) / Kv for Kp = z, Ki = z Kv."""
    s = 1j * w
    v = s if tau_v is None else s / (tau_v * s + 1.0)
    c = z + v  # the arguments by h4bench.portable.atan2 (numpy's and the C library's differ between CPUs)
    return -float(atan2(z, w)) + float(atan2(c.imag, c.real)) - math.pi / 2 - float(atan2(w * J, Fv))


def _gain_per_kv(w: float, z: float, J: float, Fv: float, tau_v: float | None) -> float:
    s = 1j * w
    v = s if tau_v is None else s / (tau_v * s + 1.0)
    return abs((1.0 + z / s) * (z + v) / (s * (J * s + Fv)))


def _gains_at_crossover(wc: float, J: float, Fv: float, tau_v: float | None, pm: float,
                        dt: float) -> tuple[float, float, float]:
    """(Kp, Kv, Ki) giving phase margin pm (+ the ZOH allowance wc dt/2) at crossover wc."""
    target = -math.pi + pm + wc * dt / 2.0

    def f(log_z: float) -> float:
        return _phase(wc, float(exp(log_z)), J, Fv, tau_v) - target

    lo, hi = float(log(wc * 1e-9)), float(log(wc * 1e6))
    if f(lo) <= 0.0:
        raise ValueError(
            f"phase_margin_deg = {math.degrees(pm):g} cannot be reached at a crossover of "
            f"{wc / (2 * math.pi):.3g} Hz: the velocity filter, friction pole and sample-and-hold leave at most "
            f"{math.degrees(f(lo) + pm):.1f} deg; lower bandwidth_hz or phase_margin_deg")
    z = float(exp(brentq(f, lo, hi, xtol=1e-12)))
    kv = 1.0 / _gain_per_kv(wc, z, J, Fv, tau_v)
    return z, kv, z * kv


def design_joint_controller(J, Fv, bandwidth_hz: float = 20.0, dt: float = 1e-3, phase_margin_deg: float = 60.0,
                            velocity_filter_hz: float | None = 100.0) -> ControllerDesign:
    """Design the four position-P / velocity-PI joint controllers for ``G = 1/(J s^2 + Fv s)``.

    J : float or (4,) axis inertia seen by the motor [kg m^2] (> 0); Fv : float or (4,) viscous friction
    [N m s/rad] (>= 0); bandwidth_hz : -3 dB bandwidth of the tracking loop ``T = L/(1+L)`` [Hz], default
    20 Hz (twice the ~10 Hz useful motion of the exciting trajectories, 1/50 of the sample rate); dt : sample
    period [s]; phase_margin_deg : of the SAMPLED loop (the continuous design adds ``w_c dt/2`` for the
    zero-order hold), default 60 deg (tracking peak |T| about 1.4; the set-point step, governed by
    Kp ~ w_c/5, rises in about 0.1 s without overshoot at the defaults);
    velocity_filter_hz : cut-off of the velocity estimate the law receives (:class:`VelocityFilter`),
    None if the caller passes exact velocities.

    Returns a :class:`ControllerDesign` (immutable: frozen, read-only arrays). Designs are cached by their inputs
    (J and Fv bit for bit and the other arguments): per process (:data:`DESIGN_CACHE_SIZE` entries; the same
    inputs give the same object) and on disk (:mod:`sim.design_cache`, every float stored exactly), so a
    campaign's worker designs nothing and loads no python-control once any process has designed the same.
    Raises ValueError for bad inputs (non-positive J, negative Fv,
    bandwidth at or above the Nyquist frequency, wrong shapes), for a phase margin that cannot be reached, or
    if the sampled loop is unstable.

    Parameters
    ----------
    J : float or (4,) axis inertia seen by each motor [kg m^2], > 0
    Fv : float or (4,) viscous friction [N m s/rad], >= 0
    bandwidth_hz : tracking bandwidth [Hz], below 1 / (2 dt)
    dt : sample period [s]
    phase_margin_deg : phase margin of the sampled loop [deg], in (0, 90)
    velocity_filter_hz : cut-off of the velocity estimate [Hz], or None (exact velocity)

    Returns
    -------
    ControllerDesign
        Gains (4,) and the continuous and sampled loop analyses.
    """
    J = axis_array(J, "J", allow_zero=False)
    Fv = axis_array(Fv, "Fv", allow_zero=True)
    dt = positive(dt, "dt")
    nyquist = 0.5 / dt
    bandwidth_hz = positive(bandwidth_hz, "bandwidth_hz")
    if bandwidth_hz >= nyquist:
        raise ValueError(f"bandwidth_hz must be below the Nyquist frequency 1/(2 dt) = {nyquist:g} Hz, "
                         f"got {bandwidth_hz:g}")
    pm_deg = real(phase_margin_deg, "phase_margin_deg")
    if not 0.0 < pm_deg < 90.0:
        raise ValueError(f"phase_margin_deg must be in (0, 90), got {pm_deg:g}")
    if velocity_filter_hz is not None:
        velocity_filter_hz = positive(velocity_filter_hz, "velocity_filter_hz")
        if velocity_filter_hz >= nyquist:
            raise ValueError(f"velocity_filter_hz must be below the Nyquist frequency {nyquist:g} Hz, "
                             f"got {velocity_filter_hz:g}")
    key = (J.tobytes(), Fv.tobytes(), bandwidth_hz, dt, pm_deg, velocity_filter_hz)
    design = _DESIGNS.get(key)
    if design is None:
        from h4bench.sim.design_cache import design_key, load_design, store_design

        disk_key = design_key(J, Fv, bandwidth_hz, dt, pm_deg, velocity_filter_hz)
        design = load_design(disk_key, J, Fv, bandwidth_hz, dt, pm_deg, velocity_filter_hz, ControllerDesign,
                             LoopReport)
        if design is None:
            design = _design(J, Fv, bandwidth_hz, dt, pm_deg, velocity_filter_hz)
            store_design(disk_key, design)
        if len(_DESIGNS) >= DESIGN_CACHE_SIZE:
            _DESIGNS.pop(next(iter(_DESIGNS)))
        _DESIGNS[key] = design
    return design


#: Designs kept per process by :func:`design_joint_controller`, keyed by its inputs (oldest dropped first).
DESIGN_CACHE_SIZE = 64
_DESIGNS: dict = {}


def _design(J: np.ndarray, Fv: np.ndarray, bandwidth_hz: float, dt: float, pm_deg: float,
            velocity_filter_hz: float | None) -> ControllerDesign:
    """:func:`design_joint_controller` on validated arguments (J, Fv (4,) arrays; the rest checked floats)."""
    nyquist = 0.5 / dt
    tau_v = None if velocity_filter_hz is None else 1.0 / (2 * math.pi * velocity_filter_hz)
    pm = math.radians(pm_deg)
    w_bw = 2 * math.pi * bandwidth_hz
    w_max = 2 * math.pi * nyquist * (1.0 - 1e-9)

    kp, kv, ki = np.empty(N_JOINTS), np.empty(N_JOINTS), np.empty(N_JOINTS)
    cont, disc = [], []
    for i in range(N_JOINTS):  # 4 axes, not samples

        def bw_error(log_wc: float, i: int = i) -> float:
            gains = _gains_at_crossover(float(exp(log_wc)), J[i], Fv[i], tau_v, pm, dt)
            sysc = _axis_systems(J[i], Fv[i], *gains, tau_v, None)
            return float(log(_bandwidth(sysc["tracking"], 1e3 * w_max) / w_bw))

        # bandwidth / crossover is about 1.3-1.7 for these loops: bracket generously
        lo, hi = float(log(w_bw / 4.0)), float(log(w_bw * 1.2))
        try:
            log_wc = brentq(bw_error, lo, hi, xtol=1e-10)
        except ValueError as exc:
            raise ValueError(f"axis {i + 1}: cannot reach bandwidth_hz = {bandwidth_hz:g} with "
                             f"phase_margin_deg = {pm_deg:g} ({exc})") from exc
        kp[i], kv[i], ki[i] = _gains_at_crossover(float(exp(log_wc)), J[i], Fv[i], tau_v, pm, dt)
        w_lo = 1e-3 * min(kp[i], w_bw)  # three decades below the controller zeros
        cont.append(_analyse(_axis_systems(J[i], Fv[i], kp[i], kv[i], ki[i], tau_v, None), None, w_lo,
                             1e3 * w_max))
        rep = _analyse(_axis_systems(J[i], Fv[i], kp[i], kv[i], ki[i], tau_v, dt), dt, w_lo, w_max)
        if not rep.stable:
            raise ValueError(f"axis {i + 1}: the sampled loop is unstable at dt = {dt:g} s "
                             f"(max |pole| {np.abs(rep.poles).max():.4f}); lower bandwidth_hz")
        disc.append(rep)
    for arr in (J, Fv, kp, kv, ki):
        arr.setflags(write=False)
    return ControllerDesign(J=J, Fv=Fv, kp=kp, kv=kv, ki=ki, dt=dt, velocity_filter_hz=velocity_filter_hz,
                            bandwidth_hz=bandwidth_hz, phase_margin_deg=pm_deg, continuous=tuple(cont),
                            discrete=tuple(disc))
