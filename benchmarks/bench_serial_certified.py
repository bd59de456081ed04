"""The certified box on serial arms people own: width, enclosure and time of ``identify --urdf --spec``.

For each arm (UR5; the Panda with its fingers fixed; public URDFs of the ``example-robot-data`` package), a 12 s,
1 kHz log with a known truth (:mod:`scenarios.arm_log`: pinocchio RNEA + friction, rotor inertia, offsets;
2^17 counts/turn; sample-instant torques; a bounded structured torque error of 0.8 N m) is identified twice:

* certified: ``identify log.csv --urdf ARM --spec spec.toml`` (the spec states the truth; the processing is the
  tool's own choice unless ``--kernel-steps`` is given, which writes a ``[certified]`` table);
* tuned: ``identify log.csv --urdf ARM --bound 0.8`` (the hull of the filtered equation at the true torque
  bound: the reference a certified box is compared with).

Printed per arm: the median over the base parameters of width / prior width for both, the median of the
per-parameter ratio certified / tuned, the enclosed count of the true base parameters, the seconds of each command
(the certified one split into its equation and its hull, and its CPU seconds) and the certified hull's LP
counters; ``--out FILE`` writes it all as JSON.

``--compare`` runs the certified command ``--repeats`` times in each of two variants, interleaved (the same
machine load): ``former``, the hull LPs as at 7b00d11 (``ident.estimators.hull.POOL_ENTRIES = 0``: the pool of the
4000 nearest rows; ``ident.estimators.uncertain_signed.WARM_ROWS = False``: every refinement round from its own
first rows), and ``new`` (the defaults: every row in the pool of a problem up to 2e6 entries; each round
warm-started from the previous round's tight rows and bases). Printed: the median seconds (total, CPU, equation,
hull) of each, the ratio new / former, and the largest endpoint difference of the two boxes relative to the
former's width (signed: > 0 where the new box is narrower). The tuned command runs once.

    pip install example-robot-data
    python benchmarks/bench_serial_certified.py [--arms ur5,panda] [--seconds 12] [--kernel-steps N] [--out F]
                                                [--compare] [--repeats 1]

Printed per arm also: each round of the certified hull (its rows: the first rounds on every k-th kernel window,
:func:`ident.estimators.uncertain_signed.coarse_step`; seconds; simplex iterations; the median of its box's
width over the prior's).

The measured history of this benchmark (per commit: seconds, LP runs, widths, what changed) is in
docs/serial.md, section "Measured history of the arms' certified box".

``--compare`` (the hull's LP switches against their state at 7b00d11) was measured at 3217b55 with ``--repeats 1``
(load 2-4): UR5 649 s former against 218 s new (hull 573 s against 171 s, 2364 against 1251 HiGHS runs, the boxes
within 1.6e-8 of each width); Panda 592 s against 285 s (hull 539 against 234 s, 3106 against 1476 runs, within
9.7e-8). The UR5's hull alone on the same equation, in one process, by CPU time: former 260 s (893 327 simplex
iterations, final working set 6618 rows), new 110 s (299 585 iterations, 4420 rows).
"""

import _setup  # noqa: F401  (repository root on sys.path, --threads)

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: the hull's switches of the ``--compare`` variants (module docstring)
VARIANTS = {"former": {"POOL_ENTRIES": 0, "WARM_ROWS": False}, "new": {}}
ARMS = {"ur5": "ur_description/urdf/ur5_robot.urdf", "panda": "panda_description/urdf/panda.urdf"}


def urdf_path(arm: str, workdir: Path) -> Path:
    """The arm's URDF from the example-robot-data package (the Panda's fingers fixed)."""
    import site

    from h4bench.scenarios.arm_log import fixed_fingers_urdf

    for root in site.getsitepackages():
        p = Path(root) / "cmeel.prefix/share/example-robot-data/robots" / ARMS[arm]
        if p.is_file():
            return fixed_fingers_urdf(p, workdir / f"{arm}.urdf") if arm == "panda" else p
    sys.exit(f"the URDF of {arm} was not found: pip install example-robot-data")


