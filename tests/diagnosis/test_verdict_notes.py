"""The verdict's notes: aliases, compensators, honest parameters, discovery on a layout,
and probe manoeuvres that stay within the robot's limits."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pytest

from realitygap.diagnosis.adapters.diffdrive.manoeuvres import (
    MANOEUVRES,
    PROBE_MANOEUVRES,
    probe_description,
)
from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.fit.status import parameter_status
from realitygap.diagnosis.problem.problem import AttributionSettings, Layout, Problem
from realitygap.diagnosis.report.words import explain, explain_markdown
from realitygap.diagnosis.stages.discovery import discover
from realitygap.diagnosis.verdict.advice import Advice
from realitygap.diagnosis.verdict.rules import (
    alias_notes,
    combination_check,
    decide,
    dominant_single,
    nuisance_partner,
    regime_consistency,
    run_discovery,
    unsingled_partner,
)
from realitygap.diagnosis.verdict.types import (
    Confidence,
    Decision,
    Judgement,
    Verdict,
    VerdictKind,
    VerdictNotes,
)
from realitygap.robots.diffdrive import DiffDriveParams


# --------------------------------------------------------------------------- discovery
def _discovery_problem(
    toy_problem: Callable[..., Problem], rng: np.random.Generator, m: int = 40
) -> tuple[Problem, dict[int, np.ndarray]]:
    """Four training and two held-out logs of ``m`` windows, each with three candidate terms
    per window (the second, ω̇, is the one a test plants)."""
    terms = {
        i: np.column_stack([rng.uniform(-1, 1, m), rng.normal(0, 2, m), np.arange(m, dtype=float)])
        for i in range(6)
    }
    named = [
        {"ω": (X[:, 0], "rad/s"), "ω̇": (X[:, 1], "rad/s²"), "time": (X[:, 2], "s")}
        for X in terms.values()
    ]
    problem = toy_problem(windows=m, train_logs=4, holdout_logs=2, terms=named)
    return problem, terms


def _residual(
    problem: Problem, terms: dict[int, np.ndarray], layout: Layout, coef: float, rng
) -> np.ndarray:
    """``coef`` · ω̇ plus noise, SI, in the layout's feature-scale units."""
    dw = np.array([terms[i][w, 1] for i, w in zip(layout.log, layout.window)])
    scale = float(problem.features.scale("tether")[0])
    return (coef * dw + rng.normal(0, 0.004, layout.n)) / scale


def test_discovery_recovers_planted_term_through_the_layout(
    toy_problem: Callable[..., Problem],
) -> None:
    rng = np.random.default_rng(11)
    problem, terms = _discovery_problem(toy_problem, rng)
    z_tr = _residual(problem, terms, problem.train, 0.012, rng)
    z_ho = _residual(problem, terms, problem.holdout, 0.012, rng)
    d = discover(problem, z_tr, z_ho)
    assert d is not None and d.found
    fit = d.fits[0]
    assert [t["term"] for t in fit.terms] == ["ω̇"]
    assert fit.terms[0]["coef"] == pytest.approx(0.012, rel=0.05)
    assert "ω̇" in d.message and "held-out shrink" in d.message
    assert d.message.startswith("not in the library")


def test_discovery_on_pure_noise_says_it_found_nothing(
    toy_problem: Callable[..., Problem],
) -> None:
    rng = np.random.default_rng(12)
    problem, terms = _discovery_problem(toy_problem, rng)
    z_tr = _residual(problem, terms, problem.train, 0.0, rng)
    z_ho = _residual(problem, terms, problem.holdout, 0.0, rng)
    d = discover(problem, z_tr, z_ho)
    assert d is not None and not d.found
    assert d.message.startswith("no term of the 3-term library")


def test_discovery_rejects_misaligned_residuals(toy_problem: Callable[..., Problem]) -> None:
    problem, _ = _discovery_problem(toy_problem, np.random.default_rng(0))
    with pytest.raises(ValueError, match="must follow the layouts"):
        discover(problem, np.zeros(3), np.zeros(problem.holdout.n))


def test_discovery_never_runs_on_a_named_verdict(
    model_fit: Callable[..., ModelFit], make_judgement: Callable[..., Judgement]
) -> None:
    best = model_fit(effects=("wheelbase_error",), z_heldout=np.zeros(4))
    j = make_judgement(best=best, nominal_heldout=np.zeros(4), shrink_pct_best=90.0)
    # the problem is never consulted: a named verdict whose rest is noise has nothing to discover
    assert run_discovery(None, j) is None  # type: ignore[arg-type]
    assert j.kind is VerdictKind.EFFECTS and j.draft.effects == ("wheelbase_error",)


