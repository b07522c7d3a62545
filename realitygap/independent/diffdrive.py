"""An independent differential-drive simulator that writes OptiOdom session folders.

Nothing here comes from the rest of the package: the kinematics, the firmware,
the motors, the wheel–floor contact, the encoders and the motion capture are
written from first principles in plain numpy, and the files are written from
the OptiOdom on-disk format (Sousa et al., J. Intell. Robot. Syst. 105:39, 2022).

The simulated robot
-------------------
A path planner issues a request ``(v, ω)`` every control cycle ``Δ`` (50 ms by
default, :attr:`DriveRobot.cycle`), in the robot's own units (ticks/cycle,
rad/cycle). The firmware turns it into wheel-speed set-points

.. math:: s_{R,L} = v \\pm \\frac{\\omega\\, b_0}{2\\, m_0}

(``b_0`` nominal wheelbase, ``m_0`` nominal metres per tick). By default
(``ramp="wheels"``) it rate-limits each *wheel* set-point by ``DV`` ticks/cycle² —
its ramp acts on the wheels, not on the body twist; the ``DWMAX`` written to the
header is the equivalent limit of a turn in place, :math:`2\\,DV\\,m_0/b_0`. With
``ramp="body"`` it rate-limits the requested ``v`` by ``DV`` and ``ω`` by its own
``DWMAX`` (:attr:`DriveRobot.angular_ramp`) before splitting them into wheel
set-points, as a twist-level speed limiter does. Each wheel motor follows its set-point
with a first-order lag,

.. math:: \\tau\\, \\dot\\varphi = \\varphi^* - \\dot\\varphi ,

integrated at a fine internal step (1 ms). Rim speeds become ground speeds
through the wheel radius (optionally periodic in the wheel angle) and a creep
term; the body moves as a unicycle,

.. math:: v = \\tfrac12 (u_R + u_L),\\quad \\omega = (u_R - u_L)/b .

The planner follows its path on the robot's own odometry (as UMBmark is driven):
a square's side ends when the odometry has covered it (less the braking
distance), and each corner waits until the encoders have been still for 0.4 s.

Encoders count ``floor(φ · cpr / 2π)`` edges (quantised); the run files hold the
per-cycle increments. Motion capture samples the pose of its marker body at its
own rate (100 Hz by default, first sample ``mocap_phase`` s after the run start)
with Gaussian noise and a fixed latency; each row of the cycle rate holds the most
recent sample (zero-order hold). Named sets of these conventions (robot size,
rates, noise) are in :mod:`realitygap.independent.variants`.

Hidden effects are the fields of :class:`Hidden`; every one is neutral by default.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "DriveRobot",
    "Hidden",
    "RunRecord",
    "circle_path",
    "free_path",
    "simulate_run",
    "square_path",
    "write_session",
]

G = 9.81


@dataclass(frozen=True)
class DriveRobot:
    """Nominal robot, firmware, sensors (what the session's files declare, plus sensor noise).

    Attributes
    ----------
    diameter : float
        Nominal wheel diameter, m.
    wheelbase : float
        Nominal wheelbase, m.
    gear, enc_res : float
        Gear ratio and encoder counts per motor turn (ticks per wheel turn = product).
    cycle : float
        Control cycle, s.
    v_nom : float
        Cruise request, ticks/cycle.
    w_nom : float
        Turn request, rad/cycle.
    dv_max : float
        Firmware ramp of each wheel set-point, ticks/cycle².
    motor_tau : float
        Motor time constant, s.
    substep : float
        Internal integration step, s.
    mocap_rate : float
        Motion-capture rate, Hz.
    mocap_latency : float
        Age of a motion-capture sample when it is stamped, s.
    mocap_pos_sigma, mocap_yaw_sigma : float
        Motion-capture noise, m and rad (one standard deviation).
    mocap_phase : float
        Time of the first motion-capture sample after the run start, s, in
        ``[0, 1/mocap_rate)``: the camera clock is not locked to the control cycle.
    ramp : {"wheels", "body"}
        What the firmware rate-limits: each wheel set-point by ``dv_max``, or the body
        twist — ``v`` by ``dv_max`` and ``ω`` by :attr:`dw_max`.
    angular_ramp : float or None
        ``ramp="body"``: limit of ``ω``'s change, rad/cycle²; None: the wheel ramp's
        equivalent for a turn in place (and always so with ``ramp="wheels"``).
    """

    diameter: float = 0.084
    wheelbase: float = 0.2
    gear: float = 43.7
    enc_res: float = 64.0
    cycle: float = 0.05
    v_nom: float = 60.0
    w_nom: float = 0.025
    dv_max: float = 2.0
    motor_tau: float = 0.045
    substep: float = 0.001
    mocap_rate: float = 100.0
    mocap_latency: float = 0.003
    mocap_pos_sigma: float = 3e-4
    mocap_yaw_sigma: float = 1.5e-3
    mocap_phase: float = 0.0
    ramp: str = "wheels"
    angular_ramp: float | None = None

    def __post_init__(self) -> None:
        for name in (
            "diameter",
            "wheelbase",
            "gear",
            "enc_res",
            "cycle",
            "v_nom",
            "dv_max",
            "mocap_rate",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"DriveRobot.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("mocap_latency", "mocap_pos_sigma", "mocap_yaw_sigma"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"DriveRobot.{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.mocap_phase < 1.0 / self.mocap_rate:
            raise ValueError(
                f"DriveRobot.mocap_phase must lie in [0, 1/mocap_rate = {1.0 / self.mocap_rate:g}) "
                f"s, got {self.mocap_phase!r}"
            )
        if self.ramp not in ("wheels", "body"):
            raise ValueError(f"DriveRobot.ramp must be 'wheels' or 'body', got {self.ramp!r}")
        if self.angular_ramp is not None and (self.ramp != "body" or not self.angular_ramp > 0):
            raise ValueError(
                "DriveRobot.angular_ramp is a limit > 0 rad/cycle² of a body ramp "
                f"(ramp='body'); got angular_ramp={self.angular_ramp!r} with ramp={self.ramp!r}"
            )
        if not 0 < self.substep <= self.cycle:
            raise ValueError(
                f"DriveRobot.substep must lie in (0, cycle={self.cycle}], got {self.substep!r}"
            )

    @property
    def ticks_per_rev(self) -> float:
        """Nominal encoder ticks per wheel revolution."""
        return self.gear * self.enc_res

    @property
    def m_per_tick(self) -> float:
        """Nominal wheel travel per tick, m."""
        return math.pi * self.diameter / self.ticks_per_rev

    @property
    def dw_max(self) -> float:
        """Header's angular ramp (rad/cycle²): :attr:`angular_ramp`, else a turn in place
        under the wheel ramp."""
        if self.angular_ramp is not None:
            return self.angular_ramp
        return 2.0 * self.dv_max * self.m_per_tick / self.wheelbase

    @property
    def cruise_speed(self) -> float:
        """Cruise request in m/s (``v_nom`` ticks/cycle on the nominal wheels)."""
        return self.v_nom * self.m_per_tick / self.cycle


@dataclass(frozen=True)
class Hidden:
    """What the real robot does differently from its declared model (all neutral by default).

    Attributes (units in brackets)
    ------------------------------
    d_right, d_left : true wheel diameter / nominal [1]
    b_true : true wheelbase / nominal [1]
    delay : time a set-point takes to reach the motor drivers [s]
    speed_cap : highest wheel rim speed the motors reach [m/s] (inf: none)
    stiction : wheel set-points below this rim speed do not turn the wheel [m/s]
    cpr_right, cpr_left : counted / declared edges per wheel revolution [1]
    clock_skew : motion-capture stamp minus true time [s]
    clock_wander : standard deviation of a slow wander of that stamp error [s]: the sum
        of two sinusoids of random phase and period (2–10 s), amplitude ``clock_wander``
        each, drawn per run
    creep : constant fraction of rim speed lost at the contact [1]
    grip : traction limit of each wheel, ground acceleration ≤ grip·g [1] (inf: none)
    tau_true : motor time constant when it differs from the declared one [s] (None: same)
    ellipticity : wheel radius ``r(1 + e cos 2φ)`` of the right wheel [1]
    caster_drag : yaw-rate lost to a dragging caster while turning [rad/s]
    slope : floor tilt [rad]; ``slope_dir`` its downhill direction in the world frame [rad]
    battery_sag : fraction of motor speed lost by the end of the session [1]
    marker_dx, marker_dy : motion-capture body origin in the robot frame [m]
    marker_yaw : motion-capture body heading minus the robot's [rad]
    skid : lateral skid speed per unit v·ω [s]
    enc_wobble : periodic count error amplitude of the left encoder [rad of wheel angle]
    """

    d_right: float = 1.0
    d_left: float = 1.0
    b_true: float = 1.0
    delay: float = 0.0
    speed_cap: float = math.inf
    stiction: float = 0.0
    cpr_right: float = 1.0
    cpr_left: float = 1.0
    clock_skew: float = 0.0
    clock_wander: float = 0.0
    creep: float = 0.0
    grip: float = math.inf
    tau_true: float | None = None
    ellipticity: float = 0.0
    caster_drag: float = 0.0
    slope: float = 0.0
    slope_dir: float = 0.0
    battery_sag: float = 0.0
    marker_dx: float = 0.0
    marker_dy: float = 0.0
    marker_yaw: float = 0.0
    skid: float = 0.0
    enc_wobble: float = 0.0

    def __post_init__(self) -> None:
        for name in ("d_right", "d_left", "b_true", "cpr_right", "cpr_left"):
            v = getattr(self, name)
            if not 0.5 < v < 1.5:
                raise ValueError(f"Hidden.{name} is a ratio near 1, expected (0.5, 1.5), got {v!r}")
        if self.delay < 0 or self.stiction < 0 or self.speed_cap <= 0 or self.grip <= 0:
            raise ValueError(
                "Hidden.delay and .stiction must be >= 0, .speed_cap and .grip > 0; "
                f"got delay={self.delay}, stiction={self.stiction}, "
                f"speed_cap={self.speed_cap}, grip={self.grip}"
            )
        if not 0.0 <= self.battery_sag < 0.9 or not 0.0 <= self.creep < 0.5:
            raise ValueError(
                f"Hidden.battery_sag must lie in [0, 0.9) and .creep in [0, 0.5); "
                f"got {self.battery_sag}, {self.creep}"
            )
        if not 0.0 <= self.clock_wander <= 0.1:
            raise ValueError(
                "Hidden.clock_wander must lie in [0, 0.1] s (a wander that keeps the stamps "
                f"in order), got {self.clock_wander!r}"
            )


# --------------------------------------------------------------------------- paths
# A path is a per-cycle planner: f(state) -> (v request ticks/cyc, ω request rad/cyc) or None (done)


@dataclass
class _Planner:
    """Segments of (kind, target, request) followed on the robot's own odometry."""

    segments: list[tuple[str, float, float, float]]
    index: int = 0
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wait_left: int = 0
    pending: bool = True
    still: int = 0

    def request(
        self, odo: FloatArray, robot: DriveRobot, moving: bool = False
    ) -> tuple[float, float] | None:
        """The request of this cycle; ``moving``: the encoders counted in the last cycle."""
        if self.index >= len(self.segments):
            return None
        kind, target, v, w = self.segments[self.index]
        if self.pending:
            self.start = (float(odo[0]), float(odo[1]), float(odo[2]))
            self.pending = False
            self.wait_left = int(round(target / robot.cycle)) if kind == "wait" else 0
        done = False
        if kind == "stop":
            # hold zero until the encoders have been still for ``target`` s
            self.still = 0 if moving else self.still + 1
            done = self.still * robot.cycle >= target
            v = w = 0.0
        elif kind == "wait":
            self.wait_left -= 1
            done = self.wait_left <= 0
            v = w = 0.0
        elif kind == "dist":
            travelled = math.hypot(odo[0] - self.start[0], odo[1] - self.start[1])
            speed = abs(v) * robot.m_per_tick / robot.cycle
            a = robot.dv_max * robot.m_per_tick / robot.cycle**2
            done = travelled >= target - 0.5 * speed**2 / a
        elif kind == "turn":
            turned = abs(odo[2] - self.start[2])
            rate = abs(w) / robot.cycle
            alpha = robot.dw_max / robot.cycle**2
            done = turned >= target - 0.5 * rate**2 / alpha
        elif kind == "time":
            self.wait_left += 1
            done = self.wait_left * robot.cycle >= target
        if done:
            self.index += 1
            self.pending = True
            return (0.0, 0.0)
        return (v, w)


def square_path(
    robot: DriveRobot, side: float, direction: str
) -> list[tuple[str, float, float, float]]:
    """UMBmark square of ``side`` m, ``"cw"`` or ``"ccw"``: drive, stop, turn 90°, stop, four times.

    Each stop holds a zero request until the robot's own encoders have been still for 0.4 s.
    """
    if direction not in ("cw", "ccw"):
        raise ValueError(f"direction must be 'cw' or 'ccw', got {direction!r}")
    if not side > 0:
        raise ValueError(f"side must be > 0 m, got {side!r}")
    sign = 1.0 if direction == "ccw" else -1.0
    segs: list[tuple[str, float, float, float]] = [("wait", 0.5, 0.0, 0.0)]
    for _ in range(4):
        segs += [("dist", side, robot.v_nom, 0.0), ("stop", 0.4, 0.0, 0.0)]
        segs += [("turn", math.pi / 2, 0.0, sign * robot.w_nom), ("stop", 0.4, 0.0, 0.0)]
    return segs


def circle_path(
    robot: DriveRobot, radius: float, direction: str
) -> list[tuple[str, float, float, float]]:
    """One full circle of ``radius`` m at cruise speed (timed on the planned rate)."""
    if direction not in ("cw", "ccw"):
        raise ValueError(f"direction must be 'cw' or 'ccw', got {direction!r}")
    if not radius > 0:
        raise ValueError(f"radius must be > 0 m, got {radius!r}")
    sign = 1.0 if direction == "ccw" else -1.0
    v = robot.v_nom
    w = sign * v * robot.m_per_tick / radius
    seconds = 2 * math.pi / abs(w / robot.cycle)
    return [("wait", 0.5, 0.0, 0.0), ("time", seconds, v, w), ("stop", 0.4, 0.0, 0.0)]


def free_path(
    robot: DriveRobot, rng: np.random.Generator, n_segments: int = 8
) -> list[tuple[str, float, float, float]]:
    """Random arcs, straights and turns in place (durations 2–5 s), drawn from ``rng``."""
    if n_segments < 1:
        raise ValueError(f"n_segments must be >= 1, got {n_segments!r}")
    segs: list[tuple[str, float, float, float]] = [("wait", 0.5, 0.0, 0.0)]
    for _ in range(n_segments):
        kind = rng.choice(3)
        secs = float(rng.uniform(2.0, 5.0))
        if kind == 0:
            segs.append(("time", secs, robot.v_nom * rng.uniform(0.4, 1.0), 0.0))
        elif kind == 1:
            v = robot.v_nom * rng.uniform(0.4, 1.0)
            segs.append(("time", secs, v, robot.w_nom * rng.uniform(-0.8, 0.8)))
        else:
            segs.append(("time", secs * 0.6, 0.0, robot.w_nom * rng.choice([-1.0, 1.0])))
        if rng.random() < 0.4:
            segs.append(("wait", 0.5, 0.0, 0.0))
    segs.append(("wait", 1.5, 0.0, 0.0))
    return segs


# --------------------------------------------------------------------------- simulation


@dataclass(frozen=True)
class RunRecord:
    """One simulated run at the cycle rate (row ``k`` at ``k·Δ``).

    Attributes
    ----------
    time : (N,) s from the run start
    gt : (N, 3) motion-capture pose in the start frame, continuous heading
    ticks_left, ticks_right : (N,) int, edges counted in the cycle ending at row k
    request : (N, 2) the planner's request (ticks/cycle, rad/cycle) issued at row k
    odo : (N, 3) the robot's own odometry (nominal kinematics), start frame
    truth : (N, 3) true body pose (axle centre) in the start frame
    """

    time: FloatArray
    gt: FloatArray
    ticks_left: npt.NDArray[np.int64]
    ticks_right: npt.NDArray[np.int64]
    request: FloatArray
    odo: FloatArray
    truth: FloatArray


def _odometry_step(pose: FloatArray, dl: float, dr: float, robot: DriveRobot) -> FloatArray:
    sl, sr = dl * robot.m_per_tick, dr * robot.m_per_tick
    ds, dth = 0.5 * (sl + sr), (sr - sl) / robot.wheelbase
    mid = pose[2] + 0.5 * dth
    return np.array([pose[0] + ds * math.cos(mid), pose[1] + ds * math.sin(mid), pose[2] + dth])


def simulate_run(
    segments: Sequence[tuple[str, float, float, float]],
    robot: DriveRobot,
    hidden: Hidden,
    rng: np.random.Generator,
    *,
    session_t0: float = 0.0,
    session_length: float = 600.0,
    max_seconds: float = 240.0,
) -> RunRecord:
    """Drive ``segments`` with the hidden robot; return what the robot and motion capture log.

    Parameters
    ----------
    segments : path from :func:`square_path`, :func:`circle_path` or :func:`free_path`
    robot : DriveRobot
    hidden : Hidden
    rng : numpy Generator for every noise draw
    session_t0 : s, time of the run's start within the session (battery sag)
    session_length : s, session duration over which the battery sags by ``battery_sag``
    max_seconds : s, hard limit of a run
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    planner = _Planner(list(segments))
    dt, h = robot.cycle, robot.substep
    n_sub = int(round(dt / h))
    r0 = 0.5 * robot.diameter
    rad_l, rad_r = r0 * hidden.d_left, r0 * hidden.d_right  # true wheel radii
    b = robot.wheelbase * hidden.b_true
    tau = robot.motor_tau if hidden.tau_true is None else hidden.tau_true
    cpr = robot.ticks_per_rev * np.array([hidden.cpr_left, hidden.cpr_right])
    delay_cycles = hidden.delay / dt
    half_b_ticks = 0.5 * robot.wheelbase / robot.m_per_tick
    rad_per_tick_nom = 2 * math.pi / robot.ticks_per_rev  # set-point ticks/cycle → rad of wheel

    setpoint = np.zeros(2)  # ramped wheel set-points, ticks/cycle
    body = np.zeros(2)  # ramped (v, ω) request of a body ramp, ticks/cycle and rad/cycle
    history: list[tuple[float, float]] = []  # set-points by cycle (delay line)
    # The fine-step state is kept in plain floats, per wheel (left, right): the same
    # IEEE arithmetic as on length-2 arrays, without numpy's per-call cost.
    wl = wr = 0.0  # wheel rates, rad/s
    gl = gr = 0.0  # ground speeds, m/s
    phl = phr = 0.0  # wheel angles, rad
    px = py = pth = 0.0  # pose
    alpha = 1.0 - math.exp(-h / tau)  # motor lag over one fine step
    cap = hidden.speed_cap / r0
    grip_step = hidden.grip * G * h if math.isfinite(hidden.grip) else None
    slip = 1.0 - hidden.creep
    odo = np.zeros(3)
    counts_prev = np.zeros(2, dtype=np.int64)
    mocap_period = 1.0 / robot.mocap_rate
    mocap_t: list[float] = []
    mocap_pose: list[tuple[float, float, float]] = []
    next_mocap = robot.mocap_phase
    wander = (
        (rng.uniform(2.0, 10.0, size=2), rng.uniform(0.0, 2.0 * math.pi, size=2))
        if hidden.clock_wander > 0
        else None
    )

    rows_t, rows_req, rows_tl, rows_tr, rows_odo, rows_truth = [], [], [], [], [], []
    k = 0
    idle_after = 0
    inc = np.zeros(2, dtype=np.int64)
    while True:
        t = k * dt
        req = planner.request(odo, robot, bool(np.any(inc != 0)))
        if req is None:
            idle_after += 1
            req = (0.0, 0.0)
        if idle_after > 2 or t > max_seconds:
            break
        v_req, w_req = req
        if robot.ramp == "wheels":
            target = np.array([v_req - w_req * half_b_ticks, v_req + w_req * half_b_ticks])
            setpoint = setpoint + np.clip(target - setpoint, -robot.dv_max, robot.dv_max)
        else:
            body = body + np.clip(
                np.array([v_req, w_req]) - body,
                [-robot.dv_max, -robot.dw_max],
                [robot.dv_max, robot.dw_max],
            )
            setpoint = np.array(
                [body[0] - body[1] * half_b_ticks, body[0] + body[1] * half_b_ticks]
            )
        issued = (float(setpoint[0]), float(setpoint[1]))
        history.append(issued)
        for j in range(n_sub):
            ts = t + j * h
            # set-point reaching the drivers now: the one issued `delay` s earlier
            lag = (ts - hidden.delay) / dt
            if lag < 0:
                sp_l = sp_r = 0.0
            elif delay_cycles > 0:
                sp_l, sp_r = history[min(int(lag), len(history) - 1)]
            else:
                sp_l, sp_r = issued
            want_l = sp_l * rad_per_tick_nom / dt  # wheel rad/s
            want_r = sp_r * rad_per_tick_nom / dt
            if abs(want_l * r0) < hidden.stiction:
                want_l = 0.0
            if abs(want_r * r0) < hidden.stiction:
                want_r = 0.0
            gain = 1.0 - hidden.battery_sag * min(1.0, (session_t0 + ts) / session_length)
            want_l = min(max(want_l * gain, -cap), cap)
            want_r = min(max(want_r * gain, -cap), cap)
            wl = wl + (want_l - wl) * alpha
            wr = wr + (want_r - wr) * alpha
            r_eff_r = rad_r
            if hidden.ellipticity:
                r_eff_r = rad_r * (1.0 + hidden.ellipticity * math.cos(2.0 * phr))
            rim_l = wl * rad_l * slip
            rim_r = wr * r_eff_r * slip
            if grip_step is not None:
                gl = gl + min(max(rim_l - gl, -grip_step), grip_step)
                gr = gr + min(max(rim_r - gr, -grip_step), grip_step)
            else:
                gl, gr = rim_l, rim_r
            phl = phl + wl * h
            phr = phr + wr * h
            v = 0.5 * (gl + gr)
            w = (gr - gl) / b
            if hidden.caster_drag and abs(w) > 1e-6:
                w -= math.copysign(min(hidden.caster_drag, abs(w)), w)
            vx, vy = v, hidden.skid * v * w
            if hidden.slope:
                rel = hidden.slope_dir - pth
                pull = G * math.sin(hidden.slope) * 0.02  # creep down the slope, m/s per (m/s²)
                vx += pull * math.cos(rel) * min(1.0, abs(v) / 0.05)
                vy += pull * math.sin(rel) * min(1.0, abs(v) / 0.05 + abs(w) / 0.3)
            c, s = math.cos(pth), math.sin(pth)
            px, py, pth = px + h * (c * vx - s * vy), py + h * (s * vx + c * vy), pth + h * w
            if ts + h >= next_mocap - 1e-12:
                c, s = math.cos(pth), math.sin(pth)
                marker = (
                    px + c * hidden.marker_dx - s * hidden.marker_dy,
                    py + s * hidden.marker_dx + c * hidden.marker_dy,
                    pth + hidden.marker_yaw,
                )
                stamp = next_mocap + robot.mocap_latency + hidden.clock_skew
                if wander is not None:
                    periods, phases = wander
                    stamp += hidden.clock_wander * float(
                        np.sum(np.sin(2.0 * math.pi * next_mocap / periods + phases))
                    )
                mocap_t.append(stamp)
                mocap_pose.append(marker)
                next_mocap += mocap_period
        wobble = np.array([hidden.enc_wobble * math.sin(phl), 0.0])
        phi = np.array([phl, phr])
        counts = np.floor((phi + wobble) * cpr / (2 * math.pi)).astype(np.int64)
        inc = counts - counts_prev
        counts_prev = counts
        odo = _odometry_step(odo, float(inc[0]), float(inc[1]), robot)
        # row k+1 holds the ticks of the cycle ending at (k+1)Δ; row k the request issued at kΔ
        rows_t.append(t)
        rows_req.append((v_req, w_req))
        rows_tl.append(int(inc[0]))
        rows_tr.append(int(inc[1]))
        rows_odo.append(odo.copy())
        rows_truth.append((px, py, pth))
        k += 1
    n = len(rows_t)
    time = dt * np.arange(n, dtype=np.float64)
    # shift ticks so that row k holds the cycle ending at time[k] (row 0: nothing counted)
    tl = np.concatenate([[0], np.asarray(rows_tl[:-1], dtype=np.int64)])
    tr = np.concatenate([[0], np.asarray(rows_tr[:-1], dtype=np.int64)])
    odo_rows = np.vstack([np.zeros(3), np.asarray(rows_odo[:-1])])
    truth = np.vstack([np.zeros(3), np.asarray(rows_truth[:-1])])
    # motion capture: the most recent sample stamped at or before each row, plus noise
    mt = np.asarray(mocap_t)
    mp = np.asarray(mocap_pose)
    idx = np.clip(np.searchsorted(mt, time, side="right") - 1, 0, len(mt) - 1)
    gt = mp[idx].copy()
    gt[:, :2] += rng.normal(0.0, robot.mocap_pos_sigma, size=(n, 2))
    gt[:, 2] += rng.normal(0.0, robot.mocap_yaw_sigma, size=n)
    c, s = math.cos(gt[0, 2]), math.sin(gt[0, 2])
    d = gt[:, :2] - gt[0, :2]
    gt = np.column_stack(
        [c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], gt[:, 2] - gt[0, 2]]
    )
    return RunRecord(
        time=time,
        gt=gt,
        ticks_left=tl,
        ticks_right=tr,
        request=np.asarray(rows_req, dtype=float),
        odo=odo_rows,
        truth=truth,
    )


# --------------------------------------------------------------------------- files


def _num(x: float) -> str:
    return repr(float(x)) if x != int(x) else str(int(x))


_METHODS = {
    "square": "Borenstein and Feng (1996): UMBmark",
    "circular": "New method (circular paths)",
    "ivanjko": "Ivanjko et al. (2003)",
    "free": "Free path",
}


def write_session(
    folder: str | Path,
    session_id: str,
    runs: Sequence[RunRecord],
    robot: DriveRobot,
    path_type: str,
    *,
    side: float | None = None,
    rng: np.random.Generator | None = None,
) -> Path:
    """Write ``runs`` as the OptiOdom session ``<folder>/<path_type>/<session_id>/``.

    Files: ``<ID>_metadata.csv``, ``<ID>_run-NN.csv`` (time, x, y, θ, ticks_R,
    ticks_L), ``<ID>_run-NN_odo.csv`` (UTF-8 BOM; robot-clock time, ticks_L,
    ticks_R) and the robot log ``<ID>.csv`` (header rows, ``Run:,k`` blocks of
    time, odoL, odoR, xodo, yodo, θodo, vlin, omega, flag on the robot clock,
    with idle cycles before and after the run).

    Returns
    -------
    Path
        The session folder.
    """
    if path_type not in _METHODS:
        raise ValueError(f"path_type must be one of {sorted(_METHODS)}, got {path_type!r}")
    if not runs:
        raise ValueError("runs must hold at least one RunRecord")
    if not (len(session_id) == 12 and session_id.isdigit()):
        raise ValueError(f"session_id must be 12 digits (DDMMYYYYhhmm), got {session_id!r}")
    rng = rng if rng is not None else np.random.default_rng(0)
    out = Path(folder) / path_type / session_id
    out.mkdir(parents=True, exist_ok=True)
    sid = session_id
    pad_before, pad_after = 12, 8
    clock = 20.0 + float(rng.uniform(0.0, 5.0))
    log_lines = [
        f"Method:,{_METHODS[path_type]}",
        f"dL0(m):,{_num(robot.diameter)},dR0(m):,{_num(robot.diameter)},b0(m):,{_num(robot.wheelbase)}",
        f"N:,{len(runs)},L(LmxLm):,{'' if side is None else _num(side)}",
        f"VLIN_NOM_0(ticks/cyc):,{_num(robot.v_nom)},VANG_NOM_0(rad/cyc):,{_num(robot.w_nom)},"
        f"DVMAX(ticks/cyc^2):,{_num(robot.dv_max)},DWMAX(ticks/cyc^2):,{robot.dw_max:.6g}",
        ",".join(["+" * 10] * 10),
        "time(s):,odoL(thicks/cyc):,odoR(thicks/cyc):,xodo(m):,yodo(m):,thodo(rad):,"
        "vlin(thicks/cyc):,omega(rad/cyc):",
        ",".join(["+" * 10] * 10),
    ]
    gt_ti, gt_tf, odo_tf = [], [], []
    for i, run in enumerate(runs, start=1):
        n = run.time.shape[0]
        rows = np.column_stack(
            [run.time, run.gt, run.ticks_right.astype(float), run.ticks_left.astype(float)]
        )
        lines = [
            f"{r[0]!r},{r[1]!r},{r[2]!r},{r[3]!r},{int(r[4])},{int(r[5])}" for r in rows.tolist()
        ]
        (out / f"{sid}_run-{i:02d}.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
        robot_t = clock + robot.cycle * (pad_before + np.arange(n))
        odo_lines = [
            f"{t:.10g},{a},{b}" for t, a, b in zip(robot_t, run.ticks_left, run.ticks_right)
        ]
        (out / f"{sid}_run-{i:02d}_odo.csv").write_text(
            "\ufeff" + "\n".join(odo_lines) + "\n", encoding="utf-8"
        )
        gt0 = float(rng.uniform(2.0, 4.5))
        gt_ti.append(gt0)
        gt_tf.append(gt0 + float(run.time[-1]))
        odo_tf.append(float(run.time[-1]))
        # robot log block: idle rows, the run, idle rows (flag 1 on the last ones)
        m = pad_before + n + pad_after
        t_block = clock + robot.cycle * np.arange(m)
        tl = np.zeros(m, np.int64)
        tr = np.zeros(m, np.int64)
        tl[pad_before : pad_before + n] = run.ticks_left
        tr[pad_before : pad_before + n] = run.ticks_right
        odo = np.zeros((m, 3))
        odo[pad_before : pad_before + n] = run.odo
        odo[pad_before + n :] = run.odo[-1]
        req = np.zeros((m, 2))
        req[pad_before : pad_before + n] = run.request
        flag = np.zeros(m, np.int64)
        flag[-pad_after:] = 1
        log_lines.append(f"Run:,{i}")
        for j in range(m):
            log_lines.append(
                f"{t_block[j]:.10g},{tl[j]},{tr[j]},{odo[j, 0]:.4g},{odo[j, 1]:.4g},"
                f"{odo[j, 2]:.4g},{req[j, 0]:.6g},{req[j, 1]:.6g},{flag[j]}"
            )
        clock = float(t_block[-1]) + 5.0
    (out / f"{sid}.csv").write_text("\n".join(log_lines) + "\n", encoding="utf-8")
    n_runs = len(runs)
    meta = [
        "type,diff",
        f"ngear,{_num(robot.gear)}",
        f"encRes,{_num(robot.enc_res)}",
        f"Li,{_num(robot.wheelbase)}",
        f"Di,{_num(robot.diameter)},{_num(robot.diameter)}",
        "Thi,",
        f"N,{n_runs}",
        f"L,{'' if side is None else _num(side)}",
        "imarkers,1,4",
        "gt_ti," + ",".join(f"{v:.4g}" for v in gt_ti),
        "gt_tf," + ",".join(f"{v:.6g}" for v in gt_tf),
        "odo_ti," + ",".join("0" for _ in runs),
        "odo_tf," + ",".join(f"{v:.6g}" for v in odo_tf),
    ]
    (out / f"{sid}_metadata.csv").write_text("\n".join(meta) + "\n", encoding="utf-8")
    return out
