"""Words before numbers: the opening sentences of a diagnosis, and the names a person reads.

:func:`summary_sentences` turns a :class:`~realitygap.diagnosis.diagnose.Diagnosis`
into a few sentences — what was compared with what, where the gap lies (in plain
names: "heading, while accelerating"), which effect explains it with its fitted
value in engineering units at the precision its uncertainty allows, how much of
the held-out gap it closes, the verdict rule next to the numbers it was applied
to, and what remains. The terminal (``realitygap diagnose``, ``realitygap run``)
and the report (:mod:`realitygap.diagnosis.report.writer`) print the same sentences.

:func:`channel_name`, :func:`regime_name` and :func:`quantity` (of
:mod:`realitygap.diagnosis.problem.units`, where the stages find it too) are the one place
where feature columns, motion regimes and values get their human form; tables and
figure labels use them too. :func:`ranking_by_shrink` orders candidates by what
the reader compares: the held-out shrink.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from realitygap.diagnosis.problem.parameters import split_key
from realitygap.diagnosis.problem.shrink import concentrated_gap
from realitygap.diagnosis.problem.units import quantity
from realitygap.diagnosis.verdict.types import VerdictKind

if TYPE_CHECKING:
    from realitygap.diagnosis.diagnose import Diagnosis

__all__ = [
    "change_words",
    "channel_name",
    "data_words",
    "group_name",
    "quantity",
    "ranking_by_shrink",
    "regime_name",
    "stage_split",
    "summary_sentences",
    "value_words",
]

GROUP_NAMES: dict[str, str] = {
    "pose_gt": "ground-truth motion",
    "ticks": "wheel encoders",
    "pose_cam": "camera pose",
    "tool_dist": "tool-point distances",
    "tether": "tether",
    "surface": "ride height",
}
"""Feature group → what a person calls it."""

CHANNEL_NAMES: dict[tuple[str, str], str] = {
    ("pose_gt", "dx"): "forward travel",
    ("pose_gt", "dy"): "sideways travel",
    ("pose_gt", "dtheta"): "heading",
    ("ticks", "left"): "left wheel travel",
    ("ticks", "right"): "right wheel travel",
    ("pose_cam", "ex"): "camera forward position",
    ("pose_cam", "ey"): "camera sideways position",
    ("pose_cam", "etheta"): "camera heading",
    ("tether", "length"): "tether length",
    ("surface", "height"): "ride height",
}
"""(feature group, column) → what a person calls it; other columns fall back to
``"<group name> <column>"``."""

REGIME_NAMES: dict[str, str] = {
    "all": "over all motions",
    "standing": "while standing",
    "straight": "while driving straight",
    "turning_ccw": "while turning left",
    "turning_cw": "while turning right",
    "accelerating": "while accelerating",
}
"""Motion regime → the phrase that follows a channel name."""

DRIVE_WORDS: dict[str, str] = {
    "commands": "driven by the logged velocity commands (what the simulated robot was told)",
    "ticks": "driven by the logged wheel rotation (what the encoders counted)",
}


def change_words(
    shrink_pct: float | None, *, less: str = "less", more: str = "more", digits: int = 0
) -> str:
    """A shrink in percent (positive: the gap got smaller) in words whose direction comes
    from its sign: ``"70 % less"``, ``"worse: 70 % more"``, ``"about the same"``.

    Every sentence that states a signed change says it through this function, so that a
    candidate that makes the gap larger is never said to make it smaller ("-70 % less").

    Parameters
    ----------
    shrink_pct : float or None
        ``100 · (before − after) / before``; None or NaN when unknown.
    less, more : str
        The words after the number for a smaller and a larger gap (``"closed"``,
        ``"wider"``).
    digits : int
        Decimals shown.
    """
    if shrink_pct is None or not math.isfinite(float(shrink_pct)):
        return "change unknown"
    pct = float(shrink_pct)
    if round(abs(pct), digits) == 0:
        return "about the same"
    if pct > 0:
        return f"{pct:.{digits}f} % {less}"
    return f"worse: {-pct:.{digits}f} % {more}"


def _pose_indexed(channels: set[str]) -> bool:
    """Whether logs with these channels are poses at stations, not samples in time (the rule
    of the table importer: only joint readings and measured points)."""
    from realitygap.diagnosis.logs.importers.csv_log import POSE_ROW_CHANNELS

    return bool(channels) and channels <= set(POSE_ROW_CHANNELS)


def data_extent(logs: Sequence[Any]) -> str:
    """How much data the logs hold, in the unit their rows have: ``"598 s of motion"`` for
    logs in time, ``"1,200 measured poses"`` for pose-indexed ones (an arm's tracker
    measurements, whose row times only number the poses)."""
    channels = {c for lg in logs for c in lg.channels}
    if _pose_indexed(channels):
        return f"{sum(int(lg.n) for lg in logs):,} measured poses"
    return f"{sum(float(lg.duration) for lg in logs):.0f} s of motion"


def data_words(logs: Sequence[Any], drive: str, window_s: float) -> str:
    """What the replay was driven by and how it was cut, from what the logs hold: logged
    commands or wheel rotation over time windows, or joint readings at measured poses.

    Parameters
    ----------
    logs : sequence of Log
        The real logs (their :attr:`channels`).
    drive : str
        The requested drive (``"commands"`` or ``"ticks"``).
    window_s : float
        Window length, s (for logs in time).
    """
    channels = {c for lg in logs for c in lg.channels}
    if _pose_indexed(channels):
        return (
            f"replayed from the logged joint readings at {data_extent(logs)} (the rows are "
            "poses at stations, not instants in time: no commands), group of poses by group "
            "of poses"
        )
    source = {"commands": "cmd", "ticks": "ticks"}.get(drive)
    if source in channels:
        words = DRIVE_WORDS[drive]
    else:
        held = ", ".join(sorted(channels)) or "no channel"
        words = f"replayed from what the logs hold ({held}; no {drive} channel)"
    return f"{words}, window by window ({window_s:g} s windows)"


def group_name(group: str) -> str:
    """The human name of a feature group (``"ticks"`` → ``"wheel encoders"``)."""
    return GROUP_NAMES.get(group, group.replace("_", " "))


def channel_name(group: str, column: str) -> str:
    """The human name of a feature column (``("pose_gt", "dtheta")`` → ``"heading"``)."""
    if (group, column) in CHANNEL_NAMES:
        return CHANNEL_NAMES[(group, column)]
    if column == "all":
        return group_name(group)
    return f"{group_name(group)} {column.replace('_', ' ')}"


def regime_name(regime: str) -> str:
    """The phrase for a motion regime (``"accelerating"`` → ``"while accelerating"``)."""
    return REGIME_NAMES.get(regime, f"while {regime.replace('_', ' ')}")


def value_words(key: str, param: Mapping[str, Any], description: str = "") -> str:
    """One fitted parameter in words: what it is, its value, how far from nominal.

    Parameters
    ----------
    key : str
        ``"effect.param"``.
    param : mapping
        ``value``, ``stderr``, ``unit``, ``nominal`` (a row of
        :meth:`Diagnosis.ranking_rows`).
    description : str
        What the parameter is (its ``ParamSpec.description``).
    """
    value, unit = float(param["value"]), str(param["unit"])
    stderr = float(param.get("stderr", math.nan))
    nominal = float(param.get("nominal", math.nan))
    name = split_key(key)[1]
    what = f"{description} ({name})" if description else name
    text = f"{what} = {quantity(value, unit, stderr)}"
    if math.isfinite(stderr) and stderr > 0 and abs(value - nominal) < stderr:
        return text + ", not resolved from its nominal value by these logs"
    if unit == "1" and math.isfinite(nominal) and nominal != 0:
        pct = 100.0 * (value / nominal - 1.0)
        text += f", {abs(pct):.2g} % {'above' if pct > 0 else 'below'} nominal {nominal:g}"
    return text


def ranking_by_shrink(rows: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """Ranking rows ordered by held-out shrink, largest first (ties keep their rank)."""
    return sorted(rows, key=lambda r: (-float(r.get("heldout_shrink_pct", -math.inf)), r["rank"]))


def _param_descriptions(effects: Sequence[str]) -> dict[str, str]:
    from realitygap.robots.effects import EFFECTS

    out = {}
    for e in effects:
        cls = EFFECTS.get(e)
        if cls is None:
            continue
        for spec in cls.specs:
            out[f"{e}.{spec.name}"] = spec.description
    return out


def _kind_words(v: Any) -> str:
    """The verdict's kind in words."""
    if v.kind is VerdictKind.EFFECTS:
        return f"{' + '.join(v.effects)} ({v.confidence.value} confidence)"
    if v.kind is VerdictKind.PARTIAL:
        return f"partly {' + '.join(v.effects)} ({v.confidence.value} confidence)"
    if v.kind is VerdictKind.NONE:
        return "no significant gap"
    return "unexplained — no effect is named"


