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
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.adapters.arm.kinematics import (
    POSES_PER_WINDOW,
    TOOL_DIST_PAIRS,
    backlash_directions,
    base_tilt,
    known_direction_poses,
    pose_windows,
    probe_positions,
    reach_ratio,
    spread_windows,
    surrogate_points,
    tool_distance_features,
)
from realitygap.diagnosis.adapters.arm.poses import (
    ARM_PROBE_SETS,
    arm_params_from_meta,
    probe_poses,
    record_arm_log,
    replay_arm,
    sample_arm_poses,
    tool_from_meta,
)
from realitygap.diagnosis.adapters.contract import (
    BlindLogSettings,
    DiscoveryTerms,
    Drive,
    LogContext,
    PreparedLog,
    RobotAdapter,
)
from realitygap.diagnosis.logs.channels import ARM_CHANNELS
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.diagnosis.problem.features import FeatureSettings
from realitygap.diagnosis.problem.parameters import reality_from_values
from realitygap.diagnosis.problem.schemas import ARM_REGIMES, ARM_SCHEMA, TOOL_DIST_COLUMNS
from realitygap.robots.simulation import SimSettings

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
    "backlash_directions",
    "base_tilt",
    "known_direction_poses",
    "probe_poses",
    "probe_positions",
    "reach_ratio",
    "record_arm_log",
    "replay_arm",
    "sample_arm_poses",
    "spread_windows",
    "surrogate_points",
    "tool_distance_features",
]

_FOLDED, _OUTSTRETCHED = 0.45, 0.8

DEFAULT_TOOL_NOISE = 2.5e-5
"""Per-axis noise of a tool-point measurement (m) when a log does not state it
(``meta["tool_noise_m"]``): a laser tracker at a few metres."""


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


class ArmAdapter(RobotAdapter):
    """Arm: effects, PyBullet replay, tool-distance features and the analytic surrogate.

    Parameters
    ----------
    max_windows : int
        A log with more windows is thinned to this many, evenly spread (the
        directions of motion still come from the full sequence of poses), so a
        10 000-pose tracker series is diagnosed in a minute.
    """

    robot = "arm"
    uses_time_windows = False  # tool points at stations, not windows of a time series
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
        tool_from_meta(log)
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
        tool = tool_from_meta(log)
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
        bounds = pose_windows(keep.size)
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
        bounds = pose_windows(q.shape[0])
        return {"tool_dist": tool_distance_features(pts, bounds)}, ["tool_dist"]

    # ------------------------------------------------------------------ blind suite
    def blind_measurement_noise(self, settings: BlindLogSettings) -> dict[str, FloatArray]:
        """The laser tracker's noise per axis in the blind logs."""
        return {"tool_pos": np.full(3, settings.arm_tracker_noise)}

    def record_blind_logs(
        self, reality: Any, rng: np.random.Generator, settings: BlindLogSettings
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

    def discovery_terms(self, prepared: PreparedLog) -> DiscoveryTerms:
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
