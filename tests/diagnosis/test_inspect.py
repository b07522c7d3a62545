"""``realitygap inspect``: layouts, time bases, streams, sign conventions, proposed commands."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from realitygap import cli
from realitygap.diagnosis.logs.inspect import FileInspection, inspect_path, inspect_paths
from realitygap.diagnosis.logs.log import Log

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def drive(n: int = 200, dt: float = 0.05, v: float = 0.2, w: float = 0.4) -> dict[str, np.ndarray]:
    """A differential drive on an arc (counter-clockwise for w > 0): time, pose, wheel ticks."""
    t = dt * np.arange(n)
    th = w * t
    x = np.cumsum(np.r_[0.0, v * dt * np.cos(th[:-1])])
    y = np.cumsum(np.r_[0.0, v * dt * np.sin(th[:-1])])
    ticks_per_m = 1000.0 / (2 * math.pi * 0.05)
    left = np.floor((v - 0.15 * w) * t * ticks_per_m)
    right = np.floor((v + 0.15 * w) * t * ticks_per_m)
    return {"t": t, "x": x, "y": y, "th": th, "left": left, "right": right}


def one(path: Path) -> FileInspection:
    return inspect_path(path).files[0]


def col(f: FileInspection, name: str):
    return next(c for c in f.columns if c.name == name)


def test_mirrored_encoder_and_clockwise_heading_in_a_titled_file(tmp_path) -> None:
    d = drive()
    rows = [
        f"{1000 * t:.0f};{-le:.0f};{ri:.0f};{1000 * x:.3f};{1000 * y:.3f};{-math.degrees(th):.4f}"
        for t, le, ri, x, y, th in zip(d["t"], d["left"], d["right"], d["x"], d["y"], d["th"])
    ]
    text = "Robot log 2023-05-01 (firmware 1.2)\ntime_ms;encL;encR;x_mm;y_mm;yaw_deg\n"
    path = tmp_path / "robot.csv"
    path.write_text(text + "\n".join(r.replace(".", ",") for r in rows) + "\n")
    result = inspect_path(path)
    f = result.files[0]
    assert "semicolon-separated, decimal ','" in f.summary and "from line 3" in f.summary
    assert "'Robot log 2023-05-01 (firmware 1.2)'" in f.summary
    assert f.streams[0].rate_hz == pytest.approx(20.0) and f.streams[0].gaps == 0
    assert col(f, "encL").sign == -1 and col(f, "encR").sign == 1
    assert col(f, "yaw_deg").sign == -1 and col(f, "yaw_deg").unit == "deg"
    assert any("mirrored? use ticks.left=-encL" in n for n in f.notes)
    assert any("clockwise-positive heading? use pose_gt.theta=-yaw_deg" in n for n in f.notes)
    assert f.mapping == {
        "t": "time_ms:ms",
        "ticks.left": "-encL",
        "ticks.right": "encR",
        "pose_gt.x": "x_mm:mm",
        "pose_gt.y": "y_mm:mm",
        "pose_gt.theta": "-yaw_deg:deg",
    }
    expected = "t=time_ms:ms,ticks.left=-encL,ticks.right=encR,pose_gt.x=x_mm:mm"
    assert expected in result.command and "--drive ticks" in result.command
    assert result.command.startswith(f"realitygap diagnose {path}")
    text = result.to_text()
    assert "proposed command:\n" + result.command in text and "--robot-file" in text


def test_a_markdown_table_with_commands_and_truth(tmp_path) -> None:
    d = drive(n=120, dt=0.1, v=0.3, w=-0.5)
    lines = ["| t | v | w | x | y | theta |", "|---|---|---|---|---|---|"]
    for t, x, y, th in zip(d["t"], d["x"], d["y"], d["th"]):
        lines.append(f"| {t:.1f} | 0.3 | -0.5 | {x:.4f} | {y:.4f} | {th:.4f} |")
    path = tmp_path / "run.md"
    path.write_text("\n".join(lines) + "\n")
    f = one(path)
    assert "bar-separated" in f.summary and f.streams[0].rate_hz == pytest.approx(10.0)
    assert f.mapping == {
        "t": "t:s",
        "cmd.v": "v:m/s",
        "cmd.w": "w:rad/s",
        "pose_gt.x": "x:m",
        "pose_gt.y": "y:m",
        "pose_gt.theta": "theta:rad",
    }
    assert not f.missing and "--drive" not in f.options and not f.notes


def test_a_whitespace_file_with_per_row_tick_counts(tmp_path) -> None:
    d = drive(n=150, w=-0.3)
    inc_l, inc_r = np.diff(d["left"], prepend=0.0), np.diff(d["right"], prepend=0.0)
    lines = ["time      left   right   x_gt      y_gt      th_gt"]
    for k in range(150):
        lines.append(
            f"{d['t'][k]:<9.2f} {inc_l[k]:<6.0f} {inc_r[k]:<7.0f} {d['x'][k]:<9.4f} "
            f"{d['y'][k]:<9.4f} {d['th'][k]:.4f}"
        )
    path = tmp_path / "aligned.txt"
    path.write_text("\n".join(lines) + "\n")
    f = one(path)
    assert "whitespace" in f.summary
    assert col(f, "left").note == "counts per row" and f.mapping["ticks"] == "increments"
    assert f.mapping["ticks.left"] == "left" and f.mapping["ticks.right"] == "right"
    assert f.mapping["pose_gt.theta"] == "th_gt:rad" and not f.notes  # conventions agree


def test_a_multi_rate_file_splits_into_streams(tmp_path) -> None:
    d = drive(n=400, dt=0.01)
    rows = []
    for k in range(0, 400, 2):  # encoders at 50 Hz
        rows.append((d["t"][k], f"{d['t'][k]:.3f},{d['left'][k]:.0f},{d['right'][k]:.0f},,,"))
    for k in range(0, 400, 5):  # motion capture at 20 Hz, 5 ms later
        t = d["t"][k] + 0.005
        rows.append((t, f"{t:.3f},,,{d['x'][k]:.5f},{d['y'][k]:.5f},{d['th'][k]:.5f}"))
    path = tmp_path / "multi.csv"
    path.write_text("stamp,enc_l,enc_r,mocap_x,mocap_y,mocap_yaw\n")
    with open(path, "a") as fh:
        fh.write("\n".join(r for _, r in sorted(rows)) + "\n")
    result = inspect_path(path)
    f = result.files[0]
    rates = {s.columns: s.rate_hz for s in f.streams}
    assert rates[("enc_l", "enc_r")] == pytest.approx(50.0)
    assert rates[("mocap_x", "mocap_y", "mocap_yaw")] == pytest.approx(20.0)
    # streams at their own rates are no missing values: the map reads as proposed
    assert "--nan" not in result.command
    assert f.mapping["ticks.left"] == "enc_l" and f.mapping["pose_gt.x"] == "mocap_x:m"
    from realitygap.diagnosis.logs.read import ReadOptions, read_logs

    cols = ",".join(f"{k}={v}" for k, v in f.mapping.items())
    (log,) = read_logs(path, ReadOptions(columns=cols, check_plausible=False))
    assert log.dt == pytest.approx(0.02) and log.has("pose_gt")
    assert not any("mirrored" in n for n in f.notes)


def test_a_mat_file_with_a_matrix_and_a_struct(tmp_path) -> None:
    scipy_io = pytest.importorskip("scipy.io")
    d = drive(n=100)
    scipy_io.savemat(
        tmp_path / "run.mat",
        {
            "t": d["t"],
            "enc": np.column_stack([d["left"], d["right"]]),
            "pose": {"x": d["x"], "y": d["y"], "yaw": d["th"]},
        },
    )
    f = one(tmp_path / "run.mat")
    assert f.summary.startswith("MATLAB file, 100 rows")
    assert f.mapping["ticks.left"] == "enc[0]" and f.mapping["ticks.right"] == "enc[1]"
    assert f.mapping["pose_gt.theta"] == "pose.yaw:rad" and f.mapping["t"] == "t:s"
    assert any("enc[0] taken as the left encoder by its place" in n for n in f.notes)


def test_an_npz_arm_without_time(tmp_path) -> None:
    rng = np.random.default_rng(0)
    arrays = {f"q{j}": rng.uniform(-170, 170, 30) for j in range(1, 7)}
    arrays |= {f"tool_{a}": rng.uniform(-900, 900, 30) for a in "xyz"}
    np.savez(tmp_path / "arm.npz", **arrays)
    result = inspect_path(tmp_path / "arm.npz")
    f = result.files[0]
    assert "--robot arm" in result.command and f.mapping["t"] == "row*1"
    assert [f.mapping[f"joints.q{j}"] for j in range(1, 7)] == [f"q{j}:deg" for j in range(1, 7)]
    assert f.mapping["tool_pos.z"] == "tool_z:mm" and not result.missing


def test_missing_information_becomes_placeholders(tmp_path, capsys) -> None:
    rng = np.random.default_rng(1)
    path = tmp_path / "mystery.csv"
    path.write_text("a,b\n" + "".join(f"{u:.3f},{w:.3f}\n" for u, w in rng.normal(size=(20, 2))))
    result = inspect_path(path)
    assert "t=<time column>" in result.command
    assert any("no time column found" in m for m in result.missing)
    assert any("no ground-truth pose" in m for m in result.missing)
    assert cli.main(["inspect", str(path)]) == 0  # inspection is not an error
    assert "<time column>" in capsys.readouterr().out


def test_cli_json_output_and_refusals(tmp_path, capsys) -> None:
    path = tmp_path / "run.csv"
    path.write_text("time,v,w\n0,0.1,0\n0.05,0.1,0\n0.1,0.1,0\n")
    out = tmp_path / "out" / "inspect.json"
    assert cli.main(["inspect", str(path), "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["files"][0]["mapping"]["cmd.v"] == "v:m/s" and data["command"].startswith(
        "realitygap diagnose"
    )
    assert [p.name for p in out.parent.iterdir()] == ["inspect.json"]
    capsys.readouterr()
    assert cli.main(["inspect", str(path), "--json", str(path)]) == 2
    assert "error: --json" in capsys.readouterr().err and path.read_text().startswith("time")
    assert cli.main(["inspect", str(tmp_path / "absent.csv")]) == 2
    assert "no such file" in capsys.readouterr().err
    (tmp_path / "empty.csv").write_text("")
    assert cli.main(["inspect", str(tmp_path / "empty.csv")]) == 2
    assert "error:" in capsys.readouterr().err


def test_files_holding_different_channels_are_one_recording(tmp_path) -> None:
    d = drive(n=100)
    enc = tmp_path / "enc.csv"
    enc.write_text(
        "stamp,l,r\n"
        + "".join(
            f"{t:.2f},{-le:.0f},{ri:.0f}\n" for t, le, ri in zip(d["t"], d["left"], d["right"])
        )
    )
    mocap = tmp_path / "mocap.csv"
    mocap.write_text(
        "time,x,y,yaw\n"
        + "".join(
            f"{t + 0.01:.2f},{x:.4f},{y:.4f},{th:.4f}\n"
            for t, x, y, th in zip(d["t"][::2], d["x"][::2], d["y"][::2], d["th"][::2])
        )
    )
    result = inspect_paths([enc, mocap])
    assert f"realitygap diagnose {enc}+{mocap} " in result.command
    expected = "t=enc::stamp:s,ticks.left=enc::l,ticks.right=enc::r,t=mocap::time:s,"
    assert expected + "pose_gt.x=mocap::x:m" in result.command
    assert not result.missing  # each file supplies what the other lacks
    column_map = pytest.importorskip("realitygap.diagnosis.logs.importers.column_map")
    text = result.command.split("--columns ")[1].strip("'")
    parsed = column_map.ColumnMap.parse(text)
    assert [s.file for s in parsed.times] == ["enc", "mocap"]
    assert parsed.entries["pose_gt.theta"].file == "mocap"


def test_a_saved_log_and_several_files(tmp_path) -> None:
    Log(t=np.arange(5.0) * 0.1, channels={"cmd": np.zeros((5, 2))}).save(tmp_path / "log.npz")
    csv = tmp_path / "run.csv"
    csv.write_text("time,v,w\n0,0.1,0\n0.05,0.1,0\n0.1,0.1,0\n")
    result = inspect_paths([tmp_path / "log.npz", csv])
    assert [f.kind for f in result.files] == ["log", "table"]
    assert "needs no column map" in result.files[0].summary
    assert result.command.startswith(f"realitygap diagnose {tmp_path / 'log.npz'} {csv} ")


def test_a_ros2_bag_proposes_its_topics(tmp_path) -> None:
    pytest.importorskip("rosbags", reason="ROS bag support is the 'ros' extra")
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    path = tmp_path / "drive_bag"
    with Writer(path, version=8) as writer:
        c_cmd = writer.add_connection("/robot/cmd_vel", "geometry_msgs/msg/Twist", typestore=ts)
        c_gt = writer.add_connection("/vicon/robot", "geometry_msgs/msg/PoseStamped", typestore=ts)
        for k in range(40):
            t_ns = 10**9 + k * 50_000_000
            tw = T["geometry_msgs/msg/Twist"](
                linear=T["geometry_msgs/msg/Vector3"](x=0.2, y=0.0, z=0.0),
                angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            )
            writer.write(c_cmd, t_ns, ts.serialize_cdr(tw, "geometry_msgs/msg/Twist"))
            stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
            pose = T["geometry_msgs/msg/PoseStamped"](
                header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="world"),
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=0.01 * k, y=0.0, z=0.0),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                ),
            )
            writer.write(c_gt, t_ns, ts.serialize_cdr(pose, "geometry_msgs/msg/PoseStamped"))
    result = inspect_path(path)
    f = result.files[0]
    assert f.kind == "bag" and {s.name: s.rows for s in f.streams}["/vicon/robot"] == 40
    assert all(s.rate_hz == pytest.approx(20.0) for s in f.streams)
    assert "--truth-topic /vicon/robot" in result.command
    assert "--cmd-topic /robot/cmd_vel" in result.command and not result.missing


# --------------------------------------------------------------------------- real data
def _data(rel: str) -> Path:
    path = DATA / rel
    if not path.exists():
        pytest.skip(f"real data not found at {path}; it lives in ../shared/data beside the repo")
    return path


def test_real_optiodom_run_without_header() -> None:
    runs = sorted(_data("optiodom_diffdrive/square").glob("*/*_run-01.csv"))
    if not runs:
        pytest.skip("no OptiOdom run file under ../shared/data/optiodom_diffdrive/square")
    result = inspect_path(runs[0])
    f = result.files[0]
    assert "comma-separated" in f.summary and "no header" in f.summary
    assert col(f, "0").meaning == "t" and col(f, "0").unit == "s"
    assert f.streams[0].rate_hz == pytest.approx(20.0, rel=0.01)
    assert {col(f, "4").meaning, col(f, "5").meaning} == {"ticks.left", "ticks.right"}
    assert col(f, "4").note == "counts per row"
    # a run belongs to its session, which the diagnosis reads whole, without a column map
    assert f.kind == "optiodom" and f.diagnose == str(runs[0].parent)
    assert result.command == f"realitygap diagnose {runs[0].parent}"


def test_real_optiodom_session_ur10_and_fr3() -> None:
    session = next(iter(sorted(_data("optiodom_diffdrive/square").iterdir())))
    assert one(session).kind == "optiodom"
    ur10 = one(_data("ipa_ur10_lasertracker/Series_A/measurements_grid.csv"))
    assert ur10.kind == "ur10" and "--robot" in ur10.options
    # a series' transform file is read with the series (a 4×4 matrix without a last newline
    # is no cut-off table either)
    trafo = one(_data("ipa_ur10_lasertracker/Series_A/Trafo_TM_F_init.txt"))
    assert trafo.kind == "ur10" and trafo.diagnose == str(DATA / "ipa_ur10_lasertracker/Series_A")
    result = inspect_path(_data("franka_fr3_eyeinhand/fr3_calib_data.npz"))
    fr3 = result.files[0]
    assert [fr3.mapping[f"joints.q{j}"] for j in range(1, 8)] == [
        f"joint_positions[{j}]:rad" for j in range(7)
    ]
    assert any("tcp_poses (80×4×4) not read: a 3-D array" in n for n in fr3.notes)
    assert any("FR3 eye-in-hand archive" in n for n in fr3.notes)
    assert "--robot arm" in result.command


def test_the_proposed_maps_follow_the_column_map_grammar(tmp_path) -> None:
    column_map = pytest.importorskip("realitygap.diagnosis.logs.importers.column_map")
    d = drive(n=60)
    path = tmp_path / "odd names.csv"
    lines = ["t [ms],x [mm],y [mm],heading,enc-left,enc-right"]
    lines += [
        f"{1000 * t:.0f},{1000 * x:.2f},{1000 * y:.2f},{th:.4f},{le:.0f},{ri:.0f}"
        for t, x, y, th, le, ri in zip(d["t"], d["x"], d["y"], d["th"], d["left"], d["right"])
    ]
    path.write_text("\n".join(lines) + "\n")
    f = one(path)
    assert f.mapping["pose_gt.x"] == '"x [mm]":mm' and f.mapping["ticks.left"] == '"enc-left"'
    parsed = column_map.ColumnMap.parse(",".join(f"{k}={v}" for k, v in f.mapping.items()))
    assert (
        parsed.entries["pose_gt.x"].column == "x [mm]" and parsed.entries["pose_gt.x"].unit == "mm"
    )
    assert parsed.entries["ticks.left"].column == "enc-left" and parsed.time.unit == "ms"


def test_an_unusable_time_column_and_a_second_time_candidate(tmp_path) -> None:
    const = tmp_path / "const.csv"
    const.write_text("time,v,w\n" + "".join(f"5,{0.01 * k:.2f},0\n" for k in range(10)))
    f = one(const)
    assert f.mapping["t"] == "row*<period s>" and col(f, "time").note == "constant"
    assert any("time column time is unusable" in m for m in f.missing)
    echo = tmp_path / "echo.csv"
    stamps = [1_690_000_000_000_000_000 + k * 20_000_000 for k in range(50)]
    echo.write_text(
        "%time,field.header.seq,field.header.stamp,field.twist.linear.x,field.twist.angular.z\n"
        + "".join(f"{s},{k},{s - 3_000_000},0.2,0.1\n" for k, s in enumerate(stamps))
    )
    f = one(echo)
    assert f.mapping == {
        "t": "%time:ns",
        "cmd.v": "field.twist.linear.x:m/s",
        "cmd.w": "field.twist.angular.z:rad/s",
    }
    candidate = next(s for s in f.streams if s.name.startswith("time candidate"))
    assert candidate.columns == ("field.header.stamp",) and candidate.rate_hz == pytest.approx(50.0)
    assert col(f, "field.header.seq").meaning == ""  # a row counter is no encoder