def _rest_over_noise(residual: Mapping[str, Any]) -> tuple[float, str]:
    """Largest ratio of the remaining residual to its noise level, and where."""
    worst, where = 0.0, ""
    for g, info in residual.get("groups", {}).items():
        for ratio, place in (
            (info.get("excess_ratio", 0.0), group_name(g)),
            (info.get("worst_concentration", 0.0), info.get("worst_concentration_where", "")),
        ):
            if ratio is not None and math.isfinite(ratio) and ratio > worst:
                worst, where = float(ratio), str(place) or group_name(g)
                if place and place != group_name(g):
                    col, _, reg = str(place).partition(" while ")
                    where = channel_name(g, col) + (f", {regime_name(reg)}" if reg else "")
    return worst, where


def where_rows(d: Diagnosis, n: int = 3) -> list[dict[str, Any]]:
    """The ``n`` channel-and-regime cells with the largest share of the nominal gap."""
    table = [
        r
        for r in d.localisation.get("table", [])
        if r.get("kind") == "channel" and r.get("regime") != "all"
    ]
    return sorted(table, key=lambda r: -float(r.get("share", 0.0)))[:n]


def stage_split(d: Diagnosis) -> tuple[float, float] | None:
    """Shares (%) of the adapter's two :attr:`drive_stages` (up to the actuators, after
    them) in what both carry (normalised sums of squares over every window), or ``None``
    where the adapter names none or the diagnosis holds not both."""
    from realitygap.diagnosis.adapters.registry import get_adapter

    names = get_adapter(d.settings.robot).drive_stages
    if names is None:
        return None
    ss: dict[str, float] = {}
    for r in d.localisation.get("overall", []):
        if r["kind"] == "stage":
            ss[r["where"]] = ss.get(r["where"], 0.0) + float(r["normalised_ss"])
    a, b = ss.get(names[0]), ss.get(names[1])
    if a is None or b is None or a + b <= 0:
        return None
    return 100.0 * a / (a + b), 100.0 * b / (a + b)


