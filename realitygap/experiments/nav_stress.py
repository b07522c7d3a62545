"""``realitygap run nav-stress``: navigation over hundreds of unseen layouts, failures classified.

The classical policy and PPO (the benchmark's shipped policy) drive ``WheeledNav-v0`` in
both sensor modes over seed ranges that no test, tuning or other experiment uses
(:data:`SEED_RANGES`; episode ``k`` of range ``r`` has env seed ``1000 r + k``). Every
episode keeps a trace — true and estimated poses, the estimator's status, collisions and,
for the classical policy, the path it followed and the obstacle points it remembered — and
every failure is put in one class by :func:`classify_failure`, which compares what the
robot believed with the ground truth the env knows:

==================================  ===================================================
class                               the evidence
==================================  ===================================================
``perception: VO lost``             the localisation error exceeded
                                    :data:`LOCALISATION_TOLERANCE` before the failure
                                    and visual odometry had been lost
``perception: localisation``        the same error without a VO loss (odometry drift,
                                    a wrong VO update); or the robot stopped at the goal
                                    as it believed it, with a localisation error above
                                    the task's tolerance
``perception: map missed obstacle`` a collision on a path that ran through the obstacle
                                    where the robot's map showed it free (an unseen
                                    side or corner)
``perception: map wrong``           the planner found no path in the robot's map, but
                                    the complete grid planner finds one in the true map
                                    (phantom obstacles)
``planner: no path``                no path in the robot's map nor in the true one
``planner: stale plan``             a collision on a path that the robot's own map showed
                                    blocked (the plan was not renewed)
``planner: oscillation``            no progress over the last :data:`STALL_WINDOW_S`
                                    while driving back and forth
``planner: dead end``               no progress and hardly any motion (stopped)
``tracker: left a valid path``      a collision although the path kept the robot's
                                    radius clear of the obstacle
``tracker: final approach``         a collision in the final phases onto the goal pose
``controller: docking``             the episode ended within :data:`DOCKING_RADIUS` of the
                                    goal without settling inside the tolerances
``policy: collision``               a learned policy hit an obstacle (it has no path)
``timeout``                         none of the above: still moving, too slowly
==================================  ===================================================

The report has the success rate with its 95 % Wilson interval per policy and mode, the
fast-vs-image gap, the class table with the seeds to replay (``realitygap benchmark
--envs realitygap/WheeledNav-v0 --policies classical --sensor-modes image --seed R``
replays range ``R``), and every failed episode.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from realitygap.experiments import RunContext, experiment

ENV_ID = "realitygap/WheeledNav-v0"

SEED_RANGES: tuple[int, ...] = (11, 13, 17, 19, 23)
"""Seed ranges of the stress run (``--seed S`` shifts them by ``100 S``): episode ``k`` of
range ``r`` has env seed ``1000 r + k``. No test, tuning or other experiment draws from
them."""

LOCALISATION_TOLERANCE = 0.05
"""Localisation error (m) above which a failure is the perception's: more than half the
clearance margin the planner keeps beyond the robot's radius (0.25 − 0.176 m)."""

LOCALISATION_WINDOW_S = 2.0
"""The localisation error counts over this long before the failure (s)."""

STALL_WINDOW_S = 20.0
"""A timeout that came less than :data:`STALL_PROGRESS` m nearer to the goal than ever
before over this long (s) is a stall: an oscillation when the robot drove more than
:data:`OSCILLATION_PATH` m meanwhile, else a dead end."""

STALL_PROGRESS = 0.2
OSCILLATION_PATH = 1.0

DOCKING_RADIUS = 0.10
"""A timeout this close to the goal (m) is the final docking's failure."""

MAP_REACH = 0.5
"""A collision's path is judged against the robot's map over this distance (m) around the
contact: a remembered point nearer to that stretch than the robot's radius means the map
showed the path blocked."""


@dataclass
class EpisodeTrace:
    """What one episode leaves for classification (world frame, SI units)."""

    seed: int
    true_xy: npt.NDArray[np.float64]
    """(T, 2) true positions after each step."""
    est_xy: npt.NDArray[np.float64]
    """(T, 2) estimated positions after each step."""
    vo_lost: npt.NDArray[np.bool_]
    """(T,) whether the estimator reported visual odometry lost."""
    goal_xy: npt.NDArray[np.float64]
    dt: float
    success: bool
    collision_step: int | None
    """Index of the first step in collision, ``None`` without one."""
    body_radius: float
    obstacles: list[Any]
    """The true primitives (walls included)."""
    path: npt.NDArray[np.float64] | None = None
    """The classical policy's path at the failure, ``None`` without one (or for PPO)."""
    memory: npt.NDArray[np.float64] | None = None
    """The obstacle points the classical policy remembered at the failure."""
    phase: str = ""
    last_plan: str = ""
    has_planner: bool = False
    pos_tol: float = 0.03
    """The task's success tolerance on the position (m)."""
    true_map_has_path: bool | None = None
    """Whether the complete grid planner finds a path from the final pose in the true map
    (no-path cases)."""


