r"""Quadratic-programme smoothing of a way-point path into polynomial pieces.

Way-points (for instance from :class:`~realitygap.controllers.apf.ImprovedAPF`)
are fitted, segment by segment, by planar polynomials of a chord-length
parameter :math:`\sigma \in [0, 1]`

.. math::

    x(\sigma) = \sum_{j=0}^{d} a_j \sigma^j, \qquad
    y(\sigma) = \sum_{j=0}^{d} b_j \sigma^j .

Each segment is a quadratic programme in the coefficients: least squares to
the way-points plus a small bending term,

.. math::

    \min_{a, b} \; \frac{1}{m} \sum_{i=1}^{m}
        \lVert p(\sigma_i) - p_i \rVert^2
      + w \int_0^{L} \kappa^2 \, \mathrm{d}\ell ,

(the bending term is the quadratic surrogate
:math:`\frac{w}{L^3}\int_0^1 \lVert p''(\sigma) \rVert^2 \mathrm{d}\sigma` with
:math:`L` the segment chord length) subject to linear constraints: the path
passes exactly through the start and end points, and its tangent matches the
start and end headings :math:`\theta`,

.. math::

    \sin\theta \, x'(\sigma) - \cos\theta \, y'(\sigma) = 0, \qquad
    \cos\theta \, x'(\sigma) + \sin\theta \, y'(\sigma) \ge \delta L > 0 ,

which is :math:`y' = \tan\theta \, x'` without the singularity at
:math:`\theta = \pm\pi/2`, and with the inequality excluding the reversed
tangent.  Long paths are solved receding-horizon: a segment of about
``segment_length`` metres is fitted, its first ``1 - overlap`` part is kept, and
the next segment starts at the kept end with the same first and second
derivative with respect to arc length (so position, heading and curvature are
continuous across segments).

The QPs are solved with CasADi's ``conic`` interface, using the first of
CasADi's own active-set ``qrqp``, qpOASES and OSQP that this CasADi build
provides (see :data:`QP_SOLVERS`); results are bit-for-bit reproducible with
each of them.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import casadi
import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import check_finite, wrap_angle

FloatArray = npt.NDArray[np.float64]

__all__ = ["QP_SOLVERS", "SmoothPath", "available_qp_solvers", "smooth_path"]

QP_SOLVERS: tuple[str, ...] = ("qrqp", "qpoases", "osqp")
"""CasADi ``conic`` plugins tried, in order of preference.