def summary_sentences(d: Diagnosis) -> list[str]:
    """The opening sentences of a diagnosis report (see the module docstring)."""
    js_logs = {
        "train": [p.name for p in d.prepared if p.split == "train"],
        "holdout": [p.name for p in d.prepared if p.split == "holdout"],
    }
    robot = {"diffdrive": "differential drive", "arm": "arm", "climber": "climbing robot"}.get(
        d.settings.robot, d.settings.robot
    )
    drive = data_words([p.log for p in d.prepared], d.settings.drive, d.settings.features.window_s)
    held = (
        f"{len(js_logs['holdout'])} held-out run(s)"
        if js_logs["holdout"]
        else "held-out blocks of windows of the same runs"
    )
    out = [
        f"Compared {len(js_logs['train'])} recorded training run(s) and {held} of the real "
        f"{robot} with its nominal PyBullet simulation, {drive}."
    ]
    cells = where_rows(d)
    if cells:
        parts = [
            f"{channel_name(c['where'], c['column'])}, {regime_name(c['regime'])} "
            f"({100 * c['share']:.0f} % of the gap; RMS {quantity(c['rms'], c['unit'])} per window)"
            for c in cells
        ]
        out.append("The gap lies mostly in " + "; then ".join(parts) + ".")
    split = stage_split(d)
    if split is not None:
        out.append(
            f"By pipeline stage, {split[0]:.0f} % of it lies between the commands and the wheels "
            "(what the encoders counted against what the commands asked of the nominal drive "
            f"train) and {split[1]:.0f} % between the wheels and the body (the ground truth "
            "against the encoders)."
        )
    g = d.gap
    v = d.verdict
    budget = d.budget
    if budget is not None:
        # the answer first: the budget, its rule, what varies between sessions
        answer = [v.notes.verdict_text or budget.sentence()]
        answer.append(f"Verdict: {_kind_words(v)} — {budget.rule}.")
        for e in budget.entries:
            if not e.constant:
                ranges = "; ".join(
                    f"{k.split('.', 1)[-1]} {p['min']:.4g} … {p['max']:.4g}"
                    for k, p in e.stability["parameters"].items()
                )
                answer.append(
                    f"{e.effect.replace('_', ' ')} varies between {e.stability['unit']}s "
                    f"({ranges}): a finding in itself, not a constant of the robot."
                )
        out[1:1] = answer
        if budget.entries:
            entries = budget.to_json()["entries"]
            descs = _param_descriptions([e["effect"] for e in entries])
            vals = "; ".join(
                value_words(k, p, descs.get(k, ""))
                for e in entries
                for k, p in e["parameters"].items()
            )
            sentence = f"The budget's model: {vals}"
            if "heldout_trajectory_gap_m_best" in g:
                traj = g.get("heldout_trajectory_shrink_pct_best")
                sentence += (
                    "; replayed in PyBullet, the held-out runs' RMS position error goes from "
                    f"{quantity(g['heldout_trajectory_gap_m_nominal'], 'm')} nominal to "
                    f"{quantity(g['heldout_trajectory_gap_m_best'], 'm')}"
                    + (f" ({change_words(float(traj))})" if traj is not None else "")
                )
            out.append(sentence + ".")
    conc = concentrated_gap(g.get("heldout_trajectory_runs", []))
    if conc is not None:
        own = quantity(conc["before_m"], "m") + " nominal"
        others = quantity(conc["rest_before_m"], "m") + " nominal"
        if "after_m" in conc:
            own += f", {quantity(conc['after_m'], 'm')} with the best candidate"
            others += f" → {quantity(conc['rest_after_m'], 'm')}"
        out.append(
            f"One held-out run, {conc['log']}, carries {conc['share_pct']:.0f} % of the whole-run "
            f"gap (its squared position error; its own RMS error is {own}); over the other "
            f"{conc['runs']} runs the gap is {others}."
        )
    reasons = v.residual.get("reasons", []) if v.kind is not VerdictKind.NONE else []
    if reasons and v.residual.get("structured"):
        out.append("What remains: " + "; ".join(reasons[:3]) + ".")
    elif v.kind is not VerdictKind.NONE:
        out.append("What remains looks like measurement noise.")
    cov = d.coverage
    if cov is not None and cov.beyond_training:
        out.append(f"Beyond the training: {cov.summary()}.")
    reach = v.notes.reach
    if reach is not None:
        msg = str(reach["message"])
        out.append(
            f"What the library could reach: {msg[0].upper()}{msg[1:]} (what training over the "
            "held-out motions could do, not a score)."
        )
    return out
