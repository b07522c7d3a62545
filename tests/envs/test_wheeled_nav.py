"""WheeledNav-v0 task logic, bad input and the two sensor fidelities."""

from __future__ import annotations

import math

import cv2
import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401
from realitygap.envs.layouts import free_route_exists, room_walls
from realitygap.robots.effects import Reality, make_effect
from realitygap.robots.world import Primitive, Shape


def _ring(radius: float, n: int = 24) -> list[Primitive]:
    """Cylinders in a closed ring around the origin."""
    out = []
    for k in range(n):
        a = 2 * math.pi * k / n
        out.append(
            Primitive(
                f"post_{k}",
                Shape.CYLINDER,
                (radius * math.cos(a), radius * math.sin(a)),
                0.6,
                radius=0.12,
            )
        )
    return out


def test_a_layout_that_traps_the_start_is_a_clear_error() -> None:
    env = gym.make(
        "realitygap/WheeledNav-v0", obstacles=_ring(0.8), start=(0, 0, 0), goal=(2.5, 0, 0)
    )
    with pytest.raises(ValueError, match="no collision-free route"):
        env.reset(seed=0)
    env.close()


def test_route_check_is_not_fooled_by_a_gap() -> None:
    ring = _ring(0.8)
    assert not free_route_exists(ring, (0, 0), (2.5, 0), 0.176, 3.5)
    assert free_route_exists(ring[3:], (0, 0), (2.5, 0), 0.176, 3.5)


def test_start_outside_the_room_is_rejected() -> None:
    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=0)
    with pytest.raises(ValueError, match="outside the room"):
        env.reset(seed=0, options={"start": [9.0, 0.0, 0.0]})
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(seed=0, options={"strat": [0.0, 0.0, 0.0]})
    env.close()


def test_bad_rates_are_rejected() -> None:
    with pytest.raises(ValueError, match="whole number"):
        gym.make("realitygap/WheeledNav-v0", control_hz=7.0)
    with pytest.raises(ValueError, match="sensor_mode"):
        gym.make("realitygap/WheeledNav-v0", sensor_mode="photo")


def test_driving_into_a_wall_is_a_collision_that_ends_the_episode() -> None:
    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=0, start=(2.8, 0, 0), goal=(-2, 0, 0))
    env.reset(seed=0)
    for _ in range(100):
        _, _, terminated, _, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
        if terminated:
            break
    env.close()
    assert terminated and info["collision"]
    assert info["reward_terms"]["collision"] < 0


