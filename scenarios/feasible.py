"""The feasible set in the plane: projections onto pairs of parameters, every method's set beside it, and the plots.

* :func:`feasible_set`: outer polygons of the feasible set's projections (:mod:`ident.estimators.projection`,
  safe support bounds in K directions, refined towards the exact projection) onto the given pairs or the most
  coupled ones, as the ``feasible_set`` entry of ``result.json``;
* :func:`reference_sets`: the boxes (and ``info["set"]``) of the estimators drawn beside it, resolved from the
  registry (the spec's methods plus the bounding ellipsoid, the zonotope and a statistical reference when
  registered); a method that fails or is not available is skipped with its reason;
* :func:`polygon_history`: the polygons from the first k seconds of data (the replay's 2D views);
* :func:`plot_feasible_set` (``feasible_set.png``: a panel per pair with the polygon, each method's box, the
  ellipsoids' ellipses, the zonotopes' zonogons, the truth) and :func:`plot_prediction` (a held-out torque against
  its guaranteed envelopes).

matplotlib is imported lazily, inside the plotting functions.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from h4bench.ident.errors import EstimatorError, InconsistentDataError
from h4bench.ident.estimators import isolation, registry
from h4bench.ident.estimators.projection import ellipse_points, projections, zonogon

__all__ = ["EXTRA_METHODS", "drawn_methods", "feasible_set", "identify_projections", "pairs_option", "parse_pairs",
           "plot_feasible_set", "plot_prediction", "polygon_history", "reference_sets"]

#: drawn beside the spec's methods when registered: the bounding ellipsoid, the zonotope, a statistical reference
#: (the first of ``wls``, ``ols`` that is registered)
EXTRA_METHODS = ("ellipsoid", "zonotope", ("wls", "ols"))
_COLORS = {"hull": "black", "cgsp": "tab:orange", "ellipsoid": "tab:blue", "zonotope": "tab:purple",
           "parallelotope": "tab:pink", "contractor": "tab:brown", "wls": "tab:red", "ols": "tab:red",
           "iv": "tab:olive"}
_OTHER = ("tab:cyan", "tab:gray", "gold", "tab:olive")


def parse_pairs(text: str, names, option: str = "--pairs") -> list[tuple[int, int]]:
    """``"Fv1:Fs1,Imot1:Mnac"`` -> ``[(i, j), ...]`` parameter indices; ValueError naming ``option`` otherwise."""
    names = list(names)
    out = []
    for item in str(text).split(","):
        item = item.strip()
        if not item:
            continue
        parts = [s.strip() for s in item.split(":")]
        if len(parts) != 2 or parts[0] == parts[1]:
            raise ValueError(f"{option}: expected pairs of two different parameters NAME:NAME separated by commas, "
                             f"got {item!r}")
        for s in parts:
            if s not in names:
                raise ValueError(f"{option}: unknown parameter {s!r} in {item!r} (parameters: {', '.join(names)})")
        out.append((names.index(parts[0]), names.index(parts[1])))
    if not out:
        raise ValueError(f"{option}: expected at least one pair NAME:NAME, got {text!r}")
    return out


def drawn_methods(spec_methods) -> list[str]:
    """The spec's methods plus :data:`EXTRA_METHODS` that are registered (names, no duplicates)."""
    out = list(dict.fromkeys(m for m in spec_methods if isinstance(m, str)))
    known = set(registry.BUILTINS)
    for extra in EXTRA_METHODS:
        for name in (extra if isinstance(extra, tuple) else (extra,)):
            if name in known:
                if name not in out:
                    out.append(name)
                break
    return out


def reference_sets(W, y, bound, prior, methods, *, boxes: dict | None = None, groups=None,
                   timeout: float | None = None) -> tuple[dict, dict, dict]:
    """Each method's Box (its ``info["set"]`` kept), reusing ``boxes`` already computed.

    W (N, p), y (N,), bound (N,) [units of y]; prior a Box; methods names or callables of the registry;
    groups (N,) the row's joint (passed to the estimators that accept it); timeout : seconds per method (None: no
    limit). A plugin runs in a child process (:func:`ident.estimators.isolation.call`). Returns ``(boxes, seconds,
    skipped)``: name -> Box, name -> seconds, name -> why it is not drawn (not registered, failed, proven empty).
    """
    out, seconds, skipped = dict(boxes or {}), {}, {}
    for m in methods:
        name = m if isinstance(m, str) else getattr(m, "__name__", str(m))
        if name in out:
            continue
        t0 = time.perf_counter()
        try:
            ctx = {"groups": groups} if groups is not None else {}
            out[name] = isolation.call(m, W, y, bound, prior, timeout=timeout, **ctx)
        except (EstimatorError, InconsistentDataError, ValueError, TypeError, ArithmeticError) as exc:
            skipped[name] = f"{type(exc).__name__}: {exc}"
        seconds[name] = time.perf_counter() - t0
    return out, seconds, skipped


