"""Read anything the diagnosis accepts as a LOG: a saved log, an OptiOdom session, a CSV, a bag.

:func:`read_logs` looks at what a path *is* (its content, not its extension)
and hands it to the right reader:

* a ``.npz`` log written by :meth:`~realitygap.diagnosis.logs.log.Log.save`;
* an OptiOdom session folder ``<ID>/`` (or a folder holding sessions):
  one log per run, via :mod:`realitygap.diagnosis.logs.importers.optiodom`
  (:func:`logs_from_optiodom`);
* a CSV file with a column map (:mod:`realitygap.diagnosis.logs.importers.csv_log`);
* a ROS 1 bag or a ROS 2 bag folder (:mod:`realitygap.diagnosis.logs.importers.rosbag`).

A file whose extension promises something else than its content is refused
with a message naming both.
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from realitygap.core.checks import (
    ResourceLimits,
    check_finite_float,
    check_input_path,
    check_rows_limit,
)
from realitygap.diagnosis.logs.log import Log, LogError, sniff_file_kind
from realitygap.diagnosis.logs.options import ReadOptions, check_read_options
from realitygap.diagnosis.logs.plausibility import check_log
from realitygap.diagnosis.logs.schema import SchemaError
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.diffdrive_replay import nominal_odometry, params_to_meta

__all__ = [
    "UR10_COLUMN_MAP",
    "ReadOptions",
    "check_plausible",
    "check_read_options",
    "log_from_ur10_file",
    "log_from_ur10_series",
    "logs_from_optiodom",
    "logs_from_ur10",
    "read_logs",
    "resample_split",
]

_EXT_KIND = {
    ".npz": {"npz"},
    ".csv": {"text"},
    ".txt": {"text"},
    ".tsv": {"text"},
    ".bag": {"rosbag1"},
    ".mat": {"text", "binary"},
    ".db3": {"sqlite"},
    ".mcap": {"mcap"},
}


def logs_from_optiodom(
    folder: str | os.PathLike[str], warn: Callable[[str], None] | None = None
) -> list[Log]:
    """One :class:`Log` per run of an OptiOdom session folder (or of every session below a folder).

    Channels: ``pose_gt`` (OptiTrack, start frame), ``ticks`` (cumulative
    counts from the per-cycle increments), ``pose_est`` (the robot's own
    odometry from its log, in the start frame; nominal dead reckoning of the
    ticks when the robot log cannot be aligned) and, when
    the robot log could be aligned, ``cmd`` — the commanded linear
    (ticks/cycle → m/s) and angular (rad/cycle → rad/s) velocity. The
    firmware's acceleration limits from the robot-log header (``DVMAX``
    ticks/cycle², ``DWMAX`` rad/cycle²) go to ``meta["firmware"]``, so a replay
    ramps the commands as the robot did. A run too short to be a log is dropped and
    named through ``warn``.
    """
    from realitygap.diagnosis.logs.importers.optiodom import find_sessions, read_session

    root = Path(folder)
    sessions = find_sessions(root)
    if not sessions:
        raise LogError(
            f"{root}: no OptiOdom session found (expected <ID>/<ID>_metadata.csv below it)"
        )
    say = warn if warn is not None else (lambda msg: None)
    logs: list[Log] = []
    for sdir in sessions:
        session = read_session(sdir)
        m = session.metadata
        tpr = m.gear_ratio * m.encoder_resolution
        params = DiffDriveParams(
            wheel_radius_left=m.wheel_diameter_left / 2.0,
            wheel_radius_right=m.wheel_diameter_right / 2.0,
            wheelbase=m.wheelbase,
            ticks_per_rev=tpr,
        )
        mean_d = 0.5 * (m.wheel_diameter_left + m.wheel_diameter_right)
        m_per_tick = math.pi * mean_d / tpr
        header = session.robot_log_header
        for run in session.runs:
            t = np.asarray(run.time, dtype=float)
            if t.shape[0] < 3:
                say(
                    f"{run.path}: run dropped: {t.shape[0]} row(s), a log needs at least 3 "
                    "(a start, a motion and an end)"
                )
                continue
            dt = float(np.median(np.diff(t)))
            inc = np.column_stack([run.ticks_left, run.ticks_right]).astype(float)
            inc[0] = 0.0
            ticks = np.cumsum(inc, axis=0)
            channels: dict[str, Any] = {
                "pose_gt": np.asarray(run.gt_pose, dtype=float),
                "ticks": ticks,
            }
            # the robot's own odometry when the robot log is aligned, else nominal dead reckoning
            rl, off = run.robot_log, run.robot_log_offset
            if rl is not None and off is not None and off + t.shape[0] <= rl.odo_pose.shape[0]:
                est = np.asarray(rl.odo_pose[off : off + t.shape[0]], dtype=float)
                channels["pose_est"] = _to_start_frame(est)
            else:
                channels["pose_est"] = nominal_odometry(ticks, params, np.zeros(3))
            meta: dict[str, Any] = {
                "robot": "diffdrive",
                "params": params_to_meta(params),
                "name": f"{session.session_id}_run-{run.index:02d}",
                "source": str(run.path),
                "dataset": "optiodom",
                "path_type": session.path_type.value,
                "direction": run.direction,
                "session": session.session_id,
                "run": run.index,
            }
            if run.cmd_linear is not None and run.cmd_angular is not None:
                channels["cmd"] = np.column_stack(
                    [np.asarray(run.cmd_linear) * m_per_tick / dt, np.asarray(run.cmd_angular) / dt]
                )
                fw: dict[str, float] = {}
                for key, name, scale in (
                    ("DVMAX(ticks/cyc^2)", "a_max", m_per_tick / dt**2),
                    ("DWMAX(ticks/cyc^2)", "alpha_max", 1.0 / dt**2),
                ):
                    vals = header.get(key)
                    if vals:
                        try:
                            fw[name] = float(vals[0]) * scale
                        except ValueError:
                            pass
                if fw:
                    meta["firmware"] = fw
            meta["command_alignment"] = run.alignment
            logs.append(Log(t=t - t[0], channels=channels, meta=meta, source=str(run.path)))
    return logs


def _to_start_frame(pose: np.ndarray) -> np.ndarray:
    """Poses (N, 3) expressed in the frame of the first one, continuous heading."""
    c, s = math.cos(pose[0, 2]), math.sin(pose[0, 2])
    dx, dy = pose[:, 0] - pose[0, 0], pose[:, 1] - pose[0, 1]
    th = np.unwrap(pose[:, 2] - pose[0, 2])
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, th])


UR10_LINK_MASSES: tuple[float, ...] = (7.1, 12.7, 4.27, 2.0, 2.0, 0.365)
"""Link masses of the UR10 (kg), from Universal Robots' published dynamics parameters."""

