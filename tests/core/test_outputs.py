"""Outputs are transactions: checked before the work, never clobbering what this tool did not
write, locked against a second run, all or nothing.

The sub-command tests go through the real command line: every sub-command that writes a
``--report``/``--json``/``--out`` target must refuse a foreign target *before* its work,
leaving every file of the user as it was.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from realitygap import cli
from realitygap.core.io import write_json
from realitygap.core.outputs import MARKER, OutputError, Outputs, written_by_us
from realitygap.samples import sample_dir


def snapshot(root: Path) -> dict[str, str]:
    """Every file below ``root`` (hidden ones too) with its sha256."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def users_folder(root: Path) -> Path:
    """A folder of a user's own results, no realitygap marker."""
    folder = root / "mine"
    folder.mkdir()
    (folder / "report.md").write_text("my notes\n")
    (folder / "diagnosis.json").write_text('{"mine": true}\n')
    (folder / "fig.png").write_bytes(b"\x89PNG not really")
    return folder


# --------------------------------------------------------------------------- the API
def test_folder_is_staged_and_renamed_into_place_with_a_marker(tmp_path: Path) -> None:
    target = tmp_path / "out" / "report"
    with Outputs() as out:
        stage = out.folder(target, "--report")
        assert stage.parent == target.parent and stage != target
        (stage / "report.md").write_text("new\n")
        assert not target.exists()  # nothing in place before the commit
        out.commit()
    assert (target / "report.md").read_text() == "new\n"
    assert written_by_us(target)
    assert sorted(p.name for p in target.parent.iterdir()) == ["report"]


def test_a_previous_report_is_replaced_whole_no_stale_figure(tmp_path: Path) -> None:
    target = tmp_path / "report"
    with Outputs() as out:
        stage = out.folder(target, "--report")
        (stage / "old-figure.png").write_bytes(b"old")
        (stage / "report.md").write_text("old\n")
        out.commit()
    with Outputs() as out:
        stage = out.folder(target, "--report")
        (stage / "report.md").write_text("new\n")
        out.commit()
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "report.md"]
    assert (target / "report.md").read_text() == "new\n"


def test_a_folder_with_other_files_is_refused_unless_overwrite(tmp_path: Path) -> None:
    folder = users_folder(tmp_path)
    before = snapshot(tmp_path)
    with pytest.raises(OutputError, match=r"--report .*mine.*holds other files.*--overwrite"):
        with Outputs() as out:
            out.folder(folder, "--report")
    assert snapshot(tmp_path) == before
    with Outputs(overwrite=True) as out:
        stage = out.folder(folder, "--report")
        (stage / "report.md").write_text("new\n")
        out.commit()
    assert sorted(p.name for p in folder.iterdir()) == [MARKER, "report.md"]


def test_a_file_not_written_by_realitygap_is_refused(tmp_path: Path) -> None:
    mine = tmp_path / "results.json"
    mine.write_text('{"my": "data"}\n')
    with pytest.raises(OutputError, match=r"--json .*results\.json .*did not write"):
        with Outputs() as out:
            out.file(mine, "--json")
    assert mine.read_text() == '{"my": "data"}\n'
    ours = tmp_path / "ours.json"
    write_json(ours, {"a": 1})
    with Outputs() as out:
        stage = out.file(ours, "--json")
        write_json(stage, {"a": 2})
        out.commit()
    assert json.loads(ours.read_text())["a"] == 2


