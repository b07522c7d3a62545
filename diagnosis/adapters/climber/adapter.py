r"""The climber's diagnosis adapter: tether and ride-height features along the true path.

A climber log is sampled at the tether rate (10 Hz): the true body pose
``pose3_gt`` (position and rotation vector in the world = CAD frame, e.g. from
a total station) and the tether reading ``tether`` (m). Its metadata gives the
nominal blade mount and robot (``meta["params"]``, see
:func:`climber_params_to_meta`).

Features, per window (1 s by default)
    ``tether.length`` — mean tether reading; ``surface.height`` — mean height of
    the body origin above the nominal CAD surface (projected along the local
    normal with the CAD point cloud's :class:`~realitygap.estimators.climb.SurfaceModel`).

Regimes
    From the true motion in the window: ``standing`` (below 2 cm/s),
    ``climbing`` / ``descending`` (vertical speed above a third of the speed),
    else ``traversing``.

Replay
    The sensors are replayed along the logged true path: the tether model of
    :class:`~realitygap.robots.climber_sensors.TetherModel` (spool scale, sag, stretch,
    anchor) in closed form, and the ride height of the body as PyBullet
    measures it — the nominal (or effect-changed) robot is set at the logged
    pose and settles under gravity and adsorption, and its height above the CAD surface
    is read at every window (:func:`replay_heights`). The surrogate is the
    same closed form, batched, with the ride height linear in the adsorption
    gap on top of the nominal PyBullet heights.

Effects that these channels cannot show are named with the reason: a constant
IMU bias (no IMU channel; the climber's static initialisation removes it
anyway), a tether stretch (every reading grows in proportion to the distance
exactly as with a mis-scaled spool — reported as ``climber_spool_scale``), and
a CAD-vs-real surface deviation (its shape is not a few numbers: it shows as a
structured ride-height residual left "unexplained").
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from realitygap.diagnosis.adapters.contract import (
    BlindLogSettings,
    DiscoveryTerms,
    Drive,
    LogContext,
    PreparedLog,
    RobotAdapter,
)
from realitygap.diagnosis.adapters.registry import get_adapter
from realitygap.diagnosis.logs.channels import CLIMBER_CHANNELS
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.diagnosis.problem.features import FeatureSettings
from realitygap.diagnosis.problem.parameters import split_key
from realitygap.diagnosis.problem.schemas import CLIMBER_REGIMES, CLIMBER_SCHEMA
from realitygap.robots.simulation import SimSettings

FloatArray = npt.NDArray[np.float64]
Features = dict[str, FloatArray]

__all__ = [
    "CLIMBER_CHANNELS",
    "CLIMBER_REGIMES",
    "CLIMBER_SCHEMA",
    "CLIMB_PROBES",
    "BladeScenes",
    "ClimberAdapter",
    "ClimberContext",
    "climber_params_from_meta",
    "climber_params_to_meta",
    "log_from_climb_recording",
    "replay_heights",
]

CLIMB_PROBES: dict[str, str] = {
    "span_climb": "a straight climb along the span from root to tip and back (the tether "
    "length changes most)",
    "chord_sweeps": "chordwise traverses at several spans (the direction to the anchor "
    "changes most)",
}
"""Paths suggested to separate confounded climber effects."""

_SURROGATE_EFFECTS = (
    "climber_tether_sag",
    "climber_anchor_error",
    "climber_spool_scale",
    "climber_adsorption_gap",
)
_WHY_NOT: dict[str, str] = {
    "climber_tether_stretch": "indistinguishable from climber_spool_scale: both make every "
    "reading grow in proportion to the distance (only a tension sensor or a known-length "
    "check separates them); the diagnosis reports the pair as climber_spool_scale",
    "climber_surface_deviation": "its shape is not described by a few numbers; it shows as a "
    "structured surface.height residual that no library effect explains",
}


# --------------------------------------------------------------------------- parameters
def climber_params_to_meta(params: Any) -> dict[str, Any]:
    """The nominal-climber metadata of a log (``meta["params"]``)."""
    return {
        "blade": dataclasses.asdict(params.blade),
        "mount_pitch": float(params.mount_pitch),
        "mount_position": list(params.mount_position),
        "anchor_blade": list(params.anchor_blade),
        "wheel_radius": float(params.wheel_radius),
        "tether_sigma": float(params.tether_sigma),
    }


def climber_params_from_meta(log: Log) -> Any:
    """The nominal :class:`~realitygap.robots.climber.ClimberParams` of a climber log."""
    from realitygap.robots.blade_geometry import BladeParams
    from realitygap.robots.climber import ClimberParams

    raw = log.meta.get("params")
    if not isinstance(raw, Mapping):
        raise LogError(
            f"{log.source}: a climber log needs meta['params'] (blade, mount_pitch, "
            "mount_position, anchor_blade, wheel_radius; see climber_params_to_meta)"
        )
    try:
        kw: dict[str, Any] = {}
        if "blade" in raw:
            kw["blade"] = BladeParams(**dict(raw["blade"]))
        for key in ("mount_pitch", "wheel_radius", "tether_sigma"):
            if key in raw:
                kw[key] = float(raw[key])
        for key in ("mount_position", "anchor_blade"):
            if key in raw:
                kw[key] = tuple(float(v) for v in raw[key])
        return ClimberParams(**kw)
    except (TypeError, ValueError) as exc:
        raise LogError(f"{log.source}: meta['params'] is not a valid climber: {exc}") from None


def _geometry_key(params: Any) -> str:
    """What a blade scene and its CAD cloud depend on: the blade and its mount."""
    return json.dumps(
        {
            "blade": dataclasses.asdict(params.blade),
            "mount_pitch": float(params.mount_pitch),
            "mount_position": [float(v) for v in params.mount_position],
        },
        sort_keys=True,
    )


_SURFACES: dict[str, Any] = {}
"""CAD surface models of this process, by geometry."""


def cad_surface(params: Any) -> Any:
    """The CAD point-cloud surface model of a climber's blade (cached per geometry)."""
    from realitygap.estimators.climb import SurfaceModel

    key = _geometry_key(params)
    if key not in _SURFACES:
        _SURFACES[key] = SurfaceModel(*params.cad_cloud(0.01))
    return _SURFACES[key]


