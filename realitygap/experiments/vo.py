r"""The ``vo`` experiment: RGB-D visual odometry against ground truth.

RGB-D visual odometry on a figure-eight drive through the textured
``realitygap/WheeledNav-v0`` room (image mode): trajectory error, relative
error per metre, frames lost, processing rate, ORB against SIFT, and the precision of the
matches the ratio test, GTM and RANSAC keep, judged against ground-truth
correspondences (:func:`match_precision`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.experiments import RunContext, experiment
from realitygap.experiments.drive_harness import (
    DriveLog,
    RecordingOdometry,
    calibration_room,
    drive,
    figure_eight,
    load_average,
    nominal_kinematics,
    timed_reference,
)

FloatArray = npt.NDArray[np.float64]

__all__ = ["match_precision", "relative_pose_errors", "vo"]


def match_precision(
    points_prev: npt.ArrayLike,
    pixels_curr: npt.ArrayLike,
    T_prev_curr: npt.ArrayLike,
    intrinsics: Any,
    tol_px: float = 3.0,
) -> npt.NDArray[np.bool_]:
    r"""Which matches agree with the true camera motion (ground-truth correspondence test).

    A match pairs a 3-D point ``p`` seen in the previous camera frame with a
    pixel ``u`` in the current image. It is correct when ``p``, moved by the
    true relative camera motion, reprojects within ``tol_px`` of ``u``:

    .. math::

        \big\| \pi\big(K\, T_{prev,curr}^{-1}\, p\big) - u \big\| \le \text{tol}_{px},

    with ``π`` the perspective division. Points that end up behind the
    camera count as wrong. The reprojection test is used rather than a 3-D
    distance because the depth noise of a far point (≈ 2 cm at 3 m) would
    otherwise reject correct matches.

    Parameters
    ----------
    points_prev : array_like, shape (N, 3)
        Matched points in the previous camera's optical frame, m.
    pixels_curr : array_like, shape (N, 2)
        Their matched pixels ``(u, v)`` in the current image.
    T_prev_curr : array_like, shape (4, 4)
        True pose of the current camera in the previous one.
    intrinsics : CameraIntrinsics
        Pinhole intrinsics of the current image.
    tol_px : float
        Reprojection tolerance, pixels.

    Returns
    -------
    ndarray of bool, shape (N,)
        True where the match is correct.

    Examples
    --------
    >>> from realitygap.estimators.base import CameraIntrinsics
    >>> K = CameraIntrinsics(320, 240, 200.0, 200.0, 160.0, 120.0)
    >>> p = np.array([[0.0, 0.0, 2.0], [0.5, 0.1, 3.0]])
    >>> u = np.array([[160.0, 120.0], [0.0, 0.0]])  # second match is wrong
    >>> match_precision(p, u, np.eye(4), K).tolist()
    [True, False]
    """
    from realitygap.core.geometry import check_finite
    from realitygap.estimators.registration import check_transform

    P = check_finite("points_prev", points_prev)
    U = check_finite("pixels_curr", pixels_curr)
    if P.ndim != 2 or P.shape[1] != 3 or U.shape != (P.shape[0], 2):
        raise ValueError(
            f"points_prev must have shape (N, 3) and pixels_curr (N, 2), got {P.shape} and {U.shape}"
        )
    if not tol_px > 0:
        raise ValueError(f"tol_px must be > 0 pixels, got {tol_px!r}")
    T = check_transform("T_prev_curr", T_prev_curr)
    R, t = T[:3, :3], T[:3, 3]
    Q = (P - t) @ R  # R^T (p - t): the point in the current camera frame
    z = Q[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intrinsics.fx * Q[:, 0] / z + intrinsics.cx
        v = intrinsics.fy * Q[:, 1] / z + intrinsics.cy
    err = np.hypot(u - U[:, 0], v - U[:, 1])
    return np.asarray((z > 1e-6) & (err <= tol_px), dtype=bool)


def relative_pose_errors(
    gt: npt.ArrayLike, estimate: npt.ArrayLike, segment_m: float = 1.0
) -> tuple[FloatArray, FloatArray]:
    """Relative pose errors over segments of ``segment_m`` metres of true travel.

    For every sample ``i`` the first ``j`` with a true path length from ``i``
    to ``j`` of at least ``segment_m`` is found, and the estimated relative
    motion ``⊖e_i ⊕ e_j`` is compared with the true one ``⊖g_i ⊕ g_j``.

    Parameters
    ----------
    gt, estimate : array_like, shape (N, 3)
        True and estimated planar poses (m, m, rad) at the same instants.
    segment_m : float
        Segment length, m.

    Returns
    -------
    trans_err : ndarray, shape (M,)
        Translation error of each segment, m.
    rot_err : ndarray, shape (M,)
        Absolute heading error of each segment, rad.
    """
    from realitygap.core.geometry import se2_between, wrap_angle

    g = np.asarray(gt, dtype=float)
    e = np.asarray(estimate, dtype=float)
    if g.ndim != 2 or g.shape[1] != 3 or e.shape != g.shape:
        raise ValueError(f"gt and estimate must both have shape (N, 3), got {g.shape}, {e.shape}")
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(g[:, :2], axis=0).T))])
    trans, rot = [], []
    for i in range(len(s)):
        j = int(np.searchsorted(s, s[i] + segment_m))
        if j >= len(s):
            break
        dg = se2_between(g[i], g[j])
        de = se2_between(e[i], e[j])
        trans.append(float(np.hypot(*(de[:2] - dg[:2]))))
        rot.append(abs(float(wrap_angle(de[2] - dg[2]))))
    return np.array(trans), np.array(rot)


def _rigid_align_2d(src: FloatArray, dst: FloatArray) -> FloatArray:
    """``src`` (N, 2) moved by the rotation + translation that best fits it onto ``dst``."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    H = (src - mu_s).T @ (dst - mu_d)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, d]) @ U.T
    return (src - mu_s) @ R.T + mu_d


