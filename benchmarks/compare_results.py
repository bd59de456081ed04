"""Did a change alter any result? Run every quick scenario into a folder, then compare two such folders bit for
bit outside the keys that are timings, paths or code hashes.

    python benchmarks/compare_results.py run DIR [--skip tx40] [--workers 1]
    python benchmarks/compare_results.py compare BEFORE AFTER [--runs]

``run`` calls ``h4bench run NAME --quick --json --out DIR/NAME`` for every scenario ``h4bench scenarios`` lists
(minus ``--skip``), one after the other, and writes ``DIR/times.txt`` (exit code and wall seconds per scenario).
Keep DIR outside the repository; run it on the base commit first, then on the change.

``compare`` loads ``NAME/result.json`` of both folders (and with ``--runs`` a campaign's ``runs/*.json`` too) and
compares them as ``h4bench compare`` does (:func:`h4bench.scenarios.compare.differences`: parsed JSON, floats bit
for bit, timings, paths, code hashes and the platform ignored). Prints every difference (a JSON path, before,
after) and the keys present on one side only; exit code 0 when nothing differs, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from h4bench.scenarios.compare import IGNORED, differences  # noqa: F401  (IGNORED: re-exported for callers)


def scenarios() -> list[str]:
    out = subprocess.run(["h4bench", "scenarios"], capture_output=True, text=True, check=True).stdout
    return [line.split()[0] for line in out.splitlines() if line.strip()]


def run_all(folder: Path, skip: set[str], workers: int | None) -> int:
    folder.mkdir(parents=True, exist_ok=True)
    failed = 0
    for name in scenarios():
        if name in skip:
            continue
        cmd = ["h4bench", "run", name, "--quick", "--json", "--out", str(folder / name)]
        if workers is not None and name.startswith("enclosure"):
            cmd += ["--workers", str(workers)]
        t0 = time.perf_counter()
        with open(folder / f"{name}.stdout", "w") as so, open(folder / f"{name}.stderr", "w") as se:
            rc = subprocess.run(cmd, stdout=so, stderr=se).returncode
        line = f"{name} rc={rc} {time.perf_counter() - t0:.2f} s"
        print(line, flush=True)
        with open(folder / "times.txt", "a") as f:
            f.write(line + "\n")
        failed += rc != 0
    return 1 if failed else 0


def compare(before: Path, after: Path, runs: bool) -> int:
    total = 0
    for res in sorted(before.glob("*/result.json")):
        name = res.parent.name
        pairs = [(res, after / name / "result.json")]
        if runs:
            pairs += [(p, after / name / "runs" / p.name) for p in sorted((res.parent / "runs").glob("*.json"))]
        for p_before, p_after in pairs:
            if not p_after.is_file():
                print(f"{name}: {p_after} missing")
                total += 1
                continue
            diff = differences(json.loads(p_before.read_text()), json.loads(p_after.read_text()))
            label = f"{name}/{p_before.relative_to(res.parent)}"
            print(f"{label}: {'identical' if not diff else f'{len(diff)} difference(s)'}")
            for line in diff[:40]:
                print(f"  {line}")
            total += len(diff)
    return 1 if total else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run")
    p_run.add_argument("folder", type=Path)
    p_run.add_argument("--skip", default="", help="comma-separated scenario names not to run (e.g. tx40)")
    p_run.add_argument("--workers", type=int, default=None, help="campaigns' local workers")
    p_cmp = sub.add_parser("compare")
    p_cmp.add_argument("before", type=Path)
    p_cmp.add_argument("after", type=Path)
    p_cmp.add_argument("--runs", action="store_true", help="also compare a campaign's runs/*.json")
    args = parser.parse_args()
    if args.command == "run":
        sys.exit(run_all(args.folder, {s for s in args.skip.split(",") if s}, args.workers))
    sys.exit(compare(args.before, args.after, args.runs))


if __name__ == "__main__":
    main()
