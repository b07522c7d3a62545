"""The loop kernels of the fast sensor mode (ray cast, noisy scan, odometry propagation,
observation) give the bits of their NumPy formulations, in Python and compiled by Numba
(where installed), on random inputs that include the awkward cases: rays along box faces,
origins inside boxes and cylinders, empty scenes, headings at ±π."""

from __future__ import annotations

import math

import numpy as np
import pytest

import realitygap  # noqa: F401  (registers the envs)
from realitygap.core import jit
from realitygap.envs import wheeled_nav
from realitygap.envs.layouts import room_walls
from realitygap.estimators import diffdrive_model as dm
from realitygap.robots import raycast, sensors, world

needs_numba = pytest.mark.skipif(
    not jit.numba_available(), reason="numba is not installed (or REALITYGAP_DISABLE_JIT is set)"
)


def _random_scene(rng: np.random.Generator, walls: float | None = None) -> raycast.PrimitiveArrays:
    """Up to eight random boxes and cylinders, overlapping freely, inside a square room of
    half-size ``walls`` (m) when given."""
    prims = list(room_walls(walls)) if walls is not None else []
    for k in range(int(rng.integers(0, 9))):
        centre = (float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)))
        if rng.random() < 0.6:
            half = (float(rng.uniform(0.05, 1.5)), float(rng.uniform(0.05, 1.5)))
            yaw = float(rng.choice([0.0, math.pi / 2, rng.uniform(-3, 3)]))
            prims.append(world.Primitive(f"b{k}", world.Shape.BOX, centre, 0.5, yaw, half))
        else:
            r = float(rng.uniform(0.05, 0.8))
            prims.append(world.Primitive(f"c{k}", world.Shape.CYLINDER, centre, 0.5, radius=r))
    return raycast.PrimitiveArrays(prims)


