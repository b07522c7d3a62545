"""The replay core in robots/: the nominal robot's metadata and the recorded channels, which the
diagnosis only wraps into a log."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.diffdrive_replay import (
    MetaError,
    params_from_meta,
    params_to_meta,
    simulate_channels,
)
from realitygap.robots.effects import Reality, make_effect
from realitygap.robots.simulation import MeasurementNoise


def test_params_round_trip_through_the_metadata() -> None:
    params = DiffDriveParams().replace(wheelbase=0.25, wheel_radius_left=0.034)
    assert params_from_meta({"params": params_to_meta(params)}) == params


@pytest.mark.parametrize(
    ("meta", "words"),
    [
        ({}, "metadata has no 'params'"),
        ({"params": {"foo": 1.0}}, "unknown robot parameter(s) ['foo']"),
        ({"params": {"wheelbase": -1.0}}, "invalid robot parameters in metadata"),
    ],
)
def test_bad_metadata_names_its_source(meta: dict[str, object], words: str) -> None:
    with pytest.raises(MetaError) as exc:
        params_from_meta(meta, "run.csv")
    assert str(exc.value).startswith("run.csv: ")
    assert words in str(exc.value)


def test_the_diagnosis_log_holds_the_core_channels_bit_for_bit() -> None:
    from realitygap.diagnosis.adapters.diffdrive.replay import simulate

    params = DiffDriveParams()
    t = np.arange(0.0, 1.0, 0.05)
    cmd = np.column_stack([0.3 + 0.0 * t, 0.5 * np.sin(t)])
    reality = Reality(
        (
            make_effect("timestamp_offset", offset=0.03),
            make_effect("truth_frame_offset", x=0.02, y=-0.01, yaw=0.05),
        )
    )
    noise = MeasurementNoise(0.001, 0.001, 0.002, 0.002)
    kw = dict(params=params, reality=reality, commands=cmd, start=(0.1, 0.2, 0.3), noise=noise)
    channels, meta = simulate_channels(t, rng=np.random.default_rng(4), **kw)
    log = simulate(t, rng=np.random.default_rng(4), meta={"name": "x"}, source="s", **kw)
    assert (
        list(log.channels) == list(channels) == ["cmd", "ticks", "pose_gt", "pose_est", "pose_cam"]
    )
    for name, values in channels.items():
        assert np.asarray(log[name]).tobytes() == values.tobytes(), name
    assert dict(log.meta) == {**meta, "name": "x"}
    assert meta["params"] == params_to_meta(params)


def _replay_inputs() -> tuple[np.ndarray, np.ndarray]:
    t = 0.05 * np.arange(60)
    cmd = np.zeros((60, 2))
    cmd[5:50] = [0.3, 0.4]
    return t, cmd


def test_a_cached_replay_is_the_replay_and_any_changed_input_is_simulated_again(
    tmp_path, monkeypatch
) -> None:
    import realitygap.robots.diffdrive_replay as core
    from realitygap.core.cache import CACHE_DIR_ENV, CACHE_ENV

    monkeypatch.setenv(CACHE_ENV, "0")
    t, cmd = _replay_inputs()
    fresh, _ = simulate_channels(t, params=DiffDriveParams(), commands=cmd)

    monkeypatch.setenv(CACHE_ENV, "1")
    monkeypatch.setenv(CACHE_DIR_ENV, str(tmp_path))
    runs = []
    world = core.World

    def counting_world(*args, **kwargs):  # counts the PyBullet runs the cache did not save
        runs.append(1)
        return world(*args, **kwargs)

    monkeypatch.setattr(core, "World", counting_world)
    first, _ = simulate_channels(t, params=DiffDriveParams(), commands=cmd)
    second, _ = simulate_channels(t, params=DiffDriveParams(), commands=cmd)
    assert len(runs) == 1  # the second came from the cache
    for name in fresh:
        np.testing.assert_array_equal(first[name], fresh[name])
        np.testing.assert_array_equal(second[name], fresh[name])
    # another wheelbase, another effect value, another command: simulated, not read back
    simulate_channels(t, params=DiffDriveParams().replace(wheelbase=0.24), commands=cmd)
    simulate_channels(
        t,
        params=DiffDriveParams(),
        commands=cmd,
        reality=Reality((make_effect("wheel_diameter_ratio", E_d=1.01),)),
    )
    simulate_channels(t, params=DiffDriveParams(), commands=cmd * 1.001)
    assert len(runs) == 4