def test_an_interrupted_run_leaves_the_target_as_it_was(tmp_path: Path) -> None:
    target = tmp_path / "report"
    with Outputs() as out:
        stage = out.folder(target, "--report")
        (stage / "report.md").write_text("first\n")
        out.commit()
    before = snapshot(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        with Outputs() as out:
            stage = out.folder(target, "--report")
            js = out.file(tmp_path / "d.json", "--json")
            (stage / "report.md").write_text("half\n")
            write_json(js, {"half": True})
            raise KeyboardInterrupt
    assert snapshot(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]


def test_a_second_run_on_the_same_target_is_refused_while_the_first_runs(tmp_path: Path) -> None:
    target = tmp_path / "report"
    with Outputs() as first:
        first.folder(target, "--report")
        with pytest.raises(OutputError, match=r"being written by another realitygap run"):
            with Outputs() as second:
                second.folder(target, "--report")
    with Outputs() as third:  # free again once the first is done
        third.folder(target, "--report")


def test_too_little_free_space_is_said_before_the_work(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match=r"--report .*free .*needs about"):
        with Outputs() as out:
            out.folder(tmp_path / "r", "--report", need_bytes=10**18)
    assert list(tmp_path.iterdir()) == []


def test_a_staging_folder_of_a_killed_run_is_removed(tmp_path: Path) -> None:
    dead = tmp_path / ".report.partial-999999999-abc"
    dead.mkdir()
    (dead / "report.md").write_text("half\n")
    with Outputs() as out:
        out.folder(tmp_path / "report", "--report")
    assert not dead.exists()


# --------------------------------------------------------------------------- every sub-command
def _sample_session() -> str:
    return str(sample_dir("optiodom_diffdrive") / "square" / "231220200029")


FOLDER_WRITERS = {
    "diagnose --report": lambda f: ["diagnose", _sample_session(), "--report", str(f)],
    "run --report": lambda f: ["run", "diagnose-real", "--report", str(f)],
    "benchmark --out": lambda f: ["benchmark", "--policies", "random", "--out", str(f)],
    "train --out": lambda f: ["train", "--out", str(f)],
}
FILE_WRITERS = {
    "diagnose --json": lambda f: ["diagnose", _sample_session(), "--json", str(f)],
    "run --json": lambda f: ["run", "diagnose-real", "--json", str(f)],
    "inspect --json": lambda f: ["inspect", _sample_session(), "--json", str(f)],
    "calibrate umbmark --json": lambda f: [
        "calibrate",
        "umbmark",
        _sample_session(),
        "--json",
        str(f),
    ],
}


@pytest.mark.parametrize("command", sorted(FOLDER_WRITERS))
def test_every_folder_target_is_refused_before_work_when_foreign(
    tmp_path: Path, command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = users_folder(tmp_path)
    before = snapshot(tmp_path)
    assert cli.main([*FOLDER_WRITERS[command](folder), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "holds other files" in err and "--overwrite" in err
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("command", sorted(FILE_WRITERS))
def test_every_file_target_is_refused_before_work_when_foreign(
    tmp_path: Path, command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    mine = tmp_path / "results.json"
    mine.write_text("my,table\n1,2\n")
    before = snapshot(tmp_path)
    assert cli.main([*FILE_WRITERS[command](mine), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "did not write" in err and "--overwrite" in err
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("command", sorted(FOLDER_WRITERS))
def test_every_folder_target_that_is_a_file_is_refused(
    tmp_path: Path, command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "a-file"
    f.write_text("x\n")
    assert cli.main([*FOLDER_WRITERS[command](f), "--quiet"]) == 2
    assert "is an existing file, but a folder is expected" in capsys.readouterr().err
    assert f.read_text() == "x\n"


def test_inspect_writes_its_json_and_replaces_its_own(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    js = tmp_path / "i.json"
    for _ in range(2):  # the second run replaces the file the first wrote
        assert cli.main(["inspect", _sample_session(), "--json", str(js), "--quiet"]) == 0
    assert written_by_us(js)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["i.json"]


# --------------------------------------------------------------------------- a full disk
@pytest.fixture
def tiny_disk(tmp_path: Path):  # type: ignore[no-untyped-def]
    """A 512 kB tmpfs (needs the right to mount: root in a container; skipped otherwise)."""
    import subprocess

    mnt = tmp_path / "tiny"
    mnt.mkdir()
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=512k", "tmpfs", str(mnt)],
        capture_output=True,
        check=False,
    )
    if done.returncode != 0:
        pytest.skip("cannot mount a small tmpfs here")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


def test_a_full_disk_is_found_before_the_work(
    tiny_disk: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["diagnose", _sample_session(), "--report", str(tiny_disk / "r"), "--quiet"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "--report" in err and "free on its file system" in err and "Fix:" in err
    assert list(tiny_disk.iterdir()) == []


def test_a_disk_that_fills_while_writing_leaves_nothing_half_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import errno

    import realitygap.core.io as io

    def full(path: object, payload: object) -> Path:
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(io, "write_json", full)
    js = tmp_path / "i.json"
    assert cli.main(["inspect", _sample_session(), "--json", str(js), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "disk is full" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_a_work_folder_is_marked_only_when_the_run_wrote_into_it(tmp_path: Path) -> None:
    target = tmp_path / "bench"
    with Outputs() as out:  # a run that fails before writing leaves no trace
        out.workdir(target, "--out")
    assert list(tmp_path.iterdir()) == []
    with Outputs() as out:  # a run that streamed results (and was stopped) can resume there
        folder = out.workdir(target, "--out")
        folder.mkdir()
        (folder / "episodes.jsonl").write_text("{}\n")
    assert written_by_us(target)
    with Outputs() as out:  # so the next run may claim it again
        out.workdir(target, "--out")
