"""Same seed, same numbers under any BLAS kernel and thread count: a short paper experiment (designed trajectory,
controller, feed-forward, simulation, hull box) in fresh processes with ``OPENBLAS_CORETYPE`` in {Haswell,
SandyBridge} x ``OPENBLAS_NUM_THREADS`` in {1, 2}, each with its own empty design cache; and a serial arm's base
parameters and prior.

OpenBLAS is built with DYNAMIC_ARCH in numpy's and scipy's wheels: the kernel it runs is chosen by CPU, and
``OPENBLAS_CORETYPE`` forces the one another CPU would pick (SandyBridge: AVX without FMA; Haswell: AVX2 with
FMA). The variables are set explicitly in each child's environment (an environment may set them already, e.g.
``OPENBLAS_L2_SIZE`` for an older OpenBLAS on some CPUs; it is removed). The experiment is the quick paper
scenario made shorter (a 3 s design, the hull alone) so that the four processes take seconds, and the signed
Oettli-Prager hull of a small interval system; the full-size figures are produced by ``benchmarks/blas_matrix.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
KERNELS = ("Haswell", "SandyBridge")
THREADS = (1, 2)

CHILD = """
import json, sys
import numpy as np
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.spec import load_spec
from h4bench.fingerprint import platform
spec = load_spec("paper", quick=True)
spec["trajectory"]["duration"] = 3.0
spec["estimators"]["methods"] = ["hull"]
spec["estimators"]["wls"] = False
spec["estimators"]["explain"] = False
run = run_experiment(spec, 0)
hull = run.boxes["hull"]
# the certified path's hull (an interval regressor, a prior of both signs), data made without BLAS
from h4bench.ident.box import Box
from h4bench.ident.estimators.uncertain_signed import signed_uncertain_hull
rng = np.random.default_rng(3)
W = rng.standard_normal((400, 8))
D = 0.01 * np.abs(rng.standard_normal((400, 8)))
y = np.einsum("ij,j->i", W, rng.uniform(-1, 1, 8)) + rng.uniform(-0.5, 0.5, 400)
ubox = signed_uncertain_hull(W, D, y, np.full(400, 0.5), Box(-2 * np.ones(8), 2 * np.ones(8)), refine=2)
# a serial arm's base parameters and physical prior (column-pivoted QR, least squares, the prior's map)
from h4bench.scenarios.identify import urdf_robot_and_prior
_, base, prior = urdf_robot_and_prior("examples/own_arm/ur5.urdf")
serial = {"names": list(base.names), "beta": [float(v).hex() for v in base.beta.ravel()],
          "prior": [float(v).hex() for v in prior["lower"] + prior["upper"]]}
print(json.dumps({"hashes": run.content_hashes, "lower": [float(v).hex() for v in hull.lower], "serial": serial,
                  "uncertain": [float(v).hex() for v in np.concatenate([ubox.lower, ubox.upper])],
                  "upper": [float(v).hex() for v in hull.upper],
                  "enclosed": bool(np.all((hull.lower <= run.theta_true) & (run.theta_true <= hull.upper))),
                  "kernels": sorted({b["kernel"] for b in platform()["blas"]}),
                  "threads": sorted({b["threads"] for b in platform()["blas"]})}))
"""


def run_child(code: str, env: dict) -> dict:
    """Run ``code`` in a fresh Python with the environment ``env`` (from the repository root); the JSON object its
    last line prints."""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def _child(kernel: str, threads: int, cache: Path) -> dict:
    env = dict(os.environ, OPENBLAS_CORETYPE=kernel, OPENBLAS_NUM_THREADS=str(threads),
               OMP_NUM_THREADS=str(threads), H4BENCH_CACHE=str(cache))
    env.pop("OPENBLAS_L2_SIZE", None)
    return run_child(CHILD, env)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    settings = [(k, t) for k in KERNELS for t in THREADS]
    root = tmp_path_factory.mktemp("blas")
    with ThreadPoolExecutor(max_workers=2) as pool:
        out = list(pool.map(lambda s: _child(s[0], s[1], root / f"{s[0]}-{s[1]}"), settings))
    return dict(zip(settings, out))


def test_each_child_ran_the_kernel_and_threads_it_was_given(runs):
    """The kernels must differ for the comparison to mean anything (SandyBridge is reported as 'Sandybridge')."""
    for (kernel, threads), r in runs.items():
        assert [k.lower() for k in r["kernels"]] == [kernel.lower()], (kernel, r["kernels"])
        assert r["threads"] == [threads]


def test_design_controller_dataset_and_hull_box_are_the_same_bits_everywhere(runs):
    first = next(iter(runs.values()))
    assert set(first["hashes"]) == {"trajectory", "controller", "feedforward", "dataset"}
    for setting, r in runs.items():
        assert r["hashes"] == first["hashes"], (setting, r["hashes"], first["hashes"])
        assert (r["lower"], r["upper"]) == (first["lower"], first["upper"]), setting
        assert r["enclosed"] is True, setting


def test_a_serial_arms_base_and_prior_are_the_same_bits_everywhere(runs):
    """The UR5's base parameters (which columns, their combinations) and the physical prior they map: computed by
    h4bench.portable (at 396da6f by LAPACK's pivoted QR, whose ties between equal columns followed the rounding,
    and the prior's last bits the BLAS threads)."""
    first = next(iter(runs.values()))["serial"]
    assert len(first["names"]) == 58
    for setting, r in runs.items():
        assert r["serial"] == first, setting


def test_the_signed_uncertain_hull_is_the_same_bits_everywhere(runs):
    """The certified path's hull (:func:`ident.estimators.uncertain_signed.signed_uncertain_hull`): its LP shift,
    least-squares centre and chord radii are computed without BLAS (at 7b00d11 this small problem gave different
    bits under Haswell and SandyBridge)."""
    first = next(iter(runs.values()))["uncertain"]
    for setting, r in runs.items():
        assert r["uncertain"] == first, setting
