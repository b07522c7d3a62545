"""Bad logs, files and options: each is refused with a message naming it, and nothing is lost."""

from __future__ import annotations

import argparse
import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from realitygap.core.checks import (
    check_disjoint,
    check_finite_float,
    check_int,
    check_output_path,
    parse_json_option,
)
from realitygap.diagnosis.cli import main
from realitygap.diagnosis.logs.importers.csv_log import read_csv_log, regularise_rounded_time
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.diagnosis.logs.read import ReadOptions, check_plausible, read_logs, resample_split

CSV_MAP = "t=time:s,cmd.v=v,cmd.w=w,pose_gt.x=x,pose_gt.y=y,pose_gt.theta=yaw"


def drive_log(n: int = 200, dt: float = 0.05, gap_at: int | None = None, gap: float = 0.0) -> Log:
    t = dt * np.arange(n)
    if gap_at is not None:
        t[gap_at:] += gap
    x = 0.2 * dt * np.arange(n)
    return Log(
        t=t,
        channels={
            "cmd": np.column_stack([np.full(n, 0.2), np.zeros(n)]),
            "pose_gt": np.column_stack([x, np.zeros(n), np.zeros(n)]),
        },
        meta={"robot": "diffdrive", "name": "drive"},
        source="drive.npz",
    )


def write_csv(path: Path, n: int = 100, t_fmt: str = "{:.4f}", t_scale: float = 1.0) -> Path:
    rows = ["time,v,w,x,y,yaw"]
    for k in range(n):
        rows.append(f"{t_fmt.format(t_scale * k / 30)},0.2,0,{0.2 * k / 30:.5f},0,0.000")
    path.write_text("\n".join(rows) + "\n")
    return path


# --------------------------------------------------------------------------- core checks
def test_checks_name_argument_value_and_range() -> None:
    with pytest.raises(ValueError, match=r"budget must be a positive integer, got 0"):
        check_int(0, "budget", low=1, what="a positive integer")
    with pytest.raises(TypeError, match=r"n must be an integer in \[0, 5\], got 'a' \(str\)"):
        check_int("a", "n", low=0, high=5)
    with pytest.raises(ValueError, match=r"tol must be a finite number > 0 m, got nan"):
        check_finite_float(float("nan"), "tol", low=0.0, strict_low=True, unit="m")
    assert check_int(3.0, "n") == 3


def test_params_json_error_names_option_and_position() -> None:
    with pytest.raises(ValueError) as info:
        parse_json_option("{wheelbase: 1", "--params")
    msg = str(info.value)
    assert msg.startswith("--params: invalid JSON at line 1 column 2")
    assert "{wheelbase: 1\n   ^" in msg


def test_output_path_checks(tmp_path: Path) -> None:
    log = tmp_path / "a.npz"
    log.write_bytes(b"x")
    with pytest.raises(ValueError, match=r"--json .*a\.npz is the input .*overwrite an input"):
        check_output_path(log, "--json", inputs=[log])
    with pytest.raises(ValueError, match=r"lies inside the input"):
        check_output_path(tmp_path / "out.json", "--json", inputs=[tmp_path])
    with pytest.raises(ValueError, match=r"is an existing folder, but a file path is expected"):
        check_output_path(tmp_path, "--json")
    with pytest.raises(ValueError, match=r"is an existing file, but a folder is expected"):
        check_output_path(log, "--report", folder=True)
    with pytest.raises(ValueError, match=r"a\.npz is a file, so no folder can be made under it"):
        check_output_path(log / "sub" / "d.json", "--json")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(stat.S_IRUSR | stat.S_IXUSR)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("running with permissions that ignore a read-only folder")
        with pytest.raises(ValueError, match=r"not writable"):
            check_output_path(ro / "d.json", "--json")
    finally:
        ro.chmod(stat.S_IRWXU)


def test_train_and_holdout_overlap_is_refused(tmp_path: Path) -> None:
    (tmp_path / "s").mkdir()
    with pytest.raises(ValueError, match=r"training LOG and as --holdout .*s and .*s"):
        check_disjoint([tmp_path / "s"], [tmp_path / "s"])
    with pytest.raises(ValueError, match=r"held-out score"):
        check_disjoint([tmp_path], [tmp_path / "s"])
    check_disjoint([tmp_path / "s"], [tmp_path / "t"])


