"""The joint-torque regressor of a serial chain of revolute joints, batched over many evaluations.

``regressor(chain, q, qd, qdd)`` is pinocchio's ``computeJointTorqueRegressor`` (the same quantity: ``tau = Y pi``
with each body's ``pi = (m, m c, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz)``, the inertia at the joint frame's origin)
for B evaluations at once. The certified equation of a serial arm evaluates the regressor 2 + 2 n + n (n - 1) / 2 +
n (3 n + 2) + n (n + 1) / 2 times per sample step (170 for six joints: :mod:`ident.robots.serial_steps`); called one by
one from Python, pinocchio spends most of its time crossing the binding. Here a forward pass gives each body's
spatial velocity and acceleration in its own frame (gravity as the base's acceleration), the body's 6 x 10
regressor follows from them, and joint j's row of body i's block is j's motion axis, carried into frame i, against
it: about 2 500 floating-point operations per evaluation for six joints.

**Same bits everywhere.** The compiled loop (``ident/robots/_chain.cpp``, when built) and the numpy formulas
(:func:`_regressor_numpy`) evaluate the same expressions on IEEE doubles in the same order (no fused multiply-add),
from the same cosines and sines (numpy's ``cos``, ``sin``: the same bits under each CPU dispatch setting), so the
result does not depend on the build or the CPU (``tests/ident/test_chain.py``).

**Its floating-point error** is covered by the stated allowance the certified equation already grants the
regressor (:data:`ident.robots.serial_steps.PIN_REL`, relative to the magnitudes summed); the tests measure it
against the same formulas in long double and against pinocchio.

Joints: revolute about a fixed axis of the joint frame (pinocchio's ``RX``, ``RY``, ``RZ``, ``RevoluteUnaligned``),
each the child of the one before; :func:`chain_of` returns None for any other model (the caller keeps pinocchio).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["Chain", "available", "chain_of", "live_entries", "regressor"]

_AXES = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0), "JointModelRZ": (0.0, 0.0, 1.0)}
MAXJ = 32


@dataclasses.dataclass(frozen=True)
class Chain:
    """The kinematic constants of a revolute chain: per joint i the placement ``(R0[i], p0[i])`` of its frame at
    q = 0 in its parent's, its unit axis ``axis[i]`` (in its own frame), and the gravity vector ``g`` (base frame,
    m/s^2). ``IA = I - a a^T``, ``K = skew(a)``, ``AA = a a^T`` (n, 3, 3): the joint rotation is ``c IA + s K + AA``."""

    R0: np.ndarray
    p0: np.ndarray
    axis: np.ndarray
    g: np.ndarray
    IA: np.ndarray
    K: np.ndarray
    AA: np.ndarray

    @property
    def n(self) -> int:
        return self.axis.shape[0]

    @classmethod
    def from_arrays(cls, R0, p0, axis, g) -> "Chain":
        R0, p0, axis, g = (np.ascontiguousarray(x, dtype=float) for x in (R0, p0, axis, g))
        n = axis.shape[0] if axis.ndim == 2 else -1
        if not (1 <= n <= MAXJ and R0.shape == (n, 3, 3) and p0.shape == (n, 3) and axis.shape == (n, 3)
                and g.shape == (3,)):
            raise ValueError(f"R0, p0, axis, g must have shapes (n, 3, 3), (n, 3), (n, 3), (3,) with 1 <= n <= "
                             f"{MAXJ}, got {R0.shape}, {p0.shape}, {axis.shape}, {g.shape}")
        if not all(np.all(np.isfinite(x)) for x in (R0, p0, axis, g)):
            raise ValueError("R0, p0, axis, g must be finite")
        AA = axis[:, :, None] * axis[:, None, :]
        IA = np.eye(3)[None] - AA
        K = np.zeros((n, 3, 3))
        K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
        K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = axis[:, 2], -axis[:, 1], axis[:, 0]
        return cls(R0, p0, axis, g, np.ascontiguousarray(IA), K, np.ascontiguousarray(AA))


def chain_of(model) -> Chain | None:
    """The :class:`Chain` of a pinocchio model, or None when it is not a chain of revolute joints about fixed axes
    (each joint the child of the one before, one degree of freedom each)."""
    nj = model.njoints - 1
    if not 1 <= nj <= MAXJ or model.nq != nj or model.nv != nj:
        return None
    R0, p0, axis = np.empty((nj, 3, 3)), np.empty((nj, 3)), np.empty((nj, 3))
    for i in range(1, nj + 1):
        if model.parents[i] != i - 1:
            return None
        jm = model.joints[i]
        name = jm.shortname()
        if name in _AXES:
            axis[i - 1] = _AXES[name]
        elif name == "JointModelRevoluteUnaligned":
            a = np.asarray(jm.extract().axis, dtype=float)
            axis[i - 1] = a / np.sqrt(np.sum(a * a))
        else:
            return None
        M = model.jointPlacements[i]
        R0[i - 1], p0[i - 1] = np.asarray(M.rotation), np.asarray(M.translation)
    return Chain.from_arrays(R0, p0, axis, np.asarray(model.gravity.linear, dtype=float))


def _compiled():
    """The built ``_chain`` extension, or None (not built or another layout)."""
    try:
        from h4bench.ident.robots import _chain  # noqa: PLC0415
    except ImportError:
        return None
    return _chain if (_chain.LAYOUT_VERSION, _chain.MAXJ) == (2, MAXJ) else None


def available() -> bool:
    """True when the compiled loop is built (the numpy formulas give the same bits either way)."""
    return _compiled() is not None


def _states(chain: Chain, q, qd, qdd):
    arrs = []
    for x, name in ((q, "q"), (qd, "qd"), (qdd, "qdd")):
        x = np.ascontiguousarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != chain.n:
            raise ValueError(f"{name} must have shape (B, {chain.n}), got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"{name} must be finite")
        arrs.append(x)
    if not arrs[0].shape == arrs[1].shape == arrs[2].shape:
        raise ValueError(f"q, qd, qdd must have one shape, got {arrs[0].shape}, {arrs[1].shape}, {arrs[2].shape}")
    return arrs


def live_entries(n: int) -> np.ndarray:
    """The flat indices, in a joint row-major (n, 10 n) regressor, of the entries a chain can make non-zero: joint
    j's row in the columns of bodies j .. n - 1 (a body moves the joints between it and the base only), in order;
    the others are zero for every state."""
    body = np.repeat(np.arange(n), 10)
    return np.flatnonzero((np.arange(n)[:, None] <= body[None, :]).ravel())


def regressor(chain: Chain, q, qd, qdd, *, compiled: bool | None = None, packed: bool = False) -> np.ndarray:
    """(B, n, 10 n) joint-torque regressors at the states (B, n) ``q``, ``qd``, ``qdd`` (rad, rad/s, rad/s^2), or
    with ``packed`` their :func:`live_entries` only, (B, 5 n (n + 1)).

    compiled : None (the compiled loop when built), True (it, or an error), False (the numpy formulas); the same
    bits either way."""
    q, qd, qdd = _states(chain, q, qd, qdd)
    cq, sq = np.cos(q), np.sin(q)
    ext = _compiled() if compiled is not False else None
    if compiled and ext is None:
        raise RuntimeError("the compiled regressor (ident/robots/_chain.cpp) is not built")
    B, n = q.shape
    if ext is None:
        Y = _regressor_numpy(chain, cq, sq, qd, qdd)
        return Y.reshape(B, -1)[:, live_entries(n)] if packed else Y
    Y = np.empty((B, 5 * n * (n + 1))) if packed else np.zeros((B, n, 10 * n))
    args = (cq, sq, qd, qdd, chain.R0, chain.p0, chain.axis, chain.IA, chain.K, chain.AA, chain.g, Y)
    ext.regressor(B, n, bool(packed), *(a.ctypes.data for a in args))
    return Y


def _cross(a, b):
    """a x b over the last axis (size 3), each component ``a_i b_j - a_j b_i``."""
    return a[..., [1, 2, 0]] * b[..., [2, 0, 1]] - a[..., [2, 0, 1]] * b[..., [1, 2, 0]]


def _inv_linear(R, w, p, x):
    """``R^T (x + w x p)``: R (B, 3, 3), w and x (B, ..., 3) with ``...`` empty or one axis, p (3,)."""
    t = x + _cross(w, np.broadcast_to(p, w.shape))
    Rb = R if x.ndim == 2 else R[:, None]
    return Rb[..., 0, :] * t[..., 0:1] + Rb[..., 1, :] * t[..., 1:2] + Rb[..., 2, :] * t[..., 2:3]


def _inv_angular(R, w):
    Rb = R if w.ndim == 2 else R[:, None]
    return Rb[..., 0, :] * w[..., 0:1] + Rb[..., 1, :] * w[..., 1:2] + Rb[..., 2, :] * w[..., 2:3]


def _regressor_numpy(chain: Chain, cq, sq, qd, qdd, dtype=float) -> np.ndarray:
    """The compiled loop's formulas (``_chain.cpp``: ``evaluate``) on arrays over the evaluations, in its order.
    dtype : float (the same bits as the compiled loop), or np.longdouble for the tests' error estimate (then the
    inputs should be long double too)."""
    B, n = cq.shape
    cst = {k: np.asarray(getattr(chain, k), dtype=dtype) for k in ("R0", "p0", "axis", "IA", "K", "AA", "g")}
    Y = np.zeros((B, n, 10 * n), dtype=dtype)
    zero = np.zeros((B, 3), dtype=dtype)
    lv, w, dw = zero.copy(), zero.copy(), zero.copy()
    la = np.broadcast_to(-cst["g"], (B, 3)).copy()
    SL = np.zeros((B, 0, 3), dtype=dtype)
    SA = np.zeros((B, 0, 3), dtype=dtype)
    for i in range(n):
        c, s = cq[:, i, None, None], sq[:, i, None, None]
        r0, p, e = cst["R0"][i], cst["p0"][i], cst["axis"][i]
        Rj = c * cst["IA"][i] + s * cst["K"][i] + cst["AA"][i]
        R = r0[None, :, 0, None] * Rj[:, None, 0, :] + r0[None, :, 1, None] * Rj[:, None, 1, :] \
            + r0[None, :, 2, None] * Rj[:, None, 2, :]
        lv = _inv_linear(R, w, p, lv)
        w = _inv_angular(R, w)
        u = e * qd[:, i, None]
        w = w + u
        la = _inv_linear(R, dw, p, la)
        dw = _inv_angular(R, dw)
        la = la + _cross(lv, u)
        dw = (dw + _cross(w, u)) + e * qdd[:, i, None]
        if i:
            SL = _inv_linear(R, SA, p, SL)
            SA = _inv_angular(R, SA)
        SL = np.concatenate([SL, np.zeros((B, 1, 3), dtype=dtype)], axis=1)
        SA = np.concatenate([SA, np.broadcast_to(e, (B, 1, 3))], axis=1)
        b = la + _cross(w, lv)
        w0, w1, w2 = w[:, 0], w[:, 1], w[:, 2]
        d0, d1, d2 = dw[:, 0], dw[:, 1], dw[:, 2]
        ww = w0 * w0 + w1 * w1 + w2 * w2
        M3 = np.stack([np.stack([w0 * w0 - ww, w0 * w1 - d2, w0 * w2 + d1], -1),
                       np.stack([w1 * w0 + d2, w1 * w1 - ww, w1 * w2 - d0], -1),
                       np.stack([w2 * w0 - d1, w2 * w1 + d0, w2 * w2 - ww], -1)], 1)
        z = np.zeros(B, dtype=dtype)
        b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
        N3 = np.stack([np.stack([z, b2, -b1], -1), np.stack([-b2, z, b0], -1), np.stack([b1, -b0, z], -1)], 1)
        A6 = np.stack([np.stack([d0, d1 - w2 * w0, -(w2 * w1), d2 + w1 * w0, w1 * w1 - w2 * w2, w1 * w2], -1),
                       np.stack([w2 * w0, d0 + w2 * w1, d1, w2 * w2 - w0 * w0, d2 - w0 * w1, -(w0 * w2)], -1),
                       np.stack([-(w1 * w0), w0 * w0 - w1 * w1, w0 * w1, d0 - w1 * w2, d1 + w0 * w2, d2], -1)], 1)
        sl0, sl1, sl2 = SL[..., 0, None], SL[..., 1, None], SL[..., 2, None]
        sa0, sa1, sa2 = SA[..., 0, None], SA[..., 1, None], SA[..., 2, None]
        blk = Y[:, :i + 1, 10 * i:10 * i + 10]
        blk[..., 0] = (sl0 * b[:, None, 0:1] + sl1 * b[:, None, 1:2] + sl2 * b[:, None, 2:3])[..., 0]
        blk[..., 1:4] = (sl0 * M3[:, None, 0] + sl1 * M3[:, None, 1] + sl2 * M3[:, None, 2] + sa0 * N3[:, None, 0]
                         + sa1 * N3[:, None, 1] + sa2 * N3[:, None, 2])
        blk[..., 4:10] = sa0 * A6[:, None, 0] + sa1 * A6[:, None, 1] + sa2 * A6[:, None, 2]
    return Y
