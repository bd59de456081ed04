"""``h4bench identify`` on a user's log: bounded-memory reading, block processing, exit codes, option errors,
a table that fits 80 columns, per-parameter priors and per-joint bounds, one JSON document on stdout.

Oracles: Python's own ``float()`` on the CSV text (reader), the whole-record processing rebuilt here from
:mod:`ident.processing.filtering` and :func:`ident.robots.h4.regressor` (blocks), the propagated bound ``|h| * b`` computed
from the taps (per-joint bounds), the simulator's true parameters (enclosure), ``json.loads`` (stdout).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from h4bench import ident
from h4bench import sim
from h4bench.ident.processing.filtering import ProcessingSettings, derivatives, exclude_low_speed, parallel_filter
from h4bench.ident.robots.h4_equation import build_equation
from h4bench.ident.robots.h4 import regressor
from h4bench.scenarios.cli import app
from h4bench.scenarios.cli_output import print_summary as _print_summary
from h4bench.scenarios.spec import DEFAULTS

HEADER = "t,q1,q2,q3,q4,tau1,tau2,tau3,tau4"
ROOT = Path(__file__).resolve().parents[2]


def _write(path, t, q, tau, fmt="%.17g"):
    np.savetxt(path, np.column_stack([t, q, tau]), delimiter=",", header=HEADER, comments="", fmt=fmt)
    return path


@pytest.fixture(scope="module")
def experiment():
    from h4bench.scenarios.experiment import run_experiment
    from h4bench.scenarios.spec import load_spec

    spec = load_spec("paper", quick=True)  # 4 s at 1 kHz, uniform noise of bound 1.0 N m, bound 1.5 N m
    spec["replay"]["enabled"] = False
    return run_experiment(spec, seed=5, estimate=False)


@pytest.fixture(scope="module")
def good_csv(experiment, tmp_path_factory):
    ds = experiment.dataset
    return _write(tmp_path_factory.mktemp("log") / "good.csv", ds.t, ds.q, ds.tau)


def _invoke(*args):
    return CliRunner().invoke(app, ["identify", *map(str, args)])


def _one_error_line(res, *fragments):
    """exit 2, one ``error:`` line naming the fragments, no traceback."""
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and res.exception is None or isinstance(res.exception, SystemExit)
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    for f in fragments:
        assert f in lines[0], (f, lines[0])


# ---------------------------------------------------------------------------------------------- 1. reading


def test_reader_is_exact_with_both_engines(tmp_path):
    from h4bench.sim.csvlog import read_log

    rng = np.random.default_rng(0)
    n = 5000
    t = np.arange(n) * 1e-3
    q, tau = rng.normal(size=(n, 4)) * 10.0 ** rng.integers(-8, 3, (n, 4)), rng.normal(size=(n, 4))
    path = _write(tmp_path / "log.csv", t, q, tau, fmt="%.17g")
    text = [line.split(",") for line in path.read_text().splitlines()[1:]]
    oracle = np.array([[float(v) for v in row] for row in text])  # Python's correctly rounded float()
    for engine in ("arrow", "numpy"):
        t2, q2, tau2 = read_log(path, engine=engine)
        assert np.array_equal(t2, oracle[:, 0]) and np.array_equal(q2, oracle[:, 1:5])
        assert np.array_equal(tau2, oracle[:, 5:]), engine
        assert q2.flags.c_contiguous and tau2.shape == (n, 4)


def test_reader_memory_is_a_small_multiple_of_the_arrays(tmp_path):
    """The generic text reader took ~12x the file size; the streaming reader holds the 72 bytes/row result
    plus one block. Measured as the growth of the peak RSS in a fresh process (pyarrow's pool is outside
    tracemalloc's view)."""
    n = 200_000
    rng = np.random.default_rng(1)
    import pyarrow
    import pyarrow.csv

    cols = {"t": np.arange(n) * 1e-3, **{c: rng.normal(size=n) for c in HEADER.split(",")[1:]}}
    path = tmp_path / "big.csv"
    with path.open("wb") as fh:  # pyarrow's C++ writer: 17 significant digits, fast
        fh.write(HEADER.encode() + b"\n")
        pyarrow.csv.write_csv(pyarrow.table(cols), fh, write_options=pyarrow.csv.WriteOptions(include_header=False))
    code = ("import resource, sys, numpy, pyarrow.csv, sim\n"
            "r0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
            "d = sim.Dataset.from_csv(sys.argv[1])\n"
            "print((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - r0) * 1024, len(d))\n")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True, cwd=ROOT)
    growth, rows = map(int, out.stdout.split())
    assert rows == n
    size = path.stat().st_size  # ~34 MB; result arrays 72 * n = 14.4 MB
    assert growth < 1.5 * size, (growth, size)


