"""Visual front-end: metric relative motion from two rendered down-looking views."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import (
    rot_z,
    so3_log,
)
from realitygap.estimators.climb.frontend import relative_motion_from_images
from realitygap.robots.climb_synthetic import render_planar_view

# ------------------------------------------------------------------ visual front-end

K = np.array([[280.0, 0.0, 160.0], [0.0, 280.0, 120.0], [0.0, 0.0, 1.0]])
DOWN = np.diag([1.0, -1.0, -1.0])  # camera looking along -z of the plane frame
TEXEL = 0.25 / 1024


def test_homography_front_end_recovers_metric_motion(texture: np.ndarray) -> None:
    c0 = np.array([0.11, 0.07, 0.06])
    R0 = DOWN
    R1 = rot_z(np.deg2rad(3.0)) @ Rotation.from_euler("x", 1.0, degrees=True).as_matrix() @ DOWN
    c1 = c0 + np.array([0.008, -0.005, 0.0])
    img0 = render_planar_view(texture, TEXEL, K, (320, 240), R0, c0)
    img1 = render_planar_view(texture, TEXEL, K, (320, 240), R1, c1)
    m = relative_motion_from_images(img0, img1, K, 0.06, t0=0.0, t1=0.1)
    assert m.ok and m.n_inliers > 50
    R_true = R0.T @ R1
    t_true = R0.T @ (c1 - c0)
    assert np.degrees(np.linalg.norm(so3_log(R_true.T @ m.rotation))) < 0.2
    assert np.linalg.norm(m.translation - t_true) < 0.03 * np.linalg.norm(t_true) + 2e-4
    assert np.all(np.linalg.eigvalsh(m.cov) > 0)
    blank = np.full((240, 320), 128, np.uint8)
    assert not relative_motion_from_images(blank, blank, K, 0.06).ok
