"""Each differential-drive effect really does, in PyBullet, what its description says."""

from __future__ import annotations

import math

import numpy as np
import pytest

from realitygap.diagnosis.adapters.diffdrive.replay import simulate
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import (
    EFFECTS,
    LIBRARY_VERSION,
    Channel,
    Reality,
    Stage,
    blind_ranges,
    library,
    make_effect,
)

P = DiffDriveParams()
DT = 0.05


def _settled_trail(tau: float) -> float:
    """Seconds a first-order lag of time constant ``tau``, stepped once per period ``DT``,
    trails a steady command by once it settles: ``dt·(1 − k)/k``, ``k = 1 − e^{−dt/τ}``."""
    from realitygap.robots.effects.diffdrive_drivetrain import _lag_gain

    k = float(_lag_gain(tau, DT))
    return DT * (1.0 - k) / k


def run(cmd: list[tuple[float, float, float]], *effects, ramp: bool = False):
    rows = [np.zeros((1, 2))]
    for duration, v, w in cmd:
        rows.append(np.tile([v, w], (int(round(duration / DT)), 1)))
    rows.append(np.zeros((1, 2)))
    c = np.concatenate(rows)
    if ramp:  # the firmware's acceleration limits, as in the env
        v = w = 0.0
        for k in range(c.shape[0]):
            v += float(np.clip(c[k, 0] - v, -P.a_max * DT, P.a_max * DT))
            w += float(np.clip(c[k, 1] - w, -P.alpha_max * DT, P.alpha_max * DT))
            c[k] = v, w
    t = DT * np.arange(c.shape[0])
    reality = Reality(tuple(make_effect(n, **vals) for n, vals in effects))
    return simulate(t, params=P, commands=c, reality=reality)


@pytest.fixture(scope="module")
def straight():
    return run([(2.0, 0.3, 0.0)])


def test_library_is_documented() -> None:
    names = {n for n, cls in EFFECTS.items() if cls.robot == "diffdrive"}
    assert {
        "wheel_radius_scale",
        "wheel_diameter_ratio",
        "wheelbase_error",
        "longitudinal_slip",
        "command_latency",
        "motor_deadband",
        "velocity_saturation",
        "encoder_scale",
        "camera_mount_offset",
        "timestamp_offset",
    } <= names
    for n in names:
        cls = EFFECTS[n]
        assert cls.description and cls.observed_in and cls.stage
        for s in cls.specs:
            assert s.unit and s.low <= s.nominal <= s.high and s.description


def test_every_effect_declares_typed_stage_channels_and_valid_blind_ranges() -> None:
    for cls in EFFECTS.values():
        assert isinstance(cls.stage, Stage)
        assert cls.observed_in and all(isinstance(c, Channel) for c in cls.observed_in)
        for r in cls.blind:
            spec = cls.spec(r.param)
            assert 0.0 <= r.low < r.high
            assert spec.high - spec.low >= r.high


def test_command_stage_effects_are_those_the_tick_drive_cannot_see() -> None:
    from realitygap.diagnosis.adapters.contract import Drive
    from realitygap.diagnosis.adapters.registry import get_adapter

    adapter = get_adapter("diffdrive")
    command = {n for n in adapter.effect_names() if EFFECTS[n].stage is Stage.COMMAND}
    assert command == {
        "command_latency",
        "motor_deadband",
        "velocity_saturation",
        "wheel_velocity_lag",
        "acceleration_limits",
        "wheel_dead_zone",
        "torque_speed_saturation",
    }
    for n in command:
        assert "acts on the commands" in adapter.observable(n, [], Drive.TICKS)
    assert adapter.observable("encoder_scale", [], Drive.TICKS).startswith("shows only in")