# --------------------------------------------------------------------------- aliases
def test_two_perfectly_correlated_candidates_are_aliases(
    model_fit: Callable[..., ModelFit],
    toy_problem: Callable[..., Problem],
    make_judgement: Callable[..., Judgement],
    make_verdict: Callable[..., Verdict],
) -> None:
    rng = np.random.default_rng(3)
    n = 200
    z_nom = rng.normal(0, 1, n) + 4.0
    z = rng.normal(0, 1, n)
    a = model_fit(effects=("scale_a",), z_heldout=z)
    b = model_fit(effects=("scale_b",), z_heldout=z.copy())
    other = model_fit(effects=("other",), z_heldout=z_nom * 0.9)
    j = make_judgement(best=a, nominal_heldout=z_nom, shrink_pct_best=80.0)
    notes = alias_notes(toy_problem(windows=n), [a, b, other], j, [])
    assert [x["model"] for x in notes] == ["scale_b"]
    assert "as well within noise" in notes[0]["why"][0]
    # a clearly worse candidate is not an alias
    assert "other" not in [x["model"] for x in notes]


def test_alias_from_parameter_correlation_and_known_groups(
    model_fit: Callable[..., ModelFit],
    toy_problem: Callable[..., Problem],
    make_judgement: Callable[..., Judgement],
    make_verdict: Callable[..., Verdict],
) -> None:
    rng = np.random.default_rng(4)
    n = 200
    z_nom = rng.normal(0, 1, n) + 4.0
    a = model_fit(effects=("tool_offset",), z_heldout=rng.normal(0, 1, n))
    # worse on held-out data
    b = model_fit(effects=("link_lengths",), z_heldout=rng.normal(0, 1, n) * 1.3)
    j = make_judgement(best=a, nominal_heldout=z_nom, shrink_pct_best=80.0)
    assert alias_notes(toy_problem(windows=n), [a, b], j, []) == []
    ident = [{"effects": ["tool_offset", "link_lengths"], "separable": False, "correlation": 0.99}]
    notes = alias_notes(toy_problem(windows=n), [a, b], j, ident)
    assert notes and "parameter correlation 0.99" in notes[0]["why"]
    known = toy_problem(windows=n, alias_pairs=[("tool_offset", "link_lengths")])
    notes = alias_notes(known, [a, b], j, [])
    assert notes and "a known alias of this robot" in notes[0]["why"]
    verdict = make_verdict(
        effects=a.effects,
        notes=VerdictNotes(
            verdict_text="tool_offset or link_lengths (aliases on this data)",
            aliases=tuple(notes),
        ),
    )
    text = "\n".join(explain(verdict))
    assert "verdict: tool_offset or link_lengths (aliases on this data)" in text
    assert "alias: link_lengths fits as well" in text
    md = explain_markdown(verdict)
    assert md[1] == "- verdict: tool_offset or link_lengths (aliases on this data)"


def test_a_pair_whose_partner_several_effects_replace_names_the_shared_effect(
    model_fit: Callable[..., ModelFit],
    toy_problem: Callable[..., Problem],
    make_judgement: Callable[..., Judgement],
) -> None:
    # A + B is best, A + C and A + D fit as well: the data identifies A, not its partner
    rng = np.random.default_rng(8)
    n = 300
    z_nom = rng.normal(0, 1, n) + 4.0
    pair = model_fit(effects=("a_eff", "b_eff"), z_heldout=rng.normal(0, 1, n))
    # a little worse alone
    single = model_fit(effects=("a_eff",), z_heldout=1.05 * rng.normal(0, 1, n))
    j = make_judgement(best=pair, nominal_heldout=z_nom, shrink_pct_best=75.0)
    pr = toy_problem(windows=n)
    aliases = [{"model": f"a_eff + {e}", "effects": ["a_eff", e]} for e in ("c_eff", "d_eff")]
    out = unsingled_partner(pr, [pair, single], j, aliases)
    assert out is not None and out[0] is single and out[1] == ["b_eff", "c_eff", "d_eff"]
    # one alternative partner is an alias statement ("A + B or A + C"), not this rule
    assert unsingled_partner(pr, [pair, single], j, aliases[:1]) is None
    # an alias that does not hold the shared effect (a known alias of it with B) leaves it
    known = [*aliases, {"model": "e_eff + b_eff", "effects": ["e_eff", "b_eff"]}]
    out = unsingled_partner(pr, [pair, single], j, known)
    assert out is not None and out[0] is single and out[1] == ["b_eff", "c_eff", "d_eff"]
    # aliases that share no one effect with the pair
    mixed = [aliases[0], {"model": "b_eff + d_eff", "effects": ["b_eff", "d_eff"]}]
    assert unsingled_partner(pr, [pair, single], j, mixed) is None
    # the shared effect alone must close the gap (above noise) as a dominant effect does
    weak = model_fit(effects=("a_eff",), z_heldout=0.5 * z_nom)
    assert unsingled_partner(pr, [pair, weak], j, aliases) is None
    # a named single effect, or an unexplained verdict, is left alone
    j1 = make_judgement(best=single, nominal_heldout=z_nom, shrink_pct_best=75.0)
    assert unsingled_partner(pr, [single], j1, aliases) is None
    j0 = make_judgement(
        best=pair, nominal_heldout=z_nom, kind=VerdictKind.UNEXPLAINED, shrink_pct_best=75.0
    )
    assert unsingled_partner(pr, [pair, single], j0, aliases) is None


