"""Validation of values at the package's public boundaries.

One ``check_*`` function per kind of value (as :mod:`pytransform3d` does with
``check_matrix``): each converts its input, and on a bad one raises
:class:`TypeError` (wrong kind) or :class:`ValueError` (right kind, wrong
value) with a message that names the argument or file, what was expected, what
came, and the fix. Entry points (env constructors, the command line, the log
importers, the experiments) call these rather than testing values themselves.

Resource limits (:class:`ResourceLimits`) bound what an input may make the
package allocate; each has a stated default and an environment variable that
raises it.
"""

from __future__ import annotations

import argparse
import json
import math
import numbers
import os
import stat
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "LIMITS",
    "ResourceLimits",
    "check_choice",
    "check_disjoint",
    "check_finite_float",
    "check_int",
    "check_nonnegative_int",
    "check_output_path",
    "check_positive_int",
    "check_regular_file",
    "check_rows_limit",
    "int_option",
    "parse_json_option",
]


def _describe(value: object) -> str:
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def check_int(
    value: Any,
    name: str,
    *,
    low: int | None = None,
    high: int | None = None,
    fix: str = "",
    what: str = "an integer",
) -> int:
    """``value`` as an ``int`` in ``[low, high]``; ``what`` names the kind in messages.

    Accepts Python and NumPy integers and floats that hold a whole number
    (``3.0``); refuses ``bool``, strings, NaN, fractions (``2.5``) and values
    out of range.

    Raises
    ------
    TypeError
        Not a number.
    ValueError
        NaN/inf, a fraction, or outside ``[low, high]``.
    """
    tail = f". Fix: {fix}" if fix else ""
    rng = "" if what != "an integer" and high is None else _range_text(low, high)
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be {what}{rng}, got {_describe(value)}{tail}")
    if isinstance(value, numbers.Integral):
        out = int(value)
    else:
        f = float(value)
        if not math.isfinite(f) or f != math.floor(f):
            raise ValueError(f"{name} must be {what}{rng}, got {value!r}{tail}")
        out = int(f)
    if (low is not None and out < low) or (high is not None and out > high):
        raise ValueError(f"{name} must be {what}{rng}, got {value!r}{tail}")
    return out


def check_positive_int(value: Any, name: str, *, high: int | None = None, fix: str = "") -> int:
    """:func:`check_int` with ``low=1``."""
    return check_int(value, name, low=1, high=high, fix=fix, what="a positive integer")


def check_nonnegative_int(value: Any, name: str, *, high: int | None = None, fix: str = "") -> int:
    """:func:`check_int` with ``low=0``."""
    return check_int(value, name, low=0, high=high, fix=fix, what="a non-negative integer")


def _range_text(low: float | None, high: float | None, *, strict_low: bool = False) -> str:
    if low is None and high is None:
        return ""
    if high is None:
        return f" {'>' if strict_low else '≥'} {low:g}"
    if low is None:
        return f" ≤ {high:g}"
    return f" in {'(' if strict_low else '['}{low:g}, {high:g}]"


def check_finite_float(
    value: Any,
    name: str,
    *,
    low: float | None = None,
    high: float | None = None,
    strict_low: bool = False,
    unit: str = "",
    fix: str = "",
) -> float:
    """``value`` as a finite ``float`` in ``[low, high]`` (``(low, high]`` with ``strict_low``).

    Raises
    ------
    TypeError
        Not a real number (a string, ``None``, ``bool``, an array).
    ValueError
        NaN/inf or out of range.
    """
    tail = f". Fix: {fix}" if fix else ""
    u = f" {unit}" if unit else ""
    rng = _range_text(low, high, strict_low=strict_low) + u
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a finite number{rng}, got {_describe(value)}{tail}")
    f = float(value)
    bad = not math.isfinite(f)
    if low is not None:
        bad = bad or (f <= low if strict_low else f < low)
    if high is not None:
        bad = bad or f > high
    if bad:
        raise ValueError(f"{name} must be a finite number{rng}, got {value!r}{tail}")
    return f


