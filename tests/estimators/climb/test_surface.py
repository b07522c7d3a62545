"""Fast projection on analytic point clouds against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.estimators.climb.surface import SurfaceModel

R_SPHERE = 0.5
SPACING = 0.01


def _sphere_cloud() -> tuple[np.ndarray, np.ndarray]:
    n = int(4 * np.pi * R_SPHERE**2 / SPACING**2)
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5**0.5) * i
    dirs = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
    return R_SPHERE * dirs, dirs


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.fixture(scope="module")
def sphere() -> SurfaceModel:
    return SurfaceModel(*_sphere_cloud())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sphere_projection_matches_line_sphere_intersection(
    sphere: SurfaceModel, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    w = _unit(rng.normal(size=(400, 3)))
    h = 0.05
    p = (R_SPHERE + h + rng.uniform(-0.02, 0.02, (400, 1))) * w
    d = _unit(w + 0.1 * rng.normal(size=(400, 3)))
    pr = sphere.project(p, d, h)
    # closed form: |p + s d| = R, root nearest to p
    b = np.einsum("ij,ij->i", p, d)
    c = np.einsum("ij,ij->i", p, p) - R_SPHERE**2
    roots = np.stack([-b + np.sqrt(b * b - c), -b - np.sqrt(b * b - c)], 1)
    s = roots[np.arange(400), np.argmin(np.abs(roots), axis=1)]
    x = p + s[:, None] * d
    n_true = x / R_SPHERE
    assert np.all(pr.ok)
    assert np.abs(np.linalg.norm(pr.incidence - x, axis=1)).max() < 0.01 * SPACING
    angle = np.arccos(np.clip(np.einsum("ij,ij->i", pr.normal, n_true), -1, 1))
    assert angle.max() < np.deg2rad(0.05)
    assert np.linalg.norm(pr.point - (x + h * n_true), axis=1).max() < 0.01 * SPACING
    # offset: signed distance along d beyond the projected point
    np.testing.assert_allclose(pr.offset, np.einsum("ij,ij->i", p - pr.point, d), atol=1e-12)


def test_vectorised_equals_pointwise(sphere: SurfaceModel) -> None:
    rng = np.random.default_rng(4)
    p = _unit(rng.normal(size=(5, 3))) * (R_SPHERE + 0.03)
    d = _unit(p)
    batch = sphere.project(p, d, 0.03)
    for k in range(5):
        one = sphere.project(p[k], d[k], 0.03)
        assert one.point.shape == (3,) and isinstance(one.ok, bool)
        np.testing.assert_allclose(one.point, batch.point[k], atol=1e-12)
        np.testing.assert_allclose(one.normal, batch.normal[k], atol=1e-12)


def test_cylinder_projection_along_tilted_axis() -> None:
    # cylinder of radius 0.4 about x, sampled on a grid
    radius, h = 0.4, 0.06
    x = np.arange(-0.5, 0.5, SPACING)
    ang = np.arange(0, 2 * np.pi, SPACING / radius)
    X, A = np.meshgrid(x, ang, indexing="ij")
    normals = np.stack([np.zeros_like(A), np.cos(A), np.sin(A)], -1).reshape(-1, 3)
    points = np.c_[X.ravel(), radius * normals[:, 1:]]
    model = SurfaceModel(points, normals)
    rng = np.random.default_rng(7)
    a = rng.uniform(0, 2 * np.pi, 200)
    p = np.c_[rng.uniform(-0.2, 0.2, 200), (radius + h) * np.cos(a), (radius + h) * np.sin(a)]
    d = _unit(np.c_[rng.normal(0, 0.2, 200), np.cos(a), np.sin(a)])
    pr = model.project(p, d, h)
    # closed form: (y + s dy)^2 + (z + s dz)^2 = r^2, nearest root
    A2 = d[:, 1] ** 2 + d[:, 2] ** 2
    B = p[:, 1] * d[:, 1] + p[:, 2] * d[:, 2]
    C = p[:, 1] ** 2 + p[:, 2] ** 2 - radius**2
    disc = np.sqrt(B * B - A2 * C)
    s = np.where(
        np.abs((-B + disc) / A2) < np.abs((-B - disc) / A2), (-B + disc) / A2, (-B - disc) / A2
    )
    xi = p + s[:, None] * d
    n_true = np.c_[np.zeros(200), xi[:, 1:] / radius]
    assert np.all(pr.ok)
    assert np.linalg.norm(pr.point - (xi + h * n_true), axis=1).max() < 0.01 * SPACING


def test_nearest_normal_projection_and_failures(sphere: SurfaceModel) -> None:
    p = np.array([0.0, 0.0, R_SPHERE + 0.1])
    pr = sphere.project(p, None, 0.1)  # closest-point projection
    np.testing.assert_allclose(pr.point, p, atol=0.05 * SPACING)
    # a line parallel to the local plane has no incidence point: not ok, never NaN
    bad = sphere.project(p, [1.0, 0.0, 0.0], 0.1)
    assert not bad.ok
    assert np.all(np.isfinite(bad.point)) and np.all(np.isfinite(bad.normal))
    far = sphere.project(np.array([0.0, 0.0, 2.0]), [0.0, 0.0, 1.0], 0.0, max_distance=0.5)
    assert not far.ok


def test_spacing_and_readonly(sphere: SurfaceModel) -> None:
    assert sphere.spacing == pytest.approx(SPACING, rel=0.2)
    with pytest.raises(ValueError, match="read-only"):
        sphere.points[0, 0] = 1.0
    pts, _, dist = sphere.nearest(np.array([0.0, 0.0, 0.6]))
    assert pts.shape == (3,) and dist == pytest.approx(0.1, abs=SPACING)


def test_errors() -> None:
    pts, nrm = _sphere_cloud()
    with pytest.raises(ValueError, match="M ≥ 3"):
        SurfaceModel(pts[:2], nrm[:2])
    with pytest.raises(ValueError, match="shape of points"):
        SurfaceModel(pts, nrm[:-1])
    zero = nrm.copy()
    zero[0] = 0.0
    with pytest.raises(ValueError, match="non-zero"):
        SurfaceModel(pts, zero)
    with pytest.raises(ValueError, match="min_sine"):
        SurfaceModel(pts, nrm, min_sine=1.5)
    model = SurfaceModel(pts[:500], nrm[:500])
    with pytest.raises(ValueError, match=r"shape \(3,\) or \(N, 3\)"):
        model.project(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="non-zero direction"):
        model.project(np.ones(3), np.zeros(3))
    with pytest.raises(ValueError, match="body_z"):
        model.project(np.ones((4, 3)), np.ones((3, 3)))
    with pytest.raises(ValueError, match="finite"):
        model.project(np.array([np.nan, 0, 0]))
