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
import errno
import json
import math
import numbers
import os
import shlex
import stat
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "LIMITS",
    "ResourceLimits",
    "UnknownNameError",
    "check_choice",
    "check_disjoint",
    "check_distinct",
    "check_finite_float",
    "check_input_path",
    "check_int",
    "check_nonnegative_int",
    "check_output_path",
    "check_positive_int",
    "check_regular_file",
    "check_rows_limit",
    "int_option",
    "load_json_or_yaml",
    "parse_json_option",
    "path_option",
    "set_path_types",
    "text_encoding_of",
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


def check_regular_file(
    path: str | os.PathLike[str],
    name: str,
    *,
    needs: str = "",
    unicode: str = "refuse",
) -> Path:
    """``path`` if it is an existing, readable, non-empty regular file.

    :func:`check_input_path` with ``kind="file"``: a folder, FIFO, socket or device
    is refused (a FIFO would block the reader forever and a device could stream
    without end, so neither is opened), and so are a symbolic-link loop, an
    unreadable file, an empty one and UTF-16/32 text (unless ``unicode="accept"``).

    Raises
    ------
    FileNotFoundError
        Nothing at ``path`` (or a link to nothing).
    ValueError
        Something else that cannot be read as a file; the message names ``name``, the
        path, what it is and the fix.
    """
    return check_input_path(path, name, kind="file", needs=needs, unicode=unicode)


_BOMS: tuple[tuple[bytes, str, str], ...] = (
    (b"\xff\xfe\x00\x00", "utf-32", "UTF-32 LE"),  # before UTF-16 LE, whose BOM it starts with
    (b"\x00\x00\xfe\xff", "utf-32", "UTF-32 BE"),
    (b"\xff\xfe", "utf-16", "UTF-16 LE"),
    (b"\xfe\xff", "utf-16", "UTF-16 BE"),
)


def text_encoding_of(head: bytes) -> tuple[str, str] | None:
    """``(codec, label)`` of text that starts with a UTF-16 or UTF-32 byte-order mark
    (``("utf-16", "UTF-16 LE")``), else None. The codec reads the mark and drops it.

    Such text holds NUL bytes, so a sniffer that only knows UTF-8 takes it for binary.
    """
    for bom, codec, label in _BOMS:
        if head.startswith(bom):
            return codec, label
    return None


def _link_chain(p: Path, steps: int = 6) -> str:
    """``a → b → a`` for a symbolic link (up to ``steps`` links)."""
    chain = [str(p)]
    seen = {os.path.abspath(p)}
    cur = p
    for _ in range(steps):
        try:
            target = os.readlink(cur)
        except OSError:
            break
        cur = cur.parent / target
        chain.append(target)
        if os.path.abspath(cur) in seen:
            return " → ".join(chain)
        seen.add(os.path.abspath(cur))
    return " → ".join(chain) + " → …"


DEFAULT_NEEDS = "a log needs rows of data (a header line and rows of numbers)"
"""What an empty input lacks, said by :func:`check_input_path` unless the caller says more."""