def feasible_set(W, y, bound, box, names, pairs=None, *, count: int = 3, directions: int = 32, refine: int = 3,
                 engine=None) -> tuple[list, dict]:
    """Outer polygons of the projections of ``S = {theta in box : |y - W theta| <= bound}`` onto pairs.

    box : a Box containing S (the hull: the polygons' axis extents are then its intervals); names (p,);
    pairs : ``[(i, j), ...]`` or None for the ``count`` most coupled pairs (1 - octagon area / box area);
    directions : K (a multiple of 4); refine : rounds of refinement towards the exact projection.
    Returns ``(polygons, entry)`` with ``entry`` the ``feasible_set`` of ``result.json``: ``{"pairs": [
    {"parameters", "vertices" (counter-clockwise), "directions", "gap", "area", "inner_area"}, ...],
    "selection", "scores", "seconds", "lp_solves", "lp_failures"}``.
    """
    polys, info = projections(W, y, bound, box, pairs, count=count, directions=directions, refine=refine,
                              names=names, engine=engine)
    entry = {"pairs": [q.to_json() for q in polys], "selection": info["selection"], "scores": info.get("scores", {}),
             "seconds": info["seconds"], "lp_solves": info["lp_solves"], "lp_failures": info["lp_failures"],
             "refine": int(refine)}
    return polys, entry


def _color(name: str, k: int) -> str:
    return _COLORS.get(name, _OTHER[k % len(_OTHER)])


def _set_outline(box, i: int, j: int):
    """The projected outline of a method's ``info["set"]`` (ellipse or zonogon) or None."""
    s = (box.info or {}).get("set") if hasattr(box, "info") else None
    if not isinstance(s, dict):
        return None, None
    try:
        if s.get("type") == "ellipsoid":
            return ellipse_points(s["center"], s["shape"], i, j), "ellipse"
        if s.get("type") == "zonotope":
            return zonogon(s["center"], s["generators"], i, j), "zonogon"
    except (KeyError, ValueError, IndexError, np.linalg.LinAlgError):
        return None, None
    return None, None


def _panel(ax, poly, sets, truth, kinds, units, view_lo, view_hi, notes: bool) -> None:
    """One pair's panel: the polygon, each method's box and set outline, the truth, in the view given."""
    from matplotlib.patches import Polygon as Patch
    from matplotlib.patches import Rectangle

    i, j = poly.indices
    v = poly.vertices
    ax.add_patch(Patch(v, closed=True, facecolor="tab:green", alpha=0.35, edgecolor="darkgreen", lw=1.5,
                       label=f"feasible set (outer polygon, {poly.directions} directions)", zorder=3))
    for k, (name, box) in enumerate(sets.items()):
        col = _color(name, k)
        tag = f"{name} box" + (" (95 % confidence)" if (kinds or {}).get(name) == "statistical" else "")
        lo, hi = box.lower[[i, j]], box.upper[[i, j]]
        ax.add_patch(Rectangle((lo[0], lo[1]), hi[0] - lo[0], hi[1] - lo[1], fill=False, edgecolor=col, lw=1.3,
                               label=tag, zorder=4))
        outline, what = _set_outline(box, i, j)
        if outline is not None:
            closed = np.vstack([outline, outline[:1]])
            ax.plot(closed[:, 0], closed[:, 1], ls="--", color=col, lw=1.0, label=f"{name} {what}", zorder=4)
    if truth is not None:
        ax.plot(truth[i], truth[j], marker="*", ms=12, color="red", mec="k", ls="none", label="truth", zorder=5)
    ax.set_xlim(view_lo[0], view_hi[0])
    ax.set_ylim(view_lo[1], view_hi[1])
    if notes:  # the sets larger than the view, with their widths relative to the polygon's extent
        ext = np.maximum(np.ptp(v, axis=0), 1e-300)
        lines = [f"{name}: {(box.upper[[i, j]] - box.lower[[i, j]])[0] / ext[0]:.3g}x, "
                 f"{(box.upper[[i, j]] - box.lower[[i, j]])[1] / ext[1]:.3g}x" for name, box in sets.items()
                 if np.any(box.lower[[i, j]] < view_lo) or np.any(box.upper[[i, j]] > view_hi)]
        if lines:
            ax.text(0.98, 0.98, "box width / polygon's:\n" + "\n".join(lines), transform=ax.transAxes, ha="right",
                    va="top", fontsize=7, zorder=6, bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "0.7"})
    xl, yl = poly.parameters
    if units is not None:
        xl, yl = f"{xl} [{units[i]}]", f"{yl} [{units[j]}]"
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    ax.grid(alpha=0.3)


