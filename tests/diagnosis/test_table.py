"""The generic table reader: text layouts, cells, binary formats, limits and its errors."""

from __future__ import annotations

import math
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from realitygap.core.checks import ResourceLimits
from realitygap.diagnosis.logs.importers.table import Table, read_table
from realitygap.diagnosis.logs.log import Log, LogError


def write(path: Path, text: str, encoding: str = "utf-8") -> Path:
    path.write_bytes(text.encode(encoding))
    return path


# --------------------------------------------------------------------------- delimiters
LAYOUTS = {
    "comma": (",", ".", "t,x,y\n0,1.5,-2\n0.1,2.5,-3\n0.2,3.5,-4\n"),
    "semicolon": (";", ",", "t;x;y\n0;1,5;-2\n0,1;2,5;-3\n0,2;3,5;-4\n"),
    "tab": ("\t", ",", "t\tx\ty\n0\t1,5\t-2\n0,1\t2,5\t-3\n0,2\t3,5\t-4\n"),
    "markdown": (
        "|",
        ".",
        "| t | x | y |\n|---|:--|--:|\n| 0 | 1.5 | -2 |\n| 0.1 | 2.5 | -3 |\n| 0.2 | 3.5 | -4 |\n",
    ),
    "psql": (
        "|",
        ".",
        "  t  |  x  |  y\n-----+-----+----\n 0 | 1.5 | -2\n 0.1 | 2.5 | -3\n 0.2 | 3.5 | -4\n"
        "(3 rows)\n",
    ),
    "whitespace": (" ", ".", "t      x      y\n0      1.5    -2\n0.1    2.5    -3\n0.2 3.5 -4\n"),
    "whitespace-comma": (" ", ",", "t  x  y\n0  1,5  -2\n0,1  2,5  -3\n0,2  3,5  -4\n"),
}


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_every_layout_reads_the_same_table(tmp_path, layout: str) -> None:
    delim, decimal, text = LAYOUTS[layout]
    table = read_table(write(tmp_path / "run.txt", text))
    assert (table.delimiter, table.decimal) == (delim, decimal)
    assert table.names == ("t", "x", "y") and table.has_header
    np.testing.assert_allclose(table.data, [[0, 1.5, -2], [0.1, 2.5, -3], [0.2, 3.5, -4]])
    assert table.kind == "text" and table.n_rows == 3
    assert table.lines[0] == (3 if layout in ("markdown", "psql") else 2)


def test_a_header_with_spaces_inside_names_in_a_whitespace_aligned_file(tmp_path) -> None:
    text = "time    x pos [mm]    y pos [mm]\n0.00    1.0    2.0\n0.05    1.5    2.5\n"
    text += "0.10    2.0    3.0\n"
    table = read_table(write(tmp_path / "aligned.txt", text))
    assert table.delimiter == " "
    assert table.names == ("time", "x pos [mm]", "y pos [mm]")
    np.testing.assert_allclose(table.column("y pos [mm]"), [2.0, 2.5, 3.0])


def test_title_preamble_comments_and_blank_lines_are_skipped(tmp_path) -> None:
    text = (
        "Robot log 2023-05-01 (firmware 1.2)\n"
        "operator: Ada\n"
        "# columns below\n"
        "\n"
        "time,enc_left,enc_right\n"
        "0,0,0\n"
        "# paused\n"
        "\n"
        "0.05,3,4\n"
        "% another comment\n"
        "0.10,6,8\n"
    )
    table = read_table(write(tmp_path / "titled.csv", text))
    assert table.names == ("time", "enc_left", "enc_right")
    assert table.skipped == (
        "Robot log 2023-05-01 (firmware 1.2)",
        "operator: Ada",
        "# columns below",
    )
    assert table.lines.tolist() == [6, 9, 11]
    np.testing.assert_allclose(table.column("enc_right"), [0, 4, 8])