# --------------------------------------------------------------------------- the CLI
def test_cli_refuses_output_over_input_before_reading(tmp_path: Path, capsys) -> None:
    log = drive_log().save(tmp_path / "in.npz")
    before = log.read_bytes()
    rc = main(["diagnose", str(log), "--json", str(log), "--quiet"])
    assert rc == 2 and log.read_bytes() == before
    assert "overwrite an input" in capsys.readouterr().err
    rc = main(["diagnose", str(log), "--holdout", str(log), "--json", str(tmp_path / "d.json")])
    assert rc == 2 and "--holdout" in capsys.readouterr().err
    # the output is checked first: a missing log is not even read
    rc = main(["diagnose", str(tmp_path / "missing.npz"), "--json", str(tmp_path), "--quiet"])
    assert rc == 2 and "is an existing folder" in capsys.readouterr().err
    rc = main(
        ["diagnose", str(log), "--json", str(tmp_path / "d.json"), "--params", "{wheelbase: 1"]
    )
    assert rc == 2 and "--params: invalid JSON at line 1 column 2" in capsys.readouterr().err
    rc = main(["diagnose", str(log), "--json", str(tmp_path / "d.json"), "--resample", "-1"])
    assert rc == 2 and "(--resample) must be a finite number > 0 s" in capsys.readouterr().err
    assert not (tmp_path / "d.json").exists()


# --------------------------------------------------------------------------- logs
def test_resampling_splits_at_gaps_instead_of_inventing_rows() -> None:
    log = drive_log(n=200, gap_at=100, gap=600.0)
    said: list[str] = []
    pieces = resample_split(log, 0.05, said.append)
    assert [p.n for p in pieces] == [100, 100]
    assert "a gap of 600.05 s" in said[0] and "split" in said[0]
    assert pieces[1].name == "drive_part-2"
    with pytest.raises(LogError, match=r"--resample 1e-06: .* exceed the limit"):
        resample_split(drive_log(n=2000), 1e-6)


def test_implausible_units_are_refused_with_the_unit() -> None:
    log = drive_log()
    check_plausible(log)
    mm = log.with_channels(pose_gt=log["pose_gt"] * 1000.0)
    with pytest.raises(LogError, match=r"'pose_gt' moves at 200 m/s .*x:mm"):
        check_plausible(mm)
    ms = log.replace(t=log.t * 1000.0)
    with pytest.raises(LogError, match=r"rows arrive at 0.02 Hz .*'t=time:ms'"):
        check_plausible(ms)
    tpr = 2000.0
    ticks = np.column_stack([log["pose_gt"][:, 0]] * 2) / (2 * np.pi * 0.035) * tpr
    params = {"wheel_radius_left": 0.035, "wheel_radius_right": 0.035, "ticks_per_rev": tpr}
    good = log.replace(meta={**log.meta, "params": params}).with_channels(ticks=ticks)
    check_plausible(good)
    with pytest.raises(LogError, match=r"wheels travelled 4 × the true path"):
        check_plausible(good.with_channels(ticks=4 * ticks))
    with pytest.raises(LogError, match=r"rev/min"):
        check_plausible(good.with_channels(ticks=3000 * ticks))


def test_a_fast_noisy_ground_truth_is_not_taken_for_a_unit_error() -> None:
    # 50 Hz rows, 0.1 m/s for 30 s, motion capture with 2.5 mm of noise per axis: row to
    # row the noise is larger than the motion, and summing rows would more than double the path
    rng = np.random.default_rng(4)
    t = 0.02 * np.arange(1500)
    x = 0.1 * t
    truth = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    noisy = truth + np.column_stack([rng.normal(0, 2.5e-3, (t.size, 2)), np.zeros(t.size)])
    tpr, r = 2000.0, 0.035
    ticks = np.column_stack([x, x]) / (2 * np.pi * r) * tpr
    params = {"wheel_radius_left": r, "wheel_radius_right": r, "ticks_per_rev": tpr}
    log = Log(
        t=t,
        channels={"pose_gt": noisy, "ticks": ticks},
        meta={"robot": "diffdrive", "name": "noisy", "params": params},
    )
    check_plausible(log)
    # a real unit error in the same log is still refused
    with pytest.raises(LogError, match=r"wheels travelled (3\.9\d|4) × the true path"):
        check_plausible(log.with_channels(ticks=4 * ticks))


def test_cut_last_line_is_flagged(tmp_path: Path) -> None:
    f = write_csv(tmp_path / "run.csv")
    text = f.read_text().rstrip("\n")
    f.write_text(text[:-3])  # "0.000" → "0.": cut inside its last field, no newline
    with pytest.raises(
        LogError, match=r"run\.csv, line \d+: the last line .* no newline .*cut off"
    ):
        read_csv_log(f, CSV_MAP)
    f.write_text(text)  # complete line, only the newline missing: fine
    assert read_csv_log(f, CSV_MAP).n == 100


