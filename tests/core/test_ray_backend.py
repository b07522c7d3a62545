"""The Ray backend on a local two-CPU cluster gives the process backend's results."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'realitygap[ray]')")


@pytest.fixture(scope="module")
def local_cluster():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def _square(shared: int, item: int) -> int:
    return shared + item * item


@pytest.mark.slow
def test_map_keeps_item_order(local_cluster) -> None:
    from realitygap.core.parallel import RayBackend

    assert RayBackend().map(_square, list(range(7)), 10) == [10 + k * k for k in range(7)]


@pytest.mark.slow
def test_small_diagnose_suite_equals_the_process_backend(local_cluster) -> None:
    """Two blind cases (hidden effects realised in PyBullet, then diagnosed) on each backend;
    a small candidate library and single effects keep it quick."""
    from realitygap.core.parallel import ProcessBackend, RayBackend
    from realitygap.diagnosis.diagnose import DiagnosisSettings
    from realitygap.diagnosis.problem.problem import AttributionSettings
    from realitygap.diagnosis.validation.suite import SuiteSettings, draw_cases, run_suite

    settings = SuiteSettings(
        diagnosis=DiagnosisSettings(
            effects=("wheelbase_error", "wheel_diameter_ratio", "command_latency"),
            attribution=AttributionSettings(pair_candidates=0, verify_top=1),
        ),
        open_set_every=2,
    )
    cases = draw_cases(2, 3, settings)
    on_ray = run_suite(cases, settings, RayBackend())
    on_processes = run_suite(cases, settings, ProcessBackend(2))
    strip = [
        [
            json.dumps(
                {k: v for k, v in row.items() if not k.startswith("seconds")},
                sort_keys=True,
                default=str,
            )
            for row in rows
        ]
        for rows in (on_ray, on_processes)
    ]
    assert strip[0] == strip[1]  # as JSON: NaN-safe
    assert [o["index"] for o in on_ray] == [c.index for c in cases]


def _episodes(folder: Path) -> list[str]:
    """The episode records without their wall-clock timing, as sorted JSON strings (NaN-safe)."""
    rows = [json.loads(line) for line in (folder / "episodes.jsonl").read_text().splitlines()]
    timing = {"compute_ms", "wall_s", "seconds"}
    return sorted(
        json.dumps({k: v for k, v in r.items() if k not in timing}, sort_keys=True) for r in rows
    )


@pytest.mark.slow
def test_small_benchmark_equals_the_process_backend(local_cluster, tmp_path: Path) -> None:
    from realitygap.cli import main

    common = [
        "benchmark",
        "--envs",
        "realitygap/WheeledNav-v0",
        "--policies",
        "classical,random",
        "--episodes",
        "1",
        "--sensor-modes",
        "fast",
        "--reality",
        "none",
        "--quiet",
    ]
    assert main([*common, "--backend", "ray", "--out", str(tmp_path / "ray")]) == 0
    assert main([*common, "--workers", "2", "--out", str(tmp_path / "process")]) == 0
    assert _episodes(tmp_path / "ray") == _episodes(tmp_path / "process")
    assert len(_episodes(tmp_path / "ray")) == 2  # one episode of each policy
