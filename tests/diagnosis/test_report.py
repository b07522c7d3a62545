"""The diagnosis report: sentences before numbers, figures that load, files that follow the umask."""

from __future__ import annotations

import base64
import io
import os
import re
import shutil
import stat
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from realitygap.core.parallel import SerialBackend
from realitygap.diagnosis.adapters.diffdrive.manoeuvres import Manoeuvre
from realitygap.diagnosis.adapters.diffdrive.replay import simulate
from realitygap.diagnosis.diagnose import Diagnosis, DiagnosisSettings, diagnose
from realitygap.diagnosis.report.html import markdown_to_html
from realitygap.diagnosis.report.summary import (
    channel_name,
    quantity,
    ranking_by_shrink,
    regime_name,
    summary_sentences,
    value_words,
)
from realitygap.diagnosis.report.writer import write_report, write_reports
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
def planted() -> Diagnosis:
    """A wheelbase 5 % short, diagnosed from one run and scored on another."""
    rng = np.random.default_rng(5)
    reality = Reality((make_effect("wheelbase_error", E_b=0.95),))
    logs = []
    for man in (TURNS, LOOP):
        t, cmd = man.applied(0.05, P)
        noise = MeasurementNoise(0.0005, 0.001, 0.001, 0.002)
        logs.append(
            simulate(
                t,
                params=P,
                reality=reality,
                commands=cmd,
                noise=noise,
                rng=rng,
                meta={"name": man.name},
            )
        )
    settings = DiagnosisSettings(effects=("wheelbase_error", "wheel_radius_scale", "encoder_scale"))
    return diagnose(logs[:1], logs[1:], settings=settings, backend=SerialBackend())


# ----------------------------------------------------------------------------- words
def test_quantity_uses_engineering_units_at_the_precision_of_the_uncertainty() -> None:
    assert quantity(0.0017233, "s", 0.00021) == "1.72 ± 0.21 ms"
    assert quantity(1.7233e-21, "s", 0.021) == "0 ± 21 ms"  # not a raw 1.7e-21
    assert quantity(0.2066, "m", 0.0004) == "206.60 ± 0.40 mm"
    assert quantity(np.pi / 2, "rad") == "90°"
    # a thousand engineering units or more go back to the SI unit, not to an exponent
    assert quantity(1.0712, "m") == "1.07 m"
    assert quantity(-2.5, "m", 0.01) == "-2.500 ± 0.010 m"
    assert quantity(0.999, "m") == "999 mm"
    assert quantity(1.2, "1", 931.0) == "1 ± 931"
    assert quantity(0.012, "N") == "0.012 N"


def test_value_words_states_the_deviation_from_nominal_or_that_it_is_not_resolved() -> None:
    p = {"value": 1.008, "stderr": 0.0005, "unit": "1", "nominal": 1.0}
    text = value_words("wheelbase_error.E_b", p, "actual / nominal wheelbase")
    assert text.startswith("actual / nominal wheelbase (E_b) = 1.00800 ± 0.00050")
    assert "0.8 % above nominal 1" in text
    loose = {"value": 1.2, "stderr": 931.0, "unit": "1", "nominal": 1.2}
    assert "not resolved" in value_words("wheel_slip.mu", loose)


def test_names_are_human_and_fall_back_readably() -> None:
    assert channel_name("pose_gt", "dtheta") == "heading"
    assert regime_name("accelerating") == "while accelerating"
    assert channel_name("wrist", "angle_err") == "wrist angle err"
    assert regime_name("slow_climb") == "while slow climb"


def test_ranking_by_shrink_orders_by_what_the_reader_compares() -> None:
    rows = [
        {"rank": 1, "heldout_shrink_pct": 4.0},
        {"rank": 2, "heldout_shrink_pct": 4.3},
        {"rank": 3, "heldout_shrink_pct": -57.0},
    ]
    assert [r["rank"] for r in ranking_by_shrink(rows)] == [2, 1, 3]


@pytest.mark.slow
def test_summary_opens_with_what_where_which_and_the_rule(planted: Diagnosis) -> None:
    sentences = summary_sentences(planted)
    text = " ".join(sentences)
    assert sentences[0].startswith("Compared 1 recorded training run(s) and 1 held-out run(s)")
    assert "The gap lies mostly in heading, while" in text
    assert re.search(r"wheelbase \(E_b\) = 0\.95\d* ± 0\.000\d+, (5|4\.9) % below nominal 1", text)
    assert "Verdict: wheelbase_error" in text
    # the budget's sentence with its share and interval, then the rule that set the kind
    assert re.search(
        r"Of the held-out whole-run drift \(.*\), wheelbase error \(E_b = 0\.95\d* ± [\d.e-]+\) "
        r"explains \d+ % \[\d+, \d+\]",
        text,
    )
    assert "named effects leave a structured remainder of" in text


