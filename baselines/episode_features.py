"""Episode features of learned WheeledNav policies: inputs that need a memory of the episode.

A network maps one observation to one action; what a navigating robot has seen earlier
in the episode is not in one observation, so these classes keep it and append it. They
read only the observation (estimated pose, goal, scan), so the same code runs in
training (:class:`EpisodeFeaturesWrapper`) and behind a trained policy's ``predict``,
and are reset at the start of each episode.

:class:`RestTimer` — how long the robot has stood still (see there why a deterministic
policy needs it).

:class:`ObstacleMemory` — what the robot saw, all around it. The scan covers only the
camera's 70° field of view, so an obstacle the robot has driven past, or turned away
from, is gone from the observation. The classical policy keeps the obstacle points it
has seen; this gives a network the same memory as a fixed-size input:

1. each scan hit (a beam that saw something within ``horizon``) is put into the
   estimated world frame through the estimated pose of the observation and kept,
   one point per ``cell`` × ``cell`` grid cell;
2. the feature is, for each of ``n_sectors`` equal sectors around the robot (sector
   0 centred straight ahead, counter-clockwise), the distance to the nearest kept
   point in that sector, divided by ``horizon`` and clipped to 1 (1: nothing seen
   nearer than ``horizon``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "EpisodeFeatures",
    "EpisodeFeaturesWrapper",
    "ObstacleMemory",
    "RestTimer",
    "memory_spec_for_env",
]

SCAN_START = 12
"""Index of the first scan column of a WheeledNav observation."""


def check_memory_settings(
    scan_angles: npt.ArrayLike, range_max: float, n_sectors: int, horizon: float, cell: float
) -> npt.NDArray[np.float64]:
    """Check an obstacle memory's settings; return the scan angles (rad) as a flat array.

    Raises
    ------
    ValueError
        Naming the setting, what it must be and what came.
    """
    angles = np.asarray(scan_angles, dtype=float).reshape(-1)
    if angles.size == 0 or not np.all(np.isfinite(angles)):
        raise ValueError(f"scan_angles must be a non-empty finite list, got {scan_angles!r}")
    if not (range_max > 0 and horizon > 0 and cell > 0):
        raise ValueError(
            f"range_max, horizon and cell must be > 0, got {range_max}, {horizon}, {cell}"
        )
    if int(n_sectors) < 4:
        raise ValueError(f"n_sectors must be >= 4, got {n_sectors}")
    return angles


class ObstacleMemory:
    """Remembered scan hits of one episode, as ranges per sector around the robot.

    Parameters
    ----------
    scan_angles : (n_beams,) bearings of the observation's scan beams in the base frame (rad).
    range_max : range (m) that a scan value of 1 stands for.
    n_sectors : sectors around the robot in the feature.
    horizon : hits farther than this (m) are neither kept nor shown.
    cell : grid cell (m) in which one point is kept.
    """

    def __init__(
        self,
        scan_angles: npt.ArrayLike,
        range_max: float,
        n_sectors: int = 36,
        horizon: float = 2.0,
        cell: float = 0.05,
    ):
        self.scan_angles = check_memory_settings(scan_angles, range_max, n_sectors, horizon, cell)
        self.range_max = float(range_max)
        self.n_sectors = int(n_sectors)
        self.horizon = float(horizon)
        self.cell = float(cell)
        self.n_obs = SCAN_START + self.scan_angles.size
        self._cells: set[tuple[int, int]] = set()
        # the kept points are rows 0 … _n − 1, in the order they were seen; the buffer
        # grows by doubling so a step does not rebuild an array of the whole episode
        self._points = np.empty((64, 2))
        self._n = 0

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any]) -> ObstacleMemory:
        """From a policy's ``obs_memory`` metadata (see :func:`memory_spec_for_env`)."""
        return cls(
            spec["scan_angles"],
            float(spec["range_max"]),
            int(spec.get("n_sectors", 36)),
            float(spec.get("horizon", 2.0)),
            float(spec.get("cell", 0.05)),
        )

    def __len__(self) -> int:
        return self._n

    @property
    def n_features(self) -> int:
        return self.n_sectors

    def bounds(self) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """Bounds of the feature: ``[0, 1]`` per sector."""
        return np.zeros(self.n_sectors, np.float32), np.ones(self.n_sectors, np.float32)

    def reset(self) -> None:
        """Forget everything (a new episode)."""
        self._cells.clear()
        self._n = 0

    def update(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Add the hits of one observation and return the sector feature ``(n_sectors,)``."""
        o = np.asarray(obs, dtype=float).reshape(-1)
        if o.size != self.n_obs:
            raise ValueError(
                f"ObstacleMemory expects a WheeledNav observation of {self.n_obs} values "
                f"(12 + {self.scan_angles.size} beams), got {o.size}"
            )
        x, y, c, s = o[0], o[1], o[2], o[3]
        theta = math.atan2(s, c)
        ranges = o[SCAN_START:] * self.range_max
        hit = (o[SCAN_START:] < 0.999) & (ranges <= self.horizon)
        if np.any(hit):
            bearings = theta + self.scan_angles[hit]
            px = x + ranges[hit] * np.cos(bearings)
            py = y + ranges[hit] * np.sin(bearings)
            inv = 1.0 / self.cell
            new: list[tuple[float, float]] = []
            for qx, qy in zip(px.tolist(), py.tolist()):
                key = (math.floor(qx * inv), math.floor(qy * inv))
                if key not in self._cells:
                    self._cells.add(key)
                    new.append((qx, qy))
            if new:
                self._append(new)
        return self.features(x, y, theta)

    def _append(self, points: list[tuple[float, float]]) -> None:
        end = self._n + len(points)
        if end > len(self._points):
            grown = np.empty((max(end, 2 * len(self._points)), 2))
            grown[: self._n] = self._points[: self._n]
            self._points = grown
        self._points[self._n : end] = points
        self._n = end

    def features(self, x: float, y: float, theta: float) -> npt.NDArray[np.float32]:
        """Sector ranges / horizon around the pose ``(x, y, θ)``, clipped to 1."""
        out = np.ones(self.n_sectors, dtype=np.float64)
        if not self._n:
            return out.astype(np.float32)
        pts = self._points[: self._n]
        dx, dy = pts[:, 0] - x, pts[:, 1] - y
        d = np.hypot(dx, dy)
        near = d < self.horizon
        if not np.any(near):
            return out.astype(np.float32)
        width = 2.0 * math.pi / self.n_sectors
        rel = np.arctan2(dy[near], dx[near]) - theta + 0.5 * width
        idx = np.floor(np.mod(rel, 2.0 * math.pi) / width).astype(int) % self.n_sectors
        np.minimum.at(out, idx, d[near] / self.horizon)
        return out.astype(np.float32)


def memory_spec_for_env(env: gym.Env[Any, Any], settings: Mapping[str, Any]) -> dict[str, Any]:
    """The full ``obs_memory`` spec for a WheeledNav env: ``settings`` (``n_sectors``,
    ``horizon``, ``cell``) plus the env's scan geometry, so a trained policy can rebuild
    its memory without the env."""
    base: Any = env.unwrapped
    if not hasattr(base, "scan_angles") or not hasattr(base, "scan_range_max"):
        raise ValueError(
            f"obs_memory needs an env with a planar scan (WheeledNav), got {type(base).__name__}"
        )
    unknown = set(settings) - {"n_sectors", "horizon", "cell"}
    if unknown:
        raise ValueError(
            f"unknown obs_memory setting(s) {sorted(unknown)}; known: n_sectors, horizon, cell"
        )
    spec = {
        "n_sectors": int(settings.get("n_sectors", 36)),
        "horizon": float(settings.get("horizon", 2.0)),
        "cell": float(settings.get("cell", 0.05)),
        "scan_angles": [float(a) for a in base.scan_angles],
        "range_max": float(base.scan_range_max),
    }
    ObstacleMemory.from_spec(spec)  # validates
    return spec


class RestTimer:
    """How long the robot has been standing still, ``min(k, horizon_steps) / horizon_steps``
    for ``k`` control steps since the last applied command (observation columns 10, 11)
    became zero.

    An episode ends the moment the robot rests on the goal pose, so "at rest and the
    episode goes on" means "not there yet". Without this column that state is a fixed
    point of a deterministic policy: the same observation every step, the same decision
    to stand still.
    """

    def __init__(self, horizon_steps: int = 40):
        if int(horizon_steps) < 1:
            raise ValueError(f"horizon_steps must be >= 1, got {horizon_steps}")
        self.horizon_steps = int(horizon_steps)
        self._k = 0

    n_features = 1

    def bounds(self) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        return np.zeros(1, np.float32), np.ones(1, np.float32)

    def reset(self) -> None:
        self._k = 0

    def update(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        o = np.asarray(obs, dtype=float).reshape(-1)
        still = abs(o[10]) < 1e-6 and abs(o[11]) < 1e-6
        self._k = self._k + 1 if still else 0
        return np.array([min(self._k, self.horizon_steps) / self.horizon_steps], np.float32)


class EpisodeFeatures:
    """The episode features of one env — an :class:`ObstacleMemory` and/or a
    :class:`RestTimer` — their columns in that order."""

    def __init__(
        self, memory: Mapping[str, Any] | None = None, rest_timer: Mapping[str, Any] | None = None
    ):
        self.parts: list[Any] = []
        if memory:
            self.parts.append(ObstacleMemory.from_spec(memory))
        if rest_timer:
            unknown = set(rest_timer) - {"horizon_steps"}
            if unknown:
                raise ValueError(
                    f"unknown obs_rest_timer setting(s) {sorted(unknown)}; known: horizon_steps"
                )
            self.parts.append(RestTimer(int(rest_timer.get("horizon_steps", 40))))

    @property
    def n_features(self) -> int:
        return sum(p.n_features for p in self.parts)

    def bounds(self) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """Lower and upper bounds of the columns."""
        lows, highs = zip(*(p.bounds() for p in self.parts))
        return np.concatenate(lows), np.concatenate(highs)

    def reset(self) -> None:
        for part in self.parts:
            part.reset()

    def update(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        return np.concatenate([part.update(obs) for part in self.parts]).astype(np.float32)


class EpisodeFeaturesWrapper(gym.ObservationWrapper):
    """Appends :class:`EpisodeFeatures` columns to each observation (training side)."""

    def __init__(self, env: gym.Env[Any, Any], features: EpisodeFeatures):
        super().__init__(env)
        self.features = features
        space = env.observation_space
        assert isinstance(space, gym.spaces.Box)
        low, high = features.bounds()
        self.observation_space = gym.spaces.Box(
            np.concatenate([space.low, low]), np.concatenate([space.high, high]), dtype=np.float32
        )

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self.features.reset()
        return super().reset(**kwargs)

    def observation(self, observation: Any) -> Any:
        extra = self.features.update(observation)
        return np.concatenate([np.asarray(observation, dtype=np.float32), extra])
