"""Independent teleoperation world of a mid-size differential-drive robot.

This module generates logged data sets of a differential-drive robot driven by
a human with a joystick, for testing a sim-to-real gap diagnosis tool.  It is
written independently of that tool and imports only NumPy and the standard
library.

Physical model (SI units throughout)
------------------------------------
Robot
    Two driven wheels on an axle (nominal wheelbase 0.38 m, wheel radius
    0.075 m) and a passive caster 0.25 m behind the axle; 12 kg.  The
    datasheet values live in :class:`TeleopRobot`, the drive-train constants
    in :class:`DriveTrain`.
Drive train
    Each wheel is a permanent-magnet DC motor (gearbox included in the
    constants, referred to the wheel shaft): back-EMF, resistive armature
    (inductance neglected, its time constant is well below the 2 ms step),
    inertia, viscous and Coulomb friction.  A PI speed loop per wheel runs at
    100 Hz on the encoder count differences, with conditional-integration
    anti-windup and a PWM voltage limit.  The firmware turns the commanded body
    twist ``(v, w)`` into wheel speed set-points with the *nominal* geometry.
    With the nominal gains the loop overshoots a step (and the end of each
    speed ramp) by a few per cent: a drive-train property, not a fault.
Contact
    Wheels and body are coupled by friction-limited longitudinal contact
    forces (an impulse solver per step: stick when the floor can provide the
    force, slide at ``mu N`` otherwise).  The body moves with the *true*
    geometry.  Lateral tyre creep (a slip angle proportional to lateral force)
    is applied to the external lateral loads of the hidden effects (caster
    drag, floor slope); the centripetal creep of a nominal robot is neglected.
    Integration step 2 ms.
Sensors
    Cumulative integer encoder counts, the logged joystick command and a
    motion-capture ground truth (120 Hz own clock, 1 mm / 2 mrad noise)
    resampled onto the log clock and expressed in the start frame of each run.

Data set layout
---------------
A case has two days.  Day 1 (training): session ``d1_s1`` (3 runs, logged at
25 Hz) and ``d1_s2`` (3 runs, 40 Hz).  Day 2 (held out): ``d2_s1`` (2 runs,
25 Hz) and ``d2_s2`` (2 runs, 40 Hz).  Runs last 60-120 s.  Battery voltage
(+-3 %), floor grip and bearing friction change slightly between days.

Hidden effects are set with :class:`TeleopHidden`; every field defaults to
"no effect".  All randomness comes from a :class:`numpy.random.Generator`.
"""

from __future__ import annotations

import json
import math
import os
import pathlib
import tempfile
import zlib
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

__all__ = [
    "SESSIONS",
    "DriveTrain",
    "RunConditions",
    "SessionSpec",
    "TeleopHidden",
    "TeleopRobot",
    "Trace",
    "joystick_commands",
    "measure_run",
    "simulate_runs",
    "write_case",
]

GRAVITY = 9.81
TWO_PI = 2.0 * math.pi


# --------------------------------------------------------------------------
# Robot description
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class TeleopRobot:
    """Datasheet (nominal) values of the robot, as written into ``dataset.json``.

    Attributes
    ----------
    wheelbase_m : float
        Distance between the wheel contact points, m.
    wheel_radius_m : float
        Wheel radius, m.
    counts_per_rev : int
        Encoder counts per wheel revolution (quadrature included).
    v_max_mps : float
        Top wheel (and body) speed rating, m/s.
    w_max_radps : float
        Turn-rate rating (firmware clamp), rad/s.
    a_max_mps2 : float
        Linear acceleration rating, m/s^2.
    alpha_max_radps2 : float
        Angular acceleration rating, rad/s^2.
    mass_kg : float
        Robot mass, kg.
    """

    wheelbase_m: float = 0.38
    wheel_radius_m: float = 0.075
    counts_per_rev: int = 4096
    v_max_mps: float = 1.2
    w_max_radps: float = 3.0
    a_max_mps2: float = 3.0
    alpha_max_radps2: float = 8.0
    mass_kg: float = 12.0

    def as_json(self) -> dict[str, float | int]:
        """Return the ``robot`` block of ``dataset.json``."""
        return {
            "wheelbase_m": self.wheelbase_m,
            "wheel_radius_m": self.wheel_radius_m,
            "counts_per_rev": self.counts_per_rev,
            "v_max_mps": self.v_max_mps,
            "w_max_radps": self.w_max_radps,
            "a_max_mps2": self.a_max_mps2,
            "alpha_max_radps2": self.alpha_max_radps2,
        }


