"""Where do two results differ? ``h4bench compare A/result.json B/result.json`` (and
``benchmarks/compare_results.py``, which compares folders of quick runs with the same code).

Two runs are compared as parsed JSON: floats with ``==`` (bit for bit, NaN written as null on both sides),
lists element by element, dicts key by key. Ignored wherever they appear: the keys in :data:`IGNORED` (timings,
throughput, provenance hashes of the code, paths, the platform a run was computed on) and every key ending in
``seconds``; the model path (:data:`CHECKOUT_PATHS`) is compared inside its checkout (``models/h4.xml``).

A run's ``content_hashes`` name its stages in the order they are made (:data:`STAGES`: the designed trajectory,
the controller, the feed-forward, the simulated dataset), so the first that differs says where two runs part:
everything after it follows from it. Then come the other differences (boxes, verdicts, ...), as JSON paths.
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["CHECKOUT_PATHS", "IGNORED", "STAGES", "compare_results", "differences", "first_stage", "load_result"]

#: Keys whose values are timings, paths, hashes of the code or the platform: never compared (anywhere in the tree).
IGNORED = frozenset({
    "timings", "seconds", "wall_seconds", "runs_per_minute", "provenance", "code_hash", "spec_hash",
    "model_hash", "version", "versions", "out", "path", "folder", "replay", "stage_seconds", "campaign_timings",
    "platform",
})

#: Keys whose values are files of the checkout (the model): compared by their path inside it (``models/h4.xml``),
#: so that two checkouts of the same code compare equal while another model file still shows.
CHECKOUT_PATHS = frozenset({"model"})

#: A run's stages in the order they are made (keys of ``result.json``'s ``content_hashes``).
STAGES = ("trajectory", "controller", "feedforward", "dataset")


def _in_checkout(path: str) -> str:
    return "/".join(Path(path).parts[-2:])


def differences(a, b, where: str = "") -> list[str]:
    """Every difference between two parsed JSON values (ignoring :data:`IGNORED` keys), as lines
    ``path: before -> after`` (or ``path: only before/after``)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k in IGNORED or k.endswith("seconds"):
                continue
            if k not in a or k not in b:
                out.append(f"{where}/{k}: only {'after' if k not in a else 'before'}")
                continue
            if k in CHECKOUT_PATHS and isinstance(a[k], str) and isinstance(b[k], str):
                out += differences(_in_checkout(a[k]), _in_checkout(b[k]), f"{where}/{k}")
                continue
            out += differences(a[k], b[k], f"{where}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: length {len(a)} -> {len(b)}"]
        out = []
        for i, (x, y) in enumerate(zip(a, b)):
            out += differences(x, y, f"{where}[{i}]")
        return out
    if type(a) is not type(b) or a != b:
        return [f"{where}: {a!r} -> {b!r}"]
    return []


def first_stage(a: dict, b: dict) -> str | None:
    """The first of :data:`STAGES` whose content hash differs between two results (a hash missing on one side
    counts as different), or None when all agree."""
    ha, hb = a.get("content_hashes") or {}, b.get("content_hashes") or {}
    return next((s for s in STAGES if ha.get(s) != hb.get(s)), None)


def load_result(path) -> dict:
    """A run's result: ``path`` is a result.json or a folder holding one. Raises ValueError if neither."""
    p = Path(path)
    if p.is_dir():
        p = p / "result.json"
    try:
        return json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{str(path)!r} must be a result.json or a run folder holding one ({exc})") from None


def compare_results(a: dict, b: dict, limit: int = 40) -> tuple[list[str], int]:
    """(report lines, number of differences) of two parsed results: the first stage that differs (or that all
    agree), each stage's hashes when one differs, the platforms when they differ, then up to ``limit``
    differences."""
    lines = []
    stage = first_stage(a, b)
    ha, hb = a.get("content_hashes") or {}, b.get("content_hashes") or {}
    if stage is None and ha:
        lines.append(f"same {', '.join(STAGES)} ({len(ha)} content hashes agree)")
    elif stage is not None:
        lines.append(f"first difference: {stage} (content hash {str(ha.get(stage))[:12]} -> {str(hb.get(stage))[:12]})")
    pa, pb = a.get("platform"), b.get("platform")
    if pa != pb:
        lines.append(f"platforms: {json.dumps(pa)} | {json.dumps(pb)}")
    diff = differences(a, b)
    lines.append("results identical" if not diff else f"{len(diff)} difference(s) in the results:")
    lines += [f"  {line}" for line in diff[:limit]]
    if len(diff) > limit:
        lines.append(f"  ... {len(diff) - limit} more")
    return lines, len(diff)
