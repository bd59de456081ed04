"""Visual replay of one experiment in Rerun (``runs/<name>/replay.rrd``, opened by ``h4bench replay FILE``).

What the recording holds (one timeline, ``sim_time``: a duration in seconds, the dataset's own clock):

* ``robot/...``: the simulated H4 from the *exact* states (``truth.q``, ``truth.x``) at ``scene_hz`` (50 Hz by
  default, not 1 kHz): static base plate, motors and axes; per frame the arms P_i B_i, the forearms B_i A_i,
  the nacelle's H (central bar C_1 C_3 turning with theta, lateral bars through the A_i that only translate)
  and the joint points; the nacelle path travelled (static line strip);
* ``reference/...``: what the controller tracks, as a ghost: the reference nacelle path (static) and a pale
  H at the reference pose, at the same rate;
* ``series/<quantity>/joint<i>/<signal>`` at the full sample rate: q (measured against exact), qd and qdd
  (estimated by the processing chain, :func:`ident.processing.filtering.derivatives` with ``run.settings``, against
  exact), the motor torques (commanded = measured, applied, noise = applied - commanded) and the residual
  ``y - W theta_true`` of the processed rows against ``+- bound`` at ``dataset.t[equation.sample]``;
* ``estimate/<parameter>/<method>/lower|upper`` and ``estimate/<parameter>/true``: the box history of
  :func:`box_history` (the box from the first k seconds of data, at ``sim_time = t0 + k``);
* ``feasible/<A>_<B>/polygon|hull|true``: for a run with projections (``run.feasible``, the paper kind), each
  pair's outer polygon of the feasible set from the first k seconds of data (the same k as the box history,
  :func:`scenarios.feasible.polygon_history`), the hull box of those data and the truth, in the plane scaled so
  that the final hull box is the unit square: the polygons shrink as data arrive;
* ``summary``: a markdown table (truth, final boxes, enclosure);
* a blueprint: the 3D view and the summary on the left, tabs of time-series grids (one view per joint or
  parameter) on the right.

Bulk data goes through ``send_columns`` (one call per series or per 3D entity), never one call per sample.
Rerun is imported inside the functions only (it is the scenario layer's optional viewer, not a dependency of
the numerics). The calls are those of rerun-sdk 0.41 (the version pinned in pyproject.toml).

Cost: the 3D scene and series are a few tens of ``send_columns`` calls (0.2-0.3 s for a 10 s run, a ~9 MB
file); the box history runs each estimator on ``points - 1`` growing prefixes of the rows (the full-data box is
reused from ``run.boxes``), i.e. about ``(points - 1) / 2`` full-data estimations per method for an estimator
linear in the row count (measured: 0.6 s for hull + cgsp, points = 10, on a 10 s run whose simulation took
1.2-1.4 s). ``history_points = 0`` turns it off.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["ReplayError", "RRD_MAGIC", "TIMELINE", "box_history", "open_viewer", "viewer_command", "write_replay"]

TIMELINE = "sim_time"
RRD_MAGIC = b"RRF2"  # first bytes of a Rerun .rrd stream (checked on files written by rerun-sdk 0.41)
SIGNAL_QUANTITIES = ("q", "qd", "qdd", "torque", "residual")

_BLUE, _ORANGE, _GREY, _GREEN, _RED = (31, 119, 180), (255, 127, 14), (150, 150, 150), (44, 160, 44), (214, 39, 40)
_TRUE = (0, 200, 80)  # the true value in the box-history plots
_METHOD_COLORS = {"hull": _BLUE, "cgsp": _ORANGE, "wls": _GREEN}
_COLOR_NAMES = {_BLUE: "blue", _ORANGE: "orange", _GREEN: "green", _GREY: "grey"}
_SIGNAL_STYLE = {  # signal -> (colour, line width, legend name)
    "measured": (_BLUE, 2.0, "measured"), "estimated": (_BLUE, 2.0, "estimated"), "exact": (_ORANGE, 1.0, "exact"),
    "commanded": (_BLUE, 1.0, "commanded (measured)"), "applied": (_ORANGE, 1.0, "applied"),
    "noise": (_GREY, 1.0, "noise = applied - commanded"),
    "residual": (_BLUE, 1.0, "y - W theta_true"), "upper_bound": (_RED, 1.5, "+bound"),
    "lower_bound": (_RED, 1.5, "-bound"),
}
_UNITS = {"q": "rad", "qd": "rad/s", "qdd": "rad/s^2", "torque": "N m", "residual": "N m"}


class ReplayError(ValueError):
    """A replay cannot be written or opened (bad path, not an .rrd file, bad argument, viewer failure)."""


# ------------------------------------------------------------------------------------------------ box history


def _contained_estimator(timeout: float | None):
    """``f(W, y, bound, prior, method=...) -> Box``: :func:`ident.estimators.isolation.call` (a plugin in a child
    process of its own, a built-in here on read-only views) with the run's time limit per call [s]."""
    from h4bench.ident.estimators import isolation

    def estimator(W, y, bound, prior, method="hull"):
        return isolation.call(method, W, y, bound, prior, timeout=timeout)

    return estimator


