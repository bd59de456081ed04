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
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(purelib), str(wheel)],
                   check=True, capture_output=True, timeout=300)
    return python, purelib, wheel


def test_the_wheel_holds_the_models(installed):
    import zipfile

    _, _, wheel = installed
    names = zipfile.ZipFile(wheel).namelist()
    assert "h4bench_models/h4.xml" in names and "h4bench_models/scene.xml" in names
    assert "scenarios/paper.toml" in names and "scenarios/kinds/paper.py" in names
    assert {"h4bench_data/tx40/curr_data.csv.gz", "h4bench_data/tx40/pos_read_data.csv.gz",
            "h4bench_data/tx40/LICENSE-Apache-2.0.txt", "h4bench_data/tx40/README.md"} <= set(names)


def test_an_installed_wheel_runs_the_paper_scenario_from_anywhere(installed, tmp_path):
    python, purelib, _ = installed
    where = subprocess.run([str(python), "-c", "import sim, scenarios, ident.robots.tx40; print(sim.__file__); "
                            "print(sim.DEFAULT_MODEL_PATH); print(ident.robots.tx40.DATA_DIR)"],
                           capture_output=True, text=True, cwd=tmp_path, check=True, env=CLEAN_ENV)
    sim_file, model_path, data_dir = where.stdout.split()
    assert all(Path(p).is_relative_to(purelib) for p in (sim_file, model_path, data_dir)), where.stdout
    assert (Path(data_dir) / "curr_data.csv.gz").is_file()
    res = subprocess.run([str(python), "-m", "scenarios.cli", "run", "paper", "--quick", "--json", "--out",
                          str(tmp_path / "paper")], capture_output=True, text=True, cwd=tmp_path, timeout=600,
                         env=CLEAN_ENV)
    assert res.returncode == 0, res.stderr
    result = json.loads(res.stdout)
    assert Path(result["model"]).is_relative_to(purelib)
    assert result["methods"]["hull"]["all_enclosed"]