UR10_REPEATABILITY_SIGMA = 0.1e-3 / 3.0
"""One standard deviation of the UR10's pose repeatability (m): its data sheet gives ±0.1 mm,
taken as a 3-σ bound."""

UR10_TRACKER_SIGMA = 1.0e-5
"""Per-axis noise of the laser tracker (m) for series that do not report their own."""

UR10_PROBE_MASS = 1.2
"""Mass of the tracker probe and its adapter on the flange (kg); an assumption (a T-Mac
probe weighs about 1.1 kg), used only for the holding torques of the compliance effect."""


def log_from_ur10_series(series: Any) -> Log:
    """An arm :class:`Log` from one UR10 laser-tracker series
    (:class:`~realitygap.diagnosis.logs.importers.ur10.UR10Series`).

    One row per pose in file order (``t`` counts poses): ``joints`` are the joint
    readings, ``tool_pos`` the probe positions in the tracker frame; the nominal
    arm is the published UR10 table with UR10 link masses, the tool the probe
    point in the flange frame from the series' ``Trafo_TM_F_init.txt``, and the
    noise of one measurement (``meta["tool_noise_m"]``) the tracker's reported
    standard deviation (or :data:`UR10_TRACKER_SIGMA`) combined with the arm's
    repeatability (:data:`UR10_REPEATABILITY_SIGMA`).
    """
    from realitygap.estimators.arm.mdh import MDHTable
    from realitygap.robots.arm import ArmParams, arm_params_to_meta

    params = ArmParams(
        mdh=MDHTable.ur10(), link_masses=UR10_LINK_MASSES, camera_mass=UR10_PROBE_MASS
    )
    tracker = (
        float(np.median(series.position_std))
        if series.position_std is not None
        else UR10_TRACKER_SIGMA
    )
    noise = math.hypot(tracker, UR10_REPEATABILITY_SIGMA)
    return Log(
        t=np.arange(series.n, dtype=float),
        channels={"joints": series.joint_angles, "tool_pos": series.probe_positions},
        meta={
            "robot": "arm",
            "name": series.name,
            "params": arm_params_to_meta(params),
            "tool": series.probe_in_flange.tolist(),
            "tool_noise_m": noise,
            "importer": "ur10",
            "timestamps_valid": bool(series.timestamps_valid),
        },
        source=series.source,
    )


