"""Library reach: every single effect fitted on the held-out windows themselves (two-fold)
tells an effect the training could not pin down from a gap no library effect expresses."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.core.parallel import SerialBackend
from realitygap.diagnosis.problem.parameters import from_range_position, param_spec, range_position
from realitygap.diagnosis.problem.problem import AttributionSettings, Layout
from realitygap.diagnosis.stages.reach import WHERE, heldout_problem, library_reach


def _layout(n: int, log: int) -> Layout:
    """``n`` windows of log ``log`` with one entry each (group ``g``)."""
    wins = np.arange(n, dtype=np.int64)
    return Layout(
        blocks=[(log, "g", wins)] if n else [],
        group=np.array(["g"] * n),
        column=np.array(["c"] * n),
        regime=np.array(["r"] * n),
        log=np.full(n, log, dtype=np.int64),
        window=wins,
        motion=np.zeros((n, 1)),
        schema=None,  # type: ignore[arg-type]
    )


class _CapProblem:
    """A stand-in for :class:`~realitygap.diagnosis.problem.problem.Problem`: a top speed
    (``velocity_saturation.v_limit``) acts only in the held-out windows (log 1; the training,
    log 0, never drives that fast), so the training windows cannot see it. With ``outside``
    the held-out gap is a pattern no parameter changes (an effect outside the library)."""

    def __init__(
        self, outside: bool = False, n_train: int = 30, n_holdout: int = 40, u_star: float = 0.3
    ) -> None:
        self.u_star = u_star
        self.settings = AttributionSettings()
        self.f_scale = 1.0
        self.baseline_values = {"timestamp_offset.offset": 0.0}
        self.baseline_ranges = {"timestamp_offset.offset": (-0.05, 0.05)}
        self.train = _layout(n_train, 0)
        self.holdout = _layout(n_holdout, 1)
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

        w, trained = layout.window, layout.log == 0
        out = np.empty((batch, layout.n))
        out[:, trained] = self._noise_tr[w[trained]]  # the training: the cap is never reached
        ho = w[~trained]
        if self._outside:
            out[:, ~trained] = 3.0 * self._w[ho] + self._noise_ho[ho]
        else:
            gap = 4.0 * (u("velocity_saturation.v_limit") - self.u_star)
            out[:, ~trained] = gap[:, None] * self._w[ho][None, :] + self._noise_ho[ho][None, :]
        return out


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
    assert reach.message.startswith(WHERE)
    assert "against 3 % fitted on the training" in reach.message
    assert "does not pin it down" in reach.message
    # the diagnosis's own problem is untouched: its fits still run on the training
    assert pr.train is train_before and pr.baseline_ranges == ranges_before
    js = reach.to_json()
    assert js["rows"][0]["model"] == "velocity_saturation" and js["expressible"]


def test_a_training_fit_that_reaches_the_ceiling_is_said_to_get_most_of_it() -> None:
    reach = _reach(_CapProblem(), trained=95.0)
    assert reach is not None and reach.expressible and reach.training_reaches
    assert "against 95 % for the verdict's model fitted on the training" in reach.message
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


def test_alternate_blocks_split_a_layout_into_two_interleaved_halves() -> None:
    lay = _layout(25, 3)
    (a, ia), (b, ib) = lay.alternate(10, 0), lay.alternate(10, 1)
    assert a.window.tolist() == [*range(10), *range(20, 25)] and b.window.tolist() == [
        *range(10, 20)
    ]
    assert sorted([*ia, *ib]) == list(range(25)) and not set(ia) & set(ib)
    assert [w.tolist() for _, _, w in a.blocks] == [a.window.tolist()]
    assert (a.log == 3).all() and a.n == 15 and b.n == 10
    # a block longer than the log leaves the second half empty
    assert lay.alternate(30, 1)[0].n == 0 and lay.alternate(30, 1)[0].blocks == []
    with pytest.raises(ValueError, match="block must be >= 1 and parity 0 or 1"):
        lay.alternate(0, 0)


def test_a_short_held_out_run_is_split_window_by_window() -> None:
    pr = _CapProblem(n_holdout=6)  # one block of 10 would leave the second half empty
    reach = _reach(pr)
    assert reach is not None and reach.rows[0]["model"] == "velocity_saturation"
    assert reach.rows[0]["shrink_pct"] > 90.0
    assert _reach(_CapProblem(n_holdout=1)) is None  # one window cannot be split


def test_the_held_out_problem_fits_on_one_part_and_scores_on_the_other() -> None:
    pr = _CapProblem()
    pr.__dict__["_held_cache"] = {("x",): {}}
    (a, _), (b, _) = pr.holdout.alternate(10, 0), pr.holdout.alternate(10, 1)
    flipped = heldout_problem(pr, a, b)  # type: ignore[arg-type]
    assert flipped.train is a and flipped.holdout is b
    assert pr.train is not a and pr.holdout is not b  # only the copy changes
    assert flipped.baseline_ranges == {} and pr.baseline_ranges
    assert "_held_cache" not in flipped.__dict__ and "_held_cache" in pr.__dict__
    assert flipped.baseline_values == pr.baseline_values  # nuisances stay at their values


def test_bad_arguments_are_refused() -> None:
    pr = _CapProblem()
    with pytest.raises(ValueError, match="fit_on and score_on need windows"):
        heldout_problem(pr, pr.holdout, _layout(0, 1))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"must have shape \(40,\)"):
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
