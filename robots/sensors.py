"""Sensor models of the differential-drive robot.

Each sensor turns the simulated world into a measurement dataclass of
:mod:`realitygap.estimators.base`. Sensors run in one of two fidelities with the
same output types:

* ``SensorMode.IMAGE`` — the RGB-D camera is rendered by PyBullet's TinyRenderer
  and the planar scan is derived from the depth image, as on the real robot;
* ``SensorMode.FAST`` — no rendering; the scan is ray-cast analytically against
  the world's primitives in numpy (orders of magnitude faster, for RL).

All noise is drawn from a ``numpy.random.Generator`` handed down by the env.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from enum import Enum

import numpy as np
import numpy.typing as npt
import pybullet as p

from realitygap.core.jit import KERNELS, compiled
from realitygap.estimators.base import CameraIntrinsics, RGBDFrame, Scan
from realitygap.estimators.scan import scan_angles
from realitygap.robots.diffdrive import DiffDriveRobot, RGBDCameraParams
from realitygap.robots.raycast import cast_rotated_beams, cast_rotated_beams_compiled

FloatArray = npt.NDArray[np.float64]


class SensorMode(str, Enum):
    """Sensor fidelity of every robot: rendered images or fast geometry.

    The same estimators run downstream of every mode; the modes differ in how the
    sensors form their output.
    """

    IMAGE = "image"
    """PyBullet TinyRenderer frames, processed as a real camera's would be."""
    FAST = "fast"
    """No PyBullet rendering: the wheeled robot's scan is ray-cast in numpy, the
    climber's camera reports its motion from the true motion with noise, the arm's
    flange camera draws the board alone from the true camera pose."""
    GEOMETRIC = "geometric"
    """No image at all: the arm's flange camera reports the board corners a detector
    would find (pixel positions with noise and their board ids)."""


def check_sensor_mode(value: str | SensorMode, accepted: tuple[SensorMode, ...]) -> SensorMode:
    """``value`` as a :class:`SensorMode`, or a ``ValueError`` naming the ``accepted`` modes."""
    for mode in accepted:
        if mode == value:
            return mode
    raise ValueError(f"sensor_mode must be one of {[m.value for m in accepted]}, got {value!r}")


def depth_sigma(z: npt.ArrayLike, params: RGBDCameraParams) -> FloatArray:
    """Depth noise standard deviation in m at range ``z`` m: ``a + b z²``."""
    z = np.asarray(z, dtype=float)
    return params.depth_noise_a + params.depth_noise_b * z * z


def _check_size(size: object) -> tuple[int, int]:
    """``size`` as ``(width, height)`` in pixels, each a whole number in [2, 4096]."""
    values = list(size) if isinstance(size, (tuple, list)) else []
    if len(values) != 2 or not all(
        isinstance(v, (int, np.integer)) and not isinstance(v, bool) and 2 <= v <= 4096
        for v in values
    ):
        raise ValueError(
            f"size must be (width, height) in pixels, two whole numbers in [2, 4096], got {size!r}"
        )
    return int(values[0]), int(values[1])


