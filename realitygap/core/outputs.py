"""Where a run writes: every output target checked before the work, and written as one
transaction.

A command that writes files (``--report DIR``, ``--json FILE``, ``--out DIR``) opens an
:class:`Outputs` before any work starts and asks it for each target:

* :meth:`Outputs.folder` — a folder written whole (a report). The run writes into a fresh
  staging folder beside the target; :meth:`Outputs.commit` renames it into place. A target
  folder is replaced only if a previous run of this tool wrote it (it holds the marker file
  :data:`MARKER`), or with ``overwrite=True`` (``--overwrite``); a folder with other files is
  never touched otherwise.
* :meth:`Outputs.file` — one file (``--json``). Written to a staging file beside it and renamed
  into place on commit. An existing file is replaced only if this tool wrote it (a JSON
  object whose ``"written_by"`` names realitygap), or with ``overwrite=True``.
* :meth:`Outputs.workdir` — a folder a long run fills as it goes and can resume from (the
  benchmark's streamed episodes, a training run's checkpoints). It is claimed in place: the
  same ownership rule; the marker is written when the run ends with results in it, and a run
  that wrote nothing leaves no trace.

Each target is checked when it is asked for (:func:`~realitygap.core.checks.check_output_path`:
no input overwritten, the right kind, a writable folder), its file system must have the free
space the target needs, and it is locked (``fcntl.flock`` on a lock file beside it) until
the run ends, so that a second run on the same target is refused at once instead of mixing
two results. Leaving the ``with`` block before :meth:`Outputs.commit` (an exception,
Ctrl-C, SIGTERM) removes every staging file and folder: an interrupted run leaves the targets exactly as they were. A
staging folder a killed run left behind is removed by the next run on the same target.

Example
-------
>>> with Outputs(inputs=["run1.npz"]) as out:                    # doctest: +SKIP
...     report = out.folder("out/", "--report")    # checked, locked; a staging folder
...     result = diagnose(...)                     # the work
...     write_reports([("", result)], report)      # into the staging folder
...     out.commit()                               # renames the staging folder to out/
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import stat
import sys
import tempfile
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from realitygap.core.checks import check_output_path

__all__ = [
    "FILE_BYTES",
    "MARKER",
    "REPORT_BYTES",
    "WORKDIR_BYTES",
    "OutputError",
    "Outputs",
    "free_bytes",
    "written_by_us",
]

MARKER = ".realitygap-output"
"""File in every folder this tool writes whole or claims: who wrote it, when, with which
command. Its presence is what lets a later run replace the folder."""

WRITTEN_BY = "written_by"
"""Key of a JSON object this tool wrote, whose value starts with ``realitygap``."""

REPORT_BYTES = 64 * 2**20
"""Free space a report folder needs (its figures and HTML take a few MB; with margin)."""
FILE_BYTES = 16 * 2**20
"""Free space a single output file (``--json``) needs."""
WORKDIR_BYTES = 256 * 2**20
"""Free space a folder of streamed results or checkpoints needs to start."""

_LOCK_SUFFIX = ".realitygap-lock"
_STAGING = ".partial-"


class OutputError(ValueError):
    """An output target that cannot be written as asked; the message names the option,
    the path, what is wrong and the fix."""


def command_line() -> str:
    """This process's command line, quoted as a shell would need it."""
    import shlex

    return " ".join(shlex.quote(a) for a in ["realitygap", *sys.argv[1:]])


def _existing_ancestor(path: str | os.PathLike[str]) -> Path:
    p = Path(path).absolute()
    while not p.exists() and p.parent != p:
        p = p.parent
    return p


def free_bytes(path: str | os.PathLike[str]) -> int:
    """Free bytes on the file system of ``path`` or of its nearest existing ancestor."""
    return int(shutil.disk_usage(_existing_ancestor(path)).free)


def _words_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(n) < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} TB"  # pragma: no cover


