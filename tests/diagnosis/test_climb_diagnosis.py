"""The climber's diagnosis: tether model against the robot's sensor, ride height above the
CAD surface, a blind case end to end, what cannot be seen, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.diagnosis.adapters.climber.adapter import (
    climber_params_to_meta,
    heights_above_cad,
    record_climber_logs,
    tether_model,
)
from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.diagnosis.verdict.types import VerdictKind
from realitygap.robots.climber import ClimberParams, ClimbFaults
from realitygap.robots.climber_sensors import TetherModel
from realitygap.robots.effects import Reality, make_effect


def test_tether_model_matches_the_robots_tether_sensor() -> None:
    values = {
        "climber_tether_sag.k": 0.003,
        "climber_tether_stretch.strain": 0.004,
        "climber_spool_scale.s": 1.01,
        "climber_anchor_error.dx": 0.02,
        "climber_anchor_error.dy": -0.03,
        "climber_anchor_error.dz": 0.01,
    }
    nominal = ClimberParams(tether_sigma=0.0)
    real = Reality(
        (
            make_effect("climber_tether_sag", k=0.003),
            make_effect("climber_tether_stretch", strain=0.004),
            make_effect("climber_spool_scale", s=1.01),
            make_effect("climber_anchor_error", dx=0.02, dy=-0.03, dz=0.01),
        )
    ).apply_params(nominal)
    sensor = TetherModel(real, np.random.default_rng(0), ClimbFaults())
    rng = np.random.default_rng(1)
    positions = nominal.world_from_blade(rng.uniform([1, -0.3, 0], [7, 0.3, 0.2], (20, 3)))
    readings = np.array([sensor.read(0.0, p, 0.1).length for p in positions])
    batch = {k: np.array([v]) for k, v in values.items()}
    np.testing.assert_allclose(tether_model(nominal.anchor_world, positions, batch)[0], readings)
    # the nominal model is the straight line to the nominal anchor
    straight = np.linalg.norm(positions - nominal.anchor_world, axis=1)
    np.testing.assert_allclose(tether_model(nominal.anchor_world, positions, {})[0], straight)


def test_height_above_the_cad_surface_is_the_offset_along_the_normal() -> None:
    params = ClimberParams()
    pts, nrm = params.cad_cloud(0.01)
    pick = np.random.default_rng(2).choice(len(pts), 10, replace=False)
    offsets = np.linspace(0.01, 0.06, 10)
    h = heights_above_cad(params, pts[pick] + offsets[:, None] * nrm[pick])
    np.testing.assert_allclose(h, offsets, atol=5e-4)


@pytest.fixture(scope="module")
def spool_logs() -> tuple[list[Log], list[Log]]:
    real = Reality((make_effect("climber_spool_scale", s=1.008),))
    return record_climber_logs(real, np.random.default_rng(3))


@pytest.mark.slow
def test_a_hidden_spool_scale_is_named_and_estimated(
    spool_logs: tuple[list[Log], list[Log]],
) -> None:
    train, holdout = spool_logs
    d = diagnose(train, holdout, settings=DiagnosisSettings(robot="climber"))
    assert d.verdict.kind is VerdictKind.EFFECTS, d.verdict.reason
    assert d.verdict.effects == ("climber_spool_scale",)
    assert d.ranking[0].values["climber_spool_scale.s"] == pytest.approx(1.008, abs=5e-4)
    assert d.gap["heldout_shrink_pct"] > 80.0
    # what these logs cannot show is named, with the reason
    assert "climber_spool_scale" in d.not_observable["climber_tether_stretch"]
    assert "imu" in d.not_observable["climber_gyro_bias"]


@pytest.mark.slow
def test_a_withheld_spool_scale_leaves_a_structured_remainder(
    spool_logs: tuple[list[Log], list[Log]],
) -> None:
    train, holdout = spool_logs
    library = ("climber_tether_sag", "climber_adsorption_gap")
    d = diagnose(train, holdout, settings=DiagnosisSettings(robot="climber", effects=library))
    b = d.budget
    assert b is not None
    # the spool scale is not named, nor the surface; a sag may stand in for part of the
    # reading's error (it lengthens it with the paid-out tether too), and what it leaves
    # is structured far beyond the sensors' noise, stated as such
    assert "climber_adsorption_gap" not in b.named
    rest = b.remainder["window"]
    assert rest["structured_pct"] > 5.0 * rest["noise_pct"]
    assert "points structured" in b.sentence()


def _log(**changes: object) -> Log:
    n = 40
    t = 0.1 * np.arange(n)
    params = ClimberParams()
    pos = params.world_from_blade(np.column_stack([np.linspace(2, 3, n), np.zeros(n), 0.1 + 0 * t]))
    channels = {
        "pose3_gt": np.column_stack([pos, np.zeros((n, 3))]),
        "tether": np.linalg.norm(pos - params.anchor_world, axis=1),
    }
    meta: dict[str, object] = {"robot": "climber", "params": climber_params_to_meta(params)}
    for key, value in changes.items():
        if key == "drop":
            channels.pop(str(value))
        else:
            meta[key] = value
    return Log(t=t, channels=channels, meta=meta, source="bad.npz")


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"drop": "tether"}, "tether"),
        ({"params": None}, r"meta\['params'\]"),
        ({"params": {"wheel_radius": -1.0}}, "not a valid climber"),
        ({"robot": "arm"}, "not 'climber'"),
    ],
)
def test_bad_climber_logs_are_refused_with_the_reason(
    changes: dict[str, object], message: str
) -> None:
    with pytest.raises(LogError, match=message):
        diagnose([_log(**changes)], settings=DiagnosisSettings(robot="climber"))
