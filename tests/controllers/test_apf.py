"""Properties of the improved potential-field planner."""

from __future__ import annotations

import itertools
import math

import numpy as np
import numpy.typing as npt
import pytest
from scipy.spatial import cKDTree

from realitygap.controllers import (
    APFOutcome,
    APFParams,
    ImprovedAPF,
    path_length,
    segment_clearance,
    shortcut_waypoints,
)

FloatArray = npt.NDArray[np.float64]
NO_OBSTACLES = np.zeros((0, 2))


def wall(a: npt.ArrayLike, b: npt.ArrayLike, spacing: float = 0.02) -> FloatArray:
    """Points every ``spacing`` m from ``a`` to ``b`` (both included)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    count = max(2, math.ceil(float(np.linalg.norm(b - a)) / spacing) + 1)
    return a + np.linspace(0.0, 1.0, count)[:, None] * (b - a)


def ring(centre: npt.ArrayLike, radius: float, spacing: float = 0.02) -> FloatArray:
    count = max(8, math.ceil(2 * math.pi * radius / spacing))
    angle = np.linspace(0.0, 2 * math.pi, count, endpoint=False)
    c = np.asarray(centre, dtype=float)
    return np.column_stack([c[0] + radius * np.cos(angle), c[1] + radius * np.sin(angle)])


def u_trap() -> FloatArray:
    """A U open towards -x, 1 m deep and 1.6 m wide; a goal at +x lies behind it."""
    return np.vstack(
        [wall((0, -0.8), (1, -0.8)), wall((1, -0.8), (1, 0.8)), wall((1, 0.8), (0, 0.8))]
    )


def clutter(rng: np.random.Generator) -> FloatArray:
    """A 6 m room with a few random discs and walls."""
    h = 3.0
    parts = [
        wall((-h, -h), (h, -h)),
        wall((h, -h), (h, h)),
        wall((h, h), (-h, h)),
        wall((-h, h), (-h, -h)),
    ]
    for _ in range(int(rng.integers(2, 6))):
        if rng.random() < 0.5:
            parts.append(ring(rng.uniform(-2, 2, 2), float(rng.uniform(0.1, 0.5))))
        else:
            a = rng.uniform(-2.5, 2.5, 2)
            angle = rng.uniform(0, math.pi)
            parts.append(
                wall(a, a + rng.uniform(0.5, 2.0) * np.array([math.cos(angle), math.sin(angle)]))
            )
    return np.vstack(parts)


def assert_clear_of_inflation(waypoints: FloatArray, points: FloatArray, inflation: float) -> None:
    """Every way-point and every segment between way-points is outside the inflated points."""
    if len(points) == 0:
        return
    assert float(np.min(cKDTree(points).query(waypoints)[0])) > inflation
    for a, b in itertools.pairwise(waypoints):
        assert segment_clearance(a, b, points) > inflation


# -- forces -----------------------------------------------------------------------------------


@pytest.mark.parametrize("exponent", [0.0, 1.0, 2.0, 3.0])
def test_forces_match_closed_form_and_are_minus_gradient(exponent: float) -> None:
    params = APFParams(goal_exponent=exponent, repulsive_gain=0.05)
    planner = ImprovedAPF(params)
    obstacle = np.array([[1.0, 0.4]])
    goal = np.array([2.0, -0.5])
    rng = np.random.default_rng(0)
    r, rho0, eta, eps = (
        params.inflation_radius, params.influence_distance, params.repulsive_gain,
        params.attractive_gain,
    )  # fmt: skip

    def potential(q: FloatArray) -> float:
        rho_goal = float(np.linalg.norm(goal - q))
        rho = float(np.linalg.norm(q - obstacle[0])) - r
        repulsive = (
            0.5 * eta * (1 / rho - 1 / rho0) ** 2 * rho_goal**exponent if rho <= rho0 else 0.0
        )
        return 0.5 * eps * rho_goal**2 + repulsive

    checked = 0
    while checked < 10:
        q = obstacle[0] + rng.uniform(-0.75, 0.75, 2)
        clearance = float(np.linalg.norm(q - obstacle[0])) - r
        if not 0.05 < clearance < rho0 - 0.02:
            continue
        attractive, repulsive = planner.forces(q, goal, obstacle)
        rho_goal = float(np.linalg.norm(goal - q))
        n_or = (q - obstacle[0]) / np.linalg.norm(q - obstacle[0])
        n_rg = (goal - q) / rho_goal
        gap = 1 / clearance - 1 / rho0
        f_rep1 = eta * gap * rho_goal**exponent / clearance**2
        f_rep2 = 0.5 * exponent * eta * gap**2 * rho_goal ** (exponent - 1)
        np.testing.assert_allclose(attractive, eps * (goal - q), rtol=1e-12)
        np.testing.assert_allclose(repulsive, f_rep1 * n_or + f_rep2 * n_rg, rtol=1e-10)
        h = 1e-6
        gradient = np.array(
            [(potential(q + h * e) - potential(q - h * e)) / (2 * h) for e in np.eye(2)]
        )
        np.testing.assert_allclose(attractive + repulsive, -gradient, rtol=1e-5, atol=1e-7)
        checked += 1


def test_no_repulsion_beyond_influence_distance() -> None:
    params = APFParams()
    far = params.inflation_radius + params.influence_distance + 0.01
    _, repulsive = ImprovedAPF(params).forces([0.0, 0.0], [1.0, 1.0], [[far, 0.0]])
    np.testing.assert_array_equal(repulsive, 0.0)


def test_repulsion_does_not_grow_with_point_density() -> None:
    planner = ImprovedAPF()
    q, goal = [0.5, 0.3], [0.0, 1.5]
    _, coarse = planner.forces(q, goal, wall((1, -2), (1, 2), spacing=0.005))
    _, fine = planner.forces(q, goal, wall((1, -2), (1, 2), spacing=0.001))
    # Five times the points: the force converges instead of growing five-fold.
    assert np.linalg.norm(fine - coarse) < 0.03 * np.linalg.norm(coarse)


def test_improved_field_points_to_a_goal_near_an_obstacle_where_the_classical_one_does_not() -> (
    None
):
    points = wall((1.0, -1.0), (1.0, 1.0))
    goal = np.array([0.75, 0.0])  # 3 cm from the inflated wall
    q = goal - np.array([0.03, 0.0])
    improved = ImprovedAPF(APFParams(goal_exponent=2.0))
    classical = ImprovedAPF(APFParams(goal_exponent=0.0))
    assert float(np.sum(improved.forces(q, goal, points), axis=0) @ (goal - q)) > 0.0
    assert float(np.sum(classical.forces(q, goal, points), axis=0) @ (goal - q)) < 0.0


# -- planning ---------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(5))
def test_free_space_path_is_straight_and_monotone(seed: int) -> None:
    rng = np.random.default_rng(seed)
    start, goal = rng.uniform(-3, 3, (2, 2))
    params = APFParams()
    result = ImprovedAPF(params).plan(start, goal, NO_OBSTACLES)
    assert result.reached and not result.gave_up
    assert result.reason is APFOutcome.REACHED and result.reason == "reached"
    assert result.stuck_events == 0
    np.testing.assert_array_equal(result.waypoints[0], start)
    np.testing.assert_array_equal(result.waypoints[-1], goal)
    distance = np.linalg.norm(result.waypoints - goal, axis=1)
    assert np.all(np.diff(distance) < 0.0)
    steps = np.linalg.norm(np.diff(result.waypoints, axis=0), axis=1)
    assert np.all(steps <= params.step_length + 1e-12)
    np.testing.assert_allclose(
        path_length(result.waypoints), np.linalg.norm(goal - start), rtol=1e-9
    )


def test_goal_close_to_obstacle_is_reached_by_the_improved_field_only() -> None:
    points = wall((1.0, -1.0), (1.0, 1.0))
    start, goal = np.array([-0.5, 0.2]), np.array([0.75, 0.0])
    improved = ImprovedAPF(APFParams(goal_exponent=2.0)).plan(start, goal, points)
    assert improved.reached and improved.stuck_events == 0
    np.testing.assert_array_equal(improved.waypoints[-1], goal)
    classical = ImprovedAPF(APFParams(goal_exponent=0.0, max_escapes=0)).plan(start, goal, points)
    assert not classical.reached and classical.gave_up
    assert classical.stuck_events == 1
    assert classical.reason is APFOutcome.ESCAPES_EXHAUSTED
    # It stalls where attraction and repulsion balance, well short of the goal.
    assert np.linalg.norm(classical.waypoints[-1] - goal) > 0.1


def test_u_trap_local_minimum_is_detected_and_escaped() -> None:
    points = u_trap()
    params = APFParams()
    result = ImprovedAPF(params).plan([-1.5, 0.0], [2.0, 0.0], points)
    assert result.stuck_events >= 1
    assert result.reached, result.reason
    assert result.escapes == result.stuck_events
    assert_clear_of_inflation(result.waypoints, points, params.inflation_radius)
    assert len(result.waypoints) <= params.max_iterations + 2


def test_u_trap_without_escapes_gives_up() -> None:
    points = u_trap()
    result = ImprovedAPF(APFParams(max_escapes=0)).plan([-1.5, 0.0], [2.0, 0.0], points)
    assert (result.reached, result.gave_up, result.stuck_events) == (False, True, 1)
    assert result.reason is APFOutcome.ESCAPES_EXHAUSTED
    # Stuck inside the U, short of its bottom.
    assert 0.0 < result.waypoints[-1][0] < 1.0 - APFParams().inflation_radius


def test_unreachable_goal_terminates_and_reports_giving_up() -> None:
    points = ring([2.0, 0.0], 0.8)  # the goal is fenced in
    params = APFParams(max_iterations=1500)
    result = ImprovedAPF(params).plan([-1.0, 0.0], [2.0, 0.0], points)
    assert not result.reached and result.gave_up
    assert result.reason in (APFOutcome.ESCAPES_EXHAUSTED, APFOutcome.ITERATION_LIMIT)
    assert result.stuck_events >= 1
    assert len(result.waypoints) <= params.max_iterations + 1
    assert_clear_of_inflation(result.waypoints, points, params.inflation_radius)


def test_goal_inside_inflated_obstacle_is_reported() -> None:
    result = ImprovedAPF().plan([0.0, 0.0], [1.0, 0.0], [[1.1, 0.0]])
    assert result.reason is APFOutcome.GOAL_BLOCKED
    assert result.gave_up and not result.reached
    assert result.waypoints.shape == (1, 2)


def test_start_inside_inflation_leaves_it_first() -> None:
    params = APFParams()
    points = wall((0.1, -1.0), (0.1, 1.0))  # 10 cm from the start
    result = ImprovedAPF(params).plan([0.0, 0.0], [-1.0, 0.5], points)
    assert result.reached
    clearance = cKDTree(points).query(result.waypoints)[0] - params.inflation_radius
    inside = np.nonzero(clearance <= 0.0)[0]
    assert inside.tolist() == list(range(len(inside)))  # only a prefix is inside
    assert np.all(np.diff(clearance[: len(inside) + 1]) > 0.0)
    assert_clear_of_inflation(result.waypoints[len(inside) :], points, params.inflation_radius)


@pytest.mark.parametrize("seed", range(12))
def test_waypoints_stay_outside_inflated_obstacles_in_clutter(seed: int) -> None:
    rng = np.random.default_rng(seed)
    points = clutter(rng)
    tree = cKDTree(points)
    while True:
        start, goal = rng.uniform(-2.6, 2.6, (2, 2))
        if (
            min(tree.query(start)[0], tree.query(goal)[0]) > 0.25
            and np.linalg.norm(goal - start) > 1
        ):
            break
    params = APFParams()
    result = ImprovedAPF(params).plan(start, goal, points)
    assert result.reached != result.gave_up
    assert len(result.waypoints) <= params.max_iterations + 2
    assert_clear_of_inflation(result.waypoints, points, params.inflation_radius)
    shortened = shortcut_waypoints(result.waypoints, points, params.inflation_radius)
    np.testing.assert_array_equal(shortened[[0, -1]], result.waypoints[[0, -1]])
    assert path_length(shortened) <= path_length(result.waypoints) + 1e-9
    assert_clear_of_inflation(shortened, points, params.inflation_radius)


def test_plan_is_deterministic() -> None:
    points = u_trap()
    first = ImprovedAPF().plan([-1.5, 0.0], [2.0, 0.0], points)
    second = ImprovedAPF().plan([-1.5, 0.0], [2.0, 0.0], points)
    np.testing.assert_array_equal(first.waypoints, second.waypoints)
    assert first.stuck_events == second.stuck_events


@pytest.mark.parametrize(
    ("start", "goal", "points", "match"),
    [
        ([np.nan, 0.0], [1.0, 0.0], None, "start_xy must be finite"),
        ([0.0, 0.0], [1.0, 0.0, 0.0], None, r"goal_xy must have shape \(2,\)"),
        ([0.0, 0.0], [1.0, 0.0], np.zeros((4, 3)), r"obstacle_points must have shape \(M, 2\)"),
        ([0.0, 0.0], [1.0, 0.0], [[1.0, np.inf]], "obstacle_points must be finite"),
    ],
)
def test_bad_input_raises(start: object, goal: object, points: object, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ImprovedAPF().plan(start, goal, points)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("step_length", 0.0, "step_length must be finite and > 0"),
        ("influence_distance", math.nan, "influence_distance must be finite and > 0"),
        ("repulsive_gain", -1.0, "repulsive_gain must be finite and >= 0"),
        ("max_iterations", 0, "max_iterations must be an integer >= 1"),
        ("max_escapes", -1, "max_escapes must be an integer >= 0"),
    ],
)
def test_bad_params_raise(field: str, value: float, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        APFParams(**{field: value})
