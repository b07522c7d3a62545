r"""A privileged teacher for WheeledNav: shortest paths on the true map, a command that is a
function of the state.

A network cloned from the classical pipeline (:mod:`realitygap.baselines.classical`)
learns a blur wherever that pipeline's command depends on its own history: the side of
an obstacle it passes comes from the plan it made at its last re-plan, the direction of
a turn in place from the phase it is in. Least squares averages the two answers, and the
average drives straight at the obstacle or does not turn at all.

:class:`GeodesicNavExpert` sees what the policy does not — the true obstacle layout of
the episode (``env.unwrapped.obstacles``), as "learning by cheating" (Chen et al. 2019)
lets a teacher see the simulator's state — and in exchange its command is a function of
the estimated pose and that layout alone:

1. **Cost-to-go.** The room is rasterised at ``resolution``; cells whose clearance to an
   obstacle footprint is below ``robot_radius + margin`` are blocked, and a move between
   free neighbours (8-connected) costs its length times
   :math:`1 + w \max(0, 1 - (c - c_0)/s)^2` (``c``: clearance of the cells, ``c_0``:
   the blocked clearance, ``s``: ``soft_clearance``), so paths keep off obstacles where
   the room allows. Dijkstra from the goal cell (:func:`scipy.sparse.csgraph.dijkstra`)
   gives every cell's cost-to-go and its next cell towards the goal.
2. **Carrot.** From the robot's cell the next-cell chain is followed until a cell lies
   ``lookahead`` m from the robot (or the goal is reached); the carrot is the last cell of
   that chain the robot sees along a free segment, so steering at it from off the path
   does not cut a corner into an obstacle.
3. **Command.** With :math:`e` the bearing of the carrot in the robot frame,

   .. math::

      \omega = \omega_c \tanh(k_e e / \omega_c), \qquad
      v = v_c \max(0, \cos e)^3 \min(1, d_g / d_s, \sigma(c)),

   (:math:`d_g`: cost-to-go in metres; :math:`\sigma(c)` falls from 1 to
   ``min_speed_fraction`` as the robot's clearance :math:`c` nears the blocked band, so
   there is time to turn); within ``stabilise_radius`` of the goal the polar stabiliser
   (:class:`~realitygap.controllers.PolarStabiliser`, no hysteresis, so its choice of
   forwards or backwards is a function of the bearing) drives onto the goal pose; within
   ``align_radius`` the robot turns in place onto the goal heading, never slower than
   ``align_min_rate``, and stops once within ``stop_angle`` of it.

Its labels differ only across the cut locus of the cost-to-go (where two routes cost the
same) and the bearing :math:`e = \pm\pi`, sets of measure zero, instead of over every
state the classical pipeline reached with another history. It is an expert for
demonstrations (:mod:`realitygap.baselines.imitation`), not a benchmark policy: a real
robot has no true map.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from realitygap.baselines.common import PerEnvPolicy
from realitygap.controllers import PolarStabiliser, VelocityLimits
from realitygap.core.geometry import wrap_angle
from realitygap.envs.layouts import clearance, room_grid
from realitygap.robots.world import Primitive

FloatArray = npt.NDArray[np.float64]

__all__ = ["GeodesicField", "GeodesicNavConfig", "GeodesicNavExpert"]

_NEIGHBOURS = ((1, 0), (0, 1), (1, 1), (1, -1))
"""Half of the 8-neighbourhood; the graph is undirected."""


class GeodesicField:
    """Cost-to-go to ``goal_xy`` over a square room among ``primitives`` (see the module
    docstring, step 1).

    Parameters
    ----------
    primitives : obstacle footprints (walls included), world frame.
    half_size : half the side of the square room (m).
    goal_xy : goal position (m).
    robot_radius : radius of the robot's footprint (m).
    margin : extra clearance a free cell needs (m).
    soft_clearance : width (m) of the band beyond the blocked clearance that costs extra.
    soft_weight : the extra cost factor :math:`w` at the edge of the blocked band.
    resolution : cell size (m).
    """

    def __init__(
        self,
        primitives: list[Primitive],
        half_size: float,
        goal_xy: npt.ArrayLike,
        robot_radius: float,
        margin: float = 0.04,
        soft_clearance: float = 0.3,
        soft_weight: float = 4.0,
        resolution: float = 0.05,
    ):
        if not (math.isfinite(half_size) and half_size > 0.0):
            raise ValueError(f"half_size must be a positive number of metres, got {half_size!r}")
        if not (math.isfinite(resolution) and 0.0 < resolution < half_size):
            raise ValueError(
                f"resolution must lie in (0, half_size = {half_size}) m, got {resolution!r}"
            )
        goal = np.asarray(goal_xy, dtype=float).reshape(-1)
        if goal.shape != (2,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"goal_xy must be 2 finite numbers (m), got {goal_xy!r}")
        self.half_size = float(half_size)
        self.xy = room_grid(half_size, resolution)
        n = self.n = self.xy.shape[0]
        self.resolution = 2.0 * self.half_size / (n - 1)  # the grid's own spacing
        clear = clearance(primitives, self.xy)
        edge = half_size - np.max(np.abs(self.xy), axis=-1)
        clear = np.minimum(clear, edge)
        self.clearance = clear
        blocked_below = robot_radius + margin
        self.blocked_below = blocked_below
        free = clear > blocked_below
        goal_cell = self.cell(goal)
        free[goal_cell] = True  # the env keeps the goal clear; never lose it to rounding
        cost = (
            1.0
            + soft_weight * np.clip(1.0 - (clear - blocked_below) / soft_clearance, 0.0, 1.0) ** 2
        )
        index = np.arange(n * n).reshape(n, n)
        rows, cols, weights = [], [], []
        for di, dj in _NEIGHBOURS:
            a = (slice(max(0, -di), n - max(0, di)), slice(max(0, -dj), n - max(0, dj)))
            b = (slice(max(0, di), n - max(0, -di)), slice(max(0, dj), n - max(0, -dj)))
            ok = free[a] & free[b]
            step = resolution * math.hypot(di, dj)
            rows.append(index[a][ok])
            cols.append(index[b][ok])
            weights.append(step * 0.5 * (cost[a][ok] + cost[b][ok]))
        graph = coo_matrix(
            (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
            shape=(n * n, n * n),
        ).tocsr()
        dist, pred = dijkstra(
            graph, directed=False, indices=int(index[goal_cell]), return_predecessors=True
        )
        self.cost_to_go = dist.reshape(n, n)
        self.next_cell = pred.reshape(n, n)
        self.goal_cell = goal_cell
        reachable = np.isfinite(self.cost_to_go)
        self._reachable = np.flatnonzero(reachable.reshape(-1))
        self._tree = cKDTree(self.xy.reshape(-1, 2)[self._reachable])

    def cells(self, xy: npt.ArrayLike) -> npt.NDArray[np.intp]:
        """Indices ``(..., 2)`` of the grid cells nearest to points ``xy`` (..., 2), clamped
        into the room."""
        p = np.asarray(xy, dtype=float)[..., :2]
        return np.clip(np.rint((p + self.half_size) / self.resolution), 0, self.n - 1).astype(
            np.intp
        )

    def cell(self, xy: npt.ArrayLike) -> tuple[int, int]:
        """The grid cell nearest to ``xy`` (clamped into the room)."""
        i, j = self.cells(xy)
        return int(i), int(j)

    def nearest_reachable(self, xy: npt.ArrayLike) -> tuple[int, int]:
        """The cell nearest to ``xy`` from which the goal can be reached."""
        i, j = self.cell(xy)
        if math.isfinite(self.cost_to_go[i, j]):
            return i, j
        k = int(self._reachable[int(self._tree.query(np.asarray(xy, dtype=float)[:2])[1])])
        return divmod(k, self.n)

    def clearance_at(self, xy: npt.ArrayLike) -> float:
        """Clearance (m) of the cell nearest to ``xy`` to the nearest obstacle or wall."""
        return float(self.clearance[self.cell(xy)])

    def visible(self, a: npt.ArrayLike, b: npt.ArrayLike) -> bool:
        """Whether the straight segment from ``a`` to ``b`` runs through free cells only."""
        a, b = np.asarray(a, dtype=float)[:2], np.asarray(b, dtype=float)[:2]
        n = max(2, int(math.ceil(np.hypot(*(b - a)) / (0.5 * self.resolution))) + 1)
        ij = self.cells(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
        return bool(np.all(self.clearance[ij[:, 0], ij[:, 1]] > self.blocked_below))

    def carrot(self, xy: npt.ArrayLike, lookahead: float) -> tuple[FloatArray, float]:
        """The point to steer at, and the cost-to-go of ``xy``'s cell (m).

        The next-cell chain from ``xy`` is followed to the goal or to ``lookahead`` m from
        ``xy``; the carrot is the last cell of it that ``xy`` sees along a free segment
        (:meth:`visible`), so steering at it does not cut a corner into an obstacle. From a
        blocked cell (the robot has come too close) it is the first free cell of the chain.
        """
        p = np.asarray(xy, dtype=float)[:2]
        i, j = self.nearest_reachable(p)
        togo = float(self.cost_to_go[i, j])
        k = i * self.n + j
        goal = self.goal_cell[0] * self.n + self.goal_cell[1]
        flat = self.xy.reshape(-1, 2)
        nxt = self.next_cell.reshape(-1)
        chain = [k]
        for _ in range(4 * self.n):
            if k == goal or np.hypot(*(flat[k] - p)) >= lookahead:
                break
            k = int(nxt[k])
            chain.append(k)
        best = next(
            (k for k in reversed(chain[1:]) if self.visible(p, flat[k])),
            chain[min(1, len(chain) - 1)],
        )
        return flat[best].copy(), togo


@dataclass(frozen=True)
class GeodesicNavConfig:
    """Settings of :class:`GeodesicNavExpert` (SI units)."""

    lookahead: float = 0.35
    """Distance (m) of the carrot from the robot along the shortest path."""
    cruise_speed: float = 0.5
    """:math:`v_c`, the speed (m/s) on a straight path."""
    turn_gain: float = 2.5
    """:math:`k_e` (1/s)."""
    turn_rate: float = 2.5
    """:math:`\\omega_c` (rad/s), the yaw rate the turn saturates to."""
    slow_distance: float = 0.5
    """:math:`d_s` (m): the speed falls linearly to the goal from this cost-to-go."""
    clear_slow: float = 0.25
    """Beyond the blocked clearance, the speed falls linearly to ``min_speed_fraction`` of
    :math:`v_c` within this band (m): close to an obstacle there is time to turn."""
    min_speed_fraction: float = 0.3
    stabilise_radius: float = 0.20
    """Polar stabilisation within this distance of the goal (m)."""
    align_radius: float = 0.02
    """Turn in place onto the goal heading within this distance (m)."""
    stop_angle: float = math.radians(2.5)
    """Stand still within ``align_radius`` once the heading is this close (rad)."""
    align_gain: float = 6.0
    """:math:`k_a` (1/s) of the turn in place onto the goal heading,
    :math:`\\omega = \\max(\\omega_{min}, \\omega_a \\tanh(k_a |e| / \\omega_a)) \\operatorname{sign} e`."""
    align_rate: float = 1.5
    """:math:`\\omega_a` (rad/s)."""
    align_min_rate: float = 0.5
    """:math:`\\omega_{min}` (rad/s): a final turn a few degrees short is not a crawl that a
    network fitted by least squares rounds to zero."""
    margin: float = 0.04
    """Clearance (m) beyond the robot's radius that a free cell needs."""
    soft_clearance: float = 0.3
    soft_weight: float = 4.0
    resolution: float = 0.05

    def __post_init__(self) -> None:
        rules: dict[str, tuple[str, Callable[[float], bool]]] = {
            "soft_weight": (">= 0", lambda v: math.isfinite(v) and v >= 0.0),
            "min_speed_fraction": ("in (0, 1]", lambda v: 0.0 < v <= 1.0),
        }
        positive = ("> 0", lambda v: math.isfinite(v) and v > 0.0)
        for name, value in vars(self).items():
            rule, ok = rules.get(name, positive)
            if not ok(value):
                raise ValueError(f"GeodesicNavConfig.{name} must be {rule}, got {value!r}")
        if self.align_radius >= self.stabilise_radius:
            raise ValueError(
                f"align_radius ({self.align_radius} m) must be below stabilise_radius "
                f"({self.stabilise_radius} m)"
            )


