"""Learning-curve figures of training runs."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from realitygap.baselines.rl.persistence import read_csv
from realitygap.core.io import atomic_write


def learning_curve_files(
    run_dir: str | os.PathLike[str], label: str | None = None
) -> tuple[str, Path | None, Path | None]:
    """``(label, episodes.csv, eval.csv)`` of a training folder (missing files as ``None``)."""
    d = Path(run_dir)
    ep, ev = d / "episodes.csv", d / "eval.csv"
    return (label or d.name, ep if ep.is_file() else None, ev if ev.is_file() else None)


def plot_learning_curve(run_dir: str | os.PathLike[str], window: int = 100) -> Path | None:
    """Plot one training folder's learning curve to ``<run_dir>/learning_curve.png``."""
    d = Path(run_dir)
    return plot_learning_curves([learning_curve_files(d)], d / "learning_curve.png", window)


def plot_learning_curves(
    curves: Sequence[tuple[str, Path | None, Path | None]],
    out: str | os.PathLike[str],
    window: int = 100,
) -> Path | None:
    """Plot learning curves: training success and return (rolling mean over ``window``
    episodes) and the strict / within-10-cm success of the evaluations.

    ``curves`` holds ``(label, episodes_csv, eval_csv)`` per run. Returns the PNG path, or
    ``None`` when matplotlib is not installed.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    out_path = Path(out)
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for label, ep, ev in curves:
        if ep is not None and Path(ep).is_file():
            rows = read_csv(ep)
            if rows:
                steps = np.array([float(r["timesteps"]) for r in rows])
                succ = np.array([float(r["success"]) for r in rows])
                ret = np.array([float(r["return"]) for r in rows])
                k = max(1, min(window, len(rows)))
                kernel = np.ones(k) / k
                axes[0].plot(
                    steps[k - 1 :],
                    np.convolve(succ, kernel, "valid"),
                    label=f"{label}: training (curriculum tolerances)",
                )
                axes[1].plot(steps[k - 1 :], np.convolve(ret, kernel, "valid"), label=label)
        if ev is not None and Path(ev).is_file():
            rows = read_csv(ev)
            if rows:
                steps = np.array([float(r["timesteps"]) for r in rows])
                axes[0].plot(
                    steps, [float(r["success"]) for r in rows], "o-", label=f"{label}: eval strict"
                )
                axes[0].plot(
                    steps,
                    [float(r["reached_10cm"]) for r in rows],
                    "s--",
                    label=f"{label}: eval within 10 cm",
                )
    axes[0].set_xlabel("env steps")
    axes[0].set_ylabel("success rate")
    axes[0].set_ylim(-0.02, 1.02)
    axes[1].set_xlabel("env steps")
    axes[1].set_ylabel(f"episode return (rolling {window})")
    for ax in axes:
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.tight_layout()
    try:
        return atomic_write(out_path, lambda fh: fig.savefig(fh, dpi=110, format="png"))
    finally:
        plt.close(fig)
