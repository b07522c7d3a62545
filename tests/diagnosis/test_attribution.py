"""Blind attribution on small cases: a known effect is recovered, a withheld one is refused,
and one-direction logs are flagged as unable to separate E_b from E_d."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.diagnosis.adapters.diffdrive.manoeuvres import Manoeuvre
from realitygap.diagnosis.adapters.diffdrive.replay import simulate
from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
from realitygap.diagnosis.problem.problem import AttributionSettings
from realitygap.diagnosis.verdict.types import Confidence, VerdictKind
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import Reality, make_effect
from realitygap.robots.simulation import MeasurementNoise

P = DiffDriveParams()
NOISE = MeasurementNoise(truth_xy=0.0005, truth_theta=0.001, camera_xy=0.001, camera_theta=0.002)

TURNS = Manoeuvre(
    "turns",
    "turning both ways, a straight leg",
    ((2.0, 0.0, 1.2), (0.5, 0, 0), (2.0, 0.0, -1.2), (0.5, 0, 0), (2.5, 0.3, 0.0), (0.5, 0, 0)),
)
ARCS = Manoeuvre(
    "arcs", "arcs both ways", ((2.5, 0.3, 0.7), (0.5, 0, 0), (2.5, 0.3, -0.7), (0.5, 0, 0))
)
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
CCW_A = Manoeuvre("ccw_a", "counter-clockwise arcs", ((6.0, 0.3, 0.6), (0.5, 0, 0)))
CCW_B = Manoeuvre("ccw_b", "counter-clockwise arcs", ((5.0, 0.25, 0.5), (0.5, 0, 0)))


def record(man: Manoeuvre, reality: Reality, rng: np.random.Generator):
    t, cmd = man.applied(0.05, P)
    return simulate(
        t, params=P, reality=reality, commands=cmd, noise=NOISE, rng=rng, meta={"name": man.name}
    )


def run(reality: Reality, train, holdout, effects, seed: int = 0):
    rng = np.random.default_rng(seed)
    tr = [record(m, reality, rng) for m in train]
    ho = [record(m, reality, rng) for m in holdout]
    fast = AttributionSettings(pair_candidates=2, verify_top=1)
    return diagnose(tr, ho, settings=DiagnosisSettings(effects=effects, attribution=fast))


@pytest.mark.slow
def test_known_effect_is_recovered() -> None:
    reality = Reality((make_effect("wheelbase_error", E_b=1.04),))
    d = run(
        reality,
        [TURNS, ARCS],
        [LOOP],
        ("wheelbase_error", "wheel_diameter_ratio", "wheel_radius_scale", "command_latency"),
    )
    assert d.verdict.label == ["wheelbase_error"]
    top = d.ranking_rows()[0]
    assert top["effects"] == ["wheelbase_error"] and top["verified_in_pybullet"]
    assert top["params"]["wheelbase_error.E_b"]["value"] == pytest.approx(1.04, abs=0.004)
    assert top["heldout_shrink_pct"] > 60.0
    js = d.to_json()
    assert js["verdict"] == ["wheelbase_error"]
    assert {"rank", "params", "heldout_shrink_pct"} <= set(js["ranking"][0])
    # localisation puts the gap where E_b acts: ground-truth heading while turning
    first = js["localisation"]["table"][0]
    assert first["where"] == "pose_gt" and first["column"] == "dtheta"
    assert first["regime"].startswith("turning") or first["regime"] == "accelerating"


@pytest.mark.slow
def test_withheld_effect_comes_out_unexplained() -> None:
    reality = Reality((make_effect("wheel_radius_scale", scale=1.035),))
    d = run(
        reality,
        [TURNS, ARCS],
        [LOOP],
        ("wheelbase_error", "wheel_diameter_ratio", "encoder_scale"),
        seed=1,
    )
    # a library effect may stand in for part of it (a narrower wheelbase turns the
    # same), but half the gap or more stays unexplained: never a plain "effects"
    assert d.verdict.kind in (VerdictKind.UNEXPLAINED, VerdictKind.PARTIAL), d.verdict.reason
    assert d.budget is not None and d.budget.unexplained_share >= 50.0


@pytest.mark.slow
def test_one_turning_direction_cannot_separate_eb_from_ed() -> None:
    reality = Reality((make_effect("wheel_diameter_ratio", E_d=1.01),))
    d = run(reality, [CCW_A], [CCW_B], ("wheel_diameter_ratio", "wheelbase_error"), seed=2)
    confounded = [i for i in d.identifiability if not i["separable"]]
    assert confounded, d.identifiability
    info = confounded[0]
    assert set(" ".join(info["effects"]).split()) >= {"wheel_diameter_ratio", "wheelbase_error"}
    assert info["correlation"] > 0.95
    assert info["separating_motion"]["name"] in {
        "turn_cw",
        "circle_cw",
        "straight_medium",
        "straight_fast",
        "straight_slow",
        "turn_ccw",
        "hard_starts",
    }
    assert info["separating_motion"]["correlation_after"] < 0.9
    assert "cannot tell" in info["message"]
    if d.verdict.kind is VerdictKind.EFFECTS:
        assert d.verdict.ambiguous_with
        assert d.verdict.confidence is Confidence.NOT_IDENTIFIABLE


# --------------------------------------------------------------------------- residual structure
def _regime_layout(n: int, busy_every: int = 4) -> tuple[object, np.ndarray]:
    from realitygap.diagnosis.problem.features import FeatureGroup, FeatureSchema
    from realitygap.diagnosis.problem.problem import Layout

    schema = FeatureSchema(
        groups=(FeatureGroup("pose_gt", ("dtheta",), ("rad",), (0.002,)),),
        regimes=("quiet", "busy"),
    )
    busy = (np.arange(n) // 5) % busy_every == 0  # blocks of 5 busy windows
    lay = Layout(
        blocks=[(0, "pose_gt", np.arange(n))],
        group=np.full(n, "pose_gt"),
        column=np.full(n, "dtheta"),
        regime=np.where(busy, "busy", "quiet"),
        log=np.zeros(n, dtype=np.int64),
        window=np.arange(n, dtype=np.int64),
        motion=np.zeros((n, 6)),
        schema=schema,
    )
    return lay, busy


def test_a_regime_that_only_scatters_more_is_not_structure() -> None:
    from realitygap.diagnosis.problem.features import FeatureSettings
    from realitygap.diagnosis.problem.residual import describe_residual

    lay, busy = _regime_layout(800)
    rng = np.random.default_rng(3)
    z = rng.normal(0.0, 1.0, 800) * np.where(busy, 3.0, 1.0)
    out = describe_residual(z, lay, AttributionSettings(), FeatureSettings())
    assert not any("while busy" in r for r in out["reasons"]), out["reasons"]
    # the same regime with a residual that stays put is structure
    z_bias = rng.normal(0.0, 1.0, 800) + np.where(busy, 3.0, 0.0)
    out = describe_residual(z_bias, lay, AttributionSettings(), FeatureSettings())
    assert out["structured"]
    assert any("dtheta while busy is" in r and "× the noise level" in r for r in out["reasons"])
