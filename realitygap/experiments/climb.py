"""Climbing-robot experiments on the PyBullet blade: ``climb003`` and ``climb-speed``.

``climb003`` drives the simulated climber (:mod:`realitygap.robots.climber`) along an
excitation loop and a sweep on the pitched blade with a pure-pursuit controller on
the true pose, records IMU (120 Hz), geometric visual motion and tether readings
(10 Hz) with ground truth into a :class:`.ClimbRecording`, and scores VIO, VIO +
tether and VIO + tether + adsorption with :func:`.evaluate_recording`. Drift is the
largest position error over the tracked part divided by the distance travelled.
"""

from __future__ import annotations

import itertools
import math
import time
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.estimators.climb import SurfaceModel
from realitygap.experiments import RunContext, experiment
from realitygap.robots.climb_synthetic import ClimbRecording, evaluate_recording
from realitygap.robots.climber import (
    CameraMode,
    CameraModel,
    ClimberParams,
    ClimberRobot,
    ClimbFaults,
    ClimbWorld,
    ImuModel,
    TetherModel,
    chart_pose,
)

FloatArray = npt.NDArray[np.float64]

INIT_LOOP: tuple[tuple[float, float], ...] = (
    (1.5, 0.15),
    (2.3, 0.15),
    (2.3, 0.5),
    (1.5, 0.5),
    (1.5, 0.15),
)
"""Excitation loop (chart ``(x [m], ξ)``) for the global initialisation."""

SWEEPS: tuple[tuple[tuple[float, float], ...], ...] = (
    ((5.5, 0.15), (5.5, 0.27), (1.5, 0.27), (1.5, 0.39), (5.5, 0.39)),
    ((5.0, 0.15), (5.0, 0.3), (1.8, 0.3), (1.8, 0.45), (5.0, 0.45)),
    ((6.0, 0.15), (6.0, 0.25), (2.0, 0.25), (2.0, 0.35), (6.0, 0.35)),
)
"""Sweeps after the loop, one per run."""


def _dense_chart(waypoints: FloatArray, step: float = 0.01) -> FloatArray:
    out = [waypoints[:1]]
    for a, b in itertools.pairwise(waypoints):
        n = max(int(math.ceil(np.linalg.norm((b - a) * [1.0, 1.2]) / step)), 1)
        lam = np.linspace(0, 1, n + 1)[1:, None]
        out.append(a + lam * (b - a))
    return np.concatenate(out)


def _order_key(m: Any) -> tuple[float, int]:
    from realitygap.estimators.climb import ImuSample, TetherReading

    if isinstance(m, ImuSample):
        return (m.t, 0)
    if isinstance(m, TetherReading):
        return (m.t, 2)
    return (m.t1, 1)


