"""The documentation site builds with no warning (MkDocs strict mode: every link, anchor and cross-reference
resolves, every API directive finds its object), and the figures it states are ``docs/figures.py``'s output for the
committed ``docs/figures.json`` (regenerated here from the JSON: no simulation)."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _figures_module():
    spec = importlib.util.spec_from_file_location("docs_figures", ROOT / "docs" / "figures.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_site_builds_strict_with_no_warning(tmp_path):
    assert importlib.util.find_spec("mkdocs") and importlib.util.find_spec("mkdocstrings_handlers"), \
        "the documentation tools are missing: pip install -e '.[test]' (mkdocs, mkdocstrings[python])"
    site = tmp_path / "site"
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
                           str(ROOT / "mkdocs.yml"), "--site-dir", str(site)], cwd=ROOT, capture_output=True,
                          text=True)
    log = done.stdout + done.stderr
    assert done.returncode == 0, log
    assert "WARNING" not in log and "ERROR" not in log, log
    for page in ("index.html", "own-arm.html", "api/ident.html", "api/sim.html", "api/trajectories.html"):
        assert (site / page).is_file(), page
    api = (site / "api" / "sim.html").read_text()
    assert 'id="h4bench.sim.simulate.simulate"' in api  # a function of __all__, rendered from its docstring
    assert (site / "_generated" / "paper-quick-boxes.png").stat().st_size > 1000
    own_arm = (site / "own-arm.html").read_text()
    assert "torque_rate" in own_arm and "<!-- include" not in own_arm  # the spec file and the table included


def test_a_broken_link_fails_the_build(tmp_path):
    """The strict build is a check that can fail: a page with a link to a missing page is refused."""
    import shutil

    docs = tmp_path / "docs"
    shutil.copytree(ROOT / "docs", docs)
    for folder in ("h4bench", "ident", "sim", "trajectories", "scenarios", "models", "data", "examples"):
        (tmp_path / folder).symlink_to(ROOT / folder, target_is_directory=True)  # the sources the hook links
    (docs / "index.md").write_text((docs / "index.md").read_text() + "\n[gone](no-such-page.md)\n")
    config = (ROOT / "mkdocs.yml").read_text().replace("docs_dir: docs", f"docs_dir: {docs}").replace(
        "  - docs/hooks.py", f"  - {docs / 'hooks.py'}")
    (tmp_path / "mkdocs.yml").write_text(config)
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
                           str(tmp_path / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode != 0 and "no-such-page.md" in done.stdout + done.stderr


def test_the_generated_tables_are_the_committed_json():
    figures = _figures_module()
    data = json.loads((ROOT / "docs" / "figures.json").read_text())
    assert data["groups"]["quick"]["commit"] and "figures" in data["groups"]["quick"]
    for rel, text in figures.tables(data).items():
        if rel == "README.md":
            readme = (ROOT / rel).read_text()
            assert figures.readme_with_block(readme, text) == readme, "README's figures block: python docs/figures.py --tables"
        else:
            assert (ROOT / rel).read_text() == text, f"{rel}: python docs/figures.py --tables"


def test_the_pages_include_only_existing_files():
    """Every include of the pages names a generated file or a file of the checkout."""
    import re

    for page in (ROOT / "docs").rglob("*.md"):
        text = page.read_text()
        for rel in re.findall(r"^<!-- include: ([\w./-]+) -->$", text, re.M):
            assert (ROOT / "docs" / rel).is_file(), (page, rel)
        for rel in re.findall(r"^<!-- include-code: ([\w./-]+) -->$", text, re.M):
            assert (ROOT / rel).is_file(), (page, rel)


@pytest.mark.parametrize("group", ["quick"])
def test_the_readme_figures_are_stamped(group):
    data = json.loads((ROOT / "docs" / "figures.json").read_text())
    g = data["groups"][group]
    assert len(g["commit"]) == 40 and g["machine"] and g["date"]
    assert g["commit"][:10] in (ROOT / "README.md").read_text()
