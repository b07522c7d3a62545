"""Where a command-driven gap lies: between the commands and the wheels, or between the
wheels and the body (logs of the package's independent generator)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.diagnose import Diagnosis, DiagnosisSettings, diagnose
from realitygap.diagnosis.report.summary import stage_split, summary_sentences


def _diagnose(root: Path, drive: str, **hidden: float) -> Diagnosis:
    import realitygap.independent.diffdrive as dd
    from realitygap.diagnosis.logs.read import logs_from_optiodom

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
        settings=DiagnosisSettings(drive=drive, effects=("wheelbase_error",)),
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
@pytest.mark.slow
def test_the_stage_that_carries_the_gap_is_the_one_the_effect_acts_in(
    tmp_path: Path, hidden: dict[str, float], stage: int
) -> None:
    split = _split(tmp_path, "commands", **hidden)
    assert split is not None
    assert sum(split) == pytest.approx(100.0)
    assert split[stage] > 60.0, split


@pytest.mark.slow
def test_a_tick_driven_replay_has_no_command_stage(tmp_path: Path) -> None:
    assert _split(tmp_path, "ticks", b_true=1.03) is None


@pytest.mark.parametrize(
    ("hidden", "slower"), [({"b_true": 1.03}, False), ({"speed_cap": 0.1}, True)]
)
@pytest.mark.slow
def test_wheel_gains_say_whether_the_wheels_did_what_the_commands_asked(
    tmp_path: Path, hidden: dict[str, float], slower: bool
) -> None:
    from realitygap.diagnosis.adapters.registry import get_adapter

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
        assert d.verdict.notes.actuation is None  # one robot, one drive train


def test_actuation_spread_is_cochrans_q() -> None:
    from scipy.stats import chi2

    from realitygap.diagnosis.adapters.diffdrive.actuation import actuation_spread

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


class _Travel:
    """An adapter stand-in whose logs hold given wheel travels."""

    def __init__(self, travel: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
        self.travel = travel

    def wheel_travel(self, p: object) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        return self.travel.get(p.name)  # type: ignore[attr-defined]


def test_wheel_tracking_compares_the_gain_beyond_the_training_with_the_training(
    make_prepared,
) -> None:
    from realitygap.diagnosis.adapters.diffdrive.actuation import wheel_tracking

    rng = np.random.default_rng(3)
    dur = np.ones(40)
    slow = np.column_stack([rng.uniform(0.05, 0.15, 40), rng.uniform(0.05, 0.15, 40)])
    fast = np.column_stack([rng.uniform(0.2, 0.3, 40), rng.uniform(0.2, 0.3, 40)])
    noise = 1e-3 * rng.normal(size=(2, 40, 2))
    cap = 0.21  # the left wheel tops out at 0.21 m/s; the right follows
    real_fast = np.column_stack([np.minimum(fast[:, 0], cap), fast[:, 1]])
    adapter = _Travel(
        {"sq": (slow + noise[0], slow, dur), "free": (real_fast + noise[1], fast, dur)}
    )
    prepared = [make_prepared("sq", "train", 40), make_prepared("free", "holdout", 40)]
    out = wheel_tracking(adapter.wheel_travel, prepared, v_max=0.5)  # type: ignore[arg-type]
    assert out is not None and out["beyond"] and out["departs"]
    left, right = out["wheels"]
    assert left["train_top_speed"] == pytest.approx(slow[:, 0].max())
    r, a = real_fast[:, 0] + noise[1][:, 0], fast[:, 0]
    assert left["beyond_gain"] == pytest.approx(r @ a / (a @ a), rel=1e-12)
    assert left["departs"] and not right["departs"]
    assert left["reached_max"] == pytest.approx(np.max(r), rel=1e-12)
    assert left["logs"] == ["free"] and left["n_beyond"] == 40
    # the left wheel never exceeds the cap although most windows ask for more than it
    asked_over = int(np.sum(a > (1.1 * np.max(r))))
    assert left["n_capped"] == asked_over > 3 and right["n_capped"] == 0
    assert left["capped_logs"] == ["free"] and "(in free)" in out["message"]
    assert "the left wheel" in out["message"] and "within the robot's 0.50 m/s" in out["message"]
    # the same held-out run with both wheels following: beyond, but nothing departs
    follow = _Travel({"sq": (slow + noise[0], slow, dur), "free": (fast + noise[1], fast, dur)})
    calm = wheel_tracking(follow.wheel_travel, prepared, v_max=0.5)  # type: ignore[arg-type]
    assert calm is not None and calm["beyond"] and not calm["departs"]
    assert "following the commands as in training" in calm["message"]
    # one held-out run whose drive train turns 10 % less, among six that follow: the pooled
    # gain stays within tolerance, the run's own gain departs
    logs = {"sq": (slow + noise[0], slow, dur)}
    runs = [make_prepared("sq", "train", 40)]
    for k in range(7):
        gain = 0.9 if k == 6 else 1.0
        part = slice(6 * k, 6 * k + 6) if k < 6 else slice(0, 6)
        logs[f"run{k}"] = (gain * fast[part] + noise[1][part], fast[part], dur[part])
        runs.append(make_prepared(f"run{k}", "holdout", 6))
    mixed = wheel_tracking(_Travel(logs).wheel_travel, runs, v_max=0.5)  # type: ignore[arg-type]
    assert mixed is not None and mixed["departs"]
    for w in mixed["wheels"]:
        assert abs(w["beyond_gain"] - w["train_gain"]) < 0.05 and w["n_capped"] == 0
        assert [b["log"] for b in w["by_log"] if b["departs"]] == ["run6"]
    assert "in run6" in mixed["message"]
    # held-out runs no faster than the training: nothing beyond it
    same = _Travel({"sq": (slow + noise[0], slow, dur), "free": (slow + noise[1], slow, dur)})
    within = wheel_tracking(same.wheel_travel, prepared, v_max=0.5)  # type: ignore[arg-type]
    assert within is not None and not within["beyond"]
    # no training windows, or no log with wheel travel: no answer
    assert wheel_tracking(adapter.wheel_travel, prepared[1:]) is None  # type: ignore[arg-type]
    assert wheel_tracking(lambda p: None, prepared) is None  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="min_windows"):
        wheel_tracking(adapter.wheel_travel, prepared, min_windows=1)  # type: ignore[arg-type]


def test_only_a_command_driven_replay_has_actuation_figures() -> None:
    from realitygap.diagnosis.adapters.contract import Drive
    from realitygap.diagnosis.adapters.registry import get_adapter

    for robot in ("diffdrive", "arm", "climber"):
        for drive in Drive:
            assert get_adapter(robot).actuation([], drive) == {}


@pytest.mark.slow
def test_a_wheel_capped_beyond_the_training_speeds_is_found_by_the_encoders(
    tmp_path: Path,
) -> None:
    """Independent generator: squares at the cruise speed train, a circle at twice it is
    held out; a top wheel speed between the two is invisible to the training."""
    import dataclasses

    import realitygap.independent.diffdrive as dd
    from realitygap.diagnosis.logs.read import logs_from_optiodom

    rng = np.random.default_rng(5)
    robot = dd.DriveRobot()
    fast = dataclasses.replace(robot, v_nom=2.0 * robot.v_nom)
    top = 1.5 * robot.v_nom * robot.m_per_tick / robot.cycle  # m/s, between the two
    results = {}
    for label, hidden in (("capped", dd.Hidden(speed_cap=top)), ("free", dd.Hidden())):
        root = tmp_path / label
        squares = [
            dd.simulate_run(dd.square_path(robot, 1.0, d), robot, hidden, rng)
            for d in ("cw", "ccw")
        ]
        dd.write_session(root, "010320241010", squares, robot, "square", side=1.0, rng=rng)
        circle = [dd.simulate_run(dd.circle_path(fast, 0.6, "ccw"), fast, hidden, rng)]
        dd.write_session(root, "010320241220", circle, fast, "circular", rng=rng)
        logs = logs_from_optiodom(root)
        d = diagnose(
            [lg for lg in logs if lg.meta.get("path_type") == "square"],
            [lg for lg in logs if lg.meta.get("path_type") != "square"],
            settings=DiagnosisSettings(drive="commands", effects=("wheelbase_error",)),
        )
        results[label] = d.actuation["tracking"]
        if label == "capped":  # the report shows what the encoders say, with its table
            from realitygap.diagnosis.report.writer import _coverage_section

            text = "\n".join(_coverage_section(d))
            assert "What the encoders show: beyond the training's wheel speeds" in text
            assert "| windows asking above the reached |" in text
    capped, free = results["capped"], results["free"]
    assert capped["beyond"] and capped["departs"], capped["message"]
    outer = max(capped["wheels"], key=lambda r: r.get("asked_max", 0.0))  # the circle's outer wheel
    assert outer["departs"] and outer["reached_max"] < 1.1 * top
    assert outer["beyond_gain"] < 0.95 * outer["train_gain"]
    assert free["beyond"] and not free["departs"], free["message"]
