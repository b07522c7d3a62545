"""The ``realitygap`` command line.

``realitygap list`` shows environments, experiments and effects;
``realitygap run EXPERIMENT`` runs one experiment, prints its figures and
writes them as JSON.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import realitygap
from realitygap import experiments


def default_data_dir() -> Path | None:
    """``shared/data`` beside the checkout or the working directory, when present."""
    candidates = [
        Path.cwd() / "shared" / "data",
        Path.cwd().parent / "shared" / "data",
        Path(__file__).resolve().parents[1].parent / "shared" / "data",
    ]
    for cand in candidates:
        if cand.is_dir():
            return cand
    return None


def _cmd_list(args: argparse.Namespace) -> int:
    from realitygap.robots.effects import EFFECTS

    print("environments:")
    for env_id in realitygap.ENV_IDS:
        print(f"  {env_id}")
    print("experiments:")
    for name, exp in sorted(experiments.load_all().items()):
        print(f"  {name:<18} {exp.description}")
    print("effects:")
    for name, cls in sorted(EFFECTS.items()):
        params = ", ".join(f"{s.name} [{s.unit}]" for s in cls.specs)
        print(f"  {name:<22} ({cls.robot}) {params}")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    data = Path(args.data) if args.data else default_data_dir()
    if args.data and not Path(args.data).is_dir():
        print(f"error: --data {args.data!r} is not a folder", file=sys.stderr)
        return 2
    options: dict[str, object] = {}
    if args.robot is not None:
        try:
            spec = experiments.get(args.experiment)
        except KeyError as exc:
            print(f"error: {exc.args[0]}", file=sys.stderr)
            return 2
        if args.robot not in spec.robots:
            can = f"one of {', '.join(spec.robots)}" if spec.robots else "no --robot option"
            print(
                f"error: experiment {args.experiment!r} takes {can}, got --robot {args.robot!r}",
                file=sys.stderr,
            )
            return 2
        options["robot"] = args.robot
    ctx = experiments.RunContext(
        quick=args.quick, seed=args.seed, data_dir=data, verbose=not args.silent, options=options
    )
    try:
        result = experiments.run(args.experiment, ctx, json_path=args.json)
    except KeyError as exc:
        print(f"error: {exc.args[0]}", file=sys.stderr)
        return 2
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(experiments.format_figures(result))
    if args.json:
        print(f"wrote {args.json}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="realitygap", description=__doc__.splitlines()[0] if __doc__ else None
    )
    parser.add_argument(
        "--version", action="version", version=f"realitygap {realitygap.__version__}"
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p_list = sub.add_parser("list", help="list environments, experiments and effects")
    p_list.set_defaults(func=_cmd_list)

    p_run = sub.add_parser("run", help="run an experiment and print its figures")
    p_run.add_argument("experiment", help="experiment name (see `realitygap list`)")
    p_run.add_argument("--quick", action="store_true", help="a smaller, faster version")
    p_run.add_argument("--seed", type=int, default=0, help="base random seed (default 0)")
    p_run.add_argument(
        "--data", help="folder laid out like shared/data/ (default: shared/data when present)"
    )
    p_run.add_argument(
        "--robot", help="robot, for experiments that run for several (e.g. diagnose-suite)"
    )
    p_run.add_argument("--json", help="write the result as JSON to this path")
    p_run.add_argument("--silent", action="store_true", help="no progress output")
    p_run.set_defaults(func=_cmd_run)

    from realitygap.calibrate import add_calibrate_parser

    add_calibrate_parser(sub)

    from realitygap.diagnosis.cli import add_diagnose_parser

    add_diagnose_parser(sub)

    from realitygap.baselines.cli import add_benchmark_parser, add_train_parser

    add_benchmark_parser(sub)
    add_train_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
