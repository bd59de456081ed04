"""The one door for untrusted code: a plugin's callable that always runs in a forked child process.

Resolving an estimator that is not a built-in (an entry point, a ``"module:attribute"`` string:
:func:`ident.estimators.registry.get`) gives an :class:`Isolated` callable, never the plugin's own function: whoever
calls it (``ident.estimate``, :func:`registry.call`, the replay's box history, the projections, the conformance
check, a benchmark) runs the plugin in a child of its own. What the plugin does cannot reach the caller:

- **inputs**: the child is forked (Linux ``fork``): it sees W, y, bound, the prior and the context copy-on-write,
  so changing them in place changes only the child's pages; the plugin gets read-only views, and a checksum of each
  input (the prior's bounds included) taken before the call is compared after it (a plugin that made a view
  writable again through ``.base`` is caught): a method that changed its inputs fails (:class:`InputsChanged`,
  naming the arrays);
- **exits and crashes**: ``sys.exit``, ``KeyboardInterrupt`` raised by the plugin, any ``BaseException``,
  ``os._exit`` and a crash (SIGSEGV) end only the child and come back as an EstimatorError naming the method;
- **output**: the child's standard output (``print`` and file descriptor 1) goes to standard error, so a
  command's ``--json`` stays one JSON document;
- **time**: an :class:`Isolated` with a ``timeout`` [s] kills its child (SIGKILL) past it: :class:`MethodTimeout`;
- **its import**: resolving a plugin imports it in a child too (:func:`resolve_in_child`): the caller learns its
  claims and the hash of its source, never running the plugin's import code itself.

The child ends with ``os._exit`` (no ``atexit`` handlers, no flushing of the parent's buffers twice). The result
travels back pickled over a pipe; a box whose ``info`` cannot be pickled has those values replaced by their
``repr`` (under ``<key>_repr``); a result that is an object of the plugin's own classes is refused by its type name
(unpickling it would import the plugin here). Python's own threads do not survive ``fork``; OpenBLAS and HiGHS are
used in children after the parent used them (tested: the hull in a child after the hull in the parent).

This module imports no estimator: the registry hands it what runs in the child (``run_here``).
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
from pathlib import Path
from typing import Callable

import numpy as np

from h4bench.ident.box import Box
from h4bench.ident.errors import EstimatorError, InconsistentDataError

__all__ = ["InputsChanged", "Isolated", "MethodTimeout", "checksums", "forked", "module_source", "readonly",
           "resolve_in_child", "source_hash"]

_PR_SET_PDEATHSIG = 1


class MethodTimeout(EstimatorError):
    """A method ran longer than its time limit (its child process was killed)."""


class InputsChanged(EstimatorError):
    """A method changed its inputs in place (in its child: the caller's arrays are untouched); ``inputs`` names
    them (``"W"``, ``"y"``, ``"bound"``, ``"prior.lower"``, ``"prior.upper"`` or a context keyword)."""

    def __init__(self, message: str, *, inputs) -> None:
        super().__init__(message)
        self.inputs = tuple(inputs)


def readonly(a):
    """A read-only view of an array (numbers and other objects are returned as they are); O(1)."""
    if isinstance(a, np.ndarray):
        v = a.view()
        v.flags.writeable = False
        return v
    return a



# ------------------------------------------------------------------------------------------------ the child
def _checksum(a) -> int | None:
    if not isinstance(a, np.ndarray):
        return None
    c = np.ascontiguousarray(a)
    return zlib.crc32(memoryview(c).cast("B")) ^ (hash((c.shape, c.dtype.str)) & 0xFFFFFFFF)


def checksums(arrays: dict) -> dict:
    """CRC-32 of each array of ``arrays`` (with its shape and dtype; None for what is not an array): one pass."""
    return {k: _checksum(v) for k, v in arrays.items()}

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
    if kind == "box" and isinstance(payload, Box):
        payload = _plain_box(payload)
    elif kind == "box" and not _plain(payload):  # an object of the plugin's own: unpickling it would import it here
        kind, payload = "not a box", type(payload).__name__
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


def forked(work, timeout: float | None, what: str):
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


# --------------------------------------------------------------------------------------------- provenance
def module_source(module_name: str) -> dict:
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
    return module_source(name)


# ------------------------------------------------------------------------------------------------ the door
class Isolated:
    """A method behind the door: ``Isolated(name, origin, run_here)(W, y, bound, prior, **context) -> Box`` runs
    ``run_here(W, y, bound, prior, **context)`` in a forked child (module docstring).

    name, origin : what the messages name (``estimator 'name' (origin)``); run_here : what the child runs (for a
    plugin named by a string: import it, call it, check its box; it is never called in this process);
    timeout : seconds or None (no limit); source : the provenance of the plugin's code (:func:`module_source`).
    W (N, p), y (N,), bound (N,) [y's units], prior a Box, context arrays: passed as read-only views.
    Returns what the method returned (a Box, its ``info`` made plain data; or plain data such as a
    ``(lower, upper)`` pair, for the registry to check). Raises :class:`InconsistentDataError` (proven empty),
    :class:`MethodTimeout`, :class:`InputsChanged`, or EstimatorError naming the method for everything else it
    did (raised, exited, crashed, returned an object of its own class).
    """

    def __init__(self, name: str, origin: str, run_here: Callable, *, timeout: float | None = None,
                 source: dict | None = None) -> None:
        self.name, self.origin, self.run_here, self.timeout = name, origin, run_here, timeout
        self.source = source or {}

    def limited(self, timeout: float | None) -> "Isolated":
        """The same method with the time limit ``timeout`` [s] (None: no limit)."""
        return Isolated(self.name, self.origin, self.run_here, timeout=timeout, source=self.source)

    def __repr__(self) -> str:
        return f"Isolated({self.name!r}, {self.origin!r}, timeout={self.timeout!r})"

    def __call__(self, W, y, bound, prior, **context):
        what = f"estimator {self.name!r} ({self.origin})"
        inputs = {"W": readonly(W), "y": readonly(y), "bound": readonly(bound)}
        inputs.update({k: readonly(v) for k, v in context.items()})
        watched = dict(inputs)
        if isinstance(prior, Box):
            watched.update({"prior.lower": prior.lower, "prior.upper": prior.upper})

        def work():  # in the child: the checksums of the inputs before and after the call
            before = checksums(watched)

            def changed() -> list[str]:
                return [k for k, v in checksums(watched).items() if v != before[k]]

            try:
                value = self.run_here(inputs.pop("W"), inputs.pop("y"), inputs.pop("bound"), prior, **inputs)
            except BaseException:  # a changed input outweighs what the method then raised (e.g. "inconsistent")
                if changed():
                    return ("changed", changed())
                raise
            return ("changed", changed()) if changed() else ("box", value)

        kind, payload = forked(work, self.timeout, what)
        if kind == "box":
            return payload
        if kind == "changed":
            raise InputsChanged(f"{what} changed its inputs in place ({', '.join(payload)}); its box is not kept "
                                "(the other methods saw the original data)", inputs=payload)
        if kind == "not a box":
            raise EstimatorError(f"{what} returned a {payload}, not an ident.Box")
        if payload["inconsistent"]:
            raise InconsistentDataError(payload["message"], min_bound=payload["min_bound"], bound=payload["bound"],
                                        scale_lower=payload["scale_lower"])
        if payload["estimator_error"]:
            raise EstimatorError(payload["message"])
        raise EstimatorError(f"{what} raised {payload['type']}: {payload['message']}{payload['where']}")


def resolve_in_child(method: str, describe_here: Callable):
    """``describe_here(method)`` (which imports the plugin) run in a forked child: its value, plain data.

    EstimatorError naming ``method`` when the plugin cannot load, raises at import, exits at import
    (``sys.exit``, ``os._exit``), crashes or states bad claims."""
    kind, payload = forked(lambda: ("resolved", describe_here(method)), None, f"estimator {method!r} (loading it)")
    if kind == "resolved":
        return payload
    if payload["estimator_error"]:
        raise EstimatorError(payload["message"] if repr(method) in payload["message"]
                             else f"estimator {method!r}: {payload['message']}")
    raise EstimatorError(f"estimator {method!r}: cannot load ({payload['type']}: {payload['message']}"
                         f"{payload['where']})")
