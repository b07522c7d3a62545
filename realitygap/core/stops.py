"""How a command ends: cleanly on Ctrl-C (SIGINT) or SIGTERM, in words on an error.

:func:`run_command` runs a command-line command and maps how it ends to an exit status and
one message (no traceback): 0 done; 1 done with failed parts or an operating-system error
(disk full, …); 2 a bad input or option; 130 / 143 stopped by SIGINT / SIGTERM; 70 an internal
error, said to be a bug (``--verbose`` shows the traceback).

Inside :func:`stop_on_signals`, both signals raise :class:`Stopped` in the main thread.
It is a :class:`BaseException` (like :class:`KeyboardInterrupt`), so that no ``except
Exception`` on the way swallows it: it unwinds the run, whose ``with`` blocks stop the worker
pool (:mod:`realitygap.core.parallel`) and remove staged outputs
(:mod:`realitygap.core.outputs`); the command line then prints one line and exits with
``128 + signal number`` (130 for SIGINT, 143 for SIGTERM), the shell convention.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from types import FrameType

__all__ = [
    "Stopped",
    "adopt_orphans",
    "descendants",
    "end_descendants",
    "run_command",
    "stop_of",
    "stop_on_signals",
]


class Stopped(BaseException):
    """The run was stopped by a signal; :attr:`signum` is its number."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)

    @property
    def name(self) -> str:
        """``"SIGINT"``, ``"SIGTERM"``, …"""
        try:
            return signal.Signals(self.signum).name
        except ValueError:  # pragma: no cover
            return f"signal {self.signum}"

    @property
    def exit_code(self) -> int:
        """``128 + signum``: 130 for SIGINT, 143 for SIGTERM."""
        return 128 + self.signum


_RECEIVED: list[int] = []
"""The signal that stopped the run, once one came: an exception that an extension module
raises while :class:`Stopped` unwinds through it (a ``SystemError`` "returned a result with
an exception set") is still that stop."""


def _raise(signum: int, _frame: FrameType | None) -> None:
    # a second signal while the first unwinds is ignored: the unwinding is the stop
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    _RECEIVED.append(int(signum))
    raise Stopped(signum)


def stop_of(exc: BaseException) -> Stopped | None:
    """The stop behind ``exc``: itself, a ``KeyboardInterrupt``, one in its cause or context
    chain, or any exception raised after a stop signal came; else ``None``."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, Stopped):
            return e
        if isinstance(e, KeyboardInterrupt):
            return Stopped(signal.SIGINT)
        e = e.__cause__ or e.__context__
    return Stopped(_RECEIVED[-1]) if _RECEIVED else None


@contextlib.contextmanager
def stop_on_signals() -> Iterator[None]:
    """SIGINT and SIGTERM raise :class:`Stopped` inside the block (main thread only; in
    another thread this does nothing). The previous handlers come back after it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    _RECEIVED.clear()
    for sig in previous:
        signal.signal(sig, _raise)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


def adopt_orphans() -> bool:
    """Make this process the "subreaper" of its descendants (Linux ``PR_SET_CHILD_SUBREAPER``):
    a process whose parent dies (a Ray agent whose raylet went first, a worker of a crashed
    pool) is re-parented to this process instead of to ``init``, so that
    :func:`end_descendants` still finds it. Returns whether it took effect."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_child_subreaper = 36
        return libc.prctl(pr_set_child_subreaper, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):  # pragma: no cover - not Linux
        return False


def descendants(pid: int | None = None) -> list[int]:
    """Process ids of every living descendant of ``pid`` (default: this process), from
    ``/proc`` (empty where there is none)."""
    root = os.getpid() if pid is None else int(pid)
    parent_of: dict[int, int] = {}
    try:
        entries = os.listdir("/proc")
    except OSError:  # pragma: no cover - not Linux
        return []
    for entry in entries:
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", encoding="ascii", errors="replace") as fh:
                stat = fh.read()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        if fields and fields[0] != "Z":  # a zombie is dead already
            parent_of[int(entry)] = int(fields[1])
    found: set[int] = set()
    frontier = {root}
    while frontier:
        frontier = {q for q, parent in parent_of.items() if parent in frontier} - found
        found |= frontier
    return sorted(found)


def end_descendants(timeout_s: float = 5.0) -> int:
    """SIGTERM every descendant of this process, wait up to ``timeout_s`` for them to go,
    SIGKILL the rest, and reap the ones that are children. Returns how many there were."""
    pids = descendants()
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in pids:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, sig)
        deadline = time.monotonic() + (timeout_s if sig == signal.SIGTERM else 1.0)
        while time.monotonic() < deadline:
            _reap()
            if not [p for p in pids if p in set(descendants())]:
                return len(pids)
            time.sleep(0.05)
    _reap()
    return len(pids)


def _reap() -> None:
    with contextlib.suppress(ChildProcessError, OSError):
        while os.waitpid(-1, os.WNOHANG)[0] > 0:
            pass


def _is_console_script() -> bool:
    """Whether this process is the ``realitygap`` command (its console script, or ``python -m``
    of a command-line module), not a program calling a ``main``."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    name = getattr(spec, "name", "")
    return Path(sys.argv[0]).name == "realitygap" or name.endswith(".cli")


def _os_error_words(exc: OSError) -> str:
    """An operating-system error in words: the file, the cause, the fix where one is known."""
    import errno

    where = f"{exc.filename}: " if exc.filename else ""
    fixes = {
        errno.ENOSPC: "the disk is full. Fix: free some space or write to another disk",
        errno.EDQUOT: "the disk quota is used up. Fix: free some space or write elsewhere",
        errno.EROFS: "the file system is read-only. Fix: write to a writable folder",
        errno.EACCES: "permission denied. Fix: choose a path you may write, or fix its mode",
        errno.EMFILE: "too many open files. Fix: raise the limit (ulimit -n) or use fewer workers",
    }
    cause = fixes.get(exc.errno or -1, exc.strerror or str(exc))
    return f"{where}{cause}; outputs not yet complete were not put in place"


def run_command(command: Callable[[], int], *, verbose: bool = False) -> int:
    """Run ``command`` (a sub-command with its arguments bound) and return its exit status.

    Inside, SIGINT and SIGTERM stop the run (:func:`stop_on_signals`); a stopped run ends
    every process it started (:func:`end_descendants`) and prints one line. An ``OSError``
    is said in words (exit 1); any other exception escaping a command is a bug of this
    package, said so (exit 70) with the traceback only under ``verbose``.
    """
    try:
        with stop_on_signals():
            if _is_console_script():
                adopt_orphans()
            return int(command())
    except BaseException as exc:
        stop = stop_of(exc)
        if stop is None:
            if isinstance(exc, OSError):
                print(f"error: {_os_error_words(exc)}", file=sys.stderr)
                return 1
            if not isinstance(exc, Exception):  # SystemExit and the like go on
                raise
            return _internal_error(exc, verbose)
        end_descendants()
        print(f"\nrealitygap: stopped by {stop.name}; no output was changed", file=sys.stderr)
        return stop.exit_code


def _internal_error(exc: Exception, verbose: bool) -> int:
    """Say that an exception escaped a command: a bug of this package (exit 70)."""
    if verbose:
        import traceback

        traceback.print_exception(exc)
    print(
        f"error: internal error ({type(exc).__name__}: {exc}). This is a bug in realitygap, "
        "not in your input; please report it with the command line"
        + ("" if verbose else " and the output of --verbose"),
        file=sys.stderr,
    )
    return 70
