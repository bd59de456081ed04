"""Calling an estimator by name with a plugin contained, and what resolving it found (its claims, its source).

The containment itself is the registry's door (:mod:`ident.estimators.door`): a plugin named by a string (an entry
point, ``"module:attribute"``) resolves to an :class:`~ident.estimators.door.Isolated` callable that runs it in a
forked child at every call, whoever calls it (``ident.estimate``, :func:`registry.call`, this module's
:func:`call`). This module adds what a caller by name needs: :func:`call` with a per-call ``timeout``, a callable
plugin contained too, the built-ins on read-only views; :func:`resolve` with the plugin's source hash; and
:func:`available`.

The built-ins run in this process (they are the project's code, tested not to write to their inputs:
tests/ident/estimators/test_isolation.py), on read-only views of the inputs, with standard output sent to standard
error. With a ``timeout`` they run in a child too, so that the limit holds for every method.

Cost (``benchmarks/bench_isolation.py``, W of 10^6 x 14, y and bound, on this project's 2-core machine, median of 3):
read-only views 0.007 ms, copies 16 ms, one CRC-32 checksum pass over the inputs 33 ms, a whole isolated call of a
plugin that returns its prior (two checksum passes, the fork, the result over the pipe) 100 ms, against 272 ms for
the exact hull on the same rows. Copies would not catch ``os._exit``, output or time; the fork contains them all.
"""

from __future__ import annotations

import contextlib
import sys
from dataclasses import dataclass, replace

from h4bench.ident.box import Box
from h4bench.ident.estimators import registry
from h4bench.ident.estimators.door import InputsChanged, Isolated, MethodTimeout, readonly, source_hash

__all__ = ["InputsChanged", "MethodTimeout", "Resolved", "available", "call", "contained", "forget", "readonly",
           "resolve", "source_hash"]


@dataclass(frozen=True)
class Resolved:
    """What resolving a method found, without running its import code here: the :class:`registry.Estimator`
    (``func`` for a plugin named by a string the :class:`~ident.estimators.door.Isolated` callable: it is imported
    only in the children that run it) and ``source``, the provenance of its code: ``{"module": file, "sha256": hash
    of its module's (or top-level package's) .py files, "distribution": name, "version": version}`` (the
    distribution only for an entry point; ``{"built-in": True}`` for a built-in, whose code the project's own hash
    covers)."""

    estimator: registry.Estimator
    source: dict


def forget() -> None:
    """Forget the methods resolved in this process (e.g. after a plugin's file changed): :func:`registry.forget`."""
    registry.forget()


def resolve(method) -> Resolved:
    """Resolve ``method`` (anything :func:`registry.get` takes) without running a plugin's import code here.

    A built-in resolves here (no import). A plugin named by a string is imported in a child process
    (:func:`registry.get`): EstimatorError naming it when it cannot load, raises at import, exits at import
    (``sys.exit``, ``os._exit``) or states bad claims. Remembered per process (a method string is resolved once)."""
    est = registry.get(method)
    if est.origin == "built-in":
        return Resolved(est, {"built-in": True})
    if isinstance(est.func, Isolated):
        return Resolved(est, est.func.source)
    return Resolved(est, source_hash(est.resolve()))


def available() -> registry.Available:
    """:func:`registry.available`: each entry point loaded in a child of its own (its import code never runs
    here; one that exits or crashes at import is listed as broken with the reason)."""
    return registry.available()


# ------------------------------------------------------------------------------------------------ the call
def call(method, W, y, bound, prior, timeout: float | None = None, **context) -> Box:
    """:func:`registry.call` with the method contained: a plugin (named, or a callable) runs in a forked child
    (:class:`~ident.estimators.door.Isolated`), a built-in here on read-only views (in a child too when ``timeout``
    is given). Returns the checked Box; raises InconsistentDataError (proven empty, from a guaranteed method),
    :class:`MethodTimeout`, :class:`InputsChanged`, or EstimatorError naming the method for everything else it did
    (raised, exited, crashed, bad result).

    W (N, p), y (N,), bound scalar or (N,) [y's units], prior a Box or (lower, upper); timeout [s] or None."""
    if timeout is not None and not (isinstance(timeout, (int, float)) and not isinstance(timeout, bool)
                                    and timeout > 0):
        raise ValueError(f"timeout must be a number of seconds > 0 or None, got {timeout!r}")
    est = registry.get(method)
    if est.origin == "built-in" and timeout is None:
        inputs = {k: readonly(v) for k, v in context.items()}
        with contextlib.redirect_stdout(sys.stderr):
            return registry.call(est, readonly(W), readonly(y), readonly(bound), prior, **inputs)
    return registry.call(contained(est, timeout), W, y, bound, prior, **context)


def contained(est: registry.Estimator, timeout: float | None = None) -> registry.Estimator:
    """``est`` (a :class:`registry.Estimator`) with ``func`` an :class:`~ident.estimators.door.Isolated` of time
    limit ``timeout`` [s] (None: no limit): every call of it runs in a forked child, a built-in or a callable too."""
    door = est.func if isinstance(est.func, Isolated) else Isolated(est.name, est.origin, est.resolve())
    return replace(est, func=door.limited(timeout))
