"""Laser-like scans from depth images, checked against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.estimators.base import CameraIntrinsics, Scan
from realitygap.estimators.scan import beam_window, scan_angles, scan_from_depth
from realitygap.estimators.vo import T_BASE_CAMERA_FORWARD

INTR = CameraIntrinsics(width=320, height=240, fx=226.0, fy=226.0, cx=159.5, cy=119.5)
HFOV = 2.0 * np.arctan(160.0 / 226.0)  # ≈ 70.6°
HEIGHT_M = 0.4  # camera height above the floor


def mount(x: float = 0.0, y: float = 0.0, z: float = HEIGHT_M, yaw: float = 0.0) -> np.ndarray:
    """Level camera looking along base x rotated by ``yaw``, at (x, y, z) in the base."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix() @ T_BASE_CAMERA_FORWARD[:3, :3]
    T[:3, 3] = [x, y, z]
    return T


def pixel_rays() -> tuple[np.ndarray, np.ndarray]:
    v, u = np.mgrid[0 : INTR.height, 0 : INTR.width].astype(float)
    return (u - INTR.cx) / INTR.fx, (v - INTR.cy) / INTR.fy


def wall_depth(distance_ahead: float) -> np.ndarray:
    """A level camera facing a wall perpendicular to its axis sees constant depth."""
    return np.full((INTR.height, INTR.width), distance_ahead, dtype=np.float32)


def floor_depth(height: float = HEIGHT_M) -> np.ndarray:
    """Level camera at ``height`` over an infinite floor: depth = h / y_n below the horizon."""
    _, yn = pixel_rays()
    with np.errstate(divide="ignore"):
        depth = np.where(yn > 0, height / np.where(yn > 0, yn, 1.0), np.nan)
    return depth.astype(np.float32)


@pytest.mark.parametrize("distance", [0.8, 2.0, 5.5])
@pytest.mark.parametrize("n_beams", [31, 120])
def test_wall_ahead_gives_closed_form_ranges(distance: float, n_beams: int) -> None:
    """Wall x_b = d: a beam at bearing φ with window w reports d / cos(min |φ'|) over
    φ' ∈ [φ − w, φ + w], to within the pixel spacing."""
    offset = 0.12  # camera ahead of the base origin
    fov = np.deg2rad(60.0)  # inside the camera's view of the wall from the base origin
    scan = scan_from_depth(
        wall_depth(distance - offset), INTR, mount(x=offset), (0.05, 1.0), n_beams, fov
    )
    angles = scan_angles(n_beams, fov)
    w = beam_window(n_beams, fov, INTR.fx)
    expected = distance / np.cos(np.maximum(np.abs(angles) - w, 0.0))
    pixel_m = (distance - offset) / INTR.fx
    assert np.all(np.isfinite(scan.ranges))
    assert np.all(scan.ranges >= expected - 1e-5)
    np.testing.assert_allclose(scan.ranges, expected, atol=pixel_m * 1.5)
    np.testing.assert_allclose(scan.angles, angles, atol=1e-15)


@pytest.mark.parametrize("incidence_deg", [0.0, 45.0, 70.0, 80.0])
def test_a_slanted_wall_is_ranged_along_each_beam(incidence_deg: float) -> None:
    """A wall seen at a slant: every beam reports the range along its own bearing (the
    closed-form ray-plane intersection), not the nearest pixel of a wedge in front of it —
    which lies up to ``r · tan(incidence) · spacing / 2`` short at the wedge's edge."""
    xn, _ = pixel_rays()
    # wall through (d, 0) in the base frame with normal n at `incidence` from base x
    d, inc = 3.0, np.deg2rad(incidence_deg)
    n = np.array([np.cos(inc), np.sin(inc)])
    # optical frame: x right (= -y_b), z forward (= x_b); depth z where the ray meets it
    depth = (d * n[0]) / (n[0] * 1.0 + n[1] * (-xn))
    depth = np.where(depth > 0, depth, np.nan).astype(np.float32)
    n_beams, fov = 64, np.deg2rad(60.0)
    scan = scan_from_depth(depth, INTR, mount(), (0.05, 1.0), n_beams, fov)
    bearing = scan.angles
    truth = d * n[0] / (n[0] * np.cos(bearing) + n[1] * np.sin(bearing))
    ok = np.isfinite(truth) & (truth > 0) & (truth < 8.0)
    # what is left: the window's half-width (a pixel or two) times the range's slope
    slope = truth * np.abs(np.tan(bearing - inc))
    window = beam_window(n_beams, fov, INTR.fx)
    tolerance = slope * window + 2.0 * truth / INTR.fx
    assert np.all(truth[ok] - scan.ranges[ok] <= tolerance[ok] + 1e-4)
    assert np.all(scan.ranges[ok] <= truth[ok] + 2.0 * truth[ok] / INTR.fx + 1e-4)
    # the wedge's error would have been larger wherever the wall is slanted
    spacing = fov / (n_beams - 1)
    if incidence_deg >= 45.0:
        assert np.median((truth - scan.ranges)[ok]) < 0.5 * np.median((slope * spacing / 2)[ok])