def int_option(low: int = 0, high: int | None = None) -> Callable[[str], int]:
    """An ``argparse`` ``type=`` converter for integers in ``[low, high]``.

    ``argparse`` prefixes its message with the option (``argument --seed: expected
    a non-negative integer, got -5``).
    """

    def convert(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        what = {0: "a non-negative integer", 1: "a positive integer"}.get(low, "an integer")
        if value is None or value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(
                f"expected {what}{_range_text(low, high) if low not in (0, 1) or high else ''}, "
                f"got {text!r}"
            )
        return value

    convert.__name__ = "integer"
    return convert


def check_choice(value: Any, name: str, choices: Iterable[Any]) -> Any:
    """``value`` if it is one of ``choices``, else ``ValueError`` listing them."""
    options = list(choices)
    if value not in options:
        raise ValueError(
            f"{name} must be one of {', '.join(repr(c) for c in options)}, got {_describe(value)}"
        )
    return value


def check_regular_file(path: str | os.PathLike[str], name: str) -> Path:
    """``path`` if it is an existing regular file (not a folder, FIFO, socket or device).

    A FIFO would block the reader forever and a device could stream without end,
    so neither is opened.

    Raises
    ------
    FileNotFoundError
        Nothing at ``path``.
    ValueError
        Something that is not a regular file.
    """
    p = Path(path)
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        raise FileNotFoundError(f"{name}: no such file: {p}") from None
    except OSError as exc:
        raise ValueError(f"{name}: cannot read {p} ({exc.strerror})") from None
    if not stat.S_ISREG(mode):
        raise ValueError(
            f"{name}: {p} is {_kind_of_mode(mode)}, not a regular file. Fix: pass a file "
            "(copy a stream to a file first)"
        )
    return p


def _kind_of_mode(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "not a regular file"


def _same_or_inside(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists() and os.path.samefile(a, b):
            return True
    except OSError:
        pass
    ra, rb = a.resolve(), b.resolve()
    return ra == rb or rb in ra.parents


def check_output_path(
    path: str | os.PathLike[str],
    name: str,
    *,
    inputs: Iterable[str | os.PathLike[str]] = (),
    folder: bool = False,
) -> Path:
    """Check, before any work starts, that ``path`` can be written and is no input.

    ``folder=False`` expects a file path (an existing folder there is refused);
    ``folder=True`` a folder (an existing file there is refused). The nearest
    existing ancestor must be a writable folder (the missing ones are created
    when writing). A path equal to an input, or (for a file) inside an input
    folder, is refused so that an input is never overwritten.

    Raises
    ------
    ValueError
        With the argument ``name``, the path, what is wrong and the fix.
    """
    p = Path(path)
    for inp in inputs:
        q = Path(inp)
        if _same_or_inside(p, q) and (p.resolve() == q.resolve() or q.is_dir()):
            what = "is" if p.resolve() == q.resolve() else "lies inside"
            raise ValueError(
                f"{name} {p} {what} the input {q}; writing it would overwrite an input. "
                f"Fix: choose another {name} path"
            )
    if p.exists():
        if folder and not p.is_dir():
            raise ValueError(
                f"{name} {p} is an existing file, but a folder is expected. Fix: give a folder path"
            )
        if not folder and p.is_dir():
            raise ValueError(
                f"{name} {p} is an existing folder, but a file path is expected. "
                f"Fix: give a file name, e.g. {p / 'out.json'}"
            )
        if not folder and not stat.S_ISREG(os.stat(p).st_mode):
            raise ValueError(f"{name} {p} is {_kind_of_mode(os.stat(p).st_mode)}; give a file path")
    parent = p if folder and p.exists() else p.parent
    ancestor = parent
    while not ancestor.exists():
        if ancestor.parent == ancestor:
            break
        ancestor = ancestor.parent
    if ancestor.exists() and not ancestor.is_dir():
        raise ValueError(
            f"{name} {p}: {ancestor} is a file, so no folder can be made under it. "
            f"Fix: choose another {name} path"
        )
    if _read_only_fs(ancestor) or not os.access(ancestor, os.W_OK | os.X_OK):
        raise ValueError(
            f"{name} {p}: the folder {ancestor} is not writable (read-only file system or no "
            f"permission). Fix: choose a writable {name} path"
        )
    return p


def _read_only_fs(path: Path) -> bool:
    """Whether ``path`` lies on a file system mounted read-only (``False`` where unknown)."""
    try:
        return bool(os.statvfs(path).f_flag & getattr(os, "ST_RDONLY", 1))
    except (OSError, AttributeError):
        return False


def check_disjoint(
    train: Iterable[str | os.PathLike[str]],
    holdout: Iterable[str | os.PathLike[str]],
    *,
    names: tuple[str, str] = ("training LOG", "--holdout"),
) -> None:
    """Refuse paths given both as training and held-out inputs (or one inside the other).

    A held-out score on training data would look like generalisation without being it.

    Raises
    ------
    ValueError
        Naming every overlapping pair.
    """
    tr = [Path(p) for p in train]
    ho = [Path(p) for p in holdout]
    pairs = [(a, b) for a in tr for b in ho if _same_or_inside(a, b) or _same_or_inside(b, a)]
    if pairs:
        listed = "; ".join(f"{a} and {b}" for a, b in pairs)
        raise ValueError(
            f"the same data is given as {names[0]} and as {names[1]} ({listed}); a held-out "
            f"score needs logs not used for fitting. Fix: remove them from one of the two sets"
        )


def parse_json_option(text: str, name: str) -> Any:
    """Parse ``text`` as JSON; on a syntax error name the option and point at the place.

    Raises
    ------
    ValueError
        ``"--params: invalid JSON at line 1 column 2: Expecting property name …"``
        followed by the text and a caret under the column.
    """
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        line = text.splitlines()[exc.lineno - 1] if text.splitlines() else ""
        raise ValueError(
            f"{name}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}\n"
            f"  {line}\n  {' ' * (exc.colno - 1)}^\n"
            "Fix: quote keys and close braces, e.g. '{\"wheelbase\": 0.23}', or use 'k=v,k=v'"
        ) from None


def _env_number(var: str, default: float) -> float:
    raw = os.environ.get(var)
    if raw is None or not raw.strip():
        return default
    try:
        value = float(raw)
    except ValueError:
        raise ValueError(f"environment variable {var} must be a number, got {raw!r}") from None
    if not (value > 0 and math.isfinite(value)):
        raise ValueError(f"environment variable {var} must be a positive number, got {raw!r}")
    return value


@dataclass(frozen=True)
class ResourceLimits:
    """Upper bounds on what one input may make the package allocate.

    Attributes
    ----------
    max_cells : int
        Rows × channels of one log (default 50 million float64 cells, 400 MB);
        raise with ``REALITYGAP_MAX_CELLS``.
    max_file_bytes : int
        Size of one text log file (default 512 MB); ``REALITYGAP_MAX_FILE_MB``.
    max_gap_steps : float
        Longest time gap, in resampling steps, that resampling may bridge
        (default 5); a longer one splits the run. ``REALITYGAP_MAX_GAP_STEPS``.
    """

    max_cells: int = 50_000_000
    max_file_bytes: int = 512 * 1024 * 1024
    max_gap_steps: float = 5.0

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] | None = None) -> ResourceLimits:
        """The defaults, changed by ``REALITYGAP_MAX_CELLS``, ``REALITYGAP_MAX_FILE_MB`` and
        ``REALITYGAP_MAX_GAP_STEPS``."""
        base = cls()
        return cls(
            max_cells=int(_env_number("REALITYGAP_MAX_CELLS", base.max_cells)),
            max_file_bytes=int(
                _env_number("REALITYGAP_MAX_FILE_MB", base.max_file_bytes / 2**20) * 2**20
            ),
            max_gap_steps=_env_number("REALITYGAP_MAX_GAP_STEPS", base.max_gap_steps),
        )


LIMITS = ResourceLimits()
"""The default limits (see :meth:`ResourceLimits.from_environment` for raised ones)."""


def check_rows_limit(
    rows: int, columns: int, name: str, limits: ResourceLimits | None = None
) -> None:
    """Refuse an allocation of ``rows × columns`` float cells above ``limits.max_cells``.

    Raises
    ------
    ValueError
        With the numbers, the limit and how to raise it.
    """
    lim = limits if limits is not None else ResourceLimits.from_environment()
    cells = int(rows) * max(int(columns), 1)
    if cells > lim.max_cells:
        raise ValueError(
            f"{name}: {rows} rows × {columns} columns = {cells:,} values exceed the limit of "
            f"{lim.max_cells:,} ({lim.max_cells * 8 / 2**20:.0f} MB as float64). Fix: split or "
            "shorten the log, use a coarser step, or raise the limit with the environment "
            "variable REALITYGAP_MAX_CELLS"
        )
