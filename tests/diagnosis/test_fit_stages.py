"""The fit stages: screen every candidate on the surrogate, and tell how long the rest takes
from the work measured in the run."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.core.parallel import SerialBackend
from realitygap.diagnosis.adapters.contract import Drive
from realitygap.diagnosis.adapters.diffdrive.manoeuvres import MANOEUVRES
from realitygap.diagnosis.adapters.diffdrive.replay import simulate
from realitygap.diagnosis.adapters.registry import get_adapter
from realitygap.diagnosis.diagnose import DiagnosisSettings, prepare_logs
from realitygap.diagnosis.fit.candidates import fit_candidates
from realitygap.diagnosis.fit.model import _rho, fit_model
from realitygap.diagnosis.fit.workload import ROWS, Workload, row_seconds
from realitygap.diagnosis.problem.problem import Problem
from realitygap.diagnosis.stages.baseline import calibrate_baseline
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import Reality, make_effect
from realitygap.robots.simulation import MeasurementNoise

EFFECTS = (
    "wheel_diameter_ratio",
    "wheelbase_error",
    "command_latency",
    "longitudinal_slip",
    "motor_deadband",
)


@pytest.fixture(scope="module")
def problem() -> Problem:
    params = DiffDriveParams()
    dt = 0.05
    cmd = np.concatenate(
        [MANOEUVRES[m].applied(dt, params)[1] for m in ("square_cw", "arcs", "turns_in_place")]
    )[:800]
    cmd[-1] = 0.0
    log = simulate(
        dt * np.arange(cmd.shape[0]),
        params=params,
        reality=Reality((make_effect("wheel_diameter_ratio", E_d=1.01),)),
        commands=cmd,
        noise=MeasurementNoise(0.0005, 0.001, 0.001, 0.002),
        rng=np.random.default_rng(3),
        meta={"name": "screening"},
    )
    settings = DiagnosisSettings(effects=EFFECTS)
    adapter = get_adapter(settings.robot)
    backend = SerialBackend()
    prepared = prepare_logs(adapter, [log], None, settings, backend, lambda m: None)
    pr = Problem(
        adapter,
        prepared,
        Drive(settings.drive),
        settings.features,
        settings.sim,
        settings.attribution,
    )
    calibrate_baseline(pr, list(EFFECTS), backend, lambda m: None)
    return pr


def test_every_single_effect_is_screened_and_the_planted_one_leads(problem):
    messages: list[str] = []
    singles, pairs, _ = fit_candidates(problem, EFFECTS, SerialBackend(), messages.append)
    assert pairs == [] and all(f.screened for f in singles)
    assert [len(f.effects) for f in singles] == [1] * len(EFFECTS)
    assert singles[0].effects == ("wheel_diameter_ratio",)
    assert abs(singles[0].values["wheel_diameter_ratio.E_d"] - 1.01) < 1e-3
    assert any(m.startswith("screening 5 single effects") for m in messages)


def robust_cost(problem: Problem, values: dict[str, float]) -> float:
    """The training cost the fits minimise, at ``values``."""
    z = problem.surrogate_residuals(problem.train, {k: np.array([v]) for k, v in values.items()}, 1)
    return float(np.sum(_rho(z**2, problem.settings.loss, problem.f_scale)))


@pytest.mark.parametrize("effect", ["wheel_diameter_ratio", "command_latency"])
def test_the_full_fit_never_ends_above_the_screening_fit_it_refines(problem, effect):
    screened = fit_model(problem, (effect,), screen=True)
    full = fit_model(problem, (effect,), starts=[screened.values], local_only=True)
    assert screened.screened and not full.screened
    assert robust_cost(problem, full.values) <= robust_cost(problem, screened.values) * (1 + 1e-9)
    # the screening fit holds the nuisances it does not fit at the calibrated baseline
    held = {k: v for k, v in problem.baseline_values.items() if k not in screened.keys}
    assert held and all(screened.values[k] == v for k, v in held.items())


def test_the_row_rate_is_measured_on_the_problem(problem):
    rate = row_seconds(problem, EFFECTS)
    assert 0.0 < rate < 1.0
    # a batch of B rows costs about B rows: the measured rate is per row, not per call
    assert row_seconds(problem, EFFECTS, batch=64, repeats=1) < 4.0 * rate


def test_the_plan_counts_the_work_and_spreads_parallel_stages_over_the_workers(problem):
    serial = Workload.plan(problem, 5, row_s=1e-3, replay_s=2.0, workers=1)
    two = Workload.plan(problem, 5, row_s=1e-3, replay_s=2.0, workers=2)
    by_name = {st.name: st.predicted_s for st in serial.stages}
    assert by_name["screen singles"] == pytest.approx(5 * ROWS["screen_single"] * 1e-3)
    # one log, trained on in its training windows: each verified model replays it per
    # defect iteration and once more to score
    assert by_name["verify"] == pytest.approx(
        problem.settings.verify_top * (1 + problem.settings.defect_iterations) * 2.0
    )
    # no pairs by default (the budget combines effects): two selection steps of 5 tries
    assert by_name["screen pairs"] == 0.0
    assert by_name["budget"] == pytest.approx(10 * ROWS["budget_try"] * 1e-3)
    for st2, st1 in zip(two.stages, serial.stages):
        assert st2.predicted_s <= st1.predicted_s
    assert two.remaining_s() < serial.remaining_s()


def test_finished_stages_correct_the_estimate_of_the_rest_of_their_kind(problem):
    w = Workload.plan(problem, 5, row_s=1e-3, replay_s=2.0, workers=1, conventions=6)
    kinds = {st.name: st.kind for st in w.stages}
    assert kinds["baseline"] == "mixed" and kinds["verify"] == "replays"
    # a baseline that ran ten times longer (its own reasons) corrects nothing else
    base = next(st for st in w.stages if st.name == "baseline")
    rest = sum(st.predicted_s for st in w.stages if st.name != "baseline")
    w.finish("baseline", 10.0 * base.predicted_s)
    assert w.remaining_s() == pytest.approx(rest)
    # surrogate stages three times slower than predicted: the other surrogate stages too
    first = next(st for st in w.stages if st.name == "screen singles")
    w.finish("screen singles", 3.0 * first.predicted_s)
    rows_left = sum(
        st.predicted_s for st in w.stages if st.kind == "rows" and st.measured_s is None
    )
    replays_left = sum(st.predicted_s for st in w.stages if st.kind == "replays")
    assert w.correction("rows") == pytest.approx(3.0)
    assert w.remaining_s() == pytest.approx(3.0 * rows_left + replays_left)
    w.finish("no such stage", 100.0)  # ignored
    assert w.remaining_s() == pytest.approx(3.0 * rows_left + replays_left)
    with pytest.raises(ValueError, match="kind"):
        w.add("x", 1.0, kind="other")
