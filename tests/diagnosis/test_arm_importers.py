"""Arm-data importers: the real UR10 and FR3 files, and small malformed ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.logs.importers.franka import read_franka_npz
from realitygap.diagnosis.logs.importers.ur10 import (
    read_transform_txt,
    read_ur10_dataset,
    read_ur10_measurements,
)

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
UR10 = DATA / "ipa_ur10_lasertracker"
FR3 = DATA / "franka_fr3_eyeinhand" / "fr3_calib_data.npz"

HEADER = (
    "Timestamp;Goal x;Goal y;Goal z;Goal roll;Goal pitch;Goal yaw;shoulder_pan_joint;"
    "shoulder_lift_joint;elbow_joint;wrist_1_joint;wrist_2_joint;wrist_3_joint;"
    "measurement_temperature;measurement_x;measurement_y;measurement_z;measurement_rx;"
    "measurement_ry;measurement_rz"
)
ROW = (
    "20200714163904;0,365141;-0,000212669;1,4273;1,57002;1,57007;1,57073;-1,5708;-1,5708;"
    "0,0;-1,5708;0,0;4,79369e-05;23,68;2361,9831;-1368,5474;119,39713;-90,409151;"
    "-59,885105;-90,887438"
)
TRAFO = (
    "-0.00079633 0.99999968 -0. -0.\n-0.99999937 -0.00079633 -0.00079633 0.08679961\n"
    "-0.00079633 -0.00000063 0.99999968 -108.99996544\n0. 0. 0. 1.\n"
)


def _need(path: Path) -> None:
    if not path.exists():
        pytest.skip(
            f"real arm data not found at {path}; it lives in ../shared/data beside the repo"
        )


# --------------------------------------------------------------------------- real files
def test_ur10_dataset_reads_both_series() -> None:
    _need(UR10)
    ds = read_ur10_dataset(UR10)
    assert [s.name.split("/")[0] for s in ds.series] == ["Series_A", "Series_B"]
    a, b = ds.get("Series_A"), ds.get("Series_B")
    assert a.joint_angles.shape == (a.n, 6) and a.n > 1000
    assert b.probe_positions.shape == (b.n, 3) and b.n > 1000
    # first row of Series_A, converted to SI
    np.testing.assert_allclose(a.joint_angles[0], [-1.5708, -1.5708, 0, -1.5708, 0, 0])
    np.testing.assert_allclose(a.probe_positions[0], [2.3619831, -1.3685474, 0.11939713])
    assert a.timestamps_valid and not b.timestamps_valid  # spreadsheet-mangled in B
    assert a.position_std is None and b.position_std is not None
    assert np.all(b.position_std < 1e-3)  # tracker std in m
    R = a.probe_rotations
    np.testing.assert_allclose(
        R @ np.transpose(R, (0, 2, 1)), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )
    np.testing.assert_allclose(a.probe_in_flange, [0.0, 0.0, 0.109], atol=1e-6)
    assert 15.0 < a.temperature_c.min() and a.temperature_c.max() < 35.0
    assert ds.handeye is not None
    np.testing.assert_allclose(np.linalg.norm(ds.handeye.flange_quat_xyzw, axis=1), 1.0)
    with pytest.raises(KeyError, match="available"):
        ds.get("Series_C")


def test_fr3_npz_reads() -> None:
    _need(FR3)
    d = read_franka_npz(FR3)
    assert d.joint_positions.shape == (d.n, 7) and d.n >= 40
    assert d.T_base_tcp.shape == d.T_board_camera.shape == (d.n, 4, 4)
    assert np.all(np.abs(d.camera_positions) < 1.0)


# --------------------------------------------------------------------------- malformed UR10
def _series(tmp_path: Path, body: str, header: str = HEADER) -> Path:
    d = tmp_path / "Series_X"
    d.mkdir(exist_ok=True)
    f = d / "measurements_test.csv"
    f.write_text(header + "\r\n" + body, encoding="utf-8")
    (d / "Trafo_TM_F_init.txt").write_text(TRAFO)
    return f


def test_small_valid_folder(tmp_path: Path) -> None:
    _series(tmp_path, ROW + "\r\n" + ROW.replace("20200714163904", "2,02011E+13") + "\r\n")
    ds = read_ur10_dataset(tmp_path)
    s = ds.series[0]
    assert s.n == 2 and not s.timestamps_valid and ds.handeye is None
    assert s.joint_angles[0, 5] == pytest.approx(4.79369e-05)
    np.testing.assert_allclose(s.T_probe_flange[:3, 3], [0.0, 8.679961e-5, -0.10899996544])


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (ROW + "\n" + ROW.replace(";2361,9831", ";abc"), r"line 3, column 'measurement_x'.*number"),
        (
            ROW + "\n" + ROW[: ROW.rfind(";")],
            r"line 3: expected 20 fields separated by ';', got 19",
        ),
        (ROW.replace("-1,5708;-1,5708", "-90;-1,5708"), r"line 2: joint angle .*radians"),
        ("", "no data rows"),
    ],
)
def test_garbled_measurements_are_named(tmp_path: Path, body: str, message: str) -> None:
    f = _series(tmp_path, body)
    with pytest.raises(ValueError, match=message):
        read_ur10_measurements(f)


def test_missing_column_is_named(tmp_path: Path) -> None:
    f = _series(tmp_path, ROW, HEADER.replace("elbow_joint", "elbow"))
    with pytest.raises(ValueError, match=r"line 1: missing column\(s\) \['elbow_joint'\]"):
        read_ur10_measurements(f)


def test_bad_transform_files(tmp_path: Path) -> None:
    f = tmp_path / "T.txt"
    f.write_text("1 0 0 0\n0 1 0 0\n0 0 1\n0 0 0 1\n")
    with pytest.raises(ValueError, match="line 3: expected 4 numbers"):
        read_transform_txt(f)
    f.write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n")
    with pytest.raises(ValueError, match="line 4: expected '0 0 0 1'"):
        read_transform_txt(f)
    f.write_text("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(ValueError, match="not a rotation"):
        read_transform_txt(f)
    f.write_text("1 0 0 x\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(ValueError, match="line 1, column 'column 4'"):
        read_transform_txt(f)


def test_folder_without_series(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="measurements"):
        read_ur10_dataset(tmp_path)
    with pytest.raises(FileNotFoundError, match="not a directory"):
        read_ur10_dataset(tmp_path / "nope")


# --------------------------------------------------------------------------- malformed npz
def _npz(tmp_path: Path, **arrays) -> Path:
    n = 4
    base = {
        "joint_positions": np.zeros((n, 7)),
        "tcp_poses": np.tile(np.eye(4), (n, 1, 1)),
        "camera_poses": np.tile(np.eye(4), (n, 1, 1)),
    }
    base.update(arrays)
    base = {k: v for k, v in base.items() if v is not None}
    f = tmp_path / "d.npz"
    np.savez(f, **base)
    return f


def test_npz_errors(tmp_path: Path) -> None:
    assert read_franka_npz(_npz(tmp_path)).n == 4
    with pytest.raises(ValueError, match=r"missing array.*did you mean 'joint_position'"):
        read_franka_npz(_npz(tmp_path, joint_positions=None, joint_position=np.zeros((4, 7))))
    with pytest.raises(ValueError, match=r"'camera_poses' must have shape \(4, 4, 4\)"):
        read_franka_npz(_npz(tmp_path, camera_poses=np.zeros((3, 4, 4))))
    bad = np.tile(np.eye(4), (4, 1, 1))
    bad[2, :3, :3] *= 2.0
    with pytest.raises(ValueError, match=r"tcp_poses\[2\] rotation block"):
        read_franka_npz(_npz(tmp_path, tcp_poses=bad))
    with pytest.raises(ValueError, match="non-finite"):
        read_franka_npz(_npz(tmp_path, joint_positions=np.full((4, 7), np.nan)))
    with pytest.raises(ValueError, match="pickled objects"):
        read_franka_npz(_npz(tmp_path, joint_positions=np.array([{"a": 1}] * 4, dtype=object)))
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"not a readable \.npz"):
        read_franka_npz(tmp_path / "junk.npz")
    with pytest.raises(FileNotFoundError):
        read_franka_npz(tmp_path / "missing.npz")
