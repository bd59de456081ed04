"""A campaign's code provenance (scenarios.campaign.code_hash) and the lazy kind registry: the source files are
hashed from disk without importing the packages, every edit changes the hash, and a command imports only its
own kind. Oracles: the import system's own module files, a byte-edited copy of the sources, fresh interpreters."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import h4bench
from h4bench.scenarios import campaign as camp
from h4bench.scenarios import registry


def test_the_source_files_cover_every_imported_module_of_the_project():
    import h4bench.scenarios.kinds.enclosure  # noqa: F401  (imports much of every sub-package)

    hashed = {path.resolve() for _, path in camp.source_files()}
    imported = {sys.modules[m].__file__ for m in list(sys.modules)
                if m.split(".")[:2][-1] in h4bench.SUBPACKAGES and m.startswith("h4bench.")
                and getattr(sys.modules[m], "__file__", None)}
    assert imported and {p for p in imported if p.endswith(".py")} <= {str(p) for p in hashed}
    assert any(name.endswith(".toml") for name, _ in camp.source_files())  # the scenario specs too


def test_the_code_hash_changes_with_any_source_byte(tmp_path, monkeypatch):
    files = camp.source_files()
    copies = []
    for name, path in files:
        copy = tmp_path / name
        copy.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, copy)
        copies.append((name, copy))
    monkeypatch.setattr(camp, "_CODE_HASH", None)
    monkeypatch.setattr(camp, "source_files", lambda: copies)
    same = camp.code_hash()
    assert same == camp.hash_files(files)  # the copies hash as the originals
    for index in (0, len(copies) // 2, len(copies) - 1):  # a .py of sim, one in the middle, a .toml at the end
        name, copy = copies[index]
        original = copy.read_bytes()
        copy.write_bytes(original + b" ")
        monkeypatch.setattr(camp, "_CODE_HASH", None)
        assert camp.code_hash() != same, name
        copy.write_bytes(original)
    monkeypatch.setattr(camp, "_CODE_HASH", None)
    assert camp.code_hash() == same
    renamed = [(name + "x", path) if i == 3 else (name, path) for i, (name, path) in enumerate(copies)]
    assert camp.hash_files(renamed) != same


def _fresh(code: str) -> dict:
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_code_hash_and_the_spec_import_no_other_package_or_kind():
    out = _fresh(
        "import json, sys\n"
        "from h4bench.scenarios import campaign, registry\n"
        "before = set(sys.modules)\n"
        "campaign.code_hash()\n"
        "hashed = sorted(m for m in set(sys.modules) - before if m.startswith('h4bench'))\n"
        "registry.load_spec('enclosure')\n"
        "registry.get('enclosure')\n"
        "kinds = sorted(m.rsplit('.', 1)[1] for m in sys.modules if m.startswith('h4bench.scenarios.kinds.'))\n"
        "from h4bench.ident.estimators import registry as est\n"
        "spec = registry.load_spec('enclosure')\n"
        "spec['estimators']['methods'] = list(est.BUILTINS)\n"
        "before = set(sys.modules)\n"
        "campaign.provenance(spec, 0)\n"
        "estimators = sorted(m for m in set(sys.modules) - before if m.startswith('h4bench.ident.estimators.'))\n"
        "print(json.dumps({'hashed': hashed, 'kinds': kinds, 'toppra': 'toppra' in sys.modules,\n"
        "                  'estimators': estimators}))\n")
    assert out["hashed"] == []
    assert out["estimators"] == []  # "name in BUILTINS" does not import the built-in's module
    # enclosure itself, and tx40 whose SPEC_DEFAULTS is not a literal (it is built from another module's table)
    assert out["kinds"] == ["enclosure", "tx40"]
    assert out["toppra"] is False  # trajectories.timing (toppra) is imported on first use only


def test_the_lazy_registry_lists_and_merges_as_the_imported_kinds_do():
    modules = registry.kinds()
    assert registry.names() == tuple(modules)
    merged: dict = {}
    for module in modules.values():
        merged.update(getattr(module, "SPEC_DEFAULTS", {}))
    assert registry.spec_defaults() == merged
    assert registry.get("prior-bound") is modules["prior_bound"]
