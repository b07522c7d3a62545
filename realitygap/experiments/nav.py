"""Wheeled-navigation experiments: ``nav8``, ``nav-obstacles``, ``bench-speed``."""

from __future__ import annotations

import math
import time
from typing import Any

import gymnasium as gym
import numpy as np

from realitygap.core.jit import use_compiled
from realitygap.experiments import RunContext, experiment


def _make_env(**kwargs: Any) -> Any:
    import realitygap  # noqa: F401  (registers the ids)

    return gym.make("realitygap/WheeledNav-v0", **kwargs)


LOW_PHYSICS_HZ = 120.0
"""Physics rate (Hz) of bench-speed's opt-in fast-mode row (``physics_hz=`` of the env; the
default is 240 Hz)."""

BENCH_CAMERA_RATES = (20.0, 10.0, 5.0)
"""Camera rates (Hz) of bench-speed's image-mode rows besides the env's default one: VO
frames every first, second or fourth control step, scans (10 Hz) from their own small depth
pictures in between."""


def _default_camera_hz() -> float:
    """The env's default camera rate (Hz), read from its signature."""
    import inspect

    from realitygap.envs.wheeled_nav import WheeledNavEnv

    return float(inspect.signature(WheeledNavEnv).parameters["camera_hz"].default)


def _timed_steps(env: Any, actions: np.ndarray, *, cpu: bool) -> tuple[float, float]:
    """Seconds spent in ``env.step`` over ``actions`` and in the physics inside it: wall
    clock, or with ``cpu`` this thread's CPU time (resetting where an episode ends).

    The two are taken in separate passes: the CPU clock is a system call (~0.4 µs), and the
    world's two reads of it around its physics would otherwise count in a wall-clock step
    but not in its physics. In the CPU pass they still do (an upper bound on the overhead).
    """
    world = env.unwrapped.world
    world.cpu_timing = cpu
    clock = time.thread_time if cpu else time.perf_counter
    world.physics_seconds = world.physics_cpu_seconds = 0.0
    spent = 0.0
    for a in actions:
        t0 = clock()
        _, _, terminated, truncated, _ = env.step(a)
        spent += clock() - t0
        if terminated or truncated:
            env.reset()
    physics = world.physics_cpu_seconds if cpu else world.physics_seconds
    world.cpu_timing = False
    return spent, physics


def _bench_mode(ctx: RunContext, n_steps: int, **env_kwargs: Any) -> dict[str, float]:
    """Time ``n_steps`` seeded env steps: wall clock and, in a second pass over the same
    episode, this thread's CPU time, each for the whole step and for the physics inside it;
    and the first and a repeated reset."""
    env = _make_env(n_obstacles=6, **env_kwargs)
    t0 = time.perf_counter()
    env.reset(seed=ctx.seed)
    reset_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    env.reset(seed=ctx.seed)  # the same layout again: its textures come from the cache
    reset_again_s = time.perf_counter() - t0
    rng = np.random.default_rng(ctx.seed)
    actions = rng.uniform(-1, 1, size=(n_steps, 2)).astype(np.float32)
    # smooth the random commands so the robot drives rather than jitters
    for i in range(1, len(actions)):
        actions[i] = 0.9 * actions[i - 1] + 0.1 * actions[i]
    for a in actions[:10]:  # warm-up
        env.step(a)
    step_time, physics = _timed_steps(env, actions, cpu=False)
    env.reset(seed=ctx.seed)
    for a in actions[:10]:
        env.step(a)
    step_cpu, physics_cpu = _timed_steps(env, actions, cpu=True)
    dt = env.unwrapped.dt
    env.close()
    n = len(actions)
    return {
        "env_steps_per_s": n / step_time,
        "real_time_factor": n * dt / step_time,
        "overhead_ratio": step_time / physics,
        "cpu_real_time_factor": n * dt / step_cpu,
        "cpu_overhead_ratio": step_cpu / physics_cpu,
        "physics_cpu_us_per_step": 1e6 * physics_cpu / n,
        "reset_s": reset_s,
        "reset_again_s": reset_again_s,
    }