def heights_above_cad(params: Any, positions: FloatArray) -> FloatArray:
    """Signed height (N,) of body origins (N, 3) above the CAD surface along its normal, m."""
    proj = cad_surface(params).project(positions, None, 0.0)
    return np.asarray(proj.offset, dtype=float).reshape(-1)


class BladeScenes:
    """PyBullet blade scenes by geometry, built on first use and closed by :meth:`close`.

    Building a scene takes about a second, so a replay keeps one per blade
    geometry; the owner (a :class:`ClimberAdapter`) closes them. Also a context
    manager.
    """

    def __init__(self) -> None:
        self._scenes: dict[str, Any] = {}

    def scene(self, params: Any) -> Any:
        """The :class:`~realitygap.robots.climber.ClimbWorld` of ``params``' blade and mount."""
        from realitygap.robots.climber import ClimbWorld

        key = _geometry_key(params)
        if key not in self._scenes:
            scene = ClimbWorld(params.replace(gap_offset=0.0))
            # bodies of other ride heights are loaded from the same file name: no caching
            scene.world.set_file_caching(False)
            self._scenes[key] = scene
        return self._scenes[key]

    def close(self) -> None:
        """Close every scene (disconnect its physics client)."""
        while self._scenes:
            _, scene = self._scenes.popitem()
            scene.close()

    def __len__(self) -> int:
        return len(self._scenes)

    def __enter__(self) -> BladeScenes:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def replay_heights(
    params: Any,
    poses: FloatArray,
    gap: float = 0.0,
    settle_steps: int = 96,
    *,
    scenes: BladeScenes,
) -> FloatArray:
    """Ride height (M,) of the PyBullet climber above the CAD surface at ``poses`` (M, 6).

    The robot (``params`` with the adsorption ``gap`` added) is set at each logged
    pose (position, rotation vector; world frame) and settles for ``settle_steps``
    physics steps under gravity and suction on its wheels and casters; then the
    height of its origin above the nominal CAD surface is read. On a curved
    blade this differs from the wheel radius by the sagitta under the body. The
    blade scene comes from ``scenes``.
    """
    from realitygap.robots.climber import ClimberRobot

    body = params.replace(gap_offset=float(gap))
    scene = scenes.scene(params)
    robot = ClimberRobot(scene, body)
    world = scene.world
    try:
        out = np.empty(poses.shape[0])
        for m, pose in enumerate(np.array(poses, dtype=float)):
            R = Rotation.from_rotvec(pose[3:6]).as_matrix()
            # start with the wheels touching: a larger ride height lifts the body along its z
            robot.reset(pose[:3] + (body.h_true - params.h_true) * R[:, 2], R)
            world.step(settle_steps, before_each=robot.apply_adsorption)
            pos = robot.state(0.0).position
            out[m] = float(heights_above_cad(params, pos[None])[0])
        return out
    finally:
        robot.remove()