@dataclass(frozen=True)
class DriveTrain:
    """Drive-train, body and sensor constants of the simulated robot.

    Motor constants are referred to the wheel shaft (gearbox included).

    Attributes
    ----------
    battery_v : float
        Nominal battery voltage, V (the PWM limit at full duty).
    k_e : float
        Back-EMF constant, V s/rad.
    k_t : float
        Torque constant, N m/A.
    resistance_ohm : float
        Armature resistance, ohm.
    wheel_inertia : float
        Wheel plus reflected rotor inertia, kg m^2.
    viscous_nms : float
        Viscous friction, N m s/rad.
    coulomb_nm : float
        Coulomb (bearing/gear) friction, N m.
    yaw_inertia : float
        Body yaw inertia about the axle centre, kg m^2.
    drive_load_fraction : float
        Share of the weight on the two driven wheels (rest on the caster).
    floor_mu : float
        Nominal floor friction coefficient (the robot never slides on it).
    caster_offset_m : float
        Caster distance behind the axle, m.
    cornering_stiffness_n_per_rad : float
        Lateral force per rad of slip angle, both tyres together, N/rad.
    control_hz : float
        Speed-loop rate, Hz.
    kp : float
        Proportional gain, V per rad/s of wheel speed error.
    ki : float
        Integral gain, V per rad of wheel angle error.
    dt : float
        Integration step, s (an integer fraction of the control period).
    joystick_hz : float
        Rate at which the teleop node sends twists, Hz.
    mocap_hz : float
        Motion-capture sample rate, Hz.
    mocap_pos_noise_m : float
        Motion-capture position noise (standard deviation), m.
    mocap_yaw_noise_rad : float
        Motion-capture yaw noise (standard deviation), rad.
    """

    battery_v: float = 24.0
    k_e: float = 1.3
    k_t: float = 1.3
    resistance_ohm: float = 2.0
    wheel_inertia: float = 0.01
    viscous_nms: float = 0.02
    coulomb_nm: float = 0.05
    yaw_inertia: float = 0.40
    drive_load_fraction: float = 0.85
    floor_mu: float = 0.8
    caster_offset_m: float = 0.25
    cornering_stiffness_n_per_rad: float = 600.0
    control_hz: float = 100.0
    kp: float = 1.4
    ki: float = 60.0
    dt: float = 0.002
    joystick_hz: float = 50.0
    mocap_hz: float = 120.0
    mocap_pos_noise_m: float = 0.001
    mocap_yaw_noise_rad: float = 0.002

    def voltage_for_speed(self, wheel_speed_radps: float) -> float:
        """Steady voltage that holds an unloaded wheel at a speed.

        Parameters
        ----------
        wheel_speed_radps : float
            Wheel angular speed, rad/s.

        Returns
        -------
        float
            Armature voltage, V (back-EMF plus the friction current drop).
        """
        friction = self.viscous_nms * wheel_speed_radps + self.coulomb_nm
        return self.k_e * wheel_speed_radps + self.resistance_ohm * friction / self.k_t


@dataclass(frozen=True)
class TeleopHidden:
    """Hidden effects of one case; every default means "no effect".

    Attributes
    ----------
    wheelbase_factor : float
        True wheelbase / nominal wheelbase.
    wheel_radius_scale : float
        Common factor on both true wheel radii (mean radius / nominal).
    wheel_radius_ratio : float
        True right radius / true left radius, at a kept mean radius.
    encoder_counts_factor : float
        Counts the encoders really give per revolution / datasheet value (both
        wheels).  The firmware still converts with the datasheet value.
    command_delay_s : float
        Delay of the commands on their way to the motor controllers, s.
    top_speed_limit_mps : float or None
        If set, the PWM voltage limit is lowered to the voltage that holds an
        unloaded wheel at this speed (nominal battery), m/s.
    deadzone_left_mps, deadzone_right_mps : float
        A wheel stands still (drive off, integrator reset) while the magnitude
        of its set-point is below this wheel speed, m/s.
    friction_coefficient : float or None
        Floor friction coefficient replacing the nominal grip (traction slip).
    caster_side_drag_n_per_radps : float
        Lateral caster drag per rad/s of turn rate, N s/rad (out of library).
    out_of_round_right : float
        Relative amplitude of a sinusoidal right-wheel radius variation with
        wheel angle (out of library).
    mocap_yaw_drift_rad : float
        Amplitude of a sinusoidal drift of the ground-truth yaw, rad (out of
        library).
    mocap_yaw_drift_period_s : float
        Period of that drift, s.
    right_motor_gain_sag : float
        Fraction by which the right motor's torque and back-EMF constants
        fall, linearly, over each run (out of library).
    floor_slope_rad : float
        Floor tilt, rad (out of library).
    right_torque_ripple_nm : float
        Amplitude of a sinusoidal torque oscillation on the right wheel, N m
        (out of library).
    right_torque_ripple_hz : float
        Its frequency, Hz.
    mocap_occlusion_rate_hz : float
        Mean rate of motion-capture occlusions during which the ground truth
        holds its last value, 1/s (out of library).
    mocap_occlusion_mean_s : float
        Mean occlusion length, s.
    """

    wheelbase_factor: float = 1.0
    wheel_radius_scale: float = 1.0
    wheel_radius_ratio: float = 1.0
    encoder_counts_factor: float = 1.0
    command_delay_s: float = 0.0
    top_speed_limit_mps: float | None = None
    deadzone_left_mps: float = 0.0
    deadzone_right_mps: float = 0.0
    friction_coefficient: float | None = None
    caster_side_drag_n_per_radps: float = 0.0
    out_of_round_right: float = 0.0
    mocap_yaw_drift_rad: float = 0.0
    mocap_yaw_drift_period_s: float = 30.0
    right_motor_gain_sag: float = 0.0
    floor_slope_rad: float = 0.0
    right_torque_ripple_nm: float = 0.0
    right_torque_ripple_hz: float = 3.0
    mocap_occlusion_rate_hz: float = 0.0
    mocap_occlusion_mean_s: float = 1.2

    def true_radii(self, robot: TeleopRobot) -> tuple[float, float]:
        """True (left, right) wheel radii, m."""
        mean = robot.wheel_radius_m * self.wheel_radius_scale
        q = self.wheel_radius_ratio
        return 2.0 * mean / (1.0 + q), 2.0 * mean * q / (1.0 + q)

    def true_wheelbase(self, robot: TeleopRobot) -> float:
        """True wheelbase, m."""
        return robot.wheelbase_m * self.wheelbase_factor


