"""Scoring the climbing-robot localisation on a recording of the blade.

* :func:`evaluate_recording` — runs :class:`.ClimbLocaliser` on any
  :class:`~realitygap.robots.climb_synthetic.ClimbRecording` (synthetic, simulated
  or real) and scores three estimators on the same VIO run: VIO alone (mapped into
  the CAD frame by the global initialisation), VIO + tether, and VIO + tether +
  adsorption;
* :func:`evaluate` — several seeded runs of a
  :class:`~realitygap.robots.climb_synthetic.ClimbScenario` and a summary
  (:class:`EvaluationReport`).

Drift is the largest position error over the tracked part of the run divided by the
distance travelled in that part (the figure the source reports as 0.51 %).
Frames: ``cad`` (blade frame, z up), ``world`` (VIO frame).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import rot_z, wrap_angle
from realitygap.estimators.climb.constrained import ConstrainedConfig, ConstrainedEstimator
from realitygap.estimators.climb.localiser import ClimbLocaliser, LocaliserConfig, LocaliserPhase
from realitygap.estimators.climb.measurements import ClimbEstimate, TetherReading
from realitygap.estimators.climb.surface import SurfaceModel
from realitygap.estimators.climb.vio import VioConfig
from realitygap.robots.blade_geometry import cad_point_cloud
from realitygap.robots.climb_synthetic import ClimbRecording, ClimbScenario, synthesise_recording

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "EstimatorMetrics",
    "EvaluationReport",
    "RunMetrics",
    "evaluate",
    "evaluate_recording",
]


@dataclass(frozen=True)
class EstimatorMetrics:
    """Position accuracy of one estimator over the tracked part of a run.

    Attributes
    ----------
    max_error
        Largest position error, m.
    final_error
        Position error at the end, m.
    rms_error
        m.
    max_drift_pct
        ``100 · max_error / distance``.
    max_yaw_error_deg
        Largest heading error, deg.
    """

    max_error: float
    final_error: float
    rms_error: float
    max_drift_pct: float
    max_yaw_error_deg: float


@dataclass(frozen=True)
class RunMetrics:
    """Scores of one run.

    Attributes
    ----------
    distance
        Distance travelled while tracking, m.
    vio, vio_tether, constrained
        :class:`EstimatorMetrics` of VIO alone (mapped by the global
        initialisation), VIO + tether, VIO + tether + adsorption.
    vio_aligned
        VIO alone, aligned to the truth at the start of tracking (pure VIO drift).
    init_yaw_error_deg
        Error of the global initialisation's yaw (the rotation between the VIO frame
        at its start and the CAD frame), deg.
    init_heading_error_deg
        Heading error of the pose tracking starts from (the transform applied to the
        VIO pose at the end of the excitation path, so it includes the VIO's yaw
        drift along that path), deg.
    init_position_error_cm
        Error of the CAD-frame position at the start of tracking, cm.
    init_translation_error_cm
        Error of the translation :math:`t` of the 4-DOF transform, cm.
    init_status
        The global initialisation's status.
    status_counts
        How often each status flag of the constrained estimator occurred.
    """

    distance: float
    vio: EstimatorMetrics
    vio_tether: EstimatorMetrics
    constrained: EstimatorMetrics
    vio_aligned: EstimatorMetrics
    init_yaw_error_deg: float
    init_heading_error_deg: float
    init_position_error_cm: float
    init_translation_error_cm: float
    init_status: str
    status_counts: tuple[tuple[str, int], ...]


def _metrics(
    t: FloatArray, p: FloatArray, R: FloatArray, rec: ClimbRecording, distance: float
) -> EstimatorMetrics:
    p_true, R_true = rec.truth_at(t)
    err = np.linalg.norm(p - p_true, axis=1)
    yaw_err = np.array(
        [
            abs(float(wrap_angle(math.atan2(Ra[1, 0], Ra[0, 0]) - math.atan2(Rb[1, 0], Rb[0, 0]))))
            for Ra, Rb in zip(R, R_true)
        ]
    )
    return EstimatorMetrics(
        max_error=float(err.max()),
        final_error=float(err[-1]),
        rms_error=float(np.sqrt(np.mean(err**2))),
        max_drift_pct=float(100.0 * err.max() / max(distance, 1e-9)),
        max_yaw_error_deg=float(np.degrees(yaw_err.max())),
    )


def _zyx_yaw(R: FloatArray) -> float:
    return float(Rotation.from_matrix(R).as_euler("ZYX")[0])


def evaluate_recording(
    recording: ClimbRecording,
    surface: SurfaceModel,
    *,
    vio_config: VioConfig | None = None,
    constrained_config: ConstrainedConfig | None = None,
    localiser_config: LocaliserConfig | None = None,
) -> RunMetrics:
    """Run the localisation on a recording and score VIO, VIO + tether and constrained.

    One :class:`.ClimbLocaliser` run provides the VIO keyframes, the global
    initialisation and the constrained (VIO + tether + adsorption) track; VIO + tether
    replays :class:`.ConstrainedEstimator` without the adsorption updates on the same
    VIO keyframes and tether readings from the same starting state.

    Parameters
    ----------
    recording
        Measurements and ground truth.
    surface
        The CAD surface model (nominal).
    vio_config, constrained_config
        Settings; ``localiser_config`` defaults to the recording's excitation length.

    Raises
    ------
    ValueError
        If the global initialisation never completes.
    """
    cc = ConstrainedConfig() if constrained_config is None else constrained_config
    lc = localiser_config or LocaliserConfig(
        init_path_length=0.97 * recording.init_path_length,
        init_max_path_length=max(6.0, 1.5 * recording.init_path_length),
    )
    loc = ClimbLocaliser(
        surface,
        recording.anchor_cad,
        recording.h,
        vio_config=vio_config,
        config=cc,
        localiser_config=lc,
    )
    vio_kf: list[ClimbEstimate] = []
    tracked: list[ClimbEstimate] = []
    tethers: list[TetherReading] = []
    start: ClimbEstimate | None = None
    start_cov: FloatArray | None = None
    kf_count = 0
    flags: dict[str, int] = {}
    for m in recording.measurements:
        was_tracking = loc.phase is LocaliserPhase.TRACKING
        est = loc.update(m)
        if isinstance(m, TetherReading):
            if was_tracking:
                tethers.append(m)
            continue
        if loc.vio.keyframe_count != kf_count:
            kf_count = loc.vio.keyframe_count
            kf = loc.vio.keyframe_estimate()
            vio_kf.append(kf)
            if loc.phase is LocaliserPhase.TRACKING:
                if start is None:
                    start = est
                    start_cov = est.cov
                tracked.append(est)
                for f in est.status.split("|"):
                    flags[f] = flags.get(f, 0) + 1
    if start is None or loc.global_init is None or loc.vio.static_init is None:
        raise ValueError("the global initialisation never completed on this recording")
    gi = loc.global_init
    t_start = start.t
    # VIO + tether replay
    vt = ConstrainedEstimator(
        surface, recording.anchor_cad, recording.h, dataclasses.replace(cc, use_surface=False)
    )
    vt.reset(start, start_cov)
    stream: list[tuple[float, int, ClimbEstimate | TetherReading]] = [
        (k.t, 0, k) for k in vio_kf if k.t >= t_start - 1e-9
    ] + [(r.t, 1, r) for r in tethers]
    stream.sort(key=lambda item: (item[0], item[1]))
    vt_track: list[ClimbEstimate] = []
    for _, kind, item in stream:
        e = vt.update(item)
        if kind == 0:
            vt_track.append(e)
    # tracks
    tk = np.array([e.t for e in tracked])
    p_true, _ = recording.truth_at(tk)
    distance = float(np.sum(np.linalg.norm(np.diff(p_true, axis=0), axis=1)))
    constrained = _metrics(
        tk,
        np.array([e.position for e in tracked]),
        np.array([e.rotation for e in tracked]),
        recording,
        distance,
    )
    vt_m = _metrics(
        np.array([e.t for e in vt_track]),
        np.array([e.position for e in vt_track]),
        np.array([e.rotation for e in vt_track]),
        recording,
        distance,
    )
    vio_track = [k for k in vio_kf if k.t >= t_start - 1e-9]
    tv = np.array([k.t for k in vio_track])
    pw = np.array([k.position for k in vio_track])
    Rw = np.array([k.rotation for k in vio_track])
    Rgw = gi.R_world_cad.T
    vio_m = _metrics(tv, gi.cad_from_world(pw), Rgw @ Rw, recording, distance)
    # VIO aligned to the truth at the start of tracking (4 DOF)
    p0, R0 = recording.truth_at(tv[0])
    dyaw = _zyx_yaw(R0[0]) - _zyx_yaw(Rw[0])
    Ra = rot_z(dyaw)
    vio_al = _metrics(tv, (pw - pw[0]) @ Ra.T + p0[0], Ra @ Rw, recording, distance)
    # global initialisation vs truth: the VIO world frame is the body frame at the
    # static initialisation, yaw only
    t_init = loc.vio.static_init.t
    pi, Ri = recording.truth_at(t_init)
    psi0 = _zyx_yaw(Ri[0])
    yaw_true = -psi0
    t_true = -rot_z(yaw_true) @ pi[0]
    p_start_true, R_start_true = recording.truth_at(t_start)
    R_s, R_t = start.rotation, R_start_true[0]
    heading_err = float(
        wrap_angle(math.atan2(R_s[1, 0], R_s[0, 0]) - math.atan2(R_t[1, 0], R_t[0, 0]))
    )
    return RunMetrics(
        distance=distance,
        vio=vio_m,
        vio_tether=vt_m,
        constrained=constrained,
        vio_aligned=vio_al,
        init_yaw_error_deg=abs(math.degrees(float(wrap_angle(gi.yaw - yaw_true)))),
        init_heading_error_deg=abs(math.degrees(heading_err)),
        init_position_error_cm=float(100 * np.linalg.norm(start.position - p_start_true[0])),
        init_translation_error_cm=float(100 * np.linalg.norm(gi.t - t_true)),
        init_status=gi.status,
        status_counts=tuple(sorted(flags.items())),
    )


@dataclass(frozen=True)
class EvaluationReport:
    """Runs of :func:`evaluate` and their summary.

    Attributes
    ----------
    seeds
        Seeds of the runs.
    runs
        :class:`RunMetrics` per seed.
    """

    seeds: tuple[int, ...]
    runs: tuple[RunMetrics, ...]

    def summary(self) -> dict[str, float | bool]:
        """Worst and mean figures over the runs (drift in % of distance)."""

        def col(get: Callable[[RunMetrics], float]) -> FloatArray:
            return np.array([get(r) for r in self.runs])

        out: dict[str, float | bool] = {
            "min_distance_m": float(col(lambda r: r.distance).min()),
        }
        for name in ("vio", "vio_tether", "constrained", "vio_aligned"):
            d = np.array([getattr(r, name).max_drift_pct for r in self.runs])
            out[f"{name}_max_drift_pct_worst"] = float(d.max())
            out[f"{name}_max_drift_pct_mean"] = float(d.mean())
        yaw = col(lambda r: r.init_yaw_error_deg)
        heading = col(lambda r: r.init_heading_error_deg)
        pos = col(lambda r: r.init_position_error_cm)
        out["init_yaw_error_deg_worst"] = float(yaw.max())
        out["init_yaw_error_deg_mean"] = float(yaw.mean())
        out["init_heading_error_deg_worst"] = float(heading.max())
        out["init_heading_error_deg_mean"] = float(heading.mean())
        out["init_position_error_cm_worst"] = float(pos.max())
        out["init_position_error_cm_mean"] = float(pos.mean())
        out["constrained_better_than_vio_every_run"] = bool(
            np.all(col(lambda r: r.constrained.max_drift_pct) < col(lambda r: r.vio.max_drift_pct))
        )
        return out


def evaluate(
    scenario: ClimbScenario | None = None,
    seeds: Sequence[int] = (0, 1, 2),
    *,
    cloud_spacing: float = 0.01,
    vio_config: VioConfig | None = None,
    constrained_config: ConstrainedConfig | None = None,
) -> EvaluationReport:
    """Seeded synthetic runs of ``scenario`` scored by :func:`evaluate_recording`.

    The estimators use the nominal blade's CAD cloud (``cloud_spacing`` m) even when
    the scenario deforms the real surface.
    """
    sc = ClimbScenario() if scenario is None else scenario
    pts, nrm = cad_point_cloud(sc.blade, cloud_spacing)
    surface = SurfaceModel(pts, nrm)
    runs = []
    for seed in seeds:
        rec = synthesise_recording(sc, np.random.default_rng(seed), vio_config=vio_config)
        runs.append(
            evaluate_recording(
                rec, surface, vio_config=vio_config, constrained_config=constrained_config
            )
        )
    return EvaluationReport(tuple(int(s) for s in seeds), tuple(runs))
