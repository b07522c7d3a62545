r"""Borenstein's UMBmark calibration of differential-drive odometry.

The robot drives an ``L × L`` square ``n`` times clockwise (cw) and ``n`` times
counter-clockwise (ccw), steered by its own (uncalibrated) odometry, and the
end pose measured by an absolute reference is compared with the end pose
computed by odometry. Two systematic errors are separated:

* ``E_d = D_R / D_L`` — unequal wheel diameters make the robot curve on the
  straight legs (type B);
* ``E_b = b_actual / b_nominal`` — a wrong wheelbase makes every 90° turn
  too short or too long (type A).

Frame convention (the one implemented here)
-------------------------------------------
Errors are expressed in the **start frame of each run**: origin at the start
point, x along the robot's initial heading, y to its left, θ counter-clockwise.
The robot starts facing +x; a cw run turns right (θ decreases, the square lies
at ``y ≤ 0``), a ccw run turns left. Borenstein & Feng draw the square in a
fixed lab frame; in the frame above their formulas hold exactly as printed,
which the first-order analysis below verifies (a frame in which the robot
starts facing +y would swap the roles of x and y).

First-order analysis
--------------------
Let ``α`` be the amount by which every 90° turn is **short** in reality (rad,
type A) and ``β`` the heading change accumulated on each straight leg, positive
when the robot curves to the left (type B, ``D_R > D_L``). Leg ``i`` starts with
heading ``φ_i`` and moves the robot by ``L [cos(φ_i + β/2), sin(φ_i + β/2)]``.
Summing the four legs to first order gives the end positions

.. math::

    x_{cw} = y_{cw} = -2L(\alpha + \beta), \qquad
    x_{ccw} = -y_{ccw} = 2L(\beta - \alpha),

so that

.. math::

    \alpha = \frac{x_{c.g.,cw} + x_{c.g.,ccw}}{-4L}, \qquad
    \beta = \frac{x_{c.g.,cw} - x_{c.g.,ccw}}{-4L},

with the centres of gravity ``x_cg = mean(ε_x)`` of the end-position errors
``ε = p_absolute − p_calculated``. Then (SEEDS_DIGEST §1.5)

.. math::

    R = \frac{L/2}{\sin(\beta/2)}, \quad
    E_d = \frac{R + b/2}{R - b/2}, \quad
    E_b = \frac{\pi/2}{\pi/2 - \alpha}, \quad
    c_L = \frac{2}{E_d + 1}, \quad c_R = \frac{2}{1/E_d + 1},

and ``E_max,syst = max(r_cg,cw, r_cg,ccw)`` with ``r_cg = √(x_cg² + y_cg²)``.
``c_L``, ``c_R`` multiply the nominal left/right distance-per-tick factors and
``E_b`` the nominal wheelbase (:meth:`DiffDriveKinematics.with_umbmark`).

References
----------
J. Borenstein, L. Feng, "Measurement and correction of systematic odometry
errors in mobile robots", IEEE Trans. Robotics and Automation 12(6), 1996.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import se2_between, wrap_angle
from realitygap.estimators.diffdrive_model import DiffDriveKinematics

FloatArray = npt.NDArray[np.float64]
Direction = Literal["cw", "ccw"]

__all__ = [
    "UMBmarkResult",
    "UMBmarkRun",
    "end_pose_error",
    "umbmark",
    "umbmark_end_errors",
    "umbmark_from_runs",
]

_DIRECTIONS = ("cw", "ccw")


@dataclass(frozen=True)
class UMBmarkResult:
    """Outcome of a UMBmark calibration (all lengths in m, angles in rad).

    Attributes
    ----------
    E_d : float
        Estimated ratio of the right to the left wheel diameter (relative to
        the nominal ratio).
    E_b : float
        Estimated ratio of the actual to the nominal wheelbase.
    c_L, c_R : float
        Correction factors for the left and right wheel distance per tick.
    alpha : float
        Per-turn shortfall of the 90° turns (type A), rad.
    beta : float
        Heading change per straight leg, positive curving left (type B), rad.
    radius : float
        Signed radius of the curved legs, m (``inf`` when ``beta == 0``).
    E_max_syst : float
        Measure of systematic odometry error, ``max(r_cg,cw, r_cg,ccw)``, m.
    x_cg_cw, y_cg_cw, x_cg_ccw, y_cg_ccw : float
        Centres of gravity of the end-position errors per direction, m.
    n_cw, n_ccw : int
        Number of runs per direction that entered the result.
    """

    E_d: float
    E_b: float
    c_L: float
    c_R: float
    alpha: float
    beta: float
    radius: float
    E_max_syst: float
    x_cg_cw: float
    y_cg_cw: float
    x_cg_ccw: float
    y_cg_ccw: float
    n_cw: int = 0
    n_ccw: int = 0

    def corrected(self, nominal: DiffDriveKinematics) -> DiffDriveKinematics:
        """``nominal`` with these corrections applied."""
        return nominal.with_umbmark(self.E_d, self.E_b)


@dataclass(frozen=True)
class UMBmarkRun:
    """One recorded square run for :func:`umbmark_from_runs`.

    Attributes
    ----------
    gt_poses : ndarray, shape (N, 3)
        Ground-truth poses ``[x, y, θ]`` (m, m, rad) of the base in any fixed
        frame; they are re-expressed in the frame of ``gt_poses[0]``.
    ticks_left, ticks_right : ndarray, shape (N,)
        Tick increments per sample; row ``k`` holds the ticks counted between
        samples ``k - 1`` and ``k`` (row 0 is normally zero).
    direction : {"cw", "ccw"}
        Direction in which the square was driven.
    """

    gt_poses: FloatArray
    ticks_left: FloatArray
    ticks_right: FloatArray
    direction: Direction


def _check_errors(name: str, errors: npt.ArrayLike) -> FloatArray:
    try:
        arr = np.asarray(errors, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a numeric array of shape (n, 3)") from exc
    if arr.ndim == 1 and arr.shape == (3,):
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] not in (2, 3):
        raise ValueError(
            f"{name} must have shape (n, 3) (rows ε = [ε_x, ε_y, ε_θ]), got {arr.shape}"
        )
    if arr.shape[0] == 0:
        raise ValueError(
            f"UMBmark needs both clockwise and counter-clockwise runs; {name} holds no run"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got NaN or inf in {arr!r}")
    return arr


def umbmark(
    cw_errors: npt.ArrayLike,
    ccw_errors: npt.ArrayLike,
    side_length: float,
    wheelbase: float,
) -> UMBmarkResult:
    r"""Borenstein's UMBmark correction factors from end-pose errors.

    Parameters
    ----------
    cw_errors, ccw_errors : array_like, shape (n, 3)
        End-pose errors ``ε = absolute − calculated`` of the clockwise and
        counter-clockwise runs, ``[ε_x, ε_y, ε_θ]`` in m, m, rad, expressed in
        the start frame of each run (robot initially facing +x, y to its
        left; see the module notes). Only ``ε_x``, ``ε_y`` are used; the
        heading column may be omitted (shape (n, 2)).
    side_length : float
        Side ``L`` of the square, m.
    wheelbase : float
        Wheelbase ``b`` used in ``E_d = (R + b/2)/(R − b/2)``, m (the nominal
        one in Borenstein's formulation).

    Returns
    -------
    UMBmarkResult

    Raises
    ------
    ValueError
        If a direction has no run, inputs are not finite, ``L`` or ``b`` is
        not positive, or the errors are too large for the first-order model
        (``|α| ≥ π/2`` or ``|R| ≤ b/2``).

    Examples
    --------
    >>> res = umbmark([[-0.02, -0.02, 0.0]], [[-0.02, 0.02, 0.0]], 4.0, 0.5)
    >>> round(res.E_b, 6), res.E_d
    (1.001594, 1.0)
    """
    cw = _check_errors("cw_errors", cw_errors)
    ccw = _check_errors("ccw_errors", ccw_errors)
    L = float(side_length)
    b = float(wheelbase)
    if not math.isfinite(L) or L <= 0.0:
        raise ValueError(f"side_length must be a positive length in m, got {side_length!r}")
    if not math.isfinite(b) or b <= 0.0:
        raise ValueError(f"wheelbase must be a positive length in m, got {wheelbase!r}")

    x_cw, y_cw = (float(v) for v in cw[:, :2].mean(axis=0))
    x_ccw, y_ccw = (float(v) for v in ccw[:, :2].mean(axis=0))
    alpha = (x_cw + x_ccw) / (-4.0 * L)
    beta = (x_cw - x_ccw) / (-4.0 * L)
    if abs(alpha) >= 0.5 * math.pi:
        raise ValueError(
            f"UMBmark turn error alpha = {alpha:.3f} rad is outside the first-order model "
            "(|alpha| < pi/2); check side_length and the error sign convention "
            "(ε = absolute − calculated, start frame)"
        )
    if beta == 0.0:
        radius = math.inf
        E_d = 1.0
    else:
        radius = (0.5 * L) / math.sin(0.5 * beta)
        if abs(radius) <= 0.5 * b:
            raise ValueError(
                f"UMBmark curvature radius R = {radius:.3f} m is not larger than b/2 = "
                f"{0.5 * b:.3f} m; the errors are too large for the first-order model"
            )
        E_d = (radius + 0.5 * b) / (radius - 0.5 * b)
    E_b = (0.5 * math.pi) / (0.5 * math.pi - alpha)
    c_L = 2.0 / (E_d + 1.0)
    c_R = 2.0 / (1.0 / E_d + 1.0)
    E_max = max(math.hypot(x_cw, y_cw), math.hypot(x_ccw, y_ccw))
    return UMBmarkResult(
        E_d=E_d,
        E_b=E_b,
        c_L=c_L,
        c_R=c_R,
        alpha=alpha,
        beta=beta,
        radius=radius,
        E_max_syst=E_max,
        x_cg_cw=x_cw,
        y_cg_cw=y_cw,
        x_cg_ccw=x_ccw,
        y_cg_ccw=y_ccw,
        n_cw=int(cw.shape[0]),
        n_ccw=int(ccw.shape[0]),
    )


def end_pose_error(
    gt_poses: npt.ArrayLike,
    ticks_left: npt.ArrayLike,
    ticks_right: npt.ArrayLike,
    kinematics: DiffDriveKinematics,
) -> FloatArray:
    """End-pose error ``ε = absolute − calculated`` of one run.

    Parameters
    ----------
    gt_poses : array_like, shape (N, 3)
        Ground-truth poses (m, m, rad) in any fixed frame.
    ticks_left, ticks_right : array_like, shape (N,)
        Tick increments per sample (all are integrated).
    kinematics : DiffDriveKinematics
        Kinematics used for the calculated (odometry) pose.

    Returns
    -------
    eps : ndarray, shape (3,)
        ``[x_gt − x_odo, y_gt − y_odo, wrap(θ_gt − θ_odo)]`` with both end poses
        expressed in the start frame ``gt_poses[0]`` (odometry starts at the origin).
    """
    gt = np.asarray(gt_poses, dtype=float)
    if gt.ndim != 2 or gt.shape[1] != 3 or gt.shape[0] < 2:
        raise ValueError(f"gt_poses must have shape (N, 3) with N >= 2, got {gt.shape}")
    if not np.all(np.isfinite(gt)):
        raise ValueError("gt_poses must be finite; found NaN or inf")
    t_l = np.asarray(ticks_left, dtype=float)
    t_r = np.asarray(ticks_right, dtype=float)
    if t_l.shape != (gt.shape[0],) or t_r.shape != (gt.shape[0],):
        raise ValueError(
            f"ticks_left/ticks_right must have shape ({gt.shape[0]},) like gt_poses rows, got "
            f"{t_l.shape} and {t_r.shape}"
        )
    gt_end = se2_between(gt[0], gt[-1])
    odo = kinematics.integrate(np.zeros(3), t_l, t_r, wrap=False)[-1]
    eps = gt_end - odo
    eps[2] = wrap_angle(gt_end[2] - odo[2])
    return eps


def _as_run(run: UMBmarkRun | Sequence[object], index: int) -> UMBmarkRun:
    if isinstance(run, UMBmarkRun):
        return run
    try:
        gt, t_l, t_r, direction = run
    except (TypeError, ValueError) as exc:
        raise TypeError(
            f"runs[{index}] must be an UMBmarkRun or a tuple (gt_poses, ticks_left, "
            f"ticks_right, direction), got {type(run).__name__}"
        ) from exc
    return UMBmarkRun(
        gt_poses=np.asarray(gt, dtype=float),
        ticks_left=np.asarray(t_l, dtype=float),
        ticks_right=np.asarray(t_r, dtype=float),
        direction=direction,  # type: ignore[arg-type]
    )


def umbmark_end_errors(
    runs: Sequence[UMBmarkRun | Sequence[object]],
    nominal_kinematics: DiffDriveKinematics,
) -> tuple[FloatArray, FloatArray]:
    """End-pose errors of cw and ccw runs.

    Parameters
    ----------
    runs : sequence of UMBmarkRun or (gt_poses, ticks_left, ticks_right, direction)
        See :class:`UMBmarkRun`.
    nominal_kinematics : DiffDriveKinematics
        Kinematics the robot's odometry used.

    Returns
    -------
    cw_errors, ccw_errors : ndarray, shape (n_cw, 3) and (n_ccw, 3)
        ``ε = absolute − calculated`` per run (see :func:`end_pose_error`).
    """
    errors: dict[str, list[FloatArray]] = {"cw": [], "ccw": []}
    for i, item in enumerate(runs):
        run = _as_run(item, i)
        direction = str(run.direction).lower()
        if direction not in _DIRECTIONS:
            raise ValueError(f"runs[{i}] direction must be 'cw' or 'ccw', got {run.direction!r}")
        errors[direction].append(
            end_pose_error(run.gt_poses, run.ticks_left, run.ticks_right, nominal_kinematics)
        )
    return (
        np.array(errors["cw"]).reshape(-1, 3),
        np.array(errors["ccw"]).reshape(-1, 3),
    )


def umbmark_from_runs(
    runs: Sequence[UMBmarkRun | Sequence[object]],
    nominal_kinematics: DiffDriveKinematics,
    side_length: float,
    *,
    wheelbase: float | None = None,
) -> UMBmarkResult:
    """UMBmark from recorded runs: ground truth vs odometry end poses.

    Parameters
    ----------
    runs : sequence of UMBmarkRun or (gt_poses (N,3), ticks_left (N,), ticks_right (N,), direction)
        Square runs; ``direction`` is ``"cw"`` or ``"ccw"``. Ground truth may be
        in any fixed frame: it is expressed in the frame of the run's first pose.
    nominal_kinematics : DiffDriveKinematics
        Kinematics of the odometry under calibration (the calculated pose).
    side_length : float
        Side of the square, m.
    wheelbase : float, optional
        ``b`` for the ``E_d`` formula; defaults to ``nominal_kinematics.wheelbase``.

    Returns
    -------
    UMBmarkResult

    Raises
    ------
    ValueError
        If only one direction is present, e.g. "UMBmark needs both clockwise
        and counter-clockwise runs; got only cw".
    """
    if not isinstance(nominal_kinematics, DiffDriveKinematics):
        raise TypeError(
            "nominal_kinematics must be a DiffDriveKinematics, got "
            f"{type(nominal_kinematics).__name__}"
        )
    cw, ccw = umbmark_end_errors(runs, nominal_kinematics)
    if cw.shape[0] == 0 or ccw.shape[0] == 0:
        got = "cw" if cw.shape[0] else ("ccw" if ccw.shape[0] else "no runs")
        got_text = f"only {got}" if got != "no runs" else got
        raise ValueError(f"UMBmark needs both clockwise and counter-clockwise runs; got {got_text}")
    b = nominal_kinematics.wheelbase if wheelbase is None else wheelbase
    return umbmark(cw, ccw, side_length, b)
