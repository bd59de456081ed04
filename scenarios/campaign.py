"""The campaign engine shared by the campaign kinds (``enclosure``, ``enclosure_critical``): many independent runs
of a job on a local process pool or a Dask cluster, resumable, with provenance, and safe to interrupt.

- Each finished run is written at once to ``<out>/runs/<index>.json`` (atomically) with its *provenance*: the
  hash of the spec (without the run count and where it runs), the base seed, the hash of the model file, the
  code's version and source hash. ``<out>/campaign.json`` holds the campaign's provenance. A restarted campaign
  reuses only runs whose provenance matches and says how many; a folder holding a campaign of other inputs is
  refused (:class:`CampaignMismatchError`) unless ``fresh`` recomputes it.
- ``result.json`` and the report are written only when every run is in, and removed at the start, so a partial
  campaign never looks complete.
- Ctrl-C (SIGINT) or SIGTERM stops the campaign within seconds: queued runs are cancelled, workers are
  terminated, what finished is kept, and :class:`CampaignInterrupted` says how to resume. Workers die with the
  campaign even when it is killed (SIGKILL): each worker asks the kernel for a signal when its parent dies
  (Linux ``PR_SET_PDEATHSIG``) and watches its parent process as a fallback.

The runs' experiments are built by :mod:`scenarios.campaign_build`, the summary and reports written by
:mod:`scenarios.campaign_report`.
"""

from __future__ import annotations

import concurrent.futures
import ctypes
import hashlib
import importlib.metadata
import importlib.util
import json
import multiprocessing
import os
import signal
import sys
import threading
import time
from pathlib import Path

import h4bench
from h4bench import sim
from h4bench.scenarios import plugins
from h4bench.scenarios.rundir import prepare_folder, write_json
from h4bench.scenarios.spec import ScenarioError
from h4bench.scenarios.threads import single_blas_thread
from h4bench.scenarios.timings import TimedJob

# spec keys that do not change what a run computes
_NOT_INPUTS = {"name", "description", "quick", "quick_applied"}
_NOT_CAMPAIGN_INPUTS = {"runs", "workers", "scheduler"}


class CampaignMismatchError(ScenarioError):
    """The output folder holds a campaign computed from other inputs."""


class CampaignRunError(ScenarioError):
    """Some runs of a campaign raised; ``errors`` maps their index to the message. The others are saved."""

    def __init__(self, message: str, errors: dict[int, str]):
        super().__init__(message)
        self.errors = errors


class CampaignInterrupted(ScenarioError):
    """The campaign was stopped (Ctrl-C, SIGTERM); finished runs are saved and it can be resumed."""


# ------------------------------------------------------------------------------------------------ provenance
def _sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


_CODE_HASH: str | None = None


def source_files() -> list[tuple[str, Path]]:
    """The project's source files as ``(name, path)``: every ``*.py`` then every ``*.toml`` under each of
    ``h4bench.SUBPACKAGES``' folders, found on disk (``importlib.util.find_spec``: no package is imported), named
    by their path from the folder's parent (``sim/simulate.py``)."""
    out = []
    for pkg in h4bench.SUBPACKAGES:
        spec = importlib.util.find_spec(f"h4bench.{pkg}")
        if spec is None or not spec.submodule_search_locations:  # pragma: no cover - a broken installation
            raise ImportError(f"h4bench.{pkg} is not installed")
        for folder in spec.submodule_search_locations:
            root = Path(folder)
            for f in sorted(root.rglob("*.py")) + sorted(root.rglob("*.toml")):
                out.append((str(f.relative_to(root.parent)), f))
    return out


