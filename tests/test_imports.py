"""What an import loads at run time (a fresh interpreter per case, over ``sys.modules``): the numerical layers load
no simulator, no python-control, no plotting, no pinocchio and no rerun; ``import sim`` loads no plotting and no
python-control until a controller is designed."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("mujoco", "control", "matplotlib", "pinocchio", "rerun")


def _loaded(statement: str) -> set[str]:
    code = (f"import sys, json\n{statement}\n"
            "print(json.dumps(sorted({m.removeprefix('h4bench.').split('.')[0] for m in sys.modules})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120,
                         cwd="/")
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


def test_the_probe_sees_what_is_imported():
    """The checker itself: a module that is imported must be seen (a probe that sees nothing would pass all)."""
    assert "numpy" in _loaded("import numpy")


@pytest.mark.parametrize("statement", ["import h4bench.ident", "import h4bench.ident.estimators",
                                       "import h4bench.ident.numerics",
                                       "from h4bench.ident.estimators import registry, estimate, hull, cgsp, wls, online",
                                       "import h4bench.ident.processing.filtering, h4bench.ident.processing.processing"])
def test_the_numerical_layers_load_no_simulator_nor_plotting(statement):
    loaded = _loaded(statement)
    assert not loaded & {*HEAVY, "sim"}, sorted(loaded & {*HEAVY, "sim"})


def test_robot_names_are_loaded_on_use():
    loaded = _loaded("from h4bench import ident\nident.PARAMETER_NAMES, ident.regressor, ident.SerialRobot")
    assert "ident" in loaded and not loaded & {*HEAVY, "sim"}  # the regressor imports the kinematics when called


def test_the_old_top_level_names_are_not_installed():
    """Only ``h4bench`` is an import name: ``import ident`` (a name other distributions use) fails."""
    for name in ("sim", "ident", "trajectories", "scenarios", "h4bench_models", "h4bench_data"):
        res = subprocess.run([sys.executable, "-c", f"import {name}"], capture_output=True, text=True, timeout=120,
                             cwd="/")
        assert res.returncode != 0 and "ModuleNotFoundError" in res.stderr, name


def test_import_sim_loads_no_plotting_nor_control():
    loaded = _loaded("import h4bench.sim")
    assert not loaded & {"matplotlib", "control"}, sorted(loaded & {"matplotlib", "control"})
