r"""The arm's diagnosis adapter: tool-point distances, PyBullet replay, analytic surrogate.

An arm log is a sequence of measurement poses (``t`` counts poses, one per
second): joint encoder readings ``joints`` (N, 6) and the tool point
``tool_pos`` (N, 3) as an external instrument measured it — a laser tracker
on a probe, in the tracker's own frame. Its metadata gives the nominal arm
(``meta["params"]``: MDH table, link masses, payload) and the tool point in the
flange frame (``meta["tool"]``, m) and the noise of one tool-point measurement
(``meta["tool_noise_m"]``, m per axis: instrument noise and the arm's own
repeatability).

Features
    Poses are grouped in windows of four, a quarter of the series apart
    (:func:`spread_windows`: long distances across the workspace, whatever the
    order of measurement); each window's features are the six distances between
    their tool points (group ``tool_dist``). Distances do not depend on where the instrument stands, so
    no base registration enters the comparison — the distance-accuracy idea of
    the calibration, applied to the gap. (The base yaw offset ``dtheta1`` and
    the base height ``d1`` are invisible to distances, and say so.)

Regimes
    ``folded``, ``mid_reach`` or ``outstretched`` by the horizontal reach of the
    wrist from the base axis relative to the arm's length (upper arm plus
    forearm): below 0.45, above 0.8, or between. Gravity loads shoulder and
    elbow in proportion to the reach.

Replay (the simulator)
    Every pose of the log is set in a PyBullet arm built from the nominal
    parameters with the effects applied
    (:meth:`~realitygap.robots.effects.Reality.apply_params`); the link angles
    follow from the readings through the arm's transmission model
    (:meth:`~realitygap.robots.arm.ArmRobot.link_target`: encoder scale, gearbox
    compliance under the holding torque from PyBullet's inverse dynamics,
    backlash in the direction of the last move), and the tool point is read
    from PyBullet's link state.

Surrogate (for the fit)
    The same model in closed form, batched over effect values: link angles

    .. math:: q^{link} = q^{enc} / s - c\,\tau^g(q^{enc}) - \tfrac{b}{2}\,\mathrm{dir},

    with :math:`\tau^g` precomputed once per pose from the nominal body, then
    vectorised 5-parameter MDH forward kinematics with the geometric effects
    added to the table, the measured point moved by the tool errors, the base
    tilt and the instrument's length scale applied
    (:mod:`~realitygap.diagnosis.adapters.arm.kinematics`). It matches the replay to well
    below the noise (the only approximation is :math:`\tau^g` at the reading
    instead of the sagged angle: a second-order term).

Unknown directions
    The first pose of a series has no known approach direction, nor has any
    joint before its first move; windows with such a pose are left out
    (:func:`~realitygap.diagnosis.adapters.arm.kinematics.known_direction_poses`), so a
    direction-dependent fit (backlash) never assumes one.

Structured residual and discovery
    Windows of random poses are independent, so the verdict's residual tests use
    the stated measurement noise; :meth:`ArmAdapter.residual_structure` adds two
    held-out tests (the noise floor raised by the fitted parameters' own noise,
    and terms fitted on the training residual that predict the held-out one), and
    :meth:`ArmAdapter.discover_residual` describes a residual by joint-angle error
    generators (:mod:`~realitygap.diagnosis.adapters.arm.discovery`).

Aliases
    :meth:`ArmAdapter.alias_groups` states which effects tool-point distances
    cannot separate (tool offset / link lengths / measurement scale; base tilt /
    joint-2 compliance) with the correlation measured on the logs
    (:mod:`~realitygap.diagnosis.adapters.arm.aliases`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.adapters.arm.kinematics import (
    backlash_directions,
    base_tilt,
    known_direction_poses,
    probe_positions,
    surrogate_points,
)
from realitygap.diagnosis.adapters.contract import AdapterBase, Drive, LogContext, PreparedLog
from realitygap.diagnosis.logs.log import ChannelSpec, Log, LogError, Role
from realitygap.diagnosis.problem.features import FeatureGroup, FeatureSchema, FeatureSettings
from realitygap.diagnosis.problem.parameters import reality_from_values
from realitygap.estimators.arm.mdh import MDHTable
from realitygap.robots.simulation import SimSettings

if TYPE_CHECKING:
    from realitygap.diagnosis.validation.suite import SuiteSettings

FloatArray = npt.NDArray[np.float64]
Features = dict[str, FloatArray]

__all__ = [
    "ARM_CHANNELS",
    "ARM_PROBE_SETS",
    "ARM_REGIMES",
    "ARM_SCHEMA",
    "POSES_PER_WINDOW",
    "TOOL_DIST_COLUMNS",
    "TOOL_DIST_PAIRS",
    "ArmAdapter",
    "ArmContext",
    "arm_params_from_meta",
    "arm_params_to_meta",
    "backlash_directions",
    "base_tilt",
    "known_direction_poses",
    "probe_poses",
    "probe_positions",
    "reach_ratio",
    "record_arm_log",
    "sample_arm_poses",
    "spread_windows",
    "surrogate_points",
    "tool_distance_features",
]

POSES_PER_WINDOW = 4
"""Consecutive poses per window (their 6 pairwise distances are the features)."""

TOOL_DIST_COLUMNS: tuple[str, ...] = ("d01", "d02", "d03", "d12", "d13", "d23")
"""Pairs of the four poses of an arm window whose tool-point distance is compared."""

ARM_REGIMES: tuple[str, ...] = ("folded", "mid_reach", "outstretched")
"""Arm windows, by how far the wrist reaches out from the base axis."""

ARM_CHANNELS: tuple[ChannelSpec, ...] = (
    ChannelSpec(
        "joints",
        ("q1", "q2", "q3", "q4", "q5", "q6"),
        ("rad",) * 6,
        Role.SENSOR,
        "joint encoder readings of the arm at rest",
    ),
    ChannelSpec(
        "tool_pos",
        ("x", "y", "z"),
        ("m", "m", "m"),
        Role.TRUTH,
        "tool point measured by an external instrument (laser tracker), in its own frame",
    ),
)
"""Channels of an arm log: one row per measurement pose, the arm at rest."""

ARM_SCHEMA = FeatureSchema(
    groups=(
        FeatureGroup(
            "tool_dist",
            TOOL_DIST_COLUMNS,
            ("m",) * len(TOOL_DIST_COLUMNS),
            (1e-4,) * len(TOOL_DIST_COLUMNS),
        ),
    ),
    regimes=ARM_REGIMES,
)
"""The arm's window features (tool-point distances, default scale 0.1 mm) and regimes."""

