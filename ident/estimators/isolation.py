"""A plugin is untrusted code: each estimator that is not a built-in runs in a child process of its own.

What a plugin (an entry point, a ``"module:attribute"`` string or a callable) does cannot reach the caller:

- **inputs**: the child is forked (Linux ``fork``): it sees W, y, bound, the prior and the context copy-on-write,
  so changing them in place changes only the child's pages; the child also receives them as read-only views and
  compares a checksum of each after the call with the one taken before (a plugin that made a view writable again
  through ``.base`` is caught): a method that changed its inputs is failed, naming the arrays;
- **exits and crashes**: ``sys.exit``, ``KeyboardInterrupt`` raised by the plugin, any ``BaseException``,
  ``os._exit`` and a crash (SIGSEGV) end only the child and are reported as that method's failure, by name;
- **output**: the child's standard output (``print`` and file descriptor 1) goes to standard error, so a
  command's ``--json`` stays one JSON document;
- **time**: ``timeout`` seconds (default None: no limit) per method; past it the child is killed (SIGKILL) and
  the method fails with ``timeout``;
- **its import**: resolving a plugin (:func:`resolve`, :func:`available`) imports it in a child too: the caller
  learns its claims (kind, level, rigorous, description, citation) and the hash of its source (:data:`Resolved`),
  never running the plugin's import code itself; one plugin's import never runs another's.

The built-ins run in this process (they are the project's code, tested not to write to their inputs:
tests/ident/estimators/test_isolation.py), on read-only views of the inputs, with standard output sent to standard
error. With a ``timeout`` they run in a child too, so that the limit holds for every method.

Cost (``benchmarks/bench_isolation.py``, W of 10^6 x 14, y and bound, on this project's 2-core machine, median of 3):
read-only views 0.007 ms, copies 16 ms, one CRC-32 checksum pass over the inputs 33 ms, a whole isolated call of a
plugin that returns its prior (two checksum passes, the fork, the result over the pipe) 100 ms, against 272 ms for
the exact hull on the same rows. Copies would not catch ``os._exit``, output or time; the fork contains them all.
(The prior is not checksummed: :func:`registry.call` hands a plugin a new Box built from copies of its bounds.)

The child ends with ``os._exit`` (no ``atexit`` handlers, no flushing of the parent's buffers twice). The result
travels back pickled over a pipe; a box whose ``info`` cannot be pickled has those values replaced by their
``repr`` (under ``<key>_repr``). Python's own threads do not survive ``fork``; OpenBLAS and HiGHS are used in
children after the parent used them (tested: the hull in a child after the hull in the parent).
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import os
import pickle
import select
import signal
import sys
import time
import traceback
import zlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from h4bench.ident.box import Box
from h4bench.ident.errors import EstimatorError, InconsistentDataError
from h4bench.ident.estimators import registry

__all__ = ["MethodTimeout", "Resolved", "available", "call", "forget", "readonly", "resolve", "source_hash"]

_PR_SET_PDEATHSIG = 1


class MethodTimeout(EstimatorError):
    """A method ran longer than its time limit (its child process was killed)."""


@dataclass(frozen=True)
class Resolved:
    """What resolving a method found, without running its import code here: the :class:`registry.Estimator`
    (``func`` the method's string for a plugin, imported only in the child that runs it) and ``source``, the
    provenance of its code: ``{"module": file, "sha256": hash of its module's (or top-level package's) .py files,
    "distribution": name, "version": version}`` (the distribution only for an entry point; ``{"built-in": True}``
    for a built-in, whose code the project's own hash covers)."""

    estimator: registry.Estimator
    source: dict


def readonly(a):
    """A read-only view of an array (numbers and other objects are returned as they are); O(1)."""
    if isinstance(a, np.ndarray):
        v = a.view()
        v.flags.writeable = False
        return v
    return a


def _checksum(a) -> int | None:
    if not isinstance(a, np.ndarray):
        return None
    c = np.ascontiguousarray(a)
    return zlib.crc32(memoryview(c).cast("B")) ^ (hash((c.shape, c.dtype.str)) & 0xFFFFFFFF)


def _checksums(arrays: dict) -> dict:
    return {k: _checksum(v) for k, v in arrays.items()}


# ------------------------------------------------------------------------------------------------ the child
def _die_with_parent() -> None:
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
        except OSError:
            pass


def _where(exc: BaseException) -> str:
    tb = traceback.extract_tb(exc.__traceback__)
    return f" (at {tb[-1].filename}:{tb[-1].lineno})" if tb else ""


def _describe(exc: BaseException) -> dict:
    """An exception as plain data (a plugin's exception class may not unpickle here)."""
    out = {"type": type(exc).__name__, "message": str(exc), "where": _where(exc),
           "inconsistent": isinstance(exc, InconsistentDataError), "estimator_error": isinstance(exc, EstimatorError)}
    if isinstance(exc, InconsistentDataError):
        out.update(min_bound=exc.min_bound, bound=exc.bound, scale_lower=exc.scale_lower)
    if isinstance(exc, SystemExit):
        out["message"] = f"called sys.exit({exc.code!r})"
    return out


def _plain(v) -> bool:
    """True for what a result may carry back as it is: numbers, strings, None, numeric arrays, and lists, tuples
    and string-keyed dicts of those (never an object of the plugin's own classes: unpickling one here would
    import the plugin in this process)."""
    if v is None or isinstance(v, (bool, int, float, str, np.bool_, np.integer, np.floating)):
        return True
    if isinstance(v, np.ndarray):
        return v.dtype.kind in "biuf"
    if isinstance(v, (list, tuple)):
        return all(_plain(x) for x in v)
    if isinstance(v, dict):
        return all(isinstance(k, str) and _plain(x) for k, x in v.items())
    return False


def _plain_box(box: Box) -> Box:
    """``box`` with every ``info`` value that is not plain data (:func:`_plain`) replaced by its ``repr`` under
    ``<key>_repr``, and lower, upper and names as plain arrays and strings."""
    info = {}
    for k, v in box.info.items():
        if _plain(v):
            info[str(k)] = v
        else:
            try:
                text = repr(v)
            except Exception as exc:  # noqa: BLE001 - a repr that raises
                text = f"<{type(v).__name__} whose repr raised {type(exc).__name__}>"
            info[f"{k}_repr"] = text
    return Box(np.array(box.lower, dtype=float), np.array(box.upper, dtype=float), tuple(str(n) for n in box.names),
               info)


def _picklable(value) -> bytes:
    kind, payload = value
    if kind == "box":
        payload = _plain_box(payload)
    try:
        return pickle.dumps((kind, payload), protocol=pickle.HIGHEST_PROTOCOL)
    except Exception as exc:  # noqa: BLE001 - an exception's text or a claim that does not pickle
        return pickle.dumps(("raised", {"type": type(exc).__name__, "message": f"its result cannot be passed back "
                                        f"({exc})", "where": "", "inconsistent": False, "estimator_error": False}))


def _in_child(work, w: int) -> None:  # pragma: no cover - runs in the forked child (measured through the parent)
    try:
        _die_with_parent()
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the caller's: it stops the child (SIGKILL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        sys.stdout.flush()
        os.dup2(2, 1)  # the plugin's output goes to stderr: stdout stays the command's
        sys.stdout = sys.stderr
        try:
            value = work()
        except BaseException as exc:  # noqa: BLE001 - SystemExit, KeyboardInterrupt of the plugin included
            value = ("raised", _describe(exc))
        data = _picklable(value)
        view = memoryview(data)
        while view:
            view = view[os.write(w, view):]
        os.close(w)
        sys.stderr.flush()
    finally:
        os._exit(0)


def _forked(work, timeout: float | None, what: str):
    """Run ``work()`` in a forked child; returns its value (``("box" | "raised" | ..., payload)``) or raises
    EstimatorError (the child ended without a result: exit, crash) / :class:`MethodTimeout`."""
    sys.stdout.flush()
    sys.stderr.flush()
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        os.close(r)
        _in_child(work, w)
    os.close(w)
    chunks, status = [], None
    deadline = None if timeout is None else time.monotonic() + timeout
    try:
        while True:
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([r], [], [], wait)
            if not ready:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                status = "killed"
                raise MethodTimeout(f"{what}: timeout (still running after {timeout:g} s; stopped)")
            chunk = os.read(r, 1 << 16)
            if not chunk:
                break
            chunks.append(chunk)
        _, code = os.waitpid(pid, 0)
        status = "waited"
    finally:
        os.close(r)
        if status is None:  # interrupted (Ctrl-C) or failed while waiting: the child ends with us
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
    data = b"".join(chunks)
    if data:
        return pickle.loads(data)
    if os.WIFSIGNALED(code):
        sig = os.WTERMSIG(code)
        raise EstimatorError(f"{what}: its process was killed by {signal.Signals(sig).name} (a crash), no result")
    raise EstimatorError(f"{what}: ended its process (os._exit({os.WEXITSTATUS(code)}) or a crash) without a "
                         "result")


# --------------------------------------------------------------------------------------------- resolution
def _module_source(module_name: str) -> dict:
    mod = sys.modules.get(module_name)
    path = getattr(mod, "__file__", None)
    if not path:
        return {"module": module_name, "sha256": None}
    path = Path(path)
    top = sys.modules.get(module_name.split(".")[0])
    top_file = getattr(top, "__file__", None)
    if top_file and Path(top_file).name == "__init__.py":  # a package: every .py file of it
        root = Path(top_file).parent
        files = sorted(root.rglob("*.py"))
    else:
        root, files = path.parent, [path]
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return {"module": str(path), "sha256": h.hexdigest()}


def source_hash(func) -> dict:
    """The provenance of a loaded estimator callable's code: its module's (or top-level package's) file hash."""
    name = getattr(func, "__module__", None) or getattr(type(func), "__module__", "")
    if name not in sys.modules:
        try:
            path = inspect.getsourcefile(func)
        except TypeError:
            path = None
        return {"module": path, "sha256": hashlib.sha256(Path(path).read_bytes()).hexdigest() if path else None}
    return _module_source(name)


def _resolve_here(method: str) -> Resolved:
    """In the child: resolve the method string (imports it) and describe it as plain data."""
    est = registry.get(method)
    if est.origin == "built-in":
        return Resolved(est, {"built-in": True})
    if ":" in method:
        source = _module_source(method.partition(":")[0])
    else:  # an entry point: its distribution and its module's files
        ep = next(ep for ep in registry._entry_points() if ep.name == method)
        source = {**_module_source(ep.value.partition(":")[0]), "distribution": getattr(ep.dist, "name", None),
                  "version": getattr(ep.dist, "version", None)}
    return Resolved(replace(est, func=method), source)


_RESOLVED: dict = {}


def forget() -> None:
    """Forget the methods resolved in this process (e.g. after a plugin's file changed)."""
    _RESOLVED.clear()


def resolve(method) -> Resolved:
    """Resolve ``method`` (anything :func:`registry.get` takes) without running a plugin's import code here.

    A built-in resolves here (no import). A plugin is imported in a child process: EstimatorError naming it when
    it cannot load, raises at import, exits at import (``sys.exit``, ``os._exit``) or states bad claims.
    Remembered per process (a method string is resolved once)."""
    if isinstance(method, registry.Estimator):
        return Resolved(method, {"built-in": True} if method.origin == "built-in" else source_hash(method.resolve()))
    if isinstance(method, str) and method in registry.BUILTINS:
        return Resolved(registry.BUILTINS[method], {"built-in": True})
    if not isinstance(method, str):  # a callable: its attributes are read here, it runs in a child
        est = registry.get(method)
        return Resolved(est, source_hash(method))
    if method in _RESOLVED:
        return _RESOLVED[method]
    kind, payload = _forked(lambda: ("resolved", _resolve_here(method)), None, f"estimator {method!r} (loading it)")
    if kind != "resolved":
        if payload["estimator_error"]:
            raise EstimatorError(payload["message"] if repr(method) in payload["message"]
                                 else f"estimator {method!r}: {payload['message']}")
        raise EstimatorError(f"estimator {method!r}: cannot load ({payload['type']}: {payload['message']}"
                             f"{payload['where']})")
    _RESOLVED[method] = payload
    return payload


def available() -> registry.Available:
    """:func:`registry.available`, each entry point loaded in a child of its own (its import code never runs
    here; one that exits or crashes at import is listed as broken with the reason)."""
    found, broken = list(registry.BUILTINS.values()), []
    usable, problems = registry.entry_point_names()
    broken += problems
    for name in usable:
        try:
            found.append(resolve(name).estimator)
        except EstimatorError as exc:
            broken.append((name, str(exc)))
    return registry.Available(tuple(found), tuple(broken))


# ------------------------------------------------------------------------------------------------ the call
def call(method, W, y, bound, prior, timeout: float | None = None, **context) -> Box:
    """:func:`registry.call` with the plugin contained (module docstring): returns the checked Box; raises
    InconsistentDataError (proven empty, from a guaranteed method), :class:`MethodTimeout`, or EstimatorError
    naming the method for everything else it did (raised, exited, crashed, changed its inputs, bad result).

    W (N, p), y (N,), bound scalar or (N,) [y's units], prior a Box or (lower, upper); timeout [s] or None."""
    if timeout is not None and not (isinstance(timeout, (int, float)) and not isinstance(timeout, bool)
                                    and timeout > 0):
        raise ValueError(f"timeout must be a number of seconds > 0 or None, got {timeout!r}")
    res = resolve(method)
    est = res.estimator
    name = est.name
    inputs = {"W": readonly(W), "y": readonly(y), "bound": readonly(bound)}
    inputs.update({k: readonly(v) for k, v in context.items()})
    if est.origin == "built-in" and timeout is None:
        with contextlib.redirect_stdout(sys.stderr):
            return registry.call(est, inputs.pop("W"), inputs.pop("y"), inputs.pop("bound"), prior, **inputs)
    before = _checksums(inputs)
    target = est if est.origin == "built-in" else method

    def changed() -> list[str]:
        return [k for k, v in _checksums(inputs).items() if v != before[k]]

    def work():
        try:
            box = registry.call(target, inputs["W"], inputs["y"], inputs["bound"], prior,
                                **{k: v for k, v in inputs.items() if k not in ("W", "y", "bound")})
        except BaseException:  # a changed input outweighs what the method then raised (e.g. "inconsistent")
            if changed():
                return ("changed", changed())
            raise
        return ("changed", changed()) if changed() else ("box", box)

    kind, payload = _forked(work, timeout, f"estimator {name!r} ({est.origin})")
    if kind == "box":
        return payload
    if kind == "changed":
        raise EstimatorError(f"estimator {name!r} ({est.origin}) changed its inputs in place ({', '.join(payload)}); "
                             "its box is not kept (the other methods saw the original data)")
    if payload["inconsistent"]:
        raise InconsistentDataError(payload["message"], min_bound=payload["min_bound"], bound=payload["bound"],
                                    scale_lower=payload["scale_lower"])
    if payload["estimator_error"]:
        raise EstimatorError(payload["message"])
    raise EstimatorError(f"estimator {name!r} ({est.origin}) raised {payload['type']}: {payload['message']}"
                         f"{payload['where']}")
