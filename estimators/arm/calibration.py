"""End-to-end calibration checks of an arm: identify on training poses, score held-out ones.

:func:`calibrate_ur10` works on laser-tracker data (probe positions in the
tracker frame), :func:`calibrate_fr3` on an eye-in-hand camera over a fixed board;
both report the held-out accuracy of the nominal and the identified model as
:class:`ErrorStats`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from .handeye import solve_ax_xb
from .identification import IdentificationResult, IdentificationSettings, identify
from .least_squares import kabsch
from .mdh import MDHTable, forward_kinematics, tool_positions
from .residuals import PairObservations, PositionObservations, ResidualMode

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ArmCalibrationReport",
    "ErrorStats",
    "EyeInHandData",
    "LaserTrackerData",
    "calibrate_fr3",
    "calibrate_ur10",
    "pair_distance_errors",
    "registered_position_errors",
]


# =========================================================================== evaluation helpers
@dataclass(frozen=True)
class ErrorStats:
    """Summary of error magnitudes (m)."""

    median: float
    rms: float
    p95: float
    max: float
    n: int

    @classmethod
    def of(cls, errors: npt.ArrayLike) -> ErrorStats:
        """Statistics of absolute errors (m)."""
        e = np.abs(np.asarray(errors, dtype=float).reshape(-1))
        if e.size == 0:
            raise ValueError("no errors to summarise")
        return cls(
            float(np.median(e)),
            float(np.sqrt(np.mean(e**2))),
            float(np.percentile(e, 95)),
            float(e.max()),
            int(e.size),
        )


def registered_position_errors(
    model_positions: npt.ArrayLike,
    measured_positions: npt.ArrayLike,
    T_meas_base: npt.ArrayLike | None = None,
) -> FloatArray:
    """3-D errors (N,) (m) after the rigid registration the model allows.

    With ``T_meas_base`` that registration is used; without, it is fitted to these
    points (:func:`~.least_squares.kabsch`).
    """
    P = np.asarray(model_positions, dtype=float)
    M = np.asarray(measured_positions, dtype=float)
    T = kabsch(P, M) if T_meas_base is None else np.asarray(T_meas_base, dtype=float)
    return np.linalg.norm(np.einsum("ij,nj->ni", T[:3, :3], P) + T[:3, 3] - M, axis=1)


def pair_distance_errors(
    model_positions: npt.ArrayLike,
    measured_positions: npt.ArrayLike,
    pairs: npt.ArrayLike | None = None,
) -> FloatArray:
    """Distance-accuracy errors (P,) (m): :math:`\\|p_j - p_i\\| - \\|m_j - m_i\\|` over pairs
    (all ``i < j`` when omitted)."""
    P = np.asarray(model_positions, dtype=float)
    M = np.asarray(measured_positions, dtype=float)
    if pairs is None:
        i, j = np.triu_indices(len(P), k=1)
    else:
        pr = np.asarray(pairs)
        i, j = pr[:, 0], pr[:, 1]
    return np.linalg.norm(P[j] - P[i], axis=1) - np.linalg.norm(M[j] - M[i], axis=1)


# =========================================================================== end-to-end
class LaserTrackerData(Protocol):
    """What :func:`calibrate_ur10` needs (e.g. a UR10 laser-tracker series)."""

    @property
    def joint_angles(self) -> FloatArray:  # (N, n) rad
        ...

    @property
    def probe_positions(self) -> FloatArray:  # (N, 3) m, tracker frame
        ...

    @property
    def probe_in_flange(self) -> FloatArray:  # (3,) m, nominal probe point in the flange frame
        ...


class EyeInHandData(Protocol):
    """What :func:`calibrate_fr3` needs (an eye-in-hand camera over a fixed board)."""

    @property
    def joint_positions(self) -> FloatArray:  # (N, n) rad
        ...

    @property
    def T_board_camera(self) -> FloatArray:  # (N, 4, 4) m
        ...


@dataclass(frozen=True)
class ArmCalibrationReport:
    """Held-out accuracy of a nominal and a calibrated kinematic model.

    Attributes
    ----------
    metric : str
        What the errors are.
    nominal, calibrated : ErrorStats
        Held-out errors of the nominal and the identified model (m).
    identification : IdentificationResult
        The fit on the training part.
    n_train, n_test : int
        Poses used.
    secondary : dict of str to ErrorStats
        Further held-out figures (e.g. with the training registration).
    """

    metric: str
    nominal: ErrorStats
    calibrated: ErrorStats
    identification: IdentificationResult
    n_train: int
    n_test: int
    secondary: dict[str, ErrorStats]

    @property
    def improvement(self) -> float:
        """``nominal.rms / calibrated.rms``."""
        return self.nominal.rms / max(self.calibrated.rms, 1e-300)


def _check_split(
    train_idx: npt.ArrayLike, test_idx: npt.ArrayLike, n: int
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    tr = np.asarray(train_idx)
    te = np.asarray(test_idx)
    for name, a in (("train_idx", tr), ("test_idx", te)):
        if a.ndim != 1 or a.size == 0 or not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"{name} must be a non-empty 1-D int array, got shape {a.shape}")
        if a.min() < 0 or a.max() >= n:
            raise ValueError(f"{name} indexes outside 0..{n - 1}")
    if np.intersect1d(tr, te).size:
        raise ValueError("train_idx and test_idx overlap; held-out poses must not be trained on")
    return tr.astype(np.int64), te.astype(np.int64)


def calibrate_ur10(
    dataset: LaserTrackerData,
    train_idx: npt.ArrayLike,
    test_idx: npt.ArrayLike,
    *,
    table: MDHTable | None = None,
    settings: IdentificationSettings | None = None,
) -> ArmCalibrationReport:
    """Identify MDH + registration + probe offset on laser-tracker data, test held out.

    Parameters
    ----------
    dataset : LaserTrackerData
        Joint angles (N, 6), probe positions (N, 3) in the tracker frame and the
        nominal probe point in the flange frame.
    train_idx, test_idx : array_like of int
        Disjoint pose indices.
    table : MDHTable, optional
        Nominal geometry (:meth:`MDHTable.ur10` by default).
    settings : IdentificationSettings, optional
        Default: position mode, Gauss–Newton, MDH, tool and registration estimated.

    Returns
    -------
    ArmCalibrationReport
        ``nominal``/``calibrated``: 3-D position errors of the held-out poses after
        the rigid registration refitted on them (what a rigid fit of model to
        tracker allows); ``secondary["*_train_registration"]``: with the
        registration of the training fit instead.
    """
    q = np.asarray(dataset.joint_angles, dtype=float)
    m = np.asarray(dataset.probe_positions, dtype=float)
    tool0 = np.asarray(dataset.probe_in_flange, dtype=float).reshape(3)
    tr, te = _check_split(train_idx, test_idx, len(q))
    tab = table or MDHTable.ur10()
    s = settings or IdentificationSettings(mode=ResidualMode.POSITION)
    if s.mode is not ResidualMode.POSITION:
        raise ValueError("calibrate_ur10 needs settings.mode = 'position'")
    res = identify(tab, PositionObservations(q[tr], m[tr]), tool=tool0, settings=s)
    p_nom_tr = tool_positions(tab, q[tr], tool0)
    T_nom = kabsch(p_nom_tr, m[tr])
    p_nom = tool_positions(tab, q[te], tool0)
    p_cal = res.tool_positions(q[te])
    nominal = ErrorStats.of(registered_position_errors(p_nom, m[te]))
    calibrated = ErrorStats.of(registered_position_errors(p_cal, m[te]))
    secondary = {
        "nominal_train_registration": ErrorStats.of(
            registered_position_errors(p_nom, m[te], T_nom)
        ),
        "calibrated_train_registration": ErrorStats.of(
            registered_position_errors(p_cal, m[te], res.T_meas_base)
        ),
        "nominal_train_fit": ErrorStats.of(registered_position_errors(p_nom_tr, m[tr])),
        "calibrated_train_fit": ErrorStats.of(
            registered_position_errors(res.tool_positions(q[tr]), m[tr])
        ),
    }
    return ArmCalibrationReport(
        metric="3-D probe position error after rigid registration (m)",
        nominal=nominal,
        calibrated=calibrated,
        identification=res,
        n_train=int(tr.size),
        n_test=int(te.size),
        secondary=secondary,
    )


def calibrate_fr3(
    dataset: EyeInHandData,
    train_idx: npt.ArrayLike,
    test_idx: npt.ArrayLike,
    *,
    table: MDHTable | None = None,
    settings: IdentificationSettings | None = None,
) -> ArmCalibrationReport:
    """Identify MDH + camera point + board rotation from eye-in-hand board poses.

    The tool point is the camera's optical centre. Its start value and the
    board's start rotation come from an :math:`AX = XB` hand–eye calibration
    (:func:`~.handeye.solve_ax_xb`) on the training poses with the nominal model;
    the identification then fits displacement residuals between all training
    pose pairs.

    Parameters
    ----------
    dataset : EyeInHandData
        Joint positions (N, n) and camera poses in the board frame (N, 4, 4).
    train_idx, test_idx : array_like of int
        Disjoint pose indices.
    table : MDHTable, optional
        Nominal geometry (:meth:`MDHTable.franka_fr3` by default).
    settings : IdentificationSettings, optional
        Default: displacement mode, Gauss–Newton, MDH, tool and board rotation estimated.

    Returns
    -------
    ArmCalibrationReport
        ``nominal``/``calibrated``: distance-accuracy errors
        :math:`\\|p_j - p_i\\|_{\\mathrm{model}} - \\|c_j - c_i\\|_{\\mathrm{camera}}`
        over all pairs of held-out poses; ``secondary["*_displacement"]``: 3-D
        displacement errors with the board rotation of the respective model.
    """
    q = np.asarray(dataset.joint_positions, dtype=float)
    C = np.asarray(dataset.T_board_camera, dtype=float)
    if C.ndim != 3 or C.shape[1:] != (4, 4) or C.shape[0] != q.shape[0]:
        raise ValueError(f"T_board_camera must have shape ({q.shape[0]}, 4, 4), got {C.shape}")
    tr, te = _check_split(train_idx, test_idx, len(q))
    tab = table or MDHTable.franka_fr3()
    s = settings or IdentificationSettings(mode=ResidualMode.DISPLACEMENT)
    if s.mode is ResidualMode.POSITION:
        raise ValueError("calibrate_fr3 needs settings.mode = 'distance' or 'displacement'")
    he = solve_ax_xb(forward_kinematics(tab, q[tr]), C[tr])
    tool0 = he.T_flange_camera[:3, 3].copy()
    assert he.T_base_board is not None
    T0 = np.eye(4)
    T0[:3, :3] = he.T_base_board[:3, :3].T  # rotation of the base seen from the board
    cam = C[:, :3, 3]
    res = identify(
        tab,
        PairObservations.from_positions(q[tr], cam[tr]),
        tool=tool0,
        T_meas_base=T0,
        settings=s,
    )
    p_nom = tool_positions(tab, q[te], tool0)
    p_cal = res.tool_positions(q[te])
    nominal = ErrorStats.of(pair_distance_errors(p_nom, cam[te]))
    calibrated = ErrorStats.of(pair_distance_errors(p_cal, cam[te]))
    i, j = np.triu_indices(te.size, k=1)
    R_nom = T0[:3, :3]
    R_cal = res.T_meas_base[:3, :3] if res.T_meas_base is not None else R_nom
    d_meas = cam[te][j] - cam[te][i]
    secondary = {
        "nominal_displacement": ErrorStats.of(
            np.linalg.norm(np.einsum("ab,nb->na", R_nom, p_nom[j] - p_nom[i]) - d_meas, axis=1)
        ),
        "calibrated_displacement": ErrorStats.of(
            np.linalg.norm(np.einsum("ab,nb->na", R_cal, p_cal[j] - p_cal[i]) - d_meas, axis=1)
        ),
        "nominal_train_distance": ErrorStats.of(
            pair_distance_errors(tool_positions(tab, q[tr], tool0), cam[tr])
        ),
        "calibrated_train_distance": ErrorStats.of(
            pair_distance_errors(res.tool_positions(q[tr]), cam[tr])
        ),
    }
    return ArmCalibrationReport(
        metric="distance-accuracy error between held-out pose pairs (m)",
        nominal=nominal,
        calibrated=calibrated,
        identification=res,
        n_train=int(tr.size),
        n_test=int(te.size),
        secondary=secondary,
    )
