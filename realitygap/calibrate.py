r"""``realitygap calibrate umbmark``: Borenstein's UMBmark on recorded square runs.

Each session folder (OptiOdom layout, see
:mod:`realitygap.diagnosis.logs.importers.optiodom`) holds squares of side ``L``
driven clockwise and counter-clockwise, with wheel ticks and the ground-truth
pose. Per session the end-pose errors ``ε = absolute − odometry`` (nominal
kinematics of that session) give

.. math::

    E_d = D_R / D_L, \qquad E_b = b_{actual} / b_{nominal}, \qquad
    c_L = \frac{2}{E_d + 1}, \quad c_R = \frac{2}{1/E_d + 1},

and the corrected diameters ``c_L D_L``, ``c_R D_R`` and wheelbase ``E_b b``
(:func:`realitygap.estimators.umbmark.umbmark`).

UMBmark sees rotation only through ``(s_R − s_L)/b`` with ``s ∝ D``, so what it
determines is the wheelbase *in units of the mean wheel diameter*; the mean
diameter itself is left at its nominal value. When sessions with different
nominal geometry are pooled, their results are therefore combined as
``E_d`` and the dimensionless ``b/D̄`` (:func:`pool_calibrations`).

Usage::

    realitygap calibrate umbmark SESSION_DIR [SESSION_DIR ...] [--json PATH]

The package CLI hooks it in with :func:`add_calibrate_parser`.
"""

from __future__ import annotations

import argparse
import datetime
import math
import shlex
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "PooledCalibration",
    "SessionCalibration",
    "add_calibrate_parser",
    "calibrate_session",
    "check_session_folder",
    "format_calibrations",
    "pool_calibrations",
    "session_time",
]


@dataclass(frozen=True)
class SessionCalibration:
    """UMBmark result of one square session (lengths in m, angles in rad).

    Attributes
    ----------
    session_id : str
        Folder name.
    path : str
        Folder path.
    side_length : float
        Square side ``L``.
    n_cw, n_ccw : int
        Runs per direction that entered the result.
    E_d, E_b : float
        Wheel-diameter ratio and wheelbase factor relative to the session's nominal geometry.
    c_L, c_R : float
        Correction factors of the left and right distance per tick.
    alpha, beta : float
        Turn shortfall per 90° turn and heading change per leg (UMBmark's type A and B errors).
    E_max_syst : float
        Borenstein's measure of systematic error, ``max(r_cg,cw, r_cg,ccw)``.
    nominal_D_L, nominal_D_R, nominal_b : float
        Nominal wheel diameters and wheelbase of the session.
    D_L, D_R, b : float
        Corrected diameters ``c_L D_L``, ``c_R D_R`` and wheelbase ``E_b b``.
    b_over_D : float
        Corrected wheelbase over the nominal mean wheel diameter (what UMBmark observes).
    ticks_per_rev : float
        Encoder counts per wheel revolution.
    recorded : str
        Recording time from the session id ``DDMMYYYYhhmm`` as ISO ``YYYY-MM-DDThh:mm``
        (empty if the id does not parse).
    """

    session_id: str
    path: str
    side_length: float
    n_cw: int
    n_ccw: int
    E_d: float
    E_b: float
    c_L: float
    c_R: float
    alpha: float
    beta: float
    E_max_syst: float
    nominal_D_L: float
    nominal_D_R: float
    nominal_b: float
    D_L: float
    D_R: float
    b: float
    b_over_D: float
    ticks_per_rev: float
    recorded: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-able mapping of the fields."""
        return asdict(self)


@dataclass(frozen=True)
class PooledCalibration:
    """Several session calibrations combined.

    Attributes
    ----------
    sessions : tuple of str
        Session ids that entered.
    E_d : float
        Mean wheel-diameter ratio.
    b_over_D : float
        Mean corrected wheelbase over the nominal mean wheel diameter.
    E_d_std, b_over_D_std : float
        Standard deviations over the sessions (0 for one session).
    """

    sessions: tuple[str, ...]
    E_d: float
    b_over_D: float
    E_d_std: float
    b_over_D_std: float

    def E_b_for(self, wheel_diameter_mean: float, wheelbase: float) -> float:
        """Wheelbase factor relative to a robot description with these nominal values (m)."""
        return self.b_over_D * float(wheel_diameter_mean) / float(wheelbase)

    def kinematics_for(self, nominal: Any) -> Any:
        """``nominal`` (DiffDriveKinematics) corrected with this calibration.

        The mean wheel size stays nominal (UMBmark cannot see it); the
        wheelbase becomes ``b/D̄ · D̄_nominal`` and the radii are split by ``E_d``.
        """
        d_mean = nominal.wheel_radius_left + nominal.wheel_radius_right
        return nominal.with_umbmark(self.E_d, self.E_b_for(d_mean, nominal.wheelbase))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able mapping of the fields."""
        out = asdict(self)
        out["sessions"] = list(self.sessions)
        return out


