"""The whole-run gap per run: closed forms, pooling, and when one run carries it."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.shrink import concentrated_gap, trajectory_gap, trajectory_runs


def _track(name: str, n: int, offset: tuple[float, float] = (0.0, 0.0)) -> Log:
    t = 0.05 * np.arange(n)
    pose = np.column_stack([0.1 * t + offset[0], np.sin(t) + offset[1], 0.2 * t])
    return Log(t=t, channels={"pose_gt": pose}, meta={"robot": "diffdrive", "name": name})


def _runs() -> tuple[list[Log], list[Log], list[Log]]:
    real = [_track("a", 40), _track("b", 100), _track("c", 60)]
    # a constant position offset of length L gives an RMS error of exactly L
    nominal = [
        _track("a", 40, (0.03, 0.04)),
        _track("b", 100, (0.0, 0.5)),
        _track("c", 60, (0.1, 0)),
    ]
    best = [_track("a", 40, (0.0, 0.01)), _track("b", 100, (0.0, 0.4)), _track("c", 60, (0.02, 0))]
    return real, nominal, best


def test_rows_are_each_runs_rms_error_and_pool_to_the_whole_run_gap() -> None:
    real, nominal, best = _runs()
    rows = trajectory_runs(real, {"nominal": nominal, "best": best})
    assert [r["log"] for r in rows] == ["a", "b", "c"]
    assert [r["samples"] for r in rows] == [40, 100, 60]
    np.testing.assert_allclose([r["nominal_m"] for r in rows], [0.05, 0.5, 0.1], rtol=1e-12)
    np.testing.assert_allclose([r["best_m"] for r in rows], [0.01, 0.4, 0.02], rtol=1e-12)
    sq = np.array([40 * 0.05**2, 100 * 0.5**2, 60 * 0.1**2])
    np.testing.assert_allclose([r["share_pct"] for r in rows], 100 * sq / sq.sum(), rtol=1e-12)
    pooled = np.sqrt(sum(r["samples"] * r["nominal_m"] ** 2 for r in rows) / 200)
    assert pooled == pytest.approx(trajectory_gap(real, nominal), rel=1e-12)


def test_one_run_carrying_the_gap_is_named_with_the_gap_of_the_others() -> None:
    real, nominal, best = _runs()
    rows = trajectory_runs(real, {"nominal": nominal, "best": best})
    conc = concentrated_gap(rows)
    assert conc is not None and conc["log"] == "b" and conc["runs"] == 2
    assert conc["share_pct"] == pytest.approx(100 * 25 / (25 + 0.1 + 0.6))
    assert conc["before_m"] == pytest.approx(0.5) and conc["after_m"] == pytest.approx(0.4)
    assert conc["rest_before_m"] == pytest.approx(trajectory_gap(real[::2], nominal[::2]))
    assert conc["rest_after_m"] == pytest.approx(trajectory_gap(real[::2], best[::2]))
    # a share below the threshold, or too few runs to speak of "the others": nothing
    assert concentrated_gap(rows, share_pct=99.0) is None
    assert concentrated_gap(rows[:2]) is None


def test_evenly_spread_gaps_are_not_concentrated() -> None:
    real = [_track(k, 50) for k in "abcd"]
    sims = [_track(k, 50, (0.1, 0.0)) for k in "abcd"]
    rows = trajectory_runs(real, {"nominal": sims})
    assert [r["share_pct"] for r in rows] == pytest.approx([25.0] * 4)
    assert concentrated_gap(rows) is None


def test_bad_arguments_are_refused() -> None:
    real, nominal, _ = _runs()
    with pytest.raises(ValueError, match="replays must name at least one"):
        trajectory_runs(real, {})
    with pytest.raises(ValueError, match=r"share_pct must lie in \(0, 100\)"):
        concentrated_gap(trajectory_runs(real, {"nominal": nominal}), share_pct=100.0)
