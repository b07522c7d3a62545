"""Learned baselines: training, saving, loading and refusing policies that do not fit."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import realitygap
from realitygap.baselines import rl
from realitygap.envs.layouts import clearance

ENV_ID = "realitygap/WheeledNav-v0"

pytest.importorskip("stable_baselines3")


def _tiny_hyperparams(n_beams: int = 8) -> dict:
    return {
        "n_timesteps": 256,
        "n_envs": 1,
        "vec_env": "dummy",
        "env_kwargs": {"sensor_mode": "fast", "n_obstacles": 0, "n_beams": n_beams},
        "policy": "MlpPolicy",
        "n_steps": 128,
        "batch_size": 64,
        "n_epochs": 1,
        "policy_kwargs": {"net_arch": [16, 16]},
        "action_deadband": 0.1,
        "obs_features": "wheeled_nav_goal_polar",
        "normalize": {"obs": True},
        "curriculum": {
            "start": {"success_pos_tol": 0.3, "success_ang_tol": 0.5},
            "end": {"success_pos_tol": 0.03, "success_ang_tol": 0.0872665},
            "n_stages": 4,
            "gate": "eval",
            "max_stage_steps": 100,
        },
    }


@pytest.fixture(scope="module")
def tiny_ppo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ppo")
    cfg = rl.TrainConfig(
        env_id=ENV_ID,
        algo="ppo",
        out_dir=out,
        seed=3,
        hyperparams=_tiny_hyperparams(),
        checkpoint_every=128,
        eval_every=256,
        eval_episodes=1,
        progress_every_s=1e9,
    )
    result = rl.train(cfg)
    assert result.timesteps == 256
    return result.model_path


@pytest.mark.slow
def test_training_writes_model_metadata_curve_and_checkpoints(tiny_ppo: Path) -> None:
    folder = tiny_ppo.parent
    meta = json.loads((folder / "model.json").read_text())
    assert meta["env_id"] == ENV_ID and meta["algo"] == "ppo" and meta["seed"] == 3
    assert meta["env_observation_space"]["shape"] == [12 + 8]
    assert meta["observation_space"]["shape"] == [12 + 8 + 5]  # with the goal features
    assert meta["action_deadband"] == 0.1 and len(meta["obs_normalizer"]["mean"]) == 25
    assert meta["curriculum_stage"] >= 1  # the stage step limit promoted it
    assert (folder / "episodes.csv").read_text().startswith("timesteps,")
    assert (folder / "eval.csv").read_text().startswith("timesteps,wall_s,success,reached_10cm")
    assert set(meta["final_eval"]) == {"success", "reached_10cm", "collision", "return"}
    assert sorted(p.name for p in (folder / "checkpoints").iterdir()) == [
        "model_128_steps.json",
        "model_128_steps.zip",
        "model_256_steps.json",
        "model_256_steps.zip",
    ]
    assert not [p for p in folder.iterdir() if p.name.startswith(".")], "temporary files left"


def test_saved_policy_loads_and_predicts_the_right_shape(tiny_ppo: Path) -> None:
    env = gym.make(ENV_ID, n_obstacles=0, n_beams=8)
    policy = rl.load_policy(tiny_ppo, env)
    obs, _ = env.reset(seed=0)
    env.close()
    action, state = policy.predict(obs, deterministic=True)
    assert action.shape == (2,) and action.dtype == np.float32 and state is None
    assert np.all(np.abs(action) <= 1.0)
    batch, _ = policy.predict(np.stack([obs, obs, obs]))
    assert batch.shape == (3, 2)
    np.testing.assert_array_equal(batch[0], action)
    # features, normalisation and dead band are part of the policy
    assert policy.obs_normalizer is not None
    x = policy.obs_normalizer(rl.wheeled_nav_goal_features(obs))
    raw, _ = policy.model.predict(x, deterministic=True)
    np.testing.assert_allclose(action, rl.deadband(raw, 0.1))


def test_policy_for_another_observation_space_is_refused(tiny_ppo: Path) -> None:
    env = gym.make(ENV_ID, n_beams=64)
    with pytest.raises(ValueError, match=r"expects observations of shape \(20,\).*\(76,\)"):
        rl.load_policy(tiny_ppo, env)
    env.close()


def test_policy_for_another_env_is_refused(tiny_ppo: Path, tmp_path: Path) -> None:
    other = tmp_path / "other.zip"
    other.write_bytes(tiny_ppo.read_bytes())
    meta = json.loads(tiny_ppo.with_suffix(".json").read_text())
    meta["env_id"] = "realitygap/ArmCalib-v0"
    other.with_suffix(".json").write_text(json.dumps(meta))
    env = gym.make(ENV_ID, n_obstacles=0, n_beams=8)
    with pytest.raises(ValueError, match="was trained for 'realitygap/ArmCalib-v0'"):
        rl.load_policy(other, env)
    env.close()


def test_not_a_policy_file_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.zip"
    bad.write_text("not a zip")
    with pytest.raises(ValueError, match="not a stable-baselines3 policy file"):
        rl.read_policy_meta(bad)
    with pytest.raises(FileNotFoundError, match="no policy file"):
        rl.read_policy_meta(tmp_path / "missing.zip")


def test_missing_stable_baselines3_gives_the_install_hint(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)
    with pytest.raises(ImportError, match=r"pip install 'realitygap\[rl\]'"):
        rl.require_sb3()
    with pytest.raises(ImportError, match=r"pip install 'realitygap\[rl\]'"):
        rl.algo_class("ppo")


@pytest.mark.parametrize("algo", rl.ALGOS)
def test_hyperparameter_files_are_valid_and_keyed_by_registered_envs(algo: str) -> None:
    table = json.loads((rl.HYPERPARAMS_DIR / f"{algo}.json").read_text())
    env_ids = [k for k in table if not k.startswith("_")]
    assert "realitygap/WheeledNav-v0" in env_ids
    vector_ids = set(rl.VECTOR_ENVS.values())
    for env_id in env_ids:
        assert env_id in realitygap.ENV_IDS or env_id in vector_ids
        hp = rl.load_hyperparams(algo, env_id)
        assert hp["n_timesteps"] > 0 and "sensor_mode" in hp["env_kwargs"]
        if "curriculum" in hp:
            rl.Curriculum.from_dict(hp["curriculum"])
        rl.obs_feature_fn(hp.get("obs_features"))
    for env_id in set(realitygap.ENV_IDS) - set(env_ids):
        with pytest.raises(KeyError, match="Add an entry"):
            rl.load_hyperparams(algo, env_id)


def test_bad_names_are_refused_with_suggestions(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown algorithm 'ddpg'"):
        rl.check_algo("ddpg")
    with pytest.raises(ValueError, match="Did you mean 'realitygap/WheeledNav-v0'"):
        rl.check_env_id("realitygap/WheeledNav-v1")
    with pytest.raises(KeyError, match="no hyperparameters for 'realitygap/Nope-v0'"):
        rl.load_hyperparams("ppo", "realitygap/Nope-v0")


def test_deadband_closed_form() -> None:
    a = np.array([-1.0, -0.55, -0.1, -0.05, 0.0, 0.05, 0.1, 0.55, 1.0])
    expected = np.array([-1.0, -0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 1.0])
    np.testing.assert_allclose(rl.deadband(a, 0.1), expected, atol=1e-7)
    np.testing.assert_array_equal(rl.deadband(a, 0.0), a.astype(np.float32))
    with pytest.raises(ValueError, match=r"action_deadband must be in \[0, 1\)"):
        rl.deadband(a, 1.0)


def test_stop_gate_closed_form() -> None:
    a = np.array([[0.5, -0.3, -0.2], [0.5, -0.3, 0.1], [0.05, 1.0, -1.0]], dtype=np.float32)
    np.testing.assert_allclose(rl.stop_gate(a), [[0.5, -0.3], [0.0, 0.0], [0.05, 1.0]])
    np.testing.assert_allclose(rl.stop_gate(a, 0.1)[2], [0.0, 1.0])
    io = rl.PolicyIO(action_stop_gate=True)
    assert rl.PolicyIO.from_dict(io.to_dict()) == io
    env = io.wrap(gym.make(ENV_ID, n_obstacles=0))
    assert env.action_space.shape == (3,)
    env.reset(seed=0)
    env.step(np.array([1.0, 0.0, 1.0], dtype=np.float32))  # gate open: the robot stays
    assert env.unwrapped.robot.command.tolist() == [0.0, 0.0]
    env.close()


def test_goal_features_match_the_closed_form() -> None:
    rng = np.random.default_rng(2)
    obs = rng.uniform(-1, 1, size=(6, 20)).astype(np.float32)
    theta, theta_goal = rng.uniform(-np.pi, np.pi, 6), rng.uniform(-np.pi, np.pi, 6)
    obs[:, 2], obs[:, 3] = np.cos(theta), np.sin(theta)
    obs[:, 6], obs[:, 7] = np.cos(theta_goal), np.sin(theta_goal)
    x = rl.wheeled_nav_goal_features(obs)
    assert x.shape == (6, 25)
    np.testing.assert_array_equal(x[:, :20], obs)
    np.testing.assert_allclose(x[:, 20], np.hypot(obs[:, 8], obs[:, 9]), rtol=1e-6)
    alpha = np.arctan2(obs[:, 9], obs[:, 8])
    np.testing.assert_allclose(x[:, 21:23], np.stack([np.cos(alpha), np.sin(alpha)], 1), atol=1e-6)
    beta = theta_goal - theta
    np.testing.assert_allclose(x[:, 23:25], np.stack([np.cos(beta), np.sin(beta)], 1), atol=1e-6)
    with pytest.raises(ValueError, match="unknown obs_features 'polar'"):
        rl.obs_feature_fn("polar")


def test_zoomed_goal_features_match_the_closed_form() -> None:
    rng = np.random.default_rng(4)
    obs = rng.uniform(-0.2, 0.2, size=(6, 20)).astype(np.float32)
    theta, beta = rng.uniform(-np.pi, np.pi, 6), rng.uniform(-0.3, 0.3, 6)
    obs[:, 2], obs[:, 3] = np.cos(theta), np.sin(theta)
    obs[:, 6], obs[:, 7] = np.cos(theta + beta), np.sin(theta + beta)
    x = rl.wheeled_nav_goal_zoom_features(obs)
    assert x.shape == (6, 20 + rl.OBS_FEATURES["wheeled_nav_goal_zoom"][1])
    np.testing.assert_array_equal(x[:, :25], rl.wheeled_nav_goal_features(obs))
    xr, yr = obs[:, 8], obs[:, 9]
    expected = [np.tanh(xr / 0.05), np.tanh(yr / 0.05), np.tanh(xr / 0.3), np.tanh(yr / 0.3)]
    expected += [np.tanh(beta / 0.1), np.tanh(beta / 0.5)]
    np.testing.assert_allclose(x[:, 25:], np.stack(expected, 1), atol=1e-5)
    # a 1 cm offset moves the finest column by about 0.2, the polar distance by 0.01
    near = np.zeros((2, 20), np.float32)
    near[:, 2] = near[:, 6] = 1.0
    near[1, 8] = 0.01
    d = np.diff(rl.wheeled_nav_goal_zoom_features(near), axis=0)[0]
    assert d[20] == pytest.approx(0.01, abs=1e-6) and d[25] == pytest.approx(0.197, abs=1e-3)


def test_smooth_goal_bearing_is_continuous_at_the_goal() -> None:
    # a millimetre circle around the goal: the polar bearing turns through 360°, the
    # smooth one stays within a few hundredths of zero
    phi = np.linspace(-np.pi, np.pi, 9)
    obs = np.zeros((9, 20), np.float32)
    obs[:, 2] = obs[:, 6] = 1.0
    obs[:, 8], obs[:, 9] = 1e-3 * np.cos(phi), 1e-3 * np.sin(phi)
    polar = rl.wheeled_nav_goal_zoom_features(obs)[:, 21:23]
    smooth = rl.wheeled_nav_goal_smooth_features(obs)
    assert np.ptp(polar[:, 0]) > 1.9
    assert np.max(np.abs(smooth[:, 21:23])) == pytest.approx(1e-3 / np.hypot(1e-3, 0.05), rel=1e-4)
    # elsewhere the same columns as the zoomed features; the bearing, far away, a unit vector
    rng = np.random.default_rng(5)
    far = rng.uniform(-3, 3, size=(6, 20)).astype(np.float32)
    zoom, smooth = rl.wheeled_nav_goal_zoom_features(far), rl.wheeled_nav_goal_smooth_features(far)
    keep = [k for k in range(zoom.shape[1]) if k not in (21, 22)]
    np.testing.assert_array_equal(smooth[:, keep], zoom[:, keep])
    rho = np.hypot(far[:, 8], far[:, 9])
    np.testing.assert_allclose(
        smooth[:, 21:23], zoom[:, 21:23] * (rho / np.hypot(rho, 0.05))[:, None], rtol=1e-5
    )


def _rigidly_moved(obs: np.ndarray, dx: float, dy: float, dth: float) -> np.ndarray:
    """``obs`` of the same scene after moving the world (robot and goal) by a rigid motion:
    the world-frame columns change, the robot-frame ones do not."""
    out = obs.copy()
    c, s = np.cos(dth), np.sin(dth)
    for i in (0, 4):  # positions
        x, y = obs[:, i].astype(float), obs[:, i + 1].astype(float)
        out[:, i], out[:, i + 1] = c * x - s * y + dx, s * x + c * y + dy
    for i in (2, 6):  # headings as (cos, sin)
        x, y = obs[:, i].astype(float), obs[:, i + 1].astype(float)
        out[:, i], out[:, i + 1] = c * x - s * y, s * x + c * y
    return out


def test_egocentric_features_do_not_see_where_the_room_puts_the_robot() -> None:
    rng = np.random.default_rng(6)
    obs = rng.uniform(0.0, 1.0, size=(6, 20)).astype(np.float32)
    theta, theta_g = rng.uniform(-np.pi, np.pi, 6), rng.uniform(-np.pi, np.pi, 6)
    theta_g[0] = theta[0]  # facing the goal heading
    obs[:, 0:2], obs[:, 4:6] = rng.uniform(-3, 3, (6, 2)), rng.uniform(-3, 3, (6, 2))
    obs[:, 2], obs[:, 3], obs[:, 6], obs[:, 7] = (
        np.cos(theta),
        np.sin(theta),
        np.cos(theta_g),
        np.sin(theta_g),
    )
    d = obs[:, 4:6] - obs[:, 0:2]
    obs[:, 8] = np.cos(theta) * d[:, 0] + np.sin(theta) * d[:, 1]
    obs[:, 9] = -np.sin(theta) * d[:, 0] + np.cos(theta) * d[:, 1]
    ego = rl.wheeled_nav_egocentric_features(obs)
    # the smooth features less the eight world-frame columns
    assert ego.shape == (6, 20 + rl.OBS_FEATURES["wheeled_nav_egocentric"][1])
    np.testing.assert_array_equal(ego, rl.wheeled_nav_goal_smooth_features(obs)[:, 8:])
    moved = _rigidly_moved(obs, 1.7, -2.2, 2.5)
    # the smooth features change with the room, the egocentric ones do not
    assert np.max(np.abs(rl.wheeled_nav_goal_smooth_features(moved)[:, :8] - obs[:, :8])) > 1.0
    np.testing.assert_allclose(rl.wheeled_nav_egocentric_features(moved), ego, atol=1e-5)
    # 3° off the goal heading is seen (the finest zoomed heading column moves by tanh(0.5))
    turned = obs.copy()
    turned[:, 6], turned[:, 7] = np.cos(theta_g + 0.05), np.sin(theta_g + 0.05)
    change = rl.wheeled_nav_egocentric_features(turned)[0] - ego[0]
    assert np.max(np.abs(change)) == pytest.approx(np.tanh(0.5), abs=1e-4)


def test_mirror_of_egocentric_inputs_is_the_input_of_the_mirrored_scene() -> None:
    env = gym.make(ENV_ID, n_obstacles=2, sensor_mode="fast")
    io = rl.PolicyIO(
        obs_features="wheeled_nav_egocentric",
        action_stop_gate=True,
        obs_memory={"n_sectors": 36, "horizon": 2.0},
        obs_rest_timer={"horizon_steps": 40},
    ).for_env(env)
    perm, sign, action_sign = io.mirror(env)
    obs0, _ = env.reset(seed=0)
    n_beams = obs0.size - 12
    rng = np.random.default_rng(8)
    # the robot drives along the world x axis (the mirror line) past a few obstacle hits
    states, mirrored_states = [io.new_episode_features()], [io.new_episode_features()]
    goal = (1.2, 0.4, 0.3)
    for step in range(3):
        x_r = 0.1 * step
        raw = np.zeros(obs0.size, np.float32)
        raw[:12] = (
            x_r,
            0.0,
            1.0,
            0.0,
            goal[0],
            goal[1],
            np.cos(goal[2]),
            np.sin(goal[2]),
            goal[0] - x_r,
            goal[1],
            0.3,
            0.2,
        )
        scan = np.ones(n_beams, np.float32)
        hits = rng.choice(n_beams, size=4, replace=False)
        scan[hits] = rng.uniform(0.05, 0.2, 4)
        raw[12:] = scan
        m = raw.copy()
        m[[1, 3, 5, 7, 9, 11]] *= -1.0
        m[12:] = scan[::-1]
        x = io.observation(raw[None], states)[0]
        xm = io.observation(m[None], mirrored_states)[0]
        assert x.shape == perm.shape == sign.shape
        np.testing.assert_allclose(x[perm] * sign, xm, atol=1e-5)
    assert np.any(x[4 + n_beams : 4 + n_beams + 36] < 1.0)  # the memory holds hits
    # mirroring twice is the identity; the turn command flips, speed and stop gate do not
    np.testing.assert_array_equal((x[perm] * sign)[perm] * sign, x)
    np.testing.assert_array_equal(action_sign, [1.0, -1.0, 1.0])
    # a policy whose inputs are in the world frame has no mirror
    with pytest.raises(ValueError, match="wheeled_nav_egocentric"):
        rl.PolicyIO(obs_features="wheeled_nav_goal_smooth").mirror(env)


def test_feature_wrapper_space_matches_what_the_map_gives() -> None:
    env = gym.make(ENV_ID, n_obstacles=2)
    for name, (_fn, n_extra) in rl.OBS_FEATURES.items():
        wrapped = rl.ObsFeatures(env, name)
        obs, _ = wrapped.reset(seed=0)
        assert obs.shape == wrapped.observation_space.shape
        assert obs.shape[-1] == env.observation_space.shape[-1] + n_extra
        assert wrapped.observation_space.contains(obs)
        # the observation columns a map keeps keep their bounds
        drop = rl.OBS_FEATURES_DROP.get(name, 0)
        kept = env.observation_space.shape[-1] - drop
        np.testing.assert_array_equal(
            wrapped.observation_space.low[:kept], env.observation_space.low[drop:]
        )


def test_shaping_potential_telescopes_and_collisions_cost_more() -> None:
    def run(wrappers: list) -> tuple[list[float], list[dict]]:
        env = rl.apply_train_wrappers(
            gym.make(ENV_ID, n_obstacles=0, start=(0.0, 0.0, 0.0), goal=(1.5, 0.2, 1.0)),
            wrappers,
        )
        _, info = env.reset(seed=0)
        rewards, infos = [], [info]
        for _ in range(40):
            _, r, term, trunc, info = env.step(np.array([0.6, 0.3], dtype=np.float32))
            rewards.append(float(r))
            infos.append(info)
            if term or trunc:
                break
        env.close()
        return rewards, infos

    shaping = {"name": "wheeled_nav_shaping", "precision": 2.0}
    plain, infos = run([])
    shaped, _ = run([shaping])
    w = rl.WheeledNavShaping(gym.make(ENV_ID, n_obstacles=0), precision=2.0)
    phi = [w.potential(i["pos_error"], i["heading_error"]) for i in infos]
    # the extra reward sums to 2 (Φ(end) − Φ(start)) whatever the path
    assert sum(shaped) - sum(plain) == pytest.approx(2.0 * (phi[-1] - phi[0]), abs=1e-9)
    assert w.potential(0.0, 0.0) == 1.0
    assert w.potential(0.02, 0.05) > w.potential(0.03, 0.05) > w.potential(0.03, 0.09)
    assert w.potential(3.0, 3.0) < 1e-6

    # drive into a wall: the collision costs the extra penalty
    def crash(wrappers: list) -> float:
        env = rl.apply_train_wrappers(
            gym.make(ENV_ID, n_obstacles=0, start=(2.6, 0.0, 0.0), goal=(-2.0, 0.0, 0.0)),
            wrappers,
        )
        env.reset(seed=0)
        for _ in range(100):
            _, r, term, _, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
            if term:
                break
        env.close()
        assert info["collision"]
        return float(r)

    extra = crash([{"name": "wheeled_nav_shaping", "collision_penalty": 10.0}]) - crash([])
    assert extra == pytest.approx(-10.0)
    with pytest.raises(ValueError, match="pos_scale and ang_scale"):
        rl.WheeledNavShaping(gym.make(ENV_ID, n_obstacles=0), pos_scale=0.0)


def test_curriculum_is_geometric_from_start_to_end() -> None:
    cur = rl.Curriculum(start={"tol": 0.32}, end={"tol": 0.02}, n_stages=4)
    got = [cur.values(k)["tol"] for k in range(6)]
    np.testing.assert_allclose(got, [0.32, 0.16, 0.08, 0.04, 0.02, 0.02])
    ints = rl.Curriculum.from_dict(
        {"start": {"n_obstacles": 0}, "end": {"n_obstacles": 6}, "n_stages": 4}
    )
    assert [ints.values(k)["n_obstacles"] for k in range(5)] == [0, 2, 3, 4, 6]
    with pytest.raises(ValueError, match="unknown curriculum key"):
        rl.Curriculum.from_dict({"start": {}, "end": {}, "stages": 3})


def test_observation_normaliser_round_trips_through_json() -> None:
    rng = np.random.default_rng(0)
    norm = rl.ObsNormalizer(rng.normal(size=5), rng.uniform(0.5, 2.0, size=5), clip=3.0)
    again = rl.ObsNormalizer.from_dict(json.loads(json.dumps(norm.to_dict())))
    x = rng.normal(size=(4, 5)) * 10
    np.testing.assert_array_equal(norm(x), again(x))
    assert np.all(np.abs(norm(x)) <= 3.0)
    np.testing.assert_allclose(
        norm(x[0]), np.clip((x[0] - norm.mean) / np.sqrt(norm.var + 1e-8), -3, 3), rtol=1e-6
    )


def test_learned_policy_runs_through_the_benchmark_harness(tiny_ppo: Path) -> None:
    from realitygap.baselines import benchmark as bm

    spec = bm.PolicySpec("mine", "file", (("*", str(tiny_ppo)),))
    task = bm.ChunkTask(ENV_ID, (("n_beams", 8), ("n_obstacles", 0)), "nominal", "fast", spec, (5,))
    (rec,) = bm.run_chunk(task)
    assert rec["policy"] == "mine" and rec["seed"] == 5 and rec["steps"] > 0
    assert math.isfinite(rec["compute_ms"]) and rec["compute_ms"] > 0


def test_training_is_seeded(tmp_path: Path) -> None:
    hp = {**_tiny_hyperparams(), "n_timesteps": 128, "curriculum": None}
    params = []
    for run in ("a", "b"):
        cfg = rl.TrainConfig(
            env_id=ENV_ID,
            algo="ppo",
            out_dir=tmp_path / run,
            seed=11,
            hyperparams=hp,
            checkpoint_every=0,
            eval_every=0,
            eval_episodes=0,
            progress_every_s=1e9,
        )
        model_path = rl.train(cfg).model_path
        env = gym.make(ENV_ID, n_obstacles=0, n_beams=8)
        policy = rl.load_policy(model_path, env)
        env.close()
        params.append({k: v.numpy().copy() for k, v in policy.model.policy.state_dict().items()})
    assert params[0].keys() == params[1].keys()
    for key in params[0]:
        np.testing.assert_array_equal(params[0][key], params[1][key], err_msg=key)


def test_rest_relaxation_and_attributes_through_the_wrapper_chain() -> None:
    base = gym.make(
        ENV_ID, n_obstacles=0, start=(0.0, 0.0, 0.0), goal=(0.1, 0.0, 0.0), success_pos_tol=0.2
    )
    env = rl.AttributeSetter(
        rl.apply_train_wrappers(base, [{"name": "wheeled_nav_rest_relaxation"}])
    )
    env.reset(seed=0)
    _, reward, terminated, _, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert terminated and info["is_success"] and info["relaxed_success"] and float(reward) > 4.0
    env.set_env_attrs({"rest_v_tol": 0.01, "success_pos_tol": 0.05})
    assert env.env.rest_v_tol == 0.01 and env.unwrapped.success_pos_tol == 0.05
    env.reset(seed=0)
    _, _, terminated, _, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert not terminated and not info["is_success"]  # moving, and 10 cm off
    with pytest.raises(AttributeError, match="attribute 'nope'"):
        env.set_env_attrs({"nope": 1})
    with pytest.raises(ValueError, match="unknown training wrapper 'x'"):
        rl.apply_train_wrappers(base, [{"name": "x"}])
    env.close()


def _predictions(policy: rl.LearnedPolicy, n: int = 5) -> np.ndarray:
    env = gym.make(ENV_ID, n_obstacles=2, n_beams=8)
    obs = [env.reset(seed=k)[0] for k in range(n)]
    env.close()
    return np.stack([policy.predict(o)[0] for o in obs])


def test_exported_weights_load_without_pickle_and_act_the_same(
    tiny_ppo: Path, tmp_path: Path
) -> None:
    env = gym.make(ENV_ID, n_obstacles=0, n_beams=8)
    from_zip = rl.load_policy(tiny_ppo, env)
    meta = rl.read_policy_meta(tiny_ppo)
    dest = rl.export_policy(from_zip.model, meta, tmp_path / "WheeledNav-v0_ppo")
    assert dest.suffix == ".pth" and dest.stat().st_size < tiny_ppo.stat().st_size
    from_weights = rl.load_policy(dest, env)
    env.close()
    np.testing.assert_array_equal(_predictions(from_zip), _predictions(from_weights))
    other = gym.make(ENV_ID)
    with pytest.raises(ValueError, match="expects observations of shape"):
        rl.load_policy(dest, other)
    other.close()


def test_sac_trains_exports_and_loads(tmp_path: Path) -> None:
    hp = {
        **_tiny_hyperparams(),
        "n_timesteps": 160,
        "learning_starts": 64,
        "batch_size": 32,
        "train_freq": 8,
        "gradient_steps": 1,
        "buffer_size": 1000,
        "curriculum": None,
    }
    for key in ("n_steps", "n_epochs"):
        hp.pop(key)
    cfg = rl.TrainConfig(
        env_id=ENV_ID,
        algo="sac",
        out_dir=tmp_path,
        seed=1,
        hyperparams=hp,
        checkpoint_every=0,
        eval_every=0,
        eval_episodes=0,
        progress_every_s=1e9,
    )
    result = rl.train(cfg)
    env = gym.make(ENV_ID, n_obstacles=0, n_beams=8)
    from_zip = rl.load_policy(result.model_path, env)
    dest = rl.export_policy(from_zip.model, rl.read_policy_meta(result.model_path), tmp_path / "s")
    from_weights = rl.load_policy(dest, env)
    env.close()
    np.testing.assert_allclose(_predictions(from_zip), _predictions(from_weights), atol=1e-6)


def test_a_continued_run_takes_the_files_optimisation_settings(
    tiny_ppo: Path, tmp_path: Path
) -> None:
    hp = {**_tiny_hyperparams(), "learning_rate": 1e-5, "clip_range": 0.05, "n_epochs": 2}
    cfg = rl.TrainConfig(
        env_id=ENV_ID,
        algo="ppo",
        out_dir=tmp_path,
        seed=3,
        total_timesteps=128,
        hyperparams=hp,
        checkpoint_every=0,
        eval_every=0,
        eval_episodes=0,
        progress_every_s=1e9,
        init_model=tiny_ppo,
    )
    result = rl.train(cfg)
    assert result.timesteps == 256 + 128  # the step count goes on
    from stable_baselines3 import PPO

    model = PPO.load(result.model_path, device="cpu")
    assert model.learning_rate == pytest.approx(1e-5) and model.n_epochs == 2
    assert model.clip_range(1.0) == pytest.approx(0.05)
    assert rl.read_policy_meta(result.model_path)["init_model"] == str(tiny_ppo)


@pytest.mark.slow
@pytest.mark.parametrize("path", sorted(rl.POLICIES_DIR.glob("*.pth")), ids=lambda p: p.stem)
def test_shipped_policies_load_for_their_env_and_act_in_bounds(path: Path) -> None:
    meta = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
    env = gym.make(meta["env_id"], **meta["env_kwargs"])
    policy = rl.load_policy(path, env)
    obs, _ = env.reset(seed=0)
    for k in range(5):
        action, _ = policy.predict(obs, episode_start=np.array([k == 0]))
        assert action.shape == env.action_space.shape
        assert np.all(action >= env.action_space.low) and np.all(action <= env.action_space.high)
        obs, *_ = env.step(action)
    env.close()


@pytest.mark.slow
def test_docking_starts_put_some_episodes_next_to_the_goal_and_are_seeded() -> None:
    def starts(seed0: int, probability: float) -> list[tuple[float, float]]:
        env = rl.apply_train_wrappers(
            gym.make(ENV_ID, n_obstacles=6),
            [{"name": "wheeled_nav_docking_starts", "probability": probability, "radius": 0.2}],
        )
        out = []
        for s in range(seed0, seed0 + 30):
            _, info = env.reset(seed=s)
            # the start is free of obstacles and walls, with the body's clearance
            base = env.unwrapped
            free = clearance(list(base.obstacles), info["true_pose"][:2])
            assert np.min(free, initial=np.inf) > base.true_params.body_radius
            out.append((info["pos_error"], info["heading_error"]))
        env.close()
        return out

    all_near = starts(0, 1.0)
    assert max(d for d, _ in all_near) <= 0.2 + 1e-9
    assert max(a for _, a in all_near) > 1.5  # facing anywhere, not towards the goal
    none_near = starts(0, 0.0)
    assert min(d for d, _ in none_near) > 1.0  # the env's own goals are > 1 m away
    some = starts(100, 0.5)
    near = sum(d <= 0.2 for d, _ in some)
    assert 5 <= near <= 25
    assert some == starts(100, 0.5)  # seeded by the env
    # a caller's own poses are left alone
    env = rl.WheeledNavDockingStarts(gym.make(ENV_ID, n_obstacles=0), probability=1.0)
    _, info = env.reset(seed=0, options={"start": [2.0, 2.0, 0.0], "goal": [-2.0, -2.0, 0.0]})
    assert info["pos_error"] == pytest.approx(math.hypot(4.0, 4.0), abs=1e-3)
    with pytest.raises(ValueError, match="obstacle-free margin"):
        rl.WheeledNavDockingStarts(gym.make(ENV_ID, n_obstacles=0), radius=0.5)
    with pytest.raises(ValueError, match="probability"):
        rl.WheeledNavDockingStarts(gym.make(ENV_ID, n_obstacles=0), probability=1.5)


def test_a_run_continues_from_exported_weights(tiny_ppo: Path, tmp_path: Path) -> None:
    env = gym.make(ENV_ID, n_obstacles=0, n_beams=8)
    from_zip = rl.load_policy(tiny_ppo, env)
    env.close()
    weights = rl.export_policy(
        from_zip.model, rl.read_policy_meta(tiny_ppo), tmp_path / "shipped" / "WheeledNav-v0_ppo"
    )
    common = {
        "env_id": ENV_ID,
        "algo": "ppo",
        "seed": 3,
        "checkpoint_every": 0,
        "eval_every": 0,
        "eval_episodes": 0,
        "progress_every_s": 1e9,
        "init_model": weights,
    }
    # zero updates: the continued model is the exported network, step count included
    frozen = {**_tiny_hyperparams(), "learning_rate": 0.0}
    result = rl.train(
        rl.TrainConfig(out_dir=tmp_path / "a", total_timesteps=128, hyperparams=frozen, **common)
    )
    assert result.timesteps == 256 + 128
    import torch
    from stable_baselines3 import PPO

    continued = PPO.load(result.model_path, device="cpu").policy.state_dict()
    exported = torch.load(weights, weights_only=True)
    assert continued.keys() == exported.keys()
    for key, value in exported.items():
        torch.testing.assert_close(continued[key], value, msg=key)
    other_net = {**_tiny_hyperparams(), "policy_kwargs": {"net_arch": [8]}}
    with pytest.raises(ValueError, match="same network"):
        rl.train(
            rl.TrainConfig(
                out_dir=tmp_path / "b", total_timesteps=128, hyperparams=other_net, **common
            )
        )


def test_arm_observability_shaping_telescopes_and_pays_for_spread_poses() -> None:
    def campaign(actions: np.ndarray, weight: float) -> tuple[float, list[dict], object]:
        env = rl.apply_train_wrappers(
            gym.make("realitygap/ArmCalib-v0", sensor_mode="geometric"),
            [{"name": "arm_observability_shaping", "weight": weight}] if weight else [],
        )
        env.reset(seed=1)
        total, infos = 0.0, []
        for a in actions:
            _, r, term, _, info = env.step(a.astype(np.float32))
            total += float(r)
            infos.append(info)
            if term:
                break
        env.close()
        return total, infos, env

    rng = np.random.default_rng(0)
    spread = rng.uniform(-0.8, 0.8, size=(20, 6))
    plain, infos, _ = campaign(spread, 0.0)
    shaped, _, env = campaign(spread, 2.0)
    shaping = env
    while not isinstance(shaping, rl.ArmObservabilityShaping):
        shaping = shaping.env
    measured = [i["q_encoder"] for i in infos if i["outcome"] == "ok"]
    assert len(measured) >= 8
    # the extra reward sums to w (Φ(measured poses) − Φ(none)), whatever the order
    assert shaped - plain == pytest.approx(
        2.0 * (shaping.potential(measured) - shaping.potential([])), abs=1e-9
    )
    assert shaping.potential(measured[::-1]) == pytest.approx(shaping.potential(measured))
    # the same pose twice over tells nothing; spread poses tell more
    same = [measured[0]] * len(measured)
    assert shaping.potential(same) < shaping.potential(measured[:4]) < shaping.potential(measured)
    with pytest.raises(ValueError, match="needs ArmCalib-v0"):
        rl.ArmObservabilityShaping(gym.make(ENV_ID, n_obstacles=0))


@pytest.mark.slow
def test_vector_training_gives_a_wheeled_nav_policy_evaluated_in_pybullet(tmp_path: Path) -> None:
    hp = rl.load_hyperparams("ppo", "realitygap/WheeledNavVec-v0")
    hp.update(n_steps=32, batch_size=256, n_epochs=1)
    hp["demonstrations"] = {**hp["demonstrations"], "rounds": 1, "episodes": 4, "epochs": 1}
    cfg = rl.TrainConfig(
        env_id="realitygap/WheeledNav-v0",
        algo="ppo",
        out_dir=tmp_path / "vec",
        total_timesteps=1024,
        n_envs=16,
        hyperparams=hp,
        checkpoint_every=0,
        eval_every=0,
        eval_episodes=1,
        vector=True,
    )
    result = rl.train(cfg)
    meta = json.loads(result.meta_path.read_text())
    assert meta["env_id"] == "realitygap/WheeledNav-v0"
    assert meta["train_env"] == "realitygap/WheeledNavVec-v0"
    assert [row["round"] for row in meta["demonstrations"]] == [0.0]
    assert (tmp_path / "vec" / "demonstrations.csv").is_file()
    assert set(result.final_eval) >= {"success", "reached_10cm", "collision"}
    env = gym.make("realitygap/WheeledNav-v0")
    policy = rl.load_policy(result.model_path, env, env_id="realitygap/WheeledNav-v0")
    obs, _ = env.reset(seed=0)
    action, _ = policy.predict(obs)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
    env.close()


def test_vector_training_refuses_single_env_wrappers_and_other_envs() -> None:
    venv = gym.make_vec("realitygap/WheeledNavVec-v0", num_envs=2)
    with pytest.raises(ValueError, match="acts on single envs"):
        rl.sb3_vector_env(venv, train_wrappers=[{"name": "arm_observability_shaping"}])
    with pytest.raises(ValueError, match="no vectorised surrogate"):
        rl.vector_env_id("realitygap/ArmCalib-v0")


def test_vector_shaping_is_the_wrappers_potential_difference() -> None:
    shaping = {"name": "wheeled_nav_shaping", "precision": 2.0, "collision_penalty": 10.0}
    plain = rl.sb3_vector_env(gym.make_vec("realitygap/WheeledNavVec-v0", num_envs=4))
    shaped = rl.sb3_vector_env(
        gym.make_vec("realitygap/WheeledNavVec-v0", num_envs=4), train_wrappers=[shaping]
    )
    for v in (plain, shaped):
        v.seed(3)
        v.reset()
    base = plain.venv.unwrapped
    phi0 = rl.wheeled_nav_potential(*base._pose_error(), 0.05, 0.1)
    a = np.full((4, 2), 0.5, np.float32)
    _, r_plain, _, _ = plain.step(a)
    _, r_shaped, _, _ = shaped.step(a)
    phi1 = rl.wheeled_nav_potential(*base._pose_error(), 0.05, 0.1)
    np.testing.assert_allclose(r_shaped - r_plain, 2.0 * (phi1 - phi0), atol=1e-5)


def test_vector_recipe_randomises_effects_only_in_the_vector_env(tmp_path: Path) -> None:
    hp = rl.load_hyperparams("ppo", "realitygap/WheeledNavVec-v0")
    hp.update(n_steps=16, batch_size=128, n_epochs=1)
    hp.pop("demonstrations")
    hp["vector_env_kwargs"] = {"randomize": {"wheelbase_error.E_b": [0.95, 1.05]}}
    cfg = rl.TrainConfig(
        env_id="realitygap/WheeledNav-v0",
        algo="ppo",
        out_dir=tmp_path / "dr",
        total_timesteps=256,
        n_envs=8,
        hyperparams=hp,
        checkpoint_every=0,
        eval_every=0,
        eval_episodes=0,
        vector=True,
    )
    result = rl.train(cfg)
    assert result.timesteps >= 256
    venv = rl.make_vector_train_env(
        "realitygap/WheeledNavVec-v0", hp["vector_env_kwargs"], 8, seed=0
    )
    venv.reset()
    eb = venv.venv.unwrapped.drive.values["wheelbase_error.E_b"]
    assert np.all((eb >= 0.95) & (eb <= 1.05)) and np.ptp(eb) > 0
