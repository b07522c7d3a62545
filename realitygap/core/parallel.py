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

import contextlib
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
    "available_cpus",
    "cap_workers",
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
    controller = _blas_controller()
    if controller is not None:
        _BLAS_LIMIT = controller.limit(limits=threads)


_CONTROLLER: Any = None


def _blas_controller() -> Any:
    """This process's ``threadpoolctl`` controller (``None`` without threadpoolctl), made once.

    Finding the loaded BLAS / OpenMP libraries takes a few tenths of a second; made in
    the parent before a pool forks, every worker inherits the result and only sets its
    limit (a pool started per stage of a diagnosis would otherwise pay it per worker).
    """
    global _CONTROLLER
    if _CONTROLLER is None:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - optional
            return None
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER


def _quiet_worker_signals() -> None:
    """Signals in a worker process: Ctrl-C (sent by a terminal to the whole process group) is
    the main process's to handle, so a worker ignores it and prints no traceback; SIGTERM
    ends the worker at once; and a worker ends when its parent dies (Linux), so that a
    killed run leaves no orphan processes."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_pdeathsig = 1
        libc.prctl(pr_set_pdeathsig, signal.SIGTERM)
        if os.getppid() == 1:  # the parent died before the line above
            os._exit(1)
    except (OSError, AttributeError):  # pragma: no cover - not Linux
        pass


def _init_worker(shared: Any, blas_threads: int | None = None) -> None:
    global _SHARED
    _quiet_worker_signals()
    if blas_threads is not None:
        limit_blas_threads(blas_threads)
    _SHARED = shared


def _call(job: tuple[Callable[[Any, Any], Any], Any]) -> Any:
    fn, item = job
    return fn(_SHARED, item)


@contextlib.contextmanager
def _stopping(pool: ProcessPoolExecutor) -> Iterator[ProcessPoolExecutor]:
    """``pool`` for a ``with`` block that, when left by an error or an interruption (Ctrl-C,
    SIGTERM), cancels the pending items and terminates the running workers at once instead
    of waiting for them to finish."""
    try:
        yield pool
    except BaseException:
        processes = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in processes:
            with contextlib.suppress(Exception):
                proc.terminate()
        for proc in processes:
            with contextlib.suppress(Exception):
                proc.join(timeout=5)
        raise
    else:
        pool.shutdown(wait=True)


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
            workers = available_cpus()
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
        if self.blas_threads is not None:
            _blas_controller()  # found once here; the forked workers inherit it
        with _stopping(
            ProcessPoolExecutor(
                max_workers=n,
                mp_context=self._context(),
                initializer=_init_worker,
                initargs=(shared, self.blas_threads),
            )
        ) as pool:
            return list(pool.map(_call, [(fn, item) for item in items]))

    def imap_unordered(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[Outcome[T, R]]:
        """Submit every item to a pool of ``workers`` processes; yield each as it finishes.

        A crashed worker shows as a
        :class:`concurrent.futures.process.BrokenProcessPool` error of its items.
        """
        items = list(items)
        if self.blas_threads is not None:
            _blas_controller()
        with _stopping(
            ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=self._context(),
                initializer=_init_worker,
                initargs=(None, self.blas_threads),
            )
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
    """Tasks on a Ray cluster: the one at ``address``, else the one ``RAY_ADDRESS`` names,
    else a local one.

    The connection is made on first use. Where this process is already connected to Ray,
    that connection is used; it must be to the cluster ``address`` names, if one is named.
    :meth:`shutdown` (or leaving a ``with`` block) disconnects, when this backend made the
    connection.

    Parameters
    ----------
    address : str, optional
        Ray cluster address (``"host:port"`` of its head, ``"ray://host:port"`` for Ray
        Client); ``None``: the ``RAY_ADDRESS`` environment variable when it is set, else a
        local cluster (started, or the last one ``ray start`` started on this machine).
    missing : str, optional
        Message of the ``ImportError`` when Ray is not installed.
    task_options : mapping, optional
        Ray task options of :meth:`map` and :meth:`imap_unordered` (default one CPU,
        one retry).
    log_to_driver : bool
        Whether the workers' output reaches this process (default ``False``).

    Raises
    ------
    ImportError
        If Ray is not installed, with the ``pip install`` fix.
    TypeError
        If ``address`` is not a string or ``None``.
    """

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        missing: str = RAY_MISSING,
        task_options: Mapping[str, Any] | None = None,
        log_to_driver: bool = False,
    ):
        if address is not None and not isinstance(address, str):
            raise TypeError(
                f"address must be a Ray cluster address such as '10.0.0.5:6379' or None, "
                f"got {type(address).__name__} {address!r}"
            )
        self._ray = require_ray(missing)
        if address is None:
            address = os.environ.get("RAY_ADDRESS") or None
        self.address = address
        self.task_options = dict(
            {"num_cpus": 1, "max_retries": 1} if task_options is None else task_options
        )
        self.log_to_driver = log_to_driver
        self._connected_here = False

    def _init(self) -> Any:
        ray = self._ray
        if ray.is_initialized():
            self._check_same_cluster(ray.get_runtime_context().gcs_address)
            return ray
        import signal
        import threading

        # ray.init installs its own SIGTERM handler (sys.exit(15)); the caller's handlers,
        # which stop a run cleanly (realitygap.core.stops), come back after it
        main = threading.current_thread() is threading.main_thread()
        sigs = (signal.SIGINT, signal.SIGTERM)
        handlers = {sig: signal.getsignal(sig) for sig in sigs} if main else {}
        ray.init(address=self.address, log_to_driver=self.log_to_driver)
        for sig, handler in handlers.items():
            if handler is not None:
                signal.signal(sig, handler)
        self._connected_here = True
        return ray

    def _check_same_cluster(self, connected: str) -> None:
        """Refuse an ``address`` that names another cluster than the one already connected."""
        named = self.address
        if named is None or named in ("auto", "local") or "://" in named or not connected:
            return  # no address to compare (Ray Client addresses name a proxy, not the GCS)
        if self._same_endpoint(named, connected):
            return
        raise RuntimeError(
            f"RayBackend(address={named!r}): this process is already connected to the Ray "
            f"cluster at {connected!r}, and Ray connects a process to one cluster at a time. "
            f"Fix: call ray.shutdown() before using the cluster at {named!r}, or pass "
            f"address={connected!r} to use the connected one"
        )

    @staticmethod
    def _same_endpoint(a: str, b: str) -> bool:
        """Whether ``host:port`` addresses ``a`` and ``b`` name the same server: same port,
        and the same host or both hosts this machine (a cluster started here answers on its
        IP and on the loopback)."""
        host_a, _, port_a = a.rpartition(":")
        host_b, _, port_b = b.rpartition(":")
        if port_a != port_b:
            return False
        if host_a == host_b:
            return True
        return RayBackend._is_this_machine(host_a) and RayBackend._is_this_machine(host_b)

    @staticmethod
    def _is_this_machine(host: str) -> bool:
        import socket

        host = host.strip("[]")
        if host in ("localhost", "::1", "0.0.0.0", socket.gethostname()) or host.startswith("127."):
            return True
        ours: set[str] = set()
        try:
            ours |= {str(info[4][0]) for info in socket.getaddrinfo(socket.gethostname(), None)}
        except OSError:
            pass
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
                probe.connect(("192.0.2.1", 9))  # sends nothing: picks the outgoing interface
                ours.add(probe.getsockname()[0])
        except OSError:
            pass
        return host in ours

    @property
    def connected(self) -> bool:
        """Whether this backend made the process's current Ray connection."""
        return self._connected_here and self._ray.is_initialized()

    def shutdown(self) -> None:
        """Disconnect from Ray if this backend connected; a connection made elsewhere stays.

        For a local cluster that the connection started, this also stops that cluster.
        """
        if self.connected:
            self._ray.shutdown()
        self._connected_here = False

    def __enter__(self) -> RayBackend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    def map(self, fn: Callable[[Any, T], R], items: Sequence[T], shared: Any) -> list[R]:
        """One Ray task per item (with :attr:`task_options`); ``shared`` is put in the object
        store once. Returns the results in item order; the first failing task's error is
        raised."""
        ray = self._init()
        ref = ray.put(shared)
        remote = ray.remote(**self.task_options)(_ray_call)
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


