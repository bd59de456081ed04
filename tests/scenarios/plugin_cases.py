"""Misbehaving estimator plugins and fake installed distributions, shared by tests/scenarios/test_plugin_trust.py.

Each plugin reproduces one defect a user met (issue "a plugin is untrusted code"): it changes its inputs in place,
exits, prints, sleeps, returns an object JSON cannot hold. They are written into a test's folder, never installed.
"""

from __future__ import annotations

import textwrap
from pathlib import Path
from types import SimpleNamespace

import numpy as np

PLUGIN = '''\
import os, signal, sys, time
import numpy as np
from h4bench import ident

print("trustcases: a print at import")


def _hull(W, y, bound, prior):
    return ident.estimate(W, y, bound, prior, method="hull")


def _root(a):
    while a.base is not None:
        a = a.base
    return a


def add_y(W, y, bound, prior):
    """adds 100 N m to y in place, through the read-only view's base (a view's .base is writable)"""
    _root(y)[...] += 100.0
    return _hull(W, y, bound, prior)


def scale_w(W, y, bound, prior):
    _root(W)[...] *= 2.0
    return prior


def hard_exit(W, y, bound, prior):
    os._exit(7)


def soft_exit(W, y, bound, prior):
    sys.exit(5)


def talker(W, y, bound, prior):
    print("trustcases: a print at call")
    os.write(1, b"trustcases: a write to fd 1\\n")
    return _hull(W, y, bound, prior)


class Thing:
    pass


def weird_info(W, y, bound, prior):
    box = _hull(W, y, bound, prior)
    return ident.Box(box.lower, box.upper, box.names, {"obj": Thing(), "fn": lambda: 1, "ok": [1, 2],
                                                       "objs": [Thing()]})


def raiser(W, y, bound, prior):
    raise RuntimeError("plugin bug")


def change_bound(W, y, bound, prior):
    _root(bound)[...] *= 10.0
    return prior


def change_prior(W, y, bound, prior):
    _root(prior.lower)[...] = -1e9
    return prior


def crasher(W, y, bound, prior):
    os.kill(os.getpid(), signal.SIGSEGV)


def sleeper(W, y, bound, prior):
    time.sleep(120)
    return prior


def shrunk(W, y, bound, prior):
    box = _hull(W, y, bound, prior)
    return ident.Box(box.lower + 0.1 * box.width, box.upper - 0.1 * box.width, box.names)
'''

EXIT_AT_IMPORT = "import os\nos._exit(3)\n"

#: each failing plugin of PLUGIN and the words its failure message holds (besides its name)
FAILURES = {"soft_exit": "sys.exit(5)", "hard_exit": "os._exit(7)", "crasher": "SIGSEGV", "raiser": "plugin bug",
            "add_y": "changed its inputs in place (y)", "scale_w": "changed its inputs in place (W)",
            "change_bound": "changed its inputs in place (bound)",
            "change_prior": "changed its inputs in place (prior.lower)", "sleeper": "timeout"}


def write_plugin(folder: Path, name: str = "trustcases") -> Path:
    """``<folder>/<name>.py``: the plugins above; returns the file."""
    path = Path(folder) / f"{name}.py"
    path.write_text(PLUGIN)
    return path


class _Rows(SimpleNamespace):
    def __len__(self) -> int:
        return len(self.y)


def prefix_run(W, y, bound, prior, per_sample: int = 4):
    """What :func:`scenarios.replay.box_history` reads of an ExperimentRun, for the rows W (N, p), y (N,), bound (N,)
    (``per_sample`` rows per sample, one sample every 0.1 s) and a prior Box: no method ran yet (every point of the
    history is estimated), truth the prior's midpoint."""
    n = len(y) // per_sample
    eq = _Rows(W=W, y=y, bound=bound, sample=np.repeat(np.arange(n), per_sample), names=prior.names)
    return SimpleNamespace(equation=eq, dataset=SimpleNamespace(t=0.1 * np.arange(n)), prior=prior, boxes={},
                           failures={}, spec={}, theta_true=0.5 * (np.asarray(prior.lower) + np.asarray(prior.upper)))


def fake_distribution(site: Path, dist: str, entries: dict[str, str], modules: dict[str, str] = {}) -> None:
    """A distribution 'installed' under ``site`` (a dist-info with entry points of group h4bench.estimators, and
    module files), found when ``site`` is on sys.path (PYTHONPATH): no pip."""
    info = Path(site) / f"{dist}-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 1.0\n")
    lines = "\n".join(f"{k} = {v}" for k, v in entries.items())
    (info / "entry_points.txt").write_text(textwrap.dedent(f"[h4bench.estimators]\n{lines}\n"))
    for name, source in modules.items():
        (Path(site) / f"{name}.py").write_text(source)
