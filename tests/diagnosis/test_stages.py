"""Where a command-driven gap lies: between the commands and the wheels, or between the
wheels and the body (logs of the package's independent generator)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.diagnose import Diagnosis, DiagnosisSettings, diagnose
from realitygap.diagnosis.summary import stage_split, summary_sentences


def _diagnose(root: Path, drive: str, **hidden: float) -> Diagnosis:
    import realitygap.independent.diffdrive as dd
    from realitygap.diagnosis.io import logs_from_optiodom

    rng = np.random.default_rng(11)
    robot = dd.DriveRobot()
    h = dd.Hidden(**hidden)
    squares = [dd.simulate_run(dd.square_path(robot, 1.0, d), robot, h, rng) for d in ("cw", "ccw")]
    dd.write_session(root, "010320241010", squares, robot, "square", side=1.0, rng=rng)
    circles = [dd.simulate_run(dd.circle_path(robot, 0.5, "cw"), robot, h, rng)]
    dd.write_session(root, "010320241220", circles, robot, "circular", rng=rng)
    logs = logs_from_optiodom(root)
    train = [lg for lg in logs if lg.meta.get("path_type") == "square"]
    held = [lg for lg in logs if lg.meta.get("path_type") != "square"]
    d = diagnose(
        train,
        held,
        settings=DiagnosisSettings(drive=drive, effects=("wheelbase_error",), scales=None),
    )
    return d


def _split(root: Path, drive: str, **hidden: float) -> tuple[float, float] | None:
    d = _diagnose(root, drive, **hidden)
    split = stage_split(d)
    if split is not None:
        assert any(s.startswith("By pipeline stage, ") for s in summary_sentences(d))
    return split


@pytest.mark.parametrize(
    ("hidden", "stage"),
    [({"stiction": 0.03, "delay": 0.12}, 0), ({"b_true": 1.03}, 1)],
    ids=["drive train", "wheelbase"],
)
def test_the_stage_that_carries_the_gap_is_the_one_the_effect_acts_in(
    tmp_path: Path, hidden: dict[str, float], stage: int
) -> None:
    split = _split(tmp_path, "commands", **hidden)
    assert split is not None
    assert sum(split) == pytest.approx(100.0)
    assert split[stage] > 60.0, split


def test_a_tick_driven_replay_has_no_command_stage(tmp_path: Path) -> None:
    assert _split(tmp_path, "ticks", b_true=1.03) is None


@pytest.mark.parametrize(
    ("hidden", "slower"), [({"b_true": 1.03}, False), ({"speed_cap": 0.1}, True)]
)
def test_wheel_gains_say_whether_the_wheels_did_what_the_commands_asked(
    tmp_path: Path, hidden: dict[str, float], slower: bool
) -> None:
    from realitygap.diagnosis.adapters import get_adapter

    d = _diagnose(tmp_path, "commands", **hidden)
    adapter = get_adapter("diffdrive")
    gains = [adapter.command_wheel_gains(p) for p in d.prepared]
    assert all(g is not None for g in gains)
    dist = np.array([g["distance_gain"] for g in gains])
    if slower:  # wheels capped below the commanded speed travel less than asked
        assert np.all(dist < 0.97), dist
    else:  # a wider axle acts after the wheels: they travel and turn as asked
        turn = np.array([g["turn_gain"] for g in gains])
        assert np.all(np.abs(dist - 1.0) < 0.02), dist
        assert np.all(np.abs(turn - 1.0) < 0.03), turn
        assert "actuation" not in d.verdict.notes  # one robot, one drive train


def test_actuation_spread_is_cochrans_q() -> None:
    from scipy.stats import chi2

    from realitygap.diagnosis.actuation import actuation_spread

    rows = [
        {"log": "a", "turn_gain": 0.986, "turn_gain_se": 0.002},
        {"log": "b", "turn_gain": 1.025, "turn_gain_se": 0.004},
        {"log": "c", "turn_gain": 1.001, "turn_gain_se": 0.003},
        {"log": "d", "turn_gain": float("nan"), "turn_gain_se": 0.003},  # left out
    ]
    out = actuation_spread(rows)
    assert out is not None and out["logs"] == ["a", "b", "c"]
    g, se = np.array([0.986, 1.025, 1.001]), np.array([0.002, 0.004, 0.003])
    w = se**-2
    mean = w @ g / w.sum()
    q = w @ (g - mean) ** 2
    assert out["mean"] == pytest.approx(mean, rel=1e-12)
    assert out["q"] == pytest.approx(q, rel=1e-12)
    assert out["p"] == pytest.approx(chi2.sf(q, 2), rel=1e-9)
    assert out["differs"] and "0.986 in a … 1.025 in b" in out["message"]
    # gains that scatter as their errors say are one drive train
    rng = np.random.default_rng(4)
    same = [
        {"log": str(i), "turn_gain": 1.0 + 0.003 * rng.normal(), "turn_gain_se": 0.003}
        for i in range(8)
    ]
    one = actuation_spread(same)
    assert one is not None and not one["differs"]
    assert actuation_spread(rows[:1]) is None
    with pytest.raises(ValueError, match="alpha must lie in"):
        actuation_spread(rows, alpha=1.5)
