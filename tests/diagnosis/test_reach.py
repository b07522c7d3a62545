"""Library reach: every single effect fitted on the held-out windows themselves tells an
effect the training could not pin down from a gap no library effect expresses."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.core.parallel import SerialBackend
from realitygap.diagnosis.attribute import AttributionSettings, Layout
from realitygap.diagnosis.parameters import from_range_position, param_spec, range_position
from realitygap.diagnosis.reach import heldout_problem, library_reach


def _layout(n: int) -> Layout:
    return Layout(
        blocks=[],
        group=np.array(["g"] * n),
        column=np.array(["c"] * n),
        regime=np.array(["r"] * n),
        log=np.zeros(n, dtype=np.int64),
        window=np.arange(n, dtype=np.int64),
        motion=np.zeros((n, 1)),
        schema=None,  # type: ignore[arg-type]
    )


class _CapProblem:
    """A stand-in for :class:`~realitygap.diagnosis.attribute.Problem`: a top speed
    (``velocity_saturation.v_limit``) acts only in the held-out windows (the training never
    drives that fast), so the training windows cannot see it. With ``outside`` the held-out
    gap is a pattern no parameter changes (an effect outside the library)."""

    def __init__(
        self, outside: bool = False, n_train: int = 30, n_holdout: int = 20, u_star: float = 0.3
    ) -> None:
        self.u_star = u_star
        self.settings = AttributionSettings()
        self.f_scale = 1.0
        self.baseline_values = {"timestamp_offset.offset": 0.0}
        self.baseline_ranges = {"timestamp_offset.offset": (-0.05, 0.05)}
        self.train = _layout(n_train)
        self.holdout = _layout(n_holdout)
        self._ho = self.holdout
        self._outside = outside
        rng = np.random.default_rng(5)
        self._noise_tr = 0.05 * rng.standard_normal(n_train)
        self._noise_ho = 0.005 * rng.standard_normal(n_holdout)
        self._w = np.linspace(0.5, 1.5, n_holdout)

    def held_parameters(self, effects: object) -> dict[str, str]:
        return {}

    def surrogate_residuals(self, layout, values, batch, bias=None):  # type: ignore[no-untyped-def]
        def u(key: str) -> np.ndarray:
            v = values.get(key, np.full(batch, param_spec(key).nominal))
            return np.array([range_position(key, float(x)) for x in np.asarray(v, dtype=float)])

        if layout is not self._ho:  # the training: the cap is never reached
            return np.tile(self._noise_tr, (batch, 1))
        if self._outside:
            return np.tile(3.0 * self._w + self._noise_ho, (batch, 1))
        gap = 4.0 * (u("velocity_saturation.v_limit") - self.u_star)
        return gap[:, None] * self._w[None, :] + self._noise_ho[None, :]


CANDIDATES = ("wheelbase_error", "velocity_saturation")


def _reach(pr: _CapProblem, trained: float = 0.0):  # type: ignore[no-untyped-def]
    z_nom = pr.surrogate_residuals(pr.holdout, {}, 1)[0]
    mask = np.ones(pr.holdout.n, dtype=bool)
    return library_reach(pr, CANDIDATES, z_nom, mask, trained, SerialBackend())  # type: ignore[arg-type]


def test_an_effect_the_training_cannot_see_is_reached_on_the_held_out_windows() -> None:
    pr = _CapProblem()
    train_before, ranges_before = pr.train, dict(pr.baseline_ranges)
    reach = _reach(pr, trained=3.0)
    assert reach is not None and reach.expressible and not reach.training_reaches
    top = reach.rows[0]
    assert top["model"] == "velocity_saturation" and top["shrink_pct"] > 90.0
    want = float(from_range_position("velocity_saturation.v_limit", pr.u_star))
    assert top["params"]["velocity_saturation.v_limit"] == pytest.approx(want, rel=0.02)
    assert set(top["params"]) == {"velocity_saturation.v_limit"}  # no nuisance among them
    assert reach.rows[1]["model"] == "wheelbase_error" and reach.rows[1]["shrink_pct"] < 5.0
    assert "against 3 % fitted on the training" in reach.message
    assert "does not pin it down" in reach.message
    # the diagnosis's own problem is untouched: its fits still run on the training
    assert pr.train is train_before and pr.baseline_ranges == ranges_before
    js = reach.to_json()
    assert js["rows"][0]["model"] == "velocity_saturation" and js["expressible"]


def test_a_training_fit_that_reaches_the_ceiling_is_said_to_pin_it_down() -> None:
    reach = _reach(_CapProblem(), trained=95.0)
    assert reach is not None and reach.expressible and reach.training_reaches
    assert "hardly more than the 95 %" in reach.message
    assert "does not pin it down" not in reach.message
    below = _reach(_CapProblem(), trained=0.7 * reach.rows[0]["shrink_pct"])
    assert below is not None and not below.training_reaches


def test_an_effect_stretched_to_the_edge_of_its_range_does_not_express_the_gap() -> None:
    # the held-out gap asks for a top speed below the range's floor: the fit stops at the
    # floor and closes most of the gap there, but a pinned effect is stretched, not a cause
    reach = _reach(_CapProblem(u_star=-0.3))
    assert reach is not None and reach.rows[0]["model"] == "velocity_saturation"
    assert reach.rows[0]["shrink_pct"] > 60.0
    assert reach.rows[0]["pinned"] == ["velocity_saturation.v_limit"]
    assert not reach.expressible
    assert "only at the edge of its physical range (velocity_saturation.v_limit)" in reach.message
    assert "outside the library" in reach.message


def test_a_gap_no_library_effect_expresses_is_said_to_lie_outside_it() -> None:
    reach = _reach(_CapProblem(outside=True))
    assert reach is not None and not reach.expressible and not reach.training_reaches
    assert all(r["shrink_pct"] < 5.0 for r in reach.rows)
    assert "outside the library or changes between runs" in reach.message


def test_the_held_out_problem_fits_on_the_held_out_windows_with_nuisances_held() -> None:
    pr = _CapProblem()
    pr.__dict__["_held_cache"] = {("x",): {}}
    flipped = heldout_problem(pr)  # type: ignore[arg-type]
    assert flipped.train is pr.holdout and flipped.holdout is pr.holdout
    assert flipped.baseline_ranges == {} and pr.baseline_ranges  # only the copy changes
    assert "_held_cache" not in flipped.__dict__ and "_held_cache" in pr.__dict__
    assert flipped.baseline_values == pr.baseline_values  # nuisances stay at their values


def test_bad_arguments_are_refused() -> None:
    empty = _CapProblem(n_holdout=0)
    with pytest.raises(ValueError, match="no held-out windows"):
        heldout_problem(empty)  # type: ignore[arg-type]
    pr = _CapProblem()
    with pytest.raises(ValueError, match=r"must have shape \(20,\)"):
        library_reach(
            pr,  # type: ignore[arg-type]
            CANDIDATES,
            np.zeros(7),
            np.ones(7, dtype=bool),
            0.0,
            SerialBackend(),
        )
    z = np.ones(pr.holdout.n)
    assert library_reach(pr, (), z, z > 0, 0.0, SerialBackend()) is None  # type: ignore[arg-type]
    assert library_reach(pr, CANDIDATES, z, z < 0, 0.0, SerialBackend()) is None  # type: ignore[arg-type]
