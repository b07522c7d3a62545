"""Importer for OptiOdom session folders (differential drive, wheel ticks + OptiTrack).

Source: Sousa et al., "OptiOdom: a Generic Approach for Odometry Calibration of
Wheeled Mobile Robots", J. Intell. Robot. Syst. 105:39 (2022). A session
folder ``<ID>/`` holds:

``<ID>_metadata.csv``
    ``key,value[,value…]`` rows, trailing cells empty: ``type`` (robot kind,
    ``diff``), ``ngear`` (gear ratio), ``encRes`` (encoder counts per motor
    revolution), ``Li`` (wheelbase, m), ``Di`` (wheel diameters, m, **right
    first, then left**, as in the dataset's reference code), ``Thi`` (unused
    here), ``N`` (number of runs), ``L`` (square side, m; empty for other
    paths), ``imarkers`` (marker indices), and per run the synchronisation
    windows ``gt_ti, gt_tf`` (OptiTrack clock, s) and ``odo_ti, odo_tf``
    (odometry clock from the run start, s).
``<ID>_run-NN.csv``
    No header, 20 Hz: ``time [s], x_gt [m], y_gt [m], θ_gt [rad], ticks_R,
    ticks_L``; ticks are per 50 ms cycle, the ground truth is in the start
    frame with a continuous (unwrapped) heading.
``<ID>_run-NN_odo.csv``
    UTF-8 with byte-order mark, ``time [s] (robot clock), ticks_L, ticks_R``.
``<ID>.csv``
    The robot's own log: header rows (``Method:``, ``dL0(m):…``, …), rows of
    ``+`` separators, a column header and, after each ``Run:,k`` row, data rows
    ``time, odoL, odoR, xodo, yodo, thodo, vlin, omega, flag`` with the
    robot's tick increments, its on-board odometry and the **commanded**
    linear (ticks/cycle) and angular (rad/cycle) velocity. The ninth column is
    unnamed in the header; it is 1 on the last cycles of a run.
``<ID>_run-NN_opti.csv``
    (some sessions) raw 100 Hz OptiTrack export; not read.

Conventions established from the data (and checked by the tests):

* **Ticks per wheel revolution** are ``ngear · encRes`` (43.7 · 64 = 2796.8),
  without a further ×4: with it the 0.75 m squares would come out 0.19 m wide,
  and the robot's own odometry column confirms 1 tick = π·D/2796.8 m.
  :func:`infer_quadrature_factor` re-derives this from any session's ground truth.
* **Left/right**: in the run files column 5 is the right wheel; the robot log
  and the ``_odo`` files list the left wheel first.
* **Direction** of a run is taken from the sign of the ground-truth net
  rotation (``cw`` below −π/2, ``ccw`` above π/2, else ``None``), not from
  its index; for the square sessions here it agrees with the index rule
  (first half cw, second half ccw), and :attr:`OptiOdomSession.direction_mismatches`
  lists runs where it would not.
* **Robot-log alignment**: run ``k`` corresponds to the block after
  ``Run:,k`` in ``<ID>.csv``. The run's first row is located in that block by
  exact agreement of the per-cycle tick sequences (the ``_odo`` file's first
  time stamp, plus ``odo_ti``, is used to confirm or to break ties); see
  :class:`OptiOdomRun` ``alignment``.

Nothing here unpickles or executes data; malformed files raise
:class:`ValueError` naming the file, the line and what was expected.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.logs.importers.numeric_text import (
    make_readonly,
    numeric_file,
    numeric_rows,
    read_text_lines,
    whole_ticks,
)
from realitygap.estimators.diffdrive_model import DiffDriveKinematics

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Alignment = Literal["exact", "time", "ambiguous", "unavailable"]

__all__ = [
    "OptiOdomMetadata",
    "OptiOdomRobotLog",
    "OptiOdomRun",
    "OptiOdomSession",
    "PathType",
    "find_sessions",
    "infer_quadrature_factor",
    "read_session",
    "ticks_per_wheel_rev",
]

RUN_COLUMNS = ("time", "x_gt", "y_gt", "th_gt", "ticks_R", "ticks_L")
ODO_COLUMNS = ("time", "ticks_L", "ticks_R")
LOG_COLUMNS = ("time", "odoL", "odoR", "xodo", "yodo", "thodo", "vlin", "omega", "flag")
_RUN_FILE = re.compile(r"_run-(\d+)\.csv$")
_TIME_TOL = 1e-6


class PathType(str, Enum):
    """Kind of path driven in a session."""

    SQUARE = "square"
    CIRCULAR = "circular"
    IVANJKO = "ivanjko"
    FREE = "free"
    UNKNOWN = "unknown"


# Robot-log "Method:" text → path type (lower-case substrings).
_METHOD_PATH = (
    ("umbmark", PathType.SQUARE),
    ("borenstein", PathType.SQUARE),
    ("ivanjko", PathType.IVANJKO),
    ("free path", PathType.FREE),
    ("new method", PathType.CIRCULAR),
)


@dataclass(frozen=True)
class OptiOdomMetadata:
    """Contents of ``<ID>_metadata.csv``.

    Attributes
    ----------
    robot_type : str
        ``type`` (``"diff"`` for a differential drive).
    gear_ratio : float
        ``ngear``, motor turns per wheel turn.
    encoder_resolution : float
        ``encRes``, encoder counts per motor revolution as logged.
    wheelbase : float
        ``Li``, m.
    wheel_diameter_right, wheel_diameter_left : float
        ``Di`` (right first), m.
    n_runs : int or None
        ``N``.
    side_length : float or None
        ``L``, square side in m (``None`` for other paths).
    markers : tuple of int
        ``imarkers``.
    gt_t_start, gt_t_end, odo_t_start, odo_t_end : tuple of float
        Per-run synchronisation windows (s), possibly empty.
    values : dict of str to tuple of str
        Every row as read, trailing empty cells removed.
    """

    robot_type: str
    gear_ratio: float
    encoder_resolution: float
    wheelbase: float
    wheel_diameter_right: float
    wheel_diameter_left: float
    n_runs: int | None
    side_length: float | None
    markers: tuple[int, ...]
    gt_t_start: tuple[float, ...]
    gt_t_end: tuple[float, ...]
    odo_t_start: tuple[float, ...]
    odo_t_end: tuple[float, ...]
    values: dict[str, tuple[str, ...]] = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class OptiOdomRobotLog:
    """The robot-log block of one run (robot clock, 20 Hz, one row per control cycle).

    Attributes
    ----------
    time : ndarray, shape (M,)
        Robot clock, s.
    ticks_left, ticks_right : ndarray, shape (M,), int
        Tick increments of the cycle.
    odo_pose : ndarray, shape (M, 3)
        The robot's on-board odometry ``[x, y, θ]`` (m, m, rad), as printed
        (4 significant digits), continuous heading.
    cmd_linear : ndarray, shape (M,)
        Commanded linear velocity, ticks/cycle.
    cmd_angular : ndarray, shape (M,)
        Commanded angular velocity, rad/cycle.
    flag : ndarray, shape (M,), int
        Unnamed ninth column (1 on the final cycles of a run).
    first_line : int
        1-based line number of the block's first data row in ``<ID>.csv``.
    """

    time: FloatArray
    ticks_left: IntArray
    ticks_right: IntArray
    odo_pose: FloatArray
    cmd_linear: FloatArray
    cmd_angular: FloatArray
    flag: IntArray
    first_line: int


@dataclass(frozen=True)
class OptiOdomRun:
    """One run: synchronised ground truth and ticks, plus the robot-log slice.

    Attributes
    ----------
    index : int
        Run number ``NN`` (1-based).
    path : Path
        The ``_run-NN.csv`` file.
    time : ndarray, shape (N,)
        s, from 0, 20 Hz.
    gt_pose : ndarray, shape (N, 3)
        Ground-truth base pose ``[x, y, θ]`` (m, m, rad) in the start frame
        (``gt_pose[0] = 0``, x along the initial heading, y left), continuous heading.
    ticks_right, ticks_left : ndarray, shape (N,), int
        Tick increments; row ``k`` holds the ticks counted in the cycle ending
        at ``time[k]``. The odometry pose at row ``k`` is therefore the
        integral of rows ``0..k`` (see :meth:`odometry`).
    direction : {"cw", "ccw"} or None
        From the sign of the ground-truth net rotation (``None`` if
        ``|net| < π/2``, e.g. straight runs).
    net_rotation : float
        Ground-truth heading change over the run, rad.
    robot_log : OptiOdomRobotLog or None
        The whole ``Run:,k`` block of ``<ID>.csv`` (robot clock, usually longer
        than the run), ``None`` if the session has no robot log or no such block.
    alignment : {"exact", "time", "ambiguous", "unavailable"}
        How run rows were matched to robot-log rows: ``"exact"`` — the tick
        sequences agree row by row at a unique offset (or at the offset
        confirmed by the ``_odo`` time stamps); ``"time"`` — only the time
        stamps line up, the ticks disagree; ``"ambiguous"`` — several offsets
        fit equally; ``"unavailable"`` — no robot-log block or nothing fits.
    robot_log_offset : int or None
        Index into ``robot_log`` of run row 0 (``"exact"``/``"time"`` only).
    robot_time_offset : float or None
        ``robot clock − run time``, s.
    cmd_linear, cmd_angular : ndarray, shape (N,), or None
        Commanded velocities (ticks/cycle, rad/cycle) aligned to the run rows,
        as logged on the same cycle; ``None`` unless ``alignment`` is
        ``"exact"`` or ``"time"``.
    """

    index: int
    path: Path
    time: FloatArray
    gt_pose: FloatArray
    ticks_right: IntArray
    ticks_left: IntArray
    direction: Literal["cw", "ccw"] | None
    net_rotation: float
    robot_log: OptiOdomRobotLog | None
    alignment: Alignment
    robot_log_offset: int | None
    robot_time_offset: float | None
    cmd_linear: FloatArray | None
    cmd_angular: FloatArray | None

    @property
    def n(self) -> int:
        """Number of rows."""
        return int(self.time.shape[0])

    def odometry(self, kinematics: DiffDriveKinematics) -> FloatArray:
        """Dead-reckoned poses at the run rows, shape (N, 3), start frame, continuous heading."""
        return kinematics.integrate(np.zeros(3), self.ticks_left, self.ticks_right, wrap=False)[1:]


@dataclass(frozen=True)
class OptiOdomSession:
    """One OptiOdom session folder.

    Attributes
    ----------
    session_id : str
        Folder name ``<ID>`` (recording date and time, ``DDMMYYYYhhmm``).
    path : Path
        The folder.
    path_type : PathType
        From metadata ``type`` if it names a path, else the parent folder
        name, else the robot log's ``Method:`` line.
    path_type_source : str
        ``"metadata"``, ``"folder"``, ``"robot log"`` or ``"none"``.
    metadata : OptiOdomMetadata
    runs : tuple of OptiOdomRun
        Runs whose ``_run-NN.csv`` exists, sorted by index.
    robot_log_header : dict of str to tuple of str
        Header rows of ``<ID>.csv`` (e.g. ``"Method"``, ``"dL0(m)"``, ``"b0(m)"``).
    """

    session_id: str
    path: Path
    path_type: PathType
    path_type_source: str
    metadata: OptiOdomMetadata
    runs: tuple[OptiOdomRun, ...]
    robot_log_header: dict[str, tuple[str, ...]] = field(default_factory=dict, compare=False)

    def kinematics(self, quadrature_factor: int = 1) -> DiffDriveKinematics:
        """Nominal kinematics of the session (wheel diameters, wheelbase, resolution)."""
        m = self.metadata
        return DiffDriveKinematics.from_diameters(
            m.wheel_diameter_left,
            m.wheel_diameter_right,
            m.wheelbase,
            ticks_per_wheel_rev(m, quadrature_factor),
        )

    @property
    def direction_mismatches(self) -> tuple[int, ...]:
        """Square runs whose ground-truth direction contradicts the index rule.

        The rule: of ``n`` runs the first ``n/2`` are cw, the rest ccw.
        """
        if self.path_type is not PathType.SQUARE or not self.runs:
            return ()
        n = len(self.runs)
        bad = []
        for pos, run in enumerate(self.runs):
            expected = "cw" if pos < n // 2 else "ccw"
            if run.direction != expected:
                bad.append(run.index)
        return tuple(bad)


# ---------------------------------------------------------------------------
# metadata
# ---------------------------------------------------------------------------


def read_metadata(path: Path) -> OptiOdomMetadata:
    lines = read_text_lines(path)
    values: dict[str, tuple[str, ...]] = {}
    where: dict[str, int] = {}
    for i, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        cells = [c.strip() for c in line.split(",")]
        key = cells[0]
        if not key:
            if any(cells):
                raise ValueError(
                    f"{path}, line {i}: expected 'key,value[,value…]' with a key in the first "
                    f"cell, got {line.strip()!r}"
                )
            continue
        if key in values:
            raise ValueError(f"{path}, line {i}: key {key!r} repeated (first on line {where[key]})")
        vals = cells[1:]
        while vals and vals[-1] == "":
            vals.pop()
        values[key] = tuple(vals)
        where[key] = i
    if not values:
        raise ValueError(f"{path}: empty metadata file, expected 'key,value' rows")

    def number(key: str, *, required: bool, index: int = 0) -> float | None:
        vals = values.get(key)
        if vals is None or len(vals) <= index or vals[index] == "":
            if required:
                line = f", line {where[key]}" if key in where else ""
                raise ValueError(
                    f"{path}{line}: missing value for {key!r} (expected a number"
                    f"{' in cell ' + str(index + 2) if index else ''})"
                )
            return None
        try:
            v = float(vals[index])
        except ValueError:
            raise ValueError(
                f"{path}, line {where[key]}: {key!r} must be a number, got {vals[index]!r}"
            ) from None
        if not math.isfinite(v):
            raise ValueError(f"{path}, line {where[key]}: {key!r} must be finite, got {v}")
        return v

    def numbers(key: str) -> tuple[float, ...]:
        out = []
        for j, text in enumerate(values.get(key, ())):
            if text == "":
                continue
            try:
                out.append(float(text))
            except ValueError:
                raise ValueError(
                    f"{path}, line {where[key]}, cell {j + 2}: {key!r} values must be numbers, "
                    f"got {text!r}"
                ) from None
        return tuple(out)

    robot_type = values.get("type", ("",))[0] if values.get("type") else ""
    if not robot_type:
        raise ValueError(f"{path}: missing 'type' row (robot kind, e.g. 'type,diff')")
    gear = number("ngear", required=True)
    enc = number("encRes", required=True)
    wheelbase = number("Li", required=True)
    d_right = number("Di", required=True, index=0)
    d_left = number("Di", required=False, index=1)
    assert gear is not None and enc is not None and wheelbase is not None and d_right is not None
    for key, v in (("ngear", gear), ("encRes", enc), ("Li", wheelbase), ("Di", d_right)):
        if v <= 0:
            raise ValueError(f"{path}, line {where[key]}: {key!r} must be > 0, got {v}")
    if d_left is None:
        d_left = d_right
    elif d_left <= 0:
        raise ValueError(f"{path}, line {where['Di']}: 'Di' must be > 0, got {d_left}")
    n_runs = number("N", required=False)
    side = number("L", required=False)
    if n_runs is not None and (n_runs < 0 or n_runs != int(n_runs)):
        raise ValueError(f"{path}, line {where['N']}: 'N' must be a whole number, got {n_runs}")
    return OptiOdomMetadata(
        robot_type=robot_type,
        gear_ratio=gear,
        encoder_resolution=enc,
        wheelbase=wheelbase,
        wheel_diameter_right=d_right,
        wheel_diameter_left=d_left,
        n_runs=None if n_runs is None else int(n_runs),
        side_length=side,
        markers=tuple(int(v) for v in numbers("imarkers")),
        gt_t_start=numbers("gt_ti"),
        gt_t_end=numbers("gt_tf"),
        odo_t_start=numbers("odo_ti"),
        odo_t_end=numbers("odo_tf"),
        values=values,
    )


def ticks_per_wheel_rev(
    meta: OptiOdomMetadata | OptiOdomSession, quadrature_factor: int = 1
) -> float:
    """Encoder ticks per wheel revolution, ``ngear · encRes · quadrature_factor``.

    Parameters
    ----------
    meta : OptiOdomMetadata or OptiOdomSession
    quadrature_factor : int, default 1
        Extra edge-counting factor. The logged ticks need none: ``encRes``
        already counts every edge (see the module notes and
        :func:`infer_quadrature_factor`).
    """
    m = meta.metadata if isinstance(meta, OptiOdomSession) else meta
    if quadrature_factor not in (1, 2, 4):
        raise ValueError(f"quadrature_factor must be 1, 2 or 4, got {quadrature_factor!r}")
    return m.gear_ratio * m.encoder_resolution * quadrature_factor


def infer_quadrature_factor(
    session: OptiOdomSession, candidates: tuple[int, ...] = (1, 2, 4)
) -> int:
    """Choose the edge-counting factor that makes odometry redraw the ground truth.

    For each candidate the runs are dead-reckoned with the session's nominal
    kinematics and compared with the ground truth over the whole run (mean of
    position error plus ``wheelbase · |heading error|``). A wrong factor scales
    distances and rotations and is off by tens of centimetres.

    Raises
    ------
    ValueError
        If the session has no run or the best candidate is not clearly (2×)
        better than the next.
    """
    if not session.runs:
        raise ValueError(f"session {session.session_id} has no run to infer the tick factor from")
    scores = []
    for factor in candidates:
        kin = session.kinematics(factor)
        err = []
        for run in session.runs:
            odo = run.odometry(kin)
            pos = np.hypot(*(odo[:, :2] - run.gt_pose[:, :2]).T)
            head = np.abs(odo[:, 2] - run.gt_pose[:, 2])
            err.append(float(np.mean(pos + kin.wheelbase * head)))
        scores.append(float(np.mean(err)))
    order = np.argsort(scores)
    best, second = scores[order[0]], scores[order[1]] if len(scores) > 1 else math.inf
    if not best < 0.5 * second:
        raise ValueError(
            f"session {session.session_id}: tick factor ambiguous, mean errors "
            f"{dict(zip(candidates, scores))} m"
        )
    return int(candidates[order[0]])


# ---------------------------------------------------------------------------
# robot log
# ---------------------------------------------------------------------------


def _read_robot_log(
    path: Path,
) -> tuple[dict[str, tuple[str, ...]], dict[int, OptiOdomRobotLog]]:
    lines = read_text_lines(path)
    header: dict[str, tuple[str, ...]] = {}
    blocks: dict[int, list[tuple[int, str]]] = {}
    current: int | None = None
    for i, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped:
            continue
        cells = [c.strip() for c in stripped.split(",")]
        if all(c and set(c) == {"+"} for c in cells):
            continue  # separator row
        first = cells[0]
        if first == "Run:":
            try:
                current = int(cells[1])
            except (IndexError, ValueError):
                raise ValueError(
                    f"{path}, line {i}: expected 'Run:,<run number>', got {stripped!r}"
                ) from None
            if current in blocks:
                raise ValueError(f"{path}, line {i}: run {current} appears twice")
            blocks[current] = []
            continue
        if first.lower().startswith("time"):
            header["columns"] = tuple(c.rstrip(":") for c in cells if c)
            continue
        if first.endswith(":"):
            if current is not None:
                raise ValueError(
                    f"{path}, line {i}: header row {first!r} after the first 'Run:' row"
                )
            for k in range(0, len(cells), 2):
                if cells[k]:
                    header[cells[k].rstrip(":")] = tuple(v for v in cells[k + 1 : k + 2] if v)
            continue
        if current is None:
            raise ValueError(
                f"{path}, line {i}: data row before the first 'Run:,<n>' row; expected header "
                f"rows ('key:,value'), '+++' separators or 'Run:' first, got {stripped!r}"
            )
        blocks[current].append((i, line))
    runs: dict[int, OptiOdomRobotLog] = {}
    for k, numbered in blocks.items():
        if not numbered:
            runs[k] = OptiOdomRobotLog(
                time=np.zeros(0),
                ticks_left=np.zeros(0, np.int64),
                ticks_right=np.zeros(0, np.int64),
                odo_pose=np.zeros((0, 3)),
                cmd_linear=np.zeros(0),
                cmd_angular=np.zeros(0),
                flag=np.zeros(0, np.int64),
                first_line=0,
            )
            continue
        data = numeric_rows(path, numbered, LOG_COLUMNS)
        first_line = numbered[0][0]
        log = OptiOdomRobotLog(
            time=data[:, 0].copy(),
            ticks_left=whole_ticks(path, data[:, 1], "odoL", first_line),
            ticks_right=whole_ticks(path, data[:, 2], "odoR", first_line),
            odo_pose=data[:, 3:6].copy(),
            cmd_linear=data[:, 6].copy(),
            cmd_angular=data[:, 7].copy(),
            flag=np.rint(data[:, 8]).astype(np.int64),
            first_line=first_line,
        )
        make_readonly(
            log.time,
            log.ticks_left,
            log.ticks_right,
            log.odo_pose,
            log.cmd_linear,
            log.cmd_angular,
            log.flag,
        )
        runs[k] = log
    return header, runs


def _tick_offsets(log: OptiOdomRobotLog, t_left: IntArray, t_right: IntArray) -> list[int]:
    """Offsets ``j`` with ``log ticks[j : j + N] == run ticks``."""
    n, m = t_left.shape[0], log.ticks_left.shape[0]
    if n == 0 or n > m:
        return []
    moving = np.flatnonzero((t_left != 0) | (t_right != 0))
    r = int(moving[0]) if moving.size else 0
    cand = np.flatnonzero((log.ticks_left == t_left[r]) & (log.ticks_right == t_right[r])) - r
    out = []
    for j in cand[(cand >= 0) & (cand <= m - n)]:
        j = int(j)
        if np.array_equal(log.ticks_left[j : j + n], t_left) and np.array_equal(
            log.ticks_right[j : j + n], t_right
        ):
            out.append(j)
    return out


def _align(
    log: OptiOdomRobotLog | None,
    time: FloatArray,
    t_left: IntArray,
    t_right: IntArray,
    odo_start_time: float | None,
) -> tuple[Alignment, int | None]:
    if log is None or log.time.shape[0] == 0:
        return "unavailable", None
    time_offset = None
    if odo_start_time is not None:
        hit = np.flatnonzero(np.abs(log.time - odo_start_time) < _TIME_TOL)
        if hit.size == 1 and hit[0] + time.shape[0] <= log.time.shape[0]:
            time_offset = int(hit[0])
    offsets = _tick_offsets(log, t_left, t_right)
    if len(offsets) == 1:
        return "exact", offsets[0]
    if len(offsets) > 1:
        if time_offset is not None and time_offset in offsets:
            return "exact", time_offset
        return "ambiguous", None
    if time_offset is not None:
        return "time", time_offset
    return "unavailable", None


# ---------------------------------------------------------------------------
# sessions
# ---------------------------------------------------------------------------


def _run_direction(theta: FloatArray) -> tuple[Literal["cw", "ccw"] | None, float]:
    if theta.shape[0] < 2:
        return None, 0.0
    d = np.diff(theta)
    net = float(np.sum((d + np.pi) % (2.0 * np.pi) - np.pi))
    if net <= -0.5 * math.pi:
        return "cw", net
    if net >= 0.5 * math.pi:
        return "ccw", net
    return None, net


def _read_run(
    path: Path,
    index: int,
    log: OptiOdomRobotLog | None,
    odo_path: Path,
    odo_t_start: float,
) -> OptiOdomRun:
    data = numeric_file(path, RUN_COLUMNS)
    time = data[:, 0].copy()
    if time.shape[0] > 1 and not np.all(np.diff(time) > 0):
        i = int(np.flatnonzero(np.diff(time) <= 0)[0]) + 2
        raise ValueError(f"{path}, line {i}: time must increase strictly, got {time[i - 1]!r}")
    gt = data[:, 1:4].copy()
    # Express in the frame of the first pose (already the case in the dataset).
    c, s = math.cos(gt[0, 2]), math.sin(gt[0, 2])
    dx, dy = gt[:, 0] - gt[0, 0], gt[:, 1] - gt[0, 1]
    gt = np.column_stack([c * dx + s * dy, -s * dx + c * dy, gt[:, 2] - gt[0, 2]])
    t_right = whole_ticks(path, data[:, 4], "ticks_R")
    t_left = whole_ticks(path, data[:, 5], "ticks_L")
    direction, net = _run_direction(gt[:, 2])

    odo_start = None
    if odo_path.is_file():
        odo = numeric_file(odo_path, ODO_COLUMNS)
        odo_start = float(odo[0, 0]) + odo_t_start
    alignment, offset = _align(log, time, t_left, t_right, odo_start)
    cmd_lin = cmd_ang = None
    time_offset = None
    if offset is not None and log is not None:
        n = time.shape[0]
        cmd_lin = log.cmd_linear[offset : offset + n].copy()
        cmd_ang = log.cmd_angular[offset : offset + n].copy()
        time_offset = float(log.time[offset] - time[0])
    make_readonly(time, gt, t_right, t_left, cmd_lin, cmd_ang)
    return OptiOdomRun(
        index=index,
        path=path,
        time=time,
        gt_pose=gt,
        ticks_right=t_right,
        ticks_left=t_left,
        direction=direction,
        net_rotation=net,
        robot_log=log,
        alignment=alignment,
        robot_log_offset=offset,
        robot_time_offset=time_offset,
        cmd_linear=cmd_lin,
        cmd_angular=cmd_ang,
    )


def _path_type(
    meta: OptiOdomMetadata, folder: Path, header: dict[str, tuple[str, ...]]
) -> tuple[PathType, str]:
    known = {p.value for p in PathType if p is not PathType.UNKNOWN}
    if meta.robot_type.lower() in known:
        return PathType(meta.robot_type.lower()), "metadata"
    parent = folder.resolve().parent.name.lower()
    if parent in known:
        return PathType(parent), "folder"
    method = " ".join(header.get("Method", ())).lower()
    for needle, kind in _METHOD_PATH:
        if needle in method:
            return kind, "robot log"
    return PathType.UNKNOWN, "none"


def read_session(folder: str | Path) -> OptiOdomSession:
    """Read one OptiOdom session folder.

    Parameters
    ----------
    folder : str or Path
        The ``<ID>/`` folder holding ``<ID>_metadata.csv`` and ``<ID>_run-NN.csv``.

    Returns
    -------
    OptiOdomSession

    Raises
    ------
    FileNotFoundError
        If the folder or its metadata file does not exist.
    ValueError
        If a file is malformed (the message names the file, the line and
        what was expected) or the folder holds no run file.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"OptiOdom session folder not found: {folder}")
    sid = folder.name
    meta_path = folder / f"{sid}_metadata.csv"
    if not meta_path.is_file():
        raise FileNotFoundError(
            f"{folder} is not an OptiOdom session: missing {meta_path.name} "
            "(expected <ID>/<ID>_metadata.csv)"
        )
    meta = read_metadata(meta_path)
    log_path = folder / f"{sid}.csv"
    header: dict[str, tuple[str, ...]] = {}
    logs: dict[int, OptiOdomRobotLog] = {}
    if log_path.is_file():
        header, logs = _read_robot_log(log_path)

    run_files = []
    for p in folder.iterdir():
        if p.name.startswith(f"{sid}_run-"):
            m = _RUN_FILE.search(p.name)
            if m and p.name == f"{sid}_run-{m.group(1)}.csv":
                run_files.append((int(m.group(1)), p))
    if not run_files:
        raise ValueError(f"{folder}: no run file, expected {sid}_run-01.csv, …")
    runs = []
    for index, p in sorted(run_files):
        k = index - 1
        odo_t_start = meta.odo_t_start[k] if k < len(meta.odo_t_start) else 0.0
        odo_path = folder / f"{sid}_run-{index:02d}_odo.csv"
        runs.append(_read_run(p, index, logs.get(index), odo_path, odo_t_start))
    path_type, source = _path_type(meta, folder, header)
    return OptiOdomSession(
        session_id=sid,
        path=folder,
        path_type=path_type,
        path_type_source=source,
        metadata=meta,
        runs=tuple(runs),
        robot_log_header=header,
    )


def find_sessions(root: str | Path) -> list[Path]:
    """Session folders below ``root`` (any depth), sorted.

    A session folder ``<ID>/`` is recognised by its ``<ID>_metadata.csv``;
    ``root`` itself may be one.

    Raises
    ------
    FileNotFoundError
        If ``root`` is not a directory.
    """
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"OptiOdom data folder not found: {root}")
    found = {
        p.parent for p in root.rglob("*_metadata.csv") if p.name == f"{p.parent.name}_metadata.csv"
    }
    return sorted(found)