@dataclass(frozen=True)
class _PairFeatures:
    pixels: FloatArray
    points: FloatArray
    descriptors: Any


def _features(detector: Any, frame: Any, params: Any) -> _PairFeatures:
    """Keypoints, their back-projected 3-D points (nan without depth) and descriptors."""
    import cv2

    gray = cv2.cvtColor(np.asarray(frame.rgb), cv2.COLOR_RGB2GRAY)
    kps, desc = detector.detectAndCompute(gray, None)
    pixels = np.array([kp.pt for kp in kps], dtype=float).reshape(-1, 2)
    intr = frame.intrinsics
    depth = np.asarray(frame.depth, dtype=float)
    # the 2×2 neighbourhood rule of the VO front end: valid, in range, not on a depth edge
    u0 = np.clip(np.floor(pixels[:, 0]).astype(int), 0, intr.width - 2)
    v0 = np.clip(np.floor(pixels[:, 1]).astype(int), 0, intr.height - 2)
    z4 = np.stack([depth[v0, u0], depth[v0, u0 + 1], depth[v0 + 1, u0], depth[v0 + 1, u0 + 1]])
    with np.errstate(invalid="ignore"):
        zmin, zmax = z4.min(axis=0), z4.max(axis=0)
        good = (
            np.all(np.isfinite(z4), axis=0)
            & (zmin >= params.depth_min_m)
            & (zmax <= params.depth_max_m)
            & (zmax - zmin <= params.depth_edge_ratio * zmin)
        )
    z = np.where(good, z4.mean(axis=0), np.nan)
    points = np.stack(
        [(pixels[:, 0] - intr.cx) * z / intr.fx, (pixels[:, 1] - intr.cy) * z / intr.fy, z], 1
    )
    return _PairFeatures(pixels, points, desc)


