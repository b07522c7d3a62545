"""Self-consistency of the recording generator (realitygap.independent.recordings).

The files are parsed here with plain ``csv``/NumPy (and ``scipy.io.loadmat``,
``rosbags`` for the bag); dead reckoning and arm kinematics are re-implemented
here, so the tests check that the files mean what ``answer.json`` says.
"""

from __future__ import annotations

import csv
import json
import math
import pathlib
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy import io as sio

from realitygap.independent import recordings as rec

SHORT = (20.0, 30.0)  # short runs keep the tests fast
TWO_PI = 2.0 * math.pi


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------
def _answer(folder: pathlib.Path) -> dict:
    return json.loads((folder / "answer.json").read_text(encoding="utf-8"))


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + math.pi) % TWO_PI - math.pi


def _wheel_angles(counts: np.ndarray, answer: dict, side: int) -> np.ndarray:
    """Wheel angle since the run start (forward positive) from raw counts."""
    enc = answer["encoders"]
    sign = enc["left_sign"] if side == 0 else enc["right_sign"]
    counts = np.asarray(counts, dtype=float)
    return sign * (counts - counts[0]) * TWO_PI / enc["ticks_per_rev"]


def _dead_reckon(
    phi_l: np.ndarray, phi_r: np.ndarray, rl: float, rr: float, track: float, start: list
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axle-centre pose from wheel angles (midpoint heading per interval)."""
    th = start[2] + (rr * phi_r - rl * phi_l) / track
    ds = (rr * np.diff(phi_r) + rl * np.diff(phi_l)) / 2.0
    thm = 0.5 * (th[:-1] + th[1:])
    x = start[0] + np.concatenate([[0.0], np.cumsum(ds * np.cos(thm))])
    y = start[1] + np.concatenate([[0.0], np.cumsum(ds * np.sin(thm))])
    return x, y, th


def _marker(x, y, th, offset, yaw_offset):
    c, s = np.cos(th), np.sin(th)
    return x + c * offset[0] - s * offset[1], y + s * offset[0] + c * offset[1], th + yaw_offset


def _errors(answer: dict, run: dict, phi_l, phi_r, logged, *, geometry: str = "true", at=None):
    """Max position (m) and yaw (rad) error of dead reckoning against the logged pose.

    ``at`` optionally gives (encoder times, mocap times) to interpolate onto.
    """
    g = answer[geometry]
    if answer["robot"] == "skid_steer":
        rl = rr = g["wheel_radius_m"]
        track = g["effective_track_m"] if geometry == "true" else g["track_m"]
    else:
        rl = g["wheel_radius_left_m"] if geometry == "true" else g["wheel_radius_m"]
        rr = g["wheel_radius_right_m"] if geometry == "true" else g["wheel_radius_m"]
        track = g["wheelbase_m"]
    x, y, th = _dead_reckon(phi_l, phi_r, rl, rr, track, run["start_pose_world"])
    if at is not None:
        x, y, th = (np.interp(at[1], at[0], s) for s in (x, y, th))
    true = answer["true"]
    xm, ym, yaw = _marker(x, y, th, true["mocap_offset_m"], true["mocap_yaw_offset_rad"])
    lx, ly, lyaw = logged
    pos = np.hypot(xm - lx, ym - ly)
    return float(pos.max()), float(np.abs(_wrap(yaw - lyaw)).max())


def _read_text(path: pathlib.Path, separator: str) -> tuple[list[str], list[str], np.ndarray]:
    lines = path.read_text(encoding="utf-8").splitlines()
    split = (lambda s: s.split()) if separator == "whitespace" else (lambda s: s.split("|"))
    header = [h.strip() for h in split(lines[2])]
    data = np.array([[float(v) for v in split(line)] for line in lines[3:]])
    return lines[:2], header, data


# --------------------------------------------------------------------------
# fixtures: every shape written once, with short runs
# --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def out(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    root = tmp_path_factory.mktemp("recordings")
    rec.text_title_mirrored(11, root / "text_ws", duration_s=SHORT)
    rec.text_title_mirrored(12, root / "text_pipe", separator="pipe", duration_s=SHORT)
    rec.multirate_one_file(13, root / "multi", duration_s=SHORT)
    rec.multirate_one_file(14, root / "split", layout="split", duration_s=SHORT)
    rec.mat_file(15, root / "mat", duration_s=SHORT)
    rec.skid_steer(16, root / "skid", duration_s=SHORT)
    rec.arm_csv(17, root / "arm")
    return root


# --------------------------------------------------------------------------
# determinism and layout
# --------------------------------------------------------------------------
def _files(folder: pathlib.Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


@pytest.mark.parametrize(
    ("writer", "kwargs"),
    [
        (rec.text_title_mirrored, {"duration_s": (15.0, 16.0)}),
        (rec.multirate_one_file, {"duration_s": (15.0, 16.0)}),
        (rec.multirate_one_file, {"duration_s": (15.0, 16.0), "layout": "split"}),
        (rec.mat_file, {"duration_s": (15.0, 16.0)}),
        (rec.skid_steer, {"duration_s": (15.0, 16.0)}),
        (rec.arm_csv, {}),
    ],
)
def test_same_seed_same_bytes(tmp_path: pathlib.Path, writer, kwargs) -> None:
    a = writer(5, tmp_path / "a", **kwargs)
    b = writer(np.random.default_rng(5), tmp_path / "b", **kwargs)
    c = writer(6, tmp_path / "c", **kwargs)
    fa, fb, fc = _files(a.folder), _files(b.folder), _files(c.folder)
    fa.pop("answer.json"), fb.pop("answer.json"), fc.pop("answer.json")  # seed field differs
    assert fa == fb
    assert fa.keys() == fc.keys()
    assert any(fa[k] != fc[k] for k in fa)
    assert a.answer["seed"] == 5 and b.answer["seed"] is None


def test_runs_days_and_answer_written(out: pathlib.Path) -> None:
    for name in ("text_ws", "text_pipe", "multi", "split", "mat", "skid"):
        ans = _answer(out / name)
        assert len(ans["runs"]) >= 4
        assert set(ans["days"]) == {"1", "2"} and all(ans["days"].values())
        for run in ans["runs"]:
            assert run["file"] in ans["days"][str(run["day"])]
            assert (out / name / run["file"]).exists()
            assert SHORT[0] - 0.05 <= run["duration_s"] <= SHORT[1] + 0.05
        assert (out / name / "robot.urdf").exists()
        nominal = json.loads((out / name / "robot.json").read_text())
        assert nominal["wheel_radius_m"] == ans["nominal"]["wheel_radius_m"]
        assert ans["nominal"]["wheel_radius_m"] != ans["true"]["wheel_radius_left_m"]


def test_default_runs_last_60_to_120_s() -> None:
    rng = np.random.default_rng(3)
    for _ in range(5):
        length = rng.uniform(60.0, 120.0)
        v, w = rec.plan_commands(rng, length, 20, (0.0, 0.0, 0.0), (0.0, 0.0))
        assert abs(v.size / 20.0 - length) <= 0.05
        assert np.all(v[-40:] == 0.0) and np.all(w[-40:] == 0.0)
        assert v.max() <= 0.5 and np.abs(w).max() <= 1.2


# --------------------------------------------------------------------------
# 1. text, mirrored encoder, clockwise heading
# --------------------------------------------------------------------------
@pytest.mark.parametrize(("name", "separator"), [("text_ws", "whitespace"), ("text_pipe", "pipe")])
def test_text_means_what_the_answer_says(out: pathlib.Path, name: str, separator: str) -> None:
    ans = _answer(out / name)
    assert ans["separator"] == separator
    for run in ans["runs"]:
        titles, header, data = _read_text(out / name / run["file"], separator)
        assert titles[0].startswith("Kobuki logger v2.1")
        assert titles[1] == "units: time s, pose mm, heading deg"
        assert header == ["time", "enc_l", "enc_r", "v_cmd", "w_cmd", "x", "y", "heading"]
        t, el, er, _v, _w, x, y, hd = data.T
        assert np.allclose(np.diff(t), 0.02)
        assert el[0] == run["encoder_offsets_counts"][0]
        logged = (x / 1e3, y / 1e3, -np.radians(hd))
        pos, yaw = _errors(ans, run, _wheel_angles(el, ans, 0), _wheel_angles(er, ans, 1), logged)
        assert pos < 0.004 and yaw < 0.006, (pos, yaw)
        pos_n, yaw_n = _errors(
            ans,
            run,
            _wheel_angles(el, ans, 0),
            _wheel_angles(er, ans, 1),
            logged,
            geometry="nominal",
        )
        assert yaw_n > 5 * yaw and pos_n > 5 * pos


def test_mirrored_left_encoder_and_clockwise_heading(out: pathlib.Path) -> None:
    ans = _answer(out / "text_ws")
    assert ans["encoders"]["left_sign"] == -1 and ans["encoders"]["right_sign"] == 1
    _, _, data = _read_text(out / "text_ws" / ans["runs"][0]["file"], "whitespace")
    _t, el, er, v, w, _, _, hd = data.T
    # steady straight driving (command held for 0.3 s): left counts fall, right counts rise
    held = np.array([np.all(v[max(0, k - 15) : k + 1] == v[k]) for k in range(v.size)])
    fwd = np.flatnonzero(held & (v > 0.1) & (w == 0.0))
    assert fwd.size > 20
    assert np.all(el[fwd] - el[fwd - 1] < 0) and np.all(er[fwd] - er[fwd - 1] > 0)
    # a counter-clockwise turn (w > 0) makes the logged heading fall
    ccw = np.flatnonzero(held & (v == 0.0) & (w > 0.3))
    cw = np.flatnonzero(held & (v == 0.0) & (w < -0.3))
    dh = np.diff(np.unwrap(np.radians(hd)))
    for idx, sign in ((ccw, -1.0), (cw, 1.0)):
        if idx.size:
            assert np.all(sign * dh[idx - 1] > 0)
    assert ccw.size + cw.size > 20


# --------------------------------------------------------------------------
# 2. two rates
# --------------------------------------------------------------------------
def _read_csv(path: pathlib.Path) -> tuple[list[str], list[list[str]]]:
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def _check_stamps(ans: dict, run: dict, te: np.ndarray, tm: np.ndarray) -> None:
    t0 = run["start_stamp_s"]
    k = np.arange(te.size)
    assert np.abs(te - (t0 + k / ans["encoder_rate_hz"])).max() < 2e-6
    j = np.arange(tm.size)
    dev = tm - (t0 + ans["mocap_stamp_offset_s"] + j / ans["mocap_rate_hz"])
    sigma = ans["mocap_jitter_std_s"]
    assert ans["mocap_stamp_offset_s"] == pytest.approx(0.001)
    assert np.abs(dev).max() <= 3 * sigma + 2e-6
    assert abs(dev.mean()) < 0.2 * sigma
    assert 0.7 * sigma < dev.std() < 1.3 * sigma


def test_multirate_interleaved(out: pathlib.Path) -> None:
    ans = _answer(out / "multi")
    assert ans["file_layout"] == "interleaved"
    for run in ans["runs"]:
        header, rows = _read_csv(out / "multi" / run["file"])
        assert header == [
            "time",
            "enc_left",
            "enc_right",
            "v_cmd",
            "w_cmd",
            "mocap_x",
            "mocap_y",
            "mocap_yaw",
        ]
        stamps = np.array([float(r[0]) for r in rows])
        assert np.all(np.diff(stamps) > 0)
        enc = [r for r in rows if r[1] != ""]
        moc = [r for r in rows if r[5] != ""]
        assert len(enc) + len(moc) == len(rows)
        assert all(r[5:] == ["", "", ""] for r in enc)
        assert all(r[1:5] == ["", "", "", ""] for r in moc)
        te = np.array([float(r[0]) for r in enc])
        tm = np.array([float(r[0]) for r in moc])
        assert 2.2 < tm.size / te.size < 2.6
        _check_stamps(ans, run, te, tm)
        e = np.array([[float(v) for v in r[1:5]] for r in enc])
        m = np.array([[float(v) for v in r[5:]] for r in moc])
        phi_l, phi_r = _wheel_angles(e[:, 0], ans, 0), _wheel_angles(e[:, 1], ans, 1)
        pos, yaw = _errors(ans, run, phi_l, phi_r, m.T, at=(te - te[0], tm - te[0]))
        assert pos < 0.004 and yaw < 0.006, (pos, yaw)


def test_multirate_two_files(out: pathlib.Path) -> None:
    ans = _answer(out / "split")
    assert ans["file_layout"] == "split"
    for run in ans["runs"]:
        h_enc, enc = _read_csv(out / "split" / run["file"] / "enc.csv")
        h_moc, moc = _read_csv(out / "split" / run["file"] / "mocap.csv")
        assert h_enc == ["stamp", "enc_left", "enc_right", "v_cmd", "w_cmd"]
        assert h_moc == ["time", "x", "y", "yaw"]
        e = np.array(enc, dtype=float)
        m = np.array(moc, dtype=float)
        _check_stamps(ans, run, e[:, 0], m[:, 0])
        phi_l, phi_r = _wheel_angles(e[:, 1], ans, 0), _wheel_angles(e[:, 2], ans, 1)
        t0 = e[0, 0]
        pos, yaw = _errors(ans, run, phi_l, phi_r, m[:, 1:].T, at=(e[:, 0] - t0, m[:, 0] - t0))
        assert pos < 0.004 and yaw < 0.006, (pos, yaw)


# --------------------------------------------------------------------------
# 3. MATLAB
# --------------------------------------------------------------------------
def test_mat_file(out: pathlib.Path) -> None:
    ans = _answer(out / "mat")
    for run in ans["runs"]:
        mat = sio.loadmat(out / "mat" / run["file"])
        names = ("t", "encL", "encR", "x", "y", "yaw", "v", "w")
        n = mat["t"].size
        assert all(mat[k].shape == (n, 1) for k in names)
        t = mat["t"].ravel()
        assert t[0] == pytest.approx(run["start_time_s"])
        assert np.allclose(np.diff(t), 1.0 / ans["log_rate_hz"])
        phi_l = _wheel_angles(mat["encL"].ravel(), ans, 0)
        phi_r = _wheel_angles(mat["encR"].ravel(), ans, 1)
        logged = (mat["x"].ravel(), mat["y"].ravel(), mat["yaw"].ravel())
        pos, yaw = _errors(ans, run, phi_l, phi_r, logged)
        assert pos < 0.004 and yaw < 0.006, (pos, yaw)


# --------------------------------------------------------------------------
# 4. ROS 2 bag
# --------------------------------------------------------------------------
def test_ros2_bag(tmp_path: pathlib.Path) -> None:
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    written = rec.ros2_bag(21, tmp_path / "bag", duration_s=(12.0, 15.0))
    ans = written.answer
    assert ans == _answer(tmp_path / "bag")
    store = get_typestore(Stores.ROS2_HUMBLE)
    urdf = ET.parse(tmp_path / "bag" / "robot.urdf").getroot()
    joints = {j.get("name"): j for j in urdf.iter("joint")}
    assert joints["wheel_left_joint"].get("type") == "continuous"
    y_left = float(joints["wheel_left_joint"].find("origin").get("xyz").split()[1])
    assert y_left == pytest.approx(ans["nominal"]["wheelbase_m"] / 2.0)
    radius = float(
        urdf.find("link[@name='wheel_left_link']/visual/geometry/cylinder").get("radius")
    )
    assert radius == pytest.approx(ans["nominal"]["wheel_radius_m"])
    assert "caster_joint" in joints
    assert len(ans["runs"]) >= 4
    for run in ans["runs"]:
        with Reader(tmp_path / "bag" / run["file"]) as reader:
            types = {c.topic: c.msgtype for c in reader.connections}
            assert types == {k: v["type"] for k, v in ans["topics"].items()}
            counts = {c.topic: c.msgcount for c in reader.connections}
            assert counts == run["message_counts"]
            got: dict[str, list] = {k: [] for k in types}
            for conn, ts, raw in reader.messages():
                got[conn.topic].append((ts, store.deserialize_cdr(raw, conn.msgtype)))
        for topic, spec in ans["topics"].items():
            n = len(got[topic])
            assert abs(n / run["duration_s"] - spec["rate_hz"]) < 0.1 * spec["rate_hz"]
        js = got["/joint_states"]
        assert all(list(m.name) == ["wheel_left_joint", "wheel_right_joint"] for _, m in js)
        t_js = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for _, m in js])
        assert all(ts > m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for ts, m in js)
        assert np.allclose(np.diff(t_js), 0.02, atol=1e-6)
        pos = np.array([m.position for _, m in js])
        mo = got["/mocap/robot/pose"]
        assert all(m.header.frame_id == "world" for _, m in mo)
        t_mo = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for _, m in mo])
        xyz = np.array([[m.pose.position.x, m.pose.position.y] for _, m in mo])
        q = np.array([[m.pose.orientation.z, m.pose.orientation.w] for _, m in mo])
        yaw = 2.0 * np.arctan2(q[:, 0], q[:, 1])
        t0 = run["start_stamp_ns"] * 1e-9
        assert t_js[0] == pytest.approx(t0, abs=1e-6)
        pos_e, yaw_e = _errors(
            ans,
            run,
            pos[:, 0] - pos[0, 0],
            pos[:, 1] - pos[0, 1],
            (xyz[:, 0], xyz[:, 1], yaw),
            at=(t_js - t0, t_mo - t0),
        )
        assert pos_e < 0.004 and yaw_e < 0.006, (pos_e, yaw_e)
        cmd = np.array([[m.linear.x, m.angular.z] for _, m in got["/cmd_vel"]])
        assert np.abs(cmd[:, 0]).max() <= 0.5 and np.any(cmd[:, 1] != 0.0)


# --------------------------------------------------------------------------
# 5. skid-steer
# --------------------------------------------------------------------------
def test_skid_steer(out: pathlib.Path) -> None:
    ans = _answer(out / "skid")
    true = ans["true"]
    assert 1.2 <= ans["chi"] <= 1.8
    assert ans["effective_track_m"] == pytest.approx(ans["chi"] * true["track_m"])
    assert true["mocap_offset_m"] == [0.0, 0.0]
    urdf = ET.parse(out / "skid" / "robot.urdf").getroot()
    wheels = [j for j in urdf.iter("joint") if j.get("type") == "continuous"]
    assert len(wheels) == 4
    xy = np.array([[float(v) for v in j.find("origin").get("xyz").split()[:2]] for j in wheels])
    assert np.allclose(np.sort(np.abs(xy[:, 0])), ans["wheelbase_m"] / 2.0)
    assert np.allclose(np.abs(xy[:, 1]), ans["nominal"]["track_m"] / 2.0)
    for run in ans["runs"]:
        header, rows = _read_csv(out / "skid" / run["file"])
        assert header == ["time", "enc_left", "enc_right", "v_cmd", "w_cmd", "x", "y", "yaw"]
        d = np.array(rows, dtype=float)
        assert np.allclose(np.diff(d[:, 0]), 0.02)
        phi_l, phi_r = _wheel_angles(d[:, 1], ans, 0), _wheel_angles(d[:, 2], ans, 1)
        logged = (d[:, 5], d[:, 6], d[:, 7])
        # heading is exact in the wheel angles; the lateral slip moves the position a little
        pos, yaw = _errors(ans, run, phi_l, phi_r, logged)
        assert pos < 0.05 and yaw < 0.006, (pos, yaw)
        _pos_n, yaw_n = _errors(ans, run, phi_l, phi_r, logged, geometry="nominal")
        assert yaw_n > 0.1


# --------------------------------------------------------------------------
# 6. arm
# --------------------------------------------------------------------------
def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _fk(chain: list, q: np.ndarray, origins=None, offsets=None) -> np.ndarray:
    rot, pos = np.eye(3), np.zeros(3)
    for i, (origin, axis) in enumerate(chain):
        pos = pos + rot @ (origin if origins is None else np.asarray(origins[i]))
        if axis is not None:
            rot = rot @ _rot(axis, q[i] + (0.0 if offsets is None else offsets[i]))
    return pos


def test_arm_csv(out: pathlib.Path) -> None:
    ans = _answer(out / "arm")
    root = ET.parse(out / "arm" / "arm.urdf").getroot()
    joints = {j.find("child").get("link"): j for j in root.iter("joint")}
    parents = {
        j.find("child").get("link"): j.find("parent").get("link") for j in root.iter("joint")
    }
    order, link = [], "tool_point"
    while link in parents:
        order.append(joints[link])
        link = parents[link]
    order.reverse()
    assert [j.get("type") for j in order] == ["revolute"] * 6 + ["fixed"]
    assert [j.get("name") for j in order[:6]] == ans["joint_names"]
    chain = []
    for j in order:
        assert j.find("origin").get("rpy") == "0 0 0"
        origin = np.array([float(v) for v in j.find("origin").get("xyz").split()])
        axis = j.find("axis")
        chain.append(
            (
                origin,
                None if axis is None else np.array([float(v) for v in axis.get("xyz").split()]),
            )
        )
    axes = [c[1] for c in chain[:6]]
    assert [tuple(np.flatnonzero(a)) for a in axes] == [(2,), (1,), (1,), (1,), (2,), (1,)]
    for upper_arm_or_forearm in (chain[2][0], chain[3][0]):
        assert 0.4 <= np.linalg.norm(upper_arm_or_forearm) <= 0.65
    header, rows = _read_csv(out / "arm" / "measurements.csv")
    assert header[0] == "pose" and header[1:7] == [f"q{i}_deg" for i in range(1, 7)]
    assert header[7:] == ["x_mm", "y_mm", "z_mm"]
    d = np.array(rows, dtype=float)
    q, p_tr = np.radians(d[:, 1:7]), d[:, 7:] / 1e3
    tr = ans["tracker_from_base"]
    rot, t = np.array(tr["rotation"]), np.array(tr["translation_m"])
    assert np.allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    p_base = (p_tr - t) @ rot  # R^T (p - t) row-wise
    true = ans["true"]
    err_true, err_nom = [], []
    for qk, pk in zip(q, p_base):
        tip_true = _fk(chain, qk, true["joint_origins_m"], true["joint_offsets_rad"])
        tip_nom = _fk(chain, qk)
        err_true.append(np.linalg.norm(tip_true - pk))
        err_nom.append(np.linalg.norm(tip_nom - pk))
    noise = ans["noise_std_m"]
    assert max(err_true) < 6 * noise
    assert np.mean(err_true) == pytest.approx(noise * math.sqrt(8 / math.pi), rel=0.3)
    assert 0.5e-3 < np.median(err_nom) < 10e-3 and max(err_nom) > 1e-3
    assert np.abs(true["joint_offsets_rad"]).max() <= 0.002
    assert np.abs(ans["origin_errors_m"]).max() <= 0.001


# --------------------------------------------------------------------------
# everything at once
# --------------------------------------------------------------------------
def test_write_all_and_summary(tmp_path: pathlib.Path) -> None:
    result = rec.write_all(tmp_path, seed=3, duration_s=(12.0, 14.0))
    assert set(result) == set(rec.CASES)
    written = {name for name, w in result.items() if w is not None}
    assert written >= set(rec.CASES) - {"ros2_bag"}
    for name in written:
        ans = _answer(tmp_path / name)
        assert ans["seed"] == [3, rec.CASES.index(name)]
    lines = rec.summary(tmp_path).splitlines()
    assert len(lines) == len(written)
    assert all(line.split()[0] in written for line in lines)