@dataclass(frozen=True)
class RunConditions:
    """Per-run conditions that are not hidden effects.

    Attributes
    ----------
    duration_s : float
        Run length, s.
    battery_factor : float
        Battery voltage / nominal (changes between days).
    floor_mu : float
        Floor friction coefficient of the day.
    coulomb_scale : float
        Bearing-friction factor of the day.
    heading0_rad : float
        Initial world heading (matters for a sloped floor).
    slope_dir_rad : float
        World direction of steepest descent.
    encoder_phase : tuple of float
        Fractional count phase of the (left, right) encoder at the start.
    ripple_phase_rad : float
        Phase of the torque ripple, if any.
    """

    duration_s: float
    battery_factor: float = 1.0
    floor_mu: float = 0.8
    coulomb_scale: float = 1.0
    heading0_rad: float = 0.0
    slope_dir_rad: float = 0.0
    encoder_phase: tuple[float, float] = (0.5, 0.5)
    ripple_phase_rad: float = 0.0


@dataclass
class Trace:
    """True motion of one run at the integration step.

    Attributes
    ----------
    t : ndarray
        Times, s (0 at the run start).
    x, y, yaw : ndarray
        World pose of the axle centre, m and rad (yaw continuous).
    v, w : ndarray
        Forward speed, m/s, and yaw rate, rad/s, of the body.
    phi_left, phi_right : ndarray
        Wheel angles, rad (0 at the start).
    cmd_v, cmd_w : ndarray
        Joystick twist sent, at the joystick rate.
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    v: np.ndarray
    w: np.ndarray
    phi_left: np.ndarray
    phi_right: np.ndarray
    cmd_v: np.ndarray
    cmd_w: np.ndarray


# --------------------------------------------------------------------------
# Joystick
# --------------------------------------------------------------------------
_STYLES: dict[str, dict[str, Any]] = {
    # ramp rates (m/s^2, rad/s^2) drawn per segment, thumb filter time constant
    "normal": {"acc": (0.6, 1.8), "alpha": (1.5, 4.5), "tau": 0.15, "release_acc": 2.0},
    "aggressive": {"acc": (2.2, 3.0), "alpha": (4.0, 8.0), "tau": 0.05, "release_acc": 3.0},
}
_MODES = ("cruise", "arc", "spin", "stop", "creep", "reverse")
_MODE_P = np.array([0.27, 0.27, 0.10, 0.14, 0.10, 0.12])


def joystick_commands(
    rng: np.random.Generator,
    duration_s: float,
    style: str = "normal",
    rate_hz: float = 50.0,
    v_limit: float = 0.6,
    w_limit: float = 1.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Teleop twist stream of one run.

    A sequence of stick targets (cruise, arc, turn on the spot, stop, creep,
    short reversal), each held for 0.5-4 s, is followed by a thumb that ramps
    towards the target at a rate drawn per segment and a first-order filter.
    The stick is at rest for the first 1-2 s and released at least 2 s before
    the end.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness.
    duration_s : float
        Run length, s.
    style : str
        ``"normal"`` or ``"aggressive"`` (hard ramps and stops).
    rate_hz : float
        Rate of the twist stream, Hz.
    v_limit : float
        Full-stick forward speed, m/s.
    w_limit : float
        Full-stick turn rate, rad/s.

    Returns
    -------
    v, w : ndarray
        Forward speed (m/s) and turn rate (rad/s) sent at ``k / rate_hz``.
    """
    st = _STYLES[style]
    n = int(round(duration_s * rate_hz))
    h = 1.0 / rate_hz
    tgt_v = np.zeros(n)
    tgt_w = np.zeros(n)
    rate_v = np.full(n, st["release_acc"])
    rate_w = np.full(n, st["alpha"][1])
    k = int(round(rng.uniform(1.0, 2.0) * rate_hz))
    end = n - int(round(2.0 * rate_hz))
    while k < end:
        mode = _MODES[int(rng.choice(len(_MODES), p=_MODE_P))]
        hold = rng.uniform(0.5, 4.0)
        sign = 1.0 if rng.random() < 0.5 else -1.0
        if mode == "cruise":
            v, w = rng.uniform(0.2, 0.6), rng.normal(0.0, 0.1)
        elif mode == "arc":
            v, w = rng.uniform(0.1, 0.55), sign * rng.uniform(0.3, 1.5)
        elif mode == "spin":
            v, w = 0.0, sign * rng.uniform(0.5, 1.5)
        elif mode == "stop":
            v, w = 0.0, 0.0
        elif mode == "creep":
            v, w = rng.uniform(0.02, 0.12), sign * rng.uniform(0.0, 0.3)
        else:  # reverse
            v, w = -rng.uniform(0.1, 0.35), rng.normal(0.0, 0.3)
            hold = rng.uniform(0.5, 1.5)
        m = min(end, k + int(round(hold * rate_hz)))
        tgt_v[k:m] = float(np.clip(v, -v_limit, v_limit))
        tgt_w[k:m] = float(np.clip(w, -w_limit, w_limit))
        if mode != "stop":
            rate_v[k:m] = rng.uniform(*st["acc"])
            rate_w[k:m] = rng.uniform(*st["alpha"])
        k = m
    # thumb: rate-limited stick followed by a first-order filter
    a = 1.0 - math.exp(-h / st["tau"])
    out_v = np.zeros(n)
    out_w = np.zeros(n)
    pv = pw = fv = fw = 0.0
    for i in range(n):
        dv = tgt_v[i] - pv
        lim = rate_v[i] * h
        pv += lim if dv > lim else (-lim if dv < -lim else dv)
        dw = tgt_w[i] - pw
        lim = rate_w[i] * h
        pw += lim if dw > lim else (-lim if dw < -lim else dw)
        fv += a * (pv - fv)
        fw += a * (pw - fw)
        out_v[i] = fv
        out_w[i] = fw
    # joystick axis quantisation (and exact zeros at rest)
    return np.round(out_v, 4) + 0.0, np.round(out_w, 4) + 0.0