def _gtm_precision_pair(
    prev: _PairFeatures,
    curr: _PairFeatures,
    matcher: Any,
    params: Any,
    T_prev_curr: FloatArray,
    intrinsics: Any,
) -> tuple[int, int, int, int]:
    """(ratio-test matches, correct ones, kept by GTM, correct ones) for one frame pair."""
    from realitygap.estimators.gtm import gtm_filter

    if prev.descriptors is None or curr.descriptors is None or len(prev.pixels) < 2:
        return 0, 0, 0, 0
    knn = matcher.knnMatch(curr.descriptors, prev.descriptors, k=2)
    pairs = [
        (m[0].trainIdx, m[0].queryIdx)
        for m in knn
        if len(m) == 2 and m[0].distance < params.ratio * m[1].distance
    ]
    if len(pairs) < 3:
        return 0, 0, 0, 0
    i_prev, i_curr = np.array(pairs).T
    has_depth = np.all(np.isfinite(prev.points[i_prev]), axis=1)
    i_prev, i_curr = i_prev[has_depth], i_curr[has_depth]
    if len(i_prev) < 3:
        return 0, 0, 0, 0
    correct = match_precision(prev.points[i_prev], curr.pixels[i_curr], T_prev_curr, intrinsics)
    keep = gtm_filter(prev.pixels[i_prev], curr.pixels[i_curr], tolerance=params.gtm_tolerance)
    return len(correct), int(correct.sum()), int(keep.sum()), int(correct[keep].sum())