@pytest.mark.parametrize("body, fragments", [
    ("0,1,1,1,1,1,1,1,1\n0.001,1,x,1,1,1,1,1,1\n", ["column q2", "'x'", "data row 2"]),
    ("0,1,1,1,1,1,1,1,1\n0.001,1,1,1,1,1,1,1\n", ["data row 2", "8 values", "expected 9"]),
    ("0,1,1,1,1,1,1,1,1\n0.001,1,1,1,1,,1,1,1\n", ["column tau", "NaN/empty", "data row 2", "tau1"]),
    ("0,1,1,1,1,1,1,1,1\n0.001,1,1,inf,1,1,1,1,1\n", ["column q", "non-finite", "data row 2", "q3"]),
])
def test_reader_errors_name_file_column_and_row(tmp_path, body, fragments):
    path = tmp_path / "bad.csv"
    path.write_text(HEADER + "\n" + body)
    with pytest.raises(sim.DatasetError) as err:
        sim.Dataset.from_csv(path)
    for f in [str(path)] + fragments:
        assert f in str(err.value), (f, str(err.value))


def test_reader_header_errors(tmp_path):
    path = tmp_path / "dup.csv"
    path.write_text("t,q1,q1,q2,q3,q4,tau1,tau2,tau3,tau4\n" + "0,1,1,1,1,1,1,1,1,1\n" * 3)
    with pytest.raises(sim.DatasetError, match=r"once, got \['q1'\] repeated"):
        sim.Dataset.from_csv(path)
    path.write_text('"t","q1","q2","q3","q4","tau1","tau2","tau3","tau4",extra\n'
                    + "".join(f"{k * 1e-3},1,2,3,4,5,6,7,8,text\n" for k in range(5)))
    d = sim.Dataset.from_csv(path)  # quoted header, a non-numeric extra column: ignored
    assert len(d) == 5 and np.array_equal(d.tau[0], [5, 6, 7, 8])


# --------------------------------------------------------------------------------------------- 1. blocks


