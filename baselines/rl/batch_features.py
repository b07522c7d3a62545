"""Episode features of N robots at once, in numpy: the batched twins of
:class:`~realitygap.baselines.episode_features.ObstacleMemory` and
:class:`~realitygap.baselines.episode_features.RestTimer`.

A vector env steps every robot in one call; keeping one Python object per robot there
costs more than the step itself. These classes keep the same state for the whole batch
and give, row for row, the same columns as the single-robot classes fed the same
observations (pinned by a test):

- :class:`BatchObstacleMemory` keeps each robot's points in one padded buffer
  ``(N, capacity, 2)`` (row ``i`` holds robot ``i``'s first ``count[i]`` points, in the
  order seen) and the occupied grid cells of all robots in one sorted ``int64`` array of
  keys ``robot · 2^42 + cell``, so a robot's cells are one contiguous slice (forgotten
  at once on reset) and a scan's new cells are found by one ``searchsorted``;
- :class:`BatchRestTimer` is one counter per robot.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.baselines.episode_features import SCAN_START, check_memory_settings

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

__all__ = ["BatchEpisodeFeatures", "BatchObstacleMemory", "BatchRestTimer"]

_CELL_BITS = 21
"""Bits per grid-cell coordinate in a key (cells within ±2^20 of the origin)."""
_CELL_OFFSET = 1 << (_CELL_BITS - 1)


def _rows(rows: npt.ArrayLike | None, n: int, name: str) -> IntArray:
    if rows is None:
        return np.arange(n)
    r = np.asarray(rows, dtype=np.intp).reshape(-1)
    if r.size and (r.min() < 0 or r.max() >= n):
        raise ValueError(f"{name}: row indices must be in [0, {n}), got {r.min()} … {r.max()}")
    if np.unique(r).size != r.size:
        raise ValueError(f"{name}: row indices must be distinct, got {r.tolist()}")
    return r


class BatchObstacleMemory:
    """Remembered scan hits of ``n`` robots' episodes, as ranges per sector around each robot.

    Parameters
    ----------
    n : number of robots.
    scan_angles : (n_beams,) bearings of the observation's scan beams in the base frame (rad).
    range_max : range (m) that a scan value of 1 stands for.
    n_sectors : sectors around the robot in the feature.
    horizon : hits farther than this (m) are neither kept nor shown.
    cell : grid cell (m) in which one point is kept.
    """

    def __init__(
        self,
        n: int,
        scan_angles: npt.ArrayLike,
        range_max: float,
        n_sectors: int = 36,
        horizon: float = 2.0,
        cell: float = 0.05,
    ):
        if int(n) < 1 or int(n) >= 1 << (63 - 2 * _CELL_BITS):
            raise ValueError(f"n (robots) must be in [1, {1 << (63 - 2 * _CELL_BITS)}), got {n}")
        self.scan_angles = check_memory_settings(scan_angles, range_max, n_sectors, horizon, cell)
        self.n = int(n)
        self.range_max = float(range_max)
        self.n_sectors = int(n_sectors)
        self.horizon = float(horizon)
        self.cell = float(cell)
        self.n_obs = SCAN_START + self.scan_angles.size
        self._keys = np.empty(0, dtype=np.int64)  # sorted; robot i's keys are one slice
        # zeros, not np.empty: slots past a robot's count are masked, but never read as garbage
        self._points = np.zeros((self.n, 64, 2))
        self.count = np.zeros(self.n, dtype=np.intp)

    @classmethod
    def from_spec(cls, n: int, spec: Mapping[str, Any]) -> BatchObstacleMemory:
        """From a policy's ``obs_memory`` metadata (as
        :meth:`~realitygap.baselines.episode_features.ObstacleMemory.from_spec`)."""
        return cls(
            n,
            spec["scan_angles"],
            float(spec["range_max"]),
            int(spec.get("n_sectors", 36)),
            float(spec.get("horizon", 2.0)),
            float(spec.get("cell", 0.05)),
        )

    @property
    def n_features(self) -> int:
        return self.n_sectors

    def reset(self, rows: npt.ArrayLike | None = None) -> None:
        """Forget everything of robots ``rows`` (all robots if ``None``): new episodes."""
        r = _rows(rows, self.n, "reset")
        if r.size == self.n:
            self._keys = self._keys[:0]
        elif r.size:
            robot = self._keys >> (2 * _CELL_BITS)
            self._keys = self._keys[~np.isin(robot, r)]
        self.count[r] = 0

    def update(
        self, obs: npt.ArrayLike, rows: npt.ArrayLike | None = None
    ) -> npt.NDArray[np.float32]:
        """Add the hits of one observation per robot of ``rows`` (all robots if ``None``;
        ``obs`` is ``(len(rows), 12 + n_beams)``) and return their sector features
        ``(len(rows), n_sectors)``."""
        r = _rows(rows, self.n, "update")
        o = np.asarray(obs, dtype=float)
        if o.ndim != 2 or o.shape != (r.size, self.n_obs):
            raise ValueError(
                f"BatchObstacleMemory expects WheeledNav observations of shape "
                f"({r.size}, {self.n_obs}) (12 + {self.scan_angles.size} beams per robot), "
                f"got {o.shape}"
            )
        x, y = o[:, 0], o[:, 1]
        theta = np.arctan2(o[:, 3], o[:, 2])
        scan = o[:, SCAN_START:]
        ranges = scan * self.range_max
        hit = (scan < 0.999) & (ranges <= self.horizon)
        if np.any(hit):
            who, beam = np.nonzero(hit)  # row-major: robot by robot, beams in order
            bearings = theta[who] + self.scan_angles[beam]
            rng_hit = ranges[who, beam]
            px = x[who] + rng_hit * np.cos(bearings)
            py = y[who] + rng_hit * np.sin(bearings)
            self._add(r[who], px, py)
        return self._features(r, x, y, theta)

    def _add(self, robot: IntArray, px: FloatArray, py: FloatArray) -> None:
        inv = 1.0 / self.cell
        kx = np.floor(px * inv).astype(np.int64) + _CELL_OFFSET
        ky = np.floor(py * inv).astype(np.int64) + _CELL_OFFSET
        lim = 1 << _CELL_BITS
        if np.any((kx < 0) | (kx >= lim) | (ky < 0) | (ky >= lim)):
            raise ValueError(
                f"an obstacle point lies beyond ±{_CELL_OFFSET * self.cell:.0f} m of the "
                "origin; BatchObstacleMemory keys cells within that range"
            )
        keys = (robot.astype(np.int64) << (2 * _CELL_BITS)) | (kx << _CELL_BITS) | ky
        # first sighting of each cell in this batch, in the order seen
        _, first = np.unique(keys, return_index=True)
        first.sort()
        keys, robot, px, py = keys[first], robot[first], px[first], py[first]
        pos = np.searchsorted(self._keys, keys)
        known = pos < self._keys.size
        known[known] = self._keys[pos[known]] == keys[known]
        new = ~known
        if not np.any(new):
            return
        keys, robot, px, py = keys[new], robot[new], px[new], py[new]
        ks = np.sort(keys)
        self._keys = np.insert(self._keys, np.searchsorted(self._keys, ks), ks)
        # each robot's new points go after its kept ones, in the order seen
        order = np.argsort(robot, kind="stable")
        robot, px, py = robot[order], px[order], py[order]
        starts = np.searchsorted(robot, robot, side="left")
        slot = self.count[robot] + (np.arange(robot.size) - starts)
        need = int(slot.max()) + 1
        if need > self._points.shape[1]:
            grown = np.zeros((self.n, max(need, 2 * self._points.shape[1]), 2))
            grown[:, : self._points.shape[1]] = self._points
            self._points = grown
        self._points[robot, slot, 0] = px
        self._points[robot, slot, 1] = py
        np.add.at(self.count, robot, 1)

    def _features(
        self, r: IntArray, x: FloatArray, y: FloatArray, theta: FloatArray
    ) -> npt.NDArray[np.float32]:
        out = np.ones((r.size, self.n_sectors), dtype=np.float64)
        cap = int(self.count[r].max()) if r.size else 0
        if cap == 0:
            return out.astype(np.float32)
        pts = self._points[r, :cap]
        kept = np.arange(cap)[None, :] < self.count[r][:, None]
        dx, dy = pts[..., 0] - x[:, None], pts[..., 1] - y[:, None]
        d = np.hypot(dx, dy)
        near = kept & (d < self.horizon)
        if not np.any(near):
            return out.astype(np.float32)
        who, _ = np.nonzero(near)
        width = 2.0 * math.pi / self.n_sectors
        rel = np.arctan2(dy[near], dx[near]) - theta[who] + 0.5 * width
        idx = np.floor(np.mod(rel, 2.0 * math.pi) / width).astype(int) % self.n_sectors
        flat = out.reshape(-1)
        np.minimum.at(flat, who * self.n_sectors + idx, d[near] / self.horizon)
        return out.astype(np.float32)


class BatchRestTimer:
    """How long each of ``n`` robots has stood still (as
    :class:`~realitygap.baselines.episode_features.RestTimer`, one counter per robot)."""

    n_features = 1

    def __init__(self, n: int, horizon_steps: int = 40):
        if int(horizon_steps) < 1:
            raise ValueError(f"horizon_steps must be >= 1, got {horizon_steps}")
        if int(n) < 1:
            raise ValueError(f"n (robots) must be >= 1, got {n}")
        self.n = int(n)
        self.horizon_steps = int(horizon_steps)
        self.k = np.zeros(self.n, dtype=np.int64)

    def reset(self, rows: npt.ArrayLike | None = None) -> None:
        self.k[_rows(rows, self.n, "reset")] = 0

    def update(
        self, obs: npt.ArrayLike, rows: npt.ArrayLike | None = None
    ) -> npt.NDArray[np.float32]:
        r = _rows(rows, self.n, "update")
        o = np.asarray(obs, dtype=float)
        if o.ndim != 2 or o.shape[0] != r.size or o.shape[1] < 12:
            raise ValueError(
                f"BatchRestTimer expects WheeledNav observations of shape ({r.size}, >= 12), "
                f"got {o.shape}"
            )
        still = (np.abs(o[:, 10]) < 1e-6) & (np.abs(o[:, 11]) < 1e-6)
        self.k[r] = np.where(still, self.k[r] + 1, 0)
        return (np.minimum(self.k[r], self.horizon_steps) / self.horizon_steps).astype(np.float32)[
            :, None
        ]


class BatchEpisodeFeatures:
    """The episode features of ``n`` robots — a :class:`BatchObstacleMemory` and/or a
    :class:`BatchRestTimer`, columns in that order, as
    :class:`~realitygap.baselines.episode_features.EpisodeFeatures` gives them per robot."""

    def __init__(
        self,
        n: int,
        memory: Mapping[str, Any] | None = None,
        rest_timer: Mapping[str, Any] | None = None,
    ):
        self.n = int(n)
        self.parts: list[Any] = []
        if memory:
            self.parts.append(BatchObstacleMemory.from_spec(n, memory))
        if rest_timer:
            unknown = set(rest_timer) - {"horizon_steps"}
            if unknown:
                raise ValueError(
                    f"unknown obs_rest_timer setting(s) {sorted(unknown)}; known: horizon_steps"
                )
            self.parts.append(BatchRestTimer(n, int(rest_timer.get("horizon_steps", 40))))

    @property
    def n_features(self) -> int:
        return sum(p.n_features for p in self.parts)

    def reset(self, rows: npt.ArrayLike | None = None) -> None:
        """New episodes for robots ``rows`` (all if ``None``)."""
        for part in self.parts:
            part.reset(rows)

    def update(
        self, obs: npt.ArrayLike, rows: npt.ArrayLike | None = None
    ) -> npt.NDArray[np.float32]:
        """The feature columns ``(len(rows), n_features)`` after one observation per robot."""
        return np.concatenate([p.update(obs, rows) for p in self.parts], axis=1).astype(np.float32)
