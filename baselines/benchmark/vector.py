"""The vectorised WheeledNav against PyBullet: speed, pose agreement, policy transfer.

* :func:`vector_speed` — env steps per second of ``realitygap/WheeledNavVec-v0``
  at given numbers of robots, with uniform random actions.
* :func:`pose_agreement` — the benchmark's episodes driven in the PyBullet env
  by a policy; its actions replayed open loop in the vector env (same seeds,
  hence same start, goal and obstacles). Per step, the pose increment of each
  simulator in its own body frame (translation mm, rotation mrad) and their
  difference; over the episode, the open-loop position and heading gaps and
  whether both report a collision at the same step.
* :func:`vector_success` — a policy's deterministic episodes in the vector
  env on the benchmark's seeds (the surrogate side of the transfer column).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

VECTOR_ENV_ID = "realitygap/WheeledNavVec-v0"
"""Id of the vectorised WheeledNav (``gymnasium.make_vec``)."""

__all__ = [
    "VECTOR_ENV_ID",
    "pose_agreement",
    "surrogate_transfer_rows",
    "vector_speed",
    "vector_success",
]


def vector_speed(
    sizes: Sequence[int] = (1, 64, 1024),
    seconds: float = 3.0,
    seed: int = 0,
    env_kwargs: Mapping[str, Any] | None = None,
) -> dict[int, float]:
    """Env steps per second (robots × calls / wall s) of the vector env for each size in
    ``sizes``, each timed for about ``seconds`` of stepping with uniform random actions."""
    import realitygap  # noqa: F401  (registers the ids)

    out: dict[int, float] = {}
    rng = np.random.default_rng(seed)
    for n in sizes:
        env = gym.make_vec(VECTOR_ENV_ID, num_envs=int(n), **dict(env_kwargs or {}))
        env.reset(seed=seed)
        actions = rng.uniform(-1.0, 1.0, size=(64, int(n), 2))
        calls = 0
        t0 = time.perf_counter()
        while True:
            env.step(actions[calls % 64])
            calls += 1
            wall = time.perf_counter() - t0
            if wall >= seconds and calls >= 3:
                break
        out[int(n)] = calls * int(n) / wall
        env.close()
    return out


def _body_increment(before: FloatArray, after: FloatArray) -> FloatArray:
    """Pose increments (K, 3) of ``after`` relative to ``before`` in the body frame."""
    d = after - before
    c, s = np.cos(before[:, 2]), np.sin(before[:, 2])
    dth = (d[:, 2] + math.pi) % (2.0 * math.pi) - math.pi
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], dth])


def pose_agreement(
    policy_factory: Any,
    seeds: Sequence[int],
    env_kwargs: Mapping[str, Any] | None = None,
    max_steps: int = 1200,
) -> dict[str, Any]:
    """Drive episodes ``seeds`` in PyBullet with ``policy_factory(env)`` and replay the
    actions in the vector env (see the module docstring).

    Returns
    -------
    dict
        ``step_translation_mm`` and ``step_rotation_mrad``: per-step increment
        differences (all steps, pooled) as median, p95 and max; ``drift_pos_cm`` /
        ``drift_heading_deg``: open-loop gap at 5 s and at the end (medians);
        ``collision_agreement``: share of episodes whose collision flag (and step,
        within one) agrees; ``episodes``, ``steps``.
    """
    import realitygap  # noqa: F401

    kwargs = dict(env_kwargs or {})
    pb = gym.make("realitygap/WheeledNav-v0", max_episode_steps=max_steps, **kwargs)
    policy = policy_factory(pb)
    runs: list[tuple[FloatArray, FloatArray, int | None]] = []
    for seed in seeds:
        if hasattr(policy, "seed") and callable(policy.seed):
            policy.seed(seed)
        obs, info = pb.reset(seed=int(seed))
        poses, actions, hit = [info["true_pose"].copy()], [], None
        start, done = True, False
        while not done:
            a, _ = policy.predict(obs, episode_start=np.array([start]), deterministic=True)
            start = False
            a = np.clip(np.asarray(a, dtype=float).reshape(2), -1.0, 1.0)
            obs, _, term, trunc, info = pb.step(a)
            actions.append(a)
            poses.append(info["true_pose"].copy())
            if info["collision"] and hit is None:
                hit = len(actions)
            done = term or trunc
        runs.append((np.asarray(poses), np.asarray(actions), hit))
    pb.close()

    n = len(runs)
    vec = gym.make_vec(VECTOR_ENV_ID, num_envs=n, max_episode_steps=10**9, **kwargs)
    _, info = vec.reset(seed=[int(s) for s in seeds])
    length = max(a.shape[0] for _, a, _ in runs)
    vec_poses = np.full((n, length + 1, 3), np.nan)
    vec_poses[:, 0] = info["true_pose"]
    vec_hit: list[int | None] = [None] * n
    alive = np.ones(n, dtype=bool)
    acts = np.zeros((n, 2))
    for k in range(length):
        for i, (_, a, _) in enumerate(runs):
            acts[i] = a[k] if k < a.shape[0] else 0.0
        _, _, term, trunc, info = vec.step(acts)
        view = info.get("final_info", info)
        poses = view["true_pose"]
        for i in range(n):
            if not alive[i]:
                continue
            vec_poses[i, k + 1] = poses[i]
            if view["collision"][i] and vec_hit[i] is None:
                vec_hit[i] = k + 1
            if term[i] or trunc[i] or k + 1 >= runs[i][1].shape[0]:
                alive[i] = False
    vec.close()

    trans, rot, gap5, gap_end, head5, head_end, agree = [], [], [], [], [], [], []
    five = int(round(5.0 / 0.05))
    for i, (pp, a, hit) in enumerate(runs):
        vp = vec_poses[i, : a.shape[0] + 1]
        ok = np.all(np.isfinite(vp), axis=1)
        m = int(np.argmin(ok)) if not ok.all() else ok.size
        if m < 2:
            continue
        inc_pb = _body_increment(pp[: m - 1], pp[1:m])
        inc_vec = _body_increment(vp[: m - 1], vp[1:m])
        diff = inc_vec - inc_pb
        trans.append(np.hypot(diff[:, 0], diff[:, 1]) * 1000.0)
        rot.append(np.abs(diff[:, 2]) * 1000.0)
        gap = np.hypot(*(vp[:m, :2] - pp[:m, :2]).T) * 100.0
        head = np.degrees(np.abs((vp[:m, 2] - pp[:m, 2] + math.pi) % (2 * math.pi) - math.pi))
        gap_end.append(gap[-1])
        head_end.append(head[-1])
        if m > five:
            gap5.append(gap[five])
            head5.append(head[five])
        agree.append(
            (hit is None) == (vec_hit[i] is None)
            and (hit is None or abs(hit - int(vec_hit[i] or 0)) <= 1)
        )

    def stats(parts: list[FloatArray]) -> dict[str, float]:
        x = np.concatenate(parts) if parts else np.array([np.nan])
        return {
            "median": float(np.median(x)),
            "p95": float(np.percentile(x, 95)),
            "max": float(np.max(x)),
        }

    return {
        "episodes": n,
        "steps": int(sum(t.size for t in trans)),
        "step_translation_mm": stats(trans),
        "step_rotation_mrad": stats(rot),
        "drift_pos_cm": {
            "at_5s_median": float(np.median(gap5)) if gap5 else math.nan,
            "end_median": float(np.median(gap_end)) if gap_end else math.nan,
        },
        "drift_heading_deg": {
            "at_5s_median": float(np.median(head5)) if head5 else math.nan,
            "end_median": float(np.median(head_end)) if head_end else math.nan,
        },
        "collision_agreement": float(np.mean(agree)) if agree else math.nan,
    }


def vector_success(
    policy: Any, seeds: Sequence[int], env_kwargs: Mapping[str, Any] | None = None
) -> dict[str, float]:
    """Deterministic episodes of ``policy`` in the vector env, one robot per seed, all
    stepped together; returns success, within-10-cm and collision rates.

    ``policy.predict`` is called on the batch of observations (every learned policy of
    :mod:`realitygap.baselines.rl` takes a batch); each robot's first episode counts."""
    import realitygap  # noqa: F401

    n = len(seeds)
    env = gym.make_vec(VECTOR_ENV_ID, num_envs=n, **dict(env_kwargs or {}))
    obs, info = env.reset(seed=[int(s) for s in seeds])
    open_ = np.ones(n, dtype=bool)
    success = np.zeros(n, dtype=bool)
    collision = np.zeros(n, dtype=bool)
    best = np.full(n, np.inf)
    start = np.ones(n, dtype=bool)
    while open_.any():
        actions, _ = policy.predict(obs, episode_start=start, deterministic=True)
        start[:] = False
        obs, _, term, trunc, info = env.step(np.asarray(actions, dtype=float).reshape(n, 2))
        final = info.get("final_info", info)
        done = term | trunc
        src = {
            k: np.where(done, final[k], info[k]) for k in ("pos_error", "collision", "is_success")
        }
        best = np.where(open_, np.minimum(best, src["pos_error"]), best)
        ended = open_ & done
        success[ended] = src["is_success"][ended]
        collision[ended] = src["collision"][ended]
        open_ &= ~done
        start |= done
    env.close()
    reached = (best <= 0.10) & ~collision
    return {
        "success": float(success.mean()),
        "reached_10cm": float(reached.mean()),
        "collision": float(collision.mean()),
    }


