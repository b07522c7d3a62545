"""What the fast paths of the simulation must keep: ray casts, textures and rendered frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from realitygap.robots import textures
from realitygap.robots.textures import (
    clear_texture_cache,
    set_texture_cache_limit,
    surface_texture,
    texture_cache_info,
)
from realitygap.robots.world import Primitive, PrimitiveArrays, Shape, World


def _reference_ray(
    origin: np.ndarray, direction: np.ndarray, prims: list[Primitive], range_max: float
) -> float:
    """One ray, one primitive at a time, in plain Python floats (slab method, circle roots)."""
    best = math.inf
    for q in prims:
        rx, ry = origin[0] - q.center[0], origin[1] - q.center[1]
        dx, dy = float(direction[0]), float(direction[1])
        if q.shape is Shape.CYLINDER:
            b = rx * dx + ry * dy
            cc = rx * rx + ry * ry - q.radius**2
            disc = b * b - cc
            if disc < 0:
                continue
            t = 0.0 if cc < 0 else -b - math.sqrt(disc)
            if t >= 0:
                best = min(best, t)
            continue
        c, s = math.cos(q.yaw), math.sin(q.yaw)
        o = (c * rx + s * ry, -s * rx + c * ry)
        d = (c * dx + s * dy, -s * dx + c * dy)
        lo, hi = 0.0, math.inf
        for k in range(2):
            h = q.half_extents[k]
            if d[k] == 0.0:
                if abs(o[k]) > h:
                    lo, hi = 1.0, 0.0
                continue
            t1, t2 = (-h - o[k]) / d[k], (h - o[k]) / d[k]
            lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
        if hi >= lo:
            best = min(best, lo)
    return best if best <= range_max else math.inf


def test_vectorised_ray_cast_matches_a_per_ray_reference() -> None:
    rng = np.random.default_rng(7)
    for trial in range(40):
        prims: list[Primitive] = []
        for k in range(int(rng.integers(1, 10))):
            centre = (float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)))
            if rng.random() < 0.5:
                he = (float(rng.uniform(0.05, 1.5)), float(rng.uniform(0.05, 1.5)))
                yaw = 0.0 if trial % 4 == 0 else float(rng.uniform(-3, 3))
                prims.append(Primitive(f"b{k}", Shape.BOX, centre, 0.5, yaw, he))
            else:
                r = float(rng.uniform(0.05, 0.6))
                prims.append(Primitive(f"c{k}", Shape.CYLINDER, centre, 0.5, radius=r))
        angles = rng.uniform(-np.pi, np.pi, 48)
        if trial % 4 == 0:  # rays parallel to axis-aligned faces: the division by zero
            angles[:4] = [0.0, np.pi / 2, np.pi, -np.pi / 2]
        dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        if trial % 4 == 0:
            dirs[:4] = [[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]]
        origin = rng.uniform(-3, 3, 2)
        got = PrimitiveArrays(prims).ray_cast(origin, dirs, 6.0)
        want = [_reference_ray(origin, d, prims, 6.0) for d in dirs]
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_cached_texture_is_identical_and_leaves_the_generator_where_drawing_would() -> None:
    clear_texture_cache()
    a_rng, b_rng = np.random.default_rng(11), np.random.default_rng(11)
    a = surface_texture(a_rng, 1.5, 0.5, "wall")
    after_draw = a_rng.integers(1 << 30, size=4)
    assert texture_cache_info()["misses"] == 1
    b = surface_texture(b_rng, 1.5, 0.5, "wall")  # same state on entry: a hit
    assert texture_cache_info()["hits"] == 1
    assert np.array_equal(a, b)
    assert np.array_equal(b_rng.integers(1 << 30, size=4), after_draw)
    b[:] = 0  # the caller's copy; the cached image is untouched
    assert np.array_equal(surface_texture(np.random.default_rng(11), 1.5, 0.5, "wall"), a)
    # another kind, size or state is another texture
    assert not np.array_equal(surface_texture(np.random.default_rng(11), 1.5, 0.5, "object"), a)
    assert texture_cache_info()["misses"] == 2


def test_texture_cache_is_bounded_and_can_be_turned_off() -> None:
    clear_texture_cache()
    try:
        one = surface_texture(np.random.default_rng(0), 1.0, 1.0, "object").nbytes
        set_texture_cache_limit(int(2.5 * one))
        for seed in range(1, 5):
            surface_texture(np.random.default_rng(seed), 1.0, 1.0, "object")
        info = texture_cache_info()
        assert info["entries"] == 2 and info["bytes"] <= info["max_bytes"]
        set_texture_cache_limit(0)
        assert texture_cache_info()["entries"] == 0
        surface_texture(np.random.default_rng(9), 1.0, 1.0, "object")
        assert texture_cache_info()["entries"] == 0
        with pytest.raises(ValueError, match="max_bytes must be a whole number"):
            set_texture_cache_limit(-1)
    finally:
        set_texture_cache_limit(textures.DEFAULT_TEXTURE_CACHE_BYTES)
        clear_texture_cache()


def _room(world: World, seed: int, plain_slab: bool) -> None:
    """A textured 2 m room with a box; with ``plain_slab`` also a full plain floor slab in the
    floor's colour, as the floor was drawn before it became a frame around the texture."""
    rng = np.random.default_rng(seed)
    world.reset_simulation()
    world.add_floor(textured_half_size=2.1, rng=rng)
    if plain_slab:
        import pybullet as p

        c = world.bullet
        half = World.PLAIN_FLOOR_HALF_SIZE
        rgba = [0.55, 0.5, 0.45, 1.0]  # add_floor's default colour
        vis = c.createVisualShape(p.GEOM_BOX, halfExtents=[half, half, 0.001], rgbaColor=rgba)
        c.createMultiBody(0.0, -1, vis, [0, 0, 0])
    for k, (x, y, hx, hy) in enumerate(
        [(0, 2.05, 2.1, 0.05), (0, -2.05, 2.1, 0.05), (2.05, 0, 0.05, 2.1), (-2.05, 0, 0.05, 2.1)]
    ):
        world.add_primitive(
            Primitive(f"wall_{k}", Shape.BOX, (x, y), 0.5, half_extents=(hx, hy)),
            surface="wall",
            rng=rng,
        )
    world.add_primitive(
        Primitive("box", Shape.BOX, (1.0, 0.3), 0.4, yaw=0.4, half_extents=(0.2, 0.3)),
        surface="object",
        rng=rng,
    )