# --------------------------------------------------------------------------- sensor models
def _values(values: Mapping[str, npt.ArrayLike]) -> tuple[int, dict[str, FloatArray]]:
    sizes = {np.size(v) for v in values.values()}
    if len(sizes) > 1:
        raise ValueError(f"effect values of one batch must have one length, got {sorted(sizes)}")
    B = sizes.pop() if sizes else 1
    out = {k: np.asarray(v, dtype=float).reshape(-1) for k, v in values.items()}
    for key in out:
        effect = split_key(key)[0]
        if effect not in _SURROGATE_EFFECTS and effect != "climber_tether_stretch":
            raise KeyError(f"the climber surrogate has no parameter {key!r}")
    return B, out


def tether_model(
    anchor: FloatArray, positions: FloatArray, values: Mapping[str, npt.ArrayLike]
) -> FloatArray:
    """Tether readings (B, N) along ``positions`` (N, 3) for a batch of effect values.

    :math:`l = s\\,(d + k d^2 + \\epsilon d)`, :math:`d = \\lVert p - (a + \\delta a)\\rVert`
    (as :class:`~realitygap.robots.climber_sensors.TetherModel`, without noise).
    """
    B, v = _values(values)

    def get(key: str, default: float) -> FloatArray:
        return v.get(key, np.full(B, default))[:, None]

    da = np.stack([get(f"climber_anchor_error.d{a}", 0.0)[:, 0] for a in "xyz"], axis=-1)  # (B, 3)
    d = np.linalg.norm(positions[None] - (anchor[None, None] + da[:, None]), axis=-1)
    s = get("climber_spool_scale.s", 1.0)
    k = get("climber_tether_sag.k", 0.0)
    eps = get("climber_tether_stretch.strain", 0.0)
    return s * (d + k * d * d + eps * d)


def _window_means(x: FloatArray, bounds: npt.NDArray[np.int64]) -> FloatArray:
    """Means over rows ``a .. b-1`` of every window: (…, N) → (…, M)."""
    csum = np.concatenate([np.zeros((*x.shape[:-1], 1)), np.cumsum(x, axis=-1)], axis=-1)
    a, b = bounds[:, 0], bounds[:, 1]
    return (csum[..., b] - csum[..., a]) / (b - a)


# --------------------------------------------------------------------------- the adapter
@dataclass
class ClimberContext(LogContext):
    """What the climber keeps about a prepared log.

    Attributes
    ----------
    params : ClimberParams
        The nominal climber of the log.
    positions : ndarray, shape (N, 3)
        True body positions, world frame, m.
    anchor : ndarray, shape (3,)
        Nominal tether anchor, world frame, m.
    motion : ndarray, shape (M, 6)
        Per window: speed and vertical speed (m/s), then zeros.
    window_poses : ndarray, shape (M, 6)
        True pose at each window's middle row (position, rotation vector).
    nominal_heights : ndarray, shape (M,) or None
        Ride heights of the nominal body, once replayed.
    """

    params: Any
    positions: FloatArray
    anchor: FloatArray
    motion: FloatArray
    window_poses: FloatArray
    nominal_heights: FloatArray | None = None

    def window_motion(self, bounds: npt.NDArray[np.int64]) -> FloatArray | None:
        return self.motion

    def reference_wheelbase(self) -> float | None:
        """The climber's wheelbase (m; its logs have no planar ground truth to turn into
        wheel speeds)."""
        return None if self.params.wheelbase is None else float(self.params.wheelbase)