def session_time(session_id: str) -> datetime.datetime | None:
    """Recording time from an OptiOdom session id ``DDMMYYYYhhmm``, ``None`` if it does not parse."""
    if not (len(session_id) == 12 and session_id.isdigit()):
        return None
    try:
        return datetime.datetime.strptime(session_id, "%d%m%Y%H%M")
    except ValueError:
        return None


def _recorded(session_id: str) -> str:
    when = session_time(session_id)
    return "" if when is None else when.strftime("%Y-%m-%dT%H:%M")


SESSION_LAYOUT = """\
an OptiOdom session folder of square runs:
  <ID>/<ID>_metadata.csv        wheel diameters, wheelbase, ticks per revolution, side L
  <ID>/<ID>_run-01.csv, …       one run each: wheel ticks and the ground-truth pose"""
"""The folder layout ``calibrate umbmark`` reads, for messages."""


def check_session_folder(folder: str | Path, name: str = "SESSION_DIR") -> Path:
    """``folder`` if it exists as a readable folder, else an error that says what is there
    (a file, a link loop, nothing) and shows :data:`SESSION_LAYOUT`.

    A file of a session (its metadata or a run) gets the command with its folder; a folder
    that holds sessions below it gets the command with them.

    Raises
    ------
    FileNotFoundError
        Nothing at ``folder``.
    ValueError
        Something other than a folder, or a folder that holds no session.
    """
    from realitygap.core.checks import check_input_path

    p = Path(folder)
    try:
        check_input_path(p, name, kind="folder", expected=SESSION_LAYOUT.partition(":")[0])
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"{exc}\nExpected {SESSION_LAYOUT}") from None
    except ValueError as exc:
        parent = p.parent
        if p.is_file() and (parent / f"{parent.name}_metadata.csv").is_file():
            fix = (
                f"{p.name} is a file of the session {parent}; pass the folder:\n  realitygap "
                f"calibrate umbmark {shlex.quote(str(parent))}"
            )
        else:
            fix = f"Expected {SESSION_LAYOUT}"
        raise ValueError(f"{exc}\n{fix}") from None
    if not (p / f"{p.name}_metadata.csv").is_file():
        from realitygap.diagnosis.logs.importers.optiodom import find_sessions

        below = find_sessions(p)
        if below:
            shown = " ".join(shlex.quote(str(s)) for s in below[:6])
            more = f" (and {len(below) - 6} more)" if len(below) > 6 else ""
            raise ValueError(
                f"{name}: {p} is not a session folder but holds {len(below)} below it; pass "
                f"them:\n  realitygap calibrate umbmark {shown}{more}"
            )
        raise ValueError(
            f"{name}: {p} is not an OptiOdom session folder (no {p.name}_metadata.csv in "
            f"it, none below it). Expected {SESSION_LAYOUT}"
        )
    return p


SIDE_LENGTH_TOLERANCE = 0.25
"""Largest relative difference between the stated square side and the side the ground truth
shows (its path length over four) before the side is refused as a wrong number or unit."""


def _check_side_length(L: float, runs: list[Any], session: str, given: bool) -> None:
    """Refuse a square side that the driven squares contradict (a side in mm given as m)."""
    sides = [
        float(np.sum(np.hypot(*np.diff(np.asarray(r.gt_poses)[:, :2], axis=0).T))) / 4.0
        for r in runs
    ]
    measured = float(np.median(sides))
    if measured > 0 and abs(L / measured - 1.0) > SIDE_LENGTH_TOLERANCE:
        source = f"--side-length {L:g}" if given else f"the metadata's L = {L:g} m"
        raise ValueError(
            f"session {session}: {source} disagrees with the squares its ground truth shows "
            f"(about {measured:.2f} m a side: path length / 4, median of {len(sides)} runs). "
            "Fix: give the side in metres"
            + (", or leave --side-length out to use the metadata's L" if given else "")
        )