def _hit_obstacle(trace: EpisodeTrace, xy: npt.NDArray[np.float64]) -> Any:
    from realitygap.envs.layouts import clearance

    dists = [float(clearance([p], xy[None])[0]) for p in trace.obstacles]
    return trace.obstacles[int(np.argmin(dists))]


def classify_failure(trace: EpisodeTrace) -> tuple[str, str]:
    """The class of a failed episode and a one-line detail (see the module's table).

    The rules run in order, and the first that holds names the class: a wrong belief about
    where the robot is explains everything after it, so perception comes first; then a
    collision is judged by the path it happened on, and a timeout by what the planner
    reported and how the robot moved.
    """
    if trace.success:
        return "success", ""
    n = len(trace.true_xy)
    end = trace.collision_step if trace.collision_step is not None else n - 1
    w = max(1, int(round(LOCALISATION_WINDOW_S / trace.dt)))
    lo = max(0, end - w)
    err = np.linalg.norm(trace.true_xy[: end + 1] - trace.est_xy[: end + 1], axis=1)
    window_err = float(err[lo:].max()) if len(err) else 0.0
    final_xy = trace.true_xy[end]
    dist_goal = float(np.linalg.norm(final_xy - trace.goal_xy))
    # or it stopped where it believed the goal was, beyond the task's tolerance of it
    stopped_off = (
        trace.collision_step is None and dist_goal <= DOCKING_RADIUS and err[end] > trace.pos_tol
    )
    if window_err > LOCALISATION_TOLERANCE or stopped_off:
        if stopped_off:
            detail = (
                f"ended {100 * dist_goal:.1f} cm from the goal with a localisation error of "
                f"{100 * float(err[end]):.1f} cm (tolerance {100 * trace.pos_tol:.0f} cm)"
            )
        else:
            first = int(np.argmax(err > LOCALISATION_TOLERANCE))
            detail = (
                f"localisation error {100 * window_err:.1f} cm before the failure (above "
                f"{100 * LOCALISATION_TOLERANCE:.0f} cm from t = {first * trace.dt:.1f} s)"
            )
        lost = bool(np.any(trace.vo_lost[: end + 1]))
        return ("perception: VO lost" if lost else "perception: localisation"), detail
    if trace.collision_step is not None:
        return _classify_collision(trace, final_xy)
    return _classify_timeout(trace, end)


def _classify_collision(trace: EpisodeTrace, xy: npt.NDArray[np.float64]) -> tuple[str, str]:
    from realitygap.envs.layouts import clearance

    hit = _hit_obstacle(trace, xy)
    where = f"hit {hit.name} at ({xy[0]:.2f}, {xy[1]:.2f}) m"
    if not trace.has_planner:
        return "policy: collision", where
    if trace.phase in ("stabilise", "align_final", "done"):
        return "tracker: final approach", f"{where} in phase {trace.phase}"
    if trace.path is None or len(trace.path) == 0:
        return "tracker: left a valid path", f"{where} with no path (phase {trace.phase})"
    path_clear = clearance([hit], trace.path)
    if float(path_clear.min()) >= trace.body_radius:
        return (
            "tracker: left a valid path",
            f"{where}; the path kept {100 * float(path_clear.min()):.0f} cm from it",
        )
    # did the robot's map say that the path, where it met the obstacle, was blocked?
    mem = trace.memory if trace.memory is not None else np.zeros((0, 2))
    stretch = trace.path[np.linalg.norm(trace.path - xy, axis=1) <= MAP_REACH]
    blocked = (
        len(mem) > 0
        and len(stretch) > 0
        and float(cKDTree(mem).query(stretch)[0].min()) < trace.body_radius
    )
    through = f"the path passed {100 * float(path_clear.min()):.0f} cm from it"
    if blocked:
        return "planner: stale plan", f"{where}; the map showed it on the path, {through}"
    return (
        "perception: map missed obstacle",
        f"{where}; the map did not show the part the path met (unseen), {through}",
    )


