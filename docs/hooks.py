"""MkDocs hooks of the documentation site (``mkdocs.yml``: ``hooks``), applied to each page's Markdown before it is
rendered:

- ``<!-- api: h4bench.sim -->`` becomes the API reference of that package's ``__all__``: one mkdocstrings
  directive (``::: module.name``) per public function or class, at the module that defines it, and a table of the
  other public names (constants: their type and value);
- ``<!-- include: _generated/table.md -->`` becomes that file's text (a path relative to ``docs/``): the tables
  that ``docs/figures.py`` writes from ``docs/figures.json``. A missing file is an error;
- ``<!-- include-code: examples/python_api.py -->`` becomes that file of the checkout (a path relative to its
  root) as a fenced code block, so a page shows the example the tests run.

An error stops the build (no page is rendered with a directive left in it).

The API reference is read from the sources by griffe (static analysis, no import). The checkout's folders
``ident/``, ``sim/``, ... are the package ``h4bench.ident``, ``h4bench.sim``, ... only once installed (``setup.py``
maps them), so :func:`on_config` lays out a temporary tree ``h4bench/{__init__.py, ident, sim, ...}`` of symbolic
links to them and gives it to the Python handler as its search path.
"""

from __future__ import annotations

import importlib
import inspect
import re
import shutil
import tempfile
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.plugins import event_priority

DOCS = Path(__file__).resolve().parent
_API = re.compile(r"^<!-- api: ([\w.]+) -->$", re.M)
_INCLUDE = re.compile(r"^<!-- include: ([\w./-]+) -->$", re.M)
_CODE = re.compile(r"^<!-- include-code: ([\w./-]+) -->$", re.M)


ROOT = DOCS.parent
_TREE: list[Path] = []


def source_tree() -> Path:
    """A temporary folder holding ``h4bench/`` as installed: the package's own files and one link per folder that
    ``h4bench/__init__.py`` maps (SUBPACKAGES, DATA_PACKAGES)."""
    import h4bench

    tree = Path(tempfile.mkdtemp(prefix="h4bench-docs-src-"))
    pkg = tree / "h4bench"
    pkg.mkdir()
    for f in (ROOT / "h4bench").iterdir():
        if f.suffix == ".py":
            (pkg / f.name).symlink_to(f)
    for folder in (*h4bench.SUBPACKAGES, *h4bench.DATA_PACKAGES):
        (pkg / folder).symlink_to(ROOT / folder, target_is_directory=True)
    _TREE.append(tree)
    return tree


@event_priority(100)  # before mkdocstrings reads its handlers' configuration
def on_config(config):
    handler = config.plugins["mkdocstrings"].config["handlers"].setdefault("python", {})
    handler["paths"] = [str(source_tree())]
    return config


def on_shutdown() -> None:
    while _TREE:
        shutil.rmtree(_TREE.pop(), ignore_errors=True)


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def api_markdown(package: str) -> str:
    """The reference of ``package``'s ``__all__``: directives for functions and classes, a table of constants."""
    mod = importlib.import_module(package)
    names = getattr(mod, "__all__", None)
    if not names:
        raise PluginError(f"api: {package} has no __all__")
    objects, constants = [], []
    for name in sorted(names, key=str.lower):
        obj = getattr(mod, name)
        if inspect.isclass(obj) or inspect.isfunction(obj) or inspect.isbuiltin(obj):
            objects.append(f"::: {obj.__module__}.{obj.__qualname__}")
        else:
            constants.append(f"| `{name}` | {type(obj).__name__} | `{_short(obj)}` |".replace("\n", " "))
    out = []
    if constants:
        out += ["| constant | type | value |", "|---|---|---|", *constants, ""]
    return "\n".join(out + ["\n\n".join(objects), ""])


def include_markdown(relative: str) -> str:
    path = (DOCS / relative).resolve()
    if DOCS not in path.parents or not path.is_file():
        raise PluginError(f"include: {relative} is not a file of docs/ (run python docs/figures.py --tables)")
    return path.read_text()


def code_markdown(relative: str) -> str:
    path = (ROOT / relative).resolve()
    if ROOT not in path.parents or not path.is_file():
        raise PluginError(f"include-code: {relative} is not a file of the checkout")
    lang = {".py": "python", ".toml": "toml"}.get(path.suffix, "")
    return f"```{lang}\n{path.read_text().rstrip()}\n```"


def on_page_markdown(markdown: str, page=None, config=None, files=None) -> str:
    markdown = _API.sub(lambda m: api_markdown(m.group(1)), markdown)
    markdown = _CODE.sub(lambda m: code_markdown(m.group(1)), markdown)
    return _INCLUDE.sub(lambda m: include_markdown(m.group(1)), markdown)
