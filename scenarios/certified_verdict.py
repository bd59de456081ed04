"""What a certified result says beyond its box, for every robot kind: a stated motion bound the data prove false
(:func:`contradicted_entry`), the parameters a box leaves at their prior and why (:func:`prior_diagnosis`), and the
row radius named by its parts (:func:`row_radius_summary`).

A certified box is only as good as its error specification; these are the checks that need no truth:

* the stated ``qd_max``, ``qdd_max`` against what the positions prove (:mod:`ident.processing.motion_check`): a
  bound below the proven one is a false premise, so no box is claimed (status :data:`SPEC_CONTRADICTED`);
* a box that stays at the prior on some parameters is not an identification of them: the term of the row radius
  that dominates (at the box's largest ``|theta|``) says what would help.
"""

from __future__ import annotations

import numpy as np

__all__ = ["H4_HINTS", "SERIAL_HINTS", "SPEC_CONTRADICTED", "contradicted_entry", "contradiction_lines",
           "prior_diagnosis", "row_radius_summary"]

SPEC_CONTRADICTED = "spec_contradicted"  # the method entry's status when the data prove a stated bound false
AT_PRIOR = 0.99  # a parameter whose width is at least this fraction of its prior's is "at the prior"

# what would shrink each term of the radius (the H4's derived equation, ident.robots.h4_certified)
H4_HINTS = {
    "torque": "a smaller stated torque_error (better drive or current sensing) or a longer log",
    "model": "a smaller stated model_error",
    "rounding": "nothing in the specification (floating-point rounding of the rows)",
    "measurement": "a finer encoder (counts_per_turn) or a longer kernel (kernel_steps: the encoder's first-order "
                   "radius falls about as 1 / kernel_steps^2 on the acceleration columns)",
    "second_order": "a finer encoder (counts_per_turn): the encoder's second-order term does not shrink with the "
                    "kernel",
    "truncation": "a finer encoder (counts_per_turn: each step's motion tube holds the position error, and the "
                  "nacelle terms' second derivatives over it grow fast with its width) or a tighter stated qdd_max",
    "sign": "a tighter stated qdd_max or a motion with fewer slow speed reversals (the Coulomb sign is uncertain "
            "near rest)",
}
# the same for a serial robot (ident.robots.serial_certified)
SERIAL_HINTS = {
    "position": "a finer position resolution (more counts or written digits) or a longer kernel (kernel_steps)",
    "motion": "a tighter stated qdd_max (and qd_max) or a faster sample rate",
    "coulomb": "a tighter stated qdd_max or a motion with fewer slow speed reversals",
    "float": "nothing in the specification (the stated floating-point allowance)",
    "torque": "a smaller stated torque_error (or torque_rate) or a longer log",
    "model": "a smaller stated model_error",
    "rounding": "nothing in the specification (floating-point rounding of the rows)",
}


def contradiction_lines(check, label: str) -> list[str]:
    """One line per stated bound the data prove false, each starting with ``label`` (e.g. ``--spec FILE``)."""
    return [f"{label}: {c}" for c in check.contradicted]


def contradicted_entry(check, label: str) -> dict:
    """The ``certified`` method entry when the data contradict the stated motion bounds: no box, the status
    :data:`SPEC_CONTRADICTED` and every contradiction (entry, joint, stated value, proven lower bound)."""
    lines = contradiction_lines(check, label)
    return {"kind": "guaranteed", "rigorous": True, "status": SPEC_CONTRADICTED,
            "message": "; ".join(lines) + " (no box is claimed: the certified radii rest on the stated bounds)",
            "contradicted": lines, "contradictions": check.contradictions}


def _row_terms(terms: dict, theta_abs) -> dict:
    return {k: (np.asarray(v) @ theta_abs if np.ndim(v) == 2 else np.asarray(v, dtype=float)) for k, v in terms.items()}


def row_radius_summary(bound, D, theta_abs, at: str) -> dict:
    """The row radius by its parts [N m]: ``torque_side_max``/``_median`` (the theta-free part: torque, model and
    rounding terms) and ``total_median``/``_max`` (``bound + D |theta|`` at ``theta_abs``, described by ``at``)."""
    total = np.asarray(bound) + np.asarray(D) @ np.abs(np.asarray(theta_abs, dtype=float))
    return {"torque_side_max": float(np.max(bound)), "torque_side_median": float(np.median(bound)),
            "total_median": float(np.median(total)), "total_max": float(np.max(total)), "at": at}


def prior_diagnosis(names, relative_width, terms: dict, theta_abs, y, hints: dict) -> dict:
    """Which parameters a box leaves at the prior and which radius term is why.

    names (p,); relative_width (p,) box width / prior width; terms: name -> (m, p) regressor-side radii (units of
    W) or (m,) torque-side radii [N m]; theta_abs (p,) the |theta| the radii are evaluated at (the box's largest
    magnitudes); y (m,) [N m]; hints: term -> what would shrink it. Returns ``parameters`` (those at the prior),
    ``dominant`` (the term of largest share of the summed row radii), ``share``, ``radius_median``, ``y_median``
    [N m], ``columns`` (the columns carrying most of a regressor-side dominant term, each with its largest radius
    per unit parameter), ``help`` and ``message`` (None when no parameter is at the prior).
    """
    rel = np.asarray(relative_width, dtype=float)
    th = np.abs(np.asarray(theta_abs, dtype=float))
    rows = _row_terms(terms, th)
    summed = {k: float(np.sum(v)) for k, v in rows.items()}
    total = sum(summed.values()) or 1.0
    dominant = max(summed, key=summed.get)
    radius = sum(rows.values())
    out = {"parameters": [str(n) for n, r in zip(names, rel) if r >= AT_PRIOR], "dominant": dominant,
           "share": summed[dominant] / total, "radius_median": float(np.median(radius)),
           "y_median": float(np.median(np.abs(y))), "columns": [], "help": hints.get(dominant, ""), "message": None}
    term = np.asarray(terms[dominant])
    if term.ndim == 2:
        contrib = term.sum(axis=0) * th
        order = np.argsort(-contrib, kind="stable")
        cum = np.cumsum(contrib[order]) / max(float(contrib.sum()), 1e-300)
        keep = order[: int(np.searchsorted(cum, 0.9)) + 1]
        out["columns"] = [{"name": str(names[j]), "max_radius_per_unit": float(term[:, j].max())} for j in keep]
    if out["parameters"]:
        shown = out["columns"][:6]
        more = f" and {len(out['columns']) - 6} more" if len(out["columns"]) > 6 else ""
        cols = (" on the " + ", ".join(c["name"] for c in shown) + f"{more} column(s) (radius up to "
                + ", ".join(f"{c['max_radius_per_unit']:.3g}" for c in shown) + " N m per unit parameter)"
                if shown else "")
        out["message"] = (f"{len(out['parameters'])} of {len(rel)} parameters stay at the prior "
                          f"({', '.join(out['parameters'])}): the rows' radius is dominated by the {dominant} term"
                          f"{cols}: {100 * out['share']:.1f} % of the summed radii, median row radius "
                          f"{out['radius_median']:.3g} N m against a median |y| of {out['y_median']:.3g} N m. "
                          f"What would help: {out['help']}.")
    return out
