"""``realitygap benchmark`` and ``realitygap train``: parsers and commands.

The main CLI adds them with::

    from realitygap.baselines.cli import add_benchmark_parser, add_train_parser

    add_benchmark_parser(sub)
    add_train_parser(sub)

Each sets ``func`` on its sub-parser to a command returning an exit code.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path
from typing import Any

from realitygap.core.checks import int_option
from realitygap.core.outputs import Outputs, command_line
from realitygap.core.parallel import cap_workers

DEFAULT_EVAL_EVERY = 50_000
"""``--eval-every`` when not given (a shorter budget just has no evaluation before the end)."""
DEFAULT_CHECKPOINT_EVERY = 100_000
"""``--checkpoint-every`` when not given."""


def show_progress(logger_name: str, stream: Any) -> None:
    """Print the ``INFO`` lines of logger ``logger_name`` (training or benchmark progress)
    on ``stream`` as bare messages; calling it again adds no second handler."""
    log = logging.getLogger(logger_name)
    if not any(getattr(h, "realitygap_progress", False) for h in log.handlers):
        handler = logging.StreamHandler(stream)
        handler.setFormatter(logging.Formatter("%(message)s"))
        handler.realitygap_progress = True  # type: ignore[attr-defined]
        log.addHandler(handler)
    log.setLevel(logging.INFO)


def _csv_list(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def add_benchmark_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``benchmark`` to ``subparsers`` (from ``ArgumentParser.add_subparsers``)."""
    p = subparsers.add_parser(
        "benchmark",
        help="every policy on identical seeded episodes, nominal and under a reality profile",
        description=(
            "Run classical, learned and random policies on identical seeded episodes of each "
            "environment, on the nominal robot and under a reality profile; write a Markdown "
            "and CSV table, plots and the streamed episodes."
        ),
    )
    p.add_argument("--envs", default="all", help="comma-separated env ids (default: all)")
    p.add_argument(
        "--policies",
        default="classical,ppo,sac,random",
        help="comma-separated: classical, ppo, sac, random, or name=path/to/model.zip",
    )
    p.add_argument(
        "--episodes", type=int_option(1), default=50, help="episodes per cell (default 50)"
    )
    p.add_argument(
        "--image-episodes",
        type=int_option(1),
        default=10,
        help="episodes per cell in image sensor mode, which renders and is ~50x slower "
        "(default 10)",
    )
    p.add_argument(
        "--reality",
        default=None,
        help="reality profile(s) besides nominal, comma-separated (each applies to the envs of "
        "its robot), or a Reality JSON file (default: the worn profile of each robot; 'none' "
        "for nominal only)",
    )
    p.add_argument(
        "--estimator-reality",
        default=None,
        help="a reality profile or file whose effects the envs' default estimators include "
        "(a diagnosis's twin calibrates the odometry); applies to the envs that take it",
    )
    p.add_argument(
        "--sensor-modes", default="fast,image", help="fast and/or image (default fast,image)"
    )
    p.add_argument(
        "--seed", type=int_option(0), default=0, help="episode k uses env seed 1000*seed + k"
    )
    p.add_argument("--out", default="runs/benchmark", help="output folder (default runs/benchmark)")
    p.add_argument("--backend", choices=("local", "ray"), default="local")
    p.add_argument("--address", default=None, help="Ray cluster address (default: a local one)")
    p.add_argument(
        "--workers",
        type=int_option(1),
        default=None,
        help="local worker processes (default 1: in-process; --backend local only)",
    )
    p.add_argument("--fresh", action="store_true", help="discard finished episodes in --out")
    p.add_argument(
        "--train",
        action="store_true",
        help="train the ppo/sac policies first (deterministic, hyperparameter files) instead "
        "of loading the shipped ones",
    )
    p.add_argument(
        "--train-timesteps",
        type=int_option(1),
        default=None,
        help="training budget with --train (default: files)",
    )
    p.add_argument(
        "--train-seeds",
        default=None,
        help="training seeds with --train, comma-separated (default 0)",
    )
    p.add_argument("--silent", action="store_true", help="no progress output")
    p.set_defaults(func=cmd_benchmark)
    return p


