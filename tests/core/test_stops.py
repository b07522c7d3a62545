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


def _alive(pids: set[int]) -> list[int]:
    """The ones of ``pids`` still running (zombies are dead)."""
    out = []
    for pid in pids:
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
        except OSError:
            continue
        if stat[stat.rindex(")") + 2 :].split()[0] != "Z":
            out.append(pid)
    return out


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def _has_ray() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


CASES = [
    pytest.param("process", signal.SIGINT, True, 130, 1, id="process-ctrl-c-to-group"),
    pytest.param("process", signal.SIGTERM, False, 143, 1, id="process-sigterm-to-main"),
    pytest.param(
        "ray",
        signal.SIGINT,
        True,
        130,
        3,
        id="ray-ctrl-c-to-group",
        marks=pytest.mark.skipif(not _has_ray(), reason="ray is not installed"),
    ),
    pytest.param(
        "ray",
        signal.SIGTERM,
        False,
        143,
        3,
        id="ray-sigterm-to-main",
        marks=pytest.mark.skipif(not _has_ray(), reason="ray is not installed"),
    ),
]


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
@pytest.mark.parametrize(("backend", "sig", "to_group", "code", "started"), CASES)
def test_signal_stops_a_pool_run_cleanly(
    tmp_path: Path, backend: str, sig: signal.Signals, to_group: bool, code: int, started: int
) -> None:
    from realitygap.core.stops import descendants

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
        backend,
        *(["--workers", "2"] if backend == "process" else []),
        "--quick",
        "--report",
        str(report),
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    seen: set[int] = set()
    try:
        start = time.monotonic()
        while len(seen) < started and proc.poll() is None:
            assert time.monotonic() - start < CHILDREN_TIMEOUT_S, "the workers never started"
            seen |= set(descendants(proc.pid))
            time.sleep(0.1)
        assert proc.poll() is None, f"the run ended before its workers started: {proc.stderr}"
        time.sleep(0.5 if backend == "process" else 8.0)
        seen |= set(descendants(proc.pid))
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
    while (_group_alive(proc.pid) or _alive(seen)) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _group_alive(proc.pid), "worker processes outlived the run"
    assert not _alive(seen), f"processes the run started outlived it: {_alive(seen)}"
    # the target is as it was: the old report, no new file, no staging folder beside it
    assert sorted(p.name for p in report.iterdir()) == [".realitygap-output", "report.md"]
    assert old.read_text() == "a previous report\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]
