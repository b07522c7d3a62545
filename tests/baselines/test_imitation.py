"""The obstacle memory and the DAgger warm start of learned WheeledNav policies."""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401
from realitygap.baselines import rl
from realitygap.baselines.episode_features import EpisodeFeatures, ObstacleMemory, RestTimer
from realitygap.baselines.imitation import DemoSettings, Rollouts, expert_action_to_model

ENV_ID = "realitygap/WheeledNav-v0"


def _obs(
    x: float, y: float, theta: float, ranges: list[float], range_max: float = 8.0
) -> np.ndarray:
    o = np.zeros(12 + len(ranges), dtype=np.float32)
    o[:4] = (x, y, math.cos(theta), math.sin(theta))
    o[12:] = np.minimum(np.asarray(ranges) / range_max, 1.0)
    return o


def test_memory_keeps_what_left_the_field_of_view() -> None:
    # three beams at -10°, 0°, +10°; only the middle one sees a wall 1 m ahead
    mem = ObstacleMemory(np.radians([-10.0, 0.0, 10.0]), 8.0, n_sectors=36, horizon=2.0)
    f = mem.update(_obs(0.0, 0.0, 0.0, [np.inf, 1.0, np.inf]))
    assert f[0] == pytest.approx(0.5, abs=1e-6) and np.all(np.delete(f, 0) == 1.0)
    # turn left by 90° and see nothing: the point is now at -90°, sector 36 - 9 = 27
    f = mem.update(_obs(0.0, 0.0, math.pi / 2, [np.inf, np.inf, np.inf]))
    assert f[27] == pytest.approx(0.5, abs=1e-6) and np.all(np.delete(f, 27) == 1.0)
    # drive 0.5 m towards the remembered point, facing it again: it is 0.5 m ahead
    f = mem.update(_obs(0.5, 0.0, 0.0, [np.inf, np.inf, np.inf]))
    assert f[0] == pytest.approx(0.25, abs=1e-6)


def test_memory_keeps_one_point_per_cell_and_forgets_on_reset() -> None:
    mem = ObstacleMemory(np.radians([-10.0, 0.0, 10.0]), 8.0, cell=0.05)
    for _ in range(5):
        mem.update(_obs(0.0, 0.0, 0.0, [1.0, 1.0, 1.0]))
    assert len(mem) == 3
    far = ObstacleMemory(np.radians([0.0]), 8.0, horizon=2.0)
    far.update(_obs(0.0, 0.0, 0.0, [3.0]))
    assert len(far) == 0  # beyond the horizon: not kept
    mem.reset()
    assert len(mem) == 0
    with pytest.raises(ValueError, match="12 \\+ 3 beams"):
        mem.update(np.zeros(20))


def test_memory_wrapper_and_policy_io_see_the_same_features() -> None:
    env = gym.make(ENV_ID, n_obstacles=3, n_beams=16)
    io = rl.PolicyIO(obs_features="wheeled_nav_goal_polar", obs_memory={"n_sectors": 12}).for_env(
        env
    )
    assert io.obs_memory is not None and len(io.obs_memory["scan_angles"]) == 16
    wrapped = io.wrap(gym.make(ENV_ID, n_obstacles=3, n_beams=16))
    raw_obs, _ = env.reset(seed=5)
    w_obs, _ = wrapped.reset(seed=5)
    memory = io.new_episode_features()
    rng = np.random.default_rng(0)
    for _ in range(30):
        np.testing.assert_allclose(io.observation(raw_obs[None], [memory])[0], w_obs, atol=1e-6)
        a = rng.uniform(-1, 1, 2).astype(np.float32)
        raw_obs, *_ = env.step(a)
        w_obs, *_ = wrapped.step(a)
    assert wrapped.observation_space.shape == (16 + 12 + 12 + 5,)
    with pytest.raises(ValueError, match="needs its episode features"):
        io.observation(raw_obs)
    env.close()
    wrapped.close()


def test_rest_timer_counts_still_steps_saturates_and_restarts() -> None:
    timer = RestTimer(horizon_steps=4)
    still, moving = np.zeros(20), np.zeros(20)
    moving[10] = 0.3
    got = [timer.update(o)[0] for o in (still, still, moving, still, still, still, still, still)]
    np.testing.assert_allclose(got, [0.25, 0.5, 0.0, 0.25, 0.5, 0.75, 1.0, 1.0])
    timer.reset()
    assert timer.update(still)[0] == 0.25
    with pytest.raises(ValueError, match="unknown obs_rest_timer"):
        EpisodeFeatures(rest_timer={"steps": 3})


