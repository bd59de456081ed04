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
and the certified hull's LP fallbacks; ``--out FILE`` writes it all as JSON.

    pip install example-robot-data
    python benchmarks/bench_serial_certified.py [--arms ur5,panda] [--seconds 12] [--kernel-steps N] [--out F]
"""

import _setup  # noqa: F401  (repository root on sys.path, --threads)

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

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


def one_arm(arm: str, seconds: float, kernel_steps, workdir: Path, seed: int) -> dict:
    from h4bench.ident.robots.serial import SerialRobot
    from h4bench.scenarios.arm_log import arm_log, arm_spec, write_arm_csv
    from h4bench.scenarios.identify import identify_urdf_csv, urdf_robot_and_prior
    from h4bench.scenarios.identify_serial_certified import identify_urdf_spec

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
    t0 = time.perf_counter()
    cert = identify_urdf_spec(csv, urdf, spec_toml, out=workdir / f"{arm}-certified")
    t_cert = time.perf_counter() - t0
    t0 = time.perf_counter()
    tuned = identify_urdf_csv(csv, urdf, str(log.torque_error), out=workdir / f"{arm}-tuned")
    t_tuned = time.perf_counter() - t0
    out = {"arm": arm, "joints": robot.n_joints, "base_parameters": len(base), "seconds_log": seconds,
           "seconds_certified": t_cert, "seconds_tuned": t_tuned, "kernel": cert["certified"].get("kernel"),
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
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", default="ur5,panda")
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("--kernel-steps", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None)
    ap.add_argument("--threads", default=None)
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for arm in a.arms.split(","):
            r = one_arm(arm, a.seconds, a.kernel_steps, Path(tmp), a.seed)
            rows.append(r)
            c, t = r["certified"], r["tuned"]
            print(f"{arm}: {r['base_parameters']} base parameters; certified width/prior "
                  f"{c.get('width_over_prior_median', float('nan')):.4g} (enclosed {c.get('enclosed')}, "
                  f"{r['seconds_certified']:.1f} s, kernel {r['kernel']}, dominant {r['dominant']}, lp {c.get('lp')}); "
                  f"tuned {t.get('width_over_prior_median', float('nan')):.4g} (enclosed {t.get('enclosed')}, "
                  f"{r['seconds_tuned']:.1f} s); certified/tuned median {r.get('certified_over_tuned_median', float('nan')):.3g}",
                  flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
