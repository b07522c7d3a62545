"""The figures of a diagnosis report.

Every figure has a title, one unit per axis (lengths in mm, angles in degrees),
labelled thresholds, human names for channels and regimes
(:mod:`realitygap.diagnosis.report.summary`), and marks any value drawn beyond the axis
instead of clipping it silently. :func:`make_figures` writes them as PNG files and
returns ``(file name, caption)`` pairs:

* ``trajectories.png`` — held-out runs: real path, nominal replay, replay with the
  best candidate.
* ``timeline.png`` — the residual of the channel with the largest gap over each
  held-out run's time, nominal and with the best candidate, motion regimes shaded
  behind it and transient events marked.
* ``residuals.png`` — held-out RMS per channel and regime, one panel per unit.
* ``ranking.png`` — candidates by held-out shrink with the naming threshold.
* ``localisation.png`` — where the nominal gap is (share per channel and regime).
* ``surrogate_agreement.png`` — the fast surrogate against PyBullet at the fitted values.
* ``transients.png`` — transient events on each run's timeline (when there are any).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from realitygap.diagnosis.report.summary import (
    channel_name,
    group_name,
    ranking_by_shrink,
    regime_name,
    where_rows,
)
from realitygap.diagnosis.verdict.types import VerdictKind

if TYPE_CHECKING:
    from realitygap.diagnosis.diagnose import Diagnosis

__all__ = ["make_figures"]

_DPI = 110
_REGIME_COLOURS = {
    "standing": "0.85",
    "straight": "#cfe3f5",
    "turning_ccw": "#f8dcc0",
    "turning_cw": "#f5ecb8",
    "accelerating": "#e3d3f0",
}
_PLOT_UNITS = {"m": ("mm", 1e3), "rad": ("°", 180.0 / math.pi), "1": ("", 1.0)}


def plot_unit(unit: str) -> tuple[str, float]:
    """The unit a figure shows an SI ``unit`` in, and the factor from SI."""
    return _PLOT_UNITS.get(unit, (unit, 1.0))


def _save(fig: Any, out: Path, name: str, plt: Any) -> None:
    from realitygap.core.io import atomic_write

    fig.tight_layout()
    atomic_write(out / name, lambda fh: fig.savefig(fh, dpi=_DPI, format="png"))
    plt.close(fig)


def make_figures(d: Diagnosis, out: Path, prefix: str = "") -> list[tuple[str, str]]:
    """Write the report's figures for ``d`` into ``out`` (file names start with ``prefix``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    made: list[tuple[str, str]] = []
    for maker in (
        _waterfall,
        _trajectories,
        _timeline,
        _residuals,
        _ranking,
        _localisation,
        _agreement,
        _transients,
    ):
        item = maker(d, out, prefix, plt)
        if item is not None:
            made.append(item)
    return made


def _best_label(d: Diagnosis) -> str:
    b = d.budget
    if b is None or not b.entries:
        return "best candidate"
    return "with the budget's effects (" + " + ".join(e.effect for e in b.entries) + ")"