class ClimberAdapter(RobotAdapter):
    """Climber: tether and ride-height features, sensor replay with PyBullet ride height.

    The adapter owns the PyBullet blade scenes of its replays (:attr:`scenes`);
    :meth:`close` releases them. A copy unpickled in another process uses the
    scenes of that process's registered climber adapter.
    """

    robot = "climber"
    channels = CLIMBER_CHANNELS
    schema = CLIMBER_SCHEMA
    surrogate_effects = _SURROGATE_EFFECTS
    unobservable = _WHY_NOT
    motion_labels = (
        ("speed on the blade", "m/s"),
        ("vertical speed", "m/s"),
        *((("unused", "1"),) * 4),
    )
    """Meaning of the window motion columns (:mod:`realitygap.diagnosis.stages.coverage`)."""

    def __init__(self) -> None:
        self.scenes = BladeScenes()

    def close(self) -> None:
        """Close the blade scenes of the replays."""
        self.scenes.close()

    def __getstate__(self) -> dict[str, Any]:
        # live simulator scenes do not travel to other processes
        state = self.__dict__.copy()
        del state["scenes"]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        # a copy sent to another process replays in that process's registered adapter's scenes
        self.__dict__.update(state)
        registered = get_adapter(self.robot)
        self.scenes = registered.scenes if isinstance(registered, ClimberAdapter) else BladeScenes()

    @staticmethod
    def _context(prepared: PreparedLog) -> ClimberContext:
        ctx = prepared.context
        assert isinstance(ctx, ClimberContext)
        return ctx

    def probe_manoeuvres(self) -> dict[str, str]:
        return dict(CLIMB_PROBES)

    # ------------------------------------------------------------------ checks
    def check(self, log: Log, drive: Drive) -> Log:
        self.check_robot(log, drive, replayed_from="its true path")
        log.require(["pose3_gt", "tether"], "a climber diagnosis")
        climber_params_from_meta(log)
        log.check_uniform()
        if log.n < 3:
            raise LogError(f"{log.source}: the log is too short ({log.n} rows)")
        return log

    # ------------------------------------------------------------------ preparation
    def prepare(
        self,
        log: Log,
        *,
        split: str,
        drive: Drive,
        features_settings: FeatureSettings,
        sim: SimSettings | None,
    ) -> PreparedLog:
        params = climber_params_from_meta(log)
        bounds = self.time_windows(log, features_settings)
        pos = np.asarray(log["pose3_gt"], dtype=float)[:, :3]
        heights = heights_above_cad(params, pos)
        real = {
            "tether": _window_means(np.asarray(log["tether"])[:, 0], bounds)[:, None],
            "surface": _window_means(heights, bounds)[:, None],
        }
        regimes = []
        motion = np.zeros((bounds.shape[0], 6))
        for m, (a, b) in enumerate(bounds):
            dp = pos[b] - pos[a]
            dt = float(log.t[b] - log.t[a])
            speed = float(np.linalg.norm(dp)) / dt
            vz = float(dp[2]) / dt
            motion[m, :2] = (speed, vz)
            if speed < 0.02:
                regimes.append("standing")
            elif vz > speed / 3:
                regimes.append("climbing")
            elif vz < -speed / 3:
                regimes.append("descending")
            else:
                regimes.append("traversing")
        context = ClimberContext(
            sim=sim if sim is not None else SimSettings(),
            params=params,
            positions=pos,
            anchor=np.asarray(params.anchor_world, dtype=float),
            motion=motion,
            window_poses=np.asarray(log["pose3_gt"], dtype=float)[
                (bounds[:, 0] + bounds[:, 1]) // 2
            ],
        )
        prepared = PreparedLog(
            log=log,
            split=split,
            bounds=bounds,
            regimes=regimes,
            real=real,
            nominal={},
            replay_log=log,
            holdout_windows=np.full(bounds.shape[0], split == "holdout"),
            schema=self.schema,
            context=context,
        )
        nominal, replay_log = self.replay_features(prepared, {}, drive, context.sim)
        prepared.nominal = nominal
        prepared.replay_log = replay_log
        sur = self.surrogate_features(prepared, {}, drive)
        prepared.bias = {g: prepared.nominal[g] - sur[g][0] for g in prepared.groups}
        return prepared

    # ------------------------------------------------------------------ observability
    # ------------------------------------------------------------------ models
    def _predict(
        self, prepared: PreparedLog, values: Mapping[str, npt.ArrayLike], heights: FloatArray
    ) -> Features:
        """Window features for a batch of values; ``heights`` the ride heights, (B, M) or (M,)."""
        ctx = self._context(prepared)
        tether = tether_model(ctx.anchor, ctx.positions, values)
        B, M = tether.shape[0], prepared.bounds.shape[0]
        h = np.broadcast_to(np.asarray(heights, dtype=float).reshape(-1, M), (B, M))
        return {
            "tether": _window_means(tether, prepared.bounds)[..., None],
            "surface": h[..., None].copy(),
        }

    def replay_features(
        self, prepared: PreparedLog, values: Mapping[str, float], drive: Drive, sim: SimSettings
    ) -> tuple[Features, Log]:
        """Tether model along the true path; ride height measured in PyBullet."""
        ctx = self._context(prepared)
        gap = float(values.get("climber_adsorption_gap.gap", 0.0))
        if gap == 0.0 and ctx.nominal_heights is not None:  # the nominal body: replayed once
            h = ctx.nominal_heights
        else:
            h = replay_heights(ctx.params, ctx.window_poses, gap, scenes=self.scenes)
            if gap == 0.0:
                ctx.nominal_heights = h
        tether = tether_model(
            ctx.anchor, ctx.positions, {k: np.array([v]) for k, v in values.items()}
        )[0]
        rep = Log(
            t=prepared.log.t,
            channels={"pose3_gt": prepared.log["pose3_gt"], "tether": tether},
            meta={
                **dict(prepared.log.meta),
                "replay": True,
                "window_ride_heights": [float(x) for x in h],
            },
            source=f"replay of {prepared.log.name}",
        )
        return self.log_features(prepared, rep), rep

    def log_features(self, prepared: PreparedLog, log: Log) -> Features:
        """Features of a replay: its tether readings and the ride heights it measured per
        window (``meta["window_ride_heights"]``)."""
        tether = _window_means(np.asarray(log["tether"])[:, 0], prepared.bounds)[:, None]
        heights = np.asarray(log.meta["window_ride_heights"], dtype=float)[:, None]
        return {"tether": tether, "surface": heights}

    def surrogate_features(
        self, prepared: PreparedLog, values: Mapping[str, npt.ArrayLike], drive: Drive
    ) -> Features:
        B, v = _values(values)
        gap = v.get("climber_adsorption_gap.gap", np.zeros(B))
        # the gap on top of the nominal PyBullet ride height of each window (the bias adds it)
        return self._predict(prepared, values, gap[:, None] + np.zeros(prepared.bounds.shape[0]))

    def probe_features(
        self, manoeuvre: str, params_like: PreparedLog, values: Mapping[str, npt.ArrayLike]
    ) -> tuple[Features, list[str]]:
        from realitygap.robots.climber import chart_pose

        ctx = self._context(params_like)
        params = ctx.params
        surf = params.real_surface()
        if manoeuvre == "span_climb":
            chart = [(x, 0.3) for x in np.linspace(1.0, 6.5, 60)]
        elif manoeuvre == "chord_sweeps":
            chart = [(x, xi) for x in (1.5, 3.5, 5.5) for xi in np.linspace(0.1, 0.5, 20)]
        else:
            raise ValueError(
                f"unknown climber path {manoeuvre!r}; known: {', '.join(CLIMB_PROBES)}"
            )
        pos = np.array([chart_pose(surf, params, x, xi, 0.0, params.h)[0] for x, xi in chart])
        fake = dataclasses.replace(
            params_like,
            bounds=np.stack([np.arange(len(pos) - 1), np.arange(1, len(pos))], axis=1),
            context=dataclasses.replace(ctx, positions=pos),
        )
        B, v = _values(values)
        gap = v.get("climber_adsorption_gap.gap", np.zeros(B))
        heights = gap[:, None] + np.zeros(fake.bounds.shape[0])
        return self._predict(fake, values, heights), ["tether", "surface"]

    # ------------------------------------------------------------------ blind suite
    def record_blind_logs(
        self, reality: Any, rng: np.random.Generator, settings: BlindLogSettings
    ) -> tuple[list[Log], list[Log]]:
        """One training and one held-out run of the climber on the blade."""
        return record_climber_logs(reality, rng)

    def discovery_terms(self, prepared: PreparedLog) -> DiscoveryTerms:
        """Candidate terms of an unexplained residual, one value per window, with SI units.

        Height of the body (m), the angle between its normal and the vertical
        (rad), the nominal tether length from the anchor (m) and the time (s), each
        at the window's middle row.
        """
        from scipy.spatial.transform import Rotation

        ctx = self._context(prepared)
        poses = ctx.window_poses
        normal = Rotation.from_rotvec(poses[:, 3:6]).apply(np.array([0.0, 0.0, 1.0]))
        mid = (prepared.bounds[:, 0] + prepared.bounds[:, 1]) // 2
        return {
            "height": (poses[:, 2].copy(), "m"),
            "surface normal angle": (np.arccos(np.clip(normal[:, 2], -1.0, 1.0)), "rad"),
            "tether length": (np.linalg.norm(poses[:, :3] - ctx.anchor, axis=1), "m"),
            "time": (np.asarray(prepared.log.t, dtype=float)[mid], "s"),
        }


