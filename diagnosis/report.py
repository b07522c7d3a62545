"""Write a diagnosis as a Markdown report with figures, and as JSON.

:func:`write_report` creates ``DIR/report.md`` and, when matplotlib is
installed, ``DIR/*.png``: the trajectory overlay (real / nominal replay /
corrected replay) of held-out logs, the held-out residual per channel and
regime before and after, the candidate ranking, where the gap is, and the
surrogate's agreement with PyBullet. Without matplotlib the report says so
and keeps its tables. :func:`write_json` writes :meth:`Diagnosis.to_json`.
Every file is written atomically.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np

from realitygap.core.io import atomic_write
from realitygap.diagnosis.diagnose import Diagnosis
from realitygap.diagnosis.verdict import explain_markdown

__all__ = ["jsonable", "write_json", "write_report"]


def jsonable(value: Any) -> Any:
    """``value`` with arrays as lists, non-finite floats as ``None``/``"inf"``/``"-inf"``."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: str | os.PathLike[str], payload: Any) -> Path:
    """Write ``payload`` as indented JSON, atomically."""
    text = json.dumps(jsonable(payload), indent=2) + "\n"

    def writer(fh: IO[bytes]) -> None:
        fh.write(text.encode("utf-8"))

    return atomic_write(path, writer)


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
    if unit == "m":
        return f"{value * 1e3:.3g} mm"
    if unit == "rad":
        return f"{value * 1e3:.3g} mrad"
    if unit == "1":
        return f"{value:.3g}"
    return f"{value:.3g} {unit}"