def _rotated_directions(c: float, s: float, cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """The (2, 1, n) directions of PlanarScanner.scan_fast's NumPy path."""
    d = np.stack([cos, cos])[:, None, :] * np.array([c, s]).reshape(2, 1, 1)
    d += np.stack([sin, sin])[:, None, :] * np.array([-s, c]).reshape(2, 1, 1)
    return d


def _cast_cases(n_scenes: int):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(21)
    for _ in range(n_scenes):
        arrays = _random_scene(rng)
        n = int(rng.integers(2, 80))
        ang = rng.uniform(-0.7, 0.7) + np.linspace(-0.6, 0.6, n)
        for _ in range(4):
            th = float(rng.choice([0.0, math.pi / 2, -math.pi, rng.uniform(-4, 4)]))
            c, s = math.cos(th), math.sin(th)
            if rng.random() < 0.3 and len(arrays.box_center):  # on a box face or inside
                ox = float(arrays.box_center[0, 0] + arrays.box_half[0, 0])
                oy = float(arrays.box_center[0, 1])
            else:
                ox, oy = (float(v) for v in rng.uniform(-3.5, 3.5, 2))
            yield arrays, ox, oy, c, s, np.cos(ang), np.sin(ang), float(rng.uniform(0.5, 6.0))


def test_loop_cast_matches_the_numpy_cast_bit_for_bit() -> None:
    for arrays, ox, oy, c, s, cos, sin, range_max in _cast_cases(25):
        want = arrays.cast_directions(ox, oy, _rotated_directions(c, s, cos, sin), range_max)
        got = np.empty_like(want)
        with np.errstate(invalid="ignore", divide="ignore"):
            raycast.cast_rotated_beams(
                ox, oy, c, s, cos, sin, arrays.box_rows, arrays.cyl_rows, range_max, got
            )
        assert got.tobytes() == want.tobytes()


@needs_numba
def test_compiled_cast_matches_the_numpy_cast_bit_for_bit() -> None:
    kernel = raycast.cast_rotated_beams_compiled
    n_hits = 0
    for arrays, ox, oy, c, s, cos, sin, range_max in _cast_cases(300):
        want = arrays.cast_directions(ox, oy, _rotated_directions(c, s, cos, sin), range_max)
        got = np.empty_like(want)
        kernel(ox, oy, c, s, cos, sin, arrays.box_rows, arrays.cyl_rows, range_max, got)
        assert got.tobytes() == want.tobytes()
        n_hits += int(np.isfinite(want).sum())
    assert n_hits > 1000  # the scenes were hit, not only missed


def test_loop_cast_in_a_walled_room_matches_the_numpy_cast() -> None:
    """Inside a room of walls, beams along the axes (direction components of exactly
    ±0.0) and origins on wall faces, in corners and outside: the loop cast's bounding-circle
    skips and slab arithmetic give the NumPy cast's bits."""
    from realitygap.envs.layouts import room_walls

    rng = np.random.default_rng(8)
    arrays = raycast.PrimitiveArrays(
        [*room_walls(2.0), world.Primitive("b", world.Shape.BOX, (0.5, 0.5), 0.5, 0.3, (0.2, 0.4))]
    )
    kernels = [raycast.cast_rotated_beams]
    if jit.numba_available():
        kernels.append(raycast.cast_rotated_beams_compiled)
    ang = np.concatenate([np.linspace(-math.pi, math.pi, 9), rng.uniform(-math.pi, math.pi, 40)])
    cos, sin = np.cos(ang), np.sin(ang)
    origins = [(0.0, 0.0), (2.0, 0.0), (-2.0, 2.0), (1.9999, -2.0), (2.05, 0.3), (2.3, 2.3)]
    origins += [tuple(float(v) for v in rng.uniform(-2.0, 2.0, 2)) for _ in range(20)]
    n_hits = 0
    for (ox, oy), th in [(o, t) for o in origins for t in (0.0, math.pi / 2, -math.pi, 1.0)]:
        c, s = math.cos(th), math.sin(th)
        want = arrays.cast_directions(ox, oy, _rotated_directions(c, s, cos, sin), 6.0)
        for kernel in kernels:
            got = np.empty_like(want)
            with np.errstate(invalid="ignore", divide="ignore"):
                kernel(ox, oy, c, s, cos, sin, arrays.box_rows, arrays.cyl_rows, 6.0, got)
            assert got.tobytes() == want.tobytes(), (ox, oy, th)
        n_hits += int(np.isfinite(want).sum())
    assert n_hits > 1000


@needs_numba
def test_compiled_noisy_scan_matches_the_numpy_scan() -> None:
    """The compiled scan and the NumPy scan of one scanner, from generators in one state."""
    import gymnasium as gym

    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=6)
    env.reset(seed=4)
    u = env.unwrapped
    rng = np.random.default_rng(9)
    for k in range(60):
        env.step(rng.uniform(-1, 1, 2))
        pose = u.robot.pose2d().tolist()
        got = u.scanner.scan_fast(0.1 * k, np.random.default_rng(k), pose)
        with jit.numpy_only():
            want = u.scanner.scan_fast(0.1 * k, np.random.default_rng(k), pose)
        assert got.ranges.tobytes() == want.ranges.tobytes()
        assert got.angles.tobytes() == want.angles.tobytes()
    env.close()