def _waterfall(d: Diagnosis, out: Path, prefix: str, plt: Any) -> tuple[str, str] | None:
    """The gap budget as a waterfall per scale: the held-out gap (100 %), each effect's share
    with its interval, the remainder split into sensor noise and structured."""
    b = d.budget
    if b is None:
        return None
    scales = list(b.scales)
    fig, axes = plt.subplots(
        1, len(scales), figsize=(4.6 * len(scales), 0.5 * (len(b.entries) + 3) + 1.8), squeeze=False
    )
    titles = {"run": "whole-run drift", "window": "windows"}
    for ax, sc in zip(axes.flat, scales):
        labels = ["held-out gap"]
        rem = b.remainder[sc]
        left = 100.0
        ax.barh(0, 100.0, color="tab:red", alpha=0.8)
        y = 1
        for e in b.entries:
            share = e.share[sc]
            lo, hi = b.interval_of(e, sc)
            start = left - share
            ax.barh(y, share, left=start, color="tab:green" if share >= 0 else "tab:gray",
                    alpha=0.9 if e.named else 0.45)  # fmt: skip
            ax.errorbar([start], [y], xerr=[[max(0.0, hi - share)], [max(0.0, share - lo)]],
                        fmt="none", ecolor="k", capsize=3, lw=0.8)  # fmt: skip
            ax.text(min(left, 100.0) + 1.0, y, f"{share:.0f} % [{lo:.0f}, {hi:.0f}]", va="center",
                    fontsize=7)  # fmt: skip
            labels.append(
                e.effect.replace("_", " ")
                + ("" if e.named else " (varies)" if not e.constant else " (does not carry over)")
            )
            left = start
            y += 1
        ax.barh(y, rem["noise_pct"], color="tab:blue", alpha=0.6, label="sensor noise")
        ax.barh(y, rem["structured_pct"], left=rem["noise_pct"], color="tab:orange", alpha=0.8,
                label="structured, unexplained")  # fmt: skip
        labels.append(f"remains {rem['remaining_pct']:.0f} %")
        ax.set_yticks(range(len(labels)), labels, fontsize=8)
        ax.invert_yaxis()
        ax.set_xlim(0.0, 115.0)
        ax.set_xlabel("share of the held-out gap [%]")
        ax.set_title(f"{titles.get(sc, sc)} (RMS {b.gap[sc]:.3g} noise units)", fontsize=10)
        ax.legend(fontsize=7, loc="lower right")
    fig.suptitle(f"Gap budget: {b.kind}", fontsize=11)
    name = f"{prefix}budget.png"
    _save(fig, out, name, plt)
    return (
        name,
        "The gap budget: the held-out gap, each effect's share (interval: bootstrap over held-out "
        "runs), and what remains, sensor noise and structured",
    )


def _holdout_indices(d: Diagnosis, limit: int = 6) -> list[int]:
    return [
        i for i, p in enumerate(d.prepared) if p.holdout_windows.any() and p.log.has("pose_gt")
    ][:limit]


