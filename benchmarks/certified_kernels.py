"""Each kernel of the certified family alone against the family's stacked rows, on the H4's `certified` scenario.

One simulated run (seed, quick or full size); the certified equation's per-step stage once; for each kernel length
of :func:`ident.processing.choice.kernel_family` (and the former default, 100 steps at stride 2) the certified
box of that kernel's rows alone, then the box of the family's rows stacked. Printed per line: rows, the box's
width over the tuned hull's (geometric mean over the 14 parameters), its width over the prior (geometric mean),
the hull's seconds. The family's box lies inside every single kernel's (one true equation each).

    python benchmarks/certified_kernels.py [--quick] [--seed 0] [--counts 20000] [--out F.json]
"""

import _setup  # noqa: F401  (repository root on sys.path, --threads)

import argparse
import json
import time
from pathlib import Path

import numpy as np


def main() -> None:
    from h4bench.ident.processing.choice import kernel_family
    from h4bench.ident.processing.weakform import make_kernel, row_windows
    from h4bench.ident.robots import h4_certified as hc
    from h4bench.scenarios import judging
    from h4bench.scenarios.certificate import processing_of, simulated_error_spec
    from h4bench.scenarios.experiment import run_experiment
    from h4bench.scenarios.registry import load_spec

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--counts", type=int, default=0, help="encoder counts per turn (0: the scenario's)")
    ap.add_argument("--out", default=None)
    ap.add_argument("--threads", default=None)
    a = ap.parse_args()
    spec = load_spec("certified", quick=a.quick)
    if a.counts:
        spec["encoder"]["counts_per_turn"] = a.counts
    run_ = run_experiment(spec, a.seed)
    es = simulated_error_spec(spec, run_.reference, run_.dataset.dt, run_.noise_bound)
    proc = processing_of(spec)
    q, tau, h = run_.dataset.q, run_.dataset.tau, run_.dataset.dt
    t0 = time.perf_counter()
    steps = hc.certified_steps(run_.geometry, q, es, proc)
    print(f"per-step stage {time.perf_counter() - t0:.1f} s", flush=True)
    tuned = run_.boxes["hull"].upper - run_.boxes["hull"].lower
    width0 = run_.prior.upper - run_.prior.lower
    fam = kernel_family(q.shape[0], h, proc.stride)
    eqs = {}
    for L, st in [(100, 2)] + list(zip(fam.steps, fam.strides)):
        eqs[(L, st)] = hc.certified_rows(steps, make_kernel(L, h, proc.kernel_shape), row_windows(q.shape[0], L, st),
                                         tau)
    rows = []

    def box(name, parts):
        Wc, D = np.vstack([e.Wc for e in parts]), np.vstack([e.D for e in parts])
        y, b = np.concatenate([e.y for e in parts]), np.concatenate([e.bound for e in parts])
        g = np.concatenate([e.joint for e in parts]).astype(np.int64)
        t = time.perf_counter()
        out, _ = judging.run_methods(["certified"], Wc, y, b, run_.prior, {"regressor_radius": D, "groups": g})
        bx = out["certified"].box
        w = bx.upper - bx.lower
        r = {"kernels": name, "rows": int(y.size), "width_over_tuned_geomean": float(np.exp(np.mean(np.log(w / tuned)))),
             "width_over_prior_geomean": float(np.exp(np.mean(np.log(w / width0)))),
             "enclosed": int(np.sum((bx.lower <= run_.theta_true) & (run_.theta_true <= bx.upper))),
             "seconds": time.perf_counter() - t, "width": w.tolist()}
        rows.append(r)
        print(f"{name:>28}: rows {r['rows']:6d}  width/tuned {r['width_over_tuned_geomean']:.4f}  width/prior "
              f"{r['width_over_prior_geomean']:.4f}  enclosed {r['enclosed']}/14  hull {r['seconds']:.1f} s", flush=True)

    for (L, st), e in eqs.items():
        box(f"{L} steps, stride {st}", [e])
    box("family " + ",".join(map(str, fam.steps)), [eqs[k] for k in zip(fam.steps, fam.strides)])
    if a.out:
        Path(a.out).write_text(json.dumps({"seed": a.seed, "quick": a.quick, "counts": a.counts, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
