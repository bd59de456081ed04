"""A campaign's plugins: the provenance of their code, and their way to Dask workers.

- :func:`methods_code`: what a resumed campaign must match besides the project's own code: per plugin method the
  hash of its module's (or top-level package's) .py files and, for an entry point, its distribution's name and
  version (``campaign.json`` and every run's ``provenance["methods_code"]``): a change is refused (or recomputed
  with ``--fresh``) and the message says the methods' code changed.
- :func:`ship_plugins`: a ``module:attribute`` plugin reaches every Dask worker through distributed's own
  ``Client.upload_file`` (the module file, or its top-level package zipped; not imported on upload), and every
  worker must then resolve every plugin method, or the campaign is refused before any run, naming what the
  workers lack (an entry point must be installed on the workers: it is not shipped).
- :func:`worker_death_note`: a campaign whose worker process died names the methods it was running.
"""

from __future__ import annotations

from pathlib import Path

from h4bench.scenarios.spec import ScenarioError

__all__ = ["methods_code", "ship_plugins", "worker_death_note", "worker_lacks"]


def methods_code(methods) -> dict:
    """The provenance of the plugins' code (the built-ins' is ``code_hash``): per plugin method, the hash of its
    module's (or top-level package's) .py files and, for an entry point, its distribution's name and version
    (:func:`ident.estimators.isolation.resolve`, which imports it in a child process). A plugin that cannot be
    resolved is recorded as such (its runs report it failed)."""
    from h4bench.ident.errors import EstimatorError
    from h4bench.ident.estimators import isolation, registry

    out = {}
    for m in methods:
        if not isinstance(m, str) or m in registry.BUILTINS:
            continue
        try:
            src = isolation.resolve(m).source
        except EstimatorError as exc:
            src = {"unresolved": str(exc)}
        out[m] = {k: src.get(k) for k in ("sha256", "distribution", "version", "unresolved") if src.get(k) is not None}
    return out


def _plugin_source(method: str) -> Path:
    """The file or top-level package folder of a ``module:attribute`` method (resolved here in a child process)."""
    from h4bench.ident.estimators import isolation

    module = method.partition(":")[0]
    path = Path(isolation.resolve(method).source["module"])
    depth = module.count(".")
    if path.name == "__init__.py":
        return path.parents[depth]
    return path if depth == 0 else path.parents[depth - 1]


def _zip_package(folder: Path, into: Path) -> Path:
    """``folder``'s .py files (the top-level package, a namespace package too: each of its folders gets an empty
    ``__init__.py`` in the zip) as ``<into>/<name>.zip``."""
    import zipfile

    import hashlib

    h = hashlib.sha256()
    for f in sorted(folder.rglob("*.py")):
        h.update(str(f.relative_to(folder)).encode())
        h.update(f.read_bytes())
    # named by its content: a worker caches a zip's listing by path (zipimport), so a new version needs a new name
    target = into / f"{folder.name}-{h.hexdigest()[:12]}.zip"
    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(folder.rglob("*.py")):
            if "__pycache__" not in f.parts:
                z.write(f, str(f.relative_to(folder.parent)))
        for d in sorted({folder, *(f.parent for f in folder.rglob("*.py"))}):
            if not (d / "__init__.py").is_file() and "__pycache__" not in d.parts:
                # zipimport finds no namespace package: an empty __init__ makes the folder a package in the zip
                z.writestr(str((d / "__init__.py").relative_to(folder.parent)), "")
    return target


def worker_lacks(methods, shipped=(), dask_worker=None) -> dict:
    """On a worker (``Client.run``): put the shipped files (names in the worker's ``local_directory``: a zip on
    ``sys.path`` itself, a module's folder for a .py) on ``sys.path``, then return the plugin methods it cannot
    resolve, ``{method: reason}`` (each resolved in a child process: the worker never runs a plugin's import code
    itself)."""
    import os
    import sys

    from h4bench.ident.errors import EstimatorError
    from h4bench.ident.estimators import isolation, registry

    if dask_worker is not None:
        for name in shipped:
            path = os.path.join(dask_worker.local_directory, name)
            entry = path if name.endswith(".zip") else dask_worker.local_directory
            if os.path.exists(path) and entry not in sys.path:
                sys.path.insert(0, entry)
    out = {}
    for m in methods:
        if m in registry.BUILTINS:
            continue
        try:
            isolation.resolve(m)
        except EstimatorError as exc:
            out[m] = str(exc)
    return out


def ship_plugins(client, methods) -> None:
    """Make the campaign's plugin methods reach every Dask worker, or refuse before any run.

    A ``module:attribute`` method is shipped with distributed's own mechanism (``Client.upload_file``, not
    imported on upload): its module file, or its top-level package zipped. Then every worker resolves every
    plugin method (:func:`worker_lacks`); an entry point (or a module) that a worker lacks raises ScenarioError
    naming the method, the worker and why."""
    import tempfile

    plugins = [m for m in methods if isinstance(m, str) and ":" in m]
    names = set()
    with tempfile.TemporaryDirectory(prefix="h4bench-plugins-") as tmp:
        shipped = set()
        for m in plugins:
            src = _plugin_source(m)
            if src in shipped:
                continue
            shipped.add(src)
            path = src if src.is_file() else _zip_package(src, Path(tmp))
            names.add(path.name)
            try:
                client.upload_file(str(path), load=False)
            except Exception as exc:  # noqa: BLE001 - a scheduler or worker that refuses the file
                raise ScenarioError(f"cannot send the plugin {m!r} ({path.name}) to the Dask workers: "
                                    f"{type(exc).__name__}: {exc}") from exc
    lacking = {w: r for w, r in client.run(worker_lacks, [m for m in methods if isinstance(m, str)],
                                           sorted(names)).items() if r}
    if lacking:
        worker, missing = next(iter(lacking.items()))
        raise ScenarioError(
            f"{len(lacking)} Dask worker(s) lack estimator(s) the campaign needs, e.g. {worker}: "
            + "; ".join(f"{m}: {why}" for m, why in missing.items())
            + ". Install the plugin's distribution on every worker (entry points are not shipped); nothing was run")


def worker_death_note(spec: dict, errors: dict) -> str:
    """The words added to a campaign's crash message when a worker process died (``BrokenProcessPool``, Dask's
    ``KilledWorker``): the methods it was running, the plugins named."""
    from h4bench.ident.estimators import registry

    if not any("BrokenProcessPool" in e or "KilledWorker" in e for e in errors.values()):
        return ""
    methods = [str(m) for m in spec.get("estimators", {}).get("methods", [])]
    plugins = [m for m in methods if m not in registry.BUILTINS]
    return ("; a worker process died while running the methods " + ", ".join(methods)
            + (f" (plugins: {', '.join(plugins)}, each in a child process of its own)" if plugins else ""))