def plot_feasible_set(polygons, sets: dict, truth, path: Path, *, units=None, title: str | None = None,
                      kinds: dict | None = None, prior=None) -> None:
    """``feasible_set.png``: per pair, two panels: a close view (the polygon with a margin of 60 % of its extent)
    and a wide view (every method's box, cut by the prior), each with the polygon (filled), each method's box
    (rectangle), the projection of its ``info["set"]`` (ellipse or zonogon, dashed) and the truth (a star).

    polygons : list of :class:`ident.estimators.projection.Polygon`; sets : name -> Box; truth : (p,) or None;
    units : (p,) unit strings; kinds : name -> "guaranteed" / "statistical" (the legend says which); prior : a Box
    cutting the views.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = max(len(polygons), 1)
    cols = min(n, 3)
    blocks = -(-n // cols)
    fig, axes = plt.subplots(2 * blocks, cols, figsize=(5.2 * cols, 4.4 * 2 * blocks), squeeze=False)
    for k in range(blocks * cols):
        close, wide = axes[2 * (k // cols), k % cols], axes[2 * (k // cols) + 1, k % cols]
        if k >= len(polygons):
            close.set_visible(False)
            wide.set_visible(False)
            continue
        poly = polygons[k]
        i, j = poly.indices
        v = poly.vertices
        p_lo = prior.lower[[i, j]] if prior is not None else np.full(2, -np.inf)
        p_hi = prior.upper[[i, j]] if prior is not None else np.full(2, np.inf)
        lo_v, hi_v = v.min(axis=0), v.max(axis=0)
        pad = 0.6 * np.maximum(hi_v - lo_v, 1e-300)
        _panel(close, poly, sets, truth, kinds, units, np.maximum(lo_v - pad, p_lo), np.minimum(hi_v + pad, p_hi),
               True)
        close.set_title(f"{poly.parameters[0]} vs {poly.parameters[1]}: close view", fontsize=10)
        all_lo = np.min([lo_v] + [b.lower[[i, j]] for b in sets.values()], axis=0)
        all_hi = np.max([hi_v] + [b.upper[[i, j]] for b in sets.values()], axis=0)
        span = np.maximum(all_hi - all_lo, 1e-300)
        _panel(wide, poly, sets, truth, kinds, units, np.maximum(all_lo - 0.04 * span, p_lo),
               np.minimum(all_hi + 0.04 * span, p_hi), False)
        wide.set_title(f"{poly.parameters[0]} vs {poly.parameters[1]}: every method's box", fontsize=10)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 5), fontsize=8, frameon=False)
    fig.suptitle(title or "Projections of the feasible set (outer polygons from safe LP bounds)")
    fig.tight_layout(rect=(0, 0.05 + 0.015 * (len(labels) > 5), 1, 0.96))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_prediction(t, measured, poly_lo, poly_hi, box_lo, box_hi, bound, path: Path, *, joint: str = "joint 1",
                    title: str | None = None) -> None:
    """The measured held-out torque of one joint against its guaranteed envelopes widened by the bound.

    t (k,) [s]; measured (k,) [N m]; poly_lo, poly_hi (k,) the polytope envelope; box_lo, box_hi (k,) the box's
    (interval evaluation); bound (k,) or scalar [N m].
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    b = np.broadcast_to(np.asarray(bound, dtype=float), np.shape(t))
    fig, ax = plt.subplots(figsize=(10, 4.2))
    dt = float(np.median(np.diff(t))) if np.size(t) > 1 else 1.0
    ax.bar(t, (box_hi + b) - (box_lo - b), bottom=box_lo - b, width=0.8 * dt, color="tab:orange", alpha=0.35,
           label="hull box envelope + bound")
    ax.bar(t, (poly_hi + b) - (poly_lo - b), bottom=poly_lo - b, width=0.5 * dt, color="tab:green", alpha=0.7,
           label="feasible-set envelope + bound")
    ax.plot(t, measured, ".", ms=3, color="k", label="measured (held out)")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"torque {joint} [N m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(title or f"Guaranteed torque on a held-out motion, {joint}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def identify_projections(folder: Path, W, y, bound, prior, names, pairs, *, box=None, method: str | None = None,
                         units=None) -> dict:
    """``h4bench identify --pairs``: the projections of the data's feasible set, ``feasible_set.png`` in ``folder``.

    W (N, p), y (N,), bound (N,) [N m]; prior a Box; names (p,); pairs ``[(i, j), ...]`` or None (the most
    coupled); box : the method's box when it is guaranteed (``method`` its name; drawn, and the LPs' box when
    it is the hull), else the prior. Returns the ``feasible_set`` entry of ``result.json``.
    """
    start = box if (box is not None and method == "hull") else prior
    polys, entry = feasible_set(W, y, bound, start, list(names), pairs)
    sets = {method: box} if box is not None and method else {}
    plot_feasible_set(polys, sets, None, Path(folder) / "feasible_set.png", units=units, prior=prior,
                      title="Projections of the data's feasible set (outer polygons from safe LP bounds)")
    return entry


