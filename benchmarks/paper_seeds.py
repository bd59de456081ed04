"""The paper run's boxes against the paper's Table 1, over seeds: the figures the README quotes.

    python benchmarks/paper_seeds.py [--seeds 0 1 2 3] [--quick] [--out DIR] [--json]

Runs ``h4bench run paper --seed S`` per seed (in a fresh process; the design cache is ``$H4BENCH_CACHE`` as
usual: a design is the same on any machine, so a cached one is the one a fresh run would make) and reads its
``result.json``: the number of parameters whose hull is at most as wide, relative to the true value, as the
paper's Table 1 relative width (``width_analysis.at_most_paper`` of ``compared``), the geometric mean of those
ratios (``width_analysis.geometric_mean_ratio``), whether the truth is enclosed, and the design's content hash.
Prints the commit the figures were measured at (``git rev-parse --short HEAD``, ``+dirty`` with local changes).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def commit() -> str:
    """The checkout's commit, ``+dirty`` when tracked files differ from it."""
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT)
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True,
                           cwd=ROOT).stdout.strip()
    return head.stdout.strip() + ("+dirty" if dirty else "")


def run(seed: int, out: Path, quick: bool) -> dict:
    """One paper run's figures (module docstring)."""
    cmd = [sys.executable, "-m", "h4bench", "run", "paper", "--seed", str(seed), "--out", str(out), "--json"]
    subprocess.run(cmd + (["--quick"] if quick else []), check=True, capture_output=True, text=True, cwd=ROOT)
    r = json.loads((out / "result.json").read_text())
    a = r["width_analysis"]
    return {"seed": seed, "at_most_paper": a["at_most_paper"], "compared": a["compared"],
            "geometric_mean_ratio": a["geometric_mean_ratio"], "all_enclosed": r["methods"]["hull"]["all_enclosed"],
            "trajectory": r.get("content_hashes", {}).get("trajectory")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", type=Path, default=None, help="keep the runs in DIR/seed-S (default: a temp folder)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    at = commit()
    rows = []
    with tempfile.TemporaryDirectory(prefix="h4-paper-") as tmp:
        base = args.out or Path(tmp)
        for seed in args.seeds:
            row = run(seed, base / f"seed-{seed}", args.quick)
            rows.append(row)
            print(f"seed {seed}: hull at most the paper's relative width on {row['at_most_paper']} of "
                  f"{row['compared']}, geometric mean of the ratios {row['geometric_mean_ratio']:.3f}, truth "
                  f"{'enclosed' if row['all_enclosed'] else 'NOT enclosed'}, design {str(row['trajectory'])[:8]}",
                  file=sys.stderr, flush=True)
    counts = [r["at_most_paper"] for r in rows]
    means = [r["geometric_mean_ratio"] for r in rows]
    print(f"commit {at}, seeds {args.seeds}: at most as wide on {min(counts)}-{max(counts)} of "
          f"{rows[0]['compared']} parameters, geometric mean {min(means):.2f}-{max(means):.2f}, truth enclosed in "
          f"{sum(r['all_enclosed'] for r in rows)} of {len(rows)}")
    if args.json:
        print(json.dumps({"commit": at, "runs": rows}, indent=2))


if __name__ == "__main__":
    main()