def hash_files(files: list[tuple[str, Path]]) -> str:
    """SHA-256 over ``(name, path)`` pairs: each name, then the file's bytes, in the order given."""
    h = hashlib.sha256()
    for name, path in files:
        h.update(name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def code_hash() -> str:
    """SHA-256 over the source of the project's packages (:func:`source_files`), computed once per process
    without importing them."""
    global _CODE_HASH
    if _CODE_HASH is None:
        _CODE_HASH = hash_files(source_files())
    return _CODE_HASH


def model_hash(path: str | Path | None) -> str:
    """SHA-256 of the MJCF file a campaign loads and of the XML files beside it (includes, scene)."""
    path = Path(path) if path else Path(sim.DEFAULT_MODEL_PATH)
    h = hashlib.sha256()
    for f in [path] + sorted(p for p in path.parent.glob("*.xml") if p != path):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def provenance(spec: dict, seed: int) -> dict:
    """What a campaign's runs are computed from (a dict; equal dicts mean reusable runs)."""
    inputs = {k: v for k, v in spec.items() if k not in _NOT_INPUTS}
    inputs["campaign"] = {k: v for k, v in spec["campaign"].items() if k not in _NOT_CAMPAIGN_INPUTS}
    try:
        version = importlib.metadata.version("h4bench")
    except importlib.metadata.PackageNotFoundError:
        version = None
    return {
        "spec_hash": _sha256_bytes(json.dumps(inputs, sort_keys=True, default=str).encode()),
        "seed": int(seed),
        "model_hash": model_hash(spec["model"] or None),
        "version": version,
        "code_hash": code_hash(),
        "methods_code": plugins.methods_code(spec.get("estimators", {}).get("methods", [])),
    }


def _differences(saved: dict, now: dict) -> list[str]:
    out = []
    for k in now:
        if saved.get(k) == now.get(k):
            continue
        if k == "methods_code":
            old, new = saved.get(k) or {}, now[k]
            changed = sorted(m for m in new if old.get(m) != new[m])
            out.append(f"the methods' code changed ({', '.join(changed) or 'methods_code'}: saved "
                       f"{[old.get(m) for m in changed]!r}, now {[new[m] for m in changed]!r})")
        else:
            out.append(f"{k} (saved {saved.get(k)!r}, now {now.get(k)!r})")
    return out


# ------------------------------------------------------------------------------------------------ workers
def _watch_parent(parent: int) -> None:
    while True:
        if os.getppid() != parent:
            os._exit(3)
        time.sleep(0.5)


def _worker_init(parent: int) -> None:
    """In each worker: die with the campaign process (never an orphan), ignore SIGINT (the parent decides), one
    BLAS thread and no process of its own for the certified path's halves (:mod:`scenarios.threads`: the pool has
    a worker per core; set last, after the signals)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the campaign's handler (inherited through fork)
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except OSError:
            pass
    if os.getppid() != parent:
        os._exit(3)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()
    single_blas_thread()
    os.environ.setdefault("H4BENCH_HULL_PROCESSES", "1")  # a worker per core: no process of its own beside it


def _executor(camp: dict):
    if camp["scheduler"]:
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - a dependency
            raise ScenarioError("scheduler needs dask.distributed (pip install distributed)") from exc
        try:
            client = Client(camp["scheduler"], timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise ScenarioError(f"the Dask scheduler at {camp['scheduler']!r} does not answer: {exc}") from exc
        return client.get_executor(), client
    workers = camp["workers"] or max(1, (os.cpu_count() or 1))
    return concurrent.futures.ProcessPoolExecutor(max_workers=workers, initializer=_worker_init,
                                                  initargs=(os.getpid(),)), None


def _pool_children() -> set[int]:
    """Process ids of this process's live :mod:`multiprocessing` children (public API: ``active_children``)."""
    return {p.pid for p in multiprocessing.active_children()}


def _stop_executor(executor, known_children: set[int]) -> None:
    """Cancel what is queued and end the workers now (a process pool's shutdown would wait for them).

    known_children : :func:`_pool_children` before the pool was made; the workers are the children started since
    (the pool's, found through the public ``multiprocessing.active_children``). They are terminated (killed after
    3 s); then ``shutdown(wait=True, cancel_futures=True)`` cancels the queue and joins the pool's manager thread,
    which finds its workers gone and ends. On Python < 3.12 that thread raises ``InvalidStateError: CANCELLED``
    on a future cancelled meanwhile (printed as "Exception in thread"): while stopping, that one error of a thread
    other than the main thread is not printed (``threading.excepthook``, restored afterwards)."""
    previous = threading.excepthook
    main = threading.main_thread()

    def hook(args):
        if not (args.thread is not main and args.exc_type is not None
                and issubclass(args.exc_type, concurrent.futures.InvalidStateError)):
            previous(args)

    threading.excepthook = hook
    procs = [p for p in multiprocessing.active_children() if p.pid not in known_children]
    try:
        for proc in procs:
            try:
                proc.terminate()
            except (OSError, AttributeError):
                pass
        deadline = time.monotonic() + 3.0
        for proc in procs:
            proc.join(max(0.0, deadline - time.monotonic()))
            if proc.is_alive():
                proc.kill()
                proc.join(1.0)
        executor.shutdown(wait=True, cancel_futures=True)
    finally:
        threading.excepthook = previous


class _TermAsInterrupt:
    """A stop signal while a campaign runs. With ``event`` (the engine's loop), SIGINT and SIGTERM only set it: the
    loop polls it between waits and stops at a safe point, so no exception is ever raised inside
    ``concurrent.futures``' own lock handling (a KeyboardInterrupt there can leave a future's lock held and hang
    the pool's shutdown). Without ``event``, SIGTERM raises KeyboardInterrupt in the main thread (the same stop as
    Ctrl-C). The previous handlers are restored on exit; a handler that was not installed from Python
    (``getsignal`` gives None) cannot be restored, so it is then left in place."""

    def __init__(self, event: threading.Event | None = None):
        self.event = event

    def __enter__(self):
        self.previous = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM) if self.event is not None else (signal.SIGTERM,):
                if signal.getsignal(sig) is not None:
                    self.previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame):
        if self.event is None:
            raise KeyboardInterrupt
        self.event.set()

    def __exit__(self, *exc):
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)


