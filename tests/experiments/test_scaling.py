"""``diagnose-scaling`` and ``diagnose-ray``: the bench log, the power-law fit, the comparison
of two diagnoses, the local Ray cluster, and small end-to-end runs."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from realitygap.experiments import EXPERIMENTS, RunContext, load_all
from realitygap.experiments.scaling import (
    HIDDEN_EFFECT,
    bench_log,
    bench_logs,
    candidate_sets,
    fit_power_law,
    fresh_replay_cache,
    json_differences,
    strip_timing,
)


def test_both_experiments_are_registered() -> None:
    load_all()
    assert "diagnose-scaling" in EXPERIMENTS and "diagnose-ray" in EXPERIMENTS


# --------------------------------------------------------------------------- power law
@pytest.mark.parametrize("k", [0.5, 1.0, 1.7])
def test_power_law_recovers_an_exact_exponent(k: float) -> None:
    x = np.array([90.0, 360.0, 1440.0, 5760.0])
    fit = fit_power_law(x, 0.2 * x**k)
    assert fit.exponent == pytest.approx(k, abs=1e-12)
    assert fit.prefactor == pytest.approx(0.2, rel=1e-9)
    assert fit.r2 == pytest.approx(1.0) and fit.stderr == pytest.approx(0.0, abs=1e-9)
    assert fit.points == 4


def test_power_law_on_noisy_times_is_within_its_standard_error() -> None:
    rng = np.random.default_rng(7)
    x = np.geomspace(1.0, 64.0, 7)
    y = 3.0 * x**0.8 * np.exp(rng.normal(0.0, 0.05, x.size))
    fit = fit_power_law(x, y)
    assert 0.0 < fit.stderr < 0.05
    assert abs(fit.exponent - 0.8) < 4 * fit.stderr
    two = fit_power_law([1.0, 4.0], [2.0, 8.0])
    assert two.exponent == pytest.approx(1.0) and math.isnan(two.stderr)  # no residual dof


@pytest.mark.parametrize(
    ("x", "y", "match"),
    [
        ([90.0], [1.0], "at least two points, got 1"),
        ([1.0, 2.0], [1.0], "must pair up, got 2 and 1"),
        ([0.0, 2.0], [1.0, 2.0], r"every x must be finite and > 0.*\[0\.0\]"),
        ([1.0, 2.0], [1.0, float("nan")], "every time must be finite and > 0"),
        ([3.0, 3.0], [1.0, 2.0], r"two distinct values of x, got \[3\.0, 3\.0\]"),
    ],
)
def test_power_law_refuses_what_it_cannot_fit(x, y, match) -> None:
    with pytest.raises(ValueError, match=match):
        fit_power_law(x, y)


# --------------------------------------------------------------------------- comparing results
def test_json_differences_finds_what_differs_beyond_the_tolerance() -> None:
    a = {
        "verdict": ["wheel_diameter_ratio"],
        "ranking": [{"name": "a", "heldout_score": 0.5}, {"name": "b", "heldout_score": 0.25}],
        "margin": math.nan,
        "flags": np.array([1.0, 2.0]),
        "timing_s": {"total": 3.0},
    }
    b = {
        "verdict": ["wheel_diameter_ratio"],
        "ranking": [
            {"name": "a", "heldout_score": 0.5 + 1e-12},
            {"name": "b", "heldout_score": 0.25},
        ],
        "margin": float("nan"),
        "flags": [np.float64(1.0), 2.0],
        "timing_s": {"total": 9.0},
    }
    assert json_differences(strip_timing(a), strip_timing(b)) == []
    assert json_differences(a, b) == ["$.timing_s.total: 3.0 != 9.0 (differ by 6)"]
    b["ranking"][1]["heldout_score"] = 0.25 + 1e-6
    b["ranking"][0]["name"] = "c"
    b["extra"] = True
    found = json_differences(strip_timing(a), strip_timing(b))
    assert found == [
        "$.extra: only in the second",
        "$.ranking[0].name: 'a' != 'c'",
        "$.ranking[1].heldout_score: 0.25 != 0.250001 (differ by 1e-06)",
    ]


def test_json_differences_tells_types_and_lengths_apart() -> None:
    assert json_differences({"x": True}, {"x": 1}) == ["$.x: True != 1"]
    assert json_differences({"x": 1}, {"x": True}) == ["$.x: 1 != True"]
    assert json_differences([1, 2], [1, 2, 3]) == ["$: lengths 2 != 3"]
    assert json_differences(None, 0.0) == ["$: None != 0.0"]
    assert len(json_differences(list(range(100)), list(range(1, 101)), limit=5)) == 5


# --------------------------------------------------------------------------- bench logs
def test_candidate_sets_put_the_hidden_effect_first() -> None:
    library = ("wheel_radius_scale", "wheel_diameter_ratio", "wheelbase_error", "encoder_scale")
    assert candidate_sets([1, 3, 4], library) == [
        (HIDDEN_EFFECT,),
        (HIDDEN_EFFECT, "wheel_radius_scale", "wheelbase_error"),
        (HIDDEN_EFFECT, "wheel_radius_scale", "wheelbase_error", "encoder_scale"),
    ]
    with pytest.raises(ValueError, match="between 1 and the library's 4 effects, got 5"):
        candidate_sets([5], library)
    with pytest.raises(ValueError, match="must hold 'wheel_diameter_ratio'"):
        candidate_sets([1], ("wheelbase_error",))


def test_bench_logs_are_reproducible_from_their_seeds() -> None:
    logs, seeds = bench_logs(np.random.default_rng(3), 2, seconds=12.0, prefix="t")
    again, seeds_again = bench_logs(np.random.default_rng(3), 2, seconds=12.0, prefix="t")
    assert seeds == seeds_again and seeds[0] != seeds[1]
    assert [lg.name for lg in logs] == ["t-00", "t-01"]
    assert logs[0].duration == pytest.approx(12.0)
    rebuilt = bench_log(np.random.default_rng(seeds[1]), 12.0, name="t-01")
    for name in ("cmd", "pose_gt", "pose_cam"):
        np.testing.assert_array_equal(again[1].channels[name], logs[1].channels[name])
        np.testing.assert_array_equal(rebuilt.channels[name], logs[1].channels[name])
    # the same drive, measured with other noise
    np.testing.assert_array_equal(logs[0].channels["cmd"], logs[1].channels["cmd"])
    assert not np.array_equal(logs[0].channels["pose_gt"], logs[1].channels["pose_gt"])
    assert np.abs(logs[0].channels["cmd"][:-1]).max() > 0 and not logs[0].channels["cmd"][-1].any()


def test_bench_log_refuses_bad_arguments() -> None:
    with pytest.raises(TypeError, match=r"rng must be a numpy.random.Generator, got int"):
        bench_log(3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"finite duration ≥ 1 s, got 0.5"):
        bench_log(np.random.default_rng(0), 0.5)


def test_fresh_replay_cache_is_empty_and_goes_away(monkeypatch: pytest.MonkeyPatch) -> None:
    from realitygap.core.cache import CACHE_DIR_ENV, CACHE_ENV, default_cache

    monkeypatch.delenv(CACHE_ENV, raising=False)
    monkeypatch.setenv(CACHE_DIR_ENV, "/somewhere/else")
    with fresh_replay_cache() as folder:
        store = default_cache()
        assert store is not None and store.directory == folder
        assert folder.is_dir() and not any(folder.iterdir())
        store.put("replay", "ab12", {"x": np.arange(3.0)})
        assert store.get("replay", "ab12") is not None
    assert os.environ[CACHE_DIR_ENV] == "/somewhere/else"
    assert not folder.exists()
    monkeypatch.delenv(CACHE_DIR_ENV)
    with fresh_replay_cache():
        pass
    assert CACHE_DIR_ENV not in os.environ


# --------------------------------------------------------------------------- the experiments
def test_scaling_needs_two_sizes_per_sweep() -> None:
    load_all()
    ctx = RunContext(quick=True, verbose=False, options={"log_counts": (4,)})
    with pytest.raises(ValueError, match="'log_counts' needs at least two distinct positive"):
        EXPERIMENTS["diagnose-scaling"].func(ctx)


@pytest.mark.slow
def test_a_small_scaling_run_reports_exponents_points_and_stages() -> None:
    load_all()
    ctx = RunContext(
        quick=True,
        seed=4,
        verbose=False,
        options={
            "log_counts": (1, 2),
            "candidate_counts": (1, 2),
            "log_seconds": 30.0,
            "duration_effects": (HIDDEN_EFFECT,),
            "repeats": 1,
            "backend": "serial",
        },
    )
    out = EXPERIMENTS["diagnose-scaling"].func(ctx)
    fig, tables = out["figures"], out["tables"]
    assert math.isfinite(fig["duration_exponent"]) and math.isfinite(fig["candidates_exponent"])
    assert fig["duration_exponent_le_1_1"] == ("yes" if fig["duration_exponent"] <= 1.1 else "no")
    assert [r["log_seconds"] for r in tables["duration"]] == pytest.approx([30.0, 60.0])
    assert [r["candidates_asked"] for r in tables["candidates"]] == [1, 2]
    for row in tables["duration"] + tables["candidates"]:
        assert row["seconds"] > 0 and row["fit_s"] > 0 and row["prepare_s"] >= 0
        assert row["total_s"] == pytest.approx(row["seconds"], rel=0.05, abs=0.05)
    x = [r["log_seconds"] for r in tables["duration"]]
    assert fig["duration_exponent"] == pytest.approx(
        fit_power_law(x, [r["seconds"] for r in tables["duration"]]).exponent
    )
    assert {r["stage"] for r in tables["stages"]} >= {"prepare", "fit", "total"}
    assert "k ≤ 1.1" in out["notes"][0] and f"k = {fig['duration_exponent']:.2f}" in out["notes"][0]
    assert len(out["config"]["log_seeds"]) == 2


@pytest.fixture
def no_ray_connection(monkeypatch: pytest.MonkeyPatch):
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'realitygap[ray]')")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    if ray.is_initialized():
        ray.shutdown()
    yield ray
    if ray.is_initialized():
        ray.shutdown()


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.mark.slow
def test_local_cluster_has_two_nodes_and_stops_only_what_it_started(no_ray_connection) -> None:
    from realitygap.core.parallel import RayBackend
    from realitygap.experiments.scaling import LocalRayCluster, alive_nodes, node_of

    ray = no_ray_connection
    with LocalRayCluster(nodes=2, cpus_per_node=1) as cluster:
        pids, temp_dir = cluster.pids, Path(str(cluster.temp_dir))
        assert len(pids) == 2 and temp_dir.is_dir()
        nodes = alive_nodes()
        assert len(nodes) == 2 and sum(n["Resources"]["CPU"] for n in nodes) == 2
        used = set(RayBackend(cluster.address).map(node_of, list(range(4)), None))
        assert used == {n["NodeID"] for n in nodes}
        second = LocalRayCluster()
        with pytest.raises(RuntimeError, match="already connected to a Ray cluster"):
            second.__enter__()
        assert ray.is_initialized()  # the refused cluster left this connection alone
    assert not ray.is_initialized()
    assert all(_gone(pid) for pid in pids)
    assert not temp_dir.exists()


@pytest.mark.slow
def test_a_small_ray_run_gives_the_serial_results_on_two_nodes(no_ray_connection) -> None:
    load_all()
    ctx = RunContext(
        seed=2,
        verbose=False,
        options={"logs": 2, "log_seconds": 30.0, "effects": (HIDDEN_EFFECT, "wheelbase_error")},
    )
    out = EXPERIMENTS["diagnose-ray"].func(ctx)
    fig = out["figures"]
    assert fig["identical"] == "yes" and fig["differences"] == 0, out["notes"]
    assert fig["ranking_names_equal"] == "yes" and fig["heldout_score_max_diff"] <= 1e-9
    assert fig["verdict_serial"] == fig["verdict_ray"]
    assert fig["ray_nodes"] == 2 and fig["ray_nodes_used"] == 2 and fig["ray_cpus"] == 2
    assert fig["speedup_serial_over_ray"] == pytest.approx(
        fig["serial_seconds"] / fig["ray_seconds"]
    )
    assert out["config"]["cluster"].startswith("local")
    assert not no_ray_connection.is_initialized()