TOOL_DIST_PAIRS: tuple[tuple[int, int], ...] = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
"""The pose pairs of a window behind :data:`TOOL_DIST_COLUMNS`, in their order."""
assert len(TOOL_DIST_PAIRS) == len(TOOL_DIST_COLUMNS)

_FOLDED, _OUTSTRETCHED = 0.45, 0.8

DEFAULT_TOOL_NOISE = 2.5e-5
"""Per-axis noise of a tool-point measurement (m) when a log does not state it
(``meta["tool_noise_m"]``): a laser tracker at a few metres."""

ARM_PROBE_SETS: dict[str, str] = {
    "outstretched_poses": "poses with the upper arm and forearm stretched out near the "
    "horizontal (largest gravity torque on shoulder and elbow)",
    "approach_reversals": "each pose measured twice, approached once from below and once from "
    "above on every joint",
    "wrist_sweep": "the wrist joints 4-6 over their full range with the arm held still",
    "base_sweep": "joint 1 over its full range at a few fixed arm postures",
}
"""Pose sets suggested to separate confounded arm effects (identifiability advice)."""


# --------------------------------------------------------------------------- parameters
def arm_params_to_meta(params: Any) -> dict[str, Any]:
    """The nominal-arm metadata of a log (``meta["params"]``) from an :class:`ArmParams`."""
    return {
        "mdh": params.mdh.param_dict(),
        "mdh_name": params.mdh.name,
        "link_masses": list(params.link_masses),
        "payload_mass": float(params.camera_mass),
        "joint_lower": list(params.joint_lower),
        "joint_upper": list(params.joint_upper),
    }