@pytest.mark.parametrize("gate", [False, True])
def test_expert_targets_invert_the_policy_output_map(gate: bool) -> None:
    io = rl.PolicyIO(action_deadband=0.05, action_stop_gate=gate)
    rng = np.random.default_rng(1)
    a = rng.uniform(-1, 1, (200, 2)).astype(np.float32)
    a[:20] = 0.0
    a[20:40, 1] = 0.0
    model = expert_action_to_model(a, 0.05, gate)
    assert model.shape == (200, 3 if gate else 2)
    np.testing.assert_allclose(io.action(model), a, atol=1e-6)
    if gate:
        assert np.all(model[:20, -1] == 1.0) and np.all(model[20:, -1] == -1.0)


def test_discounted_returns_restart_at_each_episode_end() -> None:
    r = Rollouts(rewards=[1.0, 1.0, 1.0, 2.0, 2.0], ends=[0, 0, 1, 0, 2])
    np.testing.assert_allclose(r.returns(0.5), [1.75, 1.5, 1.0, 3.0, 2.0])


def test_bad_demonstration_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="unknown demonstrations setting"):
        DemoSettings.from_dict({"round": 3})
    with pytest.raises(ValueError, match="expert must be one of \\['classical', 'geodesic'\\]"):
        DemoSettings(expert="oracle")
    assert DemoSettings(expert="geodesic").expert == "geodesic"
    with pytest.raises(ValueError, match="beta_decay"):
        DemoSettings(beta_decay=1.5)
    with pytest.raises(ValueError, match="unknown training wrapper 'nope'"):
        DemoSettings.from_dict({"train_wrappers": [{"name": "nope"}]})
    own = DemoSettings.from_dict(
        {"train_wrappers": [{"name": "wheeled_nav_docking_starts", "probability": 0.5}]}
    )
    assert own.train_wrappers == ({"name": "wheeled_nav_docking_starts", "probability": 0.5},)
    assert DemoSettings().train_wrappers is None  # the run's own wrappers


sb3 = pytest.importorskip("stable_baselines3")


def _hyperparams() -> dict:
    return {
        "n_timesteps": 128,
        "n_envs": 1,
        "vec_env": "dummy",
        "env_kwargs": {"sensor_mode": "fast", "n_obstacles": 1, "n_beams": 8},
        "policy": "MlpPolicy",
        "n_steps": 64,
        "batch_size": 64,
        "n_epochs": 1,
        "policy_kwargs": {"net_arch": [32, 32], "log_std_init": -1.6},
        "action_deadband": 0.05,
        "action_stop_gate": True,
        "obs_features": "wheeled_nav_goal_zoom",
        "obs_memory": {"n_sectors": 12},
        "normalize": {"obs": True},
        "train_max_episode_steps": 300,
        "demonstrations": {"rounds": 2, "episodes": 3, "epochs": 30, "workers": 1},
    }


def _quiet_ppo(env_id: str, out_dir: Path, hyperparams: dict, seed: int = 0) -> rl.TrainConfig:
    """A PPO run without checkpoints, evaluations or progress lines."""
    return rl.TrainConfig(
        env_id=env_id,
        algo="ppo",
        out_dir=out_dir,
        seed=seed,
        hyperparams=hyperparams,
        checkpoint_every=0,
        eval_every=0,
        eval_episodes=0,
        progress_every_s=1e9,
    )


