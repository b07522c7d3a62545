"""The vector env's batched reset and its cost said before it is spent.

Batched episodes: each robot's start, goal and obstacles are those the single-robot
task draws from the same seeded generator, so every constraint of the task holds
for every robot; the cost estimate refuses sizes that cannot fit in memory before
anything is allocated, and warns about large ones.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import realitygap.envs.vector_nav as vector_nav
from realitygap.envs.layouts import free_route_exists
from realitygap.envs.tasks.nav import NavTask
from realitygap.envs.vector_drive import RobotStreams, free_routes
from realitygap.envs.vector_nav import (
    WheeledNavVecEnv,
    check_vector_cost,
    estimate_vector_cost,
)
from realitygap.robots.world import Primitive, Shape


def _episodes(env: WheeledNavVecEnv) -> tuple[np.ndarray, ...]:
    a = env.obstacles.arrays
    return (
        env.pose.copy(),
        env.goal.copy(),
        a.is_box.copy(),
        a.center.copy(),
        a.yaw.copy(),
        a.half_extents.copy(),
        a.radius.copy(),
        env.scenery.box_center.copy(),
        env.scenery.cyl_center.copy(),
    )


# ---------------------------------------------------------------------- determinism
def test_reset_repeats_exactly_for_a_seed_and_differs_across_seeds() -> None:
    a, b = WheeledNavVecEnv(num_envs=64), WheeledNavVecEnv(num_envs=64)
    obs_a, _ = a.reset(seed=123)
    obs_b, _ = b.reset(seed=123)
    np.testing.assert_array_equal(obs_a, obs_b)
    for x, y in zip(_episodes(a), _episodes(b), strict=True):
        np.testing.assert_array_equal(x, y)
    again, _ = a.reset(seed=123)  # the same env, re-seeded
    np.testing.assert_array_equal(again, obs_a)
    b.reset(seed=124)
    assert not np.array_equal(a.pose, b.pose)
    # robot i of seed s is robot i - 1 of seed s + 1
    np.testing.assert_array_equal(a.pose[1:], b.pose[:-1])


@pytest.mark.parametrize("kwargs", [{}, {"n_obstacles": 12}, {"n_obstacles": 0}])
def test_robot_i_gets_the_tasks_episode_from_generator_seed_plus_i(kwargs: dict) -> None:
    """The batched draws are the single-robot task's draws, robot by robot, and each
    robot's stream then continues exactly where its generator would."""
    n, seed = 150, 31
    env = WheeledNavVecEnv(num_envs=n, **kwargs)
    env.reset(seed=seed)
    task, radius = NavTask(**kwargs), env.true_params.body_radius
    assert env.streams is not None
    for i in range(n):
        rng = np.random.default_rng(seed + i)
        start, goal = task.sample_start_goal(rng, {}, radius)
        arena = task.sample_arena(rng, start, goal, radius)
        np.testing.assert_array_equal(env.pose[i], start)
        np.testing.assert_array_equal(env.goal[i], goal)
        assert env.obstacles[i] == arena
        np.testing.assert_array_equal(env.streams.take(np.array([i]), 3)[0], rng.random(3))


def test_fixed_layout_keeps_the_tasks_episodes_and_errors() -> None:
    # beside the corner that drawn poses (|x|, |y| <= 2.9 m) can reach, but clear of them
    layout = [
        Primitive("c", Shape.CYLINDER, (3.2, 3.2), 0.6, radius=0.2),
        Primitive("b", Shape.BOX, (-3.25, 0.0), 0.6, half_extents=(0.05, 1.0)),
    ]
    env = WheeledNavVecEnv(num_envs=50, obstacles=layout)
    env.reset(seed=3)
    task, radius = NavTask(obstacles=layout), env.true_params.body_radius
    for i in range(50):
        rng = np.random.default_rng(3 + i)
        start, goal = task.sample_start_goal(rng, {}, radius)
        np.testing.assert_array_equal(env.pose[i], start)
        assert env.obstacles[i] == task.sample_arena(rng, start, goal, radius)
    with pytest.raises(ValueError, match="overlaps an obstacle of the given layout"):
        env.reset(options={"start": [3.0, 3.0, 0.0]})
    # a wall across the room: no route from the left half to the right half
    wall = [Primitive("w", Shape.BOX, (0.0, 0.0), 0.6, half_extents=(0.2, 3.6))]
    split = WheeledNavVecEnv(num_envs=2, obstacles=wall, start=[-2, 0, 0], goal=[2, 0, 0])
    with pytest.raises(ValueError, match="no collision-free route"):
        split.reset(seed=0)


