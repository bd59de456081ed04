"""The H4's derived interval equation: every radius from an :class:`~ident.processing.errorspec.ErrorSpec`.

The weak form of :mod:`ident.processing.weakform` applied to the H4 model of :mod:`ident.robots.h4`:

* ``Imot_i``: ``P = qd_i`` (exact in the true positions; encoder by summation by parts);
* ``Mnac``, ``Ibc``: the nacelle's Lagrangian per unit parameter, ``T = 1/2 |J_c qd|^2`` (``J_c`` the rows x, y, z
  of J for Mnac, the row theta for Ibc) and ``V = -g . x`` (Mnac only), so that
  ``J_c^T (J_c qdd + Jd_c qd) - [Mnac] J_p^T g = d/dt (dT/dqd) - dT/dq + dV/dq`` with
  ``P = dT/dqd = J_c^T J_c qd`` and ``F = -Jd_c^T J_c qd - [Mnac] J_p^T g`` (``dT/dq = Jd^T J qd`` because
  ``d(J qd)/dq = Jd`` for a holonomic x(q)): functions of (q, qd) only;
* ``Fv_i``: ``F = qd_i``; ``Fs_i``: ``F = sign(qd_i)``, certain or the interval [-1, 1] step by step.

What is proven and what is not (``CertifiedEquation.info["not_proven"]``): everything, from the ErrorSpec, once
the interval jets of :mod:`ident.robots.h4_jets` verify each step's boxes: the values and gradients of P and F at
the measured secant states, their gradients and second derivatives over each step's ENCODER box (the encoder's
second-order term, and the transfer of the gradients to the true secant state) and their second derivatives over
each step's MOTION (the truncation's second-order remainder), the latter as a Taylor model along the step (a tube
``q_m + (v h / 2) tau`` with a small box around it; a plain box over the same span fails the pose test on about
half of the steps of ``certified --quick``). A step whose box cannot be verified falls back to second-derivative
bounds SAMPLED along the measured motion (central differences at every ``curvature_every``-th step, local maximum
times :data:`CURVATURE_FACTOR`) and is listed in ``not_proven``. Stated: the robot stays in the assembly mode the
forward kinematics of the measured positions gives, and numpy's sin/cos are within 4 ulp.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from h4bench.ident.processing.errorspec import ErrorSpec
from h4bench.ident.processing.choice import MIN_KERNEL_STEPS, check_kernel_steps, kernel_family, stack_family
from h4bench.ident.processing.weakform import (NonlinearSteps, coulomb_columns, imot_columns,
                                               make_kernel, nonlinear_rows, nonlinear_steps, row_windows,
                                               torque_rows, torque_side_terms, viscous_columns)
from h4bench.ident.robots.h4 import PARAMETER_NAMES
from h4bench.ident.robots.h4_interval import IntervalEquation
from h4bench.ident.numerics.interval import up
from h4bench.ident.numerics.jets import MR
from h4bench.ident.workers import shared_map, worker
from h4bench.ident.robots.h4_jets import box_jets_started, point_jets, point_jets_started

__all__ = ["CURVATURE_FACTOR", "ENCODER_JETS", "encoder_from_tube", "MIN_KERNEL_STEPS", "STATED", "CertifiedEquation", "CertifiedSteps", "MotionBounds", "Processing", "certified_equation",
           "certified_rows", "certified_steps", "curvature_bounds", "nacelle_terms", "stated_assumptions"]

#: where each step's encoder-box bounds (the encoder's second-order term and the gradients' transfer to the true
#: state) come from: ``"box"`` interval jets over the encoder box itself, ``"tube"`` those of the step's motion tube
#: (which holds the encoder box: valid, a little wider, one evaluation instead of two), ``"auto"`` the tube's on the
#: steps where :func:`encoder_from_tube` says the position error is small against the motion, the box's elsewhere
ENCODER_JETS = ("auto", "box", "tube")
CURVATURE_FACTOR = 2.0  # stated factor on the sampled second-derivative maxima (not proven; see module docstring)
N_JOINTS = 4
# What the derived equation states without proving it (module docstring), entry -> source
STATED = {
    "assembly_mode": "stated, not proven: the robot stays in the assembly mode that the forward kinematics of the "
                     "measured positions gives (the interval jets verify the pose within that branch)",
    "sin_cos": "stated, not proven: numpy's sin and cos are within 4 ulp (the interval jets widen by that much)",
}


@dataclass(frozen=True)
class Processing:
    """The weak form's processing settings (a scenario's ``[certified]`` table): kernel length in sample steps
    (None: every kernel of :func:`ident.processing.choice.kernel_family`, rows stacked), its shape, the stride
    between rows [samples], the sampling of the curvature bounds [steps] and where the encoder's derivative
    bounds come from (``encoder_jets``, :data:`ENCODER_JETS`: ``"auto"`` applies :func:`encoder_from_tube`)."""

    kernel_steps: int | None = None
    kernel_shape: str = "hann"
    stride: int = 2
    curvature_every: int = 10
    encoder_jets: str = "auto"

    def __post_init__(self) -> None:
        from h4bench.ident.processing.weakform import KERNEL_SHAPES  # noqa: PLC0415

        for key in ("stride", "curvature_every"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{key} must be an integer >= 1, got {v!r}")
        if self.kernel_steps is not None:
            check_kernel_steps(self.kernel_steps)
        if self.kernel_shape not in KERNEL_SHAPES:
            raise ValueError(f"kernel_shape must be one of {KERNEL_SHAPES}, got {self.kernel_shape!r}")
        if self.encoder_jets not in ENCODER_JETS:
            raise ValueError(f"encoder_jets must be one of {ENCODER_JETS}, got {self.encoder_jets!r}")


@dataclass(frozen=True)
class CertifiedEquation(IntervalEquation):
    """``y in [Wc - D, Wc + D] theta + [-bound, bound]`` row by row (rows ``4 r + i``: window r, joint i).

    Wc, D (m, 14); y, bound (m,) [N m]; sample (m,) the centre sample of each row's window; joint (m,);
    names the columns; terms: the radii by origin, ``torque``, ``model``, ``rounding`` (m,) [N m] and
    ``measurement``, ``second_order``, ``truncation``, ``sign`` (m, 14) (units of W); D is the sum of the four
    matrices, bound the sum of the three vectors; info: the settings and what is not proven."""

    names: tuple = PARAMETER_NAMES
    terms: dict = field(default_factory=dict, compare=False)
    motion: MotionBounds | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class MotionBounds:
    """Each step's motion tube and the bounds over it of the second derivatives of P and F: q_tube (S, 4) a Taylor
    model in tau [rad], v_tube (S, 4) [rad/s] (:class:`~ident.numerics.jets.MR`), HP, HF (S, 4, 2, 8, 8) and the
    (S,) mask of the steps whose bounds the interval jets proved (the others hold sampled bounds)."""

    q_tube: MR
    v_tube: MR
    HP: np.ndarray
    HF: np.ndarray
    proven: np.ndarray

    def covers(self, q_tube: MR, v_tube: MR) -> np.ndarray:
        """(S,) True where the proven tube of this step contains the given one (q_tube a Taylor model in the same
        tau, v_tube a plain box, both (S, 4)) for every tau: ``|c1 - c2| + |a1 - a2| + r1 <= r2`` elementwise,
        its float sum rounded up; a bound over the bigger tube holds over every tube inside it."""
        if q_tube.shape != self.q_tube.shape:
            return np.zeros(q_tube.shape[0], dtype=bool)
        grow = 1.0 + 8 * 2.0**-53
        dq = (np.abs(q_tube.c - self.q_tube.c) + np.abs(q_tube.a - self.q_tube.a) + q_tube.r) * grow + 1e-300
        dv = (np.abs(v_tube.c - self.v_tube.c) + v_tube.r) * grow + 1e-300
        return self.proven & np.all(dq <= self.q_tube.r, axis=1) & np.all(dv <= self.v_tube.r, axis=1)


def stated_assumptions(info: dict) -> dict:
    """Every assumption a :class:`CertifiedEquation` rests on without proof, entry -> source: :data:`STATED`, the
    fallback's ``curvature_factor`` (with the number of steps that used it) and the equation's own
    ``info["not_proven"]`` (sampled curvature bounds x :data:`CURVATURE_FACTOR`, the torque between samples) as
    ``not_proven_1``, ``not_proven_2``, ..."""
    out = dict(STATED)
    steps = info.get("steps", 0)
    fallback = max(steps - info.get("encoder_boxes_proven", steps), steps - info.get("motion_boxes_proven", steps))
    out["curvature_factor"] = (f"stated, not proven: a step whose box the interval jets cannot verify falls back to "
                               f"second-derivative bounds sampled along the measured motion times "
                               f"{info.get('curvature_factor', CURVATURE_FACTOR):g}; used on {fallback} of {steps} "
                               "steps of this equation")
    for i, what in enumerate(info.get("not_proven", []), start=1):
        out[f"not_proven_{i}"] = f"stated, not proven: {what}"
    return out


def encoder_from_tube(ev, qdd_max, h: float) -> np.ndarray:
    """(S,) the steps whose encoder-box bounds ``"auto"`` takes from the motion tube's interval jets: those where on
    every joint the encoder's speed error ``ev`` (S, n_j) [rad/s] (the secant's, ``(e_j + e_j+1) / h``) is at most
    the motion's own ``qdd_max h / 2``, the tube's speed allowance beyond it. There the position error is small
    against the motion within a step: its terms are a small part of the rows, and bounding them over the tube (2-8 %
    wider on ``certified --quick``) changes the box by well under 1 % (docs/guarantee.md), while the second
    evaluation would cost as much as the tube's. Elsewhere (a coarse encoder, a slow motion) the encoder's terms
    weigh, and their own box's tighter bounds are worth their time. Reads the specification and the measured
    positions only."""
    allowance = np.asarray(qdd_max, dtype=float) * (h / 2)
    return np.all(np.asarray(ev, dtype=float) <= allowance, axis=-1)


def nacelle_terms(geometry, q, qd, x=None, x0=None):
    """P, F (S, 4, 2) of the Mnac and Ibc columns at states q, qd (S, 4) (module docstring); x (S, 4) the nacelle
    poses of q if known, else forward kinematics started at x0 (S, 4) (default the home pose)."""
    from h4bench.sim.kinematics import forward_kinematics, jacobian_dot, jacobians  # noqa: PLC0415

    if x is None:
        x = np.atleast_2d(forward_kinematics(geometry, q, x0=x0))
    jac = jacobians(geometry, q, x)
    jd = jacobian_dot(geometry, q, qd, x)
    J = jac.J
    xd = np.einsum("sab,sb->sa", J, qd)
    P = np.empty(q.shape + (2,))
    F = np.empty_like(P)
    P[..., 0] = np.einsum("sai,sa->si", J[:, :3, :], xd[:, :3])
    P[..., 1] = J[:, 3, :] * xd[:, 3, None]
    F[..., 0] = -np.einsum("sai,sa->si", jd[:, :3, :], xd[:, :3]) - np.einsum("sai,a->si", J[:, :3, :],
                                                                             geometry.gravity)
    F[..., 1] = -jd[:, 3, :] * xd[:, 3, None]
    return P, F


def curvature_bounds(geometry, q, h: float, every: int = 10, factor: float = CURVATURE_FACTOR,
                     steps: tuple[float, float] = (1e-3, 0.5)):
    """Sampled bounds (MP, MF), each (S, 4, 2, 8, 8) per step, of ``|d^2 P / dx_a dx_b|``, ``|d^2 F / ...|`` over
    ``x = (q, qd)``: central second differences at every ``every``-th secant state of the measured positions
    q (n, 4); each step takes the maximum over the sampled states within two sampling intervals of it, times
    ``factor``. NOT a proof (module docstring)."""
    from h4bench.sim.kinematics import forward_kinematics  # noqa: PLC0415

    S = q.shape[0] - 1
    idx = np.unique(np.append(np.arange(0, S, every), S - 1))
    qm = 0.5 * (q[:-1] + q[1:])[idx]
    v = (np.diff(q, axis=0) / h)[idx]
    x0 = np.concatenate([qm, v], axis=1)
    d = np.concatenate([np.full(4, steps[0]), np.full(4, steps[1])])

    pose = np.atleast_2d(forward_kinematics(geometry, x0[:, :4]))

    def ev(x):  # the base pose when q is not perturbed, else a warm start from it
        same = np.array_equal(x[:, :4], x0[:, :4])
        return nacelle_terms(geometry, x[:, :4], x[:, 4:], x=pose if same else None, x0=None if same else pose)

    MP = np.zeros((idx.size, 4, 2, 8, 8))
    MF = np.zeros_like(MP)
    base = ev(x0)
    for a in range(8):
        for b in range(a, 8):
            ea, eb = np.zeros(8), np.zeros(8)
            ea[a], eb[b] = d[a], d[b]
            if a == b:
                p1, p0 = ev(x0 + ea), ev(x0 - ea)
                hp = [(u1 - 2 * u + u0) / d[a] ** 2 for u1, u, u0 in zip(p1, base, p0)]
            else:
                pp, pm, mp, mm = ev(x0 + ea + eb), ev(x0 + ea - eb), ev(x0 - ea + eb), ev(x0 - ea - eb)
                hp = [(a1 - a2 - a3 + a4) / (4 * d[a] * d[b]) for a1, a2, a3, a4 in zip(pp, pm, mp, mm)]
            for M, hv in zip((MP, MF), hp):
                M[..., a, b] = M[..., b, a] = np.abs(hv)
    # per step: the maximum over the sampled states within 2 sampling intervals
    near = np.clip(np.searchsorted(idx, np.arange(S))[:, None] + np.arange(-2, 3)[None, :], 0, idx.size - 1)
    return factor * MP[near].max(axis=1), factor * MF[near].max(axis=1)


def certified_equation(geometry, q, tau, spec: ErrorSpec, processing: Processing | None = None,
                       position_error=None, motion: MotionBounds | None = None,
                       processes: int = 1) -> CertifiedEquation:
    """The H4's derived interval equation of a log: q (n, 4) measured positions [rad], tau (n, 4) logged torques
    [N m] (held over each step, or the torque at each sample instant: ``spec.torque_timing``), spec the error
    specification (4 joints).

    processing : the weak form's settings; ``kernel_steps = None`` (the default) stacks the rows of every kernel
    of :func:`ident.processing.choice.kernel_family` (one true interval equation; ``info["kernels"]``); an
    explicit length gives that kernel's rows alone, and one under
    :data:`ident.processing.choice.MIN_KERNEL_STEPS` is refused.
    position_error : (n, 4) bounds of the position error [rad]; default ``spec.position_error(q)`` (0 gives the
    equation of exact positions, used by the certificate to check the truncation terms alone).
    motion : the :class:`MotionBounds` of another equation of the same steps (e.g. the measured log's,
    ``CertifiedEquation.motion``): its proven bounds serve every step whose motion tube lies inside that
    equation's (checked step by step, :meth:`MotionBounds.covers`), the interval jets the others.
    processes : 1, or 2: the later half of the steps' interval jets in a worker process (:func:`certified_steps`),
    and about half of the kernels' rows (:func:`_family_rows`); the same bits.
    """
    processing = processing or Processing()
    q = np.asarray(q, dtype=float)
    tau = np.asarray(tau, dtype=float)
    if q.ndim != 2 or q.shape[1] != N_JOINTS or tau.shape != q.shape:
        raise ValueError(f"q and tau must have the same shape (n, {N_JOINTS}), got {q.shape} and {tau.shape}")
    h = spec.sample_period
    if processing.kernel_steps is None:
        family = kernel_family(q.shape[0], h, processing.stride)
        pairs = list(zip(family.steps, family.strides))
    else:
        pairs = [(int(processing.kernel_steps), processing.stride)]
    if processes not in (1, 2):
        raise ValueError(f"processes must be 1 or 2, got {processes!r}")
    with worker(processes) as pool:
        steps = _certified_steps(geometry, q, spec, processing, position_error, motion, pool)
        eqs = _family_rows(steps, pairs, processing.kernel_shape, tau, pool)
    eq = eqs[0] if processing.kernel_steps is not None else stack_family(
        eqs, family, kernel_steps=None, kernel_l1=max(e.info["kernel_l1"] for e in eqs))
    eq.info.update(kernel_shape=processing.kernel_shape, stride=processing.stride,
                   curvature_every=processing.curvature_every, encoder_jets=processing.encoder_jets,
                   encoder_boxes_from_tube=steps.encoder_from_tube)
    if len(eq) <= len(PARAMETER_NAMES):
        raise ValueError(f"the log gives {len(eq)} rows ({eq.info['windows']} kernel windows, 4 joints), which must "
                         f"exceed the {len(PARAMETER_NAMES)} parameters: a longer log or a smaller stride")
    return eq


@dataclass(frozen=True)
class CertifiedSteps:
    """The kernel-independent stage of the H4's certified equation of a log (:func:`certified_steps`): q, e (n, 4)
    the measured positions and their error bounds [rad], spec, the nonlinear columns' per-step stage, the counts
    of verified boxes and the statements of what is not proven."""

    q: np.ndarray
    e: np.ndarray
    spec: ErrorSpec
    nonlinear: NonlinearSteps
    proven: np.ndarray
    proven_motion: np.ndarray
    motion: MotionBounds | None = None
    encoder_from_tube: int = 0


def certified_steps(geometry, q, spec: ErrorSpec, processing: Processing, position_error=None,
                    motion: MotionBounds | None = None, processes: int = 1) -> CertifiedSteps:
    """Everything of the certified equation that does not depend on the kernel: the position error bounds, the
    interval jets of every step's encoder box and motion tube (or the sampled fallback; ``motion``: bounds over
    containing tubes, :func:`certified_equation`), and the nonlinear columns' per-step stage
    (:func:`ident.processing.weakform.nonlinear_steps`). q (n, 4) [rad].

    processes : 1, or 2: the later half of the interval jets' chunks (encoder boxes and motion tubes) runs in a
    ``forkserver`` worker while this process computes the first half and the rest
    (:func:`ident.robots.h4_jets.box_jets_started`): each chunk's numbers are its own, so the bits are the same."""
    if processes not in (1, 2):
        raise ValueError(f"processes must be 1 or 2, got {processes!r}")
    with worker(processes) as pool:
        return _certified_steps(geometry, q, spec, processing, position_error, motion, pool)


