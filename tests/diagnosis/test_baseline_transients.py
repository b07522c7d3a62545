"""Calibrated baseline, transient events, robust fit and the library's input checks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from realitygap.diagnosis.adapters.diffdrive.manoeuvres import Manoeuvre
from realitygap.diagnosis.adapters.diffdrive.replay import simulate
from realitygap.diagnosis.diagnose import Diagnosis, DiagnosisSettings, diagnose
from realitygap.diagnosis.fit.model import _rho
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.diagnosis.problem.problem import AttributionSettings
from realitygap.diagnosis.report.writer import write_report
from realitygap.diagnosis.stages.transients import TransientSettings
from realitygap.diagnosis.verdict.types import VerdictKind
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import EFFECTS, Reality, make_effect
from realitygap.robots.effects.base import ParamSpec
from realitygap.robots.simulation import MeasurementNoise

P = DiffDriveParams()
NOISE = MeasurementNoise(truth_xy=0.0005, truth_theta=0.001, camera_xy=0.001, camera_theta=0.002)
LOOP = Manoeuvre(
    "loop",
    "straight legs and turns in place both ways",
    (
        (3.0, 0.3, 0.0),
        (1.5, 0.0, 1.0),
        (3.0, 0.25, 0.0),
        (1.5, 0.0, -1.0),
        (3.0, 0.4, 0.0),
        (1.0, 0.3, 0.6),
        (3.0, 0.3, 0.0),
        (0.5, 0, 0),
    ),
)
ARCS = Manoeuvre(
    "arcs",
    "arcs both ways, turns in place",
    ((2.5, 0.3, 0.7), (0.5, 0, 0), (2.5, 0.3, -0.7), (1.5, 0.0, 1.0), (1.5, 0.0, -1.0)),
)
FAST = AttributionSettings(pair_candidates=2, verify_top=1)
LIBRARY = ("wheelbase_error", "wheel_diameter_ratio", "wheel_radius_scale", "timestamp_offset")


def record(man: Manoeuvre, reality: Reality, rng: np.random.Generator) -> Log:
    t, cmd = man.applied(0.05, P)
    return simulate(
        t, params=P, reality=reality, commands=cmd, noise=NOISE, rng=rng, meta={"name": man.name}
    )


def stall(log: Log, t0: float, t1: float) -> Log:
    """The body stops between t0 and t1 (wedged, lifted) while the wheels keep turning; the
    rest of the run continues rigidly from where the body stopped (camera and estimate
    channels dropped)."""
    gt = np.array(log["pose_gt"], dtype=float)
    a, b = (int(i) for i in np.searchsorted(log.t, [t0, t1]))
    dth = gt[a, 2] - gt[b, 2]
    c, s = np.cos(dth), np.sin(dth)
    rel = gt[b:, :2] - gt[b, :2]
    gt[b:, :2] = gt[a, :2] + rel @ np.array([[c, s], [-s, c]])
    gt[b:, 2] += dth
    gt[a:b] = gt[a]
    return log.without("pose_cam", "pose_est").with_channels(pose_gt=gt)


# --------------------------------------------------------------------------- input checks
def test_duplicate_effect_names_are_refused() -> None:
    rng = np.random.default_rng(0)
    lg = record(LOOP, Reality(()), rng)
    with pytest.raises(ValueError, match="'wheelbase_error' more than once"):
        diagnose([lg], settings=DiagnosisSettings(effects=("wheelbase_error", "wheelbase_error")))


def test_bounds_with_low_not_below_high_are_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    bad = (ParamSpec("E_b", "1", 1.0, 1.1, 0.9, "inverted bounds"),)
    monkeypatch.setattr(EFFECTS["wheelbase_error"], "specs", bad)
    lg = record(LOOP, Reality(()), np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"effect 'wheelbase_error'.*low=1\.1 ≥ high=0\.9"):
        diagnose([lg], settings=DiagnosisSettings(effects=("wheelbase_error",)))


def test_settings_are_checked() -> None:
    with pytest.raises(ValueError, match=r"AttributionSettings\.loss"):
        AttributionSettings(loss="l3")
    with pytest.raises(ValueError, match=r"TransientSettings\.stall_ratio"):
        TransientSettings(stall_ratio=1.5)


# --------------------------------------------------------------------------- robust loss
@pytest.mark.parametrize("loss", ["soft_l1", "cauchy", "huber", "arctan", "linear"])
def test_rho_is_scipys_loss(loss: str) -> None:
    r = np.array([0.1, -0.5, 2.0, 7.0, -30.0])
    c = 1.7
    res = least_squares(lambda x: r + 0.0 * x, np.zeros(1), loss=loss, f_scale=c, max_nfev=1)
    assert res.cost == pytest.approx(0.5 * float(np.sum(_rho(r**2, loss, c))), rel=1e-9)


# --------------------------------------------------------------------------- transients
@pytest.fixture(scope="module")
def stalled() -> Diagnosis:
    rng = np.random.default_rng(3)
    reality = Reality((make_effect("wheelbase_error", E_b=1.04),))
    arcs = record(ARCS, reality, rng).without("pose_cam", "pose_est")
    train = [stall(record(LOOP, reality, rng), 7.2, 8.4), arcs]
    hold = [stall(record(LOOP, reality, rng), 3.1, 4.0)]
    return diagnose(train, hold, settings=DiagnosisSettings(effects=LIBRARY, attribution=FAST))


@pytest.mark.slow
def test_stall_is_set_aside_and_the_planted_wheelbase_recovered(stalled: Diagnosis) -> None:
    d = stalled
    tr = d.transients
    kinds = {e.kind for e in tr.events if e.excluded}
    assert kinds == {"ground truth frozen"} or kinds <= {"ground truth frozen", "stall or slip"}
    excluded = [e for e in tr.events if e.excluded]
    # the stalls are found where they were planted, in the runs they were planted in
    assert {(e.log_index, e.windows[0]) for e in excluded} >= {(0, 7), (2, 3)}
    assert 0 < tr.n_excluded <= 6
    assert tr.share_excluded == pytest.approx(tr.n_excluded / tr.n_windows)
    js = d.to_json()["transients"]
    assert js["n_excluded"] == tr.n_excluded and js["events"][0]["run"] in ("loop", "arcs")
    assert d.verdict.label == ["wheelbase_error"]
    top = d.ranking_rows()[0]
    assert top["params"]["wheelbase_error.E_b"]["value"] == pytest.approx(1.04, abs=0.004)


def test_report_states_baseline_and_transients(
    stalled: Diagnosis, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import builtins

    real_import = builtins.__import__

    def no_matplotlib(name: str, *args: object, **kwargs: object) -> object:
        if name.startswith("matplotlib"):
            raise ImportError("no matplotlib here")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    text = write_report(stalled, tmp_path).read_text()
    assert "## Baseline calibration" in text and "## Transient events" in text
    n, m = stalled.transients.n_excluded, stalled.transients.n_windows
    assert f"{n} of {m} windows" in text
    assert "| loop | 7.0–" in text and "ground truth frozen" in text
    assert "matplotlib is not installed" in text


def test_transient_detector_is_off_without_settings() -> None:
    rng = np.random.default_rng(3)
    reality = Reality((make_effect("wheelbase_error", E_b=1.04),))
    train = [stall(record(LOOP, reality, rng), 7.2, 8.4)]
    s = DiagnosisSettings(effects=("wheelbase_error",), attribution=FAST, transients=None)
    d = diagnose(train, settings=s)
    assert d.transients.n_excluded == 0 and not d.transients.events


def test_robot_held_in_the_air_has_not_enough_clean_data() -> None:
    rng = np.random.default_rng(4)
    lg = record(LOOP, Reality(()), rng)
    gt = np.array(lg["pose_gt"], dtype=float)
    held = lg.with_channels(pose_gt=gt[0] + 1e-4 * rng.standard_normal(gt.shape))
    ok = record(ARCS, Reality(()), rng)
    with pytest.raises(LogError, match=r"not enough clean data in loop: .* stall or slip"):
        diagnose([ok], [held], settings=DiagnosisSettings(effects=LIBRARY, attribution=FAST))
    frozen = lg.with_channels(pose_gt=np.repeat(gt[:1], gt.shape[0], axis=0))
    with pytest.raises(LogError, match=r"not enough clean data in loop: .*ground truth frozen"):
        diagnose([ok], [frozen], settings=DiagnosisSettings(effects=LIBRARY, attribution=FAST))


# --------------------------------------------------------------------------- baseline
@pytest.mark.slow
def test_the_ground_truths_body_frame_goes_to_the_baseline_and_the_drift_is_named() -> None:
    rng = np.random.default_rng(6)
    frame = {"x": 0.012, "y": -0.008, "yaw": 0.02}
    reality = Reality(
        (make_effect("wheelbase_error", E_b=1.04), make_effect("truth_frame_offset", **frame))
    )
    train = [record(LOOP, reality, rng), record(ARCS, reality, rng)]
    hold = [record(LOOP, reality, rng)]
    d = diagnose(train, hold, settings=DiagnosisSettings(effects=LIBRARY, attribution=FAST))
    for k, v in frame.items():
        assert d.baseline.values[f"truth_frame_offset.{k}"] == pytest.approx(v, abs=2e-3), k
    assert d.verdict.label == ["wheelbase_error"], d.verdict.reason
    assert d.chosen is not None
    assert d.chosen.values["wheelbase_error.E_b"] == pytest.approx(1.04, abs=0.004)
    # a frame offset beyond the convention's range is not absorbed: it is left as a gap
    far = Reality((make_effect("truth_frame_offset", x=0.06, y=0.0, yaw=0.0),))
    d = diagnose(
        [record(LOOP, far, rng), record(ARCS, far, rng)],
        [record(LOOP, far, rng)],
        settings=DiagnosisSettings(effects=LIBRARY, attribution=FAST),
    )
    assert d.baseline.values["truth_frame_offset.x"] == pytest.approx(0.02, abs=1e-6)
    assert d.verdict.kind is not VerdictKind.NONE


def _jittered(man: Manoeuvre, rng: np.random.Generator, sigma: float = 0.015) -> Log:
    """A robot whose wheels wander around their commands (AR(1), 0.2 s, ``sigma`` m/s per
    wheel: torque ripple, a wheel breaking away sooner or later); the log keeps the clean
    commands and the encoders count what the wheels did."""
    t, cmd = man.applied(0.05, P)
    a = np.exp(-0.05 / 0.2)
    n = np.zeros((t.size, 2))
    for k in range(1, t.size):
        n[k] = a * n[k - 1] + np.sqrt(1 - a * a) * sigma * rng.normal(size=2)
    moving = (np.abs(cmd[:, 0]) + np.abs(cmd[:, 1]) > 0)[:, None]
    n *= moving  # a robot at rest stays at rest
    done = cmd + np.column_stack([n.mean(axis=1), (n[:, 1] - n[:, 0]) / P.wheelbase])
    log = simulate(t, params=P, commands=done, noise=NOISE, rng=rng, meta={"name": man.name})
    return log.without("pose_cam", "pose_est").with_channels(cmd=cmd)


@pytest.mark.slow
def test_a_drive_train_that_scatters_from_window_to_window_is_noise_not_a_gap(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # no effect: the wheels only wander around their commands, as the encoders show, so
    # the command replay's heading residual is noise no fixed effect could close
    rng = np.random.default_rng(12)
    train = [_jittered(LOOP, rng), _jittered(ARCS, rng)]
    hold = [_jittered(LOOP, rng), _jittered(ARCS, rng)]
    d = diagnose(train, hold, settings=DiagnosisSettings(effects=LIBRARY, attribution=FAST))
    pr = d.problem
    with_drive = pr.adapter.sample_noise_levels(pr.logs, pr.features)
    # the budget's noise floor holds the drive's scatter: nothing named, no gap beyond it
    assert d.budget is not None and not d.budget.named
    assert not d.budget.structured_baseline and d.verdict.kind is VerdictKind.NONE
    # the motion capture's own noise alone would be a floor far below that scatter
    monkeypatch.setattr(type(pr.adapter), "wheel_motion", lambda self, p: None)
    truth_only = pr.adapter.sample_noise_levels(pr.logs, pr.features)
    assert with_drive["pose_gt"]["dtheta"] > 2.0 * truth_only["pose_gt"]["dtheta"]
    # only a scatter the ground truth confirms counts: against a truth said to be far
    # quieter than the encoders' disagreement with it, none is added
    monkeypatch.undo()
    assert pr.adapter._drive_scatter(pr.logs, np.full(3, 1.0)) is not None
    assert pr.adapter._drive_scatter(pr.logs, np.full(3, 1e-9)) is None


@pytest.mark.slow
def test_sub_sample_time_alignment_goes_to_the_baseline_not_the_findings() -> None:
    rng = np.random.default_rng(5)
    reality = Reality(
        (make_effect("wheelbase_error", E_b=1.04), make_effect("timestamp_offset", offset=0.015))
    )
    train = [record(LOOP, reality, rng), record(ARCS, reality, rng)]
    hold = [record(LOOP, reality, rng)]
    d = diagnose(train, hold, settings=DiagnosisSettings(effects=LIBRARY, attribution=FAST))
    assert d.baseline.values["timestamp_offset.offset"] == pytest.approx(0.015, abs=0.006)
    # no command_latency candidate; the ground truth's body frame and the drive's common
    # velocity-loop lag are always nuisances, and here (none planted) they stay at none
    frame = ("truth_frame_offset.x", "truth_frame_offset.y", "truth_frame_offset.yaw")
    assert set(d.baseline.values) == {"timestamp_offset.offset", "motor_response.tau", *frame}
    assert all(abs(d.baseline.values[k]) < 2e-3 for k in frame), d.baseline.values
    assert d.baseline.values["motor_response.tau"] < 0.01, d.baseline.values
    assert d.verdict.label == ["wheelbase_error"]
    js = d.to_json()
    rows = js["baseline_calibration"]["nuisances"]
    assert rows[0]["parameter"] == "timestamp_offset.offset" and rows[0]["range"][
        1
    ] == pytest.approx(0.025)
    assert js["gap"]["reference"] == "calibrated baseline"
    # every model carries the baseline into its PyBullet replays
    assert (
        d.ranking[0].values["timestamp_offset.offset"]
        == d.baseline.values["timestamp_offset.offset"]
    )
    # the baseline stays a nuisance: the calibration switched off names it nowhere
    assert "timestamp_offset" not in d.verdict.effects
