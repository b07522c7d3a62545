"""The declared channel schemas (:mod:`realitygap.diagnosis.logs.schema`): dtypes, units against
plausible ranges, one source per target, clock resets, missing stamps and wrapping counters —
each refused or repaired with a message that names the file, what came and a fix that works."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.logs.channels import standard_channels
from realitygap.diagnosis.logs.importers.column_map import ColumnMap
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.diagnosis.logs.read import ReadOptions, check_plausible, read_logs
from realitygap.diagnosis.logs.schema import (
    COUNTER_MODULI,
    SCHEMAS,
    DType,
    Measure,
    SchemaError,
    as_real,
    clock_resets,
    counter_wrap,
    fill_time,
    unwrap_counter,
)

POSE_MAP = "t=t,{ch}.x=x,{ch}.y=y,{ch}.theta=yaw,cmd.v=v,cmd.w=w"


def drive(w: float = 0.3, n: int = 1000, dt: float = 0.02) -> dict[str, np.ndarray]:
    """A differential drive at 0.2 m/s turning at ``w`` rad/s: time, pose, commands."""
    t = dt * np.arange(n)
    th = w * t
    x = np.concatenate([[0.0], np.cumsum(0.2 * np.cos(th[:-1]) * dt)])
    y = np.concatenate([[0.0], np.cumsum(0.2 * np.sin(th[:-1]) * dt)])
    return {"t": t, "x": x, "y": y, "yaw": th, "v": np.full(n, 0.2), "w": np.full(n, w)}


def write_csv(path: Path, cols: dict[str, np.ndarray], fmt: str = "{:.6f}") -> Path:
    names = list(cols)
    rows = [",".join(names)]
    for k in range(len(cols[names[0]])):
        rows.append(",".join(fmt.format(cols[c][k]) for c in names))
    path.write_text("\n".join(rows) + "\n")
    return path


def read(path: Path | str, columns: str, **kw: object) -> tuple[list[Log], list[str]]:
    said: list[str] = []
    logs = read_logs(path, ReadOptions(columns=columns, **kw), warn=said.append)  # type: ignore[arg-type]
    return logs, said


# --------------------------------------------------------------------------- the table
def test_every_channel_known_to_the_log_has_one_schema_entry() -> None:
    assert set(SCHEMAS) == set(standard_channels())
    for name, schema in SCHEMAS.items():
        assert schema.spec is standard_channels()[name]
        assert schema.bounds, f"{name} has no plausible range"
        for bound in schema.bounds:
            assert set(bound.columns) <= set(schema.spec.columns)
            assert bound.mistake, f"{name}: a bound without the likely mistake it names"
    assert SCHEMAS["ticks"].dtype is DType.COUNT
    assert {s.dtype for n, s in SCHEMAS.items() if n != "ticks"} == {DType.REAL}
    heading = [b for b in SCHEMAS["pose_gt"].bounds if b.measure is Measure.TURN_RATE]
    assert heading and heading[0].param == "w_max"


# --------------------------------------------------------------------------- units
@pytest.mark.parametrize("channel", ["pose_gt", "pose_est", "pose_cam"])
@pytest.mark.parametrize("w", [0.3, 0.04])  # fast: turn rate; slow: heading against its path
def test_a_heading_in_degrees_is_refused_and_the_fix_reads(
    tmp_path: Path, channel: str, w: float
) -> None:
    d = drive(w)
    d["yaw"] = np.degrees((d["yaw"] + math.pi) % (2 * math.pi) - math.pi)  # wrapped, in degrees
    f = write_csv(tmp_path / "run.csv", d)
    cmap = POSE_MAP.format(ch=channel)
    with pytest.raises(
        LogError, match=rf"run.csv: {channel}.theta .*looks like degrees; fix: add :deg"
    ):
        read(f, cmap)
    (log,) = read(f, cmap.replace("yaw", "yaw:deg"))[0]
    np.testing.assert_allclose(log[channel][:, 2], w * d["t"], atol=1e-5)


def test_a_fast_robot_that_states_its_turn_rate_limit_is_not_refused(tmp_path: Path) -> None:
    d = drive(5.0)
    d["w"] = np.full_like(d["t"], 5.0)
    f = write_csv(tmp_path / "spin.csv", d)
    with pytest.raises(
        LogError, match=r"(cmd.w reaches 5 rad/s|pose_gt.theta turns at) .*2 × w_max = 2 rad/s"
    ):
        read(f, POSE_MAP.format(ch="pose_gt"), params={"w_max": 1.0})
    read(f, POSE_MAP.format(ch="pose_gt"), params={"w_max": 6.0})


def test_a_turn_rate_in_degrees_per_second_is_refused(tmp_path: Path) -> None:
    d = drive(0.15)
    d["w"] = np.degrees(d["w"])  # 8.6 "rad/s" against a limit of π
    f = write_csv(tmp_path / "run.csv", d)
    cmap = POSE_MAP.format(ch="pose_gt")
    with pytest.raises(LogError, match=r"cmd.w reaches 8.594 rad/s .*degrees per second.*:deg/s"):
        read(f, cmap)
    (log,) = read(f, cmap.replace("cmd.w=w", "cmd.w=w:deg/s"))[0]
    np.testing.assert_allclose(log["cmd"][:, 1], 0.15, atol=1e-6)


def test_a_speed_in_mm_per_second_is_refused(tmp_path: Path) -> None:
    d = drive()
    d["v"] = d["v"] * 1000.0
    f = write_csv(tmp_path / "run.csv", d)
    with pytest.raises(LogError, match=r"cmd.v reaches 200 m/s .*mm/s"):
        read(f, POSE_MAP.format(ch="pose_gt"))


def arm_log(scale: float = 1.0) -> Log:
    from realitygap.estimators.arm.mdh import MDHTable, tool_positions
    from realitygap.robots.arm import ArmParams, arm_params_to_meta

    rng = np.random.default_rng(3)
    q = rng.uniform(-1.5, 1.5, (40, 6))
    table = MDHTable.ur10()
    tool = np.array([0.0, 0.0, 0.109])
    pts = tool_positions(table, q, tool) + np.array([2.0, -1.0, 0.5])  # in the tracker frame
    return Log(
        t=np.arange(40.0),
        channels={"joints": q, "tool_pos": pts * scale},
        meta={
            "robot": "arm",
            "params": arm_params_to_meta(ArmParams(mdh=table)),
            "tool": [0, 0, 0.109],
        },
        source="arm.csv",
    )


@pytest.mark.parametrize(
    ("scale", "word"),
    [(1000.0, "millimetres declared as metres"), (1e-3, "metres declared as millimetres")],
)
def test_arm_positions_a_thousand_times_off_are_refused_against_its_reach(
    scale: float, word: str
) -> None:
    check_plausible(arm_log())
    with pytest.raises(
        LogError, match=rf"arm.csv: .*tool_pos.* looks like {word}.*Fix: fix the unit"
    ):
        check_plausible(arm_log(scale))


def test_arm_table_in_metres_mapped_as_millimetres_is_refused(tmp_path: Path) -> None:
    log = arm_log()
    cols = {f"q{i + 1}": log["joints"][:, i] for i in range(6)}
    cols.update({c: log["tool_pos"][:, i] for i, c in enumerate("xyz")})
    f = write_csv(tmp_path / "arm.csv", cols, "{:.9f}")
    joints = ",".join(f"joints.q{i}=q{i}" for i in range(1, 7))
    opts = {"params": log.meta["params"], "robot": "arm", "meta": {"tool": [0, 0, 0.109]}}
    read(f, joints + ",tool_pos.x=x,tool_pos.y=y,tool_pos.z=z", **opts)
    with pytest.raises(LogError, match=r"metres declared as millimetres"):
        read(f, joints + ",tool_pos.x=x:mm,tool_pos.y=y:mm,tool_pos.z=z:mm", **opts)
    with pytest.raises(
        LogError, match=r"joints.q1 reaches 149.8 rad \(joint angle.*looks like degrees"
    ):
        read(
            f,
            joints.replace("q1=q1", "q1=q1*100") + ",tool_pos.x=x,tool_pos.y=y,tool_pos.z=z",
            **opts,
        )


# --------------------------------------------------------------------------- the column map
def test_one_column_feeding_two_targets_is_refused_unless_marked() -> None:
    with pytest.raises(LogError, match=r"the column 'v' feeds cmd.v, cmd.w.*'cmd.w=!v'"):
        ColumnMap.parse("t=t,cmd.v=v,cmd.w=v")
    with pytest.raises(LogError, match=r"the column 'v' feeds"):
        ColumnMap.parse("t=t,cmd.v=v,cmd.w=-v*2")  # a sign or factor does not make it another
    cmap = ColumnMap.parse("t=t,pose_gt.theta=yaw,pose_est.theta=!yaw,pose_gt.x=x,pose_gt.y=y,"
                           "pose_est.x=!x,pose_est.y=!y")  # fmt: skip
    assert cmap.entries["pose_est.theta"].shared and cmap.entries["pose_est.theta"].column == "yaw"
    assert ColumnMap.parse('t=t,cmd.v="!v",cmd.w=w').entries["cmd.v"].column == "!v"


def test_a_target_given_twice_is_refused_in_text_and_json(tmp_path: Path) -> None:
    with pytest.raises(LogError, match=r"'cmd.v' is given twice"):
        ColumnMap.parse("t=t,cmd.v=v,cmd.w=w,cmd.v=w")
    f = tmp_path / "map.json"
    f.write_text('{"t": "t", "cmd.v": "v", "cmd.w": "w", "cmd.v": "w"}')
    with pytest.raises(
        LogError, match=r"map.json: the key 'cmd.v' is given twice .*only one can hold"
    ):
        ColumnMap.parse(str(f))
    f.write_text(json.dumps({"t": "t", "cmd.v": "v", "cmd.w": "w"}))
    assert set(ColumnMap.parse(str(f)).entries) == {"cmd.v", "cmd.w"}


# --------------------------------------------------------------------------- dtypes
@pytest.mark.parametrize(
    ("values", "what"),
    [(np.ones(50, bool), "booleans"), (np.ones(50, complex), "complex numbers")],
)
def test_boolean_and_complex_arrays_are_refused_by_dtype(
    tmp_path: Path, values: np.ndarray, what: str
) -> None:
    t = 0.02 * np.arange(50)
    np.savez(tmp_path / "run.npz", t=t, v=values, w=np.zeros(50))
    with pytest.raises(
        LogError, match=rf"cmd.v=v: .*run.npz: variable 'v': expected real .*{what}"
    ):
        read(tmp_path / "run.npz", "t=t,cmd.v=v,cmd.w=w")
    with pytest.raises(LogError, match=rf"channel 'cmd': expected real numbers .*{what}"):
        Log(t=t, channels={"cmd": np.column_stack([values, values])})


def test_object_arrays_are_never_unpickled(tmp_path: Path) -> None:
    t = 0.02 * np.arange(50)
    np.savez(tmp_path / "run.npz", t=t, v=np.array([{"v": 1}] * 50, dtype=object), w=np.zeros(50))
    with pytest.raises(LogError, match=r"pickled|object"):
        read(tmp_path / "run.npz", "t=t,cmd.v=v,cmd.w=w")
    with pytest.raises(SchemaError, match=r"Python objects .*never unpickled"):
        as_real(np.array([1.0, None]), "cmd")


def test_dates_are_read_as_seconds(tmp_path: Path) -> None:
    start = np.datetime64("2024-05-01T12:00:00", "ms")
    stamps = start + (20 * np.arange(50)).astype("timedelta64[ms]")
    np.savez(tmp_path / "run.npz", t=stamps, v=np.full(50, 0.2), w=np.zeros(50))
    (log,) = read(tmp_path / "run.npz", "t=t,cmd.v=v,cmd.w=w")[0]
    np.testing.assert_allclose(np.diff(log.t), 0.02, atol=1e-6)
    assert log.t[0] == pytest.approx(1714564800.0)
    lg = Log(t=stamps - start, channels={"cmd": np.zeros((50, 2))})
    np.testing.assert_allclose(lg.t, 0.02 * np.arange(50))


def test_ticks_are_whole_counts_unless_the_map_scales_them(tmp_path: Path) -> None:
    d = drive()
    ticks = np.round(d["t"] * 100)
    np.savez(tmp_path / "int.npz", t=d["t"], l=ticks.astype(np.int32), r=ticks.astype(np.int64))
    (log,) = read(tmp_path / "int.npz", "t=t,ticks.left=l,ticks.right=r")[0]
    np.testing.assert_array_equal(log["ticks"][:, 0], ticks)
    np.savez(tmp_path / "frac.npz", t=d["t"], l=ticks + 0.5, r=ticks)
    with pytest.raises(
        LogError, match=r"frac.npz: column 'l' \(ticks.left\), line 1: expected encoder counts"
    ):
        read(tmp_path / "frac.npz", "t=t,ticks.left=l,ticks.right=r")
    read(tmp_path / "frac.npz", "t=t,ticks.left=l*2,ticks.right=r")  # derived: scaled by the map


# --------------------------------------------------------------------------- time
def test_a_clock_reset_splits_the_recording_into_pieces(tmp_path: Path) -> None:
    d = drive()
    d["t"] = np.concatenate([d["t"][:600], d["t"][600:] - d["t"][600]])  # logger restarted
    f = write_csv(tmp_path / "run.csv", d)
    logs, said = read(f, POSE_MAP.format(ch="pose_gt"))
    assert [lg.n for lg in logs] == [600, 400]
    assert [lg.name for lg in logs] == ["run_part-1", "run_part-2"]
    assert "clock was reset at line 602 (time goes from 11.98 s back to 0 s)" in said[0]
    with pytest.raises(LogError, match=r"clock was reset at sample 600: time goes from 11.98 s"):
        Log(t=d["t"], channels={"cmd": np.zeros((1000, 2))})


def test_rows_slightly_out_of_order_are_not_a_reset(tmp_path: Path) -> None:
    d = drive()
    d["t"][[300, 301]] = d["t"][[301, 300]]
    f = write_csv(tmp_path / "run.csv", d)
    with pytest.raises(LogError, match=r"line 302 .*rows out of order.*sort the rows by time"):
        read(f, POSE_MAP.format(ch="pose_gt"))
    assert clock_resets(d["t"]) == ([], 301)


def test_a_reset_in_one_of_several_files_is_refused_with_the_line(tmp_path: Path) -> None:
    d = drive()
    enc = {"t": np.concatenate([d["t"][:500], d["t"][500:] - 5]), "l": d["t"] * 0, "r": d["t"] * 0}
    write_csv(tmp_path / "enc.csv", enc)
    write_csv(tmp_path / "mocap.csv", {k: d[k] for k in ("t", "x", "y", "yaw")})
    cmap = (
        "t=enc::t,t=mocap::t,ticks.left=l,ticks.right=r,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw"
    )
    with pytest.raises(LogError, match=r"enc.csv, line 502: the clock was reset .*split the file"):
        read(f"{tmp_path / 'enc.csv'}+{tmp_path / 'mocap.csv'}", cmap)


def test_the_fix_suggested_for_a_missing_stamp_works(tmp_path: Path) -> None:
    d = drive()
    f = write_csv(tmp_path / "run.csv", d)
    lines = f.read_text().splitlines()
    lines[301] = "," + lines[301].split(",", 1)[1]  # the stamp of line 302 is missing
    f.write_text("\n".join(lines) + "\n")
    cmap = POSE_MAP.format(ch="pose_gt")
    with pytest.raises(LogError, match=r"line 302: .*time stamp is missing.*--nan interpolate"):
        read(f, cmap)
    (log,), said = read(f, cmap, nan="interpolate")
    assert log.t[300] == pytest.approx(6.0) and "interpolated" in said[0]
    (log,), _ = read(f, cmap, nan="drop")
    assert log.n == 999


def test_a_missing_stamp_beside_a_gap_is_not_invented() -> None:
    t = np.array([0.0, 0.1, 0.2, np.nan, 5.0, 5.1])
    with pytest.raises(SchemaError, match=r"f.csv, line 4: .*not regular.*--nan drop"):
        fill_time(t, "f.csv")
    np.testing.assert_allclose(
        fill_time([0.0, 0.1, np.nan, 0.3, 0.4], "f"), [0, 0.1, 0.2, 0.3, 0.4]
    )


# --------------------------------------------------------------------------- counters
@pytest.mark.parametrize("modulus", [2**16, 2**32])
@pytest.mark.parametrize("signed", [False, True])
def test_a_wrapping_tick_counter_is_unwrapped(tmp_path: Path, modulus: int, signed: bool) -> None:
    d = drive(0.0, n=3000)
    # crosses the wrap after 5 s (a signed counter wraps half-way round)
    true = np.round(d["t"] * 4000.0) + ((modulus // 2 if signed else modulus) - 20000)
    raw = true % modulus
    if signed:
        raw = np.where(raw >= modulus // 2, raw - modulus, raw)
    assert counter_wrap(raw) == modulus
    unwrapped, m = unwrap_counter(raw)
    assert m == modulus
    np.testing.assert_array_equal(np.diff(unwrapped), np.diff(true))
    cols = {"t": d["t"], "x": d["x"], "y": d["y"], "yaw": d["yaw"], "l": raw, "r": raw}
    f = write_csv(tmp_path / "run.csv", cols, "{:.10g}")
    cmap = "t=t,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw,ticks.left=l,ticks.right=r"
    params = {"ticks_per_rev": 2.0 * math.pi * 0.035 * 4000.0 / 0.2, "wheel_radius_left": 0.035,
              "wheel_radius_right": 0.035}  # fmt: skip
    (log,), said = read(f, cmap, params=params)
    np.testing.assert_array_equal(np.diff(log["ticks"][:, 0]), np.diff(true))
    assert f"wraps (ticks.left at {modulus}" in said[0] and "ticks_unwrapped" in log.meta
    raw_log = Log(
        t=d["t"], channels={"ticks": np.column_stack([raw, raw])}, meta={"params": params}
    )
    with pytest.raises(LogError, match=rf"the tick counter wraps at {modulus}.*Fix: unwrap"):
        check_plausible(raw_log)


def test_a_counter_reset_or_a_fast_counter_is_no_wrap() -> None:
    assert counter_wrap([*np.arange(0, 30000, 40.0).tolist(), 0.0, 40.0]) is None
    assert counter_wrap(np.arange(0, 10**6, 997.0)) is None
    assert all(m in COUNTER_MODULI for m in (2**15, 2**16, 2**32))
    assert counter_wrap(np.r_[32000:32768:100, 0:500:100]) == 2**15


# --------------------------------------------------------------------------- other readers
def test_franka_archives_are_checked_by_the_same_schema(tmp_path: Path) -> None:
    from realitygap.diagnosis.logs.importers.franka import read_franka_npz

    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, :3, 3] = [0.4, 0.1, 0.5]
    q = np.zeros((5, 7))
    np.savez(tmp_path / "ok.npz", joint_positions=q, tcp_poses=T, camera_poses=T)
    assert read_franka_npz(tmp_path / "ok.npz").n == 5
    np.savez(tmp_path / "b.npz", joint_positions=q > 0, tcp_poses=T, camera_poses=T)
    with pytest.raises(ValueError, match=r"'joint_positions': expected real .*booleans"):
        read_franka_npz(tmp_path / "b.npz")
    T_mm = T.copy()
    T_mm[:, :3, 3] *= 1000.0
    np.savez(tmp_path / "mm.npz", joint_positions=q, tcp_poses=T_mm, camera_poses=T)
    with pytest.raises(ValueError, match=r"beyond the FR3's reach .*millimetres"):
        read_franka_npz(tmp_path / "mm.npz")
    np.savez(tmp_path / "deg.npz", joint_positions=q + 90.0, tcp_poses=T, camera_poses=T)
    with pytest.raises(ValueError, match=r"joint angle 90 rad .*expected radians.*degrees"):
        read_franka_npz(tmp_path / "deg.npz")
