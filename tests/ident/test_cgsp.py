"""The paper's CGSP (method="cgsp") against its dense reference, codac's linear contractors (run in a
subprocess: importing codac switches the process to round-upward), the exact closed form for a point
regressor (python-flint rationals) and the block identity the structured version relies on."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from flint import fmpq, fmpq_mat

from h4bench import ident
from h4bench.ident.estimators.cgsp import approximate_gram_inverse, cgsp, cgsp_dense
from h4bench.ident.estimators.hull import strip_bounds
from h4bench.ident.numerics.interval import point_matvec, sub


def q(x: float) -> fmpq:
    return fmpq(*float(x).as_integer_ratio())


def to_float(r: fmpq) -> float:
    return float(r.p) / float(r.q)


def small_problem(seed: int, n: int, p: int, scaled: bool = False):
    rng = np.random.default_rng(seed)
    W = rng.standard_normal((n, p))
    if scaled:
        W = W * 10.0 ** rng.uniform(-2, 2, p)
    theta = rng.uniform(0.2, 1.8, p) / (np.sqrt(np.mean(W**2, axis=0)))
    y = W @ theta + rng.uniform(-1, 1, n)
    lo, hi = theta - 3.0 * np.abs(theta) - 1.0, theta + 3.0 * np.abs(theta) + 1.0
    ylo, yhi = strip_bounds(y, np.ones(n))
    return W, y, ylo, yhi, lo, hi, theta


def close(a, b, scale):
    return np.all(np.abs(a - b) <= 1e-11 * scale)


@pytest.mark.parametrize("seed,n,p,scaled", [(0, 6, 1, False), (1, 12, 3, True), (2, 30, 5, False), (3, 40, 8, True)])
def test_structured_cgsp_matches_the_dense_reference(seed, n, p, scaled):
    W, y, ylo, yhi, lo, hi, theta = small_problem(seed, n, p, scaled)
    s = cgsp(W, ylo, yhi, lo, hi)
    d = cgsp_dense(W, ylo, yhi, lo, hi)
    assert not s.empty and not d.empty
    scale = hi - lo
    assert close(s.lower, d.lower, scale) and close(s.upper, d.upper, scale)
    assert (s.lower <= theta).all() and (theta <= s.upper).all()
    # the structured residual box is looser (it encloses [b'_r] by W [b'_theta] - [Y]) but contains the dense one
    rscale = np.max(np.abs(d.r_upper)) + 1.0
    assert np.all(s.r_lower <= d.r_lower + 1e-11 * rscale) and np.all(d.r_upper <= s.r_upper + 1e-11 * rscale)


def test_the_block_identity_of_the_preconditioned_matrix_exactly():
    """C A = [[Ginv G, 0], [W (Ginv G - I), I]] exactly, for C built from ANY float Ginv (rationals)."""
    rng = np.random.default_rng(5)
    n, p = 6, 2
    W = rng.standard_normal((n, p))
    Ginv = approximate_gram_inverse(W.T @ W)
    QW = fmpq_mat(n, p, [q(v) for v in W.ravel()])
    QG = fmpq_mat(p, p, [q(v) for v in Ginv.ravel()])
    G = QW.transpose() * QW
    I_n = fmpq_mat(n, n, [fmpq(1) if i == j else fmpq(0) for i in range(n) for j in range(n)])
    I_p = fmpq_mat(p, p, [fmpq(1) if i == j else fmpq(0) for i in range(p) for j in range(p)])
    P = QG * QW.transpose()  # p x n
    blocks_C = [[P, QG], [QW * P - I_n, QW * QG]]
    blocks_A = [[QW, -I_n], [fmpq_mat(p, p), QW.transpose()]]
    CA = [[blocks_C[i][0] * blocks_A[0][j] + blocks_C[i][1] * blocks_A[1][j] for j in range(2)] for i in range(2)]
    assert CA[0][0] == QG * G
    assert CA[0][1] == fmpq_mat(p, n)
    assert CA[1][0] == QW * (QG * G - I_p)
    assert CA[1][1] == I_n


def exact_pinv_hull(W, y, b, lo, hi):
    """hull(W^+ [y - b, y + b]) & Q exactly: W^+ = (W^T W)^-1 W^T in rationals; per row mid +- |row| rad."""
    n, p = W.shape
    QW = fmpq_mat(n, p, [q(v) for v in W.ravel()])
    Wp = (QW.transpose() * QW).inv() * QW.transpose()
    out_lo, out_hi = [], []
    for i in range(p):
        c = sum((Wp[i, k] * q(y[k]) for k in range(n)), fmpq(0))
        r = sum((abs(Wp[i, k]) * q(b[k]) for k in range(n)), fmpq(0))
        out_lo.append(max(c - r, q(lo[i])))
        out_hi.append(min(c + r, q(hi[i])))
    return out_lo, out_hi


@pytest.mark.parametrize("seed,n,p", [(0, 10, 2), (1, 25, 3), (2, 60, 4)])
def test_point_regressor_result_is_the_hull_of_the_pseudo_inverse_image(seed, n, p):
    """For a point regressor CGSP gives hull(W^+ [Y]) & Q (exact closed form, outer + tight)."""
    W, y, _, _, lo, hi, theta = small_problem(seed, n, p)
    lo = theta - 0.6  # make the prior clip some components
    hi = theta + 0.6
    b = np.random.default_rng(seed).uniform(1.0, 2.0, n)  # noise is within [-1, 1]
    box = ident.estimate(W, y, b, (lo, hi), method="cgsp")
    ex_lo, ex_hi = exact_pinv_hull(W, y, b, lo, hi)
    for i in range(p):
        assert q(box.lower[i]) <= ex_lo[i] and ex_hi[i] <= q(box.upper[i])
        assert abs(box.lower[i] - to_float(ex_lo[i])) < 1e-12 and abs(box.upper[i] - to_float(ex_hi[i])) < 1e-12


def test_cgsp_width_does_not_shrink_with_N_while_the_hull_does():
    rng = np.random.default_rng(11)
    p = 4
    theta = rng.uniform(0.5, 1.5, p)
    widths = {}
    for n in (400, 8000):
        W = rng.standard_normal((n, p))
        y = W @ theta + rng.uniform(-1, 1, n)
        prior = (np.zeros(p), 2 * np.ones(p))
        widths[n] = (ident.estimate(W, y, 1.0, prior, method="cgsp").width.mean(),
                     ident.estimate(W, y, 1.0, prior, method="hull").width.mean())
    assert widths[8000][0] > 0.7 * widths[400][0]  # CGSP: |W^+| 1 does not decay with N
    assert widths[8000][1] < 0.2 * widths[400][1]  # exact hull: about 1/N


def test_contractor_proves_emptiness_when_the_pseudo_inverse_image_misses_the_prior():
    W, y, ylo, yhi, lo, hi, theta = small_problem(4, 30, 3)
    y_far = y + W @ np.full(3, 100.0)  # the data point to theta + 100, far outside the prior
    ylo, yhi = strip_bounds(y_far, np.ones(30))
    assert cgsp(W, ylo, yhi, lo, hi).empty
    with pytest.raises(ident.InconsistentDataError) as err:
        ident.estimate(W, y_far, 1.0, (lo, hi), method="cgsp")
    assert err.value.min_bound > 1.0


# ------------------------------------------------------------------------------------------------ codac
CODAC_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import codac
    d = json.load(sys.stdin)
    h = lambda v: [float.fromhex(s) for s in v]
    n = len(d["xlo"])
    Alo, Ahi = h(d["Alo"]), h(d["Ahi"])
    A = codac.IntervalMatrix(n, n)
    for i in range(n):
        for j in range(n):
            A[i, j] = codac.Interval(Alo[i * n + j], Ahi[i * n + j])
    x0 = codac.IntervalVector([[a, c] for a, c in zip(h(d["xlo"]), h(d["xhi"]))])
    b = codac.IntervalVector([[a, c] for a, c in zip(h(d["blo"]), h(d["bhi"]))])
    out = {}
    for name, ctc in (("gauss_seidel", codac.CtcLinearPrecond(codac.CtcGaussSeidel())),
                      ("gauss_elim", codac.CtcLinearPrecond(codac.CtcGaussElim()))):
        x = codac.IntervalVector(x0)
        for sweep in range(200):
            old = [x[i].diam() for i in range(n)]
            # fresh A and b each call: CtcLinearPrecond also intersects them with A0 [A'] and A0 [b'],
            # which are not exact (A0 C != I) and empty Rump's point rows after a few calls
            _, x, _ = ctc.contract(codac.IntervalMatrix(A), x, codac.IntervalVector(b))
            if x.is_empty() or all(old[i] - x[i].diam() <= 1e-9 * old[i] for i in range(n)):
                break
        out[name] = {"empty": bool(x.is_empty()),
                     "lo": [float(x[i].lb()).hex() for i in range(n)],
                     "hi": [float(x[i].ub()).hex() for i in range(n)]}
    json.dump(out, sys.stdout)
    """
)


