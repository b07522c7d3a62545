"""Training coverage: held-out motions beyond the training envelope are counted, their share
of the gap measured, and a diagnosis whose held-out runs drive faster than its training
says so instead of naming an effect it could not test."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.adapters.diffdrive.manoeuvres import Manoeuvre
from realitygap.diagnosis.adapters.diffdrive.replay import simulate
from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
from realitygap.diagnosis.problem.problem import AttributionSettings
from realitygap.diagnosis.problem.shrink import overall_shrink
from realitygap.diagnosis.report.summary import summary_sentences
from realitygap.diagnosis.report.words import explain
from realitygap.diagnosis.report.writer import write_report
from realitygap.diagnosis.stages.coverage import (
    CoverageSettings,
    motion_variables,
    planar_motion,
    training_coverage,
    wheel_speeds,
)
from realitygap.diagnosis.verdict.types import VerdictKind
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import Reality, make_effect
from realitygap.robots.simulation import MeasurementNoise


def _cover(train_motion, ho_motion, z_ref, z_best, mask=None, per_window=3, **kw):
    """Coverage of held-out windows with ``per_window`` residual entries each."""
    which = np.repeat(np.arange(ho_motion.shape[0]), per_window)
    return training_coverage(train_motion, ho_motion, which, z_ref, z_best, mask, **kw)


def _motion(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    out = np.zeros((v.size, 6))
    out[:, 0], out[:, 1] = v, w
    return out


def test_held_out_motions_within_the_training_span_are_covered() -> None:
    rng = np.random.default_rng(0)
    train = _motion(rng.uniform(0.0, 0.3, 40), rng.uniform(-1.0, 1.0, 40))
    ho = _motion(rng.uniform(0.05, 0.25, 20), rng.uniform(-0.8, 0.8, 20))
    z = rng.normal(size=60)
    cov = _cover(train, ho, z, 0.5 * z)
    assert cov.n_windows == 20 and cov.n_outside == 0
    assert cov.gap_share_outside == 0.0 and not cov.beyond_training
    assert cov.suggestion() == ""
    assert cov.shrink_inside_pct == pytest.approx(50.0)
    assert np.isnan(cov.shrink_outside_pct)


def test_gap_share_and_shrink_are_split_at_the_envelope() -> None:
    rng = np.random.default_rng(1)
    train = _motion(rng.uniform(0.0, 0.1, 40), np.zeros(40))
    v_ho = np.r_[np.full(12, 0.05), np.full(4, 0.4)]  # 4 of 16 windows four times faster
    ho = _motion(v_ho, np.zeros(16))
    fast = np.repeat(v_ho > 0.2, 3)
    z_ref = np.where(fast, 3.0, 1.0) * rng.choice([-1.0, 1.0], size=48)
    z_best = np.where(fast, z_ref, 0.2 * z_ref)  # the model helps only where training looked
    cov = _cover(train, ho, z_ref, z_best, best="m")
    assert cov.n_outside == 4
    speed = cov.rows[0]
    assert speed["n_outside"] == 4 and speed["heldout_max"] == pytest.approx(0.4)
    assert speed["train_max"] <= 0.1
    assert cov.rows[1]["n_outside"] == 0  # a turn rate held at exactly 0 both times
    # 12 entries of 9 beyond, 36 of 1 within: the gap is 108 / 144 beyond the training
    assert cov.gap_share_outside == pytest.approx(108 / 144)
    # what the model leaves: 108 beyond, 36 · 0.04 within; 9 / 0.04 denser beyond
    assert cov.residual_share_outside == pytest.approx(108 / (108 + 1.44))
    assert cov.concentration == pytest.approx(9 / 0.04)
    assert cov.beyond_training
    assert cov.shrink_inside_pct == pytest.approx(overall_shrink(z_ref[~fast], z_best[~fast]))
    assert cov.shrink_outside_pct == pytest.approx(0.0)
    assert "speed up to 0.4 m/s (training: " in cov.suggestion()
    assert speed["n_above"] == 4 and speed["n_below"] == 0 and "down to" not in cov.suggestion()
    # only the channels where the gap lives count
    mask = np.tile([True, True, False], 16)
    masked = _cover(train, ho, z_ref, z_best, mask)
    sel = fast & mask
    assert masked.gap_share_outside == pytest.approx(
        np.sum(z_ref[sel] ** 2) / np.sum(z_ref[mask] ** 2)
    )


def test_a_model_that_transfers_is_not_blamed_on_coverage() -> None:
    # most held-out windows lie beyond the training, but the model leaves the same rest
    # everywhere: the unexplained part does not gather beyond the training
    rng = np.random.default_rng(2)
    train = _motion(rng.uniform(0.0, 0.1, 40), np.zeros(40))
    v_ho = np.r_[np.full(12, 0.05), np.full(30, 0.4)]
    ho = _motion(v_ho, np.zeros(42))
    fast = np.repeat(v_ho > 0.2, 3)
    z_ref = np.where(fast, 3.0, 1.0) * rng.choice([-1.0, 1.0], size=126)
    z_best = 0.15 * rng.choice([-1.0, 1.0], size=126)
    cov = _cover(train, ho, z_ref, z_best)
    assert cov.gap_share_outside > 0.9 and cov.residual_share_outside > 0.5
    assert cov.concentration == pytest.approx(1.0)
    assert not cov.beyond_training
    # nor is a held-out set with too few windows within the training to compare
    few = _cover(train, ho[9:], z_ref[27:], np.where(fast[27:], 1.0, 0.1))
    assert few.concentration > 2 and not few.beyond_training


def test_wheel_speeds_flag_a_speed_and_turn_rate_never_driven_together() -> None:
    # training: fast straight legs and turns in place; held out: a fast arc, whose outer
    # wheel runs faster than any wheel did in training although speed and turn rate are each
    # within their training spans
    train = _motion(np.r_[np.full(10, 0.3), np.zeros(10)], np.r_[np.zeros(10), np.full(10, 2.0)])
    ho = _motion(np.array([0.3]), np.array([2.0]))
    b = 0.23
    both = np.hstack([train, wheel_speeds(train, b)]), np.hstack([ho, wheel_speeds(ho, b)])
    z = np.ones(3)
    box = _cover(train, ho, z, z)
    assert box.n_outside == 0
    cov = _cover(*both, z, z, variables=motion_variables(wheels=True))
    right = next(r for r in cov.rows if r["variable"] == "v_right")
    assert right["heldout_max"] == pytest.approx(0.3 + b) and right["train_max"] == pytest.approx(
        0.3
    )
    assert cov.n_outside == 1


def test_margin_and_tolerance_decide_what_is_beyond() -> None:
    train = _motion(np.linspace(0.0, 0.1, 11), np.zeros(11))
    ho = _motion(np.array([0.105, 0.2]), np.array([5e-4, 0.0]))
    z = np.ones(6)
    cov = _cover(train, ho, z, z)
    # 0.105 is within 10 % of the 0.1 m/s span; 5e-4 rad/s within the 1e-3 tolerance of 0
    assert [r["n_outside"] for r in cov.rows[:2]] == [1, 0]
    strict = _cover(train, ho, z, z, settings=CoverageSettings(margin=0.0, atol=1e-4))
    assert [r["n_outside"] for r in strict.rows[:2]] == [2, 1]


def test_bad_arguments_are_refused() -> None:
    train = _motion(np.linspace(0, 0.1, 5), np.zeros(5))
    ho = _motion(np.array([0.05]), np.zeros(1))
    with pytest.raises(ValueError, match="one entry per held-out residual"):
        _cover(train, ho, np.ones(2), np.ones(3))
    with pytest.raises(ValueError, match="must name the 6 motion columns"):
        motion_variables([("speed", "m/s")])
    with pytest.raises(ValueError, match=r"one column per variable \['v_mean'\]"):
        _cover(train, ho, np.ones(3), np.ones(3), variables=[("v_mean", "speed", "m/s")])
    with pytest.raises(ValueError, match="wheelbase must be a positive length"):
        wheel_speeds(train, 0.0)
    with pytest.raises(ValueError, match="gap_mask must have shape"):
        _cover(train, ho, np.ones(3), np.ones(3), np.ones(2, bool))
    with pytest.raises(ValueError, match="heldout_window must index the 1 held-out windows"):
        training_coverage(train, ho, np.array([0, 1]), np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match="train_motion must be a finite"):
        training_coverage(train[:, :2], ho, np.zeros(1, int), np.ones(1), np.ones(1))
    with pytest.raises(ValueError, match="margin must be a finite number"):
        CoverageSettings(margin=-0.1)
    with pytest.raises(ValueError, match="min_gap_share must lie in"):
        CoverageSettings(min_gap_share=0.0)
    with pytest.raises(ValueError, match="min_concentration must be a finite ratio"):
        CoverageSettings(min_concentration=0.5)
    with pytest.raises(ValueError, match="min_inside_windows must be an integer"):
        CoverageSettings(min_inside_windows=0)


def test_planar_motion_recovers_a_known_arc_and_a_speed_step() -> None:
    # an arc at 0.3 m/s and 0.5 rad/s for 2 s, then straight at 0.1 m/s: closed form poses
    dt = 0.05
    t = np.arange(0, 4.0 + dt / 2, dt)
    v = np.where(t < 2.0, 0.3, 0.1)
    w = np.where(t < 2.0, 0.5, 0.0)
    th = np.cumsum(np.r_[0.0, w[:-1] * dt])
    x = np.cumsum(np.r_[0.0, (v * np.cos(th + 0.5 * w * dt))[:-1] * dt])
    y = np.cumsum(np.r_[0.0, (v * np.sin(th + 0.5 * w * dt))[:-1] * dt])
    bounds = np.array([[5, 15], [25, 35], [45, 55], [70, 80]])
    m = planar_motion(t, np.c_[x, y, th], bounds)
    np.testing.assert_allclose(m[:, 0], [0.3, 0.3, 0.1, 0.1], atol=2e-3)
    np.testing.assert_allclose(m[:, 1], [0.5, 0.5, 0.0, 0.0], atol=2e-3)
    # within steady windows neither speed nor turn rate changes
    np.testing.assert_allclose(m[[0, 3], 2:], 0.0, atol=2e-3)
    # the window across the step sees it
    across = planar_motion(t, np.c_[x, y, th], np.array([[35, 45]]))[0]
    assert across[2] == pytest.approx(-0.2, abs=0.01) and across[4] == pytest.approx(0.2, abs=0.01)
    with pytest.raises(ValueError, match="pose must have shape"):
        planar_motion(t, np.c_[x, y], bounds)


# --------------------------------------------------------------------------- end to end
P = DiffDriveParams()
NOISE = MeasurementNoise(truth_xy=0.0005, truth_theta=0.001, camera_xy=0.001, camera_theta=0.002)
SLOW = Manoeuvre(
    "slow",
    "slow straight legs and turns both ways",
    ((3.0, 0.1, 0.0), (2.0, 0.0, 0.6), (3.0, 0.12, 0.0), (2.0, 0.0, -0.6), (0.5, 0, 0)),
)
SLOW_ARCS = Manoeuvre(
    "slow_arcs", "slow arcs both ways", ((3.0, 0.1, 0.4), (3.0, 0.1, -0.4), (0.5, 0, 0))
)
FAST = Manoeuvre(
    "fast",
    "a slow leg, then fast straight legs and arcs",
    (
        (12.0, 0.1, 0.0),
        (3.0, 0.45, 0.0),
        (2.0, 0.4, 0.5),
        (3.0, 0.45, 0.0),
        (2.0, 0.4, -0.5),
        (0.5, 0, 0),
    ),
)


@pytest.mark.slow
def test_a_top_speed_the_training_never_reached_is_reported_as_beyond_the_training(
    tmp_path: Path,
) -> None:
    # the robot tops out at 0.3 m/s: the slow training runs cannot show it, the fast held-out
    # run is dominated by it
    reality = Reality((make_effect("velocity_saturation", v_limit=0.3),))
    rng = np.random.default_rng(3)

    def record(man: Manoeuvre):
        t, cmd = man.applied(0.05, P)
        return simulate(
            t,
            params=P,
            reality=reality,
            commands=cmd,
            noise=NOISE,
            rng=rng,
            meta={"name": man.name},
        )

    tr = [record(SLOW), record(SLOW_ARCS)]
    ho = [record(FAST)]
    settings = DiagnosisSettings(
        effects=("wheelbase_error", "velocity_saturation", "wheel_radius_scale"),
        attribution=AttributionSettings(pair_candidates=1, verify_top=1),
    )
    d = diagnose(tr, ho, settings=settings)
    cov = d.coverage
    assert cov is not None and cov.beyond_training
    speed = next(r for r in cov.rows if r["variable"] == "v_mean")
    # the speed the robot made: capped at 0.3 m/s, not the 0.45 m/s commanded
    assert speed["train_max"] < 0.15 and speed["n_outside"] > 0
    assert speed["heldout_max"] == pytest.approx(0.3, abs=0.01)
    assert cov.gap_share_outside > 0.9
    js = d.to_json()
    assert js["coverage"]["beyond_training"] and js["coverage"]["n_outside"] == cov.n_outside
    # the cap cannot be named from training that never reaches it
    assert d.verdict.kind is VerdictKind.UNEXPLAINED
    # the summary states the budget and the rule that set its kind
    text = " ".join(summary_sentences(d))
    assert "Of the held-out" in text and "no effect's cross-validated gain is significant" in text
    md = write_report(d, tmp_path / "r").read_text(encoding="utf-8")
    assert "## Training coverage" in md and "| left wheel speed |" in md
    lines = explain(d.verdict)
    assert any(line.startswith("beyond the training:") for line in lines)
    assert any(line.startswith("experiment: record training runs") for line in lines)
    # fitted on the held-out run itself the cap closes its gap: the library can express it,
    # the training does not pin it down (an upper bound, not a held-out score)
    reach = js["reach"]
    assert reach["expressible"] and reach["rows"][0]["model"] == "velocity_saturation"
    v_limit = reach["rows"][0]["params"]["velocity_saturation.v_limit"]
    assert v_limit == pytest.approx(0.3, abs=0.02)
    assert reach["rows"][0]["shrink_pct"] >= reach["threshold_pct"] > reach["trained_shrink_pct"]
    assert any(line.startswith("reach: ") and "does not pin it down" in line for line in lines)
    assert any(
        s.startswith("What the library could reach: Fitted on the held-out")
        for s in summary_sentences(d)
    )
