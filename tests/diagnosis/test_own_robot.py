"""A user's own robot, end to end: recordings in the shapes real robots write them, read with no
converter code (a column map, a robot file or a URDF) and diagnosed.

The recordings come from :mod:`realitygap.independent.recordings`, a generator that shares no
code with the robots or the diagnosis; its ``answer.json`` holds the values it used.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.adapters.diffdrive.skid import complete_skid_steer
from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
from realitygap.diagnosis.logs.read import ReadOptions, read_logs, read_many
from realitygap.diagnosis.logs.robot_file import (
    RobotFileError,
    description_from_urdf,
    load_robot_file,
)
from realitygap.diagnosis.problem.problem import AttributionSettings
from realitygap.independent import recordings as rec

SHORT = (40.0, 50.0)
TEXT_MAP = (
    "t=time,ticks.left=-enc_l,ticks.right=enc_r,cmd.v=v_cmd,cmd.w=w_cmd,"
    "pose_gt.x=x:mm,pose_gt.y=y:mm,pose_gt.theta=-heading:deg"
)


def _days(w: rec.Written) -> tuple[list[Path], list[Path]]:
    days = w.answer["days"]
    return [w.folder / f for f in days["1"]], [w.folder / f for f in days["2"]]


def _robot_file(path: Path, body: str) -> Path:
    path.write_text(body, encoding="utf-8")
    return path


def _quick(robot: str = "diffdrive", drive: str = "ticks") -> DiagnosisSettings:
    return DiagnosisSettings(
        robot=robot, drive=drive, attribution=AttributionSettings(pair_candidates=0, verify_top=1)
    )


@pytest.fixture(scope="module")
def titled(tmp_path_factory: pytest.TempPathFactory) -> rec.Written:
    """Whitespace-aligned text with two title lines, a mirrored left encoder, a clockwise heading
    in degrees, positions in mm, and a marker 0.2 m behind the axle."""
    return rec.text_title_mirrored(3, tmp_path_factory.mktemp("titled"), duration_s=SHORT)


def test_urdf_gives_the_nominal_that_params_give(titled: rec.Written) -> None:
    nominal = titled.answer["nominal"]
    d = description_from_urdf(titled.folder / "robot.urdf")
    assert d.kind == "diffdrive" and d.robot == "diffdrive"
    assert d.params["wheel_radius_left"] == pytest.approx(nominal["wheel_radius_m"], abs=1e-12)
    assert d.params["wheel_radius_right"] == pytest.approx(nominal["wheel_radius_m"], abs=1e-12)
    assert d.params["wheelbase"] == pytest.approx(nominal["wheelbase_m"], abs=1e-12)
    # the same logs through --urdf and through --params
    train, _ = _days(titled)
    by_urdf = read_logs(
        train[0],
        ReadOptions(
            columns=TEXT_MAP, params={**d.params, "ticks_per_rev": nominal["ticks_per_rev"]}
        ),
    )[0]
    by_params = read_logs(
        train[0],
        ReadOptions(
            columns=TEXT_MAP,
            params={
                "wheel_radius_left": nominal["wheel_radius_m"],
                "wheel_radius_right": nominal["wheel_radius_m"],
                "wheelbase": nominal["wheelbase_m"],
                "ticks_per_rev": nominal["ticks_per_rev"],
            },
        ),
    )[0]
    for k in ("wheel_radius_left", "wheel_radius_right", "wheelbase", "ticks_per_rev"):
        assert by_urdf.meta["params"][k] == pytest.approx(by_params.meta["params"][k], abs=1e-12)


def test_titled_mirrored_file_reads_with_a_column_map(titled: rec.Written) -> None:
    train, _ = _days(titled)
    log = read_logs(train[0], ReadOptions(columns=TEXT_MAP, params={"ticks_per_rev": 4096}))[0]
    a = titled.answer
    # the mirrored encoder counts up when the robot rolls forward once its sign is flipped
    moving = np.diff(log["ticks"][:, 0]) != 0
    assert np.mean(np.diff(log["ticks"][:, 0])[moving] > 0) > 0.6
    # the heading turns with the encoders (counter-clockwise positive after the sign flip)
    dturn = np.diff(log["ticks"][:, 1] - log["ticks"][:, 0])
    dth = np.diff(log["pose_gt"][:, 2])
    assert float(np.corrcoef(dturn, dth)[0, 1]) > 0.9
    rows = len(train[0].read_text().splitlines()) - a["title_lines"] - 1
    assert log.n == rows and log.dt == pytest.approx(1 / a["log_rate_hz"])


def test_undeclared_tracked_point_behind_the_axle_is_named_within_1cm(
    titled: rec.Written,
) -> None:
    nominal = titled.answer["nominal"]
    opts = ReadOptions(
        columns=TEXT_MAP,
        params={
            "wheel_radius_left": nominal["wheel_radius_m"],
            "wheel_radius_right": nominal["wheel_radius_m"],
            "wheelbase": nominal["wheelbase_m"],
            "ticks_per_rev": nominal["ticks_per_rev"],
        },
    )
    train, held = _days(titled)
    d = diagnose(read_many(train, opts), read_many(held, opts), settings=_quick())
    assert "truth_frame_offset" in d.budget_model.effects
    xo, yo = titled.answer["true"]["mocap_offset_m"]
    assert d.budget_model.values["truth_frame_offset.x"] == pytest.approx(xo, abs=0.01)
    assert d.budget_model.values["truth_frame_offset.y"] == pytest.approx(yo, abs=0.01)


def test_declared_tracked_point_is_estimated_within_its_uncertainty(
    titled: rec.Written, tmp_path: Path
) -> None:
    robot = _robot_file(
        tmp_path / "robot.yaml",
        f"""robot: diffdrive