def _kernel_rows(steps: CertifiedSteps, L: int, stride: int, shape: str, tau) -> CertifiedEquation:
    n = steps.q.shape[0]
    return certified_rows(steps, make_kernel(L, steps.spec.sample_period, shape), row_windows(n, L, stride), tau)


def _family_rows(steps: CertifiedSteps, pairs, shape: str, tau, pool=None) -> list:
    """The rows of each kernel ``(L, stride)`` of ``pairs`` (:func:`certified_rows`), in order; with ``pool`` the
    kernels are shared with the worker (:func:`ident.workers.shared_map`), sent the per-step stage without its
    motion bounds (the rows do not read them; each kernel's rows are its own: the same bits)."""
    light = steps if pool is None else dataclasses.replace(steps, motion=None)
    eqs = shared_map(pool, _kernel_rows, [(light, L, st, shape, tau) for L, st in pairs])
    return [e if e.motion is steps.motion else dataclasses.replace(e, motion=steps.motion) for e in eqs]


def _certified_steps(geometry, q, spec: ErrorSpec, processing: Processing, position_error, motion, pool):
    from h4bench.sim.kinematics import forward_kinematics  # noqa: PLC0415

    if spec.n_joints != N_JOINTS:
        raise ValueError(f"spec must describe {N_JOINTS} joints (the H4), got n_joints = {spec.n_joints}")
    if spec.latency > 0 and spec.torque_rate is None:
        raise ValueError("spec.latency > 0 needs spec.torque_rate (the bound on |d tau / dt|)")
    h = spec.sample_period
    e = spec.position_error(q) if position_error is None else np.broadcast_to(
        np.asarray(position_error, dtype=float), q.shape)
    qm = 0.5 * (q[:-1] + q[1:])
    pose = np.atleast_2d(forward_kinematics(geometry, qm))
    points = []  # the point jets at the secant states, begun after the boxes' (the worker's queue runs in order)

    def evaluate(a, b):  # rigorous values and gradients at the measured secant states
        if points and np.array_equal(a, qm) and np.array_equal(b, points[0]):
            return points[1]()
        return point_jets(geometry, a, b, pose)

    # Per step, two sets of boxes, each enclosed by interval jets (module docstring); a step whose box cannot be
    # verified falls back to the sampled bounds (listed in not_proven):
    # * the encoder box: the measured secant state +- the position error's effect (e_m, e_v);
    # * the motion tube: q_m + (v h / 2) tau +- (e_m + e_v h / 2 + qdd_max h^2 / 8) for tau in [-1, 1] (a Taylor
    #   model in tau), v +- (e_v + qdd_max h / 2): every true state of the step and every point between it and
    #   the true secant state (chord remainder qdd_max h^2 / 8, speed within qdd_max h / 2 of the secant's).
    # The encoder box lies in the motion tube, so the tube's jets bound it too, in one evaluation instead of two
    # (Processing.encoder_jets: "auto" does so where encoder_from_tube says the position error is small against the
    # motion). On certified --quick seeds 0-2 at 20000 counts per turn the equation then takes 0.7x the time and the
    # box is 0.7-1.1 % wider (width/tuned 1.0103 / 1.1641 / 1.0657 -> 1.0175 / 1.1766 / 1.0735); at 4096 counts the
    # tube's bounds would leave 6 parameters at the prior instead of 4, and "auto" keeps the encoder box's there.
    u = 2.0**-53
    qddm = np.asarray(spec.qdd_max, dtype=float)
    em, ev = up(0.5 * (e[:-1] + e[1:])), up((e[:-1] + e[1:]) / h)
    vm = np.diff(q, axis=0) / h
    em_box, ev_box = up(em + 2 * u * np.abs(qm)), up(ev + 4 * u * np.abs(vm))
    a_tube = vm * (h / 2)
    q_tube = MR(qm, up(em_box + up(ev_box * (h / 2)) + up(qddm * (h * h / 8)) + 4 * u * np.abs(a_tube)), a_tube)
    v_tube = MR(vm, up(ev_box + up(qddm * (h / 2))))
    # the steps whose encoder bounds come from their tube's jets (Processing.encoder_jets), the others' from their
    # encoder box's own
    from_tube = {"box": np.zeros(qm.shape[0], dtype=bool), "tube": np.ones(qm.shape[0], dtype=bool),
                 "auto": encoder_from_tube(ev_box, qddm, h)}[processing.encoder_jets] & bool(np.any(e))
    motion_done = _motion_jets(geometry, q_tube, v_tube, pose, motion, pool)
    own = np.flatnonzero(~from_tube) if np.any(e) else np.zeros(0, dtype=np.int64)
    encoder_done = box_jets_started(geometry, MR(qm, em_box)[own], MR(vm, ev_box)[own], pose[own], pool) \
        if own.size else None
    points += [vm, point_jets_started(geometry, qm, vm, pose, pool)]
    GPm, HPm, GFm, HFm, proven_m = motion_done()
    if np.any(e):  # the encoder box lies in the tube (its radii are the box's plus the motion's): the tube's bounds hold
        GP, HP, GF, HF, proven = GPm.copy(), HPm.copy(), GFm.copy(), HFm.copy(), proven_m.copy()
        if encoder_done is not None:
            GP[own], HP[own], GF[own], HF[own], proven[own] = encoder_done()
    else:  # exact positions (the certificate's truth equation): no encoder term, nothing to bound
        GP, GF = np.full((qm.shape[0], 4, 2, 8), np.inf), np.full((qm.shape[0], 4, 2, 8), np.inf)
        HP, HF = np.zeros((qm.shape[0], 4, 2, 8, 8)), np.zeros((qm.shape[0], 4, 2, 8, 8))
        proven = np.ones(qm.shape[0], dtype=bool)
    if not (proven.all() and proven_m.all()):
        curv = curvature_bounds(geometry, q, h, every=processing.curvature_every)
        for got, sampled in ((HP, curv[0]), (HF, curv[1])):
            got[~proven] = sampled[~proven]
        for got, sampled in ((HPm, curv[0]), (HFm, curv[1])):
            got[~proven_m] = sampled[~proven_m]
        for got in (GP, GF):
            got[~proven] = np.inf
    nonlinear = nonlinear_steps(evaluate, q, e, h, spec.qd_max, spec.qdd_max, (HPm, HFm), encoder=(HP, HF, GP, GF))
    bounds = MotionBounds(q_tube=q_tube, v_tube=v_tube, HP=HPm, HF=HFm, proven=proven_m)
    return CertifiedSteps(q=q, e=e, spec=spec, nonlinear=nonlinear, proven=proven, proven_motion=proven_m,
                          motion=bounds, encoder_from_tube=int(from_tube.sum()))