def test_given_poses_outside_the_room_are_refused_as_by_the_task() -> None:
    env = WheeledNavVecEnv(num_envs=3)
    with pytest.raises(ValueError, match=r"start .* lies outside the room"):
        env.reset(seed=0, options={"start": [3.45, 0.0, 0.0]})
    with pytest.raises(ValueError, match="goal must"):
        env.reset(seed=0, options={"goal": [np.nan, 0.0, 0.0]})


# ---------------------------------------------------------------------- constraints
def test_reset_constraints_hold_for_every_one_of_1000_robots() -> None:
    n = 1000
    env = WheeledNavVecEnv(num_envs=n)
    env.reset(seed=2024)
    h, radius = env.room_half_size, env.true_params.body_radius
    start, goal = env.pose, env.goal
    lim = h - 0.6
    for pose in (start, goal):
        assert np.all(np.abs(pose[:, :2]) <= lim)
        assert np.all(np.abs(pose[:, 2]) <= np.pi)
    assert np.all(np.hypot(*(goal[:, :2] - start[:, :2]).T) > 1.0)
    # start and goal clear of walls and obstacles for the robot's body
    assert np.all(env.scenery.clearance(start[:, :2]) > radius)
    assert np.all(env.scenery.clearance(goal[:, :2]) > radius)
    layouts = env.obstacles.arrays
    k = layouts.is_box.shape[1]
    assert k == 6
    # obstacles stand in the room, keep 0.25 m beyond the body from start and goal,
    # and each one's centre keeps 0.3 m from the footprints drawn before it
    assert np.all(np.abs(layouts.center) <= h - 0.4)
    for pose in (start, goal):
        d = layouts.footprint_distance(
            pose[:, None, 0] - layouts.center[..., 0], pose[:, None, 1] - layouts.center[..., 1]
        )
        assert np.all(d >= radius + 0.25)
    for j in range(1, k):
        dx = layouts.center[:, j, None, 0] - layouts.center[:, :, 0]
        dy = layouts.center[:, j, None, 1] - layouts.center[:, :, 1]
        d = layouts.footprint_distance(dx, dy)[:, :j]
        assert np.all(d >= 0.3)
    box, cyl = layouts.is_box, ~layouts.is_box
    assert np.all((layouts.half_extents[box] >= 0.12) & (layouts.half_extents[box] <= 0.4))
    assert np.all((layouts.radius[cyl] >= 0.1) & (layouts.radius[cyl] <= 0.3))
    # a free route, checked by the single-robot grid search on a sample of robots
    for i in np.random.default_rng(0).choice(n, size=25, replace=False):
        assert free_route_exists(
            list(env.obstacles[i]), start[i, :2], goal[i, :2], radius + 0.02, h
        )


def test_batched_route_check_is_the_single_robot_grid_search() -> None:
    """Crowded layouts, random endpoints and a wide disc: routes both found and blocked,
    each decided as ``free_route_exists`` decides it."""
    n = 40
    env = WheeledNavVecEnv(num_envs=n, n_obstacles=14)
    env.reset(seed=5)
    rng = np.random.default_rng(1)
    start, goal = rng.uniform(-3.3, 3.3, (n, 2)), rng.uniform(-3.3, 3.3, (n, 2))
    got = free_routes(env.obstacles.arrays, start, goal, 0.3, env.room_half_size)
    want = [
        free_route_exists(list(env.obstacles[i])[4:], start[i], goal[i], 0.3, env.room_half_size)
        for i in range(n)
    ]
    np.testing.assert_array_equal(got, want)
    assert 0 < got.sum() < n


def test_autoreset_draws_the_next_episode_from_the_robots_stream() -> None:
    env = WheeledNavVecEnv(num_envs=40, max_episode_steps=3)
    env.reset(seed=9)
    for _ in range(3):
        _, _, term, trunc, _ = env.step(np.zeros((40, 2)))
    assert np.all(term | trunc)
    task, radius = NavTask(), env.true_params.body_radius
    for i in (0, 17, 39):
        rng = np.random.default_rng(9 + i)
        for _ in range(2):  # the first episode, then the one autoreset started
            start, goal = task.sample_start_goal(rng, {}, radius)
            arena = task.sample_arena(rng, start, goal, radius)
        np.testing.assert_array_equal(env.pose[i], start)
        assert env.obstacles[i] == arena