def _whole_record(geometry, ds, row_bound, settings, t_abs):
    """The paper's processing on the whole record, straight from ident.processing.filtering (the reference)."""
    est = derivatives(ds.q, ds.dt, settings.position_cutoff_hz, settings.butter_order, timing=settings.torque_timing)
    v = est.valid
    samples = np.arange(len(ds))[v]
    w = regressor(geometry, est.q[v], est.qd[v], est.qdd[v])
    y = ds.tau[v].reshape(-1)
    keep = exclude_low_speed(est.qd[v], settings.speed_threshold)
    b = np.asarray(row_bound).reshape(-1)[4 * v.start: 4 * v.stop]
    fe = parallel_filter(w, y, b, settings.decimation, taps=settings.taps(), theta_abs_max=t_abs)
    rows = np.flatnonzero(fe.propagate_mask(keep))
    return fe.W[rows], fe.y[rows], fe.bound[rows], samples[fe.sample_index[rows // 4]], rows % 4


@pytest.mark.parametrize("timing", ["hold", "sample"])
def test_blocks_give_the_rows_of_the_whole_record(experiment, timing):
    ds, geometry = experiment.dataset, experiment.geometry
    settings = ProcessingSettings(dt=ds.dt, **{**DEFAULTS["processing"], "torque_timing": timing})
    prior = ident.Box(np.zeros(14), np.full(14, 2.0))
    per_joint = np.array([1.2, 1.5, 1.5, 1.0])
    W0, y0, b0, s0, j0 = _whole_record(geometry, ds, np.tile(per_joint, len(ds)), settings, np.full(14, 2.0))
    for block in (len(ds) + 1, 997, 1500):
        eq = build_equation(geometry, ds, per_joint, settings, prior=prior, block_samples=block)
        assert (eq.info["blocks"] > 1) == (block < len(ds))
        assert np.array_equal(eq.sample, s0) and np.array_equal(eq.joint, j0)
        assert np.array_equal(eq.y, y0)  # the same FIR sums in the same order
        # W: the derivative estimates differ only at the rounding level of the filter and the second difference
        # (ulp(q) / dt^2 ~ 1e-10 absolute on qdd); per column 1e-10 of its largest entry (5e-12 measured)
        scale = np.maximum(np.abs(W0).max(axis=0), 1e-300)
        assert np.all(np.abs(eq.W - W0).max(axis=0) <= 1e-10 * scale)
        assert np.array_equal(eq.W[:, 10:], W0[:, 10:])  # the sign(qd) (Coulomb) columns: no speed changed sign
        assert np.allclose(eq.bound, b0, rtol=1e-12, atol=0)
    one = build_equation(geometry, ds, per_joint, settings, prior=prior)  # a short log is one block: exact
    assert one.info["blocks"] == 1 and np.array_equal(one.W, W0) and np.array_equal(one.bound, b0)
    # without the parallel filter (decimation 1, one tap) the kept raw rows themselves, per-joint bounds
    raw = ProcessingSettings(**{**DEFAULTS["processing"], "dt": ds.dt, "decimation": 1, "numtaps": 1})
    whole, blocked = (build_equation(geometry, ds, per_joint, raw, block_samples=k) for k in (len(ds) + 1, 1234))
    assert blocked.info["blocks"] > 1 and not blocked.info["filtered"]
    assert np.array_equal(whole.sample, blocked.sample) and np.array_equal(whole.y, blocked.y)
    assert np.array_equal(blocked.bound, per_joint[blocked.joint])
    assert np.all(np.abs(whole.W - blocked.W).max(axis=0) <= 1e-10 * np.maximum(np.abs(whole.W).max(axis=0), 1e-300))


def test_blocks_bound_the_peak_memory(experiment):
    ds, geometry = experiment.dataset, experiment.geometry
    n = 40_000  # the run tiled: 10 x 4 s (the tiles join at rest)
    idx = np.tile(np.arange(len(ds)), -(-n // len(ds)))[:n]
    long = sim.Dataset(np.arange(n) * ds.dt, ds.q[idx], ds.tau[idx])
    settings = ProcessingSettings(dt=ds.dt, **DEFAULTS["processing"])
    peaks = {}
    for block in (n, 5000):
        tracemalloc.start()
        eq = build_equation(geometry, long, 1.5, settings, prior=(np.zeros(14), np.full(14, 2.0)), block_samples=block)
        peaks[block] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    # the whole record holds its raw regressor (40k x 4 x 14 x 8 B = 18 MB) and temporaries; blocks of 5000
    # samples hold an eighth of that plus the processed equation
    assert peaks[5000] < 0.35 * peaks[n], peaks
    assert peaks[5000] < 10 * eq.W.nbytes + 16 * 5000 * 4 * 14 * 8 / 4, (peaks, eq.W.nbytes)


def test_per_joint_bound_is_propagated_per_row(experiment):
    ds, geometry = experiment.dataset, experiment.geometry
    settings = ProcessingSettings(dt=ds.dt, **DEFAULTS["processing"])
    per_joint = np.array([1.2, 1.5, 1.5, 1.0])
    eq = build_equation(geometry, ds, per_joint, settings, prior=(np.zeros(14), np.full(14, 2.0)))
    l1 = np.abs(settings.taps()).sum()  # |h| * b for a bound constant along each joint's rows
    for i in range(4):
        b = eq.bound[eq.joint == i]
        assert b.size and np.all(b >= l1 * per_joint[i]) and np.all(b <= l1 * per_joint[i] * (1 + 1e-6)), i
    with pytest.raises(ValueError, match="joint 4"):
        build_equation(geometry, ds, [1.0, 1.0, 1.0, -1.0], settings)


# ---------------------------------------------------------------------------------- 2, 3, 4. exit codes


def test_inconsistent_data_exit_3_and_help(good_csv, tmp_path):
    res = _invoke(good_csv, "--bound", "0.05", "--out", tmp_path / "o")
    assert res.exit_code == 3, res.output
    assert "inconsistent" in res.output and "smallest consistent bound" in res.output
    result = json.loads((tmp_path / "o" / "result.json").read_text())
    assert result["consistent"] is False and result["methods"]["hull"]["min_bound"] > 0.05
    help_text = CliRunner().invoke(app, ["identify", "--help"], env={"COLUMNS": "200"}).output
    assert "Exit codes" in help_text and "3 the data are proven" in help_text


def test_static_log_names_the_cause(tmp_path):
    n = 3000
    path = _write(tmp_path / "static.csv", np.arange(n) * 1e-3, np.full((n, 4), 0.1), np.ones((n, 4)))
    res = _invoke(path, "--bound", "1.5", "--out", tmp_path / "o")
    _one_error_line(res, "speed threshold 0.05 rad/s", "processing.speed_threshold", "robot must move")


@pytest.mark.parametrize("args, fragments", [
    (["--prior-upper", "inf"], ["--prior-upper", "finite number", "'inf'"]),
    (["--prior-lower", "nan"], ["--prior-lower", "finite number", "'nan'"]),
    (["--prior-lower", "abc"], ["--prior-lower", "'abc'"]),
    (["--prior-lower", "3"], ["--prior-lower must be < --prior-upper", "3 and 2"]),
    (["--bound", "abc"], ["--bound", "comma-separated", "'abc'"]),
    (["--bound", "0"], ["--bound", "> 0", "'0'"]),
    (["--bound", "1,2,3"], ["--bound", "3 values"]),
    (["--bound", "1,2,x,1"], ["--bound (joint 3)", "'x'"]),
    (["--method", "lsq"], ["--method", "hull | cgsp | ", "'lsq'"]),
    (["--prior", "nope.toml"], ["--prior", "nope.toml", "not found"]),
    (["--bound", "nope.csv"], ["--bound", "nope.csv", "not found"]),
    (["--torque-timing", "zoh"], ["--torque-timing", "hold or sample", "'zoh'"]),
])
def test_bad_option_values_give_one_error_line(good_csv, tmp_path, args, fragments):
    full = ["--bound", "1.5"] + args if "--bound" not in args else args
    _one_error_line(_invoke(good_csv, *full, "--out", tmp_path / "o"), *fragments)


# -------------------------------------------------------------------------------------------- 5. the table


def _paper_like_result():
    rng = np.random.default_rng(2)
    true = np.array(ident.NOMINAL_PARAMETERS, dtype=float) * 1.37e-1
    lo, hi = true * 0.9, true * 1.1 + 3.77e-4
    return {"scenario": "paper", "seed": 0, "parameters": list(ident.PARAMETER_NAMES), "true": true.tolist(),
            "methods": {m: {"status": "ok", "lower": lo.tolist(), "upper": hi.tolist(),
                            "enclosed": [True] * 13 + [False]} for m in ("hull", "cgsp")},
            "wls": {"theta": (true * (1 + 0.01 * rng.normal(size=14))).tolist(),
                    "rel_std_percent": (100 * rng.random(14)).tolist()},
            "bound": 1.5, "bound_processed": 1.592, "oracle_residual": 1.2, "min_consistent_bound": 0.36}


def _floats(line):
    out = []
    for tok in line.replace("[", " ").replace("]", " ").replace(",", " ").split():
        try:
            out.append(float(tok))
        except ValueError:
            pass
    return np.array(out)


@pytest.mark.parametrize("columns", [80, 60, 200])
def test_summary_fits_the_terminal(monkeypatch, capsys, columns):
    monkeypatch.setenv("COLUMNS", str(columns))
    result = _paper_like_result()
    _print_summary(result)
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert max(len(ln) for ln in lines) <= columns and "…" not in out
    for j, name in enumerate(result["parameters"]):  # every value printed whole (4 digits) on its parameter's line
        values = np.concatenate([_floats(ln) for ln in lines if ln.replace("│", " ").split()[:1] == [name]])
        for v in (result["true"][j], result["methods"]["cgsp"]["upper"][j], result["wls"]["theta"][j]):
            assert np.any(np.abs(values - v) <= 5e-4 * abs(v)), (name, v, values)
    assert out.count("NO") == 2  # the one parameter not enclosed, by each method


def test_number_format_is_short_and_exact_to_4_digits():
    from h4bench.scenarios.cli_output import num as _num

    for x in (3.770e-4, -1.234e-9, 0.06074, 12.35, 1234.5, 9.99e7, 0.0, -0.5, 123456.0):
        s = _num(x)
        assert len(s) <= 9 and float(s) == pytest.approx(x, rel=5e-4), (x, s)


# ---------------------------------------------------------------------------- 6. priors and bounds files


def test_prior_and_bound_files(good_csv, experiment, tmp_path):
    theta = experiment.theta_true
    names = ident.PARAMETER_NAMES
    toml = tmp_path / "prior.toml"
    toml.write_text("".join(f"[{n}]\nlower = {float(0.5 * v)!r}\nupper = {float(1.5 * v)!r}\n" for n, v in zip(names[:6], theta)))
    csv = tmp_path / "prior.csv"
    csv.write_text("name,lower,upper\n" + "".join(f"{n},{float(0.5 * v)!r},{float(1.5 * v)!r}\n" for n, v in zip(names[6:], theta[6:])))
    bounds = tmp_path / "bounds.toml"
    bounds.write_text("joint1 = 1.5\njoint2 = 1.5\njoint3 = 1.5\njoint4 = 1.6\n")
    for prior_file, given in ((toml, slice(0, 6)), (csv, slice(6, 14))):
        res = _invoke(good_csv, "--bound", bounds, "--prior", prior_file, "--out", tmp_path / prior_file.stem, "--json")
        assert res.exit_code == 0, res.output
        result = json.loads(res.output)
        lower, upper = np.array(result["prior"]["lower"]), np.array(result["prior"]["upper"])
        assert np.array_equal(lower[given], 0.5 * theta[given]) and np.array_equal(upper[given], 1.5 * theta[given])
        others = np.ones(14, bool)
        others[given] = False
        assert np.all(lower[others] == 0.0) and np.all(upper[others] == 2.0)  # the default pair
        box = result["methods"]["hull"]
        assert np.all(np.array(box["lower"]) >= lower) and np.all(np.array(box["upper"]) <= upper)
        assert np.all(np.array(box["lower"]) <= theta) and np.all(theta <= np.array(box["upper"]))
        assert result["bound"] == [1.5, 1.5, 1.5, 1.6]
    bcsv = tmp_path / "bounds.csv"
    bcsv.write_text("joint,bound\n1,1.5\n2,1.5\n3,1.5\n4,1.6\n")
    res = _invoke(good_csv, "--bound", bcsv, "--method", "wls", "--out", tmp_path / "w", "--json")
    assert res.exit_code == 0 and json.loads(res.output)["bound"] == [1.5, 1.5, 1.5, 1.6]


@pytest.mark.parametrize("name, text, fragments", [
    ("p.toml", "[Imot9]\nlower = 0\nupper = 1\n", ["p.toml", "'Imot9'", "one of"]),
    ("p.toml", "[Fv1]\nlower = 1\nupper = 0.5\n", ["p.toml", "Fv1", "lower < upper"]),
    ("p.toml", "[Fv1]\nlower = 1\n", ["p.toml", "Fv1", "lower and upper", "['lower']"]),
    ("p.toml", "[Fv1\n", ["p.toml", "not valid TOML"]),
    ("p.csv", "name,lower,upper\n\nFv1,0,1\nMnac,0,x\n", ["p.csv", "line 4", "Mnac.upper", "'x'"]),
    ("p.csv", "name,lower,upper\nMnac,0,inf\n", ["p.csv", "line 2", "Mnac.upper", "finite"]),
    ("p.csv", "param,lo,hi\nMnac,0,1\n", ["p.csv", "header name,lower,upper"]),
    ("p.txt", "", ["--prior file must end in .toml or .csv"]),
])
def test_prior_file_errors(good_csv, tmp_path, name, text, fragments):
    path = tmp_path / name
    path.write_text(text)
    _one_error_line(_invoke(good_csv, "--bound", "1.5", "--prior", path, "--out", tmp_path / "o"), "--prior", *fragments)


@pytest.mark.parametrize("name, text, fragments", [
    ("b.toml", "joint1 = 1\njoint2 = 1\njoint3 = 1\n", ["b.toml", "missing ['joint4']"]),
    ("b.toml", "joint1 = 1\njoint2 = 1\njoint3 = 1\njoint5 = 1\n", ["b.toml", "'joint5'"]),
    ("b.csv", "joint,bound\n1,1\n2,1\n3,-1\n4,1\n", ["b.csv", "line 4", "joint3", "> 0"]),
])
def test_bound_file_errors(good_csv, tmp_path, name, text, fragments):
    path = tmp_path / name
    path.write_text(text)
    _one_error_line(_invoke(good_csv, "--bound", path, "--out", tmp_path / "o"), "--bound", *fragments)


# -------------------------------------------------------------------------------------------- 7. --json


def test_json_is_the_only_stdout(good_csv, tmp_path):
    cmd = [sys.executable, "-c", "from h4bench.scenarios.cli import app; app()", "identify", str(good_csv), "--bound", "1.5",
           "--out", str(tmp_path / "o"), "--json"]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env={**os.environ, "COLUMNS": "80"})
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["methods"]["hull"]["status"] == "ok"


def test_json_survives_native_output_on_fd_1(good_csv, tmp_path):
    """A native library writing to file descriptor 1 during the estimation (as HiGHS's banner did)."""
    code = ("import functools, os\nimport h4bench.ident.estimators.estimate as e\n"  # the registry's hull resolves this
            "est = e.hull_estimator\n"
            "@functools.wraps(est)\n"  # the same signature: the registry passes only what the hull accepts
            "def noisy(*a, **k):\n"
            "    os.write(1, b'Running HiGHS (native banner)\\n')\n"
            "    return est(*a, **k)\n"
            "e.hull_estimator = noisy\n"
            "from h4bench.scenarios.cli import app\n"
            "app()\n")
    cmd = [sys.executable, "-c", code, "identify", str(good_csv), "--bound", "1.5", "--out", str(tmp_path / "o"), "--json"]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["methods"]["hull"]["status"] == "ok" and "native banner" in out.stderr