PROFILE_PHASES = ("physics", "sensors", "estimator", "observation")
"""Phases of an env step that bench-speed's breakdown times on their own; the rest of a step
(action check, firmware, task, reward, ``info``, Gymnasium's wrappers) is ``other``."""


def _profile_steps(ctx: RunContext, n_steps: int, **env_kwargs: Any) -> dict[str, float]:
    """CPU time (µs, this thread) per env step spent in each of :data:`PROFILE_PHASES` and in
    the rest, from timers wrapped around the env's own methods (a separate pass: the timers
    cost a few µs per call)."""
    env = _make_env(n_obstacles=6, **env_kwargs)
    env.reset(seed=ctx.seed)
    u = env.unwrapped
    spent = dict.fromkeys(PROFILE_PHASES, 0.0)

    def timed(phase: str, fn: Any) -> Any:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            c0 = time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[phase] += time.thread_time() - c0

        return wrapper

    u.world.step = timed("physics", u.world.step)
    u._measure = timed("sensors", u._measure)
    u.estimator.update = timed("estimator", u.estimator.update)
    u._observation = timed("observation", u._observation)
    rng = np.random.default_rng(ctx.seed + 1)
    actions = rng.uniform(-1, 1, size=(n_steps, 2)).astype(np.float32)
    for i in range(1, len(actions)):
        actions[i] = 0.9 * actions[i - 1] + 0.1 * actions[i]
    total = 0.0
    for a in actions:
        c0 = time.thread_time()
        _, _, terminated, truncated, _ = env.step(a)
        total += time.thread_time() - c0
        if terminated or truncated:
            before = dict(spent)
            env.reset()
            spent.update(before)  # a reset's physics and sensors are not a step's
    env.close()
    out = {f"profile_{k}_us": 1e6 * v / n_steps for k, v in spent.items()}
    out["profile_other_us"] = 1e6 * (total - sum(spent.values())) / n_steps
    out["profile_step_us"] = 1e6 * total / n_steps
    return out


def _bench_renderers(ctx: RunContext, n_frames: int) -> dict[str, float]:
    """Milliseconds per 320 × 240 picture of the textured room from the robot's camera pose,
    TinyRenderer against the EGL plugin (NaN where EGL is unavailable): wall clock and the
    process's CPU time over all its threads (llvmpipe renders on several)."""
    env = _make_env(n_obstacles=6, sensor_mode="image")
    env.reset(seed=ctx.seed)
    u = env.unwrapped
    T = u.robot.T_world_camera()
    eye, target = T[:3, 3], T[:3, 3] + T[:3, 2]  # along the optical axis
    out: dict[str, float] = {}
    for renderer in ("tiny", "egl"):
        key = "tinyrenderer" if renderer == "tiny" else "egl"
        if renderer == "egl" and not u.world.load_egl_renderer():
            out[f"render_{key}_ms"] = out[f"render_{key}_cpu_ms"] = math.nan
            continue
        u.world.render_rgb(eye, target, fov_deg=60.0, renderer=renderer)  # warm-up
        c0, t0 = time.process_time(), time.perf_counter()
        for _ in range(n_frames):
            u.world.render_rgb(eye, target, fov_deg=60.0, renderer=renderer)
        out[f"render_{key}_ms"] = 1e3 * (time.perf_counter() - t0) / n_frames
        out[f"render_{key}_cpu_ms"] = 1e3 * (time.process_time() - c0) / n_frames
    env.close()
    return out


