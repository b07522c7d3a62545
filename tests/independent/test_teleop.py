"""Tests of the independent teleoperation world (realitygap.independent.teleop)."""

from __future__ import annotations

import json
import math
import pathlib
import types

import numpy as np
import pytest

from realitygap.independent.teleop import (
    CSV_HEADER,
    SESSIONS,
    RunConditions,
    TeleopHidden,
    TeleopRobot,
    simulate_runs,
    write_case,
)
from realitygap.independent.teleop_cases import LIBRARY_NAMES, TELEOP_CASES

ROBOT = TeleopRobot()
SHORT = (15.0, 20.0)  # short runs keep the tests fast
CASES = {c.name: c for c in TELEOP_CASES}


def _step(value: float, t_on: float = 0.5, duration: float = 6.0) -> tuple[np.ndarray, np.ndarray]:
    n = int(round(duration * 50.0))
    v = np.zeros(n)
    v[int(round(t_on * 50.0)) :] = value
    return v, np.zeros(n)


def _load(folder: pathlib.Path, run: dict) -> np.ndarray:
    return np.loadtxt(folder / run["file"], delimiter=",", skiprows=1, ndmin=2)


def _odometry(data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dead-reckon the logged counts with the nominal geometry."""
    per_count = 2.0 * math.pi * ROBOT.wheel_radius_m / ROBOT.counts_per_rev
    dl = np.diff(data[:, 3]) * per_count
    dr = np.diff(data[:, 4]) * per_count
    ds = 0.5 * (dl + dr)
    dth = (dr - dl) / ROBOT.wheelbase_m
    th = np.concatenate([[0.0], np.cumsum(dth)])
    mid = th[:-1] + 0.5 * dth
    x = np.concatenate([[0.0], np.cumsum(ds * np.cos(mid))])
    y = np.concatenate([[0.0], np.cumsum(ds * np.sin(mid))])
    return x, y, th


@pytest.fixture(scope="module")
def nominal_set(tmp_path_factory: pytest.TempPathFactory) -> tuple[pathlib.Path, dict]:
    folder = tmp_path_factory.mktemp("nominal")
    return folder, write_case(CASES["nominal_a"], folder, 7, run_duration_s=SHORT)


# ------------------------------------------------------------------ drive train
def test_constant_command_reaches_commanded_speed() -> None:
    (trace,) = simulate_runs([_step(0.4)], [RunConditions(duration_s=6.0)])
    late = trace.t > 4.0
    assert abs(trace.v[late].mean() / 0.4 - 1.0) < 0.01
    assert np.all(np.abs(trace.v[late] / 0.4 - 1.0) < 0.01)
    assert abs(trace.w[late]).max() < 1e-3


def test_pi_loop_overshoots_a_step_moderately() -> None:
    for value in (0.2, 0.5):
        (trace,) = simulate_runs([_step(value)], [RunConditions(duration_s=6.0)])
        overshoot = trace.v.max() / value - 1.0
        assert 0.01 < overshoot < 0.15, overshoot


def test_dead_zone_and_top_speed_effects() -> None:
    dz = TeleopHidden(deadzone_left_mps=0.04, deadzone_right_mps=0.04)
    (slow, fast) = simulate_runs(
        [_step(0.03, duration=4.0), _step(0.06, duration=4.0)],
        [RunConditions(duration_s=4.0)] * 2,
        dz,
    )
    assert abs(slow.v[-200:]).max() < 1e-3
    assert abs(fast.v[-200:].mean() - 0.06) < 0.002
    (capped,) = simulate_runs(
        [_step(0.6)], [RunConditions(duration_s=6.0)], TeleopHidden(top_speed_limit_mps=0.45)
    )
    assert abs(capped.v[-500:].mean() - 0.45) < 0.01


def test_low_grip_makes_wheels_slip_under_hard_ramps() -> None:
    cond = [RunConditions(duration_s=3.0)]
    t = np.arange(150) / 50.0
    ramp = (np.clip((t - 0.5) * 2.8, 0.0, 0.6), np.zeros(150))  # 2.8 m/s2, within the rating
    (grip,) = simulate_runs([ramp], cond)
    (ice,) = simulate_runs([ramp], cond, TeleopHidden(friction_coefficient=0.25))
    slip_grip = grip.phi_left * ROBOT.wheel_radius_m - grip.x
    slip_ice = ice.phi_left * ROBOT.wheel_radius_m - ice.x
    assert abs(slip_grip).max() < 2e-3
    assert slip_ice.max() > 0.01
    assert abs(ice.v[-100:].mean() - 0.6) < 0.01  # grip returns once at speed


# ------------------------------------------------------------------ data files
def test_json_lists_every_csv_and_files_parse(nominal_set: tuple[pathlib.Path, dict]) -> None:
    folder, meta = nominal_set
    on_disk = json.loads((folder / "dataset.json").read_text())
    assert on_disk == meta
    assert set(meta["robot"]) == {
        "wheelbase_m",
        "wheel_radius_m",
        "counts_per_rev",
        "v_max_mps",
        "w_max_radps",
        "a_max_mps2",
        "alpha_max_radps2",
    }
    assert meta["robot"]["wheelbase_m"] == 0.38 and meta["robot"]["counts_per_rev"] == 4096
    files = sorted(p.name for p in folder.glob("*.csv"))
    assert files == sorted(r["file"] for r in meta["runs"])
    assert len(files) == sum(s.runs for s in SESSIONS)
    assert {r["split"] for r in meta["runs"]} == {"train", "holdout"}
    assert {r["rate_hz"] for r in meta["runs"]} == {25.0, 40.0}
    assert not list(folder.glob("*.tmp"))
    for run in meta["runs"]:
        assert (folder / run["file"]).read_text().splitlines()[0] == CSV_HEADER
        data = _load(folder, run)
        assert data.shape[1] == 8
        t = data[:, 0]
        assert t[0] == 0.0
        assert np.allclose(np.diff(t), 1.0 / run["rate_hz"], atol=1e-6)
        assert SHORT[0] - 0.1 < t[-1] < SHORT[1]
        assert np.all(data[0, 3:5] == 0.0)
        assert np.all(data[:, 3:5] == np.round(data[:, 3:5]))
        assert abs(data[0, 5]) < 0.005 and abs(data[0, 7]) < 0.01
        assert abs(data[:, 1]).max() <= 0.6 and abs(data[:, 2]).max() <= 1.5
        assert abs(data[:, 1]).max() > 0.1  # the robot is driven


def test_counts_redraw_the_nominal_ground_truth(nominal_set: tuple[pathlib.Path, dict]) -> None:
    folder, meta = nominal_set
    for run in meta["runs"]:
        data = _load(folder, run)
        x, y, th = _odometry(data)
        assert np.hypot(x - data[:, 5], y - data[:, 6]).max() < 0.03
        assert abs(th - data[:, 7]).max() < 0.02
        assert np.hypot(data[-1, 5], data[-1, 6]) > 0.3 or abs(data[:, 7]).max() > 0.3


def test_wheelbase_case_turns_less_than_the_counts_say(tmp_path: pathlib.Path) -> None:
    meta = write_case(CASES["wheelbase_plus_2p5pct"], tmp_path, 3, run_duration_s=SHORT)
    gt, od = [], []
    for run in meta["runs"]:
        data = _load(tmp_path, run)
        _, _, th = _odometry(data)
        k = int(run["rate_hz"])  # one-second increments
        gt.append(data[k::k, 7] - data[:-k:k, 7])
        od.append(th[k::k] - th[:-k:k])
    g, o = np.concatenate(gt), np.concatenate(od)
    ratio = float(np.dot(g, o) / np.dot(o, o))
    assert abs(ratio - 1.0 / 1.025) < 0.004, ratio


def test_same_seed_same_bytes_other_seed_differs(tmp_path: pathlib.Path) -> None:
    case = CASES["traction_slip_mu_0p25"]
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    ma = write_case(case, a, 11, run_duration_s=(8.0, 10.0))
    mb = write_case(case, b, 11, run_duration_s=(8.0, 10.0))
    write_case(case, c, 12, run_duration_s=(8.0, 10.0))
    assert ma == mb
    names = [r["file"] for r in ma["runs"]] + ["dataset.json"]
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes()
    assert any((a / n).read_bytes() != (c / n).read_bytes() for n in names if n.endswith(".csv"))


def test_written_data_do_not_name_the_case(nominal_set: tuple[pathlib.Path, dict]) -> None:
    folder, _ = nominal_set
    text = (folder / "dataset.json").read_text()
    assert "nominal" not in text and "hidden" not in text


# ------------------------------------------------------------------ case list
def test_twenty_fixed_cases() -> None:
    assert len(TELEOP_CASES) == 20
    names = [c.name for c in TELEOP_CASES]
    assert len(set(names)) == 20
    nominal = [c for c in TELEOP_CASES if c.nominal]
    assert len(nominal) == 3 and all(not c.hidden and not c.accepted for c in nominal)
    in_lib = [c for c in TELEOP_CASES if c.accepted]
    assert len(in_lib) == 10
    out_lib = [c for c in TELEOP_CASES if not c.nominal and not c.accepted]
    assert len(out_lib) == 7 and all(c.hidden for c in out_lib)
    hidden_fields = set(TeleopHidden.__dataclass_fields__)
    for c in TELEOP_CASES:
        for name in c.accepted + c.ticks_aliases + c.command_aliases:
            assert name in LIBRARY_NAMES, (c.name, name)
        assert set(c.hidden) <= hidden_fields, c.name
        assert c.drives and set(c.drives) <= {"commands", "ticks"}
        assert c.motion in ("normal", "aggressive")
        TeleopHidden(**c.hidden)


def test_expected_names_per_replay() -> None:
    enc = CASES["encoder_4pct_more_counts"]
    assert set(enc.expected("ticks")) == {"encoder_scale", "wheel_radius_scale"}
    combo = CASES["wheelbase_plus_2pct_delay_80ms"]
    assert combo.expected("ticks") == ("wheelbase_error",)
    assert set(combo.expected("commands")) == {"wheelbase_error", "command_latency"}
    assert CASES["command_delay_120ms"].expected("ticks") == ()
    assert CASES["caster_side_drag"].expected("commands") == ()


def test_unknown_hidden_field_is_rejected(tmp_path: pathlib.Path) -> None:
    bad = types.SimpleNamespace(hidden={"wheel_base_factor": 1.1})
    with pytest.raises(ValueError):
        write_case(bad, tmp_path, 0, run_duration_s=SHORT)


def test_nominal_repeats_differ_under_a_shared_seed(tmp_path: pathlib.Path) -> None:
    a, c = tmp_path / "a", tmp_path / "c"
    ma = write_case(CASES["nominal_a"], a, 5, run_duration_s=(8.0, 10.0))
    write_case(CASES["nominal_c"], c, 5, run_duration_s=(8.0, 10.0))
    first = ma["runs"][0]["file"]
    assert (a / first).read_bytes() != (c / first).read_bytes()
