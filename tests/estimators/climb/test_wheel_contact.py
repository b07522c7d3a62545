"""Two-wheel adsorption contact on a closed-form cylinder.

A horizontal cylinder of radius ρ (axis along x) carries a chassis with two sphere
wheels of radius h a track b apart on its axle, the axle across the curvature. The
wheel centres lie on the circle of radius ρ + h, so the axle midpoint (the body
origin) sits at ``(ρ + h) cos δ - ρ < h`` above the surface with
``sin δ = b / (2 (ρ + h))``; the chassis may pitch about the axle.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from realitygap.core.geometry import quat_xyzw_from_matrix, so3_exp
from realitygap.estimators.climb.constrained import ConstrainedConfig, ConstrainedEstimator
from realitygap.estimators.climb.measurements import ClimbEstimate
from realitygap.estimators.climb.surface import SurfaceModel

RHO, H, TRACK = 0.5, 0.04, 0.14
PHI0 = 0.25  # where the body sits on the cylinder (rad from the top)


@pytest.fixture(scope="module")
def cylinder() -> SurfaceModel:
    x, phi = np.meshgrid(np.arange(-0.4, 0.4, 0.005), np.arange(-0.2, 0.8, 0.005 / RHO))
    normals = np.stack([np.zeros_like(x), np.sin(phi), np.cos(phi)], -1).reshape(-1, 3)
    points = normals * RHO + np.stack([x, 0 * x, 0 * x], -1).reshape(-1, 3)
    return SurfaceModel(points, normals)


def _true_pose(pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """Body origin and R_world_body on the cylinder at PHI0, heading along the axis."""
    n = np.array([0.0, math.sin(PHI0), math.cos(PHI0)])
    x = np.array([1.0, 0.0, 0.0])
    R = np.stack([x, np.cross(n, x), n], axis=1) @ so3_exp([0.0, pitch, 0.0])
    delta = math.asin(TRACK / (2 * (RHO + H)))
    return (RHO + H) * math.cos(delta) * n, R


def _estimate(p: np.ndarray, R: np.ndarray, frame: str = "world") -> ClimbEstimate:
    return ClimbEstimate(t=0.0, position=p, quat_xyzw=quat_xyzw_from_matrix(R), frame=frame)


def _settle(
    surface: SurfaceModel, config: ConstrainedConfig, start: ClimbEstimate, vio: ClimbEstimate
) -> ClimbEstimate:
    ekf = ConstrainedEstimator(surface, [0.0, 0.0, 3.0], H, config)
    ekf.reset(start, np.diag([1e-4] * 3 + [1e-4] * 3))
    est = ekf.update(vio)
    for _ in range(60):  # a robot standing still: the same VIO pose again and again
        est = ekf.update(vio)
    return est


def test_axle_midpoint_sits_below_h_on_a_convex_section(cylinder: SurfaceModel) -> None:
    p, R = _true_pose(0.0)
    pr = cylinder.project(p, None, 0.0)
    height = float(pr.normal @ (p - pr.incidence))
    sag = H - ((RHO + H) * math.cos(math.asin(TRACK / (2 * (RHO + H)))) - RHO)
    assert height == pytest.approx(H - sag, abs=2e-5)
    assert sag == pytest.approx(TRACK**2 / (8 * (RHO + H)), rel=0.02)
    # both wheel centres are exactly h above the surface
    centres = p + np.outer([0.5, -0.5], TRACK * R[:, 1])
    prw = cylinder.project(centres, None, 0.0)
    heights = np.einsum("ij,ij->i", prw.normal, centres - prw.incidence)
    np.testing.assert_allclose(heights, H, atol=2e-5)


@pytest.mark.parametrize("pitch", [0.0, 0.06])
def test_true_pose_is_a_fixed_point_only_with_the_wheel_model(
    cylinder: SurfaceModel, pitch: float
) -> None:
    """Started at the truth (chassis pitched about its axle by ``pitch``), the wheel
    model stays there; the point-contact model pulls the origin up to h along the
    normal (by the sag) and turns the body z-axis onto the normal."""
    p, R = _true_pose(pitch)
    vio = _estimate(p, R)
    start = _estimate(p, R, "cad")
    wheels = ConstrainedConfig(use_tether=False, wheel_track=TRACK, pitch_sigma=0.07)
    point = ConstrainedConfig(use_tether=False, normal_sigma=0.01)
    est_w = _settle(cylinder, wheels, start, vio)
    est_p = _settle(cylinder, point, start, vio)
    sag = TRACK**2 / (8 * (RHO + H))
    assert np.linalg.norm(est_w.position - p) < 3e-4
    assert np.linalg.norm(est_p.position - p) > 0.6 * sag


def test_wheel_model_converges_from_a_perturbed_start(cylinder: SurfaceModel) -> None:
    """1 cm off along the normal and 2 cm along the curvature: the two wheel heights
    (and gravity, which fixes the axle's tilt, hence where on the curvature it
    matches the surface) bring the body back; along the flat axis nothing changes."""
    p, R = _true_pose(0.04)
    n = np.array([0.0, math.sin(PHI0), math.cos(PHI0)])
    around = np.cross([1.0, 0.0, 0.0], n)
    start = _estimate(p + 0.01 * n + 0.02 * around, R, "cad")
    est = _settle(
        cylinder,
        ConstrainedConfig(use_tether=False, wheel_track=TRACK, pitch_sigma=0.07),
        start,
        _estimate(p, R),
    )
    err = est.position - p
    assert abs(err @ n) < 1e-3
    assert abs(err @ around) < 1.5e-3
    assert abs(err[0]) < 1e-6


def test_wheel_track_must_be_non_negative() -> None:
    with pytest.raises(ValueError, match="wheel_track"):
        ConstrainedConfig(wheel_track=-0.1)
    with pytest.raises(ValueError, match="pitch_sigma"):
        ConstrainedConfig(pitch_sigma=0.0)
