r"""The PyBullet core of a differential-drive replay: drive the body, record the standard channels.

:func:`simulate_channels` drives the simulated body through the same firmware as
:class:`~realitygap.envs.wheeled_nav.WheeledNavEnv`
(:meth:`~realitygap.robots.diffdrive.DiffDriveRobot.command_twist`: command
hooks of the effects, then the inverse kinematics with the *nominal* geometry,
then the wheel velocity motors) from a given start pose, and returns the
standard channels of a differential-drive log (``cmd``, ``ticks``, ``pose_gt``,
``pose_est``, ``pose_cam``) and the log's metadata as plain arrays and dicts.
The diagnosis wraps them into a log
(:func:`realitygap.diagnosis.adapters.diffdrive.replay.simulate`); the fit's
surrogate calibrates itself against them
(:func:`realitygap.robots.diffdrive_surrogate.calibrate`).

Also here: the nominal robot's metadata (:func:`params_to_meta`,
:func:`params_from_meta`), the nominal wheel odometry (:func:`nominal_odometry`)
and the channel post-processing the recorders share (:func:`camera_planar_pose`,
:func:`shift_channel`).

Timing convention (as in the env): row ``k`` holds the state at ``t[k]`` and
the command issued at ``t[k]``; the command is held for one control period,
after which row ``k + 1`` is measured.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.cache import ArrayCache, content_key, default_cache
from realitygap.core.geometry import reframe_track
from realitygap.estimators.diffdrive_model import DiffDriveKinematics
from realitygap.robots.diffdrive import (
    DiffDriveParams,
    DiffDriveRobot,
    RGBDCameraParams,
    check_param,
)
from realitygap.robots.effects import Reality
from realitygap.robots.simulation import MeasurementNoise, SimSettings
from realitygap.robots.world import World

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "MetaError",
    "camera_planar_pose",
    "nominal_odometry",
    "params_from_meta",
    "params_to_meta",
    "shift_channel",
    "simulate_channels",
]


class MetaError(ValueError):
    """The metadata does not describe a nominal robot; the message names the source and the fix."""


# --------------------------------------------------------------------------- parameters
def params_to_meta(params: DiffDriveParams) -> dict[str, Any]:
    """JSON-able dict of :class:`DiffDriveParams` (for ``log.meta["params"]``)."""
    out = dataclasses.asdict(params)
    cam = out.pop("camera")
    cam["mount_xyz"] = list(cam["mount_xyz"])
    out["camera"] = cam
    return out


def params_from_meta(meta: Mapping[str, Any], source: str = "") -> DiffDriveParams:
    """Nominal :class:`DiffDriveParams` from ``meta["params"]`` (missing fields keep defaults).

    Parameters
    ----------
    meta : mapping
        A log's metadata.
    source : str
        Where the metadata came from (a file), prefixed to the error messages.

    Raises
    ------
    MetaError
        If the metadata has no ``params`` or names unknown fields.
    """
    where = f"{source}: " if source else ""
    raw = meta.get("params")
    if not isinstance(raw, Mapping):
        raise MetaError(
            f"{where}metadata has no 'params' (nominal robot parameters: wheel_radius_left, "
            "wheel_radius_right, wheelbase, ticks_per_rev …). Fix: pass them to the importer"
        )
    known = {f.name for f in dataclasses.fields(DiffDriveParams)}
    raw = dict(raw)
    unknown = sorted(set(raw) - known)
    if unknown:
        raise MetaError(
            f"{where}unknown robot parameter(s) {unknown} in metadata; known: {sorted(known)}"
        )
    cam_raw = raw.pop("camera", None)
    try:
        kwargs: dict[str, Any] = {k: check_param(k, v) for k, v in raw.items()}
    except ValueError as exc:
        raise MetaError(f"{where}invalid robot parameters in metadata: {exc}") from None
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
        raise MetaError(f"{where}invalid robot parameters in metadata: {exc}") from None


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
_REPLAY_CACHE = "diffdrive_replay"


@functools.lru_cache(maxsize=1)
def _code_fingerprint() -> str:
    """SHA-256 of the robot package's source (the body, firmware, effects and world): a
    cached replay is read only by the code that wrote it."""
    h = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for path in sorted([*here.glob("*.py"), *here.glob("effects/*.py")]):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    import pybullet

    h.update(str(getattr(pybullet, "getAPIVersion", lambda: 0)()).encode())
    return h.hexdigest()


def _physics(
    t: FloatArray,
    dt: float,
    params: DiffDriveParams,
    reality: Reality,
    cmd: FloatArray | None,
    tk: FloatArray | None,
    start: FloatArray,
    settings: SimSettings,
    cache: ArrayCache | None = None,
    use_cache: bool = True,
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """The PyBullet run of a replay: body poses, encoder angles and camera poses, (N, 3/2/3),
    and the seconds the run took (when read back from the cache: when it was made).

    Deterministic in its inputs, so it is kept in the content-addressed cache
    (:mod:`realitygap.core.cache`) under the time base, the drive input, the start, the
    nominal parameters, the effects, the simulator settings and the code's fingerprint:
    a log replayed again (another diagnosis of the same logs, another split) is read
    back instead of simulated; any change of an input is another entry.
    """
    store = (cache if cache is not None else default_cache()) if use_cache else None
    key = ""
    if store is not None:
        drive_input = ("cmd", cmd) if cmd is not None else ("ticks", tk)
        key = content_key(
            _code_fingerprint(),
            t,
            drive_input[0],
            drive_input[1],
            start,
            params_to_meta(params),
            reality.to_dict(),
            settings.to_meta(),
        )
        hit = store.get(_REPLAY_CACHE, key)
        n = t.shape[0]
        if (
            hit is not None
            and all(
                name in hit and hit[name].shape == (n, k)
                for name, k in (("poses", 3), ("angles", 2), ("cams", 3))
            )
            and hit.get("seconds", np.zeros(1)).shape == ()
        ):
            return hit["poses"], hit["angles"], hit["cams"], float(hit["seconds"])

    t0 = time.perf_counter()
    n = t.shape[0]
    n_sub = max(1, int(round(settings.physics_hz * dt)))
    world = World(
        physics_hz=n_sub / dt, n_substeps=n_sub, solver_iterations=settings.solver_iterations
    )
    try:
        world.add_floor()
        true_params = reality.apply_params(params)
        robot = DiffDriveRobot(world, true_params)
        robot.reset(start)
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
    seconds = time.perf_counter() - t0
    if store is not None:
        store.put(
            _REPLAY_CACHE,
            key,
            {"poses": poses, "angles": angles, "cams": cams, "seconds": np.float64(seconds)},
        )
    return poses, angles, cams, seconds


def replay_rate(
    params: DiffDriveParams, settings: SimSettings, dt: float, seconds: float = 2.0
) -> float:
    """Seconds of computation per second of replayed motion, measured now: a short PyBullet
    run (a drive and a turn, ``seconds`` long, not read from the cache) of the robot
    ``params`` at control period ``dt``. What a replay of a log costs on this machine at
    its present load."""
    if not (dt > 0 and seconds > 0):
        raise ValueError(f"replay_rate: expected dt > 0 and seconds > 0, got {dt!r}, {seconds!r}")
    n = max(3, int(round(seconds / dt)) + 1)
    t = dt * np.arange(n)
    cmd = np.zeros((n, 2))
    cmd[: n // 2, 0] = 0.2
    cmd[n // 2 :, 1] = 0.5
    t0 = time.perf_counter()
    _physics(t, dt, params, Reality(), cmd, None, np.zeros(3), settings, use_cache=False)
    return (time.perf_counter() - t0) / (t[-1] - t[0])


def simulate_channels(
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
) -> tuple[dict[str, FloatArray], dict[str, Any]]:
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

    Returns
    -------
    channels : dict of str to ndarray
        ``cmd`` (when command-driven), ``ticks``, ``pose_gt`` (reframed, shifted and
        noisy as the effects and ``noise`` say), ``pose_est`` (nominal wheel odometry)
        and ``pose_cam``, each (N, k).
    meta : dict
        ``robot``, ``params`` (nominal, :func:`params_to_meta`) and ``sim``
        (:meth:`SimSettings.to_meta`).
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

    start_arr = np.asarray(start, dtype=float)
    k_ticks = params.ticks_per_rev / (2.0 * math.pi)
    poses, angles, cams, _ = _physics(t, dt, params, reality, cmd, tk, start_arr, settings)

    poses[:, 2] = _unwrap_continuous(poses[:, 2], float(start_arr[2]))
    cams[:, 2] = _unwrap_continuous(cams[:, 2], float(cams[0, 2]))
    ticks_out = np.floor(angles * k_ticks) if tk is None else tk.copy()
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
    channels: dict[str, FloatArray] = {
        "ticks": ticks_out,
        "pose_gt": poses,
        "pose_est": nominal_odometry(ticks_out, params, start_arr),
        "pose_cam": cams,
    }
    if cmd is not None:
        channels = {"cmd": cmd, **channels}
    meta: dict[str, Any] = {
        "robot": "diffdrive",
        "params": params_to_meta(params),
        "sim": settings.to_meta(),
    }
    return channels, meta
