r"""Replay a differential-drive log in PyBullet: the nominal (or nominal + effects) robot.

:func:`simulate` drives the simulated body through the same firmware as
:class:`~realitygap.envs.wheeled_nav.WheeledNavEnv`
(:meth:`~realitygap.robots.diffdrive.DiffDriveRobot.command_twist`: command
hooks of the effects, then the inverse kinematics with the *nominal* geometry,
then the wheel velocity motors) from a given start pose, and records the
standard channels (see :mod:`realitygap.diagnosis.logs.log`). :func:`replay` does
it for a logged episode: the logged commands (or, with ``drive="ticks"``, the
logged wheel rotation) from the logged initial pose, producing the same
channels, so real and simulated episodes can be compared sample by sample.

Timing convention (as in the env): row ``k`` holds the state at ``t[k]`` and
the command issued at ``t[k]``; the command is held for one control period,
after which row ``k + 1`` is measured.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import reframe_track
from realitygap.diagnosis.adapters.contract import Drive
from realitygap.diagnosis.adapters.diffdrive.firmware import firmware_from_meta
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.estimators.diffdrive_model import DiffDriveKinematics
from realitygap.robots.diffdrive import (
    DiffDriveParams,
    DiffDriveRobot,
    Ramp,
    RGBDCameraParams,
)
from realitygap.robots.effects import Reality
from realitygap.robots.simulation import MeasurementNoise, SimSettings
from realitygap.robots.world import World

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "applied_commands",
    "camera_planar_pose",
    "nominal_odometry",
    "params_from_meta",
    "params_to_meta",
    "replay",
    "shift_channel",
    "simulate",
]


# --------------------------------------------------------------------------- parameters
def params_to_meta(params: DiffDriveParams) -> dict[str, Any]:
    """JSON-able dict of :class:`DiffDriveParams` (for ``log.meta["params"]``)."""
    out = dataclasses.asdict(params)
    cam = out.pop("camera")
    cam["mount_xyz"] = list(cam["mount_xyz"])
    out["camera"] = cam
    return out


def params_from_meta(log_or_meta: Log | Mapping[str, Any]) -> DiffDriveParams:
    """Nominal :class:`DiffDriveParams` from ``meta["params"]`` (missing fields keep defaults).

    Raises
    ------
    LogError
        If the metadata has no ``params`` or names unknown fields.
    """
    meta = log_or_meta.meta if isinstance(log_or_meta, Log) else log_or_meta
    source = log_or_meta.source if isinstance(log_or_meta, Log) else ""
    where = f"{source}: " if source else ""
    raw = meta.get("params")
    if not isinstance(raw, Mapping):
        raise LogError(
            f"{where}metadata has no 'params' (nominal robot parameters: wheel_radius_left, "
            "wheel_radius_right, wheelbase, ticks_per_rev …). Fix: pass them to the importer"
        )
    known = {f.name for f in dataclasses.fields(DiffDriveParams)}
    raw = dict(raw)
    unknown = sorted(set(raw) - known)
    if unknown:
        raise LogError(
            f"{where}unknown robot parameter(s) {unknown} in metadata; known: {sorted(known)}"
        )
    cam_raw = raw.pop("camera", None)
    kwargs: dict[str, Any] = {k: float(v) for k, v in raw.items()}
    if isinstance(cam_raw, Mapping):
        cam_fields = {f.name for f in dataclasses.fields(RGBDCameraParams)}
        cam_kw = {k: v for k, v in cam_raw.items() if k in cam_fields}
        if "mount_xyz" in cam_kw:
            cam_kw["mount_xyz"] = tuple(float(v) for v in cam_kw["mount_xyz"])
        for k in ("width", "height"):
            if k in cam_kw:
                cam_kw[k] = int(cam_kw[k])
        kwargs["camera"] = RGBDCameraParams(**cam_kw)
    try:
        return DiffDriveParams(**kwargs)
    except ValueError as exc:
        raise LogError(f"{where}invalid robot parameters in metadata: {exc}") from None


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


# --------------------------------------------------------------------------- helpers
def camera_planar_pose(robot: DiffDriveRobot) -> FloatArray:
    """Planar pose of the camera: optical centre (x, y) and heading of the optical axis, (3,)."""
    T = robot.T_world_camera()
    z = T[:3, 2]
    return np.array([T[0, 3], T[1, 3], math.atan2(z[1], z[0])])


def shift_channel(t: FloatArray, values: FloatArray, offset: float) -> FloatArray:
    """Values stamped ``offset`` s late: the sample at ``t`` becomes the value at ``t − offset``.

    Linear interpolation of every column (angles must be continuous), clamped
    at both ends.
    """
    out = np.empty_like(values)
    for j in range(values.shape[1]):
        col = values[:, j]
        out[:, j] = np.interp(t - offset, t, col)
    return out


def nominal_odometry(
    ticks: FloatArray, params: DiffDriveParams, start: npt.ArrayLike
) -> FloatArray:
    """Dead reckoning from cumulative ticks (N, 2) with the nominal geometry, (N, 3), continuous θ."""
    kin = DiffDriveKinematics(
        params.wheel_radius_left, params.wheel_radius_right, params.wheelbase, params.ticks_per_rev
    )
    d = np.diff(ticks, axis=0)
    return kin.integrate(np.asarray(start, dtype=float), d[:, 0], d[:, 1], wrap=False)


def _unwrap_continuous(theta: FloatArray, start: float) -> FloatArray:
    th = np.unwrap(theta)
    return th + (2.0 * math.pi) * round((start - th[0]) / (2.0 * math.pi))


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

    Parameters
    ----------
    t : array_like, shape (N,)
        Regular time stamps, s (the control period is their step).
    params : DiffDriveParams
        Nominal parameters: what the firmware believes; the body is
        ``reality.apply_params(params)``.
    reality : Reality, optional
        Effects realised in the simulation (default: none).
    commands : array_like, shape (N, 2), optional
        Body twists ``[v, w]`` (m/s, rad/s) issued at each row (the last is
        unused). Exactly one of ``commands`` and ``ticks`` is needed.
    ticks : array_like, shape (N, 2), optional
        Cumulative encoder counts ``[left, right]`` to reproduce: each control
        period the wheels are driven at the logged rotation rate (through the
        inverse of the effects' encoder hooks).
    start : array_like, shape (3,)
        Initial pose ``[x, y, θ]`` (m, m, rad).
    settings : SimSettings, optional
    noise : MeasurementNoise, optional
        Noise added to ``pose_gt`` and ``pose_cam`` (needs ``rng``).
    rng : numpy.random.Generator, optional
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
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.shape[0] < 2:
        raise ValueError(f"t must be 1-D with at least 2 samples, got shape {t.shape}")
    step = np.diff(t)
    dt = float(np.median(step))
    if np.max(np.abs(step - dt)) > 0.01 * dt:
        raise ValueError("t must be regularly spaced (resample the log first)")
    if (commands is None) == (ticks is None):
        raise ValueError("give exactly one of commands= and ticks=")
    reality = reality if reality is not None else Reality()
    settings = settings if settings is not None else SimSettings()
    n = t.shape[0]
    cmd = None if commands is None else np.asarray(commands, dtype=float)
    if cmd is not None and cmd.shape != (n, 2):
        raise ValueError(f"commands must have shape ({n}, 2), got {cmd.shape}")
    tk = None if ticks is None else np.asarray(ticks, dtype=float)
    if tk is not None and tk.shape != (n, 2):
        raise ValueError(f"ticks must have shape ({n}, 2), got {tk.shape}")

    n_sub = max(1, int(round(settings.physics_hz * dt)))
    world = World(
        physics_hz=n_sub / dt, n_substeps=n_sub, solver_iterations=settings.solver_iterations
    )
    try:
        world.add_floor()
        true_params = reality.apply_params(params)
        robot = DiffDriveRobot(world, true_params)
        start_arr = np.asarray(start, dtype=float)
        robot.reset(start_arr)
        robot.attach_firmware(dt, nominal=params, reality=reality)
        k_ticks = params.ticks_per_rev / (2.0 * math.pi)

        wheel_target = None
        if tk is not None:
            ang = robot.wheel_angles_from_encoder(tk / k_ticks)
            wheel_target = np.diff(ang, axis=0) / dt

        poses = np.empty((n, 3))
        angles = np.empty((n, 2))
        cams = np.empty((n, 3))

        def record(k: int) -> None:
            poses[k] = robot.pose2d()
            angles[k] = robot.encoder_angles()
            cams[k] = camera_planar_pose(robot)

        record(0)
        for k in range(n - 1):
            if wheel_target is not None:
                robot.set_wheel_speeds(float(wheel_target[k, 0]), float(wheel_target[k, 1]))
            else:
                assert cmd is not None
                robot.command_twist(float(cmd[k, 0]), float(cmd[k, 1]))
            world.step()
            record(k + 1)
    finally:
        world.close()

    poses[:, 2] = _unwrap_continuous(poses[:, 2], float(start_arr[2]))
    cams[:, 2] = _unwrap_continuous(cams[:, 2], float(cams[0, 2]))
    ticks_out = np.floor(angles * k_ticks) if tk is None else tk.copy()
    true_gt = poses.copy()
    for channel, frame in reality.channel_frames().items():
        if channel == "pose_gt":
            poses = reframe_track(poses, frame, start_arr)
        else:
            raise ValueError(f"the recorder cannot reframe channel {channel!r}")
    for channel, offset in reality.channel_time_offsets().items():
        if channel == "pose_gt":
            poses = shift_channel(t, poses, offset)
        elif channel == "pose_cam":
            cams = shift_channel(t, cams, offset)
        else:
            raise ValueError(f"the recorder cannot shift channel {channel!r}")
    if noise is not None and any(dataclasses.astuple(noise)):
        if rng is None:
            raise ValueError("noise needs an rng (numpy.random.Generator)")
        poses = poses + rng.normal(size=poses.shape) * [
            noise.truth_xy,
            noise.truth_xy,
            noise.truth_theta,
        ]
        cams = cams + rng.normal(size=cams.shape) * [
            noise.camera_xy,
            noise.camera_xy,
            noise.camera_theta,
        ]
    del true_gt
    channels: dict[str, FloatArray] = {
        "ticks": ticks_out,
        "pose_gt": poses,
        "pose_est": nominal_odometry(ticks_out, params, start_arr),
        "pose_cam": cams,
    }
    if cmd is not None:
        channels = {"cmd": cmd, **channels}
    full_meta: dict[str, Any] = {
        "robot": "diffdrive",
        "params": params_to_meta(params),
        "sim": settings.to_meta(),
    }
    full_meta.update(dict(meta or {}))
    return Log(t=t, channels=channels, meta=full_meta, source=source)


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