def surrogate_transfer_rows(
    cfg: Any, summary: Sequence[Mapping[str, Any]], notes: list[str] | None = None
) -> list[dict[str, Any]]:
    """The surrogate → PyBullet column: every learned policy of ``cfg`` on an env with a
    vectorised surrogate, run on the benchmark's seeds in the vector env (nominal and each
    reality profile the surrogate can realise), next to its PyBullet figures in ``summary``
    (fast sensors). A policy whose success drops from the surrogate to PyBullet meets a
    sim-to-sim gap the diagnosis can localise.

    Rows: ``env``, ``policy``, ``trained_on``, ``reality``, ``n``, ``success_surrogate``,
    ``success_pybullet``, ``success_drop_pp`` (surrogate − PyBullet), ``reached_10cm_*``,
    ``collision_*``.
    """
    from realitygap.baselines.benchmark.config import episode_seeds, n_episodes
    from realitygap.baselines.benchmark.profiles import reality_for
    from realitygap.baselines.rl import VECTOR_ENVS, load_policy, read_policy_meta, shipped_policy

    by_cell = {
        (r.get("env_id", r["env"]), r["policy"], r["sensor_mode"], r["reality"]): r for r in summary
    }
    rows: list[dict[str, Any]] = []
    for env_id in cfg.env_ids:
        if env_id not in VECTOR_ENVS or "fast" not in cfg.sensor_modes:
            continue
        n = n_episodes(cfg, env_id, "fast")
        seeds = episode_seeds(cfg, n)
        for spec in cfg.policies:
            if spec.kind not in ("ppo", "sac", "file"):
                continue
            path = spec.path_for(env_id)
            if path is None:
                try:
                    path = shipped_policy(env_id, spec.kind)
                except FileNotFoundError:
                    continue
            meta = read_policy_meta(path)
            if meta.get("env_id") != env_id:
                continue
            for reality_name in ("nominal", *cfg.realities):
                base = by_cell.get((env_id, spec.name, "fast", reality_name))
                if base is None:
                    continue
                try:
                    reality = reality_for(env_id, reality_name)
                    probe = gym.make(env_id, sensor_mode="fast")
                    policy = load_policy(path, probe, env_id=env_id)
                    probe.close()
                    kwargs = {} if reality is None else {"reality": reality}
                    sur = vector_success(policy, seeds, kwargs)
                except ValueError as exc:
                    if notes is not None:
                        notes.append(
                            f"surrogate column left out for {spec.name}, {reality_name}: {exc}"
                        )
                    continue
                rows.append(
                    {
                        "env": env_id,
                        "policy": spec.name,
                        "trained_on": meta.get("train_env", env_id),
                        "reality": reality_name,
                        "n": n,
                        "success_surrogate": sur["success"],
                        "success_pybullet": base["success_mean"],
                        "success_drop_pp": 100.0 * (sur["success"] - base["success_mean"]),
                        "reached_10cm_surrogate": sur["reached_10cm"],
                        "reached_10cm_pybullet": base["reached_10cm_mean"],
                        "collision_surrogate": sur["collision"],
                        "collision_pybullet": base["collision_mean"],
                    }
                )
    return rows
