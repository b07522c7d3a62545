"""Global pose initialisation: VIO world frame ↔ blade (CAD) frame.

Gravity fixes roll and pitch in both frames, so they differ by a yaw :math:`\\psi`
and a translation :math:`t` (4 DOF):

.. math::  p^w = R_z(\\psi)\\, p^g + t ,

``w`` the VIO world frame, ``g`` the CAD frame. The tether anchor is known in the
CAD frame (:math:`a^g`) and located in the VIO frame (:math:`a^w`) by
single-point positioning (:mod:`.anchor`), so :math:`t = a^w - R_z(\\psi) a^g`
and only :math:`\\psi` remains.

**Yaw iteration (Algorithm 1).** Starting from :math:`\\psi_0`, map the
excitation trajectory into the CAD frame about the anchor,
:math:`p^g_k = R_z(\\psi)^\\top (p^w_k - a^w) + a^g`, project it on the CAD surface
at height ``h`` along the local surface normal (:class:`.SurfaceModel`; projecting
along the mis-rotated body z-axis would turn the correction's sign), and measure the yaw
:math:`\\delta` that carries the horizontal displacement vectors
:math:`m_k = (p^g_k - a^g)_{xy}` onto those of the projections
:math:`n_k = (\\pi(p^g_k) - a^g)_{xy}`,

.. math::  \\delta = \\operatorname{atan2}\\Big(\\sum_k m_k \\times n_k,
           \\sum_k m_k \\cdot n_k\\Big).

Then :math:`\\psi \\leftarrow \\psi - \\delta` until the update vanishes (a
secant step on :math:`\\delta(\\psi)` accelerates the fixed-point iteration on
gently curved surfaces, where each pass recovers only a few per cent of the error). :math:`\\partial\\delta/\\partial\\psi` measures how well the
surface's curvature observes yaw; near zero the yaw is unobservable.

**Degenerate (low-curvature) surfaces.** If the path is nearly planar the anchor's
offset from that plane is unobservable from the tether. The projected trajectory's
plane (normal :math:`n^g`, centroid :math:`c^g`) gives the anchor's height above it
in the CAD frame, :math:`e = n^{g\\top}(a^g - c^g)`; the same holds in the VIO frame
for the trajectory's plane, :math:`n^{w\\top} a^w = n^{w\\top} c^w + e`. The anchor is
recomputed with that constraint and the yaw iteration re-run.

**Refinement (optional).** A joint least-squares fit of :math:`(\\psi, t)` to the
surface offsets of the mapped trajectory, the tether residuals
:math:`\\lVert p^g_k - a^g\\rVert - l_k` and, when body z-axes are given, the
adsorption yaw residuals: the angle between the horizontal parts of the mapped
body z-axis and of the surface normal, weighted by the normal's tilt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from realitygap.core.geometry import rot_z, wrap_angle
from realitygap.estimators.climb.anchor import (
    AnchorSolution,
    fit_plane,
    solve_anchor,
    solve_anchor_with_plane,
)
from realitygap.estimators.climb.surface import SurfaceModel

FloatArray = npt.NDArray[np.float64]

__all__ = ["GlobalInit", "PlaneConstraint", "initialise_global_pose"]


class PlaneConstraint(str, Enum):
    """When to add the plane-normal constraint to the anchor solution."""

    AUTO = "auto"
    """Only when the anchor is not observable from the path alone."""
    ALWAYS = "always"
    NEVER = "never"


@dataclass(frozen=True, eq=False)
class GlobalInit:
    """The 4-DOF transform :math:`p^w = R_z(\\psi) p^g + t` and how it was found.

    Attributes
    ----------
    yaw
        :math:`\\psi`, rad, in ``[-π, π)``.
    t : (3,)
        Translation, m (VIO world frame).
    anchor_w : (3,)
        Anchor in the VIO world frame, m (consistent with ``yaw`` and ``t``).
    iterations
        Yaw-iteration steps of the final run.
    converged
        True when the yaw correction vanished, yaw was observable and the anchor
        was located.
    status
        ``"ok"`` or what went wrong, ``|``-separated.
    anchor
        The anchor solution used.
    plane_constraint_used
        True if the anchor was recomputed with the plane-normal constraint.
    surface_rms
        RMS offset of the mapped trajectory from the CAD surface at height ``h``, m.
    tether_rms
        RMS of :math:`\\lVert p^g_k - a^g\\rVert - l_k`, m.
    yaw_gain
        :math:`\\partial\\delta/\\partial\\psi` at the solution (≈ 0: yaw unobservable).
    """

    yaw: float
    t: FloatArray
    anchor_w: FloatArray
    iterations: int
    converged: bool
    status: str
    anchor: AnchorSolution
    plane_constraint_used: bool
    surface_rms: float
    tether_rms: float
    yaw_gain: float

    @property
    def R_world_cad(self) -> FloatArray:
        """:math:`R_z(\\psi)` (3, 3): CAD → VIO world."""
        return rot_z(self.yaw)

    def cad_from_world(self, p_w: npt.ArrayLike) -> FloatArray:
        """Map point(s) (3,) or (N, 3) from the VIO world frame to the CAD frame, m."""
        p = np.asarray(p_w, dtype=float)
        return (p - self.t) @ self.R_world_cad

    def world_from_cad(self, p_g: npt.ArrayLike) -> FloatArray:
        """Map point(s) (3,) or (N, 3) from the CAD frame to the VIO world frame, m."""
        p = np.asarray(p_g, dtype=float)
        return p @ self.R_world_cad.T + self.t

    def rotation_cad_from_world(self, R_world_body: npt.ArrayLike) -> FloatArray:
        """:math:`R_{gb} = R_z(\\psi)^\\top R_{wb}` for (3, 3) or (N, 3, 3) rotations."""
        return self.R_world_cad.T @ np.asarray(R_world_body, dtype=float)


def _map(traj_w: FloatArray, yaw: float, anchor_w: FloatArray, anchor_g: FloatArray) -> FloatArray:
    return (traj_w - anchor_w) @ rot_z(yaw) + anchor_g


def initialise_global_pose(
    traj_w: npt.ArrayLike,
    tether_lengths: npt.ArrayLike,
    anchor_g: npt.ArrayLike,
    surface: SurfaceModel,
    h: float,
    *,
    body_z_w: npt.ArrayLike | None = None,
    tether_weights: npt.ArrayLike | None = None,
    yaw0: float | None = 0.0,
    n_starts: int = 24,
    max_iterations: int = 100,
    tol: float = 1e-5,
    min_yaw_gain: float = 1e-3,
    plane_constraint: PlaneConstraint | str = PlaneConstraint.AUTO,
    refine: bool = True,
    surface_sigma: float = 0.003,
    tether_sigma: float = 0.003,
    normal_sigma: float = 0.01,
) -> GlobalInit:
    """Find yaw and translation between the VIO world frame and the CAD frame.

    Parameters
    ----------
    traj_w : (N, 3) array_like
        Excitation trajectory of the body origin from VIO, m, world frame (N ≥ 4).
    tether_lengths : (N,) array_like
        Tether lengths at the same instants, m.
    anchor_g : (3,) array_like
        Anchor in the CAD frame, m.
    surface
        CAD surface model (CAD frame, gravity along :math:`-z`).
    h
        Height of the body origin above the surface, m.
    body_z_w : (N, 3) array_like, optional
        Body z-axes from VIO (world frame), used by the refinement's yaw residuals.
    tether_weights : (N,) array_like, optional
        Weights of the tether readings (0 drops one).
    yaw0
        Starting yaw (rad) of Algorithm 1. If the iteration from it fails (the
        mapped path leaves the surface), or with ``None``, ``n_starts`` equally spaced
        starts are ranked by surface fit and the best three iterated; the converged
        one with the smallest surface offset is kept.
    max_iterations, tol
        Stopping rule: the yaw update is below ``tol`` rad.
    min_yaw_gain
        Least :math:`|\\partial\\delta/\\partial\\psi|` for yaw to count as observable.
    plane_constraint
        :class:`PlaneConstraint` (or its value).
    refine
        Joint least-squares refinement of yaw and translation afterwards.
    surface_sigma, tether_sigma, normal_sigma
        Residual scales of the refinement: m, m, rad.

    Returns
    -------
    GlobalInit
    """
    p = np.asarray(traj_w, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 4 or not np.all(np.isfinite(p)):
        raise ValueError(f"traj_w must be a finite (N, 3) array with N ≥ 4, got shape {p.shape}")
    lengths = np.asarray(tether_lengths, dtype=float)
    if lengths.shape != (len(p),):
        raise ValueError(f"tether_lengths must have shape ({len(p)},), got {lengths.shape}")
    a_g = np.asarray(anchor_g, dtype=float)
    if a_g.shape != (3,) or not np.all(np.isfinite(a_g)):
        raise ValueError(f"anchor_g must be a finite (3,) array, got {anchor_g!r}")
    if not isinstance(surface, SurfaceModel):
        raise TypeError(f"surface must be a SurfaceModel, got {type(surface).__name__}")
    if not (math.isfinite(h) and h >= 0):
        raise ValueError(f"h must be a non-negative height in m, got {h!r}")
    bz: FloatArray | None = None
    if body_z_w is not None:
        bz = np.asarray(body_z_w, dtype=float)
        if bz.shape != p.shape or not np.all(np.isfinite(bz)):
            raise ValueError(f"body_z_w must be a finite {p.shape} array, got {bz.shape}")
    try:
        mode = PlaneConstraint(plane_constraint)
    except ValueError:
        choices = [m.value for m in PlaneConstraint]
        raise ValueError(
            f"plane_constraint must be one of {choices}, got {plane_constraint!r}"
        ) from None
    if yaw0 is not None and not math.isfinite(yaw0):
        raise ValueError(f"yaw0 must be finite (rad) or None, got {yaw0!r}")
    if n_starts < 1:
        raise ValueError(f"n_starts must be ≥ 1, got {n_starts!r}")

    status: list[str] = []
    anchor = solve_anchor(p, lengths, weights=tether_weights)
    a_w = anchor.anchor

    def surface_rms(yaw: float, a_w_: FloatArray) -> float:
        q = _map(p, yaw, a_w_, a_g)
        pr = surface.project(q, None, h)
        off = np.where(pr.ok, pr.offset, 1.0)
        return float(np.sqrt(np.mean(off**2)))

    def run(yaw_start: float, a_w_: FloatArray) -> tuple[float, int, bool, float]:
        return _yaw_iteration(p, a_w_, a_g, surface, h, yaw_start, max_iterations, tol)

    def multi_start(a_w_: FloatArray) -> tuple[float, int, bool, float]:
        starts = np.arange(n_starts) * (2 * np.pi / n_starts) - np.pi
        scores = np.array([surface_rms(float(s), a_w_) for s in starts])
        best = (0.0, 0, False, 0.0)
        best_rms = math.inf
        for s in starts[np.argsort(scores)[:3]]:
            res = run(float(s), a_w_)
            rms = surface_rms(res[0], a_w_) if res[2] else math.inf
            if rms < best_rms:
                best_rms, best = rms, res
        return best

    if yaw0 is None:
        yaw, iterations, converged, gain = multi_start(a_w)
    else:
        yaw, iterations, converged, gain = run(float(yaw0), a_w)
        if not converged:
            yaw, iterations, converged, gain = multi_start(a_w)

    used_plane = False
    if mode is PlaneConstraint.ALWAYS or (mode is PlaneConstraint.AUTO and not anchor.observable):
        q = _map(p, yaw, a_w, a_g)
        pr = surface.project(q, None, h)
        c_g, n_g, _ = fit_plane(pr.point)
        e = float(n_g @ (a_g - c_g))
        c_w, n_w, _ = fit_plane(p)
        if n_w @ (rot_z(yaw) @ n_g) < 0:
            n_w = -n_w
        anchor = solve_anchor_with_plane(
            p, lengths, n_w, float(n_w @ c_w) + e, weights=tether_weights
        )
        a_w = anchor.anchor
        used_plane = True
        yaw, iterations, converged, gain = run(yaw, a_w)
    if not anchor.observable:
        status.append("anchor_unobservable: " + anchor.message)
    if not converged:
        status.append(
            "yaw_not_converged: the mapped path left the surface or the correction did "
            "not vanish from any start"
        )
    if abs(gain) < min_yaw_gain:
        status.append(
            f"yaw_unobservable: the surface along the path is too flat "
            f"(dδ/dψ = {gain:.2g} < {min_yaw_gain:.2g}); drive across curved regions"
        )
    t = a_w - rot_z(yaw) @ a_g

    if refine:
        yaw, t = _refine(
            p,
            lengths,
            tether_weights,
            bz,
            a_g,
            surface,
            h,
            yaw,
            t,
            surface_sigma,
            tether_sigma,
            normal_sigma,
        )
        a_w = rot_z(yaw) @ a_g + t
    yaw = float(wrap_angle(yaw))
    q = (p - t) @ rot_z(yaw)
    pr = surface.project(q, None, h)
    srms = float(np.sqrt(np.mean(np.where(pr.ok, pr.offset, 1.0) ** 2)))
    tres = np.linalg.norm(q - a_g, axis=1) - lengths
    w = np.ones(len(p)) if tether_weights is None else np.asarray(tether_weights, dtype=float)
    trms = float(np.sqrt(np.sum(w * tres**2) / max(np.sum(w), 1e-12)))
    ok = not status
    return GlobalInit(
        yaw=yaw,
        t=t,
        anchor_w=a_w,
        iterations=iterations,
        converged=ok,
        status="ok" if ok else " | ".join(status),
        anchor=anchor,
        plane_constraint_used=used_plane,
        surface_rms=srms,
        tether_rms=trms,
        yaw_gain=float(gain),
    )


def _yaw_iteration(
    p: FloatArray,
    a_w: FloatArray,
    a_g: FloatArray,
    surface: SurfaceModel,
    h: float,
    yaw: float,
    max_iterations: int,
    tol: float,
    min_ok_fraction: float = 0.5,
) -> tuple[float, int, bool, float]:
    """Algorithm 1; returns (yaw, iterations, converged, dδ/dψ)."""

    def correction(y: float) -> float:
        q = _map(p, y, a_w, a_g)
        pr = surface.project(q, None, h)
        ok = np.asarray(pr.ok)
        if ok.mean() < min_ok_fraction:
            return math.nan
        m = (q - a_g)[ok, :2]
        n = (pr.point - a_g)[ok, :2]
        cross = float(np.sum(m[:, 0] * n[:, 1] - m[:, 1] * n[:, 0]))
        dot = float(np.sum(m * n))
        return math.atan2(cross, dot)

    def slope_at(y: float) -> float:
        eps = 2e-3
        g = (correction(y + eps) - correction(y - eps)) / (2 * eps)
        return g if math.isfinite(g) else 0.0

    prev_yaw: float | None = None
    prev_d: float | None = None
    slope: float | None = None
    d = correction(yaw)
    for it in range(1, max_iterations + 1):
        if not math.isfinite(d):
            return yaw, it, False, 0.0
        if prev_yaw is not None and prev_d is not None and abs(yaw - prev_yaw) > 1e-5:
            s_new = (d - prev_d) / (yaw - prev_yaw)
            if s_new > 1e-6:
                slope = s_new
        step = -d
        if slope is not None and abs(d / slope) <= 100 * abs(d):
            step = -d / slope
        prev_yaw, prev_d = yaw, d
        yaw = yaw + step
        d = correction(yaw)
        if abs(step) < tol and math.isfinite(d):
            return yaw, it, True, slope_at(yaw)
    return yaw, max_iterations, False, slope_at(yaw)


def _refine(
    p: FloatArray,
    lengths: FloatArray,
    weights: npt.ArrayLike | None,
    bz: FloatArray | None,
    a_g: FloatArray,
    surface: SurfaceModel,
    h: float,
    yaw: float,
    t: FloatArray,
    surface_sigma: float,
    tether_sigma: float,
    normal_sigma: float,
) -> tuple[float, FloatArray]:
    w = np.ones(len(p)) if weights is None else np.asarray(weights, dtype=float)
    sw = np.sqrt(w)

    def residuals(x: FloatArray) -> FloatArray:
        y, tt = x[0], x[1:]
        q = (p - tt) @ rot_z(y)
        pr = surface.project(q, None, h)
        off = np.where(pr.ok, pr.offset, 0.0) / surface_sigma
        tr = (np.linalg.norm(q - a_g, axis=1) - lengths) * sw / tether_sigma
        parts = [off, tr]
        if bz is not None:
            zg = bz @ rot_z(y)
            n = pr.normal
            cross = zg[:, 0] * n[:, 1] - zg[:, 1] * n[:, 0]
            dot = zg[:, 0] * n[:, 0] + zg[:, 1] * n[:, 1]
            tilt = np.hypot(n[:, 0], n[:, 1])
            # angle between the horizontal parts, weighted by the normal's tilt
            parts.append(np.where(pr.ok, np.arctan2(cross, dot) * tilt, 0.0) / normal_sigma)
        return np.concatenate(parts)

    x0 = np.concatenate([[yaw], t])
    sol = least_squares(
        residuals,
        x0,
        method="trf",
        loss="huber",
        f_scale=3.0,
        x_scale=np.array([0.01, 0.01, 0.01, 0.01]),
        diff_step=1e-6,
        max_nfev=50,
    )
    if not np.all(np.isfinite(sol.x)):
        return yaw, t
    return float(sol.x[0]), sol.x[1:].copy()
