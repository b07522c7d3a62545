"""``realitygap run twin-transfer``: does the diagnosis's answer make a policy transfer?

For each hidden "real" robot (the benchmark's ``kobuki-worn`` and robots drawn from the
effects' realistic magnitudes, seeded; in some, one effect is withheld from the diagnosis's
library, so it lies outside what the diagnosis can name):

1. logs are recorded on it in PyBullet while the classical policy drives navigation
   episodes (:func:`record_policy_logs`; other episodes held out), diagnosed, and the answer
   exported as a reality file (:meth:`Diagnosis.to_reality`);
2. the classical policy and PPO (the shipped vector-recipe policy, fine-tuned on each
   simulator with the same budget) are prepared on four simulators:

   * ``nominal`` — the nominal robot (PPO: the shipped policy);
   * ``twin`` — the exported reality, its odometry calibrated to it (``estimator_reality``);
   * ``twin-randomized`` — the twin, each episode's robot drawn from its uncertainty boxes;
   * ``domain-randomized`` — plain domain randomisation over the library's magnitudes of
     the navigation effects, nominal odometry (it knows no calibration);

3. each is scored on the hidden robot in PyBullet on the same seeded episodes.

The classical policy is *tuned* on each simulator: it is deployed with that simulator's
odometry (calibrated to the twin, or nominal) and with the settings, among
:func:`classical_candidates`, that score best on 20 episodes of that simulator
(:func:`tune_classical`).

The *transfer drop* of a cell is the policy's success on its own nominal simulator minus its
success on the hidden robot; ``closed_pct`` is how much of the nominal policy's drop a
simulator gives back.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from realitygap.experiments import RunContext, experiment

ENV_ID = "realitygap/WheeledNav-v0"
CONDITIONS = ("nominal", "twin", "twin-randomized", "domain-randomized")
NAV_EFFECTS = (
    "wheel_radius_scale",
    "wheel_diameter_ratio",
    "wheelbase_error",
    "command_latency",
    "motor_deadband",
    "encoder_scale",
)
"""Effects the hidden robots and the plain domain randomisation draw from."""


def library_boxes() -> dict[str, tuple[float, float]]:
    """Plain domain randomisation: each navigation effect's parameter over the library's
    realistic magnitudes (its :class:`~realitygap.robots.effects.BlindRange` about nominal)."""
    from realitygap.robots.effects import EFFECTS

    out: dict[str, tuple[float, float]] = {}
    for name in NAV_EFFECTS:
        cls = EFFECTS[name]
        for r in cls.blind:
            s = cls.spec(r.param)
            lo, hi = (r.low, r.high) if r.absolute else (s.nominal + r.low, s.nominal + r.high)
            if r.symmetric and not r.absolute:
                lo = s.nominal - r.high
            out[f"{name}.{r.param}"] = (max(lo, s.low), min(hi, s.high))
    return out


def hidden_robots(seed: int, n: int) -> list[dict[str, Any]]:
    """``n`` hidden robots: ``kobuki-worn`` first, then two navigation effects each at
    magnitudes drawn from their library ranges; the last two withhold one of their effects
    from the diagnosis (outside the library)."""
    from realitygap.baselines.benchmark.profiles import reality_for
    from realitygap.robots.effects import EFFECTS, Reality, make_effect

    rng = np.random.default_rng([seed, 43])
    robots = [
        {"name": "kobuki-worn", "reality": reality_for(ENV_ID, "kobuki-worn"), "withheld": ()}
    ]
    k = 0
    while len(robots) < n:
        k += 1
        names = sorted(rng.choice(NAV_EFFECTS, size=2, replace=False), key=NAV_EFFECTS.index)
        effects = []
        for name in names:
            cls = EFFECTS[name]
            values = {}
            for r in cls.blind:
                s = cls.spec(r.param)
                mag = float(rng.uniform(0.5 * (r.low + r.high), r.high))
                sign = float(rng.choice([-1.0, 1.0])) if r.symmetric else 1.0
                values[r.param] = mag if r.absolute else s.nominal + sign * mag
            effects.append(make_effect(name, **values))
        pick = int(rng.integers(2))
        withheld = (str(names[pick]),) if k >= n - 2 else ()
        robots.append(
            {
                "name": f"hidden-{k}",
                "reality": Reality(tuple(effects), name=f"hidden-{k}"),
                "withheld": withheld,
            }
        )
    return robots


def record_policy_logs(reality: Any, seeds: list[int], rng: np.random.Generator) -> list[Any]:
    """Logs of the classical policy driving WheeledNav episodes (seeds ``seeds``) on the robot
    ``reality``, as a team would record its robot at work: commands, encoder ticks and
    motion-capture poses with the blind suite's noise, one log per episode. The policy runs
    with the nominal odometry (nothing is calibrated yet)."""
    import gymnasium as gym

    import realitygap  # noqa: F401  (registers the envs)
    from realitygap.baselines.classical import ClassicalNavPolicy
    from realitygap.diagnosis.adapters.diffdrive.blind import BLIND_NOISE
    from realitygap.diagnosis.adapters.diffdrive.record import RecordLog

    logs = []
    for seed in seeds:
        env = gym.make(ENV_ID, reality=reality)
        rec = RecordLog(env, noise=BLIND_NOISE, rng=rng, meta={"name": f"episode-{seed}"})
        try:
            policy = ClassicalNavPolicy.from_env(env)
            obs, _ = rec.reset(seed=seed)
            state, start, done = None, True, False
            while not done:
                action, state = policy.predict(
                    obs, state=state, episode_start=np.array([start]), deterministic=True
                )
                start = False
                obs, _, terminated, truncated, _ = rec.step(action)
                done = terminated or truncated
            logs.append(rec.log)
        finally:
            env.close()
    return logs


def diagnosis_settings(robot: str, quick: bool, effects: tuple[str, ...] | None = None) -> Any:
    """The diagnosis both experiments run: the full attribution, or in quick mode no pairs
    and one PyBullet check; ``effects`` the library (default: the robot's whole one)."""
    from realitygap.diagnosis.diagnose import DiagnosisSettings
    from realitygap.diagnosis.problem.problem import AttributionSettings

    attribution = (
        AttributionSettings(pair_candidates=0, verify_top=1) if quick else AttributionSettings()
    )
    return DiagnosisSettings(robot=robot, effects=effects, attribution=attribution)


def _diagnose(robot: dict[str, Any], seed: int, quick: bool) -> tuple[Any, dict[str, Any]]:
    """Record the hidden robot's logs with the classical policy (6 training episodes, 4
    held out; 3 and 2 in quick mode), diagnose them (the withheld effects left out of the
    library) and export the twin."""
    from realitygap.diagnosis.adapters.registry import get_adapter
    from realitygap.diagnosis.diagnose import DiagnosisSettings, candidate_library, diagnose

    adapter = get_adapter("diffdrive")
    t0 = time.perf_counter()
    rng = np.random.default_rng([seed, 7])
    n_train, n_hold = (3, 2) if quick else (6, 4)
    base = 70_000 + 100 * seed
    train = record_policy_logs(robot["reality"], list(range(base, base + n_train)), rng)
    hold = record_policy_logs(robot["reality"], list(range(base + 50, base + 50 + n_hold)), rng)
    library = candidate_library(adapter, DiagnosisSettings(robot="diffdrive"))
    settings = diagnosis_settings(
        "diffdrive", quick, tuple(e for e in library if e not in robot["withheld"])
    )
    d = diagnose(train, hold, settings=settings, progress=lambda m: None)
    twin = d.to_reality(name=f"twin of {robot['name']}")
    label = d.verdict.label
    row = {
        "robot": robot["name"],
        "hidden": "; ".join(f"{e.name}({_values(e.values)})" for e in robot["reality"].effects),
        "withheld": ", ".join(robot["withheld"]) or "-",
        "verdict": ", ".join(label) if isinstance(label, list) else str(label),
        "twin": "; ".join(f"{e.name}({_values(e.values)})" for e in twin.reality.effects),
        "diagnose_s": time.perf_counter() - t0,
    }
    return twin, row


def _values(values: dict[str, float]) -> str:
    return ", ".join(f"{k}={v:.4g}" for k, v in values.items())


def _env_kwargs(condition: str, hidden: Any, twin: Any) -> dict[str, Any]:
    """The evaluation env's keywords: the hidden robot, and the twin's odometry where the
    condition deploys with it."""
    kw: dict[str, Any] = {"reality": hidden.to_dict()}
    if condition in ("twin", "twin-randomized"):
        kw["estimator_reality"] = twin.reality.to_dict()
    return kw


def _train_kwargs(condition: str, twin: Any) -> dict[str, Any]:
    """The training simulator's keywords for ``condition`` (JSON-able)."""
    if condition == "twin":
        return {"reality": twin.reality.to_dict(), "estimator_reality": twin.reality.to_dict()}
    if condition == "twin-randomized":
        return {
            "reality": twin.reality.to_dict(),
            "randomize": {k: list(v) for k, v in twin.randomize.items()},
            "estimator_reality": twin.reality.to_dict(),
        }
    if condition == "domain-randomized":
        return {"randomize": {k: list(v) for k, v in library_boxes().items()}}
    return {}


def shipped_vector_policy() -> Path:
    """The shipped PPO policy of the vector recipe (trained on the nominal surrogate)."""
    from realitygap.baselines.rl.persistence import POLICIES_DIR, env_slug

    path = POLICIES_DIR / f"{env_slug(ENV_ID)}_ppo_vector.pth"
    if not path.is_file():
        raise FileNotFoundError(
            f"no shipped vector-recipe PPO policy ({path}); train one with `realitygap train "
            f"--env {ENV_ID} --algo ppo --vector --ship`"
        )
    return path


def _fine_tune(kwargs: dict[str, Any], out: Path, steps: int, seed: int) -> Path:
    """The shipped vector-recipe PPO policy, fine-tuned ``steps`` on the simulator ``kwargs``;
    returns the model file."""
    import json

    from realitygap.baselines import rl

    hp = json.loads((Path(rl.__file__).parent.parent / "hyperparams" / "ppo.json").read_text())
    entry = dict(hp[ENV_ID])
    entry["env_kwargs"] = {**dict(entry.get("env_kwargs", {})), **kwargs}
    entry.pop("demonstrations", None)
    cfg = rl.TrainConfig(
        env_id=ENV_ID,
        algo="ppo",
        out_dir=out,
        seed=seed,
        total_timesteps=steps,
        hyperparams=entry,
        checkpoint_every=0,
        eval_every=10 * steps,
        eval_episodes=1,
        progress_every_s=1e9,
        init_model=shipped_vector_policy(),
        vector=True,
    )
    return Path(rl.train(cfg).model_path)


def classical_candidates() -> tuple[Any, ...]:
    """The classical pipeline's settings a simulator chooses among: as shipped, and two
    gentler ones (slower references, softer acceleration) that leave more time for a late or
    sluggish drive."""
    import dataclasses

    from realitygap.baselines.classical import ClassicalNavConfig

    base = ClassicalNavConfig()
    return (
        base,
        dataclasses.replace(base, speed_fraction=0.6, acceleration_fraction=0.4),
        dataclasses.replace(base, speed_fraction=0.4, acceleration_fraction=0.3),
    )


def _tuning_task(shared: Any, item: tuple[str, int, list[int]]) -> tuple[str, int, int, float]:
    """Successes and median final error of classical candidate ``index`` on simulator ``key``."""
    import gymnasium as gym

    import realitygap  # noqa: F401  (registers the envs)
    from realitygap.baselines.benchmark.runner import run_episode
    from realitygap.baselines.classical import ClassicalNavPolicy

    key, index, seeds = item
    env = gym.make(ENV_ID, **shared[key])
    policy = ClassicalNavPolicy.from_env(env, classical_candidates()[index])
    runs = [run_episode(env, policy, s) for s in seeds]
    env.close()
    errors = [r["final_pos_error_cm"] for r in runs]
    return key, index, sum(r["success"] for r in runs), float(np.median(errors))


def tune_classical(
    sims: dict[str, dict[str, Any]], seeds: list[int], backend: Any
) -> dict[str, int]:
    """Per simulator (``gym.make`` keywords by name), the classical candidate
    (:func:`classical_candidates`) with the most successes on ``seeds`` there, ties broken by
    the lower median final error, then by the order of the candidates."""
    items = [(k, i, seeds) for k in sims for i in range(len(classical_candidates()))]
    scores = backend.map(_tuning_task, items, sims)
    best: dict[str, int] = {}
    for key in sims:
        mine = sorted((-n, err, i) for k, i, n, err in scores if k == key)
        best[key] = mine[0][2]
    return best


def _episodes(shared: Any, item: tuple[str, str, str, list[int]]) -> list[dict[str, Any]]:
    """Run one cell's episodes (a worker's task)."""
    import gymnasium as gym

    import realitygap  # noqa: F401  (registers the envs)
    from realitygap.baselines.benchmark.runner import run_episode
    from realitygap.baselines.classical import ClassicalNavPolicy
    from realitygap.baselines.rl.persistence import load_policy

    kwargs_by_cell, policies, tuned = shared
    key, policy, condition, seeds = item
    env = gym.make(ENV_ID, **kwargs_by_cell[key])
    robot = key.split("|")[0]
    if policy == "classical":
        config = classical_candidates()[tuned[(robot, condition)]]
        pol: Any = ClassicalNavPolicy.from_env(env, config)
    else:
        pol = load_policy(policies[(robot, condition)], env, env_id=ENV_ID)
    rows = []
    for s in seeds:
        r = run_episode(env, pol, s)
        rows.append(
            {
                "key": key,
                "policy": policy,
                "condition": condition,
                "seed": s,
                "success": bool(r["success"]),
                "error_cm": float(r["final_pos_error_cm"]),
            }
        )
    env.close()
    return rows


@experiment(
    "twin-transfer",
    "hidden robots diagnosed and exported; classical and PPO prepared on nominal, twin, "
    "randomised twin and domain-randomised simulators, scored on the hidden robots",
    robots=("diffdrive",),
)
def twin_transfer(ctx: RunContext) -> dict[str, Any]:
    from realitygap.baselines.benchmark.stats import wilson_interval
    from realitygap.core.parallel import available_cpus, make_backend

    n_robots = 2 if ctx.quick else 5
    episodes = 3 if ctx.quick else 100
    steps = 2048 if ctx.quick else 65536
    ctx.expect(60 if ctx.quick else 60 * (2 + n_robots * 6))
    seeds = [50_000 + ctx.seed * 1000 + i for i in range(episodes)]
    robots = hidden_robots(ctx.seed, n_robots)
    work = Path(tempfile.mkdtemp(prefix="realitygap-twin-"))
    twins, diag_rows = {}, []
    for robot in robots:
        ctx.progress(f"{robot['name']}: recording and diagnosing")
        twins[robot["name"]], row = _diagnose(robot, ctx.seed, ctx.quick)
        diag_rows.append(row)
        twins[robot["name"]].save(work / f"{robot['name']}.reality.json")
        ctx.progress(f"  found {row['twin'] or 'nothing'} (hidden {row['hidden']})")
    # PPO: the shipped policy (nominal) and one fine-tuned per simulator
    policies: dict[tuple[str, str], str] = {}
    shipped = str(shipped_vector_policy())
    dr_model = None
    for robot in robots:
        name = robot["name"]
        policies[(name, "nominal")] = shipped
        for cond in ("twin", "twin-randomized", "domain-randomized"):
            if cond == "domain-randomized" and dr_model is not None:
                policies[(name, cond)] = dr_model
                continue
            ctx.progress(f"PPO: fine-tuning on the {cond} simulator of {name} ({steps} steps)")
            model = str(
                _fine_tune(
                    _train_kwargs(cond, twins[name]), work / f"{name}-{cond}", steps, ctx.seed
                )
            )
            policies[(name, cond)] = model
            if cond == "domain-randomized":
                dr_model = model
    # the classical policy: the candidate settings each simulator scores best
    backend = make_backend("process", workers=min(2, available_cpus()))
    sims: dict[str, dict[str, Any]] = {
        "nominal": {},
        "domain-randomized": _train_kwargs("domain-randomized", None),
    }
    for robot in robots:
        for cond in ("twin", "twin-randomized"):
            sims[f"{robot['name']}|{cond}"] = _train_kwargs(cond, twins[robot["name"]])
    n_tune = 2 if ctx.quick else 20
    ctx.progress(
        f"classical: choosing its settings on {len(sims)} simulators ({n_tune} episodes each)"
    )
    best = tune_classical(sims, [40_000 + ctx.seed * 1000 + i for i in range(n_tune)], backend)
    tuned = {("nominal-sim", "nominal"): best["nominal"]}
    for robot in robots:
        name = robot["name"]
        tuned[(name, "nominal")] = best["nominal"]
        tuned[(name, "domain-randomized")] = best["domain-randomized"]
        for cond in ("twin", "twin-randomized"):
            tuned[(name, cond)] = best[f"{name}|{cond}"]
    # cells: each robot x condition x policy, plus each policy on its own nominal simulator
    kwargs_by_cell: dict[str, dict[str, Any]] = {}
    items = []
    chunk = max(1, episodes // 4)
    for robot in robots:
        name = robot["name"]
        for cond in CONDITIONS:
            key = f"{name}|{cond}"
            kwargs_by_cell[key] = _env_kwargs(cond, robot["reality"], twins[name])
            for pol in ("classical", "ppo"):
                for i in range(0, episodes, chunk):
                    items.append((key, pol, cond, seeds[i : i + chunk]))
    kwargs_by_cell["nominal-sim|nominal"] = {}
    for pol in ("classical", "ppo"):
        for i in range(0, episodes, chunk):
            items.append(("nominal-sim|nominal", pol, "nominal", seeds[i : i + chunk]))
    policies[("nominal-sim", "nominal")] = shipped
    ctx.progress(f"scoring {len(items)} chunks of episodes in PyBullet")
    shared = (kwargs_by_cell, policies, tuned)
    rows = [r for part in backend.map(_episodes, items, shared) for r in part]
    out = _summarise(rows, robots, diag_rows, episodes, wilson_interval, ctx)
    out["tables"]["classical_settings"] = [
        {"robot": r, "simulator": c, "setting": i, **_setting_words(i)}
        for (r, c), i in tuned.items()
    ]
    return out


def _setting_words(index: int) -> dict[str, float]:
    c = classical_candidates()[index]
    return {"speed_fraction": c.speed_fraction, "acceleration_fraction": c.acceleration_fraction}


def success_plot(
    rows: list[dict[str, Any]],
    group: str,
    bars: str,
    panels: str,
    title: str,
    ylabel: str = "success on the real robot (%)",
) -> bytes | None:
    """Success (%) with 95 % Wilson whiskers: one panel per ``rows[i][panels]``, groups of
    bars by ``group``, one bar per ``bars`` value; PNG bytes (``None`` without matplotlib).
    Rows hold ``success_pct`` and ``ci95_pct`` (``"[lo, hi]"``)."""
    try:
        import io

        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    names = list(dict.fromkeys(r[panels] for r in rows))
    fig, axes = plt.subplots(1, len(names), figsize=(5.5 * len(names), 3.6), squeeze=False)
    for ax, panel in zip(axes[0], names, strict=True):
        sub = [r for r in rows if r[panels] == panel]
        groups = list(dict.fromkeys(r[group] for r in sub))
        kinds = list(dict.fromkeys(r[bars] for r in sub))
        width = 0.8 / max(len(kinds), 1)
        for j, kind in enumerate(kinds):
            vals, err = [], [[], []]
            for g in groups:
                r = next((x for x in sub if x[group] == g and x[bars] == kind), None)
                v = r["success_pct"] if r else math.nan
                lo, hi = (float(x) for x in r["ci95_pct"].strip("[]").split(",")) if r else (v, v)
                vals.append(v)
                err[0].append(max(v - lo, 0.0))
                err[1].append(max(hi - v, 0.0))
            xs = np.arange(len(groups)) + (j - (len(kinds) - 1) / 2) * width
            ax.bar(xs, vals, width, yerr=err, capsize=2, label=kind)
        ax.set_xticks(np.arange(len(groups)), groups, rotation=20, fontsize=8)
        ax.set_ylim(0, 105)
        ax.set_ylabel(ylabel)
        ax.set_title(str(panel))
        ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def _summarise(rows, robots, diag_rows, episodes, wilson, ctx) -> dict[str, Any]:  # type: ignore[no-untyped-def]
    def cell(key: str, policy: str) -> list[dict[str, Any]]:
        return [r for r in rows if r["key"] == key and r["policy"] == policy]

    def rate(rs: list[dict[str, Any]]) -> float:
        return float(np.mean([r["success"] for r in rs])) if rs else math.nan

    base = {p: rate(cell("nominal-sim|nominal", p)) for p in ("classical", "ppo")}
    table, closed = [], {p: {c: [] for c in CONDITIONS[1:]} for p in ("classical", "ppo")}
    for robot in robots:
        name = robot["name"]
        for pol in ("classical", "ppo"):
            s_nom = rate(cell(f"{name}|nominal", pol))
            drop_nom = base[pol] - s_nom
            for cond in CONDITIONS:
                rs = cell(f"{name}|{cond}", pol)
                k = sum(r["success"] for r in rs)
                lo, hi = wilson(k, len(rs))
                s = rate(rs)
                row = {
                    "robot": name,
                    "policy": pol,
                    "simulator": cond,
                    "success_pct": 100 * s,
                    "ci95_pct": f"[{100 * lo:.0f}, {100 * hi:.0f}]",
                    "median_error_cm": float(np.median([r["error_cm"] for r in rs])),
                    "transfer_drop_pct": 100 * (base[pol] - s),
                    "closed_pct": math.nan,
                }
                if cond != "nominal" and drop_nom > 0:
                    row["closed_pct"] = 100 * (s - s_nom) / drop_nom
                    closed[pol][cond].append(row["closed_pct"])
                table.append(row)
    png = success_plot(
        table, "robot", "simulator", "policy", "trained or tuned on: scored on the hidden robot"
    )
    if png is not None:
        ctx.add_plot("twin_transfer.png", png)
    figures: dict[str, float] = {f"{p}_nominal_sim_success_pct": 100 * base[p] for p in base}
    for pol, by in closed.items():
        for cond, xs in by.items():
            figures[f"{pol}_{cond}_mean_closed_pct"] = float(np.mean(xs)) if xs else math.nan
    return {
        "figures": figures,
        "tables": {"diagnoses": diag_rows, "transfer": table},
        "config": {"robots": [r["name"] for r in robots], "episodes_per_cell": episodes},
        "notes": [
            "closed_pct: share of the nominal policy's transfer drop on that robot that the "
            "simulator gives back (NaN where the nominal policy did not drop)"
        ],
    }


# --------------------------------------------------------------------------- twin-worn
WORN = (
    ("realitygap/WheeledNav-v0", "diffdrive", "kobuki-worn"),
    ("realitygap/ArmCalib-v0", "arm", "arm-worn"),
    ("realitygap/WallClimb-v0", "climber", "climber-worn"),
)
"""The benchmark's worn realities: env, robot, profile."""


def record_logs(robot: str, reality: Any, seed: int, quick: bool) -> tuple[list[Any], list[Any]]:
    """Training and held-out logs recorded on ``reality``: the differential drive's by the
    classical policy at work (:func:`record_policy_logs`), the arm's as measured poses under
    a laser tracker (150 per log), the climber's as three runs on the blade each."""
    from realitygap.diagnosis.adapters.contract import BlindLogSettings
    from realitygap.diagnosis.adapters.registry import get_adapter

    rng = np.random.default_rng([seed, 11])
    if robot == "diffdrive":
        n_train, n_hold = (3, 2) if quick else (6, 4)
        base = 80_000 + 100 * seed
        return (
            record_policy_logs(reality, list(range(base, base + n_train)), rng),
            record_policy_logs(reality, list(range(base + 50, base + 50 + n_hold)), rng),
        )
    adapter = get_adapter(robot)
    settings = BlindLogSettings(None, 60 if quick else 150, 2e-5)
    train: list[Any] = []
    hold: list[Any] = []
    for _ in range(1 if (quick or robot == "arm") else 3):
        a, b = adapter.record_blind_logs(reality, rng, settings)
        train += a
        hold += b
    return train, hold


def _campaigns(shared: Any, item: tuple[str, str, str, list[int]]) -> list[dict[str, Any]]:
    """One chunk of episodes of ``policy`` on ``env_id`` (a worker's task)."""
    import gymnasium as gym

    import realitygap  # noqa: F401  (registers the envs)
    from realitygap.baselines.benchmark.policies import build_policy, parse_policies
    from realitygap.baselines.benchmark.runner import run_episode

    kwargs_by_cell = shared
    key, env_id, policy, seeds = item
    env = gym.make(env_id, **kwargs_by_cell[key])
    pol = build_policy(parse_policies(policy)[0], env, env_id, seed=seeds[0])
    rows = [
        {"key": key, "policy": policy, "seed": s, **_outcome(run_episode(env, pol, s))}
        for s in seeds
    ]
    env.close()
    return rows


def _outcome(record: dict[str, Any]) -> dict[str, Any]:
    info = record.get("final_info", {})
    if "validation_rms_mm" in info:  # the arm: the calibrated model's validation RMS, mm
        error = float(info["validation_rms_mm"])
    elif "goal_distance" in info:  # the climber: true distance to the goal, cm
        error = 100.0 * float(info["goal_distance"])
    else:
        error = float(record["final_pos_error_cm"])
    return {"success": bool(record["success"]), "error": error}


@experiment(
    "twin-worn",
    "the benchmark's worn robots diagnosed from logs recorded on them and exported; their "
    "policies scored on them before and after deploying with the twin's calibration",
)
def twin_worn(ctx: RunContext) -> dict[str, Any]:
    """For each worn reality of the benchmark: record logs on it, diagnose, export the twin,
    then score the classical policy and the shipped PPO policy on the worn robot with the
    pipeline as shipped (*before*) and calibrated to the twin (*after*:
    ``estimator_reality``; the differential drive's odometry, the arm's transmission, the
    climber's tether and IMU drivers). Errors: final distance to the goal (cm) for the mobile
    robots, validation RMS (mm) for the arm."""
    from realitygap.baselines.benchmark.profiles import reality_for
    from realitygap.baselines.benchmark.stats import wilson_interval
    from realitygap.core.parallel import available_cpus, make_backend
    from realitygap.diagnosis.diagnose import diagnose

    episodes = {"diffdrive": 50, "arm": 20, "climber": 20}
    ctx.expect(90 if ctx.quick else 900)
    work = Path(tempfile.mkdtemp(prefix="realitygap-worn-"))
    kwargs_by_cell: dict[str, dict[str, Any]] = {}
    items: list[tuple[str, str, str, list[int]]] = []
    diag_rows = []
    for env_id, robot, profile in WORN:
        reality = reality_for(env_id, profile)
        ctx.progress(f"{profile}: recording logs on it and diagnosing them")
        t0 = time.perf_counter()
        train, hold = record_logs(robot, reality, ctx.seed, ctx.quick)
        settings = diagnosis_settings(robot, ctx.quick)
        d = diagnose(train, hold, settings=settings, progress=lambda m: None)
        twin = d.to_reality(name=f"twin of {profile}")
        twin.save(work / f"{profile}.reality.json")
        label = d.verdict.label
        diag_rows.append(
            {
                "reality": profile,
                "hidden": "; ".join(f"{e.name}({_values(e.values)})" for e in reality.effects),
                "verdict": ", ".join(label) if isinstance(label, list) else str(label),
                "twin": "; ".join(f"{e.name}({_values(e.values)})" for e in twin.reality.effects)
                or "-",
                "logs": f"{len(train)} + {len(hold)} held out",
                "seconds": time.perf_counter() - t0,
            }
        )
        ctx.progress(f"  {diag_rows[-1]['verdict']}: {diag_rows[-1]['twin']}")
        n = 3 if ctx.quick else episodes[robot]
        seeds = [60_000 + 1000 * ctx.seed + i for i in range(n)]
        for when, kw in (("before", {}), ("after", {"estimator_reality": twin.reality.to_dict()})):
            key = f"{profile}|{when}"
            kwargs_by_cell[key] = {"reality": reality.to_dict(), **kw}
            for policy in ("classical", "ppo"):
                chunk = max(1, n // 4)
                for i in range(0, n, chunk):
                    items.append((key, env_id, policy, seeds[i : i + chunk]))
    ctx.progress(f"scoring {len(items)} chunks of episodes in PyBullet")
    backend = make_backend("process", workers=min(2, available_cpus()))
    rows = [r for part in backend.map(_campaigns, items, kwargs_by_cell) for r in part]
    table = []
    figures: dict[str, float] = {}
    for _, robot, profile in WORN:
        for policy in ("classical", "ppo"):
            row: dict[str, Any] = {"reality": profile, "policy": policy}
            for when in ("before", "after"):
                rs = [r for r in rows if r["key"] == f"{profile}|{when}" and r["policy"] == policy]
                k = sum(r["success"] for r in rs)
                lo, hi = wilson_interval(k, len(rs))
                row[f"{when}_success_pct"] = 100.0 * k / max(len(rs), 1)
                row[f"{when}_ci95_pct"] = f"[{100 * lo:.0f}, {100 * hi:.0f}]"
                row[f"{when}_median_error"] = float(np.median([r["error"] for r in rs]))
                figures[f"{profile}_{policy}_{when}_success_pct"] = row[f"{when}_success_pct"]
            row["error_unit"] = "mm (validation RMS)" if robot == "arm" else "cm (to the goal)"
            table.append(row)
    bars = [
        {
            "reality": r["reality"],
            "policy": r["policy"],
            "pipeline": when,
            "success_pct": r[f"{when}_success_pct"],
            "ci95_pct": r[f"{when}_ci95_pct"],
        }
        for r in table
        for when in ("before", "after")
    ]
    png = success_plot(
        bars, "policy", "pipeline", "reality", "worn robots, before and after the twin"
    )
    if png is not None:
        ctx.add_plot("twin_worn.png", png)
    return {
        "figures": figures,
        "tables": {"diagnoses": diag_rows, "before_after": table},
        "config": {"episodes": episodes, "quick": ctx.quick},
    }
