"""Rigid alignment of point sets and the small least-squares linear algebra of the
kinematic identification.

:func:`kabsch` and :func:`wahba` fit a rotation (and translation) between
corresponding vectors; :func:`thin_qr`, :func:`lstsq_min_norm` and
:func:`singular_values` work on tall Jacobians through a Gram–Schmidt QR that uses
only ``einsum``, so results do not depend on the BLAS threading.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import transform_from_rt

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "column_norms",
    "kabsch",
    "lstsq_min_norm",
    "singular_values",
    "thin_qr",
    "wahba",
]


def kabsch(source: npt.ArrayLike, target: npt.ArrayLike) -> FloatArray:
    """Rigid transform (4, 4) minimising :math:`\\sum_k \\|R s_k + t - m_k\\|^2`.

    Parameters
    ----------
    source, target : array_like, shape (N, 3), N >= 3
        Corresponding points; ``source`` is moved onto ``target``.
    """
    S = np.asarray(source, dtype=float)
    M = np.asarray(target, dtype=float)
    if S.ndim != 2 or S.shape[1] != 3 or S.shape != M.shape or S.shape[0] < 3:
        raise ValueError(
            f"source and target must have the same shape (N >= 3, 3), got {S.shape}, {M.shape}"
        )
    cs, cm = S.mean(axis=0), M.mean(axis=0)
    U, _, Vt = np.linalg.svd(np.einsum("ni,nj->ij", S - cs, M - cm))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return transform_from_rt(R, cm - R @ cs)


def wahba(source: FloatArray, target: FloatArray) -> FloatArray:
    """Rotation (3, 3) minimising :math:`\\sum_k \\|R s_k - m_k\\|^2`."""
    U, _, Vt = np.linalg.svd(np.einsum("ni,nj->ij", source, target))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def thin_qr(A: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Thin QR of a tall matrix (m, p) by classical Gram–Schmidt with
    re-orthogonalisation. Uses only ``einsum`` (no multithreaded BLAS), which keeps
    it fast and deterministic on busy machines; dependent columns give zero columns
    of Q and zero diagonal entries of R."""
    m, p = A.shape
    Q = np.zeros((m, p))
    R = np.zeros((p, p))
    for k in range(p):
        v = A[:, k].copy()
        for _ in range(2):
            c = np.einsum("ij,i->j", Q[:, :k], v)
            v -= np.einsum("ij,j->i", Q[:, :k], c)
            R[:k, k] += c
        nv = float(np.sqrt(np.einsum("i,i->", v, v)))
        scale = float(np.sqrt(np.einsum("i,i->", A[:, k], A[:, k])))
        if nv > 1e-14 * max(scale, 1e-300):
            Q[:, k] = v / nv
            R[k, k] = nv
    return Q, R


def column_norms(J: FloatArray) -> FloatArray:
    """Euclidean norms (p,) of the columns of ``J`` (m, p)."""
    return np.sqrt(np.einsum("ij,ij->j", J, J))


def lstsq_min_norm(J: FloatArray, r: FloatArray, rcond: float = 1e-12) -> FloatArray:
    """Minimum-norm least-squares solution :math:`x = J^{+} r` (columns scaled first)."""
    norms = column_norms(J)
    norms[norms == 0] = 1.0
    Q, R = thin_qr(J / norms)
    U, sv, Vt = np.linalg.svd(R)
    inv = np.where(sv > rcond * max(float(sv[0]), 1e-300), 1.0 / np.maximum(sv, 1e-300), 0.0)
    y = np.einsum("ij,i->j", Q, r)
    return (Vt.T @ (inv * (U.T @ y))) / norms


def singular_values(J: FloatArray) -> FloatArray:
    """Singular values of a tall matrix (descending) through its R factor."""
    if J.shape[1] == 0:
        return np.zeros(0)
    _, R = thin_qr(J)
    return np.asarray(np.linalg.svd(R, compute_uv=False), dtype=np.float64)
