"""An experiment's figures reach its report folder (``RunContext.add_plot``)."""

from __future__ import annotations

import pytest

from realitygap.experiments import RunContext, _write_plots


def test_plots_are_written_with_a_markdown_report(tmp_path) -> None:  # type: ignore[no-untyped-def]
    ctx = RunContext()
    ctx.add_plot("a.png", b"\x89PNG fake")
    result = {
        "experiment": "x",
        "figures": {"success_pct": 97.0},
        "tables": {"cells": [{"robot": "r1", "success_pct": 91.23456}], "empty": []},
    }
    report = _write_plots("x", "what x measures", result, ctx, tmp_path / "out")
    assert report == tmp_path / "out" / "report.md"
    assert (tmp_path / "out" / "a.png").read_bytes() == b"\x89PNG fake"
    text = report.read_text()
    assert "![a.png](a.png)" in text and "| r1 | 91.2 |" in text and "## empty" not in text
    assert "success_pct" in text


@pytest.mark.parametrize("name", ["a.jpg", "sub/a.png", "a.png"])
def test_a_plot_needs_a_new_png_file_name(name: str) -> None:
    ctx = RunContext()
    ctx.add_plot("a.png", b"")
    with pytest.raises(ValueError, match=r"\.png"):
        ctx.add_plot(name, b"")


def test_a_long_table_is_cut_in_the_report_not_in_the_result(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from realitygap.experiments import REPORT_TABLE_ROWS

    rows = [{"seed": k} for k in range(REPORT_TABLE_ROWS + 5)]
    result = {"experiment": "x", "figures": {}, "tables": {"episodes": rows}}
    text = _write_plots("x", "d", result, RunContext(), tmp_path).read_text()
    assert f"| {REPORT_TABLE_ROWS - 1} |" in text and f"| {REPORT_TABLE_ROWS} |" not in text
    assert "5 more rows in the JSON" in text
    assert len(result["tables"]["episodes"]) == REPORT_TABLE_ROWS + 5
