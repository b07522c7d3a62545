"""WheeledNav's cheaper physics (fused sub-steps, rigid static scenery) steps the robot bit
for bit as one engine call per physics step among multibody scenery does, contacts included."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.robots.diffdrive import DiffDriveParams, DiffDriveRobot
from realitygap.robots.world import Primitive, Shape, World

SCENERY = [
    Primitive("box", Shape.BOX, (0.9, 0.0), 0.6, yaw=0.4, half_extents=(0.2, 0.5)),
    Primitive("cyl", Shape.CYLINDER, (-0.2, 0.9), 0.6, radius=0.25),
    Primitive("wall", Shape.BOX, (0.0, -1.05), 2.0, half_extents=(2.0, 0.05)),
]


def _drive(fused: bool, rigid: bool, n_steps: int = 240) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth states and contact flags of the robot pushed into the scenery."""
    w = World(fused_substeps=fused, rigid_scenery=rigid)
    w.add_floor()
    for prim in SCENERY:
        w.add_primitive(prim)
    robot = DiffDriveRobot(w, DiffDriveParams())
    robot.reset([0.0, 0.0, 0.0])
    c = w.bullet
    states, contacts = [], []
    for k in range(n_steps):
        # straight into the box, then turns and pushes towards the cylinder and the wall
        phase = (k // 60) % 4
        w_left, w_right = [(15.0, 15.0), (-8.0, 12.0), (14.0, 15.0), (10.0, -12.0)][phase]
        robot.set_wheel_speeds(w_left, w_right)
        w.step()
        pos, quat = c.getBasePositionAndOrientation(robot.body)
        lin, ang = c.getBaseVelocity(robot.body)
        states.append([*pos, *quat, *lin, *ang, *robot.wheel_angles()])
        contacts.append(robot.in_contact_with_scenery())
    w.close()
    return np.array(states), np.array(contacts)


@pytest.mark.parametrize(("fused", "rigid"), [(True, False), (False, True), (True, True)])
def test_cheaper_physics_is_bit_identical_through_contacts(fused: bool, rigid: bool) -> None:
    ref_states, ref_contacts = _drive(False, False)
    states, contacts = _drive(fused, rigid)
    assert ref_contacts.sum() > 20  # the robot did push against the scenery
    assert np.array_equal(contacts, ref_contacts)
    assert np.array_equal(states, ref_states)


def test_rigid_scenery_flag_is_checked() -> None:
    with pytest.raises(TypeError, match="rigid_scenery must be True or False"):
        World(rigid_scenery=1)  # type: ignore[arg-type]


def test_rigid_scenery_renders_the_same_pictures() -> None:
    """Textured floor, walls and obstacles look the same as static rigid bodies."""
    pictures = []
    for rigid in (False, True):
        w = World(rigid_scenery=rigid)
        rng = np.random.default_rng(4)
        w.add_floor(textured_half_size=1.5, rng=rng)
        for prim in SCENERY:
            w.add_primitive(prim, surface="wall" if prim.name == "wall" else "object", rng=rng)
        pictures.append(w.render_rgb([-1.0, -0.5, 0.8], [1.0, 0.3, 0.3], width=96, height=72))
        w.close()
    assert pictures[0].std() > 5.0  # a textured scene, not a blank picture
    assert np.array_equal(pictures[0], pictures[1])