``qrqp`` (CasADi's own active-set solver, part of every build) comes first:
the segment QPs are tiny and dense, and it solves them exactly and silently.
"""

_STATELESS_SOLVERS = frozenset({"qrqp"})
"""Plugins whose result does not depend on earlier calls.  qpOASES and OSQP
warm-start from the previous problem, which changes the last bits of the
solution, so they are built afresh for every segment to keep results
reproducible whatever was solved before."""

_SOLVER_OPTIONS: dict[str, dict[str, Any]] = {
    "qpoases": {"printLevel": "none", "error_on_fail": False},
    "qrqp": {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False},
    "osqp": {
        "osqp": {"verbose": False, "eps_abs": 1e-10, "eps_rel": 1e-10, "polish": True,
                 "max_iter": 50_000},
        "error_on_fail": False,
    },
}  # fmt: skip

_solver_cache: dict[tuple[str, int, int], casadi.Function] = {}


def available_qp_solvers() -> tuple[str, ...]:
    """The plugins of :data:`QP_SOLVERS` that this CasADi build can load, in order."""
    found = []
    for name in QP_SOLVERS:
        try:
            if casadi.has_conic(name):
                found.append(name)
        except RuntimeError:
            continue
    return tuple(found)


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence file descriptor 1 (qpOASES writes a licence banner there on construction)."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError, AttributeError):
        yield
        return
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 1)
            try:
                yield
            finally:
                os.dup2(saved, 1)
    finally:
        os.close(saved)


def _qp_solver(plugin: str, n_variables: int, n_constraints: int) -> casadi.Function:
    """A dense CasADi ``conic`` solver; cached only for plugins that keep no state."""
    key = (plugin, n_variables, n_constraints)
    if key in _solver_cache:
        return _solver_cache[key]
    structure = {
        "h": casadi.Sparsity.dense(n_variables, n_variables),
        "a": casadi.Sparsity.dense(n_constraints, n_variables),
    }
    with _quiet_stdout():
        solver = casadi.conic(
            f"path_smoothing_{plugin}_{n_variables}_{n_constraints}",
            plugin,
            structure,
            _SOLVER_OPTIONS.get(plugin, {"error_on_fail": False}),
        )
    if plugin in _STATELESS_SOLVERS:
        _solver_cache[key] = solver
    return solver


@dataclass(frozen=True)
class SmoothPath:
    """A smoothed path, densely sampled at (nearly) uniform arc length.

    Attributes
    ----------
    xy : ndarray, shape (N, 2)
        Positions in m (world frame); ``xy[0]`` and ``xy[-1]`` are the first
        and last way-points.
    heading : ndarray, shape (N,)
        Tangent direction in rad, continuous along the path (not wrapped, so
        it can be interpolated); ``heading[0]`` lies in ``[-pi, pi)``.
    curvature : ndarray, shape (N,)
        Signed curvature in 1/m (positive turning left).
    s : ndarray, shape (N,)
        Arc length from the start in m, increasing, ``s[0] = 0``.
    feasible : bool
        Whether every QP was solved and every constraint holds to tolerance.
        When False, ``xy`` is the input polyline (heading along its edges,
        zero curvature) so that a caller may still fall back on it.
    message : str
        What went wrong, or ``"ok"``.
    solver : str
        The CasADi ``conic`` plugin used (empty if none was needed).
    """

    xy: FloatArray
    heading: FloatArray
    curvature: FloatArray
    s: FloatArray
    feasible: bool
    message: str
    solver: str = field(default="")

    @property
    def length(self) -> float:
        """Arc length of the path in m."""
        return float(self.s[-1]) if len(self.s) else 0.0

    def pose_at(self, arc_length: float) -> FloatArray:
        """Pose ``[x, y, heading]`` (m, m, rad; heading wrapped) at arc length ``arc_length`` m.

        Linear interpolation between samples; ``arc_length`` is clamped to
        ``[0, length]``.
        """
        s = float(np.clip(arc_length, 0.0, self.length))
        x = float(np.interp(s, self.s, self.xy[:, 0]))
        y = float(np.interp(s, self.s, self.xy[:, 1]))
        heading = float(np.interp(s, self.s, self.heading))
        return np.array([x, y, float(wrap_angle(heading))])

    def curvature_at(self, arc_length: float) -> float:
        """Curvature in 1/m at arc length ``arc_length`` m (linear interpolation, clamped)."""
        s = float(np.clip(arc_length, 0.0, self.length))
        return float(np.interp(s, self.s, self.curvature))


@dataclass(frozen=True)
class _Piece:
    """One kept polynomial piece: ``p(σ) = origin + scale · Σ c_j σ^j`` for σ in [0, end]."""

    origin: FloatArray
    scale: float
    coefficients: FloatArray  # (degree + 1, 2)
    end: float

    def derivatives(self, sigma: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Normalised value, first and second derivative in σ, each (len(sigma), 2)."""
        degree = len(self.coefficients) - 1
        powers = np.arange(degree + 1)
        basis = sigma[:, None] ** powers
        first = np.zeros_like(basis)
        second = np.zeros_like(basis)
        first[:, 1:] = powers[1:] * sigma[:, None] ** (powers[1:] - 1)
        second[:, 2:] = powers[2:] * (powers[2:] - 1) * sigma[:, None] ** (powers[2:] - 2)
        return basis @ self.coefficients, first @ self.coefficients, second @ self.coefficients


def _basis_rows(sigma: float, degree: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    powers = np.arange(degree + 1, dtype=float)
    value = sigma**powers
    first = np.zeros(degree + 1)
    second = np.zeros(degree + 1)
    first[1:] = powers[1:] * sigma ** (powers[1:] - 1)
    second[2:] = powers[2:] * (powers[2:] - 1) * sigma ** (powers[2:] - 2)
    return value, first, second


def _bending_matrix(degree: int) -> FloatArray:
    """:math:`R_{jk} = \\int_0^1 (\\sigma^j)'' (\\sigma^k)'' d\\sigma`."""
    R = np.zeros((degree + 1, degree + 1))
    for j in range(2, degree + 1):
        for k in range(2, degree + 1):
            R[j, k] = j * (j - 1) * k * (k - 1) / (j + k - 3)
    return R


def _resample_polyline(points: FloatArray, spacing: float) -> FloatArray:
    """Insert points so no edge is longer than ``spacing``; original vertices are kept."""
    out = [points[:1]]
    for a, b in itertools.pairwise(points):
        pieces = max(1, math.ceil(float(np.linalg.norm(b - a)) / spacing))
        t = np.arange(1, pieces + 1) / pieces
        out.append(a + t[:, None] * (b - a))
    return np.vstack(out)


def _polyline_path(points: FloatArray, message: str) -> SmoothPath:
    """The input polyline in :class:`SmoothPath` form, reported infeasible."""
    if len(points) < 2:
        xy = points[:1].copy() if len(points) else np.zeros((0, 2))
        return SmoothPath(
            xy, np.zeros(len(xy)), np.zeros(len(xy)), np.zeros(len(xy)), False, message
        )
    edges = np.diff(points, axis=0)
    edge_heading = np.unwrap(np.arctan2(edges[:, 1], edges[:, 0]))
    heading = np.append(edge_heading, edge_heading[-1])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(edges, axis=1))])
    return SmoothPath(points.copy(), heading, np.zeros(len(points)), s, False, message)


