"""Log-odds occupancy grid: a known square room, closed-form updates, clamping."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.estimators.base import Scan
from realitygap.estimators.occupancy import OccupancyGrid

HALF_SIDE = 2.02  # room walls at x, y = ±2.02 m (inside cells, not on their borders)
RES = 0.05


def room_ranges(pose: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Exact ranges from ``pose`` to the walls of the square room, per beam."""
    bearing = pose[2] + angles
    c, s = np.cos(bearing), np.sin(bearing)
    with np.errstate(divide="ignore"):
        tx = np.where(c != 0, (np.sign(c) * HALF_SIDE - pose[0]) / c, np.inf)
        ty = np.where(s != 0, (np.sign(s) * HALF_SIDE - pose[1]) / s, np.inf)
    return np.minimum(tx, ty)


def room_scan(pose: np.ndarray, n_beams: int = 720, range_max: float = 8.0) -> Scan:
    angles = np.linspace(-np.pi, np.pi, n_beams, endpoint=False)
    return Scan(0.0, angles, room_ranges(pose, angles), 0.0, range_max)


def wall_distance(xy: np.ndarray) -> np.ndarray:
    return HALF_SIDE - np.max(np.abs(xy), axis=-1)


@pytest.fixture(scope="module")
def mapped_room() -> OccupancyGrid:
    grid = OccupancyGrid(resolution=RES, size_m=(6.0, 6.0))
    rng = np.random.default_rng(0)
    for _ in range(6):
        pose = np.r_[rng.uniform(-1.2, 1.2, 2), rng.uniform(-np.pi, np.pi)]
        grid.update(pose, room_scan(pose))
    return grid


def test_walls_occupied_interior_free(mapped_room: OccupancyGrid) -> None:
    grid = mapped_room
    occupied = grid.occupied_points()
    # every occupied cell is a wall cell ...
    assert len(occupied) > 0
    assert np.all(np.abs(wall_distance(occupied)) <= RES * np.sqrt(2) / 2 + 1e-9)
    # ... and every wall cell is occupied: sample the walls every 1 cm
    s = np.arange(-HALF_SIDE + 0.01, HALF_SIDE, 0.01)
    walls = np.concatenate(
        [np.stack([np.full_like(s, x), s], -1) for x in (-HALF_SIDE, HALF_SIDE)]
        + [np.stack([s, np.full_like(s, y)], -1) for y in (-HALF_SIDE, HALF_SIDE)]
    )
    assert np.all(grid.is_occupied(walls))
    # interior cells are free, outside cells unknown
    iy, ix = np.mgrid[0 : grid.ny, 0 : grid.nx]
    centres = grid.world_from_cell(ix, iy)
    p = grid.probability()
    interior = wall_distance(centres) > 2 * RES
    outside = wall_distance(centres) < -2 * RES
    assert np.all(p[interior] < 0.35)
    assert np.all(p[outside] == 0.5)


def test_single_beam_closed_form() -> None:
    grid = OccupancyGrid(resolution=0.1, size_m=(4.0, 4.0), l_occ=0.9, l_free=-0.3)
    # beam along +x from (0.05, 0.05): crosses cells centred at x = 0.05 … 0.95, hits 1.05
    grid.update([0.05, 0.05, 0.0], Scan(0.0, np.array([0.0]), np.array([1.0]), 0.0, 5.0))
    row = grid.log_odds[20]
    np.testing.assert_allclose(row[20:30], -0.3)
    assert row[30] == pytest.approx(0.9)
    assert np.count_nonzero(grid.log_odds) == 11


def test_log_odds_clamped() -> None:
    grid = OccupancyGrid(resolution=RES, size_m=(6.0, 6.0), l_min=-2.0, l_max=3.0)
    pose = np.array([0.3, -0.4, 0.2])
    scan = room_scan(pose)
    for _ in range(30):
        grid.update(pose, scan)
        assert grid.log_odds.min() >= -2.0 and grid.log_odds.max() <= 3.0
    assert grid.log_odds.min() == -2.0 and grid.log_odds.max() == 3.0
    # a clamped cell flips after a bounded number of contrary observations
    target = np.array([[HALF_SIDE, 0.0]])
    assert grid.is_occupied(target)[0]
    moved = Scan(0.0, np.array([0.0]), np.array([HALF_SIDE + 0.5]), 0.0, 8.0)
    n_flip = int(np.ceil((3.0 - np.log(0.65 / 0.35)) / -grid.l_free)) + 1
    for _ in range(n_flip):
        grid.update([0.0, 0.0, 0.0], moved)
    assert not grid.is_occupied(target)[0]


