"""Per-log clock alignment: each recording's own offset is a nuisance, a common one a finding."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.adapters.diffdrive.manoeuvres import Manoeuvre
from realitygap.diagnosis.adapters.diffdrive.replay import simulate
from realitygap.diagnosis.diagnose import Diagnosis, DiagnosisSettings, diagnose
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.problem import AttributionSettings
from realitygap.diagnosis.stages.clock import ClockSettings, restamp, timing_channel
from realitygap.diagnosis.verdict.types import VerdictKind
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import Reality, make_effect
from realitygap.robots.simulation import MeasurementNoise

P = DiffDriveParams()
NOISE = MeasurementNoise(truth_xy=0.0005, truth_theta=0.001, camera_xy=0.001, camera_theta=0.002)
# stop-and-go: speed and turn rate change often, so that each log's clock shows
SQUARE = Manoeuvre(
    "square",
    "straight legs and quarter turns in place, stopping in between",
    tuple(
        leg
        for _ in range(4)
        for leg in ((2.5, 0.3, 0.0), (0.5, 0.0, 0.0), (1.6, 0.0, 1.0), (0.5, 0.0, 0.0))
    ),
)
ARCS = Manoeuvre(
    "arcs",
    "arcs both ways, turns in place",
    ((2.5, 0.3, 0.7), (0.5, 0, 0), (2.5, 0.3, -0.7), (1.5, 0.0, 1.0), (1.5, 0.0, -1.0)),
)
FAST = AttributionSettings(pair_candidates=2, verify_top=1)
LIBRARY = ("wheelbase_error", "wheel_diameter_ratio", "wheel_radius_scale", "timestamp_offset")
TRAIN_OFFSETS = (0.03, -0.03, 0.02, -0.025)
HELD_OFFSETS = (-0.03, 0.03)


def _line(n: int = 41, dt: float = 0.05) -> Log:
    t = dt * np.arange(n)
    theta = np.angle(np.exp(1j * (3.0 + 0.5 * t)))  # wraps through ±π
    pose = np.column_stack([0.2 * t, np.zeros(n), theta])
    ticks = np.column_stack([10.0 * np.arange(n), 12.0 * np.arange(n)])
    return Log(t=t, channels={"pose_gt": pose, "ticks": ticks}, meta={"name": "line"})


def test_restamp_evaluates_the_channel_later_and_keeps_its_angle_convention() -> None:
    log = _line()
    moved = restamp(log, "pose_gt", 0.02)
    inner = slice(1, -1)
    np.testing.assert_allclose(moved["pose_gt"][inner, 0], log["pose_gt"][inner, 0] + 0.2 * 0.02)
    dtheta = np.angle(np.exp(1j * (moved["pose_gt"][:, 2] - log["pose_gt"][:, 2])))
    np.testing.assert_allclose(dtheta[inner], 0.5 * 0.02, atol=1e-12)
    # wrapped stays wrapped: no sample leaves (−π, π]
    assert np.all(np.abs(moved["pose_gt"][:, 2]) <= np.pi + 1e-12)
    np.testing.assert_array_equal(moved["ticks"], log["ticks"])
    assert restamp(log, "pose_gt", 0.0) is log
    with pytest.raises(ValueError, match="no channel 'pose_cam'"):
        restamp(log, "pose_cam", 0.01)
    with pytest.raises(ValueError, match="finite number of seconds"):
        restamp(log, "pose_gt", float("nan"))


def test_restamp_undoes_a_planted_ground_truth_offset() -> None:
    t, cmd = ARCS.applied(0.05, P)
    late = Reality((make_effect("timestamp_offset", offset=0.03),))
    stamped_late = simulate(t, params=P, reality=late, commands=cmd)
    on_time = simulate(t, params=P, reality=None, commands=cmd)
    err_before = np.abs(stamped_late["pose_gt"] - on_time["pose_gt"])[5:-5].max()
    err_after = np.abs(restamp(stamped_late, "pose_gt", 0.03)["pose_gt"] - on_time["pose_gt"])
    assert err_after[5:-5].max() < 0.15 * err_before  # linear interpolation between samples


def test_timing_channel_is_read_from_the_effect() -> None:
    assert timing_channel("timestamp_offset.offset") == "pose_gt"
    assert timing_channel("wheelbase_error.E_b") is None


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"bound": 0.0}, r"ClockSettings\.bound: expected a positive"),
        ({"step": float("inf")}, r"ClockSettings\.step: expected a positive"),
        ({"bound": 0.002, "step": 0.002}, r"step \(0\.002 s\) must be below bound"),
    ],
)
def test_clock_settings_are_checked(kwargs: dict[str, float], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ClockSettings(**kwargs)


def _record(man: Manoeuvre, effects: tuple, offset: float, rng: np.random.Generator) -> Log:
    t, cmd = man.applied(0.05, P)
    reality = Reality((*effects, make_effect("timestamp_offset", offset=offset)))
    log = simulate(
        t, params=P, reality=reality, commands=cmd, noise=NOISE, rng=rng, meta={"name": man.name}
    )
    return log.without("pose_cam", "pose_est")  # what a motion-capture bench records


def _diagnose(
    effects: tuple, common: float, seed: int, clock: ClockSettings | None
) -> tuple[Diagnosis, list[float]]:
    rng = np.random.default_rng(seed)
    mans = (SQUARE, SQUARE, ARCS, SQUARE)
    train = [_record(m, effects, common + o, rng) for m, o in zip(mans, TRAIN_OFFSETS)]
    held = [_record(m, effects, common + o, rng) for m, o in zip((ARCS, SQUARE), HELD_OFFSETS)]
    settings = DiagnosisSettings(drive="ticks", effects=LIBRARY, attribution=FAST, clock=clock)
    return diagnose(train, held, settings=settings), [*TRAIN_OFFSETS, *HELD_OFFSETS]


@pytest.fixture(scope="module")
def geometry_with_clocks() -> tuple[Diagnosis, list[float]]:
    effects = (
        make_effect("wheelbase_error", E_b=1.03),
        make_effect("wheel_diameter_ratio", E_d=1.01),
    )
    return _diagnose(effects, 0.0, seed=21, clock=ClockSettings())


@pytest.mark.slow
def test_per_log_offsets_are_recovered_relative_to_the_common_one(
    geometry_with_clocks: tuple[Diagnosis, list[float]],
) -> None:
    d, planted = geometry_with_clocks
    rows = d.baseline.clock.rows
    assert [r["log"] for r in rows] == [p.name for p in d.prepared]
    fitted = np.array([r["offset_s"] for r in rows])
    # offsets agree up to a common shift (the replay's own stamp convention)
    shift = np.median(fitted - np.asarray(planted))
    np.testing.assert_allclose(fitted - shift, planted, atol=0.006)
    assert all(r["applied"] for r in rows if abs(r["deviation_s"]) > 0.01)
    js = d.to_json()["baseline_calibration"]["clock_alignment"]
    assert js["channel"] == "pose_gt" and len(js["logs"]) == len(planted)
    assert "per-log clock alignment of pose_gt" in d.baseline.summary()


def test_geometry_is_named_and_recovered_once_the_clocks_are_aligned(
    geometry_with_clocks: tuple[Diagnosis, list[float]],
) -> None:
    d, _ = geometry_with_clocks
    assert d.verdict.kind is VerdictKind.EFFECTS, d.verdict.reason
    assert "wheelbase_error" in d.verdict.effects
    fit = d.chosen
    assert fit is not None
    assert fit.values["wheelbase_error.E_b"] == pytest.approx(1.03, abs=0.006)
    if "wheel_diameter_ratio" in fit.effects:
        assert fit.values["wheel_diameter_ratio.E_d"] == pytest.approx(1.01, abs=0.004)


@pytest.mark.slow
def test_a_common_latency_is_still_named_beside_per_log_offsets() -> None:
    d, _ = _diagnose((), 0.12, seed=4, clock=ClockSettings())
    # the common part is not a per-log nuisance: it stays an effect of the verdict
    common = d.baseline.clock.common
    assert common == pytest.approx(0.12, abs=0.015)
    assert abs(np.median([r["deviation_s"] for r in d.baseline.clock.rows])) < 1e-9
    assert d.verdict.effects == ("timestamp_offset",), d.verdict.reason
    assert d.chosen is not None
    assert d.chosen.values["timestamp_offset.offset"] == pytest.approx(common, abs=0.003)
    assert f"{len(d.baseline.clock.rows)} of {len(d.baseline.clock.rows)} logs re-stamped" in (
        d.baseline.summary()
    )


@pytest.mark.slow
def test_logs_that_differ_only_by_their_clocks_and_noise_name_no_effect() -> None:
    d, _ = _diagnose((), 0.0, seed=8, clock=ClockSettings())
    assert d.verdict.kind is not VerdictKind.EFFECTS, d.verdict.reason


def _independent_sessions(root: Path, seed: int) -> None:
    """UMBmark squares and held-out circles of one robot with E_b, E_d and per-run clock skews
    (the package's independent generator)."""
    import realitygap.independent.diffdrive as dd

    rng = np.random.default_rng(seed)
    robot = dd.DriveRobot()
    hidden = {"b_true": 1.012, "d_right": 1.003, "d_left": 0.997}
    squares = [
        dd.simulate_run(
            dd.square_path(robot, 1.0, d), robot, dd.Hidden(clock_skew=s, **hidden), rng
        )
        for d, s in zip(("cw", "ccw", "cw", "ccw"), TRAIN_OFFSETS)
    ]
    dd.write_session(root, "010320241010", squares, robot, "square", side=1.0, rng=rng)
    circles = [
        dd.simulate_run(dd.circle_path(robot, r, d), robot, dd.Hidden(clock_skew=s, **hidden), rng)
        for r, d, s in zip((0.5, 0.4), ("cw", "ccw"), HELD_OFFSETS)
    ]
    dd.write_session(root, "010320241220", circles, robot, "circular", rng=rng)


@pytest.mark.slow
def test_independent_generator_geometry_with_clock_skews(tmp_path: Path) -> None:
    from realitygap.diagnosis.logs.read import logs_from_optiodom

    _independent_sessions(tmp_path, seed=5)
    logs = logs_from_optiodom(tmp_path)
    train = [lg for lg in logs if lg.meta.get("path_type") == "square"]
    held = [lg for lg in logs if lg.meta.get("path_type") != "square"]
    d = diagnose(train, held, settings=DiagnosisSettings(drive="ticks", effects=LIBRARY))
    fitted = np.array([r["offset_s"] for r in d.baseline.clock.rows])
    planted = np.array([*TRAIN_OFFSETS, *HELD_OFFSETS])
    shift = np.median(fitted - planted)
    np.testing.assert_allclose(fitted - shift, planted, atol=0.012)
    assert d.verdict.kind is VerdictKind.EFFECTS, d.verdict.reason
    fit = d.chosen
    assert fit is not None and "wheelbase_error" in fit.effects
    e_b = fit.values["wheelbase_error.E_b"] / fit.values.get("wheel_radius_scale.scale", 1.0)
    assert e_b == pytest.approx(1.012, abs=0.003)
    if "wheel_diameter_ratio" in fit.effects:
        assert fit.values["wheel_diameter_ratio.E_d"] == pytest.approx(1.003 / 0.997, abs=0.003)
