"""Absolutely coded checkerboard: an m-sequence extended to a 2-D array of unique windows.

Board frame (OpenCV calibration-pattern convention): origin at the outer corner
of cell ``(0, 0)``, x along the columns, y along the rows, z = x × y pointing
into the board, away from a camera that looks at the printed face. Corner
``(i, j)`` (row, column; ``0..cells``) lies at ``(j * cell_size, i * cell_size, 0)``.
Cell ``(i, j)`` is dark when ``i + j`` is even.

Code. An 8-stage Fibonacci LFSR with the primitive feedback polynomial
:math:`x^8 + x^4 + x^3 + x^2 + 1` yields an m-sequence :math:`m_k` of period
255 in which every cyclic window of 8 bits occurs exactly once. Row ``i`` of
the board is that sequence advanced by the triangular number :math:`i(i+1)/2`:

.. math::

    c_{ij} = m_{(j + i(i+1)/2) \\bmod 255}.

Any 8 bits of a row fix the row's phase; the phase steps ``i+1`` between
consecutive rows are all different, so a stack of 8 rows fixes ``i`` and
``j``. :func:`window_statistics` checks exhaustively that all 8×8 windows of
the 50×50 array are distinct also under the four 90° rotations, with a minimum
Hamming distance of 12 between any two (so up to 5 misread bits of an 8×8
window still decode uniquely).

Rendering. Each cell carries its bit as a centred disc of radius
``dot_radius`` (fraction of the cell) in the opposite colour when the bit is
1; the corners, where the checkerboard's X-junctions are detected, stay clean.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
UInt8Array = npt.NDArray[np.uint8]

__all__ = [
    "WINDOW",
    "CodedBoard",
    "lfsr_m_sequence",
    "render_board_image",
    "window_statistics",
]

#: Side of the square code window that identifies a cell (cells).
WINDOW = 8
#: Feedback taps of x^8 + x^4 + x^3 + x^2 + 1: a[k+8] = a[k+4] ^ a[k+3] ^ a[k+2] ^ a[k].
_TAPS = (0, 2, 3, 4)
_PERIOD = 255


def lfsr_m_sequence(taps: tuple[int, ...] = _TAPS, stages: int = 8) -> npt.NDArray[np.uint8]:
    """One period of a binary LFSR sequence, seed ``1, 0, …, 0``.

    Parameters
    ----------
    taps : tuple of int
        Offsets ``k`` whose bits are XOR-ed into the next one,
        :math:`a_{n+s} = \\bigoplus_{k} a_{n+k}` with ``s = stages``.
    stages : int
        Register length ``s``.

    Returns
    -------
    ndarray of uint8, shape (2**stages - 1,)
        One period when the feedback polynomial is primitive (the default is).
    """
    n = 2**stages - 1
    a = [1] + [0] * (stages - 1)
    while len(a) < n + stages:
        k = len(a) - stages
        bit = 0
        for t in taps:
            bit ^= a[k + t]
        a.append(bit)
    return np.array(a[:n], dtype=np.uint8)


@lru_cache(maxsize=4)
def _code_array(cells: int) -> npt.NDArray[np.uint8]:
    m = lfsr_m_sequence()
    rows = np.arange(cells)
    shift = (rows * (rows + 1) // 2) % _PERIOD
    idx = (np.arange(cells)[None, :] + shift[:, None]) % _PERIOD
    code = m[idx]
    code.setflags(write=False)
    return code


@lru_cache(maxsize=4)
def _window_table(cells: int) -> tuple[dict[bytes, tuple[int, int, int]], npt.NDArray[np.uint8]]:
    """Dict of every window and its rotations, and the stacked rotated windows."""
    code = _code_array(cells)
    n = cells - WINDOW + 1
    table: dict[bytes, tuple[int, int, int]] = {}
    stack = np.empty((4, n, n, WINDOW * WINDOW), dtype=np.uint8)
    for r in range(n):
        for c in range(n):
            w = code[r : r + WINDOW, c : c + WINDOW]
            for k in range(4):
                wk = np.ascontiguousarray(np.rot90(w, k))
                stack[k, r, c] = wk.reshape(-1)
                key = wk.tobytes()
                if key in table:
                    raise RuntimeError(f"code window at ({r}, {c}) rotated {k} is not unique")
                table[key] = (r, c, k)
    return table, stack


@dataclass(frozen=True)
class CodedBoard:
    """A square absolutely coded checkerboard.

    Parameters
    ----------
    cells : int
        Cells per side (``>= 8``); the code has ``cells x cells`` bits.
    cell_size : float
        Side of one cell (m).
    dot_radius : float
        Radius of the code dot as a fraction of the cell side, in ``(0.05, 0.3]``.

    Attributes
    ----------
    code : ndarray of uint8, shape (cells, cells)
        The code bit of every cell, ``code[row, col]``.
    """

    cells: int = 50
    cell_size: float = 0.02
    dot_radius: float = 0.2
    code: npt.NDArray[np.uint8] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.cells, (int, np.integer)) or not WINDOW <= self.cells <= 127:
            raise ValueError(f"cells must be an int in [{WINDOW}, 127], got {self.cells!r}")
        if not (np.isfinite(self.cell_size) and self.cell_size > 0):
            raise ValueError(f"cell_size must be a positive length in m, got {self.cell_size!r}")
        if not 0.05 < self.dot_radius <= 0.3:
            raise ValueError(
                f"dot_radius must be in (0.05, 0.3] cell sides (the dot must keep clear of "
                f"the corners), got {self.dot_radius!r}"
            )
        object.__setattr__(self, "code", _code_array(int(self.cells)))

    @property
    def side(self) -> float:
        """Side of the printed board (m)."""
        return self.cells * self.cell_size

    @property
    def n_corners_per_side(self) -> int:
        """Corner rows (and columns): ``cells + 1``."""
        return self.cells + 1

    def corner_positions(self) -> FloatArray:
        """All grid corners in the board frame.

        Returns
        -------
        ndarray, shape ((cells + 1)**2, 3)
            Row-major: index ``i * (cells + 1) + j`` is corner ``(i, j)`` at
            ``(j * cell_size, i * cell_size, 0)`` m.
        """
        n = self.cells + 1
        i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        return np.column_stack(
            [j.ravel() * self.cell_size, i.ravel() * self.cell_size, np.zeros(n * n)]
        )

    def cell_is_dark(self, row: npt.ArrayLike, col: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """True where cell ``(row, col)`` is printed dark (``row + col`` even)."""
        return (np.asarray(row) + np.asarray(col)) % 2 == 0

    # ------------------------------------------------------------------ decode
    def decode_window(self, bits: npt.ArrayLike) -> tuple[int, int] | None:
        """Locate an upright 8×8 window of code bits.

        Parameters
        ----------
        bits : array_like, shape (8, 8)
            Bits read in board orientation (row index along +y, column along +x).

        Returns
        -------
        (row, col) or None
            Top-left cell of the window on the board, ``None`` when the bits occur
            nowhere upright (a rotated view: see :meth:`decode_window_rotated`).
        """
        hit = self.decode_window_rotated(bits)
        if hit is None or hit[2] != 0:
            return None
        return hit[0], hit[1]

    def decode_window_rotated(self, bits: npt.ArrayLike) -> tuple[int, int, int] | None:
        """Locate an 8×8 window seen in any of the four 90° orientations.

        Returns
        -------
        (row, col, k) or None
            The window equals ``np.rot90(code[row:row+8, col:col+8], k)``.
        """
        b = _check_bits(bits)
        table, _ = _window_table(int(self.cells))
        return table.get(b.tobytes())

    def match_bits(
        self, bits: npt.ArrayLike, valid: npt.ArrayLike | None = None
    ) -> tuple[tuple[int, int, int, int], int]:
        """Best and second-best placement of an observed bit array on the board.

        Every placement of the observed ``(h, w)`` array, rotated by ``k`` quarter
        turns and shifted to every position, is scored by the number of valid bits
        that disagree with the code.

        Parameters
        ----------
        bits : array_like of {0, 1}, shape (h, w)
            Observed bits, ``bits[i, j]`` of observed cell ``(i, j)``.
        valid : array_like of bool, shape (h, w), optional
            Which bits were read (default: all).

        Returns
        -------
        best : (row, col, k, mismatches)
            ``np.rot90(bits, k)`` placed with its top-left cell at ``(row, col)``.
        second_mismatches : int
            Mismatches of the best placement that is not the best one (a large
            number when there is no other placement).
        """
        b = np.asarray(bits).astype(np.int16)
        if b.ndim != 2:
            raise ValueError(f"bits must be a 2-D array, got shape {b.shape}")
        v = np.ones(b.shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
        if v.shape != b.shape:
            raise ValueError(f"valid must have the shape of bits {b.shape}, got {v.shape}")
        code = self.code.astype(np.int16)
        results: list[tuple[int, int, int, int]] = []
        for k in range(4):
            bk = np.rot90(b, k)
            vk = np.rot90(v, k)
            h, w = bk.shape
            if h > self.cells or w > self.cells:
                continue
            win = np.lib.stride_tricks.sliding_window_view(code, (h, w))
            mism = ((win != bk[None, None]) & vk[None, None]).sum(axis=(2, 3))
            for r, c in zip(*np.nonzero(mism <= np.partition(mism.ravel(), 1)[1])):
                results.append((int(r), int(c), k, int(mism[r, c])))
        if not results:
            raise ValueError(f"the observed array {b.shape} is larger than the board")
        results.sort(key=lambda t: t[3])
        second = results[1][3] if len(results) > 1 else 10**6
        return results[0], second

    # ------------------------------------------------------------------ render
    def texture(self, px_per_cell: int = 64) -> UInt8Array:
        """Grey-level image of the printed board, for a simulator or a printer.

        Pixel ``(v, u)`` covers board x in ``[u, u+1) * cell_size / px_per_cell``
        and y in ``[v, v+1) * cell_size / px_per_cell``; dark 0, light 255; dot
        edges are anti-aliased (4×4 super-sampling).

        Parameters
        ----------
        px_per_cell : int
            Pixels per cell side, ``>= 8``.

        Returns
        -------
        ndarray of uint8, shape (cells * px_per_cell, cells * px_per_cell)
        """
        if not isinstance(px_per_cell, (int, np.integer)) or px_per_cell < 8:
            raise ValueError(f"px_per_cell must be an int >= 8, got {px_per_cell!r}")
        return _texture(int(self.cells), int(px_per_cell), float(self.dot_radius))


def _check_bits(bits: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    b = np.asarray(bits)
    if b.shape != (WINDOW, WINDOW):
        raise ValueError(f"bits must have shape ({WINDOW}, {WINDOW}), got {b.shape}")
    if not np.all((b == 0) | (b == 1)):
        raise ValueError("bits must be 0 or 1")
    return np.ascontiguousarray(b.astype(np.uint8))


@lru_cache(maxsize=2)
def _texture(cells: int, ppc: int, dot_radius: float) -> UInt8Array:
    ss = 4
    s = (np.arange(ppc * ss) + 0.5) / (ppc * ss) - 0.5
    inside = (s[None, :] ** 2 + s[:, None] ** 2) <= dot_radius**2
    dot = inside.reshape(ppc, ss, ppc, ss).mean(axis=(1, 3))  # coverage in [0, 1]
    code = _code_array(cells)
    dark = np.add.outer(np.arange(cells), np.arange(cells)) % 2 == 0
    base = np.where(dark, 0.0, 1.0)  # cell background level
    # value = base + (1 - 2 base) * bit * coverage
    sign = (1.0 - 2.0 * base) * code
    img = base[:, None, :, None] + sign[:, None, :, None] * dot[None, :, None, :]
    out = np.round(img.reshape(cells * ppc, cells * ppc) * 255.0).astype(np.uint8)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=2)
def _texture_unit(cells: int, ppc: int, dot_radius: float) -> npt.NDArray[np.float32]:
    """The texture as float32 in [0, 1] (cached for rendering)."""
    return _texture(cells, ppc, dot_radius).astype(np.float32) / np.float32(255.0)


def window_statistics(board: CodedBoard) -> tuple[int, int, int]:
    """Exhaustive check of the code's windows.

    Returns
    -------
    n_windows : int
        Number of 8×8 windows on the board, ``(cells - 7)**2``.
    n_distinct : int
        Distinct bit patterns among all windows in all four rotations
        (``4 * n_windows`` when every placement is unique).
    min_distance : int
        Minimum Hamming distance between an upright window and any other
        (window, rotation) placement.
    """
    _, stack = _window_table(int(board.cells))
    flat = stack.reshape(4, -1, WINDOW * WINDOW)
    n = flat.shape[1]
    allw = flat.reshape(-1, WINDOW * WINDOW)
    n_distinct = len({row.tobytes() for row in allw})
    upright = flat[0].astype(bool)
    packed_all = np.packbits(allw.astype(bool), axis=1)
    packed_up = np.packbits(upright, axis=1)
    min_d = 64
    pop = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1).sum(axis=1)
    for start in range(0, n, 256):
        x = packed_up[start : start + 256, None, :] ^ packed_all[None, :, :]
        d = pop[x].sum(axis=2)
        rows = np.arange(start, min(start + 256, n))
        d[rows - start, rows] = 64  # the window itself
        min_d = min(min_d, int(d.min()))
    return n, n_distinct, min_d


def render_board_image(
    board: CodedBoard,
    K: npt.ArrayLike,
    T_camera_board: npt.ArrayLike,
    image_size: tuple[int, int],
    dist: npt.ArrayLike | None = None,
    *,
    px_per_cell: int = 64,
    supersample: int = 3,
    blur_sigma_px: float = 0.0,
    noise_std: float = 0.0,
    background: float = 128.0,
    contrast: tuple[float, float] = (20.0, 235.0),
    rng: np.random.Generator | None = None,
) -> UInt8Array:
    """Render what a pinhole camera sees of the board, by sampling :meth:`CodedBoard.texture`.

    Each output pixel averages ``supersample**2`` sub-pixel rays (pixel area
    integration, no aliasing); each ray is undistorted with ``dist`` (OpenCV model),
    intersected with the board plane through the homography
    :math:`H = K [r_1\\ r_2\\ t]` and looked up bilinearly in the texture.

    Parameters
    ----------
    board : CodedBoard
    K : array_like, shape (3, 3)
        Camera matrix (px), pixel centres at integer coordinates.
    T_camera_board : array_like, shape (4, 4)
        Board pose in the camera frame (m).
    image_size : (width, height)
        Output size (px).
    dist : array_like, optional
        OpenCV distortion coefficients; ``None`` for none.
    px_per_cell : int
        Texture resolution.
    supersample : int
        Sub-pixel rays per pixel side.
    blur_sigma_px : float
        Gaussian optical blur (px), applied after integration.
    noise_std : float
        Std of additive Gaussian noise (grey levels).
    background : float
        Grey level where the board is not seen.
    contrast : (float, float)
        Grey levels of the dark and the light print.
    rng : numpy.random.Generator, optional
        Source of the noise (required when ``noise_std > 0``).

    Returns
    -------
    ndarray of uint8, shape (height, width)
    """
    Km = np.asarray(K, dtype=float).reshape(3, 3)
    T = np.asarray(T_camera_board, dtype=float).reshape(4, 4)
    w, h = int(image_size[0]), int(image_size[1])
    f = int(supersample)
    if f < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample!r}")
    if noise_std > 0 and rng is None:
        raise ValueError("noise_std > 0 needs rng (a numpy.random.Generator)")
    sub = (np.arange(f) + 0.5) / f - 0.5
    # sub-pixel ray grid laid out as an (h * f, w * f) image: axes (v, sub_v, u, sub_u)
    us = np.arange(w)[None, None, :, None] + sub[None, None, None, :]
    vs = np.arange(h)[:, None, None, None] + sub[None, :, None, None]
    us, vs = np.broadcast_arrays(us, vs)
    pu = np.ascontiguousarray(us, dtype=np.float64).reshape(h * f, w * f)
    pv = np.ascontiguousarray(vs, dtype=np.float64).reshape(h * f, w * f)
    if dist is not None and np.any(np.asarray(dist, dtype=float) != 0):
        # undistort a lattice of pixel corners exactly, interpolate inside the pixels
        gu, gv = np.meshgrid(np.arange(w + 1) - 0.5, np.arange(h + 1) - 0.5)
        lat = cv2.undistortPoints(
            np.column_stack([gu.ravel(), gv.ravel()]).reshape(-1, 1, 2),
            Km,
            np.asarray(dist, dtype=float),
            P=Km,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10),
        ).reshape(h + 1, w + 1, 2)
        und = cv2.remap(
            lat.astype(np.float32),
            (pu + 0.5).astype(np.float32),
            (pv + 0.5).astype(np.float32),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
        pu = und[..., 0].astype(np.float64)
        pv = und[..., 1].astype(np.float64)
    Hi = np.linalg.inv(Km @ np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]]))
    wz = Hi[2, 0] * pu + Hi[2, 1] * pv + Hi[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xb = (Hi[0, 0] * pu + Hi[0, 1] * pv + Hi[0, 2]) / wz
        yb = (Hi[1, 0] * pu + Hi[1, 1] * pv + Hi[1, 2]) / wz
    # keep rays that meet the board in front of the camera
    front = (T[2, 0] * xb + T[2, 1] * yb + T[2, 3]) > 0
    tex = _texture_unit(int(board.cells), int(px_per_cell), float(board.dot_radius))
    scale = px_per_cell / board.cell_size
    mx = (xb * scale - 0.5).astype(np.float32)
    my = (yb * scale - 0.5).astype(np.float32)
    bad = ~(front & np.isfinite(mx) & np.isfinite(my))
    mx[bad] = -1e6
    my[bad] = -1e6
    lo, hi = contrast
    vals = cv2.remap(
        tex,
        mx,
        my,
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=float((background - lo) / (hi - lo)) if hi != lo else 0.0,
    )
    img = lo + (hi - lo) * vals.reshape(h, f, w, f).mean(axis=(1, 3))
    if blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma_px)
    if noise_std > 0 and rng is not None:
        img = img + rng.normal(0.0, noise_std, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)
