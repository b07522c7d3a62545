"""The README runs: every Python block, and every shell command it presents.

Each ```` ```python ```` block runs on its own in a fresh interpreter from the
repository root. Each ```` ```bash ```` block runs as one script from the
repository root with the README's own paths, with two changes a test needs: the
install-and-test command is left out (CI runs it itself), an install in front of
a command is dropped (the package is installed), and ``realitygap run`` /
``realitygap diagnose`` get ``--quick``. Whatever the commands write into the
repository is checked and removed afterwards, so the tree stays clean.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
INSTALL = re.compile(r"^python -m pip install [^&]*&&\s*")


def blocks(language: str) -> list[str]:
    """The fenced code blocks of the README in ``language``, in order."""
    text = README.read_text(encoding="utf-8")
    return re.findall(rf"^```{language}\n(.*?)^```", text, flags=re.S | re.M)


def shell_commands(block: str) -> list[str]:
    """The commands of a shell block: continuation lines joined, comments dropped."""
    joined = re.sub(r"\\\n\s*", " ", block)
    return [ln.strip() for ln in joined.splitlines() if ln.strip() and not ln.startswith("#")]


def runnable(command: str) -> str | None:
    """``command`` as the test runs it, or ``None`` for the install-and-test command."""
    if "pytest" in command:
        return None
    command = INSTALL.sub("", command)
    if re.match(r"^realitygap (run|diagnose)\b", command) and "--quick" not in command:
        command += " --quick"
    return command


PY_BLOCKS = blocks("python")
SH_BLOCKS = [b for b in blocks("bash") if any(runnable(c) for c in shell_commands(b))]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env.setdefault("OMP_NUM_THREADS", "1")
    return env


def test_the_readme_has_the_blocks_it_should() -> None:
    assert len(PY_BLOCKS) >= 3
    commands = [c for b in blocks("bash") for c in shell_commands(b)]
    assert any(c.endswith("realitygap run diagnose-real") for c in commands)
    assert sum(runnable(c) is None for c in commands) == 1  # only install-and-test is left out
    assert "shared/data/optiodom" not in "".join(blocks("bash"))  # paths that exist in a clone


@pytest.mark.slow
@pytest.mark.parametrize("code", PY_BLOCKS, ids=[f"python-{i}" for i in range(len(PY_BLOCKS))])
def test_python_block_runs(code: str) -> None:
    done = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "pybullet build time" not in done.stdout + done.stderr


@pytest.mark.slow
@pytest.mark.parametrize("block", SH_BLOCKS, ids=[f"shell-{i}" for i in range(len(SH_BLOCKS))])
def test_shell_block_runs(block: str) -> None:
    script = "set -euo pipefail\n" + "\n".join(
        c for c in (runnable(c) for c in shell_commands(block)) if c
    )
    before = set(os.listdir(ROOT))
    try:
        done = subprocess.run(
            ["bash", "-c", script],
            cwd=ROOT,
            env=_env(),
            capture_output=True,
            text=True,
            timeout=1500,
        )
        assert done.returncode == 0, f"{script}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
        assert "pybullet build time" not in done.stdout + done.stderr
        reports = re.findall(r"^report: (.+)$", done.stdout, flags=re.M)
        assert reports, done.stdout[-2000:]
        for report in reports:
            page = Path(report)
            if not page.is_absolute():
                page = ROOT / page
            assert page.name == "report.html" and page.is_file()
            assert (page.parent / "report.md").is_file()
            assert (page.parent / "diagnosis.json").is_file()
            assert "data:image/png;base64," in page.read_text(encoding="utf-8")
        head = done.stdout.split("candidates by held-out shrink")[0]
        assert "Compared" in head and "Verdict" in head  # words before numbers
    finally:
        for name in set(os.listdir(ROOT)) - before:
            path = ROOT / name
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink()