# --------------------------------------------------------------------------- recording
def log_from_climb_recording(rec: Any, params: Any, *, name: str = "climb") -> Log:
    """A climber :class:`Log` from a :class:`~realitygap.robots.climb_synthetic.ClimbRecording`.

    Rows at the (valid) tether readings; the true pose interpolated to them.
    """
    from realitygap.estimators.climb import TetherReading

    readings = [m for m in rec.measurements if isinstance(m, TetherReading) and m.ok]
    if len(readings) < 3:
        raise LogError(f"{name}: the recording holds {len(readings)} valid tether readings")
    t = np.array([m.t for m in readings])
    p, R = rec.truth_at(t)
    rv = Rotation.from_matrix(R).as_rotvec()
    return Log(
        t=t - t[0],
        channels={
            "pose3_gt": np.column_stack([p, rv]),
            "tether": np.array([m.length for m in readings]),
        },
        meta={"robot": "climber", "name": name, "params": climber_params_to_meta(params)},
        source=name,
    )


TRAIN_PATH: tuple[tuple[float, float], ...] = (
    (1.5, 0.15),
    (5.5, 0.15),
    (5.5, 0.3),
    (2.0, 0.3),
    (2.0, 0.45),
    (5.0, 0.45),
)
"""Chart waypoints ``(x [m], ξ)`` of the blind suite's training run (a lawn-mower sweep)."""

HOLDOUT_PATH: tuple[tuple[float, float], ...] = (
    (2.0, 0.2),
    (6.0, 0.2),
    (6.0, 0.4),
    (3.0, 0.4),
    (3.0, 0.3),
    (4.5, 0.3),
)
"""Chart waypoints of the held-out run (other spans and chord positions)."""


def record_climber_logs(reality: Any, rng: np.random.Generator) -> tuple[list[Log], list[Log]]:
    """One training and one held-out run of the PyBullet climber ``reality`` as logs."""
    from realitygap.robots.climb_record import record_climb_run
    from realitygap.robots.climber import ClimberParams

    nominal = ClimberParams()
    params = reality.apply_params(nominal) if reality is not None else nominal
    out = []
    for name, path in (("climb_train", TRAIN_PATH), ("climb_holdout", HOLDOUT_PATH)):
        rec, _ = record_climb_run(params, path, 1, rng)
        out.append(log_from_climb_recording(rec, nominal, name=name))
    return [out[0]], [out[1]]
