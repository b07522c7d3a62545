"""Camera measurements of a calibration drive (the ``calib000`` experiment's inputs).

From the RGB-D frames of a :class:`~realitygap.experiments.drive_harness.DriveLog`:
the absolute end pose of a run (:func:`end_pose_from_frames`, UMBmark's
reference), the planar sensor ego-motion between consecutive frames with their
weights (:func:`_sensor_motions_of`) and the drive's loop closures, frames
registered directly against an earlier frame the robot came back to
(:func:`_loop_closures`); :func:`_drive_samples` bundles the last two in the
form the joint odometry/mounting fit pools.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import wrap_angle
from realitygap.experiments.drive_harness import DriveLog

FloatArray = npt.NDArray[np.float64]

__all__ = ["EndPose", "end_pose_from_frames"]


def _T_base_camera_planar(mounting: npt.ArrayLike, height: float = 0.30) -> FloatArray:
    """4×4 optical-frame pose in the base for a level camera at planar mounting ``[x, y, θ]``."""
    from realitygap.core.geometry import rot_z
    from realitygap.estimators.vo import T_BASE_CAMERA_FORWARD

    l = np.asarray(mounting, dtype=float)
    T = np.eye(4)
    T[:3, :3] = rot_z(float(l[2])) @ T_BASE_CAMERA_FORWARD[:3, :3]
    T[:3, 3] = (l[0], l[1], height)
    return T


def _sensor_motion_from_camera(T_prev_curr: FloatArray) -> FloatArray:
    """Planar ego-motion ``[x, y, θ]`` of the sensor frame (optical axis on the floor plane)."""
    from realitygap.estimators.vo import planar_motion_from_camera

    return np.array(planar_motion_from_camera(T_prev_curr))


def _vo_chain(
    frames: Sequence[Any], params: Any
) -> tuple[FloatArray, npt.NDArray[np.bool_], list[Any]]:
    """Camera poses (M, 4, 4) relative to the first frame, per-frame success and the results."""
    from realitygap.estimators.vo import RGBDVisualOdometry

    vo = RGBDVisualOdometry(params)
    vo.reset(np.eye(4))
    results = [vo.update(f) for f in frames]
    poses = np.array([r.T_world_camera for r in results])
    ok = np.array([r.ok for r in results], dtype=bool)
    return poses, ok, results


@dataclass(frozen=True)
class EndPose:
    """End pose of a run relative to its start, measured by the camera.

    Attributes
    ----------
    base_motion : ndarray, shape (3,)
        ``⊖q_start ⊕ q_end`` of the base (m, m, rad).
    source : str
        ``"loop closure"`` (last frame registered against the first) or
        ``"chained VO"``.
    n_inliers : int
        Inliers of the loop-closure registration (0 if it failed).
    """

    base_motion: FloatArray
    source: str
    n_inliers: int


def end_pose_from_frames(
    frames: Sequence[Any], mounting: npt.ArrayLike, params: Any = None, min_inliers: int = 40
) -> EndPose:
    """Absolute end pose of a run from its camera frames (the "map" reference of UMBmark).

    The last frame is registered directly against the first one; when the
    robot came back close to its start pose the two views overlap and this
    loop closure is accurate to millimetres. Otherwise the frame-to-frame
    visual-odometry chain is used. The sensor motion is carried to the base
    with the planar mounting ``l``: ``⊖q_0 ⊕ q_N = l ⊕ z ⊕ ⊖l``.

    Parameters
    ----------
    frames : sequence of RGBDFrame
        Frames of the run, the first at the start pose.
    mounting : array_like, shape (3,)
        Current estimate of the camera mounting ``[l_x, l_y, l_θ]`` (m, m, rad).
    params : VOParams, optional
    min_inliers : int
        Fewest inliers for the loop closure to be trusted.

    Returns
    -------
    EndPose
    """
    from realitygap.core.geometry import se2_compose, se2_inverse
    from realitygap.estimators.vo import RGBDVisualOdometry
    from realitygap.estimators.vo_params import VOParams

    params = params if params is not None else VOParams()
    if len(frames) < 2:
        raise ValueError(f"need at least two frames (start and end), got {len(frames)}")
    l = np.asarray(mounting, dtype=float)
    vo = RGBDVisualOdometry(params)
    vo.reset(np.eye(4))
    vo.update(frames[0])
    res = vo.update(frames[-1])
    if res.ok and res.n_inliers >= min_inliers:
        T, source, n_in = res.T_prev_curr, "loop closure", int(res.n_inliers)
    else:
        poses, _, _ = _vo_chain(frames, params)
        T, source, n_in = poses[-1], "chained VO", 0
    z = _sensor_motion_from_camera(T)
    return EndPose(se2_compose(se2_compose(l, z), se2_inverse(l)), source, n_in)


_REFERENCE_INLIERS = 50
"""Inlier count that gives a visual-odometry motion the weight 1 in the calibration."""


def _sensor_motions_of(
    log: DriveLog, params: Any
) -> tuple[FloatArray, list[FloatArray | None], FloatArray, int]:
    """Tick increments, VO sensor motions and their weights between consecutive frames.

    The weight of a frame pair is ``min(n_inliers) / 50`` over its two
    registrations (clipped to ``[0.1, 2]``): information grows with the number
    of independent point pairs.
    """
    poses, ok, results = _vo_chain(log.frames, params)
    fi = log.frame_index
    inc = log.ticks[fi[1:]] - log.ticks[fi[:-1]]
    n_in = np.array([r.n_inliers if r.status == "ok" else np.inf for r in results], dtype=float)
    motions: list[FloatArray | None] = []
    weights = np.ones(len(fi) - 1)
    for k in range(1, len(fi)):
        if ok[k] and ok[k - 1]:
            motions.append(_sensor_motion_from_camera(np.linalg.inv(poses[k - 1]) @ poses[k]))
            n = min(n_in[k - 1], n_in[k])
            weights[k - 1] = float(np.clip(n / _REFERENCE_INLIERS, 0.1, 2.0))
        else:
            motions.append(None)
    return inc, motions, weights, int(np.count_nonzero(~ok))


def _loop_closures(
    log: DriveLog,
    params: Any,
    radius: float = 0.05,
    max_yaw: float = math.radians(10.0),
    min_travel: float = 1.0,
    min_inliers: int = 40,
) -> tuple[FloatArray, FloatArray]:
    """Loop closures of a drive: summed tick increments (L, 2) and sensor motions (L, 3).

    Whenever the robot's own odometry says it is back within ``radius`` m and
    ``max_yaw`` of the last anchor frame (at first the first frame) after at
    least ``min_travel`` m, the closest frame of that visit is registered
    directly against the anchor; an accepted registration (``min_inliers``)
    becomes the next anchor.
    """
    from realitygap.estimators.vo import RGBDVisualOdometry

    fi = log.frame_index
    est = log.estimate[fi]
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(est[:, :2], axis=0).T))])
    incs: list[FloatArray] = []
    motions: list[FloatArray] = []
    anchor, j = 0, 1
    while j < len(fi):
        near = (
            np.hypot(*(est[j, :2] - est[anchor, :2])) < radius
            and abs(float(wrap_angle(est[j, 2] - est[anchor, 2]))) < max_yaw
            and travel[j] - travel[anchor] > min_travel
        )
        if not near:
            j += 1
            continue
        visit = j
        while visit + 1 < len(fi) and np.hypot(*(est[visit + 1, :2] - est[anchor, :2])) < radius:
            visit += 1
        best = j + int(np.argmin(np.hypot(*(est[j : visit + 1, :2] - est[anchor, :2]).T)))
        vo = RGBDVisualOdometry(params)
        vo.reset(np.eye(4))
        vo.update(log.frames[anchor])
        res = vo.update(log.frames[best])
        if res.ok and res.n_inliers >= min_inliers:
            incs.append(log.ticks[fi[best]] - log.ticks[fi[anchor]])
            motions.append(_sensor_motion_from_camera(res.T_prev_curr))
            anchor = best
        j = visit + 1
    return np.array(incs, dtype=float).reshape(-1, 2), np.array(motions).reshape(-1, 3)


def _drive_samples(log: DriveLog, params: Any) -> tuple[tuple[Any, ...], int]:
    """Frame-to-frame samples and loop closures of a drive (as pooled), and the lost frames."""
    inc, motions, weights, n_lost = _sensor_motions_of(log, params)
    return (inc, motions, weights, _loop_closures(log, params)), n_lost
