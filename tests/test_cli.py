"""The command line and the experiment registry."""

from __future__ import annotations

import json

import pytest

from realitygap import cli, experiments


def test_list_shows_envs_experiments_and_effects(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["list"]) == 0
    out = capsys.readouterr().out
    assert "realitygap/WheeledNav-v0" in out
    assert "nav8" in out and "bench-speed" in out
    assert "wheel_diameter_ratio" in out


def test_unknown_experiment_suggests_the_close_name(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", "nav88"]) == 2
    assert "nav8" in capsys.readouterr().err


def test_run_writes_json_atomically(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    @experiments.experiment("unit-test-exp", "a tiny experiment for the tests")
    def _tiny(ctx: experiments.RunContext) -> dict:
        return {"figures": {"answer": 42.0, "seed": ctx.seed}, "config": {"k": 1}}

    try:
        out = tmp_path / "sub" / "r.json"
        assert (
            cli.main(["run", "unit-test-exp", "--seed", "7", "--json", str(out), "--silent"]) == 0
        )
        data = json.loads(out.read_text())
        assert data["experiment"] == "unit-test-exp"
        assert data["figures"] == {"answer": 42.0, "seed": 7}
        assert data["config"]["k"] == 1 and data["config"]["seed"] == 7
        assert [p.name for p in out.parent.iterdir()] == ["r.json"]  # no temporary left behind
    finally:
        experiments.EXPERIMENTS.pop("unit-test-exp", None)


def test_failed_write_leaves_nothing(tmp_path) -> None:
    target = tmp_path / "x.json"
    with pytest.raises(TypeError):
        experiments.write_json_atomic(target, {"bad": object()})
    assert list(tmp_path.iterdir()) == []


def test_robot_option_only_for_experiments_that_take_it(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert cli.main(["run", "nav8", "--robot", "arm"]) == 2
    assert "takes no --robot option" in capsys.readouterr().err
    assert cli.main(["run", "diagnose-suite", "--robot", "tank"]) == 2
    err = capsys.readouterr().err
    assert "diffdrive" in err and "climber" in err and "'tank'" in err
