"""Every file or folder the architecture document names exists, so the document cannot drift
from the tree it describes."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("docs/architecture.md",)

# a path in backticks: folders and files of the repository, e.g. `diagnosis/fit/model.py`
PATH = re.compile(r"`([A-Za-z_][\w./-]*/[\w./-]*)`")


def named_paths(text: str) -> list[str]:
    """Repository paths named in ``text`` (placeholders such as ``<robot>`` and globs skipped)."""
    out = []
    for m in PATH.finditer(text):
        path = m.group(1).rstrip(".,;:")
        if "*" in path or "<" in path or path.startswith(("realitygap/Wheel", "realitygap/Arm")):
            continue  # env ids such as realitygap/WheeledNav-v0 are not paths
        if not re.search(r"\.(py|md|toml|json|yml|txt)$|/$", path) and "." in Path(path).name:
            continue
        out.append(path)
    return out


@pytest.mark.parametrize("doc", DOCS)
def test_every_path_named_exists(doc: str) -> None:
    text = (ROOT / doc).read_text(encoding="utf-8")
    paths = named_paths(text)
    assert paths, f"{doc} names no path: the pattern no longer matches its style"
    missing = [p for p in paths if not (ROOT / p).exists()]
    assert not missing, f"{doc} names paths that do not exist: {missing}"


def test_the_pattern_finds_and_skips_what_it_should() -> None:
    text = "`diagnosis/fit/model.py`, `robots/effects/<robot>.py`, `realitygap/WheeledNav-v0`, `tests/`"
    assert named_paths(text) == ["diagnosis/fit/model.py", "tests/"]