# --------------------------------------------------------------------------
# Simulation
# --------------------------------------------------------------------------
def _stack(values: list[float]) -> np.ndarray:
    return np.asarray(values, dtype=float)


def simulate_runs(
    commands: list[tuple[np.ndarray, np.ndarray]],
    conditions: list[RunConditions],
    hidden: TeleopHidden = TeleopHidden(),
    robot: TeleopRobot = TeleopRobot(),
    drive: DriveTrain = DriveTrain(),
) -> list[Trace]:
    """Simulate several runs of the same robot in one vectorised pass.

    Parameters
    ----------
    commands : list of (ndarray, ndarray)
        Per run, the joystick twist ``(v, w)`` at ``drive.joystick_hz``.
    conditions : list of RunConditions
        Per run conditions (same length as ``commands``).
    hidden : TeleopHidden
        Hidden effects of the robot.
    robot : TeleopRobot
        Datasheet values (used by the firmware).
    drive : DriveTrain
        Physical constants.

    Returns
    -------
    list of Trace
        True motion of every run, sampled every ``drive.dt`` from 0 to its
        duration.
    """
    n = len(commands)
    if n != len(conditions) or n == 0:
        raise ValueError("need one RunConditions per command stream")
    dt = drive.dt
    tc = 1.0 / drive.control_hz
    sub = int(round(tc / dt))
    if abs(sub * dt - tc) > 1e-12:
        raise ValueError("control period must be a multiple of dt")
    durations = _stack([c.duration_s for c in conditions])
    n_ticks = int(math.ceil(durations.max() * drive.control_hz))
    steps = n_ticks * sub
    m = robot.mass_kg
    iz = drive.yaw_inertia
    jw = drive.wheel_inertia

    # ---- true geometry
    r_left, r_right = hidden.true_radii(robot)
    hb = 0.5 * hidden.true_wheelbase(robot)
    r0 = np.array([[r_left], [r_right]]) * np.ones((2, n))

    # ---- firmware set-points at every control tick (nominal geometry)
    n_cmd = int(round(durations.max() * drive.joystick_hz)) + 1
    cv = np.zeros((n_cmd, n))
    cw = np.zeros((n_cmd, n))
    for i, (v, w) in enumerate(commands):
        v, w = np.asarray(v)[:n_cmd], np.asarray(w)[:n_cmd]  # longer streams are cut
        cv[: len(v), i] = v
        cw[: len(w), i] = w
    t_tick = np.arange(n_ticks) * tc
    t_seen = t_tick - hidden.command_delay_s
    idx = np.floor(t_seen * drive.joystick_hz + 1e-9).astype(int)
    valid = (idx >= 0)[:, None]
    idx = np.clip(idx, 0, n_cmd - 1)
    v_sp = np.where(valid, cv[idx], 0.0)
    w_sp = np.where(valid, cw[idx], 0.0)
    v_sp = np.clip(v_sp, -robot.v_max_mps, robot.v_max_mps)
    w_sp = np.clip(w_sp, -robot.w_max_radps, robot.w_max_radps)
    half_b = 0.5 * robot.wheelbase_m
    wheel_lin = np.stack([v_sp - w_sp * half_b, v_sp + w_sp * half_b], axis=1)  # (ticks, 2, n)
    wheel_lin = np.clip(wheel_lin, -robot.v_max_mps, robot.v_max_mps)
    dz = np.array([hidden.deadzone_left_mps, hidden.deadzone_right_mps])[None, :, None]
    dead = np.abs(wheel_lin) < dz  # (ticks, 2, n); all False without dead zones
    sp = wheel_lin / robot.wheel_radius_m

    # ---- drive limits and gains
    batt = drive.battery_v * _stack([c.battery_factor for c in conditions])
    if hidden.top_speed_limit_mps is not None:
        duty = drive.voltage_for_speed(hidden.top_speed_limit_mps / robot.wheel_radius_m)
        duty /= drive.battery_v
    else:
        duty = 1.0
    v_lim = duty * batt  # (n,)
    gain_r = drive.k_t / drive.resistance_ohm
    coul = drive.coulomb_nm * _stack([c.coulomb_scale for c in conditions])
    sag = hidden.right_motor_gain_sag

    # ---- encoders
    cpr_true = robot.counts_per_rev * hidden.encoder_counts_factor
    cnt_scale = cpr_true / TWO_PI
    enc_phase = np.array([c.encoder_phase for c in conditions]).T  # (2, n)
    enc_base = np.floor(enc_phase)
    meas_scale = TWO_PI / (robot.counts_per_rev * tc)

    # ---- contact
    mu = (
        _stack([c.floor_mu for c in conditions])
        if hidden.friction_coefficient is None
        else hidden.friction_coefficient * _stack([c.floor_mu / drive.floor_mu for c in conditions])
    )
    p_max = mu * drive.drive_load_fraction * m * GRAVITY / 2.0 * dt  # impulse bound per wheel
    c12 = 1.0 / m - hb * hb / iz
    cdiag = 1.0 / m + hb * hb / iz

    def contact_matrix(rl: np.ndarray, rr: np.ndarray) -> tuple[np.ndarray, ...]:
        a11 = rl * rl / jw + cdiag
        a22 = rr * rr / jw + cdiag
        det = a11 * a22 - c12 * c12
        return a11, a22, a22 / det, a11 / det, -c12 / det

    a11, a22, i11, i22, i12 = contact_matrix(r0[0], r0[1])

    # ---- external loads
    slope_acc = GRAVITY * math.sin(hidden.floor_slope_rad)
    slope_dir = _stack([c.slope_dir_rad for c in conditions])
    caster_yaw = drive.caster_offset_m * hidden.caster_side_drag_n_per_radps / iz
    ripple = hidden.right_torque_ripple_nm
    ripple_w = TWO_PI * hidden.right_torque_ripple_hz
    ripple_phase = _stack([c.ripple_phase_rad for c in conditions])
    oor = hidden.out_of_round_right

    # ---- state
    om = np.zeros((2, n))
    phi = np.zeros((2, n))
    v = np.zeros(n)
    w = np.zeros(n)
    th = _stack([c.heading0_rad for c in conditions])
    integ = np.zeros((2, n))
    volt = np.zeros((2, n))
    counts_prev = np.zeros((2, n))
    h_v = np.zeros((steps + 1, n))
    h_w = np.zeros((steps + 1, n))
    h_th = np.zeros((steps + 1, n))
    h_phi = np.zeros((steps + 1, 2, n))
    h_om = np.zeros((steps + 1, 2, n))
    h_th[0] = th
    kp, ki_tc = drive.kp, drive.ki * tc
    bv = drive.viscous_nms
    k_e = drive.k_e
    dt_j = dt / jw
    gain = np.full((2, n), gain_r)
    bemf = np.full((2, n), k_e)

    k = 0
    for c in range(n_ticks):
        t_now = c * tc
        # -- firmware: speed from count differences, PI with anti-windup
        counts = np.floor(phi * cnt_scale + enc_phase) - enc_base
        om_meas = (counts - counts_prev) * meas_scale
        counts_prev = counts
        err = sp[c] - om_meas
        i_new = integ + ki_tc * err
        u = kp * err + i_new
        sat = np.abs(u) > v_lim
        integ = np.where(sat & (np.sign(err) == np.sign(u)), integ, i_new)
        volt = np.clip(u, -v_lim, v_lim)
        if hidden.deadzone_left_mps or hidden.deadzone_right_mps:
            off = dead[c]
            volt = np.where(off, 0.0, volt)
            integ = np.where(off, 0.0, integ)
        if sag:
            g = 1.0 - sag * np.minimum(t_now / durations, 1.0)
            gain[1] = gain_r * g
            bemf[1] = k_e * g
        for _ in range(sub):
            t_k = k * dt
            # -- motor torques and unconstrained velocity update
            tau = gain * (volt - bemf * om) - bv * om - coul * np.clip(om * 20.0, -1.0, 1.0)
            if ripple:
                tau[1] += ripple * np.sin(ripple_w * t_k + ripple_phase)
            om_s = om + dt_j * tau
            v_s = v
            w_s = w
            if slope_acc:
                v_s = v + dt * slope_acc * np.cos(slope_dir - th)
            if caster_yaw:
                w_s = w - dt * caster_yaw * w
            if oor:
                rl = r0[0]
                rr = r0[1] * (1.0 + oor * np.sin(phi[1]))
                a11, a22, i11, i22, i12 = contact_matrix(rl, rr)
            else:
                rl, rr = r0[0], r0[1]
            # -- friction-limited contact impulses (stick if possible)
            s_l = rl * om_s[0] - v_s + hb * w_s
            s_r = rr * om_s[1] - v_s - hb * w_s
            p_l = np.clip(i11 * s_l + i12 * s_r, -p_max, p_max)
            p_r = np.clip(i12 * s_l + i22 * s_r, -p_max, p_max)
            if hidden.friction_coefficient is not None:
                for _sweep in range(2):
                    p_l = np.clip((s_l - c12 * p_r) / a11, -p_max, p_max)
                    p_r = np.clip((s_r - c12 * p_l) / a22, -p_max, p_max)
            om = om_s - np.stack([rl * p_l, rr * p_r]) / jw
            v = v_s + (p_l + p_r) / m
            w = w_s + hb * (p_r - p_l) / iz
            phi = phi + om * dt
            th = th + w * dt
            k += 1
            h_v[k] = v
            h_w[k] = w
            h_th[k] = th
            h_phi[k] = phi
            h_om[k] = om

    # ---- lateral creep and pose integration (vectorised over time)
    t = np.arange(steps + 1) * dt
    f_lat = hidden.caster_side_drag_n_per_radps * h_w
    if slope_acc:
        f_lat = f_lat + m * slope_acc * np.sin(slope_dir[None, :] - h_th)
    if oor:
        rr_hist = r0[1][None, :] * (1.0 + oor * np.sin(h_phi[:, 1]))
    else:
        rr_hist = r0[1][None, :]
    roll = 0.5 * (np.abs(r0[0][None, :] * h_om[:, 0]) + np.abs(rr_hist * h_om[:, 1]))
    v_y = f_lat / drive.cornering_stiffness_n_per_rad * roll
    th_mid = 0.5 * (h_th[1:] + h_th[:-1])
    vx = h_v[1:]
    vy = v_y[1:]
    dx = (vx * np.cos(th_mid) - vy * np.sin(th_mid)) * dt
    dy = (vx * np.sin(th_mid) + vy * np.cos(th_mid)) * dt
    x = np.vstack([np.zeros((1, n)), np.cumsum(dx, axis=0)])
    y = np.vstack([np.zeros((1, n)), np.cumsum(dy, axis=0)])

    traces = []
    for i, (cmd, cond) in enumerate(zip(commands, conditions)):
        last = int(round(cond.duration_s / dt)) + 1
        traces.append(
            Trace(
                t=t[:last],
                x=x[:last, i],
                y=y[:last, i],
                yaw=h_th[:last, i],
                v=h_v[:last, i],
                w=h_w[:last, i],
                phi_left=h_phi[:last, 0, i],
                phi_right=h_phi[:last, 1, i],
                cmd_v=cmd[0],
                cmd_w=cmd[1],
            )
        )
    return traces