def box_history(run, methods=("hull", "cgsp"), points: int = 10, estimator=None, progress=None, *,
                timeout: float | None = None) -> dict:
    """Each method's box from the first k seconds of data, for ``points`` values of k.

    run : a :class:`scenarios.experiment.ExperimentRun`; methods : estimator names for ``ident.estimate``;
    points : number of k values, ``k_j = T j / points`` (j = 1..points, T = ``t[-1] - t[0]`` of the dataset
    [s]), so the last point is the full-data box (taken from ``run.boxes``/``run.failures`` when the method
    ran, else estimated); estimator : ``f(W, y, bound, prior, method=...) -> Box``, default
    :func:`ident.estimators.isolation.call` with ``timeout`` [s] per call (None: no limit); progress : optional
    callable(stage, done, total).

    The rows kept for k are those whose original sample time satisfies ``t[sample] - t[0] <= k``. A point with
    fewer rows than parameters, or where the estimator raises a ``ValueError`` (``ident.InconsistentDataError``,
    ``ident.UnidentifiableError`` and ``ident.EstimatorError`` are: a plugin that raised, exited, crashed, changed
    its inputs or ran past ``timeout`` at that prefix, named), is skipped: its bounds are NaN, ``ok`` is False and
    ``message`` says why. Nothing is raised.

    Returns a dict of plain arrays: ``names`` (p,), ``true`` (p,), ``k`` (K,) [s], ``time`` (K,) = t[0] + k [s],
    ``rows`` (K,) row counts, and ``methods[name]`` with ``lower``/``upper`` (K, p), ``ok`` (K,) bool,
    ``enclosed`` (K, p) bool (False where skipped), ``seconds`` (K,) estimator time (0 where reused or
    skipped), ``message`` (K,) list of str or None.
    """
    if isinstance(points, bool) or not isinstance(points, (int, np.integer)) or points < 1:
        raise ReplayError(f"points must be an integer >= 1, got {points!r}")
    if isinstance(methods, str):
        methods = (methods,)
    methods = tuple(methods)
    eq, t = run.equation, np.asarray(run.dataset.t, dtype=float)
    names = tuple(eq.names)
    p = len(names)
    theta_true = np.asarray(run.theta_true, dtype=float)
    span = float(t[-1] - t[0])
    k = span * np.arange(1, points + 1) / points
    row_age = t[np.asarray(eq.sample, dtype=int)] - t[0]
    tol = 1e-9 * max(span, 1.0)  # k is computed from t: keep the row at exactly t[0] + k
    rows = np.array([int(np.count_nonzero(row_age <= kj + tol)) for kj in k])
    rows[-1] = len(eq)  # the last point is the full data, whatever the rounding of k
    out = {"names": names, "true": theta_true.copy(), "k": k, "time": t[0] + k, "rows": rows, "methods": {}}
    total, done = points * len(methods), 0
    boxes, failures = getattr(run, "boxes", {}) or {}, getattr(run, "failures", {}) or {}
    for method in methods:
        res = {"lower": np.full((points, p), np.nan), "upper": np.full((points, p), np.nan),
               "ok": np.zeros(points, bool), "enclosed": np.zeros((points, p), bool),
               "seconds": np.zeros(points), "message": [None] * points}
        for j in range(points):
            box, m = None, rows[j]
            if j == points - 1 and method in boxes:
                box = boxes[method]
            elif j == points - 1 and method in failures:
                res["message"][j] = str(failures[method])
            elif m < p:
                res["message"][j] = f"{m} rows < {p} parameters"
            else:
                if estimator is None:
                    estimator = _contained_estimator(timeout)
                sel = np.flatnonzero(row_age <= k[j] + tol) if j < points - 1 else slice(None)
                t0 = time.perf_counter()
                try:
                    box = estimator(eq.W[sel], eq.y[sel], eq.bound[sel], run.prior, method=method)
                except ValueError as exc:  # ident.InconsistentDataError, UnidentifiableError, EstimatorError
                    res["message"][j] = f"{type(exc).__name__}: {exc}"
                res["seconds"][j] = time.perf_counter() - t0
            if box is not None:
                res["lower"][j], res["upper"][j] = box.lower, box.upper
                res["ok"][j] = True
                res["enclosed"][j] = np.asarray(box.contains(theta_true), dtype=bool)
            done += 1
            if progress is not None:
                progress("replay history", done, total)
        out["methods"][method] = res
    return out


