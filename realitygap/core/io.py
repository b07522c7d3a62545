"""Writing files so that a failure never leaves a partial one.

Every file the package writes (logs, reports, models, tables, meshes) goes through
:func:`atomic_write`: the bytes go to a temporary file in the same folder, are
flushed to disk, and the temporary file is renamed over the target with
:func:`os.replace`. An exception, Ctrl-C or a killed process leaves the old file
(or no file) in place, never half a file.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "jsonable", "write_json"]


def atomic_write(path: str | os.PathLike[str], writer: Callable[[IO[bytes]], object]) -> Path:
    """Write a file through ``writer(fh)`` into a temporary file, then rename it into place.

    On any error the temporary file is removed and an existing ``path`` is
    left untouched. The parent folder is created if missing. The file gets the
    permissions of a newly created file (``0o666`` minus the umask), not the
    private ones of the temporary file. Returns ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            writer(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _umask() -> int:
    """The process's file-creation mask.

    Read from ``/proc/self/status`` where the kernel reports it, so that no other
    thread ever creates a file under a cleared mask; elsewhere by setting and
    restoring it.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """:func:`atomic_write` of a bytes object."""

    def write(fh: IO[bytes]) -> None:
        fh.write(data)

    return atomic_write(path, write)


def atomic_write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> Path:
    """:func:`atomic_write` of a string, encoded with ``encoding``."""
    return atomic_write_bytes(path, text.encode(encoding))


def jsonable(value: Any) -> Any:
    """``value`` with arrays as lists, non-finite floats as ``None``/``"inf"``/``"-inf"``,
    paths as strings: what :func:`json.dumps` can write."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "tolist") and callable(value.tolist):  # numpy arrays and scalars
        return jsonable(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: str | os.PathLike[str], payload: Any) -> Path:
    """Write ``payload`` (made :func:`jsonable`) as indented JSON to ``path``, atomically.

    A mapping gets a first key ``"written_by": "realitygap VERSION"``: the mark by which a
    later run knows the file as its own output and may replace it
    (:mod:`realitygap.core.outputs`). Returns ``path``.
    """
    from realitygap import __version__

    data = jsonable(payload)
    if isinstance(data, dict):
        data = {"written_by": f"realitygap {__version__}", **data}
    return atomic_write_text(path, json.dumps(data, indent=2) + "\n")
