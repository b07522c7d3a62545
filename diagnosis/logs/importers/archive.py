"""Reading a saved log archive (``.npz``) safely: sizes checked before any array is allocated.

:func:`read_log_archive` opens the zip directory, reads each member's ``.npy``
header with :func:`numpy.lib.format.read_array_header_1_0` /
``read_array_header_2_0`` (never its data), refuses object arrays (pickles)
and shapes beyond :class:`~realitygap.core.checks.ResourceLimits`, and only
then loads the arrays with ``allow_pickle=False``. A compressed "zip bomb"
therefore fails on its header, before its gigabytes are inflated.
:func:`parse_log_header` checks the JSON header field by field, so a message
names the file and the field (``channels``, ``version``, ``meta`` …).
"""

from __future__ import annotations

import json
import os
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from realitygap.core.checks import ResourceLimits, check_rows_limit

__all__ = ["ArchiveError", "parse_log_header", "read_log_archive"]

MAX_HEADER_BYTES = 16 * 1024 * 1024
"""Largest ``meta.json`` member accepted (bytes)."""


class ArchiveError(ValueError):
    """The archive cannot be read; the message names the file and what is wrong."""


def _member_header(
    zf: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path
) -> tuple[tuple[int, ...], np.dtype[Any]]:
    with zf.open(info) as fh:
        try:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
            elif version in ((2, 0), (3, 0)):
                shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
            else:
                raise ValueError(f"unsupported .npy version {version}")
        except (ValueError, EOFError, SyntaxError, TypeError) as exc:
            raise ArchiveError(
                f"{path}: member {info.filename!r} is not a readable NumPy array ({exc}); "
                "the file is damaged. Fix: save the log again"
            ) from None
    return tuple(int(n) for n in shape), dtype


def archive_members(path: str | os.PathLike[str]) -> set[str]:
    """The member names of an ``.npz`` (zip) archive, or an :class:`ArchiveError` naming the
    file when it is no readable zip (damaged, truncated, another format)."""
    p = Path(path)
    try:
        with zipfile.ZipFile(p) as zf:
            return set(zf.namelist())
    except (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, EOFError, OSError) as exc:
        raise ArchiveError(
            f"{p}: not a readable .npz archive ({type(exc).__name__}: {exc}); the file is "
            "damaged, truncated or of another format. Fix: copy or save it again"
        ) from None


