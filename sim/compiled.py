"""The sample loop of :func:`sim.simulate` in compiled code (``sim/_loop.cpp``), when it is built and applies.

The compiled loop is the Python loop (:func:`sim.simulate._loop` with :class:`sim.simulate._FloatLaw` and the
noise streams' ``at_list``) operation for operation on IEEE doubles in the same order: both give the same bits
(``tests/sim/test_compiled_loop.py``). It applies to the built-in law (:class:`~sim.controller.JointController`
and :class:`~sim.controller.VelocityFilter`) with a stream that describes itself by ``compiled_terms()`` (a
precomputed part, q-dependent ripple harmonics and command-proportional gain errors: :class:`~sim.noise.ErrorStream`
and :class:`~sim.noise.PrecomputedTorqueError`); anything else (another controller, a stream of its own) runs the
Python loop. ``H4BENCH_PURE_PYTHON=1`` in the environment forces the Python loop; :func:`available` says whether
the extension was built (an install without a C++ compiler skips it: the results are the same, only slower).

MuJoCo's functions are taken from the library the bindings loaded (``libmujoco`` beside the ``mujoco`` package),
the model and data by their addresses; no MuJoCo header is compiled in. A MuJoCo error inside the compiled calls
comes back as :class:`~sim.validation.SimulationError` (the legacy ``mju_user_error`` handler is swapped for the
duration of each chunk), never as the end of the process.
"""

from __future__ import annotations

import ctypes
import functools
import os
from pathlib import Path

import mujoco
import numpy as np

from h4bench.sim.validation import N_JOINTS, SimulationError

__all__ = ["available", "compiled_loop"]

_CHUNK = 1000  # samples per call: progress, and a KeyboardInterrupt, are seen between chunks

_PTRS = ("model", "data", "forward", "first", "step", "user_error", "qpos", "qvel", "qacc", "ctrl", "act", "efc_pos",
         "q_ref", "qd_ref", "ff", "pre", "ripple", "gain", "rec_qpos", "rec_qvel", "rec_qacc", "rec_app", "efc",
         "rec_cmd", "rec_qm", "state", "out")
_NDBL = 3 + 6 * N_JOINTS
_NSTATE = 5 * N_JOINTS + 1
_NINT = 16


@functools.cache
def _extension():
    """The built extension (None when it is missing or its layout differs from this module's)."""
    try:
        from h4bench.sim import _loop  # noqa: PLC0415
    except ImportError:
        return None
    if (_loop.LAYOUT_VERSION, _loop.NPTR, _loop.NINT, _loop.NDBL, _loop.NSTATE) != (1, len(_PTRS), _NINT, _NDBL,
                                                                                   _NSTATE):
        return None
    return _loop


@functools.cache
def _library():
    """(ctypes library, {name: address}) of the MuJoCo library the bindings use, or None if not found."""
    folder = Path(mujoco.__file__).resolve().parent
    candidates = sorted(folder.glob("libmujoco.so*")) + sorted(folder.glob("libmujoco*.dylib"))
    if not candidates:
        return None
    try:
        lib = ctypes.CDLL(str(candidates[0]))
        names = ("mj_forward", "mj_step", "mj_RungeKutta", "mj_Euler", "mj_implicit", "mju_error")
        addresses = {n: ctypes.cast(getattr(lib, n), ctypes.c_void_p).value for n in names}
        addresses["mju_user_error"] = ctypes.addressof(ctypes.c_void_p.in_dll(lib, "mju_user_error"))
    except (OSError, AttributeError, ValueError):
        return None
    return lib, addresses


def available() -> bool:
    """Whether the compiled loop can run here (built, and MuJoCo's library found)."""
    return _extension() is not None and _library() is not None