UR10_COLUMN_MAP = (
    "joints.q1=shoulder_pan_joint,joints.q2=shoulder_lift_joint,joints.q3=elbow_joint,"
    "joints.q4=wrist_1_joint,joints.q5=wrist_2_joint,joints.q6=wrist_3_joint,"
    "tool_pos.x=measurement_x:mm,tool_pos.y=measurement_y:mm,tool_pos.z=measurement_z:mm"
)
"""The column map of a UR10 laser-tracker measurement file: the generic arm table reader
(:func:`~realitygap.diagnosis.logs.importers.csv_log.read_table_logs`) with this map reads its
channels; the UR10 reader adds what the folder's other files say (the probe in the flange, the
tracker's reported noise)."""


def log_from_ur10_file(series: Any) -> Log:
    """The arm :class:`Log` of one UR10 series, its channels read by the generic table reader
    with :data:`UR10_COLUMN_MAP` and its metadata from :func:`log_from_ur10_series`."""
    from realitygap.diagnosis.logs.importers.csv_log import read_table_logs

    described = log_from_ur10_series(series)
    (log,) = read_table_logs(
        [series.source],
        UR10_COLUMN_MAP,
        params=described.meta["params"],
        meta={k: v for k, v in described.meta.items() if k != "params"},
        robot="arm",
    )
    return log.replace(meta=dict(described.meta))


def logs_from_ur10(path: str | os.PathLike[str]) -> list[Log]:
    """Arm logs from a UR10 laser-tracker folder (``Series_*/measurements_*.csv``), one
    ``Series_*`` folder, or one ``measurements_*.csv`` file; one log per measurement file
    (:func:`log_from_ur10_file`)."""
    from realitygap.diagnosis.logs.importers.ur10 import (
        read_transform_txt,
        read_ur10_dataset,
        read_ur10_measurements,
    )

    p = Path(path)
    try:
        if p.is_dir() and any(p.glob("Series_*/measurements_*.csv")):
            series = list(read_ur10_dataset(p).series)
        else:
            files = sorted(p.glob("measurements_*.csv")) if p.is_dir() else [p]
            folder = p if p.is_dir() else p.parent
            init = folder / "Trafo_TM_F_init.txt"
            T0 = read_transform_txt(init) if init.exists() else None
            series = [read_ur10_measurements(f, T0, name=f"{folder.name}/{f.stem}") for f in files]
    except ValueError as exc:
        raise LogError(str(exc)) from None
    return [log_from_ur10_file(s) for s in series]


def _looks_like_ur10(p: Path) -> bool:
    if p.is_dir():
        return any(p.glob("Series_*/measurements_*.csv")) or any(p.glob("measurements_*.csv"))
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            head = fh.readline()
    except OSError:
        return False
    return "Goal x" in head and "measurement_x" in head and "shoulder_pan_joint" in head


def _session_id_of(folder: Path) -> str | None:
    """The ID of the OptiOdom session files in ``folder`` (its ``<ID>_metadata.csv``), or None."""
    found = sorted(folder.glob("*_metadata.csv"))
    return found[0].name[: -len("_metadata.csv")] if len(found) == 1 else None