def arm_params_from_meta(log: Log) -> Any:
    """The nominal :class:`~realitygap.robots.arm.ArmParams` of an arm log.

    Raises
    ------
    LogError
        ``meta["params"]`` missing or without a full 6-joint MDH table.
    """
    from realitygap.robots.arm import ArmParams

    raw = log.meta.get("params")
    if not isinstance(raw, Mapping) or not isinstance(raw.get("mdh"), Mapping):
        raise LogError(
            f"{log.source}: an arm log needs meta['params']['mdh'] (the nominal MDH table, "
            "e.g. MDHTable.param_dict()); got "
            f"{sorted(raw) if isinstance(raw, Mapping) else type(raw).__name__}"
        )
    mdh = raw["mdh"]
    base = MDHTable(np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6))
    names = base.param_names()
    missing = [n for n in names if n not in mdh]
    if missing:
        raise LogError(
            f"{log.source}: meta['params']['mdh'] lacks {', '.join(missing[:6])}"
            f"{' …' if len(missing) > 6 else ''} (a 6-joint table needs theta1..beta6)"
        )
    table = base.with_params([float(mdh[n]) for n in names], names)
    table = MDHTable(
        table.theta_offset,
        table.d,
        table.a,
        table.alpha,
        table.beta,
        str(raw.get("mdh_name", "arm")),
    )
    kw: dict[str, Any] = {"mdh": table}
    if "link_masses" in raw:
        kw["link_masses"] = tuple(float(v) for v in raw["link_masses"])
    if "payload_mass" in raw:
        kw["camera_mass"] = float(raw["payload_mass"])
    for key in ("joint_lower", "joint_upper"):
        if key in raw:
            kw[key] = tuple(float(v) for v in raw[key])
    try:
        return ArmParams(**kw)
    except ValueError as exc:
        raise LogError(f"{log.source}: meta['params'] is not a valid arm: {exc}") from None


def _tool(log: Log) -> FloatArray:
    tool = np.asarray(log.meta.get("tool", (0.0, 0.0, 0.0)), dtype=float).reshape(-1)
    if tool.shape != (3,) or not np.all(np.isfinite(tool)):
        raise LogError(
            f"{log.source}: meta['tool'] must be the tool point in the flange frame, 3 finite "
            f"numbers in m; got {log.meta.get('tool')!r}"
        )
    return tool


# --------------------------------------------------------------------------- kinematics
def tool_distance_features(points: FloatArray, bounds: npt.NDArray[np.int64]) -> FloatArray:
    """Pairwise distances (…, M, 6) of the tool points (…, N, 3) of every window."""
    a = bounds[:, 0]
    cols = [
        np.linalg.norm(points[..., a + i, :] - points[..., a + j, :], axis=-1)
        for i, j in TOOL_DIST_PAIRS
    ]
    return np.stack(cols, axis=-1)


def reach_ratio(table: MDHTable, q: FloatArray) -> FloatArray:
    """Horizontal distance of the wrist (frame 4) from the base axis over |a2| + |a3| (N,)."""
    from realitygap.estimators.arm.mdh import joint_frames

    frames = joint_frames(table, q)
    r = np.hypot(frames[:, 4, 0, 3], frames[:, 4, 1, 3])
    length = abs(float(table.a[1])) + abs(float(table.a[2]))
    return r / max(length, 1e-9)


def _windows(n: int) -> npt.NDArray[np.int64]:
    m = n // POSES_PER_WINDOW
    a = np.arange(m) * POSES_PER_WINDOW
    return np.stack([a, a + POSES_PER_WINDOW], axis=1).astype(np.int64)


def spread_windows(n: int) -> npt.NDArray[np.int64]:
    """Rows (M, 4) of the poses of each window of a series of ``n`` poses.

    Window ``m`` holds poses ``m, m + M, m + 2M, m + 3M`` with ``M = n // 4``: its
    four poses lie a quarter of the series apart, so its tool-point distances span
    the workspace whatever order the poses were measured in (in a grid series
    neighbouring poses are a few centimetres apart, and a short distance hardly
    changes with the geometry: it would hide what the calibration sees).
    """
    m = n // POSES_PER_WINDOW
    return (np.arange(m)[:, None] + m * np.arange(POSES_PER_WINDOW)[None, :]).astype(np.int64)