def calibrate_session(folder: str | Path, side_length: float | None = None) -> SessionCalibration:
    """UMBmark for one OptiOdom square session.

    Parameters
    ----------
    folder : str or Path
        Session folder ``<ID>/`` with ``<ID>_metadata.csv`` and ``<ID>_run-NN.csv``.
    side_length : float, optional
        Square side in m; default: ``L`` from the metadata.

    Returns
    -------
    SessionCalibration

    Raises
    ------
    FileNotFoundError
        If ``folder`` does not exist.
    ValueError
        If ``folder`` is a file or no session folder (:func:`check_session_folder`), if
        the session is not a square session, has no side length, or does not
        hold runs in both directions.
    """
    from realitygap.diagnosis.logs.importers.optiodom import PathType, read_session
    from realitygap.estimators.umbmark import UMBmarkRun, umbmark_from_runs

    folder = check_session_folder(folder)
    session = read_session(folder)
    meta = session.metadata
    L = side_length if side_length is not None else meta.side_length
    if session.path_type not in (PathType.SQUARE, PathType.UNKNOWN) and side_length is None:
        raise ValueError(
            f"session {session.session_id} holds {session.path_type.value!r} runs; UMBmark needs "
            "square runs (pass --side-length to force it on other runs)"
        )
    if L is None or not (math.isfinite(L) and L > 0):
        raise ValueError(
            f"session {session.session_id}: the metadata gives no square side L; pass "
            "--side-length METRES"
        )
    runs = [
        UMBmarkRun(
            run.gt_pose,
            run.ticks_left.astype(float),
            run.ticks_right.astype(float),
            run.direction,
        )
        for run in session.runs
        if run.direction is not None
    ]
    n_cw = sum(r.direction == "cw" for r in runs)
    n_ccw = sum(r.direction == "ccw" for r in runs)
    if n_cw == 0 or n_ccw == 0:
        have = "clockwise" if n_cw else ("counter-clockwise" if n_ccw else "no closed square")
        count = n_cw or n_ccw
        raise ValueError(
            f"session {session.session_id} holds only {have} runs ({count}); UMBmark needs "
            "squares driven in both directions (clockwise and counter-clockwise)"
        )
    _check_side_length(float(L), runs, session.session_id, side_length is not None)
    kin = session.kinematics()
    res = umbmark_from_runs(runs, kin, float(L))
    d_left, d_right, b = meta.wheel_diameter_left, meta.wheel_diameter_right, meta.wheelbase
    return SessionCalibration(
        session_id=session.session_id,
        path=str(folder.resolve()),
        side_length=float(L),
        n_cw=n_cw,
        n_ccw=n_ccw,
        E_d=res.E_d,
        E_b=res.E_b,
        c_L=res.c_L,
        c_R=res.c_R,
        alpha=res.alpha,
        beta=res.beta,
        E_max_syst=res.E_max_syst,
        nominal_D_L=d_left,
        nominal_D_R=d_right,
        nominal_b=b,
        D_L=res.c_L * d_left,
        D_R=res.c_R * d_right,
        b=res.E_b * b,
        b_over_D=res.E_b * b / (0.5 * (d_left + d_right)),
        ticks_per_rev=kin.ticks_per_rev,
        recorded=_recorded(session.session_id),
    )


def pool_calibrations(calibrations: Sequence[SessionCalibration]) -> PooledCalibration:
    """Combine session calibrations: means of ``E_d`` and of ``b/D̄``.

    Raises
    ------
    ValueError
        If ``calibrations`` is empty.
    """
    if not calibrations:
        raise ValueError("pool_calibrations needs at least one session calibration")
    e_d = np.array([c.E_d for c in calibrations])
    b_d = np.array([c.b_over_D for c in calibrations])
    return PooledCalibration(
        sessions=tuple(c.session_id for c in calibrations),
        E_d=float(e_d.mean()),
        b_over_D=float(b_d.mean()),
        E_d_std=float(e_d.std()),
        b_over_D_std=float(b_d.std()),
    )


