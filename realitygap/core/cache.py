"""A content-addressed cache of arrays on disk: work done once is not done again.

A result that depends only on its inputs (a PyBullet replay of a log: its time
base, its commands, the robot's parameters, the effects, the simulator settings)
is stored under the SHA-256 of those inputs, :func:`content_key`. Any change of an
input is a new key, so nothing is ever invalidated by hand and a stale entry is
never read: a changed wheel radius, another effect value or another version of
the package simply misses.

Entries are ``.npz`` files of plain numeric arrays, read with
``allow_pickle=False`` and written atomically (:func:`~realitygap.core.io.atomic_write`),
so a crash leaves the old entry or none, and concurrent workers writing the same
key leave one whole file. When the folder grows beyond its size limit the entries
used longest ago are removed.

Where: ``$REALITYGAP_CACHE_DIR``, else ``$XDG_CACHE_HOME/realitygap``, else
``~/.cache/realitygap``. ``REALITYGAP_CACHE=0`` turns the cache off.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.io import atomic_write_bytes

__all__ = [
    "CACHE_DIR_ENV",
    "CACHE_ENV",
    "ArrayCache",
    "content_key",
    "default_cache",
]

CACHE_DIR_ENV = "REALITYGAP_CACHE_DIR"
"""Environment variable: the cache's folder."""
CACHE_ENV = "REALITYGAP_CACHE"
"""Environment variable: ``0`` turns the cache off."""
DEFAULT_LIMIT_BYTES = 2 * 1024**3
"""Default size limit of a cache folder (2 GiB)."""


def content_key(*parts: Any) -> str:
    """SHA-256 (hex) of ``parts``: arrays by dtype, shape and bytes; everything else as
    canonical JSON (sorted keys). Equal inputs give equal keys in every process."""
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            a = np.ascontiguousarray(part)
            h.update(f"ndarray:{a.dtype.str}:{a.shape}:".encode())
            h.update(a.tobytes())
        else:
            h.update(b"json:")
            h.update(json.dumps(part, sort_keys=True, default=_jsonable).encode())
        h.update(b"|")
    return h.hexdigest()


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return {"ndarray": obj.tolist(), "dtype": obj.dtype.str}
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    raise TypeError(f"content_key: cannot hash an object of type {type(obj).__name__}")


class ArrayCache:
    """Named arrays stored under content keys in one folder.

    Parameters
    ----------
    directory : str or path
        The folder (created on the first write).
    limit_bytes : int
        Size limit of the folder; beyond it the entries used longest ago go.
    """

    def __init__(self, directory: str | os.PathLike[str], limit_bytes: int = DEFAULT_LIMIT_BYTES):
        if not (isinstance(limit_bytes, int) and limit_bytes > 0):
            raise ValueError(
                f"ArrayCache: limit_bytes must be a positive number of bytes, got {limit_bytes!r}"
            )
        self.directory = Path(directory)
        self.limit_bytes = limit_bytes

    def _path(self, namespace: str, key: str) -> Path:
        if not (namespace.isidentifier() and all(c in "0123456789abcdef" for c in key)):
            raise ValueError(
                f"ArrayCache: expected an identifier namespace and a hex key, got "
                f"{namespace!r}, {key!r}"
            )
        return self.directory / namespace / f"{key}.npz"

    def get(self, namespace: str, key: str) -> dict[str, npt.NDArray[Any]] | None:
        """The arrays stored under ``key``, or ``None`` (absent or unreadable: a miss)."""
        path = self._path(namespace, key)
        try:
            with np.load(path, allow_pickle=False) as data:
                out = {name: np.array(data[name]) for name in data.files}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError):
            return None
        try:
            os.utime(path)  # used now: the last to go when the folder is pruned
        except OSError:
            pass
        return out

    def put(self, namespace: str, key: str, arrays: Mapping[str, npt.ArrayLike]) -> None:
        """Store ``arrays`` (numeric) under ``key``, atomically; then keep the size limit.

        A cache that cannot be written (read-only folder, full disk) is skipped: the
        result was computed and is returned anyway.
        """
        payload = {}
        for name, value in arrays.items():
            a = np.asarray(value)
            if a.dtype == object:
                raise TypeError(f"ArrayCache.put: array {name!r} has dtype object; store numbers")
            payload[name] = a
        buf = io.BytesIO()
        np.savez(buf, **payload)
        try:
            atomic_write_bytes(self._path(namespace, key), buf.getvalue())
            self.prune()
        except OSError:
            return

    def prune(self) -> None:
        """Remove the entries used longest ago until the folder is within 80 % of its limit."""
        entries = []
        total = 0
        for path in self.directory.glob("*/*.npz"):
            try:
                st = path.stat()
            except OSError:
                continue
            entries.append((st.st_mtime, st.st_size, path))
            total += st.st_size
        if total <= self.limit_bytes:
            return
        for _, size, path in sorted(entries):
            if total <= 0.8 * self.limit_bytes:
                break
            try:
                path.unlink()
                total -= size
            except OSError:
                continue


def default_cache() -> ArrayCache | None:
    """The user's cache (see the module's documentation), or ``None`` when turned off."""
    if os.environ.get(CACHE_ENV, "1").strip() in ("0", "false", "no", "off"):
        return None
    given = os.environ.get(CACHE_DIR_ENV)
    if given:
        return ArrayCache(given)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return ArrayCache(os.path.join(base, "realitygap"))