def _motion_jets(geometry, q_tube: MR, v_tube: MR, pose, motion: MotionBounds | None, pool=None):
    """A function returning (GP, HP, GF, HF, proven) over the motion tubes (S, 4): ``motion``'s bounds on the steps
    whose tubes it covers (it holds no gradient bounds: GP, GF infinite there), the interval jets
    (:func:`ident.robots.h4_jets.box_jets`) on the others, the later half of their chunks begun in ``pool`` now
    (:func:`ident.robots.h4_jets.box_jets_started`)."""
    reuse = np.zeros(q_tube.shape[0], dtype=bool) if motion is None else motion.covers(q_tube, v_tube)
    if not reuse.any():
        return box_jets_started(geometry, q_tube, v_tube, pose, pool)
    todo = np.flatnonzero(~reuse)
    started = box_jets_started(geometry, q_tube[todo], v_tube[todo], pose[todo], pool) if todo.size else None

    def merged():
        S = q_tube.shape[0]
        GP, GF = np.full((S, 4, 2, 8), np.inf), np.full((S, 4, 2, 8), np.inf)
        HP, HF, proven = motion.HP.copy(), motion.HF.copy(), reuse.copy()
        if started is not None:
            GP[todo], HP[todo], GF[todo], HF[todo], proven[todo] = started()
        return GP, HP, GF, HF, proven

    return merged