# --------------------------------------------------------------------------
# Sensors
# --------------------------------------------------------------------------
def _occlusion_mask(
    rng: np.random.Generator, t: np.ndarray, rate: float, mean_s: float
) -> np.ndarray:
    """Boolean mask of samples inside motion-capture occlusions."""
    mask = np.zeros(t.shape, dtype=bool)
    if rate <= 0.0:
        return mask
    start = t[0] + rng.exponential(1.0 / rate)
    while start < t[-1]:
        length = rng.uniform(0.4, 2.0 * mean_s - 0.4)
        mask |= (t >= start) & (t < start + length)
        start += length + rng.exponential(1.0 / rate)
    return mask


def measure_run(
    trace: Trace,
    cond: RunConditions,
    rate_hz: float,
    rng: np.random.Generator,
    hidden: TeleopHidden = TeleopHidden(),
    robot: TeleopRobot = TeleopRobot(),
    drive: DriveTrain = DriveTrain(),
) -> dict[str, np.ndarray]:
    """Log one run: commands, encoder counts and motion-capture ground truth.

    Parameters
    ----------
    trace : Trace
        True motion from :func:`simulate_runs`.
    cond : RunConditions
        The run's conditions (encoder phases).
    rate_hz : float
        Log rate, Hz.
    rng : numpy.random.Generator
        Source of sensor randomness.
    hidden : TeleopHidden
        Hidden effects (encoder scale and ground-truth faults).
    robot : TeleopRobot
        Datasheet values.
    drive : DriveTrain
        Sensor constants.

    Returns
    -------
    dict of str to ndarray
        Columns of the CSV file, keyed by header name.
    """
    duration = float(trace.t[-1])
    n_log = int(math.floor(duration * rate_hz + 1e-9))
    t_log = np.arange(n_log) / rate_hz

    # commands as logged: the last twist sent at or before the log instant
    j = np.floor(t_log * drive.joystick_hz + 1e-9).astype(int)
    j = np.clip(j, 0, len(trace.cmd_v) - 1)
    cmd_v = trace.cmd_v[j]
    cmd_w = trace.cmd_w[j]

    # encoders: cumulative integer counts of the true wheel angles
    cnt_scale = robot.counts_per_rev * hidden.encoder_counts_factor / TWO_PI
    ph = np.asarray(cond.encoder_phase, dtype=float)
    counts = []
    for a, p in ((trace.phi_left, ph[0]), (trace.phi_right, ph[1])):
        ang = np.interp(t_log, trace.t, a)
        counts.append((np.floor(ang * cnt_scale + p) - math.floor(p)).astype(np.int64))

    # motion capture on its own clock (phase and a small rate error)
    period = (1.0 + rng.uniform(-50e-6, 50e-6)) / drive.mocap_hz
    t0 = -rng.uniform(0.0, period) - 0.1
    t_m = t0 + period * np.arange(int((duration + 0.3) / period) + 1)
    tc = np.clip(t_m, 0.0, duration)
    mx = np.interp(tc, trace.t, trace.x) + rng.normal(0.0, drive.mocap_pos_noise_m, t_m.size)
    my = np.interp(tc, trace.t, trace.y) + rng.normal(0.0, drive.mocap_pos_noise_m, t_m.size)
    myaw = np.interp(tc, trace.t, trace.yaw) + rng.normal(0.0, drive.mocap_yaw_noise_rad, t_m.size)
    if hidden.mocap_yaw_drift_rad:
        phase = rng.uniform(0.0, TWO_PI)
        myaw = myaw + hidden.mocap_yaw_drift_rad * np.sin(
            TWO_PI * t_m / hidden.mocap_yaw_drift_period_s + phase
        )
    occl = _occlusion_mask(rng, t_m, hidden.mocap_occlusion_rate_hz, hidden.mocap_occlusion_mean_s)
    if occl.any():
        last_ok = np.maximum.accumulate(np.where(occl, 0, np.arange(t_m.size)))
        mx, my, myaw = mx[last_ok], my[last_ok], myaw[last_ok]
    myaw = np.unwrap(np.angle(np.exp(1j * myaw)))  # the mocap reports wrapped yaw
    gx = np.interp(t_log, t_m, mx)
    gy = np.interp(t_log, t_m, my)
    gyaw = np.interp(t_log, t_m, myaw)

    # start frame: mean pose while the robot stands still at the start
    still = t_log < 0.5
    x0, y0, yaw0 = gx[still].mean(), gy[still].mean(), gyaw[still].mean()
    c, s = math.cos(yaw0), math.sin(yaw0)
    dx, dy = gx - x0, gy - y0
    return {
        "time_s": t_log,
        "cmd_v_mps": cmd_v,
        "cmd_w_radps": cmd_w,
        "enc_left_counts": counts[0],
        "enc_right_counts": counts[1],
        "x_m": c * dx + s * dy,
        "y_m": -s * dx + c * dy,
        "yaw_rad": gyaw - yaw0,
    }


