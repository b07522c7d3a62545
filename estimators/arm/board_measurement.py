"""Camera pose from a partial view of the coded board.

Pipeline of :func:`measure_board` (pure OpenCV/numpy):

1. **Corners and grid** — saddle-point X-corners that pass a ring test, refined
   to sub-pixel and given integer lattice coordinates (:mod:`.board_detection`).
2. **Layout refinement (RANSAC)** — a homography from the integer grid to the
   undistorted corners (the printed layout is exact), fitted with RANSAC;
   outliers go, missing corners are searched at their predicted positions and
   the homography is refitted.
3. **Decoding** — every cell whose four corners were found is sampled at its
   centre and around it; the code bit is "centre has the opposite colour". The
   observed bit array is matched in all four rotations and all shifts against
   the board; the match must be nearly exact and clearly better than the
   runner-up, and the dark/light parity must agree. Otherwise the frame is
   rejected (``ok=False``), never mislabelled.
4. **Pose** — the cell under the optical axis (the principal point) is the
   *centre cell*; ``cv2.solvePnP`` (IPPE, then Levenberg–Marquardt) gives the
   camera pose with respect to that cell's corner frame from the local corner
   array, :math:`s\\,\\tilde p_k = K [R\\,|\\,t] P_k`.

The hierarchical displacement between two measured frames is in
:mod:`.board_displacement`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import cv2
import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import transform_from_rt, transform_inverse

from .board_detection import (
    detect_corners,
    grow_grid,
    refine_by_scale,
    ring_test,
    sample_bilinear,
    to_gray,
)
from .board_displacement import cell_under_optical_axis
from .coded_board import WINDOW, CodedBoard

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "BoardMeasurementSettings",
    "BoardObservation",
    "MeasurementStatus",
    "measure_board",
]


class MeasurementStatus(str, Enum):
    """Outcome of :func:`measure_board`."""

    OK = "ok"
    TOO_FEW_CORNERS = "too_few_corners"  #: fewer corners than needed anywhere in the chain
    NO_GRID = "no_grid"  #: the corners do not form a checkerboard lattice
    LOW_CONTRAST = "low_contrast"  #: dark and light cells are not told apart
    CODE_WINDOW_INCOMPLETE = "code_window_incomplete"  #: fewer than 8×8 readable cells
    CODE_NOT_FOUND = "code_not_found"  #: the bits match no place on the board well enough
    CODE_AMBIGUOUS = "code_ambiguous"  #: two places match about equally well
    PARITY_MISMATCH = "parity_mismatch"  #: decoded place contradicts the cell colours
    OPTICAL_AXIS_OFF_BOARD = "optical_axis_off_board"  #: no centre cell
    PNP_FAILED = "pnp_failed"  #: pose not found or reprojection error too large


@dataclass(frozen=True)
class BoardMeasurementSettings:
    """Settings of :func:`measure_board`.

    Attributes
    ----------
    min_corners : int
        Fewest inlier corners for a pose.
    smoothing_sigma_px : float
        Gaussian scale of the saddle detector (px).
    ransac_threshold_px : float
        Inlier threshold of the layout homography and of the PnP reprojection (px).
    subpix_window_fraction : float
        Half-window of ``cornerSubPix`` as a fraction of the local corner spacing;
        must stay below about 0.35 for the window to avoid the code dots.
    max_code_errors : int
        Most misread bits tolerated in the accepted placement.
    max_code_error_fraction : float
        ... or this fraction of the read bits, whichever is larger.
    min_code_margin : int
        The runner-up placement must disagree with at least this many more bits.
    min_bit_confidence : float
        Bits whose centre is not clearly closer to one colour (fraction of the
        dark/light contrast) are not used.
    pnp_window_cells : int or None
        Use only corners within this many cells of the centre cell for PnP
        (``None``: every inlier corner).
    max_reprojection_rms_px : float
        Reject the frame when the PnP reprojection RMS exceeds this.
    """

    min_corners: int = 20
    smoothing_sigma_px: float = 1.5
    ransac_threshold_px: float = 1.0
    subpix_window_fraction: float = 0.25
    max_code_errors: int = 2
    max_code_error_fraction: float = 0.03
    min_code_margin: int = 6
    min_bit_confidence: float = 0.25
    pnp_window_cells: int | None = None
    max_reprojection_rms_px: float = 1.0

    def __post_init__(self) -> None:
        if self.min_corners < 6:
            raise ValueError(f"min_corners must be >= 6 (PnP needs them), got {self.min_corners}")
        for nm in (
            "smoothing_sigma_px",
            "ransac_threshold_px",
            "max_reprojection_rms_px",
        ):
            v = getattr(self, nm)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{nm} must be positive, got {v!r}")
        if not 0.05 <= self.subpix_window_fraction <= 0.35:
            raise ValueError(
                "subpix_window_fraction must be in [0.05, 0.35] so that the cornerSubPix "
                f"window stays clear of the code dots, got {self.subpix_window_fraction!r}"
            )
        if self.max_code_errors < 0 or self.min_code_margin < 1:
            raise ValueError("max_code_errors must be >= 0 and min_code_margin >= 1")
        if self.pnp_window_cells is not None and self.pnp_window_cells < 1:
            raise ValueError(f"pnp_window_cells must be >= 1 or None, got {self.pnp_window_cells}")


def _nan_pose() -> FloatArray:
    return np.full((4, 4), np.nan)


@dataclass(frozen=True)
class BoardObservation:
    """One camera frame measured against the coded board.

    Attributes
    ----------
    ok : bool
        Whether a pose was measured; when False every array is NaN and
        ``cell_index`` is None.
    status : MeasurementStatus
        Why not, or ``OK``.
    cell_index : (int, int) or None
        ``(row, col)`` of the centre cell, the cell under the optical axis.
    T_camera_board : ndarray, shape (4, 4)
        Board pose in the camera frame (m).
    n_corners : int
        Corners used for the pose (or found, when it failed).
    reprojection_rms_px : float
        RMS reprojection error of the PnP solution (px).
    T_camera_cell : ndarray, shape (4, 4)
        Pose of the centre-cell frame (board axes, origin at the cell's corner
        ``(row, col)``) in the camera frame (m).
    code_mismatches : int
        Observed code bits that disagree with the board at the decoded place
        (-1 when not decoded).
    n_code_bits : int
        Code bits read.
    image_points : ndarray, shape (k, 2)
        Pixel positions of the corners used for the pose.
    corner_ids : ndarray of int, shape (k, 2)
        Their board corner indices ``(row, col)``.
    """

    ok: bool
    status: MeasurementStatus
    cell_index: tuple[int, int] | None
    T_camera_board: FloatArray
    n_corners: int
    reprojection_rms_px: float
    T_camera_cell: FloatArray = field(default_factory=_nan_pose)
    code_mismatches: int = -1
    n_code_bits: int = 0
    image_points: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    corner_ids: npt.NDArray[np.int64] = field(
        default_factory=lambda: np.zeros((0, 2), dtype=np.int64)
    )

    @property
    def T_board_camera(self) -> FloatArray:
        """Camera pose in the board frame, shape (4, 4)."""
        return _invert(self.T_camera_board)

    @property
    def camera_position_board(self) -> FloatArray:
        """Optical centre in the board frame (m), shape (3,)."""
        return self.T_board_camera[:3, 3].copy()

    @property
    def camera_position_cell(self) -> FloatArray:
        """Optical centre in the centre-cell frame (m), shape (3,)."""
        return _invert(self.T_camera_cell)[:3, 3].copy()


def _fail(
    status: MeasurementStatus, n: int = 0, mism: int = -1, nbits: int = 0
) -> BoardObservation:
    return BoardObservation(
        ok=False,
        status=status,
        cell_index=None,
        T_camera_board=_nan_pose(),
        n_corners=n,
        reprojection_rms_px=float("nan"),
        code_mismatches=mism,
        n_code_bits=nbits,
    )


def _invert(T: FloatArray) -> FloatArray:
    """:func:`~realitygap.core.geometry.transform_inverse`, all NaN when ``T`` is not finite."""
    out = transform_inverse(T)
    if not np.all(np.isfinite(T)):
        out[:] = np.nan
    return out


# =========================================================================== camera helpers
def _undistort(px: FloatArray, K: FloatArray, dist: FloatArray | None) -> FloatArray:
    if len(px) == 0 or dist is None:
        return px.copy()
    out = cv2.undistortPoints(
        px.reshape(-1, 1, 2).astype(np.float64),
        K,
        dist,
        P=K,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10),
    )
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def _distort(px_undist: FloatArray, K: FloatArray, dist: FloatArray | None) -> FloatArray:
    if len(px_undist) == 0 or dist is None:
        return px_undist.copy()
    xn = np.column_stack([px_undist, np.ones(len(px_undist))]) @ np.linalg.inv(K).T
    out, _ = cv2.projectPoints(xn.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def _apply_h(H: FloatArray, xy: FloatArray) -> FloatArray:
    h = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    return h[:, :2] / h[:, 2:3]


def _check_camera(
    K: npt.ArrayLike, dist: npt.ArrayLike | None
) -> tuple[FloatArray, FloatArray | None]:
    Km = np.asarray(K, dtype=float)
    if Km.shape != (3, 3) or not np.all(np.isfinite(Km)) or Km[0, 0] <= 0 or Km[1, 1] <= 0:
        raise ValueError(f"K must be a finite 3x3 camera matrix with fx, fy > 0, got {Km!r}")
    if dist is None:
        return Km, None
    d = np.asarray(dist, dtype=float).reshape(-1)
    if d.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(d)):
        raise ValueError(
            f"dist must hold 4, 5, 8, 12 or 14 finite OpenCV coefficients, got {d.size}"
        )
    return Km, (None if not np.any(d) else d)


# =========================================================================== main entry
def measure_board(
    image: npt.ArrayLike,
    K: npt.ArrayLike,
    dist: npt.ArrayLike | None,
    board: CodedBoard,
    settings: BoardMeasurementSettings | None = None,
) -> BoardObservation:
    """Measure the camera pose from one image of part of a coded board.

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, 3)
        Grey or RGB image (any numeric dtype, grey levels about 0..255).
    K : array_like, shape (3, 3)
        Camera matrix (px).
    dist : array_like or None
        OpenCV distortion coefficients of the camera.
    board : CodedBoard
        The board being looked at.
    settings : BoardMeasurementSettings, optional

    Returns
    -------
    BoardObservation
        ``ok=False`` with a :class:`MeasurementStatus` when the frame cannot be
        measured unambiguously.
    """
    s = settings or BoardMeasurementSettings()
    Km, d = _check_camera(K, dist)
    gray = to_gray(image)
    h_img, w_img = gray.shape

    corners, _, contrast = detect_corners(gray, s.smoothing_sigma_px, s.subpix_window_fraction)
    if contrast < 10.0:
        return _fail(MeasurementStatus.LOW_CONTRAST)
    if len(corners) < s.min_corners:
        return _fail(MeasurementStatus.TOO_FEW_CORNERS, len(corners))
    und = _undistort(corners, Km, d)
    coords = grow_grid(und, np.array([Km[0, 2], Km[1, 2]]))
    if coords is None or len(coords) < s.min_corners:
        return _fail(MeasurementStatus.NO_GRID, len(corners))
    keys = np.array(list(coords.keys()), dtype=float)  # (i, j)
    idx = np.array(list(coords.values()))
    src = keys[:, ::-1].copy()  # (x = j, y = i)
    H, mask = cv2.findHomography(src, und[idx], cv2.RANSAC, s.ransac_threshold_px)
    if H is None:
        return _fail(MeasurementStatus.NO_GRID, len(corners))
    inl = mask.ravel().astype(bool)
    grid: dict[tuple[int, int], FloatArray] = {
        (int(k[0]), int(k[1])): corners[i] for k, i, m in zip(keys, idx, inl) if m
    }

    # ---- layout refinement: look for every corner the layout predicts in view
    n_side = board.cells + 1
    for _ in range(2):
        ii = np.array([k[0] for k in grid])
        jj = np.array([k[1] for k in grid])
        I, J = np.meshgrid(
            np.arange(ii.max() - n_side + 1, ii.min() + n_side),
            np.arange(jj.max() - n_side + 1, jj.min() + n_side),
            indexing="ij",
        )
        ck = np.column_stack([I.ravel(), J.ravel()])
        ck = ck[[(int(a_), int(b_)) not in grid for a_, b_ in ck]]
        if len(ck) == 0:
            break
        xy = ck[:, ::-1].astype(float)
        pred_u = _apply_h(H, xy)
        step = np.minimum(
            np.linalg.norm(_apply_h(H, xy + np.array([1.0, 0.0])) - pred_u, axis=1),
            np.linalg.norm(_apply_h(H, xy + np.array([0.0, 1.0])) - pred_u, axis=1),
        )
        den = np.column_stack([xy, np.ones(len(xy))]) @ H[2]
        ok_u = (den > 0) & np.isfinite(step) & (step > 5.0)
        if d is not None:
            # stay where the distortion model is trustworthy
            ok_u &= np.linalg.norm(pred_u - Km[:2, 2], axis=1) < 1.2 * np.hypot(w_img, h_img) / 2
        ck, pred_u, step = ck[ok_u], pred_u[ok_u], step[ok_u]
        pred = _distort(pred_u, Km, d)
        margin = 0.5 * step + 2
        inside = (
            (pred[:, 0] > margin)
            & (pred[:, 1] > margin)
            & (pred[:, 0] < w_img - 1 - margin)
            & (pred[:, 1] < h_img - 1 - margin)
        )
        if not np.any(inside):
            break
        sp_in = step[inside]
        ref = refine_by_scale(gray, pred[inside], sp_in, s.subpix_window_fraction)
        ring_ok = ring_test(gray, ref, np.clip(0.28 * sp_in, 2.5, 15.0), contrast)
        ref_u = _undistort(ref, Km, d)
        close = np.linalg.norm(ref_u - pred_u[inside], axis=1) < 3 * s.ransac_threshold_px
        for key, p, good in zip(ck[inside], ref, ring_ok & close):
            if good:
                grid[(int(key[0]), int(key[1]))] = p
        gk = np.array(list(grid.keys()), dtype=float)
        gpu = _undistort(np.array(list(grid.values())), Km, d)
        H_new, _m = cv2.findHomography(gk[:, ::-1], gpu, 0)
        if H_new is None:
            return _fail(MeasurementStatus.NO_GRID, len(grid))
        H = np.asarray(H_new, dtype=np.float64)
        res = np.linalg.norm(_apply_h(H, gk[:, ::-1]) - gpu, axis=1)
        grid = {
            (int(k[0]), int(k[1])): p
            for k, p, r in zip(gk, grid.values(), res)
            if r < s.ransac_threshold_px
        }
    gk = np.array(list(grid.keys()), dtype=float)
    gp = np.array(list(grid.values()))
    gpu = _undistort(gp, Km, d)
    for _ in range(2):
        H_fit, _m = cv2.findHomography(gk[:, ::-1], gpu, 0)
        if H_fit is None:
            return _fail(MeasurementStatus.NO_GRID, len(grid))
        H = np.asarray(H_fit, dtype=np.float64)
        res = np.linalg.norm(_apply_h(H, gk[:, ::-1]) - gpu, axis=1)
        keep = res < s.ransac_threshold_px
        gk, gp, gpu = gk[keep], gp[keep], gpu[keep]
        if len(gk) < s.min_corners:
            return _fail(MeasurementStatus.TOO_FEW_CORNERS, len(gk))
    grid = {(int(k[0]), int(k[1])): p for k, p in zip(gk, gp)}

    # ---- read the code bits of every cell with four corners
    cells = [
        (i, j)
        for (i, j) in grid
        if (i + 1, j) in grid and (i, j + 1) in grid and (i + 1, j + 1) in grid
    ]
    if not cells:
        return _fail(MeasurementStatus.CODE_WINDOW_INCOMPLETE, len(grid))
    ca = np.array(cells)
    i0, j0 = ca.min(axis=0)
    hh, ww = ca.max(axis=0) - ca.min(axis=0) + 1
    centre_off = np.array([[0.0, 0.0], [0.07, 0.0], [-0.07, 0.0], [0.0, 0.07], [0.0, -0.07]])
    rr = 0.33
    dd = 0.27
    bg_off = np.array(
        [[rr, 0], [-rr, 0], [0, rr], [0, -rr], [dd, dd], [dd, -dd], [-dd, dd], [-dd, -dd]]
    )
    cxy = ca[:, ::-1] + 0.5  # (x = j + .5, y = i + .5)
    c_pts = (cxy[:, None, :] + centre_off[None]).reshape(-1, 2)
    b_pts = (cxy[:, None, :] + bg_off[None]).reshape(-1, 2)
    c_val = sample_bilinear(gray, _distort(_apply_h(H, c_pts), Km, d)).reshape(len(ca), -1)
    b_val = sample_bilinear(gray, _distort(_apply_h(H, b_pts), Km, d)).reshape(len(ca), -1)
    centre_v = np.nanmean(c_val, axis=1)
    back_v = np.nanmedian(b_val, axis=1)
    parity = (ca[:, 0] + ca[:, 1]) % 2
    if np.sum(parity == 0) == 0 or np.sum(parity == 1) == 0:
        return _fail(MeasurementStatus.CODE_WINDOW_INCOMPLETE, len(grid))
    lev = np.array([np.nanmedian(back_v[parity == 0]), np.nanmedian(back_v[parity == 1])])
    C = float(abs(lev[1] - lev[0]))
    if not np.isfinite(C) or C < 0.3 * contrast:
        return _fail(MeasurementStatus.LOW_CONTRAST, len(grid))
    dark_parity = int(np.argmin(lev))
    own = lev[parity]
    other = lev[1 - parity]
    # local estimate of the opposite colour from the four neighbours
    back_map = {c: v for c, v in zip(cells, back_v)}
    for n_, (i, j) in enumerate(cells):
        nb = [
            back_map[k] for k in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1)) if k in back_map
        ]
        nb = [v for v in nb if np.isfinite(v)]
        if nb:
            other[n_] = float(np.median(nb))
    colour_ok = np.abs(back_v - own) < 0.35 * C
    margin_bits = (np.abs(centre_v - back_v) - np.abs(centre_v - other)) / C
    bit = margin_bits > 0
    valid = colour_ok & np.isfinite(margin_bits) & (np.abs(margin_bits) > s.min_bit_confidence)
    bits = np.zeros((hh, ww), dtype=np.uint8)
    vmask = np.zeros((hh, ww), dtype=bool)
    bits[ca[:, 0] - i0, ca[:, 1] - j0] = bit
    vmask[ca[:, 0] - i0, ca[:, 1] - j0] = valid
    nbits = int(vmask.sum())
    if min(hh, ww) < WINDOW or nbits < WINDOW * WINDOW:
        return _fail(MeasurementStatus.CODE_WINDOW_INCOMPLETE, len(grid), nbits=nbits)
    if max(hh, ww) > board.cells or min(hh, ww) > board.cells:
        return _fail(MeasurementStatus.NO_GRID, len(grid), nbits=nbits)
    (r0, c0, k, mism), second = board.match_bits(bits, vmask)
    allowed = max(s.max_code_errors, int(s.max_code_error_fraction * nbits))
    if mism > allowed:
        return _fail(MeasurementStatus.CODE_NOT_FOUND, len(grid), mism, nbits)
    if second - mism < s.min_code_margin:
        return _fail(MeasurementStatus.CODE_AMBIGUOUS, len(grid), mism, nbits)

    # observed cell (i, j) -> board cell via the same rotation
    I, J = np.meshgrid(np.arange(hh) + i0, np.arange(ww) + j0, indexing="ij")
    Ir, Jr = np.rot90(I, k), np.rot90(J, k)
    # three non-collinear cell centres fix the (integer) affine map exactly:
    # [R, C] + 0.5 = [i + 0.5, j + 0.5, 1] @ M
    pick = [(0, 0), (1, 0), (0, 1)]
    obs3 = np.array([[Ir[a, b] + 0.5, Jr[a, b] + 0.5, 1.0] for a, b in pick])
    brd3 = np.array([[a + r0 + 0.5, b + c0 + 0.5] for a, b in pick])
    M = np.round(np.linalg.solve(obs3, brd3))
    # colour parity check: dark observed cells must land on dark board cells
    i_c, j_c = cells[0]
    rc = np.floor(np.array([i_c + 0.5, j_c + 0.5, 1.0]) @ M).astype(int)
    obs_dark = (i_c + j_c) % 2 == dark_parity
    if bool(board.cell_is_dark(rc[0], rc[1])) != obs_dark:
        return _fail(MeasurementStatus.PARITY_MISMATCH, len(grid), mism, nbits)

    # ---- board ids of the corners and the centre cell
    ids = np.round(np.column_stack([gk, np.ones(len(gk))]) @ M).astype(np.int64)  # (R, C)
    on_board = np.all((ids >= 0) & (ids <= board.cells), axis=1)
    ids, gp = ids[on_board], gp[on_board]
    pc = np.array([[Km[0, 2], Km[1, 2]]])
    gxy = _apply_h(np.linalg.inv(H), pc)[0]  # (x = j, y = i) continuous
    centre_rc = np.array([gxy[1], gxy[0], 1.0]) @ M
    cell = np.floor(centre_rc).astype(int)
    if not (0 <= cell[0] < board.cells and 0 <= cell[1] < board.cells):
        return _fail(MeasurementStatus.OPTICAL_AXIS_OFF_BOARD, len(ids), mism, nbits)

    # ---- PnP in the centre-cell frame
    cs = board.cell_size

    def solve(
        cell_rc: npt.NDArray[np.int_],
    ) -> tuple[FloatArray, float, npt.NDArray[np.bool_]] | None:
        use = np.ones(len(ids), dtype=bool)
        if s.pnp_window_cells is not None:
            w = s.pnp_window_cells
            use = np.all(np.abs(ids - cell_rc[None] - 0.5) <= w + 0.5, axis=1)
        if use.sum() < s.min_corners:
            return None
        obj = np.column_stack(
            [(ids[use, 1] - cell_rc[1]) * cs, (ids[use, 0] - cell_rc[0]) * cs, np.zeros(use.sum())]
        )
        img = gp[use].reshape(-1, 1, 2).astype(np.float64)
        dist_arg = np.zeros(5) if d is None else d
        okp, rvec, tvec = cv2.solvePnP(obj, img, Km, dist_arg, flags=cv2.SOLVEPNP_IPPE)
        if not okp:
            return None
        keep = np.ones(len(obj), dtype=bool)
        for _ in range(2):
            rvec, tvec = cv2.solvePnPRefineLM(
                obj[keep],
                img[keep],
                Km,
                dist_arg,
                rvec,
                tvec,
                criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-12),
            )
            proj, _ = cv2.projectPoints(obj, rvec, tvec, Km, dist_arg)
            err = np.linalg.norm(proj.reshape(-1, 2) - img.reshape(-1, 2), axis=1)
            new_keep = err < s.ransac_threshold_px
            if new_keep.sum() < s.min_corners:
                return None
            if np.array_equal(new_keep, keep):
                break
            keep = new_keep
        T = transform_from_rt(cv2.Rodrigues(rvec)[0], np.asarray(tvec).reshape(3))
        rms = float(np.sqrt(np.mean(err[keep] ** 2)))
        full = np.zeros(len(ids), dtype=bool)
        full[np.nonzero(use)[0][keep]] = True
        return T, rms, full

    sol = solve(cell)
    if sol is None:
        return _fail(MeasurementStatus.PNP_FAILED, len(ids), mism, nbits)
    T_cam_cell, rms, used = sol
    T_cell_board = np.eye(4)
    T_cell_board[:3, 3] = [-cell[1] * cs, -cell[0] * cs, 0.0]
    T_cam_board = T_cam_cell @ T_cell_board
    # the centre cell from the pose itself (differs from the homography only at a cell edge)
    pose_cell = cell_under_optical_axis(_invert(T_cam_board), cs)
    if pose_cell is None or not (
        0 <= pose_cell[0] < board.cells and 0 <= pose_cell[1] < board.cells
    ):
        return _fail(MeasurementStatus.OPTICAL_AXIS_OFF_BOARD, len(ids), mism, nbits)
    if pose_cell != (int(cell[0]), int(cell[1])):
        cell = np.array(pose_cell)
        T_cell_board[:3, 3] = [-cell[1] * cs, -cell[0] * cs, 0.0]
        T_cam_cell = T_cam_board @ _invert(T_cell_board)
    if rms > s.max_reprojection_rms_px:
        return _fail(MeasurementStatus.PNP_FAILED, int(used.sum()), mism, nbits)
    return BoardObservation(
        ok=True,
        status=MeasurementStatus.OK,
        cell_index=(int(cell[0]), int(cell[1])),
        T_camera_board=T_cam_board,
        n_corners=int(used.sum()),
        reprojection_rms_px=rms,
        T_camera_cell=T_cam_cell,
        code_mismatches=int(mism),
        n_code_bits=nbits,
        image_points=gp[used].copy(),
        corner_ids=ids[used].copy(),
    )
