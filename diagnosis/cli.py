"""``realitygap diagnose``: the sim-to-real gap diagnosis from the command line.

::

    realitygap diagnose LOG... [--holdout LOG...] [--robot diffdrive|arm|climber] [--effects a,b,…]
                        [--drive commands|ticks] [--report DIR] [--json PATH] [--export PATH] [--quiet|--verbose]

It prints the verdict in sentences and the candidates by held-out shrink; ``--report``
adds ``report.html`` (self-contained), ``report.md``, ``diagnosis.json`` and figures.

A LOG is a saved ``.npz`` log, an OptiOdom session folder, a UR10 laser-tracker set,
a CSV file (with ``--columns``) or a ROS bag (with ``--truth-topic`` …).
:func:`add_diagnose_parser` adds the sub-command to the main ``realitygap`` parser.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from realitygap.core.checks import (
    check_disjoint,
    check_distinct,
    check_finite_float,
    check_input_path,
    check_positive_int,
    load_json_or_yaml,
    set_path_types,
)

LOG_KINDS = (
    "an .npz log, a session folder, a CSV or text table, a .mat file or a ROS bag (paths are "
    "relative to the current folder)"
)

__all__ = ["add_diagnose_parser", "main", "run_diagnose"]

EXAMPLES = """\
examples:
  # the OptiOdom sample shipped with the package (realitygap sample prints its folder)
  SAMPLE="$(realitygap sample optiodom_diffdrive)"
  realitygap diagnose "$SAMPLE/square/231220200029" --holdout "$SAMPLE/circular/231220200157" \\
      --report out/
  realitygap diagnose run.csv --columns 't=time:ms,cmd.v=v,cmd.w=w,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw:deg' \\
      --report out/ --json out/d.json
  realitygap diagnose drive.bag --truth-topic /mocap/robot/pose --report out/

  # your own robot: inspect proposes the column map, the robot file holds the rest
  realitygap inspect run1.txt
  realitygap diagnose run1.txt run2.txt --holdout run3.txt --robot-file robot.yaml \
      --columns 't=time,ticks.left=-enc_l,ticks.right=enc_r,pose_gt.x=x:mm,pose_gt.y=y:mm,pose_gt.theta=-heading:deg'
  # two files of one recording (encoders and motion capture), aligned on their own stamps
  realitygap diagnose enc.csv+mocap.csv --columns 't=enc::stamp,t=mocap::time,…'

  # an arm measured by a laser tracker (UR10 layout: Series_*/measurements_*.csv);
  # the first series trains, the last is held out
  realitygap diagnose path/to/ipa_ur10_lasertracker --report out/ur10/