def _propagation_cases(n: int):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(3)
    for i in range(n):
        pose = np.array([rng.normal(), rng.normal(), rng.uniform(-math.pi, math.pi)])
        if i % 9 == 0:
            pose[2] = rng.choice([math.pi, -math.pi, math.nextafter(math.pi, 0.0)])
        m = rng.normal(size=(3, 3))
        cov = m @ m.T * 10.0 ** rng.uniform(-8, 0)
        ds = float(rng.normal(0.0, 0.02))
        dth = float(rng.choice([rng.normal(0.0, 0.003), rng.normal(0.0, 0.3), 0.0, 1e-2, -1e-2]))
        yield pose, cov, ds, dth


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=needs_numba)])
def test_in_place_propagation_matches_propagate_pose_bit_for_bit(compiled: bool) -> None:
    noise = dm.OdometryNoise(distance_var_floor=1e-6, heading_var_floor=2e-6)
    fn = dm.propagate_pose_in_place_compiled if compiled else dm.propagate_pose_in_place
    for pose, cov, ds, dth in _propagation_cases(400 if compiled else 100):
        want_pose, want_cov = dm.propagate_pose(pose, cov, ds, dth, noise)
        got_pose, got_cov = pose.copy(), cov.copy()
        fn(got_pose, got_cov, ds, dth, *noise.coefficients)
        assert got_pose.tobytes() == want_pose.tobytes()
        assert got_cov.tobytes() == want_cov.tobytes()


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=needs_numba)])
def test_odometry_step_matches_increment_then_propagation_bit_for_bit(compiled: bool) -> None:
    """The one-call odometry step gives the bits of the kinematics' increment followed by
    :func:`propagate_pose`, and returns the increment's distance."""
    noise = dm.OdometryNoise(distance_var_floor=1e-6, heading_var_floor=2e-6)
    kin = dm.DiffDriveKinematics(0.0352, 0.0349, 0.231, 2578.33)
    fn = dm.odometry_step_in_place_compiled if compiled else dm.odometry_step_in_place
    rng = np.random.default_rng(12)
    for pose, cov, _, _ in _propagation_cases(200):
        d_left, d_right = (float(v) for v in rng.integers(-300, 300, 2) * 0.997)
        if rng.random() < 0.2:
            d_right = d_left  # straight: Δθ = 0
        ds, dth = kin.increment_from_ticks(d_left, d_right)
        want_pose, want_cov = dm.propagate_pose(pose, cov, ds, dth, noise)
        got_pose, got_cov = pose.copy(), cov.copy()
        got_ds = fn(
            got_pose,
            got_cov,
            d_left,
            d_right,
            kin.meters_per_tick_left,
            kin.meters_per_tick_right,
            kin.wheelbase,
            *noise.coefficients,
        )
        assert np.float64(got_ds).tobytes() == np.float64(ds).tobytes()
        assert got_pose.tobytes() == want_pose.tobytes()
        assert got_cov.tobytes() == want_cov.tobytes()


def test_wheel_odometry_follows_replaced_kinematics() -> None:
    """The odometry's cached per-tick travels follow ``kinematics`` when it is replaced."""
    odo = dm.WheelOdometry(dm.DiffDriveKinematics(0.035, 0.035, 0.23, 1000.0))
    odo.reset()
    odo.update(dm.WheelTicks(0.0, 0, 0, 1000.0))
    odo.kinematics = dm.DiffDriveKinematics(0.07, 0.07, 0.23, 1000.0)
    est = odo.update(dm.WheelTicks(0.1, 1000, 1000, 1000.0))
    assert est.pose[0] == pytest.approx(2.0 * math.pi * 0.07)  # one revolution, new radius
    assert est.extras["distance"] == pytest.approx(2.0 * math.pi * 0.07)


def test_wheel_odometry_follows_a_replaced_noise_model() -> None:
    """The odometry's cached noise coefficients follow ``noise`` when it is replaced."""
    kin = dm.DiffDriveKinematics(0.035, 0.035, 0.23, 1000.0)
    odo = dm.WheelOdometry(kin)
    odo.reset()
    odo.update(dm.WheelTicks(0.0, 0, 0, 1000.0))
    odo.noise = dm.OdometryNoise(distance_var_per_m=1.0, heading_var_per_rad=0.0)
    est = odo.update(dm.WheelTicks(0.1, 1000, 1000, 1000.0))
    ds = 2.0 * math.pi * 0.035  # one revolution of both wheels, straight
    assert est.cov[0, 0] == pytest.approx(ds)  # k_s |Δs| with k_s = 1 m²/m
    assert est.cov[2, 2] == pytest.approx(1e-4 * ds)  # k_θs |Δs|


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=needs_numba)])
def test_loop_observation_matches_the_numpy_clip(compiled: bool) -> None:
    fn = wheeled_nav._fill_observation_compiled if compiled else wheeled_nav.fill_observation
    rng = np.random.default_rng(8)
    n = 40
    low = np.full(12 + n, -1.0, dtype=np.float32)
    high = np.full(12 + n, 1.0, dtype=np.float32)
    for idx in (0, 1, 4, 5, 8, 9):
        low[idx], high[idx] = -14.0, 14.0
    low[12:] = 0.0
    for _ in range(300):
        x, y, gx, gy = (float(v) for v in rng.uniform(-12, 12, 4))
        th, gth = (float(v) for v in rng.uniform(-4, 4, 2))
        cmd_v, cmd_w = (float(v) for v in rng.uniform(-1.2, 1.2, 2))
        ranges = rng.uniform(0.1, 9.0, n)
        ranges[rng.random(n) < 0.2] = np.inf
        # the NumPy form: float64 values, cast to float32, clipped to the space
        c, s = math.cos(th), math.sin(th)
        dx, dy = gx - x, gy - y
        head = [x, y, c, s, gx, gy, math.cos(gth), math.sin(gth)]
        head += [c * dx + s * dy, -s * dx + c * dy, cmd_v, cmd_w]
        full = np.concatenate([head, np.minimum(ranges / 8.0, 1.0)]).astype(np.float32)
        want = np.clip(full, low, high)
        got = np.full(12 + n, np.nan, dtype=np.float32)
        fn(x, y, th, gx, gy, gth, cmd_v, cmd_w, ranges, 8.0, True, low, high, got)
        assert got.tobytes() == want.tobytes()
        # without a new scan only the first 12 entries are written
        got[12:] = 7.0
        fn(x, y, th, gx, gy, gth, cmd_v, cmd_w, ranges, 8.0, False, low, high, got)
        assert got[:12].tobytes() == want[:12].tobytes() and np.all(got[12:] == 7.0)