def test_command_hooks_use_the_nominal_geometry_they_are_given() -> None:
    reality = Reality((make_effect("motor_deadband", threshold=0.05),))
    narrow, wide = P.replace(wheelbase=0.2), P.replace(wheelbase=0.4)
    # a turn in place at 0.4 rad/s: wheel speed 0.04 m/s on the narrow robot, 0.08 on the wide
    (h_narrow,) = reality.command_hooks(DT, narrow)
    (h_wide,) = reality.command_hooks(DT, wide)
    assert h_narrow(0.0, 0.4, DT) == (0.0, 0.0)
    assert h_wide(0.0, 0.4, DT)[1] == pytest.approx(0.4)
    # the effect objects are not changed by building hooks or bodies
    before = dict(reality.effects[0].__dict__)
    reality.apply_params(wide)
    reality.command_hooks(DT, narrow)
    assert reality.effects[0].__dict__ == before


def test_library_versions_keep_earlier_suites_reproducible() -> None:
    # version 2 adds the encoder ratio and the drive-train family; version 1 stays as it was
    added = {n for n in library("diffdrive") if EFFECTS[n].since == 2}
    assert added == {
        "encoder_ratio",
        "wheel_velocity_lag",
        "acceleration_limits",
        "wheel_dead_zone",
        "torque_speed_saturation",
        "traction_slip",
    }
    assert not added & set(library("diffdrive", version=1))
    # version 3 adds a tracked point off the axle (a marker on a mast): a baseline nuisance
    # within the setup's convention, an effect beyond it
    assert {n for n in library("diffdrive") if EFFECTS[n].since == 3} == {"truth_frame_offset"}
    assert LIBRARY_VERSION == 3
    old, new = (
        list(blind_ranges("diffdrive", version=1)),
        list(blind_ranges("diffdrive", version=2)),
    )
    assert new[: len(old)] == old and set(new[len(old) :]) == added
    later = [n for n, c in EFFECTS.items() if c.robot == "diffdrive" and c.since > LIBRARY_VERSION]
    assert not set(later) & set(new)


def test_encoder_ratio_changes_counts_only(straight) -> None:
    log = run([(2.0, 0.3, 0.0)], ("encoder_ratio", {"E_c": 1.04}))
    np.testing.assert_allclose(log["pose_gt"][-1], straight["pose_gt"][-1], atol=1e-6)
    ratio = log["ticks"][-1] / straight["ticks"][-1]
    np.testing.assert_allclose(ratio, [2 / 2.04, 2 * 1.04 / 2.04], rtol=1e-3)
    assert log["ticks"][-1, 1] / log["ticks"][-1, 0] == pytest.approx(
        1.04 * straight["ticks"][-1, 1] / straight["ticks"][-1, 0], rel=1e-3
    )


def test_encoder_ratio_can_drive_a_replay_by_ticks(straight) -> None:
    log = run([(2.0, 0.3, 0.0)], ("encoder_ratio", {"E_c": 1.04}))
    reality = Reality((make_effect("encoder_ratio", E_c=1.04),))
    assert len(reality.ticks_inverse_hooks()) == 1
    again = simulate(log.t, params=P, ticks=log["ticks"], reality=reality)
    np.testing.assert_allclose(again["pose_gt"][-1, :2], log["pose_gt"][-1, :2], atol=0.01)
    assert abs(again["pose_gt"][-1, 2]) < 0.01


def test_wheel_radius_scale_scales_distance_not_ticks(straight) -> None:
    big = run([(2.0, 0.3, 0.0)], ("wheel_radius_scale", {"scale": 1.05}))
    assert big["pose_gt"][-1, 0] / straight["pose_gt"][-1, 0] == pytest.approx(1.05, rel=0.01)
    np.testing.assert_allclose(big["ticks"][-1], straight["ticks"][-1], rtol=0.01)


def test_wheel_diameter_ratio_curves_a_straight_command(straight) -> None:
    log = run([(2.0, 0.3, 0.0)], ("wheel_diameter_ratio", {"E_d": 1.02}))
    # right wheel larger: turns left; Δθ = s (E_d − 1)/(E_d + 1) · 2 / b
    s = log["pose_gt"][-1, 0]
    expected = s * 2 * 0.02 / 2.02 / P.wheelbase
    assert log["pose_gt"][-1, 2] == pytest.approx(expected, rel=0.1)
    assert abs(straight["pose_gt"][-1, 2]) < 1e-3


