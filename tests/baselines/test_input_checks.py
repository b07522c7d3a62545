"""Every input of ``realitygap benchmark`` / ``train`` is checked before any work starts,
in one place per config (:class:`BenchmarkConfig`, :class:`TrainConfig` +
:func:`check_training`), with messages naming the option, what came and the fix."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import pytest

from realitygap.baselines import benchmark as bm
from realitygap.baselines import rl
from realitygap.baselines.rl import checks, config

ARM = "realitygap/ArmCalib-v0"
BENCH = ["benchmark", "--envs", ARM, "--policies", "random", "--episodes", "1"]
BENCH += ["--sensor-modes", "fast", "--reality", "none", "-q"]
TRAIN = ["train", "--env", ARM, "-q", "--timesteps", "64"]


class Reached(BaseException):
    pass


@pytest.fixture
def no_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every long-running function fails the test if reached."""
    import realitygap.baselines.benchmark as bmod
    import realitygap.baselines.cli as cli
    import realitygap.baselines.rl as rlmod

    def stop(*args: Any, **kwargs: Any) -> Any:
        raise Reached()

    monkeypatch.setattr(bmod, "run_benchmark", stop)
    monkeypatch.setattr(cli, "train_for_benchmark", stop)
    monkeypatch.setattr(rlmod, "train", stop)


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    from realitygap.cli import main

    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    return code, capsys.readouterr().err


def _files(tmp: Path) -> dict[str, Path]:
    (tmp / "bounds.json").write_text(
        json.dumps({"effects": [{"name": "command_latency", "values": {"delay": -5.0}}]})
    )
    (tmp / "typo.json").write_text(json.dumps({"effects": [{"name": "comand_latency"}]}))
    (tmp / "effects_str.json").write_text(json.dumps({"effects": "command_latency"}))
    (tmp / "syntax.json").write_text('{"effects": [\n  {"name": }\n]}')
    (tmp / "hp_list.json").write_text("[1, 2, 3]")
    (tmp / "hp_bad.json").write_text("{not json")
    (tmp / "hp_types.json").write_text(json.dumps({ARM: {"n_timesteps": "many"}}))
    (tmp / "hp_entry.json").write_text(json.dumps({ARM: [1, 2]}))
    (tmp / "hp_typo.json").write_text(json.dumps({ARM: {"n_timesteps": 64, "learnin_rate": 1}}))
    (tmp / "garbage.zip").write_bytes(b"PK\x03\x04 not a zip")
    with zipfile.ZipFile(tmp / "nodata.zip", "w") as z:
        z.writestr("other", "x")
    (tmp / "lonely.pth").write_bytes(b"PK")
    (tmp / "model.txt").write_text("x")
    return {}


# (argv tail, substrings the error must hold)
BENCH_CASES = [
    (["--envs", ","], ["--envs", "at least one"]),
    (["--envs", "realitygap/Moon-v0"], ["--envs", "Moon-v0"]),
    (["--envs", f"{ARM},{ARM}"], ["--envs", "more than once"]),
    (["--policies", ","], ["policies"]),
    (["--policies", "genius"], ["genius"]),
    (["--policies", "random,random"], ["unique"]),
    (["--policies", "mine=nope.zip"], ["--policies mine", "nope.zip", "Fix"]),
    (["--policies", "mine=garbage.zip"], ["--policies mine", "garbage.zip"]),
    (["--policies", "=garbage.zip"], ["--policies", "name"]),
    (["--reality", "kobuki-shiny"], ["--reality", "kobuki-shiny", "Did you mean"]),
    (["--reality", "bounds.json"], ["--reality", "bounds.json", "delay", "Fix"]),
    (["--reality", "typo.json"], ["--reality", "typo.json", "comand_latency"]),
    (["--reality", "effects_str.json"], ["--reality", "effects_str.json", "list"]),
    (["--reality", "syntax.json"], ["--reality", "syntax.json", "line 2"]),
    (["--reality", "missing.json"], ["--reality", "missing.json"]),
    (["--sensor-modes", "xray"], ["--sensor-modes", "xray"]),
    (["--sensor-modes", ","], ["--sensor-modes"]),
    (["--seed", "99999999999"], ["--seed"]),
    (["--train", "--train-seeds", "a,b"], ["--train-seeds", "'a'"]),
    (["--train", "--train-seeds=-1"], ["--train-seeds", "-1"]),
    (["--train", "--train-seeds", "1,1"], ["--train-seeds", "distinct"]),
    (["--train", "--train-seeds", ","], ["--train-seeds"]),
    (["--train-seeds", "1"], ["--train-seeds", "--train"]),
    (["--train-timesteps", "100"], ["--train-timesteps", "--train"]),
    (["--train"], ["--train", "ppo"]),  # random only: nothing to train
    (["--address", "auto"], ["--address", "--backend ray"]),
    (["--backend", "ray", "--workers", "2"], ["--workers", "ray"]),
    (["--episodes", "0"], ["--episodes"]),
    (["--image-episodes", "0"], ["--image-episodes"]),
]