def test_a_rostopic_header_starting_with_a_percent_sign_is_the_header(tmp_path) -> None:
    text = "%time,field.header.stamp,field.x\n1690000000000000000,1690000000000000000,1\n"
    text += "1690000000050000000,1690000000050000000,2\n1690000000100000000,1690000000100000000,3\n"
    table = read_table(write(tmp_path / "echo.csv", text))
    assert table.names == ("%time", "field.header.stamp", "field.x")
    assert table.index("%time") == 0


def test_a_file_without_header_names_its_columns_by_index(tmp_path) -> None:
    table = read_table(write(tmp_path / "bare.csv", "0,0,0\n0.05,1,2\n0.1,2,3\n"))
    assert not table.has_header and table.names == ("0", "1", "2")
    assert table.index(2) == table.index("2") == 2 and table.lines.tolist() == [1, 2, 3]
    with pytest.raises(LogError, match=r"no header row; its columns are '0', '1', '2'"):
        table.index("x")


def test_trailing_delimiters_do_not_make_a_column(tmp_path) -> None:
    table = read_table(write(tmp_path / "trail.csv", "t;x;\n0;1;\n1;2;\n2;3;\n"))
    assert table.names == ("t", "x") and table.data.shape == (3, 2)


# --------------------------------------------------------------------------- arguments
def test_forced_arguments_are_checked_and_used(tmp_path) -> None:
    path = write(tmp_path / "run.txt", "t\tx\n0\t1,5\n1\t2,5\n2\t3,5\n")
    table = read_table(path, delimiter="tab", decimal=",")
    np.testing.assert_allclose(table.column("x"), [1.5, 2.5, 3.5])
    with pytest.raises(ValueError, match=r"delimiter \(--delimiter\) must be one of .*got ':'"):
        read_table(path, delimiter=":")
    with pytest.raises(ValueError, match=r"decimal \(--decimal\) must be '\.' or ',', got ';'"):
        read_table(path, decimal=";")
    with pytest.raises(ValueError, match=r"decimal=',' with delimiter=','.*ambiguous"):
        read_table(path, delimiter=",", decimal=",")
    # a forced '.' decimal leaves decimal-comma cells as text, named per column
    table = read_table(path, decimal=".")
    assert np.isnan(table.column("x")).all() and table.text_columns["x"] == (2, "1,5")


# --------------------------------------------------------------------------- bad rows
def test_a_row_with_the_wrong_field_count_names_file_line_and_counts(tmp_path) -> None:
    path = write(tmp_path / "bad.csv", "t,x,y\n0,1,2\n1,2\n2,3,4\n3,4,5\n4,5,6\n")
    with pytest.raises(
        LogError, match=r"bad\.csv, line 3: 2 fields \(comma-separated\) but the header has 3"
    ):
        read_table(path)
    path = write(tmp_path / "commas.csv", "t,x\n0,1\n1,2\n2,3\n3,4,5\n")
    with pytest.raises(LogError, match=r"line 5: 3 field.*decimal commas in a comma-separated"):
        read_table(path)


def test_an_empty_cell_in_a_whitespace_aligned_file_is_explained(tmp_path) -> None:
    text = "t    x    y\n0    1    2\n1         3\n2    3    4\n3    4    5\n4    5    6\n"
    with pytest.raises(
        LogError, match=r"line 3: 2 field.*empty cell shifts the columns.*delimiter"
    ):
        read_table(write(tmp_path / "gap.txt", text))


def test_a_file_cut_off_mid_write_is_refused(tmp_path) -> None:
    rows = "".join(f"{k * 0.05:.2f},{1000 + k},{2000 + k}\n" for k in range(30))
    path = write(tmp_path / "cut.csv", "t,a,b\n" + rows + "1.50,103")
    with pytest.raises(LogError, match=r"line 32: 2 field.*no newline: the file looks cut off"):
        read_table(path)
    path = write(tmp_path / "cut2.csv", "t,a,b\n" + rows + "1.50,1030,20")
    with pytest.raises(LogError, match=r"line 32: the last line .* narrower .*cut off mid-write"):
        read_table(path)
    complete = read_table(write(tmp_path / "ok.csv", "t,a,b\n" + rows + "1.50,1030,2030"))
    assert complete.n_rows == 31


