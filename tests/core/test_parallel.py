"""The execution backends: results in item order, failures yielded per item."""

from __future__ import annotations

from typing import Any

import pytest

from realitygap.core.parallel import ProcessBackend, SerialBackend, make_backend


def _square(shared: Any, x: int) -> int:
    return x * x + (shared or 0)


def _fails_on_two(x: int) -> int:
    if x == 2:
        raise RuntimeError("two")
    return 10 * x


@pytest.mark.parametrize("backend", [SerialBackend(), ProcessBackend(2)])
def test_map_keeps_item_order_and_sends_the_shared_object(backend: Any) -> None:
    assert backend.map(_square, [3, 1, 2], 1) == [10, 2, 5]


@pytest.mark.parametrize("backend", [SerialBackend(), ProcessBackend(2, start_method="forkserver")])
def test_imap_unordered_yields_each_item_and_its_failure(backend: Any) -> None:
    outcomes = sorted(backend.imap_unordered(_fails_on_two, [1, 2, 3]), key=lambda o: o.index)
    assert [(o.item, o.value) for o in outcomes] == [(1, 10), (2, None), (3, 30)]
    assert [type(o.error).__name__ if o.error else None for o in outcomes] == [
        None,
        "RuntimeError",
        None,
    ]


def _blas_threads(shared: Any = None, item: Any = None) -> int:
    import numpy  # noqa: F401  (loads the BLAS)
    import threadpoolctl

    pools = [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
    return max(pools) if pools else -1


@pytest.mark.parametrize("start_method", [None, "forkserver"])
def test_process_workers_run_a_single_threaded_blas(start_method: str | None) -> None:
    pytest.importorskip("threadpoolctl")
    import threadpoolctl

    # the parent's pool stays as it is; the workers' pools are limited either way
    with threadpoolctl.threadpool_limits(limits=2):
        backend = ProcessBackend(2, start_method=start_method)
        assert backend.map(_blas_threads, [0, 1], None) == [1, 1]
        assert [o.value for o in backend.imap_unordered(_blas_threads, [0])] == [1]
        free = ProcessBackend(2, start_method=start_method, blas_threads=None)
        assert free.map(_blas_threads, [0, 1], None)[0] >= 1


def test_bad_backend_names_and_worker_counts_are_refused() -> None:
    with pytest.raises(ValueError, match="unknown backend 'slurm'"):
        make_backend("slurm")
    with pytest.raises(ValueError, match="workers must be >= 1"):
        ProcessBackend(0)
    with pytest.raises(ValueError, match="blas_threads must be a positive integer"):
        ProcessBackend(2, blas_threads=0)


def test_workers_beyond_the_cores_are_said_first_and_capped() -> None:
    from realitygap.core.parallel import available_cpus, cap_workers

    said: list[str] = []
    cpus = available_cpus()
    assert cap_workers(cpus + 1000, "--workers", said.append) == cpus
    assert len(said) == 1 and "--workers" in said[0] and f"using {cpus}" in said[0]
    assert cap_workers(1, "--workers", said.append) == 1 and len(said) == 1
    assert cap_workers(None) is None
