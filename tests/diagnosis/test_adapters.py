"""The adapter registry: each robot declares its channels, feature schema and blind suite."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.diagnosis.adapters.climber.adapter import BladeScenes, replay_heights
from realitygap.diagnosis.adapters.registry import (
    ADAPTER_CLASSES,
    feature_group,
    get_adapter,
    known_robots,
)
from realitygap.diagnosis.logs.log import standard_channels
from realitygap.diagnosis.problem.features import FeatureSettings
from realitygap.robots.climber import ClimberParams, chart_pose


def test_the_registry_lists_every_robot_in_order() -> None:
    assert known_robots()[:3] == ("diffdrive", "arm", "climber")
    assert set(ADAPTER_CLASSES) <= set(known_robots())
    with pytest.raises(ValueError, match="no diagnosis adapter for robot 'tank'"):
        get_adapter("tank")


@pytest.mark.parametrize("robot", list(ADAPTER_CLASSES))
def test_an_adapter_declares_its_schema(robot: str) -> None:
    adapter = get_adapter(robot)
    assert adapter.robot == robot
    assert adapter.channels and adapter.schema.groups and adapter.schema.regimes
    for group in adapter.schema.groups:
        assert len(group.columns) == len(group.units) == len(group.scales)
        assert feature_group(group.name) == group
        np.testing.assert_array_equal(FeatureSettings().scale(group.name), group.scales)
    for spec in adapter.channels:
        assert standard_channels()[spec.name] == spec
    table = adapter.hidden_effects()
    assert table and set(table) <= set(adapter.effect_names())


def test_standard_channels_are_the_adapters_channels_in_registry_order() -> None:
    names = [spec.name for robot in known_robots() for spec in get_adapter(robot).channels]
    assert list(standard_channels()) == names


def test_feature_scales_are_checked_against_the_groups() -> None:
    with pytest.raises(ValueError, match=r"scales\['pose_gt'\] must hold 3 positive numbers"):
        FeatureSettings(scales={"pose_gt": (0.002, 0.002)})
    custom = FeatureSettings(scales={"ticks": (0.004, 0.004)})
    np.testing.assert_array_equal(custom.scale("ticks"), [0.004, 0.004])
    np.testing.assert_array_equal(custom.scale("pose_gt"), [0.002, 0.002, 0.002])


def test_blade_scenes_are_built_once_per_geometry_and_closed_by_their_owner() -> None:
    params = ClimberParams()
    pos, R = chart_pose(params.real_surface(), params, 3.0, 0.3, 0.0, params.h)
    pose = np.concatenate([pos, Rotation.from_matrix(R).as_rotvec()])[None]
    with BladeScenes() as scenes:
        h1 = replay_heights(params, pose, settle_steps=8, scenes=scenes)
        h2 = replay_heights(params, pose, settle_steps=8, scenes=scenes)
        assert len(scenes) == 1
        np.testing.assert_allclose(h1, h2)
    assert len(scenes) == 0


def test_a_pickled_climber_adapter_leaves_its_scenes_behind() -> None:
    adapter = get_adapter("climber")
    copy = pickle.loads(pickle.dumps(adapter))
    assert copy is not adapter and copy.scenes is adapter.scenes
