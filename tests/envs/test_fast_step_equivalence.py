"""The fast-mode step of WheeledNav computes every observation bit as the plain numpy
formulation below does, and its physics as one engine call per physics step does: each
fast path is checked against a reference kept here."""

from __future__ import annotations

import contextlib
import math

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401  (registers the envs)
from realitygap.core import jit
from realitygap.envs.common import check_action_array, check_twist_action
from realitygap.envs.tasks.nav import NavTask
from realitygap.envs.wheeled_nav import WheeledNavEnv
from realitygap.estimators import diffdrive_model
from realitygap.estimators.diffdrive_model import (
    DiffDriveKinematics,
    OdometryNoise,
    propagate_pose,
)
from realitygap.robots import sensors, world
from realitygap.robots.diffdrive import DiffDriveRobot
from realitygap.robots.effects import Reality, make_effect

# ---------------------------------------------------------------- reference implementations


def reference_propagate_pose(pose, cov, ds, dtheta, noise):  # type: ignore[no-untyped-def]
    """Pose composition and covariance with 3×3 matrices (the textbook form)."""
    th = float(dtheta)
    if abs(th) < 1e-2:
        th2 = th * th
        f1 = 1.0 - th2 / 6.0 + th2 * th2 / 120.0
        f2 = th / 2.0 - th * th2 / 24.0 + th * th2 * th2 / 720.0
        df1 = -th / 3.0 + th * th2 / 30.0 - th * th2 * th2 / 840.0
        df2 = 0.5 - th2 / 8.0 + th2 * th2 / 144.0
    else:
        st, ct = math.sin(th), math.cos(th)
        f1, f2 = st / th, (1.0 - ct) / th
        df1 = (th * ct - st) / (th * th)
        df2 = (th * st - 1.0 + ct) / (th * th)
    dx, dy = ds * f1, ds * f2
    c, s = math.cos(pose[2]), math.sin(pose[2])
    new = np.array(
        [
            pose[0] + c * dx - s * dy,
            pose[1] + s * dx + c * dy,
            (pose[2] + dtheta + math.pi) % (2.0 * math.pi) - math.pi,
        ]
    )
    J_a = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
    G = np.array(
        [
            [c * f1 - s * f2, ds * (c * df1 - s * df2)],
            [s * f1 + c * f2, ds * (s * df1 + c * df2)],
            [0.0, 1.0],
        ]
    )
    new_cov = J_a @ cov @ J_a.T + G @ noise.covariance(ds, dtheta) @ G.T
    return new, 0.5 * (new_cov + new_cov.T)


def reference_increment(kin, d_left, d_right):  # type: ignore[no-untyped-def]
    s_left = kin.meters_per_tick_left * np.asarray(d_left, dtype=float)
    s_right = kin.meters_per_tick_right * np.asarray(d_right, dtype=float)
    return float(0.5 * (s_right + s_left)), float((s_right - s_left) / kin.wheelbase)


def reference_twist_action(action):  # type: ignore[no-untyped-def]
    a = check_action_array(action, (2,))
    return min(1.0, max(-1.0, float(a[0]))), min(1.0, max(-1.0, float(a[1])))


