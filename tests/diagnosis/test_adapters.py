"""The adapter contract and registry: each robot declares its channels, feature schema and
blind suite; the pipeline asks an adapter only what the contract declares."""

from __future__ import annotations

import ast
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.diagnosis.adapters.climber.adapter import BladeScenes, replay_heights
from realitygap.diagnosis.adapters.contract import (
    Drive,
    LogContext,
    RobotAdapter,
)
from realitygap.diagnosis.adapters.registry import (
    ADAPTER_CLASSES,
    get_adapter,
    known_robots,
)
from realitygap.diagnosis.logs.log import Log, standard_channels
from realitygap.diagnosis.problem.features import FeatureSettings
from realitygap.diagnosis.problem.schemas import FEATURE_SCHEMAS, feature_group
from realitygap.robots.climber import ClimberParams, chart_pose
from realitygap.robots.simulation import SimSettings

DIAGNOSIS = Path(__file__).resolve().parents[2] / "diagnosis"


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


def test_the_declared_schemas_are_the_adapters_in_registry_order() -> None:
    assert FEATURE_SCHEMAS == tuple(get_adapter(robot).schema for robot in ADAPTER_CLASSES)
    with pytest.raises(KeyError, match="no robot adapter compares a feature group 'smell'"):
        feature_group("smell")


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


# --------------------------------------------------------------------------- the contract
class _Minimal(RobotAdapter):
    """Every required member and nothing else."""

    robot = "minimal"
    channels = ()
    schema = FEATURE_SCHEMAS[0]

    def check(self, log: Log, drive: Drive) -> Log:
        return log

    def prepare(self, log: Log, **kw: Any) -> Any:
        raise NotImplementedError

    def replay_features(self, prepared: Any, values: Any, drive: Drive, sim: Any) -> Any:
        raise NotImplementedError

    def log_features(self, prepared: Any, log: Log) -> Any:
        raise NotImplementedError

    def surrogate_features(self, prepared: Any, values: Any, drive: Drive) -> Any:
        raise NotImplementedError

    def probe_manoeuvres(self) -> dict[str, str]:
        return {"wiggle": "a wiggle"}

    def probe_features(self, manoeuvre: str, params_like: Any, values: Any) -> Any:
        raise NotImplementedError


REQUIRED = (
    "check",
    "prepare",
    "replay_features",
    "log_features",
    "surrogate_features",
    "probe_manoeuvres",
    "probe_features",
)


def test_the_contract_names_its_required_members() -> None:
    assert RobotAdapter.__abstractmethods__ == frozenset({*REQUIRED, "robot", "channels", "schema"})


@pytest.mark.parametrize("missing", [*REQUIRED, "robot", "schema"])
def test_an_adapter_without_a_required_member_cannot_be_built(missing: str) -> None:
    namespace = {k: v for k, v in vars(_Minimal).items() if k != missing}
    incomplete = type("Incomplete", (RobotAdapter,), namespace)
    with pytest.raises(TypeError, match=missing):
        incomplete()
    _Minimal()  # with every member it can


def test_the_optional_capabilities_default_to_absent() -> None:
    adapter = _Minimal()
    log = Log(t=np.arange(3.0), channels={})
    assert adapter.stage_residuals(None) == {}  # type: ignore[arg-type]
    assert adapter.baseline_nuisances([], Drive.COMMANDS) == {}
    assert adapter.link_logs([], Drive.COMMANDS) == {}
    assert adapter.actuator_conventions([], Drive.COMMANDS) == {}
    assert adapter.actuator_convention(log) == ""
    assert adapter.with_actuator_convention(log, "x") is log
    assert adapter.fit_actuator_limits([log], "x") is None
    assert adapter.with_actuator_limits(log, None) is log
    assert adapter.held_parameters(None, ["a.b"]) == {}  # type: ignore[arg-type]
    assert adapter.noise_levels([], FeatureSettings()) is None
    assert adapter.sample_noise_levels([], FeatureSettings()) is None
    desc = {"structured": False}
    assert adapter.residual_structure(None, {}, desc) is desc  # type: ignore[arg-type]
    assert adapter.alias_groups([]) == []
    assert adapter.fitted_robot([], (), {}) is None
    assert adapter.actuation([], Drive.COMMANDS) == {}
    assert adapter.discovery_terms(None) is None  # type: ignore[arg-type]
    assert adapter.discover_residual(None, np.zeros(0), np.zeros(0), None, None) is None  # type: ignore[arg-type]
    assert adapter.probe_description("wiggle", None) == "a wiggle"  # type: ignore[arg-type]
    assert adapter.motion_labels is None and not adapter.transient_detection
    assert adapter.stage_group == "" and adapter.drive_stages is None
    with pytest.raises(NotImplementedError, match="cannot record 'minimal' logs"):
        adapter.record_blind_logs(None, np.random.default_rng(0), None)  # type: ignore[arg-type]
    ctx = LogContext(sim=SimSettings())
    assert ctx.window_motion(np.zeros((2, 2), dtype=np.int64)) is None
    assert ctx.wheels() is None and ctx.applied_twist() is None
    assert ctx.reference_wheelbase() is None


_ASKS_OF = ("adapter", "context", "ctx")
"""Names that stand for an adapter or a prepared log's context in the diagnosis' code."""


def _probes(path: Path) -> list[str]:
    """``hasattr`` / ``getattr`` calls of a module whose object or attribute name speaks of an
    adapter or a context, as ``"line: call"``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        if not (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in ("hasattr", "getattr")
            and node.args
        ):
            continue
        words = [
            n.id if isinstance(n, ast.Name) else n.attr
            for n in ast.walk(node.args[0])
            if isinstance(n, (ast.Name, ast.Attribute))
        ]
        if len(node.args) > 1 and isinstance(node.args[1], ast.Constant):
            words.append(str(node.args[1].value))
        if any(w in word.lower() for word in words for w in _ASKS_OF):
            found.append(f"{node.lineno}: {ast.unparse(node)}")
    return found


@pytest.mark.slow
def test_no_module_of_the_diagnosis_probes_an_adapter_or_a_context() -> None:
    found = {
        str(path.relative_to(DIAGNOSIS)): _probes(path) for path in sorted(DIAGNOSIS.rglob("*.py"))
    }
    found = {k: v for k, v in found.items() if v}
    assert not found, "ask the contract instead:\n" + "\n".join(
        f"{k}:{line}" for k, lines in found.items() for line in lines
    )


def test_the_probe_check_sees_a_probe(tmp_path: Path) -> None:
    path = tmp_path / "m.py"
    path.write_text(
        "def f(problem, p, ref):\n"
        "    a = getattr(problem.adapter, 'motion_labels', None)\n"
        "    b = hasattr(p.context, 'params')\n"
        "    c = getattr(getattr(ref, 'context', None), 'params', None)\n"
        "    d = getattr(ref, 'name', None)\n"
    )
    assert [x.split(":")[0] for x in _probes(path)] == ["2", "3", "4"]