# --------------------------------------------------------------------------- figures
def _figures(d: Diagnosis, out: Path) -> list[tuple[str, str]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    made: list[tuple[str, str]] = []
    prepared = d.prepared
    ho_idx = [
        i for i, p in enumerate(prepared) if p.holdout_windows.any() and p.log.has("pose_gt")
    ][:6]

    # trajectories ---------------------------------------------------------
    if ho_idx:
        n = len(ho_idx)
        cols = min(3, n)
        rows = math.ceil(n / cols)
        fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.0 * rows), squeeze=False)
        for ax, i in zip(axes.flat, ho_idx):
            p = prepared[i]
            real = p.log["pose_gt"]
            nom = p.replay_log["pose_gt"]
            ax.plot(real[:, 0], real[:, 1], "k-", lw=1.6, label="real")
            ax.plot(nom[:, 0], nom[:, 1], "r--", lw=1.1, label="nominal replay")
            corr = d.corrected_replays.get(i)
            if corr is not None:
                c = corr["pose_gt"]
                ax.plot(c[:, 0], c[:, 1], "g-", lw=1.0, alpha=0.8, label="with fitted effects")
            ax.set_title(p.name, fontsize=9)
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
        for ax in list(axes.flat)[n:]:
            ax.axis("off")
        axes.flat[0].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "trajectories.png", dpi=110)
        plt.close(fig)
        made.append(("trajectories.png", "Held-out trajectories: real, nominal replay, corrected"))

    # residual per channel and regime ---------------------------------------
    bars = [r for r in d.shrink if r["column"] != "all"]
    if bars:
        labels = [f"{r['group']}.{r['column']}\n{r['regime']}" for r in bars]
        before = [r["rms_before"] * (1e3 if r["unit"] in ("m", "rad") else 1) for r in bars]
        after = [r["rms_after"] * (1e3 if r["unit"] in ("m", "rad") else 1) for r in bars]
        fig, ax = plt.subplots(figsize=(max(8.0, 0.45 * len(bars)), 4.2))
        x = np.arange(len(bars))
        ax.bar(x - 0.2, before, 0.4, color="tab:red", label="nominal")
        ax.bar(x + 0.2, after, 0.4, color="tab:green", label="corrected")
        ax.set_xticks(x, labels, rotation=90, fontsize=7)
        ax.set_ylabel("held-out RMS per window [mm or mrad]")
        ax.set_yscale("symlog", linthresh=0.5)
        ax.legend()
        fig.tight_layout()
        fig.savefig(out / "residuals.png", dpi=110)
        plt.close(fig)
        made.append(("residuals.png", "Held-out residual per channel and motion regime"))

    # ranking ----------------------------------------------------------------
    ranking = d.ranking_rows()[:12]
    if ranking:
        fig, ax = plt.subplots(figsize=(7.5, 0.38 * len(ranking) + 1.2))
        names = [r["name"] + (" ✓" if r["verified_in_pybullet"] else "") for r in ranking][::-1]
        vals = [max(-50.0, r["heldout_shrink_pct"]) for r in ranking][::-1]
        ax.barh(names, vals, color=["tab:green" if v > 0 else "tab:gray" for v in vals])
        ax.set_xlabel("held-out shrink [%]  (✓ verified in PyBullet)")
        ax.axvline(100 * d.settings.attribution.min_shrink, color="k", ls=":", lw=1)
        fig.tight_layout()
        fig.savefig(out / "ranking.png", dpi=110)
        plt.close(fig)
        made.append(("ranking.png", "Candidate ranking (held-out shrink)"))

    # localisation -----------------------------------------------------------
    table = [r for r in d.localisation["table"] if r["kind"] == "channel"][:12]
    if table:
        fig, ax = plt.subplots(figsize=(7.5, 0.36 * len(table) + 1.2))
        names = [f"{r['where']}.{r['column']} / {r['regime']}" for r in table][::-1]
        ax.barh(names, [100 * r["share"] for r in table][::-1], color="tab:orange")
        ax.set_xlabel("share of the normalised squared gap [%]")
        fig.tight_layout()
        fig.savefig(out / "localisation.png", dpi=110)
        plt.close(fig)
        made.append(("localisation.png", "Where the gap is (nominal replay)"))

    # surrogate agreement ------------------------------------------------------
    chosen = next((f for f in d.ranking if f.verified and f.effects), None)
    if chosen is not None and d.corrected_replays and chosen.effects == d.ranking[0].effects:
        xs, ys = [], []
        adapter = d.problem.adapter
        point = {k: np.array([v]) for k, v in chosen.values.items()}
        for i, rep in d.corrected_replays.items():
            p = prepared[i]
            pb = adapter.log_features(p, rep)
            sur = adapter.surrogate_features(p, point, d.problem.drive)
            for g in p.groups:
                s = d.settings.features.scale(g)
                xs.append(((pb[g] - p.nominal[g]) / s).ravel())
                ys.append(((sur[g][0] + p.bias[g] - p.nominal[g]) / s).ravel())
        if xs:
            xa, ya = np.concatenate(xs), np.concatenate(ys)
            fig, ax = plt.subplots(figsize=(4.6, 4.4))
            ax.plot(xa, ya, ".", ms=3, alpha=0.5)
            lim = float(np.max(np.abs(np.concatenate([xa, ya])))) or 1.0
            ax.plot([-lim, lim], [-lim, lim], "k:", lw=1)
            ax.set_xlabel("PyBullet: effect on window features [scale units]")
            ax.set_ylabel("surrogate: effect on window features")
            ax.set_title(chosen.name, fontsize=9)
            fig.tight_layout()
            fig.savefig(out / "surrogate_agreement.png", dpi=110)
            plt.close(fig)
            made.append(
                ("surrogate_agreement.png", "Surrogate against PyBullet at the fitted values")
            )
    timeline = _transient_timeline(d, out, plt)
    if timeline:
        made.append(timeline)
    return made


def _transient_timeline(d: Diagnosis, out: Path, plt: Any) -> tuple[str, str] | None:
    """One row per run: its windows (train grey, held out blue) and transient events on top."""
    events = d.transients.events
    if not events:
        return None
    runs = sorted({e.log_index for e in events})[:12]
    fig, ax = plt.subplots(figsize=(8.0, 0.45 * len(runs) + 1.2))
    colours = {"stall or slip": "tab:red", "ground truth frozen": "tab:purple"}
    for row, i in enumerate(runs):
        p = d.prepared[i]
        t0 = float(p.log.t[0])
        ax.broken_barh(
            [(0.0, float(p.log.t[-1]) - t0)],
            (row - 0.3, 0.6),
            color="tab:blue" if p.holdout_windows.any() else "0.8",
            alpha=0.3,
        )
        for e in (e for e in events if e.log_index == i):
            ax.broken_barh(
                [(e.start_s, e.end_s - e.start_s)],
                (row - 0.3, 0.6),
                color=colours.get(e.kind, "tab:orange"),
                alpha=0.9 if e.excluded else 0.5,
            )
    ax.set_yticks(range(len(runs)))
    ax.set_yticklabels([d.prepared[i].name[:28] for i in runs], fontsize=7)
    ax.set_xlabel("time [s]")
    ax.set_title(
        "transient events (red: stall or slip, purple: ground truth frozen — set aside; "
        "orange: residual outlier, kept)",
        fontsize=8,
    )
    fig.tight_layout()
    fig.savefig(out / "transients.png", dpi=110)
    plt.close(fig)
    return ("transients.png", "Transient events on each run's timeline")


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
            f"The baseline removes {b.train_shrink_pct:.1f} % of the nominal replay's training "
            "residual."
        )
    else:
        lines.append("None applied (no nuisances stated, or they did not improve the replay).")
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