def _renamed_session(p: Path) -> str | None:
    """The message for a folder of OptiOdom session files named other than their ID."""
    sid = _session_id_of(p)
    if sid is None or sid == p.name or not sid:
        return None
    return (
        f"{p}: holds the files of the OptiOdom session {sid} ({sid}_metadata.csv, "
        f"{sid}_run-NN.csv), but a session folder must be named after the ID in its files' "
        f"names (<ID>/<ID>_metadata.csv), and this one is named {p.name!r}. Fix: rename the "
        f"folder: mv {p} {p.parent / sid}"
    )


def _part_of_dataset(p: Path) -> str | None:
    """The message for a file that is one part of a dataset folder read as a whole (an
    OptiOdom session's metadata, run or robot-log file; a file of a UR10 laser-tracker set
    other than its measurements), else None."""
    folder = p.parent
    sid = _session_id_of(folder)
    if sid and p.name.startswith(sid):
        fix = f"pass the folder: realitygap diagnose {folder}"
        if folder.name != sid:
            fix = (
                f"rename the folder after the session ID first (mv {folder} "
                f"{folder.parent / sid}), then pass the folder"
            )
        return (
            f"{p}: a file of the OptiOdom session folder {folder} (session {sid}), not a log "
            "on its own: a session's runs are read together with its metadata and robot log. "
            f"Fix: {fix}"
        )
    for root, series in ((folder.parent, folder), (folder, None)):
        if any(root.glob("Series_*/measurements_*.csv")):
            where = f"{series} (one series) or {root}" if series is not None else str(root)
            return (
                f"{p}: a file of the UR10 laser-tracker set {root}, not a log on its own: "
                "its measurement files are read with each series' transforms. Fix: pass the "
                f"folder {where}"
            )
    return None


def _looks_like_optiodom(p: Path) -> bool:
    if (p / f"{p.name}_metadata.csv").is_file():
        return True
    return any(p.glob("*/*_metadata.csv")) or any(p.glob("*/*/*_metadata.csv"))


def read_logs(
    path: str | os.PathLike[str],
    options: ReadOptions | None = None,
    warn: Callable[[str], None] | None = None,
) -> list[Log]:
    """Read one LOG argument (file or folder) into one or more logs.

    ``warn`` receives a message for every run dropped or split (with the reason).

    Raises
    ------
    LogError
        Unknown content, an extension that contradicts the content, a CSV
        without a column map, or an importer's own error (which names the
        file, the channel and the fix).
    """
    opt = check_read_options(options, warn, "read_logs")
    if not isinstance(path, str | os.PathLike):
        raise TypeError(
            f"read_logs: path must be a file or folder name (str or path-like), got "
            f"{type(path).__name__} {path!r:.80}; e.g. read_logs('run.csv', ReadOptions(columns="
            "'t=time,…'))"
        )
    p = Path(path)
    parts = split_recording(path)
    if len(parts) > 1:
        logs = _read_tables([Path(x) for x in parts], opt, warn)
        return _after_reading(logs, opt, warn)
    try:  # one input-path check: missing, a link loop, a FIFO, unreadable, empty
        check_input_path(p, "LOG")
    except FileNotFoundError:
        raise
    except ValueError as exc:
        raise LogError(str(exc)) from None
    kind = sniff_file_kind(p)
    ext = p.suffix.lower()
    if kind != "directory" and ext in _EXT_KIND and kind not in _EXT_KIND[ext]:
        raise LogError(
            f"{p}: the extension {ext!r} promises {'/'.join(sorted(_EXT_KIND[ext]))} but the "
            f"content looks like {kind}. Fix: rename the file or export it again"
        )
    if kind == "directory":
        if (p / "metadata.yaml").is_file():
            logs = _read_bag(p, opt, warn)
        elif _looks_like_optiodom(p):
            logs = logs_from_optiodom(p, warn)
        elif _looks_like_ur10(p):
            logs = logs_from_ur10(p)
        else:
            renamed = _renamed_session(p)
            if renamed:
                raise LogError(renamed)
            raise LogError(
                f"{p}: a folder that is neither an OptiOdom session (<ID>/<ID>_metadata.csv), "
                "a UR10 laser-tracker set (Series_*/measurements_*.csv) nor a ROS 2 bag "
                "(metadata.yaml)"
            )
    elif kind == "npz" and (opt.columns is None or _is_saved_log(p)):
        logs = [Log.load(p)]
    elif kind == "text" and not opt.columns and _looks_like_ur10(p):
        logs = logs_from_ur10(p)
    elif kind in ("text", "npz") or ext == ".mat":
        if not opt.columns:
            part = _part_of_dataset(p)
            if part:
                raise LogError(part)
            # a file that cannot be parsed at all is unreadable first, whatever else is missing
            from realitygap.diagnosis.logs.importers.table import read_table

            read_table(p, delimiter=opt.delimiter, decimal=opt.decimal)
            near = _ur10_near_miss(p) if kind == "text" else None
            if near:
                raise LogError(near)
            what = (
                f"{p}: a table (with the header {_header_text(p)}) of no known layout"
                if kind == "text"
                else f"{p}: a table of {ext} arrays of no known layout"
            )
            raise LogError(
                f"{what} (a UR10 measurement file has the columns "
                f"{', '.join(UR10_KEY_COLUMNS)}), so it needs a column map saying which column "
                f"is what. Fix: run 'realitygap inspect {p}', which proposes one, or pass e.g. "
                "--columns 't=time:s,cmd.v=v,cmd.w=w,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw'"
            )
        logs = _read_tables([p], opt, warn)
    elif kind in ("rosbag1", "sqlite", "mcap"):
        logs = _read_bag(p, opt, warn)
    else:
        raise LogError(
            f"{p}: not a log the diagnosis can read (content looks like {kind}, not text); "
            "expected a .npz "
            "log, a CSV file, a ROS bag or an OptiOdom session folder"
        )
    return _after_reading(logs, opt, warn)