def test_no_return_beams() -> None:
    scan = Scan(0.0, np.array([0.0, np.pi / 2]), np.array([np.inf, 5.0]), 0.0, 2.0)
    grid = OccupancyGrid(resolution=0.1, size_m=(6.0, 6.0))
    grid.update([0.0, 0.0, 0.0], scan)
    assert not np.any(grid.log_odds)  # inf and ≥ range_max are no return: nothing known
    grid.update([0.0, 0.0, 0.0], scan, free_no_return=True)
    free = grid.log_odds < 0
    assert free.sum() == 2 * 20 - 1  # two beams of 2 m over 0.1 m cells, sharing the first
    assert not np.any(grid.log_odds > 0)


def test_hit_overrides_traversal_in_one_scan() -> None:
    grid = OccupancyGrid(resolution=0.1, size_m=(4.0, 4.0))
    # the second beam passes through the first beam's end cell
    scan = Scan(0.0, np.array([0.0, 0.0]), np.array([0.55, 1.5]), 0.0, 5.0)
    grid.update([0.0, 0.0, 0.0], scan)
    assert grid.is_occupied([0.55, 0.0]) and grid.is_occupied([1.5, 0.0])
    assert grid.log_odds.max() == pytest.approx(grid.l_occ)  # each cell once per scan


def test_beams_leaving_the_grid_are_clipped() -> None:
    grid = OccupancyGrid(resolution=0.1, size_m=(2.0, 2.0))
    grid.update([0.0, 0.0, 0.3], Scan(0.0, np.linspace(-3, 3, 50), np.full(50, 5.0), 0.0, 8.0))
    assert not np.any(grid.log_odds > 0)
    assert np.any(grid.log_odds < 0)


def test_queries_and_reset(mapped_room: OccupancyGrid) -> None:
    grid = OccupancyGrid(resolution=RES, size_m=(6.0, 6.0), origin_xy=(-3.0, -3.0))
    assert grid.shape == (120, 120)
    ix, iy, inside = grid.cell_from_world([[0.01, -0.01], [3.5, 0.0]])
    np.testing.assert_array_equal(ix, [60, 130])
    np.testing.assert_array_equal(iy, [59, 60])
    np.testing.assert_array_equal(inside, [True, False])
    np.testing.assert_allclose(grid.world_from_cell(60, 59), [0.025, -0.025])
    assert grid.is_occupied([100.0, 0.0]) is False
    assert grid.occupied_points().shape == (0, 2)
    np.testing.assert_array_equal(grid.probability(), 0.5)
    pose = np.array([0.1, 0.2, 0.3])
    grid.update(pose, room_scan(pose))
    assert len(grid.occupied_points()) > 0
    with pytest.raises(ValueError, match="read-only"):
        grid.log_odds[0, 0] = 1.0
    grid.reset()
    assert not np.any(grid.log_odds)


def test_errors() -> None:
    with pytest.raises(ValueError, match="resolution must be a positive cell size in m, got 0"):
        OccupancyGrid(resolution=0)
    with pytest.raises(ValueError, match="need l_occ > 0 and l_free < 0"):
        OccupancyGrid(l_free=0.2)
    with pytest.raises(ValueError, match="need l_min < 0 < l_max"):
        OccupancyGrid(l_min=1.0)
    with pytest.raises(ValueError, match=r"size_m must have shape \(2,\)"):
        OccupancyGrid(size_m=(1.0, 2.0, 3.0))  # type: ignore[arg-type]
    grid = OccupancyGrid()
    with pytest.raises(
        ValueError, match=r"scan\.angles and scan\.ranges must be 1-D of equal length"
    ):
        grid.update([0, 0, 0], Scan(0.0, np.zeros(3), np.ones(2), 0.0, 1.0))
    with pytest.raises(ValueError, match="must not contain nan"):
        grid.update([0, 0, 0], Scan(0.0, np.zeros(1), np.array([np.nan]), 0.0, 1.0))
    with pytest.raises(ValueError, match=r"pose must have shape \(3,\)"):
        grid.update([0, 0], Scan(0.0, np.zeros(1), np.ones(1), 0.0, 2.0))
    with pytest.raises(TypeError, match="scan must be a Scan"):
        grid.update([0, 0, 0], np.ones(3))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"threshold must be a probability in \(0, 1\), got 1.2"):
        grid.occupied_points(threshold=1.2)
    with pytest.raises(ValueError, match=r"xy must have shape \(..., 2\)"):
        grid.is_occupied([1.0, 2.0, 3.0])