def record_run(
    params: ClimberParams,
    waypoints: npt.ArrayLike,
    n_init: int,
    rng: np.random.Generator,
    *,
    speed: float = 0.15,
    static_duration: float = 2.0,
    lookahead: float = 0.12,
    faults: ClimbFaults | None = None,
    scene: ClimbWorld | None = None,
    robot: ClimberRobot | None = None,
) -> tuple[ClimbRecording, dict[str, float]]:
    """Drive the simulated climber along chart ``waypoints`` and record a run.

    Parameters
    ----------
    params
        True robot parameters (nominal when no effects).
    waypoints : (K, 2)
        Chart waypoints ``(x [m], ξ)``; the first ``n_init`` form the excitation loop.
    rng
        Sensor noise.
    speed, static_duration, lookahead
        m/s, s (still at the start), m (pure pursuit).
    scene, robot
        Re-use a built world and its robot (built from ``params``); both or neither.

    Returns
    -------
    recording, stats
        The :class:`.ClimbRecording` (CAD = world frame) and ``{"sim_seconds",
        "wall_seconds", "distance_m"}``.
    """
    wall0 = time.perf_counter()
    own = scene is None
    sc = ClimbWorld(params) if scene is None else scene
    try:
        if robot is None:
            robot = ClimberRobot(sc, params)
        wp = np.asarray(waypoints, dtype=float)
        chart = _dense_chart(wp)
        s_span = chart[:, 0] / params.blade.length
        u = 1.0 - np.arccos(np.sqrt(np.clip(chart[:, 1], 1e-6, 1))) / np.pi
        surf = sc.surface
        ref = params.world_from_blade(
            surf.position(s_span, u) + params.h_true * surf.normal(s_span, u)
        )
        init_idx = len(_dense_chart(wp[:n_init])) - 1
        first = ref[1] - ref[0]
        pos, R = chart_pose(surf, params, wp[0, 0], wp[0, 1], 0.0, params.h_true)
        d_local = R.T @ first
        pos, R = chart_pose(
            surf, params, wp[0, 0], wp[0, 1], math.atan2(d_local[1], d_local[0]), params.h_true
        )
        robot.reset(pos, R)
        fl = faults or ClimbFaults()
        imu = ImuModel(params, rng)
        tether = TetherModel(params, rng, fl)
        cam = CameraModel(robot, params, CameraMode.FAST, rng, fl)
        world = sc.world
        c = world.bullet
        dtp = world.physics_dt
        imu_every = int(round(1.0 / (params.imu_rate * dtp)))
        cam_every = int(round(1.0 / (params.camera_rate * dtp)))
        meas: list[Any] = []
        truth_t: list[float] = []
        truth_p: list[FloatArray] = []
        truth_R: list[FloatArray] = []
        t = 0.0
        s_prev = robot.state(t)
        idx = 0
        done_at: float | None = None
        init_time: float | None = None
        v_cmd = w_cmd = 0.0
        k = 0
        while True:
            if k % imu_every == 0 and k > 0:
                s = robot.state(t)
                meas.append(imu.sample(s_prev, s))
                truth_t.append(s_prev.t)
                truth_p.append(s_prev.position)
                truth_R.append(s_prev.R)
                s_prev = s
                if k % cam_every == 0:
                    frame = cam.capture(s, params.h_true)
                    if frame is not None:
                        meas.append(frame)
                    meas.append(tether.read(t, s.position, 1.0 / params.camera_rate))
                if k % (imu_every * 6) == 0:  # 20 Hz control on the true pose
                    if t >= static_duration and done_at is None:
                        d = np.linalg.norm(ref[idx : idx + 25] - s.position, axis=1)
                        idx = idx + int(np.argmin(d))
                        if init_time is None and idx >= init_idx:
                            init_time = t
                        j = idx
                        while j < len(ref) - 1 and np.linalg.norm(ref[j] - s.position) < lookahead:
                            j += 1
                        target = s.R.T @ (ref[j] - s.position)
                        alpha = math.atan2(target[1], target[0])
                        v_target = speed * max(0.0, math.cos(alpha)) ** 2
                        if idx >= len(ref) - 3 or np.linalg.norm(ref[-1] - s.position) < 0.02:
                            done_at = t
                            v_target = 0.0
                        w_target = 2.0 * math.sin(alpha) * max(v_target, 0.05) / lookahead
                        w_target = max(-params.w_max, min(params.w_max, w_target))
                        dv, dw = 0.5 * 0.05, 2.0 * 0.05
                        v_cmd += max(-dv, min(dv, v_target - v_cmd))
                        w_cmd += max(-dw, min(dw, w_target - w_cmd))
                        if done_at is not None:
                            v_cmd = w_cmd = 0.0
                        robot.set_twist(v_cmd, w_cmd, params)
                    if done_at is not None and t > done_at + 1.0:
                        break
                    if t > 2000.0:
                        raise RuntimeError("the climber did not finish the path in 2000 s")
            robot.apply_adsorption()
            c.stepSimulation()
            k += 1
            t = k * dtp
        tp = np.array(truth_p)
        if init_time is None:
            raise RuntimeError("the climber never completed the excitation loop")
        t_arr = np.array(truth_t)
        seg = np.linalg.norm(np.diff(tp, axis=0), axis=1)
        init_len = float(np.sum(seg[: int(np.searchsorted(t_arr, init_time))]))
        rec = ClimbRecording(
            measurements=tuple(sorted(meas, key=_order_key)),
            truth_t=t_arr,
            truth_position=tp,
            truth_rotation=np.array(truth_R),
            init_path_length=init_len,
            anchor_cad=params.anchor_world,
            h=params.h,
        )
        stats = {
            "sim_seconds": t,
            "wall_seconds": time.perf_counter() - wall0,
            "distance_m": float(seg.sum()),
        }
        return rec, stats
    finally:
        if own:
            sc.close()


