"""Key-frame RGB-D visual odometry.

The front end follows the classical RGB-D pipeline

1. detect and describe keypoints (ORB by default, or SIFT) on the grey image;
2. match descriptors against the current key-frame with Lowe's ratio test;
3. reject outlier matches with Graph Transformation Matching
   (:func:`~realitygap.estimators.gtm.gtm_filter`);
4. back-project the matched keypoints with the depth image;
5. estimate the rigid motion with RANSAC over Kabsch fits
   (:func:`~realitygap.estimators.registration.ransac_rigid`,
   :func:`~realitygap.estimators.registration.kabsch_umeyama`), each pair weighted
   by its inverse depth variance, and refine it by maximum likelihood under the
   RGB-D noise model (pixel noise across each viewing ray, depth noise along
   it; ``VOParams.motion_solver`` also offers point-to-point ICP,
   :func:`~realitygap.estimators.registration.icp_point_to_point`, and PnP);
6. chain the key-frame-relative motions into the camera trajectory; a frame
   becomes the next key-frame when the camera has moved or turned far enough or
   the inliers thin out. When the key-frame no longer matches (it left the
   view), the frame is registered against the last tracked frame instead,
   becomes the key-frame, and says so in :attr:`VOResult.reference`.

Keypoints are spread over the image by a grid (``VOParams.bucket_grid``), so
near floor and furniture texture is kept beside the strong corners of far
posters: near points fix the translation, far ones the rotation.

Frames: ``camera`` is the optical frame (x right, y down, z forward), ``base``
the robot body (x forward, y left, z up), ``world`` the frame in which the
odometry starts. ``T_a_b`` is the 4×4 homogeneous transform that maps
coordinates in frame ``b`` to frame ``a`` (equivalently, the pose of ``b`` in
``a``). Lengths are in metres, angles in radians.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import transform_from_rt, transform_inverse
from realitygap.estimators.base import CameraIntrinsics, Estimate, RGBDFrame
from realitygap.estimators.gtm import gtm_filter
from realitygap.estimators.registration import (
    RegistrationError,
    check_transform,
    icp_point_to_point,
    ransac_rigid,
    rotation_angle,
)
from realitygap.estimators.rgbd_motion import (
    motion_covariance_ml,
    point_covariance,
    refine_motion_ml,
    solve_pnp,
)
from realitygap.estimators.vo_params import Detector, VOParams, VOStatus

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
#: SIFT (N, 128) float32 or ORB (N, 32) uint8 descriptors.
Descriptors = npt.NDArray[np.integer[Any] | np.floating[Any]]

__all__ = [
    "T_BASE_CAMERA_FORWARD",
    "RGBDVisualOdometry",
    "VOResult",
    "planar_motion_from_camera",
]

#: Camera at the base origin looking along the base x axis: optical z = base x,
#: optical x = −base y, optical y = −base z.
T_BASE_CAMERA_FORWARD: FloatArray = np.array(
    [
        [0.0, 0.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0, 0.0],
        [0.0, -1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
T_BASE_CAMERA_FORWARD.setflags(write=False)


@dataclass
class VOResult:
    """Output of :meth:`RGBDVisualOdometry.update`.

    The transforms always satisfy ``T_world_camera = T_world_keyframe @ T_prev_curr``
    and are never NaN; when ``ok`` is false they hold the last good estimate.

    Attributes
    ----------
    t : float
        Time stamp [s] of the frame (of the last frame for ``update(None)``).
    T_world_camera : ndarray, shape (4, 4)
        Camera pose in the world.
    T_prev_curr : ndarray, shape (4, 4)
        Camera motion from the reference key-frame to this frame (pose of this
        camera in the key-frame's camera frame).
    T_world_keyframe : ndarray, shape (4, 4)
        Pose of the reference key-frame.
    pose : ndarray, shape (3,)
        Planar base pose ``[x, y, theta]`` (m, m, rad) in the world, from
        ``T_world_camera`` and the camera mounting.
    ok : bool
        Whether this frame produced a motion estimate.
    status : str
        A :class:`VOStatus` value.
    n_keypoints, n_matches, n_gtm, n_depth, n_inliers : int
        Keypoints in the frame; matches after the ratio test; after GTM; with
        valid depth on both sides; RANSAC/ICP inliers.
    keyframe : bool
        This frame became the new key-frame.
    reference : str
        What the motion was registered against: ``"keyframe"``, or
        ``"previous_frame"`` when the key-frame no longer matched (too few shared
        features in view) and the frame was chained through the last tracked
        frame instead; such a frame always becomes the new key-frame.
    rms_m : float
        RMS 3-D residual of the inliers at the final motion [m] (``nan``-free;
        0 when no motion was estimated).
    inlier_indices : ndarray of int, shape (n, 2)
        Keypoint indices ``(key-frame, current)`` of the inlier matches.
    inlier_pixels_prev, inlier_pixels_curr : ndarray, shape (n, 2)
        Their pixel coordinates ``(u, v)``.
    inlier_points_prev, inlier_points_curr : ndarray, shape (n, 3)
        Their 3-D points in the key-frame and current camera frames [m].
    motion_cov : ndarray, shape (6, 6), or None
        Covariance of ``T_prev_curr`` from its own inliers
        (:func:`~realitygap.estimators.rgbd_motion.motion_covariance_ml`): rotation then
        translation increments of the camera in the reference frame (rad², m²); ``None``
        when no motion was estimated or the solver was ``"pnp"``. It refers to the motion
        against the reference the frame was registered to (see ``reference``).
    """

    t: float
    T_world_camera: FloatArray
    T_prev_curr: FloatArray
    T_world_keyframe: FloatArray
    pose: FloatArray
    ok: bool
    status: str
    n_keypoints: int = 0
    n_matches: int = 0
    n_gtm: int = 0
    n_depth: int = 0
    n_inliers: int = 0
    keyframe: bool = False
    reference: str = "keyframe"
    rms_m: float = 0.0
    inlier_indices: npt.NDArray[np.intp] = field(default_factory=lambda: np.zeros((0, 2), np.intp))
    inlier_pixels_prev: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    inlier_pixels_curr: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    inlier_points_prev: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    inlier_points_curr: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    motion_cov: FloatArray | None = None

    def to_estimate(self) -> Estimate:
        """This result as an :class:`~realitygap.estimators.base.Estimate`.

        ``pose`` is the planar base pose; ``extras["vo"]`` holds this result.
        """
        return Estimate(
            t=self.t, pose=self.pose.copy(), ok=self.ok, status=self.status, extras={"vo": self}
        )


@dataclass
class _Keyframe:
    T_world_camera: FloatArray
    pixels: FloatArray  # (n, 2)
    descriptors: Descriptors
    points: FloatArray  # (n, 3), nan where depth is invalid


def planar_motion_from_camera(
    T_prev_curr: npt.ArrayLike, T_base_camera: npt.ArrayLike | None = None
) -> tuple[float, float, float]:
    r"""Planar base increment ``(dx, dy, dθ)`` from a camera motion.

    The base motion is the camera motion seen through the mounting,

    .. math::

        T_{b_0 b_1} = T_{bc}\, T_{c_0 c_1}\, T_{bc}^{-1},

    and the increment is its translation along base x (forward) and y (left)
    [m] and its rotation about base z [rad], :math:`\operatorname{atan2}(R_{10},
    R_{00})`. Out-of-plane components are dropped.

    Parameters
    ----------
    T_prev_curr : array_like, shape (4, 4)
        Pose of the current camera (optical frame) in the previous one.
    T_base_camera : array_like, shape (4, 4), optional
        Camera mounting on the base; :data:`T_BASE_CAMERA_FORWARD` by default.

    Returns
    -------
    tuple of float
        ``(dx, dy, dtheta)`` in the previous base frame.
    """
    T_cc = check_transform("T_prev_curr", T_prev_curr)
    T_bc = (
        T_BASE_CAMERA_FORWARD
        if T_base_camera is None
        else check_transform("T_base_camera", T_base_camera)
    )
    T_bb = T_bc @ T_cc @ transform_inverse(T_bc)
    return float(T_bb[0, 3]), float(T_bb[1, 3]), float(np.arctan2(T_bb[1, 0], T_bb[0, 0]))


def _planar_pose(T_world_base: FloatArray) -> FloatArray:
    return np.array(
        [T_world_base[0, 3], T_world_base[1, 3], np.arctan2(T_world_base[1, 0], T_world_base[0, 0])]
    )


class RGBDVisualOdometry:
    """Key-frame RGB-D visual odometry (see the module docstring for the pipeline).

    Each frame is registered against the current key-frame; a frame becomes
    the new key-frame when the inliers thin out or the camera has moved or
    turned far enough, which limits drift while the robot stands still.

    Parameters
    ----------
    params : VOParams, optional
        Settings; defaults if omitted.
    T_base_camera : array_like, shape (4, 4), optional
        Camera mounting on the base, used for :attr:`VOResult.pose` and as the
        default initial camera pose; :data:`T_BASE_CAMERA_FORWARD` by default.

    Examples
    --------
    >>> vo = RGBDVisualOdometry(VOParams(detector="orb"))
    >>> vo.update(None).status
    'no_frame'
    """

    def __init__(
        self, params: VOParams | None = None, T_base_camera: npt.ArrayLike | None = None
    ) -> None:
        self.params = VOParams() if params is None else params
        if not isinstance(self.params, VOParams):
            raise TypeError(f"params must be a VOParams, got {type(self.params).__name__}")
        self.T_base_camera = (
            T_BASE_CAMERA_FORWARD.copy()
            if T_base_camera is None
            else check_transform("T_base_camera", T_base_camera)
        )
        self._T_camera_base = transform_inverse(self.T_base_camera)
        p = self.params
        self._detector: cv2.Feature2D
        if p.detector == Detector.SIFT:
            self._detector = cv2.SIFT.create(nfeatures=p.max_features * (2 if p.bucket_grid else 1))
            self._matcher = cv2.BFMatcher(cv2.NORM_L2)
        else:
            self._detector = cv2.ORB.create(nfeatures=p.max_features * (4 if p.bucket_grid else 1))
            self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        self.reset()

    # -- state ---------------------------------------------------------------

    def reset(self, initial_T_world_camera: npt.ArrayLike | None = None) -> VOResult:
        """Forget all frames and start at ``initial_T_world_camera``.

        Parameters
        ----------
        initial_T_world_camera : array_like, shape (4, 4), optional
            Initial camera pose; by default the base starts at the world origin,
            i.e. the camera pose is ``T_base_camera``.

        Returns
        -------
        VOResult
            The initial state, status ``reset``.
        """
        T0 = (
            self.T_base_camera.copy()
            if initial_T_world_camera is None
            else check_transform("initial_T_world_camera", initial_T_world_camera)
        )
        self._rng = np.random.default_rng(self.params.seed)
        self._keyframe: _Keyframe | None = None
        self._last: _Keyframe | None = None
        self._T_world_kf = T0.copy()
        self._T_kf_curr = np.eye(4)
        self._t = 0.0
        self._lost = 0
        return self._result(VOStatus.RESET, ok=True)

    @property
    def T_world_camera(self) -> FloatArray:
        """Last good camera pose in the world, shape (4, 4)."""
        return self._T_world_kf @ self._T_kf_curr

    def _result(self, status: VOStatus, ok: bool, **counts: object) -> VOResult:
        T_wc = self._T_world_kf @ self._T_kf_curr
        return VOResult(
            t=self._t,
            T_world_camera=T_wc,
            T_prev_curr=self._T_kf_curr.copy(),
            T_world_keyframe=self._T_world_kf.copy(),
            pose=_planar_pose(T_wc @ self._T_camera_base),
            ok=ok,
            status=status.value,
            **counts,  # type: ignore[arg-type]
        )

    # -- per frame -----------------------------------------------------------

    def update(self, frame: RGBDFrame | None) -> VOResult:
        """Consume one RGB-D frame (or ``None``) and return the motion estimate.

        Never raises on image content: blank images, depth holes and failed
        registrations come back as ``ok=False`` with a :class:`VOStatus`.

        Parameters
        ----------
        frame : RGBDFrame or None
            Colour (H, W, 3) uint8 or grey (H, W) uint8 image, depth (H, W) [m]
            with ``nan`` for no return, and the intrinsics.

        Returns
        -------
        VOResult

        Raises
        ------
        TypeError, ValueError
            If ``frame`` is not an :class:`RGBDFrame` or its arrays do not match
            its intrinsics.
        """
        if frame is None:
            return self._result(VOStatus.NO_FRAME, ok=False)
        gray, depth = self._check_frame(frame)
        self._t = float(frame.t)
        p = self.params

        kps, raw = self._detect(gray)
        n_kp = 0 if raw is None else len(kps)
        if n_kp < p.min_keypoints:
            return self._result(VOStatus.NO_FEATURES, ok=False, n_keypoints=n_kp)
        desc: Descriptors = np.asarray(raw)
        pixels = self._keypoint_pixels(kps, gray.shape)
        points = self._back_project(pixels, depth, frame.intrinsics)
        valid_now = np.all(np.isfinite(points), axis=1)

        kf = self._keyframe
        if kf is None:
            if np.count_nonzero(valid_now) < p.min_inliers:
                return self._result(VOStatus.DEPTH_HOLES, ok=False, n_keypoints=n_kp)
            self._set_keyframe(pixels, desc, points, self._T_world_kf)
            return self._result(VOStatus.INITIALISED, ok=True, n_keypoints=n_kp, keyframe=True)

        counts: dict[str, object] = {"n_keypoints": n_kp}
        status, motion = self._register(
            kf, pixels, desc, points, valid_now, counts, frame.intrinsics
        )
        reference = "keyframe"
        last = self._last
        if status is not VOStatus.OK and last is not None and last is not kf:
            # the key-frame is out of view: chain through the last tracked frame instead
            counts_b: dict[str, object] = {"n_keypoints": n_kp}
            status_b, motion_b = self._register(
                last, pixels, desc, points, valid_now, counts_b, frame.intrinsics
            )
            if status_b is VOStatus.OK:
                status, motion, counts, reference = status_b, motion_b, counts_b, "previous_frame"
        if status is not VOStatus.OK or motion is None:
            return self._lost_frame(status, pixels, desc, points, counts)
        R, t = motion
        self._lost = 0
        if reference == "keyframe":
            self._T_kf_curr = transform_from_rt(R, t)
        else:
            T_world_curr = last.T_world_camera @ transform_from_rt(R, t)  # type: ignore[union-attr]
            self._T_kf_curr = transform_inverse(self._T_world_kf) @ T_world_curr
        n_inliers = int(counts["n_inliers"])  # type: ignore[call-overload]
        new_kf = (
            reference != "keyframe"
            or n_inliers < p.keyframe_min_inliers
            or float(np.linalg.norm(t)) > p.keyframe_translation_m
            or rotation_angle(R) > p.keyframe_rotation_rad
        )
        result = self._result(VOStatus.OK, ok=True, keyframe=new_kf, reference=reference, **counts)
        if new_kf:
            self._set_keyframe(pixels, desc, points, result.T_world_camera)
        else:
            self._last = _Keyframe(result.T_world_camera, pixels, desc, points)
        return result

    def _register(
        self,
        ref: _Keyframe,
        pixels: FloatArray,
        desc: Descriptors,
        points: FloatArray,
        valid_now: npt.NDArray[np.bool_],
        counts: dict[str, object],
        intrinsics: CameraIntrinsics,
    ) -> tuple[VOStatus, tuple[FloatArray, FloatArray] | None]:
        """Motion ``(R, t)`` of this frame in the reference frame ``ref`` (match, GTM,
        RANSAC, ICP); fills ``counts`` and the inlier fields."""
        p = self.params
        i_kf, i_cur = self._match(ref.descriptors, desc)
        counts["n_matches"] = counts["n_gtm"] = len(i_kf)
        if len(i_kf) < p.min_matches:
            return VOStatus.TOO_FEW_MATCHES, None
        if p.use_gtm:
            keep = gtm_filter(
                ref.pixels[i_kf],
                pixels[i_cur],
                k=p.gtm_k,
                tolerance=0.0 if p.gtm_k else p.gtm_tolerance,
            )
            i_kf, i_cur = i_kf[keep], i_cur[keep]
            counts["n_gtm"] = len(i_kf)
            if len(i_kf) < p.min_matches:
                return VOStatus.TOO_FEW_MATCHES, None
        has_depth = np.all(np.isfinite(ref.points[i_kf]), axis=1) & valid_now[i_cur]
        i_kf, i_cur = i_kf[has_depth], i_cur[has_depth]
        counts["n_depth"] = len(i_kf)
        if len(i_kf) < p.min_inliers:
            return VOStatus.DEPTH_HOLES, None

        P_kf, P_cur = ref.points[i_kf], points[i_cur]
        if p.motion_solver == "pnp":
            found = solve_pnp(
                P_kf,
                pixels[i_cur],
                intrinsics,
                self._rng,
                p.ransac_max_iters,
                p.pnp_reprojection_px,
                p.min_inliers,
            )
            if found is None:
                return VOStatus.RANSAC_FAILED, None
            R, t, inl = found
        else:
            # σ_z ∝ z² for RGB-D sensors: weight each pair by its inverse depth variance
            w = 1.0 / (P_kf[:, 2] ** 4 + P_cur[:, 2] ** 4) if p.depth_weighting else None
            try:
                R, t, inl = ransac_rigid(
                    P_cur,
                    P_kf,
                    p.ransac_threshold_m,
                    self._rng,
                    p.ransac_max_iters,
                    p.min_inliers,
                    weights=w,
                )
            except RegistrationError:
                return VOStatus.RANSAC_FAILED, None
            noise = (p.pixel_sigma_px, p.depth_sigma_a_m, p.depth_sigma_b_per_m)
            S_cur = point_covariance(P_cur[inl], intrinsics, *noise)
            S_kf = point_covariance(P_kf[inl], intrinsics, *noise)
            if p.motion_solver == "ml":
                R, t = refine_motion_ml(P_cur[inl], P_kf[inl], R, t, S_cur, S_kf)
            elif p.use_icp:
                R, t = self._refine(P_cur[inl], P_kf[inl], R, t, None if w is None else w[inl])
            counts["motion_cov"] = motion_covariance_ml(P_cur[inl], P_kf[inl], R, t, S_cur, S_kf)
        res = P_cur[inl] @ R.T + t - P_kf[inl]
        counts["rms_m"] = float(np.sqrt(np.mean(np.sum(res * res, axis=1))))
        counts["n_inliers"] = int(np.count_nonzero(inl))
        i_kf, i_cur = i_kf[inl], i_cur[inl]
        counts["inlier_indices"] = np.stack([i_kf, i_cur], axis=1)
        counts["inlier_pixels_prev"] = ref.pixels[i_kf]
        counts["inlier_pixels_curr"] = pixels[i_cur]
        counts["inlier_points_prev"] = ref.points[i_kf]
        counts["inlier_points_curr"] = points[i_cur]
        return VOStatus.OK, (R, t)

    # -- helpers -------------------------------------------------------------

    def _check_frame(self, frame: RGBDFrame) -> tuple[npt.NDArray[np.uint8], FloatArray]:
        if not isinstance(frame, RGBDFrame):
            raise TypeError(f"frame must be an RGBDFrame or None, got {type(frame).__name__}")
        intr = frame.intrinsics
        if not isinstance(intr, CameraIntrinsics):
            raise TypeError(f"frame.intrinsics must be CameraIntrinsics, got {type(intr).__name__}")
        hw = (intr.height, intr.width)
        rgb = np.asarray(frame.rgb)
        if rgb.shape[:2] != hw or rgb.ndim not in (2, 3) or (rgb.ndim == 3 and rgb.shape[2] != 3):
            raise ValueError(f"frame.rgb must have shape {(*hw, 3)} or {hw}, got {rgb.shape}")
        depth = np.asarray(frame.depth, dtype=np.float64)
        if depth.shape != hw:
            raise ValueError(f"frame.depth must have shape {hw}, got {depth.shape}")
        if rgb.dtype != np.uint8:
            raise ValueError(f"frame.rgb must be uint8, got {rgb.dtype}")
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
        return np.ascontiguousarray(gray, dtype=np.uint8), depth

    def _back_project(
        self, pixels: FloatArray, depth: FloatArray, intr: CameraIntrinsics
    ) -> FloatArray:
        """3-D points (n, 3) in the camera frame; ``nan`` rows where depth is unusable.

        Depth is interpolated bilinearly from the 2×2 pixel neighbourhood; the
        keypoint is rejected when a neighbour is missing or out of range, or the
        neighbourhood spreads by more than ``depth_edge_ratio`` (an edge).
        """
        p = self.params
        h, w = depth.shape
        u, v = pixels[:, 0], pixels[:, 1]
        u0 = np.clip(np.floor(u).astype(np.intp), 0, w - 2)
        v0 = np.clip(np.floor(v).astype(np.intp), 0, h - 2)
        du, dv = np.clip(u - u0, 0.0, 1.0), np.clip(v - v0, 0.0, 1.0)
        z4 = np.stack([depth[v0, u0], depth[v0, u0 + 1], depth[v0 + 1, u0], depth[v0 + 1, u0 + 1]])
        finite = np.all(np.isfinite(z4), axis=0)
        z4 = np.where(finite, z4, 1.0)
        zmin, zmax = z4.min(axis=0), z4.max(axis=0)
        good = (
            finite
            & (zmin >= p.depth_min_m)
            & (zmax <= p.depth_max_m)
            & (zmax - zmin <= p.depth_edge_ratio * zmin)
        )
        z = (1 - dv) * ((1 - du) * z4[0] + du * z4[1]) + dv * ((1 - du) * z4[2] + du * z4[3])
        pts = np.stack([(u - intr.cx) * z / intr.fx, (v - intr.cy) * z / intr.fy, z], axis=1)
        pts[~good] = np.nan
        return pts

    def _keypoint_pixels(self, kps: Any, shape: tuple[int, ...]) -> FloatArray:
        """Keypoint positions ``(n, 2)`` in full-resolution pixels (centre of the top-left
        pixel at ``(0, 0)``).

        ORB detects on a pyramid whose level ``L`` has ``round(W / s**L)`` ×
        ``round(H / s**L)`` pixels but reports a level-``L`` position as ``x_L · s**L``.
        The image is resized edge to edge, so the true mapping is
        ``x + ½ = (x_L + ½) · W / W_L``: the reported positions carry a scale error of
        up to a few tenths of a percent per level (its sign depends on the rounding),
        which scales the image motion of those keypoints and hence the rotation. The
        exact mapping is applied here; SIFT's octaves halve exactly and need none.
        """
        pixels = np.array([kp.pt for kp in kps], dtype=float).reshape(-1, 2)
        if self.params.detector != Detector.ORB or len(pixels) == 0:
            return pixels
        orb = self._detector
        s = float(orb.getScaleFactor())  # type: ignore[attr-defined]
        level = np.array([kp.octave for kp in kps], dtype=np.intp)
        h, w = shape[:2]
        for L in np.unique(level):
            if L <= 0:
                continue
            nominal = s ** float(L)
            sel = level == L
            for axis, size in ((0, w), (1, h)):
                actual = size / float(round(size / nominal))
                pixels[sel, axis] = (pixels[sel, axis] / nominal + 0.5) * actual - 0.5
        return pixels

    def _match(self, desc_kf: Descriptors, desc: Descriptors) -> tuple[IntArray, IntArray]:
        """Ratio-test matches (key-frame index, current index), one per key-frame keypoint."""
        if len(desc_kf) < 2 or len(desc) < 1:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        knn = self._matcher.knnMatch(desc, desc_kf, k=2)
        trip = np.array(
            [
                (m[0].trainIdx, m[0].queryIdx, m[0].distance, m[1].distance)
                for m in knn
                if len(m) == 2
            ],
            dtype=float,
        ).reshape(-1, 4)
        good = trip[:, 2] < self.params.ratio * trip[:, 3]
        trip = trip[good]
        # keep the best match per key-frame keypoint (many-to-one matches are ambiguous)
        order = np.lexsort((trip[:, 2], trip[:, 0]))
        trip = trip[order]
        first = np.ones(len(trip), dtype=bool)
        first[1:] = trip[1:, 0] != trip[:-1, 0]
        trip = trip[first]
        return trip[:, 0].astype(np.intp), trip[:, 1].astype(np.intp)

    def _detect(self, gray: npt.NDArray[np.uint8]) -> tuple[Any, Any]:
        """Keypoints and descriptors; with ``bucket_grid``, the strongest candidates of each
        grid cell, so that near texture (floor, furniture) is kept beside the strong
        corners of far posters that would otherwise take the whole budget."""
        p = self.params
        if not p.bucket_grid:
            return self._detector.detectAndCompute(gray, None)
        kps = self._detector.detect(gray, None)
        if len(kps) > p.max_features:
            nx, ny = p.bucket_grid
            h, w = gray.shape
            cell = np.array(
                [
                    min(int(k.pt[0] * nx / w), nx - 1) + nx * min(int(k.pt[1] * ny / h), ny - 1)
                    for k in kps
                ]
            )
            response = np.array([k.response for k in kps])
            order = np.lexsort((-response, cell))  # by cell, strongest first
            rank = np.empty(len(kps), dtype=np.intp)
            sorted_cells = cell[order]
            starts = np.flatnonzero(np.r_[True, sorted_cells[1:] != sorted_cells[:-1]])
            counts = np.diff(np.r_[starts, len(order)])
            rank[order] = np.arange(len(order)) - np.repeat(starts, counts)
            # round-robin over the cells: every cell's best, then every cell's second, ...
            keep = np.lexsort((-response, rank))[: p.max_features]
            kps = [kps[i] for i in np.sort(keep)]
        return self._detector.compute(gray, kps)

    def _refine(
        self,
        P_cur: FloatArray,
        P_kf: FloatArray,
        R: FloatArray,
        t: FloatArray,
        w: FloatArray | None,
    ) -> tuple[FloatArray, FloatArray]:
        """ICP on the inlier points; kept only if it does not raise the residual."""
        p = self.params
        try:
            R_icp, t_icp, _, _ = icp_point_to_point(
                P_cur,
                P_kf,
                R,
                t,
                p.icp_max_iters,
                p.icp_tol_m,
                max_correspondence_m=p.ransac_threshold_m,
                weights=w,
            )
        except ValueError:
            return R, t

        def cost(R: FloatArray, t: FloatArray) -> float:
            e2 = np.minimum(np.sum((P_cur @ R.T + t - P_kf) ** 2, axis=1), p.ransac_threshold_m**2)
            return float(e2.sum() if w is None else w @ e2)

        return (R_icp, t_icp) if cost(R_icp, t_icp) <= cost(R, t) else (R, t)

    def _set_keyframe(
        self,
        pixels: FloatArray,
        desc: Descriptors,
        points: FloatArray,
        T_world_camera: FloatArray,
    ) -> None:
        self._keyframe = _Keyframe(T_world_camera.copy(), pixels, desc, points)
        self._last = self._keyframe
        self._T_world_kf = T_world_camera.copy()
        self._T_kf_curr = np.eye(4)

    def _lost_frame(
        self,
        status: VOStatus,
        pixels: FloatArray,
        desc: Descriptors,
        points: FloatArray,
        counts: dict[str, object],
    ) -> VOResult:
        """Report a failed frame; after too many in a row, restart from this one."""
        self._lost += 1
        if (
            self._lost > self.params.max_lost_frames
            and np.count_nonzero(np.all(np.isfinite(points), axis=1)) >= self.params.min_inliers
        ):
            self._lost = 0
            self._set_keyframe(pixels, desc, points, self.T_world_camera)
            return self._result(VOStatus.REINITIALISED, ok=False, keyframe=True, **counts)
        return self._result(status, ok=False, **counts)