def test_wheelbase_error_slows_turns() -> None:
    nominal = run([(2.0, 0.0, 1.0)])
    wide = run([(2.0, 0.0, 1.0)], ("wheelbase_error", {"E_b": 1.1}))
    ratio = wide["pose_gt"][-1, 2] / nominal["pose_gt"][-1, 2]
    assert ratio == pytest.approx(1 / 1.1, rel=0.02)


def test_longitudinal_slip_loses_ground_on_hard_starts(straight) -> None:
    slip = run([(2.0, 0.3, 0.0)], ("longitudinal_slip", {"mu": 0.15}))
    # the wheels spin up at once (the encoders count it), the ground lags them after the start
    assert np.all(slip["ticks"][10] >= straight["ticks"][10])
    np.testing.assert_allclose(slip["ticks"][10], straight["ticks"][10], rtol=0.05)
    assert slip["pose_gt"][4, 0] < 0.7 * straight["pose_gt"][4, 0]
    # a gentle (firmware-ramped) start needs less traction than the floor gives: no loss
    ramped = run([(2.0, 0.3, 0.0)], ("longitudinal_slip", {"mu": 0.15}), ramp=True)
    ramped_nominal = run([(2.0, 0.3, 0.0)], ramp=True)
    ramp_loss = ramped_nominal["pose_gt"][-1, 0] - ramped["pose_gt"][-1, 0]
    hard_loss = straight["pose_gt"][-1, 0] - slip["pose_gt"][-1, 0]
    assert hard_loss > 0.01 and abs(ramp_loss) < 0.25 * hard_loss


def test_command_latency_delays_motion(straight) -> None:
    late = run([(2.0, 0.3, 0.0)], ("command_latency", {"delay": 0.1}))
    np.testing.assert_allclose(late["pose_gt"][3:, 0], straight["pose_gt"][1:-2, 0], atol=2e-3)
    assert late["pose_gt"][2, 0] == pytest.approx(0.0, abs=1e-4)


def test_motor_deadband_stops_slow_commands() -> None:
    slow = run([(2.0, 0.03, 0.0)], ("motor_deadband", {"threshold": 0.05}))
    assert abs(slow["pose_gt"][-1, 0]) < 2e-3
    fast = run([(2.0, 0.2, 0.0)], ("motor_deadband", {"threshold": 0.05}))
    assert fast["pose_gt"][-1, 0] > 0.35


def test_velocity_saturation_caps_speed() -> None:
    log = run([(3.0, 0.6, 0.0)], ("velocity_saturation", {"v_limit": 0.3}))
    v = np.diff(log["pose_gt"][20:50, 0]) / DT
    assert np.mean(v) == pytest.approx(0.3, rel=0.03)


def test_encoder_scale_changes_counts_only(straight) -> None:
    log = run([(2.0, 0.3, 0.0)], ("encoder_scale", {"scale": 0.95}))
    np.testing.assert_allclose(log["pose_gt"][-1], straight["pose_gt"][-1], atol=1e-6)
    assert log["ticks"][-1, 0] / straight["ticks"][-1, 0] == pytest.approx(0.95, rel=1e-3)


def test_camera_mount_offset_moves_the_camera_link(straight) -> None:
    log = run([(2.0, 0.3, 0.0)], ("camera_mount_offset", {"dx": 0.02, "dy": -0.01, "dyaw": 0.03}))
    gt, cam = log["pose_gt"][-1], log["pose_cam"][-1]
    c, s = math.cos(gt[2]), math.sin(gt[2])
    rel = [
        c * (cam[0] - gt[0]) + s * (cam[1] - gt[1]),
        -s * (cam[0] - gt[0]) + c * (cam[1] - gt[1]),
    ]
    np.testing.assert_allclose(rel, [0.02, -0.01], atol=1e-3)
    assert cam[2] - gt[2] == pytest.approx(0.03, abs=1e-3)


def test_timestamp_offset_shifts_ground_truth_only(straight) -> None:
    log = run([(2.0, 0.3, 0.0)], ("timestamp_offset", {"offset": 0.1}))
    np.testing.assert_allclose(log["pose_gt"][2:, 0], straight["pose_gt"][:-2, 0], atol=1e-6)
    np.testing.assert_allclose(log["ticks"], straight["ticks"])


