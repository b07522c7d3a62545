"""Climbing-robot experiments on the PyBullet blade: ``climb003`` and ``climb-speed``.

``climb003`` drives the simulated climber (:mod:`realitygap.robots.climber`) along an
excitation loop and a sweep on the pitched blade with a pure-pursuit controller on
the true pose, records IMU (120 Hz), geometric visual motion and tether readings
(10 Hz) with ground truth into a :class:`.ClimbRecording`, and scores VIO, VIO +
tether and VIO + tether + adsorption with :func:`.evaluate_recording`. Drift is the
largest position error over the tracked part divided by the distance travelled.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.estimators.climb import SurfaceModel
from realitygap.experiments import RunContext, experiment
from realitygap.robots.climb_evaluation import evaluate_recording
from realitygap.robots.climb_record import record_climb_run
from realitygap.robots.climber import (
    ClimberParams,
    ClimberRobot,
    ClimbWorld,
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
            rec, stats = record_climb_run(
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
