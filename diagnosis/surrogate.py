r"""A fast, vectorised kinematic model of the differential drive with every effect in closed form.

Fitting effect parameters needs thousands of simulated episodes; the PyBullet
replay (:mod:`realitygap.diagnosis.replay`) takes about a second per minute of
log, this model a few milliseconds for a whole batch of parameter sets. It is
used only inside the fit: every number the diagnosis reports comes from
PyBullet replays, and the model's agreement with PyBullet is measured
(:func:`agreement`, figure ``surrogate_agreement.png`` of the report, and a test
bounding it).

Model, per control period ``dt`` with the twist ``u_k = [v_k, ω_k]`` issued at
``t_k`` (zero-order hold):

1. command stage — latency ``d``: :math:`u'_k = (1-f)\,u_{k-K} + f\,u_{k-K-1}`
   with ``K + f = d / dt``; firmware inverse kinematics with the nominal
   geometry, :math:`s_{L,R} = v' \mp \omega' b_0/2`; dead-band ``δ``:
   :math:`s = 0` if :math:`|s| < δ`; saturation: :math:`s \in [-s_{max}, s_{max}]`;
   wheel speed targets :math:`\Omega = s / r_0`.
2. drive — the velocity motors reach the target within the period, plus the
   calibrated overshoot of PyBullet's motors (:class:`SurrogateCalibration`);
   the contact points' ground speeds :math:`g = \Omega\, r` (true radii: scale,
   :math:`E_d`) follow at most at the traction limit
   :math:`a = \mu g_0 / (1 + \mu h / l)` (exact piecewise-linear ramp inside
   the period).
3. body — :math:`v = (g_L + g_R)/2`, :math:`\omega = (g_R - g_L)/b` (true
   wheelbase, :math:`E_b b_0`), integrated as circular arcs.
4. sensors — encoder counts :math:`\theta_{wheel}\, c\, N / 2\pi` (encoder
   scale ``c``); ground truth stamped ``Δ`` late (timestamp offset); the
   camera at the (offset) mount, :math:`T_{world,cam} = T_{world,base} \oplus m`.

Everything is an array over a leading batch axis of parameter sets.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import EFFECTS

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "SURROGATE_EFFECTS",
    "DiffDriveSurrogate",
    "SurrogateCalibration",
    "SurrogateInputs",
]

SURROGATE_EFFECTS: tuple[str, ...] = (
    "wheel_radius_scale",
    "wheel_diameter_ratio",
    "wheelbase_error",
    "longitudinal_slip",
    "command_latency",
    "motor_deadband",
    "velocity_saturation",
    "encoder_scale",
    "camera_mount_offset",
    "timestamp_offset",
)
"""Effects the surrogate expresses analytically."""


@dataclass(frozen=True)
class SurrogateCalibration:
    """Constants that make the kinematic model follow PyBullet's motors and contacts.

    Measured by :func:`calibrate` on the nominal body at a solver setting.

    Attributes
    ----------
    motor_overshoot : float
        rad/s by which PyBullet's velocity motors settle above a non-zero
        wheel-speed target, in its direction.
    motor_accel_common, motor_accel_diff : float
        Largest common / differential acceleration of the wheel surfaces that
        the motors' torque gives the loaded robot, m/s² (driving straight /
        turning in place).
    traction_common, traction_diff : float
        Friction-limited common / differential ground acceleration per unit
        friction coefficient at light load, m/s²; the limit is
        :math:`k μ / (1 + h μ)`.
    load_transfer : float
        ``h`` above: under hard acceleration the body pitches onto a caster
        and unloads the wheels.
    """

    motor_overshoot: float = 0.0
    motor_accel_common: float = math.inf
    motor_accel_diff: float = math.inf
    traction_common: float = math.inf
    traction_diff: float = math.inf
    load_transfer: float = 0.0


@dataclass(frozen=True)
class SurrogateInputs:
    """What the surrogate needs from one log.

    Attributes
    ----------
    dt : float
        Control period, s.
    start : ndarray, shape (3,)
        Initial pose (m, m, rad).
    commands : ndarray, shape (N, 2) or None
        Applied body twists (m/s, rad/s) for a command-driven run.
    ticks : ndarray, shape (N, 2) or None
        Logged cumulative encoder counts for a tick-driven run.
    """

    dt: float
    start: FloatArray
    commands: FloatArray | None = None
    ticks: FloatArray | None = None

    @property
    def n(self) -> int:
        arr = self.commands if self.commands is not None else self.ticks
        assert arr is not None
        return int(arr.shape[0])


def _shift(u: FloatArray, steps: FloatArray) -> FloatArray:
    """Delay series ``u`` (N, k) by fractional ``steps`` (B,) → (B, N, k), zeros before the start."""
    n = u.shape[0]
    K = np.floor(steps).astype(int)
    f = (steps - K)[:, None, None]
    idx = np.arange(n)[None, :] - K[:, None]
    pad = np.concatenate([np.zeros((1, u.shape[1])), u], axis=0)  # index 0 = "before start"
    a = pad[np.clip(idx + 1, 0, n)]
    b = pad[np.clip(idx, 0, n)]
    return (1.0 - f) * a + f * b


def _shift_back(t_idx_shift: FloatArray, series: FloatArray) -> FloatArray:
    """Evaluate ``series`` (B, N, k) at fractional row ``k − shift`` (B,), clamped at both ends."""
    B, n, _ = series.shape
    pos = np.arange(n)[None, :] - t_idx_shift[:, None]
    pos = np.clip(pos, 0.0, n - 1.0)
    i0 = np.floor(pos).astype(int)
    i1 = np.minimum(i0 + 1, n - 1)
    f = (pos - i0)[..., None]
    rows = np.arange(B)[:, None]
    return (1.0 - f) * series[rows, i0] + f * series[rows, i1]


class DiffDriveSurrogate:
    """Batch kinematic model of a differential drive (see the module docstring).

    Parameters
    ----------
    params : DiffDriveParams
        Nominal parameters (what the firmware believes).
    calibration : SurrogateCalibration, optional
    """

    def __init__(self, params: DiffDriveParams, calibration: SurrogateCalibration | None = None):
        self.params = params
        self.calibration = calibration if calibration is not None else SurrogateCalibration()

    @staticmethod
    def defaults() -> dict[str, float]:
        """Nominal value of every ``"effect.param"`` the model knows."""
        out = {}
        for name in SURROGATE_EFFECTS:
            for s in EFFECTS[name].specs:
                out[f"{name}.{s.name}"] = s.nominal
        return out

    def accel_limits(self, mu: npt.ArrayLike) -> dict[str, FloatArray]:
        """Rate limits (m/s²) for friction ``mu`` (B,): ground and wheel, common and differential.

        The ground follows the smaller of the motor and friction limits; the
        wheels turn with the ground while they grip and spin up at once
        (infinite limit) when friction is the tighter limit.
        """
        cal = self.calibration
        mu = np.asarray(mu, dtype=float)
        load = 1.0 / (1.0 + cal.load_transfer * mu)
        trac_c, trac_d = cal.traction_common * mu * load, cal.traction_diff * mu * load
        mot_c = np.full_like(mu, cal.motor_accel_common)
        mot_d = np.full_like(mu, cal.motor_accel_diff)
        # the wheels can only spin on the floor if a motor's force exceeds the friction force
        P = self.params
        mass = P.body_mass + 2.0 * P.wheel_mass
        r = 0.5 * (P.wheel_radius_left + P.wheel_radius_right)
        grip_c = 2.0 * P.motor_max_torque / (r * mass)
        grip_d = grip_c * cal.motor_accel_diff / max(cal.motor_accel_common, 1e-12)
        return {
            "ground_c": np.minimum(mot_c, trac_c),
            "ground_d": np.minimum(mot_d, trac_d),
            "wheel_c": np.where(trac_c < grip_c, np.inf, mot_c),
            "wheel_d": np.where(trac_d < grip_d, np.inf, mot_d),
        }

    def simulate(
        self, inputs: SurrogateInputs, values: Mapping[str, npt.ArrayLike], batch: int | None = None
    ) -> dict[str, FloatArray]:
        """Simulate a batch of parameter sets.

        Parameters
        ----------
        inputs : SurrogateInputs
        values : mapping of ``"effect.param"`` to array_like, shape (B,) or scalar
            Effect parameters; absent ones are nominal.
        batch : int, optional
            ``B`` when every value is a scalar.

        Returns
        -------
        dict
            ``pose_gt`` (B, N, 3) as stamped in the log, ``ticks`` (B, N, 2)
            (continuous counts), ``pose_cam`` (B, N, 3), ``pose_true`` (B, N, 3).
        """
        P = self.params
        dt = float(inputs.dt)
        n = inputs.n
        sizes = {np.size(v) for v in values.values()} | ({batch} if batch else set())
        sizes.discard(1)
        if len(sizes) > 1:
            raise ValueError(f"effect parameter arrays have different batch sizes {sizes}")
        B = sizes.pop() if sizes else 1
        d = self.defaults()
        unknown = set(values) - set(d)
        if unknown:
            raise KeyError(f"surrogate has no parameter(s) {sorted(unknown)}; known: {sorted(d)}")

        def val(key: str) -> FloatArray:
            v = values.get(key, d[key])
            return np.broadcast_to(np.asarray(v, dtype=float).reshape(-1), (B,)).astype(float)

        r0l, r0r, b0 = P.wheel_radius_left, P.wheel_radius_right, P.wheelbase
        hb0 = b0 / 2.0
        enc = val("encoder_scale.scale")

        # ---------------------------------------------------- wheel-speed targets (B, N)
        if inputs.commands is not None:
            u = np.asarray(inputs.commands, dtype=float)
            delay = val("command_latency.delay")
            if np.any(delay > 0):
                ud = _shift(u, delay / dt)
            else:
                ud = np.broadcast_to(u[None], (B, n, 2))
            sl = ud[..., 0] - ud[..., 1] * hb0
            sr = ud[..., 0] + ud[..., 1] * hb0
            thr = val("motor_deadband.threshold")[:, None]
            if np.any(thr > 0):
                sl = np.where(np.abs(sl) < thr, 0.0, sl)
                sr = np.where(np.abs(sr) < thr, 0.0, sr)
            v_lim = val("velocity_saturation.v_limit")[:, None]
            if np.any(v_lim < 9.99):
                sl = np.clip(sl, -v_lim, v_lim)
                sr = np.clip(sr, -v_lim, v_lim)
            wl, wr = sl / r0l, sr / r0r
            wl[:, -1] = 0.0
            wr[:, -1] = 0.0
        else:
            assert inputs.ticks is not None
            ang = np.asarray(inputs.ticks, dtype=float) * (2.0 * math.pi / P.ticks_per_rev)
            rate = np.zeros((n, 2))
            rate[:-1] = np.diff(ang, axis=0) / dt
            wl = rate[None, :, 0] / enc[:, None]
            wr = rate[None, :, 1] / enc[:, None]
        ov = self.calibration.motor_overshoot
        if ov:
            wl = wl + ov * np.sign(wl)
            wr = wr + ov * np.sign(wr)

        # ---------------------------------------------------- drive (B, N)
        scale = val("wheel_radius_scale.scale")
        e_d = val("wheel_diameter_ratio.E_d")
        mean_r = (r0l + r0r) / 2.0
        rl = 2.0 * mean_r / (e_d + 1.0) * (r0l / mean_r) * scale
        rr = 2.0 * mean_r * e_d / (e_d + 1.0) * (r0r / mean_r) * scale
        tgt_l = wl * rl[:, None]
        tgt_r = wr * rr[:, None]
        lim = self.accel_limits(val("longitudinal_slip.mu"))
        disp_l, disp_r = self._rate_limited(tgt_l, tgt_r, lim["ground_c"], lim["ground_d"], dt)
        roll_l, roll_r = self._rate_limited(tgt_l, tgt_r, lim["wheel_c"], lim["wheel_d"], dt)

        # ---------------------------------------------------- encoders (B, N, 2)
        k_ticks = P.ticks_per_rev / (2.0 * math.pi)
        ang_l = np.concatenate(
            [np.zeros((B, 1)), np.cumsum(roll_l[:, :-1], axis=1) / rl[:, None]], axis=1
        )
        ang_r = np.concatenate(
            [np.zeros((B, 1)), np.cumsum(roll_r[:, :-1], axis=1) / rr[:, None]], axis=1
        )
        ticks = np.stack([ang_l, ang_r], axis=-1) * (k_ticks * enc)[:, None, None]

        # ---------------------------------------------------- body (B, N, 3)
        b = b0 * val("wheelbase_error.E_b")
        ds = 0.5 * (disp_l + disp_r)
        dth = (disp_r - disp_l) / b[:, None]
        start = np.asarray(inputs.start, dtype=float)
        heading = start[2] + np.concatenate(
            [np.zeros((B, 1)), np.cumsum(dth[:, :-1], axis=1)], axis=1
        )
        mid = heading[:, :-1] + 0.5 * dth[:, :-1]
        chord = ds[:, :-1] * np.sinc(dth[:, :-1] / (2.0 * math.pi))
        x = start[0] + np.concatenate(
            [np.zeros((B, 1)), np.cumsum(chord * np.cos(mid), axis=1)], axis=1
        )
        y = start[1] + np.concatenate(
            [np.zeros((B, 1)), np.cumsum(chord * np.sin(mid), axis=1)], axis=1
        )
        pose = np.stack([x, y, heading], axis=-1)

        # ---------------------------------------------------- camera, stamps
        cam = P.camera
        mx = cam.mount_xyz[0] + val("camera_mount_offset.dx")
        my = cam.mount_xyz[1] + val("camera_mount_offset.dy")
        myaw = cam.mount_yaw + val("camera_mount_offset.dyaw")
        c, s = np.cos(heading), np.sin(heading)
        pose_cam = np.stack(
            [
                x + c * mx[:, None] - s * my[:, None],
                y + s * mx[:, None] + c * my[:, None],
                heading + myaw[:, None],
            ],
            axis=-1,
        )
        off = val("timestamp_offset.offset")
        pose_gt = _shift_back(off / dt, pose) if np.any(off != 0) else pose
        return {"pose_gt": pose_gt, "ticks": ticks, "pose_cam": pose_cam, "pose_true": pose}

    @staticmethod
    def _rate_limited(
        tgt_l: FloatArray,
        tgt_r: FloatArray,
        a_c: FloatArray,
        a_d: FloatArray,
        dt: float,
    ) -> tuple[FloatArray, FloatArray]:
        r"""Per-period travel of each wheel under a shared acceleration budget, (B, N) m.

        The common speed ``c = (g_L + g_R)/2`` and differential speed
        ``d = (g_R − g_L)/2`` move from where they are towards the period's
        targets along a straight line in ``(c, d)``, taking

        .. math::  T = |Δc| / a_c + |Δd| / a_d

        (each wheel's torque or friction budget is shared between speeding up
        and turning). If :math:`T \le dt` the targets are reached within the
        period and the travel is :math:`c_{tgt}\,dt - Δc\,T/2`; otherwise the
        speeds get the fraction :math:`dt/T` of the way and the remainder
        carries into the next period (evaluated step by step only there).
        """
        tc = 0.5 * (tgt_l + tgt_r)
        td = 0.5 * (tgt_r - tgt_l)
        B, n = tc.shape
        prev_c = np.concatenate([np.zeros((B, 1)), tc[:, :-1]], axis=1)
        prev_d = np.concatenate([np.zeros((B, 1)), td[:, :-1]], axis=1)
        inv_c = np.where(np.isinf(a_c), 0.0, 1.0 / np.maximum(a_c, 1e-300))[:, None]
        inv_d = np.where(np.isinf(a_d), 0.0, 1.0 / np.maximum(a_d, 1e-300))[:, None]
        dc, dd = tc - prev_c, td - prev_d
        T = np.abs(dc) * inv_c + np.abs(dd) * inv_d
        Tc = np.minimum(T, dt)
        disp_c = tc * dt - 0.5 * dc * Tc
        disp_d = td * dt - 0.5 * dd * Tc
        carry = (T > dt * (1.0 + 1e-12)).any(axis=0)
        starts = np.flatnonzero(carry)
        if starts.size:
            k = int(starts[0])
            c = prev_c[:, k].copy()
            d = prev_d[:, k].copy()
            while k < n:
                gc, gd = tc[:, k] - c, td[:, k] - d
                T_k = np.abs(gc) * inv_c[:, 0] + np.abs(gd) * inv_d[:, 0]
                frac = np.where(T_k > dt, dt / np.maximum(T_k, 1e-300), 1.0)
                tau = np.minimum(T_k, dt)
                c_end, d_end = c + gc * frac, d + gd * frac
                disp_c[:, k] = 0.5 * (c + c_end) * tau + c_end * (dt - tau)
                disp_d[:, k] = 0.5 * (d + d_end) * tau + d_end * (dt - tau)
                c, d = c_end, d_end
                if np.all(T_k <= dt):
                    later = starts[starts > k]
                    if later.size == 0:
                        break
                    k = int(later[0])
                    c = prev_c[:, k].copy()
                    d = prev_d[:, k].copy()
                    continue
                k += 1
        return disp_c - disp_d, disp_c + disp_d


_CALIBRATIONS: dict[tuple[object, ...], SurrogateCalibration] = {}


def _fit_rate(
    params: DiffDriveParams,
    runs: Sequence[tuple[FloatArray, FloatArray, Mapping[str, float]]],
    dt: float,
    column: int,
    channel: str,
    make: Callable[[float], SurrogateCalibration],
) -> tuple[float, float]:
    """1-D fit of one calibration constant: surrogate ``channel[:, column]`` against PyBullet.

    ``runs`` holds ``(commands, target series, effect values)``; returns the
    best constant and its sum of squared errors.
    """

    def err(a: float) -> float:
        total = 0.0
        for cmd, target, values in runs:
            out = DiffDriveSurrogate(params, make(a)).simulate(
                SurrogateInputs(dt, np.zeros(3), commands=cmd), values
            )
            total += float(np.sum((out[channel][0, :, column] - target) ** 2))
        return total

    grid = np.geomspace(0.05, 80.0, 41)
    errs = [err(a) for a in grid]
    i = int(np.argmin(errs))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    fine = np.linspace(lo, hi, 15)
    fine_errs = [err(a) for a in fine]
    j = int(np.argmin(fine_errs))
    return float(fine[j]), float(fine_errs[j])


def calibrate(params: DiffDriveParams, solver_iterations: int = 0) -> SurrogateCalibration:
    """Measure :class:`SurrogateCalibration` for ``params`` on the PyBullet body.

    Short runs are simulated — a hard start and stop straight ahead and
    turning in place, at the nominal friction and at two low frictions — and
    the constants fitted one at a time: the motors' overshoot from the steady
    wheel rotation, the motor limits from the encoder counts at nominal
    friction, the friction limits (and the load transfer) from the poses at
    low friction. Results are cached per parameter set and solver setting, in
    memory and on disk (``$REALITYGAP_CACHE`` or ``~/.cache/realitygap``, keyed
    by the body's URDF, the robot code and the solver setting).
    """
    from realitygap.diagnosis.replay import SimSettings, simulate  # PyBullet only here
    from realitygap.robots.effects import Reality, make_effect

    settings = SimSettings(solver_iterations=int(solver_iterations))
    key = (params, settings.solver_iterations)
    if key in _CALIBRATIONS:
        return _CALIBRATIONS[key]
    cached = _load_cached(params, settings.solver_iterations)
    if cached is not None:
        _CALIBRATIONS[key] = cached
        return cached
    dt = 0.05
    t = np.arange(0.0, 2.0, dt)
    n = t.shape[0]
    mean_r = (params.wheel_radius_left + params.wheel_radius_right) / 2.0
    v_step = 0.4
    w_step = 0.3 / (params.wheelbase / 2.0)
    fwd = np.zeros((n, 2))
    fwd[: n // 2, 0] = v_step
    turn = np.zeros((n, 2))
    turn[: n // 2, 1] = w_step
    mus = (0.1, 0.3)

    def run(cmd: FloatArray, mu: float | None) -> dict[str, FloatArray]:
        reality = None if mu is None else Reality((make_effect("longitudinal_slip", mu=mu),))
        log = simulate(t, params=params, commands=cmd, settings=settings, reality=reality)
        return {k: np.asarray(v) for k, v in log.channels.items()}

    nom_f, nom_t = run(fwd, None), run(turn, None)
    ang = nom_f["ticks"] * (2.0 * math.pi / params.ticks_per_rev)
    q = slice(n // 4, n // 2 - 1)
    rate = float(np.mean(np.diff(ang[q], axis=0)) / dt)
    overshoot = max(0.0, rate - v_step / mean_r)
    nominal = {"longitudinal_slip.mu": float(params.wheel_friction)}
    a_mc, _ = _fit_rate(
        params,
        [(fwd, nom_f["ticks"][:, 0], nominal)],
        dt,
        0,
        "ticks",
        lambda a: SurrogateCalibration(overshoot, a, math.inf),
    )
    a_md, _ = _fit_rate(
        params,
        [(turn, nom_t["ticks"][:, 1], nominal)],
        dt,
        1,
        "ticks",
        lambda a: SurrogateCalibration(overshoot, a_mc, a),
    )
    low_f = [(fwd, run(fwd, mu)["pose_gt"][:, 0], {"longitudinal_slip.mu": mu}) for mu in mus]
    low_t = [(turn, run(turn, mu)["pose_gt"][:, 2], {"longitudinal_slip.mu": mu}) for mu in mus]
    best: tuple[float, float, float, float] | None = None

    def with_common(h: float) -> Callable[[float], SurrogateCalibration]:
        return lambda a: SurrogateCalibration(overshoot, a_mc, a_md, a, math.inf, h)

    def with_diff(h: float, k_c: float) -> Callable[[float], SurrogateCalibration]:
        return lambda a: SurrogateCalibration(overshoot, a_mc, a_md, k_c, a, h)

    for h in (0.0, 0.25, 0.5, 1.0):
        k_c, e_c = _fit_rate(params, low_f, dt, 0, "pose_gt", with_common(h))
        k_d, e_d = _fit_rate(params, low_t, dt, 2, "pose_gt", with_diff(h, k_c))
        score = e_c / max(float(np.sum(low_f[0][1] ** 2)), 1e-12) + e_d / max(
            float(np.sum(low_t[0][1] ** 2)), 1e-12
        )
        if best is None or score < best[0]:
            best = (score, k_c, k_d, h)
    assert best is not None
    cal = SurrogateCalibration(
        motor_overshoot=overshoot,
        motor_accel_common=a_mc,
        motor_accel_diff=a_md,
        traction_common=best[1],
        traction_diff=best[2],
        load_transfer=best[3],
    )
    _CALIBRATIONS[key] = cal
    _store_cached(params, settings.solver_iterations, cal)
    return cal


CALIBRATION_VERSION = 1


def _cache_path(params: DiffDriveParams, solver_iterations: int) -> Path | None:
    """Cache file of a calibration: keyed by the body (URDF), the robot code and the solver."""
    import hashlib
    import inspect

    import pybullet

    from realitygap.robots import diffdrive

    root = os.environ.get("REALITYGAP_CACHE")
    base = Path(root) if root else Path.home() / ".cache" / "realitygap"
    h = hashlib.sha256()
    for part in (
        diffdrive.urdf_from_params(params),
        inspect.getsource(diffdrive),
        repr(params),
        str(solver_iterations),
        str(CALIBRATION_VERSION),
        str(getattr(pybullet, "__version__", "")),
    ):
        h.update(part.encode("utf-8"))
    return base / f"surrogate-calibration-{h.hexdigest()[:24]}.json"


def _load_cached(params: DiffDriveParams, solver_iterations: int) -> SurrogateCalibration | None:
    try:
        path = _cache_path(params, solver_iterations)
        if path is None or not path.is_file():
            return None
        data = json.loads(path.read_text(encoding="utf-8"))
        return SurrogateCalibration(**{k: float(v) for k, v in data.items()})
    except (OSError, ValueError, TypeError):
        return None


def _store_cached(
    params: DiffDriveParams, solver_iterations: int, cal: SurrogateCalibration
) -> None:
    try:
        path = _cache_path(params, solver_iterations)
        if path is None:
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(dataclasses.asdict(cal)), encoding="utf-8")
        os.replace(tmp, path)
    except OSError:
        pass
