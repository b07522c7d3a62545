"""Hierarchical displacement of the camera between two board measurements.

Between two frames ``i`` and ``j``:

.. math::

    \\delta' = t + t', \\qquad
    t = s_{\\mathrm{cell}} \\begin{bmatrix} c_j - c_i \\\\ r_j - r_i \\\\ 0 \\end{bmatrix},
    \\qquad t' = {}^{\\mathrm{cell}_j}p_j - {}^{\\mathrm{cell}_i}p_i,

with :math:`(r, c)` the centre cell decoded from the code and :math:`{}^{\\mathrm{cell}}p`
the optical centre in its centre-cell frame from PnP
(:func:`~.board_measurement.measure_board`): the large part comes from the
printed layout, only the in-cell part from the image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from .board_measurement import BoardObservation

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "HierarchicalDisplacement",
    "cell_under_optical_axis",
    "hierarchical_displacement",
    "transition_pose",
]


def cell_under_optical_axis(
    T_board_camera: npt.ArrayLike, cell_size: float
) -> tuple[int, int] | None:
    """Cell ``(row, col)`` hit by the optical axis; ``None`` if the axis misses the plane.

    Parameters
    ----------
    T_board_camera : array_like, shape (4, 4)
        Camera pose in the board frame (m).
    cell_size : float
        Cell side (m).
    """
    T = np.asarray(T_board_camera, dtype=float)
    c = T[:3, 3]
    z = T[:3, 2]
    if abs(z[2]) < 1e-12:
        return None
    lam = -c[2] / z[2]
    if lam <= 0:
        return None
    p = c + lam * z
    return int(np.floor(p[1] / cell_size)), int(np.floor(p[0] / cell_size))


@dataclass(frozen=True)
class HierarchicalDisplacement:
    """Displacement of the optical centre between two frames, in the board frame (m).

    Attributes
    ----------
    t : ndarray, shape (3,)
        Coarse part: change of the centre cell times the cell size (exact, from the code).
    t_prime : ndarray, shape (3,)
        Fine part: change of the optical centre within its centre-cell frame (PnP).
    delta : ndarray, shape (3,)
        :math:`\\delta' = t + t'`.
    cell_shift : (int, int)
        Change of the centre cell ``(rows, cols)``.
    """

    t: FloatArray
    t_prime: FloatArray
    delta: FloatArray
    cell_shift: tuple[int, int]


def hierarchical_displacement(
    obs_from: BoardObservation, obs_to: BoardObservation, cell_size: float
) -> HierarchicalDisplacement:
    """Hierarchical displacement :math:`\\delta' = t + t'` between two measured frames.

    Parameters
    ----------
    obs_from, obs_to : BoardObservation
        Successful measurements (``ok``).
    cell_size : float
        Cell side of the board (m).

    Returns
    -------
    HierarchicalDisplacement
    """
    for name, o in (("obs_from", obs_from), ("obs_to", obs_to)):
        if not o.ok or o.cell_index is None:
            raise ValueError(f"{name} is not a successful measurement (status {o.status.value!r})")
    assert obs_from.cell_index is not None and obs_to.cell_index is not None
    dr = obs_to.cell_index[0] - obs_from.cell_index[0]
    dc = obs_to.cell_index[1] - obs_from.cell_index[1]
    t = np.array([dc * cell_size, dr * cell_size, 0.0])
    tp = obs_to.camera_position_cell - obs_from.camera_position_cell
    return HierarchicalDisplacement(t, tp, t + tp, (int(dr), int(dc)))


def transition_pose(
    T_board_camera_from: npt.ArrayLike, T_board_camera_to: npt.ArrayLike, cell_size: float
) -> tuple[FloatArray, tuple[int, int]]:
    """Transition pose between two camera poses that share no centre cell.

    The transition pose has the orientation of the target pose and is shifted
    from it by whole cells so that its optical axis meets the board in the start
    pose's centre cell, at the same place within the cell as the target's axis
    meets its own. Moving start → transition is then measured inside one cell's
    corner array (:math:`t'`), transition → target is a pure translation by whole
    cells (:math:`t`, exact by the printed layout).

    Parameters
    ----------
    T_board_camera_from, T_board_camera_to : array_like, shape (4, 4)
        Start and target camera poses in the board frame (m).
    cell_size : float
        Cell side (m).

    Returns
    -------
    T_board_camera_transition : ndarray, shape (4, 4)
    cell_shift : (int, int)
        ``(rows, cols)`` from the transition to the target centre cell.
    """
    A = np.asarray(T_board_camera_from, dtype=float)
    B = np.asarray(T_board_camera_to, dtype=float)
    ca = cell_under_optical_axis(A, cell_size)
    cb = cell_under_optical_axis(B, cell_size)
    if ca is None or cb is None:
        raise ValueError("the optical axis of a pose does not meet the board plane")
    dr, dc = cb[0] - ca[0], cb[1] - ca[1]
    T = B.copy()
    T[:3, 3] = B[:3, 3] - np.array([dc * cell_size, dr * cell_size, 0.0])
    return T, (int(dr), int(dc))
