"""A plain (non-editable) install must run: the MJCF files ship with the package.

The wheel is built from this checkout and installed into a fresh virtual environment that borrows only the
third-party packages of the running one (a ``.pth`` line; the checkout's editable hook is not processed there),
then ``h4bench run paper --quick`` runs from an unrelated folder. The run must take the project and the model
from the installed wheel, never from the checkout.
"""

from __future__ import annotations

import json
import os
import shutil
import site
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CLEAN_ENV = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}


def _write_wheel(path: Path, name: str, version: str, files: dict[str, str]) -> None:
    """A minimal pure-Python wheel (PEP 427) holding ``files`` at the top level, with its RECORD."""
    import base64
    import hashlib
    import zipfile

    info = f"{name}-{version}.dist-info"
    contents = dict(files)
    contents[f"{info}/METADATA"] = f"Metadata-Version: 2.1\nName: {name.replace('_', '-')}\nVersion: {version}\n"
    contents[f"{info}/WHEEL"] = "Wheel-Version: 1.0\nGenerator: h4bench-tests\nRoot-Is-Purelib: true\nTag: py3-none-any\n"
    record = []
    for arc, text in contents.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(text.encode()).digest()).rstrip(b"=").decode()
        record.append(f"{arc},sha256={digest},{len(text.encode())}")
    record.append(f"{info}/RECORD,,")
    contents[f"{info}/RECORD"] = "\n".join(record) + "\n"
    with zipfile.ZipFile(path, "w") as zf:
        for arc, text in contents.items():
            zf.writestr(arc, text)


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wheel")
    wheels = tmp / "dist"
    # build from a clean copy of the sources: a build/ folder left in the checkout may hold stale modules
    source = tmp / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(
        ".git", "build", "dist", "*.egg-info", ".venv", "venv", ".ci-venv", "runs", "__pycache__", ".pytest_cache",
        ".hypothesis"))
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(wheels), str(source)],
                           capture_output=True, text=True, timeout=600)
    if build.returncode != 0:
        pytest.fail(f"building the wheel failed:\n{build.stdout}\n{build.stderr}")
    wheel = next(wheels.glob("h4bench-*.whl"))
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    purelib = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                                  capture_output=True, text=True, check=True).stdout.strip())
    borrowed = [p for p in {sysconfig.get_path("purelib"), sysconfig.get_path("platlib"), *site.getsitepackages()}]
    (purelib / "borrowed-deps.pth").write_text("\n".join(borrowed) + "\n")
    # another distribution that owns the generic top-level modules ``ident`` and ``scenarios`` is installed first
    other = wheels / "other_owner-1.0-py3-none-any.whl"
    _write_wheel(other, "other_owner", "1.0",
                 {f"{name}.py": f"OWNER = 'other-owner:{name}'\n" for name in ("ident", "scenarios")})
    for w in (other, wheel):
        subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(purelib), str(w)],
                       check=True, capture_output=True, timeout=300)
    return python, purelib, wheel


def test_the_wheel_installs_one_top_level_name(installed):
    """Only ``h4bench`` at the top level: a distribution owning ``ident`` and ``scenarios`` keeps its modules."""
    import zipfile

    python, _, wheel = installed
    tops = {n.split("/")[0] for n in zipfile.ZipFile(wheel).namelist() if ".dist-info" not in n.split("/")[0]}
    assert tops == {"h4bench"}, tops
    res = subprocess.run([str(python), "-c", "import ident, scenarios, h4bench.ident, h4bench.scenarios.cli; "
                          "print(ident.OWNER, scenarios.OWNER)"], capture_output=True, text=True, cwd="/",
                         env=CLEAN_ENV, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["other-owner:ident", "other-owner:scenarios"]


def test_the_wheel_holds_the_models(installed):
    import zipfile

    _, _, wheel = installed
    names = zipfile.ZipFile(wheel).namelist()
    assert "h4bench/models/h4.xml" in names and "h4bench/models/scene.xml" in names
    assert "h4bench/scenarios/paper.toml" in names and "h4bench/scenarios/kinds/paper.py" in names
    assert {"h4bench/data/tx40/curr_data.csv.gz", "h4bench/data/tx40/pos_read_data.csv.gz",
            "h4bench/data/tx40/LICENSE-Apache-2.0.txt", "h4bench/data/tx40/README.md"} <= set(names)


def test_an_installed_wheel_runs_the_paper_scenario_from_anywhere(installed, tmp_path):
    python, purelib, _ = installed
    where = subprocess.run([str(python), "-c", "from h4bench import sim, scenarios; import h4bench.ident.robots.tx40; "
                            "print(sim.__file__); print(sim.DEFAULT_MODEL_PATH); "
                            "print(h4bench.ident.robots.tx40.DATA_DIR)"],
                           capture_output=True, text=True, cwd=tmp_path, check=True, env=CLEAN_ENV)
    sim_file, model_path, data_dir = where.stdout.split()
    assert all(Path(p).is_relative_to(purelib) for p in (sim_file, model_path, data_dir)), where.stdout
    assert (Path(data_dir) / "curr_data.csv.gz").is_file()
    res = subprocess.run([str(python), "-m", "h4bench.scenarios.cli", "run", "paper", "--quick", "--json", "--out",
                          str(tmp_path / "paper")], capture_output=True, text=True, cwd=tmp_path, timeout=600,
                         env=CLEAN_ENV)
    assert res.returncode == 0, res.stderr
    result = json.loads(res.stdout)
    assert Path(result["model"]).is_relative_to(purelib)
    assert result["methods"]["hull"]["all_enclosed"]