def hull_rounds(rounds: list | None):
    """A context in which every round of the signed hull (one ``uncertain_hull_rows`` call) appends to ``rounds``:
    its rows, seconds, LP iterations and the median width / prior width of the box it found (None: no record)."""
    import contextlib

    from h4bench.ident.estimators import uncertain_signed

    @contextlib.contextmanager
    def ctx():
        if rounds is None:
            yield
            return
        real = uncertain_signed.uncertain_hull_rows

        def spy(W1, D1, y2, b2, prior, **kw):
            t0 = time.perf_counter()
            box, warm = real(W1, D1, y2, b2, prior, **kw)
            rounds.append({"rows": int(W1.shape[0]), "seconds": time.perf_counter() - t0,
                           "lp_iterations": int(box.info.get("lp_iterations", 0)),
                           "width": (box.upper - box.lower).tolist()})
            return box, warm

        uncertain_signed.uncertain_hull_rows = spy
        try:
            yield
        finally:
            uncertain_signed.uncertain_hull_rows = real

    return ctx()


def certified_run(csv, urdf, spec_toml, out, variant: str, rounds: list | None = None) -> tuple[dict, dict]:
    """``identify --spec`` with the hull switches of ``variant``; returns (result, seconds: total/equation/hull and
    cpu, the process's CPU seconds: less sensitive than wall time to the other processes of a loaded machine)."""
    from h4bench.ident.estimators import hull, uncertain_signed
    from h4bench.scenarios.identify_serial_certified import identify_urdf_spec

    saved = {"POOL_ENTRIES": hull.POOL_ENTRIES, "WARM_ROWS": uncertain_signed.WARM_ROWS}
    switch = {**saved, **VARIANTS[variant]}
    hull.POOL_ENTRIES, uncertain_signed.WARM_ROWS = switch["POOL_ENTRIES"], switch["WARM_ROWS"]
    try:
        t0, c0 = time.perf_counter(), time.process_time()
        with hull_rounds(rounds):
            res = identify_urdf_spec(csv, urdf, spec_toml, out=out)
        total, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        hull.POOL_ENTRIES, uncertain_signed.WARM_ROWS = saved["POOL_ENTRIES"], saved["WARM_ROWS"]
    return res, {"total": total, "cpu": cpu, "equation": res["certified"]["seconds"]["equation"],
                 "hull": res["methods"]["certified"].get("seconds")}


def compare(runs: dict) -> dict:
    """Medians per variant, ratios new / former, the largest endpoint difference relative to the former width."""
    out = {}
    for v, rs in runs.items():
        out[v] = {k: float(np.median([s[k] for _, s in rs])) for k in ("total", "cpu", "equation", "hull")}
        out[v]["lp"] = {k: x for k, x in (rs[0][0]["methods"]["certified"].get("info") or {}).items()
                        if k.startswith("lp")}
    out["ratio_new_over_former"] = {k: out["new"][k] / out["former"][k] for k in ("total", "cpu", "equation", "hull")}
    a, b = runs["former"][0][0]["methods"]["certified"], runs["new"][0][0]["methods"]["certified"]
    if "lower" in a and "lower" in b:
        w = np.maximum(np.asarray(a["upper"]) - np.asarray(a["lower"]), 1e-300)
        narrower = np.maximum(np.asarray(b["lower"]) - np.asarray(a["lower"]),
                              np.asarray(a["upper"]) - np.asarray(b["upper"])) / w
        out["new_narrower_by_max_rel"] = float(np.max(narrower))  # < 0: the new box is wider everywhere
        out["endpoint_diff_max_rel"] = float(max(np.max(np.abs(np.asarray(b["lower"]) - np.asarray(a["lower"])) / w),
                                                 np.max(np.abs(np.asarray(b["upper"]) - np.asarray(a["upper"])) / w)))
    return out


