"""Verification: a second effect is named only if it improves the held-out residual."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from realitygap.core.parallel import SerialBackend
from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.fit.verify import heldout_gain_counts
from realitygap.diagnosis.problem.problem import Problem


def test_heldout_gain_counts_only_beyond_noise(model_fit: Callable[..., ModelFit]) -> None:
    def _fit(z: Any) -> ModelFit:
        return model_fit(z_heldout=z)

    rng = np.random.default_rng(4)
    noise = rng.normal(0.0, 1.0, 2000)
    single = _fit(noise + 0.5)  # a systematic part the second effect removes
    assert heldout_gain_counts(_fit(noise), single)
    # a second effect that only reshuffles noise (held-out residual as large as before)
    jiggle = _fit(noise + rng.normal(0.0, 0.05, noise.size))
    assert not heldout_gain_counts(jiggle, _fit(noise))
    # a model that is worse on held-out data never counts
    assert not heldout_gain_counts(single, _fit(noise))
    # a tiny but consistent gain counts (beyond the paired standard error) ...
    assert heldout_gain_counts(_fit(0.99 * noise), _fit(noise))
    # ... and so does a large one that few windows cannot prove (one window in ten)
    few = np.zeros(30)
    few[::10] = rng.normal(0.0, 3.0, 3) + 2.0
    assert heldout_gain_counts(_fit(np.zeros(30)), _fit(few))
    # no held-out residual: nothing to judge by, the gain is taken as given
    assert heldout_gain_counts(_fit([]), _fit([]))


def _model(effects: tuple[str, ...], rank: float, sizes: dict[str, float], verified: bool) -> Any:
    from realitygap.diagnosis.fit.model import ModelFit

    return ModelFit(
        effects=effects,
        keys=(),
        values={},
        stderr={},
        corr=np.eye(0),
        train_score=rank,
        bic=rank,
        heldout_score=rank,
        rank_score=rank,
        heldout_rms=1.0,
        z_heldout=np.zeros(0),
        verified=verified,
        effect_sizes=sizes,
    )


class _NoReplays(SerialBackend):
    """A backend that fails the test if a model needs a PyBullet replay."""

    def map(self, fn: Any, items: Any, shared: Any) -> Any:
        raise AssertionError("no model here needs a PyBullet replay")


def test_many_pairs_with_a_do_nothing_partner_all_rank_behind_their_single(
    toy_problem: Callable[..., Problem],
) -> None:
    """Twelve pairs add a partner at its no-effect values to the same effect ``a`` and score
    better on held-out data (their fit of ``a`` landed elsewhere): each is ``a`` itself, so
    none may be named, however many there are against the verification's step budget."""
    from realitygap.diagnosis.fit.verify import verify_ranking
    from realitygap.diagnosis.problem.problem import AttributionSettings

    settings = AttributionSettings(verify_top=1)
    single = _model(("a",), -700.0, {"a": 11.6}, verified=True)
    pairs = [
        _model(("a", f"p{k}"), -1000.0 + k, {"a": 11.6, f"p{k}": 0.0}, verified=False)
        for k in range(12)
    ]
    # a pair whose partner does act is not demoted by the size rule
    acting = _model(("a", "q"), -900.0, {"a": 11.6, "q": 2.0}, verified=True)
    nominal = _model((), -100.0, {}, verified=True)

    problem = toy_problem(windows=4, settings=settings)
    out = verify_ranking(problem, [*pairs, single, acting], nominal, _NoReplays(), lambda _: None)
    names = [f.effects for f in out.ranking]
    assert names[0] == ("a", "q")
    assert names[1] == ("a",)
    assert set(names[2:14]) == {p.effects for p in pairs}  # right behind ``a``
