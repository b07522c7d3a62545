"""Classes of bad outcomes of the log readers, each pinned by two instances where possible:
discontinuities, conventions the inspector detects, the sign of one wheel, thousands
separators, row widths, units rows, unreadable files first, option types, dataset parts."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.logs.importers.table import read_table
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.diagnosis.logs.read import ReadOptions, read_logs, read_many
from realitygap.diagnosis.logs.schema import SchemaError, discontinuities
from realitygap.robots.diffdrive import DiffDriveParams

P = DiffDriveParams()
DRIVE_MAP = (
    "t=t,ticks.left=encL,ticks.right=encR,cmd.v=v,cmd.w=w,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw"
)


def drive(n: int = 1500, dt: float = 0.02, w: float = 0.4) -> dict[str, np.ndarray]:
    """A differential drive at 0.2 m/s turning at ``w`` rad/s, with its wheel ticks."""
    t = dt * np.arange(n)
    phase = np.sin(2 * math.pi * t / 10.0)
    w_t = w * ((phase > 0.5).astype(float) - (phase < -0.5))  # left, straight, right turns
    th = np.concatenate([[0.0], np.cumsum(w_t[:-1] * dt)])
    x = np.concatenate([[0.0], np.cumsum(0.2 * np.cos(th[:-1]) * dt)])
    y = np.concatenate([[0.0], np.cumsum(0.2 * np.sin(th[:-1]) * dt)])
    per_m = P.ticks_per_rev / (2 * math.pi * P.wheel_radius_left)
    left = np.concatenate([[0.0], np.cumsum((0.2 - w_t[:-1] * P.wheelbase / 2) * dt)])
    right = np.concatenate([[0.0], np.cumsum((0.2 + w_t[:-1] * P.wheelbase / 2) * dt)])
    return {
        "t": t, "encL": np.round(left * per_m), "encR": np.round(right * per_m),
        "v": np.full(n, 0.2), "w": w_t, "x": x, "y": y, "yaw": th,
    }  # fmt: skip


def write_csv(path: Path, cols: dict[str, np.ndarray]) -> Path:
    names = list(cols)
    rows = [",".join(names)]
    rows += [",".join(f"{cols[c][k]:.6f}" for c in names) for k in range(len(cols["t"]))]
    path.write_text("\n".join(rows) + "\n")
    return path


def read(
    path: Path | str, columns: str | None = DRIVE_MAP, **kw: object
) -> tuple[list[Log], list[str]]:
    said: list[str] = []
    logs = read_logs(path, ReadOptions(columns=columns, **kw), warn=said.append)  # type: ignore[arg-type]
    return logs, said


def test_the_drive_reads_as_it_is(tmp_path: Path) -> None:
    logs, said = read(write_csv(tmp_path / "ok.csv", drive()))
    assert len(logs) == 1 and not said


# ------------------------------------------------------------------ 1. discontinuities
@pytest.mark.parametrize("channel", ["pose", "ticks"])
def test_a_step_no_robot_can_make_splits_the_recording_like_a_clock_reset(
    tmp_path: Path, channel: str
) -> None:
    d = drive()
    if channel == "pose":
        d["x"][900:] += 3.7  # two runs joined with continuous time
    else:
        d["encL"][900:] += 145_163
    logs, said = read(write_csv(tmp_path / "joined.csv", d))
    assert [lg.n for lg in logs] == [900, 600]
    assert [lg.name for lg in logs] == ["joined_part-1", "joined_part-2"]
    (msg,) = said
    assert "line 902" in msg and "jump" in msg and "split there, like a clock reset" in msg


def test_a_channel_in_the_wrong_unit_is_no_discontinuity_and_many_jumps_are_refused() -> None:
    d = drive()
    pose = np.column_stack([d["x"], d["y"], d["yaw"]])
    assert discontinuities("pose_gt", d["t"], pose * 1000.0) == []  # every step: a unit mistake
    glitchy = pose.copy()
    glitchy[[100, 400, 700, 1000], 0] += 5.0  # a tracker losing its body, again and again
    with pytest.raises(SchemaError, match=r"jumps at \d+ steps.*a broken channel"):
        discontinuities("pose_gt", d["t"], glitchy)


# ------------------------------------------------------------------ 2. heading sign
@pytest.mark.parametrize("chan", ["pose_gt", "pose_est"])
def test_a_clockwise_heading_mapped_without_minus_is_refused(tmp_path: Path, chan: str) -> None:
    d = drive()
    d["yaw"] = -d["yaw"]  # clockwise-positive
    cols = DRIVE_MAP.replace("pose_gt", chan)
    with pytest.raises(LogError, match=rf"the heading turns the other way than the path: a "
                       rf"clockwise heading\?.*Fix: -heading \({chan}.theta=-yaw"):  # fmt: skip
        read(write_csv(tmp_path / "cw.csv", d), cols)
    logs, _ = read(tmp_path / "cw.csv", cols.replace("=yaw", "=-yaw"))
    assert len(logs) == 1


def test_a_heading_that_hardly_turns_is_not_judged(tmp_path: Path) -> None:
    d = drive(w=0.0)
    d["yaw"] = -d["yaw"]
    logs, _ = read(write_csv(tmp_path / "straight.csv", d))
    assert len(logs) == 1


# ------------------------------------------------------------------ 3. one wheel's sign
@pytest.mark.parametrize("side, column", [("left", "encL"), ("right", "encR")])
def test_a_mirrored_encoder_is_named_first_with_the_working_fix(
    tmp_path: Path, side: str, column: str
) -> None:
    d = drive()
    d[column] = -d[column]
    with pytest.raises(LogError, match=rf"encoder counts the other way \(mirrored\).*Fix: "
                       rf"ticks.{side}=-{column} in the column map"):  # fmt: skip
        read(write_csv(tmp_path / "mirror.csv", d))
    logs, _ = read(tmp_path / "mirror.csv", DRIVE_MAP.replace(f"={column}", f"=-{column}"))
    assert len(logs) == 1


# ------------------------------------------------------------------ 4, 6. thousands, decimal clash
def test_quoted_thousands_are_read_as_numbers(tmp_path: Path) -> None:
    f = tmp_path / "excel.csv"
    f.write_text('t,n,x\n0.0,"19,548",1.5\n0.1,"1,234,567.5",2.5\n0.2,"-3,000",3.5\n0.3,12,4.5\n')
    tab = read_table(f)
    assert tab.decimal == "." and tab.delimiter == ","
    np.testing.assert_array_equal(tab.column("n"), [19548.0, 1234567.5, -3000.0, 12.0])


@pytest.mark.parametrize("quoted", [False, True])
def test_a_decimal_comma_on_a_comma_separated_file_names_the_clash(
    tmp_path: Path, quoted: bool
) -> None:
    d = drive(n=50)
    f = write_csv(tmp_path / "dots.csv", d)
    if quoted:
        lines = f.read_text().splitlines()
        f.write_text("\n".join([lines[0]] + [ln.replace(",", ',"1,000",', 1) .replace(
            ',"1,000",', ",", 1) for ln in lines[1:]]) + "\n")  # fmt: skip
    with pytest.raises(LogError, match=r"decimal=',' \(CLI --decimal ,\) was given, but the file "
                       r"is comma-separated with '.' decimals.*clashes"):  # fmt: skip
        read_table(f, decimal=",")


# ------------------------------------------------------------------ 5. row widths
def test_an_extra_field_names_the_line_and_no_decimal_commas(tmp_path: Path) -> None:
    f = tmp_path / "extra.csv"
    f.write_text(
        "t,a,b\n" + "".join(f"{k * 0.1:.1f},1.5,2.5\n" for k in range(8)) + "0.9,1.5,2.5,7\n"
    )
    with pytest.raises(
        LogError, match=r"line 10: 4 fields .* header has 3 — a stray delimiter"
    ) as e:
        read_table(f)
    assert "decimal comma" not in str(e.value)
    g = tmp_path / "commas.csv"  # every cell a whole number: decimal commas split in two
    g.write_text("t,a,b\n" + "".join(f"{k},1,2\n" for k in range(8)) + "9,1,5,2,5\n")
    with pytest.raises(LogError, match=r"line 10: 5 fields .* decimal commas"):
        read_table(g)


# ------------------------------------------------------------------ 7. units row
@pytest.mark.parametrize("row", ["s,count,mm,deg", "[s],[counts],(mm),[deg]"])
def test_a_units_row_under_the_header_gives_the_units(tmp_path: Path, row: str) -> None:
    f = tmp_path / "units.csv"
    body = "".join(f"{k * 0.1:.1f},{k},{k * 100.0},{k * 10.0}\n" for k in range(6))
    f.write_text(f"time,enc,x,heading\n{row}\n{body}")
    tab = read_table(f)
    assert tab.names == ("time", "enc", "x", "heading")
    assert tab.units == ("s", "count", "mm", "deg") and tab.lines[0] == 3
    assert any("line 2: a units row" in note for note in tab.skipped)


def test_the_units_row_converts_the_log(tmp_path: Path) -> None:
    d = drive()
    f = write_csv(tmp_path / "u.csv", {**d, "x": d["x"] * 1000, "y": d["y"] * 1000,
                                       "yaw": np.degrees(d["yaw"])})  # fmt: skip
    lines = f.read_text().splitlines()
    f.write_text("\n".join([lines[0], "s,count,count,m/s,rad/s,mm,mm,deg", *lines[1:]]) + "\n")
    (lg,), _ = read(f)
    np.testing.assert_allclose(lg["pose_gt"][:, 0], d["x"], atol=1e-6)


# ------------------------------------------------------------------ 8. unreadable first
def test_a_file_that_cannot_be_parsed_is_unreadable_before_it_needs_a_map(tmp_path: Path) -> None:
    from scipy.io import savemat

    m = tmp_path / "run.mat"
    savemat(m, {"t": np.arange(2000.0), "x": np.ones(2000)})
    m.write_bytes(m.read_bytes()[:3000])
    with pytest.raises(LogError, match="unreadable MATLAB file"):
        read_logs(m)
    q = tmp_path / "wide.csv"
    q.write_text("t,x\n" + "".join(f"{k},{k}.5\n" for k in range(8)) + "8,1.5,2.5\n9,1.5\n")
    with pytest.raises(LogError, match=r"line 10: 3 fields .* header has 2") as e:
        read_logs(q)
    assert "column map" not in str(e.value)


# ------------------------------------------------------------------ 9, 11. paths and options
def test_a_symlink_loop_and_a_missing_path_are_told_apart(tmp_path: Path) -> None:
    loop = tmp_path / "loop.csv"
    os.symlink(loop.name, loop)
    with pytest.raises(LogError, match="symbolic link loop"):
        read_logs(loop)
    with pytest.raises(FileNotFoundError, match="no such file or folder"):
        read_logs(tmp_path / "none.csv")


def test_options_of_the_wrong_type_are_a_type_error_naming_the_argument(tmp_path: Path) -> None:
    f = write_csv(tmp_path / "ok.csv", drive(n=20))
    with pytest.raises(TypeError, match=r"options must be a ReadOptions.*ReadOptions\(columns="):
        read_logs(f, "t=time")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"options must be a ReadOptions.*got dict"):
        read_logs(f, {"columns": "t=time"})  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="warn must be a function"):
        read_logs(f, ReadOptions(columns=DRIVE_MAP), warn="loud")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"read_many: paths must be a list"):
        read_many(str(f))  # type: ignore[arg-type]


# ------------------------------------------------------------------ 10. robot without channels
def test_a_robot_whose_channels_the_map_does_not_give_is_said_first(tmp_path: Path) -> None:
    f = write_csv(tmp_path / "drive.csv", drive(n=50))
    with pytest.raises(LogError, match=r"read as an arm log .*gives none of its channels "
                       r"\(joints, tool_pos\).*robot='diffdrive'"):  # fmt: skip
        read_logs(f, ReadOptions(columns=DRIVE_MAP, robot="arm"))
    with pytest.raises(LogError, match=r"read as a climber log .*gives none of its channels"):
        read_logs(f, ReadOptions(columns=DRIVE_MAP, robot="climber"))


# ------------------------------------------------------------------ 12, 13. dataset parts
def test_a_file_of_a_dataset_folder_points_to_the_folder(tmp_path: Path) -> None:
    sess = tmp_path / "231220200029"
    sess.mkdir()
    for name in ("231220200029_metadata.csv", "231220200029_run-01.csv"):
        (sess / name).write_text("type,diff,,,,,\nwheelbase,0.2,,,,,\n")
        with pytest.raises(LogError, match=rf"a file of the OptiOdom session folder {sess} .*"
                           rf"pass the folder: realitygap diagnose {sess}"):  # fmt: skip
            read_logs(sess / name)
    series = tmp_path / "ur10" / "Series_1"
    series.mkdir(parents=True)
    (series / "measurements_1.csv").write_text("Goal x,measurement_x,shoulder_pan_joint\n")
    (series / "Trafo_TM_F_init.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(LogError, match=r"a file of the UR10 laser-tracker set .*pass the folder"):
        read_logs(series / "Trafo_TM_F_init.txt")


def test_a_renamed_session_folder_says_the_name_must_match_the_id(tmp_path: Path) -> None:
    copy = tmp_path / "sess_copy"
    copy.mkdir()
    (copy / "231220200029_metadata.csv").write_text("type,diff\n")
    with pytest.raises(LogError, match=r"must be named after the ID .*'sess_copy'.*Fix: rename "
                       rf"the folder: mv {copy} {tmp_path / '231220200029'}"):  # fmt: skip
        read_logs(copy)
    with pytest.raises(LogError, match=r"rename the folder after the session ID first"):
        read_logs(copy / "231220200029_metadata.csv")