def format_calibrations(
    calibrations: Sequence[SessionCalibration], pooled: PooledCalibration | None = None
) -> str:
    """A readable table of session calibrations (diameters and wheelbase in mm)."""
    head = (
        f"{'session':<14} {'L[m]':>5} {'cw':>3} {'ccw':>3} {'E_d':>8} {'E_b':>8} "
        f"{'c_L':>8} {'c_R':>8} {'D_L[mm]':>8} {'D_R[mm]':>8} {'b[mm]':>8} {'Emax[mm]':>8}"
    )
    lines = [head, "-" * len(head)]
    for c in calibrations:
        lines.append(
            f"{c.session_id:<14} {c.side_length:>5.2f} {c.n_cw:>3d} {c.n_ccw:>3d} "
            f"{c.E_d:>8.5f} {c.E_b:>8.5f} {c.c_L:>8.5f} {c.c_R:>8.5f} {1e3 * c.D_L:>8.3f} "
            f"{1e3 * c.D_R:>8.3f} {1e3 * c.b:>8.3f} {1e3 * c.E_max_syst:>8.1f}"
        )
    if pooled is not None and len(calibrations) > 1:
        lines.append(
            f"pooled over {len(pooled.sessions)} sessions: E_d = {pooled.E_d:.5f} "
            f"(± {pooled.E_d_std:.5f}), b/D = {pooled.b_over_D:.4f} (± {pooled.b_over_D_std:.4f})"
        )
    return "\n".join(lines)


def _cmd_umbmark(args: argparse.Namespace) -> int:
    from realitygap.core.checks import check_distinct
    from realitygap.core.io import write_json
    from realitygap.core.outputs import Outputs, command_line

    if args.side_length is not None and not (
        math.isfinite(args.side_length) and args.side_length > 0
    ):
        print(
            f"error: --side-length must be a positive length in m, got {args.side_length}",
            file=sys.stderr,
        )
        return 2
    calibrations = []
    overwrite = bool(getattr(args, "overwrite", False))
    with Outputs(inputs=args.sessions, overwrite=overwrite, command=command_line()) as out:
        try:
            stage = out.file(args.json, "--json") if args.json else None
            check_distinct(args.sessions, "SESSION_DIR")
            for folder in args.sessions:
                calibrations.append(calibrate_session(folder, args.side_length))
        except (FileNotFoundError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        pooled = pool_calibrations(calibrations)
        if stage is not None:
            payload = {
                "method": "UMBmark (Borenstein & Feng 1996), end-pose errors absolute − odometry",
                "sessions": [c.to_dict() for c in calibrations],
                "pooled": pooled.to_dict(),
            }
            write_json(stage, payload)
        out.commit()
    human = sys.stderr if args.json == "-" else sys.stdout  # stdout holds the JSON
    print(format_calibrations(calibrations, pooled), file=human)
    if args.json and args.json != "-":
        print(f"wrote {args.json}", file=human)
    return 0


def add_calibrate_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``calibrate umbmark`` to the ``realitygap`` command line.

    Parameters
    ----------
    subparsers : the object returned by ``ArgumentParser.add_subparsers``.

    Returns
    -------
    argparse.ArgumentParser
        The ``calibrate`` parser (its handler is in ``args.func``, returning an exit code).
    """
    p_cal = subparsers.add_parser("calibrate", help="calibrate a robot from recorded runs")
    sub = p_cal.add_subparsers(dest="calibration", required=True)
    p_umb = sub.add_parser(
        "umbmark",
        help="UMBmark (wheel-diameter ratio E_d, wheelbase factor E_b) from square sessions",
        description=(
            "Borenstein's UMBmark from OptiOdom-style session folders of square runs "
            "(clockwise and counter-clockwise, wheel ticks + ground truth)."
        ),
    )
    p_umb.add_argument("sessions", nargs="+", metavar="SESSION_DIR", help="session folder(s)")
    p_umb.add_argument("--json", metavar="PATH", help="also write the result as JSON (atomically)")
    p_umb.add_argument(
        "--side-length",
        type=float,
        default=None,
        metavar="METRES",
        help="square side (default: L from each session's metadata)",
    )
    p_umb.set_defaults(func=_cmd_umbmark)
    return p_cal
