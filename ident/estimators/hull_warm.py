"""The warm start of a hull's LPs over a smaller box (:func:`ident.estimators.hull.interval_hull`'s ``warm``).

A refinement round solves the same 2p LPs on the same rows over a smaller box (the previous round's result):
the optima move little. :class:`HullWarm` carries a hull's final working set and each LP's last optimal basis;
the next hull starts from the rows tight in some basis (:func:`tight_rows`) and each LP from its own basis.
Rows and bases steer the LPs only: the endpoints stay safe dual bounds whatever they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from h4bench.ident.numerics.lp import BASIC

__all__ = ["HullWarm", "tight_rows", "usable"]


@dataclass
class HullWarm:
    """A hull's final working set and its LPs' bases, to warm-start a hull of the same rows over a smaller box.

    rows : (k,) the working set's row indices in the model's order; bases : 2p entries, LP j's
    ``(col_status, row_status)`` after its last optimal solve (HiGHS basis statuses, for the model's first
    ``len(row_status)`` rows), or None. They steer the LPs only: any rows and any basis give rigorous endpoints.
    """

    rows: np.ndarray
    bases: list


def usable(warm: HullWarm | None, n_rows: int, n_lp: int, all_rows_up_to: int) -> bool:
    """Whether ``warm`` fits a hull of ``n_rows`` rows and ``n_lp`` LPs (distinct rows in range, one basis slot per
    LP, each basis over at most its rows); a problem of at most ``all_rows_up_to`` rows has every row from the start."""
    if warm is None or n_rows <= all_rows_up_to or len(warm.bases) != n_lp:
        return False
    rows = np.asarray(warm.rows)
    if rows.size == 0 or rows.min() < 0 or rows.max() >= n_rows or np.unique(rows).size != rows.size:
        return False
    return all(b is None or len(b[1]) <= rows.size for b in warm.bases)


def tight_rows(warm: HullWarm) -> tuple[np.ndarray, list]:
    """The rows of ``warm`` that are non-basic (tight) in some LP's basis, in their order, and the bases on them.

    A row basic in every basis (its slack basic: it cuts no LP's optimum) is dropped from each basis with its
    basic slack, so every basis keeps as many basic variables as rows. Without any basis, all rows."""
    rows = np.asarray(warm.rows, dtype=np.int64)
    known = [b for b in warm.bases if b is not None]
    if not known:
        return rows, list(warm.bases)
    tight = np.zeros(rows.size, dtype=bool)
    for _, rs in known:
        tight[: len(rs)] |= np.fromiter((st != BASIC for st in rs), dtype=bool, count=len(rs))
    keep = np.flatnonzero(tight)
    bases = [None if b is None else (b[0], [b[1][k] for k in keep[keep < len(b[1])]]) for b in warm.bases]
    return rows[keep], bases
