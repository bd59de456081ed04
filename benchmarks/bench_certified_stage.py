"""The H4's certified stage against its simulation stage: `run certified` as a campaign run spends it.

For each seed, one `certified` experiment (quick by default): the simulation stage's seconds
(``run_.timings["simulation"]``), the certified equation's, its box's (the Oettli-Prager hull) and the
certificate's (the exact positions' equation and the row checks), each also as a multiple of the simulation
stage; medians over the seeds. Wall and CPU time (a shared machine: compare ratios). Per seed also the
certified box's width over the prior's, per parameter, and how many parameters stay at the prior
(``--counts N`` simulates an encoder of N counts per turn instead of the scenario's 20000, e.g. 4096).

    python benchmarks/bench_certified_stage.py [--full] [--seeds 0,1,2] [--counts 4096] [--processes 1,2]
        [--encoder-jets auto|box|tube] [--out F.json]

Measured on a loaded 2-core machine (medians over seeds 0-2, quick), the code at 7b00d11 then at 621b7b6:
(equation + certificate) / simulation 80.4 -> 55.3 (equation 13.3 -> 14.0 s, certificate 9.15 -> 1.56 s,
simulation 0.28 s; certify CPU 16.2 -> 11.0 s), width/tuned 0.9641 / 1.1248 / 1.0118 -> 0.9608 / 1.1219 / 1.0118,
0 violations. ``--counts 4096 --seeds 0``: 14 -> 4 of 14 parameters at the prior (width/tuned 14.10 -> 2.77).
At 7769cf7, alone on the machine, with the simulated friction band (``ErrorSpec.friction_band``, :mod:`sim.friction`):
(equation + certificate) / simulation 52.4 (equation 9.08 s, certificate 0.98 s, simulation 0.19 s), width/tuned
1.0170 / 1.1938 / 1.0781, 0 violations; 1, 2 and 1 of the 14 parameters at the prior (Coulomb friction: the steps
within the band of a reversal carry the sign interval). At 11c861b (box_jets in chunks of 512 steps, the same bits):
(equation + certificate) / simulation 47.9 (equation 8.41 s, certificate 0.95 s, simulation 0.19 s), width/tuned
median 1.08, 0 violations. Motion tubes over 2 or 3 steps (one set of jets each, tried at f011427) took 8.2 and 6.9 s
for the equation but widened the box to 1.15 and 1.83 times the tuned hull (medians); 4-step tubes failed the pose
test on 2880 of 4000 steps. At cc74303, which split the interval jets' chunks between 2 processes (the same bits;
measured on another 2-core machine, idle, where the simulation stage is faster: 0.136 s): (equation + certificate) /
simulation 79.9 with 1 process, 53.9 with 2 (equation 9.64 -> 6.10 s, certificate 1.25 -> 1.24 s: it reuses the
measured equation's motion bounds), the ratio 1.5; width/tuned median 1.07, 0 violations. At e94b9ac (the rows of
the nonlinear columns in chunks of about 1536 window steps, the same bits), the same machine: 72.3 with 1 process,
46.7 with 2 (equation 8.80 -> 5.35 s, certificate 0.76 s, simulation 0.129 s); ``--full --seeds 0``: 78.2 and 50.0
(equation 21.6 -> 12.9 s, certificate 2.2 s, simulation 0.305 s; at cc74303 84.7 and 56.9, equation 25.9 and 16.0 s,
certificate 4.3 s). At bea16c5 (the (q, qd) stage of the interval jets as split jets, exact-zero blocks skipped:
679ea33), on a third 2-core machine (AMD EPYC, simulation 0.34 s), 5cc4c1e then bea16c5 in one session: 52.2 -> 37.0
with 1 process, 35.1 -> 26.7 with 2 (equation 15.4 -> 11.5 s and 10.4 -> 7.64 s, certificate 1.4-1.5 s); width/tuned
median 1.07 and 1 of 14 at the prior at both, 0 violations. At 50a18d9 (the MR products, sums and contractions in
fused ufuncs, ident/numerics/_mr.cpp; the contractions' sums in index order, so other last bits), the same machine,
55022db then 50a18d9 in one session: 41.1 -> 25.1 with 1 process, 26.3 -> 19.9 with 2 (equation 11.5 -> 6.29 s and
7.81 -> 4.83 s, certificate 1.49 -> 1.19 s, simulation 0.29-0.31 s); width/tuned 1.0103 / 1.1641 / 1.0657 at both
(the same to 4 digits), 0 violations. Without the extension (``H4BENCH_PURE_PYTHON=1``, the numpy formulas, the same
bits) at f2e1dda, seed 0: equation 11.0 s, about what it was before the extension (11.5 s at 55022db); without the
operands' own factors formed before the sums (eb5f875) 13.7 s, against 10.1 s at 55022db in the same session.
At 07502f7 (``[certified] encoder_jets``: each step's encoder bounds from its motion tube's interval jets where the
encoder's speed error is at most qdd_max h / 2, the default ``auto``), the same machine, ``--encoder-jets box`` (the
code before, the same bits) then ``auto`` in one session: 26.3 -> 19.4 with 1 process, 21.2 -> 14.8 with 2
(equation 6.91 -> 4.71 s and 5.16 -> 3.30 s, certificate 1.0-1.1 s, simulation 0.29-0.31 s); width/tuned 1.0103 /
1.1641 / 1.0657 -> 1.0175 / 1.1766 / 1.0735, 0 violations; seed 1's Fs4 0.9887 -> 0.9961 of the prior (2 of 14 at
the prior instead of 1). ``--counts 4096 --seeds 0``: ``auto`` keeps the encoder boxes (width/tuned 2.8143, 4 of
14 at the prior); ``tube`` there: 3.2645 and 6. At 5e712ba (the point jets and the kernel rows shared with the
worker too, one worker kept for the command and started before the simulation: ident/workers.py), the same
machine: 16.3 with 1 process, 12.4 with 2 (equation 4.48 and 3.30 s, certificate 0.98 and 0.84 s, simulation
0.34 s), the same widths, 0 violations.
"""

