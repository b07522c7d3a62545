"""RGB-D visual odometry on frames rendered from a textured synthetic room."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter, map_coordinates
from scipy.spatial.transform import Rotation

from realitygap.estimators.base import CameraIntrinsics, Estimate, RGBDFrame
from realitygap.estimators.vo import (
    T_BASE_CAMERA_FORWARD,
    RGBDVisualOdometry,
    VOResult,
    planar_motion_from_camera,
)
from realitygap.estimators.vo_params import VOParams, VOStatus

# Kinect-V2-like field of view (70.6° horizontal) at 320 × 240.
INTRINSICS = CameraIntrinsics(width=320, height=240, fx=226.0, fy=226.0, cx=159.5, cy=119.5)
CAMERA_HEIGHT_M = 0.45
T_BASE_CAMERA = T_BASE_CAMERA_FORWARD.copy()
T_BASE_CAMERA[:3, 3] = [0.10, 0.0, CAMERA_HEIGHT_M]


# ---------------------------------------------------------------------------
# synthetic scene
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class TexturedPlane:
    """Rectangle ``origin + a·axis_a + b·axis_b``, 0 ≤ a ≤ size[0], 0 ≤ b ≤ size[1] (m)."""

    origin: tuple[float, float, float]
    axis_a: tuple[float, float, float]
    axis_b: tuple[float, float, float]
    size: tuple[float, float]
    texture_seed: int
    texel_m: float = 0.01


@cache
def _texture(seed: int) -> np.ndarray:
    """Blurred random texture with a few bright and dark blobs, values in [0, 255]."""
    rng = np.random.default_rng(seed)
    tex = gaussian_filter(rng.random((512, 512)), 2.0, mode="wrap")
    tex = (tex - tex.mean()) / tex.std()
    yy, xx = np.mgrid[0:512, 0:512]
    for _ in range(40):
        cy, cx, r = rng.uniform(0, 512), rng.uniform(0, 512), rng.uniform(4, 14)
        tex += rng.choice([-2.0, 2.0]) * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * r * r))
    return np.clip(128.0 + 40.0 * tex, 0.0, 255.0)


ROOM = (
    # back wall, 4.5 m ahead
    TexturedPlane((4.5, 3.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (6.0, 2.5), 1),
    # side walls
    TexturedPlane((-1.0, 2.2, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (5.5, 2.5), 2),
    TexturedPlane((-1.0, -2.2, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (5.5, 2.5), 3),
    # floor
    TexturedPlane((-1.0, -2.2, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (5.5, 4.4), 4),
    # a box in front of the back wall (depth discontinuities)
    TexturedPlane((2.5, -0.2, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (0.8, 0.7), 5),
    TexturedPlane((2.5, -0.2, 0.7), (0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.8, 0.6), 6),
)


def _ray_cast(
    T_world_camera: np.ndarray, u: np.ndarray, v: np.ndarray, intr: CameraIntrinsics
) -> tuple[np.ndarray, np.ndarray]:
    """Depth along the optical axis (inf for no hit) and intensity at pixel coords u, v."""
    d_cam = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)
    R, o = T_world_camera[:3, :3], T_world_camera[:3, 3]
    d = d_cam @ R.T  # world directions whose optical z component is 1
    depth = np.full(u.shape, np.inf)
    value = np.zeros(u.shape)
    for plane in ROOM:
        a_ax, b_ax = np.asarray(plane.axis_a), np.asarray(plane.axis_b)
        n = np.cross(a_ax, b_ax)
        p0 = np.asarray(plane.origin)
        denom = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((p0 - o) @ n) / denom
        hit = o + t[..., None] * d - p0
        a, b = hit @ a_ax, hit @ b_ax
        inside = (
            np.isfinite(t)
            & (t > 1e-6)
            & (a >= 0)
            & (a <= plane.size[0])
            & (b >= 0)
            & (b <= plane.size[1])
        )
        closer = inside & (t < depth)
        depth = np.where(closer, t, depth)
        tex = _texture(plane.texture_seed)
        sample = map_coordinates(
            tex, [b[closer] / plane.texel_m, a[closer] / plane.texel_m], order=1, mode="grid-wrap"
        )
        value[closer] = sample
    return depth, value


def render(T_world_camera: np.ndarray, intr: CameraIntrinsics = INTRINSICS) -> RGBDFrame:
    """RGB-D frame of :data:`ROOM`; intensity averaged over 2×2 sub-pixel rays."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width].astype(float)
    depth, _ = _ray_cast(T_world_camera, u, v, intr)
    grey = np.zeros_like(u)
    for du, dv in ((-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)):
        grey += 0.25 * _ray_cast(T_world_camera, u + du, v + dv, intr)[1]
    rgb = np.repeat(np.clip(np.rint(grey), 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    depth = np.where(np.isfinite(depth), depth, np.nan).astype(np.float32)
    return RGBDFrame(t=0.0, rgb=rgb, depth=depth, intrinsics=intr)


def T_world_camera_at(x: float, y: float, yaw: float) -> np.ndarray:
    """Camera pose for the base at planar pose (x, y, yaw)."""
    T_wb = np.eye(4)
    T_wb[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    T_wb[:3, 3] = [x, y, 0.0]
    return T_wb @ T_BASE_CAMERA


@cache
def frame_at(x: float, y: float, yaw: float) -> RGBDFrame:
    return render(T_world_camera_at(x, y, yaw))


def relative_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Translation error (m) and rotation error (rad) between two transforms."""
    E = np.linalg.inv(T_true) @ T_est
    angle = np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1))
    return float(np.linalg.norm(E[:3, 3])), float(angle)


def true_motion(
    pose_a: tuple[float, float, float], pose_b: tuple[float, float, float]
) -> np.ndarray:
    return np.linalg.inv(T_world_camera_at(*pose_a)) @ T_world_camera_at(*pose_b)


def make_vo(**overrides: object) -> RGBDVisualOdometry:
    vo = RGBDVisualOdometry(VOParams(**overrides), T_base_camera=T_BASE_CAMERA)  # type: ignore[arg-type]
    vo.reset(T_world_camera_at(0.0, 0.0, 0.0))
    return vo


def assert_finite_result(result: VOResult) -> None:
    for name in ("T_world_camera", "T_prev_curr", "T_world_keyframe", "pose"):
        assert np.all(np.isfinite(getattr(result, name))), name
    assert np.isfinite(result.rms_m)
    np.testing.assert_allclose(
        result.T_world_camera, result.T_world_keyframe @ result.T_prev_curr, atol=1e-12
    )


ORIGIN = (0.0, 0.0, 0.0)
SMALL_MOTIONS = [
    (0.03, 0.01, float(np.deg2rad(1.0))),
    (0.08, -0.02, float(np.deg2rad(-2.5))),
    (0.0, 0.0, float(np.deg2rad(4.0))),
]


# ---------------------------------------------------------------------------
# accuracy
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("pose", SMALL_MOTIONS)
def test_sift_recovers_small_motion(pose: tuple[float, float, float]) -> None:
    vo = make_vo()
    first = vo.update(frame_at(*ORIGIN))
    assert first.ok and first.status == VOStatus.INITIALISED and first.keyframe
    np.testing.assert_allclose(first.T_world_camera, T_world_camera_at(*ORIGIN), atol=1e-12)

    result = vo.update(frame_at(*pose))
    assert result.ok and result.status == "ok"
    assert_finite_result(result)
    err_t, err_r = relative_error(result.T_prev_curr, true_motion(ORIGIN, pose))
    assert err_t < 0.005
    assert err_r < np.deg2rad(0.2)
    # the planar base pose follows from the camera pose through the mounting
    np.testing.assert_allclose(result.pose, pose, atol=0.005)
    dx, dy, dth = planar_motion_from_camera(result.T_prev_curr, T_BASE_CAMERA)
    np.testing.assert_allclose([dx, dy, dth], pose, atol=0.005)
    assert result.n_inliers >= 50
    assert result.n_keypoints >= result.n_matches >= result.n_gtm >= result.n_depth
    assert result.n_depth >= result.n_inliers


def test_orb_recovers_small_motion() -> None:
    vo = make_vo(detector="orb")
    vo.update(frame_at(*ORIGIN))
    pose = SMALL_MOTIONS[1]
    result = vo.update(frame_at(*pose))
    assert result.ok
    err_t, err_r = relative_error(result.T_prev_curr, true_motion(ORIGIN, pose))
    assert err_t < 0.01
    assert err_r < np.deg2rad(0.5)


def with_depth_noise(frame: RGBDFrame, rng: np.random.Generator) -> RGBDFrame:
    """Kinect-like depth noise, σ = 1 cm at 2 m growing with z²."""
    depth = frame.depth.astype(float)
    depth += rng.normal(0.0, 1.0, depth.shape) * 0.01 * (depth / 2.0) ** 2
    return with_depth(frame, depth)


def test_depth_weighting_copes_with_depth_noise() -> None:
    # four noise draws per motion: one pair's error is itself noisy (±2 mm)
    errors = {}
    for weighting in (False, True):
        err = []
        for draw in range(1, 5):
            for pose in SMALL_MOTIONS:
                rng = np.random.default_rng(draw)
                vo = make_vo(depth_weighting=weighting, motion_solver="3d3d")
                vo.update(with_depth_noise(frame_at(*ORIGIN), rng))
                result = vo.update(with_depth_noise(frame_at(*pose), rng))
                assert result.ok
                err.append(relative_error(result.T_prev_curr, true_motion(ORIGIN, pose)))
        errors[weighting] = np.array(err)
    assert errors[True][:, 0].mean() < 0.005 and np.all(errors[True][:, 0] < 0.01)
    assert np.all(errors[True][:, 1] < np.deg2rad(0.2))
    assert errors[True][:, 0].mean() < 0.5 * errors[False][:, 0].mean()


def test_inlier_correspondences_agree_with_motion() -> None:
    vo = make_vo()
    vo.update(frame_at(*ORIGIN))
    result = vo.update(frame_at(*SMALL_MOTIONS[0]))
    n = result.n_inliers
    assert result.inlier_indices.shape == (n, 2)
    assert result.inlier_pixels_prev.shape == result.inlier_pixels_curr.shape == (n, 2)
    assert result.inlier_points_prev.shape == result.inlier_points_curr.shape == (n, 3)
    T = result.T_prev_curr
    moved = result.inlier_points_curr @ T[:3, :3].T + T[:3, 3]
    residual = np.linalg.norm(moved - result.inlier_points_prev, axis=1)
    assert np.all(residual < vo.params.ransac_threshold_m)
    assert result.rms_m == pytest.approx(np.sqrt(np.mean(residual**2)))
    # pixels are the projections of the points
    for pts, pix in (
        (result.inlier_points_prev, result.inlier_pixels_prev),
        (result.inlier_points_curr, result.inlier_pixels_curr),
    ):
        uv = pts[:, :2] / pts[:, 2:] * [INTRINSICS.fx, INTRINSICS.fy] + [
            INTRINSICS.cx,
            INTRINSICS.cy,
        ]
        np.testing.assert_allclose(uv, pix, atol=1e-6)


SEQUENCE = [(0.04 * i, 0.004 * i, float(np.deg2rad(1.2 * i))) for i in range(6)]


def test_sequence_chains_keyframes() -> None:
    vo = make_vo(keyframe_translation_m=0.07)
    results = [vo.update(frame_at(*pose)) for pose in SEQUENCE]
    assert all(r.ok for r in results)
    assert sum(r.keyframe for r in results) >= 3  # first frame + translation triggers
    for r, pose in zip(results, SEQUENCE):
        assert_finite_result(r)
        err_t, err_r = relative_error(r.T_world_camera, T_world_camera_at(*pose))
        assert err_t < 0.01
        assert err_r < np.deg2rad(0.3)
    # after a key-frame, the next motion is relative to it
    i = next(i for i, r in enumerate(results[1:], 1) if r.keyframe)
    np.testing.assert_allclose(
        results[i + 1].T_world_keyframe, results[i].T_world_camera, atol=1e-12
    )


def test_reset_restarts_from_given_pose() -> None:
    vo = make_vo()
    vo.update(frame_at(*ORIGIN))
    vo.update(frame_at(*SMALL_MOTIONS[0]))
    T0 = T_world_camera_at(1.0, 2.0, 0.5)
    state = vo.reset(T0)
    assert state.status == VOStatus.RESET and state.ok
    np.testing.assert_allclose(state.T_world_camera, T0)
    np.testing.assert_allclose(state.pose, [1.0, 2.0, 0.5], atol=1e-12)
    result = vo.update(frame_at(*ORIGIN))
    assert result.status == VOStatus.INITIALISED
    np.testing.assert_allclose(result.T_world_camera, T0)


def test_default_reset_puts_base_at_origin() -> None:
    vo = RGBDVisualOdometry(T_base_camera=T_BASE_CAMERA)
    state = vo.reset()
    np.testing.assert_allclose(state.T_world_camera, T_BASE_CAMERA)
    np.testing.assert_allclose(state.pose, np.zeros(3), atol=1e-12)


def test_to_estimate_follows_the_protocol_vocabulary() -> None:
    vo = make_vo()
    vo.update(frame_at(*ORIGIN))
    result = vo.update(frame_at(*SMALL_MOTIONS[0]))
    est = result.to_estimate()
    assert isinstance(est, Estimate)
    np.testing.assert_allclose(est.pose, result.pose)
    assert est.ok and est.status == "ok" and est.extras["vo"] is result


# ---------------------------------------------------------------------------
# failure modes: never raise, never NaN
# ---------------------------------------------------------------------------


def blank_frame(value: int = 128) -> RGBDFrame:
    rgb = np.full((INTRINSICS.height, INTRINSICS.width, 3), value, dtype=np.uint8)
    depth = np.full((INTRINSICS.height, INTRINSICS.width), 2.0, dtype=np.float32)
    return RGBDFrame(t=0.0, rgb=rgb, depth=depth, intrinsics=INTRINSICS)


def with_depth(frame: RGBDFrame, depth: np.ndarray) -> RGBDFrame:
    return RGBDFrame(
        t=frame.t, rgb=frame.rgb, depth=depth.astype(np.float32), intrinsics=frame.intrinsics
    )


@pytest.mark.parametrize("detector", ["sift", "orb"])
def test_blank_frame_reports_no_features(detector: str) -> None:
    vo = make_vo(detector=detector)
    assert vo.update(blank_frame()).status == VOStatus.NO_FEATURES  # before the first key-frame
    vo.update(frame_at(*ORIGIN))
    result = vo.update(blank_frame())
    assert not result.ok and result.status == "no_features"
    assert result.n_keypoints < vo.params.min_keypoints
    assert_finite_result(result)
    np.testing.assert_allclose(result.T_world_camera, T_world_camera_at(*ORIGIN), atol=1e-12)
    # tracking resumes against the same key-frame
    again = vo.update(frame_at(*SMALL_MOTIONS[0]))
    assert again.ok
    assert relative_error(again.T_prev_curr, true_motion(ORIGIN, SMALL_MOTIONS[0]))[0] < 0.005


def test_no_frame_keeps_last_estimate() -> None:
    vo = make_vo()
    vo.update(frame_at(*ORIGIN))
    good = vo.update(frame_at(*SMALL_MOTIONS[0]))
    result = vo.update(None)
    assert not result.ok and result.status == VOStatus.NO_FRAME
    np.testing.assert_allclose(result.T_world_camera, good.T_world_camera)
    assert_finite_result(result)


def test_missing_depth_reports_depth_holes() -> None:
    vo = make_vo()
    no_depth = np.full((INTRINSICS.height, INTRINSICS.width), np.nan)
    first = vo.update(with_depth(frame_at(*ORIGIN), no_depth))
    assert not first.ok and first.status == VOStatus.DEPTH_HOLES  # cannot start a map
    vo.update(frame_at(*ORIGIN))
    result = vo.update(with_depth(frame_at(*SMALL_MOTIONS[0]), no_depth))
    assert not result.ok and result.status == "depth_holes"
    assert result.n_matches > 0 and result.n_depth == 0
    assert_finite_result(result)


def test_large_depth_holes_are_tolerated() -> None:
    """Only 35 % of the depth survives (a hole over the left 60 % and noise
    speckle); the motion is still recovered from the rest."""
    rng = np.random.default_rng(3)
    frame = frame_at(*SMALL_MOTIONS[0])
    depth = frame.depth.astype(float)
    depth[:, : int(0.6 * INTRINSICS.width)] = np.nan
    depth[rng.random(depth.shape) < 0.1] = np.nan
    depth[rng.random(depth.shape) < 0.02] = 0.2  # below the valid range
    vo = make_vo()
    vo.update(frame_at(*ORIGIN))
    result = vo.update(with_depth(frame, depth))
    assert result.ok
    assert result.n_depth < 0.6 * result.n_gtm
    err_t, err_r = relative_error(result.T_prev_curr, true_motion(ORIGIN, SMALL_MOTIONS[0]))
    # from 35 % of the depth one pair is good to a few mm (2–8 mm over hole patterns)
    assert err_t < 0.01
    assert err_r < np.deg2rad(0.3)


def test_unrelated_scene_is_lost_then_reinitialised() -> None:
    rng = np.random.default_rng(7)
    noise = gaussian_filter(rng.random((INTRINSICS.height, INTRINSICS.width)), 1.5)
    grey = np.clip(128 + 60 * (noise - noise.mean()) / noise.std(), 0, 255).astype(np.uint8)
    other = RGBDFrame(
        t=1.0,
        rgb=np.repeat(grey[..., None], 3, axis=2),
        depth=np.full(grey.shape, 2.0, dtype=np.float32),
        intrinsics=INTRINSICS,
    )
    vo = make_vo(max_lost_frames=2)
    vo.update(frame_at(*ORIGIN))
    statuses = [vo.update(other) for _ in range(4)]
    assert [r.ok for r in statuses] == [False, False, False, True]
    assert {r.status for r in statuses[:2]} <= {"too_few_matches", "ransac_failed"}
    assert statuses[2].status == VOStatus.REINITIALISED and statuses[2].keyframe
    assert statuses[3].status == "ok"  # tracking the new key-frame
    for r in statuses:
        assert_finite_result(r)
        np.testing.assert_allclose(r.T_world_camera, T_world_camera_at(*ORIGIN), atol=1e-9)


# ---------------------------------------------------------------------------
# planar motion and input checks
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(5))
def test_planar_motion_inverts_mounting(seed: int) -> None:
    rng = np.random.default_rng(seed)
    dx, dy, dth = rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-np.pi, np.pi)
    T_bb = np.eye(4)
    T_bb[:3, :3] = Rotation.from_euler("z", dth).as_matrix()
    T_bb[:3, 3] = [dx, dy, 0.0]
    T_bc = np.eye(4)
    T_bc[:3, :3] = (
        Rotation.from_euler("xyz", rng.uniform(-0.2, 0.2, 3)).as_matrix()
        @ T_BASE_CAMERA_FORWARD[:3, :3]
    )
    T_bc[:3, 3] = rng.uniform(-0.3, 0.3, 3)
    T_cc = np.linalg.inv(T_bc) @ T_bb @ T_bc
    np.testing.assert_allclose(planar_motion_from_camera(T_cc, T_bc), [dx, dy, dth], atol=1e-12)


def test_planar_motion_default_mount_forward_is_optical_z() -> None:
    T_cc = np.eye(4)
    T_cc[2, 3] = 0.3  # camera moves along its optical axis
    np.testing.assert_allclose(planar_motion_from_camera(T_cc), [0.3, 0.0, 0.0], atol=1e-15)


def test_planar_motion_rejects_non_rigid() -> None:
    with pytest.raises(ValueError, match=r"T_prev_curr\[:3, :3\] must be a proper rotation"):
        planar_motion_from_camera(np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match=r"T_prev_curr must have shape \(4, 4\)"):
        planar_motion_from_camera(np.eye(3))


def test_params_are_validated() -> None:
    with pytest.raises(ValueError, match="detector must be one of 'sift', 'orb', got 'surf'"):
        VOParams(detector="surf")
    with pytest.raises(ValueError, match=r"ratio must lie in \(0, 1\]"):
        VOParams(ratio=1.5)
    with pytest.raises(ValueError, match="min_inliers must be ≥ 3"):
        VOParams(min_inliers=2)
    with pytest.raises(ValueError, match="need 0 < depth_min_m < depth_max_m"):
        VOParams(depth_min_m=3.0, depth_max_m=2.0)
    assert VOParams(detector="ORB").detector == "orb"
    with pytest.raises(TypeError, match="params must be a VOParams"):
        RGBDVisualOdometry(params={"detector": "orb"})  # type: ignore[arg-type]


def test_malformed_frames_raise() -> None:
    vo = make_vo()
    good = frame_at(*ORIGIN)
    with pytest.raises(
        ValueError, match=r"frame.depth must have shape \(240, 320\), got \(10, 10\)"
    ):
        vo.update(RGBDFrame(0.0, good.rgb, np.zeros((10, 10), np.float32), INTRINSICS))
    with pytest.raises(ValueError, match=r"frame\.rgb must be uint8"):
        vo.update(RGBDFrame(0.0, good.rgb.astype(float), good.depth, INTRINSICS))  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="frame must be an RGBDFrame or None"):
        vo.update(good.rgb)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"T_base_camera\[:3, :3\] must be a proper rotation"):
        RGBDVisualOdometry(T_base_camera=np.diag([2.0, 1.0, 1.0, 1.0]))


@pytest.mark.slow
def test_lost_keyframe_falls_back_to_the_previous_frame_and_says_so() -> None:
    # key-frames never renew on their own: only the fallback can carry the turn
    vo = make_vo(keyframe_translation_m=10.0, keyframe_rotation_rad=3.0, keyframe_min_inliers=0)
    yaws = np.deg2rad(np.arange(0.0, 81.0, 8.0))
    results = [vo.update(frame_at(0.0, 0.0, float(yaw))) for yaw in yaws]
    assert all(r.ok for r in results), [r.status for r in results]
    fallbacks = [r for r in results if r.reference == "previous_frame"]
    assert fallbacks and all(r.keyframe for r in fallbacks)
    assert all(r.reference == "keyframe" for r in results[:3])
    err_t, err_r = relative_error(results[-1].T_world_camera, T_world_camera_at(0, 0, yaws[-1]))
    # chained 8° steps drift a little; a wrongly composed fallback is off by the step itself
    assert err_t < 0.1 and err_r < np.deg2rad(2.0), (err_t, np.rad2deg(err_r))


def test_bucketed_features_spread_over_the_image() -> None:
    frame = frame_at(*ORIGIN)
    gray = frame.rgb if frame.rgb.ndim == 2 else frame.rgb.mean(axis=2).astype(np.uint8)
    spread = {}
    for grid in (None, (8, 6)):
        vo = make_vo(detector="orb", max_features=200, bucket_grid=grid)
        kps, desc = vo._detect(np.ascontiguousarray(gray))
        assert len(kps) == len(desc) <= 200
        pts = np.array([k.pt for k in kps])
        cells = {(int(u * 4 / 320), int(v * 3 / 240)) for u, v in pts}
        spread[grid] = len(cells)
    assert spread[(8, 6)] >= spread[None]
    with pytest.raises(ValueError, match="bucket_grid must be None or two positive"):
        VOParams(bucket_grid=(0, 4))
    with pytest.raises(ValueError, match="motion_solver must be"):
        VOParams(motion_solver="icp")


@pytest.mark.parametrize("solver", ["ml", "3d3d", "pnp"])
def test_every_motion_solver_recovers_a_small_motion(solver: str) -> None:
    vo = make_vo(motion_solver=solver)
    vo.update(frame_at(*ORIGIN))
    for pose in SMALL_MOTIONS:
        result = vo.update(frame_at(*pose))
        assert result.ok, result.status
        err_t, err_r = relative_error(result.T_prev_curr, true_motion(ORIGIN, pose))
        assert err_t < 0.01 and err_r < np.deg2rad(0.3), (solver, pose, err_t, err_r)


def test_every_motion_carries_its_covariance_from_its_inliers() -> None:
    vo = make_vo(keyframe_translation_m=0.07)
    results = [vo.update(frame_at(*pose)) for pose in SEQUENCE]
    assert results[0].motion_cov is None  # the first frame has no motion
    for r in results[1:]:
        assert r.ok and r.motion_cov is not None and r.motion_cov.shape == (6, 6)
        eig = np.linalg.eigvalsh(r.motion_cov)
        assert np.all(eig > 0)
        # millimetres and tenths of a degree for a textured view at 1–3 m
        assert np.sqrt(np.max(np.diag(r.motion_cov)[3:])) < 0.01
        assert np.sqrt(np.max(np.diag(r.motion_cov)[:3])) < np.deg2rad(0.5)
    pnp = make_vo(motion_solver="pnp")
    pnp.update(frame_at(*ORIGIN))
    moved = pnp.update(frame_at(*SMALL_MOTIONS[0]))
    assert moved.ok and moved.motion_cov is None  # PnP's motion comes without one


def _shifted_view(shift_px: float) -> np.ndarray:
    """320 × 240 grey view of a texture moved left by ``shift_px`` (cubic resampling)."""
    v, u = np.mgrid[0:240, 0:320].astype(float)
    img = map_coordinates(_texture(1), [v + 100.0, u + 20.0 + shift_px], order=3, mode="grid-wrap")
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def test_orb_pyramid_keypoints_move_with_the_image() -> None:
    # An image moved by t pixels moves every keypoint by t. ORB's level L has
    # round(320 / 1.2**L) columns, not 320 / 1.2**L, so a position reported as
    # x_L·1.2**L carries a per-level scale error (+0.125 % at level 1, −0.10 % at
    # levels 2–3, −0.21 % at level 4): over a 120 px shift, −0.15…+0.25 px. Shifts
    # spread over 8.9 px average out each level's pixel quantisation.
    vo = make_vo(detector="orb", max_features=1000)
    ref = _shifted_view(0.0)
    k_ref, d_ref = vo._detect(ref)
    level_ref = np.array([k.octave for k in k_ref])
    fixed: dict[int, list[float]] = {1: [], 2: [], 3: []}
    raw: dict[int, list[float]] = {1: [], 2: [], 3: []}
    for t in 120.0 + 0.37 * np.arange(24):
        img = _shifted_view(t)
        kps, desc = vo._detect(img)
        i_ref, i_cur = vo._match(d_ref, desc)
        same = level_ref[i_ref] == np.array([k.octave for k in kps])[i_cur]
        for out, p_ref, p_cur in (
            (fixed, vo._keypoint_pixels(k_ref, ref.shape), vo._keypoint_pixels(kps, img.shape)),
            (raw, np.array([k.pt for k in k_ref]), np.array([k.pt for k in kps])),
        ):
            d = p_cur[i_cur] - p_ref[i_ref] + [t, 0.0]
            ok = same & np.all(np.abs(d) < 1.5, axis=1)
            for level, errors in out.items():
                errors.extend(d[ok & (level_ref[i_ref] == level), 0])
    for level in (1, 2, 3):
        assert len(fixed[level]) > 300, level
        assert abs(np.mean(fixed[level])) < 0.06, (level, np.mean(fixed[level]))
    # the detector's own positions carry the bias this mapping removes
    assert max(abs(np.mean(raw[level])) for level in (1, 2, 3)) > 0.09
