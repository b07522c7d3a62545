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
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.envs.layouts import room_walls
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
    "effect_values",
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
