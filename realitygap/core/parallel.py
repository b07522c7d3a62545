"""Where independent pieces of work run: here, in processes, or on Ray.

A backend maps a module-level function over items in two ways:

* :meth:`Backend.map` runs ``fn(shared, item)`` and returns the results in item
  order. The ``shared`` object (for instance a prepared diagnosis problem: logs,
  features, surrogate) is sent to each worker once, not with every item.
* :meth:`Backend.imap_unordered` runs ``fn(item)`` and yields an :class:`Outcome`
  per item as soon as it finishes; a failing item yields its exception instead of
  ending the run, so a caller can keep the finished work (the benchmark streams
  episodes to disk this way).

* :class:`SerialBackend` — in this process.
* :class:`ProcessBackend` — a :class:`concurrent.futures.ProcessPoolExecutor`
  (default: one worker per CPU), each worker's BLAS limited to one thread:
  several processes each running a multithreaded BLAS on the same cores
  oversubscribe them, and small least-squares fits then run many times slower.
* :class:`RayBackend` — tasks on a Ray cluster (a local one unless an address
  is given). Ray is optional; it is imported only when this backend is used.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

__all__ = [
    "Backend",
    "Outcome",
    "ProcessBackend",
    "RayBackend",
    "SerialBackend",
    "limit_blas_threads",
    "make_backend",
    "require_ray",
]

T = TypeVar("T")
R = TypeVar("R")

RAY_MISSING = (
    "the Ray backend needs the optional dependency 'ray', which is not installed. "
    "Fix: pip install 'realitygap[ray]' (or use --backend process)"
)


def require_ray(missing: str = RAY_MISSING) -> Any:
    """Import and return Ray, or raise an ``ImportError`` with the message ``missing``."""
    try:
        import ray
    except ImportError as exc:
        raise ImportError(missing) from exc
    return ray


@dataclass(frozen=True)
class Outcome(Generic[T, R]):
    """One finished item of :meth:`Backend.imap_unordered`.

    Attributes
    ----------
    index : position of the item in the sequence handed in.
    item : the item itself.
    value : what ``fn(item)`` returned (``None`` when it raised).
    error : the exception ``fn(item)`` raised, or ``None``.
    """

    index: int
    item: T
    value: R | None = None
    error: BaseException | None = None


class Backend(Protocol):
    """Maps a function over items: :meth:`map` in item order, :meth:`imap_unordered` as
    items finish."""

    name: str

    def map(self, fn: Callable[[Any, T], R], items: Sequence[T], shared: Any) -> list[R]: ...

    def imap_unordered(
        self, fn: Callable[[T], R], items: Sequence[T]
    ) -> Iterator[Outcome[T, R]]: ...


class SerialBackend:
    """Run everything in this process."""

    name = "serial"

    def map(self, fn: Callable[[Any, T], R], items: Sequence[T], shared: Any) -> list[R]:
        return [fn(shared, item) for item in items]

    def imap_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[Outcome[T, R]]:
        """Run the items in order; an exception of one item is yielded, not raised."""
        for i, item in enumerate(items):
            try:
                value = fn(item)
            except Exception as exc:
                yield Outcome(i, item, error=exc)
                continue
            yield Outcome(i, item, value=value)


_SHARED: Any = None
_BLAS_LIMIT: Any = None

BLAS_THREAD_VARIABLES = (
    "OPENBLAS_NUM_THREADS",
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "BLIS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)
"""Environment variables that set the thread pools of BLAS / OpenMP libraries."""


def limit_blas_threads(threads: int) -> None:
    """Limit the BLAS / OpenMP thread pools of this process to ``threads`` threads.

    Sets :data:`BLAS_THREAD_VARIABLES` (read by libraries loaded from now on and by
    child processes) and, when ``threadpoolctl`` is installed, limits the pools of
    libraries already loaded (a forked worker inherits a loaded OpenBLAS).

    Raises
    ------
    ValueError
        If ``threads`` is not a positive integer.
    """
    global _BLAS_LIMIT
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"blas_threads must be a positive integer, got {threads!r}")
    for var in BLAS_THREAD_VARIABLES:
        os.environ[var] = str(threads)
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - optional
        return
    _BLAS_LIMIT = threadpool_limits(limits=threads)


def _init_worker(shared: Any, blas_threads: int | None = None) -> None:
    global _SHARED
    if blas_threads is not None:
        limit_blas_threads(blas_threads)
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
    start_method : str, optional
        :mod:`multiprocessing` start method (default ``"fork"`` where available).
        ``"forkserver"`` suits work that imports torch or PyBullet in the workers.
    blas_threads : int or None
        Threads of each worker's BLAS / OpenMP pools (default 1, see
        :func:`limit_blas_threads`); ``None`` leaves them as the libraries choose.

    Raises
    ------
    ValueError
        If ``workers`` or ``blas_threads`` is below 1.
    """

    name = "process"

    def __init__(
        self,
        workers: int | None = None,
        start_method: str | None = None,
        blas_threads: int | None = 1,
    ):
        if workers is None:
            try:
                workers = len(os.sched_getaffinity(0))
            except AttributeError:  # pragma: no cover - not Linux
                workers = os.cpu_count() or 1
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if blas_threads is not None and (
            isinstance(blas_threads, bool) or not isinstance(blas_threads, int) or blas_threads < 1
        ):
            raise ValueError(
                f"blas_threads must be a positive integer or None, got {blas_threads!r}"
            )
        self.workers = int(workers)
        self.start_method = start_method
        self.blas_threads = blas_threads

    def _context(self) -> Any:
        if self.start_method is not None:
            return multiprocessing.get_context(self.start_method)
        methods = multiprocessing.get_all_start_methods()
        return multiprocessing.get_context("fork" if "fork" in methods else None)

    def map(self, fn: Callable[[Any, T], R], items: Sequence[T], shared: Any) -> list[R]:
        items = list(items)
        if self.workers == 1 or len(items) <= 1:
            return [fn(shared, item) for item in items]
        n = min(self.workers, len(items))
        with ProcessPoolExecutor(
            max_workers=n,
            mp_context=self._context(),
            initializer=_init_worker,
            initargs=(shared, self.blas_threads),
        ) as pool:
            return list(pool.map(_call, [(fn, item) for item in items]))

    def imap_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[Outcome[T, R]]:
        """Submit every item to a pool of ``workers`` processes; yield each as it finishes.

        A crashed worker shows as a
        :class:`concurrent.futures.process.BrokenProcessPool` error of its items.
        """
        items = list(items)
        with ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=self._context(),
            initializer=_init_worker,
            initargs=(None, self.blas_threads),
        ) as pool:
            futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
            for fut in as_completed(futures):
                i = futures[fut]
                try:
                    value = fut.result()
                except Exception as exc:
                    yield Outcome(i, items[i], error=exc)
                    continue
                yield Outcome(i, items[i], value=value)