"""


def _parse_kv(text: str, what: str) -> dict[str, Any]:
    """``"a=1,b=2"``, a JSON object, or a JSON/YAML file of one → dict."""
    text = text.strip()
    if text.startswith("{") or text.endswith((".json", ".yaml", ".yml")) or Path(text).is_file():
        return dict(load_json_or_yaml(text, what, expect=dict, example='{"wheelbase": 0.23}'))
    out: dict[str, Any] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, sep, value = part.partition("=")
        key = key.strip()
        if not sep:
            raise ValueError(f"{what}: expected key=value pairs, got {part!r}")
        if key in out:
            raise ValueError(
                f"{what}: {key} is given twice ({out[key]} and {value.strip()}); only one can "
                "hold. Fix: keep the one you mean"
            )
        try:
            out[key] = float(value)
        except ValueError:
            raise ValueError(f"{what}: {key} must be a number, got {value!r}") from None
    return out


def _effect_names(text: str) -> tuple[str, ...]:
    """``--effects a,b`` → names; a name given twice is refused."""
    names = tuple(e.strip() for e in text.split(",") if e.strip())
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"--effects: {', '.join(twice)} given twice. Fix: name each effect once")
    if not names:
        raise ValueError("--effects: no effect named. Fix: --effects NAME[,NAME…]")
    return names


def _merged(described: dict[str, Any], given: dict[str, Any], option: str, say: Any) -> dict:
    """``given`` (an option's values) over ``described`` (the robot file's): a value the
    option changes is said, so that it is never silently one or the other."""
    for key, value in given.items():
        if key in described and described[key] != value:
            say(f"{option} {key}={value} replaces the robot file's {key} = {described[key]}")
    return {**described, **given}


def _description(args: argparse.Namespace) -> dict[str, Any]:
    """The importer options a ``--robot-file`` or ``--urdf`` gives (empty without either)."""
    from realitygap.diagnosis.logs.robot_file import description_from_urdf, load_robot_file

    if args.robot_file and args.urdf:
        raise ValueError(
            "--robot-file and --urdf both given; name the URDF inside the robot file "
            "('urdf: robot.urdf') instead"
        )
    if args.robot_file:
        return load_robot_file(args.robot_file).read_options()
    if args.urdf:
        return description_from_urdf(args.urdf).read_options()
    return {}


def add_diagnose_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``diagnose`` sub-command to an ``argparse`` sub-parsers object."""
    p = subparsers.add_parser(
        "diagnose",
        help="diagnose the sim-to-real gap of recorded logs",
        description=(
            "Replay real logs in the nominal simulation, localise the gap, attribute it to "
            "effects fitted on training logs and scored on held-out ones, and report how far "
            "it shrinks. Prints the verdict; --report DIR and --json PATH also write files."
        ),
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("logs", nargs="+", metavar="LOG", help="training logs")
    p.add_argument("--holdout", nargs="+", metavar="LOG", default=[], help="held-out logs")
    p.add_argument(
        "--robot",
        help="robot: diffdrive (differential drive), arm or climber (blade-climbing robot); "
        "default: the robot the logs name, else diffdrive",
    )
    p.add_argument(
        "--effects", help="comma-separated candidate effects (default: every effect of the robot)"
    )
    p.add_argument(
        "--drive",
        choices=("commands", "ticks"),
        default="commands",
        help="replay the logged commands (default) or the logged wheel rotation",
    )
    p.add_argument(
        "--report",
        metavar="DIR",
        help="write report.html (self-contained), report.md, diagnosis.json and figures here",
    )
    p.add_argument("--json", metavar="PATH", help="write the diagnosis as JSON here")
    p.add_argument(
        "--export",
        metavar="PATH",
        help="write the robot the diagnosis found as a reality file (effects, fitted values, "
        "uncertainties) for gym.make(..., reality=PATH) and --reality PATH",
    )
    p.add_argument(
        "--backend",
        choices=("serial", "process", "ray"),
        default="process",
        help="where fits and replays run (default: process pool; ray needs realitygap[ray])",
    )
    p.add_argument("--workers", type=int, help="processes of the process backend")
    p.add_argument(
        "--ray-address", help="Ray cluster address (default: $RAY_ADDRESS, else a local cluster)"
    )
    p.add_argument("--window", type=float, default=1.0, help="feature window, s (default 1)")
    g = p.add_argument_group("importers")
    g.add_argument("--columns", help="CSV column map, e.g. 't=time:ms,cmd.v=v,…' or a .json file")
    g.add_argument("--decimal", choices=(".", ","), help="CSV decimal mark (default: detected)")
    g.add_argument("--delimiter", help="CSV separator (default: detected)")
    g.add_argument(
        "--nan",
        choices=("raise", "interpolate", "drop"),
        default="raise",
        help="missing CSV values",
    )
    g.add_argument("--params", help="nominal robot parameters: 'k=v,…', JSON or a .json file")
    g.add_argument("--firmware", help="firmware rate limits of the commands: 'a_max=…,alpha_max=…'")
    g.add_argument(
        "--cmd-topic", default="/cmd_vel", help="ROS bag: velocity command topic (default /cmd_vel)"
    )
    g.add_argument(
        "--odom-topic",
        default="/odom",
        help="ROS bag: wheel odometry topic (default /odom; empty: none)",
    )
    g.add_argument("--truth-topic", help="ground-truth pose topic, or /tf with --truth-frame")
    g.add_argument("--truth-frame", help="tracked frame in /tf")
    g.add_argument("--wheels-topic", help="JointState topic with the wheel joints")
    g.add_argument(
        "--rate",
        type=float,
        help="resample bags to this rate, Hz (default: align the topics on the wheel joints' "
        "own stamps, else the commands')",
    )
    g.add_argument("--resample", type=float, help="resample every log to this step, s")
    g.add_argument(
        "--duplicates",
        choices=("raise", "last", "mean"),
        default="raise",
        help="repeated time stamps in a table log: an error (default), keep the last, or average",
    )
    g.add_argument(
        "--max-gap",
        type=float,
        metavar="SECONDS",
        help="longest gap of a channel bridged when aligning channels at different rates or "
        "resampling (default: 5 of the channel's own periods); a longer gap cuts the log",
    )
    r = p.add_argument_group("the robot")
    r.add_argument(
        "--robot-file",
        metavar="FILE",
        help="the robot's description (YAML or JSON): kind, nominal geometry, encoders, firmware "
        "limits, where the ground truth's tracked point sits (docs/your_robot.md)",
    )
    r.add_argument(
        "--urdf",
        metavar="FILE",
        help="the robot's URDF: wheel radii and track, or an arm's joints and links",
    )
    g.add_argument(
        "--no-plausibility-check",
        action="store_true",
        help="accept wheeled logs whose speeds, wheel rates or row rate look like a unit "
        "mix-up (checked by default)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="single effects only and one PyBullet verification: faster, coarser",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="every candidate and every note, and detailed progress",
    )
    p.set_defaults(func=run_diagnose)
    return p


def run_diagnose(args: argparse.Namespace) -> int:
    """Run the ``diagnose`` sub-command; returns the exit status.

    The robot adapters' simulator scenes are closed when it returns.
    """
    from realitygap.diagnosis.adapters.registry import close_adapters

    try:
        return _diagnose(args)
    finally:
        close_adapters()


def _diagnose(args: argparse.Namespace) -> int:
    from realitygap.core.outputs import Outputs, command_line
    from realitygap.core.parallel import cap_workers, make_backend
    from realitygap.core.progress import Countdown
    from realitygap.diagnosis.diagnose import DiagnosisSettings, check_request, diagnose
    from realitygap.diagnosis.logs.log import LogError
    from realitygap.diagnosis.logs.read import ReadOptions, read_many, split_recording
    from realitygap.diagnosis.problem.features import FeatureSettings
    from realitygap.diagnosis.problem.problem import AttributionSettings
    from realitygap.diagnosis.report.writer import write_json, write_reports

    clock = Countdown(math.nan)

    def say(msg: str) -> None:
        if not args.quiet and (args.verbose or not msg.startswith("  ")):  # details: --verbose
            print(f"{clock.prefix()} {msg}", file=sys.stderr, flush=True)

    def warn(msg: str) -> None:
        print(f"warning: {msg}", file=sys.stderr, flush=True)

    inputs = [*args.logs, *args.holdout]
    with Outputs(inputs=inputs, overwrite=args.overwrite, command=command_line()) as out:
        try:
            json_stage = out.file(args.json, "--json") if args.json else None
            report_stage = out.folder(args.report, "--report") if args.report else None
            export_stage = out.file(args.export, "--export") if args.export else None
            check_distinct(args.logs, "LOG")
            check_distinct(args.holdout, "--holdout")
            if args.holdout:
                check_disjoint(args.logs, args.holdout)
            if args.workers is not None:
                check_positive_int(args.workers, "--workers")
            check_finite_float(args.window, "--window", low=0.0, strict_low=True, unit="s")
            for name, paths in (("LOG", args.logs), ("--holdout", args.holdout)):
                for path in paths:
                    for part in split_recording(path):
                        check_input_path(part, name, expected=LOG_KINDS)
            workers = cap_workers(args.workers, "--workers", warn)
            described = _description(args)
            params = dict(described.get("params") or {})
            if args.params:
                params = _merged(params, _parse_kv(args.params, "--params"), "--params", warn)
            firmware = dict(described.get("firmware") or {})
            if args.firmware:
                firmware = _merged(
                    firmware, _parse_kv(args.firmware, "--firmware"), "--firmware", warn
                )
            options = ReadOptions(
                columns=args.columns,
                decimal=args.decimal,
                delimiter=args.delimiter,
                nan=args.nan,
                params=params or None,
                firmware=firmware or None,
                meta=described.get("meta") or None,
                robot=args.robot or described.get("robot"),
                duplicates=args.duplicates,
                max_gap=args.max_gap,
                cmd_topic=args.cmd_topic,
                odom_topic=args.odom_topic or None,
                truth_topic=args.truth_topic,
                truth_frame=args.truth_frame,
                wheels_topic=args.wheels_topic,
                rate_hz=args.rate,
                resample=args.resample,
                check_plausible=not args.no_plausibility_check,
            )
            train = read_many(args.logs, options, warn=warn)
            holdout = read_many(args.holdout, options, warn=warn) if args.holdout else None
            effects = _effect_names(args.effects) if args.effects else None
            robot = args.robot
            if robot is None:
                default = DiagnosisSettings.robot
                named = {str(lg.meta.get("robot", default)) for lg in train + list(holdout or [])}
                robot = named.pop() if len(named) == 1 else default
            settings = DiagnosisSettings(
                robot=robot,
                drive=args.drive,
                effects=effects,
                features=FeatureSettings(window_s=args.window),
                attribution=AttributionSettings(pair_candidates=0, verify_top=1)
                if args.quick
                else AttributionSettings(),
            )
            check_request(train, holdout, settings)
            backend = make_backend(args.backend, workers=workers, address=args.ray_address)
            for line in _plan(train, holdout, settings, backend):
                say(line)

            def estimate(left_s: float) -> None:
                clock.estimate_s = clock.elapsed_s() + left_s

            try:
                result = diagnose(
                    train,
                    holdout,
                    settings=settings,
                    backend=backend,
                    progress=say,
                    on_estimate=estimate,
                )
            finally:
                getattr(backend, "shutdown", lambda: None)()
        except (LogError, ValueError, FileNotFoundError, ImportError, KeyError) as exc:
            msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
            print(f"error: {msg}", file=sys.stderr)
            return 2
        if json_stage is not None:
            write_json(json_stage, result.to_json())
        if report_stage is not None:
            write_reports([("", result)], report_stage)
        if export_stage is not None:
            result.to_reality(name=Path(args.export).stem).save(export_stage)
        out.commit()
    human = sys.stderr if "-" in (args.json, args.export) else sys.stdout  # stdout: the file
    for option, path in (("--json", args.json), ("--export", args.export)):
        if path and path != "-":
            say(f"wrote {path}" + (" (a reality file)" if option == "--export" else ""))
    print_result(result, verbose=args.verbose, file=human)
    if args.report:
        print(f"report: {Path(args.report).resolve() / 'report.html'}", file=human)
    return 0


def _library(settings: Any) -> tuple[str, ...]:
    from realitygap.diagnosis.adapters.registry import get_adapter
    from realitygap.diagnosis.diagnose import candidate_library
    from realitygap.robots.effects import EFFECTS

    try:
        return tuple(candidate_library(get_adapter(settings.robot), settings))
    except (KeyError, ValueError):
        return tuple(e for e, cls in EFFECTS.items() if cls.robot == settings.robot)


def _plan(train: list[Any], holdout: list[Any] | None, settings: Any, backend: Any) -> list[str]:
    """What the diagnosis is about to do, said before it starts: the split and the work.

    How long it takes is not guessed here: the diagnosis measures its replays and its
    surrogate on these logs in its first seconds and says it then
    (:class:`~realitygap.diagnosis.fit.workload.Workload`)."""

    lines = []
    if holdout:
        lines.append(f"{len(train)} training log(s), {len(holdout)} held-out log(s)")
    elif len(train) >= 2:
        n_ho = min(len(train) - 1, max(1, math.ceil(settings.holdout_fraction * len(train))))
        names = ", ".join(lg.name for lg in train[-n_ho:])
        lines.append(
            f"warning: no --holdout: holding out the last {n_ho} of {len(train)} logs ({names}); "
            "pass --holdout LOG... to choose"
        )
    else:
        lines.append(
            f"warning: no --holdout and one log: holding out alternate blocks of "
            f"{settings.block_windows} windows of {train[0].name}; a held-out log of another "
            "path is a stronger test"
        )
    from realitygap.diagnosis.report.summary import data_extent

    library = _library(settings)
    workers = max(1, int(getattr(backend, "workers", 1) or 1))
    lines.append(
        f"{len(train) + len(holdout or [])} log(s), {data_extent([*train, *(holdout or [])])} × "
        f"{len(library)} candidate effect(s) on {workers} worker(s)"
    )
    return lines


def print_result(result: Any, verbose: bool = False, file: Any = None) -> None:
    """Print a diagnosis for a person: the summary sentences, then the candidates by
    held-out shrink (the first five; all with ``verbose``) and the notes."""
    from realitygap.diagnosis.report.summary import quantity, ranking_by_shrink, summary_sentences
    from realitygap.diagnosis.report.words import explain

    out = file if file is not None else sys.stdout
    for sentence in summary_sentences(result):
        print(sentence, file=out)
    v = result.verdict
    rows = ranking_by_shrink(result.ranking_rows())
    shown = rows if verbose else rows[:5]
    print(f"candidates by held-out shrink ({len(shown)} of {len(rows)}):", file=out)
    status = v.notes.parameter_status
    for row in shown:
        marks = status.get(row["name"], {})
        vals = ", ".join(
            f"{k.split('.', 1)[-1]} = {quantity(p['value'], p['unit'], p['stderr'])}"
            + (f" ({marks[k]})" if k in marks else "")
            for k, p in row["params"].items()
        )
        print(
            f"  {row['heldout_shrink_pct']:6.1f} %  {row['name']:<40} {vals}",
            file=out,
        )
    notes = explain(v, [r["name"] for r in rows[:1]])[2:]
    for line in notes if verbose else notes[:3]:
        print(f"note: {line}", file=out)
    for info in result.identifiability:
        if not info.get("separable"):
            print(f"note: {info['message']}", file=out)


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point (``python -m realitygap.diagnosis.cli diagnose …``), with the
    exit statuses and signal handling of the ``realitygap`` command
    (:func:`~realitygap.core.stops.run_command`)."""
    from realitygap.core.stops import run_command

    parser = argparse.ArgumentParser(prog="realitygap")
    sub = parser.add_subparsers(dest="command", required=True)
    p = add_diagnose_parser(sub)
    p.add_argument("--overwrite", action="store_true", help=argparse.SUPPRESS)
    set_path_types(p)
    args = parser.parse_args(argv)
    return run_command(lambda: int(args.func(args)), verbose=bool(args.verbose))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
