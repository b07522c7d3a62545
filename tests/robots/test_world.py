from __future__ import annotations

import numpy as np
import pytest

from realitygap.robots.world import Primitive, Shape, World


def test_step_calls_before_each_once_per_physics_step() -> None:
    w = World(n_substeps=4)
    calls: list[int] = []
    w.step(before_each=lambda: calls.append(1))
    assert len(calls) == 4
    w.step(3, before_each=lambda: calls.append(1))
    assert len(calls) == 7
    w.step(0, before_each=lambda: calls.append(1))
    assert len(calls) == 7
    with pytest.raises(ValueError, match="n_physics_steps"):
        w.step(-1)
    w.close()


def test_remove_body_forgets_the_name_and_render_gives_an_rgb_picture() -> None:
    w = World()
    w.add_floor()
    w.add_primitive(Primitive("box", Shape.BOX, (1.0, 0.0), 0.5, half_extents=(0.2, 0.2)))
    img = w.render_rgb([3.0, 0.0, 1.0], [0.0, 0.0, 0.0], width=64, height=48)
    assert img.shape == (48, 64, 3) and img.dtype == np.uint8
    w.remove_body("floor")
    assert "floor" not in w.bodies
    with pytest.raises(KeyError, match="no body named 'floor'"):
        w.remove_body("floor")
    w.close()


def test_file_caching_can_be_switched_off() -> None:
    w = World()
    w.set_file_caching(False)
    w.set_file_caching(True)
    w.close()
    with pytest.raises(RuntimeError, match="closed"):
        w.set_file_caching(False)


def _drive(fused: bool, schedule: list[int | None]) -> np.ndarray:
    """Poses of a box pushed across the floor by a velocity, stepped by ``schedule``."""
    import pybullet as p

    w = World(n_substeps=12, fused_substeps=fused)
    w.add_floor()
    c = w.bullet
    box = c.createMultiBody(
        1.0, c.createCollisionShape(p.GEOM_BOX, halfExtents=[0.1, 0.2, 0.05]), -1, [0, 0, 0.06]
    )
    poses = []
    for k, n in enumerate(schedule):
        if k % 5 == 0:
            c.resetBaseVelocity(box, [1.0 - 0.1 * k, 0.3, 0.0], [0.0, 0.0, 2.0])
        w.step(n)
        pos, quat = c.getBasePositionAndOrientation(box)
        poses.append(list(pos) + list(quat))
    w.close()
    return np.array(poses)


def test_fused_substeps_step_bit_for_bit_like_one_call_per_physics_step() -> None:
    # whole control periods, and single physics steps in between (which leave the fused loop)
    schedule: list[int | None] = [None] * 20 + [3, 1, None, None, 12, 0, None] + [None] * 10
    fused = _drive(True, schedule)
    plain = _drive(False, schedule)
    assert np.array_equal(fused, plain)
    assert np.ptp(fused[:, 0]) > 0.1  # the box did slide


def test_fused_substeps_fall_back_where_the_time_step_arithmetic_is_not_exact() -> None:
    from realitygap.robots.world import fused_steps_are_exact

    assert fused_steps_are_exact(1.0 / 240.0, 12)
    exact = [n for n in range(1, 40) if fused_steps_are_exact(1.0 / 240.0, n)]
    inexact = [n for n in range(1, 40) if not fused_steps_are_exact(1.0 / 240.0, n)]
    assert inexact  # some rates are not exact in binary floating point...
    w = World(n_substeps=inexact[0], fused_substeps=True)
    assert not w.fused_substeps  # ...and step one call at a time
    w.close()
    w = World(n_substeps=exact[-1], fused_substeps=True)
    assert w.fused_substeps
    w.close()
    with pytest.raises(TypeError, match="fused_substeps must be True or False"):
        World(fused_substeps="yes")  # type: ignore[arg-type]