import _setup  # noqa: F401  (repository root on sys.path, --threads)

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np


def one(seed: int, quick: bool, counts: int = 0, processes=(1,), encoder_jets: str = "") -> list[dict]:
    """One experiment, certified once per entry of ``processes`` (``H4BENCH_HULL_PROCESSES``)."""
    from h4bench.scenarios.experiment import run_experiment
    from h4bench.scenarios.registry import load_spec

    from h4bench.ident.workers import prewarm, stop_shared_worker

    prewarm(max(processes))  # as `h4bench run certified` does before its simulation
    spec = load_spec("certified", quick=quick)
    if counts:
        spec["encoder"]["counts_per_turn"] = counts
    if encoder_jets:
        spec["certified"]["encoder_jets"] = encoder_jets
    run_ = run_experiment(spec, seed)
    out = []
    for p in processes:
        os.environ["H4BENCH_HULL_PROCESSES"] = str(p)
        stop_shared_worker()  # each measurement starts its own worker (forked from the running fork server)
        out.append(dict(_certified(run_, spec, seed), processes=p))
    return out


def _certified(run_, spec: dict, seed: int) -> dict:
    from h4bench.scenarios.certificate import certify
    from h4bench.scenarios.certified_verdict import AT_PRIOR

    t0, c0 = time.perf_counter(), time.process_time()
    extra = certify(run_, spec)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    entry, cert = extra["certified_entry"], extra["certificate"]
    sim = run_.timings["simulation"]
    eq, box, chk = entry["equation_seconds"], entry.get("seconds", 0.0), cert.get("seconds", 0.0)
    prior = np.ones(len(entry["width"])) if entry["status"] != "ok" else (
        np.asarray(entry["width"]) / (run_.prior.upper - run_.prior.lower))
    return {"seed": seed, "simulation": sim, "equation": eq, "box": box, "certificate": chk, "certify_wall": wall,
            "certify_cpu": cpu, "equation_over_simulation": eq / sim, "certificate_over_simulation": chk / sim,
            "equation_and_certificate_over_simulation": (eq + chk) / sim,
            "width_vs_tuned_geomean": float("nan") if extra["width_vs_tuned_geomean"] is None
            else extra["width_vs_tuned_geomean"], "violations": cert["violations"],
            "width_over_prior": prior.tolist(), "at_prior": int(np.sum(prior >= AT_PRIOR))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--counts", type=int, default=0, help="encoder counts per turn (0: the scenario's)")
    ap.add_argument("--encoder-jets", default="", help="[certified] encoder_jets (auto, box, tube; default the "
                    "scenario's)")
    ap.add_argument("--out", default=None)
    ap.add_argument("--processes", default="1,2",
                    help="the certified stage's processes (H4BENCH_HULL_PROCESSES), each measured on every seed")
    ap.add_argument("--threads", default=None)
    a = ap.parse_args()
    procs = [int(x) for x in a.processes.split(",")]
    rows = []
    for s in (int(x) for x in a.seeds.split(",")):
        for r in one(s, not a.full, a.counts, procs, a.encoder_jets):
            rows.append(r)
            _print(r)
    for p in procs:
        mine = [r for r in rows if r["processes"] == p]
        med = {k: float(np.median([r[k] for r in mine])) for k in mine[0] if k not in ("seed", "width_over_prior")}
        print(f"median, {p} process(es): " + ", ".join(f"{k} {v:.3g}" for k, v in med.items()))
    if len(procs) > 1:
        ratio = [r1["equation_and_certificate_over_simulation"] / r2["equation_and_certificate_over_simulation"]
                 for r1, r2 in zip(rows[::len(procs)], rows[len(procs) - 1::len(procs)])]
        print(f"(equation + certificate) with {procs[0]} over {procs[-1]} process(es), median over the seeds: "
              f"{float(np.median(ratio)):.3g}")
    if a.out:
        Path(a.out).write_text(json.dumps({"rows": rows, "quick": not a.full, "counts": a.counts}, indent=1))


def _print(r: dict) -> None:
    print(f"seed {r['seed']}, {r['processes']} process(es): simulation {r['simulation']:.2f} s, equation "
          f"{r['equation']:.2f} s, box {r['box']:.2f} s, certificate {r['certificate']:.2f} s; (equation + "
          f"certificate) / simulation {r['equation_and_certificate_over_simulation']:.1f}; width/tuned "
          f"{r['width_vs_tuned_geomean']:.4f}, violations {r['violations']}; {r['at_prior']} of 14 at the prior, "
          "width/prior " + " ".join(f"{w:.4g}" for w in r["width_over_prior"]), flush=True)


if __name__ == "__main__":
    main()