def pairs_option(text, names) -> list[tuple[int, int]] | None:
    """``--pairs``: ``auto`` (None: the most coupled pairs) or ``NAME:NAME,...`` (:func:`parse_pairs`)."""
    return None if str(text).strip() == "auto" else parse_pairs(text, names, "--pairs")


def polygon_history(run, pairs, history: dict, directions: int = 16, refine: int = 1) -> dict:
    """Each pair's outer polygon of the feasible set from the first k seconds of data, at the box history's k.

    run : an :class:`scenarios.experiment.ExperimentRun`; pairs : ``[(name_i, name_j), ...]``; history : a
    :func:`scenarios.replay.box_history` result (its k, and its hull boxes as the LPs' boxes; a k where the
    hull did not run is left out); directions, refine : :func:`ident.estimators.projection.project_pair`. The
    rows for k are those of the box history. Returns ``{"pairs", "indices", "lower", "width"`` (the final hull
    box of each pair: the unit square of the replay's plane), ``"polygons"`` (per pair, per k: (V, 2) vertices
    or None where the data of that k were not usable), ``"boxes"`` (per pair, per k: (lower (2,), upper (2,)) or None),
    ``"time"``, ``"seconds"}``.
    """
    from h4bench.ident.estimators.projection import project_pair
    from h4bench.ident.estimators import SupportLP

    t0 = time.perf_counter()
    eq, t = run.equation, np.asarray(run.dataset.t, dtype=float)
    names = list(eq.names)
    idx = [(names.index(a), names.index(b)) for a, b in pairs]
    span = float(t[-1] - t[0])
    row_age = t[np.asarray(eq.sample, dtype=int)] - t[0]
    tol = 1e-9 * max(span, 1.0)
    hull = history["methods"].get("hull")
    final = run.boxes.get("hull", run.prior)
    npts = len(history["k"])
    polys = [[None] * npts for _ in idx]
    boxes = [[None] * npts for _ in idx]
    for j, kj in enumerate(history["k"]):
        sel = np.flatnonzero(row_age <= kj + tol) if j < npts - 1 else np.arange(len(eq))
        if hull is None or not hull["ok"][j] or sel.size < len(names):
            continue  # no hull for these data (too few rows, or proven empty): nothing to project
        lo, hi = hull["lower"][j], hull["upper"][j]
        try:
            engine = SupportLP(eq.W[sel], eq.y[sel], eq.bound[sel], lo, hi)
            for n, (a, b) in enumerate(idx):
                polys[n][j] = project_pair(engine, a, b, directions=directions, refine=refine, names=names).vertices
                boxes[n][j] = (lo[[a, b]], hi[[a, b]])
        except ValueError:  # an LP HiGHS rejects: that k is left out
            continue
    lower = [final.lower[[a, b]] for a, b in idx]
    width = [np.maximum(final.upper[[a, b]] - final.lower[[a, b]], 1e-300) for a, b in idx]
    return {"pairs": [tuple(p) for p in pairs], "indices": idx, "lower": lower, "width": width, "polygons": polys,
            "boxes": boxes, "time": history["time"], "seconds": time.perf_counter() - t0}
