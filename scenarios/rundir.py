"""Run folders: written atomically, owned, and never anything else.

A run folder is built in a temporary sibling (``.<name>.tmp-<pid>``) and swapped into place only when complete,
so an interrupted run never leaves a result that looks complete. h4bench replaces or deletes only what it wrote
itself: a folder carrying its marker file :data:`MARKER` (written first into every run folder). An existing
target that is a file, or a folder without the marker and not empty, is refused with a :class:`RunFolderError`
that names the option (``--out``). A temporary folder left by a killed run (its process is gone) is removed by
the next run with the same target.

The kinds of scenario use :func:`save_run_files` to write the dataset, the truth, the trajectory and the replay.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

from h4bench.sim.dataset import atomic_write_bytes, json_default

RUNS_DIR = Path("runs")
MARKER = ".h4bench-run"


class RunFolderError(ValueError):
    """An output folder h4bench may not write (a user's file or folder, an unwritable place)."""


def json_safe(obj, _seen: frozenset = frozenset()):
    """``obj`` with everything JSON cannot hold made plain: numpy values as numbers and lists, a dict key that is
    not a string as its ``str``, and any other object (a plugin's ``Box.info`` may carry one) as
    ``{"repr": repr(obj), "type": its class name, "note": "not JSON: its repr"}``; a container that holds itself
    becomes ``"<recursion>"``."""
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    if id(obj) in _seen:
        return "<recursion>"
    seen = _seen | {id(obj)}
    if isinstance(obj, dict):
        return {(k if isinstance(k, str) else str(k)): json_safe(v, seen) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v, seen) for v in obj]
    try:
        return json_safe(json_default(obj), seen)
    except TypeError:
        pass
    try:
        text = repr(obj)
    except Exception as exc:  # noqa: BLE001 - a repr that raises
        text = f"<repr raised {type(exc).__name__}>"
    return {"repr": text, "type": type(obj).__name__, "note": "not JSON: its repr"}


def finite_json(obj, indent: int | None = 2) -> str:
    """``obj`` as strict JSON text: numpy values converted, every non-finite number (NaN, +-inf, e.g. a ratio
    to a missing paper value) written ``null``, so any JSON parser (``JSON.parse``, ``jq``) reads it; anything
    else JSON cannot hold is written as its ``repr`` (:func:`json_safe`)."""
    try:
        loose = json.dumps(obj, default=json_default)
    except (TypeError, ValueError):  # an object, a non-string key or a cycle: made plain first
        loose = json.dumps(json_safe(obj), default=json_default)
    return json.dumps(json.loads(loose, parse_constant=lambda _: None), indent=indent, allow_nan=False)


def write_json(path: Path, obj) -> None:
    """``obj`` as indented strict JSON (:func:`finite_json`: non-finite numbers are null) at ``path``, atomically."""
    atomic_write_bytes(Path(path), finite_json(obj).encode())


def is_owned(path: Path) -> bool:
    """True when ``path`` is a folder h4bench wrote (it carries the marker)."""
    path = Path(path)
    return path.is_dir() and not path.is_symlink() and (path / MARKER).is_file()


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def check_target(target: Path, option: str = "--out") -> Path:
    """Validate an output folder before any work: returns the absolute target.

    Allowed: a path that does not exist (its parent is created), an empty folder, or a folder h4bench wrote.
    Refused (:class:`RunFolderError` naming ``option``): a file, a non-empty folder without the marker, the
    current folder or one of its parents, a place that cannot be created or written.
    """
    target = Path(os.path.abspath(Path(target).expanduser()))
    cwd = Path.cwd().resolve()
    if target.exists() and (target.resolve() == cwd or target.resolve() in cwd.parents):
        raise RunFolderError(f"{option} must be a run folder, not the current folder or one of its parents, "
                             f"got {str(target)!r}")
    if target.is_symlink():
        raise RunFolderError(f"{option} must not be a symbolic link, got {str(target)!r}")
    if target.exists() and not target.is_dir():
        raise RunFolderError(f"{option} must be a folder (new, empty or written by h4bench), got the file "
                             f"{str(target)!r}; h4bench never replaces a file it did not write")
    if target.is_dir() and not is_owned(target) and any(target.iterdir()):
        raise RunFolderError(f"{option} {str(target)!r} is a folder h4bench did not write (no {MARKER} marker) "
                             "and it is not empty; choose a new or empty folder: h4bench never replaces a user's files")
    parent = target.parent
    for p in (parent, *parent.parents):
        if p.exists():
            if not p.is_dir():
                raise RunFolderError(f"{option} {str(target)!r} cannot be created: {str(p)!r} is a file")
            break
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RunFolderError(f"{option} {str(target)!r} cannot be created: {exc.strerror or exc}") from exc
    if not os.access(parent, os.W_OK | os.X_OK):
        raise RunFolderError(f"{option} {str(target)!r} cannot be written: no write permission on {str(parent)!r}")
    if not target.exists():  # the place must really take a folder (e.g. /proc does not): try, then remove ours
        try:
            target.mkdir()
            target.rmdir()
        except OSError as exc:
            raise RunFolderError(f"{option} {str(target)!r} cannot be created: {exc.strerror or exc}") from exc
    return target