def _first_step(model: mujoco.MjModel):
    """(address name, kind) of the integrator's first step after ``mj_forward`` (kind 0: ``f(m, d, 4)``)."""
    integ = mujoco.mjtIntegrator(model.opt.integrator)
    return {mujoco.mjtIntegrator.mjINT_RK4: ("mj_RungeKutta", 0),
            mujoco.mjtIntegrator.mjINT_EULER: ("mj_Euler", 1),
            mujoco.mjtIntegrator.mjINT_IMPLICIT: ("mj_implicit", 1),
            mujoco.mjtIntegrator.mjINT_IMPLICITFAST: ("mj_implicit", 1)}.get(integ)


def _c_array(x, shape, name: str) -> np.ndarray:
    arr = np.ascontiguousarray(x, dtype=np.float64)
    if arr.shape != shape:
        raise SimulationError(f"{name} must have shape {shape} for the compiled loop, got {arr.shape}")
    return arr


def _view_address(arr: np.ndarray, length: int, name: str) -> int:
    """The address of one of MjData's own arrays (a contiguous float64 view of at least ``length`` values)."""
    if arr.dtype != np.float64 or not arr.flags.c_contiguous or arr.size < length:
        raise SimulationError(f"MjData.{name} is not a contiguous float64 array of {length} values")
    return arr.ctypes.data


