"""Obstacle layouts for the wheeled navigation task.

A layout is a list of :class:`~realitygap.robots.world.Primitive` standing in a
square room. Random layouts are drawn from a generator handed down by the env
and are checked to leave a collision-free route from start to goal for a robot
of the given radius (grid breadth-first search on the inflated footprints).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from realitygap.robots.world import Primitive, Shape

FloatArray = npt.NDArray[np.float64]


def room_walls(half_size: float, height: float = 2.0, thickness: float = 0.1) -> list[Primitive]:
    """Four walls enclosing the square ``[-half_size, half_size]²`` (inner faces).

    They stand ``height`` m high (2 m by default, so that the camera sees wall, not
    sky, above the obstacles out to the far side of the room).
    """
    h, t = half_size, thickness / 2.0
    return [
        Primitive("wall_n", Shape.BOX, (0.0, h + t), height, half_extents=(h + 2 * t, t)),
        Primitive("wall_s", Shape.BOX, (0.0, -h - t), height, half_extents=(h + 2 * t, t)),
        Primitive("wall_e", Shape.BOX, (h + t, 0.0), height, half_extents=(t, h + 2 * t)),
        Primitive("wall_w", Shape.BOX, (-h - t, 0.0), height, half_extents=(t, h + 2 * t)),
    ]


def clearance(primitives: list[Primitive], xy: npt.ArrayLike) -> FloatArray:
    """Distance (m) from points ``xy`` (..., 2) to the nearest primitive footprint."""
    xy = np.asarray(xy, dtype=float)
    if not primitives:
        return np.full(xy.shape[:-1], np.inf)
    return np.min(np.stack([p.footprint_distance(xy) for p in primitives]), axis=0)


def outline_points(primitives: list[Primitive], spacing: float = 0.02) -> FloatArray:
    """Points every ``spacing`` m on the footprint outlines of ``primitives`` (m, world
    frame): the true map a planner or a reference path length is judged against."""
    pts = []
    for prim in primitives:
        if prim.shape.value == "cylinder":
            n = max(8, int(2 * math.pi * prim.radius / spacing))
            a = np.linspace(0, 2 * math.pi, n, endpoint=False)
            pts.append(np.stack([np.cos(a), np.sin(a)], 1) * prim.radius + np.asarray(prim.center))
            continue
        hx, hy = prim.half_extents
        nx, ny = max(2, int(2 * hx / spacing) + 1), max(2, int(2 * hy / spacing) + 1)
        xs, ys = np.linspace(-hx, hx, nx), np.linspace(-hy, hy, ny)
        local = np.concatenate(
            [
                np.stack([xs, np.full(nx, -hy)], 1),
                np.stack([xs, np.full(nx, hy)], 1),
                np.stack([np.full(ny, -hx), ys], 1),
                np.stack([np.full(ny, hx), ys], 1),
            ]
        )
        c, s = math.cos(prim.yaw), math.sin(prim.yaw)
        pts.append(local @ np.array([[c, s], [-s, c]]) + np.asarray(prim.center))
    return np.concatenate(pts) if pts else np.zeros((0, 2))


def room_grid(half_size: float, resolution: float) -> FloatArray:
    """Cell centres ``(n, n, 2)`` of a square grid over ``[-half_size, half_size]²``, about
    ``resolution`` apart, with points on both edges (index ``[i, j]`` is ``(x_i, y_j)``)."""
    n = int(math.ceil(2 * half_size / resolution)) + 1
    axis = np.linspace(-half_size, half_size, n)
    gx, gy = np.meshgrid(axis, axis, indexing="ij")
    return np.stack([gx, gy], -1)


def free_route_exists(
    primitives: list[Primitive],
    start_xy: npt.ArrayLike,
    goal_xy: npt.ArrayLike,
    radius: float,
    half_size: float,
    resolution: float = 0.05,
) -> bool:
    """Whether a disc of ``radius`` can move from start to goal without touching any primitive."""
    xy = room_grid(half_size, resolution)
    n = xy.shape[0]
    gx, gy = xy[..., 0], xy[..., 1]
    free = clearance(primitives, xy) > radius
    free &= (np.abs(gx) < half_size - radius) & (np.abs(gy) < half_size - radius)

    def cell(xy: npt.ArrayLike) -> tuple[int, int]:
        x, y = np.asarray(xy, dtype=float)
        return int(round((x + half_size) / resolution)), int(round((y + half_size) / resolution))

    s, g = cell(start_xy), cell(goal_xy)
    for c in (s, g):
        if not (0 <= c[0] < n and 0 <= c[1] < n):
            return False
    free[s] = free[g] = True
    # 4-connected components of the free cells (scipy's default structure in 2-D)
    from scipy import ndimage

    labels, _ = ndimage.label(free)
    return bool(labels[s] == labels[g])


MIN_ROOM_HALF_SIZE = 1.0
"""Smallest room half-size (m) with room for a start and a goal 1 m apart."""

MAX_ROOM_HALF_SIZE = 50.0
"""Largest room half-size (m): the route check and maps grow with the room's area."""

