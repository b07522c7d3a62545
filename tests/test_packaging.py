"""The distribution maps every source folder into ``realitygap.*`` and nothing else."""

from __future__ import annotations

from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")

ROOT = Path(__file__).resolve().parents[1]


def test_every_subpackage_is_listed_and_mapped() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    mapping = config["package-dir"]
    listed = set(config["packages"])
    found = set()
    for top, folder in mapping.items():
        base = ROOT / folder
        for init in base.rglob("__init__.py"):
            rel = init.parent.relative_to(base)
            name = ".".join([top, *rel.parts]) if rel.parts else top
            found.add(name)
    assert found - listed == set(), f"sub-packages missing from pyproject: {sorted(found - listed)}"
    assert all(name.startswith("realitygap") for name in listed)
    # every mapped folder exists
    assert all((ROOT / folder).is_dir() for folder in mapping.values())
