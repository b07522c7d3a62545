"""Wheeled-navigation experiments: ``nav8``, ``nav-obstacles``, ``bench-speed``."""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np

from realitygap.experiments import RunContext, experiment


def _make_env(**kwargs: Any) -> gym.Env:
    import realitygap  # noqa: F401  (registers the ids)

    return gym.make("realitygap/WheeledNav-v0", **kwargs)


@experiment(
    "bench-speed",
    "WheeledNav steps/s, real-time factor and env overhead over raw physics (fast and image modes)",
)
def bench_speed(ctx: RunContext) -> dict[str, Any]:
    n_steps = {"fast": 600 if ctx.quick else 4000, "image": 20 if ctx.quick else 200}
    figures: dict[str, float] = {}
    for mode in ("fast", "image"):
        env = _make_env(sensor_mode=mode, n_obstacles=6)
        world = env.unwrapped.world
        rng = np.random.default_rng(ctx.seed)
        env.reset(seed=ctx.seed)
        actions = rng.uniform(-1, 1, size=(n_steps[mode], 2)).astype(np.float32)
        # smooth the random commands so the robot drives rather than jitters
        for i in range(1, len(actions)):
            actions[i] = 0.9 * actions[i - 1] + 0.1 * actions[i]
        for a in actions[:10]:  # warm-up
            env.step(a)
        step_time = 0.0
        world.physics_seconds = 0.0
        physics_in_steps = 0.0
        for a in actions:
            before = world.physics_seconds
            t0 = time.perf_counter()
            _, _, terminated, truncated, _ = env.step(a)
            step_time += time.perf_counter() - t0
            physics_in_steps += world.physics_seconds - before
            if terminated or truncated:
                env.reset()
        dt = env.unwrapped.dt
        env.close()
        n = len(actions)
        figures[f"{mode}_env_steps_per_s"] = n / step_time
        figures[f"{mode}_real_time_factor"] = n * dt / step_time
        figures[f"{mode}_overhead_ratio"] = step_time / physics_in_steps
        ctx.progress(f"{mode}: {n / step_time:.0f} steps/s, RTF {n * dt / step_time:.1f}")
    return {
        "figures": figures,
        "config": {"steps": n_steps, "physics_hz": 240, "control_hz": 20, "n_obstacles": 6},
    }
