"""Grid reference path length among obstacle points."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from realitygap.controllers.paths import grid_shortest_path_length, points_from_occupancy

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


def test_grid_length_in_free_space_is_the_straight_distance() -> None:
    assert grid_shortest_path_length([0, 0], [3, 4], NO_OBSTACLES) == pytest.approx(5.0)


def test_grid_length_around_a_wall_matches_the_closed_form() -> None:
    r = 0.22
    points = wall((0, -1), (0, 1), spacing=0.01)
    # Shortest path from (-1, 0) to (1, 0) wraps round the disc of radius r at the wall end (0, 1).
    d = math.sqrt(2.0)
    exact = 2 * math.sqrt(d * d - r * r) + r * (1.5 * math.pi - 2 * math.acos(r / d))
    length = grid_shortest_path_length([-1, 0], [1, 0], points, resolution=0.05, inflation_radius=r)
    assert exact - 1e-9 <= length <= 1.03 * exact


def test_grid_length_is_infinite_when_blocked() -> None:
    points = ring([0.0, 0.0], 0.8)
    assert grid_shortest_path_length([0, 0], [2, 0], points) == math.inf
    assert grid_shortest_path_length([0, 0], [0.8, 0], points) == math.inf  # goal in an obstacle


def test_grid_length_from_occupancy_grid() -> None:
    occupancy = np.zeros((40, 40), dtype=bool)
    occupancy[0:30, 20] = True  # a wall x ∈ [1.0, 1.05], y ∈ [0, 1.5] (cells of 5 cm)
    points = points_from_occupancy(occupancy, 0.05, [0.0, 0.0])
    assert points.shape == (30, 2)
    np.testing.assert_allclose(points[0], [1.025, 0.025])
    length = grid_shortest_path_length(
        [0.5, 0.5], [1.5, 0.5], points, inflation_radius=0.1, bounds=(0.0, 0.0, 2.0, 2.0)
    )
    assert 2 * math.hypot(0.5, 1.0) < length < 2.6


def test_grid_length_bad_input() -> None:
    with pytest.raises(ValueError, match="outside bounds"):
        grid_shortest_path_length([5, 0], [1, 0], NO_OBSTACLES, bounds=(0.0, 0.0, 2.0, 2.0))
    with pytest.raises(ValueError, match="resolution must be finite and > 0"):
        grid_shortest_path_length([0, 0], [1, 0], NO_OBSTACLES, resolution=0.0)
    with pytest.raises(ValueError, match="exceeds max_cells"):
        grid_shortest_path_length([0, 0], [9, 9], [[5.0, 5.0]], resolution=0.001, max_cells=1000)
