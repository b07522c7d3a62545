"""Vectorised planar ray casting against a scene's box and cylinder footprints.

:class:`PrimitiveArrays` packs the static scenery of a
:class:`~realitygap.robots.world.World` (its :class:`~realitygap.robots.world.Primitive`
footprints) into arrays once per scene; the fast sensor mode's scan then casts all its
beams against all of them in a fixed, small number of numpy calls.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from realitygap.core.jit import KERNELS, compiled

if TYPE_CHECKING:
    from realitygap.robots.world import Primitive

FloatArray = npt.NDArray[np.float64]


class PrimitiveArrays:
    """The primitives of a scene packed into arrays for vectorised ray casting.

    Built once per scene; :meth:`ray_cast` then costs a few numpy operations on
    ``(n_primitives, n_rays)`` arrays, written into work arrays kept per ray count (one
    caster per thread).
    """

    def __init__(self, primitives: list[Primitive]):
        boxes = [q for q in primitives if q.shape == "box"]
        cyls = [q for q in primitives if q.shape == "cylinder"]
        self.box_center = np.array([b.center for b in boxes], dtype=float).reshape(-1, 2)
        self.box_cos = np.cos([b.yaw for b in boxes]).reshape(-1, 1)
        self.box_sin = np.sin([b.yaw for b in boxes]).reshape(-1, 1)
        self.box_half = np.array([b.half_extents for b in boxes], dtype=float).reshape(-1, 2)
        self.cyl_center = np.array([c.center for c in cyls], dtype=float).reshape(-1, 2)
        self.cyl_r2 = np.array([c.radius**2 for c in cyls], dtype=float).reshape(-1, 1)
        nb, nc = len(boxes), len(cyls)
        self._nb, self._nc = nb, nc
        # the two slabs of every box stacked on a leading axis (x slab, y slab), so that one
        # ufunc call does the arithmetic of both: rows of the box-frame rotation and half sizes
        self._slab_cos = np.stack([self.box_cos, -self.box_sin])  # (2, n_boxes, 1)
        self._slab_sin = np.stack([self.box_sin, self.box_cos])
        slab_half = np.stack([self.box_half[:, :1], self.box_half[:, 1:]])
        # both faces of both slabs: (face -/+, slab, n_boxes, 1)
        self._slab_faces = np.stack([-slab_half, slab_half])
        # Rows: the boxes' x slabs, their y slabs, the cylinders. Each row's formulas share
        # one form, a·X + b·Y with (a, b) a coefficient pair (a box slab's row of the
        # box-frame rotation; a cylinder's offset from the ray origin, written per cast):
        # (X, Y) = the ray direction gives a box slab's direction component and a
        # cylinder's b; (X, Y) = the row's offset from the ray origin gives a box slab's
        # origin coordinate and a cylinder's squared distance. So one call per step of the
        # arithmetic serves all rows.
        rows = 2 * nb + nc
        self._coef = np.zeros((2, rows, 1))
        self._coef[0, : 2 * nb] = self._slab_cos.reshape(-1, 1)
        self._coef[1, : 2 * nb] = self._slab_sin.reshape(-1, 1)
        centers = np.concatenate([self.box_center, self.box_center, self.cyl_center])
        self._row_center = centers.T.reshape(2, rows, 1).copy()  # (axis, row, 1)
        self._origin = np.zeros((2, 1, 1))
        self._offset = np.empty((2, rows, 1))  # origin - row centre
        self._offset_cyl = self._offset[:, 2 * nb :]
        self._coef_cyl = self._coef[:, 2 * nb :]
        self._prod = np.empty((2, rows, 1))
        self._prod_x, self._prod_y = self._prod[0], self._prod[1]
        self._sum = np.empty((rows, 1))  # a box slab's origin coordinate, a cylinder's |offset|²
        self._o_local = self._sum[: 2 * nb].reshape(2, nb, 1)  # origin in the box frames
        self._dist2 = self._sum[2 * nb :]
        self._cc = np.empty((nc, 1))
        self._buffers: dict[int, tuple[FloatArray, ...]] = {}
        # the compiled kernel's layout: one row per box (centre x, y, cos, sin of its yaw,
        # half sizes x, y, circumradius) and per cylinder (centre x, y, squared radius)
        self.box_rows = np.ascontiguousarray(
            np.column_stack(
                [
                    self.box_center,
                    self.box_cos,
                    self.box_sin,
                    self.box_half,
                    np.hypot(self.box_half[:, 0], self.box_half[:, 1]),
                ]
            )
        ).reshape(-1, 7)
        self.cyl_rows = np.ascontiguousarray(
            np.column_stack([self.cyl_center, self.cyl_r2])
        ).reshape(-1, 3)

    def clearance(self, x: float, y: float) -> float:
        """Smallest distance (m) in the plane from the point ``(x, y)`` (m) to any footprint
        (negative inside one); ``inf`` without primitives. A point this far from every
        footprint is at least as far from the primitives, whatever its height."""
        if _clearance_rows_compiled is not None and KERNELS.on:
            return _clearance_rows_compiled(float(x), float(y), self.box_rows, self.cyl_rows)
        best = math.inf
        if len(self.box_center):
            rx = x - self.box_center[:, 0]
            ry = y - self.box_center[:, 1]
            c, s = self.box_cos[:, 0], self.box_sin[:, 0]
            q = np.abs(np.stack([c * rx + s * ry, -s * rx + c * ry], axis=-1)) - self.box_half
            outside = np.hypot(*np.maximum(q, 0.0).T)
            inside = np.minimum(q.max(axis=-1), 0.0)
            best = min(best, float((outside + inside).min()))
        if len(self.cyl_center):
            d = np.hypot(x - self.cyl_center[:, 0], y - self.cyl_center[:, 1])
            best = min(best, float((d - np.sqrt(self.cyl_r2[:, 0])).min()))
        return best

    def ray_cast(
        self, origin_xy: npt.ArrayLike, directions: FloatArray, range_max: float
    ) -> FloatArray:
        """Distance along each planar ray (n, 2 unit directions) to the first hit; ``inf`` beyond
        ``range_max``."""
        ox, oy = (float(v) for v in np.asarray(origin_xy, dtype=float)[:2])
        d = np.asarray(directions, dtype=float)
        return self.ray_cast_xy(ox, oy, d[:, 0], d[:, 1], range_max)

    def _work_arrays(self, n: int) -> tuple[FloatArray, ...]:
        """Work arrays (and views of them) of a cast of ``n`` rays, made once per ray count."""
        bufs = self._buffers.get(n)
        if bufs is None:
            nb, nc = self._nb, self._nc
            rows = 2 * nb + nc
            terms = np.empty((2, rows, n))  # a·dx and b·dy per row
            lin = np.empty((rows, n))  # a·dx + b·dy per row, see __init__
            t_face = np.empty((2, 2, nb, n))  # slab distances to both faces
            t_far = np.empty((2, nb, n))
            cand = np.empty((nb + nc, n))  # each primitive's entry distance per ray
            valid = np.empty((nb + nc, n), dtype=bool)  # ... where the ray hits it
            d_local = lin[: 2 * nb].reshape(2, nb, n)  # ray directions in the box frames
            bufs = self._buffers[n] = (
                terms,
                terms[0],
                terms[1],
                lin,
                t_face,
                t_face[0],
                t_face[1],
                d_local,
                d_local[0],
                d_local[1],
                t_far,
                t_far[0],
                t_far[1],
                cand,
                cand[:nb],
                cand[nb:],
                valid,
                valid[:nb],
                valid[nb:],
                lin[2 * nb :],  # a cylinder's b = offset · direction
                terms[0, 2 * nb :],  # its discriminant
            )
        return bufs

    def ray_cast_xy(
        self, ox: float, oy: float, dx: FloatArray, dy: FloatArray, range_max: float
    ) -> FloatArray:
        """:meth:`ray_cast` from ``(ox, oy)`` (m) along unit directions given as their x and
        y components ``dx``, ``dy`` (n,)."""
        d = np.stack([np.asarray(dx, dtype=float), np.asarray(dy, dtype=float)])
        return self.cast_directions(ox, oy, d[:, None, :], range_max)

    def cast_directions(
        self, ox: float, oy: float, directions: FloatArray, range_max: float
    ) -> FloatArray:
        """:meth:`ray_cast` from ``(ox, oy)`` (m) along unit directions ``directions``
        (2, 1, n): their x components in ``[0, 0]``, y in ``[1, 0]`` (the per-step form of
        the fast scan, which keeps its directions in that layout)."""
        n = directions.shape[-1]
        nb, nc = self._nb, self._nc
        if nb + nc == 0:
            return np.full(n, np.inf)
        (
            terms,
            term_x,
            term_y,
            lin,
            t_face,
            t_lo,
            t_hi,
            d_local,
            near_x,
            near_y,
            t_far,
            far_x,
            far_y,
            cand,
            cand_box,
            cand_cyl,
            valid,
            valid_box,
            valid_cyl,
            b,
            disc,
        ) = self._work_arrays(n)
        minimum, maximum, multiply = np.minimum, np.maximum, np.multiply
        origin, coef = self._origin, self._coef
        origin[0, 0, 0], origin[1, 0, 0] = ox, oy
        with np.errstate(divide="ignore", invalid="ignore"):
            # every row's offset from the origin; a cylinder's is its coefficient pair
            np.subtract(origin, self._row_center, out=self._offset)
            if nc:
                np.copyto(self._coef_cyl, self._offset_cyl)
            # boxes: c·rx + s·ry, the origin in the box frame; cylinders: rx·rx + ry·ry
            multiply(coef, self._offset, out=self._prod)
            np.add(self._prod_x, self._prod_y, out=self._sum)
            # boxes: directions in the box frames; cylinders: b = r · direction
            multiply(coef, directions, out=terms)
            np.add(term_x, term_y, out=lin)
            if nb:
                # slab method in each box's frame; [0] is the x slab, [1] the y slab
                np.divide(self._slab_faces - self._o_local, d_local, out=t_face)
                minimum(t_lo, t_hi, out=d_local)  # near faces
                maximum(t_lo, t_hi, out=t_far)
                tmin = maximum(near_x, near_y, out=cand_box)
                maximum(tmin, 0.0, out=tmin)
                tmax = minimum(far_x, far_y, out=near_x)
                # a NaN bound (a ray along a face) compares False: no hit, never NaN
                np.greater_equal(tmax, tmin, out=valid_box)
            if nc:
                cc = np.subtract(self._dist2, self.cyl_r2, out=self._cc)
                multiply(b, b, out=disc)
                disc -= cc
                np.sqrt(disc, out=disc)  # NaN where the ray's line misses the circle
                t = np.negative(b, out=cand_cyl)
                t -= disc
                if min(cc.ravel().tolist()) < 0.0:
                    t[cc[:, 0] < 0] = 0.0  # the origin inside: hit at once
                # t >= 0 is False for NaN: a miss, like a circle behind the origin
                np.greater_equal(t, 0.0, out=valid_cyl)
            # (np.where and a plain reduction cost less than a reduction with where=)
            best = minimum.reduce(np.where(valid, cand, np.inf), axis=0)
        best[best > range_max] = np.inf
        return best


def clearance_rows(x: float, y: float, box_rows: FloatArray, cyl_rows: FloatArray) -> float:
    """Loop form of :meth:`PrimitiveArrays.clearance`: smallest signed distance (m) from
    ``(x, y)`` (m) to the boxes ``box_rows`` and cylinders ``cyl_rows``
    (:attr:`PrimitiveArrays.box_rows`, :attr:`PrimitiveArrays.cyl_rows`), ``inf`` without
    any; per box the rounded-box distance ``|max(q, 0)| + min(max(q_x, q_y), 0)`` of
    ``q = |p_box| - half``, per cylinder ``|p - c| - r``. The same operations as the NumPy
    form, primitive by primitive."""
    best = np.inf
    for i in range(box_rows.shape[0]):
        rx, ry = x - box_rows[i, 0], y - box_rows[i, 1]
        c, s = box_rows[i, 2], box_rows[i, 3]
        qx = abs(c * rx + s * ry) - box_rows[i, 4]
        qy = abs(-s * rx + c * ry) - box_rows[i, 5]
        d = np.hypot(max(qx, 0.0), max(qy, 0.0)) + min(max(qx, qy), 0.0)
        if d < best:
            best = d
    for i in range(cyl_rows.shape[0]):
        d = np.hypot(x - cyl_rows[i, 0], y - cyl_rows[i, 1]) - np.sqrt(cyl_rows[i, 2])
        if d < best:
            best = d
    return best


_clearance_rows_compiled = compiled(clearance_rows)
""":func:`clearance_rows` compiled by Numba; ``None`` without Numba."""


def cast_rotated_beams(
    ox: float,
    oy: float,
    c: float,
    s: float,
    beam_cos: FloatArray,
    beam_sin: FloatArray,
    box_rows: FloatArray,
    cyl_rows: FloatArray,
    range_max: float,
    out: FloatArray,
) -> None:
    """Loop form of :meth:`PrimitiveArrays.cast_directions` for beams at bearings with
    cosines ``beam_cos`` and sines ``beam_sin`` (n,) in a frame rotated by the angle of
    cosine ``c`` and sine ``s``, from ``(ox, oy)`` (m), into ``out`` (n,) (m, ``inf``
    beyond ``range_max``). ``box_rows`` and ``cyl_rows`` are
    :attr:`PrimitiveArrays.box_rows` and :attr:`PrimitiveArrays.cyl_rows`.

    The same floating-point operations in the same order as the NumPy form, beam by
    beam: compiled (:data:`cast_rotated_beams_compiled`) it gives the same bits.
    """
    nb, nc = box_rows.shape[0], cyl_rows.shape[0]
    # per box, whatever the beam: the origin's offset from the centre and in the box frame
    box_rx, box_ry = np.empty(nb), np.empty(nb)
    box_ox, box_oy = np.empty(nb), np.empty(nb)
    for i in range(nb):
        bc, bs = box_rows[i, 2], box_rows[i, 3]
        rx, ry = ox - box_rows[i, 0], oy - box_rows[i, 1]
        box_rx[i], box_ry[i] = rx, ry
        box_ox[i], box_oy[i] = bc * rx + bs * ry, -bs * rx + bc * ry
    for j in range(beam_cos.shape[0]):
        dx = beam_cos[j] * c + beam_sin[j] * -s  # world-frame direction
        dy = beam_cos[j] * s + beam_sin[j] * c
        best = np.inf
        for i in range(nb):
            # A box is skipped only where its circumscribed circle (radius R) shows that
            # the beam cannot meet it before the best hit so far: an entry point lies in
            # that circle, so its distance is at least proj - R, and a beam passing the
            # centre farther than R misses. The margins (1e-9 m, 1e-6 m²) exceed the
            # rounding of the slab arithmetic by far, so a skipped box is one the slab
            # method would not have taken: the result is unchanged, bit for bit.
            rx, ry, big_r = box_rx[i], box_ry[i], box_rows[i, 6]
            proj = -(rx * dx + ry * dy)  # distance along the beam to the centre's foot
            if proj - big_r > best + 1e-9 or proj + big_r < -1e-9:
                continue
            if (rx * rx + ry * ry) - proj * proj > big_r * big_r + 1e-6:
                continue
            bc, bs, hx, hy = box_rows[i, 2], box_rows[i, 3], box_rows[i, 4], box_rows[i, 5]
            o_x, o_y = box_ox[i], box_oy[i]  # origin in the box frame
            d_x, d_y = bc * dx + bs * dy, -bs * dx + bc * dy  # direction in the box frame
            # Skipped too, without the divisions: an origin beyond a slab's face with the
            # beam not pointing back (most beams and a room's walls). Both distances to
            # that slab's faces are then negative (far < 0: tmax < 0 <= tmin), or both
            # +inf for a direction of -0.0 (tmin = inf, not below best), or NaN: the slab
            # method below would not take the box either, so the result is the same bits.
            if (o_x > hx and d_x >= 0.0) or (o_x < -hx and d_x <= 0.0):
                continue
            if (o_y > hy and d_y >= 0.0) or (o_y < -hy and d_y <= 0.0):
                continue
            lo_x, hi_x = (-hx - o_x) / d_x, (hx - o_x) / d_x
            lo_y, hi_y = (-hy - o_y) / d_y, (hy - o_y) / d_y
            # np.minimum / np.maximum on two floats, NaN when either is NaN (a ray along
            # a face): "a if a <= b or a is NaN else b"
            near_x = lo_x if (lo_x <= hi_x or lo_x != lo_x) else hi_x
            far_x = lo_x if (lo_x >= hi_x or lo_x != lo_x) else hi_x
            near_y = lo_y if (lo_y <= hi_y or lo_y != lo_y) else hi_y
            far_y = lo_y if (lo_y >= hi_y or lo_y != lo_y) else hi_y
            tmin = near_x if (near_x >= near_y or near_x != near_x) else near_y
            tmin = tmin if (tmin > 0.0 or tmin != tmin) else 0.0  # -0.0 -> 0.0, as NumPy
            tmax = far_x if (far_x <= far_y or far_x != far_x) else far_y
            # a NaN bound compares False: no hit
            if tmax >= tmin and tmin < best:
                best = tmin
        for i in range(nc):
            rx, ry = ox - cyl_rows[i, 0], oy - cyl_rows[i, 1]
            cc = (rx * rx + ry * ry) - cyl_rows[i, 2]
            b = rx * dx + ry * dy
            t = -b - np.sqrt(b * b - cc)  # NaN where the ray's line misses the circle
            if cc < 0.0:
                t = 0.0  # the origin inside: hit at once
            if t >= 0.0 and t < best:
                best = t
        out[j] = np.inf if best > range_max else best


cast_rotated_beams_compiled = compiled(cast_rotated_beams)
""":func:`cast_rotated_beams` compiled by Numba; ``None`` without Numba."""
