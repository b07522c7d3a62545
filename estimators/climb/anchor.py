"""Tether anchor by single-point positioning in the VIO world frame.

The tether measures the distance between the robot and the anchor,

.. math::  l_k^2 = \\lVert p_k - a \\rVert^2, \\qquad k = 1 \\dots N,

with robot positions :math:`p_k` (VIO world frame, m) and lengths :math:`l_k` (m).
Subtracting the mean of the equations removes :math:`\\lVert a\\rVert^2`:

.. math::  2 (p_k - \\bar p)^\\top a = (\\lVert p_k\\rVert^2 - \\overline{\\lVert p\\rVert^2})
           - (l_k^2 - \\overline{l^2}),

a linear least-squares problem whose conditioning is the spread of the path (its
singular values are twice the RMS extent of the path along its principal axes). A
Gauss–Newton refinement then minimises :math:`\\sum_k (\\lVert p_k - a\\rVert - l_k)^2`;
its Jacobian rows are the unit directions from the path to the anchor.

A straight path leaves the anchor free to rotate about the line; a planar path
leaves its side of the plane ambiguous (mirror solution) and its offset from the
plane poorly conditioned. :func:`solve_anchor_with_plane` adds the constraint
:math:`n^\\top a = d` for that (low-curvature) case.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = ["AnchorSolution", "fit_plane", "solve_anchor", "solve_anchor_with_plane"]

_AXES = ("x", "y", "z")


@dataclass(frozen=True, eq=False)
class AnchorSolution:
    """Anchor estimate with its observability.

    Attributes
    ----------
    anchor : (3,)
        Anchor position, m, in the frame of the positions.
    observable
        False when the path lacks excitation in some direction (see ``message``).
    message
        ``"ok"`` or which direction is unobservable and what to do.
    path_spread : (3,) or (2,)
        RMS extent of the path along its principal axes (linear system singular
        values / :math:`2\\sqrt N`), m, descending; (2,) within the constraint plane.
    direction_spread : (3,) or (2,)
        Singular values of the Gauss–Newton Jacobian divided by :math:`\\sqrt N`
        (dimensionless, ≤ 1): how much the directions to the anchor vary.
    condition_number
        Ratio of largest to smallest Gauss–Newton singular value (``inf`` if singular).
    weak_direction : (3,)
        Unit vector of the least observable anchor direction.
    residual_rms
        RMS of :math:`\\lVert p_k - a\\rVert - l_k`, m.
    iterations
        Gauss–Newton iterations used.
    """

    anchor: FloatArray
    observable: bool
    message: str
    path_spread: FloatArray
    direction_spread: FloatArray
    condition_number: float
    weak_direction: FloatArray
    residual_rms: float
    iterations: int


def fit_plane(points: npt.ArrayLike) -> tuple[FloatArray, FloatArray, float]:
    """Least-squares plane through points.

    Returns
    -------
    centroid : (3,)
        m.
    normal : (3,)
        Unit normal (sign: non-negative z component, else non-negative x).
    rms : float
        RMS distance of the points from the plane, m.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
        raise ValueError(f"points must be an (N, 3) array with N ≥ 3, got shape {pts.shape}")
    c = pts.mean(axis=0)
    _, s, vt = np.linalg.svd(pts - c, full_matrices=False)
    n = vt[-1]
    if n[2] < 0 or (n[2] == 0 and n[0] < 0):
        n = -n
    return c, n, float(s[-1] / np.sqrt(len(pts)))


def _describe(v: FloatArray) -> str:
    k = int(np.argmax(np.abs(v)))
    sign = "+" if v[k] >= 0 else "-"
    return f"[{v[0]:+.2f}, {v[1]:+.2f}, {v[2]:+.2f}] (≈ {sign}{_AXES[k]})"


