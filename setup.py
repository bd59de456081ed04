"""The one import package ``h4bench``, mapped over the checkout's top-level folders.

The source checkout keeps ``sim/``, ``ident/``, ``trajectories/``, ``scenarios/``, ``models/`` and ``data/`` at its
top level; the wheel installs them as ``h4bench.sim``, ``h4bench.ident``, ... and nothing else at the top level.
The folders are named once, in ``h4bench/__init__.py``; their sub-packages are found, not listed.
"""

import ast
from pathlib import Path

import sys

from setuptools import Extension, find_packages, setup

ROOT = Path(__file__).resolve().parent


def _layout() -> dict[str, tuple[str, ...]]:
    tree = ast.parse((ROOT / "h4bench" / "__init__.py").read_text())
    return {node.targets[0].id: ast.literal_eval(node.value) for node in tree.body
            if isinstance(node, ast.Assign) and node.targets[0].id in ("SUBPACKAGES", "DATA_PACKAGES")}


LAYOUT = _layout()
packages = ["h4bench"]
package_dir = {"h4bench": "h4bench"}
for folder in LAYOUT["SUBPACKAGES"] + LAYOUT["DATA_PACKAGES"]:
    package_dir[f"h4bench.{folder}"] = folder
    packages += [f"h4bench.{folder}"] + [f"h4bench.{folder}.{sub}" for sub in find_packages(folder)]

# the simulator's sample loop in compiled code (sim/_loop.cpp; sim/compiled.py): optional, since the Python loop
# gives the same bits; no fused multiply-add, so that it does
FLAGS = ["/O2", "/fp:strict"] if sys.platform == "win32" else ["-O2", "-std=c++17", "-ffp-contract=off"]
LOOP = Extension("h4bench.sim._loop", ["sim/_loop.cpp"], language="c++", extra_compile_args=FLAGS, optional=True)
# a serial chain's batched regressor (ident/robots/_chain.cpp; ident/robots/chain.py): optional, the numpy formulas
# give the same bits
CHAIN = Extension("h4bench.ident.robots._chain", ["ident/robots/_chain.cpp"], language="c++",
                  extra_compile_args=FLAGS, optional=True)
EXTENSIONS = [LOOP, CHAIN]
# the interval arithmetic's fused ufuncs (ident/numerics/_mr.cpp; ident/numerics/fused.py): optional too, the numpy
# formulas give the same bits; numpy's headers come from the build requirements (pyproject.toml)
try:
    import numpy
except ImportError:  # a build without numpy: the numpy formulas alone
    numpy = None
if numpy is not None:
    EXTENSIONS.append(Extension("h4bench.ident.numerics._mr", ["ident/numerics/_mr.cpp"], language="c++",
                                include_dirs=[numpy.get_include()], extra_compile_args=FLAGS, optional=True))

setup(packages=packages, package_dir=package_dir, ext_modules=EXTENSIONS)
