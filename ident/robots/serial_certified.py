"""The derived interval equation of a serial robot: weak-form rows whose radii follow from an :class:`ErrorSpec`.

**The equation.** A row r applies a kernel ``k_r(t)`` (a triangle over ``2 H`` sample steps, piecewise linear
between the sample instants, zero at both window ends, ``int k = 1`` so rows are in N m) to both sides of
``tau = Y(q, qd, qdd) theta + e``:  ``int k tau dt = (int k Y dt) theta + int k e dt``. The torque side is a
weighted sum of the logged torques; the regressor side ``[Wc - D, Wc + D]`` encloses the TRUE row ``int k Y dt``
(of the true, unknown motion), so the true parameters satisfy ``|y - W theta| <= bound`` for some W in it.

**The regressor side** (``q_j`` the true positions at the sample instants, ``M(q)`` the mass matrix, ``h(q, v)`` the
Coriolis/centrifugal and ``g(q)`` the gravity torques, all per unit standard parameter; ``Y = M qdd + h + g``), in
Lagrangian form: ``M qdd + h = d/dt (M qd) - dT/dq`` with ``T = qd^T M qd / 2``, so by parts (``k = 0`` at both
window ends) ``int k Y dt = -int k' M(q) qd dt + int k f2(q, qd) dt`` with ``f2 = g - dT/dq = g + h - Mdot qd``. No
acceleration and no speed at a sample instant is needed:

* ``-int k' M(q) qd``: ``k'`` is constant on each step, so it is ``-k'_j int_step M(q) qd``, whose centre is ``M_j
  dq_j`` (``M_j = M(qbar_j)``, the measured mid-step position, ``dq_j`` the measured step): the position errors
  enter through the exact gradient of ``sum_j k'_j M_j dq_j``; ``M_j`` against the true mid-chord's through the
  local ``dM`` (``mass_position``); the path's deviation from its mid value, ``int (M(q(t)) - M(qh*)) qd``,
  to first order against the chord's antisymmetry (``int (t - t_mid) dt = 0`` on the step: what is left is
  ``qdd_max dt^3`` small) and to second order with the local Hessian of M (``mass_motion``, times ``|k'|``);
* ``int k f2``: ``int_step |k|`` times the integrand at the mid-step position and a speed estimate; ``f2`` is
  quadratic in v with the matrix ``Gamma - Gc`` (``Gc`` the symmetric part of ``dM``: ``Mdot v = sum_ab dM_b/dq_a
  v_a v_b``); the speed's first-order term is integrated exactly against the kernel (linear on the step): the
  step's measured mean speed enters the centre, its position error the exact gradient, and only ``qdd_max dt^3 /
  12`` times ``|k'|`` the radius (:func:`ident.robots.serial_steps.speed_linear`); the q-variation of ``g + h``
  with its local derivatives, that of ``Mdot v`` with the local Hessian of M against the chord's antisymmetry
  (:func:`ident.robots.serial_steps.c2_terms`);
* the derivatives of M: ``dM`` by a second-order one-sided difference (error ``ETA^2 / 3 * 8 M`` + the regressor's
  stated error over ``ETA``), its second derivatives by mixed differences over the rectangles ``[qh, qh + ETA (e_a
  + e_k)]``, carried to the step's box with Bernstein's ``|d3 M| <= 8 M`` (:func:`ident.robots.serial_steps.
  mass_derivatives`);
* friction, rotor inertia, offsets: ``int k qdd = -sum k'_j dq_j`` (exact), ``int k qd = -int k' q``
  (trapezoid, error ``qdd_max dt^3 / 12`` per step), ``int k = 1``; Coulomb ``sign(qd)`` per step: certain when
  the step's speed bound excludes 0, else ``[-1, 1] int_step |k|``.

(At 65d4861 and before, ``int k M(q) qdd`` froze M at each step's mid position and summed ``int_step k qdd`` by
parts: M's variation within each step against ``qdd_max`` and the differences of M between steps against the
speed secants at the sample instants, both of order ``|dM| |qd| qdd_max dt``, which dominated the radii of fast
logs with a large stated ``qdd_max``: docs/serial.md has the TX40's log before and after.)

The computed row uses the measured positions; the speed estimate of each step is the secant over the ``2 m - 1``
steps centred on it (``m`` chosen from the spec to balance ``qdd_max m dt`` against ``e / (m dt)``). **Radii** (each term in :attr:`terms`):

``position``  the encoder/format error e (``ErrorSpec.position_error``) through the exact gradient of the row's
              discrete functional (summation by parts: ``sum_j e_j |G_j|``, ``G_j`` from ``k'_{j-1} - k'_j``;
              no jerk bound), its effect on M and h through the Lipschitz bounds below;
``motion``    within-step variation of the configuration (the step's chord, ``|s*| dt / 4`` on the kernel-weighted
              mean, ``|s*| dt / 2`` at most, ``s*`` the true step speed, enclosed from the measured step, plus the
              chord's remainder ``qdd_max dt^2 / 12`` and ``/ 8``: :func:`ident.robots.serial_steps.
              step_displacements`), of the speed (``qdd_max``: the speed's deviation from the secant over ``S =
              (2 m - 1) dt`` is at most ``qdd_max (dt^2 + S^2) / (4 S)`` in the step, and its quadratic term in
              the Coriolis part takes the smaller of that bound squared and a mean-square bound, the variance
              ``qdd_max^2 dt^2 / 12`` for m = 1, through Cauchy-Schwarz: :func:`ident.robots.serial_steps.
              quadratic_speed_weights`), the trapezoid, all from the stated ``qd_max``, ``qdd_max``;
``coulomb``   sign uncertainty of steps whose speed bound includes 0;
``torque``    ``torque_error int|k|`` (+ ``torque_rate dt / 2`` for sample-instant torques, + ``torque_rate
              latency``), ``model``: ``model_error``; ``rounding``: floating-point allowance.

**Rigour of the configuration-dependent bounds** (proven, from the URDF geometry): for a chain of revolute
joints every entry of ``M(q)`` per unit standard parameter of link i is ``J_a^T I_c J_b`` (body Jacobian columns,
``|J_a| <= sqrt(1 + R^2)`` with R the sum of the joint-placement offsets: the distance of any link origin from
any joint axis before it; the unit-parameter spatial inertia ``I_c`` has 2-norm 1), so ``|M| <= 1 + R^2``; it is
a trigonometric polynomial of degree <= 2 in each joint angle (each angle enters one rotation of each Jacobian
column), so Bernstein's inequality gives ``|dM/dq_k| <= 2 (1 + R^2)``. The Christoffel symbols are sums of three
halves of such derivatives: ``|Gamma| <= 3 (1 + R^2)``, hence ``|h| <= 3 (1 + R^2) (sum|v|)^2``, ``|dh/dv_a|
<= 6 (1 + R^2) sum|v|`` and (Bernstein again) ``|dh/dq_k| <= 6 (1 + R^2) (sum|v|)^2``; gravity
``|g| <= |g0| sqrt(1 + R^2)``, ``|dg/dq_k| <= 2 |g0| sqrt(1 + R^2)``. These are global (any configuration), hence
loose, but they only multiply ``dt``, e and the speed-estimate error. The one that multiplied only a step's squared
displacement, the q-q second-order remainder of ``h + g`` (``4 (gamma (sum|v|)^2 + g)`` per entry, far above the
local second derivatives), is bounded locally instead: the step's forward-difference
Hessian, the global bounds left only on the third order and on the speed's deviation
(:func:`ident.robots.serial_steps.q_remainder`). Taylor's remainders carry their factor 1/2. Columns of link i
vanish on the rows of joints after i (structural zeros keep radius 0). **Stated, not proven**: pinocchio's
floating-point error (taken below ``1e-12`` of the magnitudes summed, in ``float``), and the spec's own
assumptions (the motion bounds, the torque error, the inter-sample torque for sample timing without a
``torque_rate``: within ``torque_error`` of the interpolation of the samples).

**Evaluation** (:mod:`ident.robots.serial_steps`): pinocchio at each step's own arguments, each step once; the
regressor at a window's scaled speed and acceleration rebuilt from them (``Y`` is affine in the acceleration and
quadratic in the speed), whose rounding bound is added to ``float``; window sums for all windows at once. The
previous per-window evaluation stays as the reference (``reference=True``, :mod:`ident.robots.serial_reference`).

Base parameters: the rows of the standard regressor satisfy the structural dependences exactly (every
evaluation is one of the regressor's), so the base columns are the independent standard ones and their radii
are the standard columns' radii.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from h4bench.ident.numerics.interval import up
from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.processing.motion_check import SpecCheck, check_motion_bounds
from h4bench.ident.processing.weakform import (
    RowWindows,
    coulomb_columns,
    imot_columns,
    make_kernel,
    row_check,
    torque_rows,
    torque_side_terms,
    viscous_columns,
)
from h4bench.ident.processing.choice import kernel_family, stack_family
from h4bench.ident.robots.serial import norm3
from h4bench.ident.robots.serial_steps import PARTS, inertial_family
from h4bench.ident.robots.serial_steps import PIN_REL as _PIN_REL

__all__ = ["SERIAL_FAMILY", "SERIAL_OVERLAP", "SERIAL_WINDOWS", "serial_strides", "CertifiedEquation", "SpecCheck",
           "certificate", "certified_equation", "certified_family",
           "check_motion_bounds", "geometry_bounds", "secant_span"]

RADII_GROW = 1.0 + 2.0**-40  # outward margin on the inertial radii's float sums (>= (1 + u)^4000)
TERMS = ("position", "motion", "coulomb", "float", "torque", "model", "rounding")  # regressor side, then torque side


# ------------------------------------------------------------------------------------------------ geometry
def geometry_bounds(robot) -> dict:
    """The proven global bounds of the module docstring for a chain of revolute joints.

    Returns dict ``R`` [m], ``M`` (|M| per unit parameter), ``dM`` (|dM/dq_k|), ``gamma`` (|Christoffel|),
    ``g``, ``dg`` (gravity and its derivative per unit parameter). Raises ValueError for a non-revolute joint
    (Bernstein's inequality needs the angle to enter through cos/sin).
    """
    model = robot.model
    for i in range(1, model.njoints):
        short = model.joints[i].shortname()
        if "Revolute" not in short and not short.startswith("JointModelR"):
            raise ValueError(f"robot must have revolute joints only for the certified equation, joint {i} is {short}")
    R = sum(norm3(model.jointPlacements[i].translation) for i in range(1, model.njoints))
    m_bar = float(up(1.0 + R * R))
    g0 = norm3(model.gravity.linear)
    g_bar = float(up(g0 * math.sqrt(1.0 + R * R) * (1 + 1e-15)))
    return {"R": R, "M": m_bar, "dM": 2.0 * m_bar, "gamma": 3.0 * m_bar, "g": g_bar, "dg": 2.0 * g_bar}


def secant_span(spec: ErrorSpec, e_typ: float, cap: int = 50) -> int:
    """Half-span m [steps] of the speed secants: minimises ``qdd_max m dt / 2 + e / (m dt)``, at most ``cap``."""
    qdd = float(np.max(spec.qdd_max))
    if qdd <= 0:
        return cap
    return int(min(cap, max(1, round(math.sqrt(2.0 * e_typ / qdd) / spec.sample_period))))


# ------------------------------------------------------------------------------------------------ equation
@dataclass(frozen=True)
class CertifiedEquation:
    """Interval equation ``y = W theta + e``, ``W in [Wc - D, Wc + D]``, ``|e| <= bound`` (base columns).

    Wc, D : (m, r); y, bound : (m,) [N m]; joint : (m,) 0-based; window : (m, 2) first and last sample;
    names : (r,); terms : name -> radius array ((m, r) regressor-side, (m,) torque-side) that sum to D and bound;
    parts : the inertial columns' position and motion radii by origin (:data:`PARTS`), (m, r) each;
    info : the kernel, the secant span, the geometry bounds, counts.
    """

    Wc: np.ndarray
    D: np.ndarray
    y: np.ndarray
    bound: np.ndarray
    joint: np.ndarray
    window: np.ndarray
    names: tuple[str, ...]
    terms: dict
    parts: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return self.y.size

    def row_radius(self, theta_abs) -> dict:
        """Per term the (m,) row radius at ``|theta| <= theta_abs`` (r,) [N m]: ``D_term |theta|`` or the
        torque-side term; with ``total``."""
        t = np.abs(np.asarray(theta_abs, dtype=float))
        out = {k: v @ t if v.ndim == 2 else v for k, v in self.terms.items()}
        out["total"] = self.bound + self.D @ t
        return out

    def summary(self, theta_abs) -> dict:
        """JSON-ready radii at ``|theta| <= theta_abs``: ``terms`` (per term the ``max``, ``median`` row radius
        [N m] and its ``share`` of the summed radii), ``parts`` (the inertial parts' ``max``, ``median``),
        ``dominant`` (the term of largest share), ``radius_median_per_joint`` [N m]."""
        t = np.abs(np.asarray(theta_abs, dtype=float))
        rr = self.row_radius(t)
        total = rr.pop("total")
        summed = sum(float(np.sum(v)) for v in rr.values()) or 1.0
        terms = {k: {"max": float(np.max(v)), "median": float(np.median(v)), "share": float(np.sum(v)) / summed}
                 for k, v in rr.items()}
        parts = {k: {"max": float(np.max(v @ t)), "median": float(np.median(v @ t))} for k, v in self.parts.items()}
        nj = int(self.joint.max()) + 1
        return {"terms": terms, "parts": parts, "dominant": max(terms, key=lambda k: terms[k]["share"]),
                "radius_median_per_joint": [float(np.median(total[self.joint == j])) for j in range(nj)]}


#: the serial arms' kernel family (:func:`ident.processing.choice.kernel_family`): lengths 0.2 s and 0.4 s. Measured
#: on a UR5 log (benchmarks/bench_serial_certified.py, 12 s at 1 kHz, 2^17 counts, seed 0; single kernels at
#: 1af7ca8): width over the tuned hull's, median over the 58 base parameters, 5.75 at 0.08 s, 1.76 at 0.2 s, 1.80 at
#: 0.4 s. Each kernel costs one pass of the per-step bounds, so the family is kept to two.
SERIAL_FAMILY = {"shortest_s": 0.2, "longest_s": 0.4, "factor": 2.0}
#: without a stated stride, a serial kernel of L steps on a log of N samples takes a row every
#: ``max(1, min(L // SERIAL_OVERLAP, (N - L) // SERIAL_WINDOWS))`` samples: every sample in about SERIAL_OVERLAP
#: windows of each kernel, and at least about SERIAL_WINDOWS windows per kernel when the log is short. Denser rows
#: say nearly the same: on the 12 s UR5 and Panda logs of benchmarks/bench_serial_certified.py, rows every 20 and 25
#: samples (6fc8ab8: 6324 and 7378 rows) gave median widths 0.0438 and 0.0426 of the prior against 0.0445 and
#: 0.0435 with these (a5ad6ff: 2190 and 2555 rows), for about twice the time on the same machine load.
SERIAL_OVERLAP = 4
SERIAL_WINDOWS = 128


def serial_strides(n_samples: int, steps) -> tuple[int, ...]:
    """The default row stride of each kernel length in ``steps`` on a log of ``n_samples`` samples
    (:data:`SERIAL_OVERLAP`, :data:`SERIAL_WINDOWS`)."""
    return tuple(max(1, min(int(L) // SERIAL_OVERLAP, (int(n_samples) - int(L)) // SERIAL_WINDOWS)) for L in steps)


def _inertial_piece(args):
    robot, geo, q, e, spec, m, kernels = args
    return inertial_family(robot, geo, q, e, spec, m, kernels)


def _inertial(robot, geo, q, e, spec, m: int, kernels, progress, processes: int, reference: bool) -> list:
    """The inertial columns of each kernel ``(kern, starts)`` (:func:`ident.robots.serial_steps.inertial_family`:
    one pass of the per-step stage for all kernels). With ``processes=2`` the windows starting in the second half
    of the log run in a worker process (``forkserver``: a clean process) beside the first half's: each window's
    numbers are the same bits either way (tested); only the steps near the middle are evaluated twice."""
    if processes not in (1, 2):
        raise ValueError(f"processes must be 1 or 2, got {processes!r}")
    if reference:
        from h4bench.ident.robots.serial_reference import inertial_rows_reference  # noqa: PLC0415

        return [inertial_rows_reference(robot, geo, q, e, spec, m, kern, starts, progress)
                for kern, starts in kernels]
    middle = (min(int(st[0]) for _, st in kernels) + max(int(st[-1]) for _, st in kernels)) // 2
    cut = [int(np.searchsorted(st, middle)) for _, st in kernels]
    if processes == 1 or not any(0 < c < len(st) for c, (_, st) in zip(cut, kernels)):
        return inertial_family(robot, geo, q, e, spec, m, kernels, progress)
    from h4bench.ident.workers import worker  # noqa: PLC0415

    second = [(kern, st[c:]) for c, (kern, st) in zip(cut, kernels) if c < len(st)]
    with worker(2) as pool:
        later = pool.submit(_inertial_piece, (robot, geo, q, e, spec, m, second))
        first_k = [(kern, st[:c]) for c, (kern, st) in zip(cut, kernels) if c > 0]
        total = sum(len(st) for _, st in kernels)
        first = inertial_family(robot, geo, q, e, spec, m, first_k,
                                None if progress is None else (lambda d, t: progress(d, 2 * t)))
        rest = later.result()
        if progress is not None:
            progress(total, total)
    out = []
    it1, it2 = iter(first), iter(rest)
    for c, (_, st) in zip(cut, kernels):
        parts = ([next(it1)] if c > 0 else []) + ([next(it2)] if c < len(st) else [])
        if len(parts) == 1:
            out.append(parts[0])
            continue
        (w1, m1, r1, p1), (w2, m2, r2, p2) = parts
        out.append((np.concatenate([w1, w2]), np.concatenate([m1, m2]), np.concatenate([r1, r2]),
                    {k: np.concatenate([p1[k], p2[k]]) for k in p1}))
    return out


def _prepare(robot, q, tau, spec: ErrorSpec, position_error):
    """The checked log: q, tau (N, n) as float arrays, the position-error bounds e, the secant half-span m and the
    geometry bounds (:func:`certified_equation`'s errors)."""
    nj = robot.n_joints
    q = np.asarray(q, dtype=float)
    tau = np.asarray(tau, dtype=float)
    if q.ndim != 2 or q.shape[1] != nj or tau.shape != q.shape:
        raise ValueError(f"q, tau must both have shape (N, {nj}), got {q.shape}, {tau.shape}")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(tau))):
        raise ValueError("q, tau must be finite")
    if spec.n_joints != nj:
        raise ValueError(f"spec must describe {nj} joints, got {spec.n_joints}")
    e = spec.position_error(q) if position_error is None else np.asarray(position_error, dtype=float)
    if e.shape != q.shape or np.any(~np.isfinite(e)) or np.any(e < 0):
        raise ValueError(f"position_error must be finite, >= 0, shape {q.shape}, got shape {e.shape}")
    return q, tau, e, secant_span(spec, float(np.median(e))), geometry_bounds(robot)


def _starts(N: int, m: int, L: int, stride: int):
    """The first samples of a kernel's windows (L steps, every ``stride`` samples; the secants' m samples at both
    ends)."""
    starts = np.arange(m, N - m - L, stride)
    if starts.size == 0:
        raise ValueError(f"q must hold more than 2 H + 2 m = {L + 2 * m} samples for one row, got {N}")
    return starts


def certified_family(robot, base, q, tau, spec: ErrorSpec, *, stride: int | None = None, progress=None,
                     processes: int = 1, position_error=None, first_sample: int = 0, kernel_shape: str = "triangle",
                     reference: bool = False) -> CertifiedEquation:
    """The rows of every kernel of the serial family (:data:`SERIAL_FAMILY`, even lengths), stacked: one true
    interval equation (each kernel's is), whose hull lies in each kernel's. stride : the shortest kernel's row
    spacing [steps] (each kernel's ``max(stride, L // 16)``), or None: :func:`serial_strides`; the kernels share one
    pass of the per-step stage, in two processes with ``processes=2`` (:func:`certified_equation`); other keywords
    as :func:`certified_equation`. ``info["kernels"]`` names the family."""
    t0 = time.perf_counter()
    n_samples = np.asarray(q).shape[0]
    fam = kernel_family(n_samples, spec.sample_period, 1 if stride is None else int(stride), even=True,
                        **SERIAL_FAMILY)
    if stride is None:
        fam = dataclasses.replace(fam, strides=serial_strides(n_samples, fam.steps),
                                  stride_rule=f"max(1, min(L // {SERIAL_OVERLAP}, (N - L) // {SERIAL_WINDOWS})) of a "
                                              "log of N samples")
    for L, st in zip(fam.steps, fam.strides):
        _check_kernel(L // 2, st)
    q, tau, e, m, geo = _prepare(robot, q, tau, spec, position_error)
    kernels = [(make_kernel(L, spec.sample_period, kernel_shape), _starts(q.shape[0], m, L, st))
               for L, st in zip(fam.steps, fam.strides)]
    inertial = _inertial(robot, geo, q, e, spec, m, kernels, progress, processes, reference)
    eqs = [_assemble(robot, base, q, tau, spec, e, m, geo, kern, kernel_shape, starts, part, first_sample, t0)
           for (kern, starts), part in zip(kernels, inertial)]
    return stack_family(eqs, fam, half_width=None, stride=None, window_seconds=None,
                        coulomb_uncertain_share=float(np.mean([e.info["coulomb_uncertain_share"] for e in eqs])),
                        seconds=time.perf_counter() - t0)


def _check_kernel(half_width, stride) -> None:
    if int(half_width) < 2 or int(stride) < 1:
        raise ValueError(f"half_width must be >= 2 and stride >= 1, got {half_width!r}, {stride!r}")


def certified_equation(robot, base, q, tau, spec: ErrorSpec, *, half_width: int, stride: int,
                       first_sample: int = 0, position_error=None, progress=None,
                       kernel_shape: str = "triangle", reference: bool = False,
                       processes: int = 1) -> CertifiedEquation:
    """The derived interval equation (module docstring) of a serial robot's log, for one kernel
    (:func:`certified_family` stacks a family's).

    Parameters
    ----------
    robot : :class:`ident.robots.serial.SerialRobot` (revolute joints)
    base : its :class:`ident.robots.serial.BaseParameters`
    q : (N, n) measured joint positions [rad]; tau : (N, n) logged joint torques [N m]
    spec : :class:`ErrorSpec` of the log (n joints, ``sample_period`` the log's step)
    half_width : H, kernel half-width [steps] (window ``2 H`` steps); stride : row spacing [steps];
    kernel_shape : ``"triangle"`` or ``"hann"`` (:func:`ident.processing.weakform.make_kernel`; the radii hold for
    any kernel linear between the samples, >= 0, zero at both ends)
    first_sample : index of q[0] in the whole log (for ``window``)
    position_error : (N, n) bound on ``|q - q_true|`` [rad], default ``spec.position_error(q)`` (give it when
        the resolution applies on another side, e.g. motor angles mapped to the joints)
    progress : callable(done, total) or None
    reference : True for the per-window reference computation (:mod:`ident.robots.serial_reference`: the same
        numbers up to floating-point rounding, many times slower; the oracle of the vectorised one)
    processes : 1, or 2: the windows of the log's second half in a worker process (the same bits)

    Returns
    -------
    :class:`CertifiedEquation`, rows ordered window-major, joint-minor.
    """
    t0 = time.perf_counter()
    _check_kernel(half_width, stride)
    q, tau, e, m, geo = _prepare(robot, q, tau, spec, position_error)
    L = 2 * int(half_width)
    kern = make_kernel(L, spec.sample_period, kernel_shape)
    starts = _starts(q.shape[0], m, L, int(stride))
    inertial = _inertial(robot, geo, q, e, spec, m, [(kern, starts)], progress, processes, reference)[0]
    return _assemble(robot, base, q, tau, spec, e, m, geo, kern, kernel_shape, starts, inertial, first_sample,
                     t0)


def _assemble(robot, base, q, tau, spec, e, m, geo, kern, kernel_shape, starts, inertial, first_sample,
              t0) -> CertifiedEquation:
    """One kernel's equation from its inertial columns (:func:`_inertial`): the generic weak-form columns, the
    torque side, the floating-point allowance and the base columns."""
    nj = robot.n_joints
    L = kern.steps
    H = L // 2
    stride = int(starts[1] - starts[0]) if starts.size > 1 else 1
    gamma_l = 8 * (2 * H + 4) * 2.0**-53  # a-priori error of the window sums (products and sums of L terms)
    dt = spec.sample_period
    N = q.shape[0]
    qddm = spec.qdd_max
    K1 = kern.integrals  # int_step k, k >= 0
    body_of_col = np.repeat(np.arange(nj), 10)
    mask = (np.arange(nj)[:, None] <= body_of_col[None, :]).astype(float)  # (n rows, 10 n cols)
    R_ = len(starts)
    Wi, mag, recon, parts_i = inertial
    parts_i = dict(parts_i)
    # ---- friction, rotor inertia, offsets (the generic weak-form columns) and the torque side
    windows = RowWindows(start=starts, steps=L)
    Fqdd, r_qdd_pos, _ = imot_columns(q, e, windows, kern)
    Fqd, r_qd_pos, r_qd_mot = viscous_columns(q, e, windows, kern, qddm)
    Fsign, r_sign, _ = coulomb_columns(q, e, windows, kern, qddm, spec.friction_band)
    if robot.coupled_wrist is not None:  # sign(qd_a + qd_b) of the wrist motor: the Coulomb column of q_a + q_b
        a, b = robot.coupled_wrist
        qm = q[:, a] + q[:, b]
        em = up(up(e[:, a] + e[:, b]) + 2.0**-53 * np.abs(qm))  # the sum's own rounding with the two errors
        # the motor turns at qd_a + qd_b: its acceleration bound and friction band are the two joints' summed
        Fsign_m, r_sign_m, _ = coulomb_columns(qm[:, None], em[:, None], windows, kern, up(qddm[a] + qddm[b]),
                                               up(spec.friction_band[a] + spec.friction_band[b]))
        Fsign_m, r_sign_m = Fsign_m[:, 0], r_sign_m[:, 0]
    y, y_fp, k_abs = torque_rows(tau, windows, kern, spec.torque_timing)
    # ---- assemble the standard columns (n rows per window)
    p = robot.n_parameters
    Wc = np.zeros((R_, nj, p))
    Dpos = np.zeros((R_, nj, p))
    Dmot = np.zeros((R_, nj, p))
    Dcou = np.zeros((R_, nj, p))
    ni = 10 * nj
    Wc[:, :, :ni] = Wi
    # the parts are sums of products of non-negative floats rounded to nearest (per step, then over the window):
    # each is within (1 + u)^k of its exact value for a chain of k operations; RADII_GROW covers k up to 4000
    for name in PARTS:
        parts_i[name] = up(parts_i[name] * mask[None] * RADII_GROW)
    Dpos[:, :, :ni] = sum(parts_i[nm] for nm in PARTS if nm.endswith("position"))
    Dmot[:, :, :ni] = sum(parts_i[nm] for nm in PARTS if nm.endswith("motion"))
    col = ni
    eye = np.arange(nj)
    k_sum = float(np.sum(K1))
    for kind in [k for k in ("fv", "fs", "Ia", "off") if f"{k}1" in robot.names]:  # SerialRobot.extra_columns order
        cols = col + eye
        if kind == "fv":
            Wc[:, eye, cols] = Fqd
            Dpos[:, eye, cols] = r_qd_pos
            Dmot[:, eye, cols] = r_qd_mot
        elif kind == "fs":
            Wc[:, eye, cols] = Fsign
            Dcou[:, eye, cols] = r_sign
        elif kind == "Ia":
            Wc[:, eye, cols] = Fqdd
            Dpos[:, eye, cols] = r_qdd_pos
        elif kind == "off":
            Wc[:, eye, cols] = k_sum
        col += nj
    if robot.coupled_wrist is not None:
        a, b = robot.coupled_wrist
        for row in (a, b):
            Wc[:, row, col] = Fqdd[:, a] + Fqdd[:, b]
            Dpos[:, row, col] = r_qdd_pos[:, a] + r_qdd_pos[:, b]
            Wc[:, row, col + 1] = Fqd[:, a] + Fqd[:, b]
            Dpos[:, row, col + 1] = r_qd_pos[:, a] + r_qd_pos[:, b]
            Dmot[:, row, col + 1] = r_qd_mot[:, a] + r_qd_mot[:, b]
            Wc[:, row, col + 2] = Fsign_m
            Dcou[:, row, col + 2] = r_sign_m
    # ---- floating-point allowance: stated for pinocchio, a-priori for the window sums (the extra columns' sums
    # are in their position radii above; the offset column's sum of L terms gets gamma_L)
    Dflt = np.zeros((R_, nj, p))
    Dflt[:, :, :ni] = ((_PIN_REL + gamma_l) * mag + recon) * mask[None]
    Dflt[:, :, ni:] = gamma_l * np.abs(Wc[:, :, ni:])
    # ---- torque side (the applied torque's timing with the stated error: both of the torque signal)
    side = torque_side_terms(spec, k_abs)
    t_err, model_term = up(side["torque"] + side["timing"]), side["model"]
    y_rnd = y_fp
    # ---- base columns, flattened rows (window-major, joint-minor)
    ind = np.asarray(base.independent)
    flat = lambda x: x.reshape(R_ * nj, p)  # noqa: E731
    Wfull = flat(Wc)
    if base.dependent.size:
        dev = np.abs(Wfull[:, base.dependent] - Wfull[:, ind] @ base.beta)
        scale = np.abs(Wfull).max()
        if dev.max() > 1e-6 * max(scale, 1.0):
            raise ValueError("the weak-form rows break the base parameters' structural dependences "
                             f"(relative {dev.max() / scale:.2e}); the base was computed for another robot model")
    joint = np.tile(eye, R_)
    terms = {"position": flat(Dpos)[:, ind], "motion": flat(Dmot)[:, ind], "coulomb": flat(Dcou)[:, ind],
             "float": flat(Dflt)[:, ind], "torque": np.tile(t_err, R_), "model": np.tile(model_term, R_), "rounding": y_rnd.reshape(-1)}
    D = up(up(up(terms["position"] + terms["motion"]) + terms["coulomb"]) + terms["float"])
    bound = up(up(terms["torque"] + terms["model"]) + terms["rounding"])
    window = np.repeat(np.stack([starts, starts + L], axis=1) + int(first_sample), nj, axis=0)
    info = {"kernel": kernel_shape, "half_width": H, "stride": stride, "window_seconds": L * dt, "secant_half_span": m,
            "rows": int(R_ * nj), "windows": int(R_), "geometry": geo, "samples": int(N),
            "coulomb_uncertain_share": float(np.mean(r_sign > 0)) if r_sign.size else 0.0,
            "seconds": time.perf_counter() - t0}
    parts = {}
    for name in PARTS:
        full = np.zeros((R_, nj, p))
        full[:, :, :ni] = parts_i[name]
        parts[name] = flat(full)[:, ind]
    return CertifiedEquation(Wc=Wfull[:, ind], D=D, y=y.reshape(-1), bound=bound, joint=joint, window=window,
                             names=tuple(base.names), terms=terms, parts=parts, info=info)


def certificate(eq: CertifiedEquation, W_true, y_true, theta_true) -> dict:
    """The derived radii beside the actual errors (truth known: a simulation), row by row.

    W_true : (m, r) the true rows ``int k Y dt`` (of the true motion); y_true : (m,) ``int k tau_applied dt``;
    theta_true : (r,) base parameters. Returns JSON-ready: ``rows``, ``entry_violations`` (``|Wc - W_true| >
    D``), ``torque_violations`` (``|y - y_true| > bound``), ``violations`` (rows with ``|y - Wc theta| > bound +
    D |theta|``), ``min_margin`` (the smallest ``bound + D |theta| - |y - Wc theta|`` [N m]), ``max_ratio`` (the
    largest actual error over its radius), per term its max and median row radius at theta and its share of
    the summed radii (``terms``), and the same for the inertial parts (``parts``).
    """
    th = np.asarray(theta_true, dtype=float)
    total = eq.row_radius(np.abs(th))["total"]
    rows = row_check(eq.y - eq.Wc @ th, total)
    summary = eq.summary(np.abs(th))
    return {
        "rows": int(len(eq)),
        "entry_violations": row_check(eq.Wc - np.asarray(W_true, dtype=float), eq.D)["violations"],
        "torque_violations": row_check(eq.y - np.asarray(y_true, dtype=float), eq.bound)["violations"],
        "violations": rows["violations"], "min_margin": rows["min_margin"],
        "max_ratio": rows["max_actual_over_radius"], "actual_max": rows["max_actual"],
        "radius_median": float(np.median(total)), "terms": summary["terms"], "parts": summary["parts"],
    }


# ---------------------------------------------------------------------------------------------- spec check
# The motion-bound check is shared by every robot kind: :mod:`ident.processing.motion_check` (re-exported here).
