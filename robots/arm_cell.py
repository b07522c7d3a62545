"""The arm's calibration cell: table, pedestal, coded board and the flange camera.

The coded board (:class:`~realitygap.estimators.arm.coded_board.CodedBoard`)
lies on the table as a texture on a thin box (:func:`add_coded_board`). The
flange camera (:class:`FlangeCamera`) captures it either rendered by PyBullet's
TinyRenderer (``"image"``) or with
:func:`~realitygap.estimators.arm.coded_board.render_board_image` from the true
camera pose (``"fast"``); both give an 8-bit grey image for the same downstream
measurement. A third mode, ``"geometric"``, renders nothing and reports the
board corners a detector would find (projected with the true camera, plus
pixel noise). :func:`build_arm_scene` puts the arm (:mod:`realitygap.robots.arm`)
and the board in a world.

Frames: world z up; the table top is ``z = 0``.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pybullet as p

from realitygap.estimators.arm.coded_board import CodedBoard, render_board_image
from realitygap.robots.arm import ArmParams, ArmRobot
from realitygap.robots.sensors import SensorMode
from realitygap.robots.world import Primitive, Shape, World

FloatArray = npt.NDArray[np.float64]
UInt8Array = npt.NDArray[np.uint8]

__all__ = [
    "BoardPlacement",
    "FlangeCamera",
    "add_coded_board",
    "build_arm_scene",
]


# =========================================================================== board
@dataclass(frozen=True)
class BoardPlacement:
    """Where the coded board lies: printed face up on the table.

    The board frame (OpenCV pattern convention, see
    :mod:`~realitygap.estimators.arm.coded_board`) has x along world
    :math:`R_z(\\psi) e_x`, y along world :math:`-R_z(\\psi) e_y` and z pointing
    down into the board. Its origin (the outer corner of cell ``(0, 0)``) lies
    at ``origin_xy`` on the board's top surface.

    Attributes
    ----------
    origin_xy : (float, float)
        World x, y of the board origin (m).
    yaw : float
        :math:`\\psi` (rad).
    thickness : float
        Board thickness (m); the printed face is at ``z = thickness``.
    """

    origin_xy: tuple[float, float] = (-1.12, 0.5)
    yaw: float = 0.0
    thickness: float = 0.005

    def T_world_board(self) -> FloatArray:
        """Pose (4, 4) of the board frame in the world (m)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        T = np.eye(4)
        T[:3, :3] = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])
        T[:3, 3] = [self.origin_xy[0], self.origin_xy[1], self.thickness]
        return T


def add_coded_board(
    world: World, board: CodedBoard, placement: BoardPlacement, px_per_cell: int = 32
) -> int:
    """Add the board to ``world``: a thin box whose top face carries the printed code.

    The printed face is a textured quad (two triangles with explicit texture
    coordinates) on top of the box; texel ``(v, u)`` of :meth:`CodedBoard.texture`
    lands at board coordinates ``((u + ½) s, (v + ½) s)``, ``s = cell_size / px_per_cell``.

    Returns
    -------
    int
        PyBullet body id (also ``world.bodies["board"]``).
    """
    c = world.bullet
    side = board.side
    T = placement.T_world_board()
    half_t = placement.thickness / 2.0
    # box centre in the world
    centre_board = np.array([side / 2.0, side / 2.0, 0.0, 1.0])
    centre = (T @ centre_board)[:3]
    centre[2] = half_t
    yaw = placement.yaw
    col = c.createCollisionShape(p.GEOM_BOX, halfExtents=[side / 2, side / 2, half_t])
    # quad in the body frame (body frame = world axes turned by yaw, at the box centre)
    h = side / 2.0
    z = half_t
    # board x = body x, board y = -body y; board (0, 0) at body (-h, +h)
    verts = [[-h, h, z], [h, h, z], [h, -h, z], [-h, -h, z]]
    # texture: u along board x, v along board y; PyBullet's v runs bottom-up in the image
    uvs = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]]
    vis = c.createVisualShape(
        p.GEOM_MESH,
        vertices=verts,
        indices=[0, 2, 1, 0, 3, 2],
        uvs=uvs,
        normals=[[0.0, 0.0, 1.0]] * 4,
        rgbaColor=[1, 1, 1, 1],
    )
    quat = c.getQuaternionFromEuler([0.0, 0.0, yaw])
    body = c.createMultiBody(0.0, col, vis, centre.tolist(), quat)
    tex = board.texture(px_per_cell)
    fd, path = tempfile.mkstemp(suffix=".png", prefix="coded_board_")
    os.close(fd)
    try:
        cv2.imwrite(path, np.ascontiguousarray(tex))
        tex_id = c.loadTexture(path)
    finally:
        os.unlink(path)
    c.changeVisualShape(body, -1, textureUniqueId=tex_id, rgbaColor=[1, 1, 1, 1])
    world.bodies["board"] = body
    return body


