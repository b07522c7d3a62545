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


class BatchGeodesicExpert:
    """:class:`GeodesicNavExpert` for ``N`` robots per call, on the state of a vector env
    (``realitygap/WheeledNavVec-v0``): the same command as the single-robot expert, from
    the same estimated poses, goals and layouts, with the carrot search, the visibility
    test and the command law evaluated for every robot at once in numpy.

    Each robot's cost-to-go (:class:`GeodesicField`) is built when its layout or goal
    changes (a new episode) and kept until then; the fields' arrays are stacked so that a
    step indexes them all at once. Only the polar stabiliser, within ``stabilise_radius``
    of the goal, runs robot by robot.

    Parameters
    ----------
    env : the vector env (or a wrapper of it) whose ``obstacles`` (one layout per robot),
        ``room_half_size``, ``params`` and ``num_envs`` the expert reads.
    config : the expert's settings (default: :class:`GeodesicNavConfig`).
    """

    def __init__(self, env: Any, config: GeodesicNavConfig | None = None):
        base = getattr(env, "unwrapped", env)
        for name in ("obstacles", "room_half_size", "params", "num_envs"):
            if not hasattr(base, name):
                raise TypeError(
                    f"BatchGeodesicExpert needs a vector WheeledNav env (with .{name}), "
                    f"got {type(base).__name__}"
                )
        self.env = base
        self.config = c = config or GeodesicNavConfig()
        p = base.params
        self.limits = VelocityLimits(
            v_max=p.v_max, w_max=p.w_max, a_max=p.a_max, alpha_max=p.alpha_max
        )
        self.robot_radius = float(p.body_radius)
        n = self.num_envs = int(base.num_envs)
        self.stabilisers = [
            PolarStabiliser(limits=self.limits, reverse_hysteresis=0.0) for _ in range(n)
        ]
        self.xy = room_grid(float(base.room_half_size), c.resolution).reshape(-1, 2)
        cells = self.xy.shape[0]
        self.fields: list[GeodesicField | None] = [None] * n
        self._keys: list[tuple[Any, tuple[float, float]] | None] = [None] * n
        self.cost_to_go = np.full((n, cells), np.inf)
        self.next_cell = np.zeros((n, cells), dtype=np.int32)
        self.clearance = np.zeros((n, cells))
        self.goal_cell = np.zeros(n, dtype=np.intp)
        self.blocked_below = self.robot_radius + c.margin

    def reset(self) -> None:
        """Forget every robot's field (they are rebuilt on the next call)."""
        self.fields = [None] * self.num_envs
        self._keys = [None] * self.num_envs

    def _refresh(self, rows: npt.NDArray[np.intp], goal_xy: FloatArray) -> None:
        """Build the fields of robots ``rows`` whose layout or goal changed."""
        c = self.config
        for i in rows:
            layout = self.env.obstacles[i]
            key = (float(goal_xy[i, 0]), float(goal_xy[i, 1]))
            cached = self._keys[i]
            if cached is not None and cached[0] is layout and cached[1] == key:
                continue
            f = GeodesicField(
                list(layout),
                float(self.env.room_half_size),
                goal_xy[i],
                self.robot_radius,
                margin=c.margin,
                soft_clearance=c.soft_clearance,
                soft_weight=c.soft_weight,
                resolution=c.resolution,
            )
            self.fields[i], self._keys[i] = f, (layout, key)
            self.cost_to_go[i] = f.cost_to_go.reshape(-1)
            self.next_cell[i] = f.next_cell.reshape(-1)
            self.clearance[i] = f.clearance.reshape(-1)
            self.goal_cell[i] = f.goal_cell[0] * f.n + f.goal_cell[1]

    def _flat_cells(self, field: GeodesicField, xy: FloatArray) -> npt.NDArray[np.intp]:
        ij = field.cells(xy)
        return ij[..., 0] * field.n + ij[..., 1]

    def act(self, pose: npt.ArrayLike, goal: npt.ArrayLike) -> FloatArray:
        """Normalised actions ``(N, 2)`` (``[v / v_max, ω / w_max]``) for estimated poses
        and goals ``(N, 3)`` ``[x, y, θ]`` (m, m, rad), world frame."""
        pose = np.asarray(pose, dtype=float)
        goal = np.asarray(goal, dtype=float)
        n = self.num_envs
        if pose.shape != (n, 3) or goal.shape != (n, 3):
            raise ValueError(
                f"pose and goal must have shape ({n}, 3), got {pose.shape} and {goal.shape}"
            )
        c = self.config
        v, w = np.zeros(n), np.zeros(n)
        dist = np.hypot(goal[:, 0] - pose[:, 0], goal[:, 1] - pose[:, 1])
        align = dist <= c.align_radius
        if np.any(align):
            err = wrap_angle(goal[align, 2] - pose[align, 2])
            rate = np.maximum(
                c.align_min_rate, c.align_rate * np.tanh(c.align_gain * np.abs(err) / c.align_rate)
            )
            w[align] = np.where(np.abs(err) <= c.stop_angle, 0.0, np.copysign(rate, err))
        for i in np.flatnonzero(~align & (dist <= c.stabilise_radius)):
            v[i], w[i] = self.stabilisers[i].command(pose[i], goal[i])
        path = np.flatnonzero(dist > c.stabilise_radius)
        if path.size:
            v[path], w[path] = self._path_command(path, pose[path], goal[path, :2])
        return np.column_stack([v / self.limits.v_max, w / self.limits.w_max])

    def _path_command(
        self, rows: npt.NDArray[np.intp], pose: FloatArray, goal_xy: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Steps 2 and 3 of the module docstring for robots ``rows`` far from the goal."""
        c = self.config
        full_goal = np.zeros((self.num_envs, 2))
        full_goal[rows] = goal_xy
        self._refresh(rows, full_goal)
        field = self.fields[int(rows[0])]
        assert field is not None
        m = rows.size
        p = pose[:, :2]
        k = self._flat_cells(field, p)
        lost = ~np.isfinite(self.cost_to_go[rows, k])
        for j in np.flatnonzero(lost):  # rare: the robot's cell cannot reach the goal
            f = self.fields[int(rows[j])]
            assert f is not None
            i, jj = f.nearest_reachable(p[j])
            k[j] = i * f.n + jj
        togo = self.cost_to_go[rows, k]
        # the next-cell chain, for all robots at once, until the goal or the lookahead
        chain = [k]
        running = np.ones(m, dtype=bool)
        goal_cell = self.goal_cell[rows]
        for _ in range(4 * field.n):
            running &= (k != goal_cell) & (np.hypot(*(self.xy[k] - p).T) < c.lookahead)
            if not np.any(running):
                break
            k = np.where(running, self.next_cell[rows, k], k)
            chain.append(np.where(running, k, -1))
        cells = np.column_stack(chain)  # (m, L); -1 past a robot's end
        length = np.sum(cells >= 0, axis=1)
        best = cells[np.arange(m), np.minimum(1, length - 1)]
        for j in range(1, cells.shape[1]):
            ok = cells[:, j] >= 0
            if not np.any(ok):
                break
            vis = self._visible(field, rows[ok], p[ok], self.xy[cells[ok, j]])
            upd = np.flatnonzero(ok)[vis]
            best[upd] = cells[upd, j]
        carrot = self.xy[best]
        e = wrap_angle(np.arctan2(carrot[:, 1] - p[:, 1], carrot[:, 0] - p[:, 0]) - pose[:, 2])
        w = c.turn_rate * np.tanh(c.turn_gain * e / c.turn_rate)
        here = self._flat_cells(field, p)
        near = (self.clearance[rows, here] - self.blocked_below) / c.clear_slow
        slow = c.min_speed_fraction + (1.0 - c.min_speed_fraction) * np.clip(near, 0.0, 1.0)
        v = (
            c.cruise_speed
            * np.maximum(0.0, np.cos(e)) ** 3
            * np.minimum(np.minimum(1.0, togo / c.slow_distance), slow)
        )
        scale = np.maximum(
            1.0, np.maximum(np.abs(v) / self.limits.v_max, np.abs(w) / self.limits.w_max)
        )
        return v / scale, w / scale

    def _visible(
        self, field: GeodesicField, rows: npt.NDArray[np.intp], a: FloatArray, b: FloatArray
    ) -> npt.NDArray[np.bool_]:
        """:meth:`GeodesicField.visible` of segments ``a[j] -> b[j]`` in the fields of robots
        ``rows[j]`` (all on ``field``'s grid)."""
        seg = b - a
        count = np.maximum(
            2, np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / (0.5 * field.resolution)).astype(int) + 1
        )
        top = int(count.max())
        idx = np.arange(top)[None, :]
        t = idx * (1.0 / (count[:, None] - 1.0))
        t = np.where(idx == count[:, None] - 1, 1.0, np.minimum(t, 1.0))
        pts = a[:, None, :] + t[..., None] * seg[:, None, :]
        flat = self._flat_cells(field, pts)
        free = self.clearance[rows[:, None], flat] > field.blocked_below
        return np.all(free | (idx >= count[:, None]), axis=1)
