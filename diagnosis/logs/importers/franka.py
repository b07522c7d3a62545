"""Reader for eye-in-hand arm-calibration data stored as ``.npz`` (Franka FR3 layout).

Expected arrays (``np.load(..., allow_pickle=False)``):

``joint_positions``
    (N, n) joint readings (rad).
``tcp_poses``
    (N, 4, 4) robot-reported :math:`T_{\\mathrm{base},\\mathrm{tcp}}` (m).
``camera_poses``
    (N, 4, 4) camera pose relative to the board, :math:`T_{\\mathrm{board},\\mathrm{camera}}`
    (m): the optical centre is ``camera_poses[:, :3, 3]`` in the board frame. (A
    hand–eye fit confirms the direction: with this reading
    :math:`T_{\\mathrm{base},\\mathrm{flange}} X T_{\\mathrm{board},\\mathrm{camera}}^{-1}`
    is constant.)
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.logs.importers.archive import ArchiveError, read_log_archive
from realitygap.diagnosis.logs.schema import SchemaError, check_values, dtype_problem

FloatArray = npt.NDArray[np.float64]

__all__ = ["REQUIRED_KEYS", "FrankaEyeInHandData", "read_franka_npz"]

#: Arrays a file must contain.
REQUIRED_KEYS: tuple[str, ...] = ("joint_positions", "tcp_poses", "camera_poses")


@dataclass(frozen=True)
class FrankaEyeInHandData:
    """Eye-in-hand calibration poses.

    Attributes
    ----------
    source : str
        File path.
    joint_positions : ndarray, shape (N, n)
        Joint readings (rad).
    T_base_tcp : ndarray, shape (N, 4, 4)
        Robot-reported TCP poses in the base frame (m).
    T_board_camera : ndarray, shape (N, 4, 4)
        Measured camera poses in the board frame (m).
    """

    source: str
    joint_positions: FloatArray
    T_base_tcp: FloatArray
    T_board_camera: FloatArray

    @property
    def n(self) -> int:
        """Number of poses."""
        return int(self.joint_positions.shape[0])

    @property
    def camera_positions(self) -> FloatArray:
        """Optical centres in the board frame (N, 3) (m)."""
        return self.T_board_camera[:, :3, 3].copy()


def _check_transforms(name: str, T: FloatArray, n: int, path: Path) -> None:
    if T.shape != (n, 4, 4):
        raise ValueError(f"{path.name}: {name!r} must have shape ({n}, 4, 4), got {T.shape}")
    if not np.allclose(T[:, 3, :], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        k = int(np.nonzero(~np.all(np.isclose(T[:, 3, :], [0, 0, 0, 1], atol=1e-9), axis=1))[0][0])
        raise ValueError(f"{path.name}: {name}[{k}] last row must be [0, 0, 0, 1]")
    R = T[:, :3, :3]
    err = np.abs(R @ np.transpose(R, (0, 2, 1)) - np.eye(3)).max(axis=(1, 2))
    bad = np.nonzero((err > 1e-4) | (np.linalg.det(R) < 0))[0]
    if bad.size:
        raise ValueError(
            f"{path.name}: {name}[{int(bad[0])}] rotation block is not a rotation matrix "
            f"(orthonormality error {err[bad[0]]:.2e})"
        )


def _check_reach(T_base_tcp: FloatArray, path: Path) -> None:
    """Refuse TCP positions beyond twice the FR3's reach (its MDH table's link lengths): a
    translation in mm stored as m."""
    from realitygap.estimators.arm.mdh import MDHTable

    table = MDHTable.franka_fr3()
    reach = float(np.hypot(table.a, table.d).sum())
    dist = np.linalg.norm(T_base_tcp[:, :3, 3], axis=1)
    far = np.flatnonzero(dist > 2.0 * reach)
    if far.size:
        k = int(far[0])
        raise ValueError(
            f"{path.name}: tcp_poses[{k}] puts the TCP {dist[k]:.4g} m from the base, beyond the "
            f"FR3's reach ({reach:.3g} m; {far.size} such pose(s)): the translations look like "
            "millimetres, expected metres. Fix: divide the translations by 1000 before saving"
        )


def read_franka_npz(path: str | Path) -> FrankaEyeInHandData:
    """Read and check an eye-in-hand ``.npz`` file.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it is not a readable ``.npz`` without pickled objects, misses an array
        (close names are suggested), or shapes, finiteness or rigid-transform
        structure are wrong.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p} does not exist")
    with p.open("rb") as fh:
        if fh.read(4) != b"PK\x03\x04":
            raise ValueError(f"{p.name}: not a readable .npz archive (no zip signature)")
    try:
        z = read_log_archive(p)
    except ArchiveError as exc:
        if "pickled" in str(exc):
            raise ValueError(f"{p.name}: contains pickled objects, which are refused") from None
        raise ValueError(f"{p.name}: not a readable .npz archive ({exc})") from None
    keys = list(z)
    missing = [k for k in REQUIRED_KEYS if k not in keys]
    if missing:
        hints = {k: difflib.get_close_matches(k, keys, n=1) for k in missing}
        raise ValueError(
            f"{p.name}: missing array(s) {missing}; found {keys}"
            + "".join(f"; for {k!r} did you mean {h[0]!r}?" for k, h in hints.items() if h)
        )
    arrays = {k: z[k] for k in REQUIRED_KEYS}
    out: dict[str, FloatArray] = {}
    for k, a in arrays.items():
        problem = dtype_problem(a.dtype, "joints")
        if problem is not None:
            raise ValueError(f"{p.name}: {k!r}: {problem}")
        a = a.astype(float)
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{p.name}: {k!r} contains non-finite values")
        out[k] = a
    q = out["joint_positions"]
    if q.ndim != 2 or q.shape[0] == 0 or q.shape[1] < 1:
        raise ValueError(f"{p.name}: 'joint_positions' must have shape (N, n), got {q.shape}")
    n = q.shape[0]
    try:
        check_values("joints", q, f"{p.name}: 'joint_positions'")
    except SchemaError as exc:
        raise ValueError(str(exc)) from None
    _check_transforms("tcp_poses", out["tcp_poses"], n, p)
    _check_transforms("camera_poses", out["camera_poses"], n, p)
    _check_reach(out["tcp_poses"], p)
    return FrankaEyeInHandData(
        source=str(p),
        joint_positions=q,
        T_base_tcp=out["tcp_poses"],
        T_board_camera=out["camera_poses"],
    )
