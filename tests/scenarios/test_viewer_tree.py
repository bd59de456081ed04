"""``h4bench replay``: the viewer's whole process tree ends with the command.

The ``rerun`` console script is a Python wrapper whose child is the viewer binary; a death signal set on the
wrapper never reached the binary, which kept listening after ``h4bench replay`` was killed. Now the binary is
started directly, in a process group of its own that the command ends (SIGTERM, then SIGKILL after a grace), and
with a death signal (SIGKILL) of its own. Tested with a grandchild that ignores SIGTERM (the wrapper's shape) and
with the real binary.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from h4bench.scenarios import replay
from tests.scenarios.test_trust import _alive

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="process checks via ps and /proc")

ROOT = Path(__file__).resolve().parents[2]

_TREE = """
import sys
import h4bench.scenarios.replay as replay
grandchild = "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('viewer up', flush=True); time.sleep(120)"
wrapper = f"import subprocess, sys; sys.exit(subprocess.call([sys.executable, '-c', {grandchild!r}]))"
replay.viewer_command = lambda *a, **k: [sys.executable, "-c", wrapper]  # a wrapper and its child, like rerun
replay.open_viewer(sys.argv[1])
"""

_REAL = """
import sys
import h4bench.scenarios.replay as replay
cmd = replay.viewer_command(sys.argv[1], web=True, port=int(sys.argv[2]))
replay.viewer_command = lambda *a, **k: cmd[:-1] + ["--port", sys.argv[3], cmd[-1]]
print("binary", cmd[0], flush=True)
replay.open_viewer(sys.argv[1])
"""


def _descendants(pid: int) -> list[int]:
    out = subprocess.run(["ps", "-e", "-o", "pid=,ppid="], capture_output=True, text=True).stdout.split()
    pairs = [(int(a), int(b)) for a, b in zip(out[::2], out[1::2])]
    found, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, parent in pairs if parent == p]
        found += kids
        todo += kids
    return found


def _gone(pid: int) -> bool:
    return not _alive(pid)


def _wait_gone(pids, seconds=15.0) -> list[int]:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not all(_gone(p) for p in pids):
        time.sleep(0.1)
    left = [p for p in pids if not _gone(p)]
    for p in left:  # never leave them behind
        os.kill(p, signal.SIGKILL)
    return left


@pytest.fixture(scope="module")
def rrd(tmp_path_factory):
    import rerun as rr

    path = tmp_path_factory.mktemp("rrd") / "replay.rrd"
    rec = rr.RecordingStream("h4bench-test")
    rec.save(str(path))
    rec.log("x", rr.Scalars(1.0))
    rec.flush()
    rec.disconnect()
    return path


def test_sigterm_ends_a_grandchild_that_ignores_sigterm(tmp_path, rrd):
    (tmp_path / "parent.py").write_text(_TREE)
    proc = subprocess.Popen([sys.executable, str(tmp_path / "parent.py"), str(rrd)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "viewer up"
    tree = _descendants(proc.pid)
    assert len(tree) == 2  # the wrapper and its child
    t0 = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=20)
    assert _wait_gone(tree) == [], f"the viewer's tree {tree} outlived h4bench replay"
    assert time.monotonic() - t0 < replay.STOP_GRACE_S + 8


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.skipif(replay.viewer_binary() is None, reason="the rerun_cli binary is not installed")
@pytest.mark.parametrize("how", ["SIGTERM", "SIGKILL"])
def test_the_real_viewer_binary_dies_with_h4bench_replay(tmp_path, rrd, how):
    (tmp_path / "parent.py").write_text(_REAL)
    proc = subprocess.Popen([sys.executable, str(tmp_path / "parent.py"), str(rrd), str(_free_port()),
                             str(_free_port())], stdout=subprocess.PIPE, text=True)
    first = proc.stdout.readline().split()
    assert first[:2] == ["binary", replay.viewer_binary()]  # the binary itself, not the Python wrapper
    deadline = time.monotonic() + 20
    tree = []
    while time.monotonic() < deadline and not tree:
        tree = _descendants(proc.pid)
        time.sleep(0.2)
    assert tree, "the viewer did not start"
    time.sleep(1.0)
    tree = _descendants(proc.pid)
    proc.send_signal(getattr(signal, how))
    proc.wait(timeout=20)
    assert _wait_gone(tree) == [], f"the viewer's tree {tree} outlived h4bench replay ({how})"