def test_robot_streams_are_the_generators_draws_across_refills() -> None:
    streams = RobotStreams([5, 6, 7], width=4)
    rows = np.array([0, 2])
    got = np.hstack([streams.take(rows, 3) for _ in range(5)])
    want = np.stack([np.random.default_rng(s).random(15) for s in (5, 7)])
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(
        streams.take(np.array([1]), 2)[0], np.random.default_rng(6).random(2)
    )
    with pytest.raises(ValueError, match="exceeds the buffer width"):
        streams.take(rows, 5)


def test_layouts_before_reset_are_empty_and_index_as_a_sequence() -> None:
    env = WheeledNavVecEnv(num_envs=3)
    assert len(env.obstacles) == 3 and env.obstacles[0] == () and list(env.obstacles) == [()] * 3
    env.reset(seed=0)
    assert env.obstacles[-1] == env.obstacles[2] and len(env.obstacles[0]) == 4 + 6
    assert env.obstacles[0:2] == [env.obstacles[0], env.obstacles[1]]
    with pytest.raises(IndexError):
        env.obstacles[3]


# ---------------------------------------------------------------------- cost
def test_an_impossible_size_is_refused_before_anything_is_allocated() -> None:
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=r"num_envs .*fits in memory.*got 1000000000000") as e:
            WheeledNavVecEnv(num_envs=10**12)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 5 * 2**20  # bytes: nothing per robot was allocated
    assert "GiB available" in str(e.value) and "Fix: pass num_envs=" in str(e.value)


def test_the_refusal_names_a_size_that_fits(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(vector_nav, "available_memory_bytes", lambda: 2**30)
    with pytest.raises(ValueError, match=r"expected num_envs <= (\d+)") as e:
        check_vector_cost(10**6)
    fits = int(str(e.value).split("num_envs <= ")[1].split(" ")[0])
    assert estimate_vector_cost(fits).bytes <= 2**30 < estimate_vector_cost(fits + 1).bytes
    suggested = int(str(e.value).split("Fix: pass num_envs=")[1].split(" ")[0])
    assert 1 <= suggested <= fits


def test_a_large_size_is_warned_about_with_its_estimate(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(vector_nav, "available_memory_bytes", lambda: 2**50)
    with pytest.warns(UserWarning, match=r"num_envs=400000: estimated ~\d+\.\d+ GiB .* per reset"):
        cost = check_vector_cost(400_000)
    assert cost.bytes > vector_nav.WARN_BYTES
    with pytest.warns(UserWarning, match="per reset"):
        check_vector_cost(200_000, n_beams=512)  # large step: the ray cast
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_vector_cost(1000)


def test_the_estimate_grows_with_the_per_robot_arrays() -> None:
    one = estimate_vector_cost(1)
    big = estimate_vector_cost(1000)
    assert big.bytes - one.bytes == 999 * one.bytes_per_robot
    assert big.reset_s == pytest.approx(1000 * one.reset_s)
    assert estimate_vector_cost(1, n_beams=128).bytes_per_robot > one.bytes_per_robot
    assert estimate_vector_cost(1, n_obstacles=0).reset_s < one.reset_s
    # at least the env's own per-robot state: pose, estimate, goal, scan, stream buffer
    assert one.bytes_per_robot > 8 * (3 + 3 + 3 + 64 + 64)


@pytest.mark.parametrize(
    "bad, what",
    [(2.5, "float"), (True, "bool"), ("64", "str"), (None, "NoneType"), (64.0, "float")],
)
def test_a_num_envs_of_the_wrong_kind_is_refused_naming_it(bad: object, what: str) -> None:
    with pytest.raises(ValueError, match=rf"num_envs must be a whole number.*\({what}\).*Fix"):
        WheeledNavVecEnv(num_envs=bad)


@pytest.mark.parametrize("bad", [0, -3])
def test_a_num_envs_below_one_is_refused(bad: int) -> None:
    with pytest.raises(
        ValueError, match=rf"num_envs must be a whole number of robots >= 1, got {bad}"
    ):
        WheeledNavVecEnv(num_envs=bad)