def test_a_pair_member_that_closes_nearly_all_of_the_gap_alone_can_be_named_alone(
    model_fit: Callable[..., ModelFit],
    toy_problem: Callable[..., Problem],
    make_judgement: Callable[..., Judgement],
) -> None:
    # a pair rejected for a structured rest falls back to the member that is dominant alone
    rng = np.random.default_rng(9)
    n = 400
    regimes = ["turning"] * 200 + ["straight"] * 200
    z_nom = rng.normal(0, 1, n) + 10.0
    pair = model_fit(effects=("a_eff", "b_eff"), z_heldout=rng.normal(0, 1, n))
    # ~ 99 % of the gap above noise
    a_alone = model_fit(effects=("a_eff",), z_heldout=1.05 * rng.normal(0, 1, n))
    b_alone = model_fit(effects=("b_eff",), z_heldout=0.5 * z_nom)  # half of it
    j = make_judgement(best=pair, nominal_heldout=z_nom, shrink_pct_best=75.0)
    pr = toy_problem(windows=n, regimes=regimes)
    assert dominant_single(pr, [pair, b_alone, a_alone], j, pair.effects) is a_alone
    # the better of two dominant members
    a_worse = model_fit(effects=("a_eff",), z_heldout=2.0 * rng.normal(0, 1, n))
    b_best = model_fit(effects=("b_eff",), z_heldout=1.0 * rng.normal(0, 1, n))
    assert dominant_single(pr, [pair, a_worse, b_best], j, pair.effects) is b_best
    # no member dominant: nothing to fall back to
    assert dominant_single(pr, [pair, b_alone], j, pair.effects) is None
    # a member that worsens a regime it touches is a compensator, never named alone
    z_two = np.concatenate([rng.normal(0, 1, 200) + 12.0, rng.normal(0, 1, 200) + 1.0])
    j2 = make_judgement(best=pair, nominal_heldout=z_two, shrink_pct_best=75.0)
    trades = model_fit(
        effects=("a_eff",),
        z_heldout=np.concatenate([rng.normal(0, 1, 200), rng.normal(0, 1, 200) + 3.0]),
    )
    assert dominant_single(pr, [pair, trades], j2, pair.effects) is None
    fair = model_fit(effects=("a_eff",), z_heldout=rng.normal(0, 1, n))
    assert dominant_single(pr, [pair, fair], j2, pair.effects) is fair


# --------------------------------------------------------------------------- compensators
def _compensator_case(
    rng: np.random.Generator,
    toy_problem: Callable[..., Problem],
    model_fit: Callable[..., ModelFit],
) -> tuple[Problem, np.ndarray, ModelFit]:
    """400 held-out windows, half turning and half straight, with a nominal gap in the
    turning half, and a candidate that closes it there but opens one while driving straight."""
    problem = toy_problem(windows=400, regimes=["turning"] * 200 + ["straight"] * 200)
    z_nom = np.concatenate([rng.normal(3, 1, 200), rng.normal(0, 1, 200)])
    comp = model_fit(
        effects=("wheel_radius_scale",),
        z_heldout=np.concatenate([rng.normal(0, 1, 200), rng.normal(2, 1, 200)]),
    )
    return problem, z_nom, comp


def test_candidate_that_helps_one_regime_and_hurts_another_is_a_compensator(
    model_fit: Callable[..., ModelFit], toy_problem: Callable[..., Problem]
) -> None:
    rng = np.random.default_rng(5)
    n = 400
    problem, z_nom, comp = _compensator_case(rng, toy_problem, model_fit)
    good = model_fit(effects=("dead_zone",), z_heldout=rng.normal(0, 1, n))
    c = regime_consistency(problem, comp, z_nom)
    assert c["compensator"] and c["improved"] == ["turning"] and c["worsened"] == ["straight"]
    g = regime_consistency(problem, good, z_nom)
    assert not g["compensator"] and g["worsened"] == []
    with pytest.raises(ValueError, match="held-out layout's length"):
        regime_consistency(problem, good, z_nom[:10])


