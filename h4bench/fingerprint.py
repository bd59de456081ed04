"""Content hashes of arrays and the platform a result was computed on (numpy only).

A run's ``result.json`` carries the SHA-256 of what selected its experiment (the designed trajectory, the
controller's gains, the feed-forward, the simulated dataset: ``content_hashes``), so that two machines compare a
run in one look, and, as information that no result depends on, the libraries and BLAS kernels it ran with
(:func:`platform`).
"""

from __future__ import annotations

import hashlib
import platform as _platform

import numpy as np

__all__ = ["array_digest", "platform"]


def array_digest(arrays, extra: bytes = b"") -> str:
    """SHA-256 of named arrays ``[(name, array), ...]`` (each as ``name:dtype:shape`` then its C-order bytes, in
    the order given) followed by ``extra``."""
    h = hashlib.sha256()
    for name, value in arrays:
        arr = np.ascontiguousarray(value)
        h.update(f"{name}:{arr.dtype.str}:{arr.shape}".encode())
        h.update(arr.tobytes())
    h.update(extra)
    return h.hexdigest()


def platform() -> dict:
    """Python, numpy and scipy versions, the CPU's machine name and each OpenBLAS's kernel and thread count
    (:func:`h4bench.blas.blas_info`): information, never a key."""
    import scipy  # noqa: PLC0415
    import scipy.linalg  # noqa: F401, PLC0415  (its OpenBLAS loaded, so that it is listed)

    from h4bench.blas import blas_info  # noqa: PLC0415

    return {"python": _platform.python_version(), "machine": _platform.machine(), "numpy": np.__version__,
            "scipy": scipy.__version__, "blas": blas_info()}