class RGBDCamera:
    """Kinect-V2-like camera rendered with PyBullet's TinyRenderer.

    Depth is the metric z-depth along the optical axis with range-dependent
    Gaussian noise; pixels outside ``[range_min, range_max]`` are ``nan``.
    """

    NEAR, FAR = 0.1, 12.0
    TINY_RENDERER_ROW_SHIFT = 1.0
    """Rows (px) by which TinyRenderer's picture sits above the pinhole projection."""

    def __init__(self, robot: DiffDriveRobot, params: RGBDCameraParams):
        self.robot = robot
        self.params = params
        self.intrinsics = params.intrinsics()
        self._projections: dict[tuple[int, int], tuple[list[float], CameraIntrinsics]] = {}
        self._proj, _ = self._projection(params.width, params.height)

    def _projection(self, width: int, height: int) -> tuple[list[float], CameraIntrinsics]:
        """OpenGL projection (column-major list) and pinhole intrinsics of a ``width`` ×
        ``height`` picture with the camera's field of view (cached per size)."""
        key = (int(width), int(height))
        if key not in self._projections:
            intr = (
                self.intrinsics
                if key == (self.params.width, self.params.height)
                else replace(self.params, width=key[0], height=key[1]).intrinsics()
            )
            w, h = key
            n, f = self.NEAR, self.FAR
            # OpenGL projection for a pinhole camera with centred principal point. TinyRenderer
            # writes image row r from its framebuffer row h - 1 - r, which puts the scene one
            # row higher than the pinhole model with cy = h / 2 that the estimators use (a
            # 0.28° pitch at 240 rows); the z-term in row 1 shifts the picture down by
            # TINY_RENDERER_ROW_SHIFT rows so that rendering and intrinsics agree.
            proj = np.array(
                [
                    [2 * intr.fx / w, 0, 0, 0],
                    [0, 2 * intr.fy / h, 2 * self.TINY_RENDERER_ROW_SHIFT / h, 0],
                    [0, 0, -(f + n) / (f - n), -2 * f * n / (f - n)],
                    [0, 0, -1, 0],
                ]
            )
            self._projections[key] = (proj.T.reshape(-1).tolist(), intr)
        return self._projections[key]

    def render(
        self, t: float, rng: np.random.Generator, size: tuple[int, int] | None = None
    ) -> RGBDFrame:
        """Render one frame at the camera's current (true) pose.

        Parameters
        ----------
        t : time stamp of the frame, s.
        rng : generator of the depth noise.
        size : ``(width, height)`` in pixels of a picture with the camera's field of view
            (its intrinsics scale with it); default the camera's own resolution. A consumer
            that needs less than a full frame (the planar scan) renders only what it needs:
            TinyRenderer's time grows with the pixel count.
        """
        if size is None:
            w, h = self.params.width, self.params.height
        else:
            w, h = _check_size(size)
        proj, intrinsics = self._projection(w, h)
        T = self.robot.T_world_camera()
        # OpenGL camera looks along -z with y up; optical frame is z forward, y down
        T_gl = T @ np.diag([1.0, -1.0, -1.0, 1.0])
        view = np.linalg.inv(T_gl).T.reshape(-1).tolist()
        _, _, rgba, zbuf, _ = self.robot.world.bullet.getCameraImage(
            w,
            h,
            viewMatrix=view,
            projectionMatrix=proj,
            renderer=p.ER_TINY_RENDERER,
            flags=p.ER_NO_SEGMENTATION_MASK,
        )
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[..., :3].copy()
        zb = np.asarray(zbuf, dtype=np.float64).reshape(h, w)
        n, f = self.NEAR, self.FAR
        depth = f * n / (f - (f - n) * zb)
        depth = depth + rng.normal(0.0, 1.0, depth.shape) * depth_sigma(depth, self.params)
        invalid = (depth < self.params.range_min) | (depth > self.params.range_max) | (zb >= 1.0)
        depth[invalid] = np.nan
        return RGBDFrame(t=t, rgb=rgb, depth=depth.astype(np.float32), intrinsics=intrinsics)


