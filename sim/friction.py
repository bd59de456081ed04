"""The simulated motors' friction law: where MuJoCo's friction loss equals the Coulomb term ``Fs sign(qd)``.

MuJoCo's ``frictionloss`` is a soft constraint: per motor row its force ``f`` lies in ``[-Fs, Fs]`` and solves
the regularised problem with the reference acceleration ``a_ref = -b qd`` (``b = 2 / (d_max timeconst)`` from
``solreffriction``, ``solimpfriction``) and regulariser ``R``. Its optimality conditions, per row, with ``a``
the joint's resulting acceleration:

* ``f`` inside ``(-Fs, Fs)`` only where ``a + b qd = -R f`` (the constraint holds the joint: soft stiction);
* ``f = -Fs`` (Coulomb's value for ``qd > 0``) whenever ``a + b qd > R Fs``, ``f = +Fs`` whenever
  ``a + b qd < -R Fs``.

So the force is Coulomb's ``-Fs sign(qd)`` wherever ``b |qd| >= |a| + R Fs``, in particular wherever
``|qd| >= (qdd_max + R Fs_max) / b`` (:func:`friction_band`); nearer rest, while the joint decelerates faster
than ``b |qd|``, it can be anywhere in ``[-Fs, Fs]``, also of the opposite sign (the joint is braked by the
constraint before its speed reaches zero). A reversal at 800 rad/s^2 spends about 2 ms there; the derived
equation treats those steps like the steps through rest (``ErrorSpec.friction_band``).
"""

from __future__ import annotations

import mujoco
import numpy as np

from h4bench.sim.model import MOTOR_JOINTS

__all__ = ["friction_band", "soft_friction"]


def soft_friction(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """``(b, R)`` (4,) each of the motors' friction-loss rows as MuJoCo builds them for this model: the reference
    damping ``b`` [1/s] (``efc_KBIP[:, 1]``) and the regulariser ``R`` [rad/s^2 per N m] (``efc_R``), read from
    ``mj_forward`` at the model's reference pose (both depend on the model's constants only)."""
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    mujoco.mj_forward(model, data)
    rows = np.flatnonzero(np.asarray(data.efc_type) == int(mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF))
    dof_of_row = {int(data.efc_id[r]): r for r in rows}
    b, R = np.empty(len(MOTOR_JOINTS)), np.empty(len(MOTOR_JOINTS))
    for i, name in enumerate(MOTOR_JOINTS):
        dof = int(model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)])
        if dof not in dof_of_row:
            raise ValueError(f"motor joint {name} has no friction-loss row (frictionloss must be > 0 for the "
                             "friction law this module describes)")
        r = dof_of_row[dof]
        b[i], R[i] = float(data.efc_KBIP[r, 1]), float(data.efc_R[r])
    return b, R


def friction_band(model: mujoco.MjModel, qdd_max, fs_max) -> np.ndarray:
    """(4,) the speed [rad/s] above which the simulated friction is Coulomb's ``-Fs sign(qd)`` (module
    docstring): ``(qdd_max + R fs_max) / b``, rounded up; qdd_max (4,) a bound on the true ``|qdd|`` [rad/s^2],
    fs_max (4,) a bound on the friction loss ``Fs`` [N m] (e.g. the prior's upper bound)."""
    b, R = soft_friction(model)
    qdd_max = np.broadcast_to(np.asarray(qdd_max, dtype=float), b.shape)
    fs_max = np.broadcast_to(np.asarray(fs_max, dtype=float), b.shape)
    if np.any(~np.isfinite(qdd_max)) or np.any(qdd_max < 0) or np.any(~np.isfinite(fs_max)) or np.any(fs_max < 0):
        raise ValueError(f"qdd_max and fs_max must be finite and >= 0, got {qdd_max.tolist()} and {fs_max.tolist()}")
    num = np.nextafter(qdd_max + np.nextafter(R * fs_max, np.inf), np.inf)
    return np.nextafter(num / b, np.inf)