def reference_ray_cast_xy(arrays, ox, oy, dx, dy, range_max):  # type: ignore[no-untyped-def]
    """Slab method per box and circle intersection per cylinder, one ufunc per formula."""
    best = np.full(dx.shape[0], np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        if len(arrays.box_center):
            rx = ox - arrays.box_center[:, :1]
            ry = oy - arrays.box_center[:, 1:]
            c = np.stack([arrays.box_cos, -arrays.box_sin])
            s = np.stack([arrays.box_sin, arrays.box_cos])
            half = np.stack([arrays.box_half[:, :1], arrays.box_half[:, 1:]])
            o_local = c * rx + s * ry
            d_local = c * dx + s * dy
            t_low = (-half - o_local) / d_local
            t_high = (half - o_local) / d_local
            t_near = np.minimum(t_low, t_high)
            t_far = np.maximum(t_low, t_high)
            tmin = np.maximum(np.maximum(t_near[0], t_near[1]), 0.0)
            tmax = np.minimum(t_far[0], t_far[1])
            hit = np.where(tmax >= tmin, tmin, np.inf)
            np.minimum(best, hit.min(axis=0), out=best)
        if len(arrays.cyl_center):
            rx = ox - arrays.cyl_center[:, :1]
            ry = oy - arrays.cyl_center[:, 1:]
            b = rx * dx + ry * dy
            cc = rx * rx + ry * ry - arrays.cyl_r2
            disc = b * b - cc
            t = -b - np.sqrt(np.maximum(disc, 0.0))
            t[cc[:, 0] < 0] = 0.0
            t[(disc < 0) | (t < 0)] = np.inf
            np.minimum(best, t.min(axis=0), out=best)
    best[best > range_max] = np.inf
    return best


def reference_scan_fast(self, t, rng, pose=None):  # type: ignore[no-untyped-def]
    x, y, th = (float(v) for v in self.robot.pose2d())  # the engine's pose, whatever is passed
    c, s = math.cos(th), math.sin(th)
    dx = c * self._cos - s * self._sin
    dy = s * self._cos + c * self._sin
    mx, my = self.params.mount_xyz[0], self.params.mount_xyz[1]
    ranges = reference_ray_cast_xy(
        self.robot.world.scenery_arrays,
        x + c * mx - s * my,
        y + s * mx + c * my,
        dx,
        dy,
        self.params.range_max,
    )
    ranges += self._along_beam_offset
    sigma = self.params.depth_noise_a + self.params.depth_noise_b * ranges * ranges
    ranges += rng.standard_normal(self.n_beams) * np.where(np.isfinite(sigma), sigma, 0.0)
    np.maximum(ranges, self.params.range_min, out=ranges)
    return sensors.Scan(t, self.angles.copy(), ranges, self.params.range_min, self.params.range_max)


def reference_pose_error(self, pose):  # type: ignore[no-untyped-def]
    """NavTask.pose_error in NumPy scalars."""
    gx, gy, gth = self.goal
    d_th = (float(pose[2]) - gth + math.pi) % (2.0 * math.pi) - math.pi
    return math.hypot(float(pose[0]) - gx, float(pose[1]) - gy), abs(d_th)


def reference_command_twist(self, v, omega):  # type: ignore[no-untyped-def]
    """DiffDriveRobot.command_twist with the previous command read as NumPy scalars."""
    if self.firmware_limits is not None:
        v, omega = self.firmware_limits.step(
            v, omega, self.command[0], self.command[1], self.control_dt, self.nominal.wheelbase
        )
    self.command[0], self.command[1] = v, omega
    applied = (v, omega)
    for hook in self._command_hooks:
        v, omega = hook(v, omega, self.control_dt)
    w_left, w_right = self.wheel_speeds_from_twist(v, omega)
    for wheel_hook in self._wheel_hooks:
        w_left, w_right = wheel_hook.command(w_left, w_right)
    self.set_wheel_speeds(float(w_left), float(w_right))
    return applied


def reference_observation(self):  # type: ignore[no-untyped-def]
    """The whole observation in float64, cast to float32 and clipped to the space."""
    x, y, th = (float(v) for v in self._estimate.pose)
    gx, gy, gth = (float(v) for v in self.task.goal)
    c, s = math.cos(th), math.sin(th)
    dx, dy = gx - x, gy - y
    obs = np.empty(12 + self.n_beams)
    obs[:12] = (
        x,
        y,
        c,
        s,
        gx,
        gy,
        math.cos(gth),
        math.sin(gth),
        c * dx + s * dy,
        -s * dx + c * dy,
        self.robot.command[0] / self.v_max,
        self.robot.command[1] / self.w_max,
    )
    obs[12:] = np.minimum(self._scan.ranges / self._scan.range_max, 1.0)
    return np.clip(obs.astype(np.float32), self.observation_space.low, self.observation_space.high)


# ---------------------------------------------------------------- unit checks


def test_scalar_pose_propagation_matches_the_matrix_form() -> None:
    rng = np.random.default_rng(3)
    noise = OdometryNoise(distance_var_floor=1e-6, heading_var_floor=2e-6)
    for _ in range(500):
        pose = np.array([rng.normal(), rng.normal(), rng.uniform(-math.pi, math.pi)])
        M = rng.normal(size=(3, 3))
        cov = M @ M.T * 10.0 ** rng.uniform(-8, 0)
        ds = rng.normal(0.0, 0.02)
        dtheta = rng.choice([rng.normal(0.0, 0.003), rng.normal(0.0, 0.3), 0.0])
        new, new_cov = propagate_pose(pose, cov, ds, dtheta, noise)
        ref, ref_cov = reference_propagate_pose(pose, cov, ds, dtheta, noise)
        assert np.array_equal(new, ref)  # the pose, bit for bit
        np.testing.assert_allclose(new_cov, ref_cov, rtol=1e-12, atol=1e-14 * np.abs(ref_cov).max())
        assert np.array_equal(new_cov, new_cov.T)


def test_scalar_tick_increment_matches_the_array_form() -> None:
    kin = DiffDriveKinematics(0.0352, 0.0349, 0.231, 2578.33)
    rng = np.random.default_rng(4)
    for d_left, d_right in rng.integers(-400, 400, size=(300, 2)) * 0.997:
        got = kin.increment_from_ticks(float(d_left), float(d_right))
        assert got == reference_increment(kin, d_left, d_right)
    ds, dth = kin.increment_from_ticks(np.array([1.0, 2.0]), np.array([3.0, 4.0]))
    assert ds.shape == dth.shape == (2,)


@pytest.mark.parametrize(
    "action",
    [
        np.array([0.3, -0.7], dtype=np.float32),
        np.array([1.7, -2.5]),
        np.array([0.1, 0.2], dtype=np.float16),
        [0.4, 0.9],
        np.array([[0.2, 0.1]]),
        np.array([3, -1]),
    ],
)
def test_twist_action_fast_path_matches_the_general_check(action: object) -> None:
    got = check_twist_action(action)  # type: ignore[arg-type]
    assert got == reference_twist_action(action)
    assert all(type(v) is float for v in got)


def test_twist_action_fast_path_still_rejects_non_finite_values() -> None:
    with pytest.raises(ValueError, match="action must be finite"):
        check_twist_action(np.array([np.nan, 0.0], dtype=np.float32))
    with pytest.raises(ValueError, match="action must be finite"):
        check_twist_action(np.array([0.0, np.inf]))


def test_clearance_is_the_nearest_footprint_distance() -> None:
    rng = np.random.default_rng(6)
    for _ in range(30):
        prims = [
            world.Primitive(
                f"b{k}",
                world.Shape.BOX,
                (float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3))),
                0.5,
                yaw=float(rng.uniform(-3, 3)),
                half_extents=(float(rng.uniform(0.05, 1.0)), float(rng.uniform(0.05, 1.0))),
            )
            for k in range(int(rng.integers(0, 4)))
        ] + [
            world.Primitive(
                f"c{k}",
                world.Shape.CYLINDER,
                (float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3))),
                0.5,
                radius=float(rng.uniform(0.05, 0.6)),
            )
            for k in range(int(rng.integers(0, 4)))
        ]
        arrays = world.PrimitiveArrays(prims)
        for x, y in rng.uniform(-4, 4, size=(10, 2)):
            want = min((float(q.footprint_distance([x, y])) for q in prims), default=math.inf)
            assert arrays.clearance(float(x), float(y)) == pytest.approx(want, abs=1e-12)