def check_input_path(
    path: str | os.PathLike[str],
    name: str,
    *,
    kind: str = "file or folder",
    needs: str = "",
    expected: str = "",
    unicode: str = "refuse",
) -> Path:
    """Check an input path before it is read: it exists, is no symbolic-link loop, is
    a regular file or a folder as ``kind`` asks, is readable, and (a file) is not empty.

    Parameters
    ----------
    path : path-like
    name : str
        The argument or option the path came from (``"LOG"``, ``"--robot-file"``), named
        in every message.
    kind : {"file or folder", "file", "folder"}
        What may be there.
    needs : str
        What an empty file lacks (default :data:`DEFAULT_NEEDS`).
    expected : str
        What is expected there, for the message when the kind is wrong (e.g. the layout
        of a folder of runs).
    unicode : {"refuse", "accept"}
        A file of UTF-16/32 text (:func:`text_encoding_of`) is refused with the command
        that converts it to UTF-8, unless the caller decodes it (``"accept"``).

    Raises
    ------
    FileNotFoundError
        Nothing at ``path``, or a symbolic link to nothing.
    ValueError
        A link loop, the wrong kind, no permission, an empty file, UTF-16/32 text: the
        message names ``name``, the path, what was expected, what is there and the fix.
    """
    if kind not in ("file or folder", "file", "folder"):
        raise ValueError(f"kind must be 'file or folder', 'file' or 'folder', got {kind!r}")
    if unicode not in ("refuse", "accept"):
        raise ValueError(f"unicode must be 'refuse' or 'accept', got {unicode!r}")
    p = Path(path)
    q = shlex.quote(str(p))
    want = expected or f"a {kind}"
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        if os.path.islink(p):
            raise FileNotFoundError(
                f"{name}: {p} is a symbolic link to {os.readlink(p)}, which does not exist. "
                f"Fix: point the link at the real {kind} (ln -sfn TARGET {q}) or pass it itself"
            ) from None
        where = "" if p.is_absolute() else f" (relative to the current folder {Path.cwd()})"
        raise FileNotFoundError(f"{name}: no such {kind}: {p}{where}") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ValueError(
                f"{name}: {p} is a symbolic link loop ({_link_chain(p)}): it never reaches a "
                f"{kind}. Fix: point the link at the real {kind} (ln -sfn TARGET {q}), or "
                f"pass the {kind} itself"
            ) from None
        if exc.errno in (errno.EACCES, errno.EPERM):
            raise ValueError(
                f"{name}: {p} cannot be reached (permission denied on a folder above it). "
                "Fix: give yourself read and search permission on its folders, or copy it"
            ) from None
        raise ValueError(f"{name}: cannot read {p} ({exc.strerror or exc})") from None
    if stat.S_ISDIR(mode):
        if kind == "file":
            raise ValueError(f"{name}: {p} is a folder, but {want} is expected. Fix: pass a file")
        if not os.access(p, os.R_OK | os.X_OK):
            raise ValueError(
                f"{name}: the folder {p} is not readable (permission denied). Fix: chmod u+rx {q}"
            )
        return p
    if not stat.S_ISREG(mode):
        raise ValueError(
            f"{name}: {p} is {_kind_of_mode(mode)}, not a regular {kind}. Fix: pass a "
            f"{kind} (copy a stream to a file first)"
        )
    if kind == "folder":
        raise ValueError(f"{name}: {p} is a file, but {want} is expected. Fix: pass the folder")
    try:
        with open(p, "rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        raise ValueError(
            f"{name}: {p} is not readable ({exc.strerror or exc}). Fix: chmod u+r {q}, or "
            "read a copy you own"
        ) from None
    if not head:
        why = (
            "pass the file the recording was written to (an empty file is often a recording "
            "stopped before it was flushed, or a failed copy)"
            if not needs or needs == DEFAULT_NEEDS
            else "write its content, or pass the file that has it (an empty file is often a "
            "failed copy or a file created but never saved)"
        )
        raise ValueError(f"{name}: {p} is empty (0 bytes); {needs or DEFAULT_NEEDS}. Fix: {why}")
    bom = text_encoding_of(head)
    if bom is not None and unicode == "refuse":
        out = shlex.quote(str(p.with_name(f"{p.stem}-utf8{p.suffix}")))
        raise ValueError(
            f"{name}: {p} is {bom[1]} text (it starts with the byte-order mark "
            f"{head[: 4 if bom[0] == 'utf-32' else 2].hex(' ')}), not UTF-8. Fix: save it as "
            f"UTF-8, e.g. iconv -f {bom[1].split()[0]} -t UTF-8 {q} > {out}, and pass {out}"
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
    try:
        ra, rb = a.resolve(), b.resolve()
    except (OSError, RuntimeError):  # a symbolic-link loop: compare the paths as written
        ra, rb = Path(os.path.abspath(a)), Path(os.path.abspath(b))
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

    def resolved(x: str | os.PathLike[str]) -> tuple[Path, Path]:
        p = Path(x)
        try:
            return p.resolve(), p
        except (OSError, RuntimeError):
            return p.absolute(), p

    tr = dict(resolved(x) for x in train)
    holding = {q: p for r, p in tr.items() for q in r.parents}  # folders holding a train path
    pairs = []
    for r, b in (resolved(x) for x in holdout):  # linear: dict lookups along the parents
        a = tr.get(r) or next((tr[q] for q in r.parents if q in tr), None) or holding.get(r)
        if a is not None:
            pairs.append((a, b))
    if pairs:
        listed = "; ".join(f"{a} and {b}" for a, b in pairs[:5])
        raise ValueError(
            f"the same data is given as {names[0]} and as {names[1]} ({listed}); a held-out "
            f"score needs logs not used for fitting. Fix: remove them from one of the two sets"
        )


class UnknownNameError(KeyError, ValueError):
    """A name that a registry (effects, experiments, environments, samples) does not hold:
    a ``KeyError`` for a lookup and a ``ValueError`` for the argument that named it, so that
    either ``except`` catches it. Its text is the message, not its quoted repr."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


PATH_OPTIONS = frozenset(
    {
        "json",
        "report",
        "out",
        "data",
        "robot_file",
        "urdf",
        "hyperparams",
        "init_model",
        "logs",
        "holdout",
        "paths",
        "sessions",
    }
)
"""Destinations of the command line's path arguments (:func:`set_path_types`)."""


def path_option(text: str) -> str:
    """The ``argparse`` type of a path argument: not empty, ``~`` expanded (a quoted
    ``'~/x'`` reaches the program unexpanded and would otherwise make a folder named ``~``).
    ``-`` is kept: standard output where an option allows it."""
    import argparse

    if not text.strip():
        raise argparse.ArgumentTypeError("expected a path, got an empty string")
    return os.path.expanduser(text) if text.startswith("~") else text


def set_path_types(parser: Any) -> None:
    """Give every path argument of ``parser`` (:data:`PATH_OPTIONS`, by destination) the
    type :func:`path_option`, where it has no type of its own."""
    for action in parser._actions:
        if action.dest in PATH_OPTIONS and action.type is None:
            action.type = path_option


def check_distinct(paths: Iterable[str | os.PathLike[str]], name: str) -> None:
    """Refuse a path given twice in one list of inputs (or one inside another): its data
    would count twice (a run pooled twice weighs double; a log trained on twice is not
    more evidence).

    Raises
    ------
    ValueError
        Naming ``name`` and every repeated pair.
    """
    index: dict[Path, Path] = {}
    pairs: list[tuple[Path, Path]] = []
    for p in (Path(x) for x in paths):  # linear: one resolve per path, a dict lookup
        try:
            r = p.resolve()
        except (OSError, RuntimeError):  # a link loop: said by the input check
            r = p.absolute()
        if r in index:
            pairs.append((index[r], p))
        else:
            index[r] = p
    for r, p in index.items():  # one inside another given folder
        outer = next((index[a] for a in r.parents if a in index), None)
        if outer is not None:
            pairs.append((outer, p))
    if pairs:
        listed = "; ".join(f"{a} and {b}" for a, b in pairs[:5])
        more = f" (and {len(pairs) - 5} more)" if len(pairs) > 5 else ""
        raise ValueError(
            f"{name}: the same data is given twice ({listed}{more}); it would count twice. "
            "Fix: give each input once"
        )


def parse_json_option(text: str, name: str, *, expect: type | tuple[type, ...] = object) -> Any:
    """Parse ``text`` as JSON; on a syntax error name the option and point at the place.

    :func:`load_json_or_yaml` of an option's text (never a file).

    Raises
    ------
    ValueError
        ``"--params: invalid JSON at line 1 column 2: Expecting property name …"``
        followed by the text and a caret under the column; or a top-level value not of
        type ``expect``.
    """
    return load_json_or_yaml(text, name, expect=expect, files=False)


_TYPE_WORDS = {
    dict: "{fmt} object ({{...}})",
    list: "{fmt} list ([...])",
    str: "a string",
    float: "a number",
    int: "an integer",
    bool: "true or false",
    type(None): "null",
}


def _type_word(value: object) -> str:
    if isinstance(value, Mapping):
        return "an object (mapping)"
    if isinstance(value, list):
        return f"a list of {len(value)} item(s)"
    if value is None:
        return "nothing (null, or an empty document)"
    return f"{type(value).__name__} {value!r:.40}"


def _syntax_error(
    where: str, fmt: str, text: str, line: int, col: int, msg: str, fix: str, in_file: bool
) -> str:
    lines = text.splitlines()
    shown = lines[line - 1] if 0 < line <= len(lines) else ""
    caret = f"\n  {shown[:200]}\n  {' ' * min(max(col - 1, 0), 200)}^" if shown.strip() else ""
    if not caret and line >= len(lines):
        caret = " (at the end of the text: something is left open)"
    what = f"not valid {fmt}, syntax error" if in_file else f"invalid {fmt}"
    return f"{where}: {what} at line {line} column {col}: {msg}{caret}\nFix: {fix}"


MAX_DATA_FILE_BYTES = 16 * 2**20
"""Largest JSON/YAML file :func:`load_json_or_yaml` reads (16 MiB)."""


def load_json_or_yaml(
    source: str | os.PathLike[str],
    name: str,
    *,
    expect: type | tuple[type, ...] = dict,
    example: str = "",
    files: bool = True,
    max_bytes: int = MAX_DATA_FILE_BYTES,
) -> Any:
    """Load JSON or YAML from a file or from an option's text, and check its top-level type.

    The one reader of configuration a user writes (a column map, ``--params``, a robot
    file): every error names the option and the file, a syntax error its line and
    column with the line and a caret under the place.

    Parameters
    ----------
    source : str or path-like
        A path (a :class:`os.PathLike`, or text naming a file: anything ending in
        ``.json``, ``.yaml`` or ``.yml``, or an existing file) or the JSON text itself.
        A ``.json`` file is read as JSON, any other file as YAML (of which JSON is a
        subset); text is read as JSON.
    name : str
        The option or argument (``"--params"``, ``"robot file"``), named in messages.
    expect : type or tuple of types
        The top-level type (``dict`` for an object / mapping; ``object`` for any).
    example : str
        An example of the expected content, shown when the type is wrong.
    files : bool
        Whether ``source`` may name a file (``False``: it is always text).
    max_bytes : int
        Largest file read.

    Raises
    ------
    FileNotFoundError
        ``source`` names a file (by its extension) that does not exist.
    ValueError
        Unreadable file (see :func:`check_input_path`), too large, not UTF-8, a syntax
        error, or a top-level value not of type ``expect``.
    """
    is_path = isinstance(source, os.PathLike)
    text = os.fspath(source) if is_path else str(source)
    if files and not is_path:
        stripped = text.strip()
        is_path = not stripped.startswith(("{", "[")) and (
            stripped.lower().endswith((".json", ".yaml", ".yml")) or os.path.lexists(stripped)
        )
        text = stripped if is_path else text
    if is_path:
        p = check_input_path(
            text, name, kind="file", needs=f"{name} needs content", unicode="accept"
        )
        size = p.stat().st_size
        if size > max_bytes:
            raise ValueError(
                f"{name}: {p} has {size:,} bytes, more than the {max_bytes:,} a configuration "
                "file may have. Fix: pass the right file"
            )
        raw = p.read_bytes()
        bom = text_encoding_of(raw[:4])
        try:
            body = raw.decode(bom[0] if bom else "utf-8-sig")
        except UnicodeDecodeError as exc:
            line = raw[: exc.start].count(b"\n") + 1
            raise ValueError(
                f"{name}: {p} is not UTF-8 text (byte {raw[exc.start]:#04x} on line {line}). "
                "Fix: save it as UTF-8"
            ) from None
        where = f"{name} {p}"
        fmt = "JSON" if p.suffix.lower() == ".json" else "YAML"
    else:
        body, where, fmt = text, name, "JSON"
    if fmt == "JSON":
        try:
            value = json.loads(body, object_pairs_hook=_refuse_twice(where))
        except json.JSONDecodeError as exc:
            fix = (
                "quote keys and strings with double quotes, separate items with commas and "
                "close every brace"
                + ("" if is_path else ", e.g. '{\"wheelbase\": 0.23}', or use 'k=v,k=v'")
            )
            raise ValueError(
                _syntax_error(where, fmt, body, exc.lineno, exc.colno, exc.msg, fix, is_path)
            ) from None
        except RecursionError:
            raise ValueError(f"{where}: JSON nested too deeply to read") from None
    else:
        import yaml

        try:
            value = yaml.load(body, Loader=_unique_key_loader(where))
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
            fix = "indent nested keys by spaces (no tabs) and write 'key: value' pairs"
            if mark is None:
                raise ValueError(f"{where}: not valid YAML: {problem}. Fix: {fix}") from None
            raise ValueError(
                _syntax_error(
                    where, fmt, body, mark.line + 1, mark.column + 1, problem, fix, is_path
                )
            ) from None
        except RecursionError:
            raise ValueError(f"{where}: YAML nested too deeply to read") from None
    if expect is not object and not isinstance(value, expect):
        kinds = expect if isinstance(expect, tuple) else (expect,)
        art = "a JSON" if fmt == "JSON" else "a YAML"
        wanted = " or ".join(
            _TYPE_WORDS[k].format(fmt=art) if k in (dict, list) else _TYPE_WORDS.get(k, k.__name__)
            for k in kinds
        )
        if dict in kinds and fmt == "YAML":
            wanted = wanted.replace("YAML object ({...})", "YAML mapping (key: value lines)")
        eg = f", e.g. {example}" if example else ""
        raise ValueError(
            f"{where}: expected {wanted} at the top level{eg}, got {_type_word(value)}. Fix: "
            f"write the entries as {wanted.split(' (')[0]}"
        )
    return value


def _refuse_twice(where: str) -> Any:
    """A :func:`json.loads` object hook that refuses a key given twice (JSON keeps the last
    silently: a typo'd copy of an entry would win without a word)."""

    def hook(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key, value in pairs:
            if key in out:
                raise ValueError(
                    f"{where}: the key {key!r} is given twice ({out[key]!r} and {value!r}); "
                    "only one can hold. Fix: keep the one you mean"
                )
            out[key] = value
        return out

    return hook


def _unique_key_loader(where: str) -> Any:
    """A YAML ``SafeLoader`` (plain data only) that refuses a key given twice in a mapping."""
    import yaml

    class UniqueKeyLoader(yaml.SafeLoader):
        def construct_mapping(self, node: Any, deep: bool = False) -> Any:
            seen: set[Any] = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=deep)
                if key in seen:
                    raise ValueError(
                        f"{where}: the key {key!r} is given twice (line "
                        f"{key_node.start_mark.line + 1}); only one can hold. Fix: keep the one "
                        "you mean"
                    )
                seen.add(key)
            return super().construct_mapping(node, deep=deep)

    return UniqueKeyLoader


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
    max_cell_chars : int
        Longest cell of a text table (default 128 KiB characters, the limit of
        Python's CSV reader); ``REALITYGAP_MAX_CELL_KB``.
    """

    max_cells: int = 50_000_000
    max_file_bytes: int = 512 * 1024 * 1024
    max_gap_steps: float = 5.0
    max_cell_chars: int = 128 * 1024

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] | None = None) -> ResourceLimits:
        """The defaults, changed by ``REALITYGAP_MAX_CELLS``, ``REALITYGAP_MAX_FILE_MB``,
        ``REALITYGAP_MAX_GAP_STEPS`` and ``REALITYGAP_MAX_CELL_KB``."""
        base = cls()
        return cls(
            max_cells=int(_env_number("REALITYGAP_MAX_CELLS", base.max_cells)),
            max_file_bytes=int(
                _env_number("REALITYGAP_MAX_FILE_MB", base.max_file_bytes / 2**20) * 2**20
            ),
            max_gap_steps=_env_number("REALITYGAP_MAX_GAP_STEPS", base.max_gap_steps),
            max_cell_chars=int(
                _env_number("REALITYGAP_MAX_CELL_KB", base.max_cell_chars / 1024) * 1024
            ),
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
