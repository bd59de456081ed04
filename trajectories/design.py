"""The coefficient optimisation behind :func:`trajectories.fourier_excitation`: objective, constraints and their
gradients on a coarse time grid.

Variables: z (2 H 4,), the Fourier coefficients (a, b) divided by a per-axis scale. At every grid sample the
reference inputs ``u = (x, xd, xdd)`` (12 numbers; (q, qd, qdd) in joint space) are linear in z,
``u = u0 + B z``, with B known in closed form from the phase schedule. Everything else is a per-sample function
``y(u)`` (motor angles, speeds, accelerations, IK reach, cond(Jx) and the regressor's nacelle columns), so the
gradient needs only the 12 partial derivatives dy/du per sample (forward differences, one batched call on 13 n
samples) and the chain rule ``dy/dz = dy/du B``: 13 evaluations per sample instead of 2 H 4 + 1 = 41.

Objective: ``log cond(W diag(theta))`` (singular values by one-sided Jacobi rotations,
:func:`h4bench.portable.jacobi_svd`; its gradient from the extreme right singular vectors v, the eigenvectors of
the Gram matrix: ``d lambda = 2 (W v) . (dW v)``), with tanh(qd / SIGN_WIDTH) for sign(qd) in the Coulomb columns.
Constraints: for each limit and joint/axis, the largest normalised violation over the grid (<= 0 satisfied;
gradient at the worst sample); SLSQP.
"""

from __future__ import annotations

import os
import pickle
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.optimize import OptimizeResult, minimize

from h4bench import sim
from h4bench.blas import one_blas_thread
from h4bench.portable import arccos, atan2, det4, jacobi_svd, log, solve4, tanh

#: The optimiser's Coulomb columns use tanh(qd / SIGN_WIDTH) for sign(qd) [rad/s]: sign has no derivative
#: (a finite-difference step across qd = 0 would jump); samples that slow are excluded or given an interval
#: sign in the identification anyway (ident.regressor's note). Constraints use the true sign.
SIGN_WIDTH = 0.05
#: Forward-difference steps on x, xd, xdd (or q, qd, qdd) per sample.
FD_STEP = np.repeat([1e-7, 1e-6, 1e-5], 4)
#: The optimiser's iterates are evaluated on a fixed grid: the criterion, the constraints and their gradients
#: are computed at z rounded to a multiple of SNAP (2^-24, about 6e-8 of the O(1) scaled coefficients; exact in
#: binary) and the result is rounded too, so that a last-bit difference of SLSQP's own steps changes nothing
#: unless it straddles a grid boundary. Those steps call scipy's BLAS and LAPACK, so they run on one OpenBLAS
#: kernel and one thread wherever that can be forced (:meth:`CoefficientProblem.optimise`): measured, a design
#: on one thread still differed between the Haswell and SandyBridge kernels (seed 7, 4 s) before that. Everything
#: computed at a point is itself BLAS-free (:mod:`h4bench.portable`).
SNAP = 2.0 ** -24
CONSTRAINT_NAMES = tuple(f"{c}:{i}" for c, n in (("x_upper", 4), ("x_lower", 4), ("q_upper", 4), ("q_lower", 4),
                                                 ("reach", 4), ("cond_jx", 1), ("qd", 4), ("qdd", 4), ("tau", 4))
                         for i in range(n))
# per-sample outputs y: columns of the (N, 29) array
_X, _Q, _QD, _QDD, _RATIO, _MNAC, _IBC, _CONDJX = (slice(0, 4), slice(4, 8), slice(8, 12), slice(12, 16),
                                                    slice(16, 20), slice(20, 24), slice(24, 28), slice(28, 29))


def snap(z) -> np.ndarray:
    """z (nz,) rounded to the nearest multiple of :data:`SNAP` (exact: a power-of-two scaling and a rounding)."""
    return np.round(np.asarray(z, float) / SNAP) * SNAP