def test_contact_query_skipped_only_far_from_scenery() -> None:
    """With the pose, the contact check skips the engine only where no contact can be: it
    agrees with the engine's answer at every step of crowded episodes with collisions."""
    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=8, room_half_size=1.5)
    u = env.unwrapped
    rng = np.random.default_rng(2)
    env.reset(seed=3)
    n_contacts = n_skipped = 0
    for _ in range(600):
        env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        robot = u.robot
        pose = robot.pose2d()
        engine = robot.in_contact_with_scenery()
        assert robot.in_contact_with_scenery(pose) == engine
        n_contacts += engine
        if robot._clear_of_scenery(float(pose[0]), float(pose[1])):
            n_skipped += 1
            clear_xy = (float(pose[0]), float(pose[1]))
    assert n_contacts > 0 and n_skipped > 0  # both cases were met
    # a body that is no scenery primitive: the engine is always asked
    assert u.robot._clear_of_scenery(*clear_xy)
    u.world.load_urdf("crate", CRATE_URDF, [0.0, 0.0, 3.0], [0, 0, 0, 1])
    assert not u.robot._clear_of_scenery(*clear_xy)
    u.world.remove_body("crate")
    assert u.robot._clear_of_scenery(*clear_xy)  # the check is kept only while nothing changes
    u.world.bodies["post"] = u.world.bodies["floor"]  # written straight into the registry
    assert not u.robot._clear_of_scenery(*clear_xy)
    env.close()


CRATE_URDF = """<?xml version="1.0"?>
<robot name="crate"><link name="base"><inertial><mass value="1"/>
<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
<collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link></robot>
"""


def test_ray_cast_matches_the_reference_on_random_scenes() -> None:
    rng = np.random.default_rng(5)
    for _ in range(50):
        prims = []
        for k in range(int(rng.integers(0, 7))):
            centre = (float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)))
            if rng.random() < 0.5:
                half = (float(rng.uniform(0.05, 1.0)), float(rng.uniform(0.05, 1.0)))
                prims.append(
                    world.Primitive(
                        f"b{k}",
                        world.Shape.BOX,
                        centre,
                        0.5,
                        yaw=float(rng.choice([0.0, math.pi / 2, rng.uniform(-3, 3)])),
                        half_extents=half,
                    )
                )
            else:
                r = float(rng.uniform(0.05, 0.6))
                prims.append(world.Primitive(f"c{k}", world.Shape.CYLINDER, centre, 0.5, radius=r))
        arrays = world.PrimitiveArrays(prims)
        ang = rng.uniform(-math.pi, math.pi) + np.linspace(-0.6, 0.6, int(rng.integers(2, 90)))
        ang[0] = 0.0  # a ray along a box face
        dx, dy = np.cos(ang), np.sin(ang)
        ox, oy = float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3))
        for _ in range(2):  # the second call re-uses buffers sized by the first
            got = arrays.ray_cast_xy(ox, oy, dx, dy, 4.0)
            ref = reference_ray_cast_xy(arrays, ox, oy, dx, dy, 4.0)
            assert np.array_equal(got, ref)