def run_codac(A, xlo, xhi, blo, bhi) -> dict:
    hexed = lambda a: [float(v).hex() for v in np.ravel(a)]  # exact transfer, independent of rounding mode
    payload = {"Alo": hexed(A), "Ahi": hexed(A), "xlo": hexed(xlo), "xhi": hexed(xhi), "blo": hexed(blo), "bhi": hexed(bhi)}
    proc = subprocess.run([sys.executable, "-c", CODAC_SCRIPT], input=json.dumps(payload), capture_output=True,
                          text=True, timeout=120, check=True)
    out = json.loads(proc.stdout)
    for v in out.values():
        v["lo"] = np.array([float.fromhex(s) for s in v["lo"]])
        v["hi"] = np.array([float.fromhex(s) for s in v["hi"]])
    return out


@pytest.mark.skipif(importlib.util.find_spec("codac") is None, reason="codac not installed (pip install codac)")
@pytest.mark.parametrize("seed,n,p", [(0, 8, 2), (1, 15, 3), (2, 24, 4)])
def test_cgsp_agrees_with_codacs_linear_contractors(seed, n, p):
    W, y, ylo, yhi, lo, hi, theta = small_problem(seed, n, p)
    m = n + p
    A = np.zeros((m, m))
    A[:n, :p] = W
    A[:n, p:] = -np.eye(n)
    A[n:, p:] = W.T
    wlo, whi = point_matvec(W, lo, hi)
    r0lo, r0hi = sub(wlo, whi, ylo, yhi)
    out = run_codac(A, np.r_[lo, r0lo], np.r_[hi, r0hi], np.r_[ylo, np.zeros(p)], np.r_[yhi, np.zeros(p)])
    ours = cgsp(W, ylo, yhi, lo, hi)
    dense = cgsp_dense(W, ylo, yhi, lo, hi)
    tol = 1e-11 * (hi - lo)
    for name, res in out.items():
        assert not res["empty"], name
        # each theta box contains the other's up to rounding
        assert np.all(res["lo"][:p] <= ours.lower + tol) and np.all(ours.upper <= res["hi"][:p] + tol), name
        assert np.all(ours.lower <= res["lo"][:p] + tol) and np.all(res["hi"][:p] <= ours.upper + tol), name
        # codac's residual box matches the dense reference's (same full preconditioning)
        rtol = 1e-11 * (np.max(np.abs(dense.r_upper)) + 1.0)
        assert np.all(np.abs(res["lo"][p:] - dense.r_lower) <= rtol) and np.all(np.abs(res["hi"][p:] - dense.r_upper) <= rtol)
