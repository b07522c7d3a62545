"""Firmware conventions: separate deceleration limits and a zero request that stops at once."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.diagnosis.adapters.diffdrive.firmware import (
    firmware_from_meta,
    fit_firmware_limits,
)
from realitygap.diagnosis.adapters.diffdrive.replay import applied_commands, simulate
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.robots.diffdrive import (
    Deceleration,
    DiffDriveParams,
    DiffDriveRobot,
    FirmwareLimits,
    Ramp,
    ramp_step,
)
from realitygap.robots.simulation import MeasurementNoise
from realitygap.robots.world import World

P = DiffDriveParams()
DT = 0.05


def _requests(rng: np.random.Generator, n: int = 240) -> np.ndarray:
    """Piecewise-constant requests with exact zeros, turns in place, arcs and reversals."""
    req = np.zeros((n, 2))
    k = 0
    while k < n:
        length = int(rng.integers(5, 30))
        kind = rng.integers(4)
        if kind == 1:
            req[k : k + length] = (rng.uniform(-0.4, 0.5), 0.0)
        elif kind == 2:
            req[k : k + length] = (0.0, rng.uniform(-2.0, 2.0))
        elif kind == 3:
            req[k : k + length] = (rng.uniform(0.0, 0.4), rng.uniform(-1.5, 1.5))
        k += length
    return req


def test_decel_step_limits_slowing_down_apart() -> None:
    assert ramp_step(0.3, 0.0, 0.01, False, 0.03) == pytest.approx(0.27)
    assert ramp_step(-0.3, 0.0, 0.01, False, 0.03) == pytest.approx(-0.27)
    assert ramp_step(0.3, 0.5, 0.01, False, 0.03) == pytest.approx(0.31)  # speeding up
    assert ramp_step(0.0, -0.5, 0.01, False, 0.03) == pytest.approx(-0.01)  # from rest
    assert ramp_step(0.3, 0.0, 0.01, True, 0.03) == 0.0  # free wins
    fw = FirmwareLimits(a_max=1.0, alpha_max=4.0, decel_factor=2.5)
    assert fw.limit(0.0, 0.0, 0.5, 2.0, DT) == pytest.approx((0.5 - 2.5 * DT, 2.0 - 10.0 * DT))
    v, w = fw.limit_wheels(0.0, 0.0, 0.5, 0.0, DT, P.wheelbase)
    assert (v, w) == pytest.approx((0.5 - 2.5 * DT, 0.0))


def test_stop_convention_drops_a_zero_request_at_once_and_ramps_the_rest() -> None:
    for ramp in Ramp:
        fw = FirmwareLimits(a_max=1.0, alpha_max=4.0, ramp=ramp, deceleration="stop")
        assert fw.convention == f"{ramp.value}/stop"
        assert fw.step(0.0, 0.0, 0.4, -1.5, DT, P.wheelbase) == (0.0, 0.0)
        # a request that is small but not zero is ramped down like the limited convention
        lim = FirmwareLimits(a_max=1.0, alpha_max=4.0, ramp=ramp)
        assert fw.step(0.0, 1e-6, 0.4, 0.0, DT, P.wheelbase) == lim.step(
            0.0, 1e-6, 0.4, 0.0, DT, P.wheelbase
        )
        assert fw.step(0.0, 1e-6, 0.4, 0.0, DT, P.wheelbase)[0] == pytest.approx(0.35, abs=1e-5)
        # speeding up from rest is ramped as before
        assert fw.step(0.5, 0.0, 0.0, 0.0, DT, P.wheelbase) == pytest.approx((0.05, 0.0))


def test_default_step_is_the_body_ramp() -> None:
    fw = FirmwareLimits(a_max=1.0, alpha_max=4.0)
    assert fw.ramp is Ramp.BODY and fw.deceleration is Deceleration.LIMITED
    rng = np.random.default_rng(3)
    v = w = 0.0
    for vr, wr in _requests(rng, 120):
        expect = fw.limit(vr, wr, v, w, DT)
        v, w = fw.step(vr, wr, v, w, DT, P.wheelbase)
        assert (v, w) == expect


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"a_max": -1.0}, r"FirmwareLimits\.a_max must be positive .*got -1\.0"),
        ({"decel_factor": 0.0}, r"FirmwareLimits\.decel_factor must be positive"),
        ({"ramp": "motor"}, r"ramp must be one of \['body', 'wheels'\].*got ramp 'motor'"),
        ({"deceleration": "brake"}, r"deceleration one of .*'stop'.*got .*'brake'"),
    ],
)
def test_bad_firmware_is_refused(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        FirmwareLimits(**kwargs)


def test_bad_firmware_metadata_names_the_log() -> None:
    t = np.arange(5) * DT
    log = Log(
        t=t,
        channels={"cmd": np.zeros((5, 2))},
        meta={"firmware": {"a_max": 1.0, "deceleration": "brake"}},
        source="run-07.csv",
    )
    with pytest.raises(LogError, match=r"run-07\.csv: meta\['firmware'\] must have .*'brake'"):
        applied_commands(log)


@pytest.mark.parametrize(
    "convention", ["body/limited", "body/free", "body/stop", "wheels/limited", "wheels/stop"]
)
def test_pybullet_firmware_and_the_replayed_commands_agree(convention: str) -> None:
    """The robot's firmware (``command_twist``) and the diagnosis' applied commands (which
    drive the PyBullet replay and the surrogate) are one realisation of a convention."""
    ramp, _, decel = convention.partition("/")
    fw_meta = {"a_max": 0.8, "alpha_max": 3.0, "ramp": ramp, "deceleration": decel}
    fw_meta["decel_factor"] = 1.5
    rng = np.random.default_rng(5)
    req = _requests(rng)
    t = np.arange(req.shape[0]) * DT
    log = Log(
        t=t, channels={"cmd": req}, meta={"params": {"wheelbase": P.wheelbase}, "firmware": fw_meta}
    )
    limits = firmware_from_meta(log)
    assert limits is not None and limits.convention == convention
    expected = applied_commands(log)
    world = World()
    try:
        robot = DiffDriveRobot(world, P)
        robot.attach_firmware(DT, limits=limits)
        got = np.array([robot.command_twist(float(v), float(w)) for v, w in req])
    finally:
        world.close()
    np.testing.assert_allclose(got, expected, atol=1e-12)
    if decel == "stop":
        zero = (req[:, 0] == 0.0) & (req[:, 1] == 0.0)
        assert zero.any() and np.all(expected[zero] == 0.0)


def _firmware_log(
    convention: str, scale: float, decel: float, rng: np.random.Generator
) -> tuple[Log, dict]:
    """A PyBullet log of requests whose firmware ramps as ``convention`` with limits ``scale``
    times the stated ones and deceleration ``decel`` times the acceleration; the log states
    the nominal limits only."""
    stated = {"a_max": 0.4, "alpha_max": 2.0 * 0.4 / P.wheelbase}
    ramp, _, dec = convention.partition("/")
    true = FirmwareLimits(
        a_max=stated["a_max"] * scale,
        alpha_max=stated["alpha_max"] * scale,
        ramp=ramp,
        deceleration=dec,
        decel_factor=decel,
    )
    req = _requests(rng, 500)
    t = np.arange(req.shape[0]) * DT
    noise = MeasurementNoise(truth_xy=0.0005, truth_theta=0.001)
    real = simulate(t, params=P, commands=true.applied(req, DT, P.wheelbase), noise=noise, rng=rng)
    return real.with_channels(cmd=req).replace(meta={**real.meta, "firmware": stated}), stated


@pytest.mark.parametrize(
    ("convention", "scale", "decel"),
    [("body/stop", 0.77, 1.8), ("wheels/limited", 1.3, 0.6), ("body/free", 0.85, 1.0)],
)
@pytest.mark.slow
def test_fitted_limits_recover_the_planted_ones(
    convention: str, scale: float, decel: float
) -> None:
    rng = np.random.default_rng(21)
    log, stated = _firmware_log(convention, scale, decel, rng)
    fit = fit_firmware_limits([log], convention)
    assert fit.n_rows == log.n - 1 and fit.cost < fit.cost_stated
    # the wheels follow their set-points through the motors' own response: a few % low
    assert fit.accel_scale == pytest.approx(scale, rel=0.05)
    if convention.endswith("free"):
        assert fit.decel_factor == 1.0  # not a parameter of this convention
    else:
        assert fit.decel_factor == pytest.approx(decel, rel=0.05)
    fw = fit.meta(stated)
    assert fw["a_max"] == pytest.approx(0.4 * scale, rel=0.05)
    assert fw["alpha_max"] == pytest.approx(stated["alpha_max"] * fit.accel_scale)
    # a robot that runs the stated limits gets them back within the motors' response
    same, _ = _firmware_log(convention, 1.0, 1.0, np.random.default_rng(22))
    kept = fit_firmware_limits([same], convention)
    assert kept.accel_scale == pytest.approx(1.0, abs=0.03)
    assert kept.decel_factor == pytest.approx(1.0, abs=0.03)


@pytest.mark.parametrize("scale", [0.2, 4.0])
def test_limits_stretched_to_the_end_of_their_range_leave_the_stated_ones(scale: float) -> None:
    # ramps five times slower (or four times faster) than stated are no rescaled stated
    # firmware: the fit would end at its bound, so the stated limits stay and the
    # difference is left to the effect library (acceleration_limits, wheel_velocity_lag)
    log, _ = _firmware_log("body/limited", scale, 1.0, np.random.default_rng(23))
    fit = fit_firmware_limits([log], "body/limited")
    assert fit.n_rows == log.n - 1
    assert (fit.accel_scale, fit.decel_factor, fit.cost) == (1.0, 1.0, fit.cost_stated)


def test_limits_fit_without_encoders_or_firmware_is_empty() -> None:
    t = np.arange(10) * DT
    log = Log(t=t, channels={"cmd": np.zeros((10, 2))}, meta={"firmware": {"a_max": 1.0}})
    assert fit_firmware_limits([log], "body/stop").n_rows == 0


def test_baseline_states_the_fitted_limits() -> None:
    from realitygap.diagnosis.adapters.diffdrive.firmware import FirmwareFit
    from realitygap.diagnosis.stages.baseline import Baseline

    fit = FirmwareFit("body/stop", accel_scale=0.77, decel_factor=1.8, n_rows=10)
    b = Baseline(convention="body/stop", convention_what="ramps", convention_limits=fit.to_json())
    assert "acceleration ×0.77 the stated, deceleration ×1.80" in b.summary()
    assert b.to_json()["actuator_convention"]["limits"]["decel_factor"] == 1.8
    stated = {"a_max": 0.4, "alpha_max": 3.0, "ramp": "body"}
    assert fit.meta(stated) == pytest.approx(
        {"a_max": 0.4 * 0.77, "alpha_max": 3.0 * 0.77, "ramp": "body", "decel_factor": 1.8}
    )


def test_a_command_latency_beyond_a_few_periods_is_not_taken_for_a_slower_ramp() -> None:
    """Set-points that reach the motors 0.2 s late (four periods here, the bound of the
    effect library's latency is 0.3 s): the limit fit's delay reaches them, and the ramp it
    fits is the stated one, not a slower ramp standing in for the delay."""
    convention = "wheels/limited"
    plain, stated = _firmware_log(convention, 1.0, 1.0, np.random.default_rng(23))
    k = round(0.2 / DT)
    cmd = np.asarray(plain["cmd"], dtype=float)
    ramp, _, dec = convention.partition("/")
    fw = FirmwareLimits(
        a_max=stated["a_max"],
        alpha_max=stated["alpha_max"],
        ramp=ramp,
        deceleration=dec,
        decel_factor=1.0,
    )
    applied = fw.applied(cmd, DT, P.wheelbase)
    late = np.vstack([np.zeros((k, 2)), applied[:-k]])
    t = np.arange(cmd.shape[0]) * DT
    noise = MeasurementNoise(truth_xy=0.0005, truth_theta=0.001)
    real = simulate(t, params=P, commands=late, noise=noise, rng=np.random.default_rng(24))
    log = real.with_channels(cmd=cmd).replace(meta={**real.meta, "firmware": stated})
    on_time = fit_firmware_limits([plain], convention)
    delayed = fit_firmware_limits([log], convention)
    assert delayed.accel_scale == pytest.approx(1.0, abs=0.03)
    assert delayed.delay_periods - on_time.delay_periods == pytest.approx(k, abs=0.3)
    # a bound given in periods is kept
    short = fit_firmware_limits([log], convention, max_delay_periods=2.0)
    assert short.delay_periods <= 2.0
