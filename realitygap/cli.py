"""The ``realitygap`` command line.

``realitygap list`` shows environments, experiments and effects;
``realitygap run EXPERIMENT`` runs one experiment, prints its figures and
writes them as JSON; an experiment that diagnoses a sim-to-real gap also
writes a report (``report.html`` with its figures embedded). Every sub-command
takes ``--quiet`` and ``--verbose``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import time
from pathlib import Path

import realitygap
from realitygap import experiments
from realitygap.core.checks import set_path_types
from realitygap.core.io import write_json
from realitygap.core.outputs import Outputs, command_line
from realitygap.core.parallel import cap_workers
from realitygap.core.progress import Countdown, duration_words


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


DESCRIPTION = (
    "realitygap: Gymnasium robot environments on PyBullet and a tool that diagnoses the "
    "sim-to-real gap of a real robot from its recorded runs."
)
EPILOG = """\
the main job (a real differential drive; an embedded sample unless --data DIR is given):
  realitygap run diagnose-real

your own robot's logs:
  realitygap diagnose LOG... --holdout LOG... --report out/
"""


def _cmd_list(args: argparse.Namespace) -> int:
    from realitygap.robots.effects import EFFECTS

    print("environments:")
    for env_id in realitygap.ENV_IDS:
        print(f"  {env_id}")
    print("experiments:")
    for name, exp in sorted(experiments.load_all().items()):
        print(f"  {name}" if args.quiet else f"  {name:<18} {exp.description}")
    print("effects:")
    for name, cls in sorted(EFFECTS.items()):
        params = ", ".join(f"{s.name} [{s.unit}]" for s in cls.specs)
        print(f"  {name}" if args.quiet else f"  {name:<22} ({cls.robot}) {params}")
        if args.verbose:
            print(f"      {cls.description}")
    return 0


class _TimedContext(experiments.RunContext):
    """A run context whose progress lines show the elapsed time and the time left, against
    the duration of the last run of the same experiment with the same options."""

    clock: Countdown | None = None
    details: bool = False
    """Show indented detail lines (one per transient event, …) too (``--verbose``)."""

    def expect(self, seconds: float) -> None:
        if self.clock is not None and not math.isfinite(self.clock.estimate_s):
            self.clock.estimate_s = self.clock.elapsed_s() + float(seconds)
        super().expect(seconds)

    def progress(self, message: str) -> None:
        if self.verbose and (self.details or not message.startswith("  ")):
            prefix = self.clock.prefix() if self.clock is not None else ""
            print(f"{prefix} {message}".strip(), file=sys.stderr, flush=True)


def _history_path() -> Path:
    from realitygap.samples import cache_root

    return cache_root() / "run-times.json"


def _last_duration(key: str) -> float | None:
    try:
        data = json.loads(_history_path().read_text(encoding="utf-8"))
        value = float(data[key])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return value if math.isfinite(value) and value > 0 else None


def _remember_duration(key: str, seconds: float) -> None:
    from realitygap.core.io import atomic_write_text

    path = _history_path()
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(data, dict):
            data = {}
    except (OSError, ValueError):
        data = {}
    data[key] = round(float(seconds), 1)
    try:
        atomic_write_text(path, json.dumps(data, indent=1, sort_keys=True) + "\n")
    except OSError:  # a read-only cache only costs the next estimate
        pass


def _cmd_run(args: argparse.Namespace) -> int:
    data = Path(args.data) if args.data else default_data_dir()
    if args.data and not Path(args.data).is_dir():
        print(f"error: --data {args.data!r} is not a folder", file=sys.stderr)
        return 2
    options: dict[str, object] = {}
    # options an experiment declares it takes (``Experiment.robots`` / ``.variants``)
    declared = {"robot": "robots", "variant": "variants"}
    given = {o: getattr(args, o) for o in declared if getattr(args, o) is not None}
    if given:
        try:
            spec = experiments.get(args.experiment)
        except KeyError as exc:
            print(f"error: {exc.args[0]}", file=sys.stderr)
            return 2
    for option, value in given.items():
        choices = getattr(spec, declared[option])
        if value not in choices:
            can = f"one of {', '.join(choices)}" if choices else f"no --{option} option"
            print(
                f"error: experiment {args.experiment!r} takes {can}, got --{option} {value!r}",
                file=sys.stderr,
            )
            return 2
        options[option] = value
    if args.backend is not None:
        options["backend"] = args.backend
    if args.workers is not None:
        if args.workers < 1:
            print(
                f"error: --workers must be a positive integer, got {args.workers}", file=sys.stderr
            )
            return 2
        options["workers"] = cap_workers(
            args.workers, "--workers", lambda m: print(f"warning: {m}", file=sys.stderr)
        )
    ctx = _TimedContext(
        quick=args.quick, seed=args.seed, data_dir=data, verbose=not args.silent, options=options
    )
    key = json.dumps([args.experiment, args.quick, str(data), options], sort_keys=True, default=str)
    last = _last_duration(key)
    ctx.clock = Countdown(last if last is not None else math.nan)
    ctx.details = bool(args.verbose)
    if last is not None and last > 30:
        ctx.progress(
            f"{args.experiment}: the last run with these options took {duration_words(last)}"
        )
    report_dir = args.report
    if report_dir is None:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        report_dir = str(Path("realitygap-reports") / f"{args.experiment}-{stamp}")
    inputs = [data] if args.data else []
    with Outputs(inputs=inputs, overwrite=args.overwrite, command=command_line()) as out:
        try:
            json_stage = out.file(args.json, "--json") if args.json else None
            report_stage = out.folder(report_dir, "--report")
            result = experiments.run(args.experiment, ctx, report_dir=report_stage)
        except KeyError as exc:
            print(f"error: {exc.args[0]}", file=sys.stderr)
            return 2
        except (FileNotFoundError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        if "report" in result:
            result["report"] = str(Path(report_dir) / Path(result["report"]).name)
        else:
            _remove_empty(report_stage)
        if json_stage is not None:
            write_json(json_stage, result)
        out.commit()
    _remember_duration(key, float(result["wall_seconds"]))
    # with --json - standard output holds the JSON; the words go to standard error
    words = contextlib.redirect_stdout(sys.stderr) if args.json == "-" else contextlib.nullcontext()
    with words:
        _print_diagnoses(ctx, verbose=args.verbose)
        print(experiments.format_figures(result))
        if args.verbose:
            for name, rows in result.get("tables", {}).items():
                print(f"table {name}:")
                for row in rows:
                    print(f"  {row}")
        if args.json and args.json != "-":
            print(f"wrote {args.json}")
        if "report" in result:
            print(f"report: {Path(result['report']).resolve()}")
        elif args.report is not None:
            print(f"note: {args.experiment} makes no diagnosis, so --report wrote nothing")
    return 0


def _remove_empty(stage: Path) -> None:
    """An experiment that made no diagnosis writes no report: its staged folder, still
    empty, is not put in place."""
    if stage.is_dir() and not any(stage.iterdir()):
        stage.rmdir()


def _cmd_sample(args: argparse.Namespace) -> int:
    from realitygap.samples import SAMPLES, sample_dir

    try:
        path = sample_dir(args.name, persistent=True)
    except (KeyError, ValueError) as exc:
        print(f"error: {exc.args[0]}", file=sys.stderr)
        return 2
    if args.verbose:
        print(f"{args.name}: {SAMPLES[args.name]}", file=sys.stderr)
    print(path)
    return 0


def _print_diagnoses(ctx: experiments.RunContext, verbose: bool) -> None:
    """Words before numbers: each diagnosis of the run in sentences, before the figures."""
    if not ctx.diagnoses:
        return
    from realitygap.diagnosis.cli import print_result

    for label, d in ctx.diagnoses:
        if label:
            print(f"{label}:")
        print_result(d, verbose=verbose)
        print()


HELP_WHERE_MISSING: dict[tuple[str, str], str] = {
    ("train", ""): "Train a PPO or SAC policy on one env with the rl-zoo style hyperparameter "
    "file of the algorithm (baselines/hyperparams/), evaluating and checkpointing as it goes.",
    ("train", "--algo"): "algorithm (default ppo)",
    ("train", "--seed"): "training seed (default 0)",
    ("train", "--eval-episodes"): "episodes per evaluation (default 20)",
    ("benchmark", "--backend"): "where episodes run: local processes or a Ray cluster "
    "(RAY_ADDRESS or --address names an existing one)",
    ("calibrate", ""): "Calibrate a robot from recorded runs (one sub-command per method).",
    ("calibrate", "calibration"): "calibration method",
}
"""Descriptions (option ``""``) and option help the sub-command modules leave out."""


def _fill_help(parser: argparse.ArgumentParser) -> None:
    """Give ``parser`` the description and option help of :data:`HELP_WHERE_MISSING` it lacks."""
    command = parser.prog.split()[-1]
    if not parser.description and (command, "") in HELP_WHERE_MISSING:
        parser.description = HELP_WHERE_MISSING[(command, "")]
    for action in parser._actions:
        name = action.option_strings[-1] if action.option_strings else action.dest
        if action.help is None and (command, name) in HELP_WHERE_MISSING:
            action.help = HELP_WHERE_MISSING[(command, name)]


def _add_verbosity(parser: argparse.ArgumentParser) -> None:
    """``--quiet`` and ``--verbose`` on ``parser`` where it lacks them (``--silent`` is kept
    as another spelling of ``--quiet``)."""
    options = parser._option_string_actions
    if "--quiet" not in options:
        silent = options.get("--silent")
        parser.add_argument(
            "-q",
            "--quiet",
            dest=silent.dest if silent is not None else "quiet",
            action="store_true",
            help="no progress output",
        )
    if "--verbose" not in options:
        parser.add_argument(
            "-v", "--verbose", action="store_true", help="more detail: tables and every note"
        )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="realitygap",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--version", action="version", version=f"realitygap {realitygap.__version__}"
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p_list = sub.add_parser(
        "list",
        help="list environments, experiments and effects",
        description="List the environments, experiments and effects this package knows.",
    )
    p_list.set_defaults(func=_cmd_list)

    p_run = sub.add_parser(
        "run",
        help="run an experiment and print its figures",
        description=(
            "Run one experiment, print its figures and, for an experiment that diagnoses a "
            "sim-to-real gap, its verdict in words and a report folder (report.html with "
            "figures, report.md, diagnosis.json)."
        ),
    )
    p_run.add_argument("experiment", help="experiment name (see: realitygap list)")
    p_run.add_argument("--quick", action="store_true", help="a smaller, faster version")
    p_run.add_argument("--seed", type=int, default=0, help="base random seed (default 0)")
    p_run.add_argument(
        "--data",
        metavar="DIR",
        help="folder of recorded data laid out like shared/data/ (default: shared/data beside "
        "the checkout when present, else the sample embedded in the package)",
    )
    p_run.add_argument(
        "--robot", help="robot, for experiments that run for several (e.g. diagnose-suite)"
    )
    p_run.add_argument(
        "--variant",
        help="named robot and conventions, for experiments that run on several worlds "
        "(e.g. diagnose-independent: default, large, fast_noisy)",
    )
    p_run.add_argument(
        "--backend",
        choices=("serial", "process", "ray"),
        help="where an experiment that runs cases in parallel (diagnose-suite) runs them "
        "(default: a process pool; ray: a local Ray cluster, or the one RAY_ADDRESS names)",
    )
    p_run.add_argument("--workers", type=int, help="processes of the process backend")
    p_run.add_argument("--json", metavar="PATH", help="write the result as JSON to this path")
    p_run.add_argument(
        "--report",
        metavar="DIR",
        help="where an experiment that diagnoses writes its report (default: "
        "realitygap-reports/EXPERIMENT-DATE-TIME/)",
    )
    p_run.add_argument("--silent", action="store_true", help=argparse.SUPPRESS)
    p_run.set_defaults(func=_cmd_run)

    p_sample = sub.add_parser(
        "sample",
        help="print the folder of a recorded-data sample embedded in the package",
        description=(
            "Unpack (once, into the user cache) a small real data set shipped with the package "
            "and print its folder, laid out like the same sub-folder of a full data folder."
        ),
    )
    p_sample.add_argument(
        "name",
        nargs="?",
        default="optiodom_diffdrive",
        help="sample name (default optiodom_diffdrive: 2 OptiOdom square sessions, 1 circular)",
    )
    p_sample.set_defaults(func=_cmd_sample)

    from realitygap.calibrate import add_calibrate_parser

    add_calibrate_parser(sub)

    from realitygap.diagnosis.cli import add_diagnose_parser

    add_diagnose_parser(sub)

    from realitygap.diagnosis.logs.inspect import add_inspect_parser

    add_inspect_parser(sub)

    from realitygap.baselines.cli import add_benchmark_parser, add_train_parser

    add_benchmark_parser(sub)
    add_train_parser(sub)
    for choice in _subparsers(parser):
        _fill_help(choice)
        _add_verbosity(choice)
        _add_overwrite(choice)
        set_path_types(choice)
    return parser


def _subparsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """Every sub-command parser below ``parser`` (nested ones included)."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):
                found.append(child)
                found += _subparsers(child)
    return found


def _add_overwrite(parser: argparse.ArgumentParser) -> None:
    """``--overwrite`` on every sub-command that writes a ``--json``, ``--report`` or ``--out``
    target (:mod:`realitygap.core.outputs`)."""
    options = parser._option_string_actions
    if "--overwrite" in options or not {"--json", "--report", "--out"} & set(options):
        return
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an output target realitygap did not write (a folder with other files "
        "is replaced whole); without it such a target is refused",
    )


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status.

    0: done; 1: done with failed parts, or an operating-system error (disk full, …); 2: a
    bad input or option (the message names it and the fix); 130 / 143: stopped by Ctrl-C /
    SIGTERM (outputs left as they were); 70: an internal error (a bug: the message says so;
    ``--verbose`` shows the traceback).
    """
    from realitygap.core.stops import run_command

    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "verbose", False):  # every module's INFO messages on stderr
        import logging

        logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    return run_command(lambda: int(args.func(args)), verbose=bool(getattr(args, "verbose", False)))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
