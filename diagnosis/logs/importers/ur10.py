"""Reader for UR10 laser-tracker accuracy data (Fraunhofer IPA layout).

Folder layout::

    <root>/Series_<X>/measurements_<name>.csv     one or more per series
    <root>/Series_<X>/Trafo_TM_F_init.txt          4x4, mm
    <root>/Series_<X>/Trafo_TM_F_init_calib.txt    4x4, mm (optional)
    <root>/Series_<X>/calibration_handeye.csv      optional

Measurement files are ``;``-separated with a decimal comma. Columns used:
``Goal x/y/z`` (m) and ``Goal roll/pitch/yaw`` (rad) — the commanded probe pose
in the robot base; the six joint angles (rad) ``shoulder_pan_joint`` …
``wrist_3_joint``; ``measurement_temperature`` (°C); ``measurement_x/y/z`` (mm)
and ``measurement_rx/ry/rz`` (deg, intrinsic XYZ) — the probe pose in the
tracker frame; optionally ``measurement_std_*`` (same units). The
``Timestamp`` column may have been mangled by a spreadsheet (``2,02011E+13``);
rows are then taken in file order and :attr:`UR10Series.timestamps_valid` is False.

``Trafo_TM_F`` files hold the pose of the flange in the probe (T-Mac) frame,
:math:`T_{\\mathrm{probe},\\mathrm{flange}}`, in mm: its inverse puts the probe
0.109 m along the flange z axis. They are returned in m.

All returned lengths are in m, angles in rad (except the raw Euler angles in
deg, kept for reference).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from realitygap.diagnosis.logs.schema import check_values

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "JOINT_COLUMNS",
    "REQUIRED_COLUMNS",
    "UR10Dataset",
    "UR10HandEyeData",
    "UR10Series",
    "read_transform_txt",
    "read_ur10_dataset",
    "read_ur10_handeye_csv",
    "read_ur10_measurements",
]

#: Joint-angle columns in joint order.
JOINT_COLUMNS: tuple[str, ...] = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
_REQUIRED = (
    "Goal x",
    "Goal y",
    "Goal z",
    "Goal roll",
    "Goal pitch",
    "Goal yaw",
    *JOINT_COLUMNS,
    "measurement_temperature",
    "measurement_x",
    "measurement_y",
    "measurement_z",
    "measurement_rx",
    "measurement_ry",
    "measurement_rz",
)
REQUIRED_COLUMNS: tuple[str, ...] = _REQUIRED
"""The columns every UR10 measurement file has (besides ``Timestamp``)."""

_STD = (
    "measurement_std_x",
    "measurement_std_y",
    "measurement_std_z",
    "measurement_std_rx",
    "measurement_std_ry",
    "measurement_std_rz",
)
_HANDEYE = (
    "flange_x",
    "flange_y",
    "flange_z",
    "flange_qx",
    "flange_qy",
    "flange_qz",
    "flange_qw",
    "measurement_x",
    "measurement_y",
    "measurement_z",
    "measurement_rx",
    "measurement_ry",
    "measurement_rz",
)
_NUMBER = re.compile(r"^[+-]?(\d+([.,]\d*)?|[.,]\d+)([eE][+-]?\d+)?$")
_TIMESTAMP = re.compile(r"^\d{14}$")


@dataclass(frozen=True)
class UR10Series:
    """One measurement file of a UR10 series.

    Attributes
    ----------
    name : str
        ``"<series folder>/<file stem>"``.
    source : str
        Path of the CSV file.
    joint_angles : ndarray, shape (N, 6)
        Joint readings (rad), in file order.
    probe_positions : ndarray, shape (N, 3)
        Probe positions in the tracker frame (m).
    probe_rotations : ndarray, shape (N, 3, 3)
        :math:`R_{\\mathrm{tracker},\\mathrm{probe}}` from intrinsic XYZ Euler angles.
    probe_euler_deg : ndarray, shape (N, 3)
        The raw ``rx, ry, rz`` (deg).
    goal_positions : ndarray, shape (N, 3)
        Commanded probe positions in the robot base (m).
    goal_rpy : ndarray, shape (N, 3)
        Commanded roll, pitch, yaw (rad).
    temperature_c : ndarray, shape (N,)
        Temperature at measurement (°C).
    position_std : ndarray, shape (N, 3) or None
        Tracker standard deviation of the position (m), when given.
    rotation_std_deg : ndarray, shape (N, 3) or None
        Standard deviation of the Euler angles (deg), when given.
    timestamps : tuple of str
        Raw ``Timestamp`` cells.
    timestamps_valid : bool
        True when every timestamp is a 14-digit ``YYYYMMDDhhmmss``.
    T_probe_flange : ndarray, shape (4, 4) or None
        ``Trafo_TM_F_init.txt`` of the series (m).
    T_probe_flange_calib : ndarray, shape (4, 4) or None
        ``Trafo_TM_F_init_calib.txt`` of the series (m).
    """

    name: str
    source: str
    joint_angles: FloatArray
    probe_positions: FloatArray
    probe_rotations: FloatArray
    probe_euler_deg: FloatArray
    goal_positions: FloatArray
    goal_rpy: FloatArray
    temperature_c: FloatArray
    position_std: FloatArray | None
    rotation_std_deg: FloatArray | None
    timestamps: tuple[str, ...]
    timestamps_valid: bool
    T_probe_flange: FloatArray | None
    T_probe_flange_calib: FloatArray | None

    @property
    def n(self) -> int:
        """Number of poses."""
        return int(self.joint_angles.shape[0])

    @property
    def probe_in_flange(self) -> FloatArray:
        """Probe point in the flange frame (3,) (m), from ``T_probe_flange``.

        Falls back to the nominal ``(0, 0, 0.109)`` when the series has no transform.
        """
        if self.T_probe_flange is None:
            return np.array([0.0, 0.0, 0.109])
        return np.linalg.inv(self.T_probe_flange)[:3, 3].copy()


@dataclass(frozen=True)
class UR10HandEyeData:
    """``calibration_handeye.csv``: flange poses from the controller vs tracker readings.

    Attributes
    ----------
    source : str
    flange_positions : ndarray, shape (M, 3)
        Flange position in the robot base (m).
    flange_quat_xyzw : ndarray, shape (M, 4)
        Flange orientation in the robot base, unit quaternion ``x, y, z, w``.
    probe_positions : ndarray, shape (M, 3)
        Probe position in the tracker frame (m).
    probe_rotations : ndarray, shape (M, 3, 3)
        From intrinsic XYZ Euler angles.
    probe_euler_deg : ndarray, shape (M, 3)
    """

    source: str
    flange_positions: FloatArray
    flange_quat_xyzw: FloatArray
    probe_positions: FloatArray
    probe_rotations: FloatArray
    probe_euler_deg: FloatArray


@dataclass(frozen=True)
class UR10Dataset:
    """All series of a dataset folder (sorted by name) and the hand–eye data, if any."""

    root: str
    series: tuple[UR10Series, ...]
    handeye: UR10HandEyeData | None

    def get(self, name: str) -> UR10Series:
        """The series whose name or folder equals ``name`` (e.g. ``"Series_A"``)."""
        hits = [s for s in self.series if s.name == name or s.name.split("/")[0] == name]
        if len(hits) != 1:
            raise KeyError(
                f"{len(hits)} series match {name!r}; available: {[s.name for s in self.series]}"
            )
        return hits[0]


# --------------------------------------------------------------------------- parsing
def _parse_number(text: str, path: Path, line: int, column: str, expected: str) -> float:
    t = text.strip()
    if not _NUMBER.match(t):
        raise ValueError(
            f"{path.name}, line {line}, column {column!r}: expected {expected}, got {text!r}"
        )
    return float(t.replace(",", "."))


def _read_table(
    path: Path, required: tuple[str, ...], optional: tuple[str, ...] = ()
) -> tuple[dict[str, FloatArray], list[str], list[str]]:
    """Parse a ``;``-separated, decimal-comma table.

    Returns numeric columns by name (required + the optional ones present), the
    raw first column and the header.
    """
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path.name}: not a UTF-8 text file ({exc.reason})") from exc
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise ValueError(f"{path.name}, line 1: expected a header row, the file is empty")
    header = [h.strip() for h in lines[0].split(";")]
    missing = [c for c in required if c not in header]
    if missing:
        raise ValueError(
            f"{path.name}, line 1: missing column(s) {missing}; expected {list(required)}, "
            f"found {header}"
        )
    wanted = list(required) + [c for c in optional if c in header]
    idx = {c: header.index(c) for c in wanted}
    cols: dict[str, list[float]] = {c: [] for c in wanted}
    first: list[str] = []
    for ln, raw in enumerate(lines[1:], start=2):
        if not raw.strip():
            continue
        cells = raw.split(";")
        if len(cells) != len(header):
            raise ValueError(
                f"{path.name}, line {ln}: expected {len(header)} fields separated by ';', "
                f"got {len(cells)}"
            )
        first.append(cells[0].strip())
        for c in wanted:
            cols[c].append(
                _parse_number(cells[idx[c]], path, ln, c, "a number (decimal comma allowed)")
            )
    if not first:
        raise ValueError(f"{path.name}: no data rows after the header")
    out = {c: np.asarray(v, dtype=float) for c, v in cols.items()}
    for c, v in out.items():
        bad = np.nonzero(~np.isfinite(v))[0]
        if bad.size:
            raise ValueError(
                f"{path.name}, line {int(bad[0]) + 2}, column {c!r}: expected a finite number"
            )
    return out, first, header


def read_transform_txt(path: str | Path) -> FloatArray:
    """Read a whitespace-separated 4×4 homogeneous transform in mm; return it in m.

    Raises
    ------
    ValueError
        Naming the file and line when a row does not hold four numbers, the last
        row is not ``0 0 0 1`` or the rotation is not orthonormal.
    """
    p = Path(path)
    rows = [ln for ln in p.read_text(encoding="utf-8-sig").splitlines() if ln.strip()]
    if len(rows) != 4:
        raise ValueError(f"{p.name}: expected 4 rows of a 4x4 transform, got {len(rows)}")
    T = np.zeros((4, 4))
    for i, ln in enumerate(rows):
        cells = ln.split()
        if len(cells) != 4:
            raise ValueError(f"{p.name}, line {i + 1}: expected 4 numbers, got {len(cells)}")
        for j, c in enumerate(cells):
            T[i, j] = _parse_number(c, p, i + 1, f"column {j + 1}", "a number")
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise ValueError(f"{p.name}, line 4: expected '0 0 0 1', got {T[3].tolist()}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
        raise ValueError(f"{p.name}: the upper-left 3x3 block is not a rotation matrix")
    T[:3, 3] /= 1000.0
    return T


def read_ur10_measurements(
    path: str | Path,
    T_probe_flange: FloatArray | None = None,
    T_probe_flange_calib: FloatArray | None = None,
    name: str | None = None,
) -> UR10Series:
    """Read one ``measurements_*.csv`` file.

    Parameters
    ----------
    path : str or Path
    T_probe_flange, T_probe_flange_calib : ndarray, shape (4, 4), optional
        Probe transforms of the series (m), attached to the result.
    name : str, optional
        Series name; the file stem by default.

    Raises
    ------
    ValueError
        Naming file, line, column and what was expected for garbled content.
    """
    p = Path(path)
    cols, first, _ = _read_table(p, _REQUIRED, _STD)
    q = np.column_stack([cols[c] for c in JOINT_COLUMNS])
    check_values("joints", q, p.name, lines=np.arange(2, q.shape[0] + 2))
    pos = np.column_stack([cols["measurement_x"], cols["measurement_y"], cols["measurement_z"]])
    eul = np.column_stack([cols["measurement_rx"], cols["measurement_ry"], cols["measurement_rz"]])
    has_std = all(c in cols for c in _STD)
    return UR10Series(
        name=name or p.stem,
        source=str(p),
        joint_angles=q,
        probe_positions=pos / 1000.0,
        probe_rotations=Rotation.from_euler("XYZ", eul, degrees=True).as_matrix(),
        probe_euler_deg=eul,
        goal_positions=np.column_stack([cols["Goal x"], cols["Goal y"], cols["Goal z"]]),
        goal_rpy=np.column_stack([cols["Goal roll"], cols["Goal pitch"], cols["Goal yaw"]]),
        temperature_c=cols["measurement_temperature"],
        position_std=(np.column_stack([cols[c] for c in _STD[:3]]) / 1000.0 if has_std else None),
        rotation_std_deg=np.column_stack([cols[c] for c in _STD[3:]]) if has_std else None,
        timestamps=tuple(first),
        timestamps_valid=all(_TIMESTAMP.match(t) for t in first),
        T_probe_flange=T_probe_flange,
        T_probe_flange_calib=T_probe_flange_calib,
    )


def read_ur10_handeye_csv(path: str | Path) -> UR10HandEyeData:
    """Read ``calibration_handeye.csv`` (flange pose in m / quaternion, tracker in mm / deg)."""
    p = Path(path)
    cols, _, _ = _read_table(p, _HANDEYE)
    quat = np.column_stack([cols[c] for c in _HANDEYE[3:7]])
    nq = np.linalg.norm(quat, axis=1)
    bad = np.nonzero(np.abs(nq - 1.0) > 1e-3)[0]
    if bad.size:
        raise ValueError(
            f"{p.name}, line {int(bad[0]) + 2}, columns flange_qx..qw: expected a unit "
            f"quaternion, norm is {nq[bad[0]]:.4f}"
        )
    eul = np.column_stack([cols[c] for c in _HANDEYE[10:13]])
    return UR10HandEyeData(
        source=str(p),
        flange_positions=np.column_stack([cols[c] for c in _HANDEYE[:3]]),
        flange_quat_xyzw=quat / nq[:, None],
        probe_positions=np.column_stack([cols[c] for c in _HANDEYE[7:10]]) / 1000.0,
        probe_rotations=Rotation.from_euler("XYZ", eul, degrees=True).as_matrix(),
        probe_euler_deg=eul,
    )


def read_ur10_dataset(root: str | Path) -> UR10Dataset:
    """Read every ``Series_*/measurements_*.csv`` under ``root`` with its transforms.

    Raises
    ------
    FileNotFoundError
        When ``root`` does not exist or holds no measurement file.
    ValueError
        For garbled files (file, line, column, expected).
    """
    r = Path(root)
    if not r.is_dir():
        raise FileNotFoundError(f"{r} is not a directory")
    files = sorted(r.glob("Series_*/measurements_*.csv"))
    if not files:
        raise FileNotFoundError(f"no Series_*/measurements_*.csv under {r}")
    series = []
    handeye = None
    for f in files:
        d = f.parent
        init = d / "Trafo_TM_F_init.txt"
        calib = d / "Trafo_TM_F_init_calib.txt"
        T0 = read_transform_txt(init) if init.exists() else None
        T1 = read_transform_txt(calib) if calib.exists() else None
        series.append(read_ur10_measurements(f, T0, T1, name=f"{d.name}/{f.stem}"))
    he = sorted(r.glob("Series_*/calibration_handeye.csv"))
    if he:
        handeye = read_ur10_handeye_csv(he[0])
    return UR10Dataset(root=str(r), series=tuple(series), handeye=handeye)
