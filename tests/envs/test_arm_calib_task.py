from __future__ import annotations

import numpy as np
import pytest

from realitygap.envs.arm_calib import DEFAULT_JOINT_CENTER, DEFAULT_JOINT_HALF_RANGE
from realitygap.envs.tasks.arm_calib import (
    ArmCalibRewardWeights,
    ArmCalibTask,
    AttemptOutcome,
    ViewConstraints,
)
from realitygap.estimators.arm.coded_board import CodedBoard
from realitygap.robots.arm import ArmParams
from realitygap.robots.arm_cell import BoardPlacement


def _task(budget: int = 3, **kw: object) -> ArmCalibTask:
    return ArmCalibTask(
        params=ArmParams(),
        board=CodedBoard(),
        placement=BoardPlacement(),
        view=ViewConstraints(),
        joint_center=np.array(DEFAULT_JOINT_CENTER),
        joint_half_range=np.array(DEFAULT_JOINT_HALF_RANGE),
        budget=budget,
        **kw,  # type: ignore[arg-type]
    )


def test_reward_budget_and_termination() -> None:
    task = _task(budget=2, weights=ArmCalibRewardWeights(error_drop=1e3, invalid_pose=0.5))
    task.reset(np.full(4, 1e-3))
    assert task.error_nominal == pytest.approx(1e-3)
    assert task.begin_attempt() is False
    r, terms = task.end_attempt(AttemptOutcome.OK, np.full(4, 0.4e-3))
    assert terms == pytest.approx({"error_drop": 0.6, "invalid_pose": 0.0})
    assert r == pytest.approx(0.6)
    assert task.begin_attempt() is True
    r, terms = task.end_attempt(AttemptOutcome.COLLISION, np.full(4, 0.4e-3))
    assert terms == pytest.approx({"error_drop": 0.0, "invalid_pose": -0.5})
    assert task.wasted == 1 and task.last_outcome is AttemptOutcome.COLLISION
    assert task.is_terminated()
    with pytest.raises(RuntimeError, match="budget is spent"):
        task.begin_attempt()
    with pytest.raises(ValueError, match="budget"):
        _task(budget=0)


def test_success_is_a_validation_rms_at_or_below_the_threshold() -> None:
    task = _task()
    assert task.is_success(np.full(3, 0.1e-3))
    assert not task.is_success(np.full(3, 0.11e-3))
    assert not task.is_success(np.zeros(0))


def test_candidate_pool_is_seeded_and_respects_the_collision_test() -> None:
    task = _task()
    a = task.candidate_pool(5, seed=2, collides=lambda q: False)
    np.testing.assert_array_equal(a, task.candidate_pool(5, seed=2, collides=lambda q: False))
    assert a.shape == (5, 6)
    with pytest.raises(ValueError, match="feasible poses"):
        task.candidate_pool(2, seed=2, collides=lambda q: True, max_draws=500)