@experiment(
    "bench-speed",
    "WheeledNav steps/s, real-time factor and env overhead over raw physics (fast and image "
    "modes; wall clock and one core's CPU time)",
)
def bench_speed(ctx: RunContext) -> dict[str, Any]:
    n_fast, n_image = (600, 20) if ctx.quick else (4000, 200)
    default_hz = _default_camera_hz()
    runs: dict[str, tuple[int, dict[str, Any]]] = {
        "fast": (n_fast, {"sensor_mode": "fast"}),
        # the opt-in lower physics rate: half the physics steps per control step (other
        # dynamics than the default 240 Hz, to which the surrogate and the vector env are
        # calibrated)
        f"fast_physics{LOW_PHYSICS_HZ:g}hz": (
            n_fast,
            {"sensor_mode": "fast", "physics_hz": LOW_PHYSICS_HZ},
        ),
        "image": (n_image, {"sensor_mode": "image"}),
    }
    camera_hz: dict[str, float] = {"image": default_hz}
    for hz in BENCH_CAMERA_RATES:
        if hz != default_hz:
            runs[f"image_camera{hz:g}hz"] = (n_image, {"sensor_mode": "image", "camera_hz": hz})
            camera_hz[f"image_camera{hz:g}hz"] = hz
    figures: dict[str, float] = {}
    for label, (n, kwargs) in runs.items():
        res = _bench_mode(ctx, n, **kwargs)
        res.update(_profile_steps(ctx, n, **kwargs))
        figures.update({f"{label}_{key}": value for key, value in res.items()})
        ctx.progress(
            f"{label}: {res['env_steps_per_s']:.0f} steps/s, RTF {res['real_time_factor']:.1f} "
            f"(one core's CPU time: RTF {res['cpu_real_time_factor']:.1f})"
        )
    figures.update(_bench_renderers(ctx, 5 if ctx.quick else 30))
    ctx.progress(
        f"320x240 frame: TinyRenderer {figures['render_tinyrenderer_ms']:.1f} ms, "
        f"EGL {figures['render_egl_ms']:.1f} ms"
    )
    return {
        "figures": figures,
        "config": {
            "steps": {"fast": n_fast, "image": n_image},
            "physics_hz": 240,
            "physics_hz_opt_in_row": LOW_PHYSICS_HZ,
            "control_hz": 20,
            "n_obstacles": 6,
            "camera_hz": camera_hz,
            "scan_hz": 10,
            # the fast mode's kernels compiled by Numba (the ``fast`` extra), else NumPy
            "compiled_kernels": use_compiled(),
        },
    }


def run_episode(
    env: gym.Env,
    policy: Any,
    seed: int,
    options: dict[str, Any] | None = None,
    settle: bool = False,
) -> dict[str, Any]:
    """Run one episode of ``policy`` on ``env``; return the final info and path statistics.

    With ``settle`` the episode also ends as soon as the policy reports it has settled on the
    goal (classical policy) — used where the env does not terminate on success.
    """
    obs, info = env.reset(seed=seed, options=options)
    path = 0.0
    prev = np.asarray(info["true_pose"][:2])
    steps, collided, success_seen = 0, False, False
    terminated = truncated = False
    start = True
    while not (terminated or truncated):
        action, _ = policy.predict(obs, episode_start=np.array([start]), deterministic=True)
        start = False
        obs, _, terminated, truncated, info = env.step(action)
        steps += 1
        xy = np.asarray(info["true_pose"][:2])
        path += float(np.hypot(*(xy - prev)))
        prev = xy
        collided |= bool(info["collision"])
        success_seen |= bool(info["is_success"])
        if (
            settle
            and getattr(policy, "is_done", lambda: False)()
            and abs(obs[10]) < 1e-6
            and abs(obs[11]) < 1e-6
        ):
            break
    return {
        "info": info,
        "steps": steps,
        "path_length": path,
        "collision": collided,
        "success": success_seen,
    }


@experiment("nav8", "seed 001's test: 8 start poses to goal (0, 0, π/2), estimator in the loop")
def nav8(ctx: RunContext) -> dict[str, Any]:
    return _nav8(
        ctx,
        lambda start, goal: _make_env(
            n_obstacles=0, start=start, goal=goal, terminate_on_success=False
        ),
        {"estimator": "wheel odometry"},
    )


