"""``realitygap/ArmCalib-v0``: campaign mechanics, bad actions, the pipeline's guards."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401  (registers the ids)
from realitygap.envs.arm_calib import N_OBS, ArmCalibEnv
from realitygap.envs.arm_calib_pipeline import (
    ArmPoseMeasurement,
    MDHCalibrationEstimator,
    observation_from_corners,
)
from realitygap.estimators.arm.board_measurement import MeasurementStatus
from realitygap.estimators.arm.coded_board import CodedBoard
from realitygap.robots.arm import ArmParams

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


@pytest.fixture(scope="module")
def env():
    e = ArmCalibEnv(budget=16, n_validation=30)
    yield e
    e.close()


@pytest.fixture(scope="module")
def pool(env) -> np.ndarray:
    return env.candidate_pool(40, seed=3)


def run(env: ArmCalibEnv, actions, seed: int = 0):
    obs, info = env.reset(seed=seed)
    out = [(obs, 0.0, info)]
    for a in actions:
        obs, r, term, _, info = env.step(a)
        out.append((obs, r, info))
        if term:
            break
    return out


def test_spaces_and_reset(env: ArmCalibEnv) -> None:
    obs, info = env.reset(seed=0)
    assert obs.shape == (N_OBS,) and obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    assert info["poses_used"] == 0 and info["attempts"] == 0
    assert info["validation_rms_mm"] == pytest.approx(info["nominal_validation_rms_mm"])
    assert info["validation_rms_mm"] > 0.3  # the default real arm is off nominal
    assert info["true_pose"].shape == (4, 4)
    assert obs[69] == 1.0 and not np.any(obs[78:83])


def test_campaign_calibrates_and_rewards_telescope(env: ArmCalibEnv, pool: np.ndarray) -> None:
    steps = run(env, env.action_from_q(pool[:16]))
    rewards = [r for _, r, _ in steps[1:]]
    first, last = steps[0][2], steps[-1][2]
    assert last["poses_used"] == 16 and last["estimate_ok"], last["estimate_status"]
    assert last["validation_rms_mm"] < 0.05 < first["validation_rms_mm"]
    assert last["validation_max_mm"] < 0.15
    assert sum(rewards) == pytest.approx(
        first["validation_rms_mm"] - last["validation_rms_mm"], abs=1e-9
    )
    assert all(s[2]["reward_terms"]["invalid_pose"] == 0.0 for s in steps[1:])
    obs = steps[-1][0]
    assert obs[33] > obs[34] > _SV_FLOOR and obs[66] > 0 and obs[68] == 1.0 and obs[78] == 1.0
    with pytest.raises(RuntimeError, match="budget is spent"):
        env.step(np.zeros(6, np.float32))


_SV_FLOOR = -12.0


def test_seeded_campaigns_are_identical_and_seeds_matter(
    env: ArmCalibEnv, pool: np.ndarray
) -> None:
    acts = env.action_from_q(pool[:10])
    a, b, c = run(env, acts, 5), run(env, acts, 5), run(env, acts, 6)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x[0], y[0])
        assert x[1] == y[1]
    assert not np.array_equal(a[-1][0], c[-1][0])  # image/encoder noise differs


def test_bad_actions_are_penalised_not_fatal() -> None:
    params = ArmParams(joint_upper=(0.5, 6.0, 6.0, 6.0, 6.0, 6.0))
    e = ArmCalibEnv(params=params, budget=8, joint_half_range=(1.0, 1.2, 0.6, 0.5, 0.4, 3.0))
    try:
        e.reset(seed=0)
        cases = {
            "out_of_reach": [1.0, 0, 0, 0, 0, 0],  # q1 = 1.0 > limit 0.5
            "collision": [0.2, 0.5, 0.1, 0.9, 0.6, 0.0],  # shoulder down: into the table
            "board_not_visible": [0.3, -0.5, -0.9, -1.0, 0.6, 0.0],  # looking past the board
        }
        for outcome, a in cases.items():
            obs, r, *_, info = e.step(np.array(a, np.float32))
            assert info["outcome"] == outcome, (outcome, info["message"])
            assert info["message"]
            assert info["reward_terms"]["invalid_pose"] == -0.2
            assert r == pytest.approx(-0.2)
            assert obs[78 + ("ok", *cases).index(outcome)] == 1.0
            assert e.observation_space.contains(obs)
        # too oblique / too far: the frame is rejected with the measurement's reason
        obs, r, *_, info = e.step(np.array([-0.9, 0.5, 0.2, -0.9, 0.4, 0.0], np.float32))
        assert info["outcome"] == "measurement_failed", info["outcome"]
        assert info["measurement_status"] == "too_few_corners"
        assert "board measurement failed: too_few_corners" in info["message"]
        assert info["poses_used"] == 0 and obs[70] == pytest.approx(4 / 8)
    finally:
        e.close()


def test_action_and_constructor_errors(env: ArmCalibEnv) -> None:
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0.0], np.float32))
    with pytest.raises(ValueError, match=r"shape \(6,\)"):
        env.step(np.zeros(5, np.float32))
    with pytest.raises(ValueError, match="no reset options"):
        env.reset(options={"start": 1})
    with pytest.raises(ValueError, match="sensor_mode must be one of"):
        ArmCalibEnv(sensor_mode="photo")
    with pytest.raises(ValueError, match="budget must be a positive"):
        ArmCalibEnv(budget=0)
    with pytest.raises(ValueError, match="joint_center must be 6 finite"):
        ArmCalibEnv(joint_center=(0.0, 1.0))
    with pytest.raises(TypeError, match="budjet"):
        gym.make("realitygap/ArmCalib-v0", budjet=3)


def test_identification_is_rejected_not_adopted_on_bad_data(
    env: ArmCalibEnv, pool: np.ndarray
) -> None:
    run(env, env.action_from_q(pool[:10]))
    ms = list(env.estimator.measurements)
    assert len(ms) == 10
    # one frame decoded one cell off (a 2 cm jump): the fit cannot explain it
    bad = ms[4].board
    r, c = bad.cell_index
    T = bad.T_camera_board.copy()
    T[:3, 3] += T[:3, :3] @ np.array([0.02, 0.0, 0.0])
    shifted = replace(bad, cell_index=(r, c - 1), T_camera_board=T)
    est = MDHCalibrationEstimator(env.params.mdh, env.tool0, 0.02)
    for k, m in enumerate(ms):
        e = est.update(ArmPoseMeasurement(m.q, shifted if k == 4 else m.board))
    assert not e.ok and not e.identified
    assert "rejected" in e.status and "RMS residual" in e.status
    assert e.table is env.params.mdh  # the nominal model stays
    # too few poses: the pipeline waits, and says so
    est.reset()
    assert "waiting: 1 of 8" in est.update(ArmPoseMeasurement(ms[0].q, ms[0].board)).status
    failed = observation_from_corners(
        np.zeros((3, 2)), np.zeros((3, 2)), np.eye(3), None, CodedBoard()
    )
    with pytest.raises(ValueError, match="only successful board measurements"):
        est.update(ArmPoseMeasurement(ms[0].q, failed))
    with pytest.raises(ValueError, match="must be 'distance' or 'displacement'"):
        from realitygap.estimators.arm.identification import IdentificationSettings

        MDHCalibrationEstimator(
            env.params.mdh, env.tool0, 0.02, IdentificationSettings(mode="position")
        )


def test_a_singular_campaign_is_reported_not_adopted(env: ArmCalibEnv, pool: np.ndarray) -> None:
    steps = run(env, [env.action_from_q(pool[0])] * 9)  # the same pose nine times
    info = steps[-1][2]
    assert info["poses_used"] == 9 and not info["estimate_ok"]
    assert "poses too similar" in info["estimate_status"]
    assert info["validation_rms_mm"] == pytest.approx(info["nominal_validation_rms_mm"])
    assert sum(r for _, r, _ in steps[1:]) == 0.0


def test_geometric_measurement_rejects_what_a_detector_could_not_read(env: ArmCalibEnv) -> None:
    env.reset(seed=0)
    uv, ids = env.camera.visible_corners(np.random.default_rng(0))
    K = env.params.camera.K
    board = env.board
    ok = observation_from_corners(uv, ids, K, None, board)
    assert ok.ok and ok.cell_index is not None
    assert observation_from_corners(uv[:10], ids[:10], K, None, board).status is (
        MeasurementStatus.TOO_FEW_CORNERS
    )
    few_rows = ids[:, 0] < ids[:, 0].min() + 5  # a strip of 4 cell rows
    assert observation_from_corners(uv[few_rows], ids[few_rows], K, None, board).status is (
        MeasurementStatus.CODE_WINDOW_INCOMPLETE
    )
    noisy = uv + np.random.default_rng(1).normal(0, 5.0, uv.shape)
    assert observation_from_corners(noisy, ids, K, None, board).status is (
        MeasurementStatus.PNP_FAILED
    )
    with pytest.raises(ValueError, match="corner ids"):
        observation_from_corners(uv, ids[:-1], K, None, board)


@pytest.mark.slow
def test_rendered_capture_feeds_the_same_pipeline() -> None:
    e = ArmCalibEnv(sensor_mode="fast", budget=3, min_poses=3, n_validation=8)
    try:
        e.reset(seed=0)
        for q in e.candidate_pool(2, seed=4):
            _, _, _, _, info = e.step(e.action_from_q(q))
            assert info["outcome"] == "ok" and info["measurement_status"] == "ok"
        m = e.estimator.measurements[-1]
        truth = np.linalg.inv(e.camera.T_camera_board())[:3, 3]
        assert np.linalg.norm(m.board.camera_position_board - truth) < 0.1e-3
        assert m.board.code_mismatches == 0 and e.capture_seconds > 0 < e.measure_seconds
    finally:
        e.close()


def test_randomised_reality_redraws_the_real_arm() -> None:
    e = ArmCalibEnv(randomize_reality=True, budget=3, min_poses=3, n_validation=12)
    try:
        n0 = e.reset(seed=1)[1]["nominal_validation_rms_mm"]
        n1 = e.reset(seed=2)[1]["nominal_validation_rms_mm"]
        n0b = e.reset(seed=1)[1]["nominal_validation_rms_mm"]
        assert n0 != n1 and n0 == n0b
        obs, *_ = e.step(np.zeros(6, np.float32))
        assert e.observation_space.contains(obs)
    finally:
        e.close()


# ------------------------------------------------------------------ arm-real: bad input
def _ur10_copy(tmp_path: Path, garble: bool) -> Path:
    src = DATA / "ipa_ur10_lasertracker" / "Series_B"
    dst = tmp_path / "ipa_ur10_lasertracker" / "Series_B"
    dst.mkdir(parents=True)
    for f in src.iterdir():
        text = f.read_text(encoding="utf-8-sig")
        if f.name.startswith("measurements_"):
            lines = text.splitlines()[:201]
            if garble:
                cells = lines[5].split(";")
                cells[7] = "n/a"
                lines[5] = ";".join(cells)
            text = "\n".join(lines) + "\n"
        (dst / f.name).write_text(text, encoding="utf-8")
    fr = tmp_path / "franka_fr3_eyeinhand"
    fr.mkdir()
    (fr / "fr3_calib_data.npz").write_bytes(
        (DATA / "franka_fr3_eyeinhand" / "fr3_calib_data.npz").read_bytes()
    )
    return tmp_path


@pytest.mark.skipif(not DATA.is_dir(), reason="shared/data is not beside the checkout")
def test_arm_real_reports_garbled_csv_clearly(tmp_path: Path) -> None:
    import realitygap.experiments as E
    import realitygap.experiments.arm  # noqa: F401

    root = _ur10_copy(tmp_path, garble=True)
    with pytest.raises(ValueError, match=r"line 6, column .*expected a number"):
        E.run("arm-real", E.RunContext(data_dir=root, verbose=False))
    with pytest.raises(FileNotFoundError, match="franka_fr3_eyeinhand"):
        (root / "franka_fr3_eyeinhand" / "fr3_calib_data.npz").unlink()
        (root / "franka_fr3_eyeinhand").rmdir()
        E.run("arm-real", E.RunContext(data_dir=root, verbose=False))