def _markdown(d: Diagnosis, figures: list[tuple[str, str]], note: str) -> str:
    js = d.to_json()
    v = d.verdict
    lines = ["# Sim-to-real gap diagnosis", ""]
    lines.append(f"Robot **{js['robot']}**, replay driven by **{js['drive']}**.  ")
    lines.append(
        f"Training logs: {', '.join(js['logs']['train']) or '—'}; held-out: "
        f"{', '.join(js['logs']['holdout']) or 'alternate blocks of windows'}."
    )
    lines += ["", "## Verdict", ""]
    label = ", ".join(v.effects) if v.kind == "effects" else v.kind.upper()
    lines.append(f"**{label}** — {v.reason}.  ")
    lines += explain_markdown(v, [f.name for f in d.ranking[:5]])
    if v.kind == "effects":
        lines.append(
            f"Confidence: {v.confidence} (score margin to the runner-up {_fmt(v.margin)})."
        )
        if v.ambiguous_with:
            lines.append(
                f"Not separable from: {', '.join(v.ambiguous_with)} (see Identifiability)."
            )
    g = d.gap
    lines.append("")
    lines.append(
        f"Held-out gap in the channels that show one ({', '.join(g.get('gap_channels', []))}): "
        f"{_fmt(g['heldout_shrink_pct_best'])} % closed by the best candidate "
        f"({_fmt(g['heldout_shrink_pct_best_all_channels'])} % over all channels; normalised window "
        f"RMS {_fmt(g['heldout_rms_nominal'])} nominal → {_fmt(g['heldout_rms_best'])})."
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
    if v.kind != "effects" and v.residual.get("reasons"):
        lines += ["", "What remains unexplained:", ""]
        lines += [f"- {r}" for r in v.residual["reasons"]]
    lines += _baseline_and_transients(d)

    lines += ["", "## Where the gap is", ""]
    lines.append("Nominal replay against the real logs, per channel and motion regime (top rows):")
    lines += [
        "",
        "| channel | column | regime | windows | RMS | mean | share |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in [r for r in d.localisation["table"] if r["kind"] == "channel"][:12]:
        lines.append(
            f"| {r['where']} | {r['column']} | {r['regime']} | {r['n_windows']} | "
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
        "Fitted on the training windows, scored on the held-out ones (profile likelihood + "
        "BIC penalty; lower is better). ✓ = verified with PyBullet replays."
    )
    lines += [
        "",
        "| # | model | fitted values (± 1σ) | held-out shrink | score | ✓ |",
        "|---|---|---|---|---|---|",
    ]
    for r in js["ranking"][:15]:
        vals = "; ".join(
            f"{k.split('.', 1)[1]} = {_fmt(p['value'], 4)} ± {_fmt(p['stderr'], 2)}"
            + ("" if p["unit"] == "1" else f" {p['unit']}")
            for k, p in r["params"].items()
        )
        lines.append(
            f"| {r['rank']} | {r['name']} | {vals or '—'} | {r['heldout_shrink_pct']:.1f} % | "
            f"{_fmt(r['rank_score'], 5)} | {'✓' if r['verified_in_pybullet'] else ''} |"
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
    if v.kind != "effects" and d.shrink_best:
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
    if figures:
        for fname, caption in figures:
            lines += [f"![{caption}]({fname})", "", f"*{caption}*", ""]
    else:
        lines.append(note)
    t = d.timing
    lines += [
        "",
        f"*Diagnosis time: {t.get('total', 0):.1f} s (replays {t.get('prepare', 0):.1f} s, fits "
        f"{t.get('fit', 0):.1f} s, verification {t.get('verify', 0):.1f} s).*",
        "",
    ]
    return "\n".join(lines)


def write_report(d: Diagnosis, directory: str | os.PathLike[str]) -> Path:
    """Write ``report.md`` (and figures when matplotlib is available) into ``directory``."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    figures: list[tuple[str, str]] = []
    note = ""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        note = (
            "matplotlib is not installed, so this report has no figures "
            "(pip install 'realitygap[plots]')."
        )
    else:
        figures = _figures(d, out)
    path = out / "report.md"
    _write_text(path, _markdown(d, figures, note))
    return path
