"""The experiment registry behind ``realitygap run``.

An experiment is a function ``f(ctx: RunContext) -> dict`` registered with
:func:`experiment`. It returns ``{"figures": {name: number, ...}, "config":
{...}}`` and may add ``"tables"`` (name → list of row dicts) and ``"notes"``
(list of str). The runner adds the experiment's name, prints a table and writes
the JSON atomically.

Experiment modules are listed in ``_MODULES`` and imported on first use, so the
CLI starts fast and an experiment's heavy dependencies load only when it runs.
"""

from __future__ import annotations

import difflib
import importlib
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from realitygap.core.checks import UnknownNameError, check_nonnegative_int
from realitygap.core.io import write_json

_MODULES = (
    "realitygap.experiments.nav",
    "realitygap.experiments.calib000",
    "realitygap.experiments.vo",
    "realitygap.experiments.umbmark_real",
    "realitygap.experiments.arm",
    "realitygap.experiments.climb",
    "realitygap.experiments.diagnosis",
    "realitygap.experiments.splits",
    "realitygap.experiments.scaling",
    "realitygap.experiments.independent",
    "realitygap.experiments.teleop",
    "realitygap.experiments.benchmark",
    "realitygap.experiments.twin_transfer",
    "realitygap.experiments.nav_stress",
)


@dataclass
class RunContext:
    """What an experiment is told: quick mode, base seed, data folder, a progress sink."""

    quick: bool = False
    seed: int = 0
    data_dir: Path | None = None
    options: dict[str, Any] = field(default_factory=dict)
    verbose: bool = True
    data_used: dict[str, str] = field(default_factory=dict)
    """Data folders the experiment read (sub-folder name → path or sample description)."""
    plots: dict[str, bytes] = field(default_factory=dict)
    """Figures the experiment drew, by file name, for its report (:meth:`add_plot`)."""
    diagnoses: list[tuple[str, Any]] = field(default_factory=list)
    """Diagnoses the experiment made, labelled, for its report (:meth:`add_diagnosis`)."""

    expected_s: float = math.nan
    """The experiment's own estimate of its duration, s (:meth:`expect`); ``nan``: none."""

    def expect(self, seconds: float) -> None:
        """State how long the run is expected to take, s (progress shows the time left)."""
        self.expected_s = float(seconds)
        self.progress(
            f"this run takes roughly {seconds / 60:.0f} min"
            if seconds >= 90
            else f"this run takes roughly {seconds:.0f} s"
        )

    def add_plot(self, name: str, png: bytes) -> None:
        """Hand a figure (PNG bytes, file name ``name``) to the run's report."""
        if not name.endswith(".png") or "/" in name or name in self.plots:
            raise ValueError(f"a plot needs a new file name ending in .png, got {name!r}")
        self.plots[name] = png

    def add_diagnosis(self, label: str, diagnosis: Any) -> None:
        """Hand a :class:`~realitygap.diagnosis.diagnose.Diagnosis` to the run's report."""
        self.diagnoses.append((label, diagnosis))

    def check(self) -> RunContext:
        """Validate the fields (``ValueError``/``TypeError`` naming the option); returns self."""
        self.seed = check_nonnegative_int(
            self.seed, "--seed", fix="seeds of NumPy generators and envs are ≥ 0"
        )
        if not isinstance(self.quick, bool):
            raise TypeError(f"quick must be True or False, got {self.quick!r}")
        if not isinstance(self.options, dict):
            raise TypeError(f"options must be a dict, got {type(self.options).__name__}")
        return self

    def progress(self, message: str) -> None:
        """Report progress of a long run on stderr (keeps stdout for the result table)."""
        if self.verbose:
            print(f"[{time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)

    def data_subdir(self, name: str) -> Path:
        """The sub-folder ``name`` of the data folder, or a clear error when it is missing.

        Without a data folder, a sample embedded in the package stands in where one
        exists (:mod:`realitygap.samples`). Every folder handed out is recorded in
        :attr:`data_used` (name → description), which the runner adds to the result.
        """
        if self.data_dir is None:
            from realitygap.samples import SAMPLES, sample_dir

            if name in SAMPLES:
                path = sample_dir(name)
                self.data_used[name] = f"{SAMPLES[name]} ({path}); --data DIR reads a full set"
                self.progress(f"data: {name}: {self.data_used[name]}")
                return path
            raise FileNotFoundError(
                f"this experiment reads recorded data from '<data>/{name}/'; no data folder was "
                "found: pass --data DIR (a folder laid out like shared/data/)"
            )
        path = Path(self.data_dir) / name
        if not path.is_dir():
            raise FileNotFoundError(
                f"--data {self.data_dir}: expected its sub-folder '{name}/' with recorded data "
                f"(a folder laid out like shared/data/); {path} does not exist. Fix: pass the "
                "data folder that holds it, or leave --data out to use the embedded sample"
            )
        self.data_used[name] = str(path)
        self.progress(f"data: {name}: {path}")
        return path


ExperimentFunc = Callable[[RunContext], dict[str, Any]]


@dataclass(frozen=True)
class Experiment:
    name: str
    func: ExperimentFunc
    description: str
    data_subdir: str | None = None
    robots: tuple[str, ...] = ()
    """Robots the experiment can run for (``realitygap run NAME --robot R``); empty: one."""
    variants: tuple[str, ...] = ()
    """Named worlds the experiment can run on (``realitygap run NAME --variant V``); empty: one."""


EXPERIMENTS: dict[str, Experiment] = {}


def experiment(
    name: str,
    description: str,
    data_subdir: str | None = None,
    robots: tuple[str, ...] = (),
    variants: tuple[str, ...] = (),
) -> Callable[[ExperimentFunc], ExperimentFunc]:
    """Decorator registering an experiment under ``name`` (``robots``, ``variants``: see
    :class:`Experiment`)."""

    def register(func: ExperimentFunc) -> ExperimentFunc:
        if name in EXPERIMENTS and EXPERIMENTS[name].func is not func:
            raise ValueError(f"experiment {name!r} is registered twice")
        EXPERIMENTS[name] = Experiment(
            name, func, description, data_subdir, tuple(robots), tuple(variants)
        )
        return func

    return register


def load_all() -> dict[str, Experiment]:
    """Import every experiment module and return the registry."""
    for module in _MODULES:
        importlib.import_module(module)
    return EXPERIMENTS


def get(name: str) -> Experiment:
    """The experiment called ``name``; a ``KeyError`` that suggests close names on a typo."""
    registry = load_all()
    if name not in registry:
        close = difflib.get_close_matches(name, list(registry), n=3)
        hint = f" Did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        raise UnknownNameError(
            f"no experiment named {name!r}.{hint} Known: {', '.join(sorted(registry))}"
        )
    return registry[name]


