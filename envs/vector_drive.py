r"""Batched pieces of the vectorised WheeledNav: the drive model, the scan and collisions.

Everything here acts on a leading axis of ``N`` robots in numpy, with the
definitions of the single-robot code it mirrors:

* :class:`BatchDrive` steps the calibrated kinematic surrogate of the
  differential drive (:mod:`realitygap.robots.diffdrive_surrogate`) one control period
  at a time: the firmware's :class:`~realitygap.robots.diffdrive.FirmwareLimits`,
  the nominal inverse kinematics, the effects' surrogate terms
  (:meth:`~realitygap.robots.effects.Effect.surrogate_term`), the motors'
  calibrated overshoot, the shared acceleration budget of motors and traction
  (:meth:`~realitygap.robots.diffdrive_surrogate.DiffDriveSurrogate.accel_limits`,
  stepped as in the surrogate's carried branch) and the arc integration of the
  body.
* :class:`BatchScenery` packs each robot's walls and obstacles
  (:class:`~realitygap.robots.world.Primitive`, the footprints the PyBullet env
  builds) into padded arrays and ray-casts and measures clearance on them with
  the equations of :class:`~realitygap.robots.world.PrimitiveArrays` and
  :meth:`~realitygap.robots.world.Primitive.footprint_distance`.
* :class:`RobotStreams`, :func:`sample_start_goals`, :func:`random_layouts` and
  :func:`free_routes` draw ``N`` robots' episodes at once: the draws of
  :meth:`~realitygap.envs.tasks.nav.NavTask.sample_start_goal` and
  :func:`~realitygap.envs.layouts.random_layout` (same constraints, same batched
  rejection: only rejected rows are drawn again) from each robot's own seeded
  stream, so robot ``i`` gets exactly the episode the single-robot code draws
  from the same generator. :class:`EpisodeLayouts` keeps the layouts as arrays
  and builds a robot's :class:`~realitygap.robots.world.Primitive` tuple on demand.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, overload

import numpy as np
import numpy.typing as npt

from realitygap.envs.layouts import obstacle_capacity, room_grid, room_walls
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import EFFECTS, Effect, Reality, pipeline_key
from realitygap.robots.effects.diffdrive import SurrogateContext, SurrogateSlot
from realitygap.robots.world import Primitive, Shape

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "CONSTANT_SLOTS",
    "SEQUENCE_SLOTS",
    "BatchDrive",
    "BatchScenery",
    "EpisodeLayouts",
    "LayoutArrays",
    "RobotStreams",
    "effect_values",
    "free_routes",
    "random_layouts",
    "sample_start_goals",
    "vector_effects",
]

CONSTANT_SLOTS: tuple[SurrogateSlot, ...] = (
    SurrogateSlot.ENCODER_GAIN,
    SurrogateSlot.WHEEL_RADII,
    SurrogateSlot.TRACTION,
    SurrogateSlot.WHEELBASE,
    SurrogateSlot.CAMERA_MOUNT,
)
"""Slots whose terms are constant over an episode: applied exactly, once per reset."""

SEQUENCE_SLOTS: tuple[SurrogateSlot, ...] = (
    SurrogateSlot.COMMAND_TWIST,
    SurrogateSlot.WHEEL_SPEED,
    SurrogateSlot.GROUND_SPEED,
)
"""Slots whose terms act on a time series: applied to a rolling window of recent commands."""


def vector_effects() -> tuple[str, ...]:
    """Names of the differential-drive effects the vector env realises (those with a
    surrogate term), in registration order."""
    return tuple(
        n
        for n, cls in EFFECTS.items()
        if cls.robot == "diffdrive" and cls.surrogate_slot is not None
    )


def _terms(names: Sequence[str]) -> dict[SurrogateSlot, tuple[type[Effect], ...]]:
    classes = [EFFECTS[n] for n in names]
    return {
        slot: tuple(sorted((c for c in classes if c.surrogate_slot is slot), key=pipeline_key))
        for slot in SurrogateSlot
    }


def effect_values(reality: Reality | None) -> dict[str, float]:
    """``"effect.param"`` → value of every non-nominal parameter of ``reality``.

    Raises
    ------
    ValueError
        If an effect of ``reality`` has no surrogate term (the vector env cannot realise it).
    """
    out: dict[str, float] = {}
    if reality is None:
        return out
    known = vector_effects()
    for effect in reality.effects:
        if effect.name not in known:
            raise ValueError(
                f"reality effect {effect.name!r} has no surrogate term, so the vector env cannot "
                f"realise it; effects it realises: {', '.join(known)}. Use the PyBullet env "
                "(realitygap/WheeledNav-v0) for this effect"
            )
        for spec in type(effect).specs:
            out[f"{effect.name}.{spec.name}"] = float(effect.values[spec.name])
    return out


class BatchDrive:
    r"""The surrogate drive of ``N`` robots, stepped one control period per call.

    Per period, with the normalised action :math:`a` and the previous applied
    twist :math:`u_{k-1}`:

    .. math::

        u_k = u_{k-1} + \operatorname{clip}(\operatorname{clip}(a\,u_{max}, \pm u_{max})
              - u_{k-1}, \pm \dot u_{max}\,\Delta t)

    (the firmware limits), then the command-stage terms, the nominal inverse
    kinematics, the wheel-speed terms, the motor overshoot, the true radii and
    the ground-speed terms give target ground speeds; common and differential
    speeds ``(c, d)`` move towards them under the budget
    :math:`T = |Δc|/a_c + |Δd|/a_d` (reached when :math:`T \le Δt`, else the
    fraction :math:`Δt/T` of the way), and the body moves on the arc
    :math:`Δs = \int c`, :math:`Δθ = 2\int d / b`.

    Parameters
    ----------
    params : DiffDriveParams
        Nominal parameters (what the firmware believes).
    calibration : SurrogateCalibration
        Motor and contact constants of the surrogate.
    n : int
        Number of robots.
    dt : float
        Control period, s.
    effects : sequence of str
        Effects whose terms enter the model (their parameters are set per robot
        with :meth:`set_values`).
    history_steps : int
        Length of the rolling window of applied twists on which the time-series
        terms act (see :data:`SEQUENCE_SLOTS`).
    """

    def __init__(
        self,
        params: DiffDriveParams,
        calibration: Any,
        n: int,
        dt: float,
        effects: Sequence[str] = (),
        history_steps: int = 40,
    ):
        from realitygap.robots.diffdrive_surrogate import DiffDriveSurrogate

        self.params = params
        self.model = DiffDriveSurrogate(params, calibration)
        self.n, self.dt = int(n), float(dt)
        self.ctx = SurrogateContext(dt=self.dt, params=params)
        self.effects = tuple(effects)
        self.terms = _terms(self.effects)
        self.specs = {
            f"{name}.{s.name}": s.nominal for name in self.effects for s in EFFECTS[name].specs
        }
        self.sequence = any(self.terms[s] for s in SEQUENCE_SLOTS)
        self.history_steps = int(history_steps)
        self.values = {k: np.full(self.n, v) for k, v in self.specs.items()}
        # per-robot constants (set_values) and state (reset)
        self.r = np.empty((self.n, 2))
        self.b = np.empty(self.n)
        self.enc = np.empty((self.n, 2))
        self.mount = np.empty((self.n, 3))
        self.lim: dict[str, FloatArray] = {}
        self.cmd = np.zeros((self.n, 2))
        self.speed = np.zeros((self.n, 2))  # ground (c, d), m/s
        self.roll_speed = np.zeros((self.n, 2))  # wheel surfaces (c, d), m/s
        self.roll = np.zeros((self.n, 2))  # rolled wheel angles (L, R), rad
        self.history = np.zeros((self.n, self.history_steps, 2)) if self.sequence else None
        self.set_values(np.arange(self.n), {})

    # ------------------------------------------------------------------ parameters
    def _term(self, slot: SurrogateSlot, x: Any, idx: npt.NDArray[np.intp]) -> Any:
        for cls in self.terms[slot]:
            p = {s.name: self.values[f"{cls.name}.{s.name}"][idx] for s in cls.specs}
            x = cls.surrogate_term(x, p, self.ctx)
        return x

    def set_values(self, idx: npt.NDArray[np.intp], values: Mapping[str, FloatArray]) -> None:
        """Set the effect parameters of robots ``idx`` (absent ones nominal) and their
        per-episode constants."""
        for key, nominal in self.specs.items():
            self.values[key][idx] = values.get(key, nominal)
        P = self.params
        m = idx.size
        ones = np.ones(m)
        enc_l, enc_r = self._term(SurrogateSlot.ENCODER_GAIN, (ones, ones.copy()), idx)
        self.enc[idx] = np.column_stack([enc_l * ones, enc_r * ones])
        rl, rr = self._term(
            SurrogateSlot.WHEEL_RADII, (P.wheel_radius_left, P.wheel_radius_right), idx
        )
        self.r[idx] = np.column_stack([rl * ones, rr * ones])
        self.b[idx] = self._term(SurrogateSlot.WHEELBASE, P.wheelbase, idx) * ones
        cam = P.camera
        mount = self._term(
            SurrogateSlot.CAMERA_MOUNT, (cam.mount_xyz[0], cam.mount_xyz[1], cam.mount_yaw), idx
        )
        self.mount[idx] = np.column_stack([np.asarray(v) * ones for v in mount])
        mu = self._term(SurrogateSlot.TRACTION, np.full(m, float(P.wheel_friction)), idx)
        lim = self.model.accel_limits(np.asarray(mu, dtype=float) * ones)
        for key, value in lim.items():
            self.lim.setdefault(key, np.empty(self.n))[idx] = value

    def reset(self, idx: npt.NDArray[np.intp]) -> None:
        """Robots ``idx`` at rest, wheel angles zero."""
        for arr in (self.cmd, self.speed, self.roll_speed, self.roll):
            arr[idx] = 0.0
        if self.history is not None:
            self.history[idx] = 0.0

    # ------------------------------------------------------------------ stepping
    def _targets(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Ground and wheel-surface target speeds (L, R) of this period, each (N,), m/s."""
        P = self.params
        hb0 = P.wheelbase / 2.0
        r0 = np.array([P.wheel_radius_left, P.wheel_radius_right])
        if self.history is None:
            u = self.cmd
            sl = u[:, 0] - u[:, 1] * hb0
            sr = u[:, 0] + u[:, 1] * hb0
            wl, wr = sl / r0[0], sr / r0[1]
        else:
            self.history[:, :-1] = self.history[:, 1:]
            self.history[:, -1] = self.cmd
            ud = self._command_terms(self.history)
            sl = ud[..., 0] - ud[..., 1] * hb0
            sr = ud[..., 0] + ud[..., 1] * hb0
            sl, sr = self._term(SurrogateSlot.WHEEL_SPEED, (sl, sr), np.arange(self.n))
            wl, wr = np.asarray(sl) / r0[0], np.asarray(sr) / r0[1]
        ov = self.model.calibration.motor_overshoot
        if ov:
            wl = wl + ov * np.sign(wl)
            wr = wr + ov * np.sign(wr)
        if self.history is None:
            tl, tr = wl * self.r[:, 0], wr * self.r[:, 1]
            return tl, tr, tl, tr
        tl, tr = wl * self.r[:, :1], wr * self.r[:, 1:]
        gl, gr = self._term(SurrogateSlot.GROUND_SPEED, (tl, tr), np.arange(self.n))
        return (np.asarray(gl)[:, -1], np.asarray(gr)[:, -1], tl[:, -1], tr[:, -1])

    def _command_terms(self, u: FloatArray) -> FloatArray:
        """The command-stage terms on windows ``u`` (N, W, 2): each distinct parameter set
        is one call (the terms take a series shared by the batch)."""
        if not self.terms[SurrogateSlot.COMMAND_TWIST]:
            return u
        keys = [
            f"{c.name}.{s.name}" for c in self.terms[SurrogateSlot.COMMAND_TWIST] for s in c.specs
        ]
        table = np.column_stack([self.values[k] for k in keys])
        sets, which = np.unique(table, axis=0, return_inverse=True)
        out = np.empty_like(u)
        n, w = u.shape[0], u.shape[1]
        for j in range(sets.shape[0]):
            rows = np.flatnonzero(which.reshape(-1) == j)
            series = u[rows].transpose(1, 0, 2).reshape(w, 2 * rows.size)
            x: Any = series
            for cls in self.terms[SurrogateSlot.COMMAND_TWIST]:
                p = {
                    s.name: np.array([sets[j, keys.index(f"{cls.name}.{s.name}")]])
                    for s in cls.specs
                }
                x = cls.surrogate_term(x, p, self.ctx)
            x = np.asarray(x).reshape(w, rows.size, 2).transpose(1, 0, 2)
            out[rows] = x
        del n
        return out

    @staticmethod
    def _advance(
        state: FloatArray,
        tc: FloatArray,
        td: FloatArray,
        a_c: FloatArray,
        a_d: FloatArray,
        dt: float,
    ) -> tuple[FloatArray, FloatArray]:
        """Move ``state`` (N, 2) = (c, d) towards the targets; returns the travel (c, d) in m."""
        c, d = state[:, 0], state[:, 1]
        gc, gd = tc - c, td - d
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_c = np.where(np.isinf(a_c), 0.0, 1.0 / np.maximum(a_c, 1e-300))
            inv_d = np.where(np.isinf(a_d), 0.0, 1.0 / np.maximum(a_d, 1e-300))
            T = np.abs(gc) * inv_c + np.abs(gd) * inv_d
            frac = np.where(T > dt, dt / np.maximum(T, 1e-300), 1.0)
        tau = np.minimum(T, dt)
        c_end, d_end = c + gc * frac, d + gd * frac
        travel_c = 0.5 * (c + c_end) * tau + c_end * (dt - tau)
        travel_d = 0.5 * (d + d_end) * tau + d_end * (dt - tau)
        state[:, 0], state[:, 1] = c_end, d_end
        return travel_c, travel_d

    def step(self, action: FloatArray, pose: FloatArray) -> None:
        """One control period for every robot: ``action`` (N, 2) in ``[-1, 1]``; ``pose``
        (N, 3) is advanced in place."""
        P, dt = self.params, self.dt
        v = np.clip(action[:, 0] * P.v_max, -P.v_max, P.v_max)
        w = np.clip(action[:, 1] * P.w_max, -P.w_max, P.w_max)
        dv, dw = P.a_max * dt, P.alpha_max * dt
        self.cmd[:, 0] += np.clip(v - self.cmd[:, 0], -dv, dv)
        self.cmd[:, 1] += np.clip(w - self.cmd[:, 1], -dw, dw)
        gl, gr, tl, tr = self._targets()
        lim = self.lim
        ds, dd = self._advance(
            self.speed, 0.5 * (gl + gr), 0.5 * (gr - gl), lim["ground_c"], lim["ground_d"], dt
        )
        rc, rd = self._advance(
            self.roll_speed, 0.5 * (tl + tr), 0.5 * (tr - tl), lim["wheel_c"], lim["wheel_d"], dt
        )
        self.roll[:, 0] += (rc - rd) / self.r[:, 0]
        self.roll[:, 1] += (rc + rd) / self.r[:, 1]
        dth = 2.0 * dd / self.b
        mid = pose[:, 2] + 0.5 * dth
        chord = ds * np.sinc(dth / (2.0 * math.pi))
        pose[:, 0] += chord * np.cos(mid)
        pose[:, 1] += chord * np.sin(mid)
        pose[:, 2] = (pose[:, 2] + dth + math.pi) % (2.0 * math.pi) - math.pi

    def twist(self) -> FloatArray:
        """Body twist ``[v, ω]`` (N, 2) at the end of the period (m/s, rad/s)."""
        return np.column_stack([self.speed[:, 0], 2.0 * self.speed[:, 1] / self.b])

    def encoder_angles(self) -> FloatArray:
        """Wheel angles (N, 2) as the encoders report them (rad)."""
        return self.roll * self.enc