def _log_polygons(rec, rr, run, ph: dict) -> None:
    for n, (a, b) in enumerate(ph["pairs"]):
        base = f"feasible/{a}_{b}"
        lo, w = ph["lower"][n], ph["width"][n]
        i, j = ph["indices"][n]
        truth = (np.asarray(run.theta_true)[[i, j]] - lo) / w
        rec.log(f"{base}/true", rr.Points2D([truth], colors=[_TRUE], radii=[0.02], labels=["truth"]), static=True)
        times, strips, rects = [], [], []
        for k, tk in enumerate(ph["time"]):
            v, box = ph["polygons"][n][k], ph["boxes"][n][k]
            if v is None or box is None:
                continue
            times.append(float(tk))
            strips.append((np.vstack([v, v[:1]]) - lo) / w)
            bl, bu = (box[0] - lo) / w, (box[1] - lo) / w
            rects.append(np.array([[bl[0], bl[1]], [bu[0], bl[1]], [bu[0], bu[1]], [bl[0], bu[1]], [bl[0], bl[1]]]))
        if not times:
            continue
        for name, data, color, radius in (("polygon", strips, _GREEN, 0.006), ("hull", rects, _BLUE, 0.004)):
            rec.log(f"{base}/{name}", rr.LineStrips2D.from_fields(colors=[color], radii=[radius]), static=True)
            rec.send_columns(f"{base}/{name}", indexes=_time(rr, times),
                             columns=rr.LineStrips2D.columns(strips=data).partition(lengths=[1] * len(times)))


# ------------------------------------------------------------------------------------------------- geometry


def _frame_indices(t: np.ndarray, rate_hz: float) -> np.ndarray:
    """Sample indices at about ``rate_hz`` (always including the last sample)."""
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    step = max(1, int(round(1.0 / (rate_hz * dt))))
    idx = np.arange(0, t.size, step)
    return idx if idx[-1] == t.size - 1 else np.append(idx, t.size - 1)


def _bars(geometry) -> list[np.ndarray]:
    """Chains grouped by the lateral bar carrying them (equal ``bar_offset``), e.g. [[0, 1], [2, 3]]."""
    groups: list[list[int]] = []
    for i in range(4):
        for g in groups:
            if np.allclose(geometry.bar_offset[g[0]], geometry.bar_offset[i], atol=1e-12):
                g.append(i)
                break
        else:
            groups.append([i])
    return [np.array(g) for g in groups]


def nacelle_strips(geometry, x: np.ndarray) -> np.ndarray:
    """The H of the nacelle as segments (n, 1 + bars, 2, 3) [m] for poses x (n, 4): first the central bar
    from C_first to C_last (it turns with theta), then each lateral bar through its attachment points A_i."""
    from h4bench.sim.kinematics import nacelle_points

    a, dc = nacelle_points(geometry, x)
    bars = _bars(geometry)
    c = x[:, None, :3] + dc  # C_k(i) per chain
    central = np.stack([c[:, bars[0][0]], c[:, bars[-1][0]]], axis=1)[:, None]
    lateral = []
    for g in bars:
        # ends of the lateral bar: the two attachment points farthest apart along it
        span = np.einsum("nij,j->ni", a[:, g] - c[:, g], geometry.attach_offset[g[0]])
        lateral.append(np.stack([a[np.arange(len(x)), g[np.argmin(span, axis=1)]],
                                 a[np.arange(len(x)), g[np.argmax(span, axis=1)]]], axis=1)[:, None])
    return np.concatenate([central] + lateral, axis=1)


