"""The privileged shortest-path teacher of WheeledNav demonstrations."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401
from realitygap.baselines.imitation import DemoSettings, pretrain
from realitygap.baselines.privileged import GeodesicField, GeodesicNavConfig, GeodesicNavExpert
from realitygap.envs.layouts import clearance, room_walls
from realitygap.robots.world import Primitive, Shape

ENV_ID = "realitygap/WheeledNav-v0"


def _octile(a: np.ndarray, b: np.ndarray) -> float:
    dx, dy = np.abs(a - b)
    return float(max(dx, dy) + (math.sqrt(2.0) - 1.0) * min(dx, dy))


def test_cost_to_go_in_open_space_is_the_octile_distance() -> None:
    # far from the walls every move costs its length: Dijkstra on the 8-connected grid
    # gives the octile distance exactly
    field = GeodesicField(room_walls(3.0), 3.0, (0.5, -0.25), robot_radius=0.2, resolution=0.05)
    goal = np.array([0.5, -0.25])
    for xy in ([-1.0, 1.0], [1.5, 0.75], [0.5, 1.2], [-1.2, -1.0]):
        i, j = field.cell(xy)
        assert field.cost_to_go[i, j] == pytest.approx(_octile(np.array(xy), goal), abs=1e-9)


def test_paths_go_round_a_wall_and_keep_their_clearance() -> None:
    wall = Primitive("wall", Shape.BOX, (0.0, 0.0), 0.5, half_extents=(0.1, 1.5))
    prims = [*room_walls(3.0), wall]
    field = GeodesicField(prims, 3.0, (1.5, 0.0), robot_radius=0.2, margin=0.05)
    start = np.array([-1.5, 0.0])
    # follow carrots from the start: the robot's centre never comes within the blocked band
    p = start.copy()
    for _ in range(200):
        carrot, togo = field.carrot(p, 0.3)
        if togo < 1e-9:
            break
        p = p + min(0.05, float(np.hypot(*(carrot - p)))) * (carrot - p) / np.hypot(*(carrot - p))
        assert float(clearance(prims, p)) > 0.2
    assert np.hypot(*(p - [1.5, 0.0])) < 0.06
    # the straight line is blocked: the shortest way passes the wall's end (y = ±1.5) with
    # the clearance of the robot, so it is longer than two legs to (0, ±1.7)
    i, j = field.cell(start)
    assert field.cost_to_go[i, j] > 2.0 * math.hypot(1.5, 1.7)


def test_bad_field_input_is_refused() -> None:
    with pytest.raises(ValueError, match="goal_xy must be 2 finite numbers"):
        GeodesicField([], 3.0, (0.0, math.nan), 0.2)
    with pytest.raises(ValueError, match="resolution must lie in"):
        GeodesicField([], 3.0, (0.0, 0.0), 0.2, resolution=0.0)
    with pytest.raises(ValueError, match=r"GeodesicNavConfig\.lookahead must be > 0"):
        GeodesicNavConfig(lookahead=-0.1)
    with pytest.raises(ValueError, match="min_speed_fraction must be in \\(0, 1\\]"):
        GeodesicNavConfig(min_speed_fraction=1.5)
    with pytest.raises(ValueError, match=r"align_radius .* must be below stabilise_radius"):
        GeodesicNavConfig(align_radius=0.3)
    with pytest.raises(TypeError, match="needs a WheeledNav env"):
        GeodesicNavExpert(gym.make("CartPole-v1"))


@pytest.mark.slow
def test_expert_reaches_the_goal_pose_without_collision() -> None:
    env = gym.make(ENV_ID, n_obstacles=6)
    expert = GeodesicNavExpert(env)
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        start, done = True, False
        while not done:
            action, _ = expert.predict(obs, episode_start=np.array([start]))
            start = False
            obs, _, term, trunc, info = env.step(action)
            done = term or trunc
        assert info["is_success"] and not info["collision"], (seed, info["pos_error"])
    env.close()


def test_expert_command_is_a_function_of_the_observation() -> None:
    # the same observation gets the same command whatever came before it
    env = gym.make(ENV_ID, n_obstacles=6)
    expert = GeodesicNavExpert(env)
    obs, _ = env.reset(seed=3)
    first, _ = expert.predict(obs, episode_start=np.array([True]))
    history = []
    rng = np.random.default_rng(0)
    for _ in range(40):
        history.append(obs)
        obs, *_ = env.step(rng.uniform(-1.0, 1.0, 2).astype(np.float32))
    for past in history[::7]:
        expert.predict(past)
        again, _ = expert.predict(history[0])
        np.testing.assert_array_equal(again, first)
    env.close()


def test_geodesic_expert_is_refused_for_an_env_without_one() -> None:
    settings = DemoSettings(expert="geodesic")
    with pytest.raises(
        ValueError, match="no demonstration expert 'geodesic' for realitygap/ArmCalib"
    ):
        pretrain(None, "realitygap/ArmCalib-v0", {}, None, settings, 0, 0.99, None)


def test_carrot_is_seen_along_a_free_segment() -> None:
    # a robot beside a post, off its path: steering at the carrot must not cross the post
    post = Primitive("post", Shape.CYLINDER, (0.0, 0.0), 0.5, radius=0.3)
    prims = [*room_walls(3.0), post]
    field = GeodesicField(prims, 3.0, (1.5, 0.0), robot_radius=0.2)
    assert not field.visible((-1.0, 0.0), (1.0, 0.0))
    assert field.visible((-1.0, 0.8), (1.0, 0.8))
    for xy in ([-0.6, 0.1], [-0.6, -0.1], [-0.2, 0.6], [0.3, -0.6]):
        carrot, _ = field.carrot(xy, 1.0)
        assert field.visible(xy, carrot), (xy, carrot)


def test_final_turn_has_a_floor_and_stops_inside_the_band() -> None:
    env = gym.make(ENV_ID, n_obstacles=0)
    expert = GeodesicNavExpert(env)
    c = expert.config
    obs, _ = env.reset(seed=0, options={"start": [0.0, 0.0, 0.0], "goal": [0.005, 0.0, 0.0]})
    obs = np.array(obs)
    for heading_deg, turning in ((-4.0, True), (3.0, True), (2.0, False), (-2.0, False)):
        th = math.radians(heading_deg)
        obs[2:4] = (math.cos(th), math.sin(th))
        v, w = expert.predict(obs)[0]
        assert v == 0.0
        if turning:
            # turns towards the goal heading (0), at least align_min_rate
            assert np.sign(w) == -np.sign(heading_deg)
            assert abs(w) * env.unwrapped.w_max >= c.align_min_rate - 1e-6
        else:
            assert w == 0.0
    env.close()