def test_effects_reach_the_env() -> None:
    from realitygap.diagnosis.adapters.diffdrive.record import RecordLog
    from realitygap.envs.wheeled_nav import WheeledNavEnv

    reality = Reality(
        (make_effect("timestamp_offset", offset=0.1), make_effect("wheel_radius_scale", scale=1.1))
    )
    logs = []
    for r in (Reality(), reality):
        env = WheeledNavEnv(
            reality=r, n_obstacles=0, start=(0, 0, 0), goal=(2.5, 2.5, 0), n_beams=8
        )
        rec = RecordLog(env)
        rec.reset(seed=0)
        for _ in range(30):
            rec.step(np.array([0.4, 0.0], dtype=np.float32))
        logs.append(rec.log)
        env.close()
    assert logs[1]["pose_gt"][-1, 0] / logs[0]["pose_gt"][-3, 0] == pytest.approx(1.1, rel=0.02)


# --------------------------------------------------------------------------- drive train
def _speed(log, a: int, b: int) -> float:
    """Mean forward speed (m/s) of a straight run between samples a and b."""
    return float((log["pose_gt"][b, 0] - log["pose_gt"][a, 0]) / ((b - a) * DT))


def test_speed_limiter_step_follows_the_diff_drive_controller_semantics() -> None:
    from realitygap.robots.effects.diffdrive_drivetrain import speed_limiter_step as step

    up, down = 0.1, 0.05
    # from standstill: the acceleration limit both ways
    assert step(0.0, 1.0, up, down) == pytest.approx(0.1)
    assert step(0.0, -1.0, up, down) == pytest.approx(-0.1)
    # moving forward: speeding up by the acceleration, slowing down by the deceleration limit
    assert step(0.5, 1.0, up, down) == pytest.approx(0.6)
    assert step(0.5, 0.0, up, down) == pytest.approx(0.45)
    # moving backward: the mirror image
    assert step(-0.5, -1.0, up, down) == pytest.approx(-0.6)
    assert step(-0.5, 0.0, up, down) == pytest.approx(-0.45)
    # a reversal is braked by the deceleration limit (judged by the previous sign)
    assert step(0.02, -1.0, up, down) == pytest.approx(-0.03)
    # within the limits the request is met; infinite limits never limit
    assert step(0.5, 0.52, up, down) == pytest.approx(0.52)
    assert step(0.0, 3.0, np.inf, np.inf) == pytest.approx(3.0)


def test_acceleration_limits_ramp_starts_and_stops_at_their_own_rates(straight) -> None:
    # 0.25 m/s² speeding up, 1 m/s² slowing down
    log = run(
        [(2.0, 0.3, 0.0), (1.0, 0.0, 0.0)], ("acceleration_limits", {"t_acc": 4.0, "t_dec": 1.0})
    )
    # the start takes 1.2 s: after 0.6 s the ramp is half way (speed 0.15 m/s)
    assert _speed(log, 10, 14) == pytest.approx(0.25 * 0.6, rel=0.12)
    assert _speed(log, 30, 40) == pytest.approx(0.3, rel=0.03)
    # the stop takes 0.3 s: distance run on after the stop command v²/(2 a_dec) = 4.5 cm
    stop = 41  # first period commanded zero
    run_on = log["pose_gt"][-1, 0] - log["pose_gt"][stop, 0]
    nominal_run_on = straight["pose_gt"][-1, 0] - straight["pose_gt"][stop, 0]
    assert run_on - nominal_run_on == pytest.approx(0.3**2 / 2.0, rel=0.25)


def test_unequal_wheel_lags_yaw_the_robot_on_a_start_and_back_on_the_stop() -> None:
    log = run(
        [(2.0, 0.3, 0.0), (2.0, 0.0, 0.0)],
        ("wheel_velocity_lag", {"tau_left": 0.3, "tau_right": 0.05}),
    )
    # each wheel falls behind its command by v·dt·(1 − k)/k once it settles
    expected = 0.3 * (_settled_trail(0.3) - _settled_trail(0.05)) / P.wheelbase
    assert log["pose_gt"][38, 2] == pytest.approx(expected, rel=0.1)
    # the lagging wheel catches up after the stop: the heading returns
    assert abs(log["pose_gt"][-1, 2]) < 0.1 * expected