def _check_inputs(
    positions: npt.ArrayLike, lengths: npt.ArrayLike, weights: npt.ArrayLike | None
) -> tuple[FloatArray, FloatArray, FloatArray]:
    p = np.asarray(positions, dtype=float)
    lengths_arr = np.asarray(lengths, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"positions must be an (N, 3) array, got shape {p.shape}")
    if lengths_arr.shape != (len(p),):
        raise ValueError(
            f"lengths must have shape ({len(p)},) to match positions, got {lengths_arr.shape}"
        )
    if len(p) < 4:
        raise ValueError(f"need at least 4 positions to locate the anchor, got {len(p)}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(lengths_arr))):
        raise ValueError("positions and lengths must be finite")
    if np.any(lengths_arr <= 0):
        raise ValueError("tether lengths must be positive, in m")
    if weights is None:
        w = np.ones(len(p))
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != (len(p),) or np.any(~np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError(f"weights must be ({len(p)},) non-negative with a positive sum")
    return p, lengths_arr, w


def _gauss_newton(
    p: FloatArray,
    lengths: FloatArray,
    w: FloatArray,
    a0: FloatArray,
    basis: FloatArray,
    max_iterations: int,
    tol: float,
) -> tuple[FloatArray, int, FloatArray]:
    """Minimise ``Σ w (‖p − a‖ − l)²`` over ``a = a0 + basis z``; return a, iterations, J."""
    a = a0.copy()
    sw = np.sqrt(w)
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        diff = a - p
        dist = np.linalg.norm(diff, axis=1)
        dist = np.maximum(dist, 1e-9)
        r = (dist - lengths) * sw
        jac = (diff / dist[:, None]) @ basis * sw[:, None]
        step, *_ = np.linalg.lstsq(jac, -r, rcond=1e-10)
        a = a + basis @ step
        if np.linalg.norm(step) < tol:
            break
    diff = a - p
    dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
    jac = (diff / dist[:, None]) @ basis * sw[:, None]
    return a, iterations, jac


def solve_anchor(
    positions: npt.ArrayLike,
    lengths: npt.ArrayLike,
    *,
    weights: npt.ArrayLike | None = None,
    min_spread: float = 0.02,
    min_direction_spread: float = 0.02,
    up: npt.ArrayLike = (0.0, 0.0, 1.0),
    max_iterations: int = 30,
    tol: float = 1e-10,
) -> AnchorSolution:
    """Locate the tether anchor from positions and tether lengths.

    Parameters
    ----------
    positions : (N, 3) array_like
        Robot (tether attachment) positions, m, VIO world frame; N ≥ 4.
    lengths : (N,) array_like
        Tether lengths, m.
    weights : (N,) array_like, optional
        Non-negative weights of the readings (e.g. 0 for a slack tether).
    min_spread
        Least RMS extent of the path along every axis for the linear system to be
        observable, m.
    min_direction_spread
        Least Gauss–Newton singular value / :math:`\\sqrt N`.
    up
        Side chosen when a planar path leaves the anchor's side of the plane
        ambiguous (the anchor is put on the side ``up`` points to).
    max_iterations, tol
        Gauss–Newton stopping rule (step norm in m).

    Returns
    -------
    AnchorSolution
        ``observable=False`` with a message naming the unobservable direction when
        the path is a straight line (anchor free to rotate about it), planar (mirror
        ambiguity across the plane), or its directions to the anchor hardly vary.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> p = rng.uniform(-1, 1, (20, 3))
    >>> a = np.array([0.5, -2.0, 3.0])
    >>> sol = solve_anchor(p, np.linalg.norm(p - a, axis=1))
    >>> bool(np.allclose(sol.anchor, a)), sol.observable
    (True, True)
    """
    p, lengths_arr, w = _check_inputs(positions, lengths, weights)
    up_v = np.asarray(up, dtype=float)
    n_eff = float(w.sum())
    wn = w / w.sum()
    pbar = wn @ p
    sq = np.einsum("ij,ij->i", p, p)
    A = 2.0 * (p - pbar)
    b = (sq - wn @ sq) - (lengths_arr**2 - wn @ lengths_arr**2)
    sw = np.sqrt(w)
    _, s, vt = np.linalg.svd(A * sw[:, None], full_matrices=False)
    spread = s / (2.0 * np.sqrt(n_eff))
    good = spread >= min_spread
    # truncated solution in the well-excited directions
    coeff = (vt @ ((A * sw[:, None]).T @ (b * sw))) / np.maximum(s**2, 1e-300)
    a_lin = vt[good].T @ coeff[good] if np.any(good) else np.zeros(3)
    weak = vt[~good]
    # components along weak directions: the path centroid's, then pushed off the
    # path by the mean residual radius towards ``up`` (a starting point only)
    a_lin = a_lin + weak.T @ (weak @ pbar)
    n_weak = len(weak)
    if n_weak:
        up_w = weak.T @ (weak @ up_v)
        if np.linalg.norm(up_w) < 1e-9:
            up_w = weak[0]
        up_w = up_w / np.linalg.norm(up_w)
        resid2 = lengths_arr**2 - np.sum((p - a_lin) ** 2, axis=1)
        a_lin = a_lin + float(np.sqrt(max(wn @ resid2, 0.0))) * up_w
    messages: list[str] = []
    if n_weak == 1:
        messages.append(
            f"path is planar (RMS extent {spread[2]:.3g} m < {min_spread:.3g} m along "
            f"normal {_describe(vt[2])}): the anchor's side of that plane is ambiguous "
            "(mirror solution) and its offset poorly conditioned; excite the path along "
            "that direction or use solve_anchor_with_plane"
        )
    elif n_weak >= 2:
        dirs = " and ".join(_describe(v) for v in weak)
        messages.append(
            f"path has no extent along {dirs} (RMS extent < {min_spread:.3g} m): the "
            "anchor is free to rotate about the path line; drive across the surface in "
            "those directions"
        )
    a, iterations, jac = _gauss_newton(p, lengths_arr, w, a_lin, np.eye(3), max_iterations, tol)
    _, sj, vtj = np.linalg.svd(jac, full_matrices=False)
    dspread = sj / np.sqrt(n_eff)
    cond = float(sj[0] / sj[-1]) if sj[-1] > 0 else float("inf")
    if dspread[-1] < min_direction_spread and n_weak < 2:
        messages.append(
            f"directions to the anchor hardly vary (spread {dspread[-1]:.3g} < "
            f"{min_direction_spread:.3g}): anchor unobservable along {_describe(vtj[-1])}; "
            "lengthen the excitation path"
        )
    resid = np.linalg.norm(p - a, axis=1) - lengths_arr
    weak_dir = vt[-1] if n_weak >= 1 else vtj[-1]
    return AnchorSolution(
        anchor=a,
        observable=not messages,
        message="ok" if not messages else "; ".join(messages),
        path_spread=spread,
        direction_spread=dspread,
        condition_number=cond,
        weak_direction=weak_dir,
        residual_rms=float(np.sqrt(wn @ resid**2)),
        iterations=iterations,
    )


def solve_anchor_with_plane(
    positions: npt.ArrayLike,
    lengths: npt.ArrayLike,
    normal: npt.ArrayLike,
    offset: float,
    *,
    weights: npt.ArrayLike | None = None,
    min_spread: float = 0.02,
    min_direction_spread: float = 0.02,
    max_iterations: int = 30,
    tol: float = 1e-10,
) -> AnchorSolution:
    """Locate the anchor subject to the plane-normal constraint :math:`n^\\top a = d`.

    For a path on a low-curvature surface the anchor's component along the path's
    plane normal is unobservable from the tether alone; knowing the anchor's offset
    from that plane (e.g. from the CAD model) fixes it:

    .. math::  a = d\\,n + B z, \\quad B^\\top n = 0,

    and the linear system and the Gauss–Newton refinement run over :math:`z \\in
    \\mathbb R^2`.

    Parameters
    ----------
    positions, lengths, weights
        As in :func:`solve_anchor`.
    normal : (3,)
        Plane normal (normalised here).
    offset
        :math:`d = n^\\top a`, m (for a plane through centroid ``c`` with the anchor at
        signed height ``e`` above it: ``n @ c + e``).

    Returns
    -------
    AnchorSolution
        ``path_spread`` and ``direction_spread`` have two entries (in-plane).
    """
    p, lengths_arr, w = _check_inputs(positions, lengths, weights)
    n = np.asarray(normal, dtype=float)
    if n.shape != (3,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) < 1e-12:
        raise ValueError(f"normal must be a finite non-zero (3,) vector, got {normal!r}")
    if not np.isfinite(offset):
        raise ValueError(f"offset must be finite, got {offset!r}")
    n = n / np.linalg.norm(n)
    basis = np.linalg.svd(np.eye(3) - np.outer(n, n))[0][:, :2]
    a0 = offset * n
    n_eff = float(w.sum())
    wn = w / w.sum()
    pbar = wn @ p
    sq = np.einsum("ij,ij->i", p, p)
    A = 2.0 * (p - pbar)
    b = (sq - wn @ sq) - (lengths_arr**2 - wn @ lengths_arr**2) - A @ a0
    sw = np.sqrt(w)
    Ab = (A @ basis) * sw[:, None]
    _, s, vt = np.linalg.svd(Ab, full_matrices=False)
    spread = s / (2.0 * np.sqrt(n_eff))
    z, *_ = np.linalg.lstsq(Ab, b * sw, rcond=1e-10)
    messages: list[str] = []
    if spread[-1] < min_spread:
        weak = basis @ vt[-1]
        messages.append(
            f"path has no in-plane extent along {_describe(weak)} (RMS {spread[-1]:.3g} m "
            f"< {min_spread:.3g} m): anchor unobservable in that direction"
        )
    a, iterations, jac = _gauss_newton(
        p, lengths_arr, w, a0 + basis @ z, basis, max_iterations, tol
    )
    _, sj, vtj = np.linalg.svd(jac, full_matrices=False)
    dspread = sj / np.sqrt(n_eff)
    cond = float(sj[0] / sj[-1]) if sj[-1] > 0 else float("inf")
    if dspread[-1] < min_direction_spread and not messages:
        messages.append(
            f"directions to the anchor hardly vary in the plane (spread {dspread[-1]:.3g}): "
            f"unobservable along {_describe(basis @ vtj[-1])}"
        )
    resid = np.linalg.norm(p - a, axis=1) - lengths_arr
    return AnchorSolution(
        anchor=a,
        observable=not messages,
        message="ok" if not messages else "; ".join(messages),
        path_spread=spread,
        direction_spread=dspread,
        condition_number=cond,
        weak_direction=basis @ vtj[-1],
        residual_rms=float(np.sqrt(wn @ resid**2)),
        iterations=iterations,
    )
