"""Record any environment run as a :class:`~realitygap.diagnosis.logs.log.Log`.

:class:`RecordLog` is a Gymnasium wrapper. For
:class:`~realitygap.envs.wheeled_nav.WheeledNavEnv` it records, per control
step, the twist the drive actually received (after the firmware's
acceleration limit), the cumulative wheel ticks exactly as the estimator saw
them (it taps the estimator), the true pose, the estimate and the planar pose
of the camera. Clock errors of the env's :class:`~realitygap.robots.effects.Reality`
(``timestamp_offset``) are applied to the stamped channels, and optional
measurement noise is drawn from a generator handed in.

Other envs can be recorded by passing ``extract``: a function
``(env, info) -> {channel: row}`` called after ``reset`` and every ``step``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.logs.log import ChannelSpec, Log
from realitygap.robots.diffdrive_replay import (
    camera_planar_pose,
    params_to_meta,
    shift_channel,
)
from realitygap.robots.simulation import MeasurementNoise, SimSettings

FloatArray = npt.NDArray[np.float64]

__all__ = ["RecordLog"]


class _EstimatorTap:
    """Passes measurements to the wrapped estimator and remembers the last one."""

    def __init__(self, inner: Any):
        self.inner = inner
        self.last: Any = None

    def reset(self, initial: Any | None = None) -> Any:
        self.last = None
        return self.inner.reset(initial)

    def update(self, measurement: Any | None) -> Any:
        self.last = measurement
        return self.inner.update(measurement)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


Extractor = Callable[[gym.Env, Mapping[str, Any]], Mapping[str, npt.ArrayLike]]


class RecordLog(gym.Wrapper):
    """Record an episode; :attr:`log` (or :meth:`save`) gives it after or during the run.

    Parameters
    ----------
    env : gymnasium.Env
        A WheeledNav env (possibly wrapped), or any env with ``extract``.
    extract : callable, optional
        ``(env, info) -> {channel: row}`` for other envs; rows of standard
        channels must use the standard units.
    specs : mapping, optional
        :class:`~realitygap.diagnosis.logs.log.ChannelSpec` of non-standard channels.
    noise : MeasurementNoise, optional
        Noise added to ground truth and camera poses (needs ``rng``).
    rng : numpy.random.Generator, optional
    meta : mapping, optional
        Extra metadata of the log (e.g. ``{"name": "square_cw"}``).

    Notes
    -----
    Row ``k`` holds the state after ``k`` steps and the command applied in
    step ``k + 1`` (the last row's command is zero), the convention of
    :mod:`realitygap.diagnosis.adapters.diffdrive.replay`.
    """

    def __init__(
        self,
        env: gym.Env,
        *,
        extract: Extractor | None = None,
        specs: Mapping[str, ChannelSpec] | None = None,
        noise: MeasurementNoise | None = None,
        rng: np.random.Generator | None = None,
        meta: Mapping[str, Any] | None = None,
    ):
        super().__init__(env)
        if noise is not None and any(dataclasses.astuple(noise)) and rng is None:
            raise ValueError("RecordLog: noise needs rng (a numpy.random.Generator)")
        self._extract = extract
        self._specs = dict(specs or {})
        self._noise = noise
        self._rng = rng
        self._meta = dict(meta or {})
        self._rows: dict[str, list[FloatArray]] = {}
        self._t: list[float] = []
        self._tap: _EstimatorTap | None = None
        base = env.unwrapped
        if extract is None:
            if not hasattr(base, "estimator") or not hasattr(base, "robot"):
                raise TypeError(
                    f"RecordLog knows how to record WheeledNavEnv; for {type(base).__name__} "
                    "pass extract=(env, info) -> {channel: row}"
                )
            self._tap = _EstimatorTap(base.estimator)
            base.estimator = self._tap

    # ------------------------------------------------------------------ gym API
    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._rows = {}
        self._t = []
        self._append(info, command=None)
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        base = self.env.unwrapped
        applied = np.array(base.robot.command, dtype=float)
        self._append(info, command=applied)
        return obs, reward, terminated, truncated, info

    # ------------------------------------------------------------------ rows
    def _append(self, info: Mapping[str, Any], command: FloatArray | None) -> None:
        if self._extract is not None:
            row = {
                k: np.asarray(v, dtype=float).reshape(-1)
                for k, v in self._extract(self.env, info).items()
            }
            self._t.append(float(info.get("t", len(self._t))))
            for k, v in row.items():
                self._rows.setdefault(k, []).append(v)
            return
        base: Any = self.env.unwrapped
        self._t.append(float(info["t"]))
        if command is not None and self._rows.get("cmd"):
            self._rows["cmd"][-1] = command  # the command applied since the previous row
        self._rows.setdefault("cmd", []).append(np.zeros(2))
        ticks = getattr(self._tap.last, "ticks", None) if self._tap is not None else None
        if ticks is None:
            raise RuntimeError("RecordLog: the env did not pass wheel ticks to its estimator")
        self._rows.setdefault("ticks", []).append(np.array([ticks.left, ticks.right], float))
        self._rows.setdefault("pose_gt", []).append(np.asarray(info["true_pose"], float))
        self._rows.setdefault("pose_est", []).append(np.asarray(info["estimated_pose"], float))
        self._rows.setdefault("pose_cam", []).append(camera_planar_pose(base.robot))

    # ------------------------------------------------------------------ output
    @property
    def log(self) -> Log:
        """The episode recorded so far (at least two rows)."""
        if len(self._t) < 2:
            raise RuntimeError("RecordLog: nothing recorded yet; reset() and step() first")
        t = np.asarray(self._t, dtype=float)
        chans = {k: np.vstack(v) for k, v in self._rows.items()}
        meta: dict[str, Any] = {}
        base: Any = self.env.unwrapped
        if self._extract is None:
            for k in ("pose_gt", "pose_est", "pose_cam"):
                chans[k][:, 2] = np.unwrap(chans[k][:, 2])
            reality = getattr(base, "reality", None)
            offsets = reality.channel_time_offsets() if reality is not None else {}
            for channel, offset in offsets.items():
                if channel in chans:
                    chans[channel] = shift_channel(t, chans[channel], offset)
            if self._noise is not None and self._rng is not None:
                nz = self._noise
                chans["pose_gt"] = chans["pose_gt"] + self._rng.normal(
                    size=chans["pose_gt"].shape
                ) * [nz.truth_xy, nz.truth_xy, nz.truth_theta]
                chans["pose_cam"] = chans["pose_cam"] + self._rng.normal(
                    size=chans["pose_cam"].shape
                ) * [nz.camera_xy, nz.camera_xy, nz.camera_theta]
            world = base.world
            meta = {
                "robot": "diffdrive",
                "params": params_to_meta(base.params),
                "sim": SimSettings(
                    physics_hz=world.physics_hz, solver_iterations=world.solver_iterations
                ).to_meta(),
                "source": f"RecordLog({type(base).__name__})",
            }
        meta.update(self._meta)
        return Log(
            t=t,
            channels=chans,
            specs=self._specs,
            meta=meta,
            source=str(meta.get("name", "RecordLog")),
        )

    def save(self, path: str | Path) -> Path:
        """Write :attr:`log` atomically (``.npz``)."""
        return self.log.save(path)