def _nav8(ctx: RunContext, make_env: Any, config: dict[str, Any]) -> dict[str, Any]:
    """Seed 001's eight-start test with envs from ``make_env(start, goal)``."""
    from realitygap.baselines import ClassicalNavPolicy
    from realitygap.envs import NAV8_STARTS

    goal = (0.0, 0.0, math.pi / 2)
    rows = []
    for k, start in enumerate(NAV8_STARTS):
        env = make_env(start, goal)
        policy = ClassicalNavPolicy.from_env(env)
        t0 = time.perf_counter()
        ep = run_episode(env, policy, seed=ctx.seed + k, settle=True)
        env.close()
        info = ep["info"]
        x, y, th = info["true_pose"]
        err_heading = abs(math.degrees((th - goal[2] + math.pi) % (2 * math.pi) - math.pi))
        row = {
            "start": list(start),
            "final_pose": [float(x), float(y), float(th)],
            "abs_x_cm": abs(x) * 100,
            "abs_y_cm": abs(y) * 100,
            "pos_err_cm": math.hypot(x, y) * 100,
            "abs_heading_deg": err_heading,
            "success": bool(math.hypot(x, y) <= 0.03 and err_heading <= 5.0),
            "time_s": ep["steps"] * 0.05,
            "wall_s": time.perf_counter() - t0,
        }
        rows.append(row)
        ctx.progress(
            f"nav8 start {k + 1}/8 {start}: error {row['pos_err_cm']:.2f} cm, {err_heading:.2f}°"
        )
    figures = {
        "mean_abs_x_cm": float(np.mean([r["abs_x_cm"] for r in rows])),
        "mean_abs_y_cm": float(np.mean([r["abs_y_cm"] for r in rows])),
        "mean_pos_err_cm": float(np.mean([r["pos_err_cm"] for r in rows])),
        "max_pos_err_cm": float(np.max([r["pos_err_cm"] for r in rows])),
        "mean_abs_heading_deg": float(np.mean([r["abs_heading_deg"] for r in rows])),
        "success_rate": float(np.mean([r["success"] for r in rows])),
        "mean_time_to_goal_s": float(np.mean([r["time_s"] for r in rows])),
    }
    return {
        "figures": figures,
        "config": {"goal": list(goal), "policy": "classical APF→QP→Kanayama→polar", **config},
        "tables": {"episodes": rows},
    }


@experiment(
    "nav8-vo",
    "nav8 with calib000's imperfect robot after calibration, fused odometry+RGB-D VO in the loop",
)
def nav8_vo(ctx: RunContext) -> dict[str, Any]:
    from dataclasses import replace

    from realitygap.estimators.diffdrive_model import DiffDriveKinematics, OdometryNoise
    from realitygap.estimators.fusion_ekf import FusionSettings
    from realitygap.estimators.pipelines import FusedOdometryVO, FusedPipelineSettings
    from realitygap.experiments.calib000 import CalibConfig, calib000
    from realitygap.experiments.drive_harness import calibration_room
    from realitygap.robots.diffdrive import DiffDriveParams

    ctx.progress("nav8-vo: calibrating the imperfect robot (calib000)")
    calib = calib000(ctx)
    cal = calib["config"]["calibrated"]
    nominal = DiffDriveParams()
    kin = DiffDriveKinematics(
        cal["wheel_radius_left"], cal["wheel_radius_right"], cal["wheelbase"], nominal.ticks_per_rev
    )
    mx, my, myaw = cal["mounting_xy_yaw"]
    cam = replace(nominal.camera, mount_xyz=(mx, my, nominal.camera.mount_xyz[2]), mount_yaw=myaw)
    reality = (CalibConfig.quick() if ctx.quick else CalibConfig()).reality()
    room = calibration_room(3.5)
    # calibrated odometry is good to ~1 mm per metre (calib000): the filter's odometry noise says
    # so, and VO (≈ 2 cm/m, 0.5°/m in `vo`) corrects only what odometry cannot see
    settings = FusedPipelineSettings(
        fusion=FusionSettings(
            odometry_noise=OdometryNoise(
                distance_var_per_m=1e-6, heading_var_per_rad=1e-5, heading_var_per_m=1e-6
            ),
            vo_timeout=math.inf,
        )
    )

    def make_env(start: Any, goal: Any) -> Any:
        return _make_env(
            sensor_mode="image",
            obstacles=room,
            room_half_size=3.5,
            reality=reality,
            start=start,
            goal=goal,
            terminate_on_success=False,
            estimator=FusedOdometryVO(kin, cam.T_base_camera(), settings),
        )

    out = _nav8(
        ctx,
        make_env,
        {
            "estimator": "fused odometry + RGB-D VO, calibrated",
            "reality": reality.to_dict(),
            "calibration": cal,
        },
    )
    out["figures"]["calib_max_err_mm_straight"] = calib["figures"]["max_err_mm_straight"]
    out["figures"]["calib_max_err_mm_curve"] = calib["figures"]["max_err_mm_curve"]
    return out


