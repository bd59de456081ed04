"""Never lose a user's files, never mix runs: owned run folders, campaign provenance, clean stops.

Each test reproduces a defect a user met: ``--out`` over a user's folder or file deleted or hid it; a resumed
campaign mixed runs of other seeds or sizes; Ctrl-C did not stop a campaign and killed campaigns left workers.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from h4bench.scenarios import campaign as camp
from h4bench.scenarios.registry import load_spec
from h4bench.scenarios.rundir import MARKER, OwnedFolder, RunFolderError, check_target, clean_stale_temporaries, is_owned
from h4bench.scenarios.runner import run_scenario
from h4bench.scenarios.spec import ScenarioError

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------------------------------ owned folders
def test_a_users_folder_is_refused_and_kept(tmp_path):
    d = tmp_path / "d"
    d.mkdir()
    (d / "notes.txt").write_text("keep")
    with pytest.raises(RunFolderError, match="--out .*did not write"):
        run_scenario("paper", quick=True, out=d)
    assert (d / "notes.txt").read_text() == "keep" and sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_a_file_as_out_is_refused_and_kept(tmp_path):
    f = tmp_path / "file.txt"
    f.write_text("keep")
    with pytest.raises(RunFolderError, match="--out must be a folder"):
        run_scenario("paper", quick=True, out=f)
    assert f.read_text() == "keep" and sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]


@pytest.mark.parametrize("where", ["dot", "parent"])
def test_the_current_folder_is_refused(tmp_path, monkeypatch, where):
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "sub")
    with pytest.raises(RunFolderError, match="current folder"):
        check_target(Path(".") if where == "dot" else Path(".."))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sub"]


def test_uncreatable_places_are_refused(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(RunFolderError, match="is a file"):
        check_target(tmp_path / "file" / "sub")
    with pytest.raises(RunFolderError, match="--out"):
        check_target(Path("/proc/h4bench-nowhere"))


def test_an_owned_folder_is_replaced_an_empty_one_used_and_failures_leave_nothing(tmp_path):
    target = tmp_path / "run"
    target.mkdir()  # empty: nothing to lose
    with OwnedFolder(target) as tmp:
        (tmp / "result.json").write_text("{}")
    assert is_owned(target) and (target / "result.json").is_file()
    with OwnedFolder(target) as tmp:  # ours: replaced whole
        (tmp / "other.json").write_text("{}")
    assert sorted(p.name for p in target.iterdir()) == sorted([MARKER, "other.json"])
    with pytest.raises(RuntimeError), OwnedFolder(target) as tmp:
        (tmp / "half.json").write_text("{}")
        raise RuntimeError("interrupted")
    assert sorted(p.name for p in target.iterdir()) == sorted([MARKER, "other.json"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_a_killed_runs_temporary_folder_is_cleaned_by_the_next_run(tmp_path):
    target = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()  # a pid that is gone
    stale = tmp_path / f".run.tmp-{proc.pid}"
    stale.mkdir()
    (stale / MARKER).write_text("{}")
    (stale / "dataset.npz").write_bytes(b"x" * 1000)
    foreign = tmp_path / f".run.tmp-{proc.pid + 1000000}"  # not ours (no marker): never touched
    foreign.mkdir()
    assert clean_stale_temporaries(check_target(target)) == [stale]
    assert not stale.exists() and foreign.exists()


# ------------------------------------------------------------------------------------------ campaigns
def fake_job(spec: dict, index: int, base_seed: int) -> dict:
    """A quick stand-in for an experiment (picklable: module level)."""
    return {"index": index, "seed": base_seed + index, "duration": spec["trajectory"]["duration"]}


def _spec(quick: bool = True, runs: int = 4) -> dict:
    spec = load_spec("enclosure", quick=quick)
    spec["campaign"]["runs"] = runs
    spec["campaign"]["workers"] = 1
    return spec


def test_resume_reuses_only_matching_runs_and_says_how_many(tmp_path):
    out = tmp_path / "c"
    runs, info = camp.run_many(_spec(), 1000, out, fake_job, lambda *a: None)
    assert [r["seed"] for r in runs] == [1000, 1001, 1002, 1003] and info["reused"] == 0 and info["computed"] == 4
    runs, info = camp.run_many(_spec(runs=6), 1000, out, fake_job, lambda *a: None)  # more runs: extend
    assert info["reused"] == 4 and info["computed"] == 2 and [r["index"] for r in runs] == list(range(6))
    # a run file of other inputs (e.g. an older code version) is recomputed, not reused
    path = camp.run_path(out, 2)
    stale = json.loads(path.read_text())
    stale["provenance"]["code_hash"] = "0" * 64
    path.write_text(json.dumps(stale))
    runs, info = camp.run_many(_spec(runs=6), 1000, out, fake_job, lambda *a: None)
    assert info["reused"] == 5 and info["computed"] == 1


def test_other_seed_or_size_is_refused_unless_fresh(tmp_path):
    out = tmp_path / "c"
    camp.run_many(_spec(), 1000, out, fake_job, lambda *a: None)
    with pytest.raises(camp.CampaignMismatchError, match=r"seed \(saved 1000, now 7\).*--fresh"):
        camp.run_many(_spec(), 7, out, fake_job, lambda *a: None)
    with pytest.raises(camp.CampaignMismatchError, match="spec_hash"):
        camp.run_many(_spec(quick=False), 1000, out, fake_job, lambda *a: None)
    runs, info = camp.run_many(_spec(), 7, out, fake_job, lambda *a: None, fresh=True)
    assert info["reused"] == 0 and [r["seed"] for r in runs] == [7, 8, 9, 10]
    assert all(json.loads(camp.run_path(out, i).read_text())["provenance"]["seed"] == 7 for i in range(4))


def test_a_campaign_never_writes_into_a_users_folder(tmp_path):
    out = tmp_path / "c"
    out.mkdir()
    (out / "mine.txt").write_text("keep")
    with pytest.raises(RunFolderError):
        camp.run_many(_spec(), 1000, out, fake_job, lambda *a: None)
    assert sorted(p.name for p in out.iterdir()) == ["mine.txt"]


def test_spec_lists_are_checked_with_their_names(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('kind = "enclosure"\n[estimators]\nmethods = [1, 2]\n')
    with pytest.raises(ScenarioError, match="estimators.methods must be a list of strings"):
        load_spec(bad)
    bad.write_text('kind = "enclosure"\n[campaign]\nnoise_shapes = []\n')
    with pytest.raises(ScenarioError, match="campaign.noise_shapes must not be empty"):
        load_spec(bad)
    with pytest.raises(ScenarioError, match="seed must be an integer >= 0"):
        run_scenario("paper", quick=True, seed=-1, out=tmp_path / "x")


_SLOW_CAMPAIGN = textwrap.dedent("""
    import os, sys, time
    from pathlib import Path
    from h4bench.scenarios import campaign as camp
    from h4bench.scenarios.registry import load_spec

    def slow_job(spec, index, base_seed):
        time.sleep(0.5 if index == 0 else 30.0)
        return {"index": index, "seed": base_seed + index}

    if __name__ == "__main__":
        import slowjob
        spec = load_spec("enclosure", quick=True)
        spec["campaign"]["runs"] = 6
        spec["campaign"]["workers"] = 2
        try:
            camp.run_many(spec, 1, Path(sys.argv[1]), slowjob.slow_job,
                          lambda stage, done, total: print("progress", done, flush=True))
        except camp.CampaignInterrupted as exc:
            print("stopped:", exc, flush=True)
            sys.exit(130)
