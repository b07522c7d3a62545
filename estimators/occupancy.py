r"""Log-odds occupancy grid built from planar scans.

Every cell stores the log-odds of being occupied,

.. math::

    l = \log \frac{p}{1 - p}, \qquad p = \frac{1}{1 + e^{-l}},

starting at ``l = 0`` (p = ½). A scan taken at a known pose adds ``l_free`` to
each cell a beam crosses before its end point and ``l_occ`` to each end-point
cell, then clamps to ``[l_min, l_max]`` so that the map can still change its
mind. A cell is updated at most once per scan, and a hit overrides a
traversal within the same scan.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import check_finite
from realitygap.estimators.base import Scan

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.intp]

__all__ = ["OccupancyGrid"]


class OccupancyGrid:
    """2-D log-odds occupancy grid in the world frame.

    Cell ``(iy, ix)`` covers ``[ox + ix·res, ox + (ix+1)·res) × [oy + iy·res,
    oy + (iy+1)·res)``; arrays are indexed ``[iy, ix]`` (rows along world y).

    Parameters
    ----------
    resolution : float
        Cell side [m].
    size_m : (float, float)
        Extent ``(W, H)`` of the map along world x and y [m]; rounded up to whole
        cells.
    origin_xy : (float, float), optional
        World position [m] of the grid's lower-left corner; by default the grid
        is centred on the world origin.
    l_occ : float
        Log-odds increment for an end-point cell, > 0 (default
        ``log(0.7/0.3)``).
    l_free : float
        Log-odds increment for a traversed cell, < 0 (default ``log(0.4/0.6)``).
    l_min, l_max : float
        Clamping bounds, ``l_min < 0 < l_max``.

    Examples
    --------
    >>> from realitygap.estimators.base import Scan
    >>> grid = OccupancyGrid(resolution=0.1, size_m=(4.0, 4.0))
    >>> scan = Scan(t=0.0, angles=np.array([0.0]), ranges=np.array([1.0]),
    ...             range_min=0.0, range_max=3.0)
    >>> grid.update([0.0, 0.0, 0.0], scan)
    >>> bool(grid.is_occupied([1.0, 0.0])), bool(grid.is_occupied([0.5, 0.0]))
    (True, False)
    """

    def __init__(
        self,
        resolution: float = 0.05,
        size_m: tuple[float, float] = (10.0, 10.0),
        origin_xy: tuple[float, float] | None = None,
        l_occ: float = float(np.log(0.7 / 0.3)),
        l_free: float = float(np.log(0.4 / 0.6)),
        l_min: float = -4.0,
        l_max: float = 4.0,
    ) -> None:
        if not (np.isfinite(resolution) and resolution > 0.0):
            raise ValueError(f"resolution must be a positive cell size in m, got {resolution}")
        size = check_finite("size_m", size_m, shape=(2,))
        if np.any(size < resolution):
            raise ValueError(
                f"size_m must be at least one cell ({resolution} m) per side, got {size_m}"
            )
        if not (l_occ > 0.0 and l_free < 0.0):
            raise ValueError(f"need l_occ > 0 and l_free < 0, got l_occ={l_occ}, l_free={l_free}")
        if not (l_min < 0.0 < l_max):
            raise ValueError(f"need l_min < 0 < l_max, got l_min={l_min}, l_max={l_max}")
        self.resolution = float(resolution)
        self.nx, self.ny = (int(np.ceil(s / self.resolution - 1e-9)) for s in size)
        origin = (
            -0.5 * size if origin_xy is None else check_finite("origin_xy", origin_xy, shape=(2,))
        )
        self.origin_xy: FloatArray = origin.copy()
        self.l_occ, self.l_free = float(l_occ), float(l_free)
        self.l_min, self.l_max = float(l_min), float(l_max)
        self._log_odds = np.zeros((self.ny, self.nx))
        self._free = np.zeros(self.ny * self.nx, dtype=bool)  # scratch masks
        self._hit = np.zeros(self.ny * self.nx, dtype=bool)

    # -- state ---------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, int]:
        """Grid shape ``(ny, nx)``."""
        return (self.ny, self.nx)

    @property
    def log_odds(self) -> FloatArray:
        """Read-only view of the log-odds, shape (ny, nx)."""
        view = self._log_odds.view()
        view.setflags(write=False)
        return view

    def reset(self) -> None:
        """Forget everything: all cells back to ``l = 0`` (p = ½)."""
        self._log_odds.fill(0.0)

    def probability(self) -> FloatArray:
        """Occupancy probability of every cell, shape (ny, nx)."""
        return 1.0 / (1.0 + np.exp(-self._log_odds))

    # -- coordinates ---------------------------------------------------------

    def cell_from_world(self, xy: npt.ArrayLike) -> tuple[IntArray, IntArray, BoolArray]:
        """Cell indices of world points.

        Parameters
        ----------
        xy : array_like, shape (..., 2)
            World positions [m].

        Returns
        -------
        ix, iy : ndarray of int, shape (...)
            Column and row indices (meaningful only where ``inside``).
        inside : ndarray of bool, shape (...)
            Whether the point lies on the grid.
        """
        xy = check_finite("xy", xy)
        if xy.ndim == 0 or xy.shape[-1] != 2:
            raise ValueError(f"xy must have shape (..., 2), got {xy.shape}")
        ix = np.floor((xy[..., 0] - self.origin_xy[0]) / self.resolution).astype(np.intp)
        iy = np.floor((xy[..., 1] - self.origin_xy[1]) / self.resolution).astype(np.intp)
        inside = (ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)
        return ix, iy, inside

    def world_from_cell(self, ix: npt.ArrayLike, iy: npt.ArrayLike) -> FloatArray:
        """World positions [m] of cell centres, shape (..., 2)."""
        x = self.origin_xy[0] + (np.asarray(ix, dtype=float) + 0.5) * self.resolution
        y = self.origin_xy[1] + (np.asarray(iy, dtype=float) + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    # -- queries -------------------------------------------------------------

    def occupied_points(self, threshold: float = 0.65) -> FloatArray:
        """World centres [m] of the cells with occupancy probability above ``threshold``.

        Returns
        -------
        ndarray, shape (M, 2)
        """
        iy, ix = np.nonzero(self._log_odds > _logit(threshold))
        return self.world_from_cell(ix, iy).reshape(-1, 2)

    def is_occupied(self, xy: npt.ArrayLike, threshold: float = 0.65) -> bool | BoolArray:
        """Whether the cells under world points are occupied (``False`` off the grid).

        Parameters
        ----------
        xy : array_like, shape (2,) or (M, 2)
            World positions [m].
        threshold : float
            Probability above which a cell counts as occupied.

        Returns
        -------
        bool or ndarray of bool, shape (M,)
        """
        ix, iy, inside = self.cell_from_world(xy)
        occ = np.zeros(inside.shape, dtype=bool)
        occ[inside] = self._log_odds[iy[inside], ix[inside]] > _logit(threshold)
        return bool(occ) if occ.ndim == 0 else occ

    # -- update --------------------------------------------------------------

    def update(self, pose: npt.ArrayLike, scan: Scan, *, free_no_return: bool = False) -> None:
        r"""Integrate one scan taken with the base at ``pose``.

        Beam ``i`` leaves the base at bearing :math:`\theta + \alpha_i`. A range
        in ``[range_min, range_max)`` is a hit: its end-point cell gets
        ``l_occ`` and the cells before it ``l_free``. The traversed cells are
        found by sampling each beam every half cell (vectorised over all beams
        and samples). Beams with no return (``inf``, or ≥ ``range_max``) clear
        the cells up to ``range_max`` only if ``free_no_return`` is set: for a
        depth camera an empty bearing may also be a hole in the depth image.

        Parameters
        ----------
        pose : array_like, shape (3,)
            Base pose ``[x, y, theta]`` (m, m, rad) in the world.
        scan : Scan
            Planar scan in the base frame.
        free_no_return : bool
            Treat beams without a return as free space up to ``range_max``.
        """
        pose = check_finite("pose", pose, shape=(3,))
        if not isinstance(scan, Scan):
            raise TypeError(f"scan must be a Scan, got {type(scan).__name__}")
        angles = check_finite("scan.angles", scan.angles)
        ranges = np.asarray(scan.ranges, dtype=float)
        if angles.ndim != 1 or ranges.shape != angles.shape:
            raise ValueError(
                f"scan.angles and scan.ranges must be 1-D of equal length, "
                f"got {angles.shape} and {ranges.shape}"
            )
        if np.any(np.isnan(ranges)):
            raise ValueError("scan.ranges must not contain nan (use inf for no return)")

        hit = (ranges >= scan.range_min) & (ranges < scan.range_max)
        free_len = np.where(hit, ranges, 0.0)
        if free_no_return:
            free_len = np.where(ranges >= scan.range_max, scan.range_max, free_len)
        bearing = pose[2] + angles
        cos_b, sin_b = np.cos(bearing), np.sin(bearing)

        free, occ = self._free, self._hit
        n_cells = self.nx * self.ny
        if np.any(hit):
            end = np.stack(
                [pose[0] + ranges[hit] * cos_b[hit], pose[1] + ranges[hit] * sin_b[hit]], -1
            )
            ix, iy, inside = self.cell_from_world(end)
            occ[(iy * self.nx + ix)[inside]] = True
        longest = float(free_len.max(initial=0.0))
        if longest > 0.0:
            step = 0.5 * self.resolution
            s = np.arange(int(np.ceil(longest / step))) * step  # (n_s,)
            beams = np.flatnonzero(free_len > 0.0)
            along = s[None, :] < free_len[beams, None]  # (n_b, n_s)
            sx = pose[0] + s[None, :] * cos_b[beams, None]
            sy = pose[1] + s[None, :] * sin_b[beams, None]
            ix = np.floor((sx[along] - self.origin_xy[0]) / self.resolution).astype(np.intp)
            iy = np.floor((sy[along] - self.origin_xy[1]) / self.resolution).astype(np.intp)
            inside = (ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)
            free[(iy * self.nx + ix)[inside]] = True
            free &= ~occ
        flat = self._log_odds.reshape(n_cells)
        flat[free] += self.l_free
        flat[occ] += self.l_occ
        np.clip(flat, self.l_min, self.l_max, out=flat)
        free.fill(False)
        occ.fill(False)


def _logit(p: float) -> float:
    if not 0.0 < p < 1.0:
        raise ValueError(f"threshold must be a probability in (0, 1), got {p}")
    return float(np.log(p / (1.0 - p)))
