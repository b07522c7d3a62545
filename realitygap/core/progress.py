"""What a long run tells the person waiting for it.

* :class:`Progress` — a progress bar on ``stderr`` with the elapsed time and an
  estimate of the time left (``tqdm``), or nothing when the run is quiet.
* :func:`quiet_c_output` — silence what C code prints to file descriptors 1
  and 2 while a block runs (PyBullet prints its build time when it is imported).
* :class:`Countdown` — elapsed time and time left against an estimate made before a
  run whose steps are not counted (a diagnosis: replays, fits, verification).
* :func:`duration_words` — a duration in the unit a person reads ("about 7 min").

Standard library only at import; ``tqdm`` is imported when a bar is shown.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from collections.abc import Iterator
from typing import IO, Any

__all__ = ["Countdown", "Progress", "duration_words", "quiet_c_output"]


@contextlib.contextmanager
def quiet_c_output() -> Iterator[None]:
    """Send whatever is written to file descriptors 1 and 2 inside the block to ``os.devnull``.

    Python's ``sys.stdout`` and ``sys.stderr`` are flushed first, so nothing printed
    before the block is lost, and C's stdio buffers are flushed inside the block (C
    code writing to a pipe buffers its output); both descriptors are restored
    afterwards, also on an error, so an exception raised inside the block is shown
    as usual. Where a descriptor cannot be duplicated (no real stream), it is left
    as is.
    """
    saved: dict[int, int] = {}
    for fd, stream in ((1, sys.stdout), (2, sys.stderr)):
        try:
            stream.flush()
            saved[fd] = os.dup(fd)
        except (OSError, ValueError, AttributeError):
            continue
    try:
        if saved:
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                for fd in saved:
                    os.dup2(devnull, fd)
            finally:
                os.close(devnull)
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError, AttributeError):
                stream.flush()
        _flush_c_stdio()
        for fd, copy in saved.items():
            os.dup2(copy, fd)
            os.close(copy)


def _flush_c_stdio() -> None:
    """Flush the C library's stdio buffers (``fflush(NULL)``), where ``ctypes`` can reach it.

    C code writing to a pipe is block-buffered: without this, its text would leave
    the buffer after descriptor 1 is restored.
    """
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):
        pass


def duration_words(seconds: float) -> str:
    """``seconds`` as a person says it: ``"40 s"``, ``"about 7 min"``, ``"about 1.5 h"``."""
    if not seconds >= 0:
        raise ValueError(f"duration_words: expected a duration >= 0 s, got {seconds!r}")
    if seconds < 90:
        return f"{max(1, round(seconds))} s"
    if seconds < 90 * 60:
        return f"about {round(seconds / 60)} min"
    return f"about {seconds / 3600:.1f} h"


class Progress:
    """A counted run shown as a bar with elapsed time and time left.

    Parameters
    ----------
    total : int
        Number of steps of the run (cases, episodes, fits).
    description : str
        What is counted, shown before the bar.
    enabled : bool
        ``False`` shows nothing (``--quiet``).
    stream : file-like, optional
        Where the bar goes (default ``sys.stderr``).

    Notes
    -----
    Without ``tqdm`` a line per step is printed with the same estimate: time
    left = elapsed × (total − done) / done.
    """

    def __init__(
        self, total: int, description: str, enabled: bool = True, stream: IO[str] | None = None
    ) -> None:
        if total < 0:
            raise ValueError(f"Progress: total must be >= 0, got {total}")
        self.total = int(total)
        self.description = description
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.done = 0
        self._t0 = time.perf_counter()
        self._bar: Any = None
        if enabled:
            try:
                from tqdm import tqdm
            except ImportError:
                self._bar = None
            else:
                self._bar = tqdm(
                    total=self.total,
                    desc=description,
                    file=self.stream,
                    unit="",
                    dynamic_ncols=True,
                    bar_format="{desc}: {n}/{total} |{bar}| {elapsed} elapsed, "
                    "{remaining} left {postfix}",
                )

    def remaining_s(self) -> float:
        """Estimated seconds left (``nan`` before the first step)."""
        if self.done == 0:
            return float("nan")
        elapsed = time.perf_counter() - self._t0
        return elapsed * (self.total - self.done) / self.done

    def update(self, steps: int = 1, note: str = "") -> None:
        """Count ``steps`` more as done; ``note`` is shown after the bar."""
        self.done += steps
        if not self.enabled:
            return
        if self._bar is not None:
            if note:
                self._bar.set_postfix_str(note, refresh=False)
            self._bar.update(steps)
            return
        left = self.remaining_s()
        left_text = duration_words(left) if left == left else "?"
        print(
            f"{self.description}: {self.done}/{self.total}, {left_text} left"
            + (f" ({note})" if note else ""),
            file=self.stream,
            flush=True,
        )

    def write(self, message: str) -> None:
        """Print ``message`` above the bar (or as a line when there is none)."""
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.write(message, file=self.stream)
        else:
            print(message, file=self.stream, flush=True)

    def close(self) -> None:
        """End the bar (idempotent)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Countdown:
    """Elapsed time and the time left of a run against an estimate made before it started.

    Parameters
    ----------
    estimate_s : float
        Expected duration of the whole run, s (``nan``: unknown).

    Examples
    --------
    >>> c = Countdown(120.0)
    >>> c.prefix(elapsed_s=30.0)
    '[0:30, about 2 min left]'
    >>> c.prefix(elapsed_s=150.0)
    '[2:30, longer than the 2 min estimated]'
    """

    def __init__(self, estimate_s: float) -> None:
        self.estimate_s = float(estimate_s)
        self._t0 = time.perf_counter()

    def elapsed_s(self) -> float:
        """Seconds since the countdown started."""
        return time.perf_counter() - self._t0

    def prefix(self, elapsed_s: float | None = None) -> str:
        """``"[m:ss, about … left]"`` for a progress line."""
        t = self.elapsed_s() if elapsed_s is None else float(elapsed_s)
        clock = f"{int(t // 60)}:{int(t % 60):02d}"
        if not math.isfinite(self.estimate_s):
            return f"[{clock}]"
        left = self.estimate_s - t
        if left < 0:
            return f"[{clock}, longer than the {duration_words(self.estimate_s).removeprefix('about ')} estimated]"
        return f"[{clock}, {duration_words(left)} left]".replace(", about", ", about")
