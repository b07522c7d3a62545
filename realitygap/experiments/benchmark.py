"""The ``benchmark`` experiment: classical vs learned vs random, nominal vs a reality profile.

Every registered env; reality profiles ``kobuki-worn`` (WheeledNav), ``arm-worn``
(ArmCalib) and ``climber-worn`` (WallClimb). Episode counts per cell:

===========================  ================  =====
cell                         ``--quick``       full
===========================  ================  =====
WheeledNav, fast sensors     10                100
WheeledNav, image sensors    2 (not random)    20
ArmCalib, geometric sensors  3                 20
ArmCalib, image sensors      –                 3
WallClimb, fast sensors      3                 20
WallClimb, image sensors     –                 3
===========================  ================  =====

Quick mode takes about 5–10 minutes on two cores, full mode about 1.5 hours;
``realitygap benchmark`` runs the same harness with every option exposed.

Learned policies (PPO, SAC) are the ones shipped in ``baselines/policies/``; without
stable-baselines3, or for an env without a shipped file, they are left out with a
note. Tables, plots and the streamed episodes go to ``runs/benchmark[-quick]`` (or
``ctx.options["out_dir"]``); ``ctx.options["resume"]`` keeps finished episodes there.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from realitygap.experiments import RunContext, experiment


@experiment(
    "benchmark",
    "classical vs PPO vs SAC vs random on identical seeded episodes, nominal and worn robots",
)
def benchmark(ctx: RunContext) -> dict[str, Any]:
    import realitygap
    from realitygap.baselines import benchmark as bm
    from realitygap.baselines.cli import shipped_curves, show_progress

    env_ids = list(realitygap.ENV_IDS)
    notes: list[str] = []
    policies = []
    for spec in bm.parse_policies("classical,ppo,sac,random"):
        try:
            policies += bm.resolve_learned_paths([spec], env_ids, notes)
        except ImportError as exc:
            notes.append(f"{spec.name} left out: {exc}")
    names = [p.name for p in policies]
    learned_and_classical = tuple(n for n in names if n != "random")
    realities = tuple(ctx.options.get("realities", ("kobuki-worn", "arm-worn", "climber-worn")))
    cfg = bm.BenchmarkConfig(
        env_ids=tuple(env_ids),
        policies=tuple(policies),
        episodes=10 if ctx.quick else 100,
        realities=realities,
        sensor_modes=("fast", "image"),
        seed=ctx.seed,
        episode_counts=(
            {
                "image": 2,
                "realitygap/ArmCalib-v0": 3,
                "realitygap/ArmCalib-v0:image": 0,
                "realitygap/WallClimb-v0": 3,
                "realitygap/WallClimb-v0:image": 0,
            }
            if ctx.quick
            else {
                "image": 20,
                "realitygap/ArmCalib-v0": 20,
                "realitygap/ArmCalib-v0:image": 3,
                "realitygap/WallClimb-v0": 20,
                "realitygap/WallClimb-v0:image": 3,
            }
        ),
        policies_by_mode={"image": learned_and_classical} if ctx.quick else {},
    )
    out_dir = Path(
        ctx.options.get("out_dir", Path("runs") / ("benchmark-quick" if ctx.quick else "benchmark"))
    )
    ctx.progress(
        f"benchmark: policies {', '.join(names)}; {cfg.episodes} fast / "
        f"{cfg.episode_counts['image']} image episodes per WheeledNav cell -> {out_dir}"
    )
    if ctx.verbose:
        show_progress("realitygap.baselines.benchmark", sys.stderr)
    result = bm.run_benchmark(
        cfg,
        out_dir,
        verbose=ctx.verbose,
        resume=bool(ctx.options.get("resume", False)),
        learning_curves=shipped_curves(policies, env_ids),
        notes=notes,
    )
    figures: dict[str, float] = {}
    for row in result.summary:
        key = f"{row['env']}.{row['policy']}.{row['sensor_mode']}.{row['reality']}"
        figures[f"{key}.success"] = row["success_mean"]
        figures[f"{key}.reached_10cm"] = row["reached_10cm_mean"]
        figures[f"{key}.final_pos_error_cm"] = row["final_pos_error_cm_mean"]
        figures[f"{key}.collision"] = row["collision_mean"]
    for t in result.transfer:
        key = f"{t['env']}.{t['policy']}.{t['sensor_mode']}.{t['reality']}"
        figures[f"{key}.success_drop_pp"] = t["success_drop_pp"]
    notes += [f"wrote {name}: {path}" for name, path in result.files.items()]
    notes += [f"failed task: {e}" for e in result.errors]
    return {
        "figures": figures,
        "config": {
            "envs": env_ids,
            "policies": names,
            "realities": list(realities),
            "episodes": {"default": cfg.episodes, **dict(cfg.episode_counts)},
            "episode_seeds": f"1000 * {ctx.seed} + k",
            "out_dir": str(out_dir),
        },
        "tables": {"summary": result.summary, "transfer": result.transfer},
        "notes": notes,
    }


@experiment(
    "bench-vec",
    "the vectorised WheeledNav: steps/s at N = 1, 64, 1024 and per-step pose agreement with "
    "PyBullet on the benchmark's episodes",
    robots=("diffdrive",),
)
def bench_vec(ctx: RunContext) -> dict[str, Any]:
    """Speed of ``realitygap/WheeledNavVec-v0`` (uniform random actions, about 5 s per size,
    2 s in quick mode) and its pose agreement with PyBullet: the classical policy drives the
    benchmark's episodes (seeds ``1000 * seed + k``; 100, quick 10) in PyBullet, its actions
    replayed open loop in the vector env (:func:`~realitygap.baselines.benchmark.vector.pose_agreement`).
    The machine's load average is recorded with the speeds."""
    import os

    from realitygap.baselines.benchmark.vector import pose_agreement, vector_speed
    from realitygap.cards import ENV_CARDS, load_object

    sizes = tuple(int(n) for n in ctx.options.get("sizes", (1, 64, 1024)))
    load_before = os.getloadavg()[0]
    ctx.progress(f"bench-vec: steps/s at N = {', '.join(map(str, sizes))}")
    speed = vector_speed(sizes, seconds=2.0 if ctx.quick else 5.0, seed=ctx.seed)
    load_after = os.getloadavg()[0]
    n_episodes = int(ctx.options.get("episodes", 10 if ctx.quick else 100))
    seeds = [1000 * ctx.seed + k for k in range(n_episodes)]
    ctx.progress(f"bench-vec: pose agreement over {n_episodes} benchmark episodes")
    factory = load_object(ENV_CARDS["realitygap/WheeledNav-v0"].classical_policy)
    agree = pose_agreement(factory, seeds)
    figures: dict[str, float] = {f"steps_per_s.N{n}": v for n, v in speed.items()}
    figures["load_average_1min"] = 0.5 * (load_before + load_after)
    figures["cpu_count"] = float(os.cpu_count() or 0)
    for key in ("step_translation_mm", "step_rotation_mrad"):
        for stat, value in agree[key].items():
            figures[f"{key}.{stat}"] = value
    for key in ("drift_pos_cm", "drift_heading_deg"):
        for stat, value in agree[key].items():
            figures[f"{key}.{stat}"] = value
    figures["collision_agreement"] = agree["collision_agreement"]
    figures["agreement_steps"] = float(agree["steps"])
    return {
        "figures": figures,
        "config": {
            "sizes": list(sizes),
            "episodes": n_episodes,
            "episode_seeds": f"1000 * {ctx.seed} + k",
            "actions": "classical policy in PyBullet, replayed open loop",
        },
        "notes": [
            "steps/s = robots x batched calls / wall s, random actions, one process",
            "per-step agreement: body-frame pose increments of the two simulators per control step",
        ],
    }