def add_train_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``train`` to ``subparsers``."""
    p = subparsers.add_parser(
        "train",
        help="train a PPO or SAC baseline (stable-baselines3) with the hyperparameter files",
    )
    p.add_argument("--env", default="realitygap/WheeledNav-v0", help="env id")
    p.add_argument("--algo", choices=("ppo", "sac"), default="ppo")
    p.add_argument("--seed", type=int_option(0), default=0)
    p.add_argument("--timesteps", type=int_option(1), default=None, help="budget (default: file)")
    p.add_argument(
        "--n-envs", type=int_option(1), default=None, help="parallel envs (default: file)"
    )
    p.add_argument(
        "--vec-env", choices=("subproc", "dummy"), default=None, help="default: the file's"
    )
    p.add_argument("--hyperparams", default=None, help="another hyperparameter JSON file")
    p.add_argument(
        "--vector",
        action="store_true",
        help=(
            "train on the env's vectorised surrogate (WheeledNav: realitygap/WheeledNavVec-v0, "
            "--n-envs robots per batched step; same as --env realitygap/WheeledNavVec-v0); "
            "evaluations run in PyBullet"
        ),
    )
    p.add_argument(
        "--reality",
        default=None,
        help="train on this robot: a reality profile or a reality file (e.g. a diagnosis's "
        "--export) instead of the nominal one",
    )
    p.add_argument(
        "--randomize",
        action="store_true",
        help="draw each episode's robot from the --reality file's uncertainty (a domain "
        "randomisation centred on the diagnosis)",
    )
    p.add_argument(
        "--estimator-reality",
        default=None,
        help="a reality profile or file whose effects the env's default estimator includes "
        "(a twin's calibrated odometry; WheeledNav)",
    )
    p.add_argument("--out", default=None, help="folder (default runs/train/<env>/<algo>/seed<k>)")
    p.add_argument(
        "--init-model",
        default=None,
        help=(
            "continue training this saved model.zip (a long run split into shorter ones), "
            "or a PPO policy's exported weights (.pth + .json, e.g. a shipped policy)"
        ),
    )
    p.add_argument(
        "--eval-every",
        type=int_option(1),
        default=None,
        help=f"steps between evaluations (default {DEFAULT_EVAL_EVERY}; at most --timesteps)",
    )
    p.add_argument(
        "--checkpoint-every",
        type=int_option(0),
        default=None,
        help=f"steps between checkpoints (0: none; default {DEFAULT_CHECKPOINT_EVERY})",
    )
    p.add_argument("--eval-episodes", type=int_option(1), default=20)
    p.add_argument(
        "--ship",
        action="store_true",
        help="copy the trained policy and its curves into the package's baselines/policies/ "
        "(with --vector as <env>_<algo>_vector, beside the PyBullet-trained one)",
    )
    p.set_defaults(func=cmd_train)
    return p


# --------------------------------------------------------------------------- commands
def _error(exc: BaseException) -> int:
    print(f"error: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
    return 2


def _warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr, flush=True)


def train_config_from_args(args: argparse.Namespace) -> tuple[Any, Any]:
    """The checked :class:`~realitygap.baselines.rl.TrainConfig` of ``realitygap train`` and
    its :class:`~realitygap.baselines.rl.checks.TrainPlan`: every option, the hyperparameter
    file, the model to continue and the cost of the envs checked, nothing started.

    Raises
    ------
    ValueError, TypeError, KeyError, FileNotFoundError, ImportError
        A bad option, naming it.
    """
    from realitygap.baselines import rl
    from realitygap.baselines.benchmark import profiles as bm_profiles
    from realitygap.baselines.rl.checks import check_training

    vector = bool(getattr(args, "vector", False))
    by_vector = {v: k for k, v in rl.VECTOR_ENVS.items()}
    env_arg = by_vector.get(args.env, by_vector.get(f"realitygap/{args.env}", args.env))
    vector = vector or env_arg != args.env
    env_id = rl.check_env_id(env_arg)
    hp_id = rl.vector_env_id(env_id) if vector else env_id
    hp = rl.load_hyperparams(args.algo, hp_id, args.hyperparams)
    sim = bm_profiles.simulator_kwargs(env_id, args.reality, args.randomize, args.estimator_reality)
    if sim:  # the simulator to train on: the evaluations' env and the vector env alike
        hp = {**hp, "env_kwargs": {**dict(hp.get("env_kwargs", {}) or {}), **sim}}
    rl.require_sb3()
    out = (
        Path(args.out)
        if args.out
        else Path("runs") / "train" / rl.env_slug(hp_id) / args.algo / f"seed{args.seed}"
    )
    cfg = rl.TrainConfig(
        env_id=env_id,
        algo=args.algo,
        out_dir=out,
        seed=args.seed,
        total_timesteps=args.timesteps,
        n_envs=args.n_envs,
        vec_env=args.vec_env,
        hyperparams=hp,
        eval_every=DEFAULT_EVAL_EVERY if args.eval_every is None else args.eval_every,
        checkpoint_every=(
            DEFAULT_CHECKPOINT_EVERY if args.checkpoint_every is None else args.checkpoint_every
        ),
        eval_episodes=args.eval_episodes,
        init_model=Path(args.init_model) if args.init_model is not None else None,
        vector=vector,
    )
    explicit = [
        name
        for name, given in (
            ("eval_every", args.eval_every is not None),
            ("checkpoint_every", args.checkpoint_every is not None),
        )
        if given
    ]
    return cfg, check_training(cfg, explicit=explicit, warn=_warn)


def cmd_train(args: argparse.Namespace) -> int:
    from realitygap.baselines import rl

    try:
        cfg, _ = train_config_from_args(args)  # every input, before any work
    except (ValueError, TypeError, KeyError, FileNotFoundError, ImportError) as exc:
        return _error(exc)
    outputs = Outputs(overwrite=args.overwrite, command=command_line())
    try:
        outputs.workdir(cfg.out_dir, "--out")
    except ValueError as exc:
        return _error(exc)
    with outputs:
        return _train(args, rl, cfg)


def _train(args: argparse.Namespace, rl: Any, cfg: Any) -> int:
    show_progress("realitygap.baselines.rl", sys.stdout)
    try:
        result = rl.train(cfg)
    except (ValueError, FileNotFoundError) as exc:
        return _error(exc)
    print(f"model: {result.model_path}\nwall-clock: {result.wall_seconds / 60:.1f} min")
    for key, value in result.final_eval.items():
        print(f"final eval {key}: {value:.3f}")
    if args.ship:
        dest = rl.ship_policy(cfg.out_dir, cfg.env_id, cfg.algo, "vector" if cfg.vector else None)
        print(f"shipped: {dest}")
    return 0


DEFAULT_REALITIES = ("kobuki-worn", "arm-worn", "climber-worn")
"""``--reality`` when not given: of these, the profiles for the requested envs' robots."""


