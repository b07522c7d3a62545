"""OptiOdom importer: real session folders and small malformed files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.logs.importers.optiodom import (
    OptiOdomSession,
    PathType,
    find_sessions,
    infer_quadrature_factor,
    read_session,
    ticks_per_wheel_rev,
)
from realitygap.estimators.diffdrive_model import DiffDriveKinematics
from realitygap.estimators.umbmark import umbmark_end_errors, umbmark_from_runs

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "optiodom_diffdrive"


@pytest.fixture(scope="module")
def sessions() -> dict[str, list[Path]]:
    if not DATA.is_dir():
        pytest.skip(
            f"OptiOdom data not found at {DATA}; these tests need ../shared/data/"
            "optiodom_diffdrive beside the repository"
        )
    found: dict[str, list[Path]] = {}
    for p in find_sessions(DATA):
        found.setdefault(p.parent.name, []).append(p)
    return found


@pytest.fixture(scope="module")
def square(sessions: dict[str, list[Path]]) -> OptiOdomSession:
    candidates = [read_session(p) for p in sessions.get("square", [])]
    candidates = [s for s in candidates if s.metadata.side_length == pytest.approx(0.75)]
    if not candidates:
        pytest.skip(f"no 0.75 m square session under {DATA / 'square'}")
    return candidates[0]


# ---------------------------------------------------------------------------
# real data
# ---------------------------------------------------------------------------


def test_find_sessions_covers_every_path_type(sessions: dict[str, list[Path]]) -> None:
    assert {"square", "circular", "ivanjko", "free"} <= set(sessions)
    for folder in (p for paths in sessions.values() for p in paths):
        assert (folder / f"{folder.name}_metadata.csv").is_file()
    assert find_sessions(DATA / "square") == sessions["square"]


def test_square_session_contents(square: OptiOdomSession) -> None:
    meta = square.metadata
    assert square.path_type is PathType.SQUARE and square.path_type_source == "folder"
    assert meta.robot_type == "diff"
    assert meta.gear_ratio == pytest.approx(43.7) and meta.encoder_resolution == 64
    assert meta.wheel_diameter_left > 0 and meta.wheel_diameter_right > 0
    assert len(meta.odo_t_end) == meta.n_runs == len(square.runs)
    assert "Method" in square.robot_log_header
    for run in square.runs:
        assert run.gt_pose.shape == (run.n, 3) and run.time.shape == (run.n,)
        np.testing.assert_allclose(run.gt_pose[0], 0.0, atol=1e-12)
        assert run.ticks_left.dtype == np.int64 and run.ticks_right.shape == (run.n,)
        assert np.all(np.diff(run.time) > 0)
        assert not run.gt_pose.flags.writeable


def test_square_directions_come_from_ground_truth(square: OptiOdomSession) -> None:
    n = len(square.runs)
    assert [r.direction for r in square.runs] == ["cw"] * (n // 2) + ["ccw"] * (n - n // 2)
    assert square.direction_mismatches == ()
    for run in square.runs:
        assert abs(abs(run.net_rotation) - 2 * math.pi) < 0.3


def test_ticks_per_revolution_without_quadrature(square: OptiOdomSession) -> None:
    assert ticks_per_wheel_rev(square) == pytest.approx(43.7 * 64)
    assert ticks_per_wheel_rev(square.metadata, 4) == pytest.approx(43.7 * 64 * 4)
    assert infer_quadrature_factor(square) == 1
    with pytest.raises(ValueError, match="quadrature_factor must be 1, 2 or 4"):
        ticks_per_wheel_rev(square, 3)


def test_nominal_odometry_redraws_the_square(square: OptiOdomSession) -> None:
    side = square.metadata.side_length
    assert side is not None
    kin, kin_x4 = square.kinematics(1), square.kinematics(4)
    for run in square.runs:
        odo = run.odometry(kin)
        extent = odo[:, :2].max(axis=0) - odo[:, :2].min(axis=0)
        np.testing.assert_allclose(extent, side, rtol=0.03)
        assert np.mean(np.hypot(*(odo[:, :2] - run.gt_pose[:, :2]).T)) < 0.05
        # with an extra quadrature x4 distances and turns shrink: no square at all
        odo_x4 = run.odometry(kin_x4)
        assert np.mean(np.hypot(*(odo_x4[:, :2] - run.gt_pose[:, :2]).T)) > 0.2


def test_robot_log_alignment_and_onboard_odometry(sessions: dict[str, list[Path]]) -> None:
    for folders in sessions.values():
        session = read_session(folders[0])
        kin = session.kinematics()
        for run in session.runs:
            assert run.alignment == "exact"
            log = run.robot_log
            assert log is not None and run.robot_log_offset is not None
            j = run.robot_log_offset
            np.testing.assert_array_equal(log.ticks_left[j : j + run.n], run.ticks_left)
            np.testing.assert_array_equal(log.ticks_right[j : j + run.n], run.ticks_right)
            assert run.cmd_linear is not None and run.cmd_linear.shape == (run.n,)
            assert run.cmd_angular is not None and run.cmd_angular.shape == (run.n,)
            assert run.robot_time_offset == pytest.approx(log.time[j] - run.time[0])
            # the robot's own odometry column (4 significant digits) is our integration
            onboard = kin.integrate(np.zeros(3), log.ticks_left, log.ticks_right, wrap=False)
            np.testing.assert_allclose(onboard[1:], log.odo_pose, rtol=5e-4, atol=1e-4)


def test_path_types_of_every_folder(sessions: dict[str, list[Path]]) -> None:
    for kind, folders in sessions.items():
        session = read_session(folders[0])
        assert session.path_type.value == kind


def test_umbmark_on_a_real_square_session(square: OptiOdomSession) -> None:
    kin = square.kinematics()
    runs = [(r.gt_pose, r.ticks_left, r.ticks_right, r.direction) for r in square.runs]
    assert square.metadata.side_length is not None
    res = umbmark_from_runs(runs, kin, square.metadata.side_length)
    assert 0.9 < res.E_d < 1.1 and 0.9 < res.E_b < 1.1
    cw, ccw = umbmark_end_errors(runs, res.corrected(kin))
    after = max(np.hypot(*cw[:, :2].mean(0)), np.hypot(*ccw[:, :2].mean(0)))
    assert after < res.E_max_syst


# ---------------------------------------------------------------------------
# synthetic session folders
# ---------------------------------------------------------------------------

BOM = "\ufeff"
KIN = DiffDriveKinematics.from_diameters(0.084, 0.084, 0.2, 43.7 * 64)


def _square_ticks(side: float = 0.3, steps: int = 10) -> tuple[np.ndarray, np.ndarray]:
    m = KIN.meters_per_tick_left
    leg = np.full(steps, round(side / m / steps))
    turn = np.full(steps, round(0.25 * math.pi * KIN.wheelbase / m / steps))
    left, right = [np.zeros(3)], [np.zeros(3)]
    for _ in range(4):  # clockwise: right turns
        left += [leg, turn]
        right += [leg, -turn]
    return np.concatenate(left).astype(int), np.concatenate(right).astype(int)


def _write_session(root: Path, sid: str = "010120200000", kind: str = "square") -> Path:
    folder = root / kind / sid
    folder.mkdir(parents=True)
    t_l, t_r = _square_ticks()
    n = t_l.shape[0]
    gt = KIN.integrate(np.zeros(3), t_l, t_r, wrap=False)[1:]
    time = 0.05 * np.arange(n)
    (folder / f"{sid}_metadata.csv").write_text(
        "type,diff,\nngear,43.7,\nencRes,64,\nLi,0.2,\nDi,0.084,0.084\nThi,,\nN,1,\n"
        "L,0.3,\nimarkers,4,3\ngt_ti,2.5,\ngt_tf,9.0,\nodo_ti,0,\nodo_tf,5.0,\n"
    )
    rows = [f"{time[k]},{gt[k, 0]},{gt[k, 1]},{gt[k, 2]},{t_r[k]},{t_l[k]}" for k in range(n)]
    (folder / f"{sid}_run-01.csv").write_text("\n".join(rows) + "\n")
    t0 = 100.0
    (folder / f"{sid}_run-01_odo.csv").write_text(
        BOM + "\n".join(f"{t0 + time[k]},{t_l[k]},{t_r[k]}" for k in range(n)) + "\n"
    )
    log = [
        "Method:,Borenstein and Feng (1996): UMBmark",
        "dL0(m):,0.084,dR0(m):,0.084,b0(m):,0.2",
        "+++++,+++++,+++++",
        "time(s):,odoL(thicks/cyc):,odoR(thicks/cyc):,xodo(m):,yodo(m):,thodo(rad):,"
        "vlin(thicks/cyc):,omega(rad/cyc):",
        "+++++,+++++,+++++",
        "Run:,1",
    ]
    log += [
        f"{t0 + time[k]},{t_l[k]},{t_r[k]},{gt[k, 0]:.4g},{gt[k, 1]:.4g},{gt[k, 2]:.4g},"
        f"    30,{-0.015 * (k % 2)},{int(k == n - 1)}"
        for k in range(n)
    ]
    (folder / f"{sid}.csv").write_text("\n".join(log) + "\n")
    return folder


def _replace_line(path: Path, line_no: int, text: str) -> None:
    lines = path.read_text(encoding="utf-8-sig").splitlines()
    lines[line_no - 1] = text
    path.write_text("\n".join(lines) + "\n")


def test_synthetic_session_round_trip(tmp_path: Path) -> None:
    folder = _write_session(tmp_path)
    assert find_sessions(tmp_path) == [folder]
    s = read_session(folder)
    assert s.session_id == folder.name and s.path_type is PathType.SQUARE
    assert s.metadata.wheel_diameter_right == 0.084 and s.metadata.side_length == 0.3
    assert s.metadata.gt_t_start == (2.5,) and s.metadata.markers == (4, 3)
    run = s.runs[0]
    assert run.direction == "cw" and run.net_rotation == pytest.approx(-2 * math.pi, abs=0.05)
    assert run.alignment == "exact" and run.robot_log_offset == 0
    assert run.robot_time_offset == pytest.approx(100.0)
    assert run.cmd_linear is not None and np.all(run.cmd_linear == 30)
    np.testing.assert_allclose(run.odometry(s.kinematics()), run.gt_pose, atol=1e-12)


def test_path_type_falls_back_to_the_robot_log(tmp_path: Path) -> None:
    folder = _write_session(tmp_path, kind="elsewhere")
    s = read_session(folder)
    assert s.path_type is PathType.SQUARE and s.path_type_source == "robot log"


def test_alignment_states(tmp_path: Path) -> None:
    folder = _write_session(tmp_path)
    sid = folder.name
    log = folder / f"{sid}.csv"
    lines = log.read_text().splitlines()
    # ticks disagree on one row but the _odo time stamps still line up
    first = lines.index("Run:,1") + 1
    fields = lines[first + 20].split(",")
    fields[1] = str(int(fields[1]) + 1)
    lines[first + 20] = ",".join(fields)
    log.write_text("\n".join(lines) + "\n")
    assert read_session(folder).runs[0].alignment == "time"
    # no block for the run at all
    log.write_text(
        "\n".join(line for line in lines if not line[:1].isdigit()).replace("Run:,1", "Run:,7")
        + "\n"
    )
    run = read_session(folder).runs[0]
    assert run.alignment == "unavailable" and run.cmd_linear is None
    log.unlink()
    assert read_session(folder).runs[0].robot_log is None


@pytest.mark.parametrize(
    ("file_suffix", "line_no", "text", "message"),
    [
        (
            "_run-01.csv",
            3,
            "0.1,0,0,0,0",
            r"run-01\.csv, line 3: expected 6 comma-separated fields",
        ),
        (
            "_run-01.csv",
            2,
            "0.05,abc,0,0,0,0",
            r"line 2, column 2 \(x_gt\): expected a number, got 'abc'",
        ),
        (
            "_run-01.csv",
            4,
            "0.15,nan,0,0,0,0",
            r"line 4, column 2 \(x_gt\): expected a finite number",
        ),
        (
            "_run-01.csv",
            5,
            "0.2,0,0,0,1.5,0",
            r"line 5: column ticks_R must hold whole tick counts",
        ),
        ("_run-01.csv", 3, "0.0,0,0,0,0,0", r"line 3: time must increase strictly"),
        ("_metadata.csv", 4, "Li,,", r"_metadata\.csv, line 4: missing value for 'Li'"),
        ("_metadata.csv", 2, "ngear,fast", r"line 2: 'ngear' must be a number, got 'fast'"),
        ("_metadata.csv", 3, "ngear,43.7", r"line 3: key 'ngear' repeated \(first on line 2\)"),
        ("_metadata.csv", 2, ",43.7", r"line 2: expected 'key,value\[,value…\]'"),
        (
            ".csv",
            8,
            "100.05,1,2,0,0,0,30,0",
            r"line 8: expected 9 comma-separated fields \(time, odoL",
        ),
        (".csv", 9, "100.1,1,x,0,0,0,30,0,0", r"line 9, column 3 \(odoR\): expected a number"),
        (".csv", 6, "1.0,0,0,0,0,0,0,0,0", r"line 6: data row before the first 'Run:,<n>' row"),
        (".csv", 6, "Run:,one", r"line 6: expected 'Run:,<run number>'"),
    ],
)
def test_malformed_files_name_file_line_and_expectation(
    tmp_path: Path, file_suffix: str, line_no: int, text: str, message: str
) -> None:
    folder = _write_session(tmp_path)
    _replace_line(folder / f"{folder.name}{file_suffix}", line_no, text)
    with pytest.raises(ValueError, match=message):
        read_session(folder)


def test_missing_and_empty_files(tmp_path: Path) -> None:
    folder = _write_session(tmp_path)
    sid = folder.name
    (folder / f"{sid}_run-01.csv").write_text("\n\n")
    with pytest.raises(ValueError, match=r"run-01\.csv: empty file, expected rows of 6"):
        read_session(folder)
    (folder / f"{sid}_run-01.csv").unlink()
    with pytest.raises(ValueError, match="no run file, expected"):
        read_session(folder)
    (folder / f"{sid}_metadata.csv").write_text("")
    with pytest.raises(ValueError, match=r"_metadata\.csv is empty \(0 bytes\)"):
        read_session(folder)
    (folder / f"{sid}_metadata.csv").unlink()
    with pytest.raises(FileNotFoundError, match=r"missing .*_metadata\.csv"):
        read_session(folder)
    with pytest.raises(FileNotFoundError, match="session folder not found"):
        read_session(tmp_path / "nope")
    with pytest.raises(FileNotFoundError, match="data folder not found"):
        find_sessions(tmp_path / "nope")


def test_byte_order_marks_everywhere_are_accepted(tmp_path: Path) -> None:
    folder = _write_session(tmp_path)
    for f in folder.iterdir():
        f.write_text(BOM + f.read_text(encoding="utf-8-sig"))
    assert read_session(folder).runs[0].alignment == "exact"


def test_non_utf8_file_is_reported(tmp_path: Path) -> None:
    folder = _write_session(tmp_path)
    (folder / f"{folder.name}_run-01.csv").write_bytes(b"\xff\xfe0,0,0")
    with pytest.raises(ValueError, match=r"run-01\.csv is UTF-16 LE text.*iconv"):
        read_session(folder)
    (folder / f"{folder.name}_run-01.csv").write_bytes(b"0,0,\xff\xff0")
    with pytest.raises(ValueError, match=r"run-01\.csv: expected UTF-8 text"):
        read_session(folder)
