"""Tick replay: wheelbase and diameter factors against UMBmark's closed form.

The tick-driven diagnosis and UMBmark (Borenstein & Feng's closed form on the end
poses of closed squares) must agree on the same squares, also when the sessions
declare different nominal geometries of the same physical robot.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from realitygap.core.geometry import wrap_angle
from realitygap.diagnosis.adapters.diffdrive.adapter import (
    DiffDriveAdapter,
    DiffDriveContext,
    values_for_log,
)
from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.features import FeatureSettings
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.diffdrive_surrogate import DiffDriveSurrogate, SurrogateInputs
from realitygap.robots.effects import Reality, make_effect
from realitygap.robots.simulation import SimSettings

GEOMETRY = ("wheelbase_error", "wheel_diameter_ratio", "wheel_radius_scale")


def _context(params: DiffDriveParams, reference: DiffDriveParams | None) -> DiffDriveContext:
    return DiffDriveContext(
        sim=SimSettings(),
        params=params,
        inputs=SurrogateInputs(0.05, np.zeros(3), commands=np.zeros((2, 2))),
        twist=np.zeros((2, 2)),
        surrogate=DiffDriveSurrogate(params),
        reference=reference,
    )


def test_values_for_log_give_every_log_the_same_physical_geometry() -> None:
    ref = DiffDriveParams(wheel_radius_left=0.042, wheel_radius_right=0.042, wheelbase=0.2)
    other = DiffDriveParams(wheel_radius_left=0.0425, wheel_radius_right=0.0425, wheelbase=0.205)
    values = {"wheelbase_error.E_b": 1.01, "wheel_radius_scale.scale": 0.995}
    physical = []
    for params in (ref, other):
        mapped = values_for_log(_context(params, ref), values)
        reality = Reality(
            tuple(make_effect(k.split(".")[0], **{k.split(".")[1]: v}) for k, v in mapped.items())
        )
        p = reality.apply_params(params)
        physical.append((p.wheel_radius_left, p.wheel_radius_right, p.wheelbase))
    np.testing.assert_allclose(physical[0], physical[1], rtol=1e-12)
    np.testing.assert_allclose(physical[0], (0.042 * 0.995, 0.042 * 0.995, 0.202), rtol=1e-12)
    # batches keep their shape; no reference leaves the values alone
    batch = values_for_log(_context(other, ref), {"wheelbase_error.E_b": np.array([1.0, 1.02])})
    np.testing.assert_allclose(batch["wheelbase_error.E_b"], [0.2 / 0.205, 1.02 * 0.2 / 0.205])
    assert values_for_log(_context(other, None), values) == values


class _Prepared:
    def __init__(self, context: DiffDriveContext, log: Log | None = None) -> None:
        self.context = context
        self.log = log
        # a replay that counted nothing: no drive-train scatter to add to the sensors' noise
        self.replay_log = log.without("ticks") if log is not None and log.has("ticks") else log


def test_fitted_robot_reads_a_ratio_and_its_scale_per_wheel() -> None:
    """One encoder 3 % high is, in the library's terms, a ratio at a kept mean and a common
    scale; read per wheel it is the right encoder alone (closed form), and a wheelbase
    verdict leaves the wheels and encoders out."""
    adapter = DiffDriveAdapter()
    params = DiffDriveParams(wheel_radius_left=0.042, wheel_radius_right=0.042, wheelbase=0.2)
    prepared = [_Prepared(_context(params, None))]
    e_c = 1.03
    values = {
        "encoder_ratio.E_c": e_c,
        "encoder_scale.scale": (e_c + 1.0) / 2.0,
        "timestamp_offset.offset": 0.004,  # a baseline nuisance: not part of the model
    }
    got = adapter.fitted_robot(prepared, ("encoder_ratio", "encoder_scale"), values)
    assert got is not None
    f = got["factors"]
    assert f["left encoder's counts per revolution"] == pytest.approx(1.0, abs=1e-12)
    assert f["right encoder's counts per revolution"] == pytest.approx(1.03, abs=1e-12)
    assert set(f) == {
        "left encoder's counts per revolution",
        "right encoder's counts per revolution",
    }
    assert "+3.00 %" in got["message"]
    # wheel sizes: E_d = 1.01 at a kept mean with a 2 % smaller mean
    got = adapter.fitted_robot(
        prepared,
        ("wheel_diameter_ratio", "wheel_radius_scale"),
        {"wheel_diameter_ratio.E_d": 1.01, "wheel_radius_scale.scale": 0.98},
    )
    assert got is not None
    f = got["factors"]
    assert f["left wheel radius"] == pytest.approx(0.98 * 2.0 / 2.01, rel=1e-12)
    assert f["right wheel radius"] == pytest.approx(0.98 * 2.0 * 1.01 / 2.01, rel=1e-12)
    got = adapter.fitted_robot(prepared, ("wheelbase_error",), {"wheelbase_error.E_b": 1.02})
    assert got is not None and got["factors"] == {"wheelbase": pytest.approx(1.02)}
    # a model that changes none of them reads as nothing
    assert (
        adapter.fitted_robot(prepared, ("command_latency",), {"command_latency.delay": 0.1}) is None
    )


def _independent_squares(root: Path, seed: int) -> tuple[list[Path], list[Path], float, float]:
    """Two square sessions of one robot declaring different wheelbases, and a circle session."""
    import realitygap.independent.diffdrive as dd

    rng = np.random.default_rng(seed)
    b_true, d_r, d_l = 0.2 * 1.012, 1.003, 0.997  # E_b = 1.012 of b = 0.2 m, E_d ≈ 1.006
    squares, held = [], []
    for k, declared_b in enumerate((0.2, 0.205)):
        robot = dd.DriveRobot(wheelbase=declared_b)
        hidden = dd.Hidden(b_true=b_true / declared_b, d_right=d_r, d_left=d_l)
        runs = [
            dd.simulate_run(dd.square_path(robot, 0.5, d), robot, hidden, rng)
            for d in ("cw", "ccw")
        ]
        squares.append(
            dd.write_session(root, f"010320240{k}10", runs, robot, "square", side=0.5, rng=rng)
        )
    robot = dd.DriveRobot()
    hidden = dd.Hidden(b_true=1.012, d_right=d_r, d_left=d_l)
    runs = [
        dd.simulate_run(dd.circle_path(robot, 0.4, d), robot, hidden, rng) for d in ("cw", "ccw")
    ]
    held.append(dd.write_session(root, "010320240220", runs, robot, "circular", rng=rng))
    return squares, held, 1.012, d_r / d_l


@pytest.mark.slow
def test_tick_replay_agrees_with_umbmark_on_the_same_squares(tmp_path: Path) -> None:
    from realitygap.calibrate import calibrate_session, pool_calibrations
    from realitygap.diagnosis.logs.read import logs_from_optiodom

    squares, _, e_b_true, e_d_true = _independent_squares(tmp_path, seed=3)
    umb = pool_calibrations([calibrate_session(p) for p in squares])
    umb_e_b = umb.E_b_for(0.084, 0.2)
    logs = logs_from_optiodom(tmp_path)
    train = [lg for lg in logs if lg.meta.get("path_type") == "square"]
    held = [lg for lg in logs if lg.meta.get("path_type") != "square"]
    d = diagnose(train, held, settings=DiagnosisSettings(drive="ticks", effects=GEOMETRY))
    assert d.nominal_reference["reference"]["wheelbase"] == pytest.approx(0.2)
    fit = next(f for f in d.ranking if "wheelbase_error" in f.effects)
    # UMBmark sees b / D: the wheelbase factor over the radius scale
    e_b = fit.values["wheelbase_error.E_b"] / fit.values.get("wheel_radius_scale.scale", 1.0)
    assert e_b == pytest.approx(umb_e_b, abs=0.003)
    assert e_b == pytest.approx(e_b_true, abs=0.003)
    assert umb_e_b == pytest.approx(e_b_true, abs=0.003)
    assert umb.E_d == pytest.approx(e_d_true, abs=0.003)
    g = d.gap
    assert g["heldout_trajectory_gap_m_best"] < 0.5 * g["heldout_trajectory_gap_m_nominal"]
    assert g["heldout_trajectory_shrink_pct_best"] == pytest.approx(
        100.0 * (1.0 - g["heldout_trajectory_gap_m_best"] / g["heldout_trajectory_gap_m_nominal"])
    )
    # the per-run rows pool back to the whole-run figures, and their shares add up
    runs = g["heldout_trajectory_runs"]
    assert [r["log"] for r in runs] == [lg.name for lg in held]
    n = sum(r["samples"] for r in runs)
    for key in ("nominal", "best"):
        pooled = np.sqrt(sum(r["samples"] * r[f"{key}_m"] ** 2 for r in runs) / n)
        assert pooled == pytest.approx(g[f"heldout_trajectory_gap_m_{key}"], rel=1e-12)
    assert sum(r["share_pct"] for r in runs) == pytest.approx(100.0)
    # diagnose-real's classical comparison replays the same calibrated baseline: with
    # neutral factors it is the baseline's gap, with UMBmark's it closes the drift
    from realitygap.experiments.diagnosis import _umbmark_heldout

    neutral = _umbmark_heldout(d, 1.0, 1.0)["umbmark_heldout_gap_cm"]
    assert neutral == pytest.approx(100.0 * g["heldout_trajectory_gap_m_baseline"], rel=1e-9)
    assert _umbmark_heldout(d, umb_e_b, umb.E_d)["umbmark_trajectory_shrink_pct"] > 50.0


@pytest.mark.slow
def test_umbmark_replay_of_the_commands_keeps_the_command_replays_baseline(
    tmp_path: Path,
) -> None:
    """diagnose-real's classical comparison in the command replay: the held-out commands
    replayed with neutral factors are the calibrated baseline's gap (its clocks, frames
    and actuator response carried over), and UMBmark's factors from the same squares close
    part of a wheelbase drift there too."""
    from realitygap.calibrate import calibrate_session, pool_calibrations
    from realitygap.diagnosis.logs.read import logs_from_optiodom
    from realitygap.experiments.diagnosis import _umbmark_heldout

    squares, _, _, _ = _independent_squares(tmp_path, seed=4)
    umb = pool_calibrations([calibrate_session(p) for p in squares])
    logs = logs_from_optiodom(tmp_path)
    assert all(lg.has("cmd") for lg in logs)
    train = [lg for lg in logs if lg.meta.get("path_type") == "square"]
    held = [lg for lg in logs if lg.meta.get("path_type") != "square"]
    d = diagnose(train, held, settings=DiagnosisSettings(drive="commands", effects=GEOMETRY))
    assert "motor_response.tau" in d.baseline.values  # the actuator response is carried
    g = d.gap
    neutral = _umbmark_heldout(d, 1.0, 1.0)
    assert neutral["umbmark_heldout_gap_cm"] == pytest.approx(
        100.0 * g["heldout_trajectory_gap_m_baseline"], rel=1e-9
    )
    classical = _umbmark_heldout(d, umb.E_b_for(0.084, 0.2), umb.E_d)
    assert 0.0 < classical["umbmark_trajectory_shrink_pct"] < 100.0


@pytest.mark.slow
def test_tick_replay_recovers_planted_factors_of_the_projects_own_generator() -> None:
    from realitygap.diagnosis.adapters.diffdrive.adapter import DiffDriveAdapter
    from realitygap.diagnosis.adapters.diffdrive.manoeuvres import MANOEUVRES
    from realitygap.diagnosis.adapters.diffdrive.replay import simulate

    params = DiffDriveParams()
    reality = Reality(
        (make_effect("wheelbase_error", E_b=1.02), make_effect("wheel_diameter_ratio", E_d=1.01))
    )
    rng = np.random.default_rng(11)

    def record(name: str) -> object:
        t, cmd = MANOEUVRES[name].applied(0.05, params)
        return simulate(
            t,
            params=params,
            reality=reality,
            commands=cmd,
            noise=DiffDriveAdapter.blind_noise,
            rng=rng,
            meta={"name": name},
        )

    train = [record("square_cw"), record("square_ccw")]
    held = [record("tour")]
    d = diagnose(train, held, settings=DiagnosisSettings(drive="ticks", effects=GEOMETRY))
    assert not d.nominal_reference  # one declared geometry: nothing to relate
    fit = d.chosen  # the budget's model
    assert fit is not None
    assert set(fit.effects) == {"wheelbase_error", "wheel_diameter_ratio"}
    # PyBullet's wheels touch the floor over their width: the body's effective wheelbase
    # is within a few tenths of a per cent of E_b · b, as for a real robot (the budget fits
    # it on whole runs, where that effective wheelbase is what the drift shows)
    for key, truth in (("wheelbase_error.E_b", 1.02), ("wheel_diameter_ratio.E_d", 1.01)):
        assert abs(fit.values[key] - truth) < max(4.0 * fit.stderr[key], 0.004), key
    assert d.gap["heldout_trajectory_shrink_pct_best"] > 50.0


def test_sample_noise_levels_read_the_ground_truths_own_noise() -> None:
    """A pose track on a slow arc at 20 Hz with independent noise of 0.5 mm and 2 mrad: a
    window feature (the difference of two samples) carries √2 times that, in feature-scale
    units; encoders quantised to one tick carry 1/√6 tick per window, log and replay each
    (closed forms). A log without ground truth gives no level."""
    rng = np.random.default_rng(3)
    params = DiffDriveParams(wheel_radius_left=0.042, wheel_radius_right=0.042, wheelbase=0.2)
    n, dt = 4000, 0.05
    t = dt * np.arange(n)
    th = 0.3 * t + 0.2 * np.sin(0.5 * t)  # turning, with a changing turn rate
    x = np.cumsum(0.1 * dt * np.cos(th))
    y = np.cumsum(0.1 * dt * np.sin(th))
    sig_xy, sig_th = 0.0005, 0.002
    truth = np.column_stack(
        [x + rng.normal(0, sig_xy, n), y + rng.normal(0, sig_xy, n), th + rng.normal(0, sig_th, n)]
    )
    truth[:, 2] = wrap_angle(truth[:, 2])  # logged wrapped: the levels unwrap it
    ticks = np.floor(np.column_stack([t, t]) * 500.0)
    log = Log(t, {"pose_gt": truth, "ticks": ticks})
    settings = FeatureSettings()
    got = DiffDriveAdapter().sample_noise_levels([_Prepared(_context(params, None), log)], settings)
    assert got is not None
    scale = dict(zip(("dx", "dy", "dtheta"), settings.scale("pose_gt"), strict=True))
    for c, sigma in (("dx", sig_xy), ("dy", sig_xy), ("dtheta", sig_th)):
        assert got["pose_gt"][c] == pytest.approx(np.sqrt(2.0) * sigma / scale[c], rel=0.08)
    mpt = 2.0 * np.pi * 0.042 / params.ticks_per_rev
    t_scale = settings.scale("ticks")[0]
    assert got["ticks"]["left"] == pytest.approx(np.sqrt(2.0 / 6.0) * mpt / t_scale, rel=1e-9)
    bare = Log(t, {"ticks": ticks})
    assert (
        DiffDriveAdapter().sample_noise_levels([_Prepared(_context(params, None), bare)], settings)
        is None
    )