def _cross(a, b):
    """Cross product over the last axis (3,), written out (faster than np.cross on small trailing axes)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def fast_motion(geometry, x, xd, xdd) -> dict:
    """Joint motion and the regressor's nacelle columns for many samples (each input (N, 4)), with no batched
    4x4 inverse but one solve for ``J^T``: the optimiser's fast path of ``sim`` and ``ident`` (tests compare).

    Same maths as ``sim.kinematics``: IK of each chain; ``Jx`` rows ``[AB, (DC x AB)_z]``, ``Jq = u . (PB x AB)``,
    differentiated row by row: ``Jx_i xd = Jq_i qd_i`` gives ``qd_i = Jx_i xd / Jq_i`` and
    ``qdd_i = (Jx_i xdd + Jxd_i xd - Jqd_i qd_i) / Jq_i``. Returns q, qd, qdd, the reach ratio |c/rho|, Jx and
    the Mnac and Ibc columns of ``ident.regressor``: ``J[:3]^T (xdd - G)`` and ``J[3] xdd_theta``, with
    ``J^T v = Jq * (Jx^-T v)``.
    """
    g = geometry
    c, s = np.cos(x[:, 3])[:, None], np.sin(x[:, 3])[:, None]
    bo = g.bar_offset[None]
    dc = np.stack([c * bo[..., 0] - s * bo[..., 1], s * bo[..., 0] + c * bo[..., 1],
                   np.broadcast_to(bo[..., 2], c.shape[:1] + (4,))], axis=-1)  # (N, 4, 3)
    a_pts = x[:, None, :3] + dc + g.attach_offset[None]
    e, u = g.arm_dir[None], g.motor_axis[None]
    f = np.cross(g.motor_axis, g.arm_dir)[None]
    w = a_pts - g.motor_pos[None]
    ca, cb = np.sum(w * e, axis=-1), np.sum(w * f, axis=-1)
    L, lf = g.arm_length[None], g.forearm_length[None]
    ratio = (L**2 + np.sum(w * w, axis=-1) - lf**2) / (2.0 * L) / np.hypot(ca, cb)
    q = atan2(cb, ca) - arccos(np.clip(ratio, -1.0, 1.0))
    q = (q + np.pi) % (2.0 * np.pi) - np.pi
    pb = L[..., None] * (np.cos(q)[..., None] * e + np.sin(q)[..., None] * f)
    ab = g.motor_pos[None] + pb - a_pts
    jx = np.concatenate([ab, (dc[..., 0] * ab[..., 1] - dc[..., 1] * ab[..., 0])[..., None]], axis=-1)
    jq = np.sum(u * _cross(pb, ab), axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        qd = np.sum(jx * xd[:, None], axis=-1) / jq
        bd = _cross(np.broadcast_to(u, pb.shape), pb) * qd[..., None]
        dcd = np.stack([-dc[..., 1], dc[..., 0], np.zeros_like(dc[..., 0])], axis=-1) * xd[:, 3, None, None]
        abd = bd - xd[:, None, :3] - dcd
        jxd = np.concatenate([abd, (dcd[..., 0] * ab[..., 1] + dc[..., 0] * abd[..., 1] - dcd[..., 1] * ab[..., 0]
                                    - dc[..., 1] * abd[..., 0])[..., None]], axis=-1)
        jqd = np.sum(u * (_cross(bd, ab) + _cross(pb, abd)), axis=-1)
        qdd = (np.sum(jx * xdd[:, None], axis=-1) + np.sum(jxd * xd[:, None], axis=-1) - jqd * qd) / jq
        rhs = np.zeros(x.shape[:1] + (4, 2))
        rhs[:, :3, 0] = xdd[:, :3] - g.gravity[None]
        rhs[:, 3, 1] = xdd[:, 3]
        ok = np.all(np.isfinite(jx), axis=(1, 2)) & (np.abs(det4(jx)) > 1e-12)
        y = np.full_like(rhs, np.nan)
        y[ok] = solve4(np.swapaxes(jx[ok], 1, 2), rhs[ok])
        jtv = jq[..., None] * y
    return {"q": q, "qd": qd, "qdd": qdd, "ratio": np.abs(ratio), "Jx": jx, "mnac": jtv[..., 0],
            "ibc": jtv[..., 1]}


def grid_regressor(y, coulomb) -> np.ndarray:
    """(4n, 14) the paper's regressor on the design grid (rows 4k + i) from the grid's joint motion ``y``
    (n, ., 4) and the Coulomb columns' values ``coulomb`` (n, 4) (the sign, or its smooth stand-in)."""
    n = y.shape[0]
    W = np.zeros((n, 4, 14))
    eye = np.eye(4)[None]
    W[..., 0:4] = eye * y[:, _QDD, None]
    W[..., 4], W[..., 5] = y[:, _MNAC], y[:, _IBC]
    W[..., 6:10] = eye * y[:, _QD, None]
    W[..., 10:14] = eye * np.asarray(coulomb)[:, :, None]
    return W.reshape(4 * n, 14)