# =========================================================================== camera
class FlangeCamera:
    """The camera on the flange, rendering what it sees of the coded board.

    Parameters
    ----------
    robot : ArmRobot
        Carries the camera (its true mount and intrinsics are ``robot.params.camera``).
    board : CodedBoard
    placement : BoardPlacement
    """

    def __init__(self, robot: ArmRobot, board: CodedBoard, placement: BoardPlacement):
        self.robot = robot
        self.params = robot.params.camera
        self.board = board
        self.placement = placement
        self.T_world_board = placement.T_world_board()
        self._maps: tuple[Any, Any] | None = None
        self._corners = board.corner_positions()
        n = board.cells + 1
        k = np.arange(n * n)
        self._ids = np.column_stack([k // n, k % n]).astype(np.int64)

    def T_camera_board(self) -> FloatArray:
        """True board pose in the camera frame (4, 4) (m)."""
        return np.linalg.inv(self.robot.T_world_camera()) @ self.T_world_board

    def axis_hits_board(self, margin: float = 0.0) -> bool:
        """Whether the true optical axis meets the printed area (shrunk by ``margin`` m)."""
        T = np.linalg.inv(self.T_camera_board())  # camera in board
        z = T[:3, 2]
        if z[2] <= 1e-9:
            return False
        lam = -T[2, 3] / z[2]
        if lam <= 0:
            return False
        hit = T[:3, 3] + lam * z
        s = self.board.side
        return bool(margin <= hit[0] <= s - margin and margin <= hit[1] <= s - margin)

    def visible_corners(
        self, rng: np.random.Generator | None = None, margin_px: float = 3.0
    ) -> tuple[FloatArray, npt.NDArray[np.int64]]:
        """Board corners in view: pixel positions (k, 2) and board ids ``(row, col)`` (k, 2).

        Projected with the true pose, intrinsics and distortion; corners behind the
        camera, beyond ``far`` or within ``margin_px`` of the image border are left
        out; ``corner_noise_px`` Gaussian noise is added when ``rng`` is given.
        """
        cp = self.params
        T = self.T_camera_board()
        P = self._corners
        z = P @ T[2, :3] + T[2, 3]
        front = (z > cp.near) & (z < cp.far)
        ids = self._ids[front]
        if not np.any(front):
            return np.zeros((0, 2)), np.zeros((0, 2), dtype=np.int64)
        rvec = cv2.Rodrigues(T[:3, :3])[0]
        dist = np.zeros(5) if cp.dist_array is None else np.asarray(cp.dist, dtype=float)
        proj, _ = cv2.projectPoints(P[front], rvec, T[:3, 3].copy(), cp.K, dist)
        uv: FloatArray = np.asarray(proj, dtype=np.float64).reshape(-1, 2)
        m = margin_px
        inside = (
            (uv[:, 0] > m)
            & (uv[:, 1] > m)
            & (uv[:, 0] < cp.width - 1 - m)
            & (uv[:, 1] < cp.height - 1 - m)
        )
        uv, ids = uv[inside], ids[inside]
        if rng is not None and cp.corner_noise_px > 0:
            uv = uv + rng.normal(0.0, cp.corner_noise_px, uv.shape)
        return uv, ids

    def capture(self, mode: SensorMode | str, rng: np.random.Generator) -> UInt8Array:
        """One grey image (height, width) uint8 of the current view.

        ``"fast"``: :func:`render_board_image` from the true camera pose with the
        true intrinsics and distortion. ``"image"``: PyBullet TinyRenderer at
        ``supersample`` times the resolution, lens distortion applied by remapping,
        area-averaged to the sensor. Both then get blur and noise.
        """
        mode = SensorMode(mode)
        cp = self.params
        if mode is SensorMode.GEOMETRIC:
            raise ValueError("geometric capture gives corners, not an image: use visible_corners()")
        if mode is SensorMode.FAST:
            return render_board_image(
                self.board,
                cp.K,
                self.T_camera_board(),
                (cp.width, cp.height),
                cp.dist_array,
                supersample=cp.supersample,
                blur_sigma_px=cp.blur_sigma_px,
                noise_std=cp.noise_std,
                contrast=cp.contrast,
                rng=rng,
            )
        lo, hi = cp.contrast
        grey = lo + (hi - lo) / 255.0 * self._render_pybullet()
        if cp.blur_sigma_px > 0:
            grey = np.asarray(cv2.GaussianBlur(grey, (0, 0), cp.blur_sigma_px), dtype=np.float64)
        if cp.noise_std > 0:
            grey = grey + rng.normal(0.0, cp.noise_std, grey.shape)
        return np.clip(np.round(grey), 0, 255).astype(np.uint8)

    # ------------------------------------------------------------------ image mode
    def projection_matrix(self, scale: int = 1) -> list[float]:
        """OpenGL projection (column-major, 16) reproducing ``K`` at ``scale`` × resolution.

        OpenCV pixel centres are integers. TinyRenderer samples column ``i`` at
        window x = ``i`` and row ``r`` at window y = ``H - 1 - r`` (checked against the
        board measurement: no systematic reprojection offset remains).
        """
        cp = self.params
        W, H = cp.width * scale, cp.height * scale
        fx, fy = cp.fx * scale, cp.fy * scale
        cx, cy = (cp.cx + 0.5) * scale - 0.5, (cp.cy + 0.5) * scale - 0.5
        n, f = cp.near, cp.far
        P = np.zeros((4, 4))
        P[0, 0] = 2 * fx / W
        P[0, 2] = 1 - 2 * cx / W
        P[1, 1] = 2 * fy / H
        P[1, 2] = 2 * (cy + 1.0) / H - 1
        P[2, 2] = -(f + n) / (f - n)
        P[2, 3] = -2 * f * n / (f - n)
        P[3, 2] = -1.0
        return P.T.reshape(-1).tolist()

    def view_matrix(self) -> list[float]:
        """OpenGL view matrix (column-major, 16) of the true camera pose."""
        T = self.robot.T_world_camera() @ np.diag([1.0, -1.0, -1.0, 1.0])
        return np.linalg.inv(T).T.reshape(-1).tolist()

    def _render_pybullet(self) -> FloatArray:
        cp = self.params
        s = int(cp.supersample)
        W, H = cp.width * s, cp.height * s
        _, _, rgba, _, _ = self.world_client.getCameraImage(
            W,
            H,
            self.view_matrix(),
            self.projection_matrix(s),
            renderer=p.ER_TINY_RENDERER,
            shadow=0,
            lightDirection=[0.0, 0.0, 1.0],
            lightAmbientCoeff=0.75,
            lightDiffuseCoeff=0.25,
            lightSpecularCoeff=0.0,
        )
        img = np.asarray(rgba, dtype=np.uint8).reshape(H, W, 4)[..., :3]
        grey = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY).astype(np.float32)
        if cp.dist_array is None:
            if s == 1:
                return grey.astype(np.float64)
            return grey.reshape(cp.height, s, cp.width, s).mean(axis=(1, 3)).astype(np.float64)
        mx, my = self._distortion_maps()
        warped = cv2.remap(grey, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return warped.reshape(cp.height, s, cp.width, s).mean(axis=(1, 3)).astype(np.float64)

    @property
    def world_client(self) -> Any:
        return self.robot.world.bullet

    def _distortion_maps(self) -> tuple[Any, Any]:
        """For every sub-pixel sample of the distorted sensor: where it lies in the render."""
        if self._maps is None:
            cp = self.params
            s = int(cp.supersample)
            sub = (np.arange(s) + 0.5) / s - 0.5
            u = (np.arange(cp.width)[None, None, :, None] + sub[None, None, None, :]).astype(float)
            v = (np.arange(cp.height)[:, None, None, None] + sub[None, :, None, None]).astype(float)
            u, v = np.broadcast_arrays(u, v)
            pts = np.column_stack([u.reshape(-1), v.reshape(-1)]).reshape(-1, 1, 2)
            K_r = cp.K.copy()
            K_r[0, 0] *= s
            K_r[1, 1] *= s
            K_r[0, 2] = (cp.cx + 0.5) * s - 0.5
            K_r[1, 2] = (cp.cy + 0.5) * s - 0.5
            und = cv2.undistortPoints(
                pts,
                cp.K,
                np.asarray(cp.dist, dtype=float),
                P=K_r,
                criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10),
            ).reshape(cp.height * s, cp.width * s, 2)
            self._maps = (
                np.ascontiguousarray(und[..., 0], dtype=np.float32),
                np.ascontiguousarray(und[..., 1], dtype=np.float32),
            )
        return self._maps


# =========================================================================== scene
def build_arm_scene(
    world: World,
    params: ArmParams,
    board: CodedBoard,
    placement: BoardPlacement,
    textured: bool = True,
    px_per_cell: int = 32,
) -> tuple[ArmRobot, FlangeCamera]:
    """Table (floor at z = 0), pedestal, coded board and the arm with its camera.

    Parameters
    ----------
    world : World
        An empty world (it is reset).
    params : ArmParams
        The true arm.
    board, placement : CodedBoard, BoardPlacement
    textured : bool
        Load the board texture (needed for ``"image"`` capture only).
    px_per_cell : int
        Texture resolution of the printed board.
    """
    world.reset_simulation()
    world.add_floor(rgba=(0.45, 0.45, 0.45, 1.0))
    h = params.base_xyz[2]
    if h > 0.01:
        world.add_primitive(
            Primitive(
                "pedestal",
                Shape.CYLINDER,
                (params.base_xyz[0], params.base_xyz[1]),
                h - 0.002,
                radius=0.08,
            ),
            rgba=(0.3, 0.3, 0.32, 1.0),
        )
    if textured:
        add_coded_board(world, board, placement, px_per_cell)
    else:
        c = world.bullet
        side = board.side
        T = placement.T_world_board()
        centre = (T @ np.array([side / 2, side / 2, 0.0, 1.0]))[:3]
        centre[2] = placement.thickness / 2
        col = c.createCollisionShape(
            p.GEOM_BOX, halfExtents=[side / 2, side / 2, placement.thickness / 2]
        )
        quat = c.getQuaternionFromEuler([0.0, 0.0, placement.yaw])
        world.bodies["board"] = c.createMultiBody(0.0, col, -1, centre.tolist(), quat)
    robot = ArmRobot(world, params)
    return robot, FlangeCamera(robot, board, placement)