def split_recording(path: str | os.PathLike[str]) -> list[str]:
    """The files of one LOG argument: ``enc.csv+mocap.csv`` names two files of one recording
    (aligned on their own stamps); a path that exists as written is one file."""
    text = os.fspath(path)
    if "+" not in text or Path(text).exists():
        return [text]
    parts = [x for x in text.split("+") if x]
    missing = [x for x in parts if not Path(x).exists()]
    if missing:
        raise FileNotFoundError(
            f"{text}: read as the files {', '.join(parts)} of one recording, but "
            f"{', '.join(missing)} does not exist"
        )
    return parts


def _is_saved_log(p: Path) -> bool:
    """Whether an ``.npz`` is a log written by :meth:`Log.save` (it holds ``meta.json``)."""
    import zipfile

    try:
        with zipfile.ZipFile(p) as zf:
            return "meta.json.npy" in zf.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


def _read_tables(
    paths: list[Path], opt: ReadOptions, warn: Callable[[str], None] | None
) -> list[Log]:
    """Table files (text, ``.mat``, ``.npz`` arrays) of one recording, with the column map."""
    from realitygap.diagnosis.logs.importers.column_map import ColumnMap
    from realitygap.diagnosis.logs.importers.csv_log import POSE_ROW_CHANNELS, read_table_logs

    if not opt.columns:
        raise LogError(
            f"{'+'.join(map(str, paths))}: table files need a column map (--columns). Fix: run "
            "'realitygap inspect' on them, which proposes one"
        )
    cmap = ColumnMap.parse(opt.columns)
    robot = opt.robot
    if robot is None:
        robot = "arm" if all(c in POSE_ROW_CHANNELS for c in cmap.channels()) else "diffdrive"
    meta: dict[str, Any] = dict(opt.meta or {})
    if opt.firmware:
        meta["firmware"] = dict(opt.firmware)
    return read_table_logs(
        paths,
        cmap,
        delimiter=opt.delimiter,
        decimal=opt.decimal,
        params=opt.params,
        meta=meta or None,
        nan=opt.nan,
        robot=robot,
        duplicates=opt.duplicates,
        max_gap=opt.max_gap,
        warn=warn,
    )


