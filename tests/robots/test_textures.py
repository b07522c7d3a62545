"""Procedural room textures and the textured scenery they are drawn on."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from realitygap.robots.diffdrive import RGBDCameraParams
from realitygap.robots.sensors import RGBDCamera
from realitygap.robots.textures import PX_PER_M, surface_texture
from realitygap.robots.world import Primitive, Shape, World, side_mesh


@pytest.mark.parametrize("kind", ["wall", "floor", "object"])
def test_texture_is_seeded_metric_and_feature_rich(kind: str) -> None:
    a = surface_texture(np.random.default_rng(3), 2.0, 1.0, kind)
    b = surface_texture(np.random.default_rng(3), 2.0, 1.0, kind)
    c = surface_texture(np.random.default_rng(4), 2.0, 1.0, kind)
    assert a.shape == (int(PX_PER_M), int(2 * PX_PER_M), 3) and a.dtype == np.uint8
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    # a camera finds corners all over it: ORB keypoints in most cells of a 4 × 2 grid
    kps = cv2.ORB.create(2000).detect(cv2.cvtColor(a, cv2.COLOR_RGB2GRAY), None)
    cells = {(int(k.pt[0] * 4 / a.shape[1]), int(k.pt[1] * 2 / a.shape[0])) for k in kps}
    assert len(kps) > 200 and len(cells) >= 6


def test_texture_rejects_bad_sizes_and_kinds() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="width_m must be a positive size"):
        surface_texture(rng, 0.0, 1.0)
    with pytest.raises(ValueError, match="kind must be one of"):
        surface_texture(rng, 1.0, 1.0, "ceiling")


@pytest.mark.parametrize(
    "prim",
    [
        Primitive("b", Shape.BOX, (0.0, 0.0), 0.6, yaw=0.3, half_extents=(0.2, 0.5)),
        Primitive("c", Shape.CYLINDER, (0.0, 0.0), 0.6, radius=0.25),
    ],
)
def test_side_mesh_unwraps_the_perimeter(prim: Primitive) -> None:
    verts, idx, uvs, normals, perimeter = side_mesh(prim)
    V, UV = np.asarray(verts), np.asarray(uvs)
    expected = 2 * np.pi * prim.radius if prim.shape is Shape.CYLINDER else 4 * 1.4 / 2
    assert perimeter == pytest.approx(expected, rel=2e-3)
    assert np.all((UV >= 0) & (UV <= 1)) and len(idx) % 3 == 0 and max(idx) < len(V)
    assert V[:, 2].min() == pytest.approx(-0.3) and V[:, 2].max() == pytest.approx(0.3)
    side = np.abs(np.asarray(normals)[:, 2]) < 0.5
    # side vertices lie on the footprint's outline
    d = prim.footprint_distance(V[side, :2] @ np.eye(2))
    if prim.shape is Shape.BOX:
        d = Primitive(
            "b0", Shape.BOX, (0.0, 0.0), 0.6, half_extents=prim.half_extents
        ).footprint_distance(V[side, :2])
    assert np.allclose(d, 0.0, atol=1e-9)


class _FixedCamera:
    """A camera 0.3 m above the origin looking along world +x."""

    def __init__(self, world: World):
        self.world = world

    def T_world_camera(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
        T[2, 3] = 0.3
        return T


def test_rendered_edges_land_where_the_intrinsics_project_them() -> None:
    world = World()
    try:
        params = dataclasses.replace(RGBDCameraParams(), depth_noise_a=0.0, depth_noise_b=0.0)
        cam = RGBDCamera(_FixedCamera(world), params)  # type: ignore[arg-type]
        K, rng = cam.intrinsics, np.random.default_rng(0)
        du, dv = [], []
        for y in np.linspace(-1.0, 1.0, 9):  # thin vertical bars 2 m ahead: column edges
            world.reset_simulation()
            world.add_primitive(
                Primitive("b", Shape.BOX, (2.0005, y), 4.0, half_extents=(5e-4, 0.1))
            )
            cols = np.flatnonzero(np.isfinite(cam.render(0.0, rng).depth[K.height // 2]))
            du += [cols.min() - 0.5 - (K.cx - K.fx * (y + 0.1) / 2.0)]
            du += [cols.max() + 0.5 - (K.cx - K.fx * (y - 0.1) / 2.0)]
        for top in np.linspace(-0.2, 0.4, 9):  # walls 2 m ahead: their top edge's row
            world.reset_simulation()
            world.add_primitive(
                Primitive("w", Shape.BOX, (2.0005, 0.0), 0.3 + top, half_extents=(5e-4, 3.0))
            )
            rows = np.flatnonzero(np.isfinite(cam.render(0.0, rng).depth[:, K.width // 2]))
            dv.append(rows.min() - 0.5 - (K.cy - K.fy * top / 2.0))
        # pixel quantisation leaves ±0.5 px per edge; a shifted principal point would not
        assert abs(np.mean(du)) < 0.2 and abs(np.mean(dv)) < 0.2
        assert np.max(np.abs(du)) <= 0.6 and np.max(np.abs(dv)) <= 0.6
    finally:
        world.close()


def test_textured_floor_and_surfaces_need_a_generator() -> None:
    world = World()
    try:
        with pytest.raises(ValueError, match="textured floor needs rng"):
            world.add_floor(textured_half_size=2.0)
        with pytest.raises(ValueError, match="needs rng"):
            world.add_primitive(
                Primitive("w", Shape.BOX, (0.0, 0.0), 1.0, half_extents=(1, 1)), surface="wall"
            )
    finally:
        world.close()
