"""The actuator convention of the nominal: a firmware that ramps the body or each wheel."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from realitygap.diagnosis.adapters.diffdrive.adapter import DiffDriveAdapter
from realitygap.diagnosis.adapters.diffdrive.manoeuvres import Manoeuvre
from realitygap.diagnosis.adapters.diffdrive.replay import applied_commands, simulate
from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.diagnosis.problem.problem import AttributionSettings
from realitygap.diagnosis.stages.baseline import Baseline
from realitygap.robots.diffdrive import DiffDriveParams, FirmwareLimits, ramp_step
from realitygap.robots.effects import Reality, make_effect
from realitygap.robots.simulation import MeasurementNoise

P = DiffDriveParams()
DT = 0.05
A_MAX, ALPHA_MAX = 0.4, 2.0 * 0.4 / P.wheelbase
FIRMWARE = {"a_max": A_MAX, "alpha_max": ALPHA_MAX}
NOISE = MeasurementNoise(truth_xy=0.0005, truth_theta=0.001, camera_xy=0.001, camera_theta=0.002)


def test_wheel_ramp_equals_body_ramp_on_straight_runs_and_turns_in_place() -> None:
    fw = FirmwareLimits(a_max=A_MAX, alpha_max=ALPHA_MAX)
    # straight: the wheels ramp with the body, a_max·dt per period
    assert fw.limit_wheels(0.5, 0.0, 0.0, 0.0, DT, P.wheelbase) == pytest.approx((A_MAX * DT, 0))
    # turn in place: each wheel moves a_max·dt, ω moves 2·a_max·dt / b
    v, w = fw.limit_wheels(0.0, 2.0, 0.0, 0.0, DT, P.wheelbase)
    assert v == pytest.approx(0.0, abs=1e-15)
    assert w == pytest.approx(2.0 * A_MAX * DT / P.wheelbase)
    assert (v, w) == pytest.approx(fw.limit(0.0, 2.0, 0.0, 0.0, DT))


def test_wheel_ramp_on_an_arc_keeps_the_outer_wheel_behind() -> None:
    fw = FirmwareLimits(a_max=A_MAX, alpha_max=ALPHA_MAX)
    # request: inner wheel 0.1 m/s, outer 0.3 m/s; one period moves each by at most 0.02 m/s
    half = P.wheelbase / 2
    v_req, w_req = 0.2, 0.1 / half
    v, w = fw.limit_wheels(v_req, w_req, 0.0, 0.0, DT, P.wheelbase)
    sl, sr = v - w * half, v + w * half
    assert (sl, sr) == pytest.approx((A_MAX * DT, A_MAX * DT))  # both saturated: no turn yet
    # the body ramp turns at once (ω moves by alpha_max·dt)
    _, w_body = fw.limit(v_req, w_req, 0.0, 0.0, DT)
    assert w_body == pytest.approx(ALPHA_MAX * DT) and w == pytest.approx(0.0, abs=1e-12)
    # ramped long enough, both reach the request
    for _ in range(40):
        v, w = fw.limit_wheels(v_req, w_req, v, w, DT, P.wheelbase)
    assert (v, w) == pytest.approx((v_req, w_req))


def _requests() -> tuple[np.ndarray, np.ndarray]:
    man = Manoeuvre(
        "arcs",
        "arcs from rest both ways, slowing down, straight runs, turns in place",
        (
            (3.0, 0.3, 0.8),
            (2.0, 0.1, 0.3),
            (2.0, 0, 0),
            (3.0, 0.35, -0.9),
            (2.0, 0, 0),
            (3.0, 0.3, 0.0),
            (2.0, 0.1, 0.0),
            (2.0, 0, 0),
            (2.0, 0.0, 1.2),
            (2.0, 0, 0),
            (3.0, 0.25, 1.0),
            (2.0, 0, 0),
        ),
        ramp=False,
    )
    return man.requested(DT)


def _log(convention: str, reality: Reality, rng: np.random.Generator) -> Log:
    """A log of requests whose robot's firmware ramps as ``convention`` (``"wheels/free"``, …)
    says; the log states the limits, not the convention."""
    t, req = _requests()
    ramp, _, decel = convention.partition("/")
    fw = {**FIRMWARE, "ramp": ramp, "deceleration": decel}
    probe = Log(
        t=t, channels={"cmd": req}, meta={"params": {"wheelbase": P.wheelbase}, "firmware": fw}
    )
    real = simulate(
        t, params=P, reality=reality, commands=applied_commands(probe), noise=NOISE, rng=rng
    )
    return real.with_channels(cmd=req).replace(meta={**real.meta, "firmware": dict(FIRMWARE)})


def _diagnose_planted(convention: str, effect: Any, seed: int) -> Any:
    """Diagnose two training logs and one held-out log of a robot whose firmware ramps as
    ``convention`` says and which carries ``effect``, among three candidate effects."""
    rng = np.random.default_rng(seed)
    reality = Reality((effect,))
    train = [_log(convention, reality, rng), _log(convention, reality, rng)]
    hold = [_log(convention, reality, rng)]
    return diagnose(
        train,
        hold,
        settings=DiagnosisSettings(
            effects=("wheelbase_error", "wheel_radius_scale", "command_latency"),
            attribution=AttributionSettings(pair_candidates=2, verify_top=1),
        ),
    )


def test_free_deceleration_limits_only_speeding_up() -> None:
    assert ramp_step(0.3, 0.0, 0.01, True) == 0.0  # brakes at once
    assert ramp_step(0.3, -0.2, 0.01, True) == -0.2  # through standstill at once
    assert ramp_step(0.0, -0.2, 0.01, True) == pytest.approx(-0.01)  # from rest: ramped
    assert ramp_step(0.3, 0.5, 0.01, True) == pytest.approx(0.31)
    assert ramp_step(0.3, 0.0, 0.01, False) == pytest.approx(0.29)
    assert ramp_step(-0.3, 0.0, 0.01, True) == 0.0
    fw = FirmwareLimits(a_max=A_MAX, alpha_max=ALPHA_MAX)
    # a turn ends: the wheels stop at once, the body twist too
    v, w = fw.limit_wheels(0.0, 0.0, 0.0, 1.0, DT, P.wheelbase, free_deceleration=True)
    assert (v, w) == (0.0, 0.0)
    assert fw.limit(0.0, 0.0, 0.2, 1.0, DT, free_deceleration=True) == (0.0, 0.0)


def test_unknown_ramp_convention_is_refused() -> None:
    t, req = _requests()
    log = Log(t=t, channels={"cmd": req}, meta={"firmware": {**FIRMWARE, "ramp": "motor"}})
    with pytest.raises(LogError, match=r"ramp 'body' or 'wheels'.*got ramp 'motor'"):
        applied_commands(log)
    with pytest.raises(ValueError, match="actuator convention must be one of body/limited"):
        DiffDriveAdapter().with_actuator_convention(log, "motor")


def test_applied_commands_follow_the_stated_convention() -> None:
    t, req = _requests()
    meta = {"params": {"wheelbase": P.wheelbase}}
    body = applied_commands(Log(t=t, channels={"cmd": req}, meta={**meta, "firmware": FIRMWARE}))
    wheels = applied_commands(
        Log(t=t, channels={"cmd": req}, meta={**meta, "firmware": {**FIRMWARE, "ramp": "wheels"}})
    )
    # both reach every request; they part only while an arc ramps
    assert np.allclose(body[-1], 0.0) and np.allclose(wheels[-1], 0.0)
    differ = np.abs(body[:, 1] - wheels[:, 1]) > 1e-9
    assert differ.any()
    # 1.5 s after the last turn request both conventions have settled
    settled = np.array([not req[max(k - 30, 0) : k + 1, 1].any() for k in range(t.size)])
    straight = settled & (req[:, 0] > 0)
    assert straight.sum() > 20
    assert not differ[settled].any()


@pytest.mark.slow
@pytest.mark.parametrize("convention", ["wheels/limited", "body/free", "body/stop"])
def test_planted_ramp_convention_is_baseline_calibration_and_the_effect_is_found(
    convention: str,
) -> None:
    d = _diagnose_planted(convention, make_effect("wheelbase_error", E_b=1.04), seed=11)
    assert d.baseline.convention == convention
    costs = d.baseline.convention_costs
    assert min(costs, key=costs.get) == convention and len(costs) == 6
    assert d.verdict.label == ["wheelbase_error"]
    assert d.ranking[0].values["wheelbase_error.E_b"] == pytest.approx(1.04, abs=0.01)
    js = d.to_json()["baseline_calibration"]["actuator_convention"]
    what = {"wheels/limited": "each wheel", "body/free": "slows down at once"}.get(
        convention, "a zero request stops at once"
    )
    assert js["chosen"] == convention and what in js["what"]
    assert what in d.baseline.summary()


def test_baseline_without_convention_says_so() -> None:
    b = Baseline()
    assert b.to_json()["actuator_convention"] is None
    assert "none" in b.summary()


@pytest.mark.slow
@pytest.mark.parametrize("convention", ["body/limited", "wheels/limited"])
def test_a_long_command_latency_does_not_choose_the_ramp_convention(convention: str) -> None:
    """Commands that act 0.2 s (four periods) late. The conventions are judged with the
    latency profiled out (each nuisance free over its physical range): the planted one
    then fits like the nominal robot itself, far better than any other, and the latency
    is the verdict. Judged with the nuisances' narrow ranges, every convention carried the
    unmodelled delay and they were apart by tens of per cent only; on another world's
    logs the ramp that best imitates a delay won."""
    d = _diagnose_planted(convention, make_effect("command_latency", delay=0.2), seed=5)
    costs = d.baseline.convention_costs
    assert d.baseline.convention == convention == min(costs, key=costs.get)
    assert min(c for k, c in costs.items() if k != convention) > 5.0 * costs[convention]
    # the baseline's own latency stays within its nuisance range (one period)
    assert d.baseline.values["command_latency.delay"] <= DT + 1e-9
    assert d.verdict.label == ["command_latency"]
    assert d.ranking[0].values["command_latency.delay"] == pytest.approx(0.2, abs=0.02)
