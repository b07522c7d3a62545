"""bench-speed's timing passes: the wall-clock pass pays for no CPU-clock reads."""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

import realitygap  # noqa: F401  (registers the ids)
from realitygap.experiments.nav import _timed_steps


def test_the_wall_clock_pass_reads_no_cpu_clock_and_the_cpu_pass_does(monkeypatch) -> None:
    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=0, sensor_mode="fast")
    env.reset(seed=3)
    world = env.unwrapped.world
    actions = np.tile(np.float32([0.5, 0.2]), (20, 1))
    calls = {"n": 0}
    thread_time = time.thread_time

    def counting() -> float:
        calls["n"] += 1
        return thread_time()

    monkeypatch.setattr(time, "thread_time", counting)
    spent, physics = _timed_steps(env, actions, cpu=False)
    assert calls["n"] == 0  # a system call each: it would count as the env's overhead
    assert 0.0 < physics < spent
    assert world.cpu_timing is False
    spent_cpu, physics_cpu = _timed_steps(env, actions, cpu=True)
    # the pass's two reads per step and the world's two around its physics
    assert calls["n"] == 4 * len(actions)
    assert 0.0 < physics_cpu < spent_cpu
    assert world.cpu_timing is False  # left as it was found: off
    env.close()