@pytest.fixture(scope="module")
def cloned(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return rl.train(
        _quiet_ppo(ENV_ID, tmp_path_factory.mktemp("dagger"), _hyperparams(), 2)
    ).model_path


@pytest.mark.slow
def test_cloning_fits_the_expert_and_freezes_the_normaliser(cloned: Path) -> None:
    meta = rl.read_policy_meta(cloned)
    rounds = meta["demonstrations"]
    assert [r["round"] for r in rounds] == [0.0, 1.0]
    assert rounds[0]["rollout_success"] == 1.0  # the expert alone reaches these goals
    assert rounds[-1]["action_mse"] < 0.05  # the network follows the expert's commands
    assert meta["obs_norm_frozen"] is True
    assert meta["obs_memory"]["n_sectors"] == 12 and len(meta["obs_memory"]["scan_angles"]) == 8
    assert (cloned.parent / "demonstrations.csv").is_file()


def test_numpy_actor_matches_the_torch_policy(cloned: Path) -> None:
    from realitygap.baselines.imitation import NumpyActor

    env = gym.make(ENV_ID, n_obstacles=1, n_beams=8)
    policy = rl.load_policy(cloned, env)
    env.close()
    actor = NumpyActor(policy.model.policy.state_dict())
    x = np.random.default_rng(0).normal(size=(16, policy.model.observation_space.shape[0]))
    torch_actions, _ = policy.model.predict(x.astype(np.float32), deterministic=True)
    np.testing.assert_allclose(actor(x), torch_actions, atol=1e-5)


def test_policy_memory_restarts_with_each_episode(cloned: Path) -> None:
    env = gym.make(ENV_ID, n_obstacles=1, n_beams=8)
    policy = rl.load_policy(cloned, env)

    def run(seed: int) -> list[np.ndarray]:
        obs, _ = env.reset(seed=seed)
        out, start = [], True
        for _ in range(25):
            a, _ = policy.predict(obs, episode_start=np.array([start]))
            start = False
            out.append(a)
            obs, *_ = env.step(a)
        return out

    first = run(4)
    run(9)  # another episode in between fills the memory with other obstacles
    again = run(4)
    env.close()
    np.testing.assert_array_equal(np.asarray(first), np.asarray(again))


ARM_ID = "realitygap/ArmCalib-v0"


def _arm_hyperparams(rounds: int = 1) -> dict:
    return {
        "n_timesteps": 64,
        "n_envs": 1,
        "vec_env": "dummy",
        "env_kwargs": {"sensor_mode": "geometric", "budget": 10},
        "policy": "MlpPolicy",
        "n_steps": 32,
        "batch_size": 32,
        "n_epochs": 1,
        "learning_rate": 0.0,
        "policy_kwargs": {"net_arch": [64, 64], "log_std_init": -3.0},
        "normalize": {"obs": True},
        "demonstrations": {"rounds": rounds, "episodes": 4, "epochs": 300, "workers": 1},
    }


@pytest.mark.slow
def test_arm_pose_selection_clones_the_greedy_expert(tmp_path: Path) -> None:
    """The cloned network's deterministic poses are the greedy selector's, so its campaign
    identifies the arm as the expert's does (a network trained by PPO alone asks for nearly
    the same pose every time)."""
    from realitygap.baselines.arm_policy import ObservabilityGreedyPolicy

    result = rl.train(_quiet_ppo(ARM_ID, tmp_path, _arm_hyperparams()))
    env = gym.make(ARM_ID, sensor_mode="geometric", budget=10)
    student = rl.load_policy(result.model_path, env)
    expert = ObservabilityGreedyPolicy.from_env(env)

    def campaign(policy: object) -> tuple[np.ndarray, dict]:
        obs, _ = env.reset(seed=123)  # not a demonstration seed
        actions, start = [], True
        while True:
            a, _ = policy.predict(obs, episode_start=np.array([start]), deterministic=True)
            start = False
            actions.append(np.asarray(a, dtype=float))
            obs, _, term, trunc, info = env.step(a)
            if term or trunc:
                return np.asarray(actions), info

    a_student, info_student = campaign(student)
    a_expert, info_expert = campaign(expert)
    env.close()
    # the poses up to the first identification are the expert's; later ones may drift
    # (four demonstrations), the campaign's outcome may not
    assert np.max(np.abs(a_student[:8] - a_expert[:8])) < 0.05
    assert info_student["poses_used"] >= 8
    assert info_student["validation_rms_mm"] < 2.0 * info_expert["validation_rms_mm"]
    assert info_student["validation_rms_mm"] < 0.1 * info_student["nominal_validation_rms_mm"]


def test_arm_expert_labels_only_its_own_episodes(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="need rounds = 1"):
        rl.train(_quiet_ppo(ARM_ID, tmp_path, _arm_hyperparams(rounds=2)))


def test_mirrored_rollouts_flip_the_turn_and_keep_the_returns() -> None:
    r = Rollouts(
        inputs=[np.array([1.0, 2.0, 3.0], np.float32), np.array([4.0, 5.0, 6.0], np.float32)],
        targets=[np.array([0.5, 0.2, -1.0], np.float32), np.array([0.1, -0.3, 1.0], np.float32)],
        rewards=[1.0, 2.0],
        ends=[0, 1],
        episodes=[{"success": 1.0, "collision": 0.0}],
    )
    m = r.mirrored(
        np.array([0, 2, 1]),
        np.array([1.0, -1.0, 1.0], np.float32),
        np.array([1.0, -1.0, 1.0], np.float32),
    )
    np.testing.assert_array_equal(m.inputs[1], [4.0, -6.0, 5.0])
    np.testing.assert_array_equal(m.targets[0], np.array([0.5, -0.2, -1.0], np.float32))
    np.testing.assert_allclose(m.returns(0.9), r.returns(0.9))
    assert m.episodes == []  # a mirror image is not an episode that was driven


def test_mirrored_demonstrations_double_the_samples(tmp_path: Path) -> None:
    hp = _hyperparams()
    hp["obs_features"] = "wheeled_nav_egocentric"
    hp["demonstrations"] = {"rounds": 1, "episodes": 2, "epochs": 2, "workers": 1, "mirror": True}
    rl.train(_quiet_ppo(ENV_ID, tmp_path / "ego", hp))
    rows = (tmp_path / "ego" / "demonstrations.csv").read_text().splitlines()
    head, first = rows[0].split(","), rows[1].split(",")
    row = dict(zip(head, first))
    assert float(row["samples"]) == 2 * float(row["rollout_steps"])
    # inputs in the world frame have no mirror image: refused before any episode is run
    hp["obs_features"] = "wheeled_nav_goal_zoom"
    with pytest.raises(ValueError, match="wheeled_nav_egocentric"):
        rl.train(_quiet_ppo(ENV_ID, tmp_path / "world", hp))


def test_scene_fade_empties_the_scene_at_the_goal_only() -> None:
    n_beams, n_sectors = 6, 4
    x = np.full((3, 12 + n_beams + n_sectors + 1), 0.4, dtype=np.float32)
    x[:, 8:10] = [[0.0, 0.0], [0.06, 0.08], [0.3, 0.0]]  # goal 0, 0.1 and 0.3 m away
    out = rl.scene_fade(x, x.shape[1] - 1, radius=0.2)
    scene = slice(12, 12 + n_beams + n_sectors)
    np.testing.assert_allclose(out[0, scene], 1.0)  # nothing seen at the goal
    np.testing.assert_allclose(out[1, scene], 1.0 - 0.6 * 0.5, rtol=1e-6)  # half-way
    np.testing.assert_array_equal(out[2], x[2])  # identity beyond the radius
    np.testing.assert_array_equal(out[:, :12], x[:, :12])
    np.testing.assert_array_equal(out[:, -1], x[:, -1])  # the rest timer is not scene


def test_scene_fade_is_the_same_in_training_and_use_and_refused_off_wheeled_nav() -> None:
    io = rl.PolicyIO(
        obs_features="wheeled_nav_egocentric",
        obs_memory={"n_sectors": 12},
        obs_rest_timer={"horizon_steps": 10},
        obs_scene_fade=0.25,
    )
    assert rl.PolicyIO.from_dict(io.to_dict()) == io
    kwargs = {"n_obstacles": 3, "n_beams": 16, "goal": [0.5, 0.0, 0.0], "start": [0.3, 0.0, 0.0]}
    env = gym.make(ENV_ID, **kwargs)
    io = io.for_env(env)
    wrapped = io.wrap(gym.make(ENV_ID, **kwargs))
    raw_obs, _ = env.reset(seed=2)
    w_obs, _ = wrapped.reset(seed=2)
    feats = io.new_episode_features()
    unfaded = rl.PolicyIO(**{**io.__dict__, "obs_scene_fade": 0.0})
    plain_feats = unfaded.new_episode_features()
    faded_some = False
    for _ in range(20):
        x = io.observation(raw_obs[None], [feats])[0]
        np.testing.assert_allclose(x, w_obs, atol=1e-6)
        faded_some |= not np.allclose(x, unfaded.observation(raw_obs[None], [plain_feats])[0])
        raw_obs, *_ = env.step(np.array([0.3, 0.0], np.float32))
        w_obs, *_ = wrapped.step(np.array([0.3, 0.0], np.float32))
    assert faded_some  # the start lies 0.2 m from the goal: the scene is faded
    with pytest.raises(ValueError, match="obs_scene_fade must be a radius"):
        rl.PolicyIO(obs_scene_fade=0.5)
    with pytest.raises(ValueError, match="obs_scene_fade fades a WheeledNav scan"):
        rl.PolicyIO(obs_scene_fade=0.1).wrap(gym.make("CartPole-v1"))
    env.close()
    wrapped.close()