# --------------------------------------------------------------------------- cells
def test_missing_cells_dates_and_text(tmp_path) -> None:
    text = (
        "stamp,x,mode\n"
        "2023-05-01T12:00:00.125,1,auto\n"
        "2023-05-01 12:00:00.250Z,,manual\n"
        "2023-05-01T14:00:00.375+02:00,nan,auto\n"
        "2023-05-01T12:00:00.500,NA,auto\n"
        "2023-05-01T12:00:00.625,null,\n"
    )
    table = read_table(write(tmp_path / "cells.csv", text))
    t0 = datetime(2023, 5, 1, 12, tzinfo=timezone.utc).timestamp()
    np.testing.assert_allclose(table.column("stamp") - t0, [0.125, 0.25, 0.375, 0.5, 0.625])
    assert np.isfinite(table.column("x")).tolist() == [True, False, False, False, False]
    assert table.text_columns == {"mode": (2, "auto")}
    assert np.isnan(table.column("mode")).all()
    with pytest.raises(ValueError, match="read-only"):
        table.data[0, 0] = 1.0


def test_index_errors_name_the_close_matches_and_the_header(tmp_path) -> None:
    table = read_table(write(tmp_path / "run.csv", "time,enc_left,enc_right\n0,1,2\n1,2,3\n"))
    assert table.index(" enc_left") == 1 and table.index("2") == 2
    with pytest.raises(LogError, match=r"no column 'Time' \(did you mean 'time'\?\)"):
        table.index("Time")
    with pytest.raises(LogError, match=r"run\.csv: no column 'enc_lft' \(did you mean 'enc_left'"):
        table.index("enc_lft")
    with pytest.raises(LogError, match=r"column index 5 is out of range.*3 column\(s\), 0\.\.2"):
        table.index(5)
    with pytest.raises(ValueError, match="do not match"):
        Table(Path("x"), ("a",), np.zeros((2, 2)), np.arange(2), "text", ",", ".")


def test_byte_order_mark_and_latin1(tmp_path) -> None:
    bom = read_table(write(tmp_path / "bom.csv", "\ufefftime,x\n0,1\n1,2\n", "utf-8"))
    assert bom.names == ("time", "x")
    latin = read_table(write(tmp_path / "latin.csv", "time;yaw [°]\n0;1,5\n1;2,5\n", "latin-1"))
    assert latin.names == ("time", "yaw [°]") and latin.decimal == ","


# --------------------------------------------------------------------------- limits, kinds
def test_limits_are_checked_before_reading(tmp_path) -> None:
    path = write(tmp_path / "run.csv", "t,x\n" + "".join(f"{k},{k}\n" for k in range(100)))
    with pytest.raises(LogError, match=r"MB is more than the .* MB.*REALITYGAP_MAX_FILE_MB"):
        read_table(path, limits=ResourceLimits(max_file_bytes=100))
    with pytest.raises(LogError, match=r"100 rows × 2 columns.*REALITYGAP_MAX_CELLS"):
        read_table(path, limits=ResourceLimits(max_cells=50))


def test_content_that_is_no_table(tmp_path) -> None:
    with pytest.raises(FileNotFoundError):
        read_table(tmp_path / "absent.csv")
    with pytest.raises(LogError, match="an empty file"):
        read_table(write(tmp_path / "empty.csv", ""))
    (tmp_path / "blob.bin").write_bytes(bytes(range(256)) * 4)
    with pytest.raises(LogError, match="not a table file"):
        read_table(tmp_path / "blob.bin")
    with pytest.raises(LogError, match="no line of numbers"):
        read_table(write(tmp_path / "words.txt", "hello world\nthis is prose\n"))


