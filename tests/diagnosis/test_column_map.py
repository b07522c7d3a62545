"""The column map's grammar and the table importer's alignment of channels at their own rates."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.logs.importers.column_map import ColumnMap
from realitygap.diagnosis.logs.importers.csv_log import read_csv_log, read_table_logs
from realitygap.diagnosis.logs.log import LogError
from realitygap.diagnosis.logs.read import ReadOptions, read_logs


def _motion(t: np.ndarray) -> dict[str, np.ndarray]:
    """A robot driving an arc: true pose (m, rad) and cumulative wheel counts."""
    v, w = 0.3, 0.4
    th = w * t
    x, y = v / w * np.sin(th), v / w * (1 - np.cos(th))
    b, r, tpr = 0.3, 0.05, 1000.0
    left = (v - w * b / 2) * t / r / (2 * math.pi) * tpr
    right = (v + w * b / 2) * t / r / (2 * math.pi) * tpr
    return {"x": x, "y": y, "th": th, "l": np.round(left), "r": np.round(right)}


def test_grammar_sign_scale_offset_quotes_files_and_rows() -> None:
    m = ColumnMap.parse(
        't=time:ms,ticks.left=-enc_l,ticks.right=enc_r*0.25,pose_gt.x="x [mm]":mm,'
        "pose_gt.y=y*1/2+3:mm,pose_gt.theta=-heading+90:deg"
    )
    e = m.entries
    assert (e["ticks.left"].sign, e["ticks.left"].column) == (-1.0, "enc_l")
    assert e["ticks.right"].factor == 0.25
    assert (e["pose_gt.x"].column, e["pose_gt.x"].unit) == ("x [mm]", "mm")
    assert (e["pose_gt.y"].factor, e["pose_gt.y"].offset) == (0.5, 3.0)
    assert (e["pose_gt.theta"].sign, e["pose_gt.theta"].offset) == (-1.0, 90.0)
    assert m.time is not None and (m.time.column, m.time.unit) == ("time", "ms")
    two = ColumnMap.parse(
        "t=enc::stamp,t=mocap::time:ms,pose_gt.x=mocap::x,pose_gt.y=2,pose_gt.theta=yaw"
    )
    assert [s.file for s in two.times] == ["enc", "mocap"]
    assert two.time_for("/data/mocap.csv").column == "time"  # type: ignore[union-attr]
    assert two.entries["pose_gt.y"].column == 2
    rows = ColumnMap.parse("t=row*33:ms,cmd.v=v,cmd.w=w")
    assert rows.time is not None and rows.time.row_period == 33.0 and rows.time.column is None


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("t=time,odom.x=x", "unknown channel 'odom'"),
        ("t=time,cmd.v", "expected 'target=column"),
        ("t=time", "no channel column given"),
        ("t=time,cmd.v=row*0.1,cmd.w=w", "stands for the time only"),
        ("t=row*-1,cmd.v=v,cmd.w=w", "positive period"),
        ("t=time,cmd.v=v*0,cmd.w=w", "factor of 0"),
        ('t=time,cmd.v="v,cmd.w=w', "unbalanced double quote"),
        ("t=a,t=b,cmd.v=v,cmd.w=w", "qualify each"),
        ("t=time,cmd.v=v,cmd.v=w,cmd.w=w", "given twice"),
    ],
)
def test_grammar_errors_name_the_entry(text: str, message: str) -> None:
    with pytest.raises(LogError, match=message):
        ColumnMap.parse(text)


def test_mirrored_encoder_and_clockwise_heading_in_a_titled_whitespace_file(tmp_path: Path) -> None:
    t = np.arange(0, 10, 0.02)
    mo = _motion(t)
    lines = [
        "Robot logger 2.1   2024-03-05 14:02",
        "units: s, mm, deg",
        "time   enc_l   enc_r   x   y   heading",
    ]
    for k in range(t.size):
        lines.append(
            f"{t[k]:.2f}  {-mo['l'][k]:.0f}  {mo['r'][k]:.0f}  {1e3 * mo['x'][k]:.2f}  "
            f"{1e3 * mo['y'][k]:.2f}  {-math.degrees(mo['th'][k]):.3f}"
        )
    f = tmp_path / "run.txt"
    f.write_text("\n".join(lines) + "\n")
    log = read_csv_log(
        f,
        "t=time,ticks.left=-enc_l,ticks.right=enc_r,pose_gt.x=x:mm,pose_gt.y=y:mm,"
        "pose_gt.theta=-heading:deg",
    )
    np.testing.assert_allclose(log["ticks"][:, 0], mo["l"])
    np.testing.assert_allclose(log["pose_gt"][:, 2], mo["th"], atol=1e-5)
    np.testing.assert_allclose(log["pose_gt"][:, 0], mo["x"], atol=1e-5)
    assert log.n == t.size


def _interleaved(tmp_path: Path, dup: bool = False) -> tuple[Path, np.ndarray, np.ndarray]:
    """Encoders at 50 Hz and motion capture at 120 Hz (stamps 1 ms later) in one file."""
    te = np.arange(0, 8, 0.02)
    tm = np.arange(0, 8, 1 / 120) + 0.001
    rows = [(s, "e") for s in te] + [(s, "m") for s in tm]
    rows.sort()
    if dup:
        rows.insert(10, rows[9])
    out = ["stamp,enc_l,enc_r,mx,my,myaw"]
    for s, kind in rows:
        if kind == "e":
            mo = _motion(np.array([s]))
            out.append(f"{s:.6f},{mo['l'][0]:.0f},{mo['r'][0]:.0f},,,")
        else:
            mo = _motion(np.array([s]))
            out.append(f"{s:.6f},,,{mo['x'][0]:.6f},{mo['y'][0]:.6f},{mo['th'][0]:.6f}")
    f = tmp_path / "multi.csv"
    f.write_text("\n".join(out) + "\n")
    return f, te, tm


MULTI = "t=stamp,ticks.left=enc_l,ticks.right=enc_r,pose_gt.x=mx,pose_gt.y=my,pose_gt.theta=myaw"


def test_streams_at_different_rates_align_on_the_encoders_own_stamps(tmp_path: Path) -> None:
    f, te, tm = _interleaved(tmp_path)
    logs = read_table_logs([f], MULTI)
    assert len(logs) == 1
    log = logs[0]
    # the encoders' stamps, within the motion capture's span: no extrapolation
    inside = te[(te >= tm[0]) & (te <= tm[-1])]
    np.testing.assert_allclose(log.t, inside)
    truth = _motion(log.t)
    np.testing.assert_allclose(log["pose_gt"][:, 0], truth["x"], atol=2e-5)
    np.testing.assert_allclose(log["pose_gt"][:, 2], truth["th"], atol=2e-5)
    assert "aligned" in log.meta and "120" in log.meta["aligned"]
    # the plausibility check sees wheel rates at the encoders' rate, not per 1-ms row
    read_logs(
        f,
        ReadOptions(
            columns=MULTI,
            params={"ticks_per_rev": 1000.0, "wheel_radius_left": 0.05, "wheel_radius_right": 0.05},
        ),
    )


def test_repeated_stamps_follow_the_stated_policy(tmp_path: Path) -> None:
    f, _, _ = _interleaved(tmp_path, dup=True)
    with pytest.raises(LogError, match=r"repeated time stamp.*line \d+.*--duplicates last"):
        read_table_logs([f], MULTI)
    last = read_table_logs([f], MULTI, duplicates="last")[0]
    mean = read_table_logs([f], MULTI, duplicates="mean")[0]
    np.testing.assert_allclose(last.t, mean.t)


def test_two_files_with_their_own_time_columns(tmp_path: Path) -> None:
    te = np.arange(0, 6, 0.02)
    tm = np.arange(0, 6, 0.01) + 0.003
    enc, moc = _motion(te), _motion(tm)
    (tmp_path / "enc.csv").write_text(
        "stamp,l,r\n"
        + "".join(f"{a:.4f},{b:.0f},{c:.0f}\n" for a, b, c in zip(te, enc["l"], enc["r"]))
    )
    (tmp_path / "mocap.csv").write_text(
        "time,x,y,yaw\n"
        + "".join(
            f"{1e3 * a:.2f},{b:.6f},{c:.6f},{d:.6f}\n"
            for a, b, c, d in zip(tm, moc["x"], moc["y"], moc["th"])
        )
    )
    cmap = (
        "t=enc::stamp,t=mocap::time:ms,ticks.left=l,ticks.right=r,pose_gt.x=x,pose_gt.y=y,"
        "pose_gt.theta=yaw"
    )
    logs = read_logs(
        f"{tmp_path / 'enc.csv'}+{tmp_path / 'mocap.csv'}",
        ReadOptions(columns=cmap, check_plausible=False),
    )
    assert len(logs) == 1
    np.testing.assert_allclose(logs[0]["pose_gt"][:, 1], _motion(logs[0].t)["y"], atol=2e-5)
    with pytest.raises(LogError, match="no time for this file"):
        read_table_logs(
            [tmp_path / "enc.csv", tmp_path / "mocap.csv"],
            "t=enc::stamp,ticks.left=l,ticks.right=r,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw",
        )


def test_a_gap_in_one_stream_cuts_the_log_instead_of_inventing_values(tmp_path: Path) -> None:
    f, _te, _tm = _interleaved(tmp_path)
    lines = f.read_text().splitlines()
    # a 2-s motion-capture dropout from 3 s to 5 s
    keep = [lines[0]] + [
        ln
        for ln in lines[1:]
        if not (3.0 < float(ln.split(",")[0]) < 5.0 and ln.split(",")[3] != "")
    ]
    f.write_text("\n".join(keep) + "\n")
    said: list[str] = []
    logs = read_table_logs([f], MULTI, warn=said.append)
    assert len(logs) == 2 and all(lg.meta["piece_of"] == "multi" for lg in logs)
    assert logs[0].t[-1] < 3.01 and logs[1].t[0] > 4.99
    assert any("instead of inventing values" in s for s in said)
    # a wider limit bridges it (the user's choice, stated)
    assert len(read_table_logs([f], MULTI, max_gap=2.5)) == 1


def test_time_from_rows_when_the_time_column_is_constant(tmp_path: Path) -> None:
    t = np.arange(0, 5, 0.05)
    mo = _motion(t)
    f = tmp_path / "const.csv"
    f.write_text(
        "time,l,r,x,y,yaw\n"
        + "".join(
            f"1700000000,{a:.0f},{b:.0f},{c:.6f},{d:.6f},{e:.6f}\n"
            for a, b, c, d, e in zip(mo["l"], mo["r"], mo["x"], mo["y"], mo["th"])
        )
    )
    cols = "ticks.left=l,ticks.right=r,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw"
    with pytest.raises(LogError, match=r"time column 'time' is constant.*t=row\*DT"):
        read_csv_log(f, "t=time," + cols)
    log = read_csv_log(f, "t=row*50:ms," + cols)
    np.testing.assert_allclose(log.t, t, atol=1e-12)


def test_a_column_whose_name_looks_like_an_expression(tmp_path: Path) -> None:
    f = tmp_path / "odd.csv"
    f.write_text("t,v-1,w\n0,1,0\n0.1,1,0\n0.2,1,0\n")
    log = read_csv_log(f, "t=t,cmd.v=v-1,cmd.w=w")
    np.testing.assert_allclose(log["cmd"][:, 0], 1.0)  # the column, not 'v' minus one


def test_interleaved_rows_read_as_one_stream_blame_the_clock_not_the_encoder() -> None:
    from realitygap.diagnosis.logs.log import Log
    from realitygap.diagnosis.logs.read import check_plausible

    # encoder rows stamped 1 ms after the pose rows, filled forward into one stream
    t = np.sort(np.concatenate([np.arange(0, 10, 0.02), np.arange(0, 10, 0.02) + 0.001]))
    ticks = np.column_stack([np.floor(t / 0.02) * 20, np.floor(t / 0.02) * 20])
    ticks[1::2] += 10
    log = Log(
        t=t,
        channels={"ticks": ticks, "pose_gt": np.column_stack([0.1 * t, 0 * t, 0 * t])},
        meta={
            "robot": "diffdrive",
            "params": {
                "ticks_per_rev": 100.0,
                "wheel_radius_left": 0.05,
                "wheel_radius_right": 0.05,
            },
        },
        source="x.csv",
    )
    with pytest.raises(LogError, match=r"uneven intervals.*clock or rate mismatch") as err:
        check_plausible(log)
    assert "ticks_per_rev" not in str(err.value).split("Fix:")[1]


def test_pieces_too_short_to_read_are_set_aside_not_fatal() -> None:
    from realitygap.diagnosis.logs.log import Log
    from realitygap.diagnosis.logs.pieces import drop_short_pieces

    def log(name: str, seconds: float, piece_of: str | None = None) -> Log:
        t = np.arange(0, seconds, 0.05)
        meta = {"name": name, **({"piece_of": piece_of} if piece_of else {})}
        return Log(t=t, channels={"cmd": np.zeros((t.size, 2))}, meta=meta)

    said: list[str] = []
    train, held = drop_short_pieces(
        [log("a_part-1", 10.0, "a"), log("a_part-2", 0.43, "a"), log("b", 0.43)],
        [log("c_part-1", 0.5, "c")],
        2.0,
        said.append,
    )
    # the importer's short piece goes, the user's own short log stays (and is refused later
    # with its own message); held-out pieces all too short: the training is split instead
    assert [lg.name for lg in train] == ["a_part-1", "b"] and held is None
    assert any("a_part-2" in s and "set aside" in s for s in said)
    with pytest.raises(LogError, match="every training log is a piece too short"):
        drop_short_pieces([log("a_part-2", 0.43, "a")], None, 2.0, said.append)


def test_effects_outside_the_default_library_are_accepted_when_named() -> None:
    from realitygap.diagnosis.adapters.registry import get_adapter
    from realitygap.diagnosis.diagnose import DiagnosisSettings, candidate_library
    from realitygap.robots.effects import EFFECTS, library

    outside = [
        n for n, c in EFFECTS.items() if c.robot == "diffdrive" and n not in library("diffdrive")
    ]
    assert outside, "the test needs an effect outside the default library"
    s = DiagnosisSettings(effects=(outside[0], "truth_frame_offset"))
    assert candidate_library(get_adapter("diffdrive"), s) == (outside[0], "truth_frame_offset")
    with pytest.raises(ValueError, match=r"unknown effect.*'truth_frame_ofset'.*did you mean"):
        candidate_library(
            get_adapter("diffdrive"), DiagnosisSettings(effects=("truth_frame_ofset",))
        )