def _reference_pose(run) -> np.ndarray:
    ref = run.reference
    x = getattr(ref, "x", None)
    if x is not None and np.shape(x) == np.shape(ref.q):
        return np.asarray(x, dtype=float)
    from h4bench import sim

    return sim.forward_kinematics(run.geometry, np.asarray(ref.q, dtype=float))


# --------------------------------------------------------------------------------------------------- logging


def _time(rr, t):
    return [rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=float))]


def _send_series(rec, rr, path: str, t, values, signal: str) -> None:
    color, width, name = _SIGNAL_STYLE[signal]
    rec.log(path, rr.SeriesLines(colors=[color], widths=[width], names=[name]), static=True)
    rec.send_columns(path, indexes=_time(rr, t), columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)))


def _send_strips(rec, rr, path: str, t, segments: np.ndarray, colors, radius: float) -> None:
    """segments (F, s, 2, 3): s two-point strips per frame at times t (F,)."""
    f, s = segments.shape[:2]
    rec.log(path, rr.LineStrips3D.from_fields(colors=colors, radii=[radius] * s), static=True)
    rec.send_columns(path, indexes=_time(rr, t),
                     columns=rr.LineStrips3D.columns(strips=segments.reshape(f * s, 2, 3)).partition(lengths=[s] * f))


