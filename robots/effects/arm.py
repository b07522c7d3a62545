"""Effects of the 6-DOF arm (``realitygap/ArmCalib-v0``).

Each effect is realised on :class:`~realitygap.robots.arm.ArmParams`: a body
with other MDH parameters or camera mount, a servo with compliance or backlash,
other encoder gains or camera intrinsics, or another measured tool point. The
blind ranges are realistic magnitudes: joint offsets ~0.1°, lengths ~0.5 mm,
twists ~0.05°, sag of 0.3–1.5 mrad at 30 N·m, play ≤ 1 mrad, encoder scale
≤ 0.1 %.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from realitygap.robots.effects.base import (
    BlindRange,
    Channel,
    Effect,
    ParamSpec,
    Reality,
    Stage,
    register_effect,
)


def _arm_mdh_delta(params: Any, deltas: Mapping[str, float]) -> Any:
    """``params`` with MDH parameters shifted by ``{name: delta}`` (m or rad)."""
    table = params.mdh
    cur = table.param_dict()
    names = [n for n, v in deltas.items() if v != 0.0]
    if not names:
        return params
    return params.replace(mdh=table.with_params([cur[n] + deltas[n] for n in names], names))


@register_effect
class ArmJointOffset(Effect):
    name = "arm_joint_offset"
    robot = "arm"
    stage = Stage.BODY
    observed_in = (Channel.CAMERA_POSE, Channel.TOOL_DIST)
    description = (
        "Joint zero offsets: the encoder's zero is not where the kinematic model puts it "
        "(mastering error). Realised as the MDH offsets theta_i of the arm's body."
    )
    specs = tuple(
        ParamSpec(f"dtheta{k}", "rad", 0.0, -0.01, 0.01, f"zero offset of joint {k}")
        for k in range(1, 7)
    )
    # joint 1's offset is invisible to tool-point distances: left at nominal
    blind = tuple(BlindRange(f"dtheta{k}", 5e-4, 2.5e-3, True) for k in range(2, 7))

    def apply_params(self, params: Any) -> Any:
        return _arm_mdh_delta(params, {f"theta{k}": self[f"dtheta{k}"] for k in range(1, 7)})


@register_effect
class ArmLinkLength(Effect):
    name = "arm_link_length"
    robot = "arm"
    stage = Stage.BODY
    observed_in = (Channel.CAMERA_POSE, Channel.TOOL_DIST)
    description = (
        "Link lengths and offsets differ from the data sheet (machining, assembly): the "
        "non-zero MDH lengths d1, a2, a3, d4, d5, d6. Realised as a body with other links."
    )
    specs = tuple(
        ParamSpec(f"d{nm}", "m", 0.0, -0.005, 0.005, f"error of MDH length {nm}")
        for nm in ("d1", "a2", "a3", "d4", "d5", "d6")
    )
    # d1 is invisible to tool-point distances: left at nominal
    blind = tuple(BlindRange(nm, 2e-4, 1e-3, True) for nm in ("da2", "da3", "dd4", "dd5", "dd6"))

    def apply_params(self, params: Any) -> Any:
        return _arm_mdh_delta(
            params, {nm: self[f"d{nm}"] for nm in ("d1", "a2", "a3", "d4", "d5", "d6")}
        )


@register_effect
class ArmParallelTwist(Effect):
    name = "arm_parallel_twist"
    robot = "arm"
    stage = Stage.BODY
    observed_in = (Channel.CAMERA_POSE, Channel.TOOL_DIST)
    description = (
        "The nominally parallel axes of joints 2, 3 and 4 are tilted against each other: about "
        "the common normal's y axis (Hayati twist beta, the case classical DH cannot describe) "
        "and about the common normal itself (twist alpha). Realised as a body whose joint 3 and "
        "4 axes are tilted."
    )
    specs = (
        ParamSpec("beta2", "rad", 0.0, -0.005, 0.005, "tilt of axis 3 against axis 2 about y"),
        ParamSpec("beta3", "rad", 0.0, -0.005, 0.005, "tilt of axis 4 against axis 3 about y"),
        ParamSpec("dalpha2", "rad", 0.0, -0.005, 0.005, "tilt of axis 3 against axis 2 about x"),
        ParamSpec("dalpha3", "rad", 0.0, -0.005, 0.005, "tilt of axis 4 against axis 3 about x"),
    )
    blind = tuple(
        BlindRange(nm, 3e-4, 1.5e-3, True) for nm in ("beta2", "beta3", "dalpha2", "dalpha3")
    )

    def apply_params(self, params: Any) -> Any:
        return _arm_mdh_delta(
            params,
            {
                "beta2": self["beta2"],
                "beta3": self["beta3"],
                "alpha2": self["dalpha2"],
                "alpha3": self["dalpha3"],
            },
        )


@register_effect
class ArmTwistError(Effect):
    name = "arm_twist_error"
    robot = "arm"
    stage = Stage.BODY
    observed_in = (Channel.CAMERA_POSE, Channel.TOOL_DIST)
    description = (
        "The right angles between the non-parallel axes are not exact (twists alpha1, alpha4, "
        "alpha5). Realised as a body with tilted joint axes."
    )
    specs = tuple(
        ParamSpec(f"dalpha{k}", "rad", 0.0, -0.005, 0.005, f"twist error of row {k}")
        for k in (1, 4, 5)
    )
    blind = tuple(BlindRange(f"dalpha{k}", 3e-4, 1.5e-3, True) for k in (1, 4, 5))

    def apply_params(self, params: Any) -> Any:
        return _arm_mdh_delta(params, {f"alpha{k}": self[f"dalpha{k}"] for k in (1, 4, 5)})


@register_effect
class ArmJointCompliance(Effect):
    name = "arm_joint_compliance"
    robot = "arm"
    stage = Stage.DRIVE
    observed_in = (Channel.CAMERA_POSE, Channel.TOOL_DIST)
    description = (
        "Elastic gearboxes: the links of the gravity-loaded joints 2, 3, 4 sag by compliance x "
        "gravity torque while the motor-side encoders read the command. Realised by the servo: "
        "the link settles at command - c * tau_g(q), tau_g the holding torque (PyBullet inverse "
        "dynamics of the body)."
    )
    specs = tuple(
        ParamSpec(f"c{k}", "rad/(N*m)", 0.0, 0.0, 5e-5, f"compliance of joint {k}")
        for k in (2, 3, 4)
    )
    # wrist 1 carries almost no gravity torque: its compliance stays nominal
    blind = (BlindRange("c2", 1e-5, 4e-5, False), BlindRange("c3", 1e-5, 4e-5, False))

    def apply_params(self, params: Any) -> Any:
        c = list(params.joint_compliance)
        for k in (2, 3, 4):
            c[k - 1] = self[f"c{k}"]
        return params.replace(joint_compliance=tuple(c))


@register_effect
class ArmBacklash(Effect):
    name = "arm_backlash"
    robot = "arm"
    stage = Stage.DRIVE
    observed_in = (Channel.CAMERA_POSE, Channel.TOOL_DIST)
    description = (
        "Gear play: the link trails the motor by half the play in the direction of the last "
        "move, so the same reading gives two link angles. Realised by the servo model."
    )
    specs = tuple(
        ParamSpec(f"b{k}", "rad", 0.0, 0.0, 2e-3, f"full play of joint {k}") for k in range(1, 7)
    )
    blind = tuple(BlindRange(f"b{k}", 2e-4, 1e-3, False) for k in range(1, 7))

    def apply_params(self, params: Any) -> Any:
        return params.replace(backlash=tuple(self[f"b{k}"] for k in range(1, 7)))


@register_effect
class ArmEncoderScale(Effect):
    name = "arm_encoder_scale"
    robot = "arm"
    stage = Stage.SENSOR
    observed_in = (Channel.CAMERA_POSE, Channel.TOOL_DIST)
    description = (
        "Joint encoders (or the gear ratios the controller assumes) are off by a factor: the "
        "reading is s times the motor angle. Realised between the joints and their readings."
    )
    specs = tuple(
        ParamSpec(f"s{k}", "1", 1.0, 0.998, 1.002, f"reading / motor angle of joint {k}")
        for k in range(1, 7)
    )
    blind = tuple(BlindRange(f"s{k}", 2e-4, 1e-3, True) for k in range(1, 7))

    def apply_params(self, params: Any) -> Any:
        return params.replace(encoder_scale=tuple(self[f"s{k}"] for k in range(1, 7)))


@register_effect
class ArmToolOffset(Effect):
    name = "arm_tool_offset"
    robot = "arm"
    stage = Stage.TOOL
    observed_in = (Channel.TOOL_DIST,)
    description = (
        "The measured tool point (a tracker probe, a TCP) is not where its nominal definition "
        "puts it on the flange: a mounting or tool-length error. Realised by moving the point "
        "the instrument measures, in the flange frame."
    )
    specs = (
        ParamSpec("dx", "m", 0.0, -0.02, 0.02, "offset along flange x"),
        ParamSpec("dy", "m", 0.0, -0.02, 0.02, "offset along flange y"),
        ParamSpec("dz", "m", 0.0, -0.02, 0.02, "offset along flange z (tool length)"),
    )
    blind = tuple(BlindRange(nm, 3e-4, 3e-3, True) for nm in ("dx", "dy", "dz"))

    def tool_offset(self) -> tuple[float, float, float]:
        """The offset of the measured point in the flange frame (m)."""
        return (self["dx"], self["dy"], self["dz"])


def arm_tool_offset(reality: Reality | None) -> tuple[float, float, float]:
    """Total tool-point offset (flange frame, m) of the :class:`ArmToolOffset` effects in
    ``reality`` (zero without)."""
    total = [0.0, 0.0, 0.0]
    for e in reality.effects if reality is not None else ():
        if isinstance(e, ArmToolOffset):
            total = [a + b for a, b in zip(total, e.tool_offset())]
    return (total[0], total[1], total[2])


@register_effect
class ArmHandEyeError(Effect):
    name = "arm_handeye_error"
    robot = "arm"
    stage = Stage.CAMERA
    observed_in = (Channel.CAMERA_POSE,)
    description = (
        "The flange camera is mounted off its nominal place: translation (flange frame) and a "
        "small rotation (rotation vector in the camera frame). Realised by moving the camera "
        "link of the body."
    )
    specs = (
        ParamSpec("dx", "m", 0.0, -0.01, 0.01, "offset along flange x"),
        ParamSpec("dy", "m", 0.0, -0.01, 0.01, "offset along flange y"),
        ParamSpec("dz", "m", 0.0, -0.01, 0.01, "offset along flange z"),
        ParamSpec("drx", "rad", 0.0, -0.05, 0.05, "rotation about the camera x axis"),
        ParamSpec("dry", "rad", 0.0, -0.05, 0.05, "rotation about the camera y axis"),
        ParamSpec("drz", "rad", 0.0, -0.05, 0.05, "rotation about the optical axis"),
    )

    def apply_params(self, params: Any) -> Any:
        from scipy.spatial.transform import Rotation

        cam = params.camera
        R = Rotation.from_euler("xyz", cam.mount_rpy) * Rotation.from_rotvec(
            [self["drx"], self["dry"], self["drz"]]
        )
        xyz = tuple(v + d for v, d in zip(cam.mount_xyz, (self["dx"], self["dy"], self["dz"])))
        rpy = tuple(float(v) for v in R.as_euler("xyz"))
        return params.replace(camera=cam.replace(mount_xyz=xyz, mount_rpy=rpy))


@register_effect
class ArmCameraIntrinsics(Effect):
    name = "arm_camera_intrinsics"
    robot = "arm"
    stage = Stage.CAMERA
    observed_in = (Channel.CAMERA_POSE,)
    description = (
        "The flange camera's intrinsics differ from the ones the measurement uses: focal "
        "length scale, principal point and radial distortion. Realised in the image formation."
    )
    specs = (
        ParamSpec("f_scale", "1", 1.0, 0.97, 1.03, "true / nominal focal length"),
        ParamSpec("dcx", "px", 0.0, -10.0, 10.0, "principal point offset, x"),
        ParamSpec("dcy", "px", 0.0, -10.0, 10.0, "principal point offset, y"),
        ParamSpec("k1", "1", 0.0, -0.3, 0.3, "added radial distortion k1"),
        ParamSpec("k2", "1", 0.0, -0.2, 0.2, "added radial distortion k2"),
    )

    def apply_params(self, params: Any) -> Any:
        cam = params.camera
        dist = list(cam.dist) + [0.0] * (5 - len(cam.dist))
        dist[0] += self["k1"]
        dist[1] += self["k2"]
        return params.replace(
            camera=cam.replace(
                fx=cam.fx * self["f_scale"],
                fy=cam.fy * self["f_scale"],
                cx=cam.cx + self["dcx"],
                cy=cam.cy + self["dcy"],
                dist=tuple(dist),
            )
        )
