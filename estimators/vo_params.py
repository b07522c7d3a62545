"""Settings and status codes of the RGB-D visual odometry (:mod:`realitygap.estimators.vo`)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

__all__ = ["Detector", "VOParams", "VOStatus"]


class VOStatus(str, Enum):
    """Outcome of one :meth:`RGBDVisualOdometry.update`."""

    OK = "ok"
    """Motion estimated."""
    INITIALISED = "initialised"
    """First usable frame: it became the first key-frame."""
    RESET = "reset"
    """State after :meth:`RGBDVisualOdometry.reset`; no frame seen yet."""
    NO_FRAME = "no_frame"
    """``update(None)``: nothing measured this step."""
    NO_FEATURES = "no_features"
    """Too few keypoints (blank or blurred image)."""
    TOO_FEW_MATCHES = "too_few_matches"
    """Too few descriptor matches with the key-frame, or too few after GTM."""
    DEPTH_HOLES = "depth_holes"
    """Too few matched keypoints with valid depth."""
    RANSAC_FAILED = "ransac_failed"
    """No rigid motion explains enough matches."""
    REINITIALISED = "reinitialised"
    """Tracking was lost for too long; this frame starts a new key-frame at the
    last good pose (the motion since then is unknown)."""


class Detector(str, Enum):
    """Keypoint detector and descriptor."""

    SIFT = "sift"
    ORB = "orb"


@dataclass(frozen=True)
class VOParams:
    r"""Settings of :class:`RGBDVisualOdometry`.

    Attributes
    ----------
    detector : {"sift", "orb"}
        SIFT (128-D float descriptors, L2 matching) or ORB (256-bit binary,
        Hamming matching).
    max_features : int
        Keypoints kept per frame.
    ratio : float
        Lowe ratio test: keep a match when its distance is below ``ratio`` times
        the second-best.
    min_keypoints : int
        Fewer keypoints make the frame ``no_features``.
    min_matches : int
        Fewer matches after the ratio test (or after GTM) make the frame
        ``too_few_matches``.
    use_gtm : bool
        Reject outliers with :func:`.gtm_filter` before RANSAC.
    gtm_k : int or None
        ``k`` of the GTM graph (``None``: mean-distance radius graph).
    gtm_tolerance : float
        Dead band of the radius graph (see :func:`.gtm_filter`).
    ransac_threshold_m : float
        RANSAC inlier distance [m].
    ransac_max_iters : int
        RANSAC hypothesis cap.
    min_inliers : int
        Fewest RANSAC inliers for a valid motion.
    depth_weighting : bool
        Weight each correspondence in the refits by its inverse depth variance,
        :math:`w_i = 1 / (z_{i,\mathrm{prev}}^4 + z_{i,\mathrm{curr}}^4)`, for the
        :math:`\sigma_z \propto z^2` noise of RGB-D sensors.
    use_icp : bool
        Refine the RANSAC motion with point-to-point ICP on the inlier points.
    bucket_grid : tuple of int or None
        ``(columns, rows)`` of a grid over the image: from four times
        ``max_features`` candidates (twice for SIFT), each cell's strongest are
        kept in turn, so features spread over the image; ``None``: the
        detector's own ``max_features`` strongest.
    motion_solver : {"ml", "pnp", "3d3d"}
        ``"ml"`` (default): RANSAC over weighted Kabsch fits selects the inliers,
        then Gauss–Newton on SE(3) minimises the Mahalanobis distance of each
        pair under its anisotropic covariance — ``pixel_sigma_px`` across the
        viewing ray, ``σ_z = depth_sigma_a_m + depth_sigma_b_per_m·z²`` along it,
        in both frames — the maximum-likelihood motion for an RGB-D sensor
        (lateral and vertical motion and the rotation come from the pixels, the
        forward motion from the near, precise depths).
        ``"pnp"``: the key-frame's 3-D points against the current frame's pixels
        (EPnP in RANSAC, then Levenberg–Marquardt on the reprojection error of
        the inliers); the current frame's depth only selects the pairs, so its
        noise (σ ∝ z²) does not enter the motion and the rotation is as precise
        as the keypoints. ``"3d3d"``: weighted Kabsch fits in RANSAC and ICP on
        the points of both frames.
    pnp_reprojection_px : float
        Inlier threshold of the PnP RANSAC, pixels.
    pixel_sigma_px : float
        Keypoint position noise (``"ml"``), pixels.
    depth_sigma_a_m, depth_sigma_b_per_m : float
        Depth noise model of the ``"ml"`` solver, m and 1/m.
    icp_max_iters : int
        ICP iteration cap.
    icp_tol_m : float
        ICP stopping RMS change [m].
    keyframe_min_inliers : int
        Start a new key-frame when fewer inliers than this remain.
    keyframe_translation_m : float
        Start a new key-frame after this camera translation [m] from the last.
    keyframe_rotation_rad : float
        Start a new key-frame after this camera rotation [rad] from the last.
    depth_min_m, depth_max_m : float
        Valid depth range [m] (Kinect V2: 0.5–8 m).
    depth_edge_ratio : float
        Reject a keypoint when its 2×2 depth neighbourhood spreads by more than
        this fraction of its depth (depth discontinuity).
    max_lost_frames : int
        After this many consecutive failed frames that still had features, the
        next such frame becomes a new key-frame (status ``reinitialised``).
    seed : int
        Seed of the RANSAC sampler (reset with :meth:`RGBDVisualOdometry.reset`).
    """

    detector: Detector | str = Detector.ORB
    max_features: int = 500
    ratio: float = 0.75
    min_keypoints: int = 10
    min_matches: int = 8
    use_gtm: bool = True
    gtm_k: int | None = None
    gtm_tolerance: float = 0.05
    ransac_threshold_m: float = 0.04
    ransac_max_iters: int = 300
    min_inliers: int = 8
    depth_weighting: bool = True
    use_icp: bool = True
    bucket_grid: tuple[int, int] | None = (8, 6)
    motion_solver: str = "ml"
    pnp_reprojection_px: float = 2.0
    pixel_sigma_px: float = 0.5
    depth_sigma_a_m: float = 0.001
    depth_sigma_b_per_m: float = 0.002
    icp_max_iters: int = 20
    icp_tol_m: float = 1e-5
    keyframe_min_inliers: int = 60
    keyframe_translation_m: float = 0.25
    keyframe_rotation_rad: float = float(np.deg2rad(15.0))
    depth_min_m: float = 0.5
    depth_max_m: float = 8.0
    depth_edge_ratio: float = 0.05
    max_lost_frames: int = 5
    seed: int = 0

    def __post_init__(self) -> None:
        try:
            object.__setattr__(
                self,
                "detector",
                Detector(str(getattr(self.detector, "value", self.detector)).lower()),
            )
        except ValueError:
            names = ", ".join(repr(d.value) for d in Detector)
            raise ValueError(f"detector must be one of {names}, got {self.detector!r}") from None
        positive_ints = (
            "max_features",
            "min_keypoints",
            "min_matches",
            "ransac_max_iters",
            "icp_max_iters",
        )
        for name in positive_ints:
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be ≥ 1, got {getattr(self, name)}")
        if self.min_inliers < 3:
            raise ValueError(f"min_inliers must be ≥ 3, got {self.min_inliers}")
        if not 0.0 < self.ratio <= 1.0:
            raise ValueError(f"ratio must lie in (0, 1], got {self.ratio}")
        if self.gtm_k is not None and self.gtm_k < 1:
            raise ValueError(f"gtm_k must be ≥ 1 or None, got {self.gtm_k}")
        if not 0.0 <= self.gtm_tolerance < 1.0:
            raise ValueError(f"gtm_tolerance must lie in [0, 1), got {self.gtm_tolerance}")
        for name in ("ransac_threshold_m", "keyframe_translation_m", "keyframe_rotation_rad"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0.0 < self.depth_min_m < self.depth_max_m:
            raise ValueError(
                f"need 0 < depth_min_m < depth_max_m, got {self.depth_min_m} and {self.depth_max_m}"
            )
        if not self.depth_edge_ratio > 0.0:
            raise ValueError(f"depth_edge_ratio must be > 0, got {self.depth_edge_ratio}")
        if self.bucket_grid is not None and (
            len(self.bucket_grid) != 2 or min(self.bucket_grid) < 1
        ):
            raise ValueError(
                f"bucket_grid must be None or two positive cell counts, got {self.bucket_grid!r}"
            )
        if self.motion_solver not in ("ml", "pnp", "3d3d"):
            raise ValueError(
                f"motion_solver must be 'ml', 'pnp' or '3d3d', got {self.motion_solver!r}"
            )
        if not (
            self.pixel_sigma_px > 0 and self.depth_sigma_a_m > 0 and self.depth_sigma_b_per_m >= 0
        ):
            raise ValueError(
                "need pixel_sigma_px > 0, depth_sigma_a_m > 0 and depth_sigma_b_per_m >= 0, got "
                f"{self.pixel_sigma_px}, {self.depth_sigma_a_m}, {self.depth_sigma_b_per_m}"
            )
        if not self.pnp_reprojection_px > 0.0:
            raise ValueError(f"pnp_reprojection_px must be > 0, got {self.pnp_reprojection_px}")
        if self.icp_tol_m < 0.0 or self.max_lost_frames < 0 or self.keyframe_min_inliers < 0:
            raise ValueError("icp_tol_m, max_lost_frames and keyframe_min_inliers must be ≥ 0")
