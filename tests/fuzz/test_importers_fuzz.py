"""Fuzzing every importer: damaged files end in a clear error naming the file, or load.

Each test starts from a valid file of one format and lets ``hypothesis`` damage it:
truncation, byte flips, column shuffles, unit scalings, NaN/inf cells and huge
headers. An importer may load the result (then the log must be finite and have
increasing time) or raise ``ValueError`` (``LogError`` is one) whose message names
the file; any other exception type, or a run past the deadline, fails.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from realitygap.diagnosis.logs.importers.csv_log import read_csv_log
from realitygap.diagnosis.logs.importers.franka import read_franka_npz
from realitygap.diagnosis.logs.importers.ur10 import read_ur10_measurements
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.logs.read import ReadOptions, read_logs

FUZZ = settings(
    max_examples=80,
    deadline=3000,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    derandomize=True,
)

CSV_MAP = "t=time:s,cmd.v=v,cmd.w=w,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw"


@contextmanager
def scratch() -> Iterator[Path]:
    d = Path(tempfile.mkdtemp(prefix="rg-fuzz-"))
    try:
        yield d
    finally:
        shutil.rmtree(d, ignore_errors=True)


def expect_clear(load: Callable[[], object], path: Path) -> object:
    """Run ``load``: a result, or a ``ValueError`` naming ``path``; nothing else."""
    try:
        out = load()
    except ValueError as exc:
        assert path.name in str(exc), f"message does not name the file: {exc}"
        return None
    for log in out if isinstance(out, list) else []:
        if isinstance(log, Log):
            assert np.all(np.diff(log.t) > 0)
            assert all(np.all(np.isfinite(v)) for v in log.channels.values())
    return out


# --------------------------------------------------------------------------- damage
def damage(data: bytes, draw: st.DataObject) -> bytes:
    kind = draw.draw(st.sampled_from(["truncate", "flip", "insert", "header"]))
    if kind == "truncate":
        return data[: draw.draw(st.integers(0, len(data)))]
    if kind == "flip":
        buf = bytearray(data)
        for _ in range(draw.draw(st.integers(1, 8))):
            i = draw.draw(st.integers(0, len(buf) - 1))
            buf[i] = draw.draw(st.integers(0, 255))
        return bytes(buf)
    if kind == "insert":
        i = draw.draw(st.integers(0, len(data)))
        return data[:i] + draw.draw(st.binary(min_size=1, max_size=64)) + data[i:]
    return b"x" * draw.draw(st.sampled_from([1000, 100_000])) + b"," + data


def csv_text(n: int = 60, scale: float = 1.0) -> str:
    lines = ["time,v,w,x,y,yaw"]
    for k in range(n):
        t = 0.05 * k
        lines.append(
            f"{t:.3f},0.2,0.1,{scale * 0.01 * k:.5f},{scale * 0.001 * k:.5f},{0.005 * k:.5f}"
        )
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- CSV
@pytest.mark.slow
@FUZZ
@given(data=st.data())
def test_csv_bytes_damaged(data: st.DataObject) -> None:
    with scratch() as d:
        f = d / "run.csv"
        f.write_bytes(damage(csv_text().encode(), data))
        expect_clear(lambda: read_csv_log(f, CSV_MAP), f)
        expect_clear(lambda: read_logs(f, ReadOptions(columns=CSV_MAP)), f)


@FUZZ
@given(
    perm=st.permutations(range(6)),
    scale=st.sampled_from([1.0, 1e-3, 1e3, -1.0]),
    cell=st.sampled_from(["nan", "inf", "-inf", "", "1e308", "0x10", "1,5"]),
    where=st.tuples(st.integers(1, 60), st.integers(0, 5)),
)
def test_csv_columns_shuffled_scaled_and_poisoned(
    perm: list[int], scale: float, cell: str, where: tuple[int, int]
) -> None:
    rows = [r.split(",") for r in csv_text(scale=scale).splitlines()]
    rows = [[r[j] for j in perm] for r in rows]
    rows[where[0]][where[1]] = cell
    with scratch() as d:
        f = d / "run.csv"
        f.write_text("\n".join(",".join(r) for r in rows) + "\n")
        for nan in ("raise", "interpolate", "drop"):
            expect_clear(lambda nan=nan: read_logs(f, ReadOptions(columns=CSV_MAP, nan=nan)), f)


# --------------------------------------------------------------------------- saved logs
def saved_log(path: Path) -> bytes:
    t = np.arange(40) * 0.05
    log = Log(
        t=t,
        channels={
            "cmd": np.column_stack([np.full(40, 0.2), np.zeros(40)]),
            "pose_gt": np.column_stack([0.01 * np.arange(40), np.zeros(40), np.zeros(40)]),
        },
        meta={"robot": "diffdrive"},
    )
    log.save(path)
    return path.read_bytes()


@FUZZ
@given(data=st.data())
def test_log_load_damaged(data: st.DataObject) -> None:
    with scratch() as d:
        f = d / "log.npz"
        raw = saved_log(f)
        f.write_bytes(damage(raw, data))
        expect_clear(lambda: [Log.load(f)], f)
        expect_clear(lambda: read_logs(f), f)


@FUZZ
@given(
    field=st.sampled_from(["channels", "version", "meta", "role", "columns", "format"]),
    value=st.sampled_from([[], "one", 1.5, None, {"a": 1}, ["x"], -1, 10**30]),
)
def test_log_load_bad_header_fields(field: str, value: object) -> None:
    import json

    with scratch() as d:
        f = d / "log.npz"
        saved_log(f)
        with np.load(f) as z:
            arrays = {k: z[k] for k in z.files}
        header = json.loads(bytes(arrays["meta.json"]))
        if field in ("role", "columns"):
            header["channels"]["cmd"][field] = value
        else:
            header[field] = value
        arrays["meta.json"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
        np.savez(f, **arrays)
        expect_clear(lambda: [Log.load(f)], f)


def test_log_load_refuses_huge_array_headers_before_allocating(tmp_path: Path) -> None:
    f = tmp_path / "bomb.npz"
    saved_log(f)
    import zipfile

    big = np.lib.format.header_data_from_array_1_0(np.zeros(1))
    big["shape"] = (10**12,)
    with zipfile.ZipFile(f, "a") as zf, zf.open("ch.huge.npy", "w") as fh:
        np.lib.format.write_array_header_1_0(fh, big)
        fh.write(b"\0" * 64)
    with pytest.raises(ValueError, match=r"bomb\.npz.*exceed the limit.*REALITYGAP_MAX_CELLS"):
        Log.load(f)


# --------------------------------------------------------------------------- UR10 and FR3
UR10_HEADER = (
    "Timestamp;Goal x;Goal y;Goal z;Goal roll;Goal pitch;Goal yaw;shoulder_pan_joint;"
    "shoulder_lift_joint;elbow_joint;wrist_1_joint;wrist_2_joint;wrist_3_joint;"
    "measurement_temperature;measurement_x;measurement_y;measurement_z;measurement_rx;"
    "measurement_ry;measurement_rz"
)
UR10_ROW = (
    "20200714163904;0,365141;-0,000212669;1,4273;1,57002;1,57007;1,57073;-1,5708;-1,5708;"
    "0,0;-1,5708;0,0;4,79369e-05;23,68;2361,9831;-1368,5474;119,39713;-90,409151;"
    "-59,885105;-90,887438"
)


@FUZZ
@given(data=st.data())
def test_ur10_damaged(data: st.DataObject) -> None:
    body = UR10_HEADER + "\r\n" + "\r\n".join([UR10_ROW] * 6) + "\r\n"
    with scratch() as d:
        f = d / "measurements_x.csv"
        f.write_bytes(damage(body.encode(), data))
        expect_clear(lambda: read_ur10_measurements(f, None), f)
        expect_clear(lambda: read_logs(f), f)


@FUZZ
@given(data=st.data())
def test_fr3_damaged(data: st.DataObject) -> None:
    with scratch() as d:
        f = d / "fr3.npz"
        n = 5
        np.savez(
            f,
            joint_positions=np.zeros((n, 7)),
            tcp_poses=np.tile(np.eye(4), (n, 1, 1)),
            camera_poses=np.tile(np.eye(4), (n, 1, 1)),
        )
        f.write_bytes(damage(f.read_bytes(), data))
        expect_clear(lambda: read_franka_npz(f), f)


# --------------------------------------------------------------------------- ROS bags
@settings(
    max_examples=15,
    deadline=5000,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(data=st.data())
def test_ros1_bag_damaged(data: st.DataObject) -> None:
    pytest.importorskip("rosbags", reason="ROS bag support is the 'ros' extra")
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Twist = ts.types["geometry_msgs/msg/Twist"]
    Vector3 = ts.types["geometry_msgs/msg/Vector3"]
    with scratch() as d:
        f = d / "drive.bag"
        with Writer(f) as w:
            c = w.add_connection("/cmd_vel", Twist.__msgtype__, typestore=ts)
            for k in range(30):
                tw = Twist(
                    linear=Vector3(x=0.2, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.1)
                )
                w.write(c, 10**9 + k * 50_000_000, ts.serialize_ros1(tw, Twist.__msgtype__))
        f.write_bytes(damage(f.read_bytes(), data))
        expect_clear(lambda: read_logs(f, ReadOptions(truth_topic="/cmd_vel")), f)


# --------------------------------------------------------------------------- OptiOdom
OPTIODOM = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "optiodom_diffdrive"


def _smallest_session() -> Path | None:
    if not OPTIODOM.is_dir():
        return None
    folders = [p for p in OPTIODOM.glob("*/*") if p.is_dir()]
    return min(folders, key=lambda p: sum(f.stat().st_size for f in p.iterdir()), default=None)


@pytest.mark.slow
@FUZZ
@given(data=st.data())
def test_optiodom_session_damaged(data: st.DataObject) -> None:
    src = _smallest_session()
    if src is None:
        pytest.skip("the OptiOdom data set is not installed")
    with scratch() as d:
        dst = d / src.name
        shutil.copytree(src, dst)
        files = sorted(p for p in dst.iterdir() if p.is_file())
        f = data.draw(st.sampled_from(files))
        f.write_bytes(damage(f.read_bytes(), data))
        expect_clear(lambda: read_logs(dst), dst)


def test_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    f = tmp_path / "pipe.csv"
    import os

    os.mkfifo(f)
    with pytest.raises(ValueError, match=r"pipe\.csv is a FIFO"):
        read_logs(f, ReadOptions(columns=CSV_MAP))
    with pytest.raises(ValueError, match=r"pipe\.csv is a FIFO"):
        Log.load(f)
    assert math.isfinite(0.0)
