"""Datasets: save/load round trips, CSV import of a robot log, and clear errors on malformed input."""

from __future__ import annotations

import numpy as np
import pytest

from h4bench import sim


def _dataset(n=50):
    rng = np.random.default_rng(0)
    t = np.arange(n) * 1e-3
    return sim.Dataset(t, rng.normal(size=(n, 4)), rng.normal(size=(n, 4)), {"seed": 1, "note": "x"})


def test_round_trip(tmp_path):
    d = _dataset()
    path = d.save(tmp_path / "run" / "data")
    back = sim.Dataset.load(path)
    np.testing.assert_array_equal(back.q, d.q)
    np.testing.assert_array_equal(back.tau, d.tau)
    np.testing.assert_array_equal(back.t, d.t)
    assert back.metadata == d.metadata
    assert not [p for p in (tmp_path / "run").iterdir() if p.name.endswith(".tmp")]


def test_ground_truth_round_trip(tmp_path):
    n = 5
    g = sim.GroundTruth(np.arange(14.0), *(np.full((n, 4), float(i)) for i in range(7)), np.zeros(n), 5e-4,
                        names=sim.TRUE_PARAMETER_ORDER)
    back = sim.GroundTruth.load(g.save(tmp_path / "truth"))
    np.testing.assert_array_equal(back.theta, g.theta)
    np.testing.assert_array_equal(back.xdd, g.xdd)
    assert back.h == g.h and back.names == g.names


def _write_csv(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return path


HEADER = ["t", "q1", "q2", "q3", "q4", "tau1", "tau2", "tau3", "tau4"]


def test_csv_import(tmp_path):
    rows = [[k * 1e-3] + [0.1 * k] * 4 + [1.0] * 4 for k in range(20)]
    d = sim.Dataset.from_csv(_write_csv(tmp_path / "log.csv", HEADER + ["extra"], [r + [9] for r in rows]))
    assert len(d) == 20 and d.dt == pytest.approx(1e-3)
    np.testing.assert_allclose(d.q[:, 2], 0.1 * np.arange(20))


def test_csv_missing_columns(tmp_path):
    p = _write_csv(tmp_path / "log.csv", HEADER[:-1], [[0.0] * 8] * 5)
    with pytest.raises(sim.DatasetError, match=r"missing \['tau4'\]"):
        sim.Dataset.from_csv(p)


def test_csv_nan(tmp_path):
    rows = [[k * 1e-3] + [0.0] * 8 for k in range(10)]
    rows[4][3] = "nan"
    with pytest.raises(sim.DatasetError, match="column q has NaN/empty value at data row 5"):
        sim.Dataset.from_csv(_write_csv(tmp_path / "log.csv", HEADER, rows))


def test_csv_non_monotonic_time(tmp_path):
    rows = [[k * 1e-3] + [0.0] * 8 for k in range(10)]
    rows[6][0] = rows[5][0]
    # the file and the 1-based data rows (the header excluded): rows[6] is data row 7
    with pytest.raises(sim.DatasetError, match=r"log\.csv'.*column t must be strictly increasing, got 0\.005 s at "
                                              r"data row 7 after 0\.005 s at data row 6"):
        sim.Dataset.from_csv(_write_csv(tmp_path / "log.csv", HEADER, rows))
    rows = [[k * 1e-3 + (0.5e-3 if k >= 6 else 0.0)] + [0.0] * 8 for k in range(10)]  # one long step
    with pytest.raises(sim.DatasetError, match=r"log\.csv'.*uniformly sampled.*between data row 6 and data row 7"):
        sim.Dataset.from_csv(_write_csv(tmp_path / "log.csv", HEADER, rows))


@pytest.mark.parametrize("engine", ["arrow", "numpy"])
def test_gzip_log_reads_as_the_plain_one(tmp_path, engine):
    """Oracle: the same text uncompressed; a .csv.gz is recognised by its content, not its name."""
    import gzip
    import shutil

    from h4bench.sim.csvlog import read_log

    rng = np.random.default_rng(0)
    rows = [[k * 1e-3] + list(rng.standard_normal(8)) for k in range(3000)]
    plain = _write_csv(tmp_path / "log.csv", HEADER, rows)
    with plain.open("rb") as src, gzip.open(tmp_path / "log.csv.gz", "wb") as dst:
        shutil.copyfileobj(src, dst)
    shutil.copy(tmp_path / "log.csv.gz", tmp_path / "renamed.csv")
    for a, b, c in zip(read_log(plain, engine=engine), read_log(tmp_path / "log.csv.gz", engine=engine),
                       read_log(tmp_path / "renamed.csv", engine=engine)):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    ds = sim.Dataset.from_csv(tmp_path / "log.csv.gz")
    assert len(ds) == 3000
    (tmp_path / "cut.csv.gz").write_bytes((tmp_path / "log.csv.gz").read_bytes()[:2000])  # truncated
    with pytest.raises(sim.DatasetError, match=r"cut\.csv\.gz"):
        read_log(tmp_path / "cut.csv.gz", engine=engine)
    (tmp_path / "bin.csv").write_bytes(b"\x8b\xff\xfe" * 10)
    with pytest.raises(sim.DatasetError, match=r"bin\.csv.*UTF-8"):
        read_log(tmp_path / "bin.csv", engine=engine)


def test_csv_missing_file(tmp_path):
    with pytest.raises(sim.DatasetError, match="existing CSV file"):
        sim.Dataset.from_csv(tmp_path / "nope.csv")


def test_dataset_shapes():
    with pytest.raises(sim.DatasetError, match=r"q must have shape \(10, 4\), got \(10, 3\)"):
        sim.Dataset(np.arange(10) * 1e-3, np.zeros((10, 3)), np.zeros((10, 4)))
    with pytest.raises(sim.DatasetError, match="uniformly sampled"):
        sim.Dataset(np.r_[0, 1, 2, 5, 6] * 1e-3, np.zeros((5, 4)), np.zeros((5, 4)))
