"""Importers: CSV with a column map, ROS 1 / ROS 2 bags, and the LOG dispatcher."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.logs.importers.csv_log import ColumnMap, read_csv_log
from realitygap.diagnosis.logs.log import LogError
from realitygap.diagnosis.logs.read import ReadOptions, read_logs

MAP = "t=time:ms,cmd.v=v:mm/s,cmd.w=w:deg/s,pose_gt.x=x:mm,pose_gt.y=y:mm,pose_gt.theta=yaw:deg"


def write_csv(path: Path, sep: str = ",", dec: str = ".", n: int = 40, **edits: str) -> Path:
    rows = ["time,v,w,x,y,yaw".replace(",", sep)]
    for k in range(n):
        vals = [50.0 * k, 300.0, 10.0, 15.0 * k, 0.5 * k, 0.5 * k]
        cells = [f"{v:.3f}".replace(".", dec) for v in vals]
        rows.append(sep.join(cells))
    text = "\n".join(rows) + "\n"
    for old, new in edits.items():
        text = text.replace(old, new)
    path.write_text(text, encoding="utf-8")
    return path


def test_csv_with_units_converts_to_si(tmp_path) -> None:
    log = read_csv_log(write_csv(tmp_path / "run.csv"), MAP)
    assert log.dt == pytest.approx(0.05)
    np.testing.assert_allclose(log["cmd"][0], [0.3, math.radians(10.0)])
    np.testing.assert_allclose(log["pose_gt"][2], [0.03, 0.001, math.radians(1.0)])
    assert log.meta["params"]["wheelbase"] == pytest.approx(0.23)


def test_csv_decimal_commas(tmp_path) -> None:
    p = write_csv(tmp_path / "semi.csv", sep=";", dec=",")
    log = read_csv_log(p, MAP)  # detected
    assert log["cmd"][0, 0] == pytest.approx(0.3)
    with pytest.raises(LogError, match=r"semi\.csv, line 2.*decimal comma.*decimal=','"):
        read_csv_log(p, MAP, decimal=".")
    comma = write_csv(tmp_path / "comma.csv", sep=",", dec=",")
    with pytest.raises(LogError, match=r"comma\.csv, line 2: \d+ fields.*decimal commas"):
        read_csv_log(comma, MAP)


def test_csv_errors_name_file_column_and_fix(tmp_path) -> None:
    p = write_csv(tmp_path / "run.csv")
    with pytest.raises(
        LogError, match=r"cmd\.v=vx:mm/s: .*run\.csv: no column 'vx'.*the header has 'time', 'v'"
    ):
        read_csv_log(p, MAP.replace("=v:", "=vx:"))
    with pytest.raises(LogError, match="unknown unit 'furlong'"):
        read_csv_log(p, MAP.replace("x:mm", "x:furlong"))
    with pytest.raises(LogError, match="cannot convert 'rad' to 'm/s'"):
        read_csv_log(p, MAP.replace("v:mm/s", "v:rad"))
    with pytest.raises(LogError, match="needs columns x, y, theta; the column map gives no theta"):
        read_csv_log(p, "t=time:ms,pose_gt.x=x,pose_gt.y=y")
    holes = write_csv(tmp_path / "holes.csv", **{"\n150.000,300.000,": "\n150.000,,"})
    with pytest.raises(LogError, match=r"holes\.csv, line 5: missing.*'cmd\.v'.*nan='interpolate'"):
        read_csv_log(holes, MAP)
    back = write_csv(tmp_path / "back.csv", **{"\n150.000,": "\n10.000,"})
    with pytest.raises(LogError, match=r"back\.csv: time stamps must increase strictly"):
        read_csv_log(back, MAP)


def test_csv_gaps_can_be_interpolated(tmp_path) -> None:
    p = write_csv(
        tmp_path / "gap.csv", **{"\n150.000,300.000,10.000,45.000": "\n150.000,300.000,10.000,"}
    )
    log = read_csv_log(p, MAP, nan="interpolate")
    assert log["pose_gt"][3, 0] == pytest.approx(0.045)
    dropped = read_csv_log(p, MAP, nan="drop")
    assert dropped.n == 39


def test_column_map_parsing_errors() -> None:
    with pytest.raises(LogError, match="no channel column given"):
        ColumnMap.parse("t=time")
    with pytest.raises(LogError, match="unknown channel 'odom'"):
        ColumnMap.parse("t=time,odom.x=x")
    with pytest.raises(LogError, match="expected 'target=column"):
        ColumnMap.parse("t=time,cmd.v")


def test_dispatcher_checks_content_against_extension(tmp_path) -> None:
    csv = write_csv(tmp_path / "run.csv")
    with pytest.raises(LogError, match="needs a column map"):
        read_logs(csv)
    assert read_logs(csv, ReadOptions(columns=MAP))[0].n == 40
    fake_bag = tmp_path / "drive.bag"
    fake_bag.write_text("time,v\n0,1\n")
    with pytest.raises(LogError, match=r"drive\.bag: the extension '\.bag' promises rosbag1"):
        read_logs(fake_bag)
    fake_npz = tmp_path / "log.npz"
    fake_npz.write_text("time,v\n0,1\n")
    with pytest.raises(LogError, match="promises npz but the content looks like text"):
        read_logs(fake_npz)


# --------------------------------------------------------------------------- bags
def _write_bag(path: Path, ros: int, with_truth: bool = True) -> None:
    pytest.importorskip("rosbags", reason="ROS bag support is the 'ros' extra")
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Twist = ts.types["geometry_msgs/msg/Twist"]
    Vector3 = ts.types["geometry_msgs/msg/Vector3"]
    PoseStamped = ts.types["geometry_msgs/msg/PoseStamped"]
    Pose = ts.types["geometry_msgs/msg/Pose"]
    Point = ts.types["geometry_msgs/msg/Point"]
    Quat = ts.types["geometry_msgs/msg/Quaternion"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    if ros == 2:
        pytest.importorskip("rosbags", reason="ROS bag support is the 'ros' extra")
        from rosbags.rosbag2 import Writer

        writer = Writer(path, version=8)
        ser = ts.serialize_cdr
    else:
        pytest.importorskip("rosbags", reason="ROS bag support is the 'ros' extra")
        from rosbags.rosbag1 import Writer  # type: ignore[assignment]

        writer = Writer(path)  # type: ignore[call-arg]
        ser = ts.serialize_ros1
    with writer:
        c_cmd = writer.add_connection("/cmd_vel", Twist.__msgtype__, typestore=ts)
        c_gt = (
            writer.add_connection("/mocap/pose", PoseStamped.__msgtype__, typestore=ts)
            if with_truth
            else None
        )
        for k in range(60):
            t_ns = 1_000_000_000 + k * 50_000_000
            tw = Twist(linear=Vector3(x=0.2, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.5))
            writer.write(c_cmd, t_ns, ser(tw, Twist.__msgtype__))
            if c_gt is not None:
                yaw = 0.025 * k
                msg = PoseStamped(
                    header=Header(
                        stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id="world"
                    ),
                    pose=Pose(
                        position=Point(x=0.01 * k, y=0.0, z=0.0),
                        orientation=Quat(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
                    ),
                )
                writer.write(c_gt, t_ns, ser(msg, PoseStamped.__msgtype__))


@pytest.mark.parametrize("ros", [1, 2])
def test_bag_round_trip(tmp_path, ros: int) -> None:
    path = tmp_path / ("drive.bag" if ros == 1 else "drive_bag")
    _write_bag(path, ros)
    opts = ReadOptions(truth_topic="/mocap/pose")
    log = read_logs(path, opts)[0]
    assert log.dt == pytest.approx(0.05)
    np.testing.assert_allclose(log["cmd"][3], [0.2, 0.5])
    np.testing.assert_allclose(log["pose_gt"][10], [0.1, 0.0, 0.25], atol=1e-9)


def test_bag_with_tf_ground_truth(tmp_path) -> None:
    pytest.importorskip("rosbags", reason="ROS bag support is the 'ros' extra")
    from rosbags.rosbag2 import Writer

    pytest.importorskip("rosbags", reason="ROS bag support is the 'ros' extra")
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    path = tmp_path / "tf_bag"
    with Writer(path, version=8) as writer:
        c_cmd = writer.add_connection("/cmd_vel", "geometry_msgs/msg/Twist", typestore=ts)
        c_tf = writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        for k in range(40):
            t_ns = 5_000_000_000 + k * 50_000_000
            stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
            tw = T["geometry_msgs/msg/Twist"](
                linear=T["geometry_msgs/msg/Vector3"](x=0.1, y=0.0, z=0.0),
                angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            )
            writer.write(c_cmd, t_ns, ts.serialize_cdr(tw, "geometry_msgs/msg/Twist"))
            frames = []
            for child, x in (("odom", 9.0), ("robot", 0.005 * k)):
                frames.append(
                    T["geometry_msgs/msg/TransformStamped"](
                        header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="world"),
                        child_frame_id=child,
                        transform=T["geometry_msgs/msg/Transform"](
                            translation=T["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0),
                            rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                        ),
                    )
                )
            msg = T["tf2_msgs/msg/TFMessage"](transforms=frames)
            writer.write(c_tf, t_ns, ts.serialize_cdr(msg, "tf2_msgs/msg/TFMessage"))
    with pytest.raises(LogError, match="needs the tracked frame"):
        read_logs(path, ReadOptions(truth_topic="/tf"))
    log = read_logs(path, ReadOptions(truth_topic="/tf", truth_frame="robot"))[0]
    np.testing.assert_allclose(log["pose_gt"][10], [0.05, 0.0, 0.0], atol=1e-9)
    with pytest.raises(LogError, match="no transform to frame 'base'"):
        read_logs(path, ReadOptions(truth_topic="/tf", truth_frame="base"))


def test_bag_without_expected_topics(tmp_path) -> None:
    path = tmp_path / "nogt_bag"
    _write_bag(path, 2, with_truth=False)
    with pytest.raises(
        LogError,
        match=r"no topic for truth \(/mocap/pose\); topics present: /cmd_vel.*--truth-topic",
    ):
        read_logs(path, ReadOptions(truth_topic="/mocap/pose"))