def _trajectories(d: Diagnosis, out: Path, prefix: str, plt: Any) -> tuple[str, str] | None:
    idx = _holdout_indices(d)
    if not idx:
        return None
    cols = min(3, len(idx))
    rows = math.ceil(len(idx) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.0 * rows + 0.5), squeeze=False)
    for ax, i in zip(axes.flat, idx):
        p = d.prepared[i]
        real, nom = p.log["pose_gt"], p.replay_log["pose_gt"]
        ax.plot(real[:, 0], real[:, 1], "k-", lw=1.6, label="real (ground truth)")
        ax.plot(nom[:, 0], nom[:, 1], "r--", lw=1.1, label="nominal simulation")
        corr = d.corrected_replays.get(i)
        if corr is not None:
            c = corr["pose_gt"]
            ax.plot(c[:, 0], c[:, 1], "g-", lw=1.0, alpha=0.8, label=_best_label(d))
        ax.set_title(p.name, fontsize=9)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    for ax in list(axes.flat)[len(idx) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("Held-out runs: real path against the simulated replays", fontsize=11)
    name = f"{prefix}trajectories.png"
    _save(fig, out, name, plt)
    return (
        name,
        "Held-out runs: the real path, the nominal replay and the replay with the best candidate",
    )


def _timeline(d: Diagnosis, out: Path, prefix: str, plt: Any) -> tuple[str, str] | None:
    """Residual of the worst channel over time, regimes shaded, transient events marked."""
    cells = where_rows(d, 1)
    idx = [i for i, p in enumerate(d.prepared) if p.holdout_windows.any()][:4]
    if not cells or not idx:
        return None
    group, column = cells[0]["where"], cells[0]["column"]
    p0 = d.prepared[idx[0]]
    if group not in p0.real or column not in p0.schema.columns(group):
        return None
    j = list(p0.schema.columns(group)).index(column)
    unit_name, factor = plot_unit(
        dict(zip(p0.schema.columns(group), p0.schema.units(group)))[column]
    )
    adapter = d.problem.adapter
    fig, axes = plt.subplots(len(idx), 1, figsize=(9.0, 2.3 * len(idx) + 0.8), squeeze=False)
    seen_regimes: dict[str, Any] = {}
    for ax, i in zip(axes[:, 0], idx):
        p = d.prepared[i]
        t = np.asarray(p.log.t, dtype=float) - float(p.log.t[0])
        b = np.asarray(p.bounds)
        start, end = t[b[:, 0]], t[np.minimum(b[:, 1], len(t) - 1)]
        mid = 0.5 * (start + end)
        for s, e, r in zip(start, end, p.regimes):
            patch = ax.axvspan(s, e, color=_REGIME_COLOURS.get(r, "0.9"), lw=0, zorder=0)
            seen_regimes.setdefault(r, patch)
        nominal = (p.real[group][:, j] - p.nominal[group][:, j]) * factor
        ax.plot(mid, nominal, "r.-", lw=1.0, ms=3, label="nominal simulation")
        corr = d.corrected_replays.get(i)
        if corr is not None:
            feats = adapter.log_features(p, corr)
            after = (p.real[group][:, j] - feats[group][:, j]) * factor
            ax.plot(mid, after, "g.-", lw=1.0, ms=3, label=_best_label(d))
        for ev in (e for e in d.transients.events if e.log_index == i):
            ax.axvspan(
                ev.start_s,
                ev.end_s,
                facecolor="none",
                edgecolor="tab:red" if ev.excluded else "tab:orange",
                hatch="///",
                lw=0.8,
                zorder=1,
            )
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_ylabel(f"real − sim [{unit_name}]" if unit_name else "real − sim")
        ax.set_title(p.name, fontsize=8, loc="left")
    axes[-1, 0].set_xlabel("time since the start of the run [s]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    handles += list(seen_regimes.values())
    labels += [regime_name(r).replace("while ", "") for r in seen_regimes]
    if d.transients.events:
        from matplotlib.patches import Patch

        handles.append(Patch(facecolor="none", edgecolor="tab:red", hatch="///"))
        labels.append("transient event")
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=7, frameon=False)
    fig.suptitle(
        f"Residual over time: {channel_name(group, column)} per "
        f"{d.settings.features.window_s:g} s window (held-out runs)",
        fontsize=11,
    )
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    name = f"{prefix}timeline.png"
    from realitygap.core.io import atomic_write

    atomic_write(out / name, lambda fh: fig.savefig(fh, dpi=_DPI, format="png"))
    plt.close(fig)
    return (
        name,
        f"The {channel_name(group, column)} residual over each held-out run, motion regimes "
        "shaded behind it, transient events hatched",
    )


def _residuals(d: Diagnosis, out: Path, prefix: str, plt: Any) -> tuple[str, str] | None:
    named = d.verdict.kind is VerdictKind.EFFECTS
    table = d.shrink if named else d.shrink_best
    bars = [r for r in table if r["column"] != "all" and r.get("n", 1) > 0]
    if not bars:
        return None
    units = sorted({plot_unit(r["unit"])[0] for r in bars})
    fig, axes = plt.subplots(
        len(units), 1, figsize=(max(8.0, 0.42 * len(bars)), 3.4 * len(units) + 0.6), squeeze=False
    )
    after_label = _best_label(d)
    for ax, unit_name in zip(axes[:, 0], units):
        rows = [r for r in bars if plot_unit(r["unit"])[0] == unit_name]
        factor = [plot_unit(r["unit"])[1] for r in rows]
        x = np.arange(len(rows))
        ax.bar(x - 0.2, [r["rms_before"] * f for r, f in zip(rows, factor)], 0.4,
               color="tab:red", label="nominal simulation")  # fmt: skip
        ax.bar(x + 0.2, [r["rms_after"] * f for r, f in zip(rows, factor)], 0.4,
               color="tab:green", label=after_label)  # fmt: skip
        labels = [
            f"{channel_name(r['group'], r['column'])}\n{regime_name(r['regime'])}" for r in rows
        ]
        ax.set_xticks(x, labels, rotation=60, ha="right", fontsize=7)
        ax.set_ylabel(f"RMS per window [{unit_name}]" if unit_name else "RMS per window")
        ax.set_ylim(bottom=0.0)
        ax.legend(fontsize=7)
    fig.suptitle("Held-out residual per channel and motion regime", fontsize=11)
    name = f"{prefix}residuals.png"
    _save(fig, out, name, plt)
    return name, "Held-out residual per channel and motion regime, before and after"


def _ranking(d: Diagnosis, out: Path, prefix: str, plt: Any) -> tuple[str, str] | None:
    rows = ranking_by_shrink(d.ranking_rows())[:12]
    if not rows:
        return None
    floor = -50.0
    fig, ax = plt.subplots(figsize=(7.8, 0.38 * len(rows) + 1.6))
    names = [r["name"] + (" ✓" if r["verified_in_pybullet"] else "") for r in rows][::-1]
    vals = [float(r["heldout_shrink_pct"]) for r in rows][::-1]
    shown = [max(floor, v) for v in vals]
    ax.barh(names, shown, color=["tab:green" if v > 0 else "tab:gray" for v in vals])
    for k, (v, s) in enumerate(zip(vals, shown)):
        if v < s:  # beyond the axis: say so with the value
            ax.annotate(f"◀ {v:.0f} %", (floor, k), xytext=(3, 0), textcoords="offset points",
                        va="center", fontsize=7, color="white")  # fmt: skip
    ax.set_xlim(floor, 100.0)
    ax.set_ylim(-0.6, len(rows) + 0.2)
    ax.set_xlabel("held-out gap closed [%]  (✓ verified in PyBullet)")
    ax.set_title("Candidate effects by held-out shrink", fontsize=11)
    name = f"{prefix}ranking.png"
    _save(fig, out, name, plt)
    return name, "Candidate effects ranked by the share of the held-out gap they close"


def _localisation(d: Diagnosis, out: Path, prefix: str, plt: Any) -> tuple[str, str] | None:
    table = where_rows(d, 12)
    if not table:
        return None
    fig, ax = plt.subplots(figsize=(7.8, 0.36 * len(table) + 1.4))
    names = [f"{channel_name(r['where'], r['column'])}, {regime_name(r['regime'])}" for r in table]
    ax.barh(names[::-1], [100 * r["share"] for r in table][::-1], color="tab:orange")
    ax.set_xlabel("share of the gap (normalised squared residual) [%]")
    ax.set_xlim(0.0, max(5.0, 100 * max(r["share"] for r in table) * 1.1))
    ax.set_title("Where the gap is (nominal simulation against the real runs)", fontsize=11)
    name = f"{prefix}localisation.png"
    _save(fig, out, name, plt)
    return name, "Where the gap is: share per channel and motion regime"


def _agreement(d: Diagnosis, out: Path, prefix: str, plt: Any) -> tuple[str, str] | None:
    chosen = next((f for f in d.ranking if f.verified and f.effects), None)
    if chosen is None or not d.corrected_replays or chosen.effects != d.ranking[0].effects:
        return None
    adapter = d.problem.adapter
    point = {k: np.array([v]) for k, v in chosen.values.items()}
    xs, ys = [], []
    for i, rep in d.corrected_replays.items():
        p = d.prepared[i]
        pb = adapter.log_features(p, rep)
        sur = adapter.surrogate_features(p, point, d.problem.drive)
        for g in p.groups:
            s = d.settings.features.scale(g)
            xs.append(((pb[g] - p.nominal[g]) / s).ravel())
            ys.append(((sur[g][0] + p.bias[g] - p.nominal[g]) / s).ravel())
    if not xs:
        return None
    xa, ya = np.concatenate(xs), np.concatenate(ys)
    fig, ax = plt.subplots(figsize=(5.0, 4.8))
    ax.plot(xa, ya, ".", ms=3, alpha=0.5)
    lim = float(np.max(np.abs(np.concatenate([xa, ya])))) or 1.0
    ax.plot([-lim, lim], [-lim, lim], "k:", lw=1, label="perfect agreement")
    ax.set_xlabel("PyBullet: change of a window feature [feature scales]")
    ax.set_ylabel("surrogate: change of a window feature [feature scales]")
    ax.legend(fontsize=7)
    groups = ", ".join(group_name(g) for g in d.prepared[0].groups)
    ax.set_title(f"Surrogate against PyBullet: {chosen.name}\n({groups})", fontsize=10)
    name = f"{prefix}surrogate_agreement.png"
    _save(fig, out, name, plt)
    return name, "The fast surrogate against PyBullet at the fitted values"


def _transients(d: Diagnosis, out: Path, prefix: str, plt: Any) -> tuple[str, str] | None:
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
        "Transient events per run\n(red: stall or slip, purple: ground truth frozen — set "
        "aside; orange: residual outlier, kept; blue: held-out run, grey: training run)",
        fontsize=9,
    )
    name = f"{prefix}transients.png"
    _save(fig, out, name, plt)
    return (name, "Transient events on each run's timeline")
