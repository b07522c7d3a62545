"""The verdict's own tests on planted residuals: the shrink of the gap above the noise
floor, the plausible-range edge of a parameter spanning decades, and a residual whose
adjacent windows cancel (an error at the window boundaries)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pytest

from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.fit.status import parameter_status, pinned_parameters
from realitygap.diagnosis.problem.features import FeatureGroup, FeatureSchema, FeatureSettings
from realitygap.diagnosis.problem.parameters import range_position
from realitygap.diagnosis.problem.problem import AttributionSettings, Layout, Problem
from realitygap.diagnosis.problem.residual import (
    describe_residual,
    shrink_above_noise,
)

SCHEMA = FeatureSchema(
    groups=(FeatureGroup("pose_gt", ("dtheta",), ("rad",), (0.002,)),), regimes=("all_of_it",)
)


def _layout(n: int, logs: int = 4) -> Layout:
    per = n // logs
    return Layout(
        blocks=[(i, "pose_gt", np.arange(per)) for i in range(logs)],
        group=np.full(n, "pose_gt"),
        column=np.full(n, "dtheta"),
        regime=np.full(n, "all_of_it"),
        log=np.repeat(np.arange(logs), per).astype(np.int64),
        window=np.tile(np.arange(per), logs).astype(np.int64),
        motion=np.zeros((n, 6)),
        schema=SCHEMA,
    )


def _slow_drift(n: int, logs: int, rng: np.random.Generator) -> np.ndarray:
    """A residual that drifts slowly from window to window (an effect), unit RMS."""
    per = n // logs
    t = np.linspace(0.0, 1.0, per)
    d = np.concatenate([np.sin(2 * np.pi * t + rng.uniform(0, 6)) for _ in range(logs)])
    return d / np.sqrt(np.mean(d**2))


# --------------------------------------------------------------------------- shrink above noise
def test_shrink_above_noise_recovers_the_planted_share_of_the_gap() -> None:
    rng = np.random.default_rng(0)
    n, sigma = 4000, 1.0
    lay = _layout(n)
    drift = _slow_drift(n, 4, rng)
    before = 1.5 * drift + rng.normal(0.0, sigma, n)
    after = 0.75 * drift + rng.normal(0.0, sigma, n)  # half the effect closed
    mask = np.ones(n, dtype=bool)
    stated = shrink_above_noise(before, after, lay, mask, {"pose_gt": sigma})
    assert stated == pytest.approx(50.0, abs=3.0)
    # the window-to-window level finds the same noise without being told
    measured = shrink_above_noise(before, after, lay, mask)
    assert measured == pytest.approx(50.0, abs=4.0)
    raw = 100.0 * (1.0 - np.sqrt(np.mean(after**2) / np.mean(before**2)))
    assert raw < 40.0  # the raw share counts the noise no effect can close


def test_shrink_above_noise_takes_each_columns_own_noise() -> None:
    """A group whose columns differ in noise (a motion-capture heading noisier than its
    position): the noisy column's noise is not gap, so closing the quiet column's effect
    closes the whole gap."""
    rng = np.random.default_rng(2)
    per_col, logs = 2000, 4
    schema = FeatureSchema(
        groups=(FeatureGroup("pose_gt", ("dx", "dtheta"), ("m", "rad"), (0.001, 0.002)),),
        regimes=("all_of_it",),
    )
    n = 2 * per_col
    per = per_col // logs
    lay = Layout(
        blocks=[(i, "pose_gt", np.arange(per)) for i in range(logs)],
        group=np.full(n, "pose_gt"),
        column=np.repeat(np.array(["dx", "dtheta"]), per_col),
        regime=np.full(n, "all_of_it"),
        log=np.tile(np.repeat(np.arange(logs), per), 2).astype(np.int64),
        window=np.tile(np.arange(per), 2 * logs).astype(np.int64),
        motion=np.zeros((n, 6)),
        schema=schema,
    )
    drift = _slow_drift(per_col, logs, rng)
    quiet = 0.1 * rng.normal(0.0, 1.0, per_col)
    noisy = rng.normal(0.0, 1.0, per_col)
    before = np.concatenate([drift + quiet, noisy])
    after = np.concatenate([quiet, noisy])  # the effect in dx closed, dtheta untouched
    got = shrink_above_noise(before, after, lay, np.ones(n, dtype=bool))
    assert got == pytest.approx(100.0, abs=5.0)


def test_shrink_above_noise_without_a_gap_is_the_raw_shrink() -> None:
    rng = np.random.default_rng(1)
    n = 400
    lay = _layout(n)
    before, after = rng.normal(0.0, 1.0, n), rng.normal(0.0, 0.9, n)
    mask = np.ones(n, dtype=bool)
    got = shrink_above_noise(before, after, lay, mask, {"pose_gt": 2.0})
    raw = 100.0 * (1.0 - np.sqrt(np.mean(after**2) / np.mean(before**2)))
    assert got == pytest.approx(raw)


def test_shrink_above_noise_refuses_misaligned_residuals() -> None:
    lay = _layout(40)
    with pytest.raises(ValueError, match="shrink_above_noise: residuals and mask must have"):
        shrink_above_noise(np.zeros(40), np.zeros(39), lay, np.ones(40, dtype=bool))


def _judged(
    toy_problem: Callable[..., Problem], z_nom: np.ndarray, logs: int = 4, **kw: Any
) -> Problem:
    """A toy problem of ``logs`` held-out logs whose nominal residual is ``z_nom``."""
    return toy_problem(
        windows=z_nom.size // logs, holdout_logs=logs, train_logs=logs, holdout=z_nom, **kw
    )


# --------------------------------------------------------------------------- plausible range edge
def test_range_position_is_logarithmic_for_a_parameter_spanning_decades() -> None:
    # velocity_saturation.v_limit: 0.05 … 10 m/s, searched in log units
    assert range_position("velocity_saturation.v_limit", 0.05) == pytest.approx(0.0)
    assert range_position("velocity_saturation.v_limit", 10.0) == pytest.approx(1.0)
    u = range_position("velocity_saturation.v_limit", 0.085)
    assert u == pytest.approx(math.log(0.085 / 0.05) / math.log(200.0))
    assert 0.09 < u < 0.11
    assert range_position("wheelbase_error.E_b", 1.05) == pytest.approx(0.75)


def test_a_speed_limit_well_inside_its_range_is_not_pinned(
    model_fit: Callable[..., ModelFit], toy_problem: Callable[..., Problem]
) -> None:
    n = 50

    def shift(batch: Mapping[str, np.ndarray]) -> np.ndarray:
        return 100.0 * np.maximum(0.3 - batch["velocity_saturation.v_limit"], 0.0)

    problem = toy_problem(windows=n, shift=shift)
    key = "velocity_saturation.v_limit"
    slow = model_fit(effects=("velocity_saturation",), z_heldout=np.zeros(n), values={key: 0.085})
    assert pinned_parameters(problem, slow) == []
    assert parameter_status(problem, slow) == {}
    at_low = model_fit(
        effects=("velocity_saturation",), z_heldout=np.zeros(n), values={key: 0.0501}
    )
    assert pinned_parameters(problem, at_low) == [key]
    assert parameter_status(problem, at_low) == {key: "at bound"}


def test_noise_in_a_group_of_unequal_columns_is_not_structure() -> None:
    """Pure noise in a group whose heading is ten times noisier than its position is not
    structure: the group's RMS is compared with its columns' levels combined as noise
    combines, and a column's regime mean with that column's own standard error. (A level
    pooled over the columns sits near the quiet ones': a ratio of about 4 and regime means
    of the heading many "standard errors" from zero.) A drift in the quiet column still is."""
    rng = np.random.default_rng(5)
    per_col, logs = 600, 4
    sigmas = {"dx": 0.1, "dy": 0.1, "dtheta": 1.0}
    schema = FeatureSchema(
        groups=(FeatureGroup("pose_gt", tuple(sigmas), ("m", "m", "rad"), (0.001, 0.001, 0.002)),),
        regimes=("straight", "turning"),
    )
    per = per_col // logs
    n = 3 * per_col
    lay = Layout(
        blocks=[(i, "pose_gt", np.arange(per)) for i in range(logs)],
        group=np.full(n, "pose_gt"),
        column=np.repeat(np.array(list(sigmas)), per_col),
        regime=np.tile(np.array(["straight", "turning"]), n // 2),
        log=np.tile(np.repeat(np.arange(logs), per), 3).astype(np.int64),
        window=np.tile(np.arange(per), 3 * logs).astype(np.int64),
        motion=np.zeros((n, 6)),
        schema=schema,
    )
    settings = AttributionSettings(floor=0.01)
    z = np.concatenate([rng.normal(0.0, s, per_col) for s in sigmas.values()])
    out = describe_residual(z, lay, settings, FeatureSettings())
    g = out["groups"]["pose_gt"]
    assert g["excess_ratio"] == pytest.approx(1.0, abs=0.2)
    assert g["worst_regime_t"] < settings.regime_t
    assert not out["structured"], out["reasons"]
    drift = np.where(lay.column == "dx", 0.5 * _slow_drift(n, logs, rng), 0.0)
    assert describe_residual(z + drift, lay, settings, FeatureSettings())["structured"]


def test_adjacent_windows_that_cancel_are_not_structure() -> None:
    """A few mis-stamped samples move displacement from one window into the next
    (e_k = b_{k+1} − b_k): large against the window-to-window level, but no effect."""
    rng = np.random.default_rng(4)
    n, logs = 800, 4
    lay = _layout(n, logs)
    per = n // logs
    z = []
    for _ in range(logs):
        b = np.where(rng.random(per + 1) < 0.15, rng.normal(0.0, 4.0, per + 1), 0.0)
        z.append(np.diff(b) + rng.normal(0.0, 0.5, per))
    z_b = np.concatenate(z)
    out = describe_residual(z_b, lay, AttributionSettings(), FeatureSettings())
    g = out["groups"]["pose_gt"]
    assert g["lag1_autocorrelation"] < -0.3
    assert g["excess_ratio"] > AttributionSettings().excess_ratio  # large against the level
    # the group's excess is set aside; a column or regime that concentrates it still counts
    assert not any(r.startswith("pose_gt: residual RMS is") for r in out["reasons"])
    assert any("adjacent windows cancel" in s for s in out["notes"])
    # the same size as a slow drift is structure
    z_d = np.sqrt(np.mean(z_b**2)) * _slow_drift(n, logs, rng) + rng.normal(0.0, 0.5, n)
    out = describe_residual(z_d, lay, AttributionSettings(), FeatureSettings())
    assert out["structured"]
    assert any(r.startswith("pose_gt: residual RMS is") for r in out["reasons"])
    # anti-correlated but not telescoping (alternating sign that accumulates) stays structure
    alt = np.tile(np.array([3.0, -1.0]), n // 2) + rng.normal(0.0, 0.5, n)
    out = describe_residual(alt, lay, AttributionSettings(), FeatureSettings())
    assert out["structured"], out["groups"]["pose_gt"]


def test_a_baseline_nuisance_at_the_edge_of_its_range_is_reported(
    model_fit: Callable[..., ModelFit], toy_problem: Callable[..., Problem]
) -> None:
    n = 50
    problem = toy_problem(
        windows=n,
        shift=lambda batch: 100.0 * (batch["wheelbase_error.E_b"] - 1.0),
        baseline_ranges={
            "command_latency.delay": (0.0, 0.05),
            "timestamp_offset.offset": (-0.025, 0.025),
        },
    )
    values = {"wheelbase_error.E_b": 1.03}
    # the nuisances are refined with the model, not fitted as its parameters
    pinned = model_fit(
        effects=("wheelbase_error",),
        z_heldout=np.zeros(n),
        values={**values, "command_latency.delay": 0.05, "timestamp_offset.offset": 0.001},
        keys=tuple(values),
    )
    assert parameter_status(problem, pinned) == {"command_latency.delay": "nuisance at range bound"}
    # a latency of 0 s is the nominal end of its range: no response delay, not pinned
    absent = model_fit(
        effects=("wheelbase_error",),
        z_heldout=np.zeros(n),
        values={**values, "command_latency.delay": 0.0, "timestamp_offset.offset": -0.025},
        keys=tuple(values),
    )
    assert parameter_status(problem, absent) == {
        "timestamp_offset.offset": "nuisance at range bound"
    }


# --------------------------------------------------------------------------- plateaus
def test_a_parameter_on_a_plateau_of_the_training_cost_takes_the_end_nearest_nominal() -> None:
    """A dead band between the commanded speeds: the training data bound it to an interval;
    the fit reports the smallest band they support, and a smooth parameter stays put."""
    from realitygap.diagnosis.fit.model import _toward_nominal

    commands = np.array([0.02, 0.04, 0.07])  # wheel speeds the training logs hold, m/s
    truth = 0.05  # a dead band: the first two stop, the third moves

    def cost(U: np.ndarray) -> np.ndarray:
        band = U[:, 0] * 0.08  # position in 0 … 0.08 m/s
        wrong = (commands[None, :] < band[:, None]) != (commands[None, :] < truth)
        smooth = (U[:, 1] - 0.3) ** 2
        return wrong.sum(axis=1).astype(float) + smooth

    u = np.array([0.066 / 0.08, 0.3])
    out = _toward_nominal(cost, u, np.array([0.0, 0.5]), 2)
    assert out[0] * 0.08 == pytest.approx(0.04, abs=0.0005)
    assert out[0] * 0.08 > 0.04  # still stops the 0.04 m/s command
    assert out[1] == 0.3  # any step raises the cost: not moved
    # a fit already at the nominal end of its plateau is left alone
    again = _toward_nominal(cost, out, np.array([0.0, 0.5]), 2)
    assert again[0] == pytest.approx(out[0], abs=1e-3)


def test_a_one_parameter_fit_finds_a_tread_narrower_than_its_grid() -> None:
    """A dead zone among densely spread commanded speeds: the training cost is a staircase
    whose lowest tread (0.02667 … 0.02693 m/s) lies between two points of the 41-point grid
    (0.026 and 0.028 m/s), where the gradient-based refinement cannot move. The fine scan
    around the best grid points lands on it."""
    from realitygap.diagnosis.fit.model import _refine_one

    commands = np.linspace(0.0, 0.08, 301)  # 0.000267 m/s apart
    truth = 0.0268

    def cost(U: np.ndarray) -> np.ndarray:
        zone = U[:, 0] * 0.08
        wrong = (commands[None, :] < zone[:, None]) != (commands[None, :] < truth)
        return wrong.sum(axis=1).astype(float)

    grid = np.linspace(0.0, 1.0, AttributionSettings().grid_points)[:, None]
    costs = cost(grid)
    assert costs.min() > 0  # no grid point on the tread
    step = 1.0 / (AttributionSettings().grid_points - 1)
    U, c = _refine_one(grid, costs, np.zeros(1), np.ones(1), step, cost)
    assert c.min() == 0.0
    found = U[np.argmin(c), 0] * 0.08
    assert commands[commands < truth].max() < found <= commands[commands >= truth].min()
    assert np.all((U >= 0.0) & (U <= 1.0)) and U.shape[0] > grid.shape[0]


class _TwoBasinProblem:
    """A stand-in for :class:`~realitygap.diagnosis.problem.problem.Problem` whose training cost
    over ``traction_slip.t_slip`` (a), ``longitudinal_slip.mu`` (b) and the baseline
    nuisance ``command_latency.delay`` (n), in range positions, has two basins: a ≈ no effect,
    and the better one at a* = 0.7, reached only with n* = 0.8, not with the calibrated
    baseline's n0 = 0.2 (a pair's start found with its own nuisances, as a single effect's
    optimum is)."""

    A_STAR, B_STAR, N_STAR, N_0 = 0.7, 0.4, 0.8, 0.2

    def __init__(self) -> None:
        from realitygap.diagnosis.problem.parameters import from_range_position
        from realitygap.diagnosis.problem.problem import AttributionSettings, Layout

        self.settings = AttributionSettings()
        self.f_scale = 1.0
        self.baseline_values = {
            "command_latency.delay": float(from_range_position("command_latency.delay", self.N_0))
        }
        self.baseline_ranges = {"command_latency.delay": (0.0, 0.3)}
        m = 12
        self.train = Layout(
            blocks=[],
            group=np.array(["g"] * 4 * m),
            column=np.array(["c"] * 4 * m),
            regime=np.array(["r"] * 4 * m),
            log=np.zeros(4 * m, dtype=np.int64),
            window=np.zeros(4 * m, dtype=np.int64),
            motion=np.zeros((4 * m, 1)),
            schema=None,  # type: ignore[arg-type]
        )
        self.holdout = self.train
        self._w = np.linspace(0.8, 1.2, m)

    def held_parameters(self, effects: object) -> dict[str, str]:
        return {}

    def surrogate_residuals(self, layout, values, batch, bias=None):  # type: ignore[no-untyped-def]
        from realitygap.diagnosis.problem.parameters import param_spec, range_position

        def u(key: str) -> np.ndarray:
            v = values.get(key, np.full(batch, self.baseline_values.get(key, np.nan)))
            if key not in values and key not in self.baseline_values:
                v = np.full(batch, param_spec(key).nominal)
            return np.array([range_position(key, float(x)) for x in np.asarray(v, dtype=float)])

        a, b, n = u("traction_slip.t_slip"), u("longitudinal_slip.mu"), u("command_latency.delay")
        a0 = float(range_position("traction_slip.t_slip", 0.0))
        z = np.stack(
            [
                10.0 * (a - a0) * (a - self.A_STAR),
                20.0 * (n - self.N_STAR) * (a - a0),
                0.1 * (b - self.B_STAR),  # the partner: a small effect
                a - self.A_STAR,
            ],
            axis=1,
        )  # (B, 4)
        return (z[:, :, None] * self._w[None, None, :]).reshape(batch, -1)


def test_a_pair_start_is_scored_with_the_nuisances_it_was_found_with() -> None:
    """A pair starts from its single effect's optimum, whose baseline nuisances were refined
    with it. Scored at the calibrated baseline's nuisances instead, that start looks worse
    than the no-effect basin and is never refined, and the pair falls into that basin."""
    from realitygap.diagnosis.fit.model import fit_model
    from realitygap.diagnosis.problem.parameters import from_range_position

    pr = _TwoBasinProblem()
    start = {
        "traction_slip.t_slip": float(from_range_position("traction_slip.t_slip", pr.A_STAR)),
        "longitudinal_slip.mu": 1.2,  # the partner at its no-effect value
        "command_latency.delay": float(from_range_position("command_latency.delay", pr.N_STAR)),
    }
    fit = fit_model(pr, ("traction_slip", "longitudinal_slip"), starts=[start])  # type: ignore[arg-type]
    want = from_range_position("traction_slip.t_slip", pr.A_STAR)
    assert fit.values["traction_slip.t_slip"] == pytest.approx(want, rel=0.02)
    assert fit.values["longitudinal_slip.mu"] == pytest.approx(
        from_range_position("longitudinal_slip.mu", pr.B_STAR), rel=0.02
    )
    assert fit.values["command_latency.delay"] == pytest.approx(
        from_range_position("command_latency.delay", pr.N_STAR), rel=0.02
    )