def test_parameters_at_a_bound_or_untested_get_no_error_bar(
    model_fit: Callable[..., ModelFit], toy_problem: Callable[..., Problem]
) -> None:
    n = 50

    def shift(batch: Mapping[str, np.ndarray]) -> np.ndarray:
        # a speed limit matters only below the 0.5 m/s these motions command
        e_b, v_lim = batch["wheelbase_error.E_b"], batch["velocity_saturation.v_limit"]
        return (e_b - 1.0) * 100.0 + 10.0 * np.maximum(0.5 - v_lim, 0.0)

    problem = toy_problem(windows=n, shift=shift)
    effects = ("wheelbase_error", "velocity_saturation")

    def fit(e_b: float, v_limit: float) -> ModelFit:
        values = {"wheelbase_error.E_b": e_b, "velocity_saturation.v_limit": v_limit}
        return model_fit(effects=effects, z_heldout=np.zeros(n), values=values)

    assert parameter_status(problem, fit(1.0999, 0.65)) == {
        "wheelbase_error.E_b": "at bound",
        "velocity_saturation.v_limit": "untestable",
    }
    assert parameter_status(problem, fit(1.03, 0.45)) == {}
    # just above the fastest command: the logs say only "above 0.5 m/s"
    assert parameter_status(problem, fit(1.03, 0.52)) == {
        "velocity_saturation.v_limit": "one-sided"
    }


def test_a_parameter_at_its_nominal_bound_is_absent_not_pinned(
    model_fit: Callable[..., ModelFit], toy_problem: Callable[..., Problem]
) -> None:
    n = 50

    def shift(batch: Mapping[str, np.ndarray]) -> np.ndarray:
        lag_l, lag_r = batch["wheel_velocity_lag.tau_left"], batch["wheel_velocity_lag.tau_right"]
        return 10.0 * (lag_l + lag_r)

    problem = toy_problem(windows=n, shift=shift)
    # tau_left = 0 is the nominal end of [0, 0.5] s: no lag on that wheel, not a pinned fit
    fit = model_fit(
        effects=("wheel_velocity_lag",),
        z_heldout=np.zeros(n),
        values={"wheel_velocity_lag.tau_left": 0.0, "wheel_velocity_lag.tau_right": 0.4999},
    )
    assert parameter_status(problem, fit) == {"wheel_velocity_lag.tau_right": "at bound"}


# --------------------------------------------------------------------------- manoeuvres
@pytest.mark.parametrize("name", PROBE_MANOEUVRES)
def test_probe_manoeuvres_respect_the_robots_speed_limits(name: str) -> None:
    params = DiffDriveParams(v_max=0.5, w_max=0.8)
    _, cmd = MANOEUVRES[name].applied(0.05, params)
    assert np.abs(cmd[:, 0]).max() <= 0.5 + 1e-12
    assert np.abs(cmd[:, 1]).max() <= 0.8 + 1e-12
    text = probe_description(name, params)
    import re

    for num, unit in re.findall(r"(\d+(?:\.\d+)?) (m/s|rad/s)", text):
        assert float(num) <= (0.5 if unit == "m/s" else 0.8) + 1e-9, text


def test_hard_starts_for_a_half_metre_per_second_robot() -> None:
    m = MANOEUVRES["hard_starts"].within(0.5, math.pi)
    assert "0.6 m/s" not in m.description and "0.5 m/s" in m.description
    assert max(abs(s[1]) for s in m.segments) == pytest.approx(0.5)
    # ratios between the legs are kept
    assert m.segments[0][1] / m.segments[2][1] == pytest.approx(0.5)
    assert MANOEUVRES["hard_starts"].within(0.7, math.pi) is MANOEUVRES["hard_starts"]
    with pytest.raises(ValueError, match="v_max and w_max must be positive"):
        MANOEUVRES["hard_starts"].within(0.0, 1.0)


