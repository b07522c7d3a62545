from __future__ import annotations

import pickle

import numpy as np
import pybullet as p
import pytest

from realitygap.robots.world import CountedDict, Primitive, Shape, World


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
    schedule: list[int | None] = [None] * 30 + [12] * 10
    fused = _drive(True, schedule)
    plain = _drive(False, schedule)
    assert np.array_equal(fused, plain)
    assert np.ptp(fused[:, 0]) > 0.1  # the box did slide


def test_fused_world_refuses_partial_periods_and_per_step_actions() -> None:
    w = World(n_substeps=4, fused_substeps=True)
    assert w.fused_substeps
    with pytest.raises(ValueError, match=r"whole control periods only.*n_physics_steps=3"):
        w.step(3)
    with pytest.raises(ValueError, match=r"before_each.*fused_substeps=False"):
        w.step(before_each=lambda: None)
    w.step(4)  # a whole period, given explicitly
    w.close()


def test_motor_force_gives_the_per_physics_step_impulse_bound_exactly() -> None:
    rng = np.random.default_rng(2)
    n_fused = 0
    for n in (2, 5, 12, 24):
        for force in [0.35, 1.0, *rng.uniform(1e-3, 50.0, 25)]:
            w = World(n_substeps=n, fused_substeps=True)
            f = w.motor_force(float(force))
            if w.fused_substeps:
                assert f * w.dt == float(force) * w.physics_dt
                n_fused += 1
            else:  # no exact command exists: the world steps one call per physics step
                assert f == float(force)
            w.close()
    assert n_fused > 80  # an exact command exists for nearly every bound
    w = World(n_substeps=12, fused_substeps=True)
    w.motor_force(0.35)  # WheeledNav's default wheel motors
    assert w.fused_substeps
    w.close()
    plain = World(n_substeps=12)
    assert plain.motor_force(0.35) == 0.35  # one call per physics step: the force as it is
    plain.close()


def test_the_world_client_id_is_the_one_its_bodies_live_in() -> None:
    world = World()
    body = world.bullet.createMultiBody(baseMass=1.0)
    pos, _ = p.getBasePositionAndOrientation(body, world.client_id)
    assert pos == pytest.approx((0.0, 0.0, 0.0))
    world.close()
    with pytest.raises(RuntimeError, match="closed"):
        _ = world.client_id


def test_a_counted_dict_counts_every_change_and_no_read() -> None:
    d = CountedDict()
    changes = [
        lambda: d.__setitem__("a", 1),
        lambda: d.update(b=2),
        lambda: d.setdefault("c", 3),
        lambda: d.__ior__({"e": 5}),
        lambda: d.pop("a"),
        lambda: d.__delitem__("b"),
        lambda: d.popitem(),
        lambda: d.clear(),
    ]
    for k, change in enumerate(changes, start=1):
        change()
        assert d.version == k, change
    d["x"] = 1
    before = d.version
    _ = d["x"], d.get("y"), list(d.keys()), "x" in d, len(d)
    assert d.version == before
    again = pickle.loads(pickle.dumps(d))
    assert again == d and again.version == d.version and type(again) is CountedDict
