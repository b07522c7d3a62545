"""The verdict on two scales: a drift named on whole runs when the window residual it
leaves does not add up along the runs."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import t as student_t

from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
from realitygap.diagnosis.problem.problem import Layout
from realitygap.diagnosis.report.summary import summary_sentences
from realitygap.diagnosis.report.words import explain
from realitygap.diagnosis.report.writer import write_report
from realitygap.diagnosis.stages.scales import ScaleSettings, run_bias
from realitygap.diagnosis.verdict.types import VerdictKind


def _layout(n_logs: int, n_win: int) -> Layout:
    from realitygap.diagnosis.adapters.diffdrive.adapter import DIFFDRIVE_SCHEMA

    cols = np.array(["dx", "dy", "dtheta"])
    log = np.repeat(np.arange(n_logs), n_win * 3)
    n = log.size
    return Layout(
        blocks=[(i, "pose_gt", np.arange(n_win)) for i in range(n_logs)],
        group=np.full(n, "pose_gt"),
        column=np.tile(cols, n_logs * n_win),
        regime=np.full(n, "straight"),
        log=log,
        window=np.tile(np.repeat(np.arange(n_win), 3), n_logs),
        motion=np.zeros((n, 6)),
        schema=DIFFDRIVE_SCHEMA,
    )


def test_run_bias_is_the_mean_in_standard_errors_per_run_and_column() -> None:
    rng = np.random.default_rng(0)
    lay = _layout(3, 40)
    z = rng.normal(size=lay.n)
    planted = (lay.log == 1) & (lay.column == "dtheta")
    z[planted] += 1.5
    rows = run_bias(z, lay)
    assert len(rows) == 9
    top = rows[0]
    assert (top["log"], top["group"], top["column"]) == (1, "pose_gt", "dtheta")
    x = z[planted]
    d = x - x.mean()
    rho = max(0.0, float(d[1:] @ d[:-1]) / float(d @ d))
    se = x.std(ddof=1) / math.sqrt(x.size) * math.sqrt((1 + rho) / (1 - rho))
    assert top["t"] == pytest.approx(x.mean() / se, rel=1e-12)
    assert top["windows"] == 40
    df = 40 * (1 - rho) / (1 + rho) - 1
    assert top["p"] == pytest.approx(2 * student_t.sf(abs(top["t"]), df), rel=1e-9)
    assert top["p"] < 1e-6
    # every other run and column is within a few standard errors of zero
    assert all(abs(r["t"]) < 3.5 for r in rows[1:])
    assert [r["p"] for r in rows] == sorted(r["p"] for r in rows)


def test_run_bias_widens_the_standard_error_of_a_correlated_residual() -> None:
    rng = np.random.default_rng(1)
    lay = _layout(1, 400)
    white = rng.normal(size=lay.n)
    # the same values, but each window's dtheta follows the previous one (AR(1), ρ = 0.8)
    walk = white.copy()
    sel = np.flatnonzero(lay.column == "dtheta")
    for a, b in itertools.pairwise(sel):
        walk[b] = 0.8 * walk[a] + 0.6 * white[b]
    row = next(r for r in run_bias(walk, lay) if r["column"] == "dtheta")
    naive = walk[sel].std(ddof=1) / math.sqrt(sel.size)
    assert row["se"] == pytest.approx(naive * 3.0, rel=0.15)


def test_run_bias_leaves_out_short_runs_and_checks_its_input() -> None:
    lay = _layout(2, 3)
    assert run_bias(np.ones(lay.n), lay) == []
    with pytest.raises(ValueError, match=r"run_bias: z has shape"):
        run_bias(np.ones(lay.n + 1), lay)
    with pytest.raises(ValueError, match=r"ScaleSettings\.run_bias_alpha"):
        ScaleSettings(run_bias_alpha=0.0)


def _wandering_clock_sessions(root: Path, seed: int, **hidden: float) -> None:
    """UMBmark squares and held-out circles of one robot whose motion-capture clock
    wanders by 30 ms against its encoders (the package's independent generator)."""
    import realitygap.independent.diffdrive as dd

    rng = np.random.default_rng(seed)
    robot = dd.DriveRobot()
    h = dd.Hidden(clock_wander=0.03, **hidden)
    squares = [
        dd.simulate_run(dd.square_path(robot, 1.0, d), robot, h, rng) for d in ("cw", "ccw") * 2
    ]
    dd.write_session(root, "010320241010", squares, robot, "square", side=1.0, rng=rng)
    circles = [
        dd.simulate_run(dd.circle_path(robot, r, d), robot, h, rng)
        for r, d in zip((0.5, 0.4, 0.6), ("cw", "ccw", "ccw"), strict=True)
    ]
    dd.write_session(root, "010320241220", circles, robot, "circular", rng=rng)


@pytest.mark.slow
def test_a_wandering_clock_moves_only_the_motion_capture() -> None:
    import realitygap.independent.diffdrive as dd

    with pytest.raises(ValueError, match=r"Hidden\.clock_wander"):
        dd.Hidden(clock_wander=0.5)
    robot = dd.DriveRobot()
    rng = np.random.default_rng(2)
    still = dd.simulate_run(dd.square_path(robot, 1.0, "cw"), robot, dd.Hidden(), rng)
    rng = np.random.default_rng(2)
    moved = dd.simulate_run(
        dd.square_path(robot, 1.0, "cw"), robot, dd.Hidden(clock_wander=0.03), rng
    )
    # the wheels and the true path are the same; only the motion capture moves in time
    np.testing.assert_array_equal(still.truth, moved.truth)
    np.testing.assert_array_equal(still.ticks_left, moved.ticks_left)
    lag = np.abs(moved.gt - still.gt).max(axis=0)
    assert lag[2] > 1e-3


@pytest.mark.slow
def test_a_drift_under_a_wandering_clock_is_named_on_whole_runs(tmp_path: Path) -> None:
    from realitygap.diagnosis.logs.read import logs_from_optiodom

    _wandering_clock_sessions(tmp_path, seed=5, b_true=1.02)
    logs = logs_from_optiodom(tmp_path)
    train = [lg for lg in logs if lg.meta.get("path_type") == "square"]
    held = [lg for lg in logs if lg.meta.get("path_type") != "square"]
    d = diagnose(train, held, settings=DiagnosisSettings(drive="ticks"))
    sc = d.scales
    # the window scale hides the drift; whole runs show it
    assert sc["window_shrink_pct"] < 50.0 <= sc["run_shrink_pct"], sc
    assert sc["named"] and sc["run_bias_p_family"] >= ScaleSettings().run_bias_alpha
    assert d.verdict.kind is VerdictKind.EFFECTS and "wheelbase_error" in d.verdict.effects
    assert d.chosen is not None
    # a wider axle (planted 2 %); the window fit under a 30 ms wander is loose
    assert 1.005 < d.chosen.values["wheelbase_error.E_b"] < 1.03
    text = d.verdict.notes.verdict_text
    assert "on whole runs" in text
    whole = d.verdict.notes.whole_runs
    assert whole is not None and ("unexplained" in text) == bool(whole.remainder)
    assert any(line.startswith("window scale:") for line in explain(d.verdict))
    assert any("on whole runs" in s for s in summary_sentences(d))
    write_report(d, tmp_path / "report")
    md = (tmp_path / "report" / "report.md").read_text()
    assert f"**{text}**" in md


@pytest.mark.slow
def test_a_drift_under_a_fast_noisy_capture_is_named_in_the_windows_above_each_channels_noise(
    tmp_path: Path,
) -> None:
    from realitygap.diagnosis.logs.read import read_logs
    from realitygap.experiments.independent import generate_case
    from realitygap.independent.cases import case_by_name

    # the independent generator's robot at a 50 Hz cycle under a motion capture with three
    # times the noise: a 3 % wider axle is a few per cent of each 1-s window's raw residual,
    # most of which is the heading's noise. Counted channel by channel, the gap above the
    # noise is the axle's: the window verdict names it, and no whole-run rule is needed
    train_p, hold_p = generate_case(case_by_name("wheelbase_plus3"), tmp_path, 0, "fast_noisy")
    # read as a user reads them: the plausibility check passes the noisy 50 Hz truth
    train = [lg for p in train_p for lg in read_logs(p)]
    held = [lg for p in hold_p for lg in read_logs(p)]
    d = diagnose(train, held, settings=DiagnosisSettings(drive="commands"))
    assert d.verdict.effects == ("wheelbase_error",), d.verdict.reason
    assert d.gap["heldout_shrink_pct_best"] < 50.0  # the raw window share: mostly noise
    assert "above the noise floor" in d.verdict.reason
    assert not d.scales  # named in the windows, not on whole runs
    assert d.ranking[0].values["wheelbase_error.E_b"] == pytest.approx(1.03, abs=0.006)
    robot = d.verdict.notes.robot
    assert robot is not None
    assert robot["factors"] == {"wheelbase": pytest.approx(1.03, abs=0.006)}
