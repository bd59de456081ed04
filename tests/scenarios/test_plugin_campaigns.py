"""Campaigns with plugins: a resumed campaign notices that a plugin's code changed, and a ``module:attribute``
plugin reaches Dask workers that do not have the user's file (a real local scheduler and worker, started here on
127.0.0.1 in another folder), or the campaign is refused before any run, naming what the workers lack.

Both run real campaigns through the command line: ``slow``.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.scenarios.plugin_cases import fake_distribution, write_plugin

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


def h4(folder, *args, env=None, timeout=600):
    return subprocess.run([sys.executable, "-m", "h4bench", *map(str, args)], cwd=folder, capture_output=True,
                          text=True, env={**os.environ, "COLUMNS": "100", **(env or {})}, timeout=timeout)


def test_a_resumed_campaign_refuses_a_plugin_whose_code_changed(tmp_path):
    plugin = write_plugin(tmp_path)
    args = ("run", "enclosure", "--quick", "--runs", "1", "--workers", "1", "--methods", "hull,trustcases:shrunk",
            "--out", "camp")
    first = h4(tmp_path, *args)
    assert first.returncode == 0, first.stderr
    saved = json.loads((tmp_path / "camp" / "campaign.json").read_text())["provenance"]["methods_code"]
    assert set(saved) == {"trustcases:shrunk"} and len(saved["trustcases:shrunk"]["sha256"]) == 64
    plugin.write_text(plugin.read_text().replace("0.1 * box.width", "0.2 * box.width"))
    again = h4(tmp_path, *args)
    assert again.returncode == 2
    assert "the methods' code changed (trustcases:shrunk" in again.stderr and "--fresh" in again.stderr
    fresh = h4(tmp_path, *args, "--fresh", "--json")
    assert fresh.returncode == 0, fresh.stderr
    result = json.loads(fresh.stdout)
    assert result["campaign"]["computed"] == 1 and result["campaign"]["reused"] == 0
    assert result["methods"]["trustcases:shrunk"]["width_vs_hull_median"][0] == pytest.approx(0.6, rel=1e-6)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def cluster(tmp_path):
    """A Dask scheduler and one worker on 127.0.0.1, started in a folder without the user's files; stopped (their
    process groups) at the end."""
    pytest.importorskip("distributed")
    dask = str(Path(sys.executable).parent / "dask")
    where = tmp_path / "cluster"
    where.mkdir()
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              cwd=where, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)]
    try:
        time.sleep(3)
        procs.append(subprocess.Popen([dask, "worker", f"tcp://127.0.0.1:{port}", "--nthreads", "1", "--nworkers",
                                       "1", "--no-dashboard", "--host", "127.0.0.1"], cwd=where, env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        from distributed import Client

        with Client(f"127.0.0.1:{port}", timeout="30s") as client:
            client.wait_for_workers(1, timeout=60)
        yield f"127.0.0.1:{port}"
    finally:
        for p in reversed(procs):
            try:
                os.killpg(p.pid, signal.SIGTERM)
                p.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(5)
            except ProcessLookupError:
                pass


def test_a_module_attribute_plugin_reaches_dask_workers(cluster, tmp_path):
    res = h4(ROOT, "run", "enclosure", "--quick", "--methods", "hull,examples.shrunk_hull:estimate", "--scheduler",
             cluster, "--out", tmp_path / "dask", "--json")
    assert res.returncode == 0, res.stderr
    m = json.loads(res.stdout)["methods"]
    shrunk = m["examples.shrunk_hull:estimate"]
    assert shrunk["failed_runs"] == [] and shrunk["unsound_runs"] == 4  # computed on the worker, and flagged
    assert m["hull"]["failed_runs"] == [] and m["hull"]["unsound_runs"] == 0


def test_an_entry_point_the_workers_lack_is_named_before_any_run(cluster, tmp_path):
    site = tmp_path / "site"
    fake_distribution(site, "trustonly", {"onlyhere": "trustonlyhere:estimate"},
                      {"trustonlyhere": "def estimate(W, y, bound, prior):\n    return prior\n"})
    env = {"PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}
    res = h4(tmp_path, "run", "enclosure", "--quick", "--methods", "hull,onlyhere", "--scheduler", cluster,
             "--out", tmp_path / "lack", env=env)
    assert res.returncode == 2
    last = res.stderr.strip().splitlines()[-1]
    assert "lack" in last and "onlyhere" in last and "nothing was run" in last
    assert not list((tmp_path / "lack" / "runs").glob("*.json"))