class CoefficientProblem:
    """Objective and constraints of the coefficient vector z on a coarse grid (see the module docstring).

    basis : ((n, H), (n, H)) x3, the sin/cos basis of P, dP/dphi, d2P/dphi2 on the grid; phid, phidd : (n,)
    phase speed and acceleration; scale : (4,) per-axis coefficient scale; centre : (4,) path origin.
    Limits are multiplied by ``design_factor`` (the box and joint range shrunk about their middle).
    """

    def __init__(self, geometry, space, centre, basis, phid, phidd, scale, limits, theta, design_factor):
        self.geometry, self.space, self.theta = geometry, space, np.asarray(theta, float)
        self.centre, self.scale = np.asarray(centre, float), np.asarray(scale, float)
        n, H = basis[0][0].shape
        self.n, self.H = n, H
        # B (n, 12, 2 H 4): d(pos, vel, acc)/dz; z index = ((ab * H) + h) * 4 + axis
        pos, d1, d2 = (np.stack([ba, bb], axis=1) for ba, bb in basis)  # (n, 2, H) each
        vel = d1 * phid[:, None, None]
        acc = d2 * (phid**2)[:, None, None] + d1 * phidd[:, None, None]
        B = np.zeros((n, 3, 4, 2, H, 4))
        for axis in range(4):
            for k, arr in enumerate((pos, vel, acc)):
                B[:, k, axis, :, :, axis] = arr * self.scale[axis]
        self.B = B.reshape(n, 12, 2 * H * 4)
        self.u0 = np.concatenate([self.centre, np.zeros(8)])
        mid = 0.5 * (np.asarray(limits.x_lower) + np.asarray(limits.x_upper))
        half = 0.5 * (np.asarray(limits.x_upper) - np.asarray(limits.x_lower))
        self.box = (mid - design_factor * half, mid + design_factor * half, half)
        q_lo, q_hi = limits.q_bounds(geometry)
        q_mid, q_half = 0.5 * (q_lo + q_hi), 0.5 * (q_hi - q_lo)
        self.qbox = (q_mid - design_factor * q_half, q_mid + design_factor * q_half, q_half)
        self.cond_max = design_factor * limits.max_cond_jx
        self.vmax = design_factor * np.asarray(limits.qd_max)
        self.amax = design_factor * np.asarray(limits.qdd_max)
        self.tmax = design_factor * limits.tau_allowed
        self._cache = None

    @property
    def size(self) -> int:
        return self.B.shape[2]

    def inputs(self, z) -> np.ndarray:
        """u (n, 12) = (pos, vel, acc) in the design space."""
        return self.u0[None] + np.einsum("nkz,z->nk", self.B, np.asarray(z, float))

    def outputs(self, U, cond_jx=True) -> np.ndarray:
        """y (N, 29) per sample: x, q, qd, qdd, reach ratio, Mnac column, Ibc column, cond(Jx) (NaN unless
        ``cond_jx``: batched 4x4 eigenvalue problems are the costliest step). Raises sim.KinematicsError in joint
        space when the forward kinematics fail."""
        if self.space == "joint":
            x = sim.forward_kinematics(self.geometry, U[:, :4])
            _, xd, xdd = sim.cartesian_motion(self.geometry, U[:, :4], U[:, 4:8], U[:, 8:], x=x)
        else:
            x, xd, xdd = U[:, :4], U[:, 4:8], U[:, 8:]
        m = fast_motion(self.geometry, x, xd, xdd)
        cond = np.full((x.shape[0], 1), np.nan)
        if cond_jx:
            jx = np.where(np.isfinite(m["Jx"]), m["Jx"], 0.0)
            sv = jacobi_svd(jx)  # descending
            with np.errstate(invalid="ignore", divide="ignore"):
                cond[:, 0] = sv[:, 0] / sv[:, -1]
        return np.concatenate([x, m["q"], m["qd"], m["qdd"], m["ratio"], m["mnac"], m["ibc"], cond], axis=1)

    def _regressor_times(self, y, v):
        """(W diag(theta)) v per sample and joint (n, 4) for a (14,) vector v, from outputs y (n, 29)."""
        th = self.theta
        return (th[0:4] * v[0:4] * y[:, _QDD] + th[4] * v[4] * y[:, _MNAC] + th[5] * v[5] * y[:, _IBC]
                + th[6:10] * v[6:10] * y[:, _QD] + th[10:14] * v[10:14] * tanh(y[:, _QD] / SIGN_WIDTH))

    def _scaled_regressor(self, y):
        return grid_regressor(y, tanh(y[:, _QD] / SIGN_WIDTH)) * self.theta[None]

    def _violations(self, y):
        """Normalised violations (n, 33) per sample (<= 0 satisfied), in CONSTRAINT_NAMES order."""
        lo, hi, half = self.box
        qlo, qhi, qhalf = self.qbox
        x, q, qd, qdd = y[:, _X], y[:, _Q], y[:, _QD], y[:, _QDD]
        tau = self._torque(y)
        return np.concatenate([
            (x - hi) / half, (lo - x) / half, (q - qhi) / qhalf, (qlo - q) / qhalf,
            20.0 * (y[:, _RATIO] - 0.995), y[:, _CONDJX] / self.cond_max - 1.0,
            np.abs(qd) / self.vmax - 1.0, np.abs(qdd) / self.amax - 1.0, np.abs(tau) / self.tmax - 1.0,
        ], axis=1)

    def _torque(self, y):
        th = self.theta
        return (th[0:4] * y[:, _QDD] + th[4] * y[:, _MNAC] + th[5] * y[:, _IBC] + th[6:10] * y[:, _QD]
                + th[10:14] * np.sign(y[:, _QD]))

    def _violation_derivatives(self, y, dy):
        """d(violations)/dz (n, 33, nz) from y (n, 29) and dy/dz (n, 29, nz) (sign(qd) held constant)."""
        _, _, half = self.box
        qhalf = self.qbox[2]
        th = self.theta
        dtau = (th[0:4, None] * dy[:, _QDD] + th[4] * dy[:, _MNAC] + th[5] * dy[:, _IBC]
                + th[6:10, None] * dy[:, _QD])
        s = lambda a: np.sign(a)[..., None]  # noqa: E731
        return np.concatenate([
            dy[:, _X] / half[:, None], -dy[:, _X] / half[:, None], dy[:, _Q] / qhalf[:, None],
            -dy[:, _Q] / qhalf[:, None], 20.0 * dy[:, _RATIO], dy[:, _CONDJX] / self.cond_max,
            s(y[:, _QD]) * dy[:, _QD] / self.vmax[:, None], s(y[:, _QDD]) * dy[:, _QDD] / self.amax[:, None],
            s(self._torque(y)) * dtau / self.tmax[:, None],
        ], axis=1)

    def evaluate(self, z, gradient=False, with_objective=True):
        """The criterion (:meth:`objective`), constraint values (33,) (max over the grid, <= 0 satisfied) and,
        with ``gradient``, their derivatives (nz,) and (33, nz). Non-finite designs give criterion = inf.
        ``with_objective=False`` (no gradient) skips the criterion and returns 0.0 in its place."""
        z = np.asarray(z, float)
        U = self.inputs(z)
        n = self.n
        try:
            y = self.outputs(U)
            if gradient:
                # cond(Jx)'s derivative only matters near its limit: elsewhere it is held constant
                near = np.nanmax(y[:, _CONDJX], initial=0.0) >= 0.8 * self.cond_max
                Up = (U[None] + np.diag(FD_STEP)[:, None, :]).reshape(-1, 12)
                Y = np.concatenate([y[None], self.outputs(Up, cond_jx=near).reshape(12, n, -1)], axis=0)
                if not near:
                    Y[1:, :, _CONDJX] = y[None, :, _CONDJX]
        except sim.KinematicsError:
            return self._failed(gradient)
        if not np.all(np.isfinite(y)):
            return self._failed(gradient)
        viol = self._violations(y)
        worst = np.argmax(viol, axis=0)
        cons = viol[worst, np.arange(viol.shape[1])]
        if not with_objective and not gradient:
            return 0.0, cons
        dy = None
        if gradient:
            dy_du = (Y[1:] - y[None]) / FD_STEP[:, None, None]  # (12, n, 29)
            if not np.all(np.isfinite(dy_du)):
                return self._failed(gradient)
            dy = np.einsum("kny,nkz->nyz", dy_du, self.B)  # (n, 29, nz)
        objective = self.objective(y, dy)
        if objective is None:
            return self._failed(gradient)
        if not gradient:
            return objective[0], cons
        value, grad = objective
        dviol = self._violation_derivatives(y[worst], dy[worst])  # (33 worst samples, 33, nz)
        dcons = dviol[np.arange(worst.size), np.arange(worst.size)]
        return value, cons, grad, dcons

    def objective(self, y, dy=None):
        """The design criterion from the grid outputs y (n, 29) and, if given, dy/dz (n, 29, nz): returns
        (value, gradient (nz,) or None), or None when the design is degenerate. Here log cond(W diag(theta));
        subclasses override it (:class:`trajectories.bounded.HalfwidthProblem`)."""
        Ws = self._scaled_regressor(y)
        sv, vec = jacobi_svd(Ws, vectors=True)  # descending; Ws^T Ws = V diag(sv^2) V^T
        lam, vec = sv[::-1] ** 2, vec[:, ::-1]  # ascending, as eigh's
        if lam[0] <= 0:
            return None
        log_cond = 0.5 * float(log(lam[-1] / lam[0]))
        if dy is None:
            return log_cond, None
        grad = np.zeros(self.size)
        th = self.theta
        tanh_d = (1.0 - tanh(y[:, _QD] / SIGN_WIDTH) ** 2) / SIGN_WIDTH
        for idx, lam_i, sign in ((-1, lam[-1], 1.0), (0, lam[0], -1.0)):
            v = vec[:, idx]
            r = self._regressor_times(y, v)  # (n, 4)
            dr = (th[0:4, None] * v[0:4, None] * dy[:, _QDD] + th[4] * v[4] * dy[:, _MNAC]
                  + th[5] * v[5] * dy[:, _IBC]
                  + (th[6:10] * v[6:10])[:, None] * dy[:, _QD]
                  + (th[10:14] * v[10:14])[:, None] * tanh_d[..., None] * dy[:, _QD])
            grad += sign * 0.5 * 2.0 * np.einsum("ni,nij->j", r, dr) / lam_i
        return log_cond, grad

    def _failed(self, gradient):
        cons = np.full(len(CONSTRAINT_NAMES), np.inf)
        return (np.inf, cons) if not gradient else (np.inf, cons, np.zeros(self.size),
                                                    np.zeros((cons.size, self.size)))

    def log_cond(self, z) -> float:
        return float(self.evaluate(z)[0])

    def feasible(self, z) -> bool:
        value, cons = self.evaluate(z, with_objective=False)
        return bool(np.isfinite(value) and np.all(cons <= 0.0))

    def largest_feasible_scale(self, z, s_max=4.0, steps=30) -> float:
        """Largest s in [0, s_max] (bisection, to 1e-3 relative) with s z feasible; 0 if none is found."""
        if self.feasible(s_max * z):
            return s_max
        lo, hi = 0.0, s_max
        for _ in range(steps):
            mid = 0.5 * (lo + hi)
            if self.feasible(mid * z):
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-3 * hi:
                break
        return lo

    def _memo(self, z):
        z = snap(z)  # the same points on every machine (SNAP)
        if self._cache is None or not np.array_equal(self._cache[0], z):
            log_cond, cons, grad, dcons = self.evaluate(z, gradient=True)
            if not np.isfinite(log_cond):  # steer SLSQP back: a large objective, constraints violated
                log_cond, cons = 1e3, np.where(np.isfinite(cons), cons, 1e3)
            self._cache = (np.array(z, copy=True), log_cond, grad, cons, dcons)
        return self._cache[1:]

    def __getstate__(self) -> dict:
        """Pickled without the evaluation memo and the LP warm start (HiGHS bases): for :meth:`optimise`'s
        process, which starts both afresh."""
        state = dict(self.__dict__)
        state["_cache"] = None
        for key in ("last", "_last_keep"):
            if key in state:
                state[key] = None
        return state

    def _slsqp(self, z0, max_iter: int):
        """SLSQP from z0 in this process (see :meth:`optimise`)."""
        self._cache = None
        with one_blas_thread():  # SLSQP's own BLAS calls: no thread-count dependence (h4bench.blas)
            res = minimize(lambda z: self._memo(z)[0], z0, jac=lambda z: self._memo(z)[1], method="SLSQP",
                           options={"maxiter": max_iter, "ftol": 1e-4},
                           constraints=[{"type": "ineq", "fun": lambda z: -self._memo(z)[2],
                                         "jac": lambda z: -self._memo(z)[3]}])
        res.x = snap(res.x)
        return res

    def optimise(self, z0, max_iter: int):
        """SLSQP from z0: minimise the criterion subject to every constraint value <= 0 (scipy: -cons >= 0);
        the criterion, constraints and gradients are evaluated at :func:`snap` (z), and the result's ``x`` is
        snapped too. Returns scipy's OptimizeResult (``x``, ``nit``, ``nfev``, ``message``).

        SLSQP's own steps call scipy's BLAS and LAPACK, whose kernel OpenBLAS picks by CPU: on x86-64 the
        optimisation runs in a child process whose OpenBLAS is forced to one kernel and one thread
        (:data:`SLSQP_ENVIRONMENT`), so that every machine takes the same steps (elsewhere, or with
        ``H4BENCH_SLSQP_IN_PROCESS=1``, in this process on its own kernel, one thread)."""
        if platform.machine().lower() not in ("x86_64", "amd64") or os.environ.get("H4BENCH_SLSQP_IN_PROCESS") == "1":
            return self._slsqp(z0, max_iter)
        with tempfile.TemporaryDirectory(prefix="h4bench-slsqp-") as tmp:
            task, answer = Path(tmp) / "task.pkl", Path(tmp) / "result.pkl"
            task.write_bytes(pickle.dumps((self, np.asarray(z0, float), int(max_iter))))
            env = dict(os.environ, **SLSQP_ENVIRONMENT)
            done = subprocess.run([sys.executable, "-c", _CHILD, str(task), str(answer)], env=env,
                                  capture_output=True, text=True)
            if done.returncode != 0:
                raise RuntimeError(f"the design's optimiser process failed ({done.returncode}): "
                                   f"{done.stderr.strip()[-2000:]}")
            x, nit, nfev, message = pickle.loads(answer.read_bytes())
        self._cache = None
        return OptimizeResult(x=x, nit=nit, nfev=nfev, message=message)


#: The environment of :meth:`CoefficientProblem.optimise`'s process: OpenBLAS's Nehalem kernel (SSE4.2, which
#: numpy 2 already requires of an x86-64 CPU) and one thread, whatever the CPU and the caller's environment.
SLSQP_ENVIRONMENT = {"OPENBLAS_CORETYPE": "Nehalem", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                     "OPENBLAS_L2_SIZE": "262144", "H4BENCH_SLSQP_IN_PROCESS": "1"}
_CHILD = ("import pickle, sys\n"
          "from h4bench.trajectories.design import optimise_task\n"
          "optimise_task(sys.argv[1], sys.argv[2])\n")


def optimise_task(task: str, answer: str) -> None:
    """The body of :meth:`CoefficientProblem.optimise`'s process: unpickle (problem, z0, max_iter) from the file
    ``task``, run SLSQP, pickle (x, nit, nfev, message) into the file ``answer``."""
    prob, z0, max_iter = pickle.loads(Path(task).read_bytes())
    res = prob._slsqp(z0, max_iter)
    Path(answer).write_bytes(pickle.dumps((np.asarray(res.x, float), int(res.nit), int(res.nfev), str(res.message))))
