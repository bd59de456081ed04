"""The Staubli TX40 log shipped in ``data/tx40/`` (real robot, FIGAROH example data): loading and conversion
from the motor side to the joint side, and the robot's regressor (:class:`ident.robots.serial.SerialRobot`).

See ``data/tx40/README.md`` for origin, licence and file contents. Conversion (the FIGAROH example's, with
its reduction ratios and coupled wrist): ``R = diag(32, 32, 45, -48, 45, 32)`` with ``R[5, 4] = 32`` maps
joint to motor angles (``q_motor = R q``); joint torques are ``R^T tau_motor`` (power balance; ``R^T[4, 5] =
32``); then ``q2 -= pi/2`` and ``q3 += pi/2`` put the joints at the URDF's zero.
"""

from __future__ import annotations

import gzip
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["A_PRIORI", "DATA_DIR", "DT", "N_JOINTS", "RATIOS", "TX40Log", "load_log", "motor_to_joint",
           "rich_friction_prior", "robot", "standard_prior", "urdf_path"]



def _data_dir() -> Path:
    """``data/tx40`` of a source checkout, else the installed package data (``h4bench_data``, the same files)."""
    checkout = Path(__file__).resolve().parents[2] / "data" / "tx40"
    if checkout.is_dir():
        return checkout
    import importlib.util

    spec = importlib.util.find_spec("h4bench.data")
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations))) / "tx40"
    return checkout


DATA_DIR = _data_dir()
N_JOINTS = 6
DT = 2e-4  # s: TX40_config.yaml ts, 5 kHz
RATIOS = (32.0, 32.0, 45.0, -48.0, 45.0, 32.0)  # motor / joint, TX40_config.yaml reduction_ratio
COUPLING = (4, 5)  # 0-based: the motor of joint 6 also turns with joint 5 (R[5, 4] = ratio of joint 6)
OFFSETS = (0.0, -np.pi / 2, np.pi / 2, 0.0, 0.0, 0.0)  # rad, added after the conversion (URDF zero)
# The example's a-priori values (TX40_config.yaml), joint side, in the units of ident.robots.serial
A_PRIORI = {
    "fv": (8.05, 5.53, 1.97, 1.11, 1.86, 0.65),
    "fs": (7.14, 8.26, 6.34, 2.48, 3.03, 0.282),
    "Ia": (0.362, 0.362, 0.0988, 0.0313, 0.0468, 0.0105),
    "off": (0.392, 1.37, 0.326, -0.102, -0.0288, 0.127),
    "Iam": 0.00964, "fvm": 0.616, "fsm": 1.95,
}


def ratio_matrix() -> np.ndarray:
    """(6, 6) ``R`` with ``q_motor = R q`` (diagonal ratios and the wrist coupling ``R[5, 4]``)."""
    R = np.diag(RATIOS)
    R[COUPLING[1], COUPLING[0]] = RATIOS[COUPLING[1]]
    return R