def _log_scene(rec, rr, run, scene_hz: float) -> None:
    from h4bench.sim.kinematics import arm_tips, nacelle_points

    g, truth, t = run.geometry, run.truth, np.asarray(run.dataset.t, dtype=float)
    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    # static: base plate above the motors, motors along their axes, labelled
    p, u = g.motor_pos, g.motor_axis
    lo, hi = p.min(axis=0) - 0.08, p.max(axis=0) + 0.08
    rec.log("robot/base", rr.Boxes3D(centers=[[(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, p[:, 2].max() + 0.06]],
                                     half_sizes=[[(hi[0] - lo[0]) / 2, (hi[1] - lo[1]) / 2, 0.01]],
                                     colors=[(160, 160, 160)], radii=[0.002]), static=True)
    z = np.array([0.0, 0.0, 1.0])
    rot = [rr.RotationAxisAngle(axis=np.cross(z, ui) if np.linalg.norm(np.cross(z, ui)) > 1e-9 else [1, 0, 0],
                                radians=float(np.arccos(np.clip(ui @ z, -1, 1)))) for ui in u]
    rec.log("robot/motors", rr.Cylinders3D(centers=p, lengths=[0.08] * 4, radii=[0.03] * 4, rotation_axis_angles=rot,
                                           colors=[(60, 60, 60)] * 4, labels=[f"M{i + 1}" for i in range(4)],
                                           fill_mode="solid"), static=True)
    rec.log("robot/nacelle_path", rr.LineStrips3D([truth.x[:, :3]], colors=[_BLUE], radii=[0.0015]), static=True)
    # per frame, from the exact states
    idx = _frame_indices(t, scene_hz)
    tf, q, x = t[idx], truth.q[idx], truth.x[idx]
    b = arm_tips(g, q)
    a, _ = nacelle_points(g, x)
    f = idx.size
    _send_strips(rec, rr, "robot/arms", tf, np.stack([np.broadcast_to(p, b.shape), b], axis=2), [(90, 90, 90)] * 4,
                 0.012)
    _send_strips(rec, rr, "robot/forearms", tf, np.stack([b, a], axis=2), [(200, 160, 60)] * 4, 0.006)
    h = nacelle_strips(g, x)
    _send_strips(rec, rr, "robot/nacelle", tf, h, [_RED] + [(60, 60, 200)] * (h.shape[1] - 1), 0.01)
    pts = np.concatenate([b, a, x[:, None, :3]], axis=1)
    rec.log("robot/joints", rr.Points3D.from_fields(radii=[0.008] * 9, colors=[(220, 220, 220)] * 8 + [_RED]),
            static=True)
    rec.send_columns("robot/joints", indexes=_time(rr, tf),
                     columns=rr.Points3D.columns(positions=pts.reshape(f * 9, 3)).partition(lengths=[9] * f))
    # the reference (ghost): path and a pale H at the reference pose
    ref_t = np.asarray(run.reference.t, dtype=float)
    ref_x = _reference_pose(run)
    rec.log("reference/nacelle_path", rr.LineStrips3D([ref_x[:, :3]], colors=[(*_GREEN, 160)], radii=[0.001]),
            static=True)
    ridx = _frame_indices(ref_t, scene_hz)
    rh = nacelle_strips(g, ref_x[ridx])
    _send_strips(rec, rr, "reference/nacelle", ref_t[ridx], rh, [(*_GREEN, 90)] * rh.shape[1], 0.006)


def _log_signals(rec, rr, run) -> None:
    from h4bench.ident.processing.filtering import derivatives

    ds, truth, s = run.dataset, run.truth, run.settings
    t = np.asarray(ds.t, dtype=float)
    est = derivatives(ds.q, ds.dt, s.position_cutoff_hz, s.butter_order, timing=s.torque_timing)
    v = est.valid
    eq = run.equation
    residual = eq.y - eq.W @ np.asarray(run.theta_true, dtype=float)
    for i in range(4):
        j = f"joint{i + 1}"
        _send_series(rec, rr, f"series/q/{j}/measured", t, ds.q[:, i], "measured")
        _send_series(rec, rr, f"series/q/{j}/exact", t, truth.q[:, i], "exact")
        _send_series(rec, rr, f"series/qd/{j}/estimated", t[v], est.qd[v, i], "estimated")
        _send_series(rec, rr, f"series/qd/{j}/exact", t, truth.qd[:, i], "exact")
        _send_series(rec, rr, f"series/qdd/{j}/estimated", t[v], est.qdd[v, i], "estimated")
        _send_series(rec, rr, f"series/qdd/{j}/exact", t, truth.qdd[:, i], "exact")
        _send_series(rec, rr, f"series/torque/{j}/commanded", t, ds.tau[:, i], "commanded")
        _send_series(rec, rr, f"series/torque/{j}/applied", t, truth.tau_applied[:, i], "applied")
        _send_series(rec, rr, f"series/torque/{j}/noise", t, truth.noise[:, i], "noise")
        rows = np.flatnonzero(eq.joint == i)
        tr = t[np.asarray(eq.sample, dtype=int)[rows]]
        _send_series(rec, rr, f"series/residual/{j}/residual", tr, residual[rows], "residual")
        _send_series(rec, rr, f"series/residual/{j}/upper_bound", tr, eq.bound[rows], "upper_bound")
        _send_series(rec, rr, f"series/residual/{j}/lower_bound", tr, -eq.bound[rows], "lower_bound")


def _log_history(rec, rr, history: dict) -> None:
    tk = history["time"]
    for n, name in enumerate(history["names"]):
        base = f"estimate/{name}"
        rec.log(f"{base}/true", rr.SeriesLines(colors=[_TRUE], widths=[2.0], names=["true"]), static=True)
        rec.send_columns(f"{base}/true", indexes=_time(rr, tk),
                         columns=rr.Scalars.columns(scalars=np.full(tk.size, history["true"][n])))
        for method, res in history["methods"].items():
            ok = res["ok"]
            if not ok.any():
                continue
            color = _METHOD_COLORS.get(method, _GREY)
            for side in ("lower", "upper"):
                path = f"{base}/{method}/{side}"
                rec.log(path, rr.SeriesLines(colors=[color], widths=[1.5], names=[f"{method} {side}"]), static=True)
                rec.send_columns(path, indexes=_time(rr, tk[ok]),
                                 columns=rr.Scalars.columns(scalars=res[side][ok, n]))


def _summary(run, history: dict | None) -> str:
    names = list(run.equation.names)
    methods = sorted(set(run.boxes) | set(run.failures))
    lines = [f"## {run.spec.get('name', '?')} (seed {run.seed})", "",
             f"{len(run.dataset)} samples over {run.dataset.t[-1] - run.dataset.t[0]:.3f} s, "
             f"{len(run.equation)} processed rows; assumed raw bound {run.bound_raw:g} N m, "
             f"max |y - W theta_true| = {np.abs(run.residual).max():.4g} N m "
             f"(processed bound {run.equation.bound.max():.4g}).", ""]
    for m in methods:
        if m in run.failures:
            lines.append(f"- **{m}** failed: {run.failures[m]}")
    lines += ["", "| parameter | true | " + " | ".join(f"{m} [lower, upper]" for m in run.boxes) + " |",
              "|---|---|" + "---|" * len(run.boxes)]
    for n, name in enumerate(names):
        cells = []
        for box in run.boxes.values():
            inside = box.lower[n] <= run.theta_true[n] <= box.upper[n]
            cells.append(f"[{box.lower[n]:.4g}, {box.upper[n]:.4g}]" + ("" if inside else " **MISSED**"))
        lines.append(f"| {name} | {run.theta_true[n]:.4g} | " + " | ".join(cells) + " |")
    if history is not None:
        lines += ["", f"Box history: {len(history['k'])} points (first k seconds of data, k = "
                  f"{', '.join(f'{v:.3g}' for v in history['k'])} s)."]
        for m, res in history["methods"].items():
            skipped = [f"k={history['k'][j]:.3g}: {msg}" for j, msg in enumerate(res["message"]) if not res["ok"][j]]
            if skipped:
                lines.append(f"- {m} skipped " + "; ".join(skipped))
    return "\n".join(lines)


def _blueprint(rrb, names, units, history_methods, eye, target, pairs=()) -> object:
    def joint_grid(quantity, title):
        return rrb.Grid(*[rrb.TimeSeriesView(origin=f"series/{quantity}/joint{i}", name=f"{title} joint {i}")
                          for i in range(1, 5)], grid_columns=2, name=f"{title} [{_UNITS[quantity]}]")

    tabs = [joint_grid("q", "q"), joint_grid("qd", "qd"), joint_grid("qdd", "qdd"), joint_grid("torque", "torque"),
            joint_grid("residual", "residual")]
    if history_methods:
        key = ", ".join(f"{m} {_COLOR_NAMES.get(_METHOD_COLORS.get(m, _GREY), 'grey')}" for m in history_methods)
        tabs.append(rrb.Grid(*[rrb.TimeSeriesView(origin=f"estimate/{n}", name=f"{n} [{u}]" if u else n,
                                                  plot_legend=rrb.PlotLegend(visible=False))
                               for n, u in zip(names, units)], grid_columns=4,
                             name=f"box history ({key}, true green)"))
    if pairs:
        bounds = rrb.VisualBounds2D(x_range=[-0.6, 1.6], y_range=[-0.6, 1.6])
        tabs.append(rrb.Grid(*[rrb.Spatial2DView(origin=f"feasible/{a}_{b}", visual_bounds=bounds,
                                                 name=f"{a} vs {b} (final hull = unit square)")
                               for a, b in pairs], grid_columns=min(len(pairs), 3),
                             name="feasible set (hull blue, projection green, true green dot)"))
    scene = rrb.Spatial3DView(origin="/", contents=["/robot/**", "/reference/**"],
                              name="H4 (exact states) and reference ghost",
                              eye_controls=rrb.EyeControls3D(position=eye, look_target=target, eye_up=[0, 0, 1]))
    left = rrb.Vertical(scene, rrb.TextDocumentView(origin="/summary", name="summary"), row_shares=[3, 1])
    return rrb.Blueprint(rrb.Horizontal(left, rrb.Tabs(*tabs, active_tab=0), column_shares=[2, 3]),
                         rrb.TimePanel(timeline=TIMELINE), collapse_panels=False)


def write_replay(run, path, history_points: int = 10, progress=None, *, history: dict | None = None,
                 scene_hz: float = 50.0) -> Path:
    """Write the Rerun recording of ``run`` to ``path`` (an ``.rrd``) atomically and return the path.

    run : a :class:`scenarios.experiment.ExperimentRun`; history_points : k values of the box history
    (0 = no history; see :func:`box_history` for its cost), for the methods of ``run.boxes`` and
    ``run.failures``; history : a precomputed :func:`box_history` result (then ``history_points`` is
    ignored); scene_hz : rate of the 3D frames [Hz]; progress : optional callable(stage, done, total).
    The bytes are built in memory and written to a temporary file in the same folder, then ``os.replace``d.
    """
    from h4bench.sim.dataset import atomic_write_bytes

    path = Path(path)
    if path.suffix != ".rrd":
        raise ReplayError(f"path must end with .rrd, got {str(path)!r}")
    if not (np.isfinite(scene_hz) and scene_hz > 0):
        raise ReplayError(f"scene_hz must be a finite number > 0 [Hz], got {scene_hz!r}")
    if isinstance(history_points, bool) or not isinstance(history_points, (int, np.integer)) or history_points < 0:
        raise ReplayError(f"history_points must be an integer >= 0, got {history_points!r}")
    progress = progress or (lambda stage, done=0, total=0: None)
    methods = tuple(dict.fromkeys(list(run.boxes) + list(run.failures)))
    if history is None and history_points > 0 and methods:
        timeout = (getattr(run, "spec", None) or {}).get("estimators", {}).get("method_timeout")
        history = box_history(run, methods=methods, points=int(history_points), progress=progress, timeout=timeout)

    import rerun as rr
    import rerun.blueprint as rrb

    name = str(run.spec.get("name", "run"))
    rec = rr.RecordingStream("h4bench", recording_id=f"{name}-seed{run.seed}")
    stream = rec.binary_stream()
    rec.send_recording_name(f"{name} (seed {run.seed})")
    steps = 4
    progress("replay", 0, steps)
    _log_scene(rec, rr, run, scene_hz)
    progress("replay", 1, steps)
    _log_signals(rec, rr, run)
    progress("replay", 2, steps)
    pairs = []
    if history is not None:
        _log_history(rec, rr, history)
        feasible = getattr(run, "feasible", None)
        if feasible and feasible.get("pairs") and "hull" in history["methods"]:
            pairs = [tuple(pj["parameters"]) for pj in feasible["pairs"]]
            from h4bench.scenarios.feasible import polygon_history

            _log_polygons(rec, rr, run, polygon_history(run, pairs, history))
    rec.log("summary", rr.TextDocument(_summary(run, history), media_type=rr.MediaType.MARKDOWN), static=True)
    names = list(run.equation.names)
    from h4bench import ident

    units = list(ident.PARAMETER_UNITS) if len(names) == len(ident.PARAMETER_UNITS) else [""] * len(names)
    hist_methods = [m for m, r in (history or {"methods": {}})["methods"].items() if r["ok"].any()]
    g = run.geometry
    target = 0.5 * (g.motor_pos.mean(axis=0) + np.asarray(g.x_home[:3]))
    reach = float(np.linalg.norm(g.motor_pos[:, :2], axis=1).max() + g.arm_length.max())
    eye = target + reach * np.array([1.5, -1.8, 0.35])  # three-quarter view from the side of chains 2-3
    rec.send_blueprint(_blueprint(rrb, names, units, hist_methods, eye.tolist(), target.tolist(), pairs))
    progress("replay", 3, steps)
    data = stream.read(flush=True)
    if not data:
        raise ReplayError("Rerun produced an empty recording")
    atomic_write_bytes(path, data)  # temp file in the same folder, fsync, os.replace
    os.chmod(path, 0o644)  # mkstemp's 0600 would hide the replay from other users of a shared runs/ folder
    progress("replay", steps, steps)
    return path


# ---------------------------------------------------------------------------------------------------- viewer


def _check_rrd(path) -> Path:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"replay file {str(path)!r} does not exist (write it with `h4bench run NAME`)")
    if not path.is_file():
        raise ReplayError(f"replay path must be a .rrd file, got a directory: {str(path)!r}")
    with open(path, "rb") as fh:
        head = fh.read(len(RRD_MAGIC))
    if path.suffix != ".rrd" or head != RRD_MAGIC:
        raise ReplayError(f"{str(path)!r} is not a Rerun recording (.rrd file starting with {RRD_MAGIC!r}, "
                          f"got suffix {path.suffix!r} and header {head!r})")
    return path