class PlanarScanner:
    """The camera's "laser-like" planar scan: nearest obstacle per bearing.

    Bearings span the camera's horizontal field of view around its mounting
    yaw; ranges are measured from the base origin in the base frame.
    """

    def __init__(
        self,
        robot: DiffDriveRobot,
        params: RGBDCameraParams,
        n_beams: int = 64,
        z_band: tuple[float, float] = (0.05, 0.45),
    ):
        if n_beams < 2:
            raise ValueError(f"n_beams must be at least 2, got {n_beams}")
        self.robot = robot
        self._world = robot.world
        self.params = params
        self.n_beams = int(n_beams)
        self.z_band = z_band
        self.angles = params.mount_yaw + scan_angles(self.n_beams, math.radians(params.hfov_deg))
        self._cos = np.cos(self.angles)
        self._sin = np.sin(self.angles)
        mx, my = params.mount_xyz[0], params.mount_xyz[1]
        self._along_beam_offset = mx * self._cos + my * self._sin
        # (2, 1, n_beams): the layout of PrimitiveArrays.cast_directions
        self._cos_cos = np.stack([self._cos, self._cos])[:, None, :]
        self._sin_sin = np.stack([self._sin, self._sin])[:, None, :]
        self._rot_cs = np.zeros((2, 1, 1))  # (cos θ, sin θ) of the base's heading
        self._rot_sc = np.zeros((2, 1, 1))  # (-sin θ, cos θ)
        self._mount_xy = (float(params.mount_xyz[0]), float(params.mount_xyz[1]))
        self._dirs = np.empty((2, 1, self.n_beams))  # work arrays of scan_fast
        self._dirs_sin = np.empty((2, 1, self.n_beams))
        self._sigma = np.empty(self.n_beams)
        self._noise = np.empty(self.n_beams)
        self._seen = np.empty(self.n_beams, dtype=bool)

    def scan_fast(
        self,
        t: float,
        rng: np.random.Generator,
        pose: Sequence[float] | None = None,
    ) -> Scan:
        """Analytic ray cast against the world's primitives, with depth noise.

        ``pose`` is the base's true planar pose ``(x, y, θ)`` (m, m, rad) when the caller
        has just read it (:meth:`DiffDriveRobot.pose2d`); default: read here.
        """
        x, y, th = self.robot.pose2d().tolist() if pose is None else pose
        c, s = math.cos(th), math.sin(th)
        P = self.params
        mx, my = self._mount_xy
        # beams leave the camera's optical centre; ranges are reported from the base origin
        ox, oy = x + c * mx - s * my, y + s * mx + c * my
        if _noisy_scan_compiled is not None and KERNELS.on:
            # one compiled call: the same operations as below, beam by beam
            arrays = self._world.scenery_arrays
            noise = rng.standard_normal(out=self._noise)
            ranges = np.empty(self.n_beams)
            _noisy_scan_compiled(
                ox,
                oy,
                c,
                s,
                self._cos,
                self._sin,
                arrays.box_rows,
                arrays.cyl_rows,
                P.range_max,
                self._along_beam_offset,
                noise,
                P.depth_noise_a,
                P.depth_noise_b,
                P.range_min,
                ranges,
            )
            return Scan(t, self.angles.copy(), ranges, P.range_min, P.range_max)
        # world-frame beam directions, both components in one pass: rows (dx, dy) of
        # (c·cos, s·cos) + (-s·sin, c·sin)
        cs, sc = self._rot_cs, self._rot_sc
        cs[0, 0, 0], cs[1, 0, 0], sc[0, 0, 0], sc[1, 0, 0] = c, s, -s, c
        d = np.multiply(self._cos_cos, cs, out=self._dirs)
        d += np.multiply(self._sin_sin, sc, out=self._dirs_sin)
        ranges = self._world.scenery_arrays.cast_directions(ox, oy, d, P.range_max)
        ranges += self._along_beam_offset
        sigma = np.multiply(ranges, P.depth_noise_b, out=self._sigma)
        sigma *= ranges
        sigma += P.depth_noise_a
        noise = rng.standard_normal(out=self._noise)
        # where nothing was seen (inf) the range stays inf: its noise is left unscaled there
        # (inf + finite noise is inf, as inf + 0)
        np.multiply(noise, sigma, out=noise, where=np.isfinite(sigma, out=self._seen))
        ranges += noise
        np.maximum(ranges, P.range_min, out=ranges)
        return Scan(t, self.angles.copy(), ranges, P.range_min, P.range_max)

    @property
    def render_size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels of the depth picture a scan needs on its own: two
        columns per beam (at most the camera's resolution) and half the rows of the camera's
        aspect ratio. Beams bin pixels by bearing, so the columns set the scan's resolution;
        the rows need only sample the height band (at 8 m a row of 48 spans 0.19 m of a
        0.4 m band), and TinyRenderer's time grows with the pixel count."""
        w = min(self.params.width, 2 * self.n_beams)
        h = max(2, round(w * self.params.height / self.params.width / 2))
        return w, h

    def scan_rendered(self, camera: RGBDCamera, t: float, rng: np.random.Generator) -> Scan:
        """Scan from a depth picture rendered for it alone at :attr:`render_size` (image
        fidelity between camera frames: the camera's full frame is not due)."""
        return self.scan_from_frame(camera.render(t, rng, size=self.render_size))

    def scan_from_frame(self, frame: RGBDFrame) -> Scan:
        """Scan derived from a rendered depth image (image fidelity)."""
        from realitygap.estimators.scan import scan_from_depth

        return scan_from_depth(
            frame.depth,
            frame.intrinsics,
            self.params.T_base_camera(),
            z_band=self.z_band,
            n_beams=self.n_beams,
            fov=math.radians(self.params.hfov_deg),
            range_max=self.params.range_max,
            depth_min=self.params.range_min,
            depth_noise=(self.params.depth_noise_a, self.params.depth_noise_b),
            t=frame.t,
        )


_cast = (
    cast_rotated_beams_compiled if cast_rotated_beams_compiled is not None else cast_rotated_beams
)


def noisy_scan(
    ox: float,
    oy: float,
    c: float,
    s: float,
    beam_cos: FloatArray,
    beam_sin: FloatArray,
    box_rows: FloatArray,
    cyl_rows: FloatArray,
    range_max: float,
    along_beam_offset: FloatArray,
    noise: FloatArray,
    noise_a: float,
    noise_b: float,
    range_min: float,
    out: FloatArray,
) -> None:
    """Loop form of :meth:`PlanarScanner.scan_fast`'s arithmetic, into ``out`` (n,) (m).

    :func:`~realitygap.robots.raycast.cast_rotated_beams` from the optical centre
    ``(ox, oy)`` (m), plus ``along_beam_offset`` (n,) (m, ranges from the base origin),
    plus standard normal draws ``noise`` (n,) scaled by the depth noise
    ``noise_a + noise_b · r²`` (m) where that is finite, clamped below at ``range_min`` (m).
    """
    _cast(ox, oy, c, s, beam_cos, beam_sin, box_rows, cyl_rows, range_max, out)
    for j in range(out.shape[0]):
        r = out[j] + along_beam_offset[j]
        sigma = r * noise_b * r + noise_a
        r = r + (noise[j] * sigma if math.isfinite(sigma) else noise[j])
        out[j] = r if (r >= range_min or r != r) else range_min


_noisy_scan_compiled = compiled(noisy_scan)
