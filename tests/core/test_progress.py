"""Progress bars, countdowns and silenced C output."""

from __future__ import annotations

import io
import os
import subprocess
import sys

import pytest

from realitygap.core.progress import Countdown, Progress, duration_words


def test_duration_words() -> None:
    assert duration_words(0.2) == "1 s"
    assert duration_words(40) == "40 s"
    assert duration_words(7 * 60 + 10) == "about 7 min"
    assert duration_words(5400) == "about 1.5 h"
    with pytest.raises(ValueError, match="expected a duration >= 0 s"):
        duration_words(-1.0)


def test_countdown_states_the_time_left_and_an_overrun() -> None:
    c = Countdown(120.0)
    assert c.prefix(elapsed_s=30.0) == "[0:30, about 2 min left]"
    assert c.prefix(elapsed_s=100.0) == "[1:40, 20 s left]"
    assert c.prefix(elapsed_s=150.0) == "[2:30, longer than the 2 min estimated]"
    assert Countdown(float("nan")).prefix(elapsed_s=61.0) == "[1:01]"


def test_progress_bar_counts_and_estimates_the_rest() -> None:
    stream = io.StringIO()
    with Progress(4, "cases", stream=stream) as bar:
        assert bar.remaining_s() != bar.remaining_s()  # nan before the first step
        bar.update(1, note="1 correct")
        bar.update(3)
        assert bar.remaining_s() == 0.0
    text = stream.getvalue()
    assert "cases" in text and "4/4" in text and "left" in text
    quiet = io.StringIO()
    with Progress(2, "cases", enabled=False, stream=quiet) as bar:
        bar.update(2)
        bar.write("not shown")
    assert quiet.getvalue() == ""
    with pytest.raises(ValueError, match="total must be >= 0"):
        Progress(-1, "x")


def test_quiet_c_output_silences_both_descriptors_and_restores_them() -> None:
    code = (
        "import os\n"
        "from realitygap.core.progress import quiet_c_output\n"
        "with quiet_c_output():\n"
        "    os.write(1, b'hidden-out\\n'); os.write(2, b'hidden-err\\n')\n"
        "os.write(1, b'shown-out\\n'); os.write(2, b'shown-err\\n')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=os.environ
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout == "shown-out\n" and done.stderr == "shown-err\n"
