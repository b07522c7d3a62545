r"""Replay a differential-drive log in PyBullet: the nominal (or nominal + effects) robot.

:func:`simulate` runs the PyBullet core of a replay
(:func:`realitygap.robots.diffdrive_replay.simulate_channels`: the firmware, the body and
the standard channels, with the timing convention stated there) and wraps its channels into
a :class:`~realitygap.diagnosis.logs.log.Log`. :func:`replay` does it for a logged episode:
the logged commands (or, with ``drive="ticks"``, the logged wheel rotation) from the logged
initial pose, so real and simulated episodes can be compared sample by sample.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.adapters.contract import Drive
from realitygap.diagnosis.adapters.diffdrive.firmware import firmware_from_meta
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.robots.diffdrive import DiffDriveParams, Ramp
from realitygap.robots.diffdrive_replay import MetaError, simulate_channels
from realitygap.robots.diffdrive_replay import params_from_meta as _params_from_meta
from realitygap.robots.effects import Reality
from realitygap.robots.simulation import MeasurementNoise, SimSettings

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "applied_commands",
    "params_from_meta",
    "replay",
    "simulate",
]


# --------------------------------------------------------------------------- parameters
def params_from_meta(log_or_meta: Log | Mapping[str, Any]) -> DiffDriveParams:
    """Nominal :class:`DiffDriveParams` from ``meta["params"]`` (missing fields keep defaults).

    :func:`realitygap.robots.diffdrive_replay.params_from_meta` on a log's metadata (or
    on a metadata mapping), its errors named after the log's source.

    Raises
    ------
    LogError
        If the metadata has no ``params`` or names unknown fields.
    """
    meta = log_or_meta.meta if isinstance(log_or_meta, Log) else log_or_meta
    source = log_or_meta.source if isinstance(log_or_meta, Log) else ""
    try:
        return _params_from_meta(meta, source)
    except MetaError as exc:
        raise LogError(str(exc)) from None


def applied_commands(log: Log) -> FloatArray:
    """The body twist the drive actually received at each row, (N, 2) [m/s, rad/s].

    Without ``meta["firmware"]`` this is the ``cmd`` channel. With it, the
    firmware's :class:`~realitygap.robots.diffdrive.FirmwareLimits` (rate limits
    ``a_max`` m/s², ``alpha_max`` rad/s²; speed limits ``v_max``, ``w_max``,
    optional) are applied from rest in the convention the metadata states
    (:func:`~realitygap.diagnosis.adapters.diffdrive.firmware.firmware_from_meta`: the body twist or
    each wheel ramped; deceleration limited, free, or limited with a zero request
    stopping at once) — as
    :meth:`~realitygap.robots.diffdrive.DiffDriveRobot.command_twist` does in
    :class:`~realitygap.envs.wheeled_nav.WheeledNavEnv`.
    """
    log.require(["cmd"], "a command-driven replay")
    cmd = np.array(log["cmd"], dtype=float)
    limits = firmware_from_meta(log)
    if limits is None:
        return cmd
    wheelbase = params_from_meta(log).wheelbase if limits.ramp is Ramp.WHEELS else 1.0
    return limits.applied(cmd, log.dt, wheelbase)


# --------------------------------------------------------------------------- simulation
def simulate(
    t: npt.ArrayLike,
    *,
    params: DiffDriveParams,
    reality: Reality | None = None,
    commands: npt.ArrayLike | None = None,
    ticks: npt.ArrayLike | None = None,
    start: npt.ArrayLike = (0.0, 0.0, 0.0),
    settings: SimSettings | None = None,
    noise: MeasurementNoise | None = None,
    rng: np.random.Generator | None = None,
    meta: Mapping[str, Any] | None = None,
    source: str = "simulation",
) -> Log:
    """Run the PyBullet robot ``params`` + ``reality`` and record the standard channels.

    The channels are :func:`realitygap.robots.diffdrive_replay.simulate_channels`' (see
    there for the parameters but ``meta`` and ``source``).

    Parameters
    ----------
    t, params, reality, commands, ticks, start, settings, noise, rng
        As :func:`~realitygap.robots.diffdrive_replay.simulate_channels`.
    meta : mapping, optional
        Extra metadata for the returned log.
    source : str

    Returns
    -------
    Log
        Channels ``cmd`` (when command-driven), ``ticks``, ``pose_gt``,
        ``pose_est`` (nominal wheel odometry) and ``pose_cam``; ``meta`` holds
        ``robot``, ``params`` (nominal), ``sim`` and the given ``meta``.
    """
    channels, full_meta = simulate_channels(
        t,
        params=params,
        reality=reality,
        commands=commands,
        ticks=ticks,
        start=start,
        settings=settings,
        noise=noise,
        rng=rng,
    )
    full_meta.update(dict(meta or {}))
    return Log(t=np.asarray(t, dtype=float), channels=channels, meta=full_meta, source=source)


def replay(
    log: Log,
    reality: Reality | None = None,
    *,
    drive: Drive | str = Drive.COMMANDS,
    settings: SimSettings | None = None,
    params: DiffDriveParams | None = None,
) -> Log:
    """The simulated counterpart of ``log``: same inputs, same start, same channels.

    Parameters
    ----------
    log : Log
        A differential-drive log with ``meta["params"]``, a regular time base
        and ``cmd`` (``drive="commands"``) or ``ticks`` (``drive="ticks"``).
    reality : Reality, optional
        Effects to add to the nominal robot (default: the nominal robot).
    drive : {"commands", "ticks"}
    settings : SimSettings, optional
        Default: the log's own ``meta["sim"]`` if it is simulated, else
        :class:`SimSettings` ().
    params : DiffDriveParams, optional
        Nominal parameters (default: from the log's metadata).

    Returns
    -------
    Log
        With the log's time base; ``cmd`` holds the applied commands.
    """
    drive = Drive(drive)
    params = params if params is not None else params_from_meta(log)
    settings = settings if settings is not None else SimSettings.for_log(log)
    log.check_uniform()
    start = log["pose_gt"][0] if log.has("pose_gt") else np.zeros(3)
    meta = {"name": f"replay of {log.name}", "drive": drive.value}
    if reality is not None and reality.effects:
        meta["reality"] = reality.to_dict()
    if drive is Drive.COMMANDS:
        return simulate(
            log.t,
            params=params,
            reality=reality,
            commands=applied_commands(log),
            start=start,
            settings=settings,
            meta=meta,
            source=f"replay({log.name})",
        )
    log.require(["ticks"], "a tick-driven replay")
    return simulate(
        log.t,
        params=params,
        reality=reality,
        ticks=log["ticks"],
        start=start,
        settings=settings,
        meta=meta,
        source=f"replay({log.name})",
    )