# --------------------------------------------------------------------------- binary formats
def test_mat_vectors_matrices_structs_and_lengths(tmp_path) -> None:
    scipy_io = pytest.importorskip("scipy.io")
    n = 50
    t = np.arange(n) * 0.02
    scipy_io.savemat(
        tmp_path / "run.mat",
        {
            "t": t,
            "enc": np.column_stack([np.arange(n), 2 * np.arange(n)]),
            "pose": {"x": np.linspace(0, 1, n), "y": np.zeros(n), "name": "robot"},
            "slow": np.arange(10.0),
            "poses": np.zeros((n, 4, 4)),
            "gain": 3.0,
        },
    )
    table = read_table(tmp_path / "run.mat")
    assert table.kind == "mat" and table.delimiter is None and table.n_rows == n
    assert set(table.names) == {"t", "enc[0]", "enc[1]", "pose.x", "pose.y"}
    np.testing.assert_allclose(table.column("enc[1]"), 2 * np.arange(n))
    np.testing.assert_allclose(table.column("t"), t)
    notes = " | ".join(table.skipped)
    assert "slow (10 rows) not read: its length differs from the 50 rows" in notes
    assert "poses (50×4×4) not read: a 3-D array" in notes and "gain not read: a single" in notes
    assert "pose.name not read: text" in notes
    assert table.lines.tolist() == list(range(1, n + 1))


def test_mat_v73_is_refused_with_the_fix(tmp_path) -> None:
    head = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon May  1 12:00:00 2023 HDF5"
    head = head.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"
    (tmp_path / "big.mat").write_bytes(head + b"\x89HDF\r\n\x1a\n" + b"\x00" * 512)
    with pytest.raises(LogError, match=r"v7\.3 file \(HDF5\).*'-v7'.*export CSV"):
        read_table(tmp_path / "big.mat")


def test_npz_arrays_and_the_refusals(tmp_path) -> None:
    n = 20
    np.savez(tmp_path / "arm.npz", q=np.ones((n, 6)), tool_x=np.arange(n), meta=np.arange(3))
    table = read_table(tmp_path / "arm.npz")
    assert table.kind == "npz" and table.n_rows == n
    assert table.names[:6] == tuple(f"q[{j}]" for j in range(6)) and "tool_x" in table.names
    assert any("meta (3 rows) not read" in s for s in table.skipped)
    log = Log(t=np.arange(5.0), channels={"cmd": np.zeros((5, 2))}, meta={"robot": "diffdrive"})
    log.save(tmp_path / "log.npz")
    with pytest.raises(LogError, match=r"a saved realitygap log.*read_logs"):
        read_table(tmp_path / "log.npz")
    np.savez(tmp_path / "pickled.npz", obj=np.array([{"a": 1}], dtype=object))
    with pytest.raises(LogError, match="pickled Python objects"):
        read_table(tmp_path / "pickled.npz")


def test_a_multi_rate_file_keeps_its_empty_cells(tmp_path) -> None:
    text = "t,enc,x\n0.00,0,\n0.01,,5.0\n0.02,3,\n0.03,,5.5\n0.04,6,\n"
    table = read_table(write(tmp_path / "multi.csv", text))
    assert np.isfinite(table.data).sum(axis=0).tolist() == [5, 3, 2]
    assert math.isnan(table.column("x")[0]) and table.column("enc")[2] == 3


def test_a_short_last_number_without_newline_is_no_cut_off_line(tmp_path) -> None:
    # a 4×4 transform whose last line is '0. 0. 0. 1.' and has no newline: too few lines to
    # tell a short number from a cut, so it is read
    path = tmp_path / "T.txt"
    path.write_text(
        "-0.0008 0.99 -0. -0.\n-0.99 -0.0008 -0.0008 0.0868\n"
        "-0.0008 -0.0000006 0.99 -108.99996544\n0. 0. 0. 1."
    )
    table = read_table(path)
    assert table.n_rows == 4 and table.data[3, 3] == 1.0
