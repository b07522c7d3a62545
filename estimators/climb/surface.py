"""Fast projection of body positions onto a CAD surface given as a point cloud with normals.

The cloud (points and unit outward normals, e.g. from
:func:`realitygap.robots.blade_geometry.cad_point_cloud`) is held in a k-d tree. For
a query position :math:`p` (the body origin, ``h`` above the surface) and the body
z-axis :math:`d`:

1. take the three nearest non-collinear cloud points :math:`q_0, q_1, q_2`; they
   define the local plane with normal :math:`n_\\pi \\propto (q_1-q_0)\\times(q_2-q_0)`;
2. intersect the line :math:`p + s\\,d` with that plane: the incidence point

   .. math::  x = p + \\frac{n_\\pi^\\top (q_0 - p)}{n_\\pi^\\top d}\\, d ;

3. interpolate the normal with the barycentric coordinates :math:`w_i` of :math:`x`,
   :math:`n = \\sum_i w_i n_i / \\lVert\\sum_i w_i n_i\\rVert`;
4. the projected body position is :math:`x + h\\,n`.

The three points are chosen around the incidence point of a first pass, so the
projection stays accurate when ``h`` exceeds the cloud spacing. Everything is
vectorised over ``N`` query points. Frames: the cloud's (CAD) frame, m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

__all__ = ["Projection", "SurfaceModel"]


@dataclass(frozen=True, eq=False)
class Projection:
    """Result of :meth:`SurfaceModel.project` (shapes ``(3,)`` or ``(N, 3)``, CAD frame).

    Attributes
    ----------
    point
        Projected body position :math:`x + h\\,n`, m.
    normal
        Interpolated unit outward normal at the incidence point.
    incidence
        Incidence point of the body z-axis line on the local surface plane, m.
    ok
        False where no valid projection exists (fewer than three non-collinear
        neighbours, line parallel to the local plane, beyond ``max_distance``, or
        the incidence point far outside the local triangle); the other fields are
        then the nearest cloud point and its normal, never NaN.
    offset
        Signed distance of the query along the projection direction beyond the
        projected point, :math:`d^\\top(p - x) - h\\,d^\\top n`, m (≈ height error).
    """

    point: FloatArray
    normal: FloatArray
    incidence: FloatArray
    ok: BoolArray | bool
    offset: FloatArray | float


class SurfaceModel:
    """A surface given by a dense point cloud with unit normals, in a k-d tree.

    Parameters
    ----------
    points : (M, 3) array_like
        Surface samples, m (CAD frame). At least 3.
    normals : (M, 3) array_like
        Outward normals at the samples (normalised here).
    k_neighbours
        Candidates examined for the non-collinear third point (≥ 3).
    min_sine
        Least sine of the angle at :math:`q_0` for the triangle to count as
        non-collinear, in ``(0, 1)``.
    """

    def __init__(
        self,
        points: npt.ArrayLike,
        normals: npt.ArrayLike,
        *,
        k_neighbours: int = 8,
        min_sine: float = 0.25,
    ) -> None:
        pts = np.asarray(points, dtype=float)
        nrm = np.asarray(normals, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
            raise ValueError(f"points must be an (M, 3) array with M ≥ 3, got shape {pts.shape}")
        if nrm.shape != pts.shape:
            raise ValueError(f"normals must have the shape of points {pts.shape}, got {nrm.shape}")
        if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(nrm))):
            raise ValueError("points and normals must be finite")
        length = np.linalg.norm(nrm, axis=1)
        if np.any(length < 1e-9):
            raise ValueError("normals must be non-zero vectors")
        if int(k_neighbours) != k_neighbours or k_neighbours < 3:
            raise ValueError(f"k_neighbours must be an integer ≥ 3, got {k_neighbours!r}")
        if not 0.0 < min_sine < 1.0:
            raise ValueError(f"min_sine must be in (0, 1), got {min_sine!r}")
        self._points = pts.copy()
        self._normals = nrm / length[:, None]
        self._points.setflags(write=False)
        self._normals.setflags(write=False)
        self._tree = cKDTree(self._points)
        self._k = int(min(k_neighbours, len(pts)))
        self._min_sine = float(min_sine)
        sample = self._points[:: max(1, len(pts) // 2000)]
        d, _ = self._tree.query(sample, k=2)
        self._spacing = float(np.median(d[:, 1]))

    @property
    def points(self) -> FloatArray:
        """(M, 3) cloud points, m (read-only)."""
        return self._points

    @property
    def normals(self) -> FloatArray:
        """(M, 3) unit normals (read-only)."""
        return self._normals

    @property
    def spacing(self) -> float:
        """Median nearest-neighbour distance of the cloud, m."""
        return self._spacing

    def nearest(self, p: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Nearest cloud point(s), their normal(s) and distance(s) (m) to ``p`` (3,) or (N, 3)."""
        q, single = self._as_points(p, "p")
        dist, idx = self._tree.query(q)
        pts, nrm = self._points[idx], self._normals[idx]
        if single:
            return pts[0], nrm[0], dist[:1]
        return pts, nrm, dist

    def project(
        self,
        p: npt.ArrayLike,
        body_z: npt.ArrayLike | None = None,
        h: float = 0.0,
        *,
        max_distance: float | None = None,
    ) -> Projection:
        """Project body position(s) along the body z-axis onto the surface, ``h`` above it.

        Parameters
        ----------
        p : (3,) or (N, 3) array_like
            Body origin(s), m, CAD frame.
        body_z : (3,) or (N, 3) array_like, optional
            Body z-axis direction(s) (normalised here); one direction is used for all
            points if shape (3,). ``None``: along the surface normal (closest-point
            projection; the nearest sample's normal, then the interpolated normal).
        h
            Height of the body origin above the surface along the normal, m.
        max_distance
            Largest admissible ``|distance|`` from ``p`` to the incidence point, m;
            beyond it ``ok`` is False.

        Returns
        -------
        Projection
            Shapes follow ``p``.
        """
        q, single = self._as_points(p, "p")
        if not np.isfinite(h):
            raise ValueError(f"h must be a finite height in m, got {h!r}")
        n = len(q)
        if body_z is None:
            _, idx0 = self._tree.query(q)
            d = self._normals[idx0].copy()
        else:
            d = np.asarray(body_z, dtype=float)
            if d.shape == (3,):
                d = np.broadcast_to(d, (n, 3)).copy()
            if d.shape != (n, 3) or not np.all(np.isfinite(d)):
                raise ValueError(
                    f"body_z must be a finite (3,) or ({n}, 3) array, got shape {d.shape}"
                )
            norm = np.linalg.norm(d, axis=1)
            if np.any(norm < 1e-12):
                raise ValueError("body_z must be a non-zero direction")
            d = d / norm[:, None]

        x, tri, ok = self._intersect(q, d, q)
        if body_z is None:
            # closest-point projection: follow the interpolated normal at the first
            # incidence point rather than the nearest sample's normal
            w0 = _barycentric(x, *(self._points[tri[:, i]] for i in range(3)))
            n0 = np.einsum("ni,nij->nj", w0, self._normals[tri])
            n0_len = np.linalg.norm(n0, axis=1)
            good = ok & (n0_len > 1e-6)
            d = np.where(good[:, None], n0 / np.where(good, n0_len, 1.0)[:, None], d)
        x2, tri2, ok2 = self._intersect(q, d, np.where(ok[:, None], x, q))
        use2 = ok2
        x = np.where(use2[:, None], x2, x)
        tri = np.where(use2[:, None], tri2, tri)
        ok = ok | ok2

        q0, q1, q2 = (self._points[tri[:, i]] for i in range(3))
        w = _barycentric(x, q0, q1, q2)
        nsum = np.einsum("ni,nij->nj", w, self._normals[tri])
        nlen = np.linalg.norm(nsum, axis=1)
        ok &= (nlen > 1e-6) & (w.min(axis=1) > -1.0)
        normal = nsum / np.where(nlen > 1e-6, nlen, 1.0)[:, None]
        dist = np.einsum("ij,ij->i", x - q, d)
        if max_distance is not None:
            ok &= np.abs(dist) <= max_distance
        # fallback: nearest cloud point, never NaN
        if not np.all(ok):
            _, idx_f = self._tree.query(q[~ok])
            x[~ok] = self._points[idx_f]
            normal[~ok] = self._normals[idx_f]
        point = x + h * normal
        offset = np.einsum("ij,ij->i", q - point, d)
        if single:
            return Projection(point[0], normal[0], x[0], bool(ok[0]), float(offset[0]))
        return Projection(point, normal, x, ok, offset)

    def _intersect(
        self, q: FloatArray, d: FloatArray, around: FloatArray
    ) -> tuple[FloatArray, npt.NDArray[np.intp], BoolArray]:
        """Line ``q + s d`` ∩ plane of the three nearest non-collinear points to ``around``."""
        _, idx = self._tree.query(around, k=self._k)
        if idx.ndim == 1:
            idx = idx[:, None]
        cand = self._points[idx]  # (N, K, 3)
        q0 = cand[:, 0]
        e = cand - q0[:, None, :]
        elen = np.linalg.norm(e, axis=2)
        # second vertex: first neighbour distinct from q0
        distinct = elen > 1e-12
        distinct[:, 0] = False
        has1 = distinct.any(axis=1)
        j1 = np.argmax(distinct, axis=1)
        rows = np.arange(len(q))
        e1 = e[rows, j1]
        cross = np.cross(e1[:, None, :], e)
        sine = np.linalg.norm(cross, axis=2) / np.maximum(
            elen * np.maximum(elen[rows, j1], 1e-300)[:, None], 1e-300
        )
        valid = sine > self._min_sine
        valid[:, 0] = False
        valid[rows, j1] = False
        has2 = valid.any(axis=1)
        j2 = np.argmax(valid, axis=1)
        tri = np.stack([idx[:, 0], idx[rows, j1], idx[rows, j2]], axis=1)
        n_pl = cross[rows, j2]
        n_len = np.linalg.norm(n_pl, axis=1)
        n_pl = n_pl / np.where(n_len > 0, n_len, 1.0)[:, None]
        denom = np.einsum("ij,ij->i", n_pl, d)
        ok = has1 & has2 & (np.abs(denom) > 1e-3)
        s = np.einsum("ij,ij->i", n_pl, q0 - q) / np.where(ok, denom, 1.0)
        x = q + np.where(ok, s, 0.0)[:, None] * d
        return x, tri, ok

    @staticmethod
    def _as_points(p: npt.ArrayLike, name: str) -> tuple[FloatArray, bool]:
        arr = np.asarray(p, dtype=float)
        single = arr.shape == (3,)
        if single:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise ValueError(f"{name} must have shape (3,) or (N, 3), got {np.shape(p)}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite")
        return arr, single


def _barycentric(x: FloatArray, a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """Barycentric coordinates (N, 3) of points ``x`` in triangles ``(a, b, c)`` (their plane)."""
    v0, v1, v2 = b - a, c - a, x - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) > 1e-300, den, 1.0)
    wb = (d11 * d20 - d01 * d21) / den
    wc = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - wb - wc, wb, wc], axis=1)
