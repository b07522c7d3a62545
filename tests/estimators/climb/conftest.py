"""Fixtures shared by the climbing-robot estimator tests."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.estimators.climb.surface import SurfaceModel
from realitygap.robots.blade_geometry import blade_texture, cad_point_cloud
from realitygap.robots.climb_synthetic import ClimbScenario


@pytest.fixture(scope="module")
def texture() -> np.ndarray:
    """Blade texture (1024 px square) drawn from seed 0."""
    return blade_texture(np.random.default_rng(0), 1024)


@pytest.fixture(scope="module")
def surface() -> SurfaceModel:
    """Blade CAD cloud (1 cm spacing) of the default scenario up to x = 5 m."""
    pts, nrm = cad_point_cloud(ClimbScenario().blade, 0.01)
    keep = pts[:, 0] < 5.0
    return SurfaceModel(pts[keep], nrm[keep])