DEFAULT_BIND = "127.0.0.1"  # the viewer's servers listen on this machine only unless --bind says otherwise


def viewer_command(path, web: bool = False, port: int | None = None, bind: str = DEFAULT_BIND) -> list[str]:
    """The ``rerun`` command line that opens ``path`` (checked: exists, .rrd, Rerun header): the native viewer,
    or with ``web`` the web viewer served over HTTP (``--web-viewer``, port ``port`` or Rerun's 9090).
    ``bind``: the IP address its servers listen on (default 127.0.0.1, this machine only; Rerun's own default
    is every interface, 0.0.0.0); :class:`ReplayError` names ``--bind`` when it is not an IP address."""
    import ipaddress

    path = _check_rrd(path)
    try:
        ipaddress.ip_address(str(bind))
    except ValueError:
        raise ReplayError(f"--bind must be an IP address (127.0.0.1, 0.0.0.0, ::), got {bind!r}") from None
    binary = viewer_binary()
    exe = binary or shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    cmd = [exe] if exe else [sys.executable, "-m", "rerun"]
    cmd += ["--bind", str(bind)]
    if web:
        cmd.append("--web-viewer")
        if port is not None:
            cmd += ["--web-viewer-port", str(int(port))]
    return cmd + [str(path)]


def viewer_binary() -> str | None:
    """The Rerun viewer's own binary (what the ``rerun`` console script, a Python wrapper, starts as its child):
    ``RERUN_CLI_PATH`` if set, else ``rerun_cli/rerun`` beside the installed package; None if not found. Started
    directly, the viewer is this command's child, not a grandchild that outlives it."""
    import importlib.util
    import os

    if os.environ.get("RERUN_CLI_PATH"):
        return os.environ["RERUN_CLI_PATH"]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is None or not spec.origin:
        return None
    exe = Path(spec.origin).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")
    return str(exe) if exe.is_file() and os.access(exe, os.X_OK) else None