def benchmark_config_from_args(args: argparse.Namespace) -> tuple[Any, dict[str, Any]]:
    """The checked :class:`~realitygap.baselines.benchmark.BenchmarkConfig` of
    ``realitygap benchmark`` (policies as given: shipped files not yet filled in) and the
    run's other options, checked: ``backend``, ``workers``, ``address``, and with
    ``--train`` the seeds and every training run (:func:`plan_training_jobs`).

    Raises
    ------
    ValueError, TypeError, FileNotFoundError, ImportError
        A bad option, naming it.
    """
    import realitygap
    from realitygap.baselines import benchmark as bm
    from realitygap.baselines.rl.checks import check_seed_list

    envs = args.envs.strip()
    env_ids = list(realitygap.ENV_IDS) if envs == "all" else _csv_list(envs)
    if args.reality is None:  # the default: the worn profile of each requested env's robot
        from realitygap.baselines.rl import check_env_id

        ids = []
        for e in env_ids:
            try:
                ids.append(check_env_id(e))
            except ValueError:
                pass  # refused by the config check below, naming --envs
        realities = list(bm.default_realities(ids, DEFAULT_REALITIES))
    else:
        reality = args.reality.strip()
        realities = [] if reality in ("none", "") else _csv_list(reality)
    workers = bm.check_run_options(args.backend, args.workers, args.address)
    if not args.train:
        for option, value in (
            ("--train-seeds", args.train_seeds),
            ("--train-timesteps", args.train_timesteps),
        ):
            if value is not None:
                raise ValueError(
                    f"{option} {value} is a setting of --train, which is not given: nothing is "
                    f"trained. Fix: add --train, or drop {option}"
                )
    seeds = check_seed_list("0" if args.train_seeds is None else args.train_seeds)
    env_kwargs: dict[str, dict[str, Any]] = {}
    if args.estimator_reality is not None:
        import gymnasium as gym

        from realitygap.baselines.benchmark.profiles import simulator_kwargs

        takers = [
            e for e in env_ids if e in gym.registry and "estimator_reality" in bm.env_keywords(e)
        ]
        if not takers:
            raise ValueError(
                f"--estimator-reality: none of the requested envs ({', '.join(env_ids)}) has "
                "an estimator that takes a reality. Fix: add realitygap/WheeledNav-v0 to "
                "--envs, or drop --estimator-reality"
            )
        for e in takers:
            env_kwargs[e] = simulator_kwargs(e, estimator_reality=args.estimator_reality)
    cfg = bm.BenchmarkConfig(
        env_ids=tuple(env_ids),
        env_kwargs=env_kwargs,
        policies=tuple(bm.parse_policies(args.policies)),
        episodes=args.episodes,
        realities=tuple(realities),
        sensor_modes=tuple(_csv_list(args.sensor_modes)),
        seed=args.seed,
        episode_counts={"image": args.image_episodes} if args.image_episodes is not None else {},
    )
    run = {"workers": workers, "seeds": seeds, "jobs": []}
    if args.train:
        jobs, notes = plan_training_jobs(
            cfg.policies, list(cfg.env_ids), seeds, args.train_timesteps, Path(args.out) / "train"
        )
        if not jobs:
            raise ValueError(
                "--train trains the ppo and sac policies, but "
                + (
                    "--policies names neither"
                    if not any(p.kind in ("ppo", "sac") for p in cfg.policies)
                    else "no env of --envs has hyperparameters for them"
                )
                + ". Fix: add ppo and/or sac to --policies, or drop --train"
            )
        run["jobs"] = jobs
        run["notes"] = notes
    return cfg, run