def test_time_rounded_to_few_decimals_is_accepted(tmp_path: Path) -> None:
    f = write_csv(tmp_path / "run.csv", t_fmt="{:.3f}")
    log = read_csv_log(f, CSV_MAP)
    step = np.diff(log.t)
    assert np.ptp(step) < 1e-9 and step[0] == pytest.approx(1 / 30, abs=5e-4)
    assert "3 decimals" in log.meta["time_regularised"]
    jitter = 1 / 30 + np.random.default_rng(0).uniform(-0.004, 0.004, 100)
    t = np.cumsum(jitter)
    assert regularise_rounded_time(t, 1e-3)[1] is False  # real jitter is kept


def test_not_text_and_renamed_ur10_columns(tmp_path: Path) -> None:
    junk = tmp_path / "junk.csv"
    junk.write_bytes(bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8)))
    with pytest.raises(LogError, match=r"junk\.csv: the extension '\.csv' promises text"):
        read_logs(junk)
    ur = tmp_path / "m.csv"
    ur.write_text("Timestamp;Goal x;measurement_X;shoulder_pan_joint\n1;2;3;4\n")
    with pytest.raises(LogError, match=r"header .Timestamp;Goal x;measurement_X.*measurement_x"):
        read_logs(ur)


def test_csv_size_limit_is_stated(tmp_path: Path, monkeypatch) -> None:
    f = write_csv(tmp_path / "run.csv", n=2000)
    monkeypatch.setenv("REALITYGAP_MAX_CELLS", "1000")
    with pytest.raises(LogError, match=r"2000 rows × 6 columns .* REALITYGAP_MAX_CELLS"):
        read_csv_log(f, CSV_MAP)
    monkeypatch.setenv("REALITYGAP_MAX_FILE_MB", "0.01")
    with pytest.raises(LogError, match=r"REALITYGAP_MAX_FILE_MB"):
        read_csv_log(f, CSV_MAP)


def _rewrite_header(path: Path, edit) -> None:
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(bytes(arrays["meta.json"]))
    edit(header)
    arrays["meta.json"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    np.savez(path, **arrays)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda h: h.update(channels=["cmd"]), r"field 'channels' must be an object"),
        (lambda h: h["channels"]["cmd"].pop("columns"), r"channel 'cmd' has no 'columns'"),
        (lambda h: h["channels"]["cmd"].update(role="bogus"), r"role 'bogus' is not one of"),
        (lambda h: h.update(version="one"), r"field 'version' must be a whole number"),
        (lambda h: h.update(meta="robot"), r"field 'meta' must be an object, got str"),
    ],
)
def test_damaged_log_header_names_file_and_field(tmp_path: Path, edit, message: str) -> None:
    f = drive_log().save(tmp_path / "log.npz")
    _rewrite_header(f, edit)
    with pytest.raises(LogError, match=r"log\.npz: .*" + message):
        Log.load(f)


def test_truncated_log_archive(tmp_path: Path) -> None:
    f = drive_log().save(tmp_path / "log.npz")
    f.write_bytes(f.read_bytes()[:-200])
    with pytest.raises(LogError, match=r"log\.npz: unreadable or truncated log archive"):
        Log.load(f)


def test_saved_files_follow_the_umask(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        f = drive_log().save(tmp_path / "log.npz")
    finally:
        os.umask(old)
    assert stat.S_IMODE(f.stat().st_mode) == 0o644


def test_short_runs_are_named(tmp_path: Path) -> None:
    said: list[str] = []
    log = drive_log(n=40, gap_at=2, gap=100.0)
    pieces = resample_split(log, 0.05, said.append)
    assert len(pieces) == 1 and any("piece 1 (rows 0..1) dropped" in s for s in said)


def test_read_options_resample_reports_through_warn(tmp_path: Path) -> None:
    f = drive_log(n=200, gap_at=100, gap=600.0).save(tmp_path / "gap.npz")
    said: list[str] = []
    logs = read_logs(f, ReadOptions(resample=0.05), warn=said.append)
    assert len(logs) == 2 and "gap.npz: a gap of 600.05 s" in said[0]


# --------------------------------------------------------------------------- experiments and training
def test_negative_seed_is_refused() -> None:
    from realitygap import experiments

    with pytest.raises(ValueError, match=r"--seed must be a non-negative integer, got -5"):
        experiments.run("nav8", experiments.RunContext(seed=-5))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["benchmark", "--image-episodes", "-1"], "argument --image-episodes: expected a positive"),
        (
            ["train", "--timesteps", "0"],
            "argument --timesteps: expected a positive integer, got '0'",
        ),
        (["train", "--timesteps", "-100"], "argument --timesteps: expected a positive"),
        (["benchmark", "--seed", "-5"], "argument --seed: expected a non-negative integer"),
    ],
)
def test_training_and_benchmark_counts(argv: list[str], message: str, capsys) -> None:
    from realitygap.baselines.cli import add_benchmark_parser, add_train_parser

    parser = argparse.ArgumentParser(prog="realitygap")
    sub = parser.add_subparsers(dest="command", required=True)
    add_benchmark_parser(sub)
    add_train_parser(sub)
    with pytest.raises(SystemExit):
        parser.parse_args(argv)
    assert message in capsys.readouterr().err


