"""Outer polygons of the feasible set's projection onto a pair of parameters, from safe support bounds.

For the feasible polytope ``S = {theta in B : |y - W theta| <= bound}`` (B a finite box containing it, e.g. the
hull) and a pair ``(i, j)``, the projection ``pi_ij(S)`` is a convex polygon. Each direction ``n`` of the plane
gives a supporting half-plane ``n . (theta_i, theta_j) <= h(n)`` with ``h(n)`` a rigorous upper bound of
``max n . pi_ij(theta)`` over S (one LP, :class:`ident.estimators.support.SupportLP`: warm-started, working set
of rows, Neumaier-Shcherbina safe bound). The polygon returned is the box ``B_i x B_j`` cut by the half-planes
of ``K`` directions evenly spaced in angle in the box-scaled plane (``theta_i / s_i``, ``s`` the power of two
nearest the box's width, so the scaling is exact): ``K`` a multiple of 4, so the four axes are among them and
the polygon's extent along each axis is the hull's interval (to the LPs' tolerance). It contains
``pi_ij(S)``: each half-plane does, and the vertices are computed with every offset ``h`` enlarged by a margin
that exceeds the rounding of the clipping (relative ``1e-12`` of the polygon's size).

Refinement (``refine`` rounds, optional): the LP maximisers are points of S (to the LP tolerance), so their
convex hull is an inner polygon; between two consecutive directions whose outer vertex lies farther than
``refine_tol`` (relative to the box) outside the inner edge, the edge's normal is added as a new direction.
This converges to the exact projection (the outer and inner polygons meet) and is reported as ``gap``.

Which pairs (:func:`coupling_scores`): the pairs whose projection fills its box least, measured by the octagon of
the four diagonal supporting lines (``1 - area / box area``), among the pairs screened by the LP vertices of the
hull's own LPs (:func:`vertex_coupling`), so that 2p + 4 x candidates LPs choose them, not 2p(p - 1).

The projections of the reference sets are here too (:func:`ellipse_points` for an ellipsoid's shadow, the 2x2
sub-matrix of its shape; :func:`zonogon` for a zonotope's, the polygon of its projected generators).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from h4bench.ident.estimators.support import SupportLP
from h4bench.portable import atan2, nearest_power_of_two

__all__ = ["Polygon", "clip_halfplane", "convex_hull", "coupling_scores", "ellipse_points", "most_coupled_pairs",
           "polygon_area", "project_pair", "projections", "vertex_coupling", "zonogon"]

_MARGIN = 1e-12


def polygon_area(v) -> float:
    """Signed area of the polygon ``v`` (n, 2) (positive when counter-clockwise)."""
    v = np.asarray(v, dtype=float)
    if v.shape[0] < 3:
        return 0.0
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def clip_halfplane(v, n, h) -> np.ndarray:
    """The convex polygon ``v`` (m, 2) cut by the half-plane ``n . x <= h`` (Sutherland-Hodgman); (m', 2)."""
    v = np.asarray(v, dtype=float)
    if v.shape[0] == 0:
        return v
    s = v @ np.asarray(n, dtype=float) - h
    out = []
    for k in range(v.shape[0]):
        a, b, sa, sb = v[k], v[(k + 1) % v.shape[0]], s[k], s[(k + 1) % v.shape[0]]
        if sa <= 0:
            out.append(a)
        if (sa < 0 < sb) or (sb < 0 < sa):
            out.append(a + (sa / (sa - sb)) * (b - a))
    return np.array(out).reshape(-1, 2)


@dataclass
class Polygon:
    """An outer polygon of the projection of S onto ``parameters`` (units of the two parameters).

    vertices : (V, 2) counter-clockwise; normals : (K, 2) the directions (in the parameters' units: the
    half-planes are ``normals_k . x <= support_k``); support : (K,) rigorous offsets; inner : (K, 2) the LP
    maximisers (float, feasible to the LP tolerance); gap : the largest distance of an outer vertex outside
    the inner polygon, relative to the box (0: the exact projection); seconds, lp_solves.
    """

    parameters: tuple[str, str]
    indices: tuple[int, int]
    vertices: np.ndarray
    normals: np.ndarray
    support: np.ndarray
    inner: np.ndarray
    gap: float
    info: dict = field(default_factory=dict)

    @property
    def directions(self) -> int:
        return int(self.normals.shape[0])

    def to_json(self) -> dict:
        """``{"parameters", "vertices", "directions", "gap", "area", "inner_area"}`` (plain lists)."""
        return {"parameters": list(self.parameters), "vertices": self.vertices.tolist(), "directions": self.directions,
                "gap": self.gap, "area": polygon_area(self.vertices),
                "inner_area": polygon_area(convex_hull(self.inner))}


def _cross(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def convex_hull(points) -> np.ndarray:
    """Convex hull (counter-clockwise, Andrew's monotone chain) of (m, 2) points."""
    pts = np.unique(np.asarray(points, dtype=float).reshape(-1, 2), axis=0)
    if pts.shape[0] < 3:
        return pts

    def half(seq):
        out = []
        for q in seq:
            while len(out) >= 2 and _cross(out[-1] - out[-2], q - out[-2]) <= 0:
                out.pop()
            out.append(q)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _outer(box, normals, support) -> np.ndarray:
    (x0, x1), (y0, y1) = box
    v = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    size = max(abs(x0), abs(x1), abs(y0), abs(y1), x1 - x0, y1 - y0, 1e-300)
    for n, h in zip(normals, support):
        v = clip_halfplane(v, n, h + _MARGIN * size * np.abs(n).sum())
    return v


def _gap(outer, inner) -> float:
    """Largest distance of an ``outer`` vertex outside the convex hull of ``inner`` (scaled plane)."""
    hull = convex_hull(inner)
    if hull.shape[0] < 3:
        return float("inf")
    e = np.roll(hull, -1, axis=0) - hull
    nrm = np.stack([e[:, 1], -e[:, 0]], axis=1) / (np.linalg.norm(e, axis=1)[:, None] + 1e-300)  # outward (ccw)
    d = np.einsum("vkd,kd->vk", outer[:, None, :] - hull[None], nrm)  # distance outside each inner edge
    return float(max(0.0, d.max(axis=1).max()))


def project_pair(engine: SupportLP, i: int, j: int, *, directions: int = 32, refine: int = 0,
                 refine_tol: float = 1e-6, names=None) -> Polygon:
    """The outer polygon of the projection of the engine's set S onto ``(theta_i, theta_j)`` (module docstring).

    Parameters
    ----------
    engine : a :class:`SupportLP` of S; its box (``engine.lower``, ``engine.upper``) starts the polygon.
    i, j : parameter indices (different); directions : K, a multiple of 4 (>= 4).
    refine : rounds of refinement towards the exact projection; refine_tol : its stopping distance (relative).
    names : parameter names (default ``theta1..thetap``).

    Returns
    -------
    :class:`Polygon`.
    """
    p = engine.lower.size
    if not (0 <= i < p and 0 <= j < p) or i == j:
        raise ValueError(f"i and j must be two different parameter indices in [0, {p}), got {i} and {j}")
    if isinstance(directions, bool) or not isinstance(directions, (int, np.integer)) or directions < 4 \
            or directions % 4:
        raise ValueError(f"directions must be a multiple of 4 (>= 4), got {directions!r}")
    t0, solves0 = time.perf_counter(), engine.solves
    names = tuple(names) if names is not None else tuple(f"theta{k + 1}" for k in range(p))
    lo, hi = engine.lower[[i, j]], engine.upper[[i, j]]
    w = hi - lo
    s = np.ldexp(1.0, nearest_power_of_two(np.where(w > 0, w, np.maximum(np.abs(hi), 1.0))))  # exact
    box = ((lo[0] / s[0], hi[0] / s[0]), (lo[1] / s[1], hi[1] / s[1]))

    def support(phi_list):
        ns, hs, pts = [], [], []
        for phi in phi_list:
            n = np.array([np.cos(phi), np.sin(phi)])
            n[np.abs(n) < 1e-15] = 0.0  # the axes exactly
            c = np.zeros(p)
            c[i], c[j] = n[0] / s[0], n[1] / s[1]
            h, x = engine.maximize(c)
            ns.append(n)
            hs.append(h)
            pts.append(np.array([x[i] / s[0], x[j] / s[1]]) if x is not None else np.full(2, np.nan))
        return ns, hs, pts

    phis = list(2.0 * np.pi * np.arange(directions) / directions)
    normals, sup, pts = support(phis)
    gap = np.inf
    for _ in range(int(refine) + 1):
        outer = _outer(box, normals, sup)
        finite = np.array([np.all(np.isfinite(q)) for q in pts])
        gap = _gap(outer, np.array(pts)[finite]) if finite.sum() >= 3 else np.inf
        if _ >= refine or gap <= refine_tol:
            break
        order = np.argsort(np.mod(phis, 2 * np.pi), kind="stable")
        new = []
        for a, b in zip(order, np.roll(order, -1)):
            pa, pb = pts[a], pts[b]
            e = pb - pa
            if not (np.all(np.isfinite(e)) and np.linalg.norm(e) > refine_tol):
                continue
            nn = np.array([e[1], -e[0]]) / np.linalg.norm(e)  # outward normal of the ccw edge
            if np.max(outer @ nn - nn @ pa) > refine_tol:
                new.append(float(atan2(nn[1], nn[0])))
        if not new:
            break
        n2, h2, p2 = support(new)
        phis += new
        normals += n2
        sup += h2
        pts += p2
    normals = np.array(normals)
    inner = np.array(pts) * s
    return Polygon(parameters=(names[i], names[j]), indices=(int(i), int(j)), vertices=outer * s,
                   normals=normals / s, support=np.array(sup), inner=inner, gap=float(gap),
                   info={"seconds": time.perf_counter() - t0, "lp_solves": engine.solves - solves0})


def vertex_coupling(engine: SupportLP) -> np.ndarray:
    """(p, p) symmetric cheap coupling: ``|x_j(max theta_i) - x_j(min theta_i)| / w_j`` (the LP maximiser and
    minimiser of each parameter, 2p LPs; ``w`` the box's widths), the larger of (i, j) and (j, i). Near 1 when
    pushing theta_i to an end drags theta_j across its interval; a screening measure (an LP vertex on a face
    of the polytope is not unique), refined by :func:`coupling_scores`."""
    p = engine.lower.size
    w = np.maximum(engine.upper - engine.lower, 1e-300)
    lo_x, hi_x = np.zeros((p, p)), np.zeros((p, p))
    for i in range(p):
        e = np.zeros(p)
        e[i] = 1.0
        x_lo, x_hi = engine.minimize(e)[1], engine.maximize(e)[1]
        lo_x[i] = engine.center if x_lo is None else x_lo
        hi_x[i] = engine.center if x_hi is None else x_hi
    c = np.abs(hi_x - lo_x) / w
    out = np.maximum(c, c.T)
    np.fill_diagonal(out, 0.0)
    return out


def coupling_scores(engine: SupportLP, candidates: int | None = None) -> np.ndarray:
    """(p, p) symmetric coupling of each pair: ``1 - area(octagon) / area(box)`` in the box-scaled plane, the
    octagon being the box cut by the four diagonal supporting lines (4 LPs per pair). 0 for a pair whose
    projection fills its box (independent), near 1 for a thin diagonal sliver (strongly coupled).

    candidates : None (every pair) or the number of pairs scored, those of largest :func:`vertex_coupling`
    (the others get 0): 2p + 4 candidates LPs instead of 2 p (p - 1).
    """
    p = engine.lower.size
    w = engine.upper - engine.lower
    out = np.zeros((p, p))
    iu = np.triu_indices(p, 1)
    todo = list(zip(*iu))
    if candidates is not None and int(candidates) < len(todo):
        screen = vertex_coupling(engine)[iu]
        todo = [todo[k] for k in np.argsort(-screen, kind="stable")[: int(candidates)]]
    for i, j in todo:
        if w[i] <= 0 or w[j] <= 0:
            continue
        box = ((0.0, 1.0), (0.0, 1.0))
        normals, sup = [], []
        for a, b in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
            c = np.zeros(p)
            c[i], c[j] = a / w[i], b / w[j]
            h = engine.maximize(c)[0] - (a * engine.lower[i] / w[i] + b * engine.lower[j] / w[j])
            normals.append(np.array([a, b], float))
            sup.append(h)
        out[i, j] = out[j, i] = 1.0 - polygon_area(_outer(box, normals, sup))
    return out


def most_coupled_pairs(scores, count: int = 3) -> list[tuple[int, int]]:
    """The ``count`` pairs ``(i, j)``, ``i < j``, of largest coupling score, the largest first."""
    scores = np.asarray(scores, dtype=float)
    iu = np.triu_indices(scores.shape[0], 1)
    order = np.argsort(-scores[iu], kind="stable")[: int(count)]
    return [(int(iu[0][k]), int(iu[1][k])) for k in order]


def projections(W, y, bound, box, pairs=None, *, count: int = 3, directions: int = 32, refine: int = 0,
                names=None, engine: SupportLP | None = None, candidates: int | None = -1) -> tuple[list[Polygon], dict]:
    """Outer polygons of the feasible set's projections onto pairs of parameters.

    Parameters
    ----------
    W : (N, p); y : (N,); bound : scalar or (N,) > 0 (units of y).
    box : :class:`ident.Box` or ``(lower, upper)`` containing S (the hull: then the polygons' axis extents
    are the hull's intervals).
    pairs : list of ``(i, j)`` indices or ``(name_i, name_j)``; None: the ``count`` most coupled pairs
    (:func:`coupling_scores` of ``candidates`` pairs screened by :func:`vertex_coupling`; -1, the default:
    ``max(4 count, 12)``; None: every pair). directions, refine : see :func:`project_pair`. names : parameter names
    (default the box's, else ``theta1..``). engine : a prebuilt :class:`SupportLP` of S over ``box``.

    Returns
    -------
    (polygons, info) : a :class:`Polygon` per pair and ``{"seconds", "lp_solves", "selection", "scores"}``.
    """
    t0 = time.perf_counter()
    lower, upper = (box.lower, box.upper) if hasattr(box, "lower") else box
    if names is None:
        names = getattr(box, "names", None)
    p = np.asarray(lower).size
    names = tuple(names) if names is not None else tuple(f"theta{k + 1}" for k in range(p))
    if engine is None:
        engine = SupportLP(W, y, bound, lower, upper)
    info = {"selection": "given"}
    if pairs is None:
        if candidates == -1:
            candidates = max(4 * int(count), 12)
        scores = coupling_scores(engine, candidates)
        pairs = most_coupled_pairs(scores, count)
        among = "every pair" if candidates is None or candidates >= p * (p - 1) // 2 else \
            f"the {candidates} pairs of largest LP-vertex coupling"
        info.update(selection=f"most coupled (1 - octagon area / box area) among {among}",
                    scores={f"{names[i]}:{names[j]}": float(scores[i, j]) for i, j in pairs})
    idx = []
    for a, b in pairs:
        ia = names.index(a) if isinstance(a, str) else int(a)
        ib = names.index(b) if isinstance(b, str) else int(b)
        idx.append((ia, ib))
    polys = [project_pair(engine, i, j, directions=directions, refine=refine, names=names) for i, j in idx]
    info.update(seconds=time.perf_counter() - t0, lp_solves=engine.solves, lp_failures=engine.failures)
    return polys, info


def ellipse_points(center, shape, i: int, j: int, n: int = 181) -> np.ndarray:
    """(n, 2) points of the projection onto ``(i, j)`` of ``{(x - c)^T shape^-1 (x - c) <= 1}``: the ellipse of
    the 2x2 sub-matrix ``shape[[i, j]][:, [i, j]]`` around ``c[[i, j]]``."""
    c = np.asarray(center, dtype=float)[[i, j]]
    P = np.asarray(shape, dtype=float)[np.ix_([i, j], [i, j])]
    vals, vecs = np.linalg.eigh(0.5 * (P + P.T))
    L = vecs * np.sqrt(np.maximum(vals, 0.0))
    t = np.linspace(0.0, 2.0 * np.pi, n)
    return c + (L @ np.stack([np.cos(t), np.sin(t)])).T


def zonogon(center, generators, i: int, j: int) -> np.ndarray:
    """(V, 2) counter-clockwise vertices of the projection onto ``(i, j)`` of the zonotope ``c + G xi``,
    ``|xi|_inf <= 1``: the Minkowski sum of the projected generators (``G`` (p, m))."""
    c = np.asarray(center, dtype=float)[[i, j]]
    G = np.asarray(generators, dtype=float).reshape(np.asarray(center).size, -1)[[i, j]].T  # (m, 2)
    G = G[np.linalg.norm(G, axis=1) > 0]
    if G.shape[0] == 0:
        return c[None, :]
    G = np.where((G[:, 1:2] < 0) | ((G[:, 1:2] == 0) & (G[:, 0:1] < 0)), -G, G)  # upper half-plane
    G = G[np.argsort(atan2(G[:, 1], G[:, 0]), kind="stable")]
    start = c - G.sum(axis=0)
    path = start + np.cumsum(np.vstack([2 * G, -2 * G]), axis=0)
    return np.vstack([start, path[:-1]])