@dataclass(frozen=True)
class _SegmentProblem:
    """One segment QP in normalised coordinates ``u = (p - origin) / scale``."""

    sigma: FloatArray  # (m,) data parameters
    target: FloatArray  # (m, 2) normalised data
    constraint_matrix: FloatArray  # (nc, 2(d+1))
    lower: FloatArray  # (nc,)
    upper: FloatArray  # (nc,)


def _solve_segment(
    problem: _SegmentProblem, degree: int, bending_weight: float, plugin: str
) -> tuple[FloatArray | None, str]:
    """Solve one segment QP; coefficients (d+1, 2) or None and a message."""
    n_coef = degree + 1
    basis = problem.sigma[:, None] ** np.arange(n_coef)
    m = len(problem.sigma)
    block = 2.0 * (basis.T @ basis / m + bending_weight * _bending_matrix(degree))
    hessian = np.zeros((2 * n_coef, 2 * n_coef))
    hessian[:n_coef, :n_coef] = block
    hessian[n_coef:, n_coef:] = block
    gradient = (
        -2.0 / m * np.concatenate([basis.T @ problem.target[:, 0], basis.T @ problem.target[:, 1]])
    )
    A = problem.constraint_matrix
    solver = _qp_solver(plugin, 2 * n_coef, A.shape[0])
    try:
        solution = solver(
            h=hessian, g=gradient, a=A, lba=problem.lower, uba=problem.upper,
            lbx=-np.inf * np.ones(2 * n_coef), ubx=np.inf * np.ones(2 * n_coef),
        )  # fmt: skip
    except RuntimeError as exc:
        return None, f"{plugin} failed: {str(exc).splitlines()[-1]}"
    z = np.asarray(solution["x"], dtype=float).ravel()
    if not np.all(np.isfinite(z)):
        return None, f"{plugin} returned a non-finite solution"
    stats = solver.stats()
    residual = A @ z
    tolerance = 1e-7
    violation = max(
        float(np.max(problem.lower - residual, initial=0.0)),
        float(np.max(residual - problem.upper, initial=0.0)),
    )
    if violation > tolerance:
        status = stats.get("return_status", "")
        return None, f"constraint violated by {violation:.2e} ({plugin}: {status})"
    if not stats.get("success", True):
        return None, f"{plugin} reported failure: {stats.get('return_status', '')}"
    return np.column_stack([z[:n_coef], z[n_coef:]]), "ok"


