"""The Rerun replay: written, read back with ``rerun.chunk.RrdReader`` and checked against the run it shows.

The run is a 2 s closed-loop experiment on the smooth Cartesian test reference (tests/conftest.py), without the
project's estimators; the boxes come from an independent naive exact hull (one scipy ``linprog`` per bound).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog

from h4bench import ident
from h4bench.scenarios.experiment import run_experiment
from h4bench.scenarios.replay import RRD_MAGIC, TIMELINE, ReplayError, box_history, viewer_command, write_replay
from h4bench.scenarios.spec import load_spec
from tests.conftest import cartesian_reference

ROOT = Path(__file__).resolve().parents[2]

SECONDS = 2.0
POINTS = 4


def lp_hull(W, y, bound, prior, method="hull"):
    """Naive exact hull of {theta in prior : |y - W theta| <= bound}: 2p linprog calls (the test's oracle)."""
    A = np.vstack([W, -W])
    b = np.concatenate([y + bound, bound - y])
    bounds = list(zip(prior.lower, prior.upper))
    lo, hi = np.empty(W.shape[1]), np.empty(W.shape[1])
    for i in range(W.shape[1]):
        c = np.zeros(W.shape[1])
        c[i] = 1.0
        r_lo, r_hi = (linprog(s * c, A_ub=A, b_ub=b, bounds=bounds, method="highs") for s in (1.0, -1.0))
        if r_lo.status == 2 or r_hi.status == 2:
            raise ValueError("inconsistent data: empty feasible set")
        lo[i], hi[i] = r_lo.fun - 1e-7, -r_hi.fun + 1e-7
    return ident.Box(np.maximum(lo, prior.lower), np.minimum(hi, prior.upper), prior.names)


@pytest.fixture(scope="module")
def run(model, geometry):
    spec = load_spec("paper", quick=True)
    r = run_experiment(spec, model=model, reference=cartesian_reference(geometry, SECONDS), estimate=False)
    eq = r.equation
    r.boxes["hull"] = lp_hull(eq.W, eq.y, eq.bound, r.prior)
    r.failures["cgsp"] = "InconsistentDataError: stand-in failure (the replay must show it, not crash)"
    return r


@pytest.fixture(scope="module")
def history(run):
    return box_history(run, methods=("hull", "cgsp"), points=POINTS, estimator=lp_hull)


@pytest.fixture(scope="module")
def rrd(run, history, tmp_path_factory):
    folder = tmp_path_factory.mktemp("replay")
    path = write_replay(run, folder / "replay.rrd", history=history)
    return path


def read_rrd(path):
    """entity path -> {"t": (rows,) seconds of the temporal rows, sorted; column name -> list of row values};
    static rows are kept apart under "static"."""
    from rerun.chunk import RrdReader

    raw = defaultdict(lambda: {"t": [], "cols": defaultdict(list), "static": defaultdict(list)})
    for chunk in RrdReader(str(path)).stream():
        rb = chunk.to_record_batch()
        entry = raw[chunk.entity_path]
        names = [n for n in rb.schema.names if not n.startswith("rerun.controls")]
        if TIMELINE in names:
            entry["t"].extend(rb.column(TIMELINE).cast("int64").to_numpy() * 1e-9)
            for n in names:
                if n != TIMELINE:
                    entry["cols"][n].extend(rb.column(n).to_pylist())
        else:
            for n in names:
                entry["static"][n].extend(rb.column(n).to_pylist())
    out = {}
    for path_, e in raw.items():
        order = np.argsort(np.asarray(e["t"]), kind="stable")
        out[path_] = {"t": np.asarray(e["t"])[order], "static": dict(e["static"]),
                      **{n: [v[k] for k in order] for n, v in e["cols"].items()}}
    return out


@pytest.fixture(scope="module")
def content(rrd):
    return read_rrd(rrd)


def scalars(entry):
    return np.array([row[0] for row in entry["Scalars:scalars"]])


def test_file_is_an_rrd_written_atomically(rrd):
    assert rrd.read_bytes()[:4] == RRD_MAGIC
    assert [p.name for p in rrd.parent.iterdir()] == ["replay.rrd"]  # no temp file left behind


def test_series_match_the_dataset(run, content):
    ds, truth, eq = run.dataset, run.truth, run.equation
    for i in range(4):
        j = f"/series/q/joint{i + 1}"
        q = content[f"{j}/measured"]
        assert q["t"].size == len(ds)  # one logged sample per dataset sample, not a 50 Hz subsample
        np.testing.assert_allclose(q["t"], ds.t, rtol=0, atol=1e-9)  # ns-resolution timeline
        np.testing.assert_array_equal(scalars(q), ds.q[:, i])
        np.testing.assert_array_equal(scalars(content[f"{j}/exact"]), truth.q[:, i])
        tau = content[f"/series/torque/joint{i + 1}/commanded"]
        assert scalars(tau)[0] == ds.tau[0, i] and tau["t"][0] == pytest.approx(ds.t[0], abs=1e-9)
        np.testing.assert_array_equal(scalars(content[f"/series/torque/joint{i + 1}/noise"]), truth.noise[:, i])
        est = content[f"/series/qd/joint{i + 1}/estimated"]
        assert 0.8 * len(ds) < est["t"].size < len(ds)  # filter edges dropped
        # logged at the right time and joint: the estimate (filtered differences of the quantised q) follows
        # MuJoCo's exact speed, up to the noise-driven jitter the 20 Hz filter removes (~6 % of the peak here)
        exact = np.interp(est["t"], ds.t, truth.qd[:, i])
        assert np.max(np.abs(scalars(est) - exact)) < 0.15 * np.max(np.abs(truth.qd[:, i]))
    # residual rows: one per processed row, y - W theta_true at dataset.t[sample], within +-bound
    residual = eq.y - eq.W @ run.theta_true
    rows = 0
    for i in range(4):
        r = content[f"/series/residual/joint{i + 1}/residual"]
        sel = np.flatnonzero(eq.joint == i)
        rows += r["t"].size
        np.testing.assert_allclose(r["t"], ds.t[eq.sample[sel]], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(scalars(r), residual[sel])
        np.testing.assert_array_equal(scalars(content[f"/series/residual/joint{i + 1}/upper_bound"]), eq.bound[sel])
    assert rows == len(eq)


def test_scene_geometry(run, geometry, content):
    n = len(run.dataset)
    frames = np.arange(0, n, 20)  # 50 Hz of 1 kHz, plus the last sample
    frames = np.append(frames, n - 1) if frames[-1] != n - 1 else frames
    for entity in ("/robot/arms", "/robot/forearms", "/robot/nacelle", "/robot/joints", "/reference/nacelle"):
        np.testing.assert_allclose(content[entity]["t"], run.dataset.t[frames], rtol=0, atol=1e-9)
    arms = np.array(content["/robot/arms"]["LineStrips3D:strips"])  # (F, 4, 2, 3), float32
    np.testing.assert_allclose(arms[:, :, 0], np.broadcast_to(geometry.motor_pos, arms[:, :, 0].shape), atol=1e-6)
    arm = np.linalg.norm(arms[:, :, 1] - arms[:, :, 0], axis=-1)
    np.testing.assert_allclose(arm, np.broadcast_to(geometry.arm_length, arm.shape), atol=1e-6)
    # forearms from MuJoCo's exact states close the loops: |B_i - A_i| = l_i (loop violation ~1e-5 m)
    fore = np.array(content["/robot/forearms"]["LineStrips3D:strips"])
    np.testing.assert_allclose(fore[:, :, 0], arms[:, :, 1], atol=1e-7)
    lengths = np.linalg.norm(fore[:, :, 1] - fore[:, :, 0], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(geometry.forearm_length, lengths.shape), atol=1e-4)
    # the H: central bar 2 |bar_offset| long, through the nacelle centre D; lateral bars span the A_i
    h = np.array(content["/robot/nacelle"]["LineStrips3D:strips"])  # (F, 3, 2, 3)
    assert h.shape[1:] == (3, 2, 3)
    np.testing.assert_allclose(np.linalg.norm(h[:, 0, 1] - h[:, 0, 0], axis=-1),
                               2 * np.linalg.norm(geometry.bar_offset[0]), atol=1e-6)
    np.testing.assert_allclose(h[:, 0].mean(axis=1), run.truth.x[frames, :3], atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(h[:, 1:, 1] - h[:, 1:, 0], axis=-1),
                               2 * np.linalg.norm(geometry.attach_offset[0]), atol=1e-6)
    # the ghost H sits at the reference pose
    ghost = np.array(content["/reference/nacelle"]["LineStrips3D:strips"])
    np.testing.assert_allclose(ghost[:, 0].mean(axis=1), run.reference.x[frames, :3], atol=1e-6)
    for static in ("/robot/base", "/robot/motors", "/robot/nacelle_path", "/reference/nacelle_path", "/summary"):
        assert content[static]["static"], static


def test_box_history_logged(run, history, content):
    names = run.equation.names
    assert history["k"].size == POINTS and history["k"][-1] == pytest.approx(SECONDS - 1e-3)
    assert np.all(np.diff(history["rows"]) >= 0) and history["rows"][-1] == len(run.equation)
    hull = history["methods"]["hull"]
    # the last point is the full-data box, and every box encloses the truth (the oracle hull is exact)
    np.testing.assert_array_equal(hull["lower"][-1], run.boxes["hull"].lower)
    assert hull["enclosed"][hull["ok"]].all()
    # boxes only shrink as data accumulate (hull of a subset of the rows of the next point)
    w = (hull["upper"] - hull["lower"])[hull["ok"]]
    assert np.all(np.diff(w, axis=0) <= 1e-6)
    ok = int(hull["ok"].sum())
    assert ok >= 2
    for n, name in enumerate(names):
        lower = content[f"/estimate/{name}/hull/lower"]
        assert lower["t"].size == ok
        np.testing.assert_allclose(lower["t"], history["time"][hull["ok"]], atol=1e-9)
        np.testing.assert_array_equal(scalars(lower), hull["lower"][hull["ok"], n])
        np.testing.assert_array_equal(scalars(content[f"/estimate/{name}/true"]), np.full(POINTS, run.theta_true[n]))
    # cgsp failed on the full data (stand-in): that point is skipped with the message, never raised
    cgsp = history["methods"]["cgsp"]
    assert not cgsp["ok"][-1] and "stand-in failure" in cgsp["message"][-1]
    assert np.isnan(cgsp["lower"][-1]).all()


def test_box_history_skips_failing_points(run):
    calls = []

    def flaky(W, y, bound, prior, method):
        calls.append(len(y))
        if len(y) < len(run.equation):
            raise ValueError("inconsistent")
        return prior

    run_no_boxes = dataclasses.replace(run, boxes={}, failures={})
    h = box_history(run_no_boxes, methods=("hull",), points=3, estimator=flaky)
    res = h["methods"]["hull"]
    assert res["ok"].tolist() == [False, False, True]
    assert all("inconsistent" in m for m in res["message"][:2]) and res["message"][2] is None
    assert calls[-1] == len(run.equation)
    # fewer rows than parameters: skipped without calling the estimator
    short = box_history(run_no_boxes, methods=("hull",), points=200, estimator=flaky)
    first = short["methods"]["hull"]["message"][0]
    assert short["rows"][0] < 14 and "rows < 14 parameters" in first


def test_blueprint_lays_out_the_views(rrd):
    from rerun.chunk import RrdReader

    reader = RrdReader(str(rrd))
    (store,) = reader.blueprints()
    origins, kinds = set(), set()
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        for name in rb.schema.names:
            if not name.endswith(("space_origin", "class_identifier")):
                continue
            values = [v for row in rb.column(name).to_pylist() for v in (row if isinstance(row, list) else [row])]
            if name.endswith("space_origin"):
                origins.update(map(str, values))
            if name.endswith("class_identifier"):
                kinds.update(map(str, values))
    assert {"3D", "TimeSeries", "TextDocument"} <= kinds
    flat = " ".join(origins)
    for origin in ("series/q/joint1", "series/torque/joint4", "series/residual/joint2", "estimate/Imot1", "summary"):
        assert origin in flat, origin


def test_write_replay_validates(run, tmp_path):
    with pytest.raises(ReplayError, match="must end with .rrd"):
        write_replay(run, tmp_path / "replay.txt", history_points=0)
    with pytest.raises(ReplayError, match="history_points"):
        write_replay(run, tmp_path / "replay.rrd", history_points=-1)
    assert list(tmp_path.iterdir()) == []


def test_write_replay_with_project_estimators(run, tmp_path):
    """The default estimator is ident.estimate (skipped until the estimators land)."""
    if not hasattr(ident, "estimate"):
        pytest.skip("h4bench.ident.estimate not available yet")
    r = dataclasses.replace(run, boxes={}, failures={})
    h = box_history(r, methods=("hull",), points=2)
    assert h["methods"]["hull"]["ok"][-1]
    assert h["methods"]["hull"]["enclosed"][-1].all()
    r.boxes["hull"] = ident.estimate(r.equation.W, r.equation.y, r.equation.bound, r.prior, method="hull")
    assert write_replay(r, tmp_path / "replay.rrd", history_points=2).is_file()


def test_viewer_command_checks_the_file(rrd, tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        viewer_command(tmp_path / "missing.rrd")
    fake = tmp_path / "fake.rrd"
    fake.write_bytes(b"not a recording")
    with pytest.raises(ReplayError, match="not a Rerun recording"):
        viewer_command(fake)
    wrong_suffix = tmp_path / "replay.bin"
    wrong_suffix.write_bytes(rrd.read_bytes()[:64])
    with pytest.raises(ReplayError, match="not a Rerun recording"):
        viewer_command(wrong_suffix)
    with pytest.raises(ReplayError, match="directory"):
        viewer_command(tmp_path)
    native = viewer_command(rrd)
    assert native[-1] == str(rrd) and "--web-viewer" not in native
    web = viewer_command(rrd, web=True, port=9191)
    assert web[-4:] == ["--web-viewer", "--web-viewer-port", "9191", str(rrd)]
    # this machine only unless asked (Rerun's own default is 0.0.0.0, every interface)
    for cmd in (native, web):
        assert cmd[cmd.index("--bind") + 1] == "127.0.0.1"
    anywhere = viewer_command(rrd, web=True, bind="0.0.0.0")
    assert anywhere[anywhere.index("--bind") + 1] == "0.0.0.0"
    with pytest.raises(ReplayError, match="--bind must be an IP address.*'localhost:80'"):
        viewer_command(rrd, bind="localhost:80")


_VIEWER_PARENT = """
import sys
import h4bench.scenarios.replay as replay
child = [sys.executable, "-c", "import time; print('viewer up', flush=True); time.sleep(120)"]
replay.viewer_command = lambda *a, **k: child  # a stand-in for rerun (same process tree)
replay.open_viewer(sys.argv[1])
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="process checks via ps and /proc")
@pytest.mark.parametrize("how", ["SIGTERM", "SIGKILL"])
def test_the_viewer_dies_with_h4bench_replay(tmp_path, rrd, how):
    import signal
    import time

    (tmp_path / "parent.py").write_text(_VIEWER_PARENT)
    proc = subprocess.Popen([sys.executable, str(tmp_path / "parent.py"), str(rrd)], stdout=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.stdout.readline().strip() == "viewer up"
    children = subprocess.run(["ps", "-o", "pid=", "--ppid", str(proc.pid)], capture_output=True,
                              text=True).stdout.split()
    assert len(children) == 1
    child = int(children[0])
    proc.send_signal(getattr(signal, how))
    proc.wait(timeout=10)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            break
        status = Path(f"/proc/{child}/status")
        if status.exists() and "\nState:\tZ" in status.read_text():
            break
        time.sleep(0.1)
    else:
        os.kill(child, signal.SIGKILL)
        pytest.fail(f"the viewer (pid {child}) outlived h4bench replay ({how})")


def test_rerun_is_imported_lazily():
    code = "import sys, scenarios.replay, scenarios.experiment; print('rerun' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
