"""h4bench: guaranteed (bounded-error) identification of the H4 parallel robot's dynamic parameters.

One import package. Its sub-packages live at the top of the source checkout (the layout of the project) and are
installed under this name only (``setup.py`` maps them):

- :mod:`h4bench.sim`: the H4 in MuJoCo, its geometry and kinematics, simulation, ground truth;
- :mod:`h4bench.ident`: interval arithmetic, the regressors, data processing, the estimators;
- :mod:`h4bench.trajectories`: exciting trajectories, time parameterisation, limits;
- :mod:`h4bench.scenarios`: scenario kinds, campaigns, the command line, reports, the Rerun replay;
- ``h4bench.models`` and ``h4bench.data``: the MJCF files and the measured data sets (package data).
"""

SUBPACKAGES = ("sim", "ident", "trajectories", "scenarios")  # folders of the checkout that are h4bench.<name>
DATA_PACKAGES = ("models", "data")  # folders of data files (no Python) installed as h4bench.<name>

__all__ = ["DATA_PACKAGES", "SUBPACKAGES"]