def format_figures(result: dict[str, Any]) -> str:
    """A readable two-column table of an experiment's figures."""
    figures = result.get("figures", {})
    width = max([len(k) for k in figures] + [6])
    lines = [
        f"experiment: {result.get('experiment', '?')}",
        f"{'figure':<{width}}  value",
        "-" * (width + 14),
    ]
    for key, value in figures.items():
        if isinstance(value, float):
            text = f"{value:.4g}"
        else:
            text = str(value)
        lines.append(f"{key:<{width}}  {text}")
    for note in result.get("notes", []):
        lines.append(f"note: {note}")
    for name, used in result.get("data", {}).items():
        lines.append(f"data: {name}: {used}")
    return "\n".join(lines)


def run(
    name: str,
    ctx: RunContext,
    json_path: str | os.PathLike[str] | None = None,
    report_dir: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """Run experiment ``name`` and return its result (also written to ``json_path`` if given).

    With ``report_dir``, the diagnoses the experiment made (:meth:`RunContext.add_diagnosis`)
    are written there as a report (``report.html``, ``report.md``, ``diagnosis.json``,
    figures) and ``result["report"]`` names the HTML file.
    """
    exp = get(name)
    ctx.check()
    if exp.data_subdir is not None:  # the data the experiment reads is there, before its work
        ctx.data_subdir(exp.data_subdir)
    start = time.perf_counter()
    out = exp.func(ctx)
    if "figures" not in out:
        raise RuntimeError(f"experiment {name!r} returned no 'figures'")
    result = {"experiment": name, "figures": out["figures"], "config": out.get("config", {})}
    for key in ("tables", "notes"):
        if key in out:
            result[key] = out[key]
    result["config"] = {"quick": ctx.quick, "seed": ctx.seed, **result["config"]}
    if ctx.data_used:
        result["data"] = dict(ctx.data_used)
    result["wall_seconds"] = time.perf_counter() - start
    if report_dir is not None and ctx.diagnoses:
        from realitygap.diagnosis.report.writer import write_reports

        ctx.progress(f"writing the report into {report_dir}")
        result["report"] = str(
            write_reports(
                ctx.diagnoses,
                report_dir,
                title=f"{name}: {exp.description}",
                intro=[f"{k}: {v}" for k, v in result.get("data", {}).items()],
            )
        )
    if report_dir is not None and ctx.plots:
        result["report"] = str(_write_plots(name, exp.description, result, ctx, Path(report_dir)))
    if json_path is not None:
        write_json(json_path, result)
    return result


REPORT_TABLE_ROWS = 60
"""Rows of a table that ``report.md`` shows; the JSON keeps them all."""


def _write_plots(
    name: str, description: str, result: dict[str, Any], ctx: RunContext, folder: Path
) -> Path:
    """The experiment's figures as PNG files in ``folder``; without a diagnosis report there,
    also ``report.md``: the figures, the figures' table and each table. Returns the report."""
    from realitygap.core.io import atomic_write_bytes, atomic_write_text

    folder.mkdir(parents=True, exist_ok=True)
    for file, png in ctx.plots.items():
        atomic_write_bytes(folder / file, png)
    if ctx.diagnoses:
        return folder / "report.html"
    lines = [f"# {name}", "", description, ""]
    lines += [f"![{file}]({file})" for file in ctx.plots]
    lines += ["", "```text", format_figures(result), "```", ""]
    for table, rows in result.get("tables", {}).items():
        if not rows:
            continue
        keys = list(rows[0])
        lines += [f"## {table}", "", "| " + " | ".join(keys) + " |"]
        lines.append("|" + "---|" * len(keys))
        for row in rows[:REPORT_TABLE_ROWS]:
            cells = (f"{v:.3g}" if isinstance(v, float) else str(v) for v in row.values())
            lines.append("| " + " | ".join(cells) + " |")
        if len(rows) > REPORT_TABLE_ROWS:
            lines += ["", f"… and {len(rows) - REPORT_TABLE_ROWS} more rows in the JSON."]
        lines.append("")
    return atomic_write_text(folder / "report.md", "\n".join(lines))
