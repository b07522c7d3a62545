"""Running the benchmark: the episode loop, task planning, result store, execution and the whole run."""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from realitygap.baselines.benchmark.config import BenchmarkConfig, episode_seeds, n_episodes
from realitygap.baselines.benchmark.policies import PolicySpec, build_policy
from realitygap.baselines.benchmark.profiles import (
    REALITY_PROFILES,
    env_sensor_mode,
    profile_robot,
    reality_for,
)
from realitygap.baselines.benchmark.report import markdown_report, plot_success
from realitygap.baselines.benchmark.stats import (
    METRICS,
    REACHED_RADIUS,
    extra_metrics,
    mode_gap_rows,
    record_key,
    summarise,
    transfer_rows,
)
from realitygap.baselines.rl import (
    env_slug,
    write_csv_atomic,
)
from realitygap.cards import ENV_CARDS
from realitygap.core import parallel
from realitygap.core.io import atomic_write_text

logger = logging.getLogger(__name__)

INSTALL_RAY = "pip install 'realitygap[ray]'"


# --------------------------------------------------------------------------- the episode loop
def run_episode(
    env: gym.Env[Any, Any],
    policy: Any,
    seed: int,
    deterministic: bool = True,
    pose_shape: tuple[int, ...] | None = None,
    on_step: Callable[[Mapping[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Run one seeded episode of ``policy`` through SB3's ``predict``; return its metrics.

    ``on_step`` is called with each step's ``info`` (e.g. to keep a trace of the episode).

    The policy is told the episode start (``episode_start``), and re-seeded with
    ``seed`` when it has a ``seed`` method (random policy), so an episode depends on
    ``seed`` only. The path length follows ``info["true_pose"]``, whose shape
    ``pose_shape`` is (default: the env card's ``info`` schema, see
    :class:`~realitygap.cards.EnvCard`): ``(3,)`` planar ``[x, y, θ]``, ``(7,)`` position
    and quaternion, ``(4, 4)`` a homogeneous transform. Without a known shape the path
    length is NaN.
    """
    if pose_shape is None:
        pose_shape = _pose_shape(env)
    if hasattr(policy, "seed") and callable(policy.seed):
        policy.seed(seed)
    obs, info = env.reset(seed=seed)
    dt = float(getattr(env.unwrapped, "dt", 1.0))
    state: Any = None
    start = True
    done = False
    steps = 0
    total_reward = 0.0
    compute = 0.0
    actions: list[npt.NDArray[np.float64]] = []
    path = 0.0
    prev_xy = _xy(info, pose_shape)
    best_before_collision = _float(info.get("pos_error"))
    collided = False
    success = False
    t_success = math.nan
    while not done:
        t0 = time.perf_counter()
        action, state = policy.predict(
            obs, state=state, episode_start=np.array([start]), deterministic=deterministic
        )
        compute += time.perf_counter() - t0
        start = False
        obs, reward, terminated, truncated, info = env.step(action)
        if on_step is not None:
            on_step(info)
        steps += 1
        done = bool(terminated or truncated)
        total_reward += float(reward)
        actions.append(np.asarray(action, dtype=np.float64).reshape(-1))
        xy = _xy(info, pose_shape)
        if xy is not None and prev_xy is not None:
            path += float(np.linalg.norm(xy - prev_xy))
        prev_xy = xy
        collided |= bool(info.get("collision", False) or info.get("detached", False))
        if not collided:
            best_before_collision = min(best_before_collision, _float(info.get("pos_error")))
        if info.get("is_success", False) and not success:
            success = True
            t_success = steps * dt
    a = np.asarray(actions) if actions else np.zeros((0, 1))
    effort = float(np.mean(np.sum(a * a, axis=1))) if len(a) else math.nan
    jerk = (
        float(np.mean(np.linalg.norm(np.diff(a, n=2, axis=0), axis=1))) / dt**2
        if len(a) > 2
        else math.nan
    )
    return {
        "seed": int(seed),
        "success": bool(success),
        "reached_10cm": (
            bool(best_before_collision <= REACHED_RADIUS)
            if math.isfinite(best_before_collision)
            else None
        ),
        "final_pos_error_cm": 100.0 * _float(info.get("pos_error")),
        "final_heading_deg": math.degrees(_float(info.get("heading_error"))),
        "path_length_m": path if prev_xy is not None else math.nan,
        "time_to_goal_s": t_success,
        "collision": bool(collided),
        "effort": effort,
        "jerk": jerk,
        "compute_ms": 1000.0 * compute / max(steps, 1),
        "steps": steps,
        "return": total_reward,
        "truncated": bool(not success and not collided),
        "final_info": {
            k: float(v)
            for k, v in info.items()
            if isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool)
        },
    }


def _pose_shape(env: gym.Env[Any, Any]) -> tuple[int, ...] | None:
    """Shape of ``info["true_pose"]`` declared by the env's card (``None`` without one)."""
    spec = getattr(env, "spec", None)
    card = ENV_CARDS.get(spec.id) if spec is not None else None
    if card is None or "true_pose" not in card.info:
        return None
    return card.info["true_pose"].shape


def _xy(
    info: Mapping[str, Any], pose_shape: tuple[int, ...] | None
) -> npt.NDArray[np.float64] | None:
    """Position from ``info["true_pose"]`` of the declared shape: ``[x, y, θ]`` → ``(x, y)``;
    ``[x, y, z, quaternion]`` → ``(x, y, z)``; a 4×4 transform → its translation."""
    pose = info.get("true_pose")
    if pose is None or pose_shape is None:
        return None
    arr = np.asarray(pose, dtype=float).reshape(pose_shape)
    if pose_shape == (3,):
        return arr[:2].copy()
    if pose_shape == (7,):
        return arr[:3].copy()
    if pose_shape == (4, 4):
        return arr[:3, 3].copy()
    return None


def _float(value: Any) -> float:
    return math.nan if value is None else float(value)


# --------------------------------------------------------------------------- tasks
@dataclass(frozen=True)
class ChunkTask:
    """Episodes of one cell for one worker (picklable)."""

    env_id: str
    env_kwargs: tuple[tuple[str, Any], ...]
    reality: str
    sensor_mode: str
    policy: PolicySpec
    seeds: tuple[int, ...]

    @property
    def cell(self) -> tuple[str, str, str, str]:
        return (self.env_id, self.policy.name, self.reality, self.sensor_mode)


def plan_tasks(
    cfg: BenchmarkConfig, done: set[tuple[str, str, str, str, int]] | None = None
) -> list[ChunkTask]:
    """Split the run into worker tasks, leaving out episodes already in ``done``."""
    done = done or set()
    tasks = []
    for env_id in cfg.env_ids:
        robot = ENV_CARDS[env_id].robot if env_id in ENV_CARDS else None
        kwargs = tuple(sorted(dict(cfg.env_kwargs.get(env_id, {})).items()))
        realities = ["nominal"] + [
            r for r in cfg.realities if r != "nominal" and profile_robot(r) in (None, robot)
        ]
        for mode in cfg.sensor_modes:
            n = n_episodes(cfg, env_id, mode)
            allowed = cfg.policies_by_mode.get(mode)
            for reality in realities:
                for pol in cfg.policies:
                    if allowed is not None and pol.name not in allowed:
                        continue
                    if pol.kind == "classical" and env_id not in ENV_CARDS:
                        continue
                    if pol.kind in ("ppo", "sac") and pol.path_for(env_id) is None:
                        continue  # no trained policy for this env (reported by the caller)
                    seeds = [
                        s
                        for s in episode_seeds(cfg, n)
                        if (env_id, pol.name, reality, mode, s) not in done
                    ]
                    for i in range(0, len(seeds), max(1, cfg.chunk)):
                        tasks.append(
                            ChunkTask(
                                env_id, kwargs, reality, mode, pol, tuple(seeds[i : i + cfg.chunk])
                            )
                        )
    return tasks


def _error_record(seed: int, exc: BaseException) -> dict[str, Any]:
    """The record of an episode that ended in an exception: failed, metrics unknown."""
    rec: dict[str, Any] = {m: math.nan for m in METRICS}
    rec.update(
        seed=int(seed),
        success=False,
        reached_10cm=None,
        collision=None,
        truncated=False,
        final_info={},
        error=f"{type(exc).__name__}: {exc}".strip(),
    )
    return rec


def run_chunk(task: ChunkTask) -> list[dict[str, Any]]:
    """Run one task's episodes (in any process); returns one record per episode."""
    return list(iter_chunk(task))


def iter_chunk(task: ChunkTask) -> Iterator[dict[str, Any]]:
    """Run one task's episodes, yielding each record as soon as its episode ends."""
    import realitygap  # noqa: F401  (registers the ids in a fresh worker)

    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    kwargs = dict(task.env_kwargs)
    reality = reality_for(task.env_id, task.reality)
    if reality is not None:
        kwargs["reality"] = reality
    env = gym.make(
        task.env_id, sensor_mode=env_sensor_mode(task.env_id, task.sensor_mode), **kwargs
    )
    extra = extra_metrics(task.env_id)
    try:
        policy = build_policy(
            task.policy, env, task.env_id, seed=task.seeds[0] if task.seeds else 0
        )
        for seed in task.seeds:
            t0 = time.perf_counter()
            try:
                record = run_episode(env, policy, seed)
            except Exception as exc:  # a crashing policy fails its episode, not the run
                record = _error_record(seed, exc)
                policy = build_policy(task.policy, env, task.env_id, seed=seed)
            record["wall_s"] = time.perf_counter() - t0
            final = record.pop("final_info")
            for key in extra:
                record[key] = final.get(key, math.nan)
            yield {
                "env_id": task.env_id,
                "policy": task.policy.name,
                "reality": task.reality,
                "sensor_mode": task.sensor_mode,
                **record,
            }
    finally:
        env.close()


# --------------------------------------------------------------------------- backends
RAY_MISSING = (
    f"--backend ray needs Ray, which is not installed: {INSTALL_RAY} (or use --backend local)"
)


def require_ray() -> Any:
    """Import Ray, or raise an ``ImportError`` with the install command."""
    return parallel.require_ray(RAY_MISSING)


class ResultStore:
    """Append-only JSON-lines store of finished episodes (flushed and fsynced per record)."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def load(self) -> list[dict[str, Any]]:
        """Every complete record; a torn last line (crash while writing) is ignored."""
        if not self.path.is_file():
            return []
        out = []
        for line in self.path.read_text(encoding="utf-8").splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        return out

    def append(self, records: Iterable[Mapping[str, Any]]) -> None:
        with self.path.open("a", encoding="utf-8") as fh:
            for rec in records:
                fh.write(json.dumps(_clean(rec), allow_nan=True) + "\n")
            fh.flush()
            os.fsync(fh.fileno())


def _clean(rec: Mapping[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in rec.items():
        if isinstance(v, (np.floating, np.integer, np.bool_)):
            v = v.item()
        out[k] = v
    return out


class Progress:
    """Progress lines (episodes done, rate, ETA) through :mod:`logging` at ``INFO``."""

    def __init__(self, total: int, every_s: float = 10.0, enabled: bool = True):
        self.total, self.done = total, 0
        self.every_s, self.enabled = every_s, enabled
        self.t0 = self.last = time.perf_counter()

    def update(self, n: int, label: str = "", force: bool = False) -> None:
        self.done += n
        now = time.perf_counter()
        if not self.enabled or (
            not force and now - self.last < self.every_s and self.done < self.total
        ):
            return
        self.last = now
        rate = self.done / max(now - self.t0, 1e-9)
        eta = (self.total - self.done) / max(rate, 1e-9)
        pct = 100.0 * self.done / max(self.total, 1)
        logger.info(
            f"[{time.strftime('%H:%M:%S')}] benchmark {self.done}/{self.total} episodes ({pct:.0f} %), "
            f"ETA {eta / 60:.1f} min {label}"
        )


def execute(
    tasks: Sequence[ChunkTask],
    store: ResultStore,
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    progress: Progress | None = None,
) -> list[str]:
    """Run ``tasks``, streaming each finished episode to ``store``. Returns error messages of
    tasks that failed (their finished episodes are kept)."""
    progress = progress or Progress(sum(len(t.seeds) for t in tasks), enabled=False)
    runner: parallel.Backend
    if backend == "local":
        if workers <= 1:
            return _execute_inline(tasks, store, progress)
        runner = parallel.ProcessBackend(workers, start_method="forkserver")
    elif backend == "ray":
        runner = parallel.RayBackend(address, missing=RAY_MISSING)
    else:
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    return _execute_streaming(runner, tasks, store, progress)


def _label(task: ChunkTask) -> str:
    return f"{env_slug(task.env_id)} {task.policy.name} {task.reality} {task.sensor_mode}"


def _execute_inline(
    tasks: Sequence[ChunkTask], store: ResultStore, progress: Progress
) -> list[str]:
    errors = []
    for task in tasks:
        try:
            for rec in iter_chunk(task):
                store.append([rec])
                progress.update(1, _label(task))
        except (ImportError, FileNotFoundError, ValueError):
            raise
        except Exception as exc:  # a failing episode must not lose the rest of the run
            errors.append(f"{_label(task)} seeds {task.seeds}: {type(exc).__name__}: {exc}")
    return errors


def _execute_streaming(
    runner: parallel.Backend, tasks: Sequence[ChunkTask], store: ResultStore, progress: Progress
) -> list[str]:
    """Run whole tasks on ``runner``; store each task's episodes as soon as it finishes."""
    from concurrent.futures.process import BrokenProcessPool

    errors: list[str] = []
    for outcome in runner.imap_unordered(run_chunk, tasks):
        task, exc = outcome.item, outcome.error
        if isinstance(exc, BrokenProcessPool):
            errors.append(f"{_label(task)} seeds {task.seeds}: worker crashed ({exc})")
        elif exc is not None:
            errors.append(f"{_label(task)} seeds {task.seeds}: {type(exc).__name__}: {exc}")
        else:
            records = outcome.value or []
            store.append(records)
            progress.update(len(records), _label(task))
    return errors


def check_run_options(backend: Any, workers: Any = None, address: Any = None) -> int:
    """The options of a benchmark run besides its :class:`BenchmarkConfig`, checked before
    any work: ``backend`` ``"local"`` or ``"ray"`` (Ray importable), ``workers`` a positive
    integer (local processes; only with ``"local"``, ``None`` for 1), ``address`` only with
    Ray. Returns ``workers``.

    Raises
    ------
    ValueError, TypeError
        Naming the option, what was expected, what came and the fix.
    ImportError
        ``backend="ray"`` without Ray (with the install command).
    """
    from realitygap.core.checks import check_int

    if backend not in ("local", "ray"):
        raise ValueError(
            f"--backend: backend must be 'local' or 'ray', got {backend!r}. Fix: "
            "--backend local (this machine) or --backend ray (a Ray cluster)"
        )
    if workers is not None and backend != "local":
        raise ValueError(
            f"--workers {workers} does nothing with --backend {backend}: it sets local worker "
            "processes, but Ray runs on the cluster's CPUs. Fix: drop --workers, or use "
            "--backend local"
        )
    workers = 1 if workers is None else workers
    workers = check_int(workers, "--workers (workers)", low=1, what="a positive integer")
    if address is not None:
        if not isinstance(address, str) or not address.strip():
            raise ValueError(
                f"--address (address) must be a Ray cluster address such as ray://head:10001 "
                f"or auto, got {address!r}"
            )
        if backend != "ray":
            raise ValueError(
                f"--address {address} is a Ray cluster's address, but --backend is {backend!r}, "
                "which runs on this machine. Fix: add --backend ray, or drop --address"
            )
    if backend == "ray":
        require_ray()  # fail before any work with the install hint
    return workers


# --------------------------------------------------------------------------- the whole run
@dataclass(frozen=True)
class BenchmarkResult:
    """Paths and tables of a finished benchmark."""

    out_dir: Path
    summary: list[dict[str, Any]]
    transfer: list[dict[str, Any]]
    errors: list[str]
    files: dict[str, Path]
    wall_seconds: float
    surrogate: list[dict[str, Any]] = field(default_factory=list)
    """Surrogate → PyBullet rows (:func:`~realitygap.baselines.benchmark.vector.surrogate_transfer_rows`)."""
    mode_gap: list[dict[str, Any]] = field(default_factory=list)
    """Fast next to image mode (:func:`~realitygap.baselines.benchmark.stats.mode_gap_rows`)."""


def run_benchmark(
    cfg: BenchmarkConfig,
    out_dir: str | os.PathLike[str],
    backend: str = "local",
    workers: int | None = None,
    address: str | None = None,
    resume: bool = True,
    verbose: bool = True,
    learning_curves: Sequence[tuple[str, Path | None, Path | None]] = (),
    notes: Sequence[str] = (),
) -> BenchmarkResult:
    """Run the benchmark described by ``cfg`` and write its tables and plots to ``out_dir``.

    Files: ``episodes.jsonl`` (streamed), ``summary.csv``, ``transfer.csv``,
    ``surrogate_transfer.csv`` (learned WheeledNav policies: success in the vectorised
    surrogate next to PyBullet), ``mode_gap.csv`` (cells run in both sensor modes: fast next to
    image, the gap with its interval), ``benchmark.md``, ``success.png``,
    ``learning_curves.png`` (when curves are given), ``config.json``.
    """
    t0 = time.perf_counter()
    if not isinstance(cfg, BenchmarkConfig):
        raise TypeError(f"cfg must be a BenchmarkConfig, got {type(cfg).__name__}")
    # the config checked its fields when it was made; the run's options before any work
    workers = check_run_options(backend, workers, address)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    store = ResultStore(out / "episodes.jsonl")
    if not resume and store.path.exists():
        store.path.unlink()
    config_json = {
        **{k: v for k, v in asdict(cfg).items() if k != "policies"},
        "policies": [asdict(p) for p in cfg.policies],
        "episode_seeds": "1000 * seed + k",
        "backend": backend,
    }
    atomic_write_text(out / "config.json", json.dumps(config_json, indent=2, default=str) + "\n")
    done = {record_key(r) for r in store.load()}
    tasks = plan_tasks(cfg, done)
    n_total = sum(len(t.seeds) for t in tasks)
    progress = Progress(n_total, enabled=verbose)
    if verbose:
        logger.info(
            f"[{time.strftime('%H:%M:%S')}] benchmark: {n_total} episodes in {len(tasks)} tasks "
            f"({len(done)} already done) on backend {backend} -> {out}"
        )
    errors = execute(tasks, store, backend, workers, address, progress)
    wanted = {(t.cell) for t in plan_tasks(cfg)}
    records = [r for r in store.load() if record_key(r)[:4] in wanted]
    summary = summarise(records)
    transfer = transfer_rows(summary)
    mode_gap = mode_gap_rows(summary)
    from realitygap.baselines.benchmark.vector import surrogate_transfer_rows

    all_notes = list(notes)
    surrogate = surrogate_transfer_rows(cfg, summary, all_notes)
    files = {
        "episodes": store.path,
        "summary_csv": out / "summary.csv",
        "transfer_csv": out / "transfer.csv",
        "markdown": out / "benchmark.md",
    }
    write_csv_atomic(files["summary_csv"], summary)
    write_csv_atomic(files["transfer_csv"], transfer)
    if surrogate:
        files["surrogate_transfer_csv"] = out / "surrogate_transfer.csv"
        write_csv_atomic(files["surrogate_transfer_csv"], surrogate)
    if mode_gap:
        files["mode_gap_csv"] = out / "mode_gap.csv"
        write_csv_atomic(files["mode_gap_csv"], mode_gap)
    all_notes += [f"failed task: {e}" for e in errors]
    crashed: dict[tuple[str, ...], list[Mapping[str, Any]]] = {}
    for rec in records:
        if rec.get("error"):
            crashed.setdefault(record_key(rec)[:4], []).append(rec)
    for (env_id, pol, reality, mode), recs in sorted(crashed.items()):
        seeds = ", ".join(str(x["seed"]) for x in recs)
        all_notes.append(
            f"{env_slug(env_id)} {pol} {reality} {mode}: {len(recs)} episode(s) ended in an "
            f"exception, counted as failures (seeds {seeds}; first: {recs[0]['error']})"
        )
    for name in cfg.realities:
        if name in REALITY_PROFILES:
            all_notes.append(f"reality `{name}`: {REALITY_PROFILES[name]['description']}")
    atomic_write_text(
        files["markdown"],
        markdown_report(summary, transfer, all_notes, surrogate=surrogate, mode_gap=mode_gap),
    )
    png = plot_success(summary, out / "success.png")
    if png is not None:
        files["success_png"] = png
    if learning_curves:
        from realitygap.baselines.rl import plot_learning_curves

        lc = plot_learning_curves(learning_curves, out / "learning_curves.png")
        if lc is not None:
            files["learning_curves_png"] = lc
    return BenchmarkResult(
        out, summary, transfer, errors, files, time.perf_counter() - t0, surrogate, mode_gap
    )
