"""``realitygap diagnose``: end to end on saved logs, and clean refusals on bad input."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from realitygap.core.parallel import ProcessBackend, RayBackend
from realitygap.diagnosis.adapters.diffdrive.manoeuvres import Manoeuvre
from realitygap.diagnosis.adapters.diffdrive.replay import simulate
from realitygap.diagnosis.cli import main
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import Reality, make_effect
from realitygap.robots.simulation import MeasurementNoise

P = DiffDriveParams()
TURNS = Manoeuvre(
    "turns",
    "turns both ways and straight legs",
    ((3.0, 0.3, 0.0), (2.0, 0.0, 1.2), (0.5, 0, 0), (2.0, 0.0, -1.2), (3.0, 0.3, 0.0), (0.5, 0, 0)),
)
LOOP = Manoeuvre(
    "loop",
    "a loop",
    ((3.0, 0.3, 0.0), (1.5, 0.0, 1.0), (3.0, 0.25, 0.0), (1.5, 0.0, -1.0), (3.0, 0.3, 0.5)),
)


@pytest.fixture(scope="module")
def saved_logs(tmp_path_factory):
    rng = np.random.default_rng(5)
    reality = Reality((make_effect("wheelbase_error", E_b=0.95),))
    out = tmp_path_factory.mktemp("logs")
    paths = []
    for man in (TURNS, LOOP):
        t, cmd = man.applied(0.05, P)
        log = simulate(
            t,
            params=P,
            reality=reality,
            commands=cmd,
            noise=MeasurementNoise(0.0005, 0.001, 0.001, 0.002),
            rng=rng,
            meta={"name": man.name},
        )
        paths.append(str(log.save(out / f"{man.name}.npz")))
    return paths


@pytest.mark.slow
def test_diagnose_writes_report_and_json(saved_logs, tmp_path, capsys) -> None:
    report, js = tmp_path / "report", tmp_path / "out" / "d.json"
    rc = main(
        [
            "diagnose",
            saved_logs[0],
            "--holdout",
            saved_logs[1],
            "--effects",
            "wheelbase_error,wheel_radius_scale,encoder_scale",
            "--report",
            str(report),
            "--json",
            str(js),
            "--export",
            str(tmp_path / "twin.json"),
            "--backend",
            "serial",
            "--quiet",
        ]
    )
    assert rc == 0
    data = json.loads(js.read_text())
    # the exported reality is the robot found, and the env simulates it
    import gymnasium as gym

    from realitygap.robots.effects import Twin

    twin = Twin.load(tmp_path / "twin.json")
    fitted = {e.name: e.values for e in twin.reality.effects}
    assert fitted["wheelbase_error"]["E_b"] == pytest.approx(0.95, abs=0.005)
    assert twin.stderr["wheelbase_error.E_b"] > 0
    env = gym.make("realitygap/WheeledNav-v0", reality=str(tmp_path / "twin.json"))
    assert env.unwrapped.true_params.wheelbase == pytest.approx(0.95 * P.wheelbase, rel=0.006)
    env.close()
    assert data["verdict"] == ["wheelbase_error"]
    first = data["ranking"][0]
    assert first["name"] == "wheelbase_error"
    assert first["params"]["wheelbase_error.E_b"]["value"] == pytest.approx(0.95, abs=0.005)
    assert first["heldout_shrink_pct"] > 50
    text = (report / "report.md").read_text()
    assert "## Verdict" in text and "wheelbase_error" in text and "## Where the gap is" in text
    for fig in ("trajectories.png", "residuals.png", "ranking.png"):
        assert (report / fig).is_file()
    out = capsys.readouterr().out
    assert "Verdict: wheelbase_error" in out and out.index("Compared") < out.index("candidates by")
    assert (report / "report.html").is_file() and (report / "diagnosis.json").is_file()


def test_bad_input_is_refused_and_nothing_is_written(saved_logs, tmp_path, capsys) -> None:
    csv = tmp_path / "run.csv"
    csv.write_text("t,v\n0,1\n0.05,1\n0.1,1\n")
    report, js = tmp_path / "report", tmp_path / "d.json"
    rc = main(["diagnose", str(csv), "--report", str(report), "--json", str(js), "--quiet"])
    assert rc == 2
    assert "needs a column map" in capsys.readouterr().err
    assert not report.exists() and not js.exists()
    rc = main(
        ["diagnose", saved_logs[0], "--effects", "wheelbase_eror", "--json", str(js), "--quiet"]
    )
    assert rc == 2
    assert "did you mean 'wheelbase_error'" in capsys.readouterr().err
    assert not js.exists()
    # a CSV that lacks the ground truth: the channel and the fix are named
    rc = main(
        ["diagnose", str(csv), "--columns", "t=t,cmd.v=v,cmd.w=!v", "--json", str(js), "--quiet"]
    )
    assert rc == 2
    err = capsys.readouterr().err
    assert "missing channel(s) 'pose_gt'" in err and "Fix" in err
    assert not js.exists()


def test_jittery_log_is_refused_with_the_resample_fix(saved_logs, tmp_path, capsys) -> None:
    from realitygap.diagnosis.logs.log import Log

    log = Log.load(saved_logs[0])
    rng = np.random.default_rng(0)
    t = log.t + rng.uniform(-0.02, 0.02, log.n) * (np.arange(log.n) % 2)
    jittery = log.replace(t=t).save(tmp_path / "jitter.npz")
    js = tmp_path / "d.json"
    assert main(["diagnose", str(jittery), "--json", str(js), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "jitter.npz" in err
    assert "time stamps are irregular" in err and "--resample" in err
    assert not js.exists()
    # the suggested fix works
    rc = main(
        [
            "diagnose",
            str(jittery),
            "--resample",
            "0.05",
            "--effects",
            "wheelbase_error",
            "--json",
            str(js),
            "--backend",
            "serial",
            "--quiet",
        ]
    )
    assert rc == 0 and js.is_file()


@pytest.mark.slow
def test_ray_backend_is_optional() -> None:
    try:
        import ray  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match=r"pip install 'realitygap\[ray\]'"):
            RayBackend()
    else:  # pragma: no cover - only where ray is installed
        assert RayBackend().map(_square, [1, 2], None) == [1, 4]


def _square(shared, x):
    return x * x


def test_process_backend_maps_in_order() -> None:
    assert ProcessBackend(2).map(_square, [3, 1, 2], None) == [9, 1, 4]


def test_diagnose_warns_before_it_starts_and_prints_without_output_options(
    saved_logs, capsys
) -> None:
    rc = main(
        [
            "diagnose",
            *saved_logs,
            "--effects",
            "wheelbase_error,encoder_scale",
            "--backend",
            "serial",
            "--quick",
        ]
    )
    assert rc == 0
    captured = capsys.readouterr()
    assert "warning: no --holdout: holding out the last 1 of 2 logs (loop)" in captured.err
    assert "2 candidate effect(s) on 1 worker(s)" in captured.err
    # the estimate comes from the replays and the surrogate measured in the run
    assert re.search(
        r"measured: a PyBullet replay of the logs [\d.]+ s, .*estimate: about", captured.err
    )
    assert re.search(r"^\[0:\d\d, .* left\]", captured.err, flags=re.M)  # elapsed and time left
    out = captured.out
    assert out.startswith("Compared 1 recorded training run(s) and 1 held-out run(s)")
    assert "Verdict: wheelbase_error" in out and "report:" not in out


def test_missing_holdout_path_is_named_before_anything_runs(saved_logs, tmp_path, capsys) -> None:
    rc = main(["diagnose", saved_logs[0], "--holdout", str(tmp_path / "nope"), "--quiet"])
    assert rc == 2
    assert "no such file or folder" in capsys.readouterr().err
