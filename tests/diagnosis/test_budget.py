"""The gap budget: its statistics against closed forms, its folds and scales, and its one
rule on planted logs (a geometry effect named with its value; a nominal robot: nothing)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest
from scipy import stats

from realitygap.core.parallel import SerialBackend
from realitygap.diagnosis.budget import Budget, BudgetEntry, kind_of
from realitygap.diagnosis.budget.budget import beyond_noise
from realitygap.diagnosis.budget.folds import MIN_FOLDS, RunCells, make_folds
from realitygap.diagnosis.budget.select import cochran_q, fold_gains, paired_test
from realitygap.diagnosis.problem.problem import Problem


def test_the_paired_test_is_students_one_sided_t_test() -> None:
    g = np.array([0.3, 0.1, 0.25, 0.4, 0.05, 0.2])
    t, p = paired_test(g)
    ref = stats.ttest_1samp(g, 0.0, alternative="greater")
    assert t == pytest.approx(ref.statistic) and p == pytest.approx(ref.pvalue)
    # the same gains negated are not a gain; a constant positive set is certain
    assert paired_test(-g)[1] > 0.99
    assert paired_test(np.full(5, 0.2)) == (math.inf, 0.0)
    assert paired_test(np.array([1.0]))[1] == 1.0


def test_cochran_q_against_its_closed_form() -> None:
    x = np.array([1.00, 1.02, 0.98, 1.01])
    s = np.array([0.01, 0.02, 0.01, 0.02])
    w = 1 / s**2
    mean = np.sum(w * x) / np.sum(w)
    q_ref = float(np.sum(w * (x - mean) ** 2))
    q, p, i2 = cochran_q(x, s)
    assert q == pytest.approx(q_ref)
    assert p == pytest.approx(stats.chi2.sf(q_ref, 3))
    assert i2 == pytest.approx(max(0.0, (q_ref - 3) / q_ref))
    # one value within its errors holds; values apart by 10 errors do not
    assert cochran_q(np.array([1.0, 1.0001, 0.9999]), np.full(3, 0.01))[1] > 0.9
    assert cochran_q(np.array([1.0, 1.1, 0.9]), np.full(3, 0.01))[1] < 1e-6


def test_fold_gains_are_log_ratios() -> None:
    np.testing.assert_allclose(
        fold_gains(np.array([2.0, 4.0]), np.array([1.0, 4.0])), [math.log(2), 0.0]
    )


def _problem(toy_problem: Callable[..., Problem], logs: int = 3, windows: int = 20) -> Problem:
    return toy_problem(windows=windows, train_logs=logs, holdout_logs=2)


def test_folds_fall_back_from_sessions_to_runs_to_segments(
    toy_problem: Callable[..., Problem],
) -> None:
    pr = _problem(toy_problem, logs=2)
    f = make_folds(pr)
    # two training runs cannot make enough folds: each run is cut into contiguous segments
    assert f.unit == "segment" and f.k >= MIN_FOLDS
    for k in range(f.k):
        wins = pr.train.window[f.train == k]
        logs = np.unique(pr.train.log[f.train == k])
        assert logs.size == 1 and np.all(np.diff(np.unique(wins)) == 1)
    pr8 = _problem(toy_problem, logs=MIN_FOLDS)
    f8 = make_folds(pr8)
    assert f8.unit == "run" and f8.k == MIN_FOLDS
    # runs of sessions: one fold per session once there are enough of them
    for i, p in enumerate(pr8.logs):
        if p.split == "train":
            p.log.meta["session"] = f"s{i // 1}"
    assert make_folds(pr8).unit == "session"
    for p in pr8.logs:
        p.log.meta["session"] = "one"
    assert make_folds(pr8).unit == "run"
    with pytest.raises(ValueError, match="min_folds"):
        make_folds(pr8, min_folds=1)


def test_run_cells_keep_white_noise_at_unit_variance_and_add_up_a_bias(
    toy_problem: Callable[..., Problem],
) -> None:
    pr = _problem(toy_problem, logs=MIN_FOLDS, windows=50)
    f = make_folds(pr)
    cells = RunCells.of(pr.train, f.train)
    rng = np.random.default_rng(0)
    z = rng.normal(0.0, 1.0, (400, pr.train.n))
    v = cells(z)
    assert v.shape == (400, cells.n)
    assert np.var(v) == pytest.approx(1.0, rel=0.05)
    # a constant bias b per window becomes b·√n per cell
    bias = cells(np.full(pr.train.n, 0.1))
    counts = np.asarray(cells.matrix.sum(axis=0)).ravel() ** 2
    np.testing.assert_allclose(bias, 0.1 * np.sqrt(counts))


def test_a_residual_beyond_the_sensors_noise_is_a_gap_whatever_its_speed() -> None:
    """χ² of the residual against the sensors' own noise: white noise at σ is not a gap;
    an oscillation within a couple of windows (white from window to window, so a
    window-to-window level would take it for noise) at three times σ is."""
    rng = np.random.default_rng(0)
    n, sigma = 2000, 0.7
    var = {"window": np.full(n, sigma**2)}
    assert not beyond_noise(rng.normal(0.0, sigma, n), None, var)
    fast = 3.0 * sigma * np.sin(np.pi * np.arange(n) * 0.9) + rng.normal(0.0, sigma, n)
    assert beyond_noise(fast, None, var)


def _entry(constant: bool = True) -> BudgetEntry:
    return BudgetEntry(
        "wheelbase_error",
        "run",
        {},
        {},
        {"run": 50.0},
        {"run": (40.0, 60.0)},
        0.5,
        1e-5,
        6,
        (),
        {"unit": "session", "constant": constant, "parameters": {}},
    )


@pytest.mark.parametrize(
    ("entries", "structured_pct", "structured", "kind"),
    [
        ((), 80.0, True, "unexplained"),
        ((), 5.0, False, "none"),
        # significant, but most of what remains is the sensors' noise: no gap
        ((), 20.0, True, "none"),
        ((True,), 10.0, True, "effects"),
        ((True,), 60.0, True, "partial"),
        ((False,), 10.0, True, "unexplained"),
    ],
)
def test_one_rule_sets_the_kind(
    entries: tuple[bool, ...], structured_pct: float, structured: bool, kind: str
) -> None:
    rem = {
        "run": {
            "remaining_pct": 90.0,
            "noise_pct": 90.0 - structured_pct,
            "structured_pct": structured_pct,
        }
    }
    got, rule = kind_of([_entry(c) for c in entries], rem, structured)
    assert got == kind and rule


def test_an_entry_that_worsens_the_held_out_runs_is_not_named() -> None:
    worse = dataclasses.replace(_entry(), share={"run": -38.0}, interval={"run": (-54.0, -25.0)})
    assert worse.constant and not worse.carries and not worse.named
    rem = {"run": {"remaining_pct": 138.0, "noise_pct": 0.0, "structured_pct": 138.0}}
    got, rule = kind_of([worse], rem, True)
    assert got == "unexplained" and "do not carry over" in rule
    # an interval that reaches above zero at some scale still carries
    mixed = dataclasses.replace(
        worse,
        share={"run": -5.0, "window": 2.0},
        interval={"run": (-9.0, -1.0), "window": (-1.0, 4.0)},
    )
    assert mixed.carries and mixed.named


# --------------------------------------------------------------------------- on planted logs
def _bench(reality: tuple[tuple[str, dict[str, float]], ...], seed: int) -> list[object]:
    from realitygap.diagnosis.adapters.diffdrive.manoeuvres import MANOEUVRES
    from realitygap.diagnosis.adapters.diffdrive.replay import simulate
    from realitygap.robots.diffdrive import DiffDriveParams
    from realitygap.robots.effects import Reality, make_effect
    from realitygap.robots.simulation import MeasurementNoise

    params = DiffDriveParams()
    dt = 0.05
    parts = [
        MANOEUVRES[n].applied(dt, params)[1] for n in ("tour", "square_cw", "arcs", "square_ccw")
    ]
    cmd = np.concatenate(parts, axis=0)
    t = dt * np.arange(cmd.shape[0])
    cmd[-1] = 0.0
    return [
        simulate(
            t,
            params=params,
            reality=Reality(tuple(make_effect(n, **v) for n, v in reality)),
            commands=cmd,
            noise=MeasurementNoise(0.0005, 0.001, 0.001, 0.002),
            rng=np.random.default_rng(seed),
            meta={"name": f"bench-{seed}"},
        )
    ]


@pytest.mark.slow
def test_a_planted_diameter_ratio_heads_the_budget_and_a_nominal_robot_names_nothing() -> None:
    from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose

    lib = ("wheel_diameter_ratio", "wheelbase_error", "wheel_radius_scale", "command_latency")
    s = DiagnosisSettings(effects=lib)
    d = diagnose(
        _bench((("wheel_diameter_ratio", {"E_d": 1.008}),), 1), settings=s, backend=SerialBackend()
    )
    b = d.budget
    assert isinstance(b, Budget) and b.entries
    first = b.entries[0]
    assert first.effect == "wheel_diameter_ratio" and first.scale == "run"
    assert first.values["wheel_diameter_ratio.E_d"] == pytest.approx(1.008, abs=0.0008)
    assert first.share["run"] > 50.0 and first.interval["run"][0] > 0.0
    assert b.kind == "effects" and d.verdict.effects[0] == "wheel_diameter_ratio"
    js = d.to_json()["budget"]
    assert js["schema"] == "realitygap.budget/1" and js["entries"][0]["named"]
    assert set(js["remainder"]) == {"run", "window"}
    # same logs, same budget (bootstrap and folds are seeded)
    again = diagnose(
        _bench((("wheel_diameter_ratio", {"E_d": 1.008}),), 1), settings=s, backend=SerialBackend()
    )
    assert again.budget is not None and again.budget.to_json() == js
    nominal = diagnose(_bench((), 2), settings=s, backend=SerialBackend())
    assert nominal.budget is not None and not nominal.budget.named
    assert nominal.verdict.kind.value in ("none", "unexplained")