def compiled_loop(law, stream, model, data, qm, n, substeps, efc_pos, records, progress):
    """Run samples [0, n) in compiled code if it applies; returns False (nothing done) when it does not.

    law : the simulator's :class:`~sim.simulate._FloatLaw` (its state is read here and written back into it);
    stream : the torque-error stream; qm : the motor angles' addresses in qpos (slice or array); substeps : MuJoCo
    steps per sample; efc_pos : the view of ``data.efc_pos`` the Python loop reads; records : the
    simulator's arrays ``rec_qpos, rec_qvel, rec_qacc, rec_app, efc, rec_cmd, rec_qm`` (filled here);
    progress : callable(k, n) or None. Raises SimulationError (diverged, MuJoCo error) or the stream's own error
    (a sample its checks refuse, raised by its ``at_list`` on that sample)."""
    if os.environ.get("H4BENCH_PURE_PYTHON") or not available():
        return False
    terms = getattr(stream, "compiled_terms", None)
    terms = terms() if callable(terms) else None
    first = _first_step(model)
    if terms is None or first is None or model.nu != N_JOINTS or not (hasattr(model, "_address")
                                                                       and hasattr(data, "_address")):
        return False
    ext = _extension()
    _, fn = _library()
    qm_idx = np.arange(model.nq)[qm].astype(np.int64)
    if qm_idx.shape != (N_JOINTS,):
        return False

    rec_qpos, rec_qvel, rec_qacc, rec_app, efc, rec_cmd, rec_qm = records
    nq, nv, ne = model.nq, model.nv, int(data.ne)
    for arr, shape, name in ((rec_qpos, (n, nq), "rec_qpos"), (rec_qvel, (n, nv), "rec_qvel"),
                             (rec_qacc, (n, nv), "rec_qacc"), (rec_app, (n, N_JOINTS), "rec_app"),
                             (rec_cmd, (n, N_JOINTS), "rec_cmd"), (rec_qm, (n, N_JOINTS), "rec_qm")):
        if arr.shape != shape or arr.dtype != np.float64 or not arr.flags.c_contiguous:
            raise SimulationError(f"{name} must be a contiguous float64 array of shape {shape}")
    if efc.ndim != 2 or efc.shape[0] != n or efc.shape[1] < ne or not efc.flags.c_contiguous:
        raise SimulationError(f"efc must be a contiguous (n, >= {ne}) float64 array")

    keep = []  # every buffer whose address is passed, alive until the loop ends

    def addr(arr):
        keep.append(arr)
        return arr.ctypes.data

    q_ref = _c_array(law.q_ref, (n, N_JOINTS), "q_ref")
    qd_ref = _c_array(law.qd_ref, (n, N_JOINTS), "qd_ref")
    ff = _c_array(law.ff, (n, N_JOINTS), "feedforward")
    pre = _c_array(terms["pre"], (n, N_JOINTS), "the stream's precomputed error")
    ripple = np.ascontiguousarray(terms["ripple"], dtype=np.float64).reshape(-1, 6)
    gain = np.ascontiguousarray(terms["gain"], dtype=np.float64).reshape(-1, 5)
    kp, kv, kidt, limits = zip(*law.gains)
    doubles = np.array([law.res or 0.0, law.pole, law.gain, *kp, *kv, *kidt, *(t for _, t, _, _ in limits),
                        *(lo for _, _, lo, _ in limits), *(hi for _, _, _, hi in limits)], dtype=np.float64)
    state = np.array([*law.integ, *law.e_prev, *law.qd_est, *(law.q_prev or [0.0] * N_JOINTS),
                      *(1.0 if s else 0.0 for s in law.sat), 0.0 if law.q_prev is None else 1.0], dtype=np.float64)
    out = np.zeros(2 * N_JOINTS)
    ints = np.array([nq, nv, ne, model.nu, int(substeps), first[1], n, ripple.shape[0], gain.shape[0],
                     1 if law.res else 0, efc.shape[1], 1 if terms.get("check_finite") else 0, *qm_idx],
                    dtype=np.int64)
    addresses = {
        "model": model._address, "data": data._address, "forward": fn["mj_forward"], "first": fn[first[0]],
        "step": fn["mj_step"], "user_error": fn["mju_user_error"],
        "qpos": _view_address(data.qpos, nq, "qpos"), "qvel": _view_address(data.qvel, nv, "qvel"),
        "qacc": _view_address(data.qacc, nv, "qacc"), "ctrl": _view_address(data.ctrl, N_JOINTS, "ctrl"),
        "act": _view_address(data.actuator_force, N_JOINTS, "actuator_force"),
        "efc_pos": _view_address(efc_pos, ne, "efc_pos") if ne else 0,
        "q_ref": addr(q_ref), "qd_ref": addr(qd_ref), "ff": addr(ff), "pre": addr(pre), "ripple": addr(ripple),
        "gain": addr(gain), "rec_qpos": addr(rec_qpos), "rec_qvel": addr(rec_qvel), "rec_qacc": addr(rec_qacc),
        "rec_app": addr(rec_app), "efc": addr(efc), "rec_cmd": addr(rec_cmd), "rec_qm": addr(rec_qm),
        "state": addr(state), "out": addr(out)}
    pointers = np.array([addresses[k] for k in _PTRS], dtype=np.uint64)
    keep += [pointers, ints, doubles, efc_pos]

    k = 0
    while k < n:
        status, stopped, message = ext.run(pointers.ctypes.data, ints.ctypes.data, doubles.ctypes.data, k,
                                           min(n, k + _CHUNK))
        if status == 1:
            raise SimulationError(f"the simulation diverged (non-finite state at t = {data.time:.4f} s); check the "
                                  "reference and the controller")
        if status == 2:  # the stream refuses this sample: its own at_list raises its own error
            stream.at_list(int(stopped), out[:N_JOINTS].tolist(), out[N_JOINTS:].tolist())
            raise SimulationError(f"the compiled loop stopped at sample {stopped} on a check the stream's at_list "
                                  "passes (a bug: please report it)")
        if status == 3:
            raise SimulationError(f"MuJoCo error at sample {stopped} (t = {data.time:.4f} s): {message}")
        if progress is not None:  # as the Python loop: after each sample j with j % 1000 == 0
            for j in range(-(-k // 1000) * 1000, stopped, 1000):
                progress(j, n)
        k = stopped
    law.integ, law.e_prev, law.qd_est = state[0:4].tolist(), state[4:8].tolist(), state[8:12].tolist()
    law.q_prev, law.sat = state[12:16].tolist(), [bool(s) for s in state[16:20]]
    return True
