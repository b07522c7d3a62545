r"""The ``umbmark-real`` experiment: UMBmark on recorded OptiOdom sessions.

UMBmark on the real OptiOdom square sessions (:mod:`realitygap.calibrate`),
checked by dead-reckoning the held-out circular, Ivanjko and free-path
sessions from their wheel ticks.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from typing import Any

import numpy as np

from realitygap.experiments import RunContext, experiment

__all__ = ["umbmark_real", "umbmark_real_calibration"]


def _session_time(session_id: str) -> float | None:
    """Recording time (days since 2000) from an id ``DDMMYYYYhhmm``, or ``None``."""
    from realitygap.calibrate import session_time

    when = session_time(session_id)
    if when is None:
        return None
    return (when - dt.datetime(2000, 1, 1)).total_seconds() / 86400.0


def _same_period(session_id: str, calibrations: Sequence[Any]) -> list[Any]:
    """The square calibrations of the day of the square session recorded closest in time.

    Falls back to all of them when the recording times are unknown.
    """
    t = _session_time(session_id)
    times = [_session_time(c.session_id) for c in calibrations]
    if t is None or any(x is None for x in times):
        return list(calibrations)
    nearest = int(np.argmin([abs(float(x) - t) for x in times]))  # type: ignore[arg-type]
    day = calibrations[nearest].session_id[:8]
    return [c for c in calibrations if c.session_id[:8] == day]


def umbmark_real_calibration(
    root: Any,
) -> tuple[list[Any], list[Any]]:
    """UMBmark per square session below ``root`` and the other (held-out) sessions.

    Parameters
    ----------
    root : path-like
        Folder holding OptiOdom session folders (any depth).

    Returns
    -------
    calibrations : list of SessionCalibration
        One per square session.
    held_out : list of OptiOdomSession
        Every session that is not a square session.

    Raises
    ------
    ValueError
        If ``root`` holds no square session or no other session.
    """
    from realitygap.calibrate import calibrate_session
    from realitygap.diagnosis.logs.importers.optiodom import PathType, find_sessions, read_session

    sessions = [read_session(p) for p in find_sessions(root)]
    squares = [s for s in sessions if s.path_type is PathType.SQUARE]
    held_out = [s for s in sessions if s.path_type is not PathType.SQUARE]
    if not squares:
        raise ValueError(f"{root}: no square (UMBmark) session to calibrate on")
    if not held_out:
        raise ValueError(f"{root}: no circular, Ivanjko or free-path session to check on")
    return [calibrate_session(s.path) for s in squares], held_out


@experiment(
    "umbmark-real",
    "UMBmark on the real OptiOdom squares, scored on held-out circular/Ivanjko/free sessions",
    data_subdir="optiodom_diffdrive",
)
def umbmark_real(ctx: RunContext) -> dict[str, Any]:
    """UMBmark on the real square sessions, scored on the held-out sessions' ground truth.

    Each held-out session keeps its own nominal kinematics; the calibration of
    the same period (see :func:`_same_period`) enters as ``E_d`` and the
    dimensionless wheelbase ``b/D̄``.
    """
    from realitygap.calibrate import pool_calibrations

    root = ctx.data_subdir("optiodom_diffdrive")
    calibrations, held_out = umbmark_real_calibration(root)
    pooled_all = pool_calibrations(calibrations)
    ctx.progress(
        f"umbmark-real: {len(calibrations)} square sessions, pooled E_d={pooled_all.E_d:.5f}, "
        f"b/D={pooled_all.b_over_D:.4f}; {len(held_out)} held-out sessions"
    )
    run_rows = []
    for session in held_out:
        nominal = session.kinematics()
        period = pool_calibrations(_same_period(session.session_id, calibrations))
        variants = {
            "nominal": nominal,
            "calibrated": period.kinematics_for(nominal),
            "pooled": pooled_all.kinematics_for(nominal),
        }
        for run in session.runs:
            row: dict[str, Any] = {
                "session": session.session_id,
                "path_type": session.path_type.value,
                "run": run.index,
                "length_m": float(np.sum(np.hypot(*np.diff(run.gt_pose[:, :2], axis=0).T))),
                "calibrated_from": list(period.sessions),
            }
            for label, kin in variants.items():
                odo = run.odometry(kin)
                err = np.hypot(*(odo[:, :2] - run.gt_pose[:, :2]).T)
                row[f"end_err_cm_{label}"] = 100.0 * float(err[-1])
                row[f"ate_cm_{label}"] = 100.0 * float(np.sqrt(np.mean(err**2)))
            run_rows.append(row)

    def stat(rows: list[dict[str, Any]], key: str, fn: Any) -> float:
        return float(fn([r[key] for r in rows]))

    type_rows = []
    for kind in [*sorted({r["path_type"] for r in run_rows}), "all"]:
        rows = run_rows if kind == "all" else [r for r in run_rows if r["path_type"] == kind]
        entry: dict[str, Any] = {"path_type": kind, "runs": len(rows)}
        for label in ("nominal", "calibrated", "pooled"):
            for metric in ("end_err_cm", "ate_cm"):
                key = f"{metric}_{label}"
                entry[f"mean_{key}"] = stat(rows, key, np.mean)
                entry[f"median_{key}"] = stat(rows, key, np.median)
        type_rows.append(entry)
        ctx.progress(
            f"umbmark-real {kind}: median end error {entry['median_end_err_cm_nominal']:.1f} cm "
            f"nominal → {entry['median_end_err_cm_calibrated']:.1f} cm calibrated ({len(rows)} runs)"
        )
    total = type_rows[-1]
    circ = next((r for r in type_rows if r["path_type"] == "circular"), None)
    figures: dict[str, float] = {
        "heldout_end_err_cm_nominal": total["mean_end_err_cm_nominal"],
        "heldout_end_err_cm_calibrated": total["mean_end_err_cm_calibrated"],
        "heldout_ate_cm_nominal": total["mean_ate_cm_nominal"],
        "heldout_ate_cm_calibrated": total["mean_ate_cm_calibrated"],
        "E_d": pooled_all.E_d,
        "E_b": pooled_all.E_b_for(0.084, 0.200),
        "heldout_end_err_cm_pooled": total["mean_end_err_cm_pooled"],
        "heldout_runs": float(total["runs"]),
    }
    if circ is not None:
        figures["circular_median_end_err_mm_nominal"] = 10.0 * circ["median_end_err_cm_nominal"]
        figures["circular_median_end_err_mm_calibrated"] = (
            10.0 * circ["median_end_err_cm_calibrated"]
        )
    return {
        "figures": figures,
        "config": {
            "data": str(root),
            "square_sessions": [c.session_id for c in calibrations],
            "heldout_sessions": [s.session_id for s in held_out],
            "calibration_transfer": (
                "each held-out session keeps its own nominal D and b from its metadata; the "
                "UMBmark result enters as E_d and the dimensionless corrected wheelbase b/D "
                "(what UMBmark observes), i.e. E_b = (b/D)·D_nominal/b_nominal of that session. "
                "'calibrated': the square sessions of the day of the square session recorded "
                "closest in time (same period), pooled; 'pooled': all square sessions"
            ),
            "E_d_E_b": "all square sessions pooled, relative to D = 0.084 m, b = 0.200 m",
            "end_err": "distance between the dead-reckoned and the ground-truth end position, "
            "start frame",
            "ate": "RMS position error over the run, both trajectories from the same start "
            "pose (no further alignment)",
        },
        "tables": {
            "calibrations": [c.to_dict() for c in calibrations],
            "path_types": type_rows,
            "runs": run_rows,
        },
    }