def cmd_benchmark(args: argparse.Namespace) -> int:
    from realitygap.baselines import benchmark as bm

    try:
        cfg, run = benchmark_config_from_args(args)  # every input, before any work
    except (ValueError, TypeError, FileNotFoundError, ImportError) as exc:
        return _error(exc)
    outputs = Outputs(overwrite=args.overwrite, command=command_line())
    try:
        outputs.workdir(args.out, "--out")
        args.workers = cap_workers(run["workers"], "--workers", _warn)
    except ValueError as exc:
        return _error(exc)
    with outputs:
        return _benchmark(args, bm, cfg, run)


def _benchmark(args: argparse.Namespace, bm: Any, cfg: Any, run: dict[str, Any]) -> int:
    import dataclasses

    try:
        policies: list[Any] = list(cfg.policies)
        env_ids = list(cfg.env_ids)
        curves: list[tuple[str, Path | None, Path | None]] = []
        if args.train:
            for note in run.get("notes", []):
                print(f"note: {note}", file=sys.stderr)
            policies, curves = train_for_benchmark(
                policies,
                env_ids,
                seeds=run["seeds"],
                timesteps=args.train_timesteps,
                out_dir=Path(args.out) / "train",
                backend=args.backend,
                address=args.address,
            )
        notes: list[str] = []
        policies = bm.resolve_learned_paths(policies, env_ids, notes)
        for note in notes:
            print(f"note: {note}", file=sys.stderr)
        if not args.train:
            curves = shipped_curves(policies, env_ids)
        if not policies:
            raise ValueError(
                "--policies: no policy is left to run (see the notes above). Fix: add "
                "classical or random, or train the learned ones with --train"
            )
        cfg = dataclasses.replace(cfg, policies=tuple(policies))
        if not args.silent:
            show_progress("realitygap.baselines.benchmark", sys.stderr)
        result = bm.run_benchmark(
            cfg,
            args.out,
            backend=args.backend,
            workers=args.workers if args.backend == "local" else None,
            address=args.address,
            resume=not args.fresh,
            verbose=not args.silent,
            learning_curves=curves,
            notes=notes,
        )
    except (ValueError, FileNotFoundError, ImportError) as exc:
        return _error(exc)
    print(result.files["markdown"].read_text(encoding="utf-8"))
    for name, path in result.files.items():
        print(f"wrote {name}: {path}")
    if result.errors:
        print(f"{len(result.errors)} task(s) failed; re-run the same command to retry them")
        return 1
    return 0


def shipped_curves(policies: Any, env_ids: list[str]) -> list[tuple[str, Path | None, Path | None]]:
    """Learning-curve files shipped beside the learned policies."""
    out = []
    for spec in policies:
        for env_id in env_ids:
            path = spec.path_for(env_id)
            if path is None:
                continue
            ep = path.with_suffix(".episodes.csv")
            ev = path.with_suffix(".eval.csv")
            if ep.is_file() or ev.is_file():
                out.append(
                    (
                        f"{spec.name} {env_id.split('/')[-1]}",
                        ep if ep.is_file() else None,
                        ev if ev.is_file() else None,
                    )
                )
    return out