def _regressor_columns(steps: CertifiedSteps, kernel, windows):
    """The regressor side of the rows: {value, measurement, truncation, second_order, sign} (R, 4, 14) and the
    Coulomb columns' uncertain steps."""
    q, e, spec = steps.q, steps.e, steps.spec
    R = windows.start.size
    p = len(PARAMETER_NAMES)
    cols = {name: np.zeros((R, N_JOINTS, p)) for name in ("value", "measurement", "truncation", "second_order",
                                                          "sign")}
    joint = np.arange(N_JOINTS)
    for offset, fn in ((0, imot_columns), (6, viscous_columns), (10, coulomb_columns)):
        args = (q, e, windows, kernel) + (() if fn is imot_columns else (spec.qdd_max,)) + (
            (spec.friction_band,) if fn is coulomb_columns else ())
        value, r1, r2 = fn(*args)
        cols["value"][:, joint, offset + joint] = value
        if fn is coulomb_columns:
            cols["sign"][:, joint, offset + joint] = r1
            sign_uncertain = r2
        else:
            cols["measurement"][:, joint, offset + joint] = r1
            cols["truncation"][:, joint, offset + joint] = r2
    value, meas, trunc, second = nonlinear_rows(steps.nonlinear, windows, kernel)
    cols["value"][..., 4:6] = value
    cols["measurement"][..., 4:6] = meas
    cols["truncation"][..., 4:6] = trunc
    cols["second_order"][..., 4:6] = second
    return cols, sign_uncertain


