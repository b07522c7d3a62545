"""The Ray backend: on a local two-CPU cluster it gives the process backend's results, and on
a local two-node cluster its tasks run on both nodes and give the serial backend's results."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'realitygap[ray]')")

from realitygap.core.parallel import (  # noqa: E402  (after the skip)
    RayBackend,
    SerialBackend,
    make_backend,
)


@pytest.fixture
def local_cluster(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """A one-node local cluster of two CPUs, this process connected."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    if ray.is_initialized():  # a connection another test left behind
        ray.shutdown()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield
    finally:
        ray.shutdown()


@pytest.fixture
def two_nodes(monkeypatch: pytest.MonkeyPatch) -> Iterator[object]:
    """A local cluster of two nodes of one CPU each (``ray.cluster_utils.Cluster``), this
    process not yet connected."""
    from ray.cluster_utils import Cluster

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    if ray.is_initialized():
        ray.shutdown()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        yield cluster
    finally:
        ray.shutdown()
        cluster.shutdown()


def _square(shared: int, item: int) -> int:
    return shared + item * item


def _square_where(shared: int, item: int) -> tuple[int, str]:
    """``shared + item²`` and the node that computed it; the pause keeps a task on its
    node's only CPU long enough that the other node takes the next one."""
    time.sleep(0.3)
    return shared + item * item, ray.get_runtime_context().get_node_id()


def _fail_on_three(item: int) -> int:
    if item == 3:
        raise ValueError("item 3 refuses")
    time.sleep(0.2)
    return 2 * item


# --------------------------------------------------------------------------- no cluster needed
def test_address_comes_from_ray_address_when_not_given(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RAY_ADDRESS", "10.1.2.3:6379")
    assert RayBackend().address == "10.1.2.3:6379"
    assert RayBackend("10.9.9.9:1234").address == "10.9.9.9:1234"  # an argument wins
    assert make_backend("ray").address == "10.1.2.3:6379"
    monkeypatch.delenv("RAY_ADDRESS")
    assert RayBackend().address is None
    assert not RayBackend().connected  # nothing connects before the first map


def test_bad_address_and_backend_names_are_refused() -> None:
    with pytest.raises(TypeError, match=r"address must be a Ray cluster address.*got int 6379"):
        RayBackend(6379)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"unknown backend 'rey'.*'serial', 'process' or 'ray'"):
        make_backend("rey")


def test_same_endpoint_compares_ports_and_this_machines_names() -> None:
    same = RayBackend._same_endpoint
    assert same("127.0.0.1:6379", "localhost:6379")
    assert same("10.0.0.5:6379", "10.0.0.5:6379")
    assert not same("127.0.0.1:6379", "127.0.0.1:6380")
    assert not same("10.255.0.5:6379", "127.0.0.1:6379")  # not an address of this machine


# --------------------------------------------------------------------------- one node, two CPUs
@pytest.mark.slow
def test_map_keeps_item_order(local_cluster) -> None:
    assert RayBackend().map(_square, list(range(7)), 10) == [10 + k * k for k in range(7)]


@pytest.mark.slow
def test_small_diagnose_suite_equals_the_process_backend(local_cluster) -> None:
    """Two blind cases (hidden effects realised in PyBullet, then diagnosed) on each backend;
    a small candidate library and single effects keep it quick."""
    from realitygap.core.parallel import ProcessBackend
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


# --------------------------------------------------------------------------- two nodes
@pytest.mark.slow
def test_map_on_two_nodes_equals_the_serial_backend_and_uses_both(two_nodes) -> None:
    items = list(range(8))
    with RayBackend(two_nodes.address) as backend:
        on_ray = backend.map(_square_where, items, 10)
        assert backend.connected  # the backend made the connection …
        alive = {n["NodeID"] for n in ray.nodes() if n["Alive"]}
        on_here = SerialBackend().map(_square_where, items, 10)
    assert not ray.is_initialized()  # … and leaving the block closed it
    assert [v for v, _ in on_ray] == [v for v, _ in on_here] == [10 + k * k for k in items]
    used = {node for _, node in on_ray}
    assert len(alive) == 2
    assert used == alive  # every task on a node of the cluster, and both nodes took some


@pytest.mark.slow
def test_imap_unordered_on_two_nodes_yields_every_item_and_the_failure(two_nodes) -> None:
    items = list(range(6))
    backend = RayBackend(two_nodes.address)
    try:
        outcomes = sorted(backend.imap_unordered(_fail_on_three, items), key=lambda o: o.index)
        with pytest.raises(RuntimeError, match=r"already connected to the Ray cluster at"):
            RayBackend("10.255.0.5:6379").map(_square, [1], 0)  # another cluster
    finally:
        backend.shutdown()
    assert [o.index for o in outcomes] == items
    assert [o.value for o in outcomes if o.error is None] == [0, 2, 4, 8, 10]
    (failed,) = [o for o in outcomes if o.error is not None]
    assert failed.item == 3 and "item 3 refuses" in str(failed.error)
