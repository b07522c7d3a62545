from __future__ import annotations

import numpy as np
import pytest

from realitygap.envs.tasks.wall_climb import WallClimbRewardWeights, WallClimbTask


def _task(**kw: object) -> WallClimbTask:
    return WallClimbTask(blade_length=8.0, **kw)  # type: ignore[arg-type]


def test_reward_is_the_weighted_sum_of_its_terms() -> None:
    w = WallClimbRewardWeights(progress=2.0, time=0.1, effort=0.5, detach=3.0, success=7.0)
    task = _task(weights=w)
    task.reset(1.0)
    r, terms = task.get_reward(0.75, (0.5, -1.0), detached=False, success=True)
    assert terms == pytest.approx(
        {"progress": 0.5, "time": -0.1, "effort": -0.625, "detach": 0.0, "success": 7.0}
    )
    assert r == pytest.approx(sum(terms.values()))
    _, terms = task.get_reward(0.75, (0.0, 0.0), detached=True, success=False)
    assert terms["progress"] == 0.0 and terms["detach"] == -3.0


def test_detachment_success_and_termination() -> None:
    task = _task(success_tol=0.05, detach_margin=0.03)
    assert not task.is_detached(0.04, 0.04)
    assert task.is_detached(0.071, 0.04) and task.is_detached(-0.03, 0.04)
    assert task.is_success(0.04, detached=False) and not task.is_success(0.04, detached=True)
    assert task.is_terminated(True, False) and task.is_terminated(False, True)
    assert not task.is_terminated(False, False)
    with pytest.raises(AttributeError):
        WallClimbRewardWeights().progress = 1.0  # type: ignore[misc]


def test_start_and_goal_come_from_options_fixed_points_or_draws() -> None:
    task = _task(start=(2.0, 0.3), goal=(3.0, 0.4))
    rng = np.random.default_rng(0)
    start, goal = task.sample_start_goal(rng, {"goal": (4.0, 0.5)})
    np.testing.assert_array_equal(start, [2.0, 0.3])
    np.testing.assert_array_equal(goal, [4.0, 0.5])
    start, goal = _task().sample_start_goal(np.random.default_rng(1), {})
    assert start.shape == (3,) and goal.shape == (2,)
    assert 1.5 <= start[0] <= 6.0 and 0.15 <= goal[1] <= 0.6
    with pytest.raises(ValueError, match="suction side"):
        _task().check_chart("goal", (7.9, 0.3), allow_heading=False)
    with pytest.raises(ValueError, match="finite numbers"):
        _task().check_chart("start", (1.0, np.nan), allow_heading=True)