def test_observation_matches_estimate_and_scan() -> None:
    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=0, start=(0, 0, 0), goal=(1, 1, 0))
    obs, info = env.reset(seed=0)
    np.testing.assert_allclose(obs[:2], info["estimated_pose"][:2], atol=1e-6)
    # the wall 3.5 m ahead: the central beam reads 3.5 m / 8 m
    n = env.unwrapped.n_beams
    centre = obs[12 + n // 2 - 1 : 12 + n // 2 + 1]
    np.testing.assert_allclose(centre * env.unwrapped.scan_range_max, 3.5, atol=0.1)
    env.close()


def test_the_real_robot_is_another_body() -> None:
    reality = Reality((make_effect("wheel_radius_scale", scale=1.05),))
    runs = []
    for r in (None, reality):
        env = gym.make(
            "realitygap/WheeledNav-v0", n_obstacles=0, start=(0, 0, 0), goal=(2, 2, 0), reality=r
        )
        env.reset(seed=0)
        for _ in range(30):
            _, _, _, _, info = env.step(np.array([0.5, 0.0], dtype=np.float32))
        runs.append((info["true_pose"][0], info["estimated_pose"][0]))
        env.close()
    (true_nom, est_nom), (true_real, est_real) = runs
    assert true_real == pytest.approx(1.05 * true_nom, rel=0.01)  # bigger wheels go farther
    assert est_real == pytest.approx(
        est_nom, rel=0.01
    )  # odometry with nominal radius does not know


def test_image_mode_renders_rgbd_and_derives_the_scan() -> None:
    env = gym.make("realitygap/WheeledNav-v0", sensor_mode="image", n_obstacles=3)
    obs, _ = env.reset(seed=1)
    frame = env.unwrapped.camera.render(0.0, np.random.default_rng(0))
    assert frame.rgb.shape == (240, 320, 3) and frame.depth.shape == (240, 320)
    valid = np.isfinite(frame.depth)
    assert valid.mean() > 0.3
    assert np.nanmin(frame.depth) >= 0.5 and np.nanmax(frame.depth) <= 8.0
    assert frame.rgb.std() > 10  # textured scenery, not a blank image
    assert obs.shape == env.observation_space.shape
    env.close()


def test_walls_enclose_the_room() -> None:
    walls = room_walls(3.0)
    inside = np.array([[0.0, 0.0], [2.9, 2.9]])
    for w in walls:
        assert np.all(w.footprint_distance(inside) > 0)


def test_image_mode_default_pipeline_fuses_vo_with_odometry() -> None:
    env = gym.make(
        "realitygap/WheeledNav-v0",
        sensor_mode="image",
        n_obstacles=4,
        start=(0, 0, 0),
        goal=(2, 2, 0),
    )
    env.reset(seed=2)
    for k in range(30):
        _, _, terminated, _, info = env.step(
            np.array([0.4, 0.3 * math.sin(k / 10)], dtype=np.float32)
        )
        assert not terminated
    extras = env.unwrapped._estimate.extras
    env.close()
    assert extras["n_vo_updates"] > 0
    assert extras["occupancy"].occupied_points().shape[0] > 10  # walls seen and mapped
    err = info["true_pose"] - info["estimated_pose"]
    assert np.hypot(err[0], err[1]) < 0.02 and abs(err[2]) < 0.02


def test_image_mode_room_is_textured_and_seeded() -> None:
    from realitygap.envs.wheeled_nav import WheeledNavEnv

    env = WheeledNavEnv(sensor_mode="image", n_obstacles=3)
    try:
        frames = []
        for _ in range(2):
            env.reset(seed=5)
            assert env.camera is not None
            frames.append(env.camera.render(0.0, np.random.default_rng(0)).rgb)
        assert np.array_equal(frames[0], frames[1])
        # walls, floor and obstacles carry texture: a camera finds corners in most of the view
        gray = frames[0].mean(axis=2).astype(np.uint8)
        kps = cv2.ORB.create(1000).detect(gray, None)
        cells = {(int(k.pt[0] * 4 / gray.shape[1]), int(k.pt[1] * 3 / gray.shape[0])) for k in kps}
        assert len(kps) > 300 and len(cells) >= 9
        assert "floor_surface" in env.world.bodies
    finally:
        env.close()


def test_image_mode_renders_camera_frames_only_at_the_camera_rate() -> None:
    """camera_hz below scan_hz: RGB-D frames reach the estimator every fourth step only, the
    scans in between come from the small depth pictures the scanner renders for itself."""
    from realitygap.envs.wheeled_nav import WheeledNavEnv

    seen: list[tuple[bool, bool]] = []

    class Recorder:
        def reset(self, initial=None):
            return inner.reset(initial)

        def update(self, m):
            seen.append((m.rgbd is not None, m.scan is not None))
            if m.rgbd is not None:
                assert m.rgbd.rgb.shape == (240, 320, 3)
            if m.scan is not None:
                assert np.isfinite(m.scan.ranges).mean() > 0.5  # walls and boxes in view
            return inner.update(m)

    from realitygap.estimators.diffdrive_model import DiffDriveKinematics, WheelOdometry

    inner = WheelOdometry(DiffDriveKinematics(0.035, 0.035, 0.23, 2578.33))
    env = WheeledNavEnv(
        sensor_mode="image", n_obstacles=3, camera_hz=5.0, scan_hz=10.0, estimator=Recorder()
    )
    try:
        env.reset(seed=3)
        sizes = []
        render = env.camera.render

        def spy(t, rng, size=None):
            sizes.append(size)
            return render(t, rng, size)

        env.camera.render = spy  # type: ignore[method-assign]
        for _ in range(8):
            env.step(np.array([0.3, 0.1], dtype=np.float32))
    finally:
        env.close()
    # steps 1..8 after the reset: frames at steps 4 and 8, scans at 2, 4, 6, 8
    assert seen[1:] == [(k % 4 == 0, k % 2 == 0) for k in range(1, 9)]
    assert sizes == [(128, 48), None, (128, 48), None]  # 2 columns per beam, 64 beams


def test_default_camera_rate_renders_full_frames_every_fourth_step() -> None:
    """The default image mode: a 5 Hz camera at 20 Hz control renders its 320 × 240 frame on
    every fourth step only; the 10 Hz scan renders its small depth picture in between."""
    import inspect

    from realitygap.envs.wheeled_nav import WheeledNavEnv

    assert inspect.signature(WheeledNavEnv).parameters["camera_hz"].default == 5.0
    env = WheeledNavEnv(sensor_mode="image", n_obstacles=3)
    try:
        env.reset(seed=5)
        sizes: list[tuple[int, int] | None] = []
        render = env.camera.render

        def spy(t, rng, size=None):
            sizes.append(size)
            return render(t, rng, size)

        env.camera.render = spy  # type: ignore[method-assign]
        for _ in range(12):
            env.step(np.array([0.3, -0.1], dtype=np.float32))
    finally:
        env.close()
    # steps 1..12 after the reset: full frames at 4, 8, 12; scan pictures at 2, 6, 10
    assert sizes == [env.scanner.render_size, None] * 3
    assert env.scanner.render_size == (128, 48)  # 2 columns per beam, half the rows
