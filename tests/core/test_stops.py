"""Clean stops: Ctrl-C and SIGTERM sent to a real diagnosis with a worker pool.

A terminal's Ctrl-C reaches the whole process group (main process and workers); a
``kill PID`` reaches the main process only. Either way the run must print one line and no
traceback, exit with 128 + the signal number, leave no process of its group alive and leave
its output target as it was.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from realitygap.samples import sample_dir

CHILDREN_TIMEOUT_S = 120.0


def _children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(c) for c in text.split()]


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
@pytest.mark.parametrize(
    ("sig", "to_group", "code"),
    [(signal.SIGINT, True, 130), (signal.SIGTERM, False, 143)],
    ids=["ctrl-c-to-group", "sigterm-to-main"],
)
def test_signal_stops_a_pool_run_cleanly(
    tmp_path: Path, sig: signal.Signals, to_group: bool, code: int
) -> None:
    sample = sample_dir("optiodom_diffdrive")
    report = tmp_path / "report"
    report.mkdir()
    old = report / "report.md"
    old.write_text("a previous report\n")
    (report / ".realitygap-output").write_text('{"written_by": "realitygap"}\n')
    cmd = [
        sys.executable,
        "-m",
        "realitygap.cli",
        "diagnose",
        str(sample / "square" / "231220200029"),
        "--holdout",
        str(sample / "circular" / "231220200157"),
        "--backend",
        "process",
        "--workers",
        "2",
        "--quick",
        "--report",
        str(report),
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        start = time.monotonic()
        while not _children(proc.pid) and proc.poll() is None:
            assert time.monotonic() - start < CHILDREN_TIMEOUT_S, "the worker pool never started"
            time.sleep(0.1)
        assert proc.poll() is None, f"the run ended before the pool started: {proc.stderr}"
        time.sleep(0.5)
        if to_group:
            os.killpg(proc.pid, sig)
        else:
            os.kill(proc.pid, sig)
        _out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == code, err
    assert "Traceback" not in err, err
    assert err.count(f"stopped by {sig.name}") == 1, err
    deadline = time.monotonic() + 10.0
    while _group_alive(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _group_alive(proc.pid), "worker processes outlived the run"
    # the target is as it was: the old report, no new file, no staging folder beside it
    assert sorted(p.name for p in report.iterdir()) == [".realitygap-output", "report.md"]
    assert old.read_text() == "a previous report\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]
