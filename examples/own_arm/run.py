"""A worked example for your own arm: the certified box of a UR5 log under a specification written from data sheets.

    python examples/own_arm/run.py [--seconds 12] [--out runs/own-arm]

What it does, as you would with your own robot:

1. ``log.csv``: the log of a UR5 (``t, q1..q6, tau1..tau6``, joint side, SI units). Here it is simulated with
   pinocchio (:func:`h4bench.scenarios.arm_log.arm_log`: a smooth motion at most 1.5 rad/s, 17-bit encoders, a
   drive torque error of at most 0.8 N m, viscous and Coulomb friction, rotor inertia, offsets), so that the truth
   is known (``truth.json``, the true base parameters: only this script reads it, to count the enclosed ones);
2. ``spec.toml`` (beside this script): the specification, written from the data sheets, commented entry by entry;
3. ``h4bench identify log.csv --urdf ur5.urdf --spec spec.toml --out OUT/identify``: the certified box;
4. the reading: each base parameter's width over its prior width (median and how many the data narrowed), the
   dominant term of the row radii, the spec check (motion bounds the data prove false), and the truth enclosed.

docs/own-arm.md says what to read in the result and what to do when the box is wide.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
UR5 = HERE / "ur5.urdf"  # the UR5's URDF of example-robot-data 6.0.0, unchanged (SOURCE.md: origin and licence)


def ur5_urdf() -> Path:
    """The UR5's URDF shipped beside this script."""
    return UR5


def make_log(urdf: Path, out: Path, seconds: float, seed: int = 0) -> np.ndarray:
    """Write ``out/log.csv`` (the arm's log) and ``out/truth.json``; return the true base parameters."""
    from h4bench.ident.robots.serial import SerialRobot
    from h4bench.scenarios.arm_log import arm_log, write_arm_csv
    from h4bench.scenarios.identify import urdf_robot_and_prior

    log = arm_log(SerialRobot(urdf), seconds=seconds, counts=2**17, torque_error=0.8, speed=1.5, seed=seed)
    write_arm_csv(log, out / "log.csv")
    _, base, _ = urdf_robot_and_prior(urdf)
    truth = base.from_standard(log.theta)
    (out / "truth.json").write_text(json.dumps({"base_parameters": truth.tolist()}))
    return truth


def reading(result: dict, truth: np.ndarray) -> dict:
    """The figures to read in ``result.json`` (see docs/own-arm.md): widths over the prior, the dominant radius
    term and its share, the spec check, and the truth enclosed (the last one only because the log is simulated)."""
    box = result["methods"]["certified"]
    prior_w = np.asarray(result["prior"]["upper"]) - np.asarray(result["prior"]["lower"])
    out = {"status": box["status"], "base_parameters": len(result["parameters"])}
    c = result.get("certified", {})
    out["dominant"] = c.get("dominant")
    out["shares"] = {k: round(v["share"], 3) for k, v in c.get("terms", {}).items()}
    out["contradicted"] = (c.get("spec_check") or {}).get("contradicted")
    if box["status"] == "ok":
        lo, hi = np.asarray(box["lower"]), np.asarray(box["upper"])
        ratio = (hi - lo) / prior_w
        out["width_over_prior_median"] = float(np.median(ratio))
        out["narrowed"] = int(np.sum(ratio < 0.99))
        out["enclosed"] = int(np.sum((lo <= truth) & (truth <= hi)))
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=12.0, help="length of the simulated log [s] (default 12)")
    ap.add_argument("--out", type=Path, default=Path("runs/own-arm"), help="folder for log.csv, truth.json, identify/")
    ap.add_argument("--spec", type=Path, default=HERE / "spec.toml", help="the specification (default: beside this)")
    args = ap.parse_args(argv)
    urdf = ur5_urdf()
    args.out.mkdir(parents=True, exist_ok=True)
    truth = make_log(urdf, args.out, args.seconds)
    cmd = [sys.executable, "-m", "h4bench", "identify", str(args.out / "log.csv"), "--urdf", str(urdf),
           "--spec", str(args.spec), "--out", str(args.out / "identify"), "--json"]
    print("$ h4bench " + " ".join(shlex.quote(c) for c in cmd[3:]), file=sys.stderr)
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode not in (0, 3):
        sys.exit(f"identify failed (exit {done.returncode}): {done.stderr.strip()}")
    result = json.loads(done.stdout)
    read = reading(result, truth)
    print(json.dumps(read, indent=1))
    return read


if __name__ == "__main__":
    main()
