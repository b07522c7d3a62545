"""Small real data sets shipped with the package, so that the main job runs anywhere.

``optiodom_diffdrive.tar.xz`` holds three sessions of the OptiOdom data set (Sousa
et al., J. Intell. Robot. Syst. 105:39, 2022; MIT licence in
``LICENSE-optiodom_diffdrive`` beside it and inside the archive): two UMBmark square
sessions (``square/231220200029``, ``square/230620202144``, 0.75 m … 1.7 m squares,
runs 1–3 clockwise, 4–6 counter-clockwise) to train on and one circular session
(``circular/231220200157``, two 30 s circle runs) to hold out. The full set
(five square, eight circular, five Ivanjko and two free sessions) is read with
``--data DIR``.

:func:`sample_dir` unpacks a sample once into the user's cache folder
(``$XDG_CACHE_HOME/realitygap`` or ``~/.cache/realitygap``; a temporary folder when
that is not writable) and returns the folder, laid out like ``<data>/<name>/``.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tarfile
import tempfile
from pathlib import Path

from realitygap.core.checks import UnknownNameError

__all__ = ["SAMPLES", "cache_root", "sample_dir"]

_HERE = Path(__file__).resolve().parent

SAMPLES: dict[str, str] = {
    "optiodom_diffdrive": (
        "embedded OptiOdom sample: 2 square sessions to train on, 1 circular session held out"
    ),
}
"""Sample name (a sub-folder of a data folder) → one-line description."""


def _archive(name: str) -> Path:
    if name not in SAMPLES:
        raise UnknownNameError(
            f"no embedded sample named {name!r}; embedded samples: {', '.join(sorted(SAMPLES))}"
        )
    return _HERE / f"{name}.tar.xz"


def cache_root() -> Path:
    """The user's cache folder of this package (``$XDG_CACHE_HOME/realitygap`` or
    ``~/.cache/realitygap``)."""
    base = os.environ.get("XDG_CACHE_HOME") or ""
    if not os.path.isabs(base):  # the XDG spec: a relative path is ignored
        base = str(Path.home() / ".cache")
    return Path(base) / "realitygap"


def _unpack(archive: Path, dest: Path) -> None:
    """Unpack ``archive`` into the new folder ``dest`` (nothing outside it, no links)."""
    with tarfile.open(archive, "r:xz") as tar:
        members = tar.getmembers()
        for m in members:
            target = (dest / m.name).resolve()
            if not (m.isfile() or m.isdir()) or not target.is_relative_to(dest.resolve()):
                raise ValueError(f"{archive}: unexpected member {m.name!r} in the sample archive")
        if hasattr(tarfile, "data_filter"):
            tar.extractall(dest, members=members, filter="data")
        else:  # pragma: no cover - Python without extraction filters; members checked above
            tar.extractall(dest, members=members)


def sample_dir(name: str, *, persistent: bool = False) -> Path:
    """The embedded sample ``name`` as a folder ``<root>/<name>/``, unpacked on first use.

    Parameters
    ----------
    name : str
        Sample name, a key of :data:`SAMPLES` (``"optiodom_diffdrive"``).
    persistent : bool
        The folder must outlive this process (a path printed for the user). Without it, a
        cache that cannot be written falls back to a temporary folder removed at exit.

    Returns
    -------
    Path
        The unpacked folder, laid out like the same sub-folder of a full data folder.

    Raises
    ------
    KeyError
        If ``name`` is not an embedded sample.
    """
    archive = _archive(name)
    digest = hashlib.sha256(archive.read_bytes()).hexdigest()[:12]
    root = cache_root() / f"sample-{name}-{digest}"
    if (root / name).is_dir():
        return root / name
    try:
        root.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=root.parent))
    except OSError as exc:
        if persistent:
            raise ValueError(
                f"the cache folder {root.parent} cannot be written ({exc.strerror or exc}), so "
                f"the sample {name!r} has nowhere to stay. Fix: set XDG_CACHE_HOME to a "
                "writable folder"
            ) from None
        staging = Path(tempfile.mkdtemp(prefix=f"realitygap-{name}-"))
        atexit.register(shutil.rmtree, staging, True)
        _unpack(archive, staging)
        return staging / name
    try:
        _unpack(archive, staging)
        os.replace(staging, root)
    except OSError:
        if (root / name).is_dir():  # another process unpacked it first
            shutil.rmtree(staging, ignore_errors=True)
        else:
            raise
    return root / name
