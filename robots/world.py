"""The simulated world: one PyBullet client per environment instance.

:class:`World` owns a :class:`pybullet_utils.bullet_client.BulletClient` in
``DIRECT`` mode (never the global client), the physics step and sub-steps, and
the static scenery: a floor, walls and box / cylinder obstacles. Every piece of
scenery is also kept as an analytic :class:`Primitive`, so that sensors in the
fast geometric mode can ray-cast against it in numpy instead of asking the
physics engine.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from enum import Enum
from typing import Any, TypeVar

import cv2
import numpy as np
import numpy.typing as npt
import pybullet as p
from pybullet_utils import bullet_client

from realitygap.robots.raycast import PrimitiveArrays
from realitygap.robots.textures import SurfaceKind, surface_texture

FloatArray = npt.NDArray[np.float64]


class Shape(str, Enum):
    """Analytic shape of a piece of static scenery."""

    BOX = "box"
    CYLINDER = "cylinder"


@dataclass(frozen=True)
class Primitive:
    """A static obstacle standing on the floor.

    ``center`` (x, y) m and ``yaw`` rad in the world frame; a box has
    ``half_extents`` (hx, hy) m, a cylinder ``radius`` m; ``height`` m.
    """

    name: str
    shape: Shape
    center: tuple[float, float]
    height: float
    yaw: float = 0.0
    half_extents: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0

    def footprint_distance(self, xy: npt.ArrayLike) -> FloatArray:
        """Signed distance (m) from points ``xy`` (..., 2) to the footprint (negative inside)."""
        pts = np.asarray(xy, dtype=float) - np.asarray(self.center)
        if self.shape is Shape.CYLINDER:
            return np.linalg.norm(pts, axis=-1) - self.radius
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        local = np.stack(
            [c * pts[..., 0] + s * pts[..., 1], -s * pts[..., 0] + c * pts[..., 1]], -1
        )
        q = np.abs(local) - np.asarray(self.half_extents)
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        inside = np.minimum(np.max(q, axis=-1), 0.0)
        return outside + inside


def ray_cast_primitives(
    origin_xy: npt.ArrayLike,
    directions: npt.ArrayLike,
    primitives: list[Primitive],
    range_max: float,
) -> FloatArray:
    """Distance along each planar ray to the first primitive it hits.

    Parameters
    ----------
    origin_xy : (2,) ray origin in the world frame, m.
    directions : (n, 2) unit ray directions in the world frame.
    primitives : scenery to hit (boxes by the slab method, cylinders as circles).
    range_max : rays that hit nothing closer get ``inf``.

    Returns
    -------
    (n,) ranges in m.
    """
    return PrimitiveArrays(primitives).ray_cast(
        np.asarray(origin_xy, dtype=float), np.asarray(directions, dtype=float), range_max
    )


def procedural_texture(rng: np.random.Generator, size: int = 256) -> npt.NDArray[np.uint8]:
    """A random, feature-rich RGB texture (blobs, lines and speckle at several scales).

    Gives a camera corners and blobs to track, like posters and furniture in a room.
    """
    img = np.full((size, size, 3), rng.integers(90, 200, size=3), dtype=np.uint8)
    for _ in range(int(rng.integers(25, 45))):
        color = tuple(int(c) for c in rng.integers(0, 256, size=3))
        kind = rng.integers(0, 3)
        x, y = (int(v) for v in rng.integers(0, size, size=2))
        r = int(rng.integers(size // 40, size // 8))
        if kind == 0:
            cv2.circle(img, (x, y), r, color, -1)
        elif kind == 1:
            cv2.rectangle(img, (x, y), (x + r, y + int(r * rng.uniform(0.5, 2))), color, -1)
        else:
            x2, y2 = (int(v) for v in rng.integers(0, size, size=2))
            cv2.line(img, (x, y), (x2, y2), color, int(rng.integers(1, 4)))
    coarse = rng.integers(-20, 21, size=(size // 4, size // 4)).astype(np.int16)
    noise = cv2.resize(coarse, (size, size), interpolation=cv2.INTER_NEAREST)
    return np.clip(img.astype(np.int16) + noise[..., None], 0, 255).astype(np.uint8)


def side_mesh(
    prim: Primitive, segments: int = 48
) -> tuple[list[list[float]], list[int], list[list[float]], list[list[float]], float]:
    """A visual mesh of ``prim`` in its body frame with texture coordinates at metric scale.

    The side faces are unwrapped into one strip: ``u`` runs along the perimeter
    (left to right as seen from outside), ``v`` from the bottom (0) to the top
    (1), so a texture of ``perimeter × height`` metres keeps its aspect on every
    face. The top is closed with a cap that samples one corner of the texture.
    A cylinder is a prism of ``segments`` faces (0.6 mm sagitta for a 0.3 m radius).

    Returns
    -------
    vertices, indices, uvs, normals, perimeter_m
        Arguments of ``createVisualShape(GEOM_MESH, ...)`` and the unwrapped width, m.
    """
    z0, z1 = -prim.height / 2.0, prim.height / 2.0
    if prim.shape is Shape.BOX:
        hx, hy = prim.half_extents
        ring = [(hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy)]
        flat = True
    else:
        ang = np.linspace(0.0, 2.0 * np.pi, int(segments), endpoint=False)
        ring = [(prim.radius * np.cos(a), prim.radius * np.sin(a)) for a in ang]
        flat = False
    n = len(ring)
    lengths = [float(np.hypot(*np.subtract(ring[(k + 1) % n], ring[k]))) for k in range(n)]
    perimeter = float(sum(lengths))
    verts: list[list[float]] = []
    uvs: list[list[float]] = []
    normals: list[list[float]] = []
    idx: list[int] = []
    s = 0.0
    for k in range(n):
        (ax, ay), (bx, by) = ring[k], ring[(k + 1) % n]
        if flat:
            mx, my = by - ay, -(bx - ax)
            na = nb = (mx / lengths[k], my / lengths[k])
        else:
            na = (ax / prim.radius, ay / prim.radius)
            nb = (bx / prim.radius, by / prim.radius)
        u0, u1 = s / perimeter, (s + lengths[k]) / perimeter
        s += lengths[k]
        base = len(verts)
        verts += [[ax, ay, z0], [bx, by, z0], [bx, by, z1], [ax, ay, z1]]
        uvs += [[u0, 0.0], [u1, 0.0], [u1, 1.0], [u0, 1.0]]
        normals += [
            [na[0], na[1], 0.0],
            [nb[0], nb[1], 0.0],
            [nb[0], nb[1], 0.0],
            [na[0], na[1], 0.0],
        ]
        idx += [base, base + 1, base + 2, base, base + 2, base + 3]
    centre = len(verts)
    verts.append([0.0, 0.0, z1])
    uvs.append([0.0, 1.0])
    normals.append([0.0, 0.0, 1.0])
    for k in range(n):
        a, b = ring[k], ring[(k + 1) % n]
        base = len(verts)
        verts += [[a[0], a[1], z1], [b[0], b[1], z1]]
        uvs += [[0.0, 1.0], [0.01, 1.0]]
        normals += [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]
        idx += [centre, base, base + 1]
    return verts, idx, uvs, normals, perimeter


@contextlib.contextmanager
def _quiet_c_stdout() -> Iterator[None]:
    """Silence output written by C code to file descriptor 1 (Python's own prints unaffected
    when stdout is not fd 1, e.g. under pytest's capture)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)
        os.close(devnull)


def physics_engine_version() -> str:
    """The PyBullet API version, for cache keys of results computed with the physics."""
    return str(p.getAPIVersion())


def fused_steps_are_exact(physics_dt: float, n_substeps: int) -> bool:
    """Whether Bullet's fixed-step loop, given the control period ``physics_dt * n_substeps``
    (s) and ``n_substeps``, takes exactly ``n_substeps`` steps of exactly ``physics_dt`` on
    every call.

    The engine (in double precision) steps ``h = T / n`` and counts
    ``k = int(t / h)`` steps of its accumulated time ``t``, keeping ``t - k h`` for the next
    call. With ``h == physics_dt``, ``k == n`` and a remainder of exactly zero, every call
    repeats the first: the same physics steps as ``n`` calls of one step each.
    """
    period = physics_dt * n_substeps
    h = period / n_substeps
    return h == physics_dt and int(period / h) == n_substeps and period - n_substeps * h == 0.0


GRAVITY = 9.81
"""Gravitational acceleration of every simulated world (m/s², along −z of the world)."""

_K = TypeVar("_K")
_V = TypeVar("_V")


class CountedDict(dict[_K, _V]):
    """A dict that counts the changes made to it (:attr:`version`), so that what is worked
    out from its keys can be kept until it changes (reads cost what a dict's do)."""

    version: int = 0  # (a class default too: unpickling sets the items before the state)

    def __setitem__(self, key: _K, value: _V) -> None:
        super().__setitem__(key, value)
        self.version += 1

    def __delitem__(self, key: _K) -> None:
        super().__delitem__(key)
        self.version += 1

    def __ior__(self, other: Any) -> CountedDict[_K, _V]:  # type: ignore[misc,override]
        self.update(other)  # (dict's own |= would not come through update)
        return self

    def pop(self, *args: Any) -> Any:
        self.version += 1
        return super().pop(*args)

    def popitem(self) -> tuple[_K, _V]:
        self.version += 1
        return super().popitem()

    def clear(self) -> None:
        self.version += 1
        super().clear()

    def update(self, *args: Any, **kwargs: Any) -> None:
        self.version += 1
        super().update(*args, **kwargs)

    def setdefault(self, key: _K, default: Any = None) -> Any:
        self.version += 1
        return super().setdefault(key, default)


class World:
    """One PyBullet simulation with static scenery.

    Parameters
    ----------
    physics_hz : physics rate in Hz (240 by default, PyBullet's native step).
    n_substeps : physics steps per control step; the control period is
        ``dt = n_substeps / physics_hz`` (default 12 → 20 Hz).
    solver_iterations : constraint-solver iterations per physics step.
    fused_substeps : run a control period's ``n_substeps`` physics steps inside one call
        into the engine (Bullet's own fixed-step loop) instead of one call per physics
        step: the same physics steps, bit for bit, at less cost (no Python call and
        command round trip per physics step). Where the time-step arithmetic is not exact
        (:func:`fused_steps_are_exact`) the world steps one call at a time. A fused world
        steps whole control periods only (:meth:`step` without arguments). Two engine
        quantities follow the engine's call period rather than the physics step, and a
        robot in a fused world must allow for them: a joint motor's force bound is
        turned into an impulse bound with the call period when the motor is commanded
        (command ``motor_force(force)``, :meth:`motor_force`), and external forces
        (``applyExternalForce``) are cleared after each call, so they would act on every
        physics step of the period (a robot that applies forces uses ``before_each``,
        which a fused world refuses, or leaves this off).
    rigid_scenery : create the floor, walls and obstacles as static rigid bodies (Bullet's
        maximal coordinates) instead of fixed-base multibodies. A static body moves nothing
        either way, and the contacts, friction and solver impulses are the same; but a
        multibody partner makes the multibody solver build its (empty) Jacobian and
        velocity update in every constraint row and iteration, about a fifth of the
        wheeled robot's physics step.
    """

    PLAIN_FLOOR_HALF_SIZE = 15.0
    """Half the side (m) of the plain-coloured floor drawn around the scene."""

    def __init__(
        self,
        physics_hz: float = 240.0,
        n_substeps: int = 12,
        solver_iterations: int = 10,
        fused_substeps: bool = False,
        rigid_scenery: bool = False,
    ):
        if not (physics_hz > 0 and np.isfinite(physics_hz)):
            raise ValueError(f"physics_hz must be a positive number, got {physics_hz!r}")
        if int(n_substeps) != n_substeps or n_substeps < 1:
            raise ValueError(f"n_substeps must be a positive integer, got {n_substeps!r}")
        for flag_name, flag in (
            ("fused_substeps", fused_substeps),
            ("rigid_scenery", rigid_scenery),
        ):
            if not isinstance(flag, (bool, np.bool_)):
                raise TypeError(f"{flag_name} must be True or False, got {type(flag).__name__}")
        self.physics_hz = float(physics_hz)
        self.n_substeps = int(n_substeps)
        self.solver_iterations = int(solver_iterations)
        self.fused_substeps = bool(fused_substeps) and fused_steps_are_exact(
            self.physics_dt, self.n_substeps
        )
        self.rigid_scenery = bool(rigid_scenery)
        # static scenery as a static rigid body (maximal coordinates) or a fixed-base multibody
        self._scenery_kwargs = {"useMaximalCoordinates": True} if self.rigid_scenery else {}
        with _quiet_c_stdout():  # PyBullet's C layer prints "argv[0]=" on every connect
            self.client: bullet_client.BulletClient | None = bullet_client.BulletClient(
                connection_mode=p.DIRECT
            )
        self._asset_dir = tempfile.mkdtemp(prefix="realitygap-")
        # name → body id and name → scenery primitive; they count their changes (CountedDict)
        self.bodies: CountedDict[str, int] = CountedDict()
        self.primitives: CountedDict[str, Primitive] = CountedDict()
        self._texture_cache: dict[str, int] = {}
        self._arrays: PrimitiveArrays | None = None
        self.physics_seconds = 0.0
        self.physics_cpu_seconds = 0.0
        self.cpu_timing = False
        self._egl_plugin: int | None = None
        self._step_simulation = self.client.stepSimulation
        self.reset_simulation()

    # ------------------------------------------------------------------ time
    @property
    def physics_dt(self) -> float:
        """Physics step in s."""
        return 1.0 / self.physics_hz

    @property
    def dt(self) -> float:
        """Control period in s: ``physics_dt * n_substeps``."""
        return self.physics_dt * self.n_substeps

    @property
    def bullet(self) -> bullet_client.BulletClient:
        """The live client; a clear error after :meth:`close`."""
        if self.client is None:
            raise RuntimeError("this World is closed; create a new one")
        return self.client

    @property
    def client_id(self) -> int:
        """The engine's id of the live client, for ``pybullet`` functions called directly
        (``physicsClientId``); a clear error after :meth:`close`."""
        return int(self.bullet._client)

    def step(
        self,
        n_physics_steps: int | None = None,
        before_each: Callable[[], object] | None = None,
    ) -> None:
        """Advance one control period (``n_substeps`` physics steps), or ``n_physics_steps``.

        ``before_each``, when given, is called before every physics step (forces that
        the engine does not keep from one step to the next, such as adsorption).
        The wall-clock time spent inside the loop is added to
        :attr:`physics_seconds`, so benchmarks can compare an env step with the
        raw physics it wraps; with :attr:`cpu_timing` on, the thread's CPU time to
        :attr:`physics_cpu_seconds` too (what one core spends, whatever else the
        machine runs; a system call per step, so off by default).
        """
        step = self._step_simulation
        fused = self.fused_substeps
        if n_physics_steps is None and before_each is None:
            n = self.n_substeps  # a whole control period: what every World steps
        else:
            n = self.n_substeps if n_physics_steps is None else int(n_physics_steps)
            if n < 0:
                raise ValueError(f"n_physics_steps must be >= 0, got {n_physics_steps!r}")
            if fused and (before_each is not None or n != self.n_substeps):
                raise ValueError(
                    "a World with fused_substeps steps whole control periods only, got "
                    f"n_physics_steps={n_physics_steps!r}"
                    + (" and before_each" if before_each is not None else "")
                    + ". Fix: create the World with fused_substeps=False to step single physics "
                    "steps or to act before each of them"
                )
        cpu0 = time.thread_time() if self.cpu_timing else 0.0
        t0 = time.perf_counter()
        if fused:
            step()  # n_substeps physics steps in the engine's fixed-step loop
        elif before_each is None:
            for _ in range(n):
                step()
        else:
            for _ in range(n):
                before_each()
                step()
        self.physics_seconds += time.perf_counter() - t0
        if self.cpu_timing:
            self.physics_cpu_seconds += time.thread_time() - cpu0

    def motor_force(self, force: float) -> float:
        """The force (N) or torque (N·m) bound to command a joint motor with so that each
        physics step's impulse bound is ``force * physics_dt``.

        The engine turns a motor's force bound into an impulse bound with its call period
        when the motor is commanded: ``physics_dt`` when it is called once per physics
        step, ``dt`` in a fused world (:attr:`fused_substeps`). There the returned value
        ``f`` has ``f * dt == force * physics_dt`` exactly, so the motors act bit for bit
        as in one call per physics step; if no such ``f`` exists, the world stops fusing
        (call this before commanding any motor).
        """
        force = float(force)
        if not self.fused_substeps:
            return force
        target = force * self.physics_dt
        f = force / self.n_substeps
        for _ in range(16):
            bound = f * self.dt
            if bound == target:
                return f
            f = math.nextafter(f, math.inf if bound < target else -math.inf)
        self.fused_substeps = False
        self._apply_step_mode()
        return force

    def _apply_step_mode(self) -> None:
        """Set the engine's call period: ``dt`` in ``n_substeps`` fixed steps when fused,
        else one physics step per call."""
        if self.fused_substeps:
            self.bullet.setPhysicsEngineParameter(
                fixedTimeStep=self.dt, numSubSteps=self.n_substeps
            )
        else:
            self.bullet.setPhysicsEngineParameter(fixedTimeStep=self.physics_dt, numSubSteps=0)

    def set_file_caching(self, enabled: bool) -> None:
        """Whether PyBullet reuses a mesh loaded earlier from the same file name (default on).

        Turn it off when bodies of different shapes are written to one file name in turn.
        """
        self.bullet.setPhysicsEngineParameter(enableFileCaching=int(bool(enabled)))

    def remove_body(self, name: str) -> None:
        """Remove the body registered under ``name`` (see :attr:`bodies`) from the simulation."""
        if name not in self.bodies:
            raise KeyError(f"no body named {name!r}; bodies: {sorted(self.bodies)}")
        self.bullet.removeBody(self.bodies.pop(name))

    def load_egl_renderer(self) -> bool:
        """Load PyBullet's EGL renderer plugin into this client: headless OpenGL on a GPU,
        or on a software device (Mesa's llvmpipe) on a CPU-only machine.

        Returns ``False`` (and changes nothing) when the plugin or an EGL device is not
        available. Once loaded, ``render_rgb(..., renderer="egl")`` uses it.
        """
        if self._egl_plugin is not None:
            return True
        import pkgutil

        loader = pkgutil.get_loader("eglRenderer")
        if loader is None or not hasattr(loader, "get_filename"):
            return False
        with _quiet_c_stdout():
            plugin = self.bullet.loadPlugin(loader.get_filename(), "_eglRendererPlugin")
        if plugin < 0:
            return False
        self._egl_plugin = int(plugin)
        return True

    def render_rgb(
        self,
        eye: npt.ArrayLike,
        target: npt.ArrayLike,
        *,
        fov_deg: float = 60.0,
        near: float = 0.1,
        far: float = 30.0,
        width: int = 320,
        height: int = 240,
        renderer: str = "tiny",
    ) -> npt.NDArray[np.uint8]:
        """An RGB picture (height, width, 3) of the scene from ``eye`` looking at ``target``
        (world frame, m; z up), rendered with the TinyRenderer (``renderer="tiny"``, works
        headless, single-threaded) or, after :meth:`load_egl_renderer`, with EGL OpenGL
        (``renderer="egl"``)."""
        if renderer not in ("tiny", "egl"):
            raise ValueError(f"renderer must be 'tiny' or 'egl', got {renderer!r}")
        if renderer == "egl" and self._egl_plugin is None:
            raise RuntimeError(
                "renderer='egl' needs the EGL plugin: call load_egl_renderer() first "
                "(it returns False where EGL is not available)"
            )
        c = self.bullet
        view = c.computeViewMatrix(
            np.asarray(eye, dtype=float).tolist(),
            np.asarray(target, dtype=float).tolist(),
            [0, 0, 1],
        )
        proj = c.computeProjectionMatrixFOV(fov_deg, width / height, near, far)
        if renderer == "tiny":
            _, _, rgba, _, _ = c.getCameraImage(
                width, height, view, proj, renderer=p.ER_TINY_RENDERER
            )
        else:
            with _quiet_c_stdout():  # the plugin reports its device on the first picture
                _, _, rgba, _, _ = c.getCameraImage(
                    width, height, view, proj, renderer=p.ER_BULLET_HARDWARE_OPENGL
                )
        return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[..., :3].copy()

    # -------------------------------------------------------------- scenery
    def reset_simulation(self) -> None:
        """Remove every body and start from an empty world with gravity and settings."""
        c = self.bullet
        c.resetSimulation()
        c.setGravity(0.0, 0.0, -GRAVITY)
        c.setPhysicsEngineParameter(
            fixedTimeStep=self.physics_dt,
            numSubSteps=0,
            numSolverIterations=self.solver_iterations,
            deterministicOverlappingPairs=1,
            enableConeFriction=0,
        )
        self._apply_step_mode()
        self.bodies.clear()
        self.primitives.clear()
        self._texture_cache.clear()
        self._arrays = None

    def add_floor(
        self,
        rgba: tuple[float, float, float, float] = (0.55, 0.5, 0.45, 1.0),
        textured_half_size: float | None = None,
        rng: np.random.Generator | None = None,
    ) -> int:
        """A flat floor at z = 0, friction 1.

        With ``textured_half_size`` (m) and ``rng``, the square
        ``[-textured_half_size, textured_half_size]²`` is covered with a tiled
        floor texture (:func:`~realitygap.robots.textures.surface_texture`) drawn
        from ``rng``; the rest keeps the plain colour ``rgba``.
        """
        c = self.bullet
        col = c.createCollisionShape(p.GEOM_PLANE)
        half, thick = self.PLAIN_FLOOR_HALF_SIZE, 0.001
        a = 0.0
        if textured_half_size is not None:
            if rng is None:
                raise ValueError("a textured floor needs rng, a numpy Generator")
            a = float(textured_half_size)
            if not (np.isfinite(a) and 0 < a < half):
                raise ValueError(
                    f"textured_half_size must be a positive size in m below {half:g}, got {a!r}"
                )
        if a > 0.0:
            # the plain colour only where the texture does not cover: a frame of four slabs.
            # A full plain slab under the texture would be rasterised on every camera frame
            # and never seen (a third of TinyRenderer's time in the default room)
            # (top faces only, at the plain slab's top, z = thick)
            ring = [[-half, -half], [half, -half], [half, half], [-half, half]]
            inner = [[-a, -a], [a, -a], [a, a], [-a, a]]
            verts = [[x, y, thick] for x, y in ring + inner]
            idx: list[int] = []
            for k in range(4):  # the quad between outer edge k and inner edge k, counter-clockwise
                o0, o1, i0, i1 = k, (k + 1) % 4, 4 + k, 4 + (k + 1) % 4
                idx += [o0, o1, i1, o0, i1, i0]
            vis = c.createVisualShape(
                p.GEOM_MESH,
                vertices=verts,
                indices=idx,
                normals=[[0.0, 0.0, 1.0]] * 8,
                rgbaColor=list(rgba),
            )
        else:
            vis = c.createVisualShape(
                p.GEOM_BOX, halfExtents=[half, half, thick], rgbaColor=list(rgba)
            )
        body = c.createMultiBody(0.0, col, vis, [0, 0, 0], **self._scenery_kwargs)
        c.changeDynamics(body, -1, lateralFriction=1.0)
        self.bodies["floor"] = body
        if a > 0.0:
            tid = self.load_texture_image(
                "floor", surface_texture(rng, 2 * a, 2 * a, SurfaceKind.FLOOR)
            )
            z = 0.0015  # just above the plain floor's top face
            quad = c.createVisualShape(
                p.GEOM_MESH,
                vertices=[[-a, -a, z], [a, -a, z], [a, a, z], [-a, a, z]],
                indices=[0, 1, 2, 0, 2, 3],
                uvs=[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
                normals=[[0.0, 0.0, 1.0]] * 4,
            )
            tile = c.createMultiBody(0.0, -1, quad, [0, 0, 0], **self._scenery_kwargs)
            c.changeVisualShape(tile, -1, textureUniqueId=tid, rgbaColor=[1, 1, 1, 1])
            self.bodies["floor_surface"] = tile
        return body

    def load_texture_image(self, key: str, image: npt.NDArray[np.uint8]) -> int:
        """Load an RGB image (H, W, 3) into the renderer under ``key``; its texture id.

        The image passes through an uncompressed BMP file in the world's asset folder
        (lossless like PNG, but written and decoded about ten times faster).
        """
        path = os.path.join(self._asset_dir, f"tex_{key}.bmp")
        if not cv2.imwrite(path, np.ascontiguousarray(image[..., ::-1])):
            raise OSError(f"could not write the texture {key!r} to {path}")
        self._texture_cache[key] = self.bullet.loadTexture(path)
        return self._texture_cache[key]

    def texture(self, key: str, rng: np.random.Generator) -> int:
        """A procedural texture loaded into the renderer (cached per world and key)."""
        if key not in self._texture_cache:
            path = os.path.join(self._asset_dir, f"tex_{key}.png")
            cv2.imwrite(path, procedural_texture(rng)[..., ::-1])
            self._texture_cache[key] = self.bullet.loadTexture(path)
        return self._texture_cache[key]

    def add_primitive(
        self,
        prim: Primitive,
        rgba: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0),
        texture_id: int | None = None,
        surface: SurfaceKind | str | None = None,
        rng: np.random.Generator | None = None,
    ) -> int:
        """Create a static body for ``prim`` and remember its analytic shape.

        With ``surface`` (``"wall"``, ``"object"``; see :class:`SurfaceKind`) and
        ``rng``, the body is drawn as a mesh whose sides carry a texture of that
        kind at metric scale (:func:`side_mesh`, :func:`surface_texture`);
        otherwise in ``rgba``, or with the whole ``texture_id`` on every face.
        """
        if prim.name in self.bodies:
            raise ValueError(f"a body named {prim.name!r} already exists in this world")
        c = self.bullet
        half_h = prim.height / 2.0
        if prim.shape is Shape.BOX:
            he = [prim.half_extents[0], prim.half_extents[1], half_h]
            col = c.createCollisionShape(p.GEOM_BOX, halfExtents=he)
            vis = c.createVisualShape(p.GEOM_BOX, halfExtents=he, rgbaColor=list(rgba))
        else:
            col = c.createCollisionShape(p.GEOM_CYLINDER, radius=prim.radius, height=prim.height)
            vis = c.createVisualShape(
                p.GEOM_CYLINDER, radius=prim.radius, length=prim.height, rgbaColor=list(rgba)
            )
        if surface is not None:
            if rng is None:
                raise ValueError(f"a {surface!r} surface for {prim.name!r} needs rng")
            verts, idx, uvs, normals, perimeter = side_mesh(prim)
            image = surface_texture(rng, perimeter, prim.height, surface)
            texture_id = self.load_texture_image(prim.name, image)
            vis = c.createVisualShape(
                p.GEOM_MESH, vertices=verts, indices=idx, uvs=uvs, normals=normals
            )
        quat = c.getQuaternionFromEuler([0.0, 0.0, prim.yaw])
        body = c.createMultiBody(
            0.0, col, vis, [prim.center[0], prim.center[1], half_h], quat, **self._scenery_kwargs
        )
        if texture_id is not None:
            c.changeVisualShape(body, -1, textureUniqueId=texture_id, rgbaColor=[1, 1, 1, 1])
        self.bodies[prim.name] = body
        self.primitives[prim.name] = prim
        self._arrays = None
        return body

    def load_urdf(
        self, name: str, urdf_text: str, position: npt.ArrayLike, quat_xyzw: npt.ArrayLike
    ) -> int:
        """Write ``urdf_text`` to the world's asset folder and load it as body ``name``."""
        path = os.path.join(self._asset_dir, f"{name}.urdf")
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(urdf_text)
        body = self.bullet.loadURDF(
            path,
            np.asarray(position, dtype=float).tolist(),
            np.asarray(quat_xyzw, dtype=float).tolist(),
            flags=p.URDF_USE_INERTIA_FROM_FILE,
        )
        self.bodies[name] = body
        return body

    def scenery_primitives(self) -> list[Primitive]:
        """All analytic scenery (walls and obstacles)."""
        return list(self.primitives.values())

    @property
    def scenery_arrays(self) -> PrimitiveArrays:
        """The scenery packed for vectorised ray casting (rebuilt when scenery changes)."""
        if self._arrays is None:
            self._arrays = PrimitiveArrays(self.scenery_primitives())
        return self._arrays

    # ------------------------------------------------------------- lifetime
    def close(self) -> None:
        """Disconnect and delete generated assets; safe to call twice."""
        if self.client is not None:
            try:
                if self._egl_plugin is not None:
                    with _quiet_c_stdout():
                        self.client.unloadPlugin(self._egl_plugin)
                    self._egl_plugin = None
                self.client.disconnect()
            except p.error:
                pass
            self.client = None
        if self._asset_dir and os.path.isdir(self._asset_dir):
            shutil.rmtree(self._asset_dir, ignore_errors=True)

    def __del__(self) -> None:  # pragma: no cover - best effort at interpreter exit
        try:
            self.close()
        except Exception:
            pass