def test_noisy_depth_gives_unbiased_ranges() -> None:
    """σ(z) = a + b z²: the nearest of many noisy pixels lies ~2.5 σ short; the beams
    report the surface to within a few tenths of σ."""
    a, b = 0.001, 0.002
    distance = 6.0
    rng = np.random.default_rng(3)
    clean = wall_depth(distance).astype(np.float64)
    sigma = a + b * distance**2
    depth = (clean + rng.normal(0.0, sigma, clean.shape)).astype(np.float32)
    fov = np.deg2rad(40.0)
    plain = scan_from_depth(depth, INTR, mount(), (0.05, 1.0), 32, fov)
    aware = scan_from_depth(depth, INTR, mount(), (0.05, 1.0), 32, fov, depth_noise=(a, b))
    truth = distance / np.cos(plain.angles)
    assert np.median(truth - plain.ranges) > 1.5 * sigma  # the nearest pixel is biased
    assert abs(np.median(truth - aware.ranges)) < 0.5 * sigma


def test_an_obstacle_inside_the_blind_zone_is_reported() -> None:
    """Pixels whose ray should meet the floor beyond depth_min but return nothing are
    blocked nearer than depth_min: their beams report the range at depth_min."""
    depth_min = 0.5
    floor = floor_depth()
    depth = np.where(floor >= depth_min, floor, np.nan).astype(np.float32)
    free = scan_from_depth(depth, INTR, mount(), (0.05, 1.0), 32, depth_min=depth_min)
    assert np.all(np.isinf(free.ranges))  # the floor alone: nothing in the band
    # a box nearer than depth_min fills the left third of the picture: no return there
    blocked = depth.copy()
    blocked[:, : INTR.width // 3] = np.nan
    scan = scan_from_depth(blocked, INTR, mount(), (0.05, 1.0), 32, depth_min=depth_min)
    left = scan.angles > np.arctan(((INTR.width / 3 - INTR.cx) * -1.0) / INTR.fx) + 0.02
    assert np.all(np.isfinite(scan.ranges[left]))
    # the point at depth depth_min on a ray at bearing φ lies depth_min / cos φ away
    assert np.all(scan.ranges[left] <= depth_min / np.cos(scan.angles[left]) + 1e-4)
    right = scan.angles < -0.05
    assert np.all(np.isinf(scan.ranges[right]))
    # without the blind zone the same picture shows nothing at all (the old failure)
    blind = scan_from_depth(blocked, INTR, mount(), (0.05, 1.0), 32)
    assert np.all(np.isinf(blind.ranges))


def test_height_band_excludes_the_floor() -> None:
    floor = floor_depth()
    above = scan_from_depth(floor, INTR, mount(), z_band=(0.05, 1.0))
    assert np.all(np.isinf(above.ranges))
    # a band reaching down to the floor sees it, no nearer than the bottom image row allows
    with_floor = scan_from_depth(floor, INTR, mount(), z_band=(-0.01, 1.0))
    nearest_floor = HEIGHT_M / ((INTR.height - 1 - INTR.cy) / INTR.fy)
    finite = np.isfinite(with_floor.ranges)
    assert finite.mean() > 0.9
    assert np.all(with_floor.ranges[finite] >= nearest_floor - 1e-5)


def test_wall_and_floor_sees_only_the_wall() -> None:
    distance = 2.0
    depth = np.fmin(floor_depth(), wall_depth(distance))  # whichever the ray hits first
    scan = scan_from_depth(depth, INTR, mount(), (0.05, 1.0), 1, np.deg2rad(1.0))
    assert scan.ranges[0] == pytest.approx(distance, abs=distance / INTR.fx)


def test_obstacles_above_the_band_are_ignored() -> None:
    """A shelf whose underside is above the robot does not block the scan."""
    _, yn = pixel_rays()
    depth = wall_depth(3.0).astype(float)
    shelf = (yn < 0) & (yn > -0.3)  # 1.5 m ahead, above the camera
    depth[shelf] = 1.5
    top = HEIGHT_M - 1.5 * yn[shelf].max()  # lowest shelf point's height
    low = scan_from_depth(depth, INTR, mount(), z_band=(0.05, top - 0.01), n_beams=9)
    tall = scan_from_depth(depth, INTR, mount(), z_band=(0.05, 2.0), n_beams=9)
    assert np.all(low.ranges > 2.9)
    assert np.all(tall.ranges < 2.0)  # the shelf plane, 1.5 / cos(bearing)
    assert tall.ranges[4] == pytest.approx(1.5, abs=1e-3)


def test_yawed_camera_shifts_the_scan() -> None:
    """Rotating the mount by whole beams rolls the ranges by as many beams."""
    n_beams, fov, shift = 72, 2 * np.pi, 5
    step = fov / n_beams
    depth = wall_depth(2.0)
    a = scan_from_depth(depth, INTR, mount(z=0.3), (0.05, 1.0), n_beams, fov)
    b = scan_from_depth(depth, INTR, mount(z=0.3, yaw=shift * step), (0.05, 1.0), n_beams, fov)
    seen = np.isfinite(a.ranges) & np.isfinite(np.roll(a.ranges, shift))
    interior = seen & np.roll(seen, 1) & np.roll(seen, -1)  # away from the view's edges
    np.testing.assert_allclose(b.ranges[np.roll(interior, shift)], a.ranges[interior], rtol=1e-3)


def test_invalid_depth_is_ignored() -> None:
    depth = wall_depth(2.0).astype(float)
    depth[:, :100] = np.nan
    depth[:, 100:120] = np.inf
    depth[:, 120:140] = 0.0
    depth[:, 140:160] = -1.0
    scan = scan_from_depth(depth, INTR, mount(), (0.05, 1.0))
    assert not np.any(np.isnan(scan.ranges))
    clean = scan_from_depth(wall_depth(2.0), INTR, mount(), (0.05, 1.0))
    right = scan.angles < -0.05  # image columns ≥ 160 look to the right
    np.testing.assert_allclose(scan.ranges[right], clean.ranges[right])
    assert np.all(np.isinf(scan.ranges[scan.angles > 0.05]))


def test_range_limits() -> None:
    near = scan_from_depth(wall_depth(1.0), INTR, mount(), (0.05, 1.0), range_min=1.5)
    assert np.all(np.isinf(near.ranges))
    far = scan_from_depth(wall_depth(6.0), INTR, mount(), (0.05, 1.0), range_max=5.0)
    assert np.all(np.isinf(far.ranges))
    assert far.range_max == 5.0 and near.range_min == 1.5


def test_precision_does_not_depend_on_input_dtype() -> None:
    depth = floor_depth() + np.float32(0.0)
    depth = np.fmin(depth, wall_depth(3.0))
    a = scan_from_depth(depth, INTR, mount(), (-0.01, 1.0), t=2.5)
    b = scan_from_depth(depth.astype(np.float64), INTR, mount(), (-0.01, 1.0))
    np.testing.assert_allclose(a.ranges, b.ranges, rtol=1e-6)
    assert isinstance(a, Scan) and a.t == 2.5 and a.ranges.dtype == np.float64


def test_scan_angles() -> None:
    np.testing.assert_allclose(
        scan_angles(4, np.pi), [-np.pi / 2, -np.pi / 6, np.pi / 6, np.pi / 2]
    )
    np.testing.assert_allclose(scan_angles(4, 2 * np.pi), [-np.pi, -np.pi / 2, 0.0, np.pi / 2])
    np.testing.assert_allclose(scan_angles(1, 1.0), [0.0])


def test_errors() -> None:
    depth = wall_depth(2.0)
    T = mount()
    with pytest.raises(
        ValueError, match=r"depth must have shape \(240, 320\) \(height, width\), got \(320, 240\)"
    ):
        scan_from_depth(depth.T, INTR, T)
    with pytest.raises(TypeError, match="convert raw millimetres"):
        scan_from_depth((depth * 1000).astype(np.uint16), INTR, T)
    with pytest.raises(ValueError, match=r"z_band must be \(z_min, z_max\) with z_min < z_max"):
        scan_from_depth(depth, INTR, T, z_band=(1.0, 0.5))
    with pytest.raises(ValueError, match="n_beams must be a positive integer, got 0"):
        scan_from_depth(depth, INTR, T, n_beams=0)
    with pytest.raises(ValueError, match=r"fov must lie in \(0, 2π\] rad"):
        scan_from_depth(depth, INTR, T, fov=7.0)
    with pytest.raises(ValueError, match="need 0 ≤ range_min < range_max"):
        scan_from_depth(depth, INTR, T, range_max=1.0, range_min=2.0)
    with pytest.raises(ValueError, match=r"T_base_camera\[:3, :3\] must be a proper rotation"):
        scan_from_depth(depth, INTR, np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(TypeError, match="intrinsics must be CameraIntrinsics"):
        scan_from_depth(depth, INTR.K, T)  # type: ignore[arg-type]


def test_camera_fov_limits_the_scan() -> None:
    """Bearings the camera cannot see stay empty."""
    scan = scan_from_depth(wall_depth(2.0), INTR, mount(), (0.05, 1.0), 36, np.deg2rad(120.0))
    outside = np.abs(scan.angles) > HFOV / 2 + np.deg2rad(2.0)
    assert outside.any() and np.all(np.isinf(scan.ranges[outside]))
    assert np.all(np.isfinite(scan.ranges[np.abs(scan.angles) < HFOV / 2 - np.deg2rad(2.0)]))
