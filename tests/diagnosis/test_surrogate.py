"""The fit's fast surrogate against the PyBullet replay: a measured, bounded agreement."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.diagnosis.adapters.diffdrive.manoeuvres import Manoeuvre
from realitygap.diagnosis.adapters.diffdrive.replay import simulate
from realitygap.diagnosis.problem.features import FeatureSettings, features, window_bounds
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.diffdrive_surrogate import (
    SURROGATE_EFFECTS,
    DiffDriveSurrogate,
    SurrogateCalibration,
    SurrogateInputs,
    calibrate,
)
from realitygap.robots.effects import EFFECTS, Reality, make_effect
from realitygap.robots.effects.diffdrive import SurrogateSlot

P = DiffDriveParams()
DT = 0.05
MPT = (
    2 * np.pi * P.wheel_radius_left / P.ticks_per_rev,
    2 * np.pi * P.wheel_radius_right / P.ticks_per_rev,
)
MIXED = Manoeuvre(
    "mixed",
    "straight, fast, slow, turns both ways, an arc",
    (
        (2.0, 0.3, 0.0),
        (1.5, 0.6, 0.0),
        (2.0, 0.04, 0.0),
        (1.5, 0.0, 1.2),
        (1.5, 0.0, -0.4),
        (2.0, 0.3, -0.6),
        (0.5, 0.0, 0.0),
    ),
)
STEPS = Manoeuvre(
    "steps", "hard starts", ((1.0, 0.4, 0.0), (1.0, 0, 0), (1.0, 0.0, 1.5), (1.0, 0, 0)), ramp=False
)


@pytest.fixture(scope="module")
def base():
    sur = DiffDriveSurrogate(P, calibrate(P))
    out = {}
    scales = FeatureSettings()
    for man in (MIXED, STEPS):
        t, cmd = man.applied(DT, P)
        b = window_bounds(t.shape[0], DT, 1.0)
        pb0 = features(simulate(t, params=P, commands=cmd).channels, b, MPT)
        s0 = features(sur.simulate(SurrogateInputs(DT, np.zeros(3), commands=cmd), {}), b, MPT)
        out[man.name] = (t, cmd, b, pb0, {g: v[0] for g, v in s0.items()})
    return sur, scales, out


def test_nominal_surrogate_matches_pybullet_within_millimetres(base) -> None:
    _, scales, out = base
    for name, (_, _, _, pb0, s0) in out.items():
        for g in pb0:
            err = np.abs(pb0[g] - s0[g]) / scales.scale(g)
            # RMS per window below 2.5 scale units (5 mm, 5 mrad, 2.5 mm of wheel travel);
            # hard starts make the body pitch, which the kinematic model leaves out
            limit = 6.0 if name == "steps" else 2.5
            assert np.sqrt(np.mean(err**2)) < limit, (name, g)


def test_every_wheeled_effect_has_a_checked_surrogate_term() -> None:
    wheeled = [n for n, cls in EFFECTS.items() if cls.robot == "diffdrive"]
    assert set(wheeled) == set(SURROGATE_EFFECTS)
    for name in SURROGATE_EFFECTS:
        cls = EFFECTS[name]
        assert isinstance(cls.surrogate_slot, SurrogateSlot)
        example = dict(cls.surrogate_example)
        assert example and 0.0 < cls.surrogate_tolerance < 1.0
        for param, value in example.items():
            spec = cls.spec(param)
            assert spec.low <= value <= spec.high and value != spec.nominal


def _composed_error(base, values: dict[str, dict[str, float]], order: tuple[str, ...]):
    """The surrogate's error of the change of the features that ``values`` make, relative to
    PyBullet's with the effects listed in ``order``, and the size of that change (the
    reality, for its order of effects)."""
    sur, scales, out = base
    flat = {f"{e}.{k}": v for e, vals in values.items() for k, v in vals.items()}
    reality = Reality(tuple(make_effect(n, **values[n]) for n in order))
    num = den = 0.0
    for t, cmd, b, pb0, s0 in out.values():
        pb = features(simulate(t, params=P, commands=cmd, reality=reality).channels, b, MPT)
        s = features(sur.simulate(SurrogateInputs(DT, np.zeros(3), commands=cmd), flat), b, MPT)
        for g in pb:
            d_pb = (pb[g] - pb0[g]) / scales.scale(g)
            d_s = (s[g][0] - s0[g]) / scales.scale(g)
            num += float(np.sum((d_s - d_pb) ** 2))
            den += float(np.sum(d_pb**2))
    return np.sqrt(num / den), den, reality


@pytest.mark.parametrize("effect", SURROGATE_EFFECTS)
def test_effect_predictions_agree_with_pybullet(base, effect) -> None:
    # the effect's typical values and the bound on the relative error of its predicted
    # change of the window features, both declared by the effect
    bound = EFFECTS[effect].surrogate_tolerance
    err, size, _ = _composed_error(
        base, {effect: dict(EFFECTS[effect].surrogate_example)}, (effect,)
    )
    assert size > 1.0, "the effect must show in the features"
    assert err < bound


def test_batches_match_single_runs(base) -> None:
    sur, _, out = base
    _, cmd, *_ = out["mixed"]
    inputs = SurrogateInputs(DT, np.zeros(3), commands=cmd)
    delays = np.array([0.0, 0.07, 0.15])
    batch = sur.simulate(inputs, {"command_latency.delay": delays})
    for i, d in enumerate(delays):
        one = sur.simulate(inputs, {"command_latency.delay": d})
        np.testing.assert_allclose(batch["pose_gt"][i], one["pose_gt"][0], atol=1e-12)


def test_a_batch_sharing_a_time_shift_matches_one_of_differing_shifts(base) -> None:
    """A delay or clock offset shared by the batch takes a faster path: the same numbers."""
    sur, _, out = base
    _, cmd, *_ = out["mixed"]
    inputs = SurrogateInputs(DT, np.zeros(3), commands=cmd)
    ratios = np.array([0.99, 1.0, 1.01])
    for key, shift in (("command_latency.delay", 0.083), ("timestamp_offset.offset", -0.031)):
        shared = sur.simulate(inputs, {key: np.full(3, shift), "wheel_diameter_ratio.E_d": ratios})
        # the same shift on each row alone (a batch of one takes the general path)
        for i, r in enumerate(ratios):
            one = sur.simulate(inputs, {key: shift, "wheel_diameter_ratio.E_d": r})
            for name in ("pose_gt", "ticks", "pose_cam"):
                np.testing.assert_array_equal(shared[name][i], one[name][0])


def test_only_the_channels_asked_for_are_computed_and_they_are_unchanged(base) -> None:
    sur, _, out = base
    _, cmd, *_ = out["mixed"]
    inputs = SurrogateInputs(DT, np.zeros(3), commands=cmd)
    values = {"camera_mount_offset.dx": np.array([0.0, 0.01]), "timestamp_offset.offset": 0.02}
    full = sur.simulate(inputs, values)
    some = sur.simulate(inputs, values, outputs=("pose_gt", "ticks"))
    assert set(some) == {"pose_gt", "ticks"}
    for name in some:
        np.testing.assert_array_equal(some[name], full[name])
    with pytest.raises(ValueError, match="unknown output"):
        sur.simulate(inputs, values, outputs=("pose_gt", "lidar"))


def test_tick_driven_runs_read_ticks_through_both_encoder_terms(base) -> None:
    sur, _, out = base
    _, cmd, *_ = out["mixed"]
    ticks = sur.simulate(SurrogateInputs(DT, np.zeros(3), commands=cmd), {})["ticks"][0]
    values = {"encoder_scale.scale": 0.98, "encoder_ratio.E_c": 1.02}
    read = sur.simulate(SurrogateInputs(DT, np.zeros(3), ticks=ticks), values)
    # the same ticks, divided by the counts per true wheel angle, with nominal encoders
    gains = 0.98 * np.array([2.0 / 2.02, 2.0 * 1.02 / 2.02])
    plain = sur.simulate(SurrogateInputs(DT, np.zeros(3), ticks=ticks / gains), {})
    np.testing.assert_allclose(read["pose_true"][0], plain["pose_true"][0], atol=1e-9)
    np.testing.assert_allclose(read["ticks"][0], plain["ticks"][0] * gains, rtol=1e-9, atol=1e-9)


def test_calibration_cache_key_follows_the_body_the_solver_and_the_version(monkeypatch) -> None:
    from realitygap.robots import diffdrive_surrogate as surrogate

    key = surrogate._cache_key(P, 0)
    assert key == surrogate._cache_key(DiffDriveParams(), 0)
    assert key != surrogate._cache_key(P.replace(wheelbase=0.24), 0)
    assert key != surrogate._cache_key(P, 10)
    monkeypatch.setattr(surrogate, "CALIBRATION_VERSION", surrogate.CALIBRATION_VERSION + 1)
    assert key != surrogate._cache_key(P, 0)


def test_a_stored_calibration_is_read_back_and_the_cache_can_be_turned_off(
    tmp_path, monkeypatch
) -> None:
    from realitygap.core.cache import CACHE_DIR_ENV, CACHE_ENV
    from realitygap.robots import diffdrive_surrogate as surrogate

    monkeypatch.setenv(CACHE_DIR_ENV, str(tmp_path))
    monkeypatch.delenv(CACHE_ENV, raising=False)
    body = P.replace(wheelbase=0.241)
    cal = SurrogateCalibration(motor_accel_common=3.25, traction_common=7.5)
    assert surrogate._load_cached(body, 0) is None
    surrogate._store_cached(body, 0, cal)
    assert surrogate._load_cached(body, 0) == cal
    assert surrogate._load_cached(body, 10) is None
    monkeypatch.setenv(CACHE_ENV, "0")
    assert surrogate._load_cached(body, 0) is None


DRIVE_TRAIN = (
    "wheel_velocity_lag",
    "acceleration_limits",
    "wheel_dead_zone",
    "torque_speed_saturation",
    "traction_slip",
)


@pytest.mark.parametrize("effect", DRIVE_TRAIN)
def test_drive_train_effects_compose_with_command_latency(base, effect) -> None:
    # a bus delay in front of each drive-train effect: the surrogate's change of the features
    # agrees with PyBullet as well as the effect's own, whatever order the effects are given in
    values = {"command_latency": {"delay": 0.1}, effect: dict(EFFECTS[effect].surrogate_example)}
    bound = max(EFFECTS[effect].surrogate_tolerance, EFFECTS["command_latency"].surrogate_tolerance)
    for order in (("command_latency", effect), (effect, "command_latency")):
        err, size, _ = _composed_error(base, values, order)
        assert size > 1.0
        assert err < bound, order


@pytest.mark.parametrize(
    "effect",
    ("motor_deadband", "velocity_saturation", "wheel_dead_zone", "torque_speed_saturation"),
)
def test_static_wheel_limits_act_before_the_drive_lag_in_either_order(base, effect) -> None:
    # a dead zone or a speed limit on the set-point, then the motor's lag: PyBullet composes
    # them in the surrogate's order whatever order the reality lists them in (the calibrated
    # baseline's motor lag comes first in a model's values)
    values = {"motor_response": {"tau": 0.12}, effect: dict(EFFECTS[effect].surrogate_example)}
    bound = max(EFFECTS[effect].surrogate_tolerance, EFFECTS["motor_response"].surrogate_tolerance)
    for order in (("motor_response", effect), (effect, "motor_response")):
        err, size, reality = _composed_error(base, values, order)
        assert [e.name for e in reality.effects] == [effect, "motor_response"]
        assert size > 1.0
        assert err < bound, order
