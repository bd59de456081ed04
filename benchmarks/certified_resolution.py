"""Resolution sweep of the certified error model: encoder counts per turn 2^14 .. 2^22 on the `certified`
scenario, the certified box's width over the tuned hull's (geometric mean over the parameters) per step, each
term's mean share of the certified row radius, a markdown table and a PNG plot.

    python benchmarks/certified_resolution.py [--quick] [--seed 0] [--exponents 12,13] [--out runs/certified-resolution]

The tuned hull keeps its spec's allowance (0.2 N m) at every resolution: where its processed equation is
proven empty (a coarse encoder) the row says so. Same trajectory and noise seed at every step.
"""

import _setup  # noqa: F401  (repository root on sys.path, --threads)

import argparse
import copy
import json
import time
from pathlib import Path

import numpy as np

from h4bench.scenarios.certificate import certify
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.registry import load_spec
from h4bench.sim.dataset import atomic_write_bytes

EXPONENTS = range(14, 23)
TERMS = ("torque", "measurement", "second_order", "truncation", "sign")


def sweep(quick: bool, seed: int, exponents=EXPONENTS) -> list[dict]:
    from h4bench.scenarios.certified_verdict import AT_PRIOR

    base = load_spec("certified", quick=quick)
    rows = []
    for ex in exponents:
        spec = copy.deepcopy(base)
        spec["encoder"]["counts_per_turn"] = 2**ex
        t0 = time.perf_counter()
        run_ = run_experiment(spec, seed)
        extra = certify(run_, spec)
        cert = extra["certificate"]
        rows.append({"counts_exponent": ex, "counts_per_turn": 2**ex,
                     "tuned_status": "ok" if "hull" in run_.boxes else "inconsistent",
                     "certified_status": extra["certified_entry"]["status"],
                     "certified_enclosed": extra["certified_entry"].get("all_enclosed"),
                     "width_vs_tuned_geomean": extra["width_vs_tuned_geomean"],
                     "violations": cert["violations"], "min_margin": cert["min_margin"],
                     "shares": {k: cert["shares"][k] for k in TERMS},
                     "terms_max": {k: cert["terms"][k] for k in TERMS},
                     "at_prior": _at_prior(extra["certified_entry"], run_.prior, AT_PRIOR),
                     "tuned_width_over_prior": None if "hull" not in run_.boxes else
                     (run_.boxes["hull"].width / (run_.prior.upper - run_.prior.lower)).tolist(),
                     "friction_band": extra["error_model"].get("friction_band"),
                     "seconds": time.perf_counter() - t0})
        print(f"2^{ex}: ratio {rows[-1]['width_vs_tuned_geomean']}, violations {cert['violations']}, at the prior: "
              f"{', '.join(rows[-1]['at_prior']) or 'none'}; tuned width/prior "
              + ("(no box)" if rows[-1]["tuned_width_over_prior"] is None
                 else " ".join(f"{w:.3g}" for w in rows[-1]["tuned_width_over_prior"]))
              + f"; friction_band {rows[-1]['friction_band']}", flush=True)
    return rows


def _at_prior(entry: dict, prior, at: float) -> list[str]:
    """The names of the parameters whose certified width is at least ``at`` of the prior's (all, without a box)."""
    from h4bench.ident.robots.h4 import PARAMETER_NAMES

    if entry["status"] != "ok":
        return list(PARAMETER_NAMES)
    rel = np.asarray(entry["width"]) / (prior.upper - prior.lower)
    return [n for n, r in zip(PARAMETER_NAMES, rel) if r >= at]


def table(rows: list[dict]) -> str:
    head = ("| counts/turn | certified / tuned (geo. mean) | violations | min margin [N m] | "
            + " | ".join(f"share {t}" for t in TERMS) + " |")
    lines = [head, "|" + "---|" * (4 + len(TERMS))]
    for r in rows:
        ratio = r["width_vs_tuned_geomean"]
        lines.append(f"| 2^{r['counts_exponent']} | {'tuned ' + r['tuned_status'] if ratio is None else f'{ratio:.3f}'}"
                     f" | {r['violations']} | {r['min_margin']:.3f} | "
                     + " | ".join(f"{r['shares'][t]:.3f}" for t in TERMS) + " |")
    agree = [f"2^{r['counts_exponent']}" for r in rows if r["width_vs_tuned_geomean"] is not None
             and abs(r["width_vs_tuned_geomean"] - 1.0) <= 0.10]
    narrower = [f"2^{r['counts_exponent']}" for r in rows if r["width_vs_tuned_geomean"] is not None
                and r["width_vs_tuned_geomean"] < 1.0]
    lines += ["", f"Within 10 % of the tuned widths at: {', '.join(agree) or 'none'}; certified narrower than tuned "
              f"at: {', '.join(narrower) or 'none'}."]
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ex = [r["counts_exponent"] for r in rows]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    a1.plot(ex, [np.nan if r["width_vs_tuned_geomean"] is None else r["width_vs_tuned_geomean"] for r in rows], "o-")
    a1.axhline(1.0, color="k", lw=0.8)
    a1.axhspan(0.9, 1.1, color="0.9")
    a1.set_xlabel("encoder resolution [log2 counts per turn]")
    a1.set_ylabel("certified / tuned width (geometric mean)")
    bottom = np.zeros(len(rows))
    for t in TERMS:
        v = np.array([r["shares"][t] for r in rows])
        a2.bar(ex, v, bottom=bottom, label=t)
        bottom += v
    a2.set_xlabel("encoder resolution [log2 counts per turn]")
    a2.set_ylabel("mean share of the row radius")
    a2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the 4 s trajectory of the scenario's quick size")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("runs/certified-resolution"))
    ap.add_argument("--exponents", default=None, help="log2 counts per turn, e.g. 12,13 (default 14..22)")
    ap.add_argument("--threads", default=None, help="BLAS threads (read by _setup)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    exponents = EXPONENTS if args.exponents is None else [int(x) for x in args.exponents.split(",")]
    rows = sweep(args.quick, args.seed, exponents)
    atomic_write_bytes(args.out / "sweep.json", json.dumps(rows, indent=2).encode())
    atomic_write_bytes(args.out / "sweep.md", table(rows).encode())
    plot(rows, args.out / "sweep.png")
    print(table(rows))


if __name__ == "__main__":
    main()