# --------------------------------------------------------------------------- end to end
def _diagnose(reality_effect, train, holdout, effects, seed):
    from realitygap.diagnosis.adapters.diffdrive.manoeuvres import Manoeuvre
    from realitygap.diagnosis.adapters.diffdrive.replay import simulate
    from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
    from realitygap.robots.effects import Reality
    from realitygap.robots.simulation import MeasurementNoise

    p = DiffDriveParams()
    noise = MeasurementNoise(0.0005, 0.001, 0.001, 0.002)
    rng = np.random.default_rng(seed)

    def record(segments):
        t, cmd = Manoeuvre("m", "m", segments).applied(0.05, p)
        return simulate(
            t,
            params=p,
            reality=Reality((reality_effect,)),
            commands=cmd,
            noise=noise,
            rng=rng,
            meta={"name": "m"},
        )

    fast = AttributionSettings(pair_candidates=2, verify_top=1)
    return diagnose(
        [record(s) for s in train],
        [record(s) for s in holdout],
        settings=DiagnosisSettings(effects=effects, attribution=fast),
    )


TURNS = ((2.0, 0.0, 1.2), (0.5, 0, 0), (2.0, 0.0, -1.2), (0.5, 0, 0), (2.5, 0.3, 0.0), (0.5, 0, 0))
ARCS = ((2.5, 0.3, 0.7), (0.5, 0, 0), (2.5, 0.3, -0.7), (0.5, 0, 0))
LOOP = (
    (3.0, 0.3, 0.0),
    (1.5, 0.0, 1.0),
    (3.0, 0.25, 0.0),
    (1.5, 0.0, -1.0),
    (3.0, 0.4, 0.0),
    (1.0, 0.3, 0.6),
    (3.0, 0.3, 0.0),
    (0.5, 0, 0),
)


@pytest.mark.slow
def test_in_library_verdict_is_kept_and_open_set_residual_is_described() -> None:
    from realitygap.robots.effects import make_effect

    d = _diagnose(
        make_effect("wheelbase_error", E_b=1.04),
        [TURNS, ARCS],
        [LOOP],
        ("wheelbase_error", "wheel_radius_scale"),
        seed=0,
    )
    assert d.verdict.label == ["wheelbase_error"]
    js = d.to_json()
    assert js["discovery"] is None and js["verdict_text"] == "wheelbase_error"
    # the right effect is consistent across regimes (a wrong one may be flagged)
    assert "wheelbase_error" not in js["compensators"]
    # a wheel radius 3.5 % large, outside the library: the straight-line residual is ∝ v
    d = _diagnose(
        make_effect("wheel_radius_scale", scale=1.035),
        [TURNS, ARCS, LOOP],
        [LOOP, TURNS],
        ("wheelbase_error", "wheel_diameter_ratio"),
        seed=1,
    )
    assert d.verdict.label == VerdictKind.UNEXPLAINED
    disc = d.to_json()["discovery"]
    assert disc["found"]
    dx = next(f for f in disc["fits"] if f["target"] == "pose_gt.dx")
    assert dx["found"] and dx["terms"][0]["term"] == "v"
    # 1-s windows: dx residual = (scale - 1) · v · 1 s
    assert dx["terms"][0]["coef"] == pytest.approx(0.035, rel=0.15)
    assert any(line.startswith("discovery: not in the library") for line in explain(d.verdict))


def test_wheeled_term_library_follows_the_commands() -> None:
    from realitygap.diagnosis.adapters.contract import Drive
    from realitygap.diagnosis.adapters.diffdrive.manoeuvres import Manoeuvre
    from realitygap.diagnosis.adapters.diffdrive.replay import simulate
    from realitygap.diagnosis.adapters.registry import get_adapter
    from realitygap.diagnosis.problem.features import FeatureSettings
    from realitygap.robots.simulation import MeasurementNoise

    p = DiffDriveParams()
    t, cmd = Manoeuvre("m", "m", ARCS, ramp=False).applied(0.05, p)
    log = simulate(
        t,
        params=p,
        commands=cmd,
        noise=MeasurementNoise(0, 0, 0, 0),
        rng=np.random.default_rng(0),
        meta={"name": "m"},
    )
    adapter = get_adapter("diffdrive")
    prep = adapter.prepare(
        log, split="train", drive=Drive.COMMANDS, features_settings=FeatureSettings(), sim=None
    )
    terms = adapter.discovery_terms(prep)
    v, w = terms["v"][0], terms["ω"][0]
    a, b = prep.bounds[2]
    assert v[2] == pytest.approx(prep.context.twist[a:b, 0].mean())
    np.testing.assert_allclose(terms["left wheel speed"][0], v - 0.5 * p.wheelbase * w)
    np.testing.assert_allclose(terms["v·ω"][0], v * w)
    assert terms["ω̇"][1] == "rad/s²" and terms["time"][1] == "s"
    assert all(x[0].shape == (prep.bounds.shape[0],) for x in terms.values())


