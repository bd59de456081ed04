"""Loading the H4 MJCF and reading its geometry from the compiled model."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from h4bench.portable import arcsin, atan2, matmul



def models_dir() -> Path:
    """The folder of the shipped MJCF files: ``models/`` of a source checkout, else the installed package data
    (``h4bench_models``, the same files, packaged by pyproject.toml)."""
    checkout = Path(__file__).resolve().parent.parent / "models"
    if (checkout / "h4.xml").is_file():
        return checkout
    import importlib.util

    spec = importlib.util.find_spec("h4bench.models")
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations)))
    return checkout


DEFAULT_MODEL_PATH = models_dir() / "h4.xml"
MOTOR_JOINTS = ("q1", "q2", "q3", "q4")
NACELLE_JOINTS = ("x", "y", "z", "theta")
FOREARM_RODS = ("forearm_rod1", "forearm_rod2", "forearm_rod3", "forearm_rod4")
INVWEIGHT_SCALE_NAME = "h4_invweight_scale"
LOOP_TOLERANCE = 1e-4  # [m] largest loop gap at qpos0 that load_model closes (a rounded file); more is refused
_LOOP_EXACT = 1e-12  # [m] a gap below this is left as written


class ModelError(ValueError):
    """The MJCF file is missing, does not compile, or is not an H4 as this package expects."""


def load_model(path: str | Path | None = None) -> mujoco.MjModel:
    """Compile an H4 MJCF file (default ``models/h4.xml``) into a ``mujoco.MjModel``.

    Raises :class:`ModelError` naming the path when the file is missing or MuJoCo rejects it.
    """
    path = DEFAULT_MODEL_PATH if path is None else Path(path)
    if not path.is_file():
        raise ModelError(f"model path must be an existing MJCF file, got {str(path)!r} (not found)")
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except Exception as exc:  # mujoco raises ValueError with the compiler's message
        raise ModelError(f"model path {str(path)!r} is not a valid MJCF model: {exc}") from exc
    _check_structure(model, path)
    assemble_loops(model, path)
    apply_solver_constants(model)
    return model


def assemble_loops(model: mujoco.MjModel, path="the model") -> float:
    """Close the four loops of a compiled H4 at ``qpos0`` exactly, in place; returns the largest gap found [m].

    A model written back by MuJoCo (``MjSpec.to_xml``, ``mj_saveLastXML``: 6 significant digits) leaves each
    forearm rod's far end ``rod_end_i`` up to ~1e-6 m off its nacelle point ``A_i``. When a gap is at most
    :data:`LOOP_TOLERANCE` (0.1 mm, far below any physical tolerance of the robot yet far above rounding), the
    rod frame is solved from the compiled geometry: the rod starts at the arm tip ``B_i``, its orientation is
    the smallest rotation of the written one putting its local +x axis along ``A_i - B_i``, its length
    ``|A_i - B_i|`` moves ``rod_end_i`` (and the rod's centre of mass when it sat at the rod end: the point
    mass) onto ``A_i``. A larger gap raises :class:`ModelError` naming the rod and the gap. Gaps below 1e-12 m
    are left as written (the shipped model is unchanged). Call :func:`apply_solver_constants` afterwards."""
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    worst = 0.0
    for i, name in enumerate(FOREARM_RODS):
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"{s}{i + 1}") for s in ("B", "A", "rod_end")]
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        if min(ids) < 0 or body < 0:
            continue  # H4Geometry.from_model names what is missing
        b_site, a_site, end = ids
        arm = model.body_parentid[body]
        start_gap = float(np.abs(data.xpos[body] - data.site_xpos[b_site]).max())
        end_gap = float(np.abs(data.site_xpos[end] - data.site_xpos[a_site]).max())
        worst = max(worst, start_gap, end_gap)
        if max(start_gap, end_gap) <= _LOOP_EXACT:
            continue
        if model.site_bodyid[b_site] != arm or start_gap > LOOP_TOLERANCE or end_gap > LOOP_TOLERANCE:
            raise ModelError(f"model {str(path)!r} must be assembled closed at qpos0: forearm rod {name!r} starts "
                             f"{start_gap:.3g} m from B{i + 1} and ends {end_gap:.3g} m from A{i + 1}; up to "
                             f"{LOOP_TOLERANCE:g} m (a rounded file) is closed at load, more is a different robot")
        model.body_pos[body] = model.site_pos[b_site]
        mujoco.mj_kinematics(model, data)
        arm_rot = data.xmat[arm].reshape(3, 3)
        v = matmul(arm_rot.T, data.site_xpos[a_site] - data.xpos[body])  # B -> A in the arm frame (no BLAS)
        length = float(np.sqrt(np.einsum("a,a->", v, v)))
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, model.body_quat[body])
        x0, t = rot.reshape(3, 3)[:, 0], v / length
        axis = np.cross(x0, t)
        sin, cos = float(np.sqrt(np.einsum("a,a->", axis, axis))), float(np.einsum("a,a->", x0, t))
        if sin > 0.0:
            turn, quat = np.zeros(4), np.zeros(4)
            mujoco.mju_axisAngle2Quat(turn, axis / sin, float(atan2(sin, cos)))
            mujoco.mju_mulQuat(quat, turn, model.body_quat[body])
            model.body_quat[body] = quat / np.sqrt(np.einsum("a,a->", quat, quat))
        if np.abs(model.body_ipos[body] - model.site_pos[end]).max() <= LOOP_TOLERANCE:
            model.body_ipos[body] = (length, 0.0, 0.0)
        model.site_pos[end] = (length, 0.0, 0.0)
        mujoco.mj_kinematics(model, data)
    return worst


def apply_solver_constants(model: mujoco.MjModel) -> mujoco.MjModel:
    """Recompute the model's constants (``mj_setConst`` at qpos0) and scale the constraint inverse weights of
    everything but the motors by the model's custom numeric ``h4_invweight_scale`` (models/README.md).

    MuJoCo's constraint softness is ``R = (1 - d) / d * invweight`` and ``d <= 0.9999`` in MJCF, so the
    equality rows' regulariser can only be lowered further through the inverse weights: ``body_invweight0``,
    ``tendon_invweight0`` and ``dof_invweight0`` of the non-motor joints (the motors keep theirs, so their
    friction constraints are unchanged). Idempotent: it starts from ``mj_setConst`` each time, so call it
    (instead of ``mj_setConst``) after editing a compiled model. Used by :func:`load_model` and the
    ``sim.variants`` builders. Returns ``model`` (edited in place)."""
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
    mujoco.mj_setConst(model, mujoco.MjData(model))
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, INVWEIGHT_SCALE_NAME)
    if i < 0:
        return model
    scale = float(model.numeric_data[model.numeric_adr[i]])
    if not 0.0 < scale <= 1.0:
        raise ModelError(f"custom numeric {INVWEIGHT_SCALE_NAME!r} must be in (0, 1], got {scale!r}")
    motor_dofs = [model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in MOTOR_JOINTS]
    others = np.setdiff1d(np.arange(model.nv), motor_dofs)
    model.dof_invweight0[others] *= scale
    model.body_invweight0[:] *= scale
    model.tendon_invweight0[:] *= scale
    return model


def _check_structure(model: mujoco.MjModel, path) -> None:
    names = MOTOR_JOINTS + NACELLE_JOINTS
    for name in names:
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name) < 0:
            raise ModelError(f"model {str(path)!r} must define joint {name!r} (an H4 needs joints {names})")
    for i, name in enumerate(FOREARM_RODS):
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"rod_end{i + 1}")
        if body < 0 or site < 0 or model.site_bodyid[site] != body:
            raise ModelError(f"model {str(path)!r} must define the forearm rod body {name!r} with site "
                             f"'rod_end{i + 1}' (its far end, held at A{i + 1})")
        if model.body_jntnum[body] != 2:
            raise ModelError(f"forearm rod {name!r} of model {str(path)!r} must have 2 hinges (a universal joint "
                             f"at the arm tip), got {model.body_jntnum[body]} joints")
    if model.nu != 4:
        raise ModelError(f"model {str(path)!r} must have 4 actuators (one per motor), got {model.nu}")


def _rot_z(theta: np.ndarray) -> np.ndarray:
    """(n,) angles -> (n, 3, 3) rotations about the world z axis."""
    c, s = np.cos(theta), np.sin(theta)
    out = np.zeros(theta.shape + (3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1], out[..., 2, 2] = c, -s, s, c, 1.0
    return out


@dataclass(frozen=True)
class H4Geometry:
    """The H4's geometry as compiled by MuJoCo (world frame, SI units), read at ``qpos0``.

    Chain i (i = 0..3): motor axis through ``motor_pos[i]`` along ``motor_axis[i]``; arm tip
    ``B_i(q) = P_i + L_i (cos q e_i + sin q (u_i x e_i))`` with ``e_i = arm_dir[i]`` the arm direction at q = 0;
    forearm of length ``forearm_length[i]`` from B_i to the nacelle point
    ``A_i(x) = D + Rz(theta) bar_offset[i] + attach_offset[i]`` (D = (x, y, z); the lateral bars only translate,
    so ``attach_offset`` does not rotate; ``bar_offset[i]`` is DC_k of the paper for the bar carrying chain i).
    """

    motor_pos: np.ndarray  # (4, 3) P_i [m]
    motor_axis: np.ndarray  # (4, 3) u_i unit
    arm_dir: np.ndarray  # (4, 3) e_i unit
    arm_length: np.ndarray  # (4,) L_i [m]
    forearm_length: np.ndarray  # (4,) l_i [m]
    bar_offset: np.ndarray  # (4, 3) D -> C_k(i) at theta = 0 [m]
    attach_offset: np.ndarray  # (4, 3) C_k(i) -> A_i [m]
    gravity: np.ndarray  # (3,) [m/s^2]
    q_range: np.ndarray  # (4, 2) motor joint limits [rad]
    x_home: np.ndarray  # (4,) nacelle pose of the 'home' keyframe (or qpos0) [m, m, m, rad]
    # qpos bookkeeping
    qpos_motor: np.ndarray  # (4,) qpos addresses of q1..q4
    qpos_nacelle: np.ndarray  # (4,) qpos addresses of x, y, z, theta
    qpos_lateral: np.ndarray  # (k,) qpos addresses of the lateral bar hinges
    nacelle_qpos0: np.ndarray  # (4,) qpos0 of x, y, z, theta
    nacelle_origin0: np.ndarray  # (4,) (D, theta) at qpos0
    lateral_qpos0: np.ndarray  # (k,)
    nq: int
    dof_motor: np.ndarray  # (4,) dof addresses of q1..q4
    # forearm rods: frame turned by rod_rot in the arm frame (x along the rod at qpos0), hinges a (local y)
    # then b (local z) at B_i, far end at (forearm_length, 0, 0)
    qpos_rod: np.ndarray  # (4, 2) qpos addresses of rod{i}_a, rod{i}_b
    rod_rot: np.ndarray  # (4, 3, 3) rod frame at zero hinge angles, in the arm frame
    arm_rot0: np.ndarray  # (4, 3, 3) world orientation of each arm frame at q = 0
    motor_axis_local: np.ndarray  # (4, 3) each motor axis in its arm frame

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> "H4Geometry":
        if not isinstance(model, mujoco.MjModel):
            raise TypeError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
        data = mujoco.MjData(model)
        data.qpos[:] = model.qpos0
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_tendon(model, data)

        def jid(name):
            return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)

        def sid(name):
            i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)
            if i < 0:
                raise ModelError(f"model must define site {name!r} (arm tip B_i / nacelle point A_i)")
            return i

        motor_ids = [jid(n) for n in MOTOR_JOINTS]
        nac_ids = [jid(n) for n in NACELLE_JOINTS]
        P = np.array([data.xanchor[j] for j in motor_ids])
        u = np.array([data.xaxis[j] for j in motor_ids])
        B = np.array([data.site_xpos[sid(f"B{i + 1}")] for i in range(4)])
        A = np.array([data.site_xpos[sid(f"A{i + 1}")] for i in range(4)])
        arm = B - P
        arm_perp = arm - np.sum(arm * u, axis=1, keepdims=True) * u
        if np.max(np.abs(arm - arm_perp)) > 1e-9:
            raise ModelError("each arm tip B_i must lie in the plane through the motor axis' anchor normal to it")
        L = np.linalg.norm(arm, axis=1)
        e = arm / L[:, None]
        D0 = data.xpos[model.jnt_bodyid[nac_ids[0]]].copy()
        theta_axis = data.xaxis[nac_ids[3]]
        if not np.allclose(theta_axis, [0.0, 0.0, 1.0], atol=1e-12):
            raise ModelError(f"the nacelle's theta joint must turn about the world vertical, got axis {theta_axis}")
        # which lateral bar carries A_i: the site's body; C_k = that body's origin
        lateral_bodies = [model.site_bodyid[sid(f"A{i + 1}")] for i in range(4)]
        C = np.array([data.xpos[b] for b in lateral_bodies])
        lateral_joints = []
        for b in dict.fromkeys(lateral_bodies):
            if model.body_jntnum[b] != 1:
                raise ModelError("each lateral bar must have exactly one hinge (its rotation relative to the nacelle)")
            lateral_joints.append(model.body_jntadr[b])
        rods = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n) for n in FOREARM_RODS]
        rod_end = np.array([model.site_pos[sid(f"rod_end{i + 1}")] for i in range(4)])
        rod_rot = np.zeros((4, 3, 3))
        for i, b in enumerate(rods):
            arm_body = model.jnt_bodyid[motor_ids[i]]
            axes = model.jnt_axis[model.body_jntadr[b]:model.body_jntadr[b] + 2]
            if (model.body_parentid[b] != arm_body or not np.array_equal(axes, [[0, 1, 0], [0, 0, 1]])
                    or rod_end[i, 0] <= 0 or np.any(rod_end[i, 1:] != 0)):
                raise ModelError(f"forearm rod {FOREARM_RODS[i]!r} must be a child of its arm with hinge axes (0 1 0) "
                                 f"then (0 0 1) and its far end on its local +x axis, got axes {axes.tolist()}, "
                                 f"end {rod_end[i].tolist()}")
            mat = np.zeros(9)
            mujoco.mju_quat2Mat(mat, model.body_quat[b])
            rod_rot[i] = mat.reshape(3, 3)
            if np.abs(data.xpos[b] - B[i]).max() > 1e-12:
                raise ModelError(f"forearm rod {FOREARM_RODS[i]!r} must start at the arm tip B{i + 1}")
        rod_tip = np.array([data.site_xpos[sid(f"rod_end{i + 1}")] for i in range(4)])
        if np.abs(rod_tip - A).max() > 1e-12:
            raise ModelError("the model must be assembled closed: each rod_end_i must coincide with A_i at qpos0 "
                             f"(off by {np.abs(rod_tip - A).max():.3g} m; write the rod vectors at full precision)")
        l = rod_end[:, 0].copy()
        key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
        nac_adr = np.array([model.jnt_qposadr[j] for j in nac_ids])
        qpos_home = model.key_qpos[key] if key >= 0 else model.qpos0
        nacelle_qpos0 = model.qpos0[nac_adr].copy()
        origin0 = np.concatenate([D0, [0.0]])
        x_home = origin0 + (qpos_home[nac_adr] - nacelle_qpos0)
        q_range = np.array([model.jnt_range[j] if model.jnt_limited[j] else (-np.pi, np.pi) for j in motor_ids])
        arrays = dict(
            motor_pos=P, motor_axis=u, arm_dir=e, arm_length=L, forearm_length=l,
            bar_offset=C - D0, attach_offset=A - C, gravity=model.opt.gravity.copy(), q_range=q_range,
            x_home=x_home, qpos_motor=np.array([model.jnt_qposadr[j] for j in motor_ids]),
            qpos_nacelle=nac_adr, qpos_lateral=np.array([model.jnt_qposadr[j] for j in lateral_joints]),
            nacelle_qpos0=nacelle_qpos0, nacelle_origin0=origin0,
            lateral_qpos0=np.array([model.qpos0[model.jnt_qposadr[j]] for j in lateral_joints]),
            dof_motor=np.array([model.jnt_dofadr[j] for j in motor_ids]),
            qpos_rod=np.array([[model.jnt_qposadr[model.body_jntadr[b] + k] for k in (0, 1)] for b in rods]),
            rod_rot=rod_rot, motor_axis_local=np.array([model.jnt_axis[j] for j in motor_ids]),
            arm_rot0=np.array([data.xmat[model.jnt_bodyid[j]].reshape(3, 3) for j in motor_ids]),
        )
        for v in arrays.values():
            v.setflags(write=False)
        return cls(nq=int(model.nq), **arrays)

    def qpos(self, q, x) -> np.ndarray:
        """Full MuJoCo qpos (n, nq) (or (nq,)) from motor angles q (n, 4) and nacelle pose x (n, 4)."""
        q = np.asarray(q, dtype=float)
        x = np.asarray(x, dtype=float)
        single = q.ndim == 1
        q2, x2 = np.atleast_2d(q), np.atleast_2d(x)
        out = np.zeros((q2.shape[0], self.nq))
        out[:, self.qpos_motor] = q2
        out[:, self.qpos_nacelle] = self.nacelle_qpos0 + (x2 - self.nacelle_origin0)
        dtheta = x2[:, 3] - self.nacelle_origin0[3]
        out[:, self.qpos_lateral] = self.lateral_qpos0[None, :] - dtheta[:, None]
        out[:, self.qpos_rod] = self.rod_angles(q2, x2)
        return out[0] if single else out

    def rod_angles(self, q, x) -> np.ndarray:
        """Forearm rod hinge angles (n, 4, 2) [rad] that put each rod's far end on A_i(x), arm at q (n, 4).

        In the rod's frame at zero angles the unit rod vector u = rod_rot^T R_arm(q)^T (A_i - B_i) / l must equal
        Ry(a) Rz(b) e_x = (cos a cos b, sin b, -sin a cos b): b = asin(u_y), a = atan2(-u_z, u_x). The
        universal joint is singular only at |b| = 90 deg, a rod turned square to its assembled direction."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        x = np.atleast_2d(np.asarray(x, dtype=float))
        w = nacelle_points(self, x)[0] - arm_tips(self, q)  # (n, 4, 3) world
        w = np.einsum("iba,nib->nia", self.arm_rot0, w)  # arm frame at q = 0
        k = self.motor_axis_local[None]
        c, s = np.cos(q)[..., None], np.sin(q)[..., None]
        v = w * c - s * np.cross(k, w) + (1 - c) * np.sum(k * w, axis=-1, keepdims=True) * k  # rotate by -q
        u = np.einsum("iba,nib->nia", self.rod_rot, v)
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        return np.stack([atan2(-u[..., 2], u[..., 0]), arcsin(np.clip(u[..., 1], -1.0, 1.0))], axis=-1)

    def nacelle_pose(self, qpos) -> np.ndarray:
        """Nacelle pose x (n, 4) read from MuJoCo qpos (n, nq)."""
        qpos = np.asarray(qpos, dtype=float)
        return self.nacelle_origin0 + (qpos[..., self.qpos_nacelle] - self.nacelle_qpos0)


def nacelle_points(geometry: H4Geometry, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A_i (n, 4, 3) and DC_i (n, 4, 3) for poses x (n, 4)."""
    c, s = np.cos(x[:, 3])[:, None], np.sin(x[:, 3])[:, None]
    b = geometry.bar_offset
    dc = np.empty((x.shape[0], 4, 3))
    dc[..., 0] = c * b[:, 0] - s * b[:, 1]  # Rz(theta) bar_offset_i
    dc[..., 1] = s * b[:, 0] + c * b[:, 1]
    dc[..., 2] = b[:, 2]
    a = x[:, None, :3] + dc + geometry.attach_offset[None]
    return a, dc


def arm_tips(geometry: H4Geometry, q: np.ndarray) -> np.ndarray:
    """B_i (n, 4, 3) for motor angles q (n, 4)."""
    e, f = geometry.arm_dir, np.cross(geometry.motor_axis, geometry.arm_dir)
    L = geometry.arm_length[None, :, None]
    return geometry.motor_pos[None] + L * (np.cos(q)[..., None] * e[None] + np.sin(q)[..., None] * f[None])