def test_numpy_only_switches_the_kernels_off_and_back() -> None:
    before = jit.use_compiled()
    with jit.numpy_only():
        assert not jit.use_compiled()
        with jit.numpy_only():
            assert not jit.use_compiled()
        assert not jit.use_compiled()
    assert jit.use_compiled() == before
    assert before == (jit.numba_available() and jit.use_compiled())
    with pytest.raises(RuntimeError, match="inside"), jit.numpy_only():
        raise RuntimeError("inside")
    assert jit.use_compiled() == before


def test_the_sensor_module_names_its_kernels() -> None:
    """The scan's compiled kernel exists exactly when Numba does."""
    assert (sensors._noisy_scan_compiled is not None) == jit.numba_available()
    assert (raycast.cast_rotated_beams_compiled is not None) == jit.numba_available()


@needs_numba
def test_compiled_clearance_gives_the_numpy_clearance_bits() -> None:
    rng = np.random.default_rng(3)
    n_inside = 0
    for _ in range(40):
        arrays = _random_scene(rng, walls=3.0)
        for x, y in rng.uniform(-3.5, 3.5, size=(25, 2)):
            got = arrays.clearance(float(x), float(y))
            with jit.numpy_only():
                want = arrays.clearance(float(x), float(y))
            assert type(got) is float
            assert np.float64(got).tobytes() == np.float64(want).tobytes(), (x, y)
            n_inside += want < 0.0
    assert n_inside > 10  # points inside footprints (negative distances) were among them
    empty = raycast.PrimitiveArrays([])
    assert empty.clearance(0.3, -0.2) == math.inf


@pytest.mark.parametrize("ramp", ["body", "wheels"])
@pytest.mark.parametrize("deceleration", ["limited", "free", "stop"])
def test_compiled_firmware_rows_match_the_step_by_step_firmware(ramp, deceleration) -> None:
    from realitygap.robots.diffdrive import FirmwareLimits

    if not jit.numba_available():
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(11)
    req = rng.normal(0.0, 0.5, size=(400, 2))
    req[rng.random(400) < 0.15] = 0.0  # zero requests: the stop convention's case
    req[100:140, 0] = 2.0  # beyond v_max
    for limits in (
        FirmwareLimits(0.7, 2.0, 0.8, 3.0, ramp, deceleration, decel_factor=1.5),
        FirmwareLimits(a_max=0.5, ramp=ramp, deceleration=deceleration),  # speed unlimited
    ):
        fast = limits.applied(req, 0.05, 0.23)
        with jit.numpy_only():
            slow = limits.applied(req, 0.05, 0.23)
        np.testing.assert_array_equal(fast, slow)
        assert not np.array_equal(fast, req)  # the firmware did act
