"""Errors name the input and the real cause, and the fix they suggest works.

One test per class of failure, each with at least two instances; every error must be a
ValueError (LogError, RobotFileError) or FileNotFoundError that names the file or option,
and where a message suggests a command or an option, the test runs it and checks that the
reading gets further.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from realitygap.calibrate import add_calibrate_parser
from realitygap.core.checks import (
    check_input_path,
    check_output_path,
    load_json_or_yaml,
    parse_json_option,
)
from realitygap.diagnosis.logs.importers.table import read_table
from realitygap.diagnosis.logs.inspect import inspect_paths
from realitygap.diagnosis.logs.robot_file import load_robot_file
from realitygap.diagnosis.report.summary import change_words, data_extent, data_words

ALLOWED = (ValueError, FileNotFoundError)
ROWS = "t,v\n" + "".join(f"{i},{0.5 * i}\n" for i in range(12))
DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "optiodom_diffdrive"


def _error(call, *args, **kwargs) -> BaseException:
    """The exception ``call`` raises; it must be a ValueError or FileNotFoundError."""
    try:
        call(*args, **kwargs)
    except ALLOWED as exc:
        return exc
    except BaseException as exc:
        pytest.fail(f"{type(exc).__name__} escaped: {exc}")
    pytest.fail(f"{call.__name__} raised nothing")


# ------------------------------------------------------------------ library parser errors
@pytest.mark.parametrize("layout", ["csv", "whitespace"])
def test_a_huge_cell_is_refused_with_file_line_and_a_limit_that_works(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, layout: str
) -> None:
    blob = "x" * 200_000
    sep, quote = (",", '"') if layout == "csv" else (" ", "")
    rows = "".join(
        f"{i}{sep}{0.5 * i}{sep}{quote}{blob if i == 3 else 'a'}{quote}\n" for i in range(12)
    )
    path = tmp_path / f"big.{layout}"
    path.write_text(f"t{sep}v{sep}blob\n" + rows)
    exc = _error(read_table, path)
    msg = str(exc)
    assert str(path) in msg and "line 5" in msg and "200,000 characters" in msg
    assert "_csv" not in msg and "REALITYGAP_MAX_CELL_KB" in msg
    monkeypatch.setenv("REALITYGAP_MAX_CELL_KB", "512")  # the fix the message names
    table = read_table(path)
    assert table.n_rows == 12 and "blob" in table.text_columns
    np.testing.assert_allclose(table.column("v"), 0.5 * np.arange(12))


# ------------------------------------------------------------------ input paths
def _loop(tmp_path: Path, name: str) -> Path:
    a, b = tmp_path / f"{name}_a", tmp_path / f"{name}_b"
    a.symlink_to(b.name)
    b.symlink_to(a.name)
    return a


@pytest.mark.parametrize("what", ["file", "folder"])
def test_a_symlink_loop_is_named_as_one_everywhere(tmp_path: Path, what: str) -> None:
    real = tmp_path / ("run.csv" if what == "file" else "runs")
    if what == "file":
        real.write_text(ROWS)
    else:
        real.mkdir()
    link = _loop(tmp_path, what)
    for call, args in (
        (check_input_path, (link, "LOG")),
        (read_table, (link,)),
        (load_robot_file, (link,)),
        (check_output_path, (tmp_path / "out.json", "--json")),
    ):
        kwargs = {"inputs": [link]} if call is check_output_path else {}
        exc = _error(call, *args, **kwargs) if call is not check_output_path else None
        if call is check_output_path:
            call(*args, **kwargs)  # no RuntimeError from resolving the input
            continue
        assert "symbolic link loop" in str(exc) and str(link) in str(exc), str(exc)
    inspected = inspect_paths([link])
    assert "symbolic link loop" in (inspected.files[0].error or "")
    # the fix: point the link at the real file or folder
    link.unlink()
    subprocess.run(["ln", "-sfn", str(real), str(link)], check=True)
    assert check_input_path(link, "LOG") == link


def test_a_dangling_link_and_a_missing_path_are_file_not_found(tmp_path: Path) -> None:
    dangling = tmp_path / "run.csv"
    dangling.symlink_to("gone.csv")
    exc = _error(check_input_path, dangling, "LOG")
    assert isinstance(exc, FileNotFoundError) and "gone.csv" in str(exc)
    exc = _error(read_table, tmp_path / "none.csv")
    assert isinstance(exc, FileNotFoundError) and "none.csv" in str(exc)


# ------------------------------------------------------------------ JSON / YAML of the wrong type
def test_json_of_the_wrong_top_level_type_names_the_file_or_option(tmp_path: Path) -> None:
    listing = tmp_path / "map.json"
    listing.write_text('["t=time", "cmd.v=v"]')
    exc = _error(load_json_or_yaml, listing, "--columns")
    assert f"--columns {listing}" in str(exc) and "a list of 2" in str(exc)
    exc = _error(parse_json_option, "[0.23]", "--params", expect=dict)
    assert str(exc).startswith("--params: expected a JSON object") and "a list" in str(exc)
    robot = tmp_path / "robot.json"
    robot.write_text(json.dumps([{"robot": "diffdrive"}]))
    exc = _error(load_robot_file, robot)
    assert str(robot) in str(exc) and "JSON object" in str(exc)
    robot_yaml = tmp_path / "robot.yaml"
    robot_yaml.write_text("- robot: diffdrive\n")
    exc = _error(load_robot_file, robot_yaml)
    assert str(robot_yaml) in str(exc) and "YAML mapping" in str(exc)
    # the fix: an object of the same entries
    robot.write_text(json.dumps({"robot": "diffdrive", "wheels": {"radius": 0.03}}))
    assert load_robot_file(robot).kind == "diffdrive"


def test_a_syntax_error_names_the_file_line_and_column(tmp_path: Path) -> None:
    bad = tmp_path / "params.json"
    bad.write_text('{\n  "wheelbase": 0.23,\n  radius: 0.03\n}\n')
    msg = str(_error(load_json_or_yaml, bad, "--params"))
    assert f"--params {bad}" in msg and "line 3 column 3" in msg and "radius: 0.03" in msg
    robot = tmp_path / "robot.yaml"
    robot.write_text("robot: diffdrive\nwheels:\n  radius: [0.03\n")
    msg = str(_error(load_robot_file, robot))
    assert str(robot) in msg and "not valid YAML" in msg and "line 4" in msg
    msg = str(_error(parse_json_option, '{"a": 1,', "--firmware"))
    assert msg.startswith("--firmware: invalid JSON at line 1 column 9")


# ------------------------------------------------------------------ empty files
def test_an_empty_file_is_called_empty(tmp_path: Path) -> None:
    for name in ("run.csv", "run.txt"):
        path = tmp_path / name
        path.write_bytes(b"")
        for call in (read_table, lambda p: check_input_path(p, "LOG")):
            msg = str(_error(call, path))
            assert str(path) in msg and "is empty (0 bytes)" in msg and "rows" in msg
            assert "rename" not in msg and "looks like" not in msg
    robot = tmp_path / "robot.yaml"
    robot.write_bytes(b"")
    msg = str(_error(load_robot_file, robot))
    assert str(robot) in msg and "empty (0 bytes)" in msg


def test_an_empty_log_through_the_diagnose_reader(tmp_path: Path) -> None:
    from realitygap.diagnosis.logs.read import ReadOptions, read_logs

    path = tmp_path / "run.csv"
    path.write_bytes(b"")
    msg = str(_error(read_logs, path, ReadOptions(columns="t=t,cmd.v=v,cmd.w=v")))
    assert "is empty (0 bytes)" in msg and "a log needs rows" in msg


# ------------------------------------------------------------------ UTF-16 / UTF-32
@pytest.mark.parametrize(
    ("codec", "bom", "label"),
    [
        ("utf-16-le", b"\xff\xfe", "UTF-16 LE"),
        ("utf-16-be", b"\xfe\xff", "UTF-16 BE"),
        ("utf-32-le", b"\xff\xfe\x00\x00", "UTF-32 LE"),
        ("utf-32-be", b"\x00\x00\xfe\xff", "UTF-32 BE"),
    ],
)
def test_unicode_text_with_a_byte_order_mark_is_read_not_called_binary(
    tmp_path: Path, codec: str, bom: bytes, label: str
) -> None:
    path = tmp_path / "run.csv"
    path.write_bytes(bom + ROWS.encode(codec))
    table = read_table(path)
    assert table.names == ("t", "v") and table.n_rows == 12 and table.encoding == label
    np.testing.assert_allclose(table.column("v"), 0.5 * np.arange(12))
    inspected = inspect_paths([path])
    assert inspected.files[0].kind == "table" and label in inspected.files[0].summary
    # the diagnose reader takes UTF-8: its message and inspect's note give the command
    msg = str(_error(check_input_path, path, "LOG"))
    assert f"is {label} text" in msg and "save it as UTF-8" in msg
    command = msg.split("e.g. ", 1)[1].split(", and pass")[0]
    assert "utf8" in inspected.command
    subprocess.run(command, shell=True, check=True, cwd=tmp_path)
    converted = tmp_path / "run-utf8.csv"
    assert check_input_path(converted, "LOG") == converted
    assert read_table(converted).n_rows == 12


def test_a_utf16_log_through_the_diagnose_reader_gets_the_conversion(tmp_path: Path) -> None:
    from realitygap.diagnosis.logs.read import ReadOptions, read_logs

    path = tmp_path / "run.csv"
    path.write_bytes(ROWS.encode("utf-16"))
    msg = str(_error(read_logs, path, ReadOptions(columns="t=t,cmd.v=v,cmd.w=v")))
    assert "UTF-16" in msg and "binary" not in msg and "iconv" in msg


# ------------------------------------------------------------------ calibrate umbmark FILE
def _calibrate(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="realitygap")
    add_calibrate_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["calibrate", "umbmark", *argv])
    return int(args.func(args))


def test_calibrate_on_a_file_says_a_folder_of_runs_is_expected(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    lone = tmp_path / "run.csv"
    lone.write_text(ROWS)
    assert _calibrate([str(lone)]) == 2
    err = capsys.readouterr().err
    assert "is a file" in err and "folder" in err and "<ID>/<ID>_metadata.csv" in err
    assert "no such" not in err
    sessions = sorted(p for p in (DATA / "square").glob("*") if p.is_dir())
    if not sessions:
        pytest.skip(f"no OptiOdom square session at {DATA}")
    run = sorted(sessions[0].glob("*_run-01.csv"))[0]
    assert _calibrate([str(run)]) == 2
    err = capsys.readouterr().err
    assert "is a file of the session" in err
    command = err.strip().splitlines()[-1].strip()
    argv = shlex.split(command)
    assert argv[:3] == ["realitygap", "calibrate", "umbmark"]
    assert _calibrate(argv[3:]) == 0  # the suggested command calibrates
    assert _calibrate([str(DATA / "square")]) == 2
    command = capsys.readouterr().err.strip().splitlines()[-1].strip()
    assert _calibrate(shlex.split(command)[3:]) == 0


# ------------------------------------------------------------------ signed changes
@pytest.mark.parametrize(
    ("pct", "words"),
    [
        (70.4, "70 % less"),
        (-70.4, "worse: 70 % more"),
        (0.2, "about the same"),
        (float("nan"), "change unknown"),
    ],
)
def test_change_words_take_the_direction_from_the_sign(pct: float, words: str) -> None:
    assert change_words(pct) == words
    assert "-" not in change_words(pct, less="closed", more="wider", digits=1)


def test_no_report_sentence_formats_a_signed_change_itself() -> None:
    root = Path(__file__).resolve().parents[2] / "diagnosis" / "report"
    for name in ("summary.py", "words.py", "writer.py"):
        text = (root / name).read_text(encoding="utf-8")
        assert "% less)" not in text and "% closed by" not in text, name


# ------------------------------------------------------------------ words about the data
def _log(channels: dict[str, int], n: int = 40, dt: float = 0.1) -> SimpleNamespace:
    t = np.arange(n) * dt
    return SimpleNamespace(
        channels={c: np.zeros((n, k)) for c, k in channels.items()},
        n=n,
        duration=float(t[-1] - t[0]),
    )


def test_the_words_about_the_data_come_from_the_logs_channels() -> None:
    arm = [_log({"joints": 6, "tool_pos": 3}, n=300, dt=1.0) for _ in range(2)]
    words = data_words(arm, "commands", 2.0)
    assert "velocity commands" not in words and "600 measured poses" in words
    assert "no commands" in words and " s windows" not in words
    assert data_extent(arm) == "600 measured poses"
    drive = [_log({"cmd": 2, "pose_gt": 3, "ticks": 2})]
    assert "velocity commands" in data_words(drive, "commands", 2.0)
    assert "wheel rotation" in data_words(drive, "ticks", 2.0)
    assert data_extent(drive) == "4 s of motion"
    no_cmd = [_log({"ticks": 2, "pose_gt": 3})]
    words = data_words(no_cmd, "commands", 2.0)
    assert "velocity commands" not in words and "no commands channel" in words


@pytest.mark.skipif(os.environ.get("CI_FAST") == "1", reason="slow")
def test_inspect_json_of_wrong_kind_and_options_exist(tmp_path: Path) -> None:
    """``realitygap inspect`` reports a folder loop per file and still writes its JSON."""
    from realitygap.diagnosis.logs.inspect import run_inspect

    link = _loop(tmp_path, "folder")
    out = tmp_path / "inspect.json"
    args = argparse.Namespace(paths=[str(link)], json=str(out), delimiter=None, decimal=None)
    assert run_inspect(args) == 2
    assert "symbolic link loop" in json.loads(out.read_text())["files"][0]["error"]