def test_floor_frame_renders_the_room_exactly_as_a_full_plain_floor_under_it() -> None:
    """The plain floor is drawn only around the texture: from inside the room and from above
    the picture is the one a full plain slab under the texture gives (a hole in the frame, or
    a slab showing through the texture, would differ)."""
    world = World()
    try:
        views = [([0.0, 0.0, 0.3], [2.0, 0.5, 0.2]), ([-1.5, -1.5, 0.3], [0.0, 0.0, 0.0])]
        views.append(([0.0, -7.0, 7.0], [0.0, 0.0, 0.0]))  # from above: the frame shows
        pictures = {}
        for slab in (False, True):
            _room(world, 3, plain_slab=slab)
            pictures[slab] = [world.render_rgb(eye, target, far=40.0) for eye, target in views]
        for a, b in zip(pictures[False], pictures[True], strict=True):
            assert np.array_equal(a, b)
        # and the floor colour does show around the room in the view from above
        grey = np.all(np.abs(pictures[False][2].astype(int) - [140, 128, 115]) < 20, axis=-1)
        assert grey.mean() > 0.05
    finally:
        world.close()


def test_textured_floor_size_is_checked() -> None:
    world = World()
    try:
        with pytest.raises(ValueError, match="textured_half_size must be a positive size"):
            world.add_floor(
                textured_half_size=World.PLAIN_FLOOR_HALF_SIZE, rng=np.random.default_rng(0)
            )
    finally:
        world.close()


def test_scan_from_its_own_small_render_agrees_with_the_full_frame_scan() -> None:
    """Between camera frames the scan renders a picture with two columns per beam; its ranges
    agree with the scan of the full frame to the bin geometry and the depth noise."""
    import gymnasium as gym

    import realitygap  # noqa: F401

    env = gym.make("realitygap/WheeledNav-v0", sensor_mode="image", n_obstacles=5)
    rel: list[np.ndarray] = []
    try:
        for seed in (0, 1):
            env.reset(seed=seed)
            u = env.unwrapped
            for _ in range(3):
                for _ in range(5):
                    env.step(np.array([0.8, 0.3], dtype=np.float32))
                full = u.scanner.scan_from_frame(u.camera.render(0.0, np.random.default_rng(1)))
                small = u.scanner.scan_rendered(u.camera, 0.0, np.random.default_rng(1))
                assert np.array_equal(small.angles, full.angles)
                both = np.isfinite(full.ranges) & np.isfinite(small.ranges)
                assert both.mean() > 0.9
                rel.append(np.abs(small.ranges[both] - full.ranges[both]) / full.ranges[both])
        with pytest.raises(ValueError, match=r"size must be \(width, height\) in pixels"):
            u.camera.render(0.0, np.random.default_rng(0), size=(0, 10))
    finally:
        env.close()
    r = np.concatenate(rel)
    # a beam's range is the nearest pixel of its bin: fewer pixels give a slightly longer
    # one (a few mm per metre); beams across an obstacle's edge may see past it
    assert np.median(r) < 0.02 and np.mean(r < 0.05) > 0.9


def test_egl_renderer_is_optional_and_checked() -> None:
    world = World()
    try:
        world.add_floor(textured_half_size=2.0, rng=np.random.default_rng(0))
        with pytest.raises(ValueError, match="renderer must be 'tiny' or 'egl'"):
            world.render_rgb([0, -3, 2], [0, 0, 0], renderer="vulkan")
        with pytest.raises(RuntimeError, match="call load_egl_renderer"):
            world.render_rgb([0, -3, 2], [0, 0, 0], renderer="egl")
        tiny = world.render_rgb([0, -3, 2], [0, 0, 0])
        if world.load_egl_renderer():  # a GPU or a software EGL device on this machine
            egl = world.render_rgb([0, -3, 2], [0, 0, 0], renderer="egl")
            assert egl.shape == tiny.shape == (240, 320, 3)
            # its own background and lighting, but the textured floor is there
            assert egl[120:].std() > 10 and tiny[120:].std() > 10
    finally:
        world.close()
        world.close()
