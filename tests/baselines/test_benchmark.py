"""The benchmark harness: identical seeded episodes, statistics, streaming, files, bad input."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from realitygap.baselines import benchmark as bm
from realitygap.baselines.benchmark import runner
from realitygap.core.io import atomic_write_text

ENV_ID = "realitygap/WheeledNav-v0"
T_975 = {3: 3.182446305284263, 9: 2.262157162798205}
"""Student-t 97.5 % quantiles (tables) for the closed-form checks."""
Z_975 = 1.959963984540054


def _cfg(**kw: Any) -> bm.BenchmarkConfig:
    base = {
        "env_ids": (ENV_ID,),
        "policies": tuple(bm.parse_policies("classical,random")),
        "episodes": 1,
        "realities": ("kobuki-worn",),
        "sensor_modes": ("fast",),
        "seed": 0,
        "env_kwargs": {ENV_ID: {"n_obstacles": 2}},
    }
    base.update(kw)
    return bm.BenchmarkConfig(**base)


def _strip(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.items() if k not in ("compute_ms", "wall_s")} for r in records]


@pytest.fixture(scope="module")
def bench_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bench")
    bm.run_benchmark(_cfg(), out, verbose=False)
    return out


# --------------------------------------------------------------------------- determinism
@pytest.mark.slow
def test_identical_seeds_give_identical_results(bench_dir: Path, tmp_path: Path) -> None:
    again = bm.run_benchmark(_cfg(), tmp_path, verbose=False)
    first = bm.ResultStore(bench_dir / "episodes.jsonl").load()
    second = bm.ResultStore(again.files["episodes"]).load()
    assert len(first) == 4  # classical and random, nominal and kobuki-worn
    key = bm.record_key
    assert _strip(sorted(first, key=key)) == _strip(sorted(second, key=key))


def test_every_policy_runs_the_same_episodes_through_one_harness(bench_dir: Path) -> None:
    records = bm.ResultStore(bench_dir / "episodes.jsonl").load()
    assert {(r["policy"], r["reality"]) for r in records} == {
        ("classical", "nominal"),
        ("classical", "kobuki-worn"),
        ("random", "nominal"),
        ("random", "kobuki-worn"),
    }
    assert {r["seed"] for r in records} == {0}
    for r in records:
        assert set(bm.METRICS) <= set(r)
        assert r["steps"] > 0 and r["compute_ms"] >= 0
    classical = next(r for r in records if r["policy"] == "classical" and r["reality"] == "nominal")
    assert classical["success"] and classical["reached_10cm"] and not classical["collision"]
    assert classical["final_pos_error_cm"] <= 3.0 and classical["time_to_goal_s"] > 0


def test_run_episode_is_deterministic_and_random_policy_is_reseeded() -> None:
    import gymnasium as gym

    env = gym.make(ENV_ID, n_obstacles=0)
    policy = bm.RandomPolicy(env.action_space, seed=123)
    a = bm.run_episode(env, policy, seed=7)
    policy.predict(np.zeros(76))  # disturb the generator between episodes
    b = bm.run_episode(env, policy, seed=7)
    env.close()
    a.pop("compute_ms"), b.pop("compute_ms")
    assert a == b


# --------------------------------------------------------------------------- statistics
def test_t_interval_matches_the_closed_form() -> None:
    x = [1.0, 2.0, 3.0, 4.0]
    mean, std, lo, hi = bm.t_interval(x)
    s = math.sqrt(sum((v - 2.5) ** 2 for v in x) / 3)
    half = T_975[3] * s / 2.0
    assert mean == pytest.approx(2.5) and std == pytest.approx(s)
    assert (lo, hi) == pytest.approx((2.5 - half, 2.5 + half))
    rng = np.random.default_rng(4)
    y = rng.normal(3.0, 2.0, size=10)
    m, _, lo, hi = bm.t_interval(y)
    assert hi - m == pytest.approx(T_975[9] * np.std(y, ddof=1) / math.sqrt(10))
    assert math.isnan(bm.t_interval([1.0])[2]) and math.isnan(bm.t_interval([])[0])
    assert bm.t_interval([1.0, math.nan, 3.0])[0] == pytest.approx(2.0)


def test_wilson_interval_matches_the_closed_form() -> None:
    n = 10
    lo, hi = bm.wilson_interval(0, n)
    assert lo == 0.0 and hi == pytest.approx(Z_975**2 / (n + Z_975**2))
    lo, hi = bm.wilson_interval(n, n)
    assert hi == 1.0 and lo == pytest.approx(n / (n + Z_975**2))
    lo, hi = bm.wilson_interval(5, n)
    assert lo + hi == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    for _ in range(50):
        n = int(rng.integers(1, 200))
        k = int(rng.integers(0, n + 1))
        lo, hi = bm.wilson_interval(k, n)
        assert 0.0 <= lo <= k / n <= hi <= 1.0
    with pytest.raises(ValueError, match="successes must be in"):
        bm.wilson_interval(11, 10)


def test_difference_interval_matches_newcombes_example() -> None:
    """Newcombe (1998), Stat. Med. 17:873, method 10 on 56/70 − 48/80: 0.0524 to 0.3339."""
    assert bm.difference_interval(56, 70, 48, 80) == pytest.approx((0.0524, 0.3339), abs=5e-5)
    lo, hi = bm.difference_interval(10, 10, 0, 10)  # stays inside [-1, 1] at the extremes
    assert hi == pytest.approx(1.0) and 0.5 < lo < 1.0
    lo, hi = bm.difference_interval(7, 20, 7, 20)
    assert lo == pytest.approx(-hi) and lo < 0 < hi
    assert all(math.isnan(v) for v in bm.difference_interval(1, 0, 1, 2))


def test_mode_gap_rows_pair_fast_with_image() -> None:
    def row(mode: str, k: int, n: int, policy: str = "p") -> dict[str, Any]:
        return {
            "env": "WheeledNav-v0",
            "policy": policy,
            "reality": "nominal",
            "sensor_mode": mode,
            "n": n,
            "success_mean": k / n,
        }

    rows = [row("fast", 56, 70), row("image", 48, 80), row("fast", 5, 5, "alone")]
    (gap,) = bm.mode_gap_rows(rows)  # a policy without image mode has no row
    assert (gap["policy"], gap["n_fast"], gap["n_image"]) == ("p", 70, 80)
    assert gap["gap_pp"] == pytest.approx(100 * (0.8 - 0.6))
    assert (gap["gap_ci_low_pp"], gap["gap_ci_high_pp"]) == pytest.approx((5.243, 33.387), abs=1e-2)


def test_summary_uses_wilson_for_rates_and_successes_for_time_to_goal() -> None:
    recs = [
        {
            "env_id": ENV_ID,
            "policy": "p",
            "reality": "nominal",
            "sensor_mode": "fast",
            "seed": k,
            **{m: 0.0 for m in bm.METRICS},
        }
        for k in range(4)
    ]
    for k, r in enumerate(recs):
        r["success"] = k < 3
        r["time_to_goal_s"] = 10.0 * (k + 1) if k < 3 else math.nan
    (row,) = bm.summarise(recs)
    assert row["n"] == 4 and row["success_mean"] == pytest.approx(0.75)
    assert (row["success_ci_low"], row["success_ci_high"]) == pytest.approx(
        bm.wilson_interval(3, 4)
    )
    assert row["time_to_goal_s_mean"] == pytest.approx(20.0)


# --------------------------------------------------------------------------- files, streaming
def test_tables_and_plots_are_written(bench_dir: Path) -> None:
    md = (bench_dir / "benchmark.md").read_text()
    assert "| WheeledNav-v0 | fast | classical | nominal | 1 |" in md
    assert "Sim-to-real transfer" in md and "kobuki-worn" in md
    header = (bench_dir / "summary.csv").read_text().splitlines()[0]
    assert "success_mean" in header and "success_ci_low" in header and "compute_ms_mean" in header
    assert (bench_dir / "transfer.csv").read_text().count("\n") == 3  # header + 2 policies
    assert not [p for p in bench_dir.iterdir() if p.name.startswith(".")], "temporary files left"


def test_files_are_written_atomically(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "table.csv"
    atomic_write_text(target, "old\n")

    def fail(*args: Any, **kwargs: Any) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_text(target, "new\n")
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["table.csv"]


def test_finished_episodes_survive_a_failing_task_and_are_resumed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_build = bm.build_policy

    def build(spec: bm.PolicySpec, env: Any, env_id: str, seed: int = 0) -> Any:
        if spec.name == "classical":
            raise RuntimeError("worker died")
        return real_build(spec, env, env_id, seed)

    monkeypatch.setattr(runner, "build_policy", build)
    cfg = _cfg(realities=(), episodes=1)
    store = bm.ResultStore(tmp_path / "episodes.jsonl")
    errors = bm.execute(bm.plan_tasks(cfg), store)
    assert len(errors) == 1 and "worker died" in errors[0]
    kept = store.load()
    assert [(r["policy"], r["seed"]) for r in kept] == [("random", 0)]
    # a torn last line (crash while writing) is ignored; finished episodes are not re-run
    with store.path.open("a") as fh:
        fh.write('{"env_id": "realitygap/Whee')
    done = {bm.record_key(r) for r in store.load()}
    left = bm.plan_tasks(cfg, done)
    assert [(t.policy.name, t.seeds) for t in left] == [("classical", (0,))]


@pytest.mark.slow
def test_a_policy_that_raises_fails_its_episode_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    class Boom:
        def predict(self, *args: Any, **kwargs: Any) -> Any:
            raise AssertionError("planner state")

    real_build = bm.build_policy

    def build(spec: bm.PolicySpec, env: Any, env_id: str, seed: int = 0) -> Any:
        return Boom() if spec.name == "classical" else real_build(spec, env, env_id, seed)

    monkeypatch.setattr(runner, "build_policy", build)
    result = bm.run_benchmark(_cfg(realities=(), episodes=2), tmp_path, verbose=False)
    assert result.errors == []
    crashed = [r for r in bm.ResultStore(result.files["episodes"]).load() if r.get("error")]
    assert [r["seed"] for r in crashed] == [0, 1]
    assert all(r["success"] is False and "planner state" in r["error"] for r in crashed)
    row = next(r for r in result.summary if r["policy"] == "classical")
    assert row["errors"] == 2 and row["success_mean"] == 0.0
    assert "2 episode(s) ended in an exception" in result.files["markdown"].read_text()


# --------------------------------------------------------------------------- bad input
def test_missing_ray_gives_the_install_hint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ImportError, match=r"pip install 'realitygap\[ray\]'"):
        bm.run_benchmark(_cfg(), tmp_path, backend="ray", verbose=False)
    assert not (tmp_path / "episodes.jsonl").exists()


def test_bad_names_are_refused_with_suggestions(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="Did you mean 'classical'"):
        bm.parse_policies("clasical,random")
    with pytest.raises(ValueError, match="Did you mean 'kobuki-worn'"):
        bm.reality_from_profile("kobuki-warn")
    with pytest.raises(FileNotFoundError, match="no file"):
        bm.parse_policies("mine=/no/such/model.zip")
    with pytest.raises(ValueError, match="backend must be"):
        bm.run_benchmark(_cfg(), tmp_path / "unused", backend="slurm", verbose=False)


def test_reality_profiles_build_and_json_profiles_load(tmp_path: Path) -> None:
    for name in bm.REALITY_PROFILES:
        reality = bm.reality_from_profile(name)
        assert reality.name == name and reality.effects
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(bm.reality_from_profile("kobuki-worn").to_dict()))
    # the effects in the pipeline's order: the command's latency before the body's geometry
    assert bm.reality_from_profile(str(path)).effect_names == (
        "command_latency",
        "wheel_diameter_ratio",
        "wheelbase_error",
    )


def test_env_specific_realities_and_sensor_modes() -> None:
    assert bm.reality_for(ENV_ID, "nominal") is None  # the env's default
    assert bm.reality_for(ENV_ID, "kobuki-worn").effect_names == (
        "command_latency",
        "wheel_diameter_ratio",
        "wheelbase_error",
    )
    assert bm.env_sensor_mode(ENV_ID, "fast") == "fast"
    assert bm.env_sensor_mode("realitygap/ArmCalib-v0", "fast") == "geometric"
    cfg = _cfg(
        env_ids=(ENV_ID, "realitygap/ArmCalib-v0"),
        realities=("kobuki-worn", "arm-worn"),
        episode_counts={"realitygap/ArmCalib-v0": 0, "image": 1},
    )
    cells = {t.cell for t in bm.plan_tasks(cfg)}
    assert {c[2] for c in cells} == {"nominal", "kobuki-worn"}  # arm cells: 0 episodes
    assert bm.n_episodes(cfg, "realitygap/ArmCalib-v0", "image") == 0
    assert bm.n_episodes(cfg, ENV_ID, "image") == 1


def test_cli_parsers_hook_up() -> None:
    from realitygap.baselines.cli import add_benchmark_parser, add_train_parser

    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command", required=True)
    add_benchmark_parser(sub)
    add_train_parser(sub)
    args = parser.parse_args(
        ["benchmark", "--policies", "classical,random", "--episodes", "3", "--backend", "ray"]
    )
    assert args.episodes == 3 and args.backend == "ray" and callable(args.func)
    args = parser.parse_args(["train", "--algo", "sac", "--timesteps", "100"])
    assert args.algo == "sac" and args.timesteps == 100


class _FakeRay:
    """Just enough of Ray's API to run the ray backend in-process; one task 'crashes'."""

    class _Ref:
        def __init__(self, fn: Any, arg: Any):
            self.fn, self.arg = fn, arg

    def __init__(self, crash_policy: str):
        self.crash_policy = crash_policy
        self.initialised_with: dict[str, Any] | None = None

    def is_initialized(self) -> bool:
        return self.initialised_with is not None

    def init(self, **kwargs: Any) -> None:
        self.initialised_with = kwargs

    def remote(self, **options: Any) -> Any:
        def wrap(fn: Any) -> Any:
            class Remote:
                @staticmethod
                def remote(arg: Any) -> _FakeRay._Ref:
                    return _FakeRay._Ref(fn, arg)

            return Remote

        return wrap

    def wait(self, refs: list[Any], num_returns: int = 1) -> tuple[list[Any], list[Any]]:
        return refs[:num_returns], refs[num_returns:]

    def get(self, ref: _Ref) -> Any:
        if ref.arg.policy.name == self.crash_policy:
            raise RuntimeError("worker crashed")
        return ref.fn(ref.arg)