def _vo_room(ctx: RunContext, panelled: bool, seconds: float) -> dict[str, Any]:
    """Drive a figure-eight in a WheeledNav room, rendering frames at 10 Hz."""
    import gymnasium as gym

    import realitygap  # noqa: F401
    from realitygap.controllers.drives import PathFollower
    from realitygap.envs.layouts import random_layout
    from realitygap.robots.diffdrive import DiffDriveParams

    half = 2.5 if panelled else 3.5
    radius = 0.9 if panelled else 1.3
    start = np.array([0.0, 0.0, 0.0])
    path = figure_eight(start, ((radius, 2),))  # longer than the drive; cut at `seconds`
    rng = np.random.default_rng(ctx.seed)
    params = DiffDriveParams()
    if panelled:
        obstacles = calibration_room(half)
    else:
        keep = [tuple(p) for p in path.xy[:: max(1, len(path.xy) // 80)]]
        obstacles = random_layout(
            rng,
            8,
            half,
            keep_clear=keep,
            clear_radius=params.body_radius + 0.25,
            robot_radius=params.body_radius,
        )
    nominal = nominal_kinematics(params)
    recorder = RecordingOdometry(nominal)
    env = gym.make(
        "realitygap/WheeledNav-v0",
        sensor_mode="image",
        estimator=recorder,
        obstacles=obstacles,
        room_half_size=half,
        start=tuple(start),
        goal=(0.0, 0.5, 0.0),
        camera_hz=10.0,
        scan_hz=10.0,
        terminate_on_success=False,
    )
    try:
        log = drive(
            env,
            recorder,
            PathFollower(timed_reference(path, v_max=0.3)),
            start,
            int(ctx.seed),
            int(round(seconds * 20.0)),
        )
    finally:
        env.close()
    return {"log": log, "mounting": params.camera.T_base_camera(), "obstacles": len(obstacles)}


def _evaluate_vo(log: DriveLog, T_base_camera: FloatArray, params: Any) -> dict[str, Any]:
    """Run VO over the frames of ``log`` and score it against ground truth."""
    from realitygap.estimators.vo import RGBDVisualOdometry

    vo = RGBDVisualOdometry(params, T_base_camera=T_base_camera)
    vo.reset(log.T_world_camera[0])
    results = []
    elapsed = 0.0
    for frame in log.frames:
        t0 = time.perf_counter()
        results.append(vo.update(frame))
        elapsed += time.perf_counter() - t0
    est = np.array([r.pose for r in results])
    est[:, 2] = np.unwrap(est[:, 2])
    gt = log.gt[log.frame_index]
    err = np.hypot(*(est[:, :2] - gt[:, :2]).T)
    aligned = _rigid_align_2d(est[:, :2], gt[:, :2])
    err_rigid = np.hypot(*(aligned - gt[:, :2]).T)
    trans, rot = relative_pose_errors(gt, est, 1.0)
    # precision of the final (RANSAC/ICP) inliers against the true key-frame → frame motion
    kf = 0
    n_in = n_ok = 0
    for k, r in enumerate(results):
        if r.status == "ok" and len(r.inlier_points_prev):
            T_true = np.linalg.inv(log.T_world_camera[kf]) @ log.T_world_camera[k]
            good = match_precision(
                r.inlier_points_prev, r.inlier_pixels_curr, T_true, log.frames[k].intrinsics
            )
            n_in += len(good)
            n_ok += int(good.sum())
        if r.keyframe:
            kf = k
    path_len = float(np.sum(np.hypot(*np.diff(gt[:, :2], axis=0).T)))
    return {
        "ate_cm": 100.0 * float(np.sqrt(np.mean(err**2))),
        "ate_cm_rigid": 100.0 * float(np.sqrt(np.mean(err_rigid**2))),
        "final_err_cm": 100.0 * float(err[-1]),
        "rpe_cm_per_m": 100.0 * float(np.mean(trans)) if len(trans) else float("nan"),
        "rpe_deg_per_m": math.degrees(float(np.mean(rot))) if len(rot) else float("nan"),
        "vo_fps": len(results) / elapsed,
        "ransac_inlier_precision": n_ok / n_in if n_in else float("nan"),
        "frames_failed": int(sum(not r.ok for r in results)),
        "frames": len(results),
        "mean_inliers": float(np.mean([r.n_inliers for r in results])),
        "path_m": path_len,
    }


def _gtm_precision(log: DriveLog, params: Any, every: int = 2) -> dict[str, float]:
    """Precision of ratio-test matches and of the matches GTM keeps, consecutive frames."""
    import cv2

    if params.detector == "sift":
        detector, matcher = (
            cv2.SIFT.create(nfeatures=params.max_features),
            cv2.BFMatcher(cv2.NORM_L2),
        )
    else:
        detector = cv2.ORB.create(nfeatures=params.max_features)
        matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    totals = np.zeros(4)
    for k in range(1, len(log.frames), every):
        prev = _features(detector, log.frames[k - 1], params)
        curr = _features(detector, log.frames[k], params)
        T_true = np.linalg.inv(log.T_world_camera[k - 1]) @ log.T_world_camera[k]
        totals += _gtm_precision_pair(prev, curr, matcher, params, T_true, log.frames[k].intrinsics)
    n_ratio, ok_ratio, n_gtm, ok_gtm = totals
    return {
        "ratio_match_precision": ok_ratio / n_ratio if n_ratio else float("nan"),
        "gtm_inlier_precision": ok_gtm / n_gtm if n_gtm else float("nan"),
        "gtm_kept_fraction": n_gtm / n_ratio if n_ratio else float("nan"),
    }


@experiment(
    "vo",
    "RGB-D visual odometry on a 60 s drive through the default room: ATE, RPE, frames lost, fps",
)
def vo(ctx: RunContext) -> dict[str, Any]:
    """RGB-D VO on 60 s (quick: 15 s) of driving, in the env's own room and a panelled one.

    Figures without suffix: the env's default room (textured walls, floor and
    8 random obstacles) with the default VO (:class:`~realitygap.estimators.vo_params.VOParams`,
    ORB). ``*_sift``: SIFT on the same frames; ``*_panelled``: the panelled
    room (:func:`calibration_room`) with the default VO.
    """
    from realitygap.estimators.vo_params import VOParams

    seconds = 15.0 if ctx.quick else 60.0
    rows = []
    for room, panelled in (("default", False), ("panelled", True)):
        drive_out = _vo_room(ctx, panelled, seconds)
        log: DriveLog = drive_out["log"]
        ctx.progress(
            f"vo {room} room: drove {log.t[-1]:.0f} s, {len(log.frames)} frames, "
            f"collision={log.collided}"
        )
        for detector in ("orb", "sift") if not panelled else ("orb",):
            params = VOParams(detector=detector, seed=int(ctx.seed))
            row = {"room": room, "detector": detector, "obstacles": drive_out["obstacles"]}
            row.update(_evaluate_vo(log, drive_out["mounting"], params))
            row["frames_lost_pct"] = 100.0 * row["frames_failed"] / max(row["frames"], 1)
            if detector == "orb":
                row.update(_gtm_precision(log, params))
            rows.append(row)
            ctx.progress(
                f"vo {room}/{detector}: ATE {row['ate_cm']:.1f} cm, RPE {row['rpe_cm_per_m']:.2f} "
                f"cm/m {row['rpe_deg_per_m']:.2f} °/m, {row['frames_failed']} frames lost, "
                f"{row['vo_fps']:.0f} fps"
            )
    by = {(r["room"], r["detector"]): r for r in rows}
    head, sift, pan = by[("default", "orb")], by[("default", "sift")], by[("panelled", "orb")]
    figures = {
        "ate_cm": head["ate_cm"],
        "ate_cm_rigid": head["ate_cm_rigid"],
        "rpe_cm_per_m": head["rpe_cm_per_m"],
        "rpe_deg_per_m": head["rpe_deg_per_m"],
        "frames_lost_pct": head["frames_lost_pct"],
        "frames_failed": head["frames_failed"],
        "frames": head["frames"],
        "vo_fps": head["vo_fps"],
        "gtm_inlier_precision": head["gtm_inlier_precision"],
        "ratio_match_precision": head["ratio_match_precision"],
        "ransac_inlier_precision": head["ransac_inlier_precision"],
        "ate_cm_sift": sift["ate_cm"],
        "rpe_cm_per_m_sift": sift["rpe_cm_per_m"],
        "frames_lost_pct_sift": sift["frames_lost_pct"],
        "vo_fps_sift": sift["vo_fps"],
        "ate_cm_panelled": pan["ate_cm"],
        "rpe_cm_per_m_panelled": pan["rpe_cm_per_m"],
        "frames_lost_pct_panelled": pan["frames_lost_pct"],
    }
    return {
        "figures": figures,
        "config": {
            "seconds": seconds,
            "resolution": [320, 240],
            "camera_hz": 10,
            "drive": "figure-eight tracked on wheel odometry (Kanayama), 0.3 m/s",
            "room": "figures without suffix: WheeledNav-v0's own room, image mode, half-size "
            "3.5 m, textured walls (posters), tiled floor and 8 random textured obstacles kept "
            "off the path; default VOParams (ORB, bucketed features, ML motion)",
            "panelled_room": "*_panelled: half-size 2.5 m, walls lined with 0.5 m panels "
            "(calibration_room) plus four pieces of furniture",
            "load_avg_1min": load_average(),
            "ate": "RMS planar position error, VO started at the true first pose (no further "
            "alignment); ate_cm_rigid after a best-fit rotation + translation",
            "rpe": "mean over all 1 m segments of true travel",
            "frames_lost": "frames whose VO result is not ok (lost or reinitialised)",
            "correct_match": "3-D point of the previous frame, moved by the true camera motion, "
            "reprojects within 3 px of the matched keypoint",
            "vo_fps": "RGBDVisualOdometry.update only (rendering excluded)",
        },
        "tables": {"runs": rows},
    }