def test_optiodom_run_cut_inside_its_last_field(tmp_path: Path) -> None:
    from realitygap.diagnosis.logs.importers.numeric_text import numeric_file

    cols = ("time", "x", "y", "theta", "ticks_right", "ticks_left")
    rows = [f"{0.05 * k:.2f},0.1,0.2,0.3,51,66" for k in range(30)]
    f = tmp_path / "s_run-01.csv"
    f.write_text("\n".join(rows)[:-1])  # "…,51,6" with no newline
    with pytest.raises(ValueError, match=r"s_run-01\.csv, line 30: .*ticks_left \('6'\).*cut off"):
        numeric_file(f, cols)
    f.write_text("\n".join(rows))  # complete, newline missing only
    assert numeric_file(f, cols)[-1, 5] == 66


def test_read_only_file_system_is_named(tmp_path: Path, monkeypatch) -> None:
    import realitygap.core.checks as checks

    class ReadOnly:
        f_flag = os.ST_RDONLY

    monkeypatch.setattr(checks.os, "statvfs", lambda path: ReadOnly())
    with pytest.raises(ValueError, match=r"--report .*not writable \(read-only file system"):
        check_output_path(tmp_path / "out", "--report", folder=True)


def test_gap_limit_can_be_raised(monkeypatch) -> None:
    log = drive_log(n=200, gap_at=100, gap=0.5)  # a 0.55 s gap: 11 steps of 0.05 s
    assert len(resample_split(log, 0.05)) == 2
    monkeypatch.setenv("REALITYGAP_MAX_GAP_STEPS", "20")
    assert [p.n for p in resample_split(log, 0.05)] == [210]


def test_ur10_file_with_a_renamed_column_names_it(tmp_path: Path) -> None:
    from realitygap.diagnosis.logs.importers.ur10 import REQUIRED_COLUMNS

    cols = ["Timestamp", *(c if c != "measurement_x" else "meas_x" for c in REQUIRED_COLUMNS)]
    f = tmp_path / "measurements_1.csv"
    f.write_text(";".join(cols) + "\n" + ";".join(["1"] * len(cols)) + "\n")
    with pytest.raises(
        LogError,
        match=r"measurements_1\.csv: looks like a UR10 .*lacks "
        r"'measurement_x' \(found 'meas_x'\)",
    ):
        read_logs(f)


def test_fifo_inside_a_session_folder_is_refused(tmp_path: Path) -> None:
    from realitygap.diagnosis.logs.importers.numeric_text import read_text_lines

    f = tmp_path / "s_run-01.csv"
    os.mkfifo(f)
    with pytest.raises(ValueError, match=r"s_run-01\.csv is a FIFO \(named pipe\), not a regular"):
        read_text_lines(f)


def test_plausibility_check_names_its_switch_and_can_be_switched_off(
    tmp_path: Path, capsys
) -> None:
    log = drive_log()
    mm = log.with_channels(pose_gt=log["pose_gt"] * 1000.0).save(tmp_path / "mm.npz")
    with pytest.raises(LogError, match=r"moves at 200 m/s .*--no-plausibility-check"):
        read_logs(mm, ReadOptions())
    (read,) = read_logs(mm, ReadOptions(check_plausible=False))
    np.testing.assert_array_equal(read["pose_gt"], log["pose_gt"] * 1000.0)
    # the command line refuses it before any work and names the switch
    rc = main(["diagnose", str(mm), "--json", str(tmp_path / "d.json"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "moves at 200 m/s" in err and "--no-plausibility-check" in err
    assert not (tmp_path / "d.json").exists()