# ------------------------------------------------------------------------------------------------ the engine
def run_path(out: Path, index: int) -> Path:
    return out / "runs" / f"{index:04d}.json"


def _load_run(path: Path, prov: dict) -> dict | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if data.get("provenance") == prov else None


def check_same_campaign(out: Path, prov: dict,
                        hint: str = "Use --fresh to recompute it there, or another --out") -> None:
    """Refuse (:class:`CampaignMismatchError`, ending with ``hint``) a folder ``out`` holding a campaign of other
    inputs than ``prov`` (seed, spec, model, code); nothing is refused when ``out`` holds no campaign."""
    saved_path = Path(out) / "campaign.json"
    if not saved_path.is_file():
        return
    try:
        saved = json.loads(saved_path.read_text()).get("provenance", {})
    except ValueError:
        saved = {}
    diff = _differences(saved, prov)
    if diff:
        raise CampaignMismatchError(
            f"--out {str(out)!r} holds a campaign computed from other inputs: {'; '.join(diff)}. {hint}")


def _import_quietly(modules: tuple[str, ...]) -> None:
    """Import ``modules`` (a thread's target; a module that fails is imported again, and fails loudly, where it
    is used)."""
    for name in modules:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - only a head start: the user of the module reports the error
            return


def run_many(spec: dict, seed: int, out: Path, job, progress, fresh: bool = False,
             report_imports: tuple[str, ...] = ()) -> tuple[list[dict], dict]:
    """Run ``job(spec, index, seed) -> dict`` for every index of ``spec['campaign']['runs']`` into ``out``,
    resuming what matches; returns (runs in index order, info with ``reused``, ``computed``, ``seconds``,
    ``runs_per_minute``). ``job`` must be a picklable top-level function.

    report_imports : modules the kind's report will import after the runs (e.g. ``matplotlib.pyplot``, most of
    a second): on a local pool they are imported by a thread of this process while it waits for the runs, once
    every worker is started (a process pool forks all its workers at the first submission), so a fork never
    copies a half-done import; the thread is joined before the runs are returned, so the report never meets a
    half-done import either."""
    camp = spec["campaign"]
    started_wall, started = time.time(), time.perf_counter()
    n = camp["runs"]
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ScenarioError(f"campaign.runs must be an integer >= 1, got {n!r}")
    prov = provenance(spec, seed)
    out = prepare_folder(out, what={"scenario": spec["name"], "kind": spec["kind"]})
    saved_path = out / "campaign.json"
    if not fresh:
        check_same_campaign(out, prov)
    try:
        (out / "runs").mkdir(exist_ok=True)
    except OSError as exc:
        from h4bench.scenarios.rundir import RunFolderError

        raise RunFolderError(f"--out {str(out)!r} cannot be written: {exc.strerror or exc}") from exc
    if fresh:
        for f in (out / "runs").glob("*.json"):
            f.unlink()
    for stale in ("result.json", "report.md"):
        (out / stale).unlink(missing_ok=True)
    write_json(saved_path, {"provenance": prov, "scenario": spec["name"], "kind": spec["kind"]})
    runs: dict[int, dict] = {}
    for i in range(n):
        if run_path(out, i).is_file():
            r = _load_run(run_path(out, i), prov)
            if r is not None:
                runs[i] = r
    reused = len(runs)
    todo = [i for i in range(n) if i not in runs]
    progress(f"campaign (reused {reused})" if reused else "campaign", reused, n)
    sections = {"setup": time.perf_counter() - started, "io": 0.0}
    started = time.perf_counter()
    errors: dict[int, str] = {}
    importer = None
    if todo:
        children = _pool_children()  # the workers are the children started after this
        executor, client = _executor(camp)
        futures = {}
        interrupted = False
        try:
            if client is not None:
                plugins.ship_plugins(client, spec.get("estimators", {}).get("methods", []))
            stop = threading.Event()
            with _TermAsInterrupt(stop):
                futures = {executor.submit(TimedJob(job), spec, i, seed): i for i in todo}
                if client is None and report_imports and multiprocessing.get_start_method() == "fork":
                    importer = threading.Thread(target=_import_quietly, args=(tuple(report_imports),),
                                                daemon=True, name="report-imports")
                    importer.start()
                pending = set(futures)
                while pending:
                    if stop.is_set():  # a stop signal: raised here, at a safe point of this loop
                        raise KeyboardInterrupt
                    done, pending = concurrent.futures.wait(pending, timeout=0.2,
                                                            return_when=concurrent.futures.FIRST_COMPLETED)
                    for fut in sorted(done, key=futures.get):
                        i = futures[fut]
                        try:
                            result = fut.result()
                        except Exception as exc:  # noqa: BLE001 - a run that crashed is reported, not hidden
                            errors[i] = f"{type(exc).__name__}: {exc}"
                            continue
                        result["provenance"] = prov
                        t_io = time.perf_counter()
                        write_json(run_path(out, i), result)
                        t_io = time.perf_counter() - t_io
                        sections["io"] += t_io
                        # in memory: the file cannot hold its own time
                        result.setdefault("timings", {})["io"] = t_io
                        runs[i] = result
                        progress(f"campaign (reused {reused})" if reused else "campaign", len(runs) + len(errors), n)
        except KeyboardInterrupt:
            interrupted = True
            if client is None:
                _stop_executor(executor, children)  # cancels the queued futures itself
            else:
                for fut in futures:
                    fut.cancel()
            raise CampaignInterrupted(
                f"interrupted: {len(runs)} of {n} runs are saved in {str(out)!r}; run the same command again to "
                "resume") from None
        finally:
            if client is not None:
                client.close()
            elif not interrupted:
                executor.shutdown(wait=True, cancel_futures=True)
    if importer is not None:
        importer.join()  # done long ago unless the runs were quicker: the report never races a half-done import
    seconds = time.perf_counter() - started
    if errors:
        first = min(errors)
        died = plugins.worker_death_note(spec, errors)
        raise CampaignRunError(
            f"{len(errors)} of {n} runs crashed (not saved; the {len(runs)} others are saved in {str(out)!r} and a "
            f"restart reuses them): run {first} (seed {seed + first}): {errors[first]}{died}. Re-run it alone with "
            f"--only {first} to inspect it", errors)
    computed = len(todo)
    info = {"reused": reused, "computed": computed, "seconds": seconds,
            "runs_per_minute": 60.0 * computed / seconds if computed and seconds > 0 else None,
            "workers": camp["workers"] or (os.cpu_count() or 1), "scheduler": camp["scheduler"] or None,
            "provenance": prov,
            # finished by write_outputs (scenarios.timings.campaign_timings)
            "timings": {"started": started_wall, "sections": {**sections, "pool": seconds}, "computed": todo}}
    return [runs[i] for i in range(n)], info
