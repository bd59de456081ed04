"""``h4bench identify --urdf``: any serial robot's log, here the real TX40's (data/tx40), and the physical prior.

Oracles: the TX40 prior's former formulas, written out here (``_tx40_prior_formulas``: the TX40 numbers of
ident.robots.tx40 and the URDF limits); for the command, the same box computed directly from :func:`ident.robots.serial.process`
and :func:`ident.estimate` with the documented settings (``URDF_PROCESSING``, default mass and reach);
``json.loads`` of stdout; exit codes 2 (bad option or data) and 3 (proven inconsistent).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from h4bench import ident
from h4bench.ident.robots import tx40
from h4bench.ident.robots.serial import SerialRobot, default_reach, parameter_joint, physical_prior, process
from h4bench.scenarios.cli import app
from h4bench.scenarios.identify import URDF_PROCESSING

URDF = tx40.urdf_path()
SAMPLES = 10_000  # 2 s of the 5 kHz log: about 90 processed rows per joint at decimation 100


def _tx40_prior_formulas(robot):
    """h4bench.ident.robots.tx40.standard_prior as it was written before physical_prior existed (the reference)."""
    p = robot.n_parameters
    lo, hi = np.zeros(p), np.zeros(p)
    M, r = tx40.ARM_MASS, tx40.REACH
    off = {"m": (0.0, M), "mx": (-M * r, M * r), "my": (-M * r, M * r), "mz": (-M * r, M * r),
           "Ixx": (0.0, M * r * r), "Iyy": (0.0, M * r * r), "Izz": (0.0, M * r * r),
           "Ixy": (-M * r * r / 2, M * r * r / 2), "Ixz": (-M * r * r / 2, M * r * r / 2),
           "Iyz": (-M * r * r / 2, M * r * r / 2)}
    effort = np.asarray(robot.model.effortLimit, dtype=float)
    vmax = np.asarray(robot.model.velocityLimit, dtype=float)
    ratios = np.abs(np.asarray(tx40.RATIOS))
    for j, name in enumerate(robot.names):
        prefix, i = parameter_joint(name)  # the name parsing is shared; the formulas below are the reference
        if prefix in off:
            lo[j], hi[j] = off[prefix]
        elif prefix in ("fv", "fvm"):
            hi[j] = effort[i] / vmax[i]
        elif prefix in ("fs", "fsm"):
            hi[j] = effort[i]
        elif prefix in ("Ia", "Iam"):
            hi[j] = tx40.MOTOR_INERTIA_MAX * ratios[i] ** 2
        elif prefix == "off":
            lo[j], hi[j] = -0.2 * effort[i], 0.2 * effort[i]
    return lo, hi


@pytest.mark.parametrize("options", [{}, {"friction": False}, {"coupled_wrist": None, "offset": False}])
def test_tx40_standard_prior_unchanged(options):
    robot = tx40.robot(**options)
    lo, hi = tx40.standard_prior(robot)
    ref_lo, ref_hi = _tx40_prior_formulas(robot)
    np.testing.assert_array_equal(lo, ref_lo)
    np.testing.assert_array_equal(hi, ref_hi)


def test_physical_prior_defaults_and_errors():
    robot = SerialRobot(URDF)
    M, r = 10.0, 0.5
    lo, hi = physical_prior(robot, M, r)
    names = list(robot.names)
    assert hi[names.index("m3")] == M and lo[names.index("mx2")] == -M * r
    assert hi[names.index("Ia1")] == M * r * r  # rotor_inertia_max None, ratios None: J = M r^2 on the joint side
    effort = np.asarray(robot.model.effortLimit)
    assert hi[names.index("off4")] == pytest.approx(0.2 * effort[3]) and lo[names.index("off4")] == -hi[names.index("off4")]
    for kwargs, word in (({"total_mass": 0.0}, "total_mass"), ({"reach": -1.0}, "reach"),
                         ({"ratios": (1.0, 2.0)}, "ratios"), ({"offset_fraction": -0.1}, "offset_fraction")):
        args = {"total_mass": M, "reach": r, **kwargs}
        with pytest.raises(ValueError, match=word):
            physical_prior(robot, args.pop("total_mass"), args.pop("reach"), **args)
    # the default reach: joint-origin offsets plus the last link's centre-of-mass distance, from the URDF
    model = robot.model
    seg = sum(np.linalg.norm(model.jointPlacements[i].translation) for i in range(1, model.njoints))
    assert default_reach(robot) == pytest.approx(seg + np.linalg.norm(model.inertias[model.njoints - 1].lever))
    assert default_reach(robot) > tx40.REACH  # wider than the data sheet's reach (axis 2 to the flange)


# ------------------------------------------------------------------------------------------------ command
def _header(n):
    return "t," + ",".join(f"q{i}" for i in range(1, n + 1)) + "," + ",".join(f"tau{i}" for i in range(1, n + 1))


@pytest.fixture(scope="module")
def log_csv(tmp_path_factory):
    """The first SAMPLES of the TX40 log on the joint side (ident.robots.tx40.load_log's conversion), with an extra
    column the reader must ignore."""
    log = tx40.load_log()
    q, tau, t = log.q[:SAMPLES], log.tau[:SAMPLES], log.t[:SAMPLES]
    path = tmp_path_factory.mktemp("tx40") / "tx40.csv"
    data = np.column_stack([t, q, tau, np.zeros(SAMPLES)])
    np.savetxt(path, data, delimiter=",", header=_header(6) + ",note", comments="", fmt="%.17g")
    return path, q, tau, log.dt


@pytest.fixture(scope="module")
def oracle(log_csv):
    """Processed equation and prior computed directly with the documented defaults."""
    import pinocchio

    _, q, tau, dt = log_csv
    robot = SerialRobot(URDF)
    p = URDF_PROCESSING
    base = robot.base(p["base_samples"], p["seed"])
    lo_s, hi_s = physical_prior(robot, 2.0 * pinocchio.computeTotalMass(robot.model), default_reach(robot),
                                offset_fraction=0.2)
    blo, bhi = base.box_from_standard(lo_s, hi_s)
    eq = process(robot, base, q, tau, dt, cutoff_hz=p["cutoff_hz"], decimation=p["decimation"],
                 numtaps=p["numtaps_per_decimation"] * p["decimation"] + 1, fir_cutoff=p["fir_cutoff"],
                 speed_threshold=p["speed_threshold"], butter_order=p["butter_order"],
                 torque_timing=p["torque_timing"], theta_abs_max=np.maximum(np.abs(blo), np.abs(bhi)))
    prior = ident.Box(blo, bhi)
    return eq, prior, base, ident.min_consistent_bound(eq.W, eq.y, prior)


def _run(*args):
    return CliRunner().invoke(app, ["identify", *map(str, args)])


def _one_error(res, *words):
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), res.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


def test_urdf_box_matches_direct_computation(log_csv, oracle, tmp_path):
    path = log_csv[0]
    eq, prior, base, t_min = oracle
    b = 2.0 * t_min / eq.gain  # raw-row bound: processed bound about 2 x the min consistent one
    res = _run(path, "--urdf", URDF, "--bound", repr(b), "--out", tmp_path / "run", "--json")
    assert res.exit_code == 0, res.output + res.stderr
    result = json.loads(res.stdout)
    assert result == json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["parameters"] == list(base.names) and len(result["parameter_expressions"]) == len(base)
    box = ident.estimate(eq.W, eq.y, eq.bound(b), prior, method="hull")
    m = result["methods"]["hull"]
    np.testing.assert_allclose(m["lower"], box.lower, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(m["upper"], box.upper, rtol=1e-9, atol=1e-9)
    assert result["consistent"] is True and result["rows"] == len(eq)
    assert result["min_consistent_bound"] == pytest.approx(t_min, rel=1e-6)
    assert np.all(np.array(m["lower"]) >= np.array(result["prior"]["lower"]))
    assert np.all(np.array(m["upper"]) <= np.array(result["prior"]["upper"]))
    assert np.mean(np.array(m["width"]) / (prior.upper - prior.lower)) < 1.0  # the data tighten the prior
    # the table fits 80 columns
    res = CliRunner().invoke(app, ["identify", str(path), "--urdf", str(URDF), "--bound", repr(b), "--out",
                                   str(tmp_path / "run2")], env={"COLUMNS": "80"})
    assert res.exit_code == 0, res.stderr
    assert max(len(ln) for ln in res.stdout.splitlines()) <= 80
    assert "Izz1'" in res.stdout and "base parameters (base <- standard)" in res.stdout


def test_urdf_inconsistent_bound_exit_3(log_csv, oracle, tmp_path):
    eq, _, _, t_min = oracle
    b = 0.2 * t_min / eq.gain  # processed bound 0.2 x the minimum consistent one: provably inconsistent
    res = _run(log_csv[0], "--urdf", URDF, "--bound", repr(b), "--out", tmp_path / "run")
    assert res.exit_code == 3, res.stderr
    assert "inconsistent" in res.stderr
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["consistent"] is False and result["methods"]["hull"]["status"] == "inconsistent"


def test_urdf_option_errors(log_csv, tmp_path):
    path = log_csv[0]
    four = tmp_path / "four.csv"  # 4 joints' columns for a 6-joint URDF
    np.savetxt(four, np.column_stack([np.arange(10) * 2e-4, np.zeros((10, 8))]), delimiter=",",
               header=_header(4), comments="", fmt="%g")
    res = _run(four, "--urdf", URDF, "--bound", "1", "--out", tmp_path / "a")
    assert res.exit_code == 2
    _one_error(res, str(four), "q5", "tau6")
    res = _run(path, "--urdf", tmp_path / "missing.urdf", "--bound", "1", "--out", tmp_path / "b")
    assert res.exit_code == 2
    _one_error(res, "--urdf", "missing.urdf")
    for bad in ("abc", "1,2", "-1", "1,2,3,4,5,nan"):
        res = _run(path, "--urdf", URDF, "--bound", bad, "--out", tmp_path / "c")
        assert res.exit_code == 2, bad
        _one_error(res, "--bound")
    res = _run(path, "--urdf", URDF, "--bound", "1", "--mass", "0", "--out", tmp_path / "d")
    assert res.exit_code == 2
    _one_error(res, "--mass")
    res = _run(path, "--bound", "1", "--reach", "0.5", "--out", tmp_path / "e")
    assert res.exit_code == 2
    _one_error(res, "--reach", "--urdf")
    assert not any((tmp_path / d).exists() for d in "abcde")


def test_read_log_n_joints(tmp_path):
    """h4bench.sim.csvlog.read_log for 6 joints: both engines give Python's float() of the text; errors name the column
    and the row."""
    from h4bench.sim.csvlog import DatasetError, read_log

    rng = np.random.default_rng(3)
    data = np.column_stack([np.arange(50) * 1e-3, rng.normal(size=(50, 12))])
    path = tmp_path / "six.csv"
    lines = ["power,extra," + _header(6)]
    for row in data:
        lines.append(",".join(["%.9g" % row[12], "x"] + ["%.9g" % v for v in row]))
    path.write_text("\n".join(lines) + "\n")
    ref = np.array([[float(f) for f in ln.split(",")[2:]] for ln in lines[1:]])
    for engine in ("arrow", "numpy"):
        t, q, tau = read_log(path, engine=engine, n_joints=6)
        np.testing.assert_array_equal(np.column_stack([t, q, tau]), ref)
    bad = lines[:]
    fields = bad[7].split(",")
    fields[2 + 5] = "oops"  # q5 of data row 7 (file line 8: the header is line 1)
    bad[7] = ",".join(fields)
    path.write_text("\n".join(bad) + "\n")
    with pytest.raises(DatasetError, match=r"column q5 .*data row 7 \(line 8\)"):
        read_log(path, n_joints=6)
    with pytest.raises(ValueError, match="n_joints"):
        read_log(path, n_joints=0)


def test_h4_path_refuses_urdf_options(log_csv, tmp_path):
    res = _run(log_csv[0], "--bound", "1", "--no-friction", "--out", tmp_path / "x")
    assert res.exit_code == 2
    _one_error(res, "--no-friction", "--urdf")


def test_urdf_coupled_wrist(log_csv, tmp_path):
    """--coupled-wrist 5,6 (1-based) is the TX40's wrist (ident.robots.tx40.COUPLING, 0-based (4, 5)): the same base
    parameters as ident.robots.tx40.robot()'s."""
    res = _run(log_csv[0], "--urdf", URDF, "--bound", "50", "--coupled-wrist", "5,6", "--json",
               "--out", tmp_path / "run")
    assert res.exit_code == 0, res.stderr
    result = json.loads(res.stdout)
    robot = tx40.robot()
    assert result["standard_parameters"] == list(robot.names)
    assert result["parameters"] == list(robot.base(URDF_PROCESSING["base_samples"], URDF_PROCESSING["seed"]).names)
    for bad in ("5", "5,5", "0,1", "a,b"):
        res = _run(log_csv[0], "--urdf", URDF, "--bound", "1", "--coupled-wrist", bad, "--out", tmp_path / "bad")
        assert res.exit_code == 2, bad
        _one_error(res, "--coupled-wrist")
    assert not (tmp_path / "bad").exists()