# --------------------------------------------------------------------------- surrogate
_SURROGATE_EFFECTS = (
    "arm_tool_offset",
    "arm_joint_offset",
    "arm_link_length",
    "arm_parallel_twist",
    "arm_twist_error",
    "arm_joint_compliance",
    "arm_backlash",
    "arm_encoder_scale",
    "arm_measurement_scale",
    "arm_geometric_tolerances",
    "arm_base_compliance",
)


# --------------------------------------------------------------------------- replay
def replay_arm(
    params: Any,
    q_enc: FloatArray,
    tool: FloatArray,
    reality: Any = None,
    direction: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Tool points (N, 3) in the base frame of the PyBullet arm for readings ``q_enc``.

    ``direction`` (N, 6) is each joint's last direction of motion (from the
    readings by default, :func:`backlash_directions`). Returns the points and the
    holding torques (N, 6) (N·m) at the link angles.
    """
    from realitygap.robots.arm import ArmRobot, constant_transform
    from realitygap.robots.effects import (
        arm_base_compliance,
        arm_measurement_scale,
        arm_tool_offset,
    )
    from realitygap.robots.world import World

    body_params = reality.apply_params(params) if reality is not None else params
    tool = np.asarray(tool, dtype=float) + np.asarray(arm_tool_offset(reality))
    if direction is None:
        direction = backlash_directions(q_enc)
    world = World()
    try:
        robot = ArmRobot(world, body_params)
        T_base_inv = np.linalg.inv(body_params.T_world_base)
        last = constant_transform(body_params.mdh, 5)
        pts = np.empty((q_enc.shape[0], 3))
        taus = np.empty((q_enc.shape[0], 6))
        for k, (q, dirn) in enumerate(zip(q_enc, direction)):
            q_link = robot.link_target(q, dirn)
            robot.set_link_angles(q_link)
            F = T_base_inv @ robot.link_pose("link6") @ last
            pts[k] = F[:3, :3] @ tool + F[:3, 3]
            taus[k] = robot.gravity_torques(q_link)
        k_tilt = arm_base_compliance(reality)
        if k_tilt != 0.0:
            pts = base_tilt(pts[None], params.mdh, q_enc, taus[:, 1], [k_tilt])[0]
        return pts * arm_measurement_scale(reality), taus
    finally:
        world.close()


# --------------------------------------------------------------------------- the adapter
@dataclass
class ArmContext(LogContext):
    """What the arm keeps about a prepared log.

    Attributes
    ----------
    params : ArmParams
        The nominal arm of the log.
    tool : ndarray, shape (3,)
        Tool point in the flange frame, m.
    q : ndarray, shape (N, 6)
        Joint readings of the kept poses, rad.
    tau : ndarray, shape (N, 6)
        Holding torques of the nominal body at those poses, N·m.
    direction : ndarray, shape (N, 6)
        Direction of each joint's last move (backlash).
    rows : ndarray of int, shape (N,)
        Rows of the log the kept poses come from.
    motion : ndarray, shape (M, 6)
        Per window: reach and the shoulder / elbow holding torques (/ 100 N·m), then zeros.
    """

    params: Any
    tool: FloatArray
    q: FloatArray
    tau: FloatArray
    direction: FloatArray
    rows: npt.NDArray[np.int64]
    motion: FloatArray

    def window_motion(self, bounds: npt.NDArray[np.int64]) -> FloatArray | None:
        return self.motion


class ArmAdapter(AdapterBase):
    """Arm: effects, PyBullet replay, tool-distance features and the analytic surrogate.

    Parameters
    ----------
    max_windows : int
        A log with more windows is thinned to this many, evenly spread (the
        directions of motion still come from the full sequence of poses), so a
        10 000-pose tracker series is diagnosed in a minute.
    """

    robot = "arm"
    channels = ARM_CHANNELS
    schema = ARM_SCHEMA
    surrogate_effects = _SURROGATE_EFFECTS
    motion_labels = (
        ("reach (share of full reach)", "1"),
        ("shoulder holding torque", "100 N·m"),
        ("elbow holding torque", "100 N·m"),
        *((("unused", "1"),) * 3),
    )
    """Meaning of the window motion columns (:mod:`realitygap.diagnosis.stages.coverage`)."""

    def __init__(self, max_windows: int = 600):
        if max_windows < 2:
            raise ValueError(f"max_windows must be at least 2, got {max_windows}")
        self.max_windows = int(max_windows)

    def probe_manoeuvres(self) -> dict[str, str]:
        """Pose sets the identifiability advice may suggest, with descriptions."""
        return dict(ARM_PROBE_SETS)

    def alias_groups(
        self,
        prepared: Sequence[PreparedLog],
        threshold: float = 0.95,
        effects: Sequence[str] | None = None,
    ) -> list[dict[str, Any]]:
        """The alias groups this adapter knows, with the correlation measured on these logs.

        Groups (:data:`~realitygap.diagnosis.adapters.arm.aliases.ARM_ALIAS_GROUPS`): tool
        offset / link lengths / measurement scale (on tool-to-tool distances a
        uniform length scale is a set of link-length and tool-length errors), and
        base compliance / joint compliance (a base tilting with the shoulder's
        load turns the arm like joint-2 compliance). For every pair the first
        canonical correlation of their feature Jacobians on the training windows
        is measured; above ``threshold`` the two are "aliases on this data".
        ``effects`` keeps only the groups that contain one of them (e.g. the
        verdict's). See :func:`~realitygap.diagnosis.adapters.arm.aliases.measure_aliases`
        for the returned dicts.
        """
        from realitygap.diagnosis.adapters.arm.aliases import measure_aliases

        return measure_aliases(self, prepared, threshold=threshold, effects=effects)

    # ------------------------------------------------------------------ checks
    def check(self, log: Log, drive: Drive) -> Log:
        self.check_robot(log, drive, replayed_from="its joint readings")
        log.require(["joints", "tool_pos"], "an arm diagnosis")
        arm_params_from_meta(log)
        _tool(log)
        if log.n < 2 * POSES_PER_WINDOW:
            raise LogError(
                f"{log.source}: {log.n} poses are too few; the diagnosis needs at least "
                f"{2 * POSES_PER_WINDOW} (two windows of {POSES_PER_WINDOW})"
            )
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
        params = arm_params_from_meta(log)
        tool = _tool(log)
        q_all = np.asarray(log["joints"], dtype=float)
        dir_all = backlash_directions(q_all)  # from the full sequence of moves
        # poses of unknown approach direction are left out, not assumed; only when fewer
        # than two windows would remain are they kept, in the middle of their play
        usable = np.flatnonzero(known_direction_poses(dir_all))
        if usable.size < 2 * POSES_PER_WINDOW:
            usable = np.arange(log.n)
        windows = usable[spread_windows(usable.size)]
        if windows.shape[0] > self.max_windows:
            # evenly spread windows; every pose keeps the direction of its real last move
            pick = np.unique(np.linspace(0, windows.shape[0] - 1, self.max_windows).round())
            windows = windows[pick.astype(np.int64)]
        keep = windows.reshape(-1)
        q, direction = q_all[keep], dir_all[keep]
        points = np.asarray(log["tool_pos"], dtype=float)[keep]
        bounds = _windows(keep.size)
        reach = reach_ratio(params.mdh, q)
        reach_w = np.array([reach[a:b].mean() for a, b in bounds])
        regimes = [
            "folded" if r < _FOLDED else "outstretched" if r > _OUTSTRETCHED else "mid_reach"
            for r in reach_w
        ]
        real = {"tool_dist": tool_distance_features(points, bounds)}
        nominal_pts, tau = replay_arm(params, q, tool, direction=direction)
        motion = np.zeros((bounds.shape[0], 6))
        for m, (a, b) in enumerate(bounds):
            motion[m, :3] = (reach[a:b].mean(), tau[a:b, 1].mean() / 100, tau[a:b, 2].mean() / 100)
        context = ArmContext(
            sim=sim if sim is not None else SimSettings(),
            params=params,
            tool=tool,
            q=q,
            tau=tau,
            direction=direction,
            rows=keep,
            motion=motion,
        )
        prepared = PreparedLog(
            log=log,
            split=split,
            bounds=bounds,
            regimes=regimes,
            real=real,
            nominal={"tool_dist": tool_distance_features(nominal_pts, bounds)},
            replay_log=self._replay_log(log, q, nominal_pts),
            holdout_windows=np.full(bounds.shape[0], split == "holdout"),
            schema=self.schema,
            context=context,
        )
        sur = self.surrogate_features(prepared, {}, drive)
        prepared.bias = {g: prepared.nominal[g] - sur[g][0] for g in prepared.groups}
        return prepared

    @staticmethod
    def _replay_log(log: Log, q: FloatArray, points: FloatArray) -> Log:
        return Log(
            t=np.arange(q.shape[0], dtype=float),
            channels={"joints": q, "tool_pos": points},
            meta={**dict(log.meta), "replay": True},
            source=f"replay of {log.name}",
        )

    # ------------------------------------------------------------------ observability
    def observable(self, effect: str, prepared: Sequence[PreparedLog], drive: Drive) -> str:
        why = super().observable(effect, prepared, drive)
        if why.startswith("shows only in camera_pose"):
            why += (
                " (a tool point measured from outside sees neither the camera mounting nor its "
                "intrinsics)"
            )
        return why

    def noise_levels(
        self, prepared: Sequence[PreparedLog], settings: FeatureSettings
    ) -> dict[str, float] | None:
        """Noise of the tool-point distances in feature-scale units.

        Windows of random poses are independent, so the window-to-window spread
        cannot tell noise from effects; the level comes from the measurement
        instead: each log's ``meta["tool_noise_m"]`` (per-axis standard deviation
        of a tool-point measurement, m; :data:`DEFAULT_TOOL_NOISE` when absent).
        A distance between two points carries √2 times that.
        """
        sigma = max(
            (float(p.log.meta.get("tool_noise_m", DEFAULT_TOOL_NOISE)) for p in prepared),
            default=DEFAULT_TOOL_NOISE,
        )
        scale = float(np.min(settings.scale("tool_dist")))
        return {"tool_dist": math.sqrt(2.0) * sigma / scale}

    # ------------------------------------------------------------------ models
    @staticmethod
    def _context(prepared: PreparedLog) -> ArmContext:
        ctx = prepared.context
        assert isinstance(ctx, ArmContext)
        return ctx

    def replay_features(
        self, prepared: PreparedLog, values: Mapping[str, float], drive: Drive, sim: SimSettings
    ) -> tuple[Features, Log]:
        reality = reality_from_values(values) if values else None
        ctx = self._context(prepared)
        pts, _ = replay_arm(ctx.params, ctx.q, ctx.tool, reality, ctx.direction)
        feats = {"tool_dist": tool_distance_features(pts, prepared.bounds)}
        return feats, self._replay_log(prepared.log, ctx.q, pts)

    def log_features(self, prepared: PreparedLog, log: Log) -> Features:
        """Window features of a replay of the prepared poses."""
        return {"tool_dist": tool_distance_features(np.asarray(log["tool_pos"]), prepared.bounds)}

    def surrogate_features(
        self, prepared: PreparedLog, values: Mapping[str, npt.ArrayLike], drive: Drive
    ) -> Features:
        ctx = self._context(prepared)
        pts = surrogate_points(ctx.params.mdh, ctx.q, ctx.tau, ctx.direction, ctx.tool, values)
        return {"tool_dist": tool_distance_features(pts, prepared.bounds)}

    def probe_features(
        self, manoeuvre: str, params_like: PreparedLog, values: Mapping[str, npt.ArrayLike]
    ) -> tuple[Features, list[str]]:
        ctx = self._context(params_like)
        q = probe_poses(manoeuvre, ctx.params.mdh)
        # holding torques of the nominal body at the probe poses
        from realitygap.robots.arm import ArmRobot
        from realitygap.robots.world import World

        world = World()
        try:
            robot = ArmRobot(world, ctx.params)
            tau = np.array([robot.gravity_torques(x) for x in q])
        finally:
            world.close()
        pts = surrogate_points(ctx.params.mdh, q, tau, backlash_directions(q), ctx.tool, values)
        bounds = _windows(q.shape[0])
        return {"tool_dist": tool_distance_features(pts, bounds)}, ["tool_dist"]

    # ------------------------------------------------------------------ blind suite
    def record_blind_logs(
        self, reality: Any, rng: np.random.Generator, settings: SuiteSettings
    ) -> tuple[list[Log], list[Log]]:
        """One training and one held-out set of random poses measured by a laser tracker."""
        train, holdout = (
            [
                record_arm_log(
                    reality,
                    rng,
                    settings.arm_poses,
                    tracker_noise=settings.arm_tracker_noise,
                    name=name,
                )
            ]
            for name in ("arm_train", "arm_holdout")
        )
        return train, holdout

    def discover_residual(
        self,
        problem: Any,
        z_train: FloatArray,
        z_holdout: FloatArray,
        mask: npt.NDArray[np.bool_] | None,
        settings: Any,
    ) -> Any:
        """Discovery on tool distances: joint-angle error generators, per residual entry
        (:func:`~realitygap.diagnosis.adapters.arm.discovery.discover_arm`); the per-window terms of
        :meth:`discovery_terms` cannot describe a distance between two poses."""
        from realitygap.diagnosis.adapters.arm.discovery import discover_arm

        return discover_arm(problem, z_train, z_holdout, mask, settings)

    def held_parameters(self, problem: Any, keys: Sequence[str]) -> dict[str, str]:
        """Parameters of a model the training poses cannot identify: held at nominal.

        Tool distances depend linearly on small geometric errors, so the rank test
        of the identification's identifiability analysis decides
        (:func:`~realitygap.diagnosis.fit.identifiability.dependent_parameters`): a
        parameter that moves no training distance, or only along the directions of
        parameters before it in the model (e.g. a wrist offset or twist when the
        training poses keep the wrist still), is not fitted into a direction the
        data cannot see.
        """
        from realitygap.diagnosis.fit.identifiability import dependent_parameters

        return dependent_parameters(problem, keys)

    def residual_structure(
        self, problem: Any, values: Mapping[str, float], desc: dict[str, Any]
    ) -> dict[str, Any]:
        """The structured-residual test with held-out predictability added
        (:func:`~realitygap.diagnosis.adapters.arm.discovery.held_out_structure`)."""
        from realitygap.diagnosis.adapters.arm.discovery import held_out_structure

        return held_out_structure(problem, values, desc)

    def discovery_terms(self, prepared: PreparedLog) -> dict[str, tuple[FloatArray, str]]:
        """Candidate terms of an unexplained residual, one value per window, with SI units.

        Window means of ``sin q_j``, ``cos q_j``, ``sin 2q_j``, ``cos 2q_j`` and the
        nominal gravity torque ``τ_j`` (N·m) of each joint, the reach ratio and the
        time of the window (s; the log's row index where time is not logged).
        """
        ctx = self._context(prepared)
        b = prepared.bounds
        t_rows = np.asarray(prepared.log.t, dtype=float)[ctx.rows]

        def wmean(x: FloatArray) -> FloatArray:
            return np.array([x[i:j].mean() for i, j in b])

        out: dict[str, tuple[FloatArray, str]] = {}
        for j in range(ctx.q.shape[1]):
            q = ctx.q[:, j]
            out[f"sin q{j + 1}"] = (wmean(np.sin(q)), "")
            out[f"cos q{j + 1}"] = (wmean(np.cos(q)), "")
            out[f"sin 2q{j + 1}"] = (wmean(np.sin(2 * q)), "")
            out[f"cos 2q{j + 1}"] = (wmean(np.cos(2 * q)), "")
            out[f"τ{j + 1} (gravity)"] = (wmean(ctx.tau[:, j]), "N·m")
        out["reach"] = (wmean(reach_ratio(ctx.params.mdh, ctx.q)), "")
        out["time"] = (wmean(t_rows), "s")
        return out


def probe_poses(name: str, table: MDHTable, n: int = 40) -> FloatArray:
    """The joint readings (n, 6) of a pose set of :data:`ARM_PROBE_SETS` (deterministic)."""
    if name not in ARM_PROBE_SETS:
        raise ValueError(f"unknown arm pose set {name!r}; known: {', '.join(ARM_PROBE_SETS)}")
    rng = np.random.default_rng(sum(ord(c) for c in name))
    q = rng.uniform(-math.pi, math.pi, (n, 6))
    if name == "outstretched_poses":
        q[:, 1] = rng.choice([-0.15, -math.pi + 0.15], n) + rng.normal(0, 0.1, n)
        q[:, 2] = rng.normal(0.0, 0.15, n)
    elif name == "approach_reversals":
        # P - δ, P (from below), P + δ, P (from above): one window per pose
        base = q[: max(n // POSES_PER_WINDOW, 1)]
        q = np.stack([base - 0.2, base, base + 0.2, base], axis=1).reshape(-1, 6)
    elif name == "wrist_sweep":
        q[:, :3] = (0.3, -1.2, 1.2)
    elif name == "base_sweep":
        postures = np.array([[-1.0, 1.2], [-0.5, 0.6], [-1.6, 1.8], [-0.2, 0.3]])
        q[:, 1:3] = postures[np.arange(n) % 4]
    return q


# --------------------------------------------------------------------------- recording
def sample_arm_poses(
    robot: Any, rng: np.random.Generator, n: int, max_tries: int = 50_000
) -> FloatArray:
    """``n`` random collision-free joint commands (n, 6) of a PyBullet arm, from ``rng``.

    Shoulder above the horizontal, elbow anywhere but fully folded, wrist free;
    configurations that collide (with the arm itself or the scenery) are drawn
    again.
    """
    out: list[FloatArray] = []
    for _ in range(max_tries):
        q = rng.uniform(-math.pi, math.pi, 6)
        q[1] = rng.uniform(-math.pi, 0.0)
        q[2] = rng.uniform(-2.6, 2.6)
        if not robot.collides_at(q):
            out.append(q)
            if len(out) == n:
                return np.asarray(out)
    raise RuntimeError(f"found only {len(out)} of {n} collision-free poses in {max_tries} draws")


def record_arm_log(
    reality: Any,
    rng: np.random.Generator,
    n_poses: int,
    *,
    params: Any = None,
    tool: npt.ArrayLike = (0.0, 0.05, 0.1),
    tracker_noise: float = 2e-5,
    name: str = "arm",
) -> Log:
    """Measure ``n_poses`` random poses of the PyBullet arm ``reality`` with a laser tracker.

    The arm (nominal ``params`` with the effects of ``reality`` built in) moves
    pose to pose through its servo (:meth:`~realitygap.robots.arm.ArmRobot.move_to`,
    so backlash follows the real order of moves and compliance sags under the
    real holding torque); at each pose the encoders are read (noise,
    quantisation) and the tool point ``tool`` (flange frame, m) is measured in
    the world with isotropic Gaussian noise of ``tracker_noise`` (m) per axis.
    """
    from realitygap.robots.arm import ArmParams, ArmRobot, constant_transform
    from realitygap.robots.effects import (
        arm_base_compliance,
        arm_measurement_scale,
        arm_tool_offset,
    )
    from realitygap.robots.world import World

    nominal = params if params is not None else ArmParams()
    body = reality.apply_params(nominal) if reality is not None else nominal
    length, k_tilt = arm_measurement_scale(reality), arm_base_compliance(reality)
    tool = np.asarray(tool, dtype=float).reshape(3)
    measured = tool + np.asarray(arm_tool_offset(reality))
    world = World()
    try:
        robot = ArmRobot(world, body)
        poses = sample_arm_poses(robot, rng, n_poses)
        robot.reset(poses[0] - 0.05)
        last = constant_transform(body.mdh, 5)
        q_enc = np.empty((n_poses, 6))
        pts = np.empty((n_poses, 3))
        for k, q in enumerate(poses):
            res = robot.move_to(q)
            if not res.ok:
                raise RuntimeError(f"pose {k} could not be reached: {res.message}")
            q_enc[k] = robot.read_encoders(rng)
            F = robot.link_pose("link6") @ last
            p = F[:3, :3] @ measured + F[:3, 3]
            if k_tilt != 0.0:
                tau2 = robot.gravity_torques(robot.link_target(q))[1]
                p = base_tilt(p[None, None], nominal.mdh, q[None], np.array([tau2]), [k_tilt])[0, 0]
            pts[k] = length * p + rng.normal(0.0, tracker_noise, 3)
    finally:
        world.close()
    return Log(
        t=np.arange(n_poses, dtype=float),
        channels={"joints": q_enc, "tool_pos": pts},
        meta={
            "robot": "arm",
            "name": name,
            "params": arm_params_to_meta(nominal),
            "tool": tool.tolist(),
            "tool_noise_m": float(tracker_noise),
        },
        source=name,
    )
