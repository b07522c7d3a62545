"""The arm at its poses: the nominal arm of a log, its tool points in PyBullet, pose sets.

:func:`arm_params_from_meta` reads the nominal arm a log states and :func:`tool_from_meta`
its tool point; :func:`replay_arm` sets every pose of a log in the PyBullet arm and reads
the tool point; :func:`probe_poses` draws the pose sets the identifiability advice
suggests (:data:`ARM_PROBE_SETS`); :func:`record_arm_log` measures random poses of a
PyBullet arm with a simulated laser tracker (the blind suite's logs,
:func:`sample_arm_poses`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.adapters.arm.kinematics import (
    POSES_PER_WINDOW,
    backlash_directions,
    base_tilt,
)
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.estimators.arm.mdh import MDHTable
from realitygap.robots.arm import arm_params_to_meta

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ARM_PROBE_SETS",
    "arm_params_from_meta",
    "probe_poses",
    "record_arm_log",
    "replay_arm",
    "sample_arm_poses",
    "tool_from_meta",
]

ARM_PROBE_SETS: dict[str, str] = {
    "outstretched_poses": "poses with the upper arm and forearm stretched out near the "
    "horizontal (largest gravity torque on shoulder and elbow)",
    "approach_reversals": "each pose measured twice, approached once from below and once from "
    "above on every joint",
    "wrist_sweep": "the wrist joints 4-6 over their full range with the arm held still",
    "base_sweep": "joint 1 over its full range at a few fixed arm postures",
}
"""Pose sets suggested to separate confounded arm effects (identifiability advice)."""


# --------------------------------------------------------------------------- parameters
def arm_params_from_meta(log: Log) -> Any:
    """The nominal :class:`~realitygap.robots.arm.ArmParams` of an arm log.

    Raises
    ------
    LogError
        ``meta["params"]`` missing or without a full 6-joint MDH table.
    """
    from realitygap.robots.arm import ArmParams

    raw = log.meta.get("params")
    if not isinstance(raw, Mapping) or not isinstance(raw.get("mdh"), Mapping):
        raise LogError(
            f"{log.source}: an arm log needs meta['params']['mdh'] (the nominal MDH table, "
            "e.g. MDHTable.param_dict()); got "
            f"{sorted(raw) if isinstance(raw, Mapping) else type(raw).__name__}"
        )
    mdh = raw["mdh"]
    base = MDHTable(np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6))
    names = base.param_names()
    missing = [n for n in names if n not in mdh]
    if missing:
        raise LogError(
            f"{log.source}: meta['params']['mdh'] lacks {', '.join(missing[:6])}"
            f"{' …' if len(missing) > 6 else ''} (a 6-joint table needs theta1..beta6)"
        )
    table = base.with_params([float(mdh[n]) for n in names], names)
    table = MDHTable(
        table.theta_offset,
        table.d,
        table.a,
        table.alpha,
        table.beta,
        str(raw.get("mdh_name", "arm")),
    )
    kw: dict[str, Any] = {"mdh": table}
    if "link_masses" in raw:
        kw["link_masses"] = tuple(float(v) for v in raw["link_masses"])
    if "payload_mass" in raw:
        kw["camera_mass"] = float(raw["payload_mass"])
    for key in ("joint_lower", "joint_upper"):
        if key in raw:
            kw[key] = tuple(float(v) for v in raw[key])
    try:
        return ArmParams(**kw)
    except ValueError as exc:
        raise LogError(f"{log.source}: meta['params'] is not a valid arm: {exc}") from None


def tool_from_meta(log: Log) -> FloatArray:
    """The tool point in the flange frame (``meta["tool"]``, m; the flange origin by default)."""
    tool = np.asarray(log.meta.get("tool", (0.0, 0.0, 0.0)), dtype=float).reshape(-1)
    if tool.shape != (3,) or not np.all(np.isfinite(tool)):
        raise LogError(
            f"{log.source}: meta['tool'] must be the tool point in the flange frame, 3 finite "
            f"numbers in m; got {log.meta.get('tool')!r}"
        )
    return tool


# --------------------------------------------------------------------------- replay
def replay_arm(
    params: Any,
    q_enc: FloatArray,
    tool: FloatArray,
    reality: Any = None,
    direction: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Tool points (N, 3) in the base frame of the PyBullet arm for readings ``q_enc``.

    ``direction`` (N, 6) is each joint's last direction of motion (from the
    readings by default, :func:`backlash_directions`). Returns the points and the
    holding torques (N, 6) (N·m) at the link angles.
    """
    from realitygap.robots.arm import ArmRobot, constant_transform
    from realitygap.robots.effects import (
        arm_base_compliance,
        arm_measurement_scale,
        arm_tool_offset,
    )
    from realitygap.robots.world import World

    body_params = reality.apply_params(params) if reality is not None else params
    tool = np.asarray(tool, dtype=float) + np.asarray(arm_tool_offset(reality))
    if direction is None:
        direction = backlash_directions(q_enc)
    world = World()
    try:
        robot = ArmRobot(world, body_params)
        T_base_inv = np.linalg.inv(body_params.T_world_base)
        last = constant_transform(body_params.mdh, 5)
        pts = np.empty((q_enc.shape[0], 3))
        taus = np.empty((q_enc.shape[0], 6))
        for k, (q, dirn) in enumerate(zip(q_enc, direction)):
            q_link = robot.link_target(q, dirn)
            robot.set_link_angles(q_link)
            F = T_base_inv @ robot.link_pose("link6") @ last
            pts[k] = F[:3, :3] @ tool + F[:3, 3]
            taus[k] = robot.gravity_torques(q_link)
        k_tilt = arm_base_compliance(reality)
        if k_tilt != 0.0:
            pts = base_tilt(pts[None], params.mdh, q_enc, taus[:, 1], [k_tilt])[0]
        return pts * arm_measurement_scale(reality), taus
    finally:
        world.close()