def read_log_archive(
    path: str | os.PathLike[str], limits: ResourceLimits | None = None
) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` archive, after checking each one's header.

    Raises
    ------
    ArchiveError
        A damaged or truncated zip, a member that is not a ``.npy`` array, an
        object (pickled) array, or an array larger than the limits (numbers and
        the way to raise them in the message).
    """
    p = Path(path)
    lim = limits if limits is not None else ResourceLimits.from_environment()
    try:
        with zipfile.ZipFile(p) as zf:
            infos = [i for i in zf.infolist() if not i.is_dir()]
            total = 0
            for info in infos:
                if not info.filename.endswith(".npy"):
                    raise ArchiveError(
                        f"{p}: member {info.filename!r} is not a .npy array; not a realitygap log"
                    )
                shape, dtype = _member_header(zf, info, p)
                if dtype.hasobject:
                    raise ArchiveError(
                        f"{p}: the archive holds pickled Python objects ({info.filename!r}), "
                        "which are never loaded (unsafe). Fix: store plain numeric arrays "
                        "(Log.save does)"
                    )
                cells = int(np.prod(shape, dtype=np.float64)) if shape else 1
                if info.filename == "meta.json.npy" and cells * dtype.itemsize > MAX_HEADER_BYTES:
                    raise ArchiveError(
                        f"{p}: the metadata member holds {cells * dtype.itemsize:,} bytes, more "
                        f"than the {MAX_HEADER_BYTES:,} a log header may have; the file is damaged"
                    )
                total += cells
                try:
                    rows = shape[0] if shape else 1
                    check_rows_limit(
                        rows, max(cells // max(rows, 1), 1), f"{p} ({info.filename})", lim
                    )
                    check_rows_limit(total, 1, f"{p} (all arrays together)", lim)
                except ValueError as exc:
                    raise ArchiveError(str(exc)) from None
            out: dict[str, np.ndarray] = {}
            for info in infos:
                with zf.open(info) as fh:
                    out[info.filename[:-4]] = np.lib.format.read_array(fh, allow_pickle=False)
            return out
    except ArchiveError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, EOFError, OSError) as exc:
        raise ArchiveError(
            f"{p}: unreadable or truncated log archive ({type(exc).__name__}: {exc}). Fix: copy "
            "the file again or save the log again"
        ) from None
    except (ValueError, NotImplementedError, RuntimeError) as exc:
        raise ArchiveError(f"{p}: unreadable log archive ({exc})") from None


def parse_log_header(raw: np.ndarray, path: Path, format_name: str, version: int) -> dict[str, Any]:
    """The JSON header of a log archive, checked field by field.

    Returns ``{"channels": {name: spec dict}, "meta": dict, "source": str}``.

    Raises
    ------
    ArchiveError
        Naming the file and the field that is wrong, what it should be, and what it is.
    """
    try:
        data = bytes(np.asarray(raw, dtype=np.uint8).reshape(-1))
        header = json.loads(data.decode("utf-8"))
    except (ValueError, TypeError, UnicodeDecodeError) as exc:
        raise ArchiveError(f"{path}: the metadata ('meta.json') is not JSON ({exc})") from None
    if not isinstance(header, dict) or header.get("format") != format_name:
        raise ArchiveError(f"{path}: metadata does not describe a {format_name!r} file")
    got = header.get("version", 0)
    if isinstance(got, bool) or not isinstance(got, int):
        raise ArchiveError(
            f"{path}: metadata field 'version' must be a whole number, got {got!r}; the file is "
            "damaged"
        )
    if got > version:
        raise ArchiveError(
            f"{path}: log format version {got} is newer than this reader ({version}). "
            "Fix: update realitygap"
        )
    channels = header.get("channels", {})
    if not isinstance(channels, Mapping):
        raise ArchiveError(
            f"{path}: metadata field 'channels' must be an object {{name: spec}}, got "
            f"{type(channels).__name__}; the file is damaged"
        )
    for name, spec in channels.items():
        where = f"{path}: metadata of channel {name!r}"
        if not isinstance(spec, Mapping):
            raise ArchiveError(f"{where} must be an object, got {type(spec).__name__}")
        for key in ("columns", "units"):
            if key not in spec:
                raise ArchiveError(f"{where} has no {key!r} list; the file is damaged")
            value = spec[key]
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise ArchiveError(f"{where}: {key!r} must be a list of strings, got {value!r:.80}")
        angles = spec.get("angle_columns", [])
        if not isinstance(angles, list) or not all(
            isinstance(i, int) and 0 <= i < len(spec["columns"]) for i in angles
        ):
            raise ArchiveError(
                f"{where}: 'angle_columns' must list column indices, got {angles!r:.80}"
            )
        role = spec.get("role", "other")
        roles = ("command", "sensor", "truth", "estimate", "other")
        if role not in roles:
            raise ArchiveError(
                f"{where}: role {role!r} is not one of {', '.join(roles)}; the file is damaged"
            )
        if not isinstance(spec.get("description", ""), str):
            raise ArchiveError(f"{where}: 'description' must be a string")
    meta = header.get("meta", {})
    if not isinstance(meta, dict):
        raise ArchiveError(
            f"{path}: metadata field 'meta' must be an object, got {type(meta).__name__} "
            f"{meta!r:.60}; the file is damaged"
        )
    source = header.get("source", "")
    return {"channels": dict(channels), "meta": meta, "source": str(source) if source else ""}