def _segment_constraints(
    degree: int,
    end_sigma_target: FloatArray | None,
    start_heading: float | None,
    start_first: FloatArray | None,
    start_second: FloatArray | None,
    end_heading: float | None,
    min_tangent: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Linear constraints ``lower <= A z <= upper`` on ``z = [a; b]`` (normalised units)."""
    n_coef = degree + 1
    zero = np.zeros(n_coef)
    rows: list[FloatArray] = []
    lower: list[float] = []
    upper: list[float] = []

    def add(row_x: FloatArray, row_y: FloatArray, lo: float, hi: float) -> None:
        rows.append(np.concatenate([row_x, row_y]))
        lower.append(lo)
        upper.append(hi)

    value0, first0, second0 = _basis_rows(0.0, degree)
    add(value0, zero, 0.0, 0.0)
    add(zero, value0, 0.0, 0.0)
    if start_first is not None:
        add(first0, zero, start_first[0], start_first[0])
        add(zero, first0, start_first[1], start_first[1])
        if start_second is not None:
            add(second0, zero, start_second[0], start_second[0])
            add(zero, second0, start_second[1], start_second[1])
    elif start_heading is not None:
        c, s = math.cos(start_heading), math.sin(start_heading)
        add(s * first0, -c * first0, 0.0, 0.0)
        add(c * first0, s * first0, min_tangent, math.inf)
    if end_sigma_target is not None:
        value1, first1, _ = _basis_rows(1.0, degree)
        add(value1, zero, end_sigma_target[0], end_sigma_target[0])
        add(zero, value1, end_sigma_target[1], end_sigma_target[1])
        if end_heading is not None:
            c, s = math.cos(end_heading), math.sin(end_heading)
            add(s * first1, -c * first1, 0.0, 0.0)
            add(c * first1, s * first1, min_tangent, math.inf)
    return np.array(rows), np.array(lower), np.array(upper)


def smooth_path(
    waypoints: npt.ArrayLike,
    start_heading: float,
    end_heading: float | None = None,
    *,
    degree: int = 5,
    segment_length: float = 1.5,
    overlap: float = 0.4,
    resample_spacing: float = 0.1,
    smoothness_weight: float = 2e-4,
    min_tangent_ratio: float = 0.3,
    sample_spacing: float = 0.01,
    solver: str | None = None,
) -> SmoothPath:
    """Fit a smooth, heading-constrained polynomial path to way-points.

    Parameters
    ----------
    waypoints : array_like, shape (K, 2)
        Way-points in m (world frame), ``K >= 2`` distinct consecutive points;
        the first is the start, the last the end of the path.
    start_heading : float
        Heading in rad the path leaves the start with (world frame).
    end_heading : float or None, optional
        Heading in rad the path arrives with; None leaves it free.
    degree : int, optional
        Polynomial degree ``d`` per segment, ``>= 3``; from 5 on, curvature is
        also continuous between segments.
    segment_length : float, optional
        Approximate length in m of the way-point stretch fitted by one QP.
    overlap : float, optional
        Fraction of each segment (except the last) that is re-fitted by the
        next one, in ``[0, 0.9]``.
    resample_spacing : float, optional
        Longer way-point edges are subdivided to this spacing in m, so that
        long straight edges are followed, not only their ends.
    smoothness_weight : float, optional
        Weight ``w`` in m³ of the bending term :math:`\\int \\kappa^2 d\\ell`
        against the mean squared distance to the way-points.
    min_tangent_ratio : float, optional
        ``δ`` of the forward-tangent condition, relative to the segment length.
    sample_spacing : float, optional
        Arc-length spacing in m of the returned samples.
    solver : str, optional
        CasADi ``conic`` plugin; by default the first available of :data:`QP_SOLVERS`.

    Returns
    -------
    SmoothPath
        Dense samples; ``feasible`` is False (with the reason in ``message``)
        when there are fewer than two distinct way-points, a QP fails, a
        constraint is violated beyond 1e-7 (normalised units) or the tangent
        vanishes somewhere.

    Raises
    ------
    ValueError
        For malformed input: way-points not a finite (K, 2) array, non-finite
        headings, out-of-range settings or an unknown solver.
    """
    points = check_finite("waypoints", waypoints)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"waypoints must have shape (K, 2) (x, y in m), got {points.shape}")
    start_heading = float(check_finite("start_heading", start_heading, shape=()))
    if end_heading is not None:
        end_heading = float(check_finite("end_heading", end_heading, shape=()))
    if int(degree) != degree or degree < 3:
        raise ValueError(f"degree must be an integer >= 3, got {degree!r}")
    degree = int(degree)
    settings = {
        "segment_length": segment_length,
        "resample_spacing": resample_spacing,
        "min_tangent_ratio": min_tangent_ratio,
        "sample_spacing": sample_spacing,
    }
    for name, setting in settings.items():
        if not (math.isfinite(setting) and setting > 0.0):
            raise ValueError(f"{name} must be finite and > 0, got {setting!r}")
    if not (0.0 <= overlap <= 0.9):
        raise ValueError(f"overlap must lie in [0, 0.9], got {overlap!r}")
    if not (math.isfinite(smoothness_weight) and smoothness_weight >= 0.0):
        raise ValueError(f"smoothness_weight must be finite and >= 0, got {smoothness_weight!r}")
    available = available_qp_solvers()
    if solver is None:
        if not available:
            return _polyline_path(points, "no CasADi QP solver plugin available")
        plugin = available[0]
    elif solver not in available:
        raise ValueError(
            f"solver {solver!r} is not available; this CasADi build offers {available}"
        )
    else:
        plugin = solver

    # Drop repeated way-points; they carry no direction.
    if len(points) > 1:
        keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9])
        points = points[keep]
    if len(points) < 2:
        return _polyline_path(points, "fewer than two distinct way-points")

    data = _resample_polyline(points, resample_spacing)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(data, axis=0), axis=1))])
    total = float(arc[-1])
    match_curvature = degree >= 5

    pieces: list[_Piece] = []
    origin = data[0].copy()
    first_index = 0  # data index of the first data point after the segment's origin
    start_first: FloatArray | None = None  # dp/dl at the origin (unit tangent)
    start_second: FloatArray | None = None  # d2p/dl2 at the origin (curvature vector)
    arc_origin = 0.0
    while True:
        is_last = total - arc_origin <= segment_length * (1.0 + 1e-9)
        if is_last:
            last_index = len(data) - 1
        else:
            last_index = int(np.searchsorted(arc, arc_origin + segment_length, side="right")) - 1
            last_index = max(last_index, first_index + 1)
        segment = np.vstack([origin, data[first_index + 1 : last_index + 1]])
        chords = np.concatenate(
            [[0.0], np.cumsum(np.linalg.norm(np.diff(segment, axis=0), axis=1))]
        )
        scale = float(chords[-1])
        if scale <= 1e-12:
            return _polyline_path(points, "degenerate segment of zero length")
        sigma = chords / scale
        target = (segment - origin) / scale

        # In normalised units u = (p - origin) / scale with σ = l / scale: u' = dp/dl and
        # u'' = scale · d²p/dl².
        second_normalised = None if start_second is None else start_second * scale
        A, lower, upper = _segment_constraints(
            degree,
            target[-1] if is_last else None,
            start_heading,
            start_first,
            second_normalised if match_curvature else None,
            end_heading if is_last else None,
            min_tangent_ratio,
        )
        coefficients, message = _solve_segment(
            _SegmentProblem(sigma, target, A, lower, upper),
            degree,
            smoothness_weight / scale**3,
            plugin,
        )
        if coefficients is None:
            result = _polyline_path(points, message)
            return SmoothPath(
                result.xy, result.heading, result.curvature, result.s, False, message, plugin
            )
        if is_last:
            pieces.append(_Piece(origin.copy(), scale, coefficients, 1.0))
            break
        commit_arc = arc_origin + (1.0 - overlap) * segment_length
        commit_local = int(np.searchsorted(arc[first_index + 1 : last_index + 1], commit_arc))
        commit_local = int(np.clip(commit_local + 1, 1, len(sigma) - 2 if len(sigma) > 2 else 1))
        commit_sigma = float(sigma[commit_local])
        piece = _Piece(origin.copy(), scale, coefficients, commit_sigma)
        pieces.append(piece)
        value, first, second = piece.derivatives(np.array([commit_sigma]))
        origin = origin + scale * value[0]
        start_first = first[0]  # dp/dl = u'(σ) for σ = l / scale
        start_second = second[0] / scale
        if float(np.linalg.norm(start_first)) <= 1e-6:
            return _polyline_path(points, "tangent vanishes at a segment junction")
        first_index = first_index + commit_local
        arc_origin = float(arc[first_index])

    return _sample_pieces(pieces, points, sample_spacing, plugin)


def _sample_pieces(
    pieces: list[_Piece], points: FloatArray, sample_spacing: float, plugin: str
) -> SmoothPath:
    """Evaluate the pieces at uniform arc length."""
    tables = []
    for index, piece in enumerate(pieces):
        count = max(64, math.ceil(4.0 * piece.scale * piece.end / sample_spacing))
        sigma = np.linspace(0.0, piece.end, count + 1)
        _, first, _ = piece.derivatives(sigma)
        speed = piece.scale * np.linalg.norm(first, axis=1)
        if float(np.min(speed)) <= 1e-6 * piece.scale:
            result = _polyline_path(points, "tangent vanishes (cusp) inside a segment")
            return SmoothPath(
                result.xy, result.heading, result.curvature, result.s, False, result.message, plugin
            )
        arc = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(sigma))])
        parameter = index + sigma / piece.end
        tables.append((parameter if index == 0 else parameter[1:], arc if index == 0 else arc[1:]))
    offsets = [0.0]
    for _, piece_arc in tables[:-1]:
        offsets.append(offsets[-1] + float(piece_arc[-1]))
    parameter = np.concatenate([t[0] for t in tables])
    arc = np.concatenate([t[1] + offset for t, offset in zip(tables, offsets)])
    total = float(arc[-1])
    count = max(2, math.ceil(total / sample_spacing) + 1)
    s = np.linspace(0.0, total, count)
    global_parameter = np.interp(s, arc, parameter)
    global_parameter[-1] = len(pieces)

    xy = np.zeros((count, 2))
    tangent = np.zeros((count, 2))
    curvature = np.zeros(count)
    piece_index = np.minimum(np.floor(global_parameter).astype(int), len(pieces) - 1)
    for index, piece in enumerate(pieces):
        mask = piece_index == index
        if not np.any(mask):
            continue
        sigma = (global_parameter[mask] - index) * piece.end
        value, first, second = piece.derivatives(sigma)
        xy[mask] = piece.origin + piece.scale * value
        tangent[mask] = first
        cross = first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0]
        curvature[mask] = cross / np.linalg.norm(first, axis=1) ** 3 / piece.scale
    heading = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
    heading += 2.0 * np.pi * np.round((float(wrap_angle(heading[0])) - heading[0]) / (2.0 * np.pi))
    return SmoothPath(xy, heading, curvature, s, True, "ok", plugin)
