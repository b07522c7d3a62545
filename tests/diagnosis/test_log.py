"""The Log: round trip, atomic writes, no pickle, and every validation error."""

from __future__ import annotations

import os
import pickle

import numpy as np
import pytest

from realitygap.diagnosis.logs.log import ChannelSpec, Log, LogError, Role, convert_units


def make_log(n: int = 50, seed: int = 0) -> Log:
    rng = np.random.default_rng(seed)
    t = 0.05 * np.arange(n)
    return Log(
        t=t,
        channels={
            "cmd": rng.normal(size=(n, 2)),
            "ticks": np.cumsum(rng.integers(0, 30, size=(n, 2)), axis=0).astype(float),
            "pose_gt": rng.normal(size=(n, 3)),
            "battery": rng.normal(size=n),
        },
        specs={"battery": ChannelSpec("battery", ("voltage",), ("V",), Role.SENSOR)},
        meta={"robot": "diffdrive", "name": "unit", "nested": {"a": [1, 2.5]}},
        source="unit-test",
    )


def test_round_trip_is_identical(tmp_path) -> None:
    log = make_log()
    path = log.save(tmp_path / "a.npz")
    again = Log.load(path)
    assert again.source == str(path)
    assert again.meta.pop("recorded_from") == "unit-test"
    assert again.replace(source=log.source).equals(log)
    assert again.specs["battery"].units == ("V",)
    # loaded without pickle: the archive holds only numeric arrays
    with np.load(path, allow_pickle=False) as data:
        assert all(data[k].dtype != object for k in data.files)


def test_atomic_save_leaves_no_partial_file(tmp_path, monkeypatch) -> None:
    log = make_log()
    target = tmp_path / "log.npz"
    log.save(target)
    before = target.read_bytes()

    def broken(fh, **arrays):
        fh.write(b"PK\x03\x04 half an archive")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", broken)
    with pytest.raises(OSError, match="disk full"):
        make_log(seed=1).save(target)
    assert target.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["log.npz"]
    with pytest.raises(OSError):
        make_log().save(tmp_path / "new.npz")
    assert sorted(os.listdir(tmp_path)) == ["log.npz"]


def test_load_refuses_pickles_and_wrong_content(tmp_path) -> None:
    pick = tmp_path / "evil.npz"
    pick.write_bytes(pickle.dumps({"t": [0, 1]}))
    with pytest.raises(LogError, match="not a realitygap log"):
        Log.load(pick)
    obj = tmp_path / "objects.npz"
    header = np.frombuffer(b'{"format": "realitygap-log", "version": 1}', dtype=np.uint8)
    np.savez(obj, t=np.arange(3.0), **{"meta.json": header, "ch.x": np.array([{}, {}, {}])})
    with pytest.raises(LogError, match="pickled Python objects"):
        Log.load(obj)
    csv = tmp_path / "actually.npz"
    csv.write_text("t,x\n0,1\n1,2\n")
    with pytest.raises(LogError, match="looks like text"):
        Log.load(csv)
    zipped = tmp_path / "plain.npz"
    np.savez(zipped, a=np.arange(3))
    with pytest.raises(LogError, match="not a realitygap log"):
        Log.load(zipped)


def test_nan_is_named_with_channel_row_and_fix() -> None:
    pose = np.zeros((10, 3))
    pose[4, 0] = np.nan
    with pytest.raises(
        LogError, match=r"src\.csv: channel 'pose_gt' column 'x' has 1 NaN.*row 4.*Fix"
    ):
        Log(t=np.arange(10.0), channels={"pose_gt": pose}, source="src.csv")


def test_non_monotonic_time_is_refused() -> None:
    t = np.array([0.0, 0.05, 0.1, 0.1, 0.2])
    with pytest.raises(LogError, match=r"increase strictly.*row 3.*sort the rows"):
        Log(t=t, channels={"cmd": np.zeros((5, 2))}, source="f.csv")


def test_jittery_time_stamps_are_refused_with_resample_fix() -> None:
    rng = np.random.default_rng(3)
    t = np.cumsum(0.05 + rng.uniform(-0.03, 0.03, 100))
    log = Log(t=t, channels={"cmd": np.zeros((100, 2))}, source="jitter.csv")
    with pytest.raises(LogError, match=r"jitter\.csv: time stamps are irregular.*--resample"):
        log.check_uniform()
    fixed = log.resampled(0.05)
    assert fixed.check_uniform() == pytest.approx(0.05)


def test_mismatched_units_are_refused() -> None:
    spec = ChannelSpec("cmd", ("v", "w"), ("mm/s", "rad/s"), Role.COMMAND)
    with pytest.raises(LogError, match="column 'v' is in 'mm/s' but logs store 'm/s'"):
        Log(t=np.arange(3.0), channels={"cmd": np.zeros((3, 2))}, specs={"cmd": spec})
    with pytest.raises(LogError, match="cannot convert 'mm' to 'rad/s'"):
        convert_units([1.0], "mm", "rad/s")
    np.testing.assert_allclose(convert_units([90.0], "deg", "rad"), [np.pi / 2])


def test_missing_channel_and_shapes() -> None:
    log = make_log()
    with pytest.raises(LogError, match=r"missing channel.*'pose_cam'.*Fix"):
        log.require(["pose_gt", "pose_cam"], "a camera diagnosis")
    with pytest.raises(LogError, match=r"must have shape \(5, 3\)"):
        Log(t=np.arange(5.0), channels={"pose_gt": np.zeros((5, 2))})
    with pytest.raises(LogError, match="not a standard channel"):
        Log(t=np.arange(5.0), channels={"speed": np.zeros(5)})
    with pytest.raises(LogError, match="JSON-able"):
        Log(t=np.arange(5.0), channels={}, meta={"x": object()})