# ----------------------------------------------------------------------------- files
class _Images(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.sources: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "img":
            self.sources.append(dict(attrs).get("src") or "")


@pytest.mark.slow
def test_report_html_is_self_contained_and_every_image_decodes(
    planted: Diagnosis, tmp_path: Path
) -> None:
    import matplotlib.image as mpimg

    md = write_report(planted, tmp_path / "r")
    page = md.with_name("report.html")
    assert md.read_text().splitlines()[2].startswith("> Compared")
    parser = _Images()
    parser.feed(page.read_text(encoding="utf-8"))
    assert len(parser.sources) >= 5
    for src in parser.sources:
        assert src.startswith("data:image/png;base64,")
        pixels = mpimg.imread(io.BytesIO(base64.b64decode(src.split(",", 1)[1])), format="png")
        assert pixels.ndim == 3 and min(pixels.shape[:2]) > 100
    names = {p.name for p in (tmp_path / "r").iterdir()}
    assert {"report.md", "report.html", "diagnosis.json", "timeline.png", "ranking.png"} <= names


@pytest.mark.slow
def test_several_diagnoses_share_one_report(planted: Diagnosis, tmp_path: Path) -> None:
    page = write_reports(
        [("commands-driven replay", planted), ("second look", planted)],
        tmp_path,
        title="two parts",
        intro=["data: a sample"],
    )
    text = page.with_name("report.md").read_text()
    assert text.startswith("# two parts\n\n> data: a sample")
    assert "## commands-driven replay" in text and "### Verdict" in text
    assert (tmp_path / "second-look-ranking.png").is_file()


def test_markdown_to_html_refuses_a_missing_image(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"missing\.png that does not exist"):
        markdown_to_html("![gone](missing.png)", tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("mask", [0o022, 0o077])
def test_report_files_follow_the_umask(planted: Diagnosis, tmp_path: Path, mask: int) -> None:
    old = os.umask(mask)
    try:
        write_report(planted, tmp_path / "r")
    finally:
        os.umask(old)
    for path in (tmp_path / "r").iterdir():
        assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask, path.name


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.browser
@pytest.mark.skipif(
    _chromium() is None, reason="Chromium is not installed (apt-get install chromium)"
)
def test_report_opens_in_headless_chromium_with_every_image_loaded(
    planted: Diagnosis, tmp_path: Path
) -> None:
    page = write_report(planted, tmp_path / "r").with_name("report.html")
    probe = tmp_path / "probe.html"
    script = (
        "<script>window.addEventListener('load', () => { const imgs = [...document.images];"
        " const ok = imgs.filter(i => i.complete && i.naturalWidth > 0).length;"
        " document.body.setAttribute('data-images', ok + '/' + imgs.length); });</script>"
    )
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", script + "</body>"))
    done = subprocess.run(
        [
            str(_chromium()),
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--virtual-time-budget=10000",
            "--dump-dom",
            probe.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    loaded = re.search(r'data-images="(\d+)/(\d+)"', done.stdout)
    assert loaded is not None, done.stdout[-2000:]
    ok, total = int(loaded.group(1)), int(loaded.group(2))
    assert total >= 5 and ok == total


def test_markdown_to_html_renders_the_subset_and_escapes_text() -> None:
    png = b"\x89PNG\r\n\x1a\nfake"
    md = "\n".join(
        [
            "# Title",
            "",
            "> first sentence",
            "> second <sentence>",
            "",
            "| a | b |",
            "|---|---|",
            "| **x** | `y<z` |",
            "",
            "- item *one*",
            "",
            "<details><summary>more</summary>",
            "",
            "![cap](f.png)",
            "",
            "*cap*",
            "",
            "</details>",
        ]
    )
    page = markdown_to_html(md, lambda src: png, title="t & u")
    assert "<title>t &amp; u</title>" in page and "<h1>Title</h1>" in page
    assert '<div class="summary"><p>first sentence</p><p>second &lt;sentence&gt;</p></div>' in page
    assert "<td><strong>x</strong></td><td><code>y&lt;z</code></td>" in page
    assert "<li>item <em>one</em></li>" in page
    assert "<details><summary>more</summary>" in page and "</details>" in page
    assert f'src="data:image/png;base64,{base64.b64encode(png).decode()}"' in page
    assert "<figcaption>cap</figcaption>" in page and "<em>cap</em>" not in page  # one caption