def one_arm(arm: str, seconds: float, kernel_steps, workdir: Path, seed: int, repeats: int = 0) -> dict:
    from h4bench.ident.robots.serial import SerialRobot
    from h4bench.scenarios.arm_log import arm_log, arm_spec, write_arm_csv
    from h4bench.scenarios.identify import identify_urdf_csv, urdf_robot_and_prior

    urdf = urdf_path(arm, workdir)
    robot = SerialRobot(urdf)
    log = arm_log(robot, seconds=seconds, seed=seed)
    csv, spec_toml = workdir / f"{arm}.csv", workdir / f"{arm}.toml"
    write_arm_csv(log, csv, spec_toml)
    if kernel_steps:
        with open(spec_toml, "a") as f:
            f.write(f"\n[certified]\nkernel_steps = {int(kernel_steps)}\n")
    _, base, prior = urdf_robot_and_prior(urdf)
    truth = base.from_standard(log.theta)
    width0 = np.asarray(prior["upper"]) - np.asarray(prior["lower"])
    runs: dict = {v: [] for v in VARIANTS}
    for k in range(max(repeats, 1)):
        for v in (VARIANTS if repeats else ["new"]):
            rounds = [] if (k == 0 and v == "new") else None
            runs[v].append(certified_run(csv, urdf, spec_toml, workdir / f"{arm}-certified-{v}-{k}", v, rounds))
            if rounds is not None:  # each round's hull width (its own box, before the intersection) / the prior's
                out_rounds = [{**{k2: r[k2] for k2 in ("rows", "seconds", "lp_iterations")},
                               "width_over_prior_median": float(np.median(np.asarray(r["width"]) / width0))}
                              for r in rounds]
    cert, secs = runs["new"][0]
    t_cert = float(np.median([s["total"] for _, s in runs["new"]]))
    t0 = time.perf_counter()
    tuned = identify_urdf_csv(csv, urdf, str(log.torque_error), out=workdir / f"{arm}-tuned")
    t_tuned = time.perf_counter() - t0
    out = {"arm": arm, "joints": robot.n_joints, "base_parameters": len(base), "seconds_log": seconds,
           "seconds_certified": t_cert, "seconds_certified_parts": secs, "seconds_tuned": t_tuned,
           "kernel": cert["certified"].get("kernel"),
           "dominant": cert["certified"].get("dominant")}
    for name, res in (("certified", cert["methods"]["certified"]), ("tuned", tuned["methods"].get("hull", {}))):
        if "lower" not in res:
            out[name] = {"status": res.get("status"), "message": res.get("message")}
            continue
        lo, hi = np.asarray(res["lower"]), np.asarray(res["upper"])
        out[name] = {"status": res.get("status"), "width_over_prior_median": float(np.median((hi - lo) / width0)),
                     "enclosed": int(np.sum((lo <= truth) & (truth <= hi))), "width": (hi - lo).tolist(),
                     "lp": {k: v for k, v in (res.get("info") or {}).items() if k.startswith("lp")}}
    if "width" in out["certified"] and "width" in out["tuned"]:
        ratio = np.asarray(out["certified"]["width"]) / np.maximum(np.asarray(out["tuned"]["width"]), 1e-300)
        out["certified_over_tuned_median"] = float(np.median(ratio))
    if repeats:
        out["compare"] = compare(runs)
    out["rounds"] = out_rounds
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", default="ur5,panda")
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("--kernel-steps", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None)
    ap.add_argument("--threads", default=None)
    ap.add_argument("--compare", action="store_true", help="the former hull against the new one (docstring)")
    ap.add_argument("--repeats", type=int, default=1, help="runs of each variant with --compare (medians)")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for arm in a.arms.split(","):
            r = one_arm(arm, a.seconds, a.kernel_steps, Path(tmp), a.seed, a.repeats if a.compare else 0)
            rows.append(r)
            c, t = r["certified"], r["tuned"]
            print(f"{arm}: {r['base_parameters']} base parameters; certified width/prior "
                  f"{c.get('width_over_prior_median', float('nan')):.4g} (enclosed {c.get('enclosed')}, "
                  f"{r['seconds_certified']:.1f} s, kernel {r['kernel']}, dominant {r['dominant']}, lp {c.get('lp')}); "
                  f"tuned {t.get('width_over_prior_median', float('nan')):.4g} (enclosed {t.get('enclosed')}, "
                  f"{r['seconds_tuned']:.1f} s); certified/tuned median {r.get('certified_over_tuned_median', float('nan')):.3g}",
                  flush=True)
            for i, rd in enumerate(r["rounds"]):
                print(f"  hull round {i + 1}: {rd['rows']} rows, {rd['seconds']:.1f} s, {rd['lp_iterations']} simplex "
                      f"iterations, width/prior median {rd['width_over_prior_median']:.4g}", flush=True)
            if "compare" in r:
                c = r["compare"]
                for v in VARIANTS:
                    print(f"  {v}: {c[v]['total']:.1f} s, cpu {c[v]['cpu']:.1f} s (equation {c[v]['equation']:.1f} s, "
                          f"hull {c[v]['hull']:.1f} s), lp {c[v]['lp']}", flush=True)
                print(f"  new / former: {c['ratio_new_over_former']}; largest endpoint difference "
                      f"{c.get('endpoint_diff_max_rel', float('nan')):.3g} of the former width (new narrower by at "
                      f"most {c.get('new_narrower_by_max_rel', float('nan')):.3g})", flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
