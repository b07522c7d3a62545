"""Atomically written files get a new file's usual permissions."""

from __future__ import annotations

import os
from pathlib import Path

from realitygap.core.io import atomic_write_text


def test_atomic_file_has_the_permissions_of_a_new_file(tmp_path: Path) -> None:
    mask = os.umask(0o022)
    try:
        path = atomic_write_text(tmp_path / "table.csv", "a,b\n")
    finally:
        os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o644
    assert path.read_text() == "a,b\n"


def test_atomic_file_follows_a_private_umask(tmp_path: Path) -> None:
    mask = os.umask(0o077)
    try:
        path = atomic_write_text(tmp_path / "private.json", "{}")
    finally:
        os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o600
