r"""A fast, vectorised kinematic model of the differential drive with every effect in closed form.

Fitting effect parameters needs thousands of simulated episodes; the PyBullet
replay (:func:`realitygap.robots.diffdrive_replay.simulate_channels`) takes about a second per
minute of log, this model a few milliseconds for a whole batch of parameter sets. In the
diagnosis it is used only inside the fit: every number the diagnosis reports comes from
PyBullet replays, and the model's agreement with PyBullet is measured (figure
``surrogate_agreement.png`` of the report, and a test bounding it). The vectorised
WheeledNav (:mod:`realitygap.envs.vector_drive`) steps it one control period at a time.

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

Everything is an array over a leading batch axis of parameter sets. The
effects' parts of the model are their own surrogate terms
(:meth:`~realitygap.robots.effects.Effect.surrogate_term`), applied at the
:class:`~realitygap.robots.effects.diffdrive.SurrogateSlot` each declares; this
module composes them with what no effect changes — the firmware's inverse
kinematics, the rate limits of motors and traction, the integration of the
body's motion — and calibrates the model against PyBullet.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.cache import content_key, default_cache
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import EFFECTS, Effect, pipeline_key
from realitygap.robots.effects.diffdrive import SurrogateContext, SurrogateSlot

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "SURROGATE_EFFECTS",
    "SURROGATE_OUTPUTS",
    "DiffDriveSurrogate",
    "SurrogateCalibration",
    "SurrogateInputs",
]

SURROGATE_EFFECTS: tuple[str, ...] = tuple(
    n for n, c in EFFECTS.items() if c.robot == "diffdrive" and c.surrogate_slot is not None
)
"""Effects with a term in the surrogate (registration order), in the default library or not."""

SURROGATE_OUTPUTS: tuple[str, ...] = ("pose_gt", "ticks", "pose_cam", "pose_true")
"""The channels :meth:`DiffDriveSurrogate.simulate` can return."""

_TERMS: dict[SurrogateSlot, tuple[type[Effect], ...]] = {
    slot: tuple(
        sorted(
            (EFFECTS[n] for n in SURROGATE_EFFECTS if EFFECTS[n].surrogate_slot is slot),
            key=pipeline_key,
        )
    )
    for slot in SurrogateSlot
}
"""The effect terms of each slot, in the order the model applies them."""


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
        self,
        inputs: SurrogateInputs,
        values: Mapping[str, npt.ArrayLike],
        batch: int | None = None,
        outputs: Collection[str] | None = None,
    ) -> dict[str, FloatArray]:
        """Simulate a batch of parameter sets.

        Parameters
        ----------
        inputs : SurrogateInputs
        values : mapping of ``"effect.param"`` to array_like, shape (B,) or scalar
            Effect parameters; absent ones are nominal.
        batch : int, optional
            ``B`` when every value is a scalar.
        outputs : collection of str, optional
            The channels wanted (default all); a channel not asked for is not computed
            (a log without a camera does not pay for the camera's track).

        Returns
        -------
        dict
            ``pose_gt`` (B, N, 3) as stamped in the log, ``ticks`` (B, N, 2)
            (continuous counts), ``pose_cam`` (B, N, 3), ``pose_true`` (B, N, 3).
        """
        wanted = set(SURROGATE_OUTPUTS if outputs is None else outputs)
        unknown = wanted - set(SURROGATE_OUTPUTS)
        if unknown:
            raise ValueError(
                f"DiffDriveSurrogate.simulate: unknown output(s) {sorted(unknown)}; "
                f"expected some of {', '.join(SURROGATE_OUTPUTS)}"
            )
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
        ctx = SurrogateContext(dt=dt, params=P)

        def term(slot: SurrogateSlot, x: Any) -> Any:
            for cls in _TERMS[slot]:
                x = cls.surrogate_term(
                    x, {s.name: val(f"{cls.name}.{s.name}") for s in cls.specs}, ctx
                )
            return x

        enc_l, enc_r = term(SurrogateSlot.ENCODER_GAIN, (np.ones(B), np.ones(B)))

        # ---------------------------------------------------- wheel-speed targets (B, N)
        if inputs.commands is not None:
            u = np.asarray(inputs.commands, dtype=float)
            ud = np.broadcast_to(term(SurrogateSlot.COMMAND_TWIST, u), (B, n, 2))
            sl = ud[..., 0] - ud[..., 1] * hb0
            sr = ud[..., 0] + ud[..., 1] * hb0
            sl, sr = term(SurrogateSlot.WHEEL_SPEED, (sl, sr))
            wl, wr = sl / r0l, sr / r0r
            wl[:, -1] = 0.0
            wr[:, -1] = 0.0
        else:
            assert inputs.ticks is not None
            ang = np.asarray(inputs.ticks, dtype=float) * (2.0 * math.pi / P.ticks_per_rev)
            rate = np.zeros((n, 2))
            rate[:-1] = np.diff(ang, axis=0) / dt
            wl = rate[None, :, 0] / enc_l[:, None]
            wr = rate[None, :, 1] / enc_r[:, None]
        ov = self.calibration.motor_overshoot
        if ov:
            wl = wl + ov * np.sign(wl)
            wr = wr + ov * np.sign(wr)

        # ---------------------------------------------------- drive (B, N)
        rl, rr = (
            np.broadcast_to(np.asarray(r, dtype=float), (B,))
            for r in term(SurrogateSlot.WHEEL_RADII, (r0l, r0r))
        )
        tgt_l = wl * rl[:, None]
        tgt_r = wr * rr[:, None]
        mu = term(SurrogateSlot.TRACTION, np.full(B, float(P.wheel_friction)))
        lim = self.accel_limits(mu)
        gnd_l, gnd_r = term(SurrogateSlot.GROUND_SPEED, (tgt_l, tgt_r))
        disp_l, disp_r = self._rate_limited(
            np.asarray(gnd_l, dtype=float),
            np.asarray(gnd_r, dtype=float),
            lim["ground_c"],
            lim["ground_d"],
            dt,
        )
        roll_l, roll_r = self._rate_limited(tgt_l, tgt_r, lim["wheel_c"], lim["wheel_d"], dt)

        # ---------------------------------------------------- encoders (B, N, 2)
        k_ticks = P.ticks_per_rev / (2.0 * math.pi)
        ang_l = np.concatenate(
            [np.zeros((B, 1)), np.cumsum(roll_l[:, :-1], axis=1) / rl[:, None]], axis=1
        )
        ang_r = np.concatenate(
            [np.zeros((B, 1)), np.cumsum(roll_r[:, :-1], axis=1) / rr[:, None]], axis=1
        )
        ticks = np.stack(
            [ang_l * (k_ticks * enc_l)[:, None], ang_r * (k_ticks * enc_r)[:, None]], axis=-1
        )

        # ---------------------------------------------------- body (B, N, 3)
        b = np.broadcast_to(np.asarray(term(SurrogateSlot.WHEELBASE, b0), dtype=float), (B,))
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

        out: dict[str, FloatArray] = {"pose_true": pose, "ticks": ticks}
        # ---------------------------------------------------- camera, stamps
        if "pose_cam" in wanted:
            cam = P.camera
            mx, my, myaw = (
                np.broadcast_to(np.asarray(m, dtype=float), (B,))
                for m in term(
                    SurrogateSlot.CAMERA_MOUNT,
                    (cam.mount_xyz[0], cam.mount_xyz[1], cam.mount_yaw),
                )
            )
            c, s = np.cos(heading), np.sin(heading)
            out["pose_cam"] = np.stack(
                [
                    x + c * mx[:, None] - s * my[:, None],
                    y + s * mx[:, None] + c * my[:, None],
                    heading + myaw[:, None],
                ],
                axis=-1,
            )
        if "pose_gt" in wanted:
            out["pose_gt"] = term(SurrogateSlot.STAMPS, pose)
        return {k: v for k, v in out.items() if k in wanted}

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
    memory and in the content-addressed cache of :mod:`realitygap.core.cache`
    (keyed by :data:`CALIBRATION_VERSION`, the body's URDF and parameters, the solver
    setting and the PyBullet version).
    """
    from realitygap.robots.diffdrive_replay import simulate_channels  # PyBullet only here
    from realitygap.robots.effects import Reality, make_effect
    from realitygap.robots.simulation import SimSettings

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
        channels, _ = simulate_channels(
            t, params=params, commands=cmd, settings=settings, reality=reality
        )
        return {k: np.array(v, dtype=float) for k, v in channels.items()}

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


CALIBRATION_VERSION = 2
"""Version of the calibration procedure and of the drive model it measures.

Part of the disk-cache key together with the body (its URDF and parameters),
the solver setting and the PyBullet version. Raise it whenever
:func:`calibrate` or the simulated drive (motors, contacts) changes in a way the
URDF does not show, so that stale cached constants are not used.
"""


_CALIBRATION_CACHE = "surrogate_calibration"


def _cache_key(params: DiffDriveParams, solver_iterations: int) -> str:
    """Content key of a calibration (:mod:`realitygap.core.cache`): :data:`CALIBRATION_VERSION`,
    the body's URDF and parameters, the solver setting and the PyBullet version."""
    from realitygap.robots.diffdrive import urdf_from_params
    from realitygap.robots.world import physics_engine_version

    return content_key(
        urdf_from_params(params),
        repr(params),
        int(solver_iterations),
        CALIBRATION_VERSION,
        physics_engine_version(),
    )


def _load_cached(params: DiffDriveParams, solver_iterations: int) -> SurrogateCalibration | None:
    store = default_cache()
    if store is None:
        return None
    hit = store.get(_CALIBRATION_CACHE, _cache_key(params, solver_iterations))
    names = [f.name for f in dataclasses.fields(SurrogateCalibration)]
    if hit is None or any(n not in hit or hit[n].shape != () for n in names):
        return None
    return SurrogateCalibration(**{n: float(hit[n]) for n in names})


def _store_cached(
    params: DiffDriveParams, solver_iterations: int, cal: SurrogateCalibration
) -> None:
    store = default_cache()
    if store is not None:
        store.put(
            _CALIBRATION_CACHE,
            _cache_key(params, solver_iterations),
            {k: np.float64(v) for k, v in dataclasses.asdict(cal).items()},
        )