@pytest.mark.parametrize("tail,must", BENCH_CASES, ids=[" ".join(c[0]) for c in BENCH_CASES])
def test_bad_benchmark_input_is_refused_before_work(
    tail: list[str],
    must: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    no_work: None,
) -> None:
    _files(tmp_path)
    monkeypatch.chdir(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    code, err = _run([*BENCH, "--out", "bench", *tail], capsys)
    assert code == 2, err
    assert "error:" in err and "Traceback" not in err
    for m in must:
        assert m in err, (m, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


TRAIN_CASES = [
    (["--n-envs", "100000000"], ["--n-envs", "memory", "Fix"]),
    (["--init-model", "nope.zip"], ["--init-model", "nope.zip"]),
    (["--init-model", "garbage.zip"], ["--init-model", "garbage.zip", "not a zip"]),
    (["--init-model", "nodata.zip"], ["--init-model", "nodata.zip", "'data'"]),
    (["--init-model", "lonely.pth"], ["--init-model", "lonely.json"]),
    (["--init-model", "model.txt"], ["--init-model", "model.txt", ".pth"]),
    (["--hyperparams", "nohp.json"], ["nohp.json"]),
    (["--hyperparams", "hp_bad.json"], ["--hyperparams", "hp_bad.json", "line 1"]),
    (["--hyperparams", "hp_list.json"], ["--hyperparams", "hp_list.json", "object"]),
    (["--hyperparams", "hp_types.json"], ["hp_types.json", "n_timesteps", "positive integer"]),
    (["--hyperparams", "hp_entry.json"], ["hp_entry.json", ARM, "object"]),
    (["--hyperparams", "hp_typo.json"], ["hp_typo.json", "learnin_rate", "learning_rate"]),
    (["--eval-every", "1000"], ["--eval-every", "64"]),
    (["--checkpoint-every", "1000"], ["--checkpoint-every", "64"]),
    (["--seed", "99999999999"], ["--seed"]),
    (["--env", "WheeledNav-v0", "--vector", "--vec-env", "subproc", "--n-envs", "0"], ["--n-envs"]),
    (["--env", "realitygap/WallClimb-v0", "--vector"], ["--vector"]),
]


@pytest.mark.parametrize("tail,must", TRAIN_CASES, ids=[" ".join(c[0]) for c in TRAIN_CASES])
def test_bad_train_input_is_refused_before_work(
    tail: list[str],
    must: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    no_work: None,
) -> None:
    pytest.importorskip("stable_baselines3")
    _files(tmp_path)
    monkeypatch.chdir(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    code, err = _run([*TRAIN, "--out", "train", *tail], capsys)
    assert code == 2, err
    assert "error:" in err and "Traceback" not in err
    for m in must:
        assert m in err, (m, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_good_input_reaches_the_work(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    no_work: None,
) -> None:
    pytest.importorskip("stable_baselines3")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(Reached):
        _run([*BENCH, "--out", "bench"], capsys)
    with pytest.raises(Reached):
        _run([*TRAIN, "--out", "train"], capsys)  # --eval-every's default may exceed 64


# --------------------------------------------------------------------------- the library
def test_benchmark_config_checks_itself(tmp_path: Path) -> None:
    pol = tuple(bm.parse_policies("random"))
    with pytest.raises(ValueError, match=r"--envs \(env_ids\): expected at least one"):
        bm.BenchmarkConfig(env_ids=(), policies=pol)
    with pytest.raises(ValueError, match=r"--sensor-modes .*'xray'"):
        bm.BenchmarkConfig(env_ids=(ARM,), policies=pol, sensor_modes=("xray",))
    with pytest.raises(ValueError, match=r"--episodes \(episodes\) must be a positive integer"):
        bm.BenchmarkConfig(env_ids=(ARM,), policies=pol, episodes=0)
    with pytest.raises(ValueError, match="--image-episodes"):
        bm.BenchmarkConfig(env_ids=(ARM,), policies=pol, episode_counts={"image": -1})
    with pytest.raises(ValueError, match="'gpu:fast'"):
        bm.BenchmarkConfig(env_ids=(ARM,), policies=pol, episode_counts={"gpu:fast": 1})
    bad = tmp_path / "r.json"
    bad.write_text('{"effects": [{"name": "command_latency", "values": {"delay": -5}}]}')
    with pytest.raises(ValueError, match=r"r\.json.*delay"):
        bm.BenchmarkConfig(env_ids=(ARM,), policies=pol, realities=(str(bad),))
    cfg = bm.BenchmarkConfig(env_ids=("ArmCalib-v0",), policies=list(pol), realities=["nominal"])
    assert cfg.env_ids == (ARM,) and isinstance(cfg.policies, tuple)


def test_run_benchmark_checks_its_options_before_writing(tmp_path: Path) -> None:
    cfg = bm.BenchmarkConfig(env_ids=(ARM,), policies=tuple(bm.parse_policies("random")))
    with pytest.raises(ValueError, match="--address"):
        bm.run_benchmark(cfg, tmp_path / "out", address="auto", verbose=False)
    with pytest.raises(ValueError, match="--workers"):
        bm.run_benchmark(cfg, tmp_path / "out", workers=0, verbose=False)
    assert not (tmp_path / "out").exists()


def test_a_reality_file_is_for_its_robot_only(tmp_path: Path) -> None:
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(bm.reality_from_profile("kobuki-worn").to_dict()))
    assert bm.profile_robot(str(path)) == "diffdrive"
    # requested for an arm-only run it would run no cell: refused before any work
    with pytest.raises(ValueError, match=r"mine\.json.*diffdrive.*WheeledNav-v0"):
        bm.BenchmarkConfig(
            env_ids=(ARM,), policies=tuple(bm.parse_policies("random")), realities=(str(path),)
        )


def test_train_config_checks_itself(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"--n-envs \(n_envs\)"):
        rl.TrainConfig(env_id=ARM, algo="ppo", out_dir=tmp_path, n_envs=0)
    with pytest.raises(ValueError, match=r"--seed \(seed\)"):
        rl.TrainConfig(env_id=ARM, algo="ppo", out_dir=tmp_path, seed=-1)
    with pytest.raises(TypeError, match=r"--timesteps \(total_timesteps\)"):
        rl.TrainConfig(env_id=ARM, algo="ppo", out_dir=tmp_path, total_timesteps="64")
    with pytest.raises(ValueError, match=r"--vec-env"):
        rl.TrainConfig(env_id=ARM, algo="ppo", out_dir=tmp_path, vec_env="threads")
    with pytest.raises(ValueError, match="unknown algorithm"):
        rl.TrainConfig(env_id=ARM, algo="dqn", out_dir=tmp_path)
    with pytest.raises(ValueError, match="vectorised surrogate"):
        rl.TrainConfig(env_id=ARM, algo="ppo", out_dir=tmp_path, vector=True)
    cfg = rl.TrainConfig(env_id="ArmCalib-v0", algo="PPO", out_dir=str(tmp_path))
    assert cfg.env_id == ARM and cfg.algo == "ppo" and cfg.out_dir == tmp_path


def test_train_checks_everything_before_an_env_starts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("stable_baselines3")
    import gymnasium as gym

    from realitygap.baselines.rl import training

    def no_env(*args: Any, **kwargs: Any) -> Any:
        raise Reached()

    monkeypatch.setattr(gym, "make", no_env)
    monkeypatch.setattr(training, "make_vec_env", no_env)
    cases: list[tuple[dict[str, Any], str]] = [
        ({"n_envs": 10**8}, "--n-envs"),
        ({"init_model": tmp_path / "nope.zip"}, "nope.zip"),
        ({"hyperparams": {"n_timesteps": 64, "n_envs": "two"}}, "n_envs"),
        ({"hyperparams": {"n_envs": 1}}, "n_timesteps"),
    ]
    for kwargs, match in cases:
        cfg = rl.TrainConfig(env_id=ARM, algo="ppo", out_dir=tmp_path / "t", **kwargs)
        with pytest.raises((ValueError, TypeError, FileNotFoundError), match=match):
            rl.train(cfg)
    assert not (tmp_path / "t").exists()


def test_env_count_cost() -> None:
    gb = 2**30
    assert checks.check_env_count(4, "subproc", available=8 * gb, cpus=4) == 4
    with pytest.raises(ValueError, match=r"--n-envs .*available.*Fix: use at most"):
        checks.check_env_count(1000, "subproc", available=8 * gb, cpus=4)
    with pytest.raises(ValueError, match="in this process"):
        checks.check_env_count(10**6, "dummy", available=8 * gb, cpus=4)
    seen: list[str] = []
    checks.check_env_count(8, "subproc", available=64 * gb, cpus=2, warn=seen.append)
    assert seen and "2 CPU" in seen[0]
    checks.check_env_count(8, "dummy", available=64 * gb, cpus=2, warn=seen.append)
    assert len(seen) == 1  # in-process envs start no processes


def test_shipped_hyperparameter_files_pass_their_checks() -> None:
    pytest.importorskip("stable_baselines3")
    for algo in rl.ALGOS:
        table = config.load_hyperparams_file(rl.HYPERPARAMS_DIR / f"{algo}.json", algo=algo)
        assert table


def test_seed_lists() -> None:
    assert checks.check_seed_list("0, 1,2") == [0, 1, 2]
    for bad in ("", "a", "-1", "1.5", "1,1", str(2**32)):
        with pytest.raises(ValueError, match="--train-seeds"):
            checks.check_seed_list(bad)


NAV = "realitygap/WheeledNav-v0"


@pytest.mark.parametrize(
    "content, match",
    [
        ({}, "has no effects"),
        (
            {"name": "m", "effects": [{"name": "wheel_diameter_ratio", "values": {}}]},
            "nominal value",
        ),
        (
            {"name": "m", "effects": [{"name": "arm_joint_offset", "values": {"dtheta1": 0.01}}]},
            "ArmCalib-v0",
        ),
    ],
)
def test_a_reality_must_change_a_requested_env(tmp_path: Path, content: Any, match: str) -> None:
    path = tmp_path / "r.json"
    path.write_text(json.dumps(content))
    with pytest.raises(
        ValueError, match=r"--reality \(realities\): reality file .*r\.json.*" + match
    ):
        bm.BenchmarkConfig(
            env_ids=(NAV,), policies=tuple(bm.parse_policies("random")), realities=(str(path),)
        )


def test_a_profile_for_no_requested_env_is_refused() -> None:
    with pytest.raises(
        ValueError, match=r"'kobuki-worn' is for the diffdrive robot.*WheeledNav-v0"
    ):
        bm.BenchmarkConfig(
            env_ids=(ARM,), policies=tuple(bm.parse_policies("random")), realities=("kobuki-worn",)
        )
    # left at its default, the reality list holds only what the requested envs can run
    cfg = bm.BenchmarkConfig(env_ids=(ARM,), policies=tuple(bm.parse_policies("random")))
    assert cfg.realities == ()


def test_workers_with_a_backend_that_uses_none_is_refused() -> None:
    with pytest.raises(ValueError, match="--workers 4 does nothing with --backend ray"):
        bm.check_run_options("ray", 4)
    assert bm.check_run_options("local", None) == 1