def test_ray_backend_streams_results_and_survives_a_crashed_worker(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fake = _FakeRay(crash_policy="classical")
    monkeypatch.setitem(sys.modules, "ray", fake)
    result = bm.run_benchmark(
        _cfg(realities=()), tmp_path, backend="ray", address="ray://head:10001", verbose=False
    )
    assert fake.initialised_with is not None
    assert fake.initialised_with["address"] == "ray://head:10001"
    assert len(result.errors) == 1 and "worker crashed" in result.errors[0]
    assert [(r["policy"], r["reality"]) for r in result.summary] == [("random", "nominal")]
    assert "failed task" in (tmp_path / "benchmark.md").read_text()


class _Line3D(gym.Env):  # type: ignore[type-arg]
    """Moves 0.1 m along (1, 2, 2)/3 per step for three steps; 3-D pose + quaternion in info."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
        super().reset(seed=seed)
        self.k = 0
        return np.zeros(1, np.float32), {"true_pose": [0, 0, 0, 0, 0, 0, 1], "pos_error": 0.3}

    def step(self, action: Any) -> Any:
        self.k += 1
        p = 0.1 * self.k * np.array([1.0, 2.0, 2.0]) / 3.0
        info = {"true_pose": [*p, 0, 0, 0, 1], "pos_error": 0.3 - 0.1 * self.k}
        return np.zeros(1, np.float32), 0.0, self.k == 3, False, info


def test_path_length_counts_all_three_axes_of_a_3d_pose() -> None:
    rec = bm.run_episode(
        _Line3D(), bm.RandomPolicy(_Line3D.action_space, 0), seed=0, pose_shape=(7,)
    )
    assert rec["path_length_m"] == pytest.approx(0.3)
    assert rec["reached_10cm"] is True