@experiment(
    "climb003",
    "seed 003: PyBullet climber on the pitched 8 m blade; VIO vs VIO+tether vs constrained drift",
)
def climb003(ctx: RunContext) -> dict[str, Any]:
    params = ClimberParams()
    n_runs = 1 if ctx.quick else len(SWEEPS)
    pts, nrm = params.cad_cloud(0.01)
    surface = SurfaceModel(pts, nrm)
    rows = []
    scene = ClimbWorld(params)
    robot = ClimberRobot(scene, params)
    try:
        for r in range(n_runs):
            wp = INIT_LOOP + SWEEPS[r]
            ctx.progress(f"climb003: recording run {r + 1}/{n_runs}")
            rec, stats = record_run(
                params,
                wp,
                len(INIT_LOOP),
                np.random.default_rng(ctx.seed + r),
                scene=scene,
                robot=robot,
            )
            ctx.progress(f"climb003: evaluating run {r + 1} ({stats['distance_m']:.1f} m)")
            t0 = time.perf_counter()
            m = evaluate_recording(
                rec,
                surface,
                vio_config=params.vio_config(),
                constrained_config=params.constrained_config(),
            )
            rows.append(
                {
                    "run": r,
                    "distance_m": m.distance,
                    "path_m": stats["distance_m"],
                    "init_yaw_err_deg": m.init_yaw_error_deg,
                    "init_pos_err_cm": m.init_position_error_cm,
                    "drift_pct_vio": m.vio.max_drift_pct,
                    "drift_pct_vio_tether": m.vio_tether.max_drift_pct,
                    "drift_pct_constrained": m.constrained.max_drift_pct,
                    "init_status": m.init_status,
                    "sim_s": stats["sim_seconds"],
                    "record_wall_s": stats["wall_seconds"],
                    "estimate_wall_s": time.perf_counter() - t0,
                }
            )
    finally:
        scene.close()
    col = lambda k: np.array([row[k] for row in rows])  # noqa: E731
    figures = {
        "init_yaw_err_deg": float(col("init_yaw_err_deg").max()),
        "init_pos_err_cm": float(col("init_pos_err_cm").max()),
        "max_drift_pct_vio": float(col("drift_pct_vio").max()),
        "max_drift_pct_vio_tether": float(col("drift_pct_vio_tether").max()),
        "max_drift_pct_constrained": float(col("drift_pct_constrained").max()),
        "constrained_beats_vio_all_runs": bool(
            np.all(col("drift_pct_constrained") < col("drift_pct_vio"))
        ),
        "total_distance_m": float(col("distance_m").sum()),
    }
    return {
        "figures": figures,
        "config": {
            "source": "pybullet",
            "runs": n_runs,
            "mount_pitch_rad": params.mount_pitch,
            "imu_rate_hz": params.imu_rate,
            "camera_rate_hz": params.camera_rate,
            "camera_mode": "fast (geometric)",
            "contact_model": "two sphere wheels on the axle, chassis pitching about it",
            "wheel_track_m": params.constrained_config().wheel_track,
            "constrained_pitch_sigma_rad": params.constrained_config().pitch_sigma,
            "seed": ctx.seed,
        },
        "tables": {"runs": rows},
        "notes": [
            "worst case over runs; drift = max position error / distance travelled while tracking"
        ],
    }


@experiment("climb-speed", "real-time factor of WallClimb-v0 with the estimator in the loop")
def climb_speed(ctx: RunContext) -> dict[str, Any]:
    from realitygap.baselines.climb_policy import ClimbChartPolicy
    from realitygap.envs.wall_climb import WallClimbEnv

    n_steps = 200 if ctx.quick else 600
    figures: dict[str, Any] = {}
    for kind in ("docked", "localiser"):
        env = WallClimbEnv(estimator=kind)
        policy = ClimbChartPolicy.from_env(env)
        obs, _ = env.reset(seed=ctx.seed)
        steps = 0
        t0 = time.perf_counter()
        cpu0 = time.process_time()
        for _ in range(n_steps):
            action, _ = policy.predict(obs)
            obs, _, term, trunc, _ = env.step(action)
            steps += 1
            if term or trunc:
                obs, _ = env.reset()
                policy.reset()
        wall = time.perf_counter() - t0
        cpu = time.process_time() - cpu0
        env.close()
        figures[f"rtf_{kind}"] = steps * env.dt / wall
        figures[f"steps_per_s_{kind}"] = steps / wall
        # simulated time per CPU second of this process: unaffected by other load
        figures[f"rtf_cpu_{kind}"] = steps * env.dt / max(cpu, 1e-9)
    figures["rtf"] = figures["rtf_docked"]
    return {
        "figures": figures,
        "config": {"steps": n_steps, "control_hz": 20, "camera": "fast", "seed": ctx.seed},
        "notes": [
            "rtf = simulated s / wall-clock s (depends on other load on the machine); "
            "rtf_cpu_* = simulated s / CPU s of this process"
        ],
    }