# --------------------------------------------------------------------------- pose sets
def probe_poses(name: str, table: MDHTable, n: int = 40) -> FloatArray:
    """The joint readings (n, 6) of a pose set of :data:`ARM_PROBE_SETS` (deterministic)."""
    if name not in ARM_PROBE_SETS:
        raise ValueError(f"unknown arm pose set {name!r}; known: {', '.join(ARM_PROBE_SETS)}")
    rng = np.random.default_rng(sum(ord(c) for c in name))
    q = rng.uniform(-math.pi, math.pi, (n, 6))
    if name == "outstretched_poses":
        q[:, 1] = rng.choice([-0.15, -math.pi + 0.15], n) + rng.normal(0, 0.1, n)
        q[:, 2] = rng.normal(0.0, 0.15, n)
    elif name == "approach_reversals":
        # P - δ, P (from below), P + δ, P (from above): one window per pose
        base = q[: max(n // POSES_PER_WINDOW, 1)]
        q = np.stack([base - 0.2, base, base + 0.2, base], axis=1).reshape(-1, 6)
    elif name == "wrist_sweep":
        q[:, :3] = (0.3, -1.2, 1.2)
    elif name == "base_sweep":
        postures = np.array([[-1.0, 1.2], [-0.5, 0.6], [-1.6, 1.8], [-0.2, 0.3]])
        q[:, 1:3] = postures[np.arange(n) % 4]
    return q


# --------------------------------------------------------------------------- recording
def sample_arm_poses(
    robot: Any, rng: np.random.Generator, n: int, max_tries: int = 50_000
) -> FloatArray:
    """``n`` random collision-free joint commands (n, 6) of a PyBullet arm, from ``rng``.

    Shoulder above the horizontal, elbow anywhere but fully folded, wrist free;
    configurations that collide (with the arm itself or the scenery) are drawn
    again.
    """
    out: list[FloatArray] = []
    for _ in range(max_tries):
        q = rng.uniform(-math.pi, math.pi, 6)
        q[1] = rng.uniform(-math.pi, 0.0)
        q[2] = rng.uniform(-2.6, 2.6)
        if not robot.collides_at(q):
            out.append(q)
            if len(out) == n:
                return np.asarray(out)
    raise RuntimeError(f"found only {len(out)} of {n} collision-free poses in {max_tries} draws")


def record_arm_log(
    reality: Any,
    rng: np.random.Generator,
    n_poses: int,
    *,
    params: Any = None,
    tool: npt.ArrayLike = (0.0, 0.05, 0.1),
    tracker_noise: float = 2e-5,
    name: str = "arm",
) -> Log:
    """Measure ``n_poses`` random poses of the PyBullet arm ``reality`` with a laser tracker.

    The arm (nominal ``params`` with the effects of ``reality`` built in) moves
    pose to pose through its servo (:meth:`~realitygap.robots.arm.ArmRobot.move_to`,
    so backlash follows the real order of moves and compliance sags under the
    real holding torque); at each pose the encoders are read (noise,
    quantisation) and the tool point ``tool`` (flange frame, m) is measured in
    the world with isotropic Gaussian noise of ``tracker_noise`` (m) per axis.
    """
    from realitygap.robots.arm import ArmParams, ArmRobot, constant_transform
    from realitygap.robots.effects import (
        arm_base_compliance,
        arm_measurement_scale,
        arm_tool_offset,
    )
    from realitygap.robots.world import World

    nominal = params if params is not None else ArmParams()
    body = reality.apply_params(nominal) if reality is not None else nominal
    length, k_tilt = arm_measurement_scale(reality), arm_base_compliance(reality)
    tool = np.asarray(tool, dtype=float).reshape(3)
    measured = tool + np.asarray(arm_tool_offset(reality))
    world = World()
    try:
        robot = ArmRobot(world, body)
        poses = sample_arm_poses(robot, rng, n_poses)
        robot.reset(poses[0] - 0.05)
        last = constant_transform(body.mdh, 5)
        q_enc = np.empty((n_poses, 6))
        pts = np.empty((n_poses, 3))
        for k, q in enumerate(poses):
            res = robot.move_to(q)
            if not res.ok:
                raise RuntimeError(f"pose {k} could not be reached: {res.message}")
            q_enc[k] = robot.read_encoders(rng)
            F = robot.link_pose("link6") @ last
            p = F[:3, :3] @ measured + F[:3, 3]
            if k_tilt != 0.0:
                tau2 = robot.gravity_torques(robot.link_target(q))[1]
                p = base_tilt(p[None, None], nominal.mdh, q[None], np.array([tau2]), [k_tilt])[0, 0]
            pts[k] = length * p + rng.normal(0.0, tracker_noise, 3)
    finally:
        world.close()
    return Log(
        t=np.arange(n_poses, dtype=float),
        channels={"joints": q_enc, "tool_pos": pts},
        meta={
            "robot": "arm",
            "name": name,
            "params": arm_params_to_meta(nominal),
            "tool": tool.tolist(),
            "tool_noise_m": float(tracker_noise),
        },
        source=name,
    )