def available_cpus() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def cap_workers(
    workers: int | None, option: str = "--workers", warn: Callable[[str], None] | None = None
) -> int | None:
    """``workers`` capped at the CPUs available, said before any work starts.

    Every item here is CPU-bound: processes beyond the cores only add their start-up (about
    0.1 s each, so 1 000 workers on 2 cores spend two minutes starting) and their memory.
    ``None`` (the default: one per CPU) is returned as is.
    """
    if workers is None:
        return None
    cpus = available_cpus()
    if workers > cpus:
        if warn is not None:
            warn(
                f"{option} {workers} on {cpus} CPU(s): workers beyond the cores only add "
                f"start-up time and memory; using {cpus}"
            )
        return cpus
    return workers


def make_backend(
    name: str = "process", workers: int | None = None, address: str | None = None
) -> Backend:
    """Backend by name: ``"serial"``, ``"process"`` (``workers`` processes) or ``"ray"`` (the
    cluster at ``address``; ``None``: ``RAY_ADDRESS``, else a local one; see
    :class:`RayBackend`).

    Raises
    ------
    ValueError
        An unknown ``name``, or ``workers`` below 1.
    ImportError
        ``"ray"`` where Ray is not installed.
    """
    if name == "serial":
        return SerialBackend()
    if name == "process":
        return ProcessBackend(workers)
    if name == "ray":
        return RayBackend(address)
    raise ValueError(
        f"unknown backend {name!r}; expected 'serial', 'process' or 'ray' "
        "(--backend serial|process|ray)"
    )
