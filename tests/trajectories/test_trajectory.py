"""The Trajectory data type: exact save/load round trip (atomic write), validation naming the field, report."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from h4bench import trajectories as tj


def test_save_load_round_trip_is_exact(tmp_path, short_excitation):
    path = short_excitation.save(tmp_path / "exc.npz")
    back = tj.Trajectory.load(path)
    assert back.equals(short_excitation)
    for name in ("t", "x", "q", "qd", "qdd"):
        assert np.array_equal(getattr(back, name), getattr(short_excitation, name))
        assert getattr(back, name).dtype == np.float64
    assert back.parameters == short_excitation.parameters and back.checks == short_excitation.checks
    assert back.kind == "fourier" and back.parameters["seed"] == 1
    assert os.listdir(tmp_path) == ["exc.npz"]  # no temporary file left behind


def test_save_replaces_atomically_and_failure_leaves_the_old_file(tmp_path, short_excitation, monkeypatch):
    path = tmp_path / "t.npz"
    short_excitation.save(path)
    first = path.read_bytes()
    other = tj.Trajectory(t=short_excitation.t[:10], x=short_excitation.x[:10], q=short_excitation.q[:10],
                          qd=short_excitation.qd[:10], qdd=short_excitation.qdd[:10], kind="cut")

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        other.save(path)
    assert path.read_bytes() == first and os.listdir(tmp_path) == ["t.npz"]
    monkeypatch.undo()
    other.save(path)
    assert tj.Trajectory.load(path).kind == "cut"


def test_load_rejects_other_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="path"):
        tj.Trajectory.load(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="not a trajectory file"):
        tj.Trajectory.load(tmp_path / "other.npz")


def test_metadata_is_plain_json(tmp_path, short_excitation):
    path = short_excitation.save(tmp_path / "m.npz")
    with np.load(path) as data:
        meta = json.loads(str(data["metadata"]))
    assert meta["format"] == "h4bench.trajectory/1" and meta["parameters"]["limits"]["qd_max"] == [8.0] * 4
    assert len(meta["parameters"]["a"]) == 5 and meta["parameters"]["parameter_names"][4] == "Mnac"


def _arrays(n=5):
    return {"t": np.arange(n) * 1e-3, "x": np.zeros((n, 4)), "q": np.zeros((n, 4)), "qd": np.zeros((n, 4)),
            "qdd": np.zeros((n, 4))}


@pytest.mark.parametrize("change, match", [
    ({"qd": np.zeros((4, 4))}, r"qd must have shape \(5, 4\), got \(4, 4\)"),
    ({"x": np.zeros((5, 3))}, r"x must have shape \(5, 4\)"),
    ({"t": np.array([0, 1, 1, 2, 3.0])}, "t must be finite and strictly increasing"),
    ({"t": np.zeros((5, 1))}, r"t must have shape \(n,\)"),
    ({"q": np.full((5, 4), np.nan)}, r"q must be finite.*sample\(s\) \[0, 1, 2, 3, 4\]"),
])
def test_validation_names_the_field(change, match):
    with pytest.raises(ValueError, match=match):
        tj.Trajectory(kind="manual", **{**_arrays(), **change})


def test_kind_and_parameters_are_checked():
    with pytest.raises(TypeError, match="kind"):
        tj.Trajectory(kind="", **_arrays())
    with pytest.raises(TypeError, match="parameters must be JSON-serialisable"):
        tj.Trajectory(kind="manual", parameters={"f": object()}, **_arrays())


def test_arrays_are_read_only_and_check_trajectory_recomputes_the_report(geometry, short_excitation):
    with pytest.raises(ValueError):
        short_excitation.q[0, 0] = 1.0
    stored = short_excitation.report()
    again = tj.check_trajectory(geometry, short_excitation, raise_on_violation=False)
    assert stored["feasible"] and again["feasible"]
    for key in ("cond_W_scaled", "max_cond_jx", "min_workspace_margin_m"):
        assert again[key] == pytest.approx(stored[key], rel=1e-12)
    assert "cond(W diag(theta_nom))" in short_excitation.summary()



def test_the_data_type_does_not_import_its_checks():
    """No import circle: trajectories.trajectory imports nothing from trajectories.checks (read from its AST)."""
    import ast  # noqa: PLC0415
    import inspect  # noqa: PLC0415

    import h4bench.trajectories.trajectory as module  # noqa: PLC0415

    imported = set()
    for node in ast.walk(ast.parse(inspect.getsource(module))):
        if isinstance(node, ast.ImportFrom):
            imported.add(node.module)
        elif isinstance(node, ast.Import):
            imported.update(a.name for a in node.names)
    assert not any(m and m.startswith("trajectories") for m in imported), imported