def _write_marker(folder: Path, what: dict) -> None:
    atomic_write_bytes(folder / MARKER, json.dumps({"h4bench": True, "created": time.time(), **what},
                                                   default=json_default).encode())


def clean_stale_temporaries(target: Path) -> list[Path]:
    """Remove the temporary folders of killed runs for ``target`` (ours: marker inside, process gone)."""
    removed = []
    for tmp in target.parent.glob(f".{target.name}.tmp-*"):
        try:
            pid = int(tmp.name.rsplit("-", 1)[1])
        except ValueError:
            continue
        if pid != os.getpid() and not _pid_alive(pid) and is_owned(tmp):
            shutil.rmtree(tmp, ignore_errors=True)
            removed.append(tmp)
    return removed


class OwnedFolder:
    """``with OwnedFolder(target, option="--out", what={...}) as tmp:`` write everything into ``tmp``; on success
    ``tmp`` replaces ``target`` (only if ``target`` is new, empty or ours), on failure ``tmp`` is removed."""

    def __init__(self, target: Path, option: str = "--out", what: dict | None = None):
        self.option = option
        self.target = check_target(target, option)
        self.tmp = self.target.parent / f".{self.target.name}.tmp-{os.getpid()}"
        self.what = what or {}

    def __enter__(self) -> Path:
        clean_stale_temporaries(self.target)
        if self.tmp.exists() and is_owned(self.tmp):
            shutil.rmtree(self.tmp)
        try:
            self.tmp.mkdir(parents=True)
        except OSError as exc:
            raise RunFolderError(f"{self.option} {str(self.target)!r}: cannot create a temporary folder beside it: "
                                 f"{exc.strerror or exc}") from exc
        _write_marker(self.tmp, self.what)
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return
        old = self.target.parent / f".{self.target.name}.old-{os.getpid()}"
        try:
            check_target(self.target, self.option)  # still ours (or new/empty) at the moment of the swap
            if self.target.is_dir() and not is_owned(self.target):
                self.target.rmdir()  # empty (checked): nothing of the user's is lost
            elif self.target.exists():
                os.replace(self.target, old)
            os.replace(self.tmp, self.target)
        except (OSError, RunFolderError) as err:
            if old.exists() and not self.target.exists():
                os.replace(old, self.target)  # the previous run folder back in place
            raise RunFolderError(f"{self.option} {str(self.target)!r} could not be written "
                                 f"({getattr(err, 'strerror', None) or err}); {keep_finished(self.tmp, self.target)}")
        shutil.rmtree(old, ignore_errors=True)


def keep_finished(tmp: Path, target: Path) -> str:
    """Move a finished run's temporary folder to a visible sibling of ``target`` (``<name>.unsaved-<time>``,
    never cleaned by h4bench); returns the sentence saying where the result is."""
    kept = target.parent / f"{target.name}.unsaved-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"
    try:
        os.replace(tmp, kept)
    except OSError:
        kept = tmp
    return f"the finished result is kept in {str(kept)!r}"


def prepare_folder(target: Path, option: str = "--out", what: dict | None = None) -> Path:
    """Create (or reuse, if ours) a folder that a resumable job fills in place (campaigns); returns it."""
    target = check_target(target, option)
    try:
        target.mkdir(exist_ok=True)
        if not is_owned(target):
            _write_marker(target, what or {})
    except OSError as exc:
        raise RunFolderError(f"{option} {str(target)!r} cannot be written: {exc.strerror or exc}") from exc
    return target


def sim_progress(progress):
    """The simulator's progress(k, n) callback as a runner stage."""
    return lambda k, n: progress("simulate", k, n)


def save_run_files(run, out: Path, progress) -> None:
    """The dataset, the ground truth (kept apart), the reference trajectory and (if enabled) the replay of an
    experiment run, into the run folder ``out``."""
    run.dataset.save(out / "dataset")
    run.truth.save(out / "truth")
    if hasattr(run.reference, "save"):
        run.reference.save(out / "trajectory.npz")
    if run.spec["replay"]["enabled"]:
        progress("replay", 0, 1)
        from h4bench.scenarios.replay import write_replay

        t0 = time.perf_counter()
        write_replay(run, out / "replay.rrd", history_points=run.spec["replay"]["history_points"])
        run.timings["replay"] = time.perf_counter() - t0