def _classify_timeout(trace: EpisodeTrace, end: int) -> tuple[str, str]:
    xy = trace.true_xy
    dist = np.linalg.norm(xy - trace.goal_xy, axis=1)
    if dist[end] <= DOCKING_RADIUS:
        prefix = "controller: docking" if trace.has_planner else "policy: docking"
        return prefix, f"ended {100 * dist[end]:.1f} cm from the goal"
    if trace.has_planner and trace.last_plan not in ("", "reached") and trace.path is None:
        if trace.true_map_has_path:
            return (
                "perception: map wrong",
                f"no path in the robot's map ({trace.last_plan}), one in the true map",
            )
        return "planner: no path", f"no path ({trace.last_plan}), nor in the true map"
    w = max(1, int(round(STALL_WINDOW_S / trace.dt)))
    lo = max(0, end - w)
    # progress: how much nearer than ever before the window the robot came within it
    progress = float(dist[: lo + 1].min() - dist[lo : end + 1].min())
    travelled = float(np.sum(np.linalg.norm(np.diff(xy[lo : end + 1], axis=0), axis=1)))
    if progress < STALL_PROGRESS:
        kind = "oscillation" if travelled > OSCILLATION_PATH else "dead end"
        prefix = "planner" if trace.has_planner else "policy"
        return (
            f"{prefix}: {kind}",
            f"{100 * progress:.0f} cm nearer than before in the last {STALL_WINDOW_S:.0f} s, "
            f"{travelled:.1f} m driven, {dist[end]:.2f} m from the goal",
        )
    return "timeout", f"still {dist[end]:.2f} m from the goal, moving"


def run_traced(env: Any, policy: Any, seed: int) -> tuple[EpisodeTrace, dict[str, Any]]:
    """Run one seeded episode of ``policy`` on a WheeledNav ``env`` (the benchmark's episode
    loop); its trace and metrics."""
    from realitygap.baselines.benchmark.runner import run_episode

    base = env.unwrapped
    steps: list[Mapping[str, Any]] = []

    def keep(info: Mapping[str, Any]) -> None:
        steps.append(
            {
                "true": np.asarray(info["true_pose"][:2], dtype=float),
                "est": np.asarray(info["estimated_pose"][:2], dtype=float),
                "lost": str(info.get("estimate_status", "")).startswith("vo_lost"),
                "collision": bool(info["collision"]),
                "goal": np.asarray(info["goal"][:2], dtype=float),
            }
        )

    ep = run_episode(env, policy, seed, on_step=keep)
    hits = [k for k, s in enumerate(steps) if s["collision"]]
    has_planner = hasattr(policy, "planned_path")
    stats = policy.episode_stats() if has_planner else {}
    trace = EpisodeTrace(
        seed=seed,
        true_xy=np.array([s["true"] for s in steps]),
        est_xy=np.array([s["est"] for s in steps]),
        vo_lost=np.array([s["lost"] for s in steps], dtype=bool),
        goal_xy=steps[-1]["goal"],
        dt=float(base.dt),
        success=bool(ep["success"]),
        collision_step=hits[0] if hits else None,
        body_radius=float(base.true_params.body_radius),
        obstacles=list(base.world.scenery_primitives()),
        path=policy.planned_path() if has_planner else None,
        memory=policy.obstacle_memory() if has_planner else None,
        phase=str(stats.get("phase", "")),
        last_plan=str(stats.get("last_plan", "")),
        has_planner=has_planner,
        pos_tol=float(base.success_pos_tol),
    )
    if has_planner and not trace.success and not hits and trace.path is None:
        # no plan at the end: does the true map have a way? (the complete grid planner)
        from realitygap.controllers import grid_shortest_path
        from realitygap.envs.layouts import outline_points

        way = grid_shortest_path(
            trace.true_xy[-1],
            trace.goal_xy,
            outline_points(trace.obstacles),
            inflation_radius=policy.config.apf.inflation_radius,
        )
        trace.true_map_has_path = way is not None
    loc = np.linalg.norm(trace.true_xy - trace.est_xy, axis=1)
    metrics = {
        "final_localisation_error_cm": 100.0 * float(loc[-1]) if len(loc) else 0.0,
        "steps": int(ep["steps"]),
        "final_pos_error_cm": float(ep["final_pos_error_cm"]),
        "max_localisation_error_cm": 100.0 * float(loc.max()) if len(loc) else 0.0,
        "vo_lost_steps": int(trace.vo_lost.sum()),
        "collision": bool(hits),
    }
    return trace, metrics