def written_by_us(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is output of this tool: a folder holding :data:`MARKER`, or a JSON
    object file whose ``"written_by"`` starts with ``realitygap`` (read at most 64 MB)."""
    p = Path(path)
    if p.is_dir():
        return (p / MARKER).is_file()
    if not p.is_file() or p.stat().st_size > 64 * 2**20:
        return False
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and str(data.get(WRITTEN_BY, "")).startswith("realitygap")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _ours(name: str) -> bool:
    """A name this tool gives its own files beside or in a target (lock, staging, marker)."""
    return name == MARKER or name.endswith(_LOCK_SUFFIX) or _STAGING in name


def _user_entries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if not _ours(p.name))


def _listing(folder: Path, limit: int = 4) -> str:
    names = _user_entries(folder)
    shown = ", ".join(names[:limit])
    return shown + (f", … ({len(names)} entries)" if len(names) > limit else "")


@dataclass
class _Target:
    path: Path
    option: str
    kind: str  # "folder" | "file" | "workdir" | "stdout"
    staging: Path | None
    lock: int | None
    lock_path: Path | None
    created: list[Path] = field(default_factory=list)
    existed: bool = True


class Outputs:
    """The output targets of one run: checked and locked when asked for, written into
    staging places, renamed into place by :meth:`commit`. Leaving the ``with`` block
    without a commit (an error, an interruption, an early return) removes the staged
    outputs and leaves the targets as they were.

    Parameters
    ----------
    inputs : iterable of path-like
        The run's input files and folders; no target may be one or lie inside one.
    overwrite : bool
        Replace targets this tool did not write (``--overwrite``): a folder with other files
        is replaced whole, an existing file is replaced.
    command : str
        The command line, recorded in each folder's marker file.
    """

    def __init__(
        self,
        *,
        inputs: Iterable[str | os.PathLike[str]] = (),
        overwrite: bool = False,
        command: str = "",
    ):
        self.inputs = [Path(p) for p in inputs]
        self.overwrite = bool(overwrite)
        self.command = command
        self._targets: list[_Target] = []
        self._done = False

    # ------------------------------------------------------------------ asking for targets
    def folder(
        self, path: str | os.PathLike[str], option: str, *, need_bytes: int = REPORT_BYTES
    ) -> Path:
        """Claim the folder ``path`` (the argument ``option``) to be written whole; return
        the staging folder to write into."""
        if os.fspath(path) == "-":
            raise OutputError(
                f"{option} -: standard output cannot hold a folder of files. Fix: give "
                f"{option} a folder path"
            )
        target = self._claim(Path(path), option, "folder", need_bytes)
        parent = target.path.parent
        target.staging = Path(
            tempfile.mkdtemp(prefix=f".{target.path.name}{_STAGING}{os.getpid()}-", dir=parent)
        )
        return target.staging

    def file(
        self, path: str | os.PathLike[str], option: str, *, need_bytes: int = FILE_BYTES
    ) -> Path:
        """Claim the file ``path`` (the argument ``option``); return the staging path to write
        (the file there is renamed to ``path`` on commit). ``-`` is standard output: the
        staged file is printed there on commit."""
        if os.fspath(path) == "-":
            fd, tmp = tempfile.mkstemp(prefix="realitygap-stdout-", suffix=".tmp")
            os.close(fd)
            os.unlink(tmp)
            target = _Target(Path("-"), option, "stdout", Path(tmp), None, None)
            self._targets.append(target)
            return Path(tmp)
        target = self._claim(Path(path), option, "file", need_bytes)
        target.staging = target.path.with_name(
            f".{target.path.name}{_STAGING}{os.getpid()}-{time.monotonic_ns()}"
        )
        return target.staging

    def workdir(
        self, path: str | os.PathLike[str], option: str, *, need_bytes: int = WORKDIR_BYTES
    ) -> Path:
        """Claim the folder ``path`` (the argument ``option``) to be filled in place (results
        streamed, checkpoints): checked and locked for the run. It gets the marker when the
        run ends with something written in it (so that a later run may resume there); a run
        that wrote nothing leaves no trace."""
        target = self._claim(Path(path), option, "workdir", need_bytes)
        target.existed = target.path.exists()
        return target.path

    # ------------------------------------------------------------------ the checks
    def _claim(self, path: Path, option: str, kind: str, need_bytes: int) -> _Target:
        if self._done:
            raise RuntimeError("Outputs: this run's outputs are already committed or closed")
        for other in self._targets:
            if other.kind == "stdout":
                continue
            if other.path == path.absolute():
                raise OutputError(
                    f"{option} {path} is also the target of {other.option}; two outputs "
                    f"cannot be one path. Fix: give {option} another path"
                )
            here = path.absolute()
            pairs = (
                (here, option, other.path, other.option),
                (other.path, other.option, here, option),
            )
            for inner, inner_opt, folder, folder_opt in pairs:
                if folder in inner.parents:
                    raise OutputError(
                        f"{inner_opt} {inner} lies inside the folder of {folder_opt}, which is "
                        f"written whole (and replaced on the next run). Fix: give {inner_opt} a "
                        "path outside it"
                    )
        try:
            check_output_path(path, option, inputs=self.inputs, folder=kind != "file")
        except ValueError as exc:
            raise OutputError(str(exc)) from None
        self._check_owner(path, option, kind)
        usage = shutil.disk_usage(_existing_ancestor(path))
        if usage.total == 0:
            raise OutputError(
                f"{option} {path} lies on a pseudo file system ({_existing_ancestor(path)}: no "
                f"disk behind it, like /proc or /sys). Fix: give {option} a folder on a disk"
            )
        free = int(usage.free)
        if free < need_bytes:
            raise OutputError(
                f"{option} {path}: only {_words_bytes(free)} free on its file system, and "
                f"{'this output' if kind == 'file' else 'the folder'} needs about "
                f"{_words_bytes(need_bytes)}. Fix: free some space or choose {option} on "
                "another disk"
            )
        path = path.absolute()
        created = _make_parents(path.parent)
        target = _Target(path, option, kind, None, None, None, created)
        try:
            target.lock, target.lock_path = _lock(path, option)
            self._remove_stale_staging(path)
        except BaseException:
            self._release(target)
            raise
        self._targets.append(target)
        return target

    def _check_owner(self, path: Path, option: str, kind: str) -> None:
        if not path.exists() or self.overwrite:
            return
        if kind == "file":
            if path.stat().st_size == 0 or written_by_us(path):
                return
            raise OutputError(
                f"{option} {path} is an existing file that realitygap did not write; refusing to "
                f"overwrite it. Fix: choose another {option} path, or pass --overwrite to replace it"
            )
        if not _user_entries(path) or written_by_us(path):
            return
        what = (
            "to write into it anyway (files of the same names are replaced)"
            if kind == "workdir"
            else "to replace the folder and everything in it"
        )
        raise OutputError(
            f"{option} {path} is a folder that holds other files ({_listing(path)}) and no "
            f"realitygap marker; refusing to write into it. Fix: choose a new or empty folder, "
            f"or pass --overwrite {what}"
        )

    @staticmethod
    def _remove_stale_staging(path: Path) -> None:
        """Remove staging folders and files of runs on ``path`` whose process is gone."""
        prefix = f".{path.name}{_STAGING}"
        with contextlib.suppress(OSError):
            for p in path.parent.iterdir():
                if not p.name.startswith(prefix):
                    continue
                pid_text = p.name[len(prefix) :].split("-", 1)[0]
                if pid_text.isdigit() and not _pid_alive(int(pid_text)):
                    _remove(p)

    # ------------------------------------------------------------------ the end of the run
    def commit(self) -> None:
        """Move every staged output into place (folders get the marker file); release the
        locks. A staged folder replaces the old target whole, so no stale file remains."""
        if self._done:
            return
        try:
            for target in self._targets:
                if target.kind == "folder" and target.staging is not None:
                    if not target.staging.exists():  # the run removed it: nothing to put
                        continue
                    self._write_marker(target.staging)
                    _replace_folder(target.staging, target.path)
                elif target.kind == "file" and target.staging is not None:
                    if target.staging.exists():
                        os.replace(target.staging, target.path)
                elif target.kind == "stdout" and target.staging is not None:
                    if target.staging.exists():
                        sys.stdout.write(target.staging.read_text(encoding="utf-8"))
                        sys.stdout.flush()
                        target.staging.unlink()
                target.staging = None
        except BaseException:
            self.close()
            raise
        self._done = True
        for target in self._targets:
            self._release(target)

    def close(self) -> None:
        """Remove every staging file and folder not yet committed; release the locks. The
        targets stay as they were before the run."""
        for target in self._targets:
            if target.staging is not None:
                _remove(target.staging)
                target.staging = None
            self._release(target)
        self._done = True

    def _release(self, target: _Target) -> None:
        if target.kind == "workdir" and target.lock is not None:
            self._settle_workdir(target)
        if target.lock is not None:
            with contextlib.suppress(OSError):
                if target.lock_path is not None:
                    os.unlink(target.lock_path)
            with contextlib.suppress(OSError):
                os.close(target.lock)
            target.lock = None
        if not target.path.exists():
            for folder in reversed(target.created):  # folders made for a target never written
                with contextlib.suppress(OSError):
                    folder.rmdir()
        target.created = []

    def _settle_workdir(self, target: _Target) -> None:
        """At the end of a run: mark a work folder that holds results; remove one this run
        made and left empty."""
        p = target.path
        if not p.is_dir():
            return
        content = [q for q in p.iterdir() if q.name != MARKER]
        if content:
            if not (p / MARKER).exists():
                with contextlib.suppress(OSError):
                    self._write_marker(p)
        elif not target.existed:
            with contextlib.suppress(OSError):
                for q in p.iterdir():
                    q.unlink()
                p.rmdir()

    def _write_marker(self, folder: Path) -> None:
        from realitygap import __version__
        from realitygap.core.io import atomic_write_text

        info = {
            WRITTEN_BY: f"realitygap {__version__}",
            "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "command": self.command,
        }
        atomic_write_text(folder / MARKER, json.dumps(info, indent=1) + "\n")

    def __enter__(self) -> Outputs:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


# --------------------------------------------------------------------------- helpers
def _make_parents(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing ancestors; return the ones created, outermost first."""
    missing = []
    p = folder
    while not p.exists() and p.parent != p:
        missing.append(p)
        p = p.parent
    missing.reverse()
    for p in missing:
        with contextlib.suppress(FileExistsError):
            p.mkdir()
    return missing


def _lock(path: Path, option: str) -> tuple[int, Path]:
    """Take the exclusive lock of target ``path`` (a lock file beside it); refuse at once
    when another process holds it."""
    import fcntl

    lock_path = path.with_name(f".{path.name}{_LOCK_SUFFIX}")
    for _ in range(10):
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            try:
                holder = lock_path.read_text(encoding="ascii").strip()
            except OSError:
                holder = "?"
            raise OutputError(
                f"{option} {path} is being written by another realitygap run (process "
                f"{holder or '?'}); two runs on one target would mix their results. Fix: wait "
                f"for that run to finish, or give {option} another path"
            ) from None
        # the file may have been unlinked by its last holder between open and flock
        try:
            same = os.fstat(fd).st_ino == os.stat(lock_path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode("ascii"))
            return fd, lock_path
        os.close(fd)
    raise OutputError(f"{option} {path}: could not take its lock file {lock_path}; try again")


def _replace_folder(staging: Path, target: Path) -> None:
    """Rename ``staging`` to ``target``; an existing ``target`` is moved aside first and
    removed after."""
    if not target.exists():
        os.rename(staging, target)
        return
    old = target.with_name(f".{target.name}{_STAGING}{os.getpid()}-old-{time.monotonic_ns()}")
    os.rename(target, old)
    try:
        os.rename(staging, target)
    except BaseException:
        os.rename(old, target)
        raise
    _remove(old)


def _remove(p: Path) -> None:
    with contextlib.suppress(FileNotFoundError):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, onerror=_force_remove)
        else:
            p.unlink()


def _force_remove(func: object, path: str, _exc: object) -> None:
    """``shutil.rmtree`` error handler: make a read-only entry writable and retry once."""
    with contextlib.suppress(OSError):
        os.chmod(os.path.dirname(path), stat.S_IRWXU)
        os.chmod(path, stat.S_IRWXU)
        if os.path.isdir(path):
            os.rmdir(path)
        else:
            os.unlink(path)
