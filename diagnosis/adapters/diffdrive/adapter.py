"""The differential drive's diagnosis adapter: PyBullet replay, pose / tick / camera features.

A differential-drive log is sampled at the control rate: the commanded body
twist ``cmd``, the cumulative encoder counts ``ticks``, the ground-truth base
pose ``pose_gt`` (motion capture), and optionally the estimated pose
``pose_est`` and a camera pose ``pose_cam``. Its metadata gives the nominal
robot (:func:`~realitygap.diagnosis.adapters.diffdrive.replay.params_from_meta`).

Features, per window (1 s by default)
    ``pose_gt`` — motion of the ground truth in the frame of its pose at the
    window start; ``ticks`` — wheel travel counted by the encoders (nominal
    metres per tick); ``pose_cam`` — mean camera pose seen from the
    ground-truth base pose (:func:`~realitygap.diagnosis.problem.features.features`).

Regimes
    From the applied commands (or, when the wheels drive the replay, from the
    wheel motion): :data:`~realitygap.diagnosis.problem.features.DIFFDRIVE_REGIMES`.

Replay and surrogate
    The nominal PyBullet robot driven by the same commands or wheel rotation
    (:func:`~realitygap.diagnosis.adapters.diffdrive.replay.replay`); the fit uses the analytic
    :class:`~realitygap.robots.diffdrive_surrogate.DiffDriveSurrogate`.

Blind logs
    Ordinary manoeuvres (:data:`TRAIN_MANOEUVRES`, :data:`HOLDOUT_MANOEUVRES`)
    recorded with motion-capture and camera noise: the firmware-ramped ones
    through :class:`~realitygap.envs.wheeled_nav.WheeledNavEnv` and
    :class:`~realitygap.diagnosis.adapters.diffdrive.record.RecordLog`, hard starts by driving
    the robot directly (:mod:`~realitygap.diagnosis.adapters.diffdrive.blind`).

The log context and the geometry the logs share are in
:mod:`~realitygap.diagnosis.adapters.diffdrive.context`, the drive-train figures of a
command-driven replay (:meth:`DiffDriveAdapter.actuation`) in
:mod:`~realitygap.diagnosis.adapters.diffdrive.actuation`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import wrap_angle
from realitygap.diagnosis.adapters.contract import (
    BlindLogSettings,
    Drive,
    PreparedLog,
    WheelDrivenAdapter,
)
from realitygap.diagnosis.adapters.diffdrive.actuation import (
    actuation_spread,
    command_wheel_gains,
    wheel_tracking,
)
from realitygap.diagnosis.adapters.diffdrive.blind import (
    BLIND_NOISE,
    HOLDOUT_MANOEUVRES,
    TRAIN_MANOEUVRES,
    record_case_logs,
)
from realitygap.diagnosis.adapters.diffdrive.context import (
    DRIVE_RESPONSE_FLOOR,
    TRUTH_FRAME_RANGE,
    TRUTH_LATENCY_FLOOR,
    TRUTH_YAW_RANGE,
    TURN_WINDOW_RAD,
    DiffDriveContext,
    declared_truth_frame,
    geometry,
    geometry_report,
    meters_per_tick,
    twist_from_ticks,
    values_for_log,
)
from realitygap.diagnosis.adapters.diffdrive.firmware import (
    FIRMWARE_CONVENTIONS,
    FirmwareFit,
    fit_firmware_limits,
)
from realitygap.diagnosis.adapters.diffdrive.manoeuvres import (
    MANOEUVRES,
    PROBE_MANOEUVRES,
    probe_description,
)
from realitygap.diagnosis.adapters.diffdrive.replay import (
    applied_commands,
    params_from_meta,
    replay,
)
from realitygap.diagnosis.adapters.diffdrive.skid import complete_skid_steer
from realitygap.diagnosis.logs.channels import DIFFDRIVE_CHANNELS
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.diagnosis.problem.features import (
    FeatureSettings,
    classify_regimes,
    features,
    window_bounds,
)
from realitygap.diagnosis.problem.parameters import param_spec, reality_from_values, split_key
from realitygap.diagnosis.problem.residual import robust_spread
from realitygap.diagnosis.problem.schemas import DIFFDRIVE_SCHEMA
from realitygap.diagnosis.stages.scales import gain_through_origin
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.diffdrive_replay import nominal_odometry, replay_rate
from realitygap.robots.diffdrive_surrogate import (
    SURROGATE_EFFECTS,
    DiffDriveSurrogate,
    SurrogateInputs,
    calibrate,
)
from realitygap.robots.effects import Reality
from realitygap.robots.simulation import SimSettings

FloatArray = npt.NDArray[np.float64]

Features = dict[str, FloatArray]

__all__ = [
    "DIFFDRIVE_CHANNELS",
    "DIFFDRIVE_SCHEMA",
    "DRIVE_RESPONSE_FLOOR",
    "HOLDOUT_MANOEUVRES",
    "TRAIN_MANOEUVRES",
    "TRUTH_FRAME_RANGE",
    "TRUTH_LATENCY_FLOOR",
    "TRUTH_YAW_RANGE",
    "DiffDriveAdapter",
    "DiffDriveContext",
    "record_case_logs",
    "values_for_log",
]


class DiffDriveAdapter(WheelDrivenAdapter):
    """Differential drive: effects, PyBullet replay, channels, features and surrogate."""

    robot = "diffdrive"
    channels = DIFFDRIVE_CHANNELS
    schema = DIFFDRIVE_SCHEMA
    stage_group = "pose_gt"
    drive_stages = ("command → wheels", "motion → sensor")
    surrogate_effects = tuple(SURROGATE_EFFECTS)
    blind_noise = BLIND_NOISE
    """Motion-capture and camera noise of the blind suite's logs."""

    transient_detection = True
    integrates = True
    """Time series: windows disturbed by stalls, bumps or lost markers are set aside
    (:mod:`~realitygap.diagnosis.stages.transients`)."""

    # ------------------------------------------------------------------ baseline
    def baseline_nuisances(
        self, prepared: Sequence[PreparedLog], drive: Drive
    ) -> dict[str, tuple[float, float, str]]:
        """Nuisances of the calibrated baseline (:mod:`~realitygap.diagnosis.stages.baseline`).

        The ground truth's time alignment (``timestamp_offset.offset``) within
        half the shortest sample period of the logs (stamps are quantised to the
        sample period, so offsets that small are a sampling convention, not a
        finding), and at least :data:`TRUTH_LATENCY_FLOOR` (a capture system's
        latency and sample hold do not shrink with the row period) and, with a command-driven replay, the response time of the
        replayed commands (``command_latency.delay``): within half a period when
        the logs hold the twist the drive received, within one period when they
        hold requests to the robot's firmware (``meta["firmware"]``) — whether
        the firmware takes a request in the period it is issued or the next one,
        and a velocity loop that settles within a period, are the robot's
        actuator response, not a finding — and, in the same range but at least
        :data:`DRIVE_RESPONSE_FLOOR` (a speed loop's time constant does not shrink
        with the command period), the time constant of both wheels' velocity loops
        (``motor_response.tau``, a first-order lag common to the two wheels).
        Longer delays and lags, and wheels that lag differently
        (``wheel_velocity_lag``), remain candidates of the effect library. The firmware's ramp convention is chosen beside them
        (:meth:`actuator_conventions`).

        Beside the clocks, the body frame the ground truth tracks
        (``truth_frame_offset``): a motion-capture rigid body defined by hand
        puts its origin within :data:`TRUTH_FRAME_RANGE` metres of the axle
        centre and its heading within :data:`TRUTH_YAW_RANGE` rad of the rolling
        direction; that is the setup's convention, not the robot's physics. Where
        the logs declare the tracked point (``meta["truth_frame"]``, from a robot
        file), the range is the declared point within its declared uncertainty
        (:func:`declared_truth_frame`). A tracked point beyond the range is the
        effect ``truth_frame_offset`` of the library, over its physical range.
        """
        if not prepared:
            return {}
        dt = min(p.log.dt for p in prepared)
        half = 0.5 * dt
        align = max(half, TRUTH_LATENCY_FLOOR)
        out = {"timestamp_offset.offset": (-align, align, "ground-truth time alignment")}
        centre, width = declared_truth_frame(prepared)
        for key, what in (
            ("x", "ground-truth body origin ahead of the axle centre"),
            ("y", "ground-truth body origin left of the axle centre"),
            ("yaw", "ground-truth body heading against the rolling direction"),
        ):
            spec = param_spec(f"truth_frame_offset.{key}")
            lo = max(centre[key] - width[key], spec.low)
            hi = min(centre[key] + width[key], spec.high)
            out[f"truth_frame_offset.{key}"] = (lo, hi, what)
        if drive is Drive.COMMANDS:
            requests = bool(self.actuator_conventions(prepared, drive))
            response = dt if requests else half
            out["command_latency.delay"] = (0.0, response, "response time of the replayed commands")
            out["motor_response.tau"] = (
                0.0,
                max(response, DRIVE_RESPONSE_FLOOR),
                "time constant of both wheels' velocity loops",
            )
        return out

    # ------------------------------------------------------------------ common geometry
    def link_logs(self, prepared: Sequence[PreparedLog], drive: Drive) -> dict[str, Any]:
        """Put the geometric effects of logs with different declared geometry on one reference.

        The logs of one diagnosis come from one physical robot, but their metadata may
        declare different nominal wheel radii or wheelbases (an odometry configuration
        changed between sessions). A factor such as ``E_b = b_actual / b_nominal``
        relative to each log's own nominal would then be a different physical wheelbase
        in each log, and no single value could fit them. When the declared geometries
        differ, the most common one (the first log's on a tie) becomes the reference:
        every geometric factor is relative to it (:func:`values_for_log`), and the
        nominal replay of a log that declares another geometry is the robot with the
        reference geometry (what its own ticks and commands would do on it).

        Returns
        -------
        dict
            Empty when every log declares the same geometry; else ``reference``
            (wheel radii and wheelbase, m), ``relinked`` (the logs whose nominal
            replay now uses it) and ``summary`` (one line).
        """
        if not prepared:
            return {}
        geoms = [geometry(self._context(p).params) for p in prepared]
        counts: dict[tuple[float, float, float], int] = {}
        for g in geoms:
            counts[g] = counts.get(g, 0) + 1
        if len(counts) < 2:
            return {}
        ref_geom = max(counts, key=lambda g: (counts[g], -geoms.index(g)))
        ref = self._context(prepared[geoms.index(ref_geom)]).params
        relinked = []
        for p, g in zip(prepared, geoms):
            ctx = self._context(p)
            ctx.reference = ref
            if g == ref_geom:
                continue
            relinked.append(p.name)
            nominal, replay_log = self.replay_features(p, {}, drive, ctx.sim)
            p.nominal = {k: v for k, v in nominal.items() if k in p.real}
            p.replay_log = replay_log
            sur = self.surrogate_features(p, {}, drive)
            p.bias = {k: p.nominal[k] - sur[k][0] for k in p.groups}
        return geometry_report(counts, ref_geom, relinked)

    def complete_nominal(
        self, train: Sequence[Log], others: Sequence[Log]
    ) -> tuple[list[Log], list[Log], dict[str, Any]]:
        """A skid-steer's effective track from the training logs
        (:func:`~realitygap.diagnosis.adapters.diffdrive.skid.complete_skid_steer`)."""
        return complete_skid_steer(train, others)

    def actuator_conventions(self, prepared: Sequence[PreparedLog], drive: Drive) -> dict[str, str]:
        """How the firmware's rate limit acts, when the commands are requests it ramps.

        A command-driven replay of logs whose ``meta["firmware"]`` states an
        acceleration limit can ramp the body twist (ros2 ``diff_drive_controller``'s
        speed limiter) or each wheel's speed set-point (many motor firmwares) —
        on arcs the two give different curvature while the speed changes
        (:meth:`~realitygap.robots.diffdrive.FirmwareLimits.limit_wheels`) — and
        it can limit deceleration as well, or only speeding up (a drive that
        brakes at once), or limit it but take a zero request for a stop command
        (:class:`~realitygap.robots.diffdrive.Deceleration`):
        ``"<body|wheels>/<limited|free|stop>"``.
        """
        if drive is not Drive.COMMANDS:
            return {}
        for p in prepared:
            fw = p.log.meta.get("firmware")
            if isinstance(fw, Mapping) and math.isfinite(float(fw.get("a_max", math.inf))):
                return dict(FIRMWARE_CONVENTIONS)
        return {}

    def actuator_convention(self, log: Log) -> str:
        """``"<ramp>/<deceleration>"`` from ``meta["firmware"]``; ``""`` without a firmware."""
        fw = log.meta.get("firmware")
        if not isinstance(fw, Mapping) or not fw:
            return ""
        return f"{fw.get('ramp', 'body')}/{fw.get('deceleration', 'limited')}"

    def with_actuator_convention(self, log: Log, name: str) -> Log:
        """A copy of ``log`` whose firmware ramps as ``name`` says (``"wheels/free"``, …)."""
        if name not in FIRMWARE_CONVENTIONS:
            raise ValueError(
                f"actuator convention must be one of {', '.join(FIRMWARE_CONVENTIONS)}, got {name!r}"
            )
        fw = log.meta.get("firmware")
        if not isinstance(fw, Mapping) or not fw:
            return log
        ramp, _, decel = name.partition("/")
        return log.replace(
            meta={**log.meta, "firmware": {**fw, "ramp": ramp, "deceleration": decel}}
        )

    def fit_actuator_limits(self, logs: Sequence[Log], name: str) -> FirmwareFit | None:
        """The firmware's rate limits under convention ``name``, fitted to the wheel speeds
        the encoders of ``logs`` saw (:func:`~realitygap.diagnosis.adapters.diffdrive.firmware.fit_firmware_limits`);
        ``None`` when no log has requests, encoder counts and a stated firmware."""
        fit = fit_firmware_limits(logs, name)
        return fit if fit.n_rows else None

    def with_actuator_limits(self, log: Log, fit: FirmwareFit | None) -> Log:
        """A copy of ``log`` whose firmware has the fitted limits ``fit`` (the stated ones
        scaled; :meth:`FirmwareFit.meta`)."""
        fw = log.meta.get("firmware")
        if fit is None or not isinstance(fw, Mapping) or not fw:
            return log
        return log.replace(meta={**log.meta, "firmware": fit.meta(fw)})

    # ------------------------------------------------------------------ checks
    def check(self, log: Log, drive: Drive) -> Log:
        """Validate a log for this robot; returns it (raises :class:`LogError` with the fix)."""
        self.check_robot(log, drive)
        params_from_meta(log)
        log.check_uniform()
        if drive is Drive.COMMANDS:
            log.require(["cmd", "pose_gt"], "a command-driven diagnosis")
        else:
            log.require(["ticks", "pose_gt"], "a tick-driven diagnosis")
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
        """Windows, regimes, real features, the nominal replay and the surrogate's bias."""
        params = params_from_meta(log)
        dt = log.dt
        bounds = self.time_windows(log, features_settings)
        if drive is Drive.COMMANDS:
            twist = applied_commands(log)
        else:
            twist = twist_from_ticks(log["ticks"], params, dt)
        regimes = classify_regimes(twist, bounds, features_settings)
        settings = sim if sim is not None else SimSettings.for_log(log)
        start = np.asarray(log["pose_gt"][0], dtype=float)
        inputs = SurrogateInputs(
            dt=dt,
            start=start,
            commands=twist if drive is Drive.COMMANDS else None,
            ticks=np.asarray(log["ticks"], dtype=float) if drive is Drive.TICKS else None,
        )
        mpt = self.meters_per_tick(params)
        real = features(log.channels, bounds, mpt)
        if drive is Drive.TICKS:
            real.pop("ticks", None)
        context = DiffDriveContext(
            sim=settings,
            params=params,
            inputs=inputs,
            twist=twist,
            surrogate=DiffDriveSurrogate(params, calibrate(params, settings.solver_iterations)),
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
        nominal, replay_log = self.replay_features(prepared, {}, drive, settings)
        prepared.nominal = {g: v for g, v in nominal.items() if g in real}
        prepared.replay_log = replay_log
        sur = self.surrogate_features(prepared, {}, drive)
        prepared.bias = {g: prepared.nominal[g] - sur[g][0] for g in prepared.groups}
        return prepared

    def replay_seconds(self, prepared: Sequence[PreparedLog]) -> float | None:
        """A short PyBullet probe of the first log's robot, scaled to all logs' duration."""
        if not prepared:
            return None
        ctx = self._context(prepared[0])
        rate = replay_rate(ctx.params, ctx.sim, prepared[0].log.dt)
        return rate * sum(float(p.log.duration) for p in prepared)

    def prepare_on_surrogate(self, prepared: PreparedLog, log: Log) -> PreparedLog | None:
        """``prepared`` with the applied commands of ``log`` (another actuator convention or
        limits), its nominal the surrogate's plus the PyBullet defect ``prepared`` measured."""
        ctx = self._context(prepared)
        if ctx.inputs.commands is None:  # a tick-driven replay: no actuator in the loop
            return None
        twist = applied_commands(log)
        inputs = dataclasses.replace(ctx.inputs, commands=twist)
        context = dataclasses.replace(ctx, inputs=inputs, twist=twist)
        out = dataclasses.replace(prepared, log=log, context=context, replay_log=log)
        sur = self.surrogate_features(out, {}, Drive.COMMANDS)
        out.nominal = {g: sur[g][0] + prepared.bias[g] for g in prepared.groups}
        out.holdout_windows = prepared.holdout_windows.copy()
        return out

    def sample_noise_levels(
        self, prepared: Sequence[PreparedLog], settings: FeatureSettings
    ) -> dict[str, dict[str, float]] | None:
        r"""Noise of each window feature that the logs' own samples show (feature-scale units).

        Ground truth: a pose track sampled at the log's rate moves smoothly between
        samples, so its second differences are noise, :math:`\sqrt 6\,σ` for
        independent samples of noise :math:`σ` (the motion adds :math:`a\,Δt^2`, well
        below a motion-capture system's noise at tens of hertz, and the robust spread
        ignores the rest). A window feature is the difference of two samples:
        :math:`\sqrt 2\,σ` (``x`` and ``y`` pooled for ``dx``, ``dy``). Encoders: a
        count is quantised to one tick, so a window's travel in the log and in the
        replay each carry :math:`1/\sqrt 6` tick. Pooled over all logs (one sensor);
        ``None`` when no log has a ground truth with three samples.

        In a command-driven replay of logs with encoders the pose features also carry
        the drive train's own scatter: how the wheels' turning, as the encoders count
        it, differs from what the nominal drive train makes of the commands
        (:meth:`wheel_motion`) changes from window to window as no fixed effect could
        make it (a wheel that breaks away a little sooner or later, torque ripple). Its
        white part — the RMS of the window-to-window differences over
        :math:`\sqrt 2`, per column (:meth:`_drive_scatter`), where the ground truth
        confirms the encoders — is added in quadrature
        to the ground truth's noise, and each wheel's to its encoder's quantisation: a
        nominal residual within both is noise, not an unexplained gap.
        """
        xy: list[FloatArray] = []
        th: list[FloatArray] = []
        mpt = 0.0
        for p in prepared:
            log = p.log
            if log.has("pose_gt"):
                gt = np.asarray(log["pose_gt"], dtype=float)
                if gt.shape[0] >= 3:
                    xy.append(np.diff(gt[:, :2], n=2, axis=0).ravel())
                    d1 = wrap_angle(np.diff(gt[:, 2]))  # heading increments across ±π
                    th.append(np.diff(d1))
            if log.has("ticks"):
                mpt = max(mpt, *self.meters_per_tick(self._context(p).params))
        if not xy:
            return None
        scale = dict(zip(self.schema.columns("pose_gt"), settings.scale("pose_gt"), strict=True))
        _, s_xy = robust_spread(np.concatenate(xy))
        _, s_th = robust_spread(np.concatenate(th))
        sig_xy = math.sqrt(2.0) * float(s_xy) / math.sqrt(6.0)
        sig_th = math.sqrt(2.0) * float(s_th) / math.sqrt(6.0)
        sig = {"dx": sig_xy, "dy": sig_xy, "dtheta": sig_th}
        scatter = self._drive_scatter(prepared, np.array([sig_xy, sig_xy, sig_th]))
        if scatter is not None:
            for j, c in enumerate(("dx", "dy", "dtheta")):
                sig[c] = math.hypot(sig[c], float(scatter[0][j]))
        out = {"pose_gt": {c: sig[c] / scale[c] for c in ("dx", "dy", "dtheta")}}
        if mpt > 0.0:
            quant = math.sqrt(2.0) * mpt / math.sqrt(6.0)
            cols = self.schema.columns("ticks")
            ts = dict(zip(cols, settings.scale("ticks"), strict=True))
            wheel = [quant] * len(cols)
            if scatter is not None:
                wheel = [math.hypot(quant, float(x)) for x in scatter[1]]
            out["ticks"] = {c: w / ts[c] for c, w in zip(cols, wheel, strict=True)}
        return out

    def _drive_scatter(
        self, prepared: Sequence[PreparedLog], truth_noise: FloatArray
    ) -> tuple[FloatArray, FloatArray] | None:
        r"""The white part of the drive train's scatter in a command-driven replay of logs
        with encoders: per window feature, the RMS of the window-to-window differences
        over :math:`\sqrt 2` of the motion (dx, dy m, dθ rad;
        :meth:`wheel_motion`) and of each wheel's travel (m; :meth:`wheel_travel`) the
        encoders show beyond the nominal drive train's.

        Only a scatter the body really made counts: the white part of the difference
        between the encoders' motion and the ground truth's must stay within twice the
        ground truth's own noise ``truth_noise`` (dx, dy, dθ per window) in every
        column. Encoders that count what the wheels did not do (a disc off centre) are
        not the drive's noise. ``None`` without such logs, or when they disagree."""
        motion, travel, sensor = [], [], []
        for p in prepared:
            w, tr = self.wheel_motion(p), self.wheel_travel(p)
            if w is None or tr is None or w[0].shape[0] < 2 or "pose_gt" not in p.real:
                continue
            motion.append(np.diff(w[0] - w[1], axis=0))
            travel.append(np.diff(tr[0] - tr[1], axis=0))
            sensor.append(np.diff(w[0] - p.real["pose_gt"], axis=0))
        if not motion:
            return None

        def white(steps: list[FloatArray]) -> FloatArray:
            d = np.concatenate(steps)
            return np.sqrt(np.mean(d**2, axis=0) / 2.0)

        if np.any(white(sensor) > 2.0 * np.asarray(truth_noise)):
            return None
        return white(motion), white(travel)

    def fitted_robot(
        self, prepared: Sequence[PreparedLog], effects: Sequence[str], values: Mapping[str, float]
    ) -> dict[str, Any] | None:
        """Wheel radii, wheelbase and encoder counts of the robot ``effects`` at ``values``
        describe, as factors of the declared ones, per wheel.

        The library splits a per-wheel quantity into a ratio at a kept mean and a common
        scale (``wheel_diameter_ratio`` and ``wheel_radius_scale``, ``encoder_ratio`` and
        ``encoder_scale``); a verdict naming both reads, per wheel, as what to change in the
        robot's description: ``E_c = 1.030`` with ``scale = 1.015`` is a right encoder
        counting 3.0 % more edges than declared and a left one counting as declared. Built
        from the effects' own definitions (their parameters and encoder hooks), so it
        holds for any combination. ``None`` when the model leaves all of them as declared.
        """
        named = set(effects)
        own = {k: float(v) for k, v in values.items() if split_key(k)[0] in named}
        if not prepared or not own:
            return None
        ctx = self._context(prepared[0])
        # the values speak of the geometry all logs share (DiffDriveAdapter.link_logs)
        declared = ctx.reference if ctx.reference is not None else ctx.params
        reality = reality_from_values(own)
        real = reality.apply_params(declared)
        counts = (1.0, 1.0)
        for hook in reality.ticks_hooks():
            counts = hook(*counts)
        # (quantity, factor) per wheel where it has two; a pair is shown whole
        quantities = (
            (
                ("left wheel radius", real.wheel_radius_left / declared.wheel_radius_left),
                ("right wheel radius", real.wheel_radius_right / declared.wheel_radius_right),
            ),
            (("wheelbase", real.wheelbase / declared.wheelbase),),
            (
                ("left encoder's counts per revolution", float(counts[0])),
                ("right encoder's counts per revolution", float(counts[1])),
            ),
        )
        shown = [
            q for group in quantities if any(abs(f - 1.0) > 5e-5 for _, f in group) for q in group
        ]
        if not shown:
            return None
        message = "; ".join(
            f"{name} {f:.4f} × the declared ({100.0 * (f - 1.0):+.2f} %)" for name, f in shown
        )
        return {"factors": dict(shown), "message": message}

    @staticmethod
    def meters_per_tick(params: DiffDriveParams) -> tuple[float, float]:
        """Nominal wheel travel per encoder count, left and right, m."""
        return meters_per_tick(params)

    @staticmethod
    def _context(prepared: PreparedLog) -> DiffDriveContext:
        ctx = prepared.context
        assert isinstance(ctx, DiffDriveContext)
        return ctx

    # ------------------------------------------------------------------ models
    def replay_features(
        self, prepared: PreparedLog, values: Mapping[str, float], drive: Drive, sim: SimSettings
    ) -> tuple[Features, Log]:
        """PyBullet replay with effect values ``{"effect.param": v}``; its features and log."""
        ctx = self._context(prepared)
        params = ctx.params
        values = values_for_log(ctx, values)
        reality = reality_from_values(values) if values else None
        rep = replay(prepared.log, reality, drive=drive, settings=sim, params=params)
        feats = features(rep.channels, prepared.bounds, self.meters_per_tick(params))
        if drive is Drive.TICKS:
            feats.pop("ticks", None)
        return feats, rep

    def log_features(self, prepared: PreparedLog, log: Log) -> Features:
        """Window features of another log of the same episode (e.g. a replay)."""
        mpt = self.meters_per_tick(self._context(prepared).params)
        return features(log.channels, prepared.bounds, mpt)

    def surrogate_features(
        self, prepared: PreparedLog, values: Mapping[str, npt.ArrayLike], drive: Drive
    ) -> Features:
        """Surrogate features for a batch of effect values, (B, M, k) per group."""
        ctx = self._context(prepared)
        # only the channels the log has (a feature of pose_cam also needs pose_gt)
        wanted = {"pose_gt", *prepared.real}
        out = ctx.surrogate.simulate(ctx.inputs, values_for_log(ctx, values), outputs=wanted)
        feats = features(out, prepared.bounds, self.meters_per_tick(ctx.params))
        return {g: v for g, v in feats.items() if g in prepared.real}

    def probe_manoeuvres(self) -> dict[str, str]:
        """Manoeuvres the identifiability advice may suggest, with descriptions."""
        return {name: MANOEUVRES[name].description for name in PROBE_MANOEUVRES}

    def probe_description(self, manoeuvre: str, params_like: PreparedLog) -> str:
        """The description of a library manoeuvre scaled into the ``v_max`` and ``w_max`` of
        the log's robot (:func:`~realitygap.diagnosis.adapters.diffdrive.manoeuvres.probe_description`),
        as its probe features are."""
        return probe_description(manoeuvre, self._context(params_like).params)

    def probe_features(
        self, manoeuvre: str, params_like: PreparedLog, values: Mapping[str, npt.ArrayLike]
    ) -> tuple[Features, list[str]]:
        """Surrogate features of a library manoeuvre (for identifiability advice)."""
        ctx = self._context(params_like)
        params = ctx.params
        man = MANOEUVRES[manoeuvre]
        dt = params_like.log.dt
        t, cmd = man.applied(dt, params)
        out = ctx.surrogate.simulate(SurrogateInputs(dt, np.zeros(3), commands=cmd), values)
        bounds = window_bounds(t.shape[0], dt, 1.0)
        feats = features(out, bounds, self.meters_per_tick(params))
        groups = [g for g in params_like.real if g in feats]
        return {g: feats[g] for g in groups}, groups

    # ------------------------------------------------------------------ stages
    def stage_residuals(self, prepared: PreparedLog) -> dict[str, FloatArray]:
        """Residuals of the pipeline stages inside the real log, per window.

        ``command → motion``: real ground truth minus the nominal replay's;
        ``command → wheels`` (a command-driven replay of a log with encoders):
        the motion nominal odometry makes of the logged ticks minus the motion it
        makes of the nominal replay's ticks — what the wheels did beyond what the
        commands, through the nominal drive train, asked of them;
        ``motion → sensor``: encoder travel minus the travel the nominal
        geometry predicts from the ground-truth motion (the wheels → body stage);
        ``sensor → estimate``: the logged estimate's motion minus nominal
        odometry of the logged ticks.
        """
        params = self._context(prepared).params
        log = prepared.log
        out: dict[str, FloatArray] = {}
        if "pose_gt" in prepared.real and "pose_gt" in prepared.nominal:
            out["command → motion"] = prepared.real["pose_gt"] - prepared.nominal["pose_gt"]
        if log.has("ticks") and log.has("pose_gt"):
            mpt = self.meters_per_tick(params)
            wheels = self.wheel_motion(prepared)
            if wheels is not None:
                f_odo = wheels[0]
                out["command → wheels"] = wheels[0] - wheels[1]
            else:
                f_odo = self._tick_motion(prepared, log["ticks"])[0]
            out["motion → sensor"] = f_odo - prepared.real["pose_gt"]
            if log.has("pose_est"):
                f_est = features({"pose_gt": log["pose_est"]}, prepared.bounds, mpt)["pose_gt"]
                out["sensor → estimate"] = f_est - f_odo
        return out

    def _command_ticks(self, prepared: PreparedLog) -> tuple[FloatArray, FloatArray] | None:
        """The logged ticks and the nominal replay's (N, 2 each) of a command-driven replay
        of a log with encoders; ``None`` otherwise."""
        if self._context(prepared).inputs.commands is None:
            return None
        log, rep = prepared.log, prepared.replay_log
        if not (log.has("ticks") and rep.has("ticks")):
            return None
        return log["ticks"], rep["ticks"]

    def wheel_motion(self, prepared: PreparedLog) -> tuple[FloatArray, FloatArray] | None:
        """Per window, the motion nominal odometry makes of the logged ticks and of the
        nominal replay's ticks (M, 3 each: dx, dy m, dθ rad), for a command-driven replay
        of a log with encoders; ``None`` otherwise."""
        ticks = self._command_ticks(prepared)
        if ticks is None:
            return None
        real, asked = self._tick_motion(prepared, *ticks)
        return real, asked

    def wheel_travel(
        self, prepared: PreparedLog
    ) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """Per window, each wheel's ground travel by the logged encoders and by the nominal
        replay's (what the nominal drive train makes of the commands), (M, 2) each, m, and
        the windows' durations (M,), s, for a command-driven replay of a log with encoders;
        ``None`` otherwise."""
        ticks = self._command_ticks(prepared)
        if ticks is None:
            return None
        mpt = np.asarray(self.meters_per_tick(self._context(prepared).params))
        a, b = prepared.bounds[:, 0], prepared.bounds[:, 1]
        real, asked = (
            (np.asarray(tk, dtype=float)[b] - np.asarray(tk, dtype=float)[a]) * mpt for tk in ticks
        )
        t = np.asarray(prepared.log.t)
        return real, asked, t[b] - t[a]

    def _tick_motion(self, prepared: PreparedLog, *ticks: FloatArray) -> FloatArray:
        """Per window, the motion (dx, dy m, dθ rad) nominal odometry makes of each tick
        series (N, 2) of the log, (len(ticks), M, 3); window motions do not depend on the
        start pose."""
        params = self._context(prepared).params
        odo = [nominal_odometry(np.asarray(tk), params, np.zeros(3)) for tk in ticks]
        mpt = self.meters_per_tick(params)
        return features({"pose_gt": np.stack(odo)}, prepared.bounds, mpt)["pose_gt"]

    def command_wheel_gains(self, prepared: PreparedLog) -> dict[str, float] | None:
        """How far and how much the wheels turned against what the commands asked of the
        nominal drive train, over a command-driven log with encoders (``None`` otherwise).

        ``distance_gain``: logged over asked wheel travel (means of the two wheels);
        ``turn_gain``: least-squares slope of the logged heading change per window on
        the asked one, over the windows that turn, and ``turn_gain_se`` its standard
        error (:func:`~realitygap.diagnosis.stages.scales.gain_through_origin`);
        NaN with fewer than three turning windows.
        """
        wheels = self.wheel_motion(prepared)
        if wheels is None:
            return None
        real, asked = wheels
        s_real, s_asked = np.hypot(real[:, 0], real[:, 1]), np.hypot(asked[:, 0], asked[:, 1])
        dist = float(s_real.sum() / s_asked.sum()) if s_asked.sum() > 0 else math.nan
        a, r = asked[:, 2], real[:, 2]
        turning = np.abs(a) > TURN_WINDOW_RAD
        n = int(turning.sum())
        turn = se = math.nan
        if n >= 3:
            turn, se = gain_through_origin(r[turning], a[turning])
        return {"distance_gain": dist, "turn_gain": turn, "turn_gain_se": se, "turning_windows": n}

    def actuation(self, prepared: Sequence[PreparedLog], drive: Drive) -> dict[str, Any]:
        """How the drive train answered the commands, for a command-driven replay of logs
        with encoders (:mod:`~realitygap.diagnosis.adapters.diffdrive.actuation`).

        ``gains`` (per log, :meth:`command_wheel_gains` with the log's name and split) and
        ``spread`` (:func:`~realitygap.diagnosis.adapters.diffdrive.actuation.actuation_spread`,
        or ``None``) where a log has gains; ``tracking``
        (:func:`~realitygap.diagnosis.adapters.diffdrive.actuation.wheel_tracking`, within the
        first log's ``v_max``) where both splits have wheel travel; empty otherwise, and
        for a tick-driven replay.
        """
        if drive is not Drive.COMMANDS:
            return {}
        out: dict[str, Any] = {}
        gains = command_wheel_gains(self.command_wheel_gains, prepared)
        if gains:
            out = {"gains": gains, "spread": actuation_spread(gains)}
        v_max = self._context(prepared[0]).params.v_max if prepared else None
        tracking = wheel_tracking(self.wheel_travel, prepared, v_max=v_max)
        if tracking is not None:
            out["tracking"] = tracking
        return out

    # ------------------------------------------------------------------ blind suite
    def record_blind_logs(
        self, reality: Reality, rng: np.random.Generator, settings: BlindLogSettings
    ) -> tuple[list[Log], list[Log]]:
        """The training and held-out manoeuvres of ``reality`` with the suite's noise."""
        noise = settings.noise if settings.noise is not None else self.blind_noise
        train = record_case_logs(reality, rng, noise, TRAIN_MANOEUVRES)
        holdout = record_case_logs(reality, rng, noise, HOLDOUT_MANOEUVRES)
        return train, holdout

    def blind_measurement_noise(self, settings: BlindLogSettings) -> dict[str, FloatArray]:
        """The ground truth's noise in the blind logs (the suite's, else :data:`BLIND_NOISE`)."""
        noise = settings.noise if settings.noise is not None else self.blind_noise
        return {"pose_gt": np.array([noise.truth_xy, noise.truth_xy, noise.truth_theta])}

    def discovery_terms(self, prepared: PreparedLog) -> dict[str, tuple[FloatArray, str]]:
        """Candidate terms of an unexplained residual, one value per window, with SI units.

        Window means of the applied twist ``v`` (m/s), ``ω`` (rad/s), their rates
        ``v̇``, ``ω̇`` (change over the window / its duration), sign and magnitude
        terms, ``v·ω``, the wheel speeds ``v ∓ ω b / 2`` and the time of the window.
        """
        ctx = self._context(prepared)
        tw, b = ctx.twist, prepared.bounds
        t = np.asarray(prepared.log.t, dtype=float)
        v = np.array([tw[i:j, 0].mean() for i, j in b])
        w = np.array([tw[i:j, 1].mean() for i, j in b])
        span = np.maximum(t[b[:, 1] - 1] - t[np.maximum(b[:, 0] - 1, 0)], 1e-9)
        dv = (tw[b[:, 1] - 1, 0] - tw[np.maximum(b[:, 0] - 1, 0), 0]) / span
        dw = (tw[b[:, 1] - 1, 1] - tw[np.maximum(b[:, 0] - 1, 0), 1]) / span
        half = 0.5 * ctx.params.wheelbase
        return {
            "v": (v, "m/s"),
            "ω": (w, "rad/s"),
            "v̇": (dv, "m/s²"),
            "ω̇": (dw, "rad/s²"),
            "sign v": (np.sign(v), ""),
            "|v|": (np.abs(v), "m/s"),
            "sign ω": (np.sign(w), ""),
            "|ω|": (np.abs(w), "rad/s"),
            "v·ω": (v * w, "m·rad/s²"),
            "left wheel speed": (v - half * w, "m/s"),
            "right wheel speed": (v + half * w, "m/s"),
            "time": (0.5 * (t[b[:, 0]] + t[b[:, 1] - 1]), "s"),
        }