def test_arm_term_library_has_every_joint() -> None:
    from realitygap.diagnosis.adapters.arm.adapter import record_arm_log
    from realitygap.diagnosis.adapters.contract import Drive
    from realitygap.diagnosis.adapters.registry import get_adapter
    from realitygap.diagnosis.problem.features import FeatureSettings

    lg = record_arm_log(None, np.random.default_rng(0), 16)
    adapter = get_adapter("arm")
    prep = adapter.prepare(
        lg, split="train", drive=Drive.COMMANDS, features_settings=FeatureSettings(), sim=None
    )
    terms = adapter.discovery_terms(prep)
    for j in range(1, 7):
        assert {f"sin q{j}", f"cos q{j}", f"sin 2q{j}", f"cos 2q{j}", f"τ{j} (gravity)"} <= set(
            terms
        )
    a, b = prep.bounds[0]
    assert terms["cos 2q2"][0][0] == pytest.approx(np.cos(2 * prep.context.q[a:b, 1]).mean())
    assert terms["τ2 (gravity)"][1] == "N·m" and "reach" in terms


# --------------------------------------------------------------------------- combinations
def _two_channel_problem(
    toy_problem: Callable[..., Problem], toy_schema: Callable[..., Any], m: int
) -> Problem:
    """``m`` windows of one log, half straight and half accelerating, in two groups: a
    coarse one (``tether``) and one that resolves far below the structure floor
    (``surface``)."""
    regimes = ["straight"] * (m // 2) + ["accelerating"] * (m - m // 2)
    schema = toy_schema("tether", "surface", regimes=("straight", "accelerating"))
    return toy_problem(windows=m, schema=schema, regimes=regimes)


def test_a_combination_must_leave_noise_wherever_it_acts(
    model_fit: Callable[..., ModelFit],
    toy_problem: Callable[..., Problem],
    toy_schema: Callable[..., Any],
) -> None:
    rng = np.random.default_rng(8)
    m = 80
    problem = _two_channel_problem(toy_problem, toy_schema, m)
    lay = problem.holdout
    noise = np.concatenate([rng.normal(0, 0.5, m), rng.normal(0, 0.02, m)])
    acc = lay.regime == "accelerating"
    gap = np.where(acc, 4.0, 0.0) * np.where(lay.group == "surface", 1.5, 1.0)
    z_nom = noise + gap
    pair = ("velocity_saturation", "acceleration_limits")
    exact = model_fit(effects=pair, z_heldout=noise.copy())
    ok = combination_check(problem, exact, z_nom)
    assert ok["passed"]
    # only where a gap lived and the model acted: both groups while accelerating
    assert {(r["group"], r["regime"]) for r in ok["checked"]} == {
        ("tether", "accelerating"),
        ("surface", "accelerating"),
    }
    # a remainder that drifts slowly from window to window, 0.5 scale units RMS: above the
    # structure floor (0.3) but below 2.5 times it, and several times its own
    # window-to-window level
    drift = np.sqrt(2.0) * 0.5 * np.sin(np.linspace(0.0, 2.0 * np.pi, m - m // 2))
    drift = np.concatenate([np.zeros(m // 2), drift])
    partial = noise + np.where(lay.group == "surface", np.tile(drift, 2), 0.0)
    bad = combination_check(problem, model_fit(effects=("a", "b"), z_heldout=partial), z_nom)
    assert not bad["passed"]
    worst = bad["failed"][0]
    assert (worst["group"], worst["regime"]) == ("surface", "accelerating")
    assert worst["ratio"] > 2 * AttributionSettings().excess_ratio
    assert 0.3 < worst["rms_model"] < 0.75
    # the same shape ten times smaller is below what the logs resolve: accepted
    small = noise + np.where(lay.group == "surface", np.tile(0.1 * drift, 2), 0.0)
    assert combination_check(problem, model_fit(effects=("a", "b"), z_heldout=small), z_nom)[
        "passed"
    ]
    with pytest.raises(ValueError, match="held-out layout's length"):
        combination_check(problem, exact, z_nom[:-1])


def test_a_combination_that_leaves_noise_in_a_group_of_unequal_columns_passes(
    model_fit: Callable[..., ModelFit],
    toy_problem: Callable[..., Problem],
    toy_schema: Callable[..., Any],
) -> None:
    """A motion-capture group whose heading is ten times noisier than its position: a
    combination that leaves exactly the noise passes, and one that leaves a drift in the
    quiet position fails. (A level pooled over the columns, near the quiet ones', took the
    heading's noise for structure: a ratio of about 4; and an RMS over the group would let
    the heading's noise hide the drift.)"""
    rng = np.random.default_rng(11)
    m, sigmas = 120, {"dx": 0.1, "dy": 0.1, "dtheta": 1.0}
    regimes = ["straight"] * (m // 2) + ["accelerating"] * (m - m // 2)
    schema = toy_schema("pose_gt", regimes=("straight", "accelerating"))
    problem = toy_problem(windows=m, schema=schema, regimes=regimes)
    lay = problem.holdout
    # each column's noise, window by window, in the layout's order
    draws = {c: rng.normal(0.0, s, m) for c, s in sigmas.items()}
    noise = np.array([draws[str(c)][w] for c, w in zip(lay.column, lay.window)])
    acc = lay.regime == "accelerating"
    z_nom = noise + np.where(acc & (lay.column == "dx"), 3.0, 0.0)
    ok = combination_check(problem, model_fit(effects=("a", "b"), z_heldout=noise.copy()), z_nom)
    assert ok["passed"], ok["failed"]
    # judged where the gap lived (dx while accelerating), at dx's own level
    (row,) = ok["checked"]
    assert (row["column"], row["regime"]) == ("dx", "accelerating")
    assert row["ratio"] == pytest.approx(1.0, abs=0.3)
    # a slow drift left in the quiet column is structure, however noisy the heading
    drift = np.where(acc & (lay.column == "dx"), 1.2 * np.sin(lay.window / 9.0), 0.0)
    bad = combination_check(problem, model_fit(effects=("a", "b"), z_heldout=noise + drift), z_nom)
    assert not bad["passed"]
    assert bad["failed"][0]["column"] == "dx"


def test_parameter_correlations_stay_within_one_whatever_the_units() -> None:
    """Two collinear parameters in very different units correlate fully, an independent one
    not at all, and one the residual does not depend on has no correlation (the
    pseudo-inverse of the unscaled, nearly singular information matrix gives 1.90)."""
    from realitygap.diagnosis.fit.identifiability import _corr
    from realitygap.diagnosis.fit.model import parameter_correlation

    rng = np.random.default_rng(8)
    u, w, z = rng.normal(size=(3, 200))
    # nearly collinear columns ten orders of magnitude apart, an independent one, and one
    # the residual ignores
    J = np.column_stack([u * 1e-3, (u + 1e-6 * z) * 1e7, w, np.zeros(200)])
    C = _corr(J)
    assert abs(C[0, 1]) == pytest.approx(1.0, abs=1e-6)
    assert abs(C[0, 2]) < 0.3 and abs(C[1, 2]) < 0.3
    assert np.all(np.isnan(C[3])) and np.all(np.isnan(C[:, 3]))
    finite = C[np.isfinite(C)]
    assert np.all(np.abs(finite) <= 1.0)
    cov = np.array([[4.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    P = parameter_correlation(cov)
    assert P[0, 1] == pytest.approx(1.0) and P[0, 0] == pytest.approx(1.0)
    assert np.all(np.isnan(P[2]))


def test_a_partner_that_only_refines_a_nuisance_inside_its_range_is_not_named(
    model_fit: Callable[..., ModelFit], toy_problem: Callable[..., Problem]
) -> None:
    z = np.zeros(4)
    ranges = {"timestamp_offset.offset": (-0.025, 0.025), "command_latency.delay": (0.0, 0.05)}
    problem = toy_problem(windows=4, baseline_ranges=ranges)
    limits = {"acceleration_limits.t_acc": 2.0, "acceleration_limits.t_dec": 1.5}

    def fit(effects: tuple[str, ...], values: dict[str, float]) -> ModelFit:
        return model_fit(effects=effects, z_heldout=z, values=values)

    clock_inside = fit(
        ("acceleration_limits", "timestamp_offset"), {**limits, "timestamp_offset.offset": 0.014}
    )
    assert nuisance_partner(problem, clock_inside) == ("acceleration_limits", "timestamp_offset")
    # a partner listed first, at the nuisance range's edge, is still only a nuisance
    edge = fit(
        ("command_latency", "motor_deadband"),
        {"command_latency.delay": 0.05, "motor_deadband.threshold": 0.02},
    )
    assert nuisance_partner(problem, edge) == ("motor_deadband", "command_latency")
    # beyond the nuisance range the partner is a finding of its own
    latency = fit(
        ("command_latency", "longitudinal_slip"),
        {"command_latency.delay": 0.097, "longitudinal_slip.mu": 0.2},
    )
    assert nuisance_partner(problem, latency) is None
    # a partner that is no nuisance, a single effect, and a problem without a baseline
    dead = fit(
        ("command_latency", "wheel_dead_zone"),
        {"command_latency.delay": 0.18, "wheel_dead_zone.dz_left": 0.01},
    )
    assert nuisance_partner(problem, dead) is None
    single = fit(("timestamp_offset",), {"timestamp_offset.offset": 0.01})
    assert nuisance_partner(problem, single) is None
    assert nuisance_partner(toy_problem(windows=4), clock_inside) is None


# --------------------------------------------------------------------------- the rules in order
def _decided(problem: Problem, ranking: list[ModelFit], judgement: Judgement) -> Decision:
    advice = Advice([], judgement.draft.ambiguous_with, judgement.draft.confidence)
    return decide(problem, ranking, judgement, advice)


def test_a_named_pair_whose_partner_refines_a_nuisance_is_decided_as_the_other_effect(
    model_fit: Callable[..., ModelFit],
    toy_problem: Callable[..., Problem],
    make_judgement: Callable[..., Judgement],
) -> None:
    rng = np.random.default_rng(21)
    n = 200
    ranges = {"timestamp_offset.offset": (-0.025, 0.025)}
    problem = toy_problem(windows=n, baseline_ranges=ranges)
    z_nom = rng.normal(0, 1, n) + 4.0
    values = {"acceleration_limits.t_acc": 2.0, "timestamp_offset.offset": 0.014}
    pair = model_fit(
        effects=("acceleration_limits", "timestamp_offset"),
        z_heldout=rng.normal(0, 1, n),
        values=values,
    )
    j = make_judgement(best=pair, nominal_heldout=z_nom, reason="the pair closes it")
    decision = _decided(problem, [pair], j)
    assert decision.kind is VerdictKind.EFFECTS
    assert decision.effects == ("acceleration_limits",)
    assert decision.judgement.draft.reason.startswith("the pair closes it; timestamp_offset only")
    assert decision.notes.verdict_text == "acceleration_limits"
    partner = decision.notes.nuisance_partner
    assert partner is not None and partner.effect == "timestamp_offset"
    assert partner.to_json() == {
        "effect": "timestamp_offset",
        "values": {"timestamp_offset.offset": 0.014},
        "units": {"timestamp_offset.offset": "s"},
        "ranges": {"timestamp_offset.offset": [-0.025, 0.025]},
    }
    # the judgement it was decided from is left as it was
    assert j.draft.effects == pair.effects and j.draft.reason == "the pair closes it"


def test_a_compensator_and_a_pair_that_leaves_structure_are_decided_unexplained(
    model_fit: Callable[..., ModelFit],
    toy_problem: Callable[..., Problem],
    toy_schema: Callable[..., Any],
    make_judgement: Callable[..., Judgement],
) -> None:
    rng = np.random.default_rng(22)
    problem, z_nom, comp = _compensator_case(rng, toy_problem, model_fit)
    decision = _decided(problem, [comp], make_judgement(best=comp, nominal_heldout=z_nom))
    assert decision.kind is VerdictKind.UNEXPLAINED and decision.effects == ()
    assert decision.judgement.draft.confidence is Confidence.NOT_APPLICABLE
    assert "likely compensator" in decision.judgement.draft.reason
    assert decision.notes.compensators == ("wheel_radius_scale",)
    assert decision.notes.verdict_text == "unexplained"
    # a pair that leaves a slow drift where it acts, with no member that closes the gap alone
    m = 80
    two = _two_channel_problem(toy_problem, toy_schema, m)
    lay = two.holdout
    noise = np.concatenate([rng.normal(0, 0.5, m), rng.normal(0, 0.02, m)])
    z_two = noise + np.where(lay.regime == "accelerating", 4.0, 0.0)
    drift = np.sqrt(2.0) * 0.5 * np.sin(np.linspace(0.0, 2.0 * np.pi, m - m // 2))
    drift = np.concatenate([np.zeros(m // 2), drift])
    pair = model_fit(
        effects=("velocity_saturation", "acceleration_limits"),
        z_heldout=noise + np.where(lay.group == "surface", np.tile(drift, 2), 0.0),
    )
    j = make_judgement(best=pair, nominal_heldout=z_two, shrink_pct_best=85.0)
    decision = _decided(two, [pair], j)
    assert decision.kind is VerdictKind.UNEXPLAINED
    assert decision.judgement.draft.reason.startswith("partially explained:")
    assert decision.notes.verdict_text == (
        "unexplained (partially explained by velocity_saturation + acceleration_limits: 85 % "
        "of the held-out gap)"
    )
    partial = decision.notes.partially_explained_by
    assert partial is not None and partial.heldout_shrink_pct == 85.0
    assert decision.notes.combination_check is not None
    assert not decision.notes.combination_check["passed"]