def _episodes(shared: Any, item: tuple[str, str, list[int]]) -> list[dict[str, Any]]:
    """Run and classify one chunk of episodes (a worker's task)."""
    import gymnasium as gym

    import realitygap  # noqa: F401  (registers the envs)
    from realitygap.baselines.benchmark.policies import build_policy, parse_policies

    policy_name, mode, seeds = item
    env = gym.make(ENV_ID, sensor_mode=mode)
    policy = build_policy(parse_policies(policy_name)[0], env, ENV_ID, seed=seeds[0])
    rows = []
    for seed in seeds:
        t0 = time.perf_counter()
        trace, metrics = run_traced(env, policy, seed)
        klass, detail = classify_failure(trace)
        rows.append(
            {
                "policy": policy_name,
                "mode": mode,
                "seed_range": seed // 1000,
                "seed": seed,
                "success": trace.success,
                "class": klass,
                "detail": detail,
                **metrics,
                "wall_s": time.perf_counter() - t0,
                "sim_s": metrics["steps"] * trace.dt,
            }
        )
    env.close()
    return rows


def _run_chunk(item: tuple[str, str, list[int]]) -> list[dict[str, Any]]:
    return _episodes(None, item)


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Success with Wilson intervals per (policy, mode), the fast-vs-image gap with its
    Newcombe interval (as the benchmark reports them), the classes."""
    from realitygap.baselines.benchmark.stats import difference_interval, wilson_interval

    summary, classes, gaps = [], [], []
    cells = sorted({(r["policy"], r["mode"]) for r in rows})
    rate: dict[tuple[str, str], tuple[int, int]] = {}
    for pol, mode in cells:
        cell = [r for r in rows if r["policy"] == pol and r["mode"] == mode]
        k = sum(r["success"] for r in cell)
        lo, hi = wilson_interval(k, len(cell))
        rate[(pol, mode)] = (k, len(cell))
        sim = sum(r["sim_s"] for r in cell)
        wall = sum(r["wall_s"] for r in cell)
        summary.append(
            {
                "policy": pol,
                "mode": mode,
                "episodes": len(cell),
                "successes": k,
                "success_pct": 100.0 * k / len(cell),
                "ci95_pct": f"[{100 * lo:.1f}, {100 * hi:.1f}]",
                "collisions": sum(r["collision"] for r in cell),
                "per_range_pct": ", ".join(
                    f"{rg}: {100 * np.mean([r['success'] for r in cell if r['seed_range'] == rg]):.0f}"
                    for rg in sorted({r["seed_range"] for r in cell})
                ),
                "real_time_factor": sim / wall if wall > 0 else math.nan,
            }
        )
        counts = Counter(r["class"] for r in cell if not r["success"])
        for klass, count in counts.most_common():
            seeds = [r["seed"] for r in cell if r["class"] == klass]
            classes.append(
                {
                    "policy": pol,
                    "mode": mode,
                    "class": klass,
                    "episodes": count,
                    "seeds": " ".join(str(s) for s in seeds),
                }
            )
    for pol in sorted({p for p, _ in cells}):
        if (pol, "fast") in rate and (pol, "image") in rate:
            (kf, nf), (ki, ni) = rate[(pol, "fast")], rate[(pol, "image")]
            lo, hi = difference_interval(kf, nf, ki, ni)
            gaps.append(
                {
                    "policy": pol,
                    "fast_pct": 100 * kf / nf,
                    "image_pct": 100 * ki / ni,
                    "gap_pct": 100 * (kf / nf - ki / ni),
                    "gap_ci95_pct": f"[{100 * lo:.1f}, {100 * hi:.1f}]",
                }
            )
    return {"summary": summary, "gaps": gaps, "classes": classes}


@experiment(
    "nav-stress",
    "classical and PPO, fast and image modes, over unseen seed ranges: success with 95 % "
    "intervals, the fast-vs-image gap and every failure classified",
    robots=("diffdrive",),
)
def nav_stress(ctx: RunContext) -> dict[str, Any]:
    from realitygap.core.parallel import available_cpus, make_backend

    per_range = 4 if ctx.quick else 40
    policies = ("classical",) if ctx.quick else ("classical", "ppo")
    ranges = [r + 100 * ctx.seed for r in SEED_RANGES]
    seeds = [1000 * r + k for r in ranges for k in range(per_range)]
    chunk = 10 if not ctx.quick else 4
    items = [
        (pol, mode, seeds[i : i + chunk])
        for pol in policies
        for mode in ("fast", "image")
        for i in range(0, len(seeds), chunk)
    ]
    ctx.expect(40 if ctx.quick else 600)
    ctx.progress(
        f"{len(seeds)} episodes per policy and mode over seed ranges {ranges}: {len(items)} chunks"
    )
    backend = make_backend("process", workers=min(2, available_cpus()))
    rows: list[dict[str, Any]] = []
    for done, outcome in enumerate(backend.imap_unordered(_run_chunk, items), start=1):
        if outcome.error is not None:
            raise outcome.error
        assert outcome.value is not None
        rows.extend(outcome.value)
        ok = sum(r["success"] for r in outcome.value)
        pol, mode, chunk_seeds = outcome.item
        ctx.progress(
            f"chunk {done}/{len(items)} ({pol}, {mode}, seeds {chunk_seeds[0]}…): "
            f"{ok}/{len(outcome.value)} succeeded"
        )
    rows.sort(key=lambda r: (r["policy"], r["mode"], r["seed"]))
    tables = summarise(rows)
    for row in tables["summary"]:
        ctx.progress(
            f"{row['policy']:>9} {row['mode']:>5}: {row['successes']}/{row['episodes']} "
            f"{row['ci95_pct']} %"
        )
    figures: dict[str, Any] = {}
    for row in tables["summary"]:
        key = f"{row['policy']}_{row['mode']}"
        figures[f"{key}_success_pct"] = row["success_pct"]
        figures[f"{key}_episodes"] = row["episodes"]
        figures[f"{key}_real_time_factor"] = row["real_time_factor"]
    for row in tables["gaps"]:
        figures[f"{row['policy']}_fast_minus_image_pct"] = row["gap_pct"]
    from realitygap.experiments.twin_transfer import success_plot

    png = success_plot(
        [{**r, "panel": "success per policy and sensor mode"} for r in tables["summary"]],
        group="mode",
        bars="policy",
        panels="panel",
        title="nav-stress: success with 95 % Wilson intervals",
        ylabel="success (%)",
    )
    if png is not None:
        ctx.add_plot("nav_stress_success.png", png)
    png = _class_plot(tables["classes"])
    if png is not None:
        ctx.add_plot("nav_stress_classes.png", png)
    failures = [
        {k: r[k] for k in ("policy", "mode", "seed", "class", "detail", "final_pos_error_cm")}
        for r in rows
        if not r["success"]
    ]
    episodes = [
        {
            k: r[k]
            for k in (
                "policy",
                "mode",
                "seed",
                "success",
                "class",
                "steps",
                "final_pos_error_cm",
                "max_localisation_error_cm",
                "final_localisation_error_cm",
                "vo_lost_steps",
                "wall_s",
            )
        }
        for r in rows
    ]
    return {
        "figures": figures,
        "config": {
            "seed_ranges": ranges,
            "episodes_per_range": per_range,
            "policies": list(policies),
            "localisation_tolerance_m": LOCALISATION_TOLERANCE,
            "stall_window_s": STALL_WINDOW_S,
            "replay": "realitygap benchmark --envs realitygap/WheeledNav-v0 --policies "
            "classical --sensor-modes image --seed R replays range R",
        },
        "tables": {**tables, "failures": failures, "episodes": episodes},
    }


def _class_plot(classes: list[dict[str, Any]]) -> bytes | None:
    """Failures per class, one bar group per (policy, mode); PNG bytes (``None`` without
    matplotlib or without failures)."""
    if not classes:
        return None
    try:
        import io

        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    cells = sorted({(c["policy"], c["mode"]) for c in classes})
    names = sorted({c["class"] for c in classes})
    fig, ax = plt.subplots(figsize=(8, 0.5 + 0.45 * len(names)))
    height = 0.8 / len(cells)
    for j, cell in enumerate(cells):
        counts = [
            sum(
                c["episodes"]
                for c in classes
                if (c["policy"], c["mode"]) == cell and c["class"] == n
            )
            for n in names
        ]
        ax.barh(np.arange(len(names)) + j * height, counts, height, label=" ".join(cell))
    ax.set_yticks(np.arange(len(names)) + 0.4 - height / 2)
    ax.set_yticklabels(names)
    ax.set_xlabel("failed episodes")
    ax.legend(fontsize=8)
    ax.set_title("nav-stress: failures by class")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()
