"""Write a diagnosis as a report a person opens: HTML and Markdown with figures, and JSON.

:func:`write_reports` (one or several diagnoses) and :func:`write_report` (one)
create ``DIR/report.html`` (self-contained, figures embedded), ``DIR/report.md``,
``DIR/diagnosis.json`` and the figures (:mod:`realitygap.diagnosis.report.figures`).
The report opens with sentences (:mod:`realitygap.diagnosis.report.summary`), then the
verdict, the baseline, where the gap is, the candidates by held-out shrink,
identifiability, the shrink per channel and the figures. :func:`write_json`
writes :meth:`Diagnosis.to_json`. Every file is written atomically.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

from realitygap.core.io import atomic_write, jsonable, write_json
from realitygap.diagnosis.diagnose import Diagnosis
from realitygap.diagnosis.report.figures import make_figures
from realitygap.diagnosis.report.html import markdown_to_html
from realitygap.diagnosis.report.summary import (
    change_words,
    channel_name,
    quantity,
    ranking_by_shrink,
    regime_name,
    summary_sentences,
)
from realitygap.diagnosis.report.words import explain_markdown, parameter_words
from realitygap.diagnosis.verdict.types import VerdictKind

__all__ = ["jsonable", "write_json", "write_report", "write_reports"]


def _write_text(path: Path, text: str) -> None:
    def writer(fh: IO[bytes]) -> None:
        fh.write(text.encode("utf-8"))

    atomic_write(path, writer)


def _fmt(x: Any, nd: int = 3) -> str:
    if isinstance(x, float):
        if not math.isfinite(x):
            return "—"
        if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e4):
            return f"{x:.{nd}e}"
        return f"{x:.{nd}g}" if abs(x) < 1 else f"{x:.{nd + 1}g}"
    return str(x)


def _si(value: float, unit: str) -> str:
    """A value of SI ``unit`` in the engineering units the summary and figures use."""
    return quantity(value, unit)


# --------------------------------------------------------------------------- markdown
def _baseline_and_transients(d: Diagnosis) -> list[str]:
    """The "Baseline calibration" and "Transient events" sections."""
    lines = ["", "## Baseline calibration", ""]
    b = d.baseline
    if b.values:
        lines.append(
            "Fitted before any effect and kept in every model; effects are scored against it "
            "(a nuisance is a sampling convention, not a finding):"
        )
        lines += ["", "| nuisance | value | allowed range | what |", "|---|---|---|---|"]
        for row in b.to_json()["nuisances"]:
            lo, hi = row["range"]
            lines.append(
                f"| {row['parameter']} | {_si(row['value'], row['unit'])} | "
                f"{_si(lo, row['unit'])} … {_si(hi, row['unit'])} | {row['what']} |"
            )
        lines.append("")
        lines.append(
            "Against the nominal replay, the baseline leaves the training residual "
            f"{change_words(b.train_shrink_pct, less='smaller', more='larger', digits=1)}."
        )
    else:
        lines.append("None applied (no nuisances stated, or they did not improve the replay).")
    for aligned in (b.clock, b.frames):
        if aligned.rows:
            lines += ["", aligned.summary()[:1].upper() + aligned.summary()[1:] + "."]
    if b.frames.rows:
        lines += [
            "",
            "Each log's own ground-truth frame (fitted beside the robot's effects; a component "
            "the log's motion does not test keeps the common value):",
            "",
            "| log | split | x | y | yaw | tested | re-framed | χ² drop |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in b.frames.rows[:30]:
            x, y, yaw = r["frame"]
            tested = "".join(c for c, t in zip("xyψ", r["tested"]) if t) or "none"
            lines.append(
                f"| {r['log']} | {r['split']} | {_si(x, 'm')} | {_si(y, 'm')} | "
                f"{_si(yaw, 'rad')} | {tested} | {'yes' if r['applied'] else 'no'} | "
                f"{r['chi2_drop']:.1f} |"
            )
        if len(b.frames.rows) > 30:
            lines.append(f"\n({len(b.frames.rows) - 30} more in the JSON.)")
    tr = d.transients
    lines += ["", "## Transient events", ""]
    lines.append(
        f"{tr.n_excluded} of {tr.n_windows} windows ({100 * tr.share_excluded:.1f} %) set aside "
        "from attribution and shrink: the signals show a stall or slip, or a frozen ground truth. "
        f"Residual outliers (robust score above {tr.settings.outlier_threshold:g} MAD standard "
        "deviations) whose signals look normal are listed and kept."
    )
    if tr.events:
        lines += [
            "",
            "| run | start–end | kind | channel | size | score | signals | set aside |",
            "|---|---|---|---|---|---|---|---|",
        ]
        shown = sorted(tr.events, key=lambda e: (not e.excluded, -e.score))[:30]
        for e in shown:
            lines.append(
                f"| {e.run} | {e.start_s:.1f}–{e.end_s:.1f} s | {e.kind} | {e.channel} | "
                f"{_si(e.size, e.unit)} | {e.score:.0f} | {e.signals} | "
                f"{'yes' if e.excluded else 'no'} |"
            )
        if len(tr.events) > len(shown):
            lines.append(f"\n({len(tr.events) - len(shown)} more in the JSON.)")
    return lines


def _run_gaps(runs: list[dict[str, Any]]) -> list[str]:
    """The held-out trajectory gap per run, largest share first."""
    if len(runs) < 2:
        return []
    cols = [k for k in ("nominal", "baseline", "best") if f"{k}_m" in runs[0]]
    lines = [
        "",
        "Per held-out run (RMS position error of the whole replay; share: the run's part of "
        "the pooled squared error of the nominal replay):",
        "",
        "| run | samples | " + " | ".join(cols) + " | share |",
        "|---|---|" + "---|" * len(cols) + "---|",
    ]
    shown = sorted(runs, key=lambda r: -r["share_pct"])[:30]
    for r in shown:
        vals = " | ".join(_si(r[f"{k}_m"], "m") for k in cols)
        lines.append(f"| {r['log']} | {r['samples']} | {vals} | {r['share_pct']:.1f} % |")
    if len(runs) > len(shown):
        lines.append(f"\n({len(runs) - len(shown)} more in the JSON.)")
    return lines


def _coverage_section(d: Diagnosis) -> list[str]:
    """The "Training coverage" section: held-out motions against the training envelope."""
    cov = d.coverage
    if cov is None or cov.n_windows == 0:
        return []
    lines = ["", "## Training coverage", "", cov.summary()[:1].upper() + cov.summary()[1:] + "."]
    if cov.suggestion():
        lines += ["", f"To test it: {cov.suggestion()}."]
    track = d.actuation.get("tracking")
    if track is not None and track["beyond"]:
        lines += ["", f"What the encoders show: {track['message']}.", ""]
        lines += [
            "| wheel | training: fastest asked | training gain | held-out windows beyond | "
            "gain there | fastest asked / reached there | windows asking above the reached |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in track["wheels"]:
            there = (
                f"{r['beyond_gain']:.3f} ± {r['beyond_gain_se']:.3f} | "
                f"{r['asked_max']:.3g} / {r['reached_max']:.3g} m/s | {r['n_capped']}"
                if "beyond_gain" in r
                else "– | – | –"
            )
            lines.append(
                f"| {r['wheel']} | {r['train_top_speed']:.3g} m/s | {r['train_gain']:.3f} ± "
                f"{r['train_gain_se']:.3f} | {r['n_beyond']} | {there} |"
            )
    lines += [
        "",
        "| motion | training | held out | held-out windows beyond |",
        "|---|---|---|---|",
    ]
    for r in cov.rows:
        unit = "" if r["unit"] == "1" else f" {r['unit']}"
        lines.append(
            f"| {r['label']} | {r['train_min']:.3g} … {r['train_max']:.3g}{unit} | "
            f"{r['heldout_min']:.3g} … {r['heldout_max']:.3g}{unit} | {r['n_outside']} |"
        )
    return lines


def _budget_section(d: Diagnosis, lead: list[tuple[str, str]]) -> list[str]:
    """The gap budget: its figures (waterfall, trajectories), then one row per entry and the
    remainder, per scale."""
    b = d.budget
    if b is None:
        return []
    lines = ["", "## Gap budget", ""]
    for fname, caption in lead:
        lines += [f"![{caption}]({fname})", "", f"*{caption}*", ""]
    scales = list(b.scales)
    head = " | ".join(
        f"{'whole runs' if s_ == 'run' else 'windows'} share [95 % interval]" for s_ in scales
    )
    lines += [
        f"| # | effect | fitted at | parameters (± 1σ) | {head} | one value across {b.folds.get('stability_unit', 'fold')}s? | aliases |",
        "|---|---|---|---|" + "---|" * len(scales) + "---|---|",
    ]
    for j, e in enumerate(b.entries, start=1):
        params = "; ".join(
            f"{parameter_words(k)} = {v:.5g}"
            + (f" ± {e.stderr[k]:.2g}" if math.isfinite(e.stderr.get(k, math.nan)) else "")
            for k, v in e.values.items()
        )
        shares = " | ".join(
            f"{e.share[s_]:.0f} % [{b.interval_of(e, s_)[0]:.0f}, {b.interval_of(e, s_)[1]:.0f}]"
            for s_ in scales
        )
        if e.constant:
            stable = "yes" if e.stability.get("tested") else "not tested (one run)"
        else:
            stable = "no: " + "; ".join(
                f"{k.split('.', 1)[-1]} {p_['min']:.4g} … {p_['max']:.4g}"
                for k, p_ in e.stability["parameters"].items()
                if not p_["holds"]
            )
        scale = "whole runs" if e.scale == "run" else "windows"
        lines.append(
            f"| {j} | {e.effect.replace('_', ' ')} | {scale} | {params} | {shares} | {stable} | "
            f"{', '.join(e.aliases) or '—'} |"
        )
    rem = " | ".join(
        f"{b.remainder[s_]['remaining_pct']:.0f} % ({b.remainder[s_]['noise_pct']:.0f} noise, "
        f"{b.remainder[s_]['structured_pct']:.0f} structured)"
        for s_ in scales
    )
    lines.append(f"| | remains | | | {rem} | | |")
    lines += [
        "",
        f"Rule: {b.rule}. Selection: forward, on {b.folds.get('k')} training "
        f"{b.folds.get('unit')} folds ({b.folds.get('test')}).",
    ]
    return lines


def _markdown(d: Diagnosis, figures: list[tuple[str, str]], title: str, note: str = "") -> str:
    js = d.to_json()
    v = d.verdict
    lines = [f"# {title}", ""]
    lines += [f"> {sentence}" for sentence in summary_sentences(d)]
    lines += [""]
    lines.append(f"Robot **{js['robot']}**, replay driven by **{js['drive']}**.  ")
    lines.append(
        f"Training logs: {', '.join(js['logs']['train']) or '—'}; held-out: "
        f"{', '.join(js['logs']['holdout']) or 'alternate blocks of windows'}."
    )
    lead = [f for f in figures if f[0].endswith(("budget.png", "trajectories.png"))]
    figures = [f for f in figures if f not in lead]
    lines += _budget_section(d, lead)
    lines += ["", "## Verdict", ""]
    named = v.kind in (VerdictKind.EFFECTS, VerdictKind.PARTIAL)
    label = ", ".join(v.effects) if named else v.kind.value.upper()
    if v.kind is VerdictKind.PARTIAL:
        label = "partly " + label
    lines.append(f"**{label}** — {v.reason}.  ")
    lines += explain_markdown(v, [f.name for f in d.ranking[:5]])
    if named:
        lines.append(
            f"Confidence: {v.confidence.value} (mean cross-validated gain of the first named "
            f"effect {_fmt(v.margin)}, log score ratio per fold)."
        )
        if v.ambiguous_with:
            lines.append(
                f"Not separable from: {', '.join(v.ambiguous_with)} (see Identifiability)."
            )
    g = d.gap
    lines.append("")
    lines.append(
        f"Held-out gap in the channels that show one ({', '.join(g.get('gap_channels', []))}) "
        "with the best candidate: "
        f"{change_words(g['heldout_shrink_pct_best'], less='closed', more='wider', digits=1)} "
        f"({change_words(g['heldout_shrink_pct_best_all_channels'], less='closed', more='wider', digits=1)}"
        f" over all channels; normalised window RMS {_fmt(g['heldout_rms_nominal'])} nominal → "
        f"{_fmt(g['heldout_rms_best'])})."
    )
    if "heldout_trajectory_gap_m_best" in g:
        lines.append(
            f"Held-out trajectory gap (RMS position error of whole replays): "
            f"{100 * g['heldout_trajectory_gap_m_nominal']:.2f} cm nominal → "
            f"{100 * g['heldout_trajectory_gap_m_best']:.2f} cm."
        )
    if "heldout_trajectory_gap_m_baseline" in g:
        lines.append(
            "Against the calibrated baseline the held-out trajectory gap is "
            f"{100 * g['heldout_trajectory_gap_m_baseline']:.2f} cm; window figures above are "
            f"measured against the {g.get('reference', 'nominal replay')}."
        )
    lines += _run_gaps(g.get("heldout_trajectory_runs", []))
    if v.residual.get("structured") and v.residual.get("reasons"):
        lines += ["", "What remains unexplained:", ""]
        lines += [f"- {r}" for r in v.residual["reasons"]]
    lines += _baseline_and_transients(d)

    lines += ["", "## Where the gap is", ""]
    lines.append("Nominal replay against the real logs, per channel and motion regime (top rows):")
    lines += [
        "",
        "| channel | regime | windows | RMS | mean | share |",
        "|---|---|---|---|---|---|",
    ]
    for r in [r for r in d.localisation["table"] if r["kind"] == "channel"][:12]:
        lines.append(
            f"| {_channel(r['where'], r['column'])} | {_regime(r['regime'])} | {r['n_windows']} | "
            f"{_si(r['rms'], r['unit'])} | {_si(r['mean'], r['unit'])} | {100 * r['share']:.1f} % |"
        )
    stages = [r for r in d.localisation["overall"] if r["kind"] == "stage"]
    if stages:
        lines += ["", "Pipeline stages (all windows):", ""]
        lines += ["| stage | column | RMS | mean |", "|---|---|---|---|"]
        for r in stages:
            lines.append(
                f"| {r['where']} | {r['column']} | {_si(r['rms'], r['unit'])} | "
                f"{_si(r['mean'], r['unit'])} |"
            )

    lines += ["", "## Candidate ranking", ""]
    lines.append(
        "Fitted on the training windows, scored on the held-out ones, sorted by the share of "
        "the held-out gap each closes (# is the rank by score: profile likelihood + BIC "
        "penalty, lower is better). ✓ = verified with PyBullet replays; s = screening fit "
        "(the baseline nuisances held at their calibrated values: the model cannot reach the "
        "top of the ranking, so it was not refined further). The ranking is a detail: what "
        "is named is decided by the gap budget's cross-validated selection (above)."
    )
    lines += [
        "",
        "| # | model | fitted values (± 1σ) | held-out shrink | score | ✓ |",
        "|---|---|---|---|---|---|",
    ]
    for r in ranking_by_shrink(js["ranking"])[:15]:
        vals = "; ".join(
            f"{k.split('.', 1)[1]} = {quantity(p['value'], p['unit'], p['stderr'])}"
            for k, p in r["params"].items()
        )
        lines.append(
            f"| {r['rank']} | {r['name']} | {vals or '—'} | {r['heldout_shrink_pct']:.1f} % | "
            f"{_fmt(r['rank_score'], 5)} | {'✓' if r['verified_in_pybullet'] else ''}"
            f"{'s' if r.get('screened') else ''} |"
        )
    if d.not_observable:
        lines += ["", "Not attributable with these logs:", ""]
        lines += [f"- `{k}`: {why}" for k, why in d.not_observable.items()]

    lines += ["", "## Identifiability", ""]
    if d.identifiability:
        for info in d.identifiability:
            if info.get("separable"):
                lines.append(
                    f"- {info['effects'][0]} vs {info['effects'][1]}: separable with these logs "
                    f"(parameter correlation {info['correlation']:.2f})."
                )
            else:
                lines.append(f"- **{info['message']}**.")
    else:
        lines.append("No close competitor to check.")

    lines += ["", "## Shrink on held-out data", ""]
    lines += [
        "| channel | column | regime | windows | before | after | shrink |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in d.shrink:
        if r["regime"] == "all" or r["column"] == "all":
            lines.append(
                f"| {r['group']} | {r['column']} | {r['regime']} | {r['n']} | "
                f"{_si(r['rms_before'], r['unit'])} | {_si(r['rms_after'], r['unit'])} | "
                f"{r['shrink_pct']:.1f} % |"
            )
    if not named and d.shrink_best:
        lines += ["", f"No effect was chosen; with the best candidate ({d.ranking[0].name}):", ""]
        lines += ["| channel | column | before | after | shrink |", "|---|---|---|---|---|"]
        for r in d.shrink_best:
            if r["regime"] == "all":
                lines.append(
                    f"| {r['group']} | {r['column']} | {_si(r['rms_before'], r['unit'])} | "
                    f"{_si(r['rms_after'], r['unit'])} | {r['shrink_pct']:.1f} % |"
                )
    per_regime = [r for r in d.shrink if r["regime"] != "all" and r["column"] != "all"]
    if per_regime:
        lines += ["", "<details><summary>per regime</summary>", ""]
        lines += [
            "| channel | column | regime | windows | before | after | shrink |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in per_regime:
            lines.append(
                f"| {r['group']} | {r['column']} | {r['regime']} | {r['n']} | "
                f"{_si(r['rms_before'], r['unit'])} | {_si(r['rms_after'], r['unit'])} | "
                f"{r['shrink_pct']:.1f} % |"
            )
        lines += ["", "</details>"]

    lines += _coverage_section(d)

    lines += ["", "## Surrogate agreement", ""]
    if d.agreement:
        lines.append(
            "The fit uses a fast kinematic surrogate corrected by its own nominal error; at the "
            "fitted values it is compared with PyBullet (relative error of the predicted effect "
            "on the window features):"
        )
        lines.append("")
        for a in d.agreement:
            lines.append(f"- {a['model']}: {100 * a['relative_error']:.1f} %")
    else:
        lines.append("No model was verified.")

    lines += ["", "## Figures", ""]
    for fname, caption in figures:
        lines += [f"![{caption}]({fname})", "", f"*{caption}*", ""]
    if note:
        lines.append(note)
    t = d.timing
    lines += [
        "",
        f"*Diagnosis time: {t.get('total', 0):.1f} s (replays {t.get('prepare', 0):.1f} s, fits "
        f"{t.get('fit', 0):.1f} s, verification {t.get('verify', 0):.1f} s).*",
        "",
    ]
    return "\n".join(lines)


def _channel(group: str, column: str) -> str:
    return f"{channel_name(group, column)} (`{group}.{column}`)"


def _regime(regime: str) -> str:
    return regime_name(regime).removeprefix("while ")


def _demote(markdown: str) -> str:
    """Headings one level down (a part of a report with several diagnoses)."""
    return "\n".join("#" + line if line.startswith("#") else line for line in markdown.splitlines())


def _slug(label: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in label.lower()).strip("-")


def write_reports(
    parts: Sequence[tuple[str, Diagnosis]],
    directory: str | os.PathLike[str],
    title: str = "Sim-to-real gap diagnosis",
    intro: Sequence[str] = (),
    payload: Any = None,
) -> Path:
    """Write one report of one or more diagnoses into ``directory``.

    Writes ``report.md``, ``report.html`` (self-contained: figures embedded as
    base64 PNG), ``diagnosis.json`` and the figures as PNG files; every file
    atomically, with the permissions the umask gives a new file.

    Parameters
    ----------
    parts : sequence of (label, Diagnosis)
        One diagnosis with an empty label, or several, each with a section title
        (their figures' file names start with the label).
    directory : path-like
        Output folder, created if missing.
    title : str
        The report's title.
    intro : sequence of str
        Sentences shown under the title, before the parts.
    payload : optional
        JSON written as ``diagnosis.json`` instead of the diagnoses' own JSON.

    Returns
    -------
    Path
        ``directory/report.html``.
    """
    if not parts:
        raise ValueError("write_reports: expected at least one (label, Diagnosis) part, got none")
    out = Path(directory)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(
            f"report folder {out} is a file; pass a folder (it is created if missing)"
        )
    out.mkdir(parents=True, exist_ok=True)
    single = len(parts) == 1 and not parts[0][0]
    note = ""
    try:
        import matplotlib  # noqa: F401
    except ImportError:  # a core dependency; an environment without it still gets the text
        note = (
            "matplotlib is not installed, so this report has no figures (pip install matplotlib)."
        )
    texts = []
    for label, d in parts:
        prefix = f"{_slug(label)}-" if label else ""
        figures = [] if note else make_figures(d, out, prefix)
        texts.append(_markdown(d, figures, label or title, note))
    if single:
        markdown = texts[0]
    else:
        head = [f"# {title}", ""] + [f"> {s}" for s in intro] + [""]
        markdown = "\n".join(head) + "\n" + "\n\n".join(_demote(t) for t in texts)
    _write_text(out / "report.md", markdown)
    _write_text(out / "report.html", markdown_to_html(markdown, out, title=title))
    if payload is None:
        payload = parts[0][1].to_json() if single else {lbl: d.to_json() for lbl, d in parts}
    write_json(out / "diagnosis.json", payload)
    return out / "report.html"


def write_report(d: Diagnosis, directory: str | os.PathLike[str]) -> Path:
    """Write the report of ``d`` into ``directory`` (see :func:`write_reports`).

    Returns
    -------
    Path
        ``directory/report.md``; ``report.html`` and ``diagnosis.json`` lie beside it.
    """
    return write_reports([("", d)], directory).with_name("report.md")