class BatchScenery:
    """Walls and obstacles of ``N`` robots' episodes, padded into arrays.

    Boxes use the slab method, cylinders the circle equation, as
    :class:`~realitygap.robots.world.PrimitiveArrays`; padding entries sit far
    outside every room and are never hit.
    """

    FAR = 1.0e4
    """Position (m) of padding primitives."""

    def __init__(self, n: int, max_boxes: int, max_cylinders: int, room_half_size: float):
        self.n = int(n)
        self.room_half_size = float(room_half_size)
        self._walls = room_walls(self.room_half_size)
        self.in_room = np.zeros(n, dtype=bool)
        self.box_center = np.full((n, max_boxes, 2), self.FAR)
        self.box_cos = np.ones((n, max_boxes))
        self.box_sin = np.zeros((n, max_boxes))
        self.box_half = np.full((n, max_boxes, 2), 0.1)
        self.cyl_center = np.full((n, max_cylinders, 2), self.FAR)
        self.cyl_radius = np.full((n, max_cylinders), 0.1)

    def set(self, i: int, primitives: Sequence[Primitive]) -> None:
        """Robot ``i``'s scenery (the arrays grow when a layout has more pieces).

        The room's walls (:func:`~realitygap.envs.layouts.room_walls`), when all four
        are present, are cast against as the planes of their inner faces: the same
        hits and clearances from inside the room, at a fraction of the cost."""
        primitives = list(primitives)
        self.in_room[i] = all(w in primitives for w in self._walls)
        if self.in_room[i]:
            primitives = [q for q in primitives if q not in self._walls]
        boxes = [q for q in primitives if q.shape is Shape.BOX]
        cyls = [q for q in primitives if q.shape is Shape.CYLINDER]
        self._grow(len(boxes), len(cyls))
        self.box_center[i] = self.FAR
        self.box_cos[i], self.box_sin[i], self.box_half[i] = 1.0, 0.0, 0.1
        self.cyl_center[i], self.cyl_radius[i] = self.FAR, 0.1
        for k, b in enumerate(boxes):
            self.box_center[i, k] = b.center
            self.box_cos[i, k], self.box_sin[i, k] = math.cos(b.yaw), math.sin(b.yaw)
            self.box_half[i, k] = b.half_extents
        for k, c in enumerate(cyls):
            self.cyl_center[i, k] = c.center
            self.cyl_radius[i, k] = c.radius

    def set_shared(self, idx: npt.NDArray[np.intp], primitives: Sequence[Primitive]) -> None:
        """Robots ``idx`` all get the scenery ``primitives`` (as :meth:`set`, row copied)."""
        if idx.size == 0:
            return
        first = int(idx[0])
        self.set(first, primitives)
        for arr in (self.in_room, self.box_center, self.box_cos, self.box_sin, self.box_half):
            arr[idx] = arr[first]
        self.cyl_center[idx], self.cyl_radius[idx] = self.cyl_center[first], self.cyl_radius[first]

    def set_layouts(self, idx: npt.NDArray[np.intp], layouts: LayoutArrays) -> None:
        """Robots ``idx`` get the room's four walls and the obstacles ``layouts`` (rows
        aligned with ``idx``), boxes and cylinders each in layout order (as :meth:`set`)."""
        is_box = layouts.is_box
        is_cyl = ~is_box
        box_rank = np.cumsum(is_box, axis=1) - 1
        cyl_rank = np.cumsum(is_cyl, axis=1) - 1
        self._grow(int(is_box.sum(axis=1).max(initial=0)), int(is_cyl.sum(axis=1).max(initial=0)))
        self.in_room[idx] = True
        self.box_center[idx] = self.FAR
        self.box_cos[idx], self.box_sin[idx], self.box_half[idx] = 1.0, 0.0, 0.1
        self.cyl_center[idx], self.cyl_radius[idx] = self.FAR, 0.1
        r, k = np.nonzero(is_box)
        row, col = idx[r], box_rank[r, k]
        self.box_center[row, col] = layouts.center[r, k]
        self.box_cos[row, col] = np.cos(layouts.yaw[r, k])
        self.box_sin[row, col] = np.sin(layouts.yaw[r, k])
        self.box_half[row, col] = layouts.half_extents[r, k]
        r, k = np.nonzero(is_cyl)
        row, col = idx[r], cyl_rank[r, k]
        self.cyl_center[row, col] = layouts.center[r, k]
        self.cyl_radius[row, col] = layouts.radius[r, k]

    def _grow(self, n_boxes: int, n_cyls: int) -> None:
        extra_b = n_boxes - self.box_center.shape[1]
        if extra_b > 0:
            n = self.n
            self.box_center = np.concatenate(
                [self.box_center, np.full((n, extra_b, 2), self.FAR)], 1
            )
            self.box_cos = np.concatenate([self.box_cos, np.ones((n, extra_b))], 1)
            self.box_sin = np.concatenate([self.box_sin, np.zeros((n, extra_b))], 1)
            self.box_half = np.concatenate([self.box_half, np.full((n, extra_b, 2), 0.1)], 1)
        extra_c = n_cyls - self.cyl_center.shape[1]
        if extra_c > 0:
            n = self.n
            self.cyl_center = np.concatenate(
                [self.cyl_center, np.full((n, extra_c, 2), self.FAR)], 1
            )
            self.cyl_radius = np.concatenate([self.cyl_radius, np.full((n, extra_c), 0.1)], 1)

    def clearance(self, xy: FloatArray) -> FloatArray:
        """Signed distance (N,) from each robot's point ``xy`` (N, 2) to its nearest footprint."""
        return self.clearance_of(np.arange(self.n), xy)

    def clearance_of(self, idx: npt.NDArray[np.intp], xy: FloatArray) -> FloatArray:
        """Signed distance (M,) from point ``xy[k]`` (M, 2) to the nearest footprint of
        robot ``idx[k]``'s scenery (as :meth:`Primitive.footprint_distance`)."""
        h = self.room_half_size
        room = np.minimum(h - np.abs(xy[:, 0]), h - np.abs(xy[:, 1]))
        best = np.where(self.in_room[idx], room, np.inf)
        if self.box_center.shape[1]:
            rx = xy[:, None, 0] - self.box_center[idx, :, 0]
            ry = xy[:, None, 1] - self.box_center[idx, :, 1]
            c, s = self.box_cos[idx], self.box_sin[idx]
            qx = np.abs(c * rx + s * ry) - self.box_half[idx, :, 0]
            qy = np.abs(-s * rx + c * ry) - self.box_half[idx, :, 1]
            outside = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0))
            inside = np.minimum(np.maximum(qx, qy), 0.0)
            best = np.minimum(best, (outside + inside).min(axis=1))
        if self.cyl_center.shape[1]:
            dist = np.hypot(
                xy[:, None, 0] - self.cyl_center[idx, :, 0],
                xy[:, None, 1] - self.cyl_center[idx, :, 1],
            )
            best = np.minimum(best, (dist - self.cyl_radius[idx]).min(axis=1))
        return best

    def ray_cast(
        self,
        idx: npt.NDArray[np.intp],
        origin: FloatArray,
        dirs: FloatArray,
        range_max: float,
        half_fov: float = math.pi,
    ) -> FloatArray:
        """Distance along each ray to the first hit for robots ``idx``: ``origin`` (M, 2),
        ``dirs`` (M, B, 2) unit directions spread at most ``half_fov`` (rad) either side of
        their mean; ``inf`` beyond ``range_max``. Returns (M, B).

        Only the (robot, obstacle) pairs whose bounding circle lies in range and within
        the rays' angular span are cast against."""
        h = self.room_half_size
        m = idx.size
        with np.errstate(divide="ignore", invalid="ignore"):
            dxr, dyr = dirs[..., 0], dirs[..., 1]
            tx = (np.copysign(h, dxr) - origin[:, :1]) / dxr
            ty = (np.copysign(h, dyr) - origin[:, 1:]) / dyr
            room = np.fmin(tx, ty)
        best = np.where(self.in_room[idx, None], room, np.inf)
        mean_dir = dirs.sum(axis=1)
        mean_dir /= np.maximum(np.linalg.norm(mean_dir, axis=1, keepdims=True), 1e-12)
        for kind in ("box", "cyl"):
            center = self.box_center if kind == "box" else self.cyl_center
            if not center.shape[1] or m == 0:
                continue
            if kind == "box":
                bound = np.hypot(self.box_half[idx, :, 0], self.box_half[idx, :, 1])
            else:
                bound = self.cyl_radius[idx]
            rel = center[idx] - origin[:, None, :]
            dist = np.hypot(rel[..., 0], rel[..., 1])
            along = rel[..., 0] * mean_dir[:, None, 0] + rel[..., 1] * mean_dir[:, None, 1]
            with np.errstate(invalid="ignore"):
                cos_off = np.clip(along / np.maximum(dist, 1e-12), -1.0, 1.0)
                spread = np.arcsin(np.clip(bound / np.maximum(dist, 1e-12), 0.0, 1.0))
            visible = (dist - bound < range_max) & (
                (dist <= bound) | (np.arccos(cos_off) <= half_fov + spread)
            )
            rows, cols = np.nonzero(visible)
            if rows.size == 0:
                continue
            hits = self._cast_pairs(kind, idx[rows], cols, origin[rows], dirs[rows])
            first = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
            nearest = np.minimum.reduceat(hits, first, axis=0)
            r = rows[first]
            best[r] = np.minimum(best[r], nearest)
        best[best > range_max] = np.inf
        return best

    def _cast_pairs(
        self,
        kind: str,
        robot: npt.NDArray[np.intp],
        col: npt.NDArray[np.intp],
        origin: FloatArray,
        dirs: FloatArray,
    ) -> FloatArray:
        """Hit distances (P, B) of pair ``p``'s rays on obstacle ``col[p]`` of ``robot[p]``:
        the slab method for boxes, the circle equation for cylinders
        (:class:`~realitygap.robots.world.PrimitiveArrays`)."""
        dx, dy = dirs[..., 0], dirs[..., 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            if kind == "box":
                rel = origin - self.box_center[robot, col]
                c = self.box_cos[robot, col][:, None]
                s = self.box_sin[robot, col][:, None]
                rx, ry = rel[:, :1], rel[:, 1:]
                olx, oly = c * rx + s * ry, -s * rx + c * ry
                dlx, dly = c * dx + s * dy, -s * dx + c * dy
                hx = self.box_half[robot, col, 0][:, None]
                hy = self.box_half[robot, col, 1][:, None]
                t1, t2 = (-hx - olx) / dlx, (hx - olx) / dlx
                t3, t4 = (-hy - oly) / dly, (hy - oly) / dly
                tmin = np.maximum(np.minimum(t1, t2), np.minimum(t3, t4))
                tmax = np.minimum(np.maximum(t1, t2), np.maximum(t3, t4))
                tmin = np.maximum(tmin, 0.0)
                return np.where(tmax >= tmin, tmin, np.inf)
            rel = origin - self.cyl_center[robot, col]
            rx, ry = rel[:, :1], rel[:, 1:]
            b = rx * dx + ry * dy
            cc = rx * rx + ry * ry - (self.cyl_radius[robot, col] ** 2)[:, None]
            disc = b * b - cc
            t = -b - np.sqrt(np.maximum(disc, 0.0))
            t = np.where(cc < 0, 0.0, t)
            return np.where((disc >= 0) & (t >= 0), t, np.inf)


# ---------------------------------------------------------------------- episodes
class RobotStreams:
    """One stream of uniform doubles in ``[0, 1)`` per robot, drawn in batches.

    Robot ``i``'s stream is exactly what ``np.random.default_rng(seeds[i]).random()``
    returns call after call (and so what ``uniform(low, high)`` maps to
    ``low + (high - low) * u``, as NumPy does): the generators fill a buffer of
    ``width`` doubles per robot, and :meth:`take` hands out each robot's next
    ones with one indexing; a robot whose buffer runs short is refilled from its
    own generator (the unused doubles kept first), so no draw is lost or reordered.

    Parameters
    ----------
    seeds : (N,) one seed per robot.
    width : doubles buffered per robot (at least the largest :meth:`take`).
    """

    def __init__(self, seeds: npt.ArrayLike, width: int = 64):
        seeds = np.asarray(seeds).reshape(-1)
        self.width = int(width)
        self.rngs = [np.random.default_rng(int(s)) for s in seeds.tolist()]
        self.buffer = np.empty((len(self.rngs), self.width))
        for row, rng in zip(self.buffer, self.rngs, strict=True):
            rng.random(out=row)
        self.position = np.zeros(len(self.rngs), dtype=np.intp)

    def take(self, rows: npt.NDArray[np.intp], k: int) -> FloatArray:
        """The next ``k`` doubles (M, k) of each robot in ``rows`` (distinct), consumed."""
        if k > self.width:
            raise ValueError(f"take(k={k}) exceeds the buffer width {self.width}")
        for i in rows[self.position[rows] + k > self.width].tolist():
            rest = self.buffer[i, self.position[i] :].copy()
            self.buffer[i, : rest.size] = rest
            self.rngs[i].random(out=self.buffer[i, rest.size :])
            self.position[i] = 0
        out = self.buffer[rows[:, None], self.position[rows, None] + np.arange(k)]
        self.position[rows] += k
        return out

    def uniform(
        self, rows: npt.NDArray[np.intp], low: float, high: float, k: int = 1
    ) -> FloatArray:
        """``k`` draws (M, k) uniform in ``[low, high)`` per robot, as ``Generator.uniform``."""
        return low + (high - low) * self.take(rows, k)


@dataclass
class LayoutArrays:
    """Obstacles of ``M`` robots' episodes, ``K`` per robot, as arrays.

    ``is_box`` (M, K); ``center`` (M, K, 2) m; ``height`` (M, K) m; ``yaw`` (M, K)
    rad (boxes; 0 for cylinders); ``half_extents`` (M, K, 2) m (boxes; 0 for
    cylinders); ``radius`` (M, K) m (cylinders; 0 for boxes).
    """

    is_box: npt.NDArray[np.bool_]
    center: FloatArray
    height: FloatArray
    yaw: FloatArray
    half_extents: FloatArray
    radius: FloatArray

    @classmethod
    def empty(cls, m: int, k: int) -> LayoutArrays:
        return cls(
            np.zeros((m, k), dtype=bool),
            np.zeros((m, k, 2)),
            np.zeros((m, k)),
            np.zeros((m, k)),
            np.zeros((m, k, 2)),
            np.zeros((m, k)),
        )

    def select(self, rows: Any) -> LayoutArrays:
        """The layouts of ``rows`` (an index or mask on the leading axis)."""
        return LayoutArrays(
            self.is_box[rows],
            self.center[rows],
            self.height[rows],
            self.yaw[rows],
            self.half_extents[rows],
            self.radius[rows],
        )

    @property
    def reach(self) -> FloatArray:
        """Bounding radius (M, K) of each footprint about its centre, m."""
        return np.where(
            self.is_box, np.hypot(self.half_extents[..., 0], self.half_extents[..., 1]), self.radius
        )

    def footprint_distance(self, px: FloatArray, py: FloatArray) -> FloatArray:
        """Signed distance (m) of points at offsets ``(px, py)`` from the centres, broadcast
        against the (M, K) footprints on their leading axes (negative inside), with the
        operations of :meth:`~realitygap.robots.world.Primitive.footprint_distance`."""
        extra = (None,) * (np.ndim(px) - 2)
        sel = (slice(None), slice(None), *extra)
        c, s = np.cos(self.yaw)[sel], np.sin(self.yaw)[sel]
        qx = np.abs(c * px + s * py) - self.half_extents[..., 0][sel]
        qy = np.abs(-s * px + c * py) - self.half_extents[..., 1][sel]
        ox, oy = np.maximum(qx, 0.0), np.maximum(qy, 0.0)
        box = np.sqrt(ox * ox + oy * oy) + np.minimum(np.maximum(qx, qy), 0.0)
        cyl = np.sqrt(px * px + py * py) - self.radius[sel]
        return np.where(self.is_box[sel], box, cyl)

    def primitives(self, row: int) -> list[Primitive]:
        """Robot ``row``'s obstacles as the :class:`Primitive` list ``random_layout`` returns."""
        out = []
        for k in range(self.is_box.shape[1]):
            center = (float(self.center[row, k, 0]), float(self.center[row, k, 1]))
            height = float(self.height[row, k])
            if self.is_box[row, k]:
                hx, hy = self.half_extents[row, k].tolist()
                prim = Primitive(
                    f"obstacle_{k}",
                    Shape.BOX,
                    center,
                    height,
                    yaw=float(self.yaw[row, k]),
                    half_extents=(hx, hy),
                )
            else:
                prim = Primitive(
                    f"obstacle_{k}",
                    Shape.CYLINDER,
                    center,
                    height,
                    radius=float(self.radius[row, k]),
                )
            out.append(prim)
        return out


class EpisodeLayouts(Sequence[tuple[Primitive, ...]]):
    """Walls and obstacles of each robot's episode; ``layouts[i]`` is robot ``i``'s tuple
    of :class:`Primitive` (empty before its first reset), built when asked for."""

    def __init__(self, n: int, n_obstacles: int, walls: Sequence[Primitive]):
        self.walls = tuple(walls)
        self.arrays = LayoutArrays.empty(n, n_obstacles)
        self._shared: tuple[Primitive, ...] | None = None
        self._set = np.zeros(n, dtype=bool)

    def set_arrays(self, idx: npt.NDArray[np.intp], layouts: LayoutArrays) -> None:
        """Robots ``idx`` get the walls and the obstacles ``layouts`` (rows aligned with ``idx``)."""
        a = self.arrays
        for name in ("is_box", "center", "height", "yaw", "half_extents", "radius"):
            getattr(a, name)[idx] = getattr(layouts, name)
        self._shared = None
        self._set[idx] = True

    def set_shared(self, idx: npt.NDArray[np.intp], primitives: Sequence[Primitive]) -> None:
        """Robots ``idx`` (every robot of a fixed-layout env) get ``primitives``."""
        self._shared = tuple(primitives)
        self._set[idx] = True

    def __len__(self) -> int:
        return int(self._set.size)

    @overload
    def __getitem__(self, i: int) -> tuple[Primitive, ...]: ...
    @overload
    def __getitem__(self, i: slice) -> list[tuple[Primitive, ...]]: ...
    def __getitem__(self, i: int | slice) -> Any:
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        j = range(len(self))[i]  # IndexError and negative indices as a list's
        if not self._set[j]:
            return ()
        if self._shared is not None:
            return self._shared
        return (*self.walls, *self.arrays.primitives(j))

    def __iter__(self) -> Iterator[tuple[Primitive, ...]]:
        return (self[j] for j in range(len(self)))


def sample_start_goals(
    streams: RobotStreams,
    rows: npt.NDArray[np.intp],
    room_half_size: float,
    start: FloatArray | None = None,
    goal: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Start and goal poses (M, 3) ``[x, y, θ]`` of robots ``rows``: the given ones, else drawn
    as :meth:`~realitygap.envs.tasks.nav.NavTask.sample_start_goal` draws them.

    A drawn pose lies in ``[-(h - 0.6), h - 0.6]²``; a drawn goal more than 1 m from the
    start (batched rejection: only the rows still too close draw again, up to 100 draws,
    after which the last one stands). The caller checks given poses.
    """
    lim = room_half_size - 0.6
    m = rows.size
    if start is None:
        xy = streams.uniform(rows, -lim, lim, 2)
        start = np.column_stack([xy, streams.uniform(rows, -math.pi, math.pi)[:, 0]])
    if goal is None:
        goal = np.empty((m, 3))
        pending = np.arange(m)
        for _ in range(100):
            r = rows[pending]
            xy = streams.uniform(r, -lim, lim, 2)
            goal[pending, :2] = xy
            goal[pending, 2] = streams.uniform(r, -math.pi, math.pi)[:, 0]
            d = goal[pending, :2] - start[pending, :2]
            pending = pending[~(np.hypot(d[:, 0], d[:, 1]) > 1.0)]
            if pending.size == 0:
                break
    return np.asarray(start, dtype=float), np.asarray(goal, dtype=float)


ROUTE_CHUNK = 256
"""Robots whose route grids :func:`free_routes` builds at once (bounds its memory to ~100 MB)."""


def _block_footprints(
    free: npt.NDArray[np.bool_],
    layouts: LayoutArrays,
    boxes: bool,
    ax: FloatArray,
    ay: FloatArray,
    spacing: float,
    radius: float,
    half_size: float,
) -> None:
    """Clear ``free[m, i, j]`` where a box (``boxes``) or cylinder footprint of robot ``m`` is
    within ``radius`` of cell ``(ax[i], ay[j])``, over the patch of cells around each
    centre that its bounding circle can reach. The products are taken per axis and
    summed on the patch, which gives the values of ``Primitive.footprint_distance``."""
    r, q = np.nonzero(layouts.is_box == boxes)
    if r.size == 0:
        return
    n = ax.size
    cx, cy = layouts.center[r, q, 0], layouts.center[r, q, 1]
    reach = layouts.reach[r, q]
    w = int(math.ceil((float(reach.max()) + radius) / spacing)) + 2
    offsets = np.arange(-w, w + 1)
    ii = np.clip(np.rint((cx + half_size) / spacing).astype(np.intp)[:, None] + offsets, 0, n - 1)
    jj = np.clip(np.rint((cy + half_size) / spacing).astype(np.intp)[:, None] + offsets, 0, n - 1)
    px = ax[ii] - cx[:, None]  # (Q, P)
    py = ay[jj] - cy[:, None]
    if boxes:
        yaw = layouts.yaw[r, q][:, None]
        c, s = np.cos(yaw), np.sin(yaw)
        qx = (c * px)[:, :, None] + (s * py)[:, None, :]
        qy = (-s * px)[:, :, None] + (c * py)[:, None, :]
        np.abs(qx, out=qx)
        np.abs(qy, out=qy)
        qx -= layouts.half_extents[r, q, 0][:, None, None]
        qy -= layouts.half_extents[r, q, 1][:, None, None]
        inside = np.maximum(qx, qy)
        np.minimum(inside, 0.0, out=inside)
        np.maximum(qx, 0.0, out=qx)
        np.maximum(qy, 0.0, out=qy)
        qx *= qx
        qy *= qy
        qx += qy
        d = np.sqrt(qx, out=qx)
        d += inside
    else:
        d = (px * px)[:, :, None] + (py * py)[:, None, :]
        np.sqrt(d, out=d)
        d -= layouts.radius[r, q][:, None, None]
    z, p1, p2 = np.nonzero(~(d > radius))
    free[r[z], ii[z, p1], jj[z, p2]] = False


def _l_path_free(
    free: npt.NDArray[np.bool_], s: npt.NDArray[np.intp], g: npt.NDArray[np.intp]
) -> npt.NDArray[np.bool_]:
    """Whether grid ``m``'s cells ``s[m]`` and ``g[m]`` are joined by free cells along one
    of the two L-shaped paths (first along ``i``, then ``j``, or the other way round):
    a 4-connected route, so the two share a component."""
    m, n = free.shape[0], free.shape[1]
    t = np.arange(n)
    rows = np.arange(m)[:, None]

    def run(fixed_i: Any, fixed_j: Any, a: Any, b: Any, along_i: bool) -> Any:
        lo, hi = np.minimum(a, b)[:, None], np.maximum(a, b)[:, None]
        cells = free[rows, t, fixed_j[:, None]] if along_i else free[rows, fixed_i[:, None], t]
        return np.all(cells | (t < lo) | (t > hi), axis=1)

    si, sj, gi, gj = s[:, 0], s[:, 1], g[:, 0], g[:, 1]
    i_first = run(None, sj, si, gi, True) & run(gi, None, sj, gj, False)
    j_first = run(si, None, sj, gj, False) & run(None, gj, si, gi, True)
    return i_first | j_first


def free_routes(
    layouts: LayoutArrays,
    start_xy: FloatArray,
    goal_xy: FloatArray,
    radius: float,
    half_size: float,
    resolution: float = 0.05,
) -> npt.NDArray[np.bool_]:
    """Whether a disc of ``radius`` (m) can move from ``start_xy`` to ``goal_xy`` (M, 2) among
    each robot's obstacles, for ``M`` robots at once.

    The test of :func:`~realitygap.envs.layouts.free_route_exists` on the same grid: a
    cell is free when it is inside the room by more than ``radius`` and every footprint
    is farther than ``radius`` (each footprint is rasterised only over the patch of cells
    its bounding circle can block), the start and goal cells count as free, and the two
    must share a 4-connected component (one :func:`scipy.ndimage.label` call per chunk).
    """
    from scipy import ndimage

    grid = room_grid(half_size, resolution)
    ax, ay = grid[:, 0, 0], grid[0, :, 1]
    n = ax.size
    spacing = float(ax[1] - ax[0])
    inside = (np.abs(grid[..., 0]) < half_size - radius) & (
        np.abs(grid[..., 1]) < half_size - radius
    )
    structure = np.zeros((3, 3, 3), dtype=bool)
    structure[1] = ndimage.generate_binary_structure(2, 1)
    m = layouts.is_box.shape[0]
    out = np.zeros(m, dtype=bool)
    cells = []
    for xy in (start_xy, goal_xy):
        c = np.rint((np.asarray(xy, dtype=float) + half_size) / resolution)
        ok = np.all((c >= 0) & (c < n), axis=1)
        cells.append((np.where(ok[:, None], c, 0).astype(np.intp), ok))
    (s_cell, s_ok), (g_cell, g_ok) = cells
    for lo in range(0, m, ROUTE_CHUNK):
        sl = slice(lo, min(lo + ROUTE_CHUNK, m))
        b = sl.stop - sl.start
        free = np.broadcast_to(inside, (b, n, n)).copy()
        part = layouts.select(sl)
        for shape_is_box in (True, False):
            _block_footprints(free, part, shape_is_box, ax, ay, spacing, radius, half_size)
        rows = np.arange(b)
        sc, gc = s_cell[sl], g_cell[sl]
        free[rows, sc[:, 0], sc[:, 1]] = True
        free[rows, gc[:, 0], gc[:, 1]] = True
        same = _l_path_free(free, sc, gc)  # enough to join them; else label the grid
        hard = np.flatnonzero(~same)
        if hard.size:
            labels, _ = ndimage.label(free[hard], structure=structure)
            sub, sh, gh = np.arange(hard.size), sc[hard], gc[hard]
            same[hard] = labels[sub, sh[:, 0], sh[:, 1]] == labels[sub, gh[:, 0], gh[:, 1]]
        out[sl] = same & s_ok[sl] & g_ok[sl]
    return out


def random_layouts(
    streams: RobotStreams,
    rows: npt.NDArray[np.intp],
    n_obstacles: int,
    half_size: float,
    keep_clear: FloatArray,
    clear_radius: float,
    robot_radius: float,
    max_tries: int = 200,
) -> LayoutArrays:
    """``n_obstacles`` boxes and cylinders for each robot of ``rows``, drawn from its stream
    with the draws, constraints and errors of :func:`~realitygap.envs.layouts.random_layout`.

    ``keep_clear`` (M, P, 2): points each robot's obstacles stay ``clear_radius`` (m)
    from; its first two are the start and goal a free route must join. Batched
    rejection: every robot still placing draws one candidate per round; rejected
    candidates are drawn again, accepted ones fill the robot's next slot; a finished
    layout whose route :func:`free_routes` finds blocked is drawn again whole.

    Raises
    ------
    ValueError
        If ``n_obstacles`` exceeds :func:`~realitygap.envs.layouts.obstacle_capacity`, or
        a robot's three draws in a row could not place them all.
    RuntimeError
        If a robot's layout finds no free route within ``max_tries``.
    """
    capacity = obstacle_capacity(half_size)
    if n_obstacles > capacity:
        raise ValueError(
            f"n_obstacles={n_obstacles}: a room of half-size {half_size:g} m cannot hold more "
            f"than {capacity} obstacles. Fix: fewer obstacles or a larger room_half_size"
        )
    m, k = rows.size, int(n_obstacles)
    out = LayoutArrays.empty(m, k)
    reach = np.zeros((m, k))
    placed = np.zeros(m, dtype=np.intp)
    attempts = np.zeros(m, dtype=np.intp)
    crowded = np.zeros(m, dtype=np.intp)
    tries = np.zeros(m, dtype=np.intp)
    active = np.arange(m)
    max_attempts = 50 * max(k, 1)
    lo, hi = -half_size + 0.4, half_size - 0.4
    slots = np.arange(k)
    while active.size:
        r = rows[active]
        u = streams.take(r, 4)
        cx, cy = lo + (hi - lo) * u[:, 0], lo + (hi - lo) * u[:, 1]
        height = 0.5 + (0.9 - 0.5) * u[:, 2]
        box = u[:, 3] < 0.5
        half = np.zeros((active.size, 2))
        yaw, radius = np.zeros(active.size), np.zeros(active.size)
        if box.any():
            v = streams.take(r[box], 3)
            half[box] = 0.12 + (0.4 - 0.12) * v[:, :2]
            yaw[box] = -math.pi + (math.pi - -math.pi) * v[:, 2]
        if (~box).any():
            radius[~box] = 0.1 + (0.3 - 0.1) * streams.take(r[~box], 1)[:, 0]
        attempts[active] += 1
        cand = LayoutArrays(
            box[:, None],
            np.column_stack([cx, cy])[:, None, :],
            height[:, None],
            yaw[:, None],
            half[:, None, :],
            radius[:, None],
        )
        pts = keep_clear[active]  # (A, P, 2)
        d_keep = cand.footprint_distance(pts[..., 0] - cx[:, None], pts[..., 1] - cy[:, None])
        reject = np.any(d_keep < clear_radius, axis=1)
        if k:
            mine = slots < placed[active, None]  # (A, K) slots already filled
            dx, dy = out.center[active, :, 0] - cx[:, None], out.center[active, :, 1] - cy[:, None]
            near = mine & (np.hypot(dx, dy) - reach[active] < 0.3)
            d_obs = out.select(active).footprint_distance(-dx, -dy)
            reject |= np.any(near & (d_obs < 0.3), axis=1)
        acc = np.flatnonzero(~reject & (placed[active] < k))
        a, slot = active[acc], placed[active[acc]]
        out.is_box[a, slot] = box[acc]
        out.center[a, slot] = np.column_stack([cx[acc], cy[acc]])
        out.height[a, slot] = height[acc]
        out.yaw[a, slot] = yaw[acc]
        out.half_extents[a, slot] = half[acc]
        out.radius[a, slot] = radius[acc]
        reach[a, slot] = np.where(box[acc], np.hypot(half[acc, 0], half[acc, 1]), radius[acc])
        placed[a] += 1

        full = active[placed[active] >= k]
        stuck = active[(placed[active] < k) & (attempts[active] >= max_attempts)]
        if stuck.size:
            crowded[stuck] += 1
            worst = stuck[crowded[stuck] >= 3]
            if worst.size:
                raise ValueError(
                    f"n_obstacles={n_obstacles}: the room (half-size {half_size:g} m) cannot hold "
                    f"them; at most {int(placed[worst[0]])} fitted with 0.3 m clearance and the "
                    "start and goal kept clear. Fix: fewer obstacles or a larger room_half_size"
                )
        retry = stuck
        if full.size:
            ok = free_routes(
                out.select(full),
                keep_clear[full, 0],
                keep_clear[full, 1],
                robot_radius + 0.02,
                half_size,
            )
            retry = np.concatenate([stuck, full[~ok]])
            finished = full[ok]
            active = np.setdiff1d(active, finished, assume_unique=True)
        if retry.size:
            tries[retry] += 1
            placed[retry] = 0
            attempts[retry] = 0
            if np.any(tries[retry] >= max_tries):
                raise RuntimeError(
                    f"could not draw a passable layout with {n_obstacles} obstacles in "
                    f"{max_tries} tries"
                )
    return out