def motor_to_joint(q_motor, tau_motor) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles [rad] and joint torques [N m] from motor angles and motor torques, each (n, 6).

    ``q = R^-1 q_motor + offsets``, ``tau = R^T tau_motor`` (module docstring).
    """
    q_motor = np.asarray(q_motor, dtype=float)
    tau_motor = np.asarray(tau_motor, dtype=float)
    for name, x in (("q_motor", q_motor), ("tau_motor", tau_motor)):
        if x.ndim != 2 or x.shape[1] != N_JOINTS:
            raise ValueError(f"{name} must have shape (n, {N_JOINTS}), got {x.shape}")
    if q_motor.shape != tau_motor.shape:
        raise ValueError(f"q_motor and tau_motor must have the same shape, got {q_motor.shape}, {tau_motor.shape}")
    R = ratio_matrix()
    q = np.linalg.solve(R, q_motor.T).T + np.asarray(OFFSETS)
    return q, tau_motor @ R  # (R^T tau^T)^T = tau R


@dataclass(frozen=True)
class TX40Log:
    """The measured log on the joint side: t (n,) [s], q (n, 6) [rad], tau (n, 6) [N m]; dt [s]; the raw
    motor-side arrays ``q_motor`` [rad], ``tau_motor`` [N m] as read."""

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    q_motor: np.ndarray
    tau_motor: np.ndarray
    dt: float = DT

    def __len__(self) -> int:
        return self.t.size


def _read_csv(path: Path) -> np.ndarray:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as f:
        header = f.readline().strip().split(",")
        if header != [f"Joint_{i + 1}" for i in range(N_JOINTS)]:
            raise ValueError(f"{path} must start with the header Joint_1..Joint_{N_JOINTS}, got {header}")
        data = np.loadtxt(f, delimiter=",", ndmin=2)
    if data.shape[1] != N_JOINTS or not np.all(np.isfinite(data)):
        raise ValueError(f"{path} must hold {N_JOINTS} finite columns, got shape {data.shape}")
    return data


def load_log(directory: str | Path | None = None) -> TX40Log:
    """Read ``pos_read_data.csv(.gz)`` and ``curr_data.csv(.gz)`` from ``directory`` (default ``data/tx40``)
    and convert them to the joint side (:func:`motor_to_joint`)."""
    d = DATA_DIR if directory is None else Path(directory)
    arrays = []
    for stem in ("pos_read_data", "curr_data"):
        for path in (d / f"{stem}.csv.gz", d / f"{stem}.csv"):
            if path.is_file():
                arrays.append(_read_csv(path))
                break
        else:
            raise ValueError(f"directory must hold {stem}.csv.gz or {stem}.csv, got {str(d)!r}")
    q_motor, tau_motor = arrays
    if q_motor.shape != tau_motor.shape:
        raise ValueError(f"positions and torques must have the same shape, got {q_motor.shape}, {tau_motor.shape}")
    q, tau = motor_to_joint(q_motor, tau_motor)
    return TX40Log(t=np.arange(q.shape[0]) * DT, q=q, tau=tau, q_motor=q_motor, tau_motor=tau_motor)


def urdf_path() -> Path:
    return DATA_DIR / "tx40_mdh_modified.urdf"


def robot(**options):
    """The TX40's :class:`ident.robots.serial.SerialRobot` (friction, rotor inertia, offsets, coupled wrist (4, 5));
    ``options`` override the keyword arguments of SerialRobot."""
    from h4bench.ident.robots.serial import SerialRobot

    kw = {"coupled_wrist": COUPLING, **options}
    return SerialRobot(urdf_path(), **kw)


# Physical bounds for the prior (sources in standard_prior's docstring)
ARM_MASS = 27.0  # kg: Staubli TX40 data sheet, weight of the arm (base included)
REACH = 0.515  # m: TX40 data sheet, maximum reach (axis 2 to the flange)
MOTOR_INERTIA_MAX = 2e-3  # kg m^2: motor-side rotor inertia bound, about 6 times the example's a priori Ia1 / 32^2


def standard_prior(robot) -> tuple[np.ndarray, np.ndarray]:
    """A physically meaningful, wide prior box on the TX40's standard parameters (lower (p,), upper (p,)).

    Every link i: ``0 <= m_i <= M`` (M = 27 kg, the whole arm's weight on the data sheet); its centre of mass
    lies within ``r = 0.515 m`` (the reach) of its joint origin, so ``|m c| <= M r``; the inertia about the
    joint origin of a body within radius r obeys ``0 <= I_aa <= M r^2`` and ``|I_ab| <= M r^2 / 2``
    (``|ab| <= (a^2 + b^2)/2``). Joint i, with the URDF's effort limit ``E_i`` and velocity limit ``V_i``:
    Coulomb ``0 <= fs_i <= E_i`` and viscous ``0 <= fv_i <= E_i / V_i`` (friction cannot exceed what the
    drive delivers at full speed), rotor inertia ``0 <= Ia_i <= J r_i^2`` with ``J = 2e-3 kg m^2`` (about six
    times the example's a-priori rotor of joint 1) and ``r_i`` the reduction ratio, offset ``|off_i| <= 0.2
    E_i`` (a larger current-sensor offset would be a drive fault). Coupled wrist: ``Iam <= J 32^2``, ``fvm <=
    E_6 / V_6``, ``fsm <= E_6``. Wide on purpose: it only excludes the unphysical. This is
    :func:`ident.robots.serial.physical_prior` with M, r, J, the ratios and the offset fraction 0.2 above.
    """
    from h4bench.ident.robots.serial import physical_prior

    return physical_prior(robot, ARM_MASS, REACH, rotor_inertia_max=MOTOR_INERTIA_MAX, ratios=RATIOS,
                          offset_fraction=0.2)


def rich_friction_prior(robot) -> tuple[np.ndarray, np.ndarray]:
    """Prior of the richer friction law's columns (:func:`ident.robots.serial.rich_friction_columns`), per joint:
    ``|fva_i| <= E_i / V_i``, ``|fst_i| <= E_i``, ``|fvq_i| <= E_i / V_i^2`` (same reasoning as
    :func:`standard_prior`). Returns (lower (3 nj,), upper (3 nj,)) in the order fva, fst, fvq."""
    effort = np.asarray(robot.model.effortLimit, dtype=float)
    vmax = np.asarray(robot.model.velocityLimit, dtype=float)
    hi = np.concatenate([effort / vmax, effort, effort / vmax**2])
    return -hi, hi
