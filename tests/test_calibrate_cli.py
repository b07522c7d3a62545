"""``realitygap calibrate umbmark``: real OptiOdom squares and the error paths."""

from __future__ import annotations

import argparse
import datetime
import json
import shutil
from pathlib import Path

import pytest

from realitygap.calibrate import (
    add_calibrate_parser,
    calibrate_session,
    format_calibrations,
    pool_calibrations,
)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "optiodom_diffdrive"


def _main(argv: list[str]) -> int:
    """Run the ``calibrate`` sub-command as the ``realitygap`` CLI would."""
    parser = argparse.ArgumentParser(prog="realitygap")
    add_calibrate_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args))


@pytest.fixture(scope="module")
def square_dirs() -> list[Path]:
    folder = DATA / "square"
    if not folder.is_dir():
        pytest.skip(
            f"OptiOdom square sessions not found at {folder}; these tests need "
            "../shared/data/optiodom_diffdrive beside the repository"
        )
    dirs = sorted(p for p in folder.iterdir() if (p / f"{p.name}_metadata.csv").is_file())
    if not dirs:
        pytest.skip(f"no session folder in {folder}")
    return dirs


def test_umbmark_on_real_squares_writes_json(
    square_dirs: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "deep" / "umbmark.json"
    assert _main(["calibrate", "umbmark", *map(str, square_dirs), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "E_d" in printed and "pooled over" in printed
    assert [p.name for p in out.parent.iterdir()] == ["umbmark.json"]  # no temporary left
    data = json.loads(out.read_text())
    assert len(data["sessions"]) == len(square_dirs)
    fields = {"session_id", "E_d", "E_b", "c_L", "c_R", "D_L", "D_R", "b", "n_cw", "n_ccw"}
    for entry in data["sessions"]:
        assert fields <= set(entry)
        assert 0.99 < entry["E_d"] < 1.01
        assert 0.95 < entry["E_b"] < 1.05
        assert entry["n_cw"] > 0 and entry["n_ccw"] > 0
        # the corrections are consistent with the factors
        assert entry["D_L"] == pytest.approx(entry["c_L"] * entry["nominal_D_L"])
        assert entry["D_R"] == pytest.approx(entry["c_R"] * entry["nominal_D_R"])
        assert entry["b"] == pytest.approx(entry["E_b"] * entry["nominal_b"])
        assert entry["c_L"] + entry["c_R"] == pytest.approx(2.0)
    assert 0.99 < data["pooled"]["E_d"] < 1.01
    # one physical robot: the calibrated wheelbase per wheel diameter agrees across sessions
    assert data["pooled"]["b_over_D_std"] < 0.01 * data["pooled"]["b_over_D"]


def test_pooling_of_one_session_is_that_session(square_dirs: list[Path]) -> None:
    cal = calibrate_session(square_dirs[0])
    pooled = pool_calibrations([cal])
    assert pooled.E_d == cal.E_d and pooled.E_d_std == 0.0
    assert pooled.E_b_for(0.5 * (cal.nominal_D_L + cal.nominal_D_R), cal.nominal_b) == (
        pytest.approx(cal.E_b)
    )
    assert cal.session_id in format_calibrations([cal], pooled)


def test_one_direction_only_is_a_clear_error(
    square_dirs: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src = square_dirs[0]
    sid = src.name
    dst = tmp_path / sid
    dst.mkdir()
    shutil.copy(src / f"{sid}_metadata.csv", dst)
    for k in (1, 2, 3):  # runs 1-3 of a session are its clockwise squares
        for suffix in ("", "_odo"):
            name = f"{sid}_run-{k:02d}{suffix}.csv"
            if (src / name).is_file():
                shutil.copy(src / name, dst)
    out = tmp_path / "never.json"
    assert _main(["calibrate", "umbmark", str(dst), "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert "only clockwise runs" in err and "both directions" in err
    assert not out.exists()
    with pytest.raises(ValueError, match="only clockwise runs"):
        calibrate_session(dst)


def test_folder_that_is_not_a_session(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "notes.txt").write_text("nothing here\n")
    assert _main(["calibrate", "umbmark", str(tmp_path)]) == 2
    assert "is not an OptiOdom session" in capsys.readouterr().err
    assert _main(["calibrate", "umbmark", str(tmp_path / "missing")]) == 2
    assert "no such folder" in capsys.readouterr().err


def test_non_square_session_needs_a_side_length(capsys: pytest.CaptureFixture[str]) -> None:
    circular = DATA / "circular"
    if not circular.is_dir():
        pytest.skip(f"OptiOdom circular sessions not found at {circular}")
    session = sorted(p for p in circular.iterdir() if p.is_dir())[0]
    assert _main(["calibrate", "umbmark", str(session)]) == 2
    assert "UMBmark needs square runs" in capsys.readouterr().err
    assert _main(["calibrate", "umbmark", str(session), "--side-length", "-1"]) == 2
    assert "--side-length" in capsys.readouterr().err


def test_session_time_parses_an_optiodom_id_and_rejects_others() -> None:
    from realitygap.calibrate import _recorded, session_time

    assert session_time("250320241432") == datetime.datetime(2024, 3, 25, 14, 32)
    assert _recorded("250320241432") == "2024-03-25T14:32"
    for bad in ("", "25032024143", "2503202414320", "25032024143x", "991320241432"):
        assert session_time(bad) is None
        assert _recorded(bad) == ""