def _after_reading(
    logs: list[Log], opt: ReadOptions, warn: Callable[[str], None] | None
) -> list[Log]:
    if opt.check_plausible:
        entries = _map_entries(opt.columns)
        for lg in logs:
            try:
                check_plausible(lg, entries)
            except LogError as exc:
                raise LogError(
                    f"{exc} (if these numbers are right, skip the check: --no-plausibility-check, "
                    "or ReadOptions(check_plausible=False))"
                ) from None
    if opt.resample is not None:
        logs = [
            piece
            for lg in logs
            for piece in resample_split(lg, opt.resample, warn, max_gap=opt.max_gap)
        ]
    if opt.meta:
        # what a robot file declares holds for every log of the robot, whatever its reader
        logs = [lg.replace(meta={**dict(opt.meta), **lg.meta}) for lg in logs]
    return logs


def _map_entries(columns: str | Mapping[str, Any] | None) -> dict[str, str]:
    """``{"ticks.left": "-enc_l", …}``: the column map's entries as written, for fixes that
    name them (empty when there is no map)."""
    if not columns:
        return {}
    from realitygap.diagnosis.logs.importers.column_map import ColumnMap

    try:
        cmap = (
            ColumnMap.parse(columns) if isinstance(columns, str) else ColumnMap.from_dict(columns)
        )
    except (LogError, ValueError, TypeError):
        return {}
    return {target: src.text for target, src in cmap.entries.items() if src.text}


def check_plausible(log: Log, columns: Mapping[str, str] | None = None) -> None:
    """Refuse a log whose numbers do not fit the schema of its channels (a unit mix-up).

    The checks are declared once per channel in :mod:`~realitygap.diagnosis.logs.schema`
    (:func:`~realitygap.diagnosis.logs.plausibility.check_log`): the row rate, a tick counter that
    wraps, speeds and turn rates against the robot's limits (a heading or turn rate in
    degrees), wheel rates and the wheel path against the true one, joint angles, and an arm's
    measured tool points against its reach.

    Raises
    ------
    LogError
        Naming the file, the channel, the value with its unit, the bound and the likely fix.
    """
    try:
        check_log(log, columns)
    except SchemaError as exc:
        raise LogError(str(exc)) from None


UR10_KEY_COLUMNS = ("Goal x", "measurement_x", "shoulder_pan_joint")
"""Header names that mark a UR10 laser-tracker measurement file."""


def _ur10_near_miss(p: Path) -> str | None:
    """The message for a file with most, but not all, UR10 measurement columns (else None)."""
    import difflib

    from realitygap.diagnosis.logs.importers.ur10 import REQUIRED_COLUMNS

    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            head = fh.readline(20_000).strip()
    except OSError:
        return None
    found = [c.strip() for c in head.replace(";", ",").split(",")]
    missing = [c for c in REQUIRED_COLUMNS if c not in found]
    if not missing or len(missing) > len(REQUIRED_COLUMNS) // 2:
        return None
    extra = [c for c in found if c and c not in REQUIRED_COLUMNS and c != "Timestamp"]
    hints = []
    for c in missing:
        close = difflib.get_close_matches(c, extra, n=1, cutoff=0.6)
        hints.append(f"{c!r}" + (f" (found {close[0]!r})" if close else ""))
    return (
        f"{p}: looks like a UR10 laser-tracker measurement file, but the header lacks "
        f"{', '.join(hints)}; expected the columns {', '.join(REQUIRED_COLUMNS)}. Fix: restore the "
        "column names (or pass a column map with --columns for another layout)"
    )


def _header_text(p: Path) -> str:
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            head = fh.readline(2000).strip()
    except OSError:
        return "(unreadable)"
    return repr(head[:200] + ("…" if len(head) > 200 else ""))