def certified_rows(steps: CertifiedSteps, kernel, windows, tau) -> CertifiedEquation:
    """The certified equation's rows for one kernel and its windows, from the per-step stage and the logged
    torques tau (n, 4) [N m]."""
    spec = steps.spec
    R = windows.start.size
    p = len(PARAMETER_NAMES)
    joint = np.arange(N_JOINTS)
    cols, sign_uncertain = _regressor_columns(steps, kernel, windows)
    y, fp, l1 = torque_rows(tau, windows, kernel, spec.torque_timing)
    side = torque_side_terms(spec, l1)  # the timing part is checked with the model's (the truth's own torque)
    terms_b = {"torque": np.broadcast_to(side["torque"], (R, N_JOINTS)),
               "model": np.broadcast_to(up(side["model"] + side["timing"]), (R, N_JOINTS)), "rounding": fp}
    m = R * N_JOINTS
    terms = {k: np.ascontiguousarray(v).reshape(m) for k, v in terms_b.items()}
    terms.update({k: cols[k].reshape(m, p) for k in ("measurement", "truncation", "second_order", "sign")})
    D = up(up(up(terms["measurement"] + terms["truncation"]) + terms["second_order"]) + terms["sign"])
    bound = up(up(terms["torque"] + terms["model"]) + terms["rounding"])
    proven, proven_m = steps.proven, steps.proven_motion
    info = {"kernel_steps": kernel.steps, "kernel_l1": l1, "rows": m, "windows": R, "sign_uncertain_steps": int(sign_uncertain.sum()),
            "steps": int(steps.q.shape[0] - 1), "curvature_factor": CURVATURE_FACTOR,
            "encoder_boxes_proven": int(proven.sum()), "motion_boxes_proven": int(proven_m.sum()),
            "not_proven": ([f"second_order (Mnac, Ibc) on {int((~proven).sum())} of {proven.size} steps whose encoder "
                            f"box could not be verified: sampled second-derivative bounds x {CURVATURE_FACTOR:g}"]
                           if not proven.all() else [])
            + ([f"truncation (Mnac, Ibc), its second-order part on {int((~proven_m).sum())} of {proven_m.size} steps "
                f"whose motion box could not be verified: sampled second-derivative bounds x {CURVATURE_FACTOR:g}"]
               if not proven_m.all() else [])
            + (["torque between samples: within torque_error of the samples' linear interpolation (stated: no "
                "torque_rate)"] if spec.torque_timing == "sample" and spec.torque_rate is None else [])}
    return CertifiedEquation(Wc=cols["value"].reshape(m, p), D=D, y=y.reshape(m), bound=bound,
                             sample=np.repeat(windows.centre, N_JOINTS), joint=np.tile(joint, R), info=info,
                             names=PARAMETER_NAMES, terms=terms, motion=steps.motion)
