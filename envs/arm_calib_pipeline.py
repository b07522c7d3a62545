"""The observation pipeline of ``realitygap/ArmCalib-v0``: board measurements → MDH model.

:func:`observation_from_corners` measures the camera pose from the corners a
detector would report (the ``"geometric"`` sensor mode); :class:`MDHCalibrationEstimator`
turns successful pose measurements into pair displacements and identifies the MDH
parameters and the camera point (distance accuracy). Pure numpy / OpenCV: no simulation.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.estimators.arm.board_displacement import (
    cell_under_optical_axis,
    hierarchical_displacement,
)
from realitygap.estimators.arm.board_measurement import (
    BoardMeasurementSettings,
    BoardObservation,
    MeasurementStatus,
)
from realitygap.estimators.arm.coded_board import WINDOW, CodedBoard
from realitygap.estimators.arm.identification import (
    IdentificationResult,
    IdentificationSettings,
    identify,
)
from realitygap.estimators.arm.mdh import TOOL_PARAM_NAMES, MDHTable
from realitygap.estimators.arm.residuals import PairObservations, ResidualMode

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ArmPoseMeasurement",
    "CalibrationEstimate",
    "MDHCalibrationEstimator",
    "observation_from_corners",
]


# --------------------------------------------------------------------------- geometric measurement
def _failed(status: MeasurementStatus, n: int) -> BoardObservation:
    return BoardObservation(
        ok=False,
        status=status,
        cell_index=None,
        T_camera_board=np.full((4, 4), np.nan),
        n_corners=int(n),
        reprojection_rms_px=float("nan"),
    )


def observation_from_corners(
    image_points: npt.ArrayLike,
    corner_ids: npt.ArrayLike,
    K: npt.ArrayLike,
    dist: npt.ArrayLike | None,
    board: CodedBoard,
    settings: BoardMeasurementSettings | None = None,
    min_spacing_px: float = 6.0,
) -> BoardObservation:
    """The camera-pose stage of :func:`measure_board` on identified corners.

    For the ``"geometric"`` sensor mode, which reports the corners a detector
    would find (pixel positions and board ids) instead of an image. The frame is
    rejected like an image would be: fewer than ``settings.min_corners`` corners
    or corners closer than ``min_spacing_px`` (too far or too oblique to resolve)
    → ``TOO_FEW_CORNERS``; fewer than 8 × 8 cells with all four corners, or their
    extent less than 8 cells either way → ``CODE_WINDOW_INCOMPLETE``;
    optical axis off the board → ``OPTICAL_AXIS_OFF_BOARD``; PnP failure or
    reprojection RMS above ``settings.max_reprojection_rms_px`` → ``PNP_FAILED``.

    Parameters
    ----------
    image_points : array_like, shape (k, 2)
        Corner pixel positions (px).
    corner_ids : array_like of int, shape (k, 2)
        Their board corner indices ``(row, col)``.
    K : array_like, shape (3, 3)
    dist : array_like or None
        Intrinsics and distortion the measurement assumes.
    board : CodedBoard
    settings : BoardMeasurementSettings, optional

    Returns
    -------
    BoardObservation
    """
    import cv2
    from scipy.spatial import cKDTree

    s = settings or BoardMeasurementSettings()
    uv = np.asarray(image_points, dtype=float).reshape(-1, 2)
    ids = np.asarray(corner_ids).astype(np.int64).reshape(-1, 2)
    if len(ids) != len(uv):
        raise ValueError(f"got {len(uv)} image points but {len(ids)} corner ids")
    n = len(uv)
    if n < s.min_corners:
        return _failed(MeasurementStatus.TOO_FEW_CORNERS, n)
    spacing = float(np.median(cKDTree(uv).query(uv, k=2)[0][:, 1]))
    if spacing < min_spacing_px:
        return _failed(MeasurementStatus.TOO_FEW_CORNERS, n)
    nc = board.cells + 1
    occ = np.zeros((nc, nc), dtype=bool)
    occ[ids[:, 0], ids[:, 1]] = True
    full = occ[:-1, :-1] & occ[1:, :-1] & occ[:-1, 1:] & occ[1:, 1:]
    rows, cols = np.nonzero(full)
    if rows.size < WINDOW * WINDOW or np.ptp(rows) + 1 < WINDOW or np.ptp(cols) + 1 < WINDOW:
        return _failed(MeasurementStatus.CODE_WINDOW_INCOMPLETE, n)
    Km = np.asarray(K, dtype=float)
    d = np.zeros(5) if dist is None else np.asarray(dist, dtype=float)
    cs = board.cell_size
    obj = np.column_stack([ids[:, 1] * cs, ids[:, 0] * cs, np.zeros(n)])
    img = uv.reshape(-1, 1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, img, Km, d, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        return _failed(MeasurementStatus.PNP_FAILED, n)
    T_cb = np.eye(4)
    T_cb[:3, :3] = cv2.Rodrigues(rvec)[0]
    T_cb[:3, 3] = np.asarray(tvec).reshape(3)
    cell = cell_under_optical_axis(np.linalg.inv(T_cb), cs)
    if cell is None or not (0 <= cell[0] < board.cells and 0 <= cell[1] < board.cells):
        return _failed(MeasurementStatus.OPTICAL_AXIS_OFF_BOARD, n)
    # refine in the centre-cell frame, as measure_board does
    offset = np.array([cell[1] * cs, cell[0] * cs, 0.0])
    obj_c = obj - offset
    tvec_c = T_cb[:3, :3] @ offset + T_cb[:3, 3]
    rvec, tvec_c = cv2.solvePnPRefineLM(
        obj_c,
        img,
        Km,
        d,
        rvec,
        tvec_c.reshape(3, 1).copy(),
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-12),
    )
    proj, _ = cv2.projectPoints(obj_c, rvec, tvec_c, Km, d)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - uv) ** 2, axis=1))))
    if not rms <= s.max_reprojection_rms_px:
        return _failed(MeasurementStatus.PNP_FAILED, n)
    T_cc = np.eye(4)
    T_cc[:3, :3] = cv2.Rodrigues(rvec)[0]
    T_cc[:3, 3] = np.asarray(tvec_c).reshape(3)
    T_cell_board = np.eye(4)
    T_cell_board[:3, 3] = -offset
    return BoardObservation(
        ok=True,
        status=MeasurementStatus.OK,
        cell_index=(int(cell[0]), int(cell[1])),
        T_camera_board=T_cc @ T_cell_board,
        n_corners=n,
        reprojection_rms_px=rms,
        T_camera_cell=T_cc,
        code_mismatches=0,
        n_code_bits=0,
        image_points=uv.copy(),
        corner_ids=ids.copy(),
    )


# --------------------------------------------------------------------------- identification
@dataclass(frozen=True)
class ArmPoseMeasurement:
    """One usable calibration pose: encoder readings and the board measurement.

    Attributes
    ----------
    q : ndarray, shape (6,)
        Joint encoder readings (rad).
    board : BoardObservation
        Successful measurement of the camera pose against the board.
    """

    q: FloatArray
    board: BoardObservation


@dataclass(frozen=True)
class CalibrationEstimate:
    """The calibration pipeline's current model.

    Attributes
    ----------
    table : MDHTable
        Estimated geometry (the nominal one until the first accepted identification).
    tool : ndarray, shape (3,)
        Estimated camera point in the flange frame (m).
    n_poses : int
        Poses measured so far.
    identified : bool
        Whether ``table`` comes from an identification.
    ok : bool
        False when the last identification attempt failed or was rejected.
    status : str
        What happened at the last update.
    result : IdentificationResult or None
        The adopted identification.
    """

    table: MDHTable
    tool: FloatArray
    n_poses: int
    identified: bool
    ok: bool
    status: str
    result: IdentificationResult | None = None
    extras: dict[str, Any] = field(default_factory=dict)


class MDHCalibrationEstimator:
    """Pose measurements → pair displacements → MDH identification (distance accuracy).

    Follows the estimator protocol: :meth:`reset`, then :meth:`update` with an
    :class:`ArmPoseMeasurement` (or ``None``: nothing new).

    Parameters
    ----------
    nominal : MDHTable
        Start geometry.
    tool0 : array_like, shape (3,)
        Start camera point in the flange frame (m), from the nominal mount.
    cell_size : float
        Cell side of the board (m).
    settings : IdentificationSettings, optional
        Default: distance residuals, Gauss–Newton, 5-parameter MDH, camera point estimated.
    min_poses : int
        Identify only from this many poses on.
    identify_every : int
        Then identify after every ``identify_every`` new poses (see :meth:`update`).
    max_fit_rms : float
        Reject an identification whose RMS distance residual exceeds this (m).
    max_length_change, max_angle_change : float
        Reject one that moves a length (m) or an angle (rad) further than this from nominal.
    max_condition : float
        Reject one whose scaled Jacobian is worse conditioned than this.
    """

    def __init__(
        self,
        nominal: MDHTable,
        tool0: npt.ArrayLike,
        cell_size: float,
        settings: IdentificationSettings | None = None,
        min_poses: int = 8,
        identify_every: int = 1,
        max_fit_rms: float = 0.5e-3,
        max_length_change: float = 0.02,
        max_angle_change: float = 0.05,
        max_condition: float = 1e6,
    ):
        self.nominal = nominal
        self.tool0 = np.asarray(tool0, dtype=float).reshape(3).copy()
        self.cell_size = float(cell_size)
        self.settings = settings or IdentificationSettings(mode=ResidualMode.DISTANCE)
        if self.settings.mode is ResidualMode.POSITION:
            raise ValueError(
                "the board gives displacements, not positions in a fixed frame: settings.mode "
                "must be 'distance' or 'displacement'"
            )
        if int(min_poses) < 3:
            raise ValueError(f"min_poses must be >= 3, got {min_poses}")
        if int(identify_every) < 1:
            raise ValueError(f"identify_every must be >= 1, got {identify_every}")
        self.min_poses = int(min_poses)
        self.identify_every = int(identify_every)
        self.max_fit_rms = float(max_fit_rms)
        self.max_length_change = float(max_length_change)
        self.max_angle_change = float(max_angle_change)
        self.max_condition = float(max_condition)
        self.measurements: list[ArmPoseMeasurement] = []
        self._last_identified_at = 0
        self._estimate = self._start_estimate("no poses yet")
        self.identify_seconds = 0.0

    def _start_estimate(self, status: str) -> CalibrationEstimate:
        return CalibrationEstimate(self.nominal, self.tool0.copy(), 0, False, True, status)

    def reset(self, initial: Any | None = None) -> CalibrationEstimate:
        """Forget every measurement; the estimate is the nominal model."""
        self.measurements = []
        self._last_identified_at = 0
        self.identify_seconds = 0.0
        self._estimate = self._start_estimate("no poses yet")
        return self._estimate

    @property
    def estimate(self) -> CalibrationEstimate:
        return self._estimate

    def pair_observations(self) -> PairObservations:
        """Hierarchical displacements between every pair of measured poses (board frame)."""
        ms = self.measurements
        if len(ms) < 2:
            raise ValueError(f"pairs need at least 2 poses, have {len(ms)}")
        i, j = np.triu_indices(len(ms), k=1)
        disp = np.array(
            [
                hierarchical_displacement(ms[a].board, ms[b].board, self.cell_size).delta
                for a, b in zip(i, j)
            ]
        )
        q = np.array([m.q for m in ms])
        return PairObservations(q[i], q[j], disp)

    def update(
        self, measurement: ArmPoseMeasurement | None, force: bool = False
    ) -> CalibrationEstimate:
        """Add a pose (``None``: none) and re-identify when due (or when ``force``)."""
        if measurement is not None:
            if not measurement.board.ok:
                raise ValueError(
                    "only successful board measurements can be added, got status "
                    f"{measurement.board.status.value!r}"
                )
            self.measurements.append(measurement)
        n = len(self.measurements)
        prev = self._estimate
        due = n >= self.min_poses and (
            n - self._last_identified_at >= self.identify_every
            or (force and n > self._last_identified_at)
        )
        if not due:
            status = (
                f"waiting: {n} of {self.min_poses} poses needed"
                if n < self.min_poses
                else prev.status
            )
            self._estimate = CalibrationEstimate(
                prev.table, prev.tool, n, prev.identified, prev.ok, status, prev.result
            )
            return self._estimate
        self._last_identified_at = n
        t0 = time.perf_counter()
        try:
            res = identify(
                self.nominal, self.pair_observations(), tool=self.tool0, settings=self.settings
            )
            reason = self._reject_reason(res)
        except (ValueError, np.linalg.LinAlgError) as exc:
            res, reason = None, f"identification failed: {exc}"
        self.identify_seconds += time.perf_counter() - t0
        if res is None or reason:
            self._estimate = CalibrationEstimate(
                prev.table, prev.tool, n, prev.identified, False, reason, prev.result
            )
        else:
            self._estimate = CalibrationEstimate(
                res.table, res.tool.copy(), n, True, True, f"identified from {n} poses", res
            )
        return self._estimate

    def _reject_reason(self, res: IdentificationResult) -> str:
        if not res.converged:
            return "identification rejected: did not converge"
        if not (np.isfinite(res.rms_after) and np.all(np.isfinite(res.table.params()))):
            return "identification rejected: non-finite result"
        if res.rms_after > self.max_fit_rms:
            return (
                f"identification rejected: RMS residual {res.rms_after * 1e3:.3f} mm exceeds "
                f"{self.max_fit_rms * 1e3:.3f} mm (outlier measurement or unmodelled effect)"
            )
        if not res.condition_number <= self.max_condition:
            return (
                f"identification rejected: condition number {res.condition_number:.3g} above "
                f"{self.max_condition:.3g} (poses too similar)"
            )
        for nm, dv in res.deltas.items():
            is_length = nm.rstrip("0123456789") in ("d", "a") or nm in TOOL_PARAM_NAMES
            lim = self.max_length_change if is_length else self.max_angle_change
            if abs(dv) > lim:
                return (
                    f"identification rejected: {nm} moved {dv:+.4g} {'m' if is_length else 'rad'} "
                    f"from nominal (limit {lim:g})"
                )
        return ""
