"""The arm's fit holds at nominal what the training poses cannot identify."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.diagnosis.adapters.arm.adapter import record_arm_log
from realitygap.diagnosis.adapters.contract import Drive
from realitygap.diagnosis.adapters.registry import get_adapter
from realitygap.diagnosis.fit.identifiability import dependent_parameters
from realitygap.diagnosis.fit.model import fit_model
from realitygap.diagnosis.fit.status import parameter_status
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.features import FeatureSettings
from realitygap.diagnosis.problem.parameters import model_keys
from realitygap.diagnosis.problem.problem import AttributionSettings, Problem
from realitygap.estimators.arm.identification import IdentificationSettings, identify
from realitygap.estimators.arm.mdh import tool_positions
from realitygap.estimators.arm.residuals import PairObservations, ResidualMode
from realitygap.robots.arm import ArmParams


def _problem(freeze_wrist: bool, seed: int = 3) -> Problem:
    """A training and a held-out log of random poses; with ``freeze_wrist`` joint 5 stands
    still in every training pose (as on a measurement grid that keeps the wrist)."""
    rng = np.random.default_rng(seed)
    adapter = get_adapter("arm")
    prepared = []
    for split in ("train", "holdout"):
        lg = record_arm_log(None, rng, 48, name=split)
        if freeze_wrist and split == "train":
            q = np.asarray(lg["joints"], dtype=float).copy()
            q[:, 4] = 0.7
            pts = tool_positions(ArmParams().mdh, q, np.asarray(lg.meta["tool"], dtype=float))
            lg = Log(
                t=lg.t,
                channels={**lg.channels, "joints": q, "tool_pos": pts},
                meta=lg.meta,
                source=lg.source,
            )
        prepared.append(
            adapter.prepare(
                lg, split=split, drive=Drive.COMMANDS, features_settings=FeatureSettings(), sim=None
            )
        )
    return Problem(
        adapter, prepared, Drive.COMMANDS, FeatureSettings(), None, AttributionSettings()
    )


@pytest.fixture(scope="module")
def random_poses() -> Problem:
    return _problem(False)


@pytest.fixture(scope="module")
def frozen_wrist() -> Problem:
    return _problem(True)


def test_random_poses_identify_the_whole_tolerance_set(random_poses: Problem) -> None:
    assert dependent_parameters(random_poses, model_keys(["arm_geometric_tolerances"])) == {}
    # a base rotation does not change a distance; the tool length along the flange axis is d6
    held = dependent_parameters(random_poses, model_keys(["arm_tool_offset", "arm_link_length"]))
    assert held["arm_link_length.dd1"] == "no effect on the training data"
    assert held["arm_link_length.dd6"].startswith("a linear combination")
    assert set(held) == {"arm_link_length.dd1", "arm_link_length.dd6"}
    assert set(dependent_parameters(random_poses, model_keys(["arm_joint_offset"]))) == {
        "arm_joint_offset.dtheta1"
    }


def test_a_still_wrist_leaves_what_the_kinematic_identification_leaves(
    frozen_wrist: Problem,
) -> None:
    keys = model_keys(["arm_geometric_tolerances"])
    held = dependent_parameters(frozen_wrist, keys)
    assert held  # the still wrist costs directions
    # the same answer as the identification's own analysis (analytic Jacobian) on the
    # pairs of the training windows
    p = next(x for x in frozen_wrist.logs if x.split == "train")
    pts = np.asarray(p.log["tool_pos"], dtype=float)[p.context.rows]
    from realitygap.diagnosis.adapters.arm.adapter import TOOL_DIST_PAIRS

    ij = np.array([(a + i, a + j) for a, _ in p.bounds for i, j in TOOL_DIST_PAIRS])
    obs = PairObservations(
        p.context.q[ij[:, 0]], p.context.q[ij[:, 1]], pts[ij[:, 1]] - pts[ij[:, 0]]
    )
    res = identify(
        p.context.params.mdh,
        obs,
        tool=p.context.tool,
        settings=IdentificationSettings(mode=ResidualMode.DISTANCE),
    )
    free_keys = {f"arm_geometric_tolerances.d{n}" for n in res.free_params}
    assert set(keys) - set(held) == free_keys & set(keys)


def test_held_parameters_stay_at_nominal_and_are_not_findings(frozen_wrist: Problem) -> None:
    fit = fit_model(frozen_wrist, ["arm_geometric_tolerances"])
    held = frozen_wrist.held_parameters(["arm_geometric_tolerances"])
    assert set(fit.held) == set(held)
    assert not set(fit.keys) & set(held)
    for k in held:
        assert fit.values[k] == 0.0
        assert np.isnan(fit.stderr[k])
    status = parameter_status(frozen_wrist, fit)
    assert {k for k, v in status.items() if v == "not identifiable"} == set(held)
    with pytest.raises(ValueError, match="rank_tol must lie in"):
        dependent_parameters(frozen_wrist, fit.keys, rank_tol=2.0)