""")


def _children(pid: int) -> set[int]:
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True).stdout
    return {int(p) for p in out.split()}


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    status = Path(f"/proc/{pid}/status")
    return not (status.exists() and "\nState:\tZ" in status.read_text())


def _start_slow_campaign(tmp_path):
    (tmp_path / "slowjob.py").write_text(_SLOW_CAMPAIGN)
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"}
    proc = subprocess.Popen([sys.executable, str(tmp_path / "slowjob.py"), str(tmp_path / "c")], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (tmp_path / "c" / "runs" / "0000.json").exists():  # the quick run is saved, the others sleep
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.1)
    workers = _children(proc.pid)
    assert workers, "the campaign should have worker processes"
    return proc, workers


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="process checks via ps and /proc")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_stops_within_seconds_keeps_finished_runs_and_leaves_no_worker(tmp_path, sig):
    proc, workers = _start_slow_campaign(tmp_path)
    t0 = time.monotonic()
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=20)
    assert time.monotonic() - t0 < 10, "a stop must take seconds, not the queued runs' time"
    assert proc.returncode == 130 and "run the same command again to resume" in stdout, (stdout, stderr)
    # nothing but the stop line: the pool's manager thread used to print "Exception in thread ... InvalidStateError"
    assert "Exception in thread" not in stderr and "Traceback" not in stderr, stderr
    assert (tmp_path / "c" / "runs" / "0000.json").is_file()
    time.sleep(1.0)
    assert not [w for w in workers if _alive(w)]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="process checks via ps and /proc")
def test_workers_die_with_a_killed_campaign(tmp_path):
    proc, workers = _start_slow_campaign(tmp_path)
    proc.kill()
    proc.communicate(timeout=20)
    deadline = time.monotonic() + 10
    while [w for w in workers if _alive(w)] and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not [w for w in workers if _alive(w)]


def test_the_campaign_restores_the_process_hooks_it_replaces():
    """SIGTERM's handler and threading.excepthook are the caller's again after a campaign's stop; the stop ends the
    pool's workers (found without CPython's private pool attributes)."""
    import concurrent.futures
    import threading

    def mine(signum, frame):
        return None

    old = signal.signal(signal.SIGTERM, mine)
    try:
        with camp._TermAsInterrupt():
            assert signal.getsignal(signal.SIGTERM) is not mine
        assert signal.getsignal(signal.SIGTERM) is mine
        # the engine's form: both signals only set the event (no exception inside concurrent.futures), restored after
        stop, sigint = threading.Event(), signal.getsignal(signal.SIGINT)
        with camp._TermAsInterrupt(stop):
            os.kill(os.getpid(), signal.SIGINT)
            deadline = time.monotonic() + 5
            while not stop.is_set() and time.monotonic() < deadline:
                time.sleep(0.01)
            assert stop.is_set()
        assert signal.getsignal(signal.SIGTERM) is mine and signal.getsignal(signal.SIGINT) is sigint
    finally:
        signal.signal(signal.SIGTERM, old)
    hook = threading.excepthook
    known = camp._pool_children()
    pool = concurrent.futures.ProcessPoolExecutor(max_workers=2)
    futures = [pool.submit(time.sleep, 30) for _ in range(4)]
    deadline = time.monotonic() + 20
    while len(camp._pool_children() - known) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    workers = camp._pool_children() - known
    assert len(workers) == 2
    t0 = time.monotonic()
    camp._stop_executor(pool, known)
    assert time.monotonic() - t0 < 10 and threading.excepthook is hook
    assert not [w for w in workers if _alive(w)] and all(f.done() for f in futures)


# ------------------------------------------------------------------------------------------ output channels
def test_json_output_is_one_json_document(tmp_path):
    """Native solver banners must not reach stdout (HiGHS prints one from C at its first use)."""
    res = subprocess.run([sys.executable, "-m", "h4bench.scenarios.cli", "run", "paper", "--quick", "--json",
                          "--out", str(tmp_path / "p")], capture_output=True, text=True, cwd=tmp_path,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert res.returncode == 0, res.stderr
    result = json.loads(res.stdout)
    assert result["scenario"] == "paper" and result["methods"]["hull"]["status"] == "ok"


def crashing_job(spec: dict, index: int, base_seed: int) -> dict:
    if index == 2:
        raise FloatingPointError("the simulation diverged")
    return fake_job(spec, index, base_seed)


def test_a_crashing_run_is_reported_and_the_others_are_kept(tmp_path):
    out = tmp_path / "c"
    with pytest.raises(camp.CampaignRunError, match=r"1 of 4 runs crashed.*run 2 \(seed 1002\).*diverged.*--only 2") as err:
        camp.run_many(_spec(), 1000, out, crashing_job, lambda *a: None)
    assert set(err.value.errors) == {2}
    assert sorted(p.name for p in (out / "runs").iterdir()) == ["0000.json", "0001.json", "0003.json"]
    runs, info = camp.run_many(_spec(), 1000, out, fake_job, lambda *a: None)  # fixed: only the crashed run reruns
    assert info["reused"] == 3 and info["computed"] == 1