def train_for_benchmark(
    policies: Any,
    env_ids: list[str],
    seeds: list[int],
    timesteps: int | None,
    out_dir: Path,
    backend: str = "local",
    address: str | None = None,
) -> tuple[list[Any], list[tuple[str, Path | None, Path | None]]]:
    """Train every ``ppo``/``sac`` policy for every env and seed; return specs pointing at the
    new files (one policy per seed, named ``ppo/s<seed>`` when there are several)."""
    from realitygap.baselines import rl
    from realitygap.baselines.benchmark import PolicySpec

    jobs, notes = plan_training_jobs(policies, env_ids, seeds, timesteps, out_dir)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    results = run_training_jobs(jobs, backend, address)
    new_specs: list[Any] = []
    curves = []
    for spec in policies:
        if spec.kind not in ("ppo", "sac"):
            new_specs.append(spec)
            continue
        for seed in seeds:
            paths = tuple(
                (cfg.env_id, str(res.model_path))
                for cfg, res in zip(jobs, results)
                if res is not None and cfg.algo == spec.kind and cfg.seed == seed
            )
            if not paths:
                continue
            name = spec.name if len(seeds) == 1 else f"{spec.name}/s{seed}"
            new_specs.append(PolicySpec(name, spec.kind, paths))
    for cfg, res in zip(jobs, results):
        if res is None:
            continue
        curves.append(
            rl.learning_curve_files(
                res.model_path.parent, f"{cfg.algo} {rl.env_slug(cfg.env_id)} s{cfg.seed}"
            )
        )
    return new_specs, curves


def plan_training_jobs(
    policies: Any,
    env_ids: list[str],
    seeds: list[int],
    timesteps: int | None,
    out_dir: Path,
) -> tuple[list[Any], list[str]]:
    """The training runs of ``benchmark --train``, each checked
    (:func:`~realitygap.baselines.rl.checks.check_training`) before any starts: one
    :class:`~realitygap.baselines.rl.TrainConfig` per ``ppo``/``sac`` policy, env with
    hyperparameters, and seed. Returns them and notes on envs without hyperparameters."""
    from realitygap.baselines import rl
    from realitygap.baselines.rl.checks import check_training

    jobs: list[Any] = []
    notes: list[str] = []
    for spec in policies:
        if spec.kind not in ("ppo", "sac"):
            continue
        for env_id in env_ids:
            try:
                rl.load_hyperparams(spec.kind, env_id)
            except KeyError:
                notes.append(f"no {spec.kind} hyperparameters for {env_id}; not trained")
                continue
            for seed in seeds:
                cfg = rl.TrainConfig(
                    env_id=env_id,
                    algo=spec.kind,
                    seed=seed,
                    total_timesteps=timesteps,
                    out_dir=out_dir / rl.env_slug(env_id) / spec.kind / f"seed{seed}",
                )
                check_training(cfg, warn=_warn)
                jobs.append(cfg)
    return jobs, notes


def run_training_jobs(
    jobs: list[Any], backend: str = "local", address: str | None = None
) -> list[Any]:
    """Run training configs in this process one after another, or as Ray tasks (each asks
    for two CPUs: its vectorised env). A failed run is reported and left out (``None``)."""
    from realitygap.baselines import rl

    if backend != "ray":
        show_progress("realitygap.baselines.rl", sys.stdout)
        return [rl.train(cfg) for cfg in jobs]
    from realitygap.baselines.benchmark import RAY_MISSING
    from realitygap.core.parallel import RayBackend

    # each run asks for two CPUs (its vectorised env); Ray's default retries; worker output shown
    runner = RayBackend(
        address, missing=RAY_MISSING, task_options={"num_cpus": 2}, log_to_driver=True
    )
    t0 = time.perf_counter()
    outcomes = sorted(runner.imap_unordered(rl.train, jobs), key=lambda o: o.index)
    results: list[Any] = []
    for outcome in outcomes:
        cfg = outcome.item
        if outcome.error is not None:  # RayTaskError, WorkerCrashedError, …
            print(
                f"error: training {cfg.algo} on {cfg.env_id} seed {cfg.seed} failed: "
                f"{outcome.error}",
                file=sys.stderr,
            )
        results.append(outcome.value)
    print(
        f"trained {sum(r is not None for r in results)}/{len(jobs)} policies on Ray in "
        f"{(time.perf_counter() - t0) / 60:.1f} min",
        file=sys.stderr,
    )
    return results
