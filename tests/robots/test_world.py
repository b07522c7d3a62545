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
