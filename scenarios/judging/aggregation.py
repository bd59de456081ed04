"""Campaign statistics of the judged methods (a room of :mod:`scenarios.judging`): coverage with its
Clopper-Pearson interval, misses, unsound runs, median widths."""

from __future__ import annotations

import numpy as np

__all__ = ["clopper_pearson", "summarise_methods"]


def clopper_pearson(k: int, n: int, alpha: float = 0.05) -> tuple[float, float]:
    """Exact (Clopper-Pearson) two-sided ``1 - alpha`` interval of a binomial proportion ``k / n``:
    ``beta.ppf(alpha/2, k, n-k+1)``, ``beta.ppf(1-alpha/2, k+1, n-k)``, with 0 and 1 at the ends.

    The quantiles are the inverse regularised incomplete beta function (``scipy.special.betaincinv``, what
    ``scipy.stats.beta.ppf`` evaluates: the same values bit for bit, tested) without importing ``scipy.stats``
    (about a second of a campaign's report)."""
    from scipy.special import betaincinv

    if n <= 0:
        return (0.0, 1.0)
    lo = 0.0 if k == 0 else float(betaincinv(k, n - k + 1, alpha / 2))
    hi = 1.0 if k == n else float(betaincinv(k + 1, n - k, 1 - alpha / 2))
    return (lo, hi)


def summarise_methods(runs: list[dict]) -> dict:
    """Per method over a campaign's runs (each a result with ``methods`` entries of :func:`judge`): the claims,
    ``runs``, ``misses`` (runs whose box does not enclose the truth), ``failed_runs`` (seeds of runs without a box:
    failed or proven empty), ``unsound_runs``, ``flagged_runs`` (runs with a miss or an unsound verdict),
    ``coverage`` (runs whose box encloses the truth / runs: a run
    without a box does not cover) with
    ``coverage_ci`` (Clopper-Pearson 95 %), ``width_vs_hull_median`` per parameter, median ``seconds``, and the
    earlier keys (``miss_seeds``, ``relative_width_median`` ...)."""
    first = runs[0]
    p = len(first["true"])
    names = list(dict.fromkeys(n for r in runs for n in r["methods"]))
    methods = {}
    for name in names:
        entries = [(r, r["methods"][name]) for r in runs if name in r["methods"]]
        ok = [(r, m) for r, m in entries if m.get("status") == "ok"]
        claims = next((m for _, m in entries if m.get("kind") is not None), entries[0][1])
        enclosed = np.array([m["enclosed"] for _, m in ok]) if ok else np.zeros((0, p), bool)
        misses = [r["seed"] for r, m in ok if not m["all_enclosed"]]
        covered = [r["seed"] for r, m in ok if not m["all_enclosed"] and r["bound_covers_residual"]]
        rel_w = np.array([np.asarray(m["width"]) / np.abs(np.asarray(r["true"])) for r, m in ok])
        wvh = np.array([[np.nan if v is None else v for v in m["width_vs_hull"]] for _, m in ok
                        if m.get("width_vs_hull")], dtype=float)
        n = len(entries)
        k = len(ok) - len(misses)
        unsound = [r["seed"] for r, m in entries if m.get("unsound")]
        failed = [r["seed"] for r, m in entries if m.get("status") != "ok"]
        messages = sorted({m.get("message", "") for _, m in entries if m.get("status") == "failed"})
        with np.errstate(all="ignore"):
            wvh_med = np.nanmedian(wvh, axis=0).tolist() if len(wvh) else []
        methods[name] = {
            "kind": claims.get("kind"), "rigorous": claims.get("rigorous"), "level": claims.get("level"),
            "origin": claims.get("origin"), "status": "ok" if ok else "failed",
            "lower": ok[0][1]["lower"] if ok else None, "upper": ok[0][1]["upper"] if ok else None,
            "enclosed": enclosed.all(axis=0).tolist() if len(ok) else [],
            "all_enclosed": bool(len(ok) == n and enclosed.all()),
            "runs": n, "misses": len(misses), "miss_seeds": misses,
            "misses_with_bound_covering_residual": covered, "failed_runs": failed,
            "failure_messages": messages[:5],
            "unsound_runs": len(unsound), "unsound_seeds": unsound,
            "flagged_runs": len({*misses, *unsound}),
            "coverage": k / n if n else None, "coverage_ci": list(clopper_pearson(k, n)),
            "width_vs_hull_median": [None if not np.isfinite(v) else float(v) for v in wvh_med],
            "relative_width_median": np.median(rel_w, axis=0).tolist() if len(ok) else [],
            "relative_width_p90": np.percentile(rel_w, 90, axis=0).tolist() if len(ok) else [],
            "seconds": float(np.median([m["seconds"] for _, m in entries if m.get("seconds") is not None])),
        }
    return methods