# ---------------------------------------------------------------- the env, step by step


def _info_row(info: dict[str, object]) -> tuple:
    """Every value of a step's ``info``, in key order (reward terms as sorted pairs)."""
    return tuple(
        (key, sorted(value.items()) if isinstance(value, dict) else value)
        for key, value in sorted(info.items())
    )


def _run(
    kwargs: dict[str, object], n_steps: int, reference: bool, compiled: bool = True
) -> list[tuple]:
    """The rows of a seeded run: the env's own paths (compiled kernels where Numba is
    installed and ``compiled``), or the reference formulations (NumPy only)."""
    mp = pytest.MonkeyPatch()
    if reference:
        mp.setattr(diffdrive_model, "propagate_pose", reference_propagate_pose)
        mp.setattr(sensors.PlanarScanner, "scan_fast", reference_scan_fast)
        mp.setattr(WheeledNavEnv, "_observation", reference_observation)
        mp.setattr(NavTask, "pose_error", reference_pose_error)
        mp.setattr(DiffDriveRobot, "command_twist", reference_command_twist)
        # the engine's contact query at every step
        engine_contacts = DiffDriveRobot.in_contact_with_scenery
        mp.setattr(
            DiffDriveRobot,
            "in_contact_with_scenery",
            lambda self, pose=None: engine_contacts(self),
        )
        # one engine call per physics step and multibody scenery
        plain_init = world.World.__init__

        def reference_world(self, *args, **kwargs):  # type: ignore[no-untyped-def]
            kwargs.update(fused_substeps=False, rigid_scenery=False)
            plain_init(self, *args, **kwargs)

        mp.setattr(world.World, "__init__", reference_world)
    try:
        with jit.numpy_only() if reference or not compiled else contextlib.nullcontext():
            env = gym.make("realitygap/WheeledNav-v0", sensor_mode="fast", **kwargs)
            rng = np.random.default_rng(11)
            obs, info = env.reset(seed=7)
            rows: list[tuple] = [(obs, *_info_row(info))]
            for k in range(n_steps):
                a = rng.uniform(-1.2, 1.2, 2).astype(np.float32 if k % 3 else np.float64)
                obs, reward, terminated, truncated, info = env.step(a)
                rows.append((obs, reward, terminated, truncated, *_info_row(info)))
                if terminated or truncated:
                    obs, info = env.reset()
                    rows.append((obs, *_info_row(info)))
            env.close()
    finally:
        mp.undo()
    return rows


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_obstacles": 6},
        {"n_obstacles": 3, "reality": Reality((make_effect("wheel_radius_scale", scale=1.03),))},
        # a crowded small room: collisions end episodes and the next ones start afresh
        {"n_obstacles": 8, "room_half_size": 1.5},
        # slippery tyres: the wheels slip on the floor
        {"n_obstacles": 2, "reality": Reality((make_effect("longitudinal_slip", mu=0.08),))},
    ],
)
def test_fast_steps_are_bit_identical_to_the_reference(kwargs: dict[str, object]) -> None:
    ref = _run(kwargs, 300, reference=True)
    # the compiled kernels (where Numba is installed) and the NumPy paths, each to the bit
    for compiled in (True, False) if jit.numba_available() else (False,):
        fast = _run(kwargs, 300, reference=False, compiled=compiled)
        assert len(fast) == len(ref)
        for k, (got, want) in enumerate(zip(fast, ref, strict=True)):
            assert _same_bits(got, want), f"row {k} differs (compiled={compiled}): {got} != {want}"


def _same_bits(got: object, want: object) -> bool:
    """Equal to the bit: arrays of one dtype and shape with equal bytes, floats with equal
    bytes (``-0.0`` is not ``0.0``), containers element by element, anything else ``==``."""
    if isinstance(want, np.ndarray):
        return (
            isinstance(got, np.ndarray)
            and got.dtype == want.dtype
            and got.shape == want.shape
            and got.tobytes() == want.tobytes()
        )
    if isinstance(want, (tuple, list)):
        return (
            isinstance(got, (tuple, list))
            and len(got) == len(want)
            and all(_same_bits(g, w) for g, w in zip(got, want, strict=True))
        )
    if isinstance(want, (float, np.floating)) and not isinstance(want, bool):
        return isinstance(got, (float, np.floating)) and (
            np.float64(got).tobytes() == np.float64(want).tobytes()
        )
    return bool(got == want) and type(got) is type(want)
