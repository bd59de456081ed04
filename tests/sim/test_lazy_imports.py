"""Importing sim costs only what is used: a fresh interpreter per case, its sys.modules read after the import."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("mujoco", "control", "matplotlib")


def _loaded(statement: str) -> set[str]:
    code = f"import json, sys\n{statement}\nprint(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd="/").stdout
    return set(json.loads(out.splitlines()[-1]))


@pytest.mark.parametrize(("statement", "absent"), [
    ("import h4bench.sim", HEAVY),
    ("import h4bench.sim.validation", HEAVY),
    ("import h4bench.sim.noise", HEAVY),
    ("import h4bench.sim.controller", HEAVY),
    ("import h4bench.sim.control_design", ("control", "matplotlib")),
    ("import h4bench.sim.kinematics", ("control", "matplotlib")),
    ("from h4bench import sim\nsim.simulate", ("control", "matplotlib")),
    ("from h4bench import sim\nsim.TorqueNoise(1.0)", HEAVY),
])
def test_import_loads_no_heavy_package(statement, absent):
    mods = _loaded(statement)
    assert not {m for m in mods if m.split(".")[0] in absent}, statement


def test_sub_modules_load_only_what_they_import():
    mods = {m for m in _loaded("import h4bench.sim.validation\nimport h4bench.sim.kinematics")
            if m.startswith("h4bench.sim")}
    assert mods == {"h4bench.sim", "h4bench.sim.validation", "h4bench.sim.kinematics", "h4bench.sim.model"}


def test_designing_a_controller_loads_python_control(tmp_path):
    design = (f"import os\nos.environ['H4BENCH_CACHE'] = {str(tmp_path)!r}\n"
              "from h4bench import sim\nsim.design_joint_controller(0.05, 0.1)")
    assert "control" in _loaded(design)  # an empty design cache: designed with python-control
    assert "control" not in _loaded(design)  # then read from the cache (sim.design_cache): no python-control


def test_public_names_resolve_and_sim_simulate_is_the_function():
    from h4bench import sim
    import h4bench.sim.simulate  # noqa: F401  (binds the sub-module; the package attribute stays the function)

    for name in sim.__all__:
        assert getattr(sim, name) is not None, name
    assert callable(sim.simulate) and sim.simulate.__module__ == "h4bench.sim.simulate"
    assert sim.TorqueNoise is sim.noise.TorqueNoise
    assert sim.SimulationError is sim.validation.SimulationError
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        sim.nope  # noqa: B018