urdf: {titled.folder / "robot.urdf"}
wheels:
  ticks_per_rev: 4096
ground_truth:
  tracked_point: {{x: -0.20, y: 0.0, yaw: 0.0}}
  uncertainty: {{xy: 0.01, yaw: 0.02}}
""",
    )
    desc = load_robot_file(robot)
    assert desc.meta["truth_frame"]["x"] == -0.2
    opts = ReadOptions(columns=TEXT_MAP, **{k: v for k, v in desc.read_options().items()})
    train, held = _days(titled)
    d = diagnose(read_many(train, opts), read_many(held, opts), settings=_quick())
    xo, yo = titled.answer["true"]["mocap_offset_m"]
    base = d.baseline.values
    assert base["truth_frame_offset.x"] == pytest.approx(xo, abs=0.01)
    assert -0.21 <= base["truth_frame_offset.x"] <= -0.19  # within the declared uncertainty
    assert base["truth_frame_offset.y"] == pytest.approx(yo, abs=0.01)
    assert "truth_frame_offset" not in d.budget_model.effects


def test_skid_steer_effective_track_within_one_percent(tmp_path: Path) -> None:
    w = rec.skid_steer(5, tmp_path / "skid", duration_s=SHORT)
    robot = _robot_file(
        tmp_path / "robot.yaml",
        f"robot: skid_steer\nurdf: {w.folder / 'robot.urdf'}\nwheels:\n"
        f"  ticks_per_rev: {w.answer['nominal']['ticks_per_rev']}\n",
    )
    desc = load_robot_file(robot)
    assert desc.meta["drive_kind"] == "skid_steer"
    assert desc.meta["wheel_track"] == pytest.approx(w.answer["nominal"]["track_m"], abs=1e-12)
    opts = ReadOptions(
        columns="t=time,ticks.left=enc_left,ticks.right=enc_right,cmd.v=v_cmd,cmd.w=w_cmd,"
        "pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw",
        **desc.read_options(),
    )
    train, held = _days(w)
    tr, ho, report = complete_skid_steer(read_many(train, opts), read_many(held, opts))
    truth = w.answer["effective_track_m"]
    assert report["value"] == pytest.approx(truth, rel=0.01)
    assert all(lg.meta["params"]["wheelbase"] == report["value"] for lg in tr + ho)
    # a declared effective track is kept as declared
    fixed = _robot_file(
        tmp_path / "fixed.yaml",
        f"robot: skid_steer\nurdf: {w.folder / 'robot.urdf'}\nwheels:\n"
        f"  ticks_per_rev: 8192\n  effective_track: 0.8\n",
    )
    assert load_robot_file(fixed).params["wheelbase"] == 0.8


def test_interleaved_streams_and_two_files_read_without_a_converter(tmp_path: Path) -> None:
    one = rec.multirate_one_file(7, tmp_path / "one", duration_s=SHORT, runs_per_day=(1, 1))
    two = rec.multirate_one_file(
        7, tmp_path / "two", duration_s=SHORT, runs_per_day=(1, 1), layout="split"
    )
    params = {
        "ticks_per_rev": one.answer["nominal"]["ticks_per_rev"],
        "wheel_radius_left": one.answer["nominal"]["wheel_radius_m"],
        "wheel_radius_right": one.answer["nominal"]["wheel_radius_m"],
        "wheelbase": one.answer["nominal"]["wheelbase_m"],
    }
    cols = (
        "t=time,ticks.left=enc_left,ticks.right=enc_right,cmd.v=v_cmd,cmd.w=w_cmd,"
        "pose_gt.x=mocap_x,pose_gt.y=mocap_y,pose_gt.theta=mocap_yaw"
    )
    (a,) = read_logs(_days(one)[0][0], ReadOptions(columns=cols, params=params))
    assert a.dt == pytest.approx(1 / one.answer["encoder_rate_hz"], rel=1e-6)
    assert "aligned" in a.meta
    run = two.folder / two.answer["days"]["1"][0]
    cols2 = (
        "t=enc::stamp,t=mocap::time,ticks.left=enc_left,ticks.right=enc_right,"
        "cmd.v=v_cmd,cmd.w=w_cmd,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw"
    )
    (b,) = read_logs(
        f"{run / 'enc.csv'}+{run / 'mocap.csv'}", ReadOptions(columns=cols2, params=params)
    )
    assert b.dt == pytest.approx(1 / two.answer["encoder_rate_hz"], rel=1e-6)
    # the same recording in both layouts reads to the same log
    np.testing.assert_allclose(a.t, b.t, atol=1e-6)
    np.testing.assert_allclose(a["pose_gt"], b["pose_gt"], atol=1e-6)


def test_mat_file_reads_with_a_column_map(tmp_path: Path) -> None:
    w = rec.mat_file(11, tmp_path / "mat", duration_s=SHORT, runs_per_day=(1, 1))
    f = _days(w)[0][0]
    (log,) = read_logs(
        f,
        ReadOptions(
            columns="t=t,ticks.left=encL,ticks.right=encR,cmd.v=v,cmd.w=w,pose_gt.x=x,pose_gt.y=y,"
            "pose_gt.theta=yaw",
            params={"ticks_per_rev": w.answer["nominal"]["ticks_per_rev"]},
        ),
    )
    assert log.dt == pytest.approx(1 / w.answer["log_rate_hz"], rel=1e-6)
    assert log.duration == pytest.approx(w.answer["runs"][0]["duration_s"], abs=0.02)


def test_ros2_bag_with_its_urdf(tmp_path: Path) -> None:
    pytest.importorskip("rosbags")
    w = rec.ros2_bag(13, tmp_path / "bag", duration_s=SHORT, runs_per_day=(1, 1))
    d = description_from_urdf(w.folder / "robot.urdf")
    assert d.params["wheelbase"] == pytest.approx(w.answer["nominal"]["wheelbase_m"], abs=1e-12)
    run = _days(w)[0][0]
    (log,) = read_logs(
        run,
        ReadOptions(
            truth_topic="/mocap/robot/pose",
            wheels_topic="/joint_states",
            odom_topic=None,
            params={**d.params, "ticks_per_rev": w.answer["nominal"]["ticks_per_rev"]},
        ),
    )
    assert log.has("ticks") and log.has("pose_gt") and log.has("cmd")
    assert log.duration == pytest.approx(w.answer["runs"][0]["duration_s"], abs=0.2)
    # the topics keep their own stamps: the log is on the wheel joints' (50 Hz), the 100 Hz
    # motion capture and the 20 Hz commands aligned there, no resampling
    rates = {t: v["rate_hz"] for t, v in w.answer["topics"].items()}
    assert log.dt == pytest.approx(1 / rates["/joint_states"], rel=1e-3)
    assert "aligned on the stamps of 'ticks'" in log.meta["aligned"]
    # the encoder counts come back exactly from the joint angles
    assert np.all(log["ticks"] == np.rint(log["ticks"]))


def test_arm_csv_with_its_urdf_is_diagnosed(tmp_path: Path) -> None:
    w = rec.arm_csv(17, tmp_path / "arm", n_poses=60)
    robot = _robot_file(
        tmp_path / "arm.yaml",
        f"robot: arm\nurdf: {w.folder / 'arm.urdf'}\narm:\n  noise: {w.answer['noise_std_m']}\n",
    )
    desc = load_robot_file(robot)
    cols = ",".join(f"joints.q{i}=q{i}_deg:deg" for i in range(1, 7)) + (
        ",tool_pos.x=x_mm:mm,tool_pos.y=y_mm:mm,tool_pos.z=z_mm:mm"
    )
    opts = ReadOptions(columns=cols, **desc.read_options())
    (log,) = read_logs(w.folder / "measurements.csv", opts)
    assert log.meta["robot"] == "arm" and log.n == 60
    half = log.n // 2
    d = diagnose([log.slice(0, half)], [log.slice(half, log.n)], settings=_quick("arm", "commands"))
    # millimetre link errors and milliradian offsets: the nominal leaves millimetres, the
    # diagnosis's geometry closes most of it on the held-out half
    assert d.budget is not None
    assert d.budget_model.effects, "a geometric error of the arm should be named"


def test_robot_file_errors_name_the_key_and_the_fix(tmp_path: Path) -> None:
    bad = _robot_file(tmp_path / "a.yaml", "robot: diffdrive\nwheels:\n  radious: 0.03\n")
    with pytest.raises(RobotFileError, match=r"a\.yaml: wheels: unknown key.*'radious'.*'radius'"):
        load_robot_file(bad)
    kind = _robot_file(tmp_path / "b.yaml", "robot: tank\n")
    with pytest.raises(RobotFileError, match="robot: expected one of diffdrive, skid_steer, arm"):
        load_robot_file(kind)
    mm = _robot_file(tmp_path / "c.yaml", "robot: diffdrive\nwheels:\n  radius: 35\n")
    with pytest.raises(RobotFileError, match=r"lies outside the physical range.*mm written as m"):
        load_robot_file(mm)
    far = _robot_file(
        tmp_path / "d.json",
        json.dumps({"robot": "diffdrive", "ground_truth": {"tracked_point": {"x": 200}}}),
    )
    with pytest.raises(
        RobotFileError, match=r"tracked_point\.x: 200 m lies outside the physical range"
    ):
        load_robot_file(far)
    tag = _robot_file(tmp_path / "e.yaml", "robot: !!python/object:os.system diffdrive\n")
    with pytest.raises(RobotFileError, match="not valid YAML"):
        load_robot_file(tag)
    with pytest.raises(FileNotFoundError):
        load_robot_file(tmp_path / "none.yaml")
    assert math.isfinite(
        load_robot_file(
            _robot_file(
                tmp_path / "f.yaml", "robot: diffdrive\nwheels: {radius: 0.05, track: 0.4}\n"
            )
        ).params["wheelbase"]
    )