OBSTACLE_MIN_SPACING = 0.4
"""Least distance between obstacle centres (m): smallest radius 0.1 m plus 0.3 m clearance."""


RSA_JAMMING_DENSITY = 0.547
"""Covered fraction at which discs dropped at random positions jam (random sequential adsorption)."""


def obstacle_capacity(half_size: float) -> int:
    """How many obstacles :func:`random_layout` may be asked to place in the room.

    Centres are drawn in a square of side ``2 (half_size - 0.4)`` m and lie at
    least :data:`OBSTACLE_MIN_SPACING` apart, so discs of half that spacing around
    them do not overlap. Discs dropped at random jam once they cover about
    :data:`RSA_JAMMING_DENSITY` of the area (random sequential adsorption), which
    gives this count over the square grown by the disc radius; more can never be
    drawn in reasonable time.
    """
    r = 0.5 * OBSTACLE_MIN_SPACING
    side = max(2.0 * (half_size - 0.4), 0.0) + 2.0 * r
    return int(side * side * RSA_JAMMING_DENSITY / (math.pi * r * r))


def random_layout(
    rng: np.random.Generator,
    n_obstacles: int,
    half_size: float,
    keep_clear: list[tuple[float, float]],
    clear_radius: float,
    robot_radius: float,
    max_tries: int = 200,
) -> list[Primitive]:
    """Draw ``n_obstacles`` boxes and cylinders, none within ``clear_radius`` of the
    ``keep_clear`` points, and a free route between the first two of them.

    Raises
    ------
    ValueError
        If ``n_obstacles`` exceeds :func:`obstacle_capacity`, or three draws in a row
        could not place them all: the room cannot hold them.
    RuntimeError
        If no draw leaves a free route within ``max_tries``.
    """
    capacity = obstacle_capacity(half_size)
    if n_obstacles > capacity:
        raise ValueError(
            f"n_obstacles={n_obstacles}: a room of half-size {half_size:g} m cannot hold more "
            f"than {capacity} obstacles. Fix: fewer obstacles or a larger room_half_size"
        )
    crowded = 0
    for _ in range(max_tries):
        prims: list[Primitive] = []
        centres: list[tuple[float, float]] = []
        reach: list[float] = []
        attempts = 0
        while len(prims) < n_obstacles and attempts < 50 * max(n_obstacles, 1):
            attempts += 1
            cx, cy = rng.uniform(-half_size + 0.4, half_size - 0.4, size=2)
            height = float(rng.uniform(0.5, 0.9))
            if rng.random() < 0.5:
                hx, hy = rng.uniform(0.12, 0.4, size=2)
                prim = Primitive(
                    f"obstacle_{len(prims)}",
                    Shape.BOX,
                    (float(cx), float(cy)),
                    height,
                    yaw=float(rng.uniform(-math.pi, math.pi)),
                    half_extents=(float(hx), float(hy)),
                )
            else:
                prim = Primitive(
                    f"obstacle_{len(prims)}",
                    Shape.CYLINDER,
                    (float(cx), float(cy)),
                    height,
                    radius=float(rng.uniform(0.1, 0.3)),
                )
            pts = np.asarray(keep_clear, dtype=float)
            if np.any(prim.footprint_distance(pts) < clear_radius):
                continue
            if prims:
                # footprint distance ≥ centre distance − bounding radius: only near ones matter
                gap = np.hypot(*(np.asarray(centres) - prim.center).T) - np.asarray(reach)
                near = [prims[i] for i in np.flatnonzero(gap < 0.3)]
                if near and np.min(clearance(near, np.asarray(prim.center))) < 0.3:
                    continue
            prims.append(prim)
            centres.append(prim.center)
            reach.append(
                prim.radius if prim.shape is Shape.CYLINDER else math.hypot(*prim.half_extents)
            )
        if len(prims) < n_obstacles:
            crowded += 1
            if crowded >= 3:
                raise ValueError(
                    f"n_obstacles={n_obstacles}: the room (half-size {half_size:g} m) cannot hold "
                    f"them; at most {len(prims)} fitted with 0.3 m clearance and the start and "
                    "goal kept clear. Fix: fewer obstacles or a larger room_half_size"
                )
            continue
        if len(keep_clear) < 2 or free_route_exists(
            prims, keep_clear[0], keep_clear[1], robot_radius + 0.02, half_size
        ):
            return prims
    raise RuntimeError(
        f"could not draw a passable layout with {n_obstacles} obstacles in {max_tries} tries"
    )