def resample_split(
    log: Log,
    dt: float,
    warn: Callable[[str], None] | None = None,
    limits: ResourceLimits | None = None,
    max_gap: float | None = None,
) -> list[Log]:
    """``log`` resampled to the step ``dt`` (s), split where its time stamps have gaps.

    ``max_gap`` (s) is the longest gap bridged (default ``limits.max_gap_steps`` steps).
    The pieces are marked ``meta["piece_of"]``; the diagnosis sets aside those too short
    to read.

    A gap longer than ``limits.max_gap_steps`` steps is never bridged by
    interpolation: the log is split there, each piece is resampled on its own
    and ``warn`` names the gap. Pieces shorter than 3 rows are dropped (and
    named). The number of rows is checked against the limits before any array
    is allocated.

    Raises
    ------
    LogError
        ``dt`` not a positive number, or the resampled log beyond the limits.
    """
    lim = limits if limits is not None else ResourceLimits.from_environment()
    say = warn if warn is not None else (lambda msg: None)
    try:
        dt = check_finite_float(dt, "--resample", low=0.0, strict_low=True, unit="s")
        if dt > log.duration / 2.0:
            raise ValueError(
                f"{log.source}: --resample {dt:g} s leaves fewer than 3 samples of this "
                f"{log.duration:.3g}-s log (one every {log.dt:.3g} s now). Fix: a step near "
                f"the log's own, e.g. --resample {log.dt:.2g}"
            )
        cols = sum(a.shape[1] for a in log.channels.values()) + 1
        check_rows_limit(int(log.duration / dt) + 1, cols, f"{log.source}: --resample {dt:g}", lim)
    except ValueError as exc:
        raise LogError(str(exc)) from None
    longest = max_gap if max_gap is not None else lim.max_gap_steps * dt
    gaps = np.flatnonzero(np.diff(log.t) > longest)
    bounds = [0, *(int(g) + 1 for g in gaps), log.n]
    for g in gaps:
        say(
            f"{log.source}: a gap of {log.t[g + 1] - log.t[g]:.6g} s after t={log.t[g]:.6g} s is "
            f"longer than {longest:g} s; the run is split "
            "there instead of inventing rows (--max-gap SECONDS, or REALITYGAP_MAX_GAP_STEPS, "
            "sets how long a gap may be bridged)"
        )
    out: list[Log] = []
    for k, (a, b) in enumerate(itertools.pairwise(bounds)):
        if b - a < 2 or int((log.t[b - 1] - log.t[a]) / dt) + 1 < 3:
            say(f"{log.source}: piece {k + 1} (rows {a}..{b - 1}) dropped: shorter than 3 steps")
            continue
        piece = log.slice(a, b) if len(bounds) > 2 else log
        res = piece.resampled(dt)
        if len(bounds) > 2:
            res = res.replace(
                meta={**res.meta, "name": f"{log.name}_part-{k + 1}", "piece_of": log.name}
            )
        out.append(res)
    return out


def _read_bag(p: Path, opt: ReadOptions, warn: Callable[[str], None] | None = None) -> list[Log]:
    from realitygap.diagnosis.logs.importers.rosbag import BagTopics, read_bag_logs

    topics = BagTopics(
        cmd=opt.cmd_topic,
        odom=opt.odom_topic,
        truth=opt.truth_topic,
        truth_frame=opt.truth_frame,
        wheels=opt.wheels_topic,
    )
    meta: dict[str, Any] = dict(opt.meta or {})
    if opt.firmware:
        meta["firmware"] = dict(opt.firmware)
    return read_bag_logs(
        p,
        topics,
        rate_hz=opt.rate_hz,
        params=opt.params,
        meta=meta or None,
        max_gap=opt.max_gap,
        warn=warn,
    )


def read_many(
    paths: Sequence[str | os.PathLike[str]],
    options: ReadOptions | None = None,
    warn: Callable[[str], None] | None = None,
) -> list[Log]:
    """:func:`read_logs` over several paths, concatenated.

    Raises
    ------
    LogError
        If no path gave a log (every run dropped), naming the paths.
    """
    check_read_options(options, warn, "read_many")
    if isinstance(paths, str | os.PathLike):
        raise TypeError(
            f"read_many: paths must be a list of file or folder names, got one: {paths!r:.80}. "
            "Fix: read_many([path]) or read_logs(path)"
        )
    out: list[Log] = []
    for path in paths:
        out += read_logs(path, options, warn)
    if paths and not out:
        raise LogError(
            f"no usable log in {', '.join(map(str, paths))}: every run was dropped (see the "
            "warnings above for each run and why)"
        )
    return out


__all__ += ["read_many"]
