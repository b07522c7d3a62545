"""The command line and the experiment registry."""

from __future__ import annotations

import json
import re

import pytest

from realitygap import cli, experiments
from realitygap.core.io import write_json


def test_list_shows_envs_experiments_and_effects(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["list"]) == 0
    out = capsys.readouterr().out
    assert "realitygap/WheeledNav-v0" in out
    assert "nav8" in out and "bench-speed" in out
    assert "wheel_diameter_ratio" in out


def test_unknown_experiment_suggests_the_close_name(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", "nav88"]) == 2
    assert "nav8" in capsys.readouterr().err


def test_run_writes_json_atomically(
    tmp_path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))

    @experiments.experiment("unit-test-exp", "a tiny experiment for the tests")
    def _tiny(ctx: experiments.RunContext) -> dict:
        return {"figures": {"answer": 42.0, "seed": ctx.seed}, "config": {"k": 1}}

    try:
        out = tmp_path / "sub" / "r.json"
        report = tmp_path / "report"
        argv = ["run", "unit-test-exp", "--seed", "7", "--json", str(out), "--report", str(report)]
        assert cli.main([*argv, "--silent"]) == 0
        assert "makes no diagnosis, so --report wrote nothing" in capsys.readouterr().out
        assert not report.exists()
        data = json.loads(out.read_text())
        assert data["experiment"] == "unit-test-exp"
        assert data["figures"] == {"answer": 42.0, "seed": 7}
        assert data["config"]["k"] == 1 and data["config"]["seed"] == 7
        assert [p.name for p in out.parent.iterdir()] == ["r.json"]  # no temporary left behind
        # the next run of the same experiment knows how long the last one took
        times = json.loads((tmp_path / "cache" / "realitygap" / "run-times.json").read_text())
        assert len(times) == 1 and next(iter(times.values())) >= 0.0
    finally:
        experiments.EXPERIMENTS.pop("unit-test-exp", None)


def test_failed_write_leaves_nothing(tmp_path) -> None:
    target = tmp_path / "x.json"
    with pytest.raises(TypeError):
        write_json(target, {"bad": object()})
    assert list(tmp_path.iterdir()) == []


def test_robot_option_only_for_experiments_that_take_it(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert cli.main(["run", "nav8", "--robot", "arm"]) == 2
    assert "takes no --robot option" in capsys.readouterr().err
    assert cli.main(["run", "diagnose-suite", "--robot", "tank"]) == 2
    err = capsys.readouterr().err
    assert "diffdrive" in err and "climber" in err and "'tank'" in err


def test_every_command_is_described_and_every_option_helped() -> None:
    import argparse

    parser = cli.build_parser()
    assert "``" not in parser.format_help()
    subs = cli._subparsers(parser)
    assert {"list", "run", "sample", "diagnose", "benchmark", "train", "calibrate"} <= {
        s.prog.split()[-1] for s in subs
    }
    for sub in subs:
        assert sub.description, f"{sub.prog} has no description"
        text = sub.format_help()
        assert "``" not in text and ":func:" not in text, sub.prog
        options = sub._option_string_actions
        assert "--quiet" in options and "--verbose" in options, sub.prog
        for action in sub._actions:
            assert action.help is not None, f"{sub.prog} {action.option_strings or action.dest}"
            if action.help is not argparse.SUPPRESS:
                assert action.help.strip(), f"{sub.prog} {action.option_strings}"
    diagnose = next(s for s in subs if s.prog.endswith("diagnose"))
    assert "climber" in diagnose._option_string_actions["--robot"].help


@pytest.mark.slow
def test_no_pybullet_banner_on_any_stream(tmp_path) -> None:
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-c", "from realitygap.cli import main; main(['list', '--quiet'])"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert "pybullet build time" not in done.stdout + done.stderr
    assert "wheel_diameter_ratio" in done.stdout


def test_embedded_sample_stands_in_without_a_data_folder(tmp_path, monkeypatch) -> None:
    import os

    from realitygap import samples

    archive = samples._archive("optiodom_diffdrive")
    assert archive.stat().st_size <= 3 * 2**20
    assert (archive.parent / "LICENSE-optiodom_diffdrive").read_text().startswith("MIT License")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    ctx = experiments.RunContext(data_dir=None, verbose=False)
    folder = ctx.data_subdir("optiodom_diffdrive")
    assert folder.is_relative_to(tmp_path / "cache")
    assert sorted(os.listdir(folder)) == ["LICENSE", "circular", "square"]
    assert len(os.listdir(folder / "square")) == 2
    assert "embedded OptiOdom sample" in ctx.data_used["optiodom_diffdrive"]
    assert ctx.data_subdir("optiodom_diffdrive") == folder  # unpacked once
    with pytest.raises(FileNotFoundError, match="no data folder was found: pass --data DIR"):
        ctx.data_subdir("ipa_ur10_lasertracker")
    with pytest.raises(KeyError, match="no embedded sample named 'nope'"):
        samples.sample_dir("nope")
    full = experiments.RunContext(data_dir=tmp_path, verbose=False)
    (tmp_path / "optiodom_diffdrive").mkdir()
    assert full.data_subdir("optiodom_diffdrive") == tmp_path / "optiodom_diffdrive"
    assert full.data_used == {"optiodom_diffdrive": str(tmp_path / "optiodom_diffdrive")}


def test_sample_command_prints_the_folder(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cli.main(["sample"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.endswith("optiodom_diffdrive") and out.startswith(str(tmp_path))
    assert cli.main(["sample", "nope"]) == 2
    assert "embedded samples: optiodom_diffdrive" in capsys.readouterr().err


def test_progress_shows_the_time_left_once_an_experiment_states_its_duration(
    tmp_path, capsys, monkeypatch
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))

    @experiments.experiment("unit-test-eta", "states its duration")
    def _eta(ctx: experiments.RunContext) -> dict:
        ctx.progress("before")
        ctx.expect(150.0)
        ctx.progress("after")
        return {"figures": {"expected_s": ctx.expected_s}}

    try:
        assert cli.main(["run", "unit-test-eta"]) == 0
        err = capsys.readouterr().err
        assert re.search(r"^\[0:00\] before$", err, flags=re.M)
        assert "this run takes roughly 2 min" in err
        assert re.search(r"^\[0:00, about 2 min left\] after$", err, flags=re.M)
    finally:
        experiments.EXPERIMENTS.pop("unit-test-eta", None)


def test_indented_detail_lines_only_with_verbose(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))

    @experiments.experiment("unit-test-details", "says a detail")
    def _details(ctx: experiments.RunContext) -> dict:
        ctx.progress("headline")
        ctx.progress("  detail")
        return {"figures": {}}

    try:
        assert cli.main(["run", "unit-test-details"]) == 0
        err = capsys.readouterr().err
        assert "headline" in err and "detail\n" not in err.replace("headline", "")
        assert cli.main(["run", "unit-test-details", "--verbose"]) == 0
        assert "  detail" in capsys.readouterr().err
        assert cli.main(["run", "unit-test-details", "--quiet"]) == 0
        assert capsys.readouterr().err == ""
    finally:
        experiments.EXPERIMENTS.pop("unit-test-details", None)