def test_motor_response_lags_both_wheels_alike_and_stays_a_baseline_nuisance() -> None:
    from realitygap.diagnosis.adapters.contract import Drive
    from realitygap.diagnosis.adapters.diffdrive.adapter import (
        DRIVE_RESPONSE_FLOOR,
        TRUTH_LATENCY_FLOOR,
        DiffDriveAdapter,
    )

    plan = [(2.0, 0.3, 0.4), (2.0, 0.0, 0.0)]
    common = run(plan, ("motor_response", {"tau": 0.15}))
    per_wheel = run(plan, ("wheel_velocity_lag", {"tau_left": 0.15, "tau_right": 0.15}))
    # one law: the common lag is the per-wheel lag with equal time constants
    np.testing.assert_array_equal(common["pose_gt"], per_wheel["pose_gt"])
    # settled, a drive trails its command by dt·(1 − k)/k seconds: in travel on a straight,
    # in heading on a turn in place, and without turning the straight
    lag_s = _settled_trail(0.15)
    for v, w in ((0.3, 0.0), (0.0, 0.4)):
        plan = [(2.0, v, w), (2.0, 0.0, 0.0)]
        behind = (
            run(plan)["pose_gt"][38] - run(plan, ("motor_response", {"tau": 0.15}))["pose_gt"][38]
        )
        assert behind[0] == pytest.approx(v * lag_s, rel=0.1, abs=1e-4)
        assert behind[2] == pytest.approx(w * lag_s, rel=0.05, abs=3e-4)
    # never a candidate: outside the default library, fitted by the baseline within a period
    adapter = DiffDriveAdapter()
    assert "motor_response" not in adapter.effect_names()
    assert "wheel_velocity_lag" in adapter.effect_names()
    prepared = [_Prepared(common)]
    low, high, _ = adapter.baseline_nuisances(prepared, Drive.COMMANDS)["motor_response.tau"]
    # the log holds the twist the drive received: half a period, but never under the floor
    assert low == 0.0 and high == pytest.approx(max(0.5 * common.dt, DRIVE_RESPONSE_FLOOR))
    fast = common.replace(t=0.2 * common.t)  # a 100 Hz log: a period of 10 ms
    assert adapter.baseline_nuisances([_Prepared(fast)], Drive.COMMANDS)["motor_response.tau"][
        1
    ] == pytest.approx(DRIVE_RESPONSE_FLOOR)
    assert "motor_response.tau" not in adapter.baseline_nuisances(prepared, Drive.TICKS)
    # the ground truth's time alignment: half a row, but a capture latency on fast rows
    for log, half in ((common, 0.5 * common.dt), (fast, 0.5 * fast.dt)):
        lo, hi, _ = adapter.baseline_nuisances([_Prepared(log)], Drive.TICKS)[
            "timestamp_offset.offset"
        ]
        assert hi == -lo == pytest.approx(max(half, TRUTH_LATENCY_FLOOR))
    assert 0.5 * fast.dt < TRUTH_LATENCY_FLOOR < 0.5 * common.dt


class _Prepared:
    """The part of a prepared log the baseline's ranges read."""

    def __init__(self, log) -> None:
        self.log = log


def test_wheel_dead_zone_pivots_slow_turns_on_the_stuck_wheel() -> None:
    # 0.26 rad/s in place: both wheels commanded 0.03 m/s; the left one's threshold is 0.05
    nominal = run([(2.0, 0.0, 0.26)])
    stuck = run([(2.0, 0.0, 0.26)], ("wheel_dead_zone", {"dz_left": 0.05}))
    assert stuck["pose_gt"][-1, 2] / nominal["pose_gt"][-1, 2] == pytest.approx(0.5, rel=0.05)
    assert abs(stuck["ticks"][-1, 0]) < 5  # the left wheel never turned
    # the pivot moves the axle midpoint on a circle of radius b/2
    moved = np.hypot(*stuck["pose_gt"][-1, :2])
    assert moved == pytest.approx(
        2 * P.wheelbase / 2 * math.sin(stuck["pose_gt"][-1, 2] / 2), rel=0.1
    )
    assert np.hypot(*nominal["pose_gt"][-1, :2]) < 2e-3


