"""Named variants of the independent generator: files the importers read back with the
variant's own geometry, rates and ramp; closed forms per variant; names checked; determinism."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from realitygap.independent import diffdrive as dd
from realitygap.independent import ur10
from realitygap.independent.cases import case_by_name
from realitygap.independent.variants import (
    SPEED_FIELDS,
    VARIANTS,
    hidden_values,
    variant_by_name,
)

NAMES = tuple(VARIANTS)


def _quiet(robot: dd.DriveRobot) -> dd.DriveRobot:
    return replace(robot, mocap_pos_sigma=0.0, mocap_yaw_sigma=0.0)


def _straight(robot: dd.DriveRobot, seconds: float) -> list[tuple[str, float, float, float]]:
    return [("time", seconds, robot.v_nom, 0.0), ("wait", 1.0, 0.0, 0.0)]


def test_the_variants_differ_in_what_they_claim_and_default_is_todays_world() -> None:
    assert set(NAMES) >= {"default", "large", "fast_noisy"}
    d = VARIANTS["default"]
    assert d.drive == dd.DriveRobot() and d.tracker == ur10.Tracker()
    np.testing.assert_array_equal(d.probe, ur10.PROBE)
    assert (d.square_side, d.circle_radius) == (0.6, 0.45)
    large, fast = VARIANTS["large"].drive, VARIANTS["fast_noisy"].drive
    assert large.diameter > 1.5 * d.drive.diameter and large.wheelbase > 1.5 * d.drive.wheelbase
    assert large.m_per_tick > 2 * d.drive.m_per_tick  # a coarser encoder
    assert large.cycle != d.drive.cycle and large.ramp == "body"
    assert fast.cycle != d.drive.cycle and fast.mocap_rate != d.drive.mocap_rate
    assert fast.mocap_latency != d.drive.mocap_latency
    assert fast.mocap_pos_sigma == pytest.approx(3 * d.drive.mocap_pos_sigma)
    # the same robot restated per cycle: the same speeds and accelerations in SI units
    assert fast.cruise_speed == pytest.approx(d.drive.cruise_speed, rel=1e-9)
    a = [r.dv_max * r.m_per_tick / r.cycle**2 for r in (fast, d.drive)]
    assert a[0] == pytest.approx(a[1], rel=5e-3)


@pytest.mark.parametrize("name", NAMES)
def test_each_variant_is_read_back_with_its_geometry_rate_and_ramp(
    name: str, tmp_path: Path
) -> None:
    from realitygap.diagnosis.logs.read import ReadOptions, read_logs

    robot = VARIANTS[name].drive
    rng = np.random.default_rng(4)
    run = dd.simulate_run(_straight(robot, 8.0), robot, dd.Hidden(), rng)
    folder = dd.write_session(tmp_path, "010320240900", [run], robot, "free", rng=rng)
    (log,) = read_logs(folder, ReadOptions(check_plausible=False))
    p = log.meta["params"]
    assert p["wheelbase"] == robot.wheelbase
    assert p["wheel_radius_left"] == p["wheel_radius_right"] == robot.diameter / 2
    assert p["ticks_per_rev"] == pytest.approx(robot.ticks_per_rev)
    assert float(np.median(np.diff(log.t))) == pytest.approx(robot.cycle, rel=1e-9)
    assert log.meta["command_alignment"] == "exact"
    assert float(np.max(log.channels["cmd"][:, 0])) == pytest.approx(robot.cruise_speed)
    fw = log.meta["firmware"]
    assert fw["a_max"] == pytest.approx(robot.dv_max * robot.m_per_tick / robot.cycle**2)
    assert fw["alpha_max"] == pytest.approx(robot.dw_max / robot.cycle**2, rel=1e-5)
    # at cruise each wheel counts the request per cycle (no effect planted)
    inc = np.diff(log.channels["ticks"][:, 0])
    assert np.max(inc) == pytest.approx(robot.v_nom, abs=1.0)


@pytest.mark.parametrize("name", NAMES)
def test_motion_capture_rows_hold_the_last_sample_of_its_rate_phase_and_latency(
    name: str,
) -> None:
    """At a steady straight speed u the truth leads the held sample by u · (age of the sample)."""
    robot = _quiet(VARIANTS[name].drive)
    run = dd.simulate_run(_straight(robot, 12.0), robot, dd.Hidden(), np.random.default_rng(0))
    k = np.flatnonzero((run.time > 8.0) & (run.time < 11.0))
    speed = np.diff(run.truth[:, 0]) / robot.cycle
    u = float(np.median(speed[k]))
    assert np.all(np.abs(speed[k] - u) < 1e-3 * u)
    period = 1.0 / robot.mocap_rate
    # the most recent sample stamped at or before the row: taken at s = phase + j·period
    j = np.floor((run.time[k] - robot.mocap_latency - robot.mocap_phase) / period + 1e-9)
    age = run.time[k] - (robot.mocap_phase + j * period)
    lead = run.truth[k, 0] - run.gt[k, 0]
    # the sample is the pose at the end of the integration step that reaches its time
    np.testing.assert_allclose(lead, u * age, atol=u * robot.substep * 1.01)


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_planted_wheelbase_turns_each_variants_square_by_the_closed_form(name: str) -> None:
    v = VARIANTS[name]
    robot = _quiet(v.drive)
    path = dd.square_path(robot, v.square_side, "ccw")
    run = dd.simulate_run(path, robot, dd.Hidden(b_true=1.04), np.random.default_rng(0))
    assert run.truth[-1, 2] == pytest.approx(run.odo[-1, 2] / 1.04, rel=3e-3)
    # four quarter turns on the odometry, each ended by the planner within 0.1 rad
    assert run.odo[-1, 2] == pytest.approx(2 * math.pi, abs=0.4)


def test_a_body_ramp_limits_the_turn_rate_by_its_own_angular_limit() -> None:
    """A turn in place under a body ramp reaches its rate no sooner than rate / DWMAX cycles."""
    base = _quiet(VARIANTS["large"].drive)
    slow = replace(base, angular_ramp=base.angular_ramp / 4)
    seconds = 1.5 * base.w_nom / slow.angular_ramp * base.cycle
    seg = [("time", seconds, 0.0, base.w_nom), ("wait", 0.5, 0.0, 0.0)]

    def rise(robot: dd.DriveRobot) -> float:
        run = dd.simulate_run(seg, robot, dd.Hidden(), np.random.default_rng(0))
        reached = np.diff(run.truth[:, 2]) / robot.cycle > 0.9 * robot.w_nom / robot.cycle
        assert reached.any()
        return float(run.time[np.argmax(reached)])

    fast_rise, slow_rise = rise(base), rise(slow)
    assert fast_rise >= 0.9 * base.w_nom / base.angular_ramp * base.cycle
    assert slow_rise >= 0.9 * base.w_nom / slow.angular_ramp * base.cycle
    assert slow_rise > 2.5 * fast_rise


@pytest.mark.parametrize("name", NAMES)
def test_each_variants_arm_files_give_the_tool_distances_of_the_closed_form(
    name: str, tmp_path: Path
) -> None:
    from realitygap.diagnosis.logs.read import read_logs

    v = VARIANTS[name]
    tracker = replace(v.tracker, sigma=0.0)
    q = ur10.random_poses(6, np.random.default_rng(1))
    s = ur10.measure_series(q, ur10.ArmHidden(), tracker, np.random.default_rng(2), probe=v.probe)
    (log,) = read_logs(ur10.write_series(tmp_path, "A", s, probe=v.probe))
    np.testing.assert_allclose(log.meta["tool"], v.probe, atol=1e-9)
    np.testing.assert_allclose(log.channels["joints"], q, atol=1e-12)
    # distances between tool points do not depend on where the tracker stands
    base = np.array([(ur10.forward(qi)[-1] @ np.append(v.probe, 1.0))[:3] for qi in q])
    pos = log.channels["tool_pos"]
    for i, j in ((0, 1), (2, 5), (3, 4)):
        assert np.linalg.norm(pos[i] - pos[j]) == pytest.approx(
            np.linalg.norm(base[i] - base[j]), abs=1e-8
        )


def test_speed_values_scale_with_the_cruise_and_nothing_else_does() -> None:
    cap = case_by_name("speed_cap").values
    assert hidden_values(cap, VARIANTS["default"]) == cap
    ratio = VARIANTS["large"].drive.cruise_speed / VARIANTS["default"].drive.cruise_speed
    assert hidden_values(cap, VARIANTS["large"])["speed_cap"] == pytest.approx(
        cap["speed_cap"] * ratio
    )
    for name in ("driver_delay", "wheelbase_plus3", "caster_drag", "marker_offset"):
        values = case_by_name(name).values
        assert not set(values) & set(SPEED_FIELDS)
        assert hidden_values(values, VARIANTS["large"]) == values
    assert hidden_values({"speed_cap": math.inf}, VARIANTS["large"]) == {"speed_cap": math.inf}


def test_an_unknown_variant_is_refused_with_the_names() -> None:
    with pytest.raises(ValueError, match=r"variant must be one of default, large, fast_noisy"):
        variant_by_name("huge")
    from realitygap import cli

    assert cli.main(["run", "diagnose-independent", "--variant", "huge", "--silent"]) == 2
    assert cli.main(["run", "nav8", "--variant", "large", "--silent"]) == 2


def test_cli_error_names_the_known_variants(capsys: pytest.CaptureFixture[str]) -> None:
    from realitygap import cli

    assert cli.main(["run", "diagnose-independent", "--variant", "huge"]) == 2
    err = capsys.readouterr().err
    assert "one of default, large, fast_noisy" in err and "'huge'" in err


def test_bad_conventions_are_refused_with_the_field_named() -> None:
    with pytest.raises(ValueError, match=r"DriveRobot\.ramp must be 'wheels' or 'body'"):
        dd.DriveRobot(ramp="twist")
    with pytest.raises(ValueError, match=r"DriveRobot\.angular_ramp is a limit > 0"):
        dd.DriveRobot(angular_ramp=0.01)
    with pytest.raises(ValueError, match=r"DriveRobot\.mocap_phase must lie in \[0, 1/mocap_rate"):
        dd.DriveRobot(mocap_phase=0.02)
    with pytest.raises(ValueError, match=r"DriveRobot\.mocap_rate must be > 0"):
        dd.DriveRobot(mocap_rate=0.0)
    with pytest.raises(ValueError, match=r"Tracker\.sigma is a laser tracker's noise"):
        ur10.Tracker(sigma=0.01)
    with pytest.raises(ValueError, match=r"probe must be a point \(3,\)"):
        ur10.measure_series(
            np.zeros((1, 6)),
            ur10.ArmHidden(),
            ur10.Tracker(),
            np.random.default_rng(0),
            probe=(0.0, 0.1),
        )


@pytest.mark.slow
@pytest.mark.parametrize("name", ("large", "fast_noisy"))
def test_a_case_on_a_variant_is_the_same_files_for_the_same_seed(name: str, tmp_path: Path) -> None:
    from realitygap.experiments.independent import generate_case

    def files(seed: int, where: str) -> dict[str, bytes]:
        root = tmp_path / where
        root.mkdir()
        generate_case(case_by_name("stiction"), root, seed, name)
        return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}

    a, b, c = files(3, "a"), files(3, "b"), files(4, "c")
    assert a == b
    assert a.keys() == c.keys() and a != c


def test_a_log_the_plausibility_check_refuses_is_kept_and_the_refusal_recorded(
    tmp_path: Path,
) -> None:
    """A session whose header states a quarter of the encoder's resolution (quadrature edges
    read as single counts) is refused by the check; the experiment keeps it and says so. A
    fast capture with three times the noise is not refused: its path is not lengthened by it."""
    from realitygap.experiments.independent import _read

    robot = VARIANTS["fast_noisy"].drive
    rng = np.random.default_rng(0)
    # the same drive in m/s, counted at four times the stated resolution
    counted = replace(
        robot, enc_res=4.0 * robot.enc_res, v_nom=4.0 * robot.v_nom, dv_max=4.0 * robot.dv_max
    )
    run = dd.simulate_run(_straight(counted, 6.0), counted, dd.Hidden(), rng)
    folder = dd.write_session(tmp_path, "010320240900", [run], robot, "free", rng=rng)
    refused: list[str] = []
    (log,) = _read(folder, refused)
    assert log.channels["ticks"].shape[0] == run.time.shape[0]
    assert len(refused) == 1 and "the wheels travelled 4" in refused[0]
    noisy = dd.simulate_run(_straight(robot, 6.0), robot, dd.Hidden(), rng)
    ok: list[str] = []
    _read(dd.write_session(tmp_path / "q", "010320240900", [noisy], robot, "free", rng=rng), ok)
    assert ok == []
