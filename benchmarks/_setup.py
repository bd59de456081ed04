"""Shared set-up of the benchmark scripts; import it before numpy.

``--threads N`` on the command line pins the BLAS thread count (it must be set before numpy loads its BLAS),
and the repository root goes on ``sys.path`` so the scripts also run from a plain checkout.
"""

import os
import sys
from pathlib import Path

if "--threads" in sys.argv:
    _n = sys.argv[sys.argv.index("--threads") + 1]
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[_var] = _n

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