def test_wheel_dead_zone_leaves_commands_above_its_thresholds_alone(straight) -> None:
    # a drive-gain ratio would be an exact alias of wheel_diameter_ratio + encoder_ratio: not here
    assert [s.name for s in EFFECTS["wheel_dead_zone"].specs] == ["dz_left", "dz_right"]
    fast = run([(2.0, 0.3, 0.0)], ("wheel_dead_zone", {"dz_left": 0.05, "dz_right": 0.02}))
    np.testing.assert_allclose(fast["pose_gt"], straight["pose_gt"], atol=1e-9)
    np.testing.assert_allclose(fast["ticks"], straight["ticks"])


def test_torque_speed_saturation_tops_out_below_the_commanded_speed() -> None:
    log = run([(3.0, 0.6, 0.0)], ("torque_speed_saturation", {"v_top": 0.35, "t_m": 0.1}))
    assert _speed(log, 30, 55) == pytest.approx(0.35, rel=0.03)
    # the approach to the top speed is the motors' first-order response, v_top (1 − e^{−t/t_m})
    nominal = run([(3.0, 0.6, 0.0)])
    assert log["pose_gt"][3, 0] < 0.8 * min(nominal["pose_gt"][3, 0], 0.35 * 3 * DT)
    # the bound reaches down to a crawl: saturation far below any commanded speed is representable
    spec = EFFECTS["torque_speed_saturation"].spec("v_top")
    assert spec.low <= 0.05 and spec.high >= P.v_max


def test_drive_train_effects_do_nothing_at_nominal(straight) -> None:
    for name in (
        "wheel_velocity_lag",
        "acceleration_limits",
        "wheel_dead_zone",
        "torque_speed_saturation",
        "traction_slip",
    ):
        assert make_effect(name).make_command_hook(DT, P) is None
        assert make_effect(name).make_wheel_hook(DT, P) is None
        log = run([(2.0, 0.3, 0.0)], (name, {}))
        np.testing.assert_allclose(log["pose_gt"], straight["pose_gt"], atol=1e-9)


def test_effects_expose_their_physical_bounds() -> None:
    bounds = EFFECTS["torque_speed_saturation"].physical_bounds()
    assert bounds == {"v_top": (0.05, 1.2), "t_m": (0.0, 0.5)}
    for cls in EFFECTS.values():
        for param, (lo, hi) in cls.physical_bounds().items():
            assert lo < hi and lo <= cls.spec(param).nominal <= hi


def test_traction_slip_lags_the_body_not_the_wheels(straight) -> None:
    log = run([(2.0, 0.3, 0.0), (1.5, 0.0, 0.0)], ("traction_slip", {"t_slip": 0.15}))
    nominal = run([(2.0, 0.3, 0.0), (1.5, 0.0, 0.0)])
    # the encoders count the wheels turning as commanded (after the first periods of the
    # start, in which the nominal motors spin the wheels up: about 2 mm of wheel travel)
    np.testing.assert_allclose(log["ticks"][10:41], nominal["ticks"][10:41], atol=40)
    # at constant speed the body runs v·dt·(1 − k)/k behind the wheels, and catches up after the stop
    behind = nominal["pose_gt"][38, 0] - log["pose_gt"][38, 0]
    assert behind == pytest.approx(0.3 * _settled_trail(0.15), rel=0.1)
    assert _speed(log, 30, 40) == pytest.approx(0.3, rel=0.02)
    assert log["pose_gt"][-1, 0] == pytest.approx(nominal["pose_gt"][-1, 0], abs=2e-3)
    np.testing.assert_allclose(log["ticks"][-1], nominal["ticks"][-1], rtol=5e-3)


