"""Where the diagnosis runs its independent pieces of work: here, in processes, or on Ray.

A backend maps a module-level function ``fn(shared, item)`` over items. The
``shared`` object (the prepared problem: logs, features, surrogate) is sent
to each worker once, not with every item.

* :class:`SerialBackend` — in this process.
* :class:`ProcessBackend` — a :class:`concurrent.futures.ProcessPoolExecutor`
  (default: one worker per CPU).
* :class:`RayBackend` — tasks on a Ray cluster (a local one unless an address
  is given). Ray is optional; it is imported only when this backend is used.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Protocol, TypeVar

__all__ = ["Backend", "ProcessBackend", "RayBackend", "SerialBackend", "make_backend"]

T = TypeVar("T")
R = TypeVar("R")

RAY_MISSING = (
    "the Ray backend needs the optional dependency 'ray', which is not installed. "
    "Fix: pip install 'realitygap[ray]' (or use --backend process)"
)


class Backend(Protocol):
    """Maps ``fn(shared, item)`` over items; results in item order."""

    name: str

    def map(self, fn: Callable[[Any, T], R], items: Sequence[T], shared: Any) -> list[R]: ...


class SerialBackend:
    """Run everything in this process."""

    name = "serial"

    def map(self, fn: Callable[[Any, T], R], items: Sequence[T], shared: Any) -> list[R]:
        return [fn(shared, item) for item in items]


_SHARED: Any = None


def _init_worker(shared: Any) -> None:
    global _SHARED
    _SHARED = shared


def _call(job: tuple[Callable[[Any, Any], Any], Any]) -> Any:
    fn, item = job
    return fn(_SHARED, item)


class ProcessBackend:
    """A process pool per :meth:`map` call; the shared object reaches each worker once.

    Parameters
    ----------
    workers : int, optional
        Number of processes (default: the CPUs available to this process).
    """

    name = "process"

    def __init__(self, workers: int | None = None):
        if workers is None:
            try:
                workers = len(os.sched_getaffinity(0))
            except AttributeError:  # pragma: no cover - not Linux
                workers = os.cpu_count() or 1
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = int(workers)

    def map(self, fn: Callable[[Any, T], R], items: Sequence[T], shared: Any) -> list[R]:
        items = list(items)
        if self.workers == 1 or len(items) <= 1:
            return [fn(shared, item) for item in items]
        methods = multiprocessing.get_all_start_methods()
        ctx = multiprocessing.get_context("fork" if "fork" in methods else None)
        n = min(self.workers, len(items))
        with ProcessPoolExecutor(
            max_workers=n, mp_context=ctx, initializer=_init_worker, initargs=(shared,)
        ) as pool:
            return list(pool.map(_call, [(fn, item) for item in items]))


class RayBackend:
    """Tasks on a Ray cluster; ``address=None`` starts (or joins) a local one.

    Raises
    ------
    ImportError
        If Ray is not installed, with the ``pip install`` fix.
    """

    name = "ray"

    def __init__(self, address: str | None = None):
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ImportError(RAY_MISSING) from None
        self.address = address

    def map(self, fn: Callable[[Any, T], R], items: Sequence[T], shared: Any) -> list[R]:
        import ray

        if not ray.is_initialized():
            ray.init(address=self.address, ignore_reinit_error=True, log_to_driver=False)
        ref = ray.put(shared)
        remote = ray.remote(_ray_call)
        return list(ray.get([remote.remote(fn, ref, item) for item in items]))


def _ray_call(fn: Callable[[Any, Any], Any], shared: Any, item: Any) -> Any:
    return fn(shared, item)


def make_backend(
    name: str = "process", workers: int | None = None, address: str | None = None
) -> Backend:
    """Backend by name: ``"serial"``, ``"process"`` or ``"ray"``."""
    if name == "serial":
        return SerialBackend()
    if name == "process":
        return ProcessBackend(workers)
    if name == "ray":
        return RayBackend(address)
    raise ValueError(f"unknown backend {name!r}; expected 'serial', 'process' or 'ray'")