class RayBackend:
    """Tasks on a Ray cluster; ``address=None`` starts (or joins) a local one.

    Parameters
    ----------
    address : str, optional
        Ray cluster address; ``None`` starts (or joins) a local cluster.
    missing : str, optional
        Message of the ``ImportError`` when Ray is not installed.
    task_options : mapping, optional
        Ray task options of :meth:`imap_unordered` (default one CPU, one retry).
    log_to_driver : bool
        Whether the workers' output reaches this process (default ``False``).

    Raises
    ------
    ImportError
        If Ray is not installed, with the ``pip install`` fix.
    """

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        missing: str = RAY_MISSING,
        task_options: Mapping[str, Any] | None = None,
        log_to_driver: bool = False,
    ):
        self._ray = require_ray(missing)
        self.address = address
        self.task_options = dict(
            {"num_cpus": 1, "max_retries": 1} if task_options is None else task_options
        )
        self.log_to_driver = log_to_driver

    def _init(self) -> Any:
        ray = self._ray
        if not ray.is_initialized():
            ray.init(
                address=self.address, ignore_reinit_error=True, log_to_driver=self.log_to_driver
            )
        return ray

    def map(self, fn: Callable[[Any, T], R], items: Sequence[T], shared: Any) -> list[R]:
        ray = self._init()
        ref = ray.put(shared)
        remote = ray.remote(_ray_call)
        return list(ray.get([remote.remote(fn, ref, item) for item in items]))

    def imap_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[Outcome[T, R]]:
        """One Ray task per item (with :attr:`task_options`); yield each as it finishes."""
        ray = self._init()
        items = list(items)
        remote = ray.remote(**self.task_options)(fn)
        pending = {remote.remote(item): i for i, item in enumerate(items)}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                i = pending.pop(ref)
                try:
                    value = ray.get(ref)
                except Exception as exc:  # RayTaskError, WorkerCrashedError, …
                    yield Outcome(i, items[i], error=exc)
                    continue
                yield Outcome(i, items[i], value=value)


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