#: seconds the viewer's process group has to end after SIGTERM before SIGKILL (the binary was measured ignoring
#: SIGTERM for over a second)
STOP_GRACE_S = 2.0


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """Linux: the viewer gets SIGKILL when ``h4bench replay`` dies, however it dies (``PR_SET_PDEATHSIG``)."""
    import ctypes
    import signal

    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)
    except OSError:
        pass


def _end_group(child) -> None:
    """End the viewer's whole process group: SIGTERM, then SIGKILL after :data:`STOP_GRACE_S`."""
    import os
    import signal

    for sig, wait in ((signal.SIGTERM, STOP_GRACE_S), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(child.pid, sig)
        except (ProcessLookupError, PermissionError):
            break
        try:
            child.wait(wait)
        except subprocess.TimeoutExpired:
            continue
        try:  # the leader is gone; a member of its group may remain
            os.killpg(child.pid, 0)
        except ProcessLookupError:
            break


def run_child(cmd: list[str]) -> int:
    """Run ``cmd`` in a process group of its own and wait; SIGTERM or Ctrl-C of this process ends the whole group
    (SIGTERM, then SIGKILL after :data:`STOP_GRACE_S`), and on Linux the child also dies (SIGKILL) when this
    process is killed. Returns its exit status, or 0 when stopped by a signal."""
    import signal

    def stop(signum, frame):
        raise KeyboardInterrupt

    main = threading_is_main()
    previous = signal.signal(signal.SIGTERM, stop) if main else None
    child = None
    try:
        child = subprocess.Popen(cmd, preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
                                 start_new_session=True)
        return child.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        if child is not None:
            _end_group(child)
        if main:
            signal.signal(signal.SIGTERM, previous)


def threading_is_main() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def open_viewer(path, web: bool = False, port: int | None = None, bind: str = DEFAULT_BIND) -> int:
    """Open a replay in the Rerun viewer and wait until it is closed (native) or interrupted (web: serves
    the web viewer on ``bind`` (default 127.0.0.1), open the printed URL; Ctrl-C or SIGTERM stops it, and the
    viewer dies with this process). Raises FileNotFoundError for a missing file, :class:`ReplayError` for a
    file that is not an .rrd, a bad ``bind`` or a viewer that fails to start."""
    cmd = viewer_command(path, web=web, port=port, bind=bind)
    try:
        rc = run_child(cmd)
    except OSError as exc:
        raise ReplayError(f"cannot start the Rerun viewer ({' '.join(cmd)}): {exc}") from exc
    if rc != 0:
        hint = "" if web else " (no display? try `h4bench replay FILE --web`)"
        raise ReplayError(f"the Rerun viewer exited with status {rc}{hint}: {' '.join(cmd)}")
    return rc