# --------------------------------------------------------------------------
# Data set writer
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class SessionSpec:
    """One logging session of a case.

    Attributes
    ----------
    name : str
        Session name.
    day : str
        Day name.
    split : str
        ``"train"`` or ``"holdout"``.
    rate_hz : float
        Log rate, Hz.
    runs : int
        Number of runs.
    """

    name: str
    day: str
    split: str
    rate_hz: float
    runs: int


#: Sessions of every case: day 1 trains, day 2 is held out; 25 Hz and 40 Hz.
SESSIONS: tuple[SessionSpec, ...] = (
    SessionSpec("d1_s1", "day1", "train", 25.0, 3),
    SessionSpec("d1_s2", "day1", "train", 40.0, 3),
    SessionSpec("d2_s1", "day2", "holdout", 25.0, 2),
    SessionSpec("d2_s2", "day2", "holdout", 40.0, 2),
)

CSV_HEADER = "time_s,cmd_v_mps,cmd_w_radps,enc_left_counts,enc_right_counts,x_m,y_m,yaw_rad"


def _atomic_write(path: pathlib.Path, text: str) -> None:
    """Write text to ``path`` via a temporary file and :func:`os.replace`."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _csv_text(cols: dict[str, np.ndarray]) -> str:
    """Format the log columns with fixed precision (byte-reproducible)."""
    lines = [CSV_HEADER]
    rows = zip(
        cols["time_s"],
        cols["cmd_v_mps"],
        cols["cmd_w_radps"],
        cols["enc_left_counts"],
        cols["enc_right_counts"],
        cols["x_m"],
        cols["y_m"],
        cols["yaw_rad"],
    )
    for t, cv, cw, el, er, x, y, yaw in rows:
        lines.append(f"{t:.4f},{cv:.4f},{cw:.4f},{el:d},{er:d},{x:.5f},{y:.5f},{yaw:.6f}")
    return "\n".join(lines).replace("-0.0000,", "0.0000,") + "\n"


def hidden_of(case: Any) -> TeleopHidden:
    """Build the :class:`TeleopHidden` of a case (checks the field names)."""
    known = {f.name for f in fields(TeleopHidden)}
    unknown = set(case.hidden) - known
    if unknown:
        raise ValueError(f"unknown hidden fields {sorted(unknown)}")
    return TeleopHidden(**case.hidden)


def write_case(
    case: Any,
    folder: pathlib.Path,
    seed: int,
    *,
    run_duration_s: tuple[float, float] = (60.0, 120.0),
    robot: TeleopRobot = TeleopRobot(),
    drive: DriveTrain = DriveTrain(),
) -> dict:
    """Generate every session of a case and write it as a data set.

    Writes one CSV file per run and ``dataset.json``; nothing about the case
    (name, hidden effects) is written.

    Parameters
    ----------
    case : TeleopCase
        The case (needs ``hidden`` and optionally ``motion``).
    folder : pathlib.Path
        Output folder (created if missing).
    seed : int
        Non-negative seed; together with the case name it seeds the one
        :class:`numpy.random.Generator` that drives everything.
    run_duration_s : tuple of float
        Range of run lengths, s (whole seconds are drawn); shorten for tests.
    robot : TeleopRobot
        Datasheet values.
    drive : DriveTrain
        Physical constants.

    Returns
    -------
    dict
        Content of ``dataset.json`` (file paths relative to ``folder``).
    """
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    hidden = hidden_of(case)
    style = getattr(case, "motion", "normal")
    # the case name is mixed into the seed so that cases sharing a seed (e.g.
    # the nominal repeats) still get their own motions and conditions
    tag = zlib.crc32(str(getattr(case, "name", "")).encode("utf-8"))
    rng = np.random.default_rng([int(seed), tag])
    cmd_rng, cond_rng, sensor_rng = rng.spawn(3)

    days = sorted({s.day for s in SESSIONS})
    day_cond = {
        d: {
            "battery_factor": float(cond_rng.uniform(0.97, 1.03)),
            "floor_mu": float(drive.floor_mu * cond_rng.uniform(0.95, 1.05)),
            "coulomb_scale": float(cond_rng.uniform(0.85, 1.15)),
        }
        for d in days
    }
    slope_dir = float(cond_rng.uniform(-math.pi, math.pi))
    lo, hi = run_duration_s

    plan: list[tuple[SessionSpec, int]] = []
    commands: list[tuple[np.ndarray, np.ndarray]] = []
    conditions: list[RunConditions] = []
    for sess in SESSIONS:
        for r in range(sess.runs):
            dur = float(cmd_rng.integers(int(lo), int(hi) + 1))
            commands.append(joystick_commands(cmd_rng, dur, style, drive.joystick_hz))
            conditions.append(
                RunConditions(
                    duration_s=dur,
                    heading0_rad=float(cond_rng.uniform(-math.pi, math.pi)),
                    slope_dir_rad=slope_dir,
                    encoder_phase=(float(cond_rng.random()), float(cond_rng.random())),
                    ripple_phase_rad=float(cond_rng.uniform(0.0, TWO_PI)),
                    **day_cond[sess.day],
                )
            )
            plan.append((sess, r))

    traces = simulate_runs(commands, conditions, hidden, robot, drive)

    runs = []
    for (sess, r), trace, cond in zip(plan, traces, conditions):
        cols = measure_run(trace, cond, sess.rate_hz, sensor_rng, hidden, robot, drive)
        name = f"{sess.name}_run{r + 1}.csv"
        _atomic_write(folder / name, _csv_text(cols))
        runs.append(
            {
                "file": name,
                "session": sess.name,
                "day": sess.day,
                "split": sess.split,
                "rate_hz": sess.rate_hz,
            }
        )
    meta = {"robot": robot.as_json(), "runs": runs}
    _atomic_write(folder / "dataset.json", json.dumps(meta, indent=2) + "\n")
    return meta