class GeodesicNavExpert(PerEnvPolicy):
    """SB3-style expert for ``realitygap/WheeledNav-v0`` that reads the true layout of
    ``env`` (see the module docstring).

    The observation supplies the estimated pose and the goal; the map comes from
    ``env.unwrapped.obstacles`` and is rebuilt whenever the goal or the layout changes, so
    the expert must be built on the env whose observations it is given.
    """

    def __init__(self, env: Any, config: GeodesicNavConfig | None = None):
        base = env.unwrapped
        for name in ("obstacles", "room_half_size", "params", "scan_angles"):
            if not hasattr(base, name):
                raise TypeError(
                    f"GeodesicNavExpert needs a WheeledNav env (with .{name}), got {type(base).__name__}"
                )
        self.env = base
        self.config = config or GeodesicNavConfig()
        p = base.params
        self.limits = VelocityLimits(
            v_max=p.v_max, w_max=p.w_max, a_max=p.a_max, alpha_max=p.alpha_max
        )
        self.robot_radius = float(p.body_radius)
        self.stabiliser = PolarStabiliser(limits=self.limits, reverse_hysteresis=0.0)
        self.n_obs = 12 + len(base.scan_angles)
        self.obs_what = f"WheeledNav-v0 with a scan of {len(base.scan_angles)} beams"
        self._fields: dict[int, tuple[Any, tuple[float, ...], GeodesicField]] = {}

    def reset(self, env_index: int | None = None) -> None:
        if env_index is None:
            self._fields.clear()
        else:
            self._fields.pop(env_index, None)

    def field(self, env_index: int, goal_xy: FloatArray) -> GeodesicField:
        """The cost-to-go of the env's current layout and goal (cached per episode)."""
        layout = self.env.obstacles
        key = tuple(float(v) for v in goal_xy)
        cached = self._fields.get(env_index)
        if cached is not None and cached[0] is layout and cached[1] == key:
            return cached[2]
        c = self.config
        f = GeodesicField(
            list(layout),
            self.env.room_half_size,
            goal_xy,
            self.robot_radius,
            margin=c.margin,
            soft_clearance=c.soft_clearance,
            soft_weight=c.soft_weight,
            resolution=c.resolution,
        )
        self._fields[env_index] = (layout, key, f)
        return f

    def act(self, env_index: int, obs: FloatArray) -> FloatArray:
        c = self.config
        pose = np.array([obs[0], obs[1], math.atan2(obs[3], obs[2])])
        goal = np.array([obs[4], obs[5], math.atan2(obs[7], obs[6])])
        dist = math.hypot(goal[0] - pose[0], goal[1] - pose[1])
        if dist <= c.align_radius:
            err = float(wrap_angle(goal[2] - pose[2]))
            if abs(err) <= c.stop_angle:
                v, w = 0.0, 0.0
            else:
                rate = max(
                    c.align_min_rate,
                    c.align_rate * math.tanh(c.align_gain * abs(err) / c.align_rate),
                )
                v, w = 0.0, math.copysign(rate, err)
        elif dist <= c.stabilise_radius:
            v, w = self.stabiliser.command(pose, goal)
        else:
            field = self.field(env_index, goal[:2])
            carrot, togo = field.carrot(pose[:2], c.lookahead)
            e = float(wrap_angle(math.atan2(carrot[1] - pose[1], carrot[0] - pose[0]) - pose[2]))
            w = c.turn_rate * math.tanh(c.turn_gain * e / c.turn_rate)
            near = (field.clearance_at(pose[:2]) - field.blocked_below) / c.clear_slow
            slow = c.min_speed_fraction + (1.0 - c.min_speed_fraction) * min(1.0, max(0.0, near))
            v = c.cruise_speed * max(0.0, math.cos(e)) ** 3 * min(1.0, togo / c.slow_distance, slow)
            v, w = self.limits.saturate(v, w)
        return np.array([v / self.limits.v_max, w / self.limits.w_max])