def test_traction_slip_shows_in_and_replays_from_the_ticks() -> None:
    log = run([(2.0, 0.3, 0.0), (1.5, 0.0, 1.0)], ("traction_slip", {"t_slip": 0.15}))
    reality = Reality((make_effect("traction_slip", t_slip=0.15),))
    again = simulate(log.t, params=P, ticks=log["ticks"], reality=reality)
    plain = simulate(log.t, params=P, ticks=log["ticks"])
    err_slip = np.abs(again["pose_gt"][:, 0] - log["pose_gt"][:, 0]).max()
    err_plain = np.abs(plain["pose_gt"][:, 0] - log["pose_gt"][:, 0]).max()
    # a tick-driven replay sees the effect, and with it reproduces the run
    assert err_plain > 0.03 and err_slip < 0.2 * err_plain


def test_skipping_recursion_equals_the_step_by_step_one() -> None:
    from realitygap.robots.effects.diffdrive_drivetrain import (
        _lag,
        _recurse,
        speed_limiter_step,
        torque_speed_step,
    )

    rng = np.random.default_rng(1)
    x = np.repeat(rng.uniform(-0.6, 0.6, (7, 20)), 25, axis=1)
    up, down = rng.uniform(0.005, 0.05, (7, 1)), rng.uniform(0.005, 0.05, (7, 1))
    up[0] = down[0] = np.inf
    v_top, k = rng.uniform(0.1, 1.2, (7, 1)), rng.uniform(0.1, 1.0, (7, 1))

    def naive(step):
        y, prev = np.empty_like(x), np.zeros((7, 1))
        for i in range(x.shape[1]):
            prev = step(prev, x[:, i : i + 1])
            y[:, i : i + 1] = prev
        return y

    for step in (
        lambda y0, xk: speed_limiter_step(y0, xk, up, down),
        lambda y0, xk: torque_speed_step(y0, xk, v_top, k),
    ):
        np.testing.assert_array_equal(_recurse(x, step), naive(step))
    np.testing.assert_allclose(
        _lag(x, k[:, 0]), naive(lambda y0, xk: y0 + k * (xk - y0)), rtol=0, atol=1e-12
    )
    # the unlimited row follows its input exactly
    np.testing.assert_array_equal(
        _recurse(x, lambda y0, xk: speed_limiter_step(y0, xk, up, down))[0], x[0]
    )


def test_the_lag_recursion_is_the_same_for_shared_and_distinct_gains() -> None:
    from realitygap.robots.effects.diffdrive_drivetrain import _lag

    rng = np.random.default_rng(3)
    x = rng.normal(size=(6, 40))
    gains = np.array([0.3, 0.3, 0.7, 1.0, 0.3, 0.05])  # repeated, distinct and pass-through

    def by_hand(row: np.ndarray, k: float) -> np.ndarray:
        y, out = 0.0, []
        for v in row:
            y += k * (v - y)
            out.append(y)
        return np.array(out)

    expected = np.stack([by_hand(x[i], g) for i, g in enumerate(gains)])
    np.testing.assert_allclose(_lag(x, gains), expected, rtol=1e-12, atol=1e-12)
    # a batch that shares its gain is filtered alike, row by row
    np.testing.assert_array_equal(_lag(x, np.full(6, 0.3))[0], _lag(x[:1], np.array([0.3]))[0])


def test_a_reality_reads_any_iterable_once_and_puts_it_in_the_pipelines_order() -> None:
    from realitygap.robots.effects import pipeline_key

    names = ("wheelbase_error", "motor_response", "motor_deadband", "command_latency")
    reality = Reality(make_effect(n) for n in names)  # a generator: read once, nothing lost
    assert reality.effect_names == (
        "command_latency",
        "motor_deadband",
        "motor_response",
        "wheelbase_error",
    )
    keys = [pipeline_key(type(e)) for e in reality.effects]
    assert keys == sorted(keys)
    with pytest.raises(TypeError, match="must hold Effect objects"):
        Reality((make_effect("wheelbase_error"), "motor_response"))