@experiment(
    "nav-obstacles",
    "classical baseline over 50 seeded obstacle layouts: success, collisions, APF dead-ends",
)
def nav_obstacles(ctx: RunContext) -> dict[str, Any]:
    from realitygap.baselines import ClassicalNavPolicy
    from realitygap.controllers import grid_shortest_path_length
    from realitygap.envs.layouts import outline_points

    n_layouts = 10 if ctx.quick else 50
    rows = []
    for k in range(n_layouts):
        env = _make_env(n_obstacles=8)
        policy = ClassicalNavPolicy.from_env(env)
        seed = ctx.seed * 1000 + k
        ep = run_episode(env, policy, seed=seed)
        base = env.unwrapped
        info = ep["info"]
        # reference: grid shortest path around the true obstacles (inflated by the body radius)
        pts = outline_points(list(base.world.scenery_primitives()))
        start_xy = np.asarray(base._start_pose)[:2]
        shortest = grid_shortest_path_length(
            start_xy,
            info["goal"][:2],
            pts,
            resolution=0.05,
            inflation_radius=base.true_params.body_radius + 0.02,
            bounds=(
                -base.room_half_size,
                -base.room_half_size,
                base.room_half_size,
                base.room_half_size,
            ),
        )
        stats = policy.episode_stats()
        env.close()
        rows.append(
            {
                "seed": seed,
                "success": bool(info["is_success"]),
                "collision": bool(ep["collision"]),
                "apf_stuck": bool(stats["apf_stuck_events"] > 0),
                "apf_gave_up": int(stats["apf_gave_up"]),
                "path_length_m": ep["path_length"],
                "shortest_m": shortest,
                "final_pos_err_cm": info["pos_error"] * 100,
                "time_s": ep["steps"] * 0.05,
            }
        )
        ctx.progress(
            f"nav-obstacles {k + 1}/{n_layouts}: success={rows[-1]['success']} collision={rows[-1]['collision']} "
            f"path {ep['path_length']:.2f} m / shortest {shortest:.2f} m"
        )
    ok = [
        r for r in rows if r["success"] and math.isfinite(r["shortest_m"]) and r["shortest_m"] > 0
    ]
    figures = {
        "success_rate": float(np.mean([r["success"] for r in rows])),
        "collision_rate": float(np.mean([r["collision"] for r in rows])),
        "apf_stuck_rate": float(np.mean([r["apf_stuck"] for r in rows])),
        "path_length_ratio": float(np.mean([r["path_length_m"] / r["shortest_m"] for r in ok]))
        if ok
        else float("nan"),
        "mean_time_to_goal_s": float(np.mean([r["time_s"] for r in rows if r["success"]]))
        if ok
        else float("nan"),
        "episodes": n_layouts,
    }
    return {
        "figures": figures,
        "config": {"n_obstacles": 8, "layouts": n_layouts},
        "tables": {"episodes": rows},
    }
