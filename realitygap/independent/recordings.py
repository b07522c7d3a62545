"""Recordings of wheeled robots and a six-joint arm, written in the shapes real logs come in.

This module generates data sets for testing tools that read robot recordings and
identify kinematic parameters from them.  It is written independently of any such
tool: the physics, the sensors and the file writers are its own, and it imports
only NumPy, SciPy, the standard library and (lazily, for bags) ``rosbags``.  Every
data set is written with the values the generator used in ``answer.json``.

Wheeled robots (SI units throughout)
------------------------------------
Kinematics
    A rigid body on a flat floor driven by the left/right wheel angular speeds
    ``wl, wr`` (rad/s).  Differential drive with true wheel radii ``rl, rr`` and
    true wheelbase ``b``::

        v = (rr wr + rl wl) / 2,   w = (rr wr - rl wl) / b

    Four-wheel skid-steer (both wheels of a side turn together) with wheel radius
    ``r``, geometric track ``T`` and effective track ``B_eff = chi T``::

        v = r (wl + wr) / 2,       w = r (wr - wl) / B_eff

    plus a lateral slip velocity ``vy = xi(t) (|v| + |w| B_eff / 2)`` where
    ``xi`` is an Ornstein-Uhlenbeck process (a slip ratio of about 1 %).
    Heading is the exact linear function of the wheel angles; the position is
    integrated at 1 kHz with RK4 (which reduces to Simpson's rule because the
    body velocity depends on time only).
Drive train
    A twist command ``(v, w)`` is sent at a command rate and held.  The firmware
    turns it into wheel-speed set-points with the *nominal* geometry; each wheel
    speed follows its set-point through a first-order lag (``tau = 0.05 s``),
    solved exactly per 1 ms step.
Motion
    A run (60-120 s) stands still for 1 s, then chains manoeuvres separated by
    short stops: straights of 0.5-2 m at 0.2-0.5 m/s, turns in place of
    +-90-180 deg at 0.5-1.2 rad/s and arcs of 0.5-2 m radius at 0.2-0.4 m/s,
    kept inside a 2 m disc around the day's arena centre; it ends standing
    still for at least 2 s.  Commands are multiples of 1 mm/s and 1 mrad/s.
Sensors
    Encoders: integer cumulative counts ``offset + floor(sign phi N / 2 pi)``
    (``phi`` the wheel angle since the run start, ``N`` counts per revolution,
    ``sign = -1`` for a mirrored encoder).  Motion capture: the pose of a rigid
    body fixed on the robot at ``(xo, yo)`` in the body frame (x forward, y left)
    from the axle centre, with yaw offset ``psi_o``, in the capture system's world
    frame (each day has its own arena centre; runs start anywhere in it), with
    0.5 mm and 1 mrad Gaussian noise; yaw is wrapped to [-pi, pi).

Arm
---
A six-revolute UR-like arm (axes z, y, y, y, z, y; upper arm 0.600 m, forearm
0.560 m) described by a URDF written here.  Its true geometry is the nominal one
plus joint-angle offsets (+-2 mrad: the joint turns to ``q_logged + offset``) and
length errors (+-1 mm on every non-zero component of every joint origin and of
the tool point).  A laser tracker measures the tool point in its own frame
(``p_tracker = R p_base + t``) with 20 um noise; the CSV holds the logged joint
angles and the tracker's positions in mm.

File shapes
-----------
One function per shape; each takes a seed or a :class:`numpy.random.Generator`
and an output folder, writes atomically and returns a :class:`Written`:

``text_title_mirrored``   whitespace-aligned or ``|``-separated text, two title lines
``multirate_one_file``    interleaved 50 Hz encoder / 120 Hz mocap CSV, or two files
``mat_file``              MATLAB v5 ``.mat`` with equal-length vectors
``ros2_bag``              ROS 2 sqlite3 bags with ``/cmd_vel``, ``/joint_states``, mocap
``skid_steer``            CSV of a 4-wheel skid-steer with its URDF
``arm_csv``               joint angles and laser-tracker positions with a nominal URDF

Every wheeled data set has runs on two days (three on day 1 and two on day 2 by
default; two and two for bags), one file (or one bag folder, or one sub-folder for the two-file
variant) per run named ``day<d>_run<k>``; ``answer.json`` lists which file
belongs to which day.  Beside the runs are ``robot.urdf`` and ``robot.json``
(the nominal values a user would put in their robot description).
:func:`write_all` writes every shape into sub-folders; ``python -m
realitygap.independent.recordings FOLDER [--seed S]`` does so and prints a
summary.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import pathlib
import shutil
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from scipy import io as sio
from scipy import signal

__all__ = [
    "SIM_RATE_HZ",
    "DriveSpec",
    "MocapMount",
    "Trajectory",
    "Written",
    "arm_csv",
    "arm_forward",
    "draw_diff_drive",
    "draw_skid_steer",
    "main",
    "mat_file",
    "multirate_one_file",
    "plan_commands",
    "ros2_bag",
    "simulate_drive",
    "skid_steer",
    "summary",
    "text_title_mirrored",
    "write_all",
]

SIM_RATE_HZ = 1000
SIM_STEP_US = 1_000_000 // SIM_RATE_HZ
TWO_PI = 2.0 * math.pi
US = 1_000_000
# Epoch (s) of 2024-03-05 09:00:00 UTC: the first day of every wheeled data set.
DAY1_EPOCH_S = 1_709_629_200
DAY_DATES = {1: ("2024-03-05", DAY1_EPOCH_S), 2: ("2024-03-07", DAY1_EPOCH_S + 2 * 86_400)}
MOCAP_POS_NOISE_M = 0.5e-3
MOCAP_YAW_NOISE_RAD = 1.0e-3
ARENA_RADIUS_M = 2.0
SeedLike = np.random.Generator | int | Sequence[int] | None


# --------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class DriveSpec:
    """Nominal and true parameters of a two-sided wheeled base.

    Attributes
    ----------
    kind : str
        ``"differential_drive"`` or ``"skid_steer"``.
    nominal_radius_m : float
        Wheel radius in the user's robot description, m.
    nominal_track_m : float
        Wheelbase (differential) or geometric track (skid-steer) in the user's
        robot description, m.  The firmware converts twists with it.
    ticks_per_rev : int
        Encoder counts per wheel revolution (true and nominal).
    radius_left_m, radius_right_m : float
        True wheel radii, m.
    yaw_track_m : float
        True track in the yaw-rate equation: the wheelbase ``b`` of a
        differential drive, ``B_eff = chi T`` of a skid-steer, m.
    lag_s : float
        Time constant of the wheel-speed response to its set-point, s.
    slip_ratio_std : float
        Standard deviation of the lateral slip ratio ``xi`` (0: no slip).
    slip_corr_s : float
        Correlation time of ``xi``, s.
    """

    kind: str
    nominal_radius_m: float
    nominal_track_m: float
    ticks_per_rev: int
    radius_left_m: float
    radius_right_m: float
    yaw_track_m: float
    lag_s: float = 0.05
    slip_ratio_std: float = 0.0
    slip_corr_s: float = 0.5


@dataclass(frozen=True)
class MocapMount:
    """Pose of the tracked rigid body in the robot body frame.

    Attributes
    ----------
    offset_x_m, offset_y_m : float
        Position of the tracked point from the axle centre (x forward, y left), m.
    yaw_offset_rad : float
        Yaw of the tracked body relative to the robot heading, rad.
    """

    offset_x_m: float = 0.0
    offset_y_m: float = 0.0
    yaw_offset_rad: float = 0.0


@dataclass(frozen=True)
class Written:
    """What a writer produced.

    Attributes
    ----------
    folder : pathlib.Path
        The data set folder.
    files : list of pathlib.Path
        Every file or bag folder written, ``answer.json`` first.
    answer : dict
        The content of ``answer.json``.
    """

    folder: pathlib.Path
    files: list[pathlib.Path]
    answer: dict[str, Any]


def _as_rng(seed: SeedLike) -> tuple[np.random.Generator, int | list[int] | None]:
    """Return a generator and the seed as JSON (``None`` if a generator was given)."""
    if isinstance(seed, np.random.Generator) or seed is None:
        return np.random.default_rng(seed), None
    if isinstance(seed, int | np.integer):
        return np.random.default_rng(int(seed)), int(seed)
    entropy = [int(s) for s in seed]
    return np.random.default_rng(entropy), entropy


def draw_diff_drive(
    rng: np.random.Generator,
    nominal_radius_m: float,
    nominal_wheelbase_m: float,
    ticks_per_rev: int,
    *,
    radius_error: float | None = None,
    radius_asymmetry: float | None = None,
    wheelbase_error: float | None = None,
    lag_s: float = 0.05,
) -> DriveSpec:
    """Draw the true geometry of a differential drive around its nominal values.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    nominal_radius_m, nominal_wheelbase_m : float
        The user's values, m.
    ticks_per_rev : int
        Encoder counts per revolution.
    radius_error : float, optional
        Relative error of the mean true radius (default: uniform in [-2 %, -0.5 %]).
    radius_asymmetry : float, optional
        ``(rr - rl) / r_mean`` (default: uniform in [-0.5 %, 0.5 %]).
    wheelbase_error : float, optional
        Relative error of the true wheelbase (default: uniform in [+1 %, +5 %]).
    lag_s : float
        Wheel-speed time constant, s.

    Returns
    -------
    DriveSpec
    """
    e_r = rng.uniform(-0.02, -0.005) if radius_error is None else radius_error
    asym = rng.uniform(-0.005, 0.005) if radius_asymmetry is None else radius_asymmetry
    e_b = rng.uniform(0.01, 0.05) if wheelbase_error is None else wheelbase_error
    r_mean = nominal_radius_m * (1.0 + e_r)
    return DriveSpec(
        kind="differential_drive",
        nominal_radius_m=nominal_radius_m,
        nominal_track_m=nominal_wheelbase_m,
        ticks_per_rev=int(ticks_per_rev),
        radius_left_m=r_mean * (1.0 - asym / 2.0),
        radius_right_m=r_mean * (1.0 + asym / 2.0),
        yaw_track_m=nominal_wheelbase_m * (1.0 + e_b),
        lag_s=lag_s,
    )


def draw_skid_steer(
    rng: np.random.Generator,
    nominal_radius_m: float,
    track_m: float,
    ticks_per_rev: int,
    *,
    chi: float | None = None,
    radius_error: float | None = None,
    slip_ratio_std: float = 0.01,
    slip_corr_s: float = 0.5,
    lag_s: float = 0.05,
) -> DriveSpec:
    """Draw the true parameters of a four-wheel skid-steer.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    nominal_radius_m : float
        The user's wheel radius, m.
    track_m : float
        Geometric track ``T`` (true and nominal), m.
    ticks_per_rev : int
        Encoder counts per revolution.
    chi : float, optional
        ``B_eff / T`` (default: uniform in [1.2, 1.8]).
    radius_error : float, optional
        Relative error of the true radius (default: uniform in [-2 %, -0.5 %]).
    slip_ratio_std, slip_corr_s : float
        Lateral slip ratio standard deviation and correlation time (s).
    lag_s : float
        Wheel-speed time constant, s.

    Returns
    -------
    DriveSpec
    """
    chi_v = rng.uniform(1.2, 1.8) if chi is None else chi
    e_r = rng.uniform(-0.02, -0.005) if radius_error is None else radius_error
    r = nominal_radius_m * (1.0 + e_r)
    return DriveSpec(
        kind="skid_steer",
        nominal_radius_m=nominal_radius_m,
        nominal_track_m=track_m,
        ticks_per_rev=int(ticks_per_rev),
        radius_left_m=r,
        radius_right_m=r,
        yaw_track_m=chi_v * track_m,
        lag_s=lag_s,
        slip_ratio_std=slip_ratio_std,
        slip_corr_s=slip_corr_s,
    )


def _draw_mount(
    rng: np.random.Generator, nominal: MocapMount, spread: Sequence[float]
) -> MocapMount:
    """True mount = nominal + uniform errors of half-widths ``spread`` (m, m, rad)."""
    return MocapMount(
        nominal.offset_x_m + rng.uniform(-spread[0], spread[0]),
        nominal.offset_y_m + rng.uniform(-spread[1], spread[1]),
        nominal.yaw_offset_rad + rng.uniform(-spread[2], spread[2]),
    )


# --------------------------------------------------------------------------
# Motion
# --------------------------------------------------------------------------
def _arc_end(pose: Sequence[float], v: float, w: float, duration: float) -> tuple[float, ...]:
    """Exact end pose of a constant twist held for ``duration`` seconds."""
    x, y, th = pose
    dth = w * duration
    if abs(dth) < 1e-12:
        return x + v * duration * math.cos(th), y + v * duration * math.sin(th), th
    radius = v / w
    return (
        x + radius * (math.sin(th + dth) - math.sin(th)),
        y - radius * (math.cos(th + dth) - math.cos(th)),
        th + dth,
    )


def plan_commands(
    rng: np.random.Generator,
    duration_s: float,
    cmd_rate_hz: int,
    start_pose: Sequence[float],
    arena_centre: Sequence[float],
    arena_radius_m: float = ARENA_RADIUS_M,
) -> tuple[np.ndarray, np.ndarray]:
    """Plan a run's twist commands, one per command period.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the manoeuvre draws.
    duration_s : float
        Run length, s (rounded to the command period); the manoeuvres stop when
        the next one would not leave 2 s of standing still at the end.
    cmd_rate_hz : int
        Command rate, Hz.
    start_pose : sequence of float
        ``(x, y, theta)`` of the axle centre in the world frame (m, m, rad).
    arena_centre : sequence of float
        Centre of the allowed disc, m.
    arena_radius_m : float
        Radius of the disc the planned path stays in, m.

    Returns
    -------
    v_cmd, w_cmd : numpy.ndarray
        Commanded speed (m/s) and turn rate (rad/s), multiples of 1e-3.
    """
    dt = 1.0 / cmd_rate_hz
    segments: list[tuple[float, float, int]] = [(0.0, 0.0, round(1.0 / dt))]
    pose: tuple[float, ...] = tuple(float(p) for p in start_pose)
    cx, cy = float(arena_centre[0]), float(arena_centre[1])
    elapsed = 1.0

    def inside(p: Sequence[float]) -> bool:
        return math.hypot(p[0] - cx, p[1] - cy) <= arena_radius_m

    def candidate() -> tuple[float, float, int]:
        kind = rng.choice(3, p=[0.4, 0.3, 0.3])
        sign = 1.0 if rng.random() < 0.5 else -1.0
        if kind == 0:  # straight
            dist = rng.uniform(0.5, 2.0)
            v = round(rng.uniform(0.2, 0.5), 3)
            return v, 0.0, max(1, round(dist / v / dt))
        if kind == 1:  # turn in place
            angle = rng.uniform(0.5 * math.pi, math.pi)
            w = round(rng.uniform(0.5, 1.2), 3)
            return 0.0, sign * w, max(1, round(angle / w / dt))
        radius = rng.uniform(0.5, 2.0)  # arc
        v = round(rng.uniform(0.2, 0.4), 3)
        w = round(v / radius, 3)
        sweep = rng.uniform(0.25 * math.pi, math.pi)
        return v, sign * w, max(1, round(sweep / w / dt))

    while elapsed < duration_s - 2.0:
        chosen = None
        for _ in range(20):
            v, w, n = candidate()
            checks = [_arc_end(pose, v, w, n * dt * f) for f in (0.25, 0.5, 0.75, 1.0)]
            if all(inside(p) for p in checks):
                chosen = (v, w, n)
                break
        if chosen is None:  # turn around: the way back is known to be inside
            chosen = (0.0, 0.8, round(math.pi / 0.8 / dt))
        v, w, n = chosen
        pause = max(1, round(rng.uniform(0.3, 1.0) / dt))
        if elapsed + (n + pause) * dt > duration_s - 2.0:
            break  # does not fit: the run ends standing still
        pose = _arc_end(pose, v, w, n * dt)
        segments += [chosen, (0.0, 0.0, pause)]
        elapsed += (n + pause) * dt
    total = round(duration_s / dt)
    segments.append((0.0, 0.0, total - sum(seg[2] for seg in segments)))
    v_cmd = np.concatenate([np.full(n, v) for v, _, n in segments])
    w_cmd = np.concatenate([np.full(n, w) for _, w, n in segments])
    return v_cmd, w_cmd


@dataclass(frozen=True)
class Trajectory:
    """A simulated run sampled at 1 kHz.

    Attributes
    ----------
    x_m, y_m, theta_rad : numpy.ndarray
        Axle-centre pose in the world frame (heading unwrapped), at ``k`` ms.
    phi_left_rad, phi_right_rad : numpy.ndarray
        Wheel angles since the run start (forward positive), rad.
    v_cmd, w_cmd : numpy.ndarray
        The commands, one per command period (m/s, rad/s).
    cmd_rate_hz : int
        Command rate, Hz.
    """

    x_m: np.ndarray
    y_m: np.ndarray
    theta_rad: np.ndarray
    phi_left_rad: np.ndarray
    phi_right_rad: np.ndarray
    v_cmd: np.ndarray
    w_cmd: np.ndarray
    cmd_rate_hz: int

    @property
    def duration_us(self) -> int:
        """Run length, microseconds."""
        return (self.x_m.size - 1) * SIM_STEP_US

    def at(self, name: str, t_us: np.ndarray) -> np.ndarray:
        """Linearly interpolate a 1 kHz series at run times ``t_us`` (int microseconds)."""
        series = getattr(self, name)
        t_us = np.asarray(t_us, dtype=np.int64)
        i = np.minimum(t_us // SIM_STEP_US, series.size - 2)
        frac = (t_us - i * SIM_STEP_US) / SIM_STEP_US
        return series[i] + frac * (series[i + 1] - series[i])

    def command_at(self, t_us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The command in effect (the last one sent) at run times ``t_us``."""
        idx = np.minimum(
            np.asarray(t_us, dtype=np.int64) * self.cmd_rate_hz // US, self.v_cmd.size - 1
        )
        return self.v_cmd[idx], self.w_cmd[idx]


def simulate_drive(
    spec: DriveSpec,
    v_cmd: np.ndarray,
    w_cmd: np.ndarray,
    cmd_rate_hz: int,
    start_pose: Sequence[float],
    rng: np.random.Generator,
) -> Trajectory:
    """Drive the base through a command sequence at 1 kHz.

    Parameters
    ----------
    spec : DriveSpec
        Nominal (firmware) and true (body) parameters.
    v_cmd, w_cmd : numpy.ndarray
        Commands, one per command period (m/s, rad/s).
    cmd_rate_hz : int
        Command rate, Hz; must divide 1000.
    start_pose : sequence of float
        Axle-centre pose at the run start, world frame (m, m, rad).
    rng : numpy.random.Generator
        Source of the lateral slip noise (drawn only when ``slip_ratio_std > 0``).

    Returns
    -------
    Trajectory
    """
    if SIM_RATE_HZ % cmd_rate_hz:
        raise ValueError(f"command rate {cmd_rate_hz} Hz must divide {SIM_RATE_HZ} Hz")
    h = 1.0 / SIM_RATE_HZ
    per = SIM_RATE_HZ // cmd_rate_hz
    u_v = np.repeat(np.asarray(v_cmd, float), per)
    u_w = np.repeat(np.asarray(w_cmd, float), per)
    half = spec.nominal_track_m / 2.0
    u = {
        "l": (u_v - u_w * half) / spec.nominal_radius_m,
        "r": (u_v + u_w * half) / spec.nominal_radius_m,
    }
    tau = spec.lag_s
    a, a_half = math.exp(-h / tau), math.exp(-h / (2.0 * tau))
    omega, phi, omega_mid, phi_mid = {}, {}, {}, {}
    for side, us in u.items():
        om = np.concatenate([[0.0], signal.lfilter([1.0 - a], [1.0, -a], us)])
        gap = om[:-1] - us
        ph = np.concatenate([[0.0], np.cumsum(us * h + gap * tau * (1.0 - a))])
        omega[side], phi[side] = om, ph
        omega_mid[side] = us + gap * a_half
        phi_mid[side] = ph[:-1] + us * h / 2.0 + gap * tau * (1.0 - a_half)
    rl, rr, bt = spec.radius_left_m, spec.radius_right_m, spec.yaw_track_m
    th0 = float(start_pose[2])

    def body(
        om_l: np.ndarray, om_r: np.ndarray, ph_l: np.ndarray, ph_r: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        return (rr * om_r + rl * om_l) / 2.0, th0 + (rr * ph_r - rl * ph_l) / bt

    v0, th = body(omega["l"], omega["r"], phi["l"], phi["r"])
    vm, thm = body(omega_mid["l"], omega_mid["r"], phi_mid["l"], phi_mid["r"])
    n = u_v.size
    if spec.slip_ratio_std > 0.0:
        e = math.exp(-h / spec.slip_corr_s)
        xi = signal.lfilter(
            [spec.slip_ratio_std * math.sqrt(1.0 - e * e)], [1.0, -e], rng.standard_normal(n)
        )
        w_body = (rr * omega["r"][:-1] - rl * omega["l"][:-1]) / bt
        vy = xi * (np.abs(v0[:-1]) + np.abs(w_body) * bt / 2.0)
    else:
        vy = np.zeros(n)

    def rate(v: np.ndarray, th_: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return v * np.cos(th_) - vy * np.sin(th_), v * np.sin(th_) + vy * np.cos(th_)

    fx0, fy0 = rate(v0[:-1], th[:-1])
    fxm, fym = rate(vm, thm)
    fx1, fy1 = rate(v0[1:], th[1:])
    dx = h / 6.0 * (fx0 + 4.0 * fxm + fx1)
    dy = h / 6.0 * (fy0 + 4.0 * fym + fy1)
    x = float(start_pose[0]) + np.concatenate([[0.0], np.cumsum(dx)])
    y = float(start_pose[1]) + np.concatenate([[0.0], np.cumsum(dy)])
    return Trajectory(
        x,
        y,
        th,
        phi["l"],
        phi["r"],
        np.asarray(v_cmd, float),
        np.asarray(w_cmd, float),
        cmd_rate_hz,
    )


@dataclass(frozen=True)
class _Run:
    """One simulated run and its bookkeeping."""

    name: str
    day: int
    start_pose: tuple[float, float, float]
    arena_centre: tuple[float, float]
    traj: Trajectory
    encoder_offsets: tuple[int, int]


def _drive_runs(
    rng: np.random.Generator,
    spec: DriveSpec,
    *,
    runs_per_day: Sequence[int],
    duration_s: Sequence[float],
    cmd_rate_hz: int,
    encoder_offsets: bool = True,
) -> list[_Run]:
    """Simulate every run of a data set (day by day)."""
    runs: list[_Run] = []
    for day, count in zip((1, 2), runs_per_day):
        centre = (float(rng.uniform(-1.5, 1.5)), float(rng.uniform(-1.5, 1.5)))
        for k in range(1, count + 1):
            rho, ang = 0.5 * math.sqrt(rng.random()), rng.uniform(-math.pi, math.pi)
            start = (
                centre[0] + rho * math.cos(ang),
                centre[1] + rho * math.sin(ang),
                float(rng.uniform(-math.pi, math.pi)),
            )
            length = rng.uniform(duration_s[0], duration_s[1])
            v_cmd, w_cmd = plan_commands(rng, length, cmd_rate_hz, start, centre)
            traj = simulate_drive(spec, v_cmd, w_cmd, cmd_rate_hz, start, rng)
            offs = (
                (int(rng.integers(0, 60_000)), int(rng.integers(0, 60_000)))
                if encoder_offsets
                else (0, 0)
            )
            runs.append(_Run(f"day{day}_run{k}", day, start, centre, traj, offs))
    return runs


def _encoder(phi: np.ndarray, ticks: int, sign: int, offset: int) -> np.ndarray:
    """Integer cumulative counts of a wheel angle."""
    return offset + np.floor(sign * phi * ticks / TWO_PI).astype(np.int64)


def _wrap(a: np.ndarray) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(a) + math.pi) % TWO_PI - math.pi


def _mocap(
    traj: Trajectory, t_us: np.ndarray, mount: MocapMount, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noisy world pose of the tracked body at run times ``t_us`` (yaw wrapped)."""
    x, y, th = traj.at("x_m", t_us), traj.at("y_m", t_us), traj.at("theta_rad", t_us)
    c, s = np.cos(th), np.sin(th)
    n = x.size
    xm = x + c * mount.offset_x_m - s * mount.offset_y_m + rng.normal(0.0, MOCAP_POS_NOISE_M, n)
    ym = y + s * mount.offset_x_m + c * mount.offset_y_m + rng.normal(0.0, MOCAP_POS_NOISE_M, n)
    yaw = th + mount.yaw_offset_rad + rng.normal(0.0, MOCAP_YAW_NOISE_RAD, n)
    return xm, ym, _wrap(yaw)


def _grid_us(traj: Trajectory, rate_hz: int, phase_us: int = 0) -> np.ndarray:
    """Run times (int microseconds) of a fixed-rate stream within the run."""
    k = np.arange((traj.duration_us - phase_us) * rate_hz // US + 1, dtype=np.int64)
    return phase_us + k * US // rate_hz


# --------------------------------------------------------------------------
# Writing helpers
# --------------------------------------------------------------------------
def _atomic_bytes(path: pathlib.Path, data: bytes) -> pathlib.Path:
    """Write bytes to ``path`` via a temporary file and :func:`os.replace`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _atomic_text(path: pathlib.Path, text: str) -> pathlib.Path:
    """Write UTF-8 text with ``\\n`` line ends atomically."""
    return _atomic_bytes(path, text.encode("utf-8"))


def _write_answer(folder: pathlib.Path, answer: dict[str, Any]) -> pathlib.Path:
    """Write ``answer.json`` (sorted keys, byte-reproducible)."""
    return _atomic_text(folder / "answer.json", json.dumps(answer, indent=2, sort_keys=True) + "\n")


def _fmt_epoch(us: int) -> str:
    """Seconds with six decimals from integer microseconds (exact)."""
    return f"{us // US}.{us % US:06d}"


def _diff_drive_urdf(name: str, spec: DriveSpec, caster_x_m: float) -> str:
    """URDF of a differential drive with the NOMINAL wheel radius and wheelbase."""
    r, half = spec.nominal_radius_m, spec.nominal_track_m / 2.0
    caster_r = min(0.02, r / 2.0)
    body_r = half + 0.02
    wheels = []
    for side, y in (("left", half), ("right", -half)):
        wheels.append(
            f"""  <link name="wheel_{side}_link">
    <visual>
      <origin xyz="0 0 0" rpy="1.5707963267948966 0 0"/>
      <geometry><cylinder radius="{r:.6f}" length="0.020000"/></geometry>
    </visual>
    <collision>
      <origin xyz="0 0 0" rpy="1.5707963267948966 0 0"/>
      <geometry><cylinder radius="{r:.6f}" length="0.020000"/></geometry>
    </collision>
    <inertial>
      <mass value="0.1"/>
      <inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/>
    </inertial>
  </link>
  <joint name="wheel_{side}_joint" type="continuous">
    <parent link="base_link"/>
    <child link="wheel_{side}_link"/>
    <origin xyz="0 {y:.6f} 0" rpy="0 0 0"/>
    <axis xyz="0 1 0"/>
  </joint>
"""
        )
    return f"""<?xml version="1.0"?>
<!-- base_link origin: the axle centre at wheel-axis height; x forward, y left. -->
<robot name="{name}">
  <link name="base_link">
    <visual>
      <origin xyz="0 0 0.040000" rpy="0 0 0"/>
      <geometry><cylinder radius="{body_r:.6f}" length="0.060000"/></geometry>
    </visual>
    <inertial>
      <mass value="5.0"/>
      <inertia ixx="0.05" ixy="0" ixz="0" iyy="0.05" iyz="0" izz="0.08"/>
    </inertial>
  </link>
{"".join(wheels)}  <link name="caster_link">
    <visual><geometry><sphere radius="{caster_r:.6f}"/></geometry></visual>
    <collision><geometry><sphere radius="{caster_r:.6f}"/></geometry></collision>
  </link>
  <joint name="caster_joint" type="fixed">
    <parent link="base_link"/>
    <child link="caster_link"/>
    <origin xyz="{caster_x_m:.6f} 0 {-(r - caster_r):.6f}" rpy="0 0 0"/>
  </joint>
</robot>
"""


def _skid_urdf(name: str, spec: DriveSpec, wheelbase_m: float) -> str:
    """URDF of a four-wheel skid-steer with the NOMINAL radius and geometric track."""
    r, half_t, half_l = spec.nominal_radius_m, spec.nominal_track_m / 2.0, wheelbase_m / 2.0
    parts = []
    for fb, x in (("front", half_l), ("rear", -half_l)):
        for side, y in (("left", half_t), ("right", -half_t)):
            parts.append(
                f"""  <link name="{fb}_{side}_wheel_link">
    <visual>
      <origin xyz="0 0 0" rpy="1.5707963267948966 0 0"/>
      <geometry><cylinder radius="{r:.6f}" length="0.110000"/></geometry>
    </visual>
    <collision>
      <origin xyz="0 0 0" rpy="1.5707963267948966 0 0"/>
      <geometry><cylinder radius="{r:.6f}" length="0.110000"/></geometry>
    </collision>
    <inertial>
      <mass value="2.6"/>
      <inertia ixx="0.02" ixy="0" ixz="0" iyy="0.035" iyz="0" izz="0.02"/>
    </inertial>
  </link>
  <joint name="{fb}_{side}_wheel_joint" type="continuous">
    <parent link="base_link"/>
    <child link="{fb}_{side}_wheel_link"/>
    <origin xyz="{x:.6f} {y:.6f} 0" rpy="0 0 0"/>
    <axis xyz="0 1 0"/>
  </joint>
"""
            )
    return f"""<?xml version="1.0"?>
<!-- base_link origin: centre of the four wheel axes at axle height; x forward, y left. -->
<robot name="{name}">
  <link name="base_link">
    <visual>
      <origin xyz="0 0 0.100000" rpy="0 0 0"/>
      <geometry><box size="{wheelbase_m + 0.4:.6f} {spec.nominal_track_m - 0.12:.6f} 0.250000"/></geometry>
    </visual>
    <inertial>
      <mass value="33.0"/>
      <inertia ixx="0.6" ixy="0" ixz="0" iyy="1.0" iyz="0" izz="1.2"/>
    </inertial>
  </link>
{"".join(parts)}</robot>
"""


def _wheeled_answer(
    shape: str,
    seed: int | list[int] | None,
    spec: DriveSpec,
    nominal_mount: MocapMount,
    mount: MocapMount,
    runs: list[_Run],
    files: dict[str, str],
    *,
    cmd_rate_hz: int,
    encoder_signs: tuple[int, int],
    extra: dict[str, Any],
) -> dict[str, Any]:
    """The common part of a wheeled data set's ``answer.json``."""
    r_nom, t_nom = spec.nominal_radius_m, spec.nominal_track_m
    nominal: dict[str, Any] = {
        "wheel_radius_m": r_nom,
        "ticks_per_rev": spec.ticks_per_rev,
        "mocap_offset_m": [nominal_mount.offset_x_m, nominal_mount.offset_y_m],
        "mocap_yaw_offset_rad": nominal_mount.yaw_offset_rad,
    }
    true: dict[str, Any] = {
        "wheel_radius_left_m": spec.radius_left_m,
        "wheel_radius_right_m": spec.radius_right_m,
        "ticks_per_rev": spec.ticks_per_rev,
        "wheel_lag_s": spec.lag_s,
        "mocap_offset_m": [mount.offset_x_m, mount.offset_y_m],
        "mocap_yaw_offset_rad": mount.yaw_offset_rad,
    }
    errors = {
        "wheel_radius_left_rel": spec.radius_left_m / r_nom - 1.0,
        "wheel_radius_right_rel": spec.radius_right_m / r_nom - 1.0,
    }
    if spec.kind == "differential_drive":
        nominal["wheelbase_m"] = t_nom
        true["wheelbase_m"] = spec.yaw_track_m
        errors["wheelbase_rel"] = spec.yaw_track_m / t_nom - 1.0
    else:
        nominal["track_m"] = t_nom
        true["track_m"] = t_nom
        true["wheel_radius_m"] = spec.radius_left_m
        true["chi"] = spec.yaw_track_m / t_nom
        true["effective_track_m"] = spec.yaw_track_m
        true["lateral_slip_ratio_std"] = spec.slip_ratio_std
        true["lateral_slip_corr_s"] = spec.slip_corr_s
        errors["wheel_radius_rel"] = spec.radius_left_m / r_nom - 1.0
        errors["effective_track_vs_nominal_rel"] = spec.yaw_track_m / t_nom - 1.0
    days: dict[str, list[str]] = {"1": [], "2": []}
    run_list = []
    for run in runs:
        days[str(run.day)].append(files[run.name])
        run_list.append(
            {
                "name": run.name,
                "file": files[run.name],
                "day": run.day,
                "duration_s": run.traj.duration_us / US,
                "start_pose_world": list(run.start_pose),
                "arena_centre_world_m": list(run.arena_centre),
                "encoder_offsets_counts": list(run.encoder_offsets),
            }
        )
    answer = {
        "shape": shape,
        "generator": "realitygap.independent.recordings",
        "seed": seed,
        "robot": spec.kind,
        "layout": "one file per run, named day<d>_run<k>; days lists the files of each day",
        "nominal": nominal,
        "true": true,
        "errors": errors,
        "commands": {
            "rate_hz": cmd_rate_hz,
            "firmware_geometry": "nominal",
            "units": "v m/s, w rad/s (counter-clockwise positive)",
        },
        "encoders": {
            "ticks_per_rev": spec.ticks_per_rev,
            "left_sign": encoder_signs[0],
            "right_sign": encoder_signs[1],
            "model": "counts = offset + floor(sign * phi * ticks_per_rev / (2 pi)), "
            "phi the wheel angle since the run start, forward positive",
        },
        "mocap": {
            "position_noise_std_m": MOCAP_POS_NOISE_M,
            "yaw_noise_std_rad": MOCAP_YAW_NOISE_RAD,
            "model": "p = p_axle + R(theta) (xo, yo); yaw = theta + psi_o (wrapped to [-pi, pi)); "
            "world frame of the capture system, start_pose_world is the axle-centre pose "
            "at the run start",
        },
        "days": days,
        "runs": run_list,
    }
    answer.update(extra)
    return answer


def _robot_json(spec: DriveSpec, mount: MocapMount, extra: dict[str, Any] | None = None) -> str:
    """Nominal values a user would write into their robot description."""
    data: dict[str, Any] = {
        "kind": spec.kind,
        "wheel_radius_m": spec.nominal_radius_m,
        "ticks_per_rev": spec.ticks_per_rev,
        "mocap_offset_m": [mount.offset_x_m, mount.offset_y_m],
        "mocap_yaw_offset_rad": mount.yaw_offset_rad,
    }
    key = "wheelbase_m" if spec.kind == "differential_drive" else "track_m"
    data[key] = spec.nominal_track_m
    data.update(extra or {})
    return json.dumps(data, indent=2, sort_keys=True) + "\n"


# --------------------------------------------------------------------------
# 1. Text file with title lines, mirrored left encoder, clockwise heading in degrees
# --------------------------------------------------------------------------
TEXT_COLUMNS = ("time", "enc_l", "enc_r", "v_cmd", "w_cmd", "x", "y", "heading")
_TEXT_WIDTHS = (10, 10, 10, 8, 8, 12, 12, 10)


def text_title_mirrored(
    seed: SeedLike,
    folder: str | os.PathLike[str],
    *,
    separator: Literal["whitespace", "pipe"] = "whitespace",
    runs_per_day: Sequence[int] = (3, 2),
    duration_s: Sequence[float] = (60.0, 120.0),
    log_rate_hz: int = 50,
    cmd_rate_hz: int = 20,
    spec: DriveSpec | None = None,
) -> Written:
    """Write a Kobuki-like logger's text files.

    Layout of ``day<d>_run<k>.txt`` (one per run)::

        Kobuki logger v2.1  2024-03-05 09:02
        units: time s, pose mm, heading deg
              time      enc_l      enc_r    v_cmd    w_cmd            x            y    heading
             0.000      50608      36694    0.000    0.000      624.465     -533.343   -91.0984

    (``separator="pipe"`` joins the same padded fields with ``" | "``.)  ``time`` s
    from the logger start; ``enc_l``/``enc_r`` cumulative counts, the LEFT encoder
    mounted mirrored (counts decrease when its wheel rolls forward); ``v_cmd`` m/s,
    ``w_cmd`` rad/s (counter-clockwise positive, as commanded); ``x``, ``y`` mm of
    the tracked point (nominally 0.20 m behind the axle); ``heading`` deg,
    clockwise positive (``-yaw``), wrapped to (-180, 180].  One rate (50 Hz).

    Parameters
    ----------
    seed : numpy.random.Generator or int or sequence of int or None
        Source of every draw.
    folder : path-like
        Output folder (created).
    separator : {"whitespace", "pipe"}
        Column separator.
    runs_per_day : sequence of int
        Runs on day 1 and day 2.
    duration_s : sequence of float
        Range of the run lengths, s.
    log_rate_hz, cmd_rate_hz : int
        Log and command rates, Hz.
    spec : DriveSpec, optional
        True and nominal geometry (default: drawn around r = 35 mm, b = 230 mm).

    Returns
    -------
    Written
    """
    rng, seed_int = _as_rng(seed)
    out = pathlib.Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    spec = spec or draw_diff_drive(rng, 0.035, 0.230, 4096)
    nominal_mount = MocapMount(-0.20, 0.0, 0.0)
    mount = _draw_mount(rng, nominal_mount, (0.003, 0.005, math.radians(0.5)))
    runs = _drive_runs(
        rng, spec, runs_per_day=runs_per_day, duration_s=duration_s, cmd_rate_hz=cmd_rate_hz
    )
    files = {run.name: f"{run.name}.txt" for run in runs}
    answer = _wheeled_answer(
        "text_title_mirrored",
        seed_int,
        spec,
        nominal_mount,
        mount,
        runs,
        files,
        cmd_rate_hz=cmd_rate_hz,
        encoder_signs=(-1, 1),
        extra={
            "separator": separator,
            "title_lines": 2,
            "columns": {
                "time": "s since the logger start",
                "enc_l": "counts, mirrored: decreasing when the left wheel rolls forward",
                "enc_r": "counts, increasing forward",
                "v_cmd": "m/s",
                "w_cmd": "rad/s, counter-clockwise positive",
                "x": "mm, tracked point, capture world frame",
                "y": "mm, tracked point, capture world frame",
                "heading": "deg, clockwise positive: -(theta + psi_o), wrapped to (-180, 180]",
            },
            "log_rate_hz": log_rate_hz,
        },
    )
    written = [_write_answer(out, answer)]
    sep = " " if separator == "whitespace" else " | "
    for i, run in enumerate(runs):
        t_us = _grid_us(run.traj, log_rate_hz)
        tr = run.traj
        el = _encoder(tr.at("phi_left_rad", t_us), spec.ticks_per_rev, -1, run.encoder_offsets[0])
        er = _encoder(tr.at("phi_right_rad", t_us), spec.ticks_per_rev, 1, run.encoder_offsets[1])
        v, w = tr.command_at(t_us)
        xm, ym, yaw = _mocap(tr, t_us, mount, rng)
        heading = -np.degrees(yaw) + 0.0  # clockwise positive, in (-180, 180]
        date = DAY_DATES[run.day][0]
        lines = [
            f"Kobuki logger v2.1  {date} {9 + i:02d}:{(7 * i + 2) % 60:02d}",
            "units: time s, pose mm, heading deg",
            sep.join(c.rjust(wd) for c, wd in zip(TEXT_COLUMNS, _TEXT_WIDTHS)),
        ]
        for row in zip(t_us, el, er, v, w, xm * 1e3, ym * 1e3, heading):
            vals = (
                f"{row[0] / US:.3f}",
                f"{row[1]:d}",
                f"{row[2]:d}",
                f"{row[3]:.3f}",
                f"{row[4]:.3f}",
                f"{row[5]:.3f}",
                f"{row[6]:.3f}",
                f"{row[7]:.4f}",
            )
            lines.append(sep.join(s.rjust(wd) for s, wd in zip(vals, _TEXT_WIDTHS)))
        written.append(_atomic_text(out / files[run.name], "\n".join(lines) + "\n"))
    written.append(_atomic_text(out / "robot.urdf", _diff_drive_urdf("kobuki_like", spec, -0.12)))
    written.append(_atomic_text(out / "robot.json", _robot_json(spec, nominal_mount)))
    return Written(out, written, answer)


# --------------------------------------------------------------------------
# 2. Two rates in one file (or in two files)
# --------------------------------------------------------------------------
MULTIRATE_COLUMNS = (
    "time",
    "enc_left",
    "enc_right",
    "v_cmd",
    "w_cmd",
    "mocap_x",
    "mocap_y",
    "mocap_yaw",
)
ENC_COLUMNS = ("stamp", "enc_left", "enc_right", "v_cmd", "w_cmd")
MOCAP_COLUMNS = ("time", "x", "y", "yaw")


def multirate_one_file(
    seed: SeedLike,
    folder: str | os.PathLike[str],
    *,
    layout: Literal["interleaved", "split"] = "interleaved",
    runs_per_day: Sequence[int] = (3, 2),
    duration_s: Sequence[float] = (60.0, 120.0),
    encoder_rate_hz: int = 50,
    mocap_rate_hz: int = 120,
    mocap_stamp_offset_s: float = 0.001,
    mocap_jitter_s: float = 0.0002,
    cmd_rate_hz: int = 10,
    spec: DriveSpec | None = None,
) -> Written:
    """Write encoder and motion-capture streams of different rates.

    ``layout="interleaved"``: one ``day<d>_run<k>.csv`` per run, header
    ``time,enc_left,enc_right,v_cmd,w_cmd,mocap_x,mocap_y,mocap_yaw``; encoder rows
    (50 Hz) fill ``enc_left, enc_right, v_cmd, w_cmd`` and mocap rows (120 Hz) fill
    ``mocap_x, mocap_y, mocap_yaw``, the other fields empty; rows in time order.
    ``layout="split"``: one folder ``day<d>_run<k>/`` per run with ``enc.csv``
    (``stamp,enc_left,enc_right,v_cmd,w_cmd``) and ``mocap.csv`` (``time,x,y,yaw``).

    Times are Unix epoch seconds with six decimals.  Encoder stamps are
    ``t0 + k / 50``; mocap stamps are ``t0 + mocap_stamp_offset_s + j / 120 +
    e_j`` with ``e_j`` Gaussian clock jitter (clipped at 3 sigma, rounded to 1 us);
    every stamp is the true instant of its sample.  Units: counts (both encoders
    forward positive), m/s, rad/s, m, m, rad (counter-clockwise, wrapped).

    Parameters
    ----------
    seed : numpy.random.Generator or int or sequence of int or None
        Source of every draw.
    folder : path-like
        Output folder.
    layout : {"interleaved", "split"}
        One file per run or two files per run.
    runs_per_day, duration_s : sequence
        Runs per day and the run-length range (s).
    encoder_rate_hz, mocap_rate_hz, cmd_rate_hz : int
        Stream rates, Hz.
    mocap_stamp_offset_s, mocap_jitter_s : float
        Offset of the mocap sample grid from the encoder grid and the standard
        deviation of its jitter, s.
    spec : DriveSpec, optional
        Geometry (default: drawn around r = 50 mm, b = 300 mm).

    Returns
    -------
    Written
    """
    rng, seed_int = _as_rng(seed)
    out = pathlib.Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    spec = spec or draw_diff_drive(rng, 0.050, 0.300, 2048)
    nominal_mount = MocapMount()
    mount = _draw_mount(rng, nominal_mount, (0.05, 0.02, math.radians(2.0)))
    runs = _drive_runs(
        rng, spec, runs_per_day=runs_per_day, duration_s=duration_s, cmd_rate_hz=cmd_rate_hz
    )
    if layout == "interleaved":
        files = {run.name: f"{run.name}.csv" for run in runs}
    else:
        files = {run.name: run.name for run in runs}
    offset_us = round(mocap_stamp_offset_s * US)
    jitter_us = mocap_jitter_s * US
    start_us = {
        run.name: (DAY_DATES[run.day][1] + 3600 * i + 17) * US + 123_000
        for i, run in enumerate(runs)
    }
    answer = _wheeled_answer(
        "multirate_one_file",
        seed_int,
        spec,
        nominal_mount,
        mount,
        runs,
        files,
        cmd_rate_hz=cmd_rate_hz,
        encoder_signs=(1, 1),
        extra={
            "file_layout": layout,
            "encoder_rate_hz": encoder_rate_hz,
            "mocap_rate_hz": mocap_rate_hz,
            "mocap_stamp_offset_s": offset_us / US,
            "mocap_jitter_std_s": mocap_jitter_s,
            "stamps": "Unix epoch s; every stamp is the true instant of its sample; "
            "encoder stamp k = start + k / encoder_rate; mocap stamp j = start + offset + "
            "j / mocap_rate + jitter",
            "columns": (
                {
                    c: u
                    for c, u in zip(
                        MULTIRATE_COLUMNS,
                        ("s", "counts", "counts", "m/s", "rad/s", "m", "m", "rad"),
                    )
                }
                if layout == "interleaved"
                else {
                    "enc.csv": dict(zip(ENC_COLUMNS, ("s", "counts", "counts", "m/s", "rad/s"))),
                    "mocap.csv": dict(zip(MOCAP_COLUMNS, ("s", "m", "m", "rad"))),
                }
            ),
        },
    )
    for entry in answer["runs"]:
        entry["start_stamp_s"] = start_us[entry["name"]] / US
    written = [_write_answer(out, answer)]
    for run in runs:
        tr = run.traj
        t0 = start_us[run.name]
        te = _grid_us(tr, encoder_rate_hz)
        el = _encoder(tr.at("phi_left_rad", te), spec.ticks_per_rev, 1, run.encoder_offsets[0])
        er = _encoder(tr.at("phi_right_rad", te), spec.ticks_per_rev, 1, run.encoder_offsets[1])
        v, w = tr.command_at(te)
        tm = _grid_us(tr, mocap_rate_hz, offset_us + round(3 * jitter_us))
        tm = tm - round(3 * jitter_us)
        jit = np.clip(rng.normal(0.0, jitter_us, tm.size), -3 * jitter_us, 3 * jitter_us)
        tm = tm + np.round(jit).astype(np.int64)
        xm, ym, yaw = _mocap(tr, tm, mount, rng)
        enc_rows = [
            (int(t), f"{a:d}", f"{b:d}", f"{c:.3f}", f"{d:.3f}")
            for t, a, b, c, d in zip(te, el, er, v, w)
        ]
        moc_rows = [
            (int(t), f"{a:.6f}", f"{b:.6f}", f"{c:.6f}") for t, a, b, c in zip(tm, xm, ym, yaw)
        ]
        if layout == "interleaved":
            merged = [(r[0], 0, (*r[1:], "", "", "")) for r in enc_rows]
            merged += [(r[0], 1, ("", "", "", "", *r[1:])) for r in moc_rows]
            merged.sort(key=lambda item: (item[0], item[1]))
            lines = [",".join(MULTIRATE_COLUMNS)]
            lines += [",".join((_fmt_epoch(t0 + t), *fields)) for t, _, fields in merged]
            written.append(_atomic_text(out / files[run.name], "\n".join(lines) + "\n"))
        else:
            sub = out / files[run.name]
            enc_lines = [",".join(ENC_COLUMNS)] + [
                ",".join((_fmt_epoch(t0 + r[0]), *r[1:])) for r in enc_rows
            ]
            moc_lines = [",".join(MOCAP_COLUMNS)] + [
                ",".join((_fmt_epoch(t0 + r[0]), *r[1:])) for r in moc_rows
            ]
            written.append(_atomic_text(sub / "enc.csv", "\n".join(enc_lines) + "\n"))
            written.append(_atomic_text(sub / "mocap.csv", "\n".join(moc_lines) + "\n"))
    written.append(_atomic_text(out / "robot.urdf", _diff_drive_urdf("lab_rover", spec, -0.18)))
    written.append(_atomic_text(out / "robot.json", _robot_json(spec, nominal_mount)))
    return Written(out, written, answer)


# --------------------------------------------------------------------------
# 3. MATLAB v5 file
# --------------------------------------------------------------------------
def _mat_bytes(variables: dict[str, np.ndarray], description: str) -> bytes:
    """MAT v5 bytes with a fixed header text (scipy stamps the current time)."""
    buf = io.BytesIO()
    sio.savemat(buf, variables, format="5", oned_as="column", do_compression=False)
    data = bytearray(buf.getvalue())
    data[:116] = description.encode("ascii")[:116].ljust(116, b" ")
    return bytes(data)


def mat_file(
    seed: SeedLike,
    folder: str | os.PathLike[str],
    *,
    runs_per_day: Sequence[int] = (3, 2),
    duration_s: Sequence[float] = (60.0, 120.0),
    log_rate_hz: int = 100,
    cmd_rate_hz: int = 10,
    spec: DriveSpec | None = None,
) -> Written:
    """Write one MATLAB v5 file per run.

    ``day<d>_run<k>.mat`` holds column vectors of one length (100 Hz): ``t`` (s
    since the controller boot), ``encL``, ``encR`` (cumulative counts, double,
    forward positive), ``x``, ``y`` (m, tracked body), ``yaw`` (rad,
    counter-clockwise, wrapped to [-pi, pi)), ``v`` (m/s) and ``w`` (rad/s), the
    commands in effect.

    Parameters
    ----------
    seed : numpy.random.Generator or int or sequence of int or None
        Source of every draw.
    folder : path-like
        Output folder.
    runs_per_day, duration_s : sequence
        Runs per day and the run-length range (s).
    log_rate_hz, cmd_rate_hz : int
        Log and command rates, Hz.
    spec : DriveSpec, optional
        Geometry (default: drawn around r = 97.5 mm, b = 330 mm).

    Returns
    -------
    Written
    """
    rng, seed_int = _as_rng(seed)
    out = pathlib.Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    spec = spec or draw_diff_drive(rng, 0.0975, 0.330, 8192)
    nominal_mount = MocapMount()
    mount = _draw_mount(rng, nominal_mount, (0.06, 0.03, math.radians(3.0)))
    runs = _drive_runs(
        rng, spec, runs_per_day=runs_per_day, duration_s=duration_s, cmd_rate_hz=cmd_rate_hz
    )
    files = {run.name: f"{run.name}.mat" for run in runs}
    boot_us = {run.name: int(rng.integers(100, 5000)) * US + 250_000 for run in runs}
    answer = _wheeled_answer(
        "mat_file",
        seed_int,
        spec,
        nominal_mount,
        mount,
        runs,
        files,
        cmd_rate_hz=cmd_rate_hz,
        encoder_signs=(1, 1),
        extra={
            "log_rate_hz": log_rate_hz,
            "variables": {
                "t": "s since the controller boot",
                "encL": "counts",
                "encR": "counts",
                "x": "m",
                "y": "m",
                "yaw": "rad, counter-clockwise, wrapped to [-pi, pi)",
                "v": "m/s",
                "w": "rad/s",
            },
        },
    )
    for entry in answer["runs"]:
        entry["start_time_s"] = boot_us[entry["name"]] / US
    written = [_write_answer(out, answer)]
    for run in runs:
        tr = run.traj
        t_us = _grid_us(tr, log_rate_hz)
        el = _encoder(tr.at("phi_left_rad", t_us), spec.ticks_per_rev, 1, run.encoder_offsets[0])
        er = _encoder(tr.at("phi_right_rad", t_us), spec.ticks_per_rev, 1, run.encoder_offsets[1])
        v, w = tr.command_at(t_us)
        xm, ym, yaw = _mocap(tr, t_us, mount, rng)
        variables = {
            "t": (boot_us[run.name] + t_us) / US,
            "encL": el.astype(float),
            "encR": er.astype(float),
            "x": xm,
            "y": ym,
            "yaw": yaw,
            "v": v,
            "w": w,
        }
        date = DAY_DATES[run.day][0]
        desc = f"MATLAB 5.0 MAT-file, Platform: GLNXA64, Created on: {date} rover log {run.name}"
        written.append(_atomic_bytes(out / files[run.name], _mat_bytes(variables, desc)))
    written.append(_atomic_text(out / "robot.urdf", _diff_drive_urdf("pioneer_like", spec, -0.20)))
    written.append(_atomic_text(out / "robot.json", _robot_json(spec, nominal_mount)))
    return Written(out, written, answer)


# --------------------------------------------------------------------------
# 4. ROS 2 bag
# --------------------------------------------------------------------------
BAG_TOPICS = {
    "/cmd_vel": "geometry_msgs/msg/Twist",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/mocap/robot/pose": "geometry_msgs/msg/PoseStamped",
}


def ros2_bag(
    seed: SeedLike,
    folder: str | os.PathLike[str],
    *,
    runs_per_day: Sequence[int] = (2, 2),
    duration_s: Sequence[float] = (60.0, 120.0),
    joint_rate_hz: int = 50,
    mocap_rate_hz: int = 100,
    cmd_rate_hz: int = 20,
    spec: DriveSpec | None = None,
) -> Written:
    """Write one ROS 2 bag (sqlite3 storage) per run, with the robot's URDF.

    Bag ``day<d>_run<k>/`` (``metadata.yaml`` + ``day<d>_run<k>.db3``) holds
    ``/cmd_vel`` (geometry_msgs/msg/Twist, 20 Hz, ``linear.x`` m/s, ``angular.z``
    rad/s), ``/joint_states`` (sensor_msgs/msg/JointState, 50 Hz, names
    ``wheel_left_joint, wheel_right_joint``, position = counts 2 pi / N rad from
    the driver start, forward positive; velocity = the count difference over the
    last period, rad/s) and ``/mocap/robot/pose`` (geometry_msgs/msg/PoseStamped,
    100 Hz, frame ``world``, m, yaw-only quaternion).  Header stamps are the true
    sample instants (Unix epoch); bag times are the receive times, 0.3-2 ms later.

    Parameters
    ----------
    seed : numpy.random.Generator or int or sequence of int or None
        Source of every draw.
    folder : path-like
        Output folder.
    runs_per_day, duration_s : sequence
        Runs per day and the run-length range (s).
    joint_rate_hz, mocap_rate_hz, cmd_rate_hz : int
        Topic rates, Hz.
    spec : DriveSpec, optional
        Geometry (default: drawn around r = 33 mm, b = 160 mm).

    Returns
    -------
    Written

    Raises
    ------
    ImportError
        If ``rosbags`` is not installed.
    """
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    rng, seed_int = _as_rng(seed)
    out = pathlib.Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    spec = spec or draw_diff_drive(rng, 0.033, 0.160, 4096)
    nominal_mount = MocapMount()
    mount = _draw_mount(rng, nominal_mount, (0.04, 0.02, math.radians(2.0)))
    runs = _drive_runs(
        rng,
        spec,
        runs_per_day=runs_per_day,
        duration_s=duration_s,
        cmd_rate_hz=cmd_rate_hz,
        encoder_offsets=False,
    )
    files = {run.name: run.name for run in runs}
    start_us = {
        run.name: (DAY_DATES[run.day][1] + 3600 * i + 41) * US + 517_000
        for i, run in enumerate(runs)
    }
    mocap_phase_us = {run.name: int(rng.integers(0, US // mocap_rate_hz)) for run in runs}
    answer = _wheeled_answer(
        "ros2_bag",
        seed_int,
        spec,
        nominal_mount,
        mount,
        runs,
        files,
        cmd_rate_hz=cmd_rate_hz,
        encoder_signs=(1, 1),
        extra={
            "storage": "sqlite3",
            "topics": {
                "/cmd_vel": {"type": BAG_TOPICS["/cmd_vel"], "rate_hz": cmd_rate_hz},
                "/joint_states": {"type": BAG_TOPICS["/joint_states"], "rate_hz": joint_rate_hz},
                "/mocap/robot/pose": {
                    "type": BAG_TOPICS["/mocap/robot/pose"],
                    "rate_hz": mocap_rate_hz,
                },
            },
            "joint_names": ["wheel_left_joint", "wheel_right_joint"],
            "joint_position": "rad = counts * 2 pi / ticks_per_rev, zero at the driver start",
            "mocap_height_m": 0.12,
            "stamps": "header stamps: true sample instants, Unix epoch; bag time = header "
            "stamp (cmd_vel: send time) + receive delay uniform in [0.3, 2.0] ms",
        },
    )
    grids = {}
    for run in runs:
        tr = run.traj
        grids[run.name] = (
            np.arange(tr.v_cmd.size, dtype=np.int64) * (US // cmd_rate_hz),
            _grid_us(tr, joint_rate_hz),
            _grid_us(tr, mocap_rate_hz, mocap_phase_us[run.name]),
        )
    for entry in answer["runs"]:
        tc, tj, tm = grids[entry["name"]]
        entry["start_stamp_ns"] = start_us[entry["name"]] * 1000
        entry["mocap_phase_s"] = mocap_phase_us[entry["name"]] / US
        entry["message_counts"] = {
            "/cmd_vel": int(tc.size),
            "/joint_states": int(tj.size),
            "/mocap/robot/pose": int(tm.size),
        }
    written = [_write_answer(out, answer)]
    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    time_t, header_t = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    vec_t, twist_t = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Twist"]
    point_t, quat_t = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    pose_t, pose_stamped_t = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/PoseStamped"]
    joint_t = T["sensor_msgs/msg/JointState"]

    def stamp(ns: int) -> Any:
        return time_t(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    for run in runs:
        tr = run.traj
        t0_ns = start_us[run.name] * 1000
        tc, tj, tm = grids[run.name]
        msgs: list[tuple[int, int, str, bytes]] = []
        delay = rng.integers(300_000, 2_000_001, tc.size)
        for k, t in enumerate(tc):
            msg = twist_t(
                linear=vec_t(x=float(tr.v_cmd[k]), y=0.0, z=0.0),
                angular=vec_t(x=0.0, y=0.0, z=float(tr.w_cmd[k])),
            )
            data = bytes(store.serialize_cdr(msg, BAG_TOPICS["/cmd_vel"]))
            msgs.append((t0_ns + int(t) * 1000 + int(delay[k]), 0, "/cmd_vel", data))
        ticks = spec.ticks_per_rev
        cl = _encoder(tr.at("phi_left_rad", tj), ticks, 1, 0)
        cr = _encoder(tr.at("phi_right_rad", tj), ticks, 1, 0)
        pos = np.stack([cl, cr], axis=1) * (TWO_PI / ticks)
        vel = np.vstack([np.zeros((1, 2)), np.diff(pos, axis=0) * joint_rate_hz])
        delay = rng.integers(300_000, 2_000_001, tj.size)
        for k, t in enumerate(tj):
            ns = t0_ns + int(t) * 1000
            msg = joint_t(
                header=header_t(stamp=stamp(ns), frame_id=""),
                name=["wheel_left_joint", "wheel_right_joint"],
                position=pos[k].copy(),
                velocity=vel[k].copy(),
                effort=np.zeros(0),
            )
            data = bytes(store.serialize_cdr(msg, BAG_TOPICS["/joint_states"]))
            msgs.append((ns + int(delay[k]), 1, "/joint_states", data))
        xm, ym, yaw = _mocap(tr, tm, mount, rng)
        zm = 0.12 + rng.normal(0.0, MOCAP_POS_NOISE_M, tm.size)
        delay = rng.integers(300_000, 2_000_001, tm.size)
        for k, t in enumerate(tm):
            ns = t0_ns + int(t) * 1000
            half = 0.5 * float(yaw[k])
            msg = pose_stamped_t(
                header=header_t(stamp=stamp(ns), frame_id="world"),
                pose=pose_t(
                    position=point_t(x=float(xm[k]), y=float(ym[k]), z=float(zm[k])),
                    orientation=quat_t(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)),
                ),
            )
            data = bytes(store.serialize_cdr(msg, BAG_TOPICS["/mocap/robot/pose"]))
            msgs.append((ns + int(delay[k]), 2, "/mocap/robot/pose", data))
        msgs.sort(key=lambda m: (m[0], m[1]))
        final = out / files[run.name]
        tmp_root = pathlib.Path(tempfile.mkdtemp(dir=out, prefix=f".{run.name}.", suffix=".tmp"))
        try:
            bag_path = tmp_root / run.name
            try:
                writer = Writer(bag_path, version=9)
            except TypeError:  # rosbags < 0.10 has no version argument
                writer = Writer(bag_path)  # type: ignore[call-arg]
            writer.open()
            conns = {
                topic: writer.add_connection(topic, msgtype, typestore=store)
                for topic, msgtype in BAG_TOPICS.items()
            }
            for ns, _, topic, data in msgs:
                writer.write(conns[topic], ns, data)
            writer.close()
            if final.exists():
                shutil.rmtree(final)
            os.replace(bag_path, final)
        finally:
            shutil.rmtree(tmp_root, ignore_errors=True)
        written.append(final)
    written.append(_atomic_text(out / "robot.urdf", _diff_drive_urdf("turtle_like", spec, -0.08)))
    written.append(_atomic_text(out / "robot.json", _robot_json(spec, nominal_mount)))
    return Written(out, written, answer)


# --------------------------------------------------------------------------
# 5. Skid-steer CSV
# --------------------------------------------------------------------------
SKID_COLUMNS = ("time", "enc_left", "enc_right", "v_cmd", "w_cmd", "x", "y", "yaw")


def skid_steer(
    seed: SeedLike,
    folder: str | os.PathLike[str],
    *,
    runs_per_day: Sequence[int] = (3, 2),
    duration_s: Sequence[float] = (60.0, 120.0),
    log_rate_hz: int = 50,
    cmd_rate_hz: int = 20,
    chi: float | None = None,
    wheelbase_m: float = 0.512,
    spec: DriveSpec | None = None,
) -> Written:
    """Write CSV logs of a four-wheel skid-steer with its URDF.

    ``day<d>_run<k>.csv`` (50 Hz), header ``time,enc_left,enc_right,v_cmd,w_cmd,x,y,yaw``:
    s from the log start; cumulative counts of the left and right side (forward
    positive); m/s; rad/s; mocap m, m, rad (counter-clockwise, wrapped) at the
    axle-centre point (zero offsets).

    Parameters
    ----------
    seed : numpy.random.Generator or int or sequence of int or None
        Source of every draw.
    folder : path-like
        Output folder.
    runs_per_day, duration_s : sequence
        Runs per day and the run-length range (s).
    log_rate_hz, cmd_rate_hz : int
        Log and command rates, Hz.
    chi : float, optional
        ``B_eff / T`` (default: drawn in [1.2, 1.8]).
    wheelbase_m : float
        Front-to-rear axle distance written into the URDF, m.
    spec : DriveSpec, optional
        Geometry (default: drawn around r = 165 mm, T = 555 mm).

    Returns
    -------
    Written
    """
    rng, seed_int = _as_rng(seed)
    out = pathlib.Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    spec = spec or draw_skid_steer(rng, 0.165, 0.555, 8192, chi=chi)
    mount = MocapMount()
    runs = _drive_runs(
        rng, spec, runs_per_day=runs_per_day, duration_s=duration_s, cmd_rate_hz=cmd_rate_hz
    )
    files = {run.name: f"{run.name}.csv" for run in runs}
    answer = _wheeled_answer(
        "skid_steer",
        seed_int,
        spec,
        mount,
        mount,
        runs,
        files,
        cmd_rate_hz=cmd_rate_hz,
        encoder_signs=(1, 1),
        extra={
            "log_rate_hz": log_rate_hz,
            "wheelbase_m": wheelbase_m,
            "columns": dict(
                zip(SKID_COLUMNS, ("s", "counts", "counts", "m/s", "rad/s", "m", "m", "rad"))
            ),
        },
    )
    answer["chi"] = answer["true"]["chi"]
    answer["effective_track_m"] = answer["true"]["effective_track_m"]
    written = [_write_answer(out, answer)]
    for run in runs:
        tr = run.traj
        t_us = _grid_us(tr, log_rate_hz)
        el = _encoder(tr.at("phi_left_rad", t_us), spec.ticks_per_rev, 1, run.encoder_offsets[0])
        er = _encoder(tr.at("phi_right_rad", t_us), spec.ticks_per_rev, 1, run.encoder_offsets[1])
        v, w = tr.command_at(t_us)
        xm, ym, yaw = _mocap(tr, t_us, mount, rng)
        lines = [",".join(SKID_COLUMNS)]
        lines += [
            f"{t / US:.3f},{a:d},{b:d},{c:.3f},{d:.3f},{x:.6f},{y:.6f},{z:.6f}"
            for t, a, b, c, d, x, y, z in zip(t_us, el, er, v, w, xm, ym, yaw)
        ]
        written.append(_atomic_text(out / files[run.name], "\n".join(lines) + "\n"))
    written.append(_atomic_text(out / "robot.urdf", _skid_urdf("husky_like", spec, wheelbase_m)))
    written.append(
        _atomic_text(out / "robot.json", _robot_json(spec, mount, {"wheelbase_m": wheelbase_m}))
    )
    return Written(out, written, answer)


# --------------------------------------------------------------------------
# 6. Arm with a laser tracker
# --------------------------------------------------------------------------
ARM_JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
ARM_LINKS = (
    "base_link",
    "shoulder_link",
    "upper_arm_link",
    "forearm_link",
    "wrist_1_link",
    "wrist_2_link",
    "wrist_3_link",
)
ARM_AXES = ((0, 0, 1), (0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 0, 1), (0, 1, 0))
# Joint origins in the parent link frame (zero rotation), then the tool point in wrist_3_link.
ARM_NOMINAL_ORIGINS = (
    (0.0, 0.0, 0.1273),
    (0.0, 0.2209, 0.0),
    (0.0, -0.1719, 0.600),
    (0.0, 0.0, 0.560),
    (0.0, 0.1149, 0.0),
    (0.0, 0.0, 0.1157),
    (0.0, 0.1422, 0.060),
)
ARM_LIMITS = ((-math.pi, math.pi), (-math.pi, math.pi), (-math.pi, math.pi)) + (
    (-2 * math.pi, 2 * math.pi),
) * 3
_ARM_SAMPLE = ((-math.pi, math.pi), (-1.5, 1.5), (-2.5, 2.5)) + ((-math.pi, math.pi),) * 3


def _axis_rot(axis: Sequence[int], angle: float) -> np.ndarray:
    """Rotation matrix about a unit coordinate axis."""
    c, s = math.cos(angle), math.sin(angle)
    if axis[2]:
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    if axis[1]:
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def arm_forward(
    q: Sequence[float] | np.ndarray,
    origins: Sequence[Sequence[float]] = ARM_NOMINAL_ORIGINS,
    offsets: Sequence[float] | np.ndarray = (0.0,) * 6,
) -> np.ndarray:
    """Tool-point position (m, base frame) of the six-joint arm.

    Parameters
    ----------
    q : sequence of float
        Logged joint angles, rad.
    origins : sequence of 3-sequences
        Six joint origins and the tool point, each in its parent link frame, m.
    offsets : sequence of float
        Joint-angle offsets: joint ``i`` turns to ``q[i] + offsets[i]``, rad.

    Returns
    -------
    numpy.ndarray
        Shape (3,).
    """
    rot, pos = np.eye(3), np.zeros(3)
    for i in range(6):
        pos = pos + rot @ np.asarray(origins[i], float)
        rot = rot @ _axis_rot(ARM_AXES[i], float(q[i]) + float(offsets[i]))
    return pos + rot @ np.asarray(origins[6], float)


def _arm_urdf(origins: Sequence[Sequence[float]]) -> str:
    """The nominal URDF of the arm (zero-rpy joint frames; the arm points up at q = 0)."""
    lines = [
        '<?xml version="1.0"?>',
        "<!-- Six-joint arm; tool_point is the laser-tracker reflector. -->",
        '<robot name="ur_like_arm">',
    ]
    for link in (*ARM_LINKS, "tool_point"):
        lines.append(f'  <link name="{link}"/>')
    for i, name in enumerate(ARM_JOINTS):
        o, ax, (lo, hi) = origins[i], ARM_AXES[i], ARM_LIMITS[i]
        lines += [
            f'  <joint name="{name}" type="revolute">',
            f'    <parent link="{ARM_LINKS[i]}"/>',
            f'    <child link="{ARM_LINKS[i + 1]}"/>',
            f'    <origin xyz="{o[0]:.6f} {o[1]:.6f} {o[2]:.6f}" rpy="0 0 0"/>',
            f'    <axis xyz="{ax[0]} {ax[1]} {ax[2]}"/>',
            f'    <limit lower="{lo:.6f}" upper="{hi:.6f}" effort="150.0" velocity="2.0"/>',
            "  </joint>",
        ]
    o = origins[6]
    lines += [
        '  <joint name="tool_point_joint" type="fixed">',
        '    <parent link="wrist_3_link"/>',
        '    <child link="tool_point"/>',
        f'    <origin xyz="{o[0]:.6f} {o[1]:.6f} {o[2]:.6f}" rpy="0 0 0"/>',
        "  </joint>",
        "</robot>",
    ]
    return "\n".join(lines) + "\n"


def _rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)``."""
    return _axis_rot((0, 0, 1), yaw) @ _axis_rot((0, 1, 0), pitch) @ _axis_rot((1, 0, 0), roll)


def arm_csv(
    seed: SeedLike,
    folder: str | os.PathLike[str],
    *,
    n_poses: int = 60,
    angle_unit: Literal["deg", "rad"] = "deg",
    offset_max_rad: float = 0.002,
    length_error_max_m: float = 0.001,
    noise_m: float = 20e-6,
) -> Written:
    """Write a laser-tracker calibration series of the six-joint arm.

    ``measurements.csv``: header ``pose,q1_deg,...,q6_deg,x_mm,y_mm,z_mm`` (or
    ``q1_rad..q6_rad``); ``q_i`` the logged angle of the i-th joint of the chain
    (``shoulder_pan_joint`` ... ``wrist_3_joint``); ``x_mm, y_mm, z_mm`` the
    tool point in the tracker frame, mm.  ``arm.urdf`` is the NOMINAL arm.

    Parameters
    ----------
    seed : numpy.random.Generator or int or sequence of int or None
        Source of every draw.
    folder : path-like
        Output folder.
    n_poses : int
        Number of poses.
    angle_unit : {"deg", "rad"}
        Unit of the joint-angle columns.
    offset_max_rad, length_error_max_m : float
        Half-widths of the uniform joint-offset and length errors.
    noise_m : float
        Tracker noise standard deviation per axis, m.

    Returns
    -------
    Written
    """
    rng, seed_int = _as_rng(seed)
    out = pathlib.Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    offsets = rng.uniform(-offset_max_rad, offset_max_rad, 6)
    true_origins = []
    for o in ARM_NOMINAL_ORIGINS:
        err = rng.uniform(-length_error_max_m, length_error_max_m, 3)
        true_origins.append(tuple(c + (e if c != 0.0 else 0.0) for c, e in zip(o, err)))
    rpy = (
        float(rng.uniform(-0.017, 0.017)),
        float(rng.uniform(-0.017, 0.017)),
        float(rng.uniform(-math.pi, math.pi)),
    )
    rot = _rpy_matrix(*rpy)
    dist, bearing = rng.uniform(2.5, 4.0), rng.uniform(-math.pi, math.pi)
    trans = np.array([dist * math.cos(bearing), dist * math.sin(bearing), rng.uniform(-1.2, -0.6)])
    poses: list[tuple[np.ndarray, np.ndarray]] = []
    while len(poses) < n_poses:
        q = np.array([rng.uniform(lo, hi) for lo, hi in _ARM_SAMPLE])
        tip = arm_forward(q, true_origins, offsets)
        wrist = arm_forward([*q[:4].tolist(), 0.0, 0.0], true_origins[:4] + [(0, 0, 0)] * 3)
        if tip[2] > 0.10 and wrist[2] > 0.10 and math.hypot(tip[0], tip[1]) > 0.30:
            poses.append((q, tip))
    unit = "deg" if angle_unit == "deg" else "rad"
    header = ["pose"] + [f"q{i}_{unit}" for i in range(1, 7)] + ["x_mm", "y_mm", "z_mm"]
    lines = [",".join(header)]
    for k, (q, tip) in enumerate(poses, start=1):
        meas = rot @ tip + trans + rng.normal(0.0, noise_m, 3)
        qs = np.degrees(q) if unit == "deg" else q
        lines.append(
            ",".join(
                [str(k)]
                + [f"{a:.6f}" if unit == "deg" else f"{a:.8f}" for a in qs]
                + [f"{c * 1e3:.4f}" for c in meas]
            )
        )
    answer = {
        "shape": "arm_csv",
        "generator": "realitygap.independent.recordings",
        "seed": seed_int,
        "files": {"measurements": "measurements.csv", "urdf": "arm.urdf"},
        "joint_names": list(ARM_JOINTS),
        "angle_unit": unit,
        "nominal": {"joint_origins_m": [list(o) for o in ARM_NOMINAL_ORIGINS]},
        "true": {
            "joint_origins_m": [list(o) for o in true_origins],
            "joint_offsets_rad": offsets.tolist(),
        },
        "origin_errors_m": [
            [t - n for t, n in zip(to, no)] for to, no in zip(true_origins, ARM_NOMINAL_ORIGINS)
        ],
        "tracker_from_base": {
            "rotation": rot.tolist(),
            "translation_m": trans.tolist(),
            "rpy_rad": list(rpy),
            "convention": "p_tracker = R p_base + t; R = Rz(yaw) Ry(pitch) Rx(roll)",
        },
        "noise_std_m": noise_m,
        "model": "joint i turns to q_i + offset_i about its axis after the translation "
        "joint_origins_m[i] in the parent frame; joint_origins_m[6] is the tool point in "
        "wrist_3_link; the arm points up at q = 0",
        "n_poses": n_poses,
    }
    written = [_write_answer(out, answer)]
    written.append(_atomic_text(out / "measurements.csv", "\n".join(lines) + "\n"))
    written.append(_atomic_text(out / "arm.urdf", _arm_urdf(ARM_NOMINAL_ORIGINS)))
    return Written(out, written, answer)


# --------------------------------------------------------------------------
# Everything, and a summary
# --------------------------------------------------------------------------
CASES = (
    "text_title_mirrored",
    "text_title_mirrored_pipe",
    "multirate_one_file",
    "multirate_two_files",
    "mat_file",
    "ros2_bag",
    "skid_steer",
    "arm_csv",
)


def write_all(
    folder: str | os.PathLike[str], seed: int = 0, *, duration_s: Sequence[float] = (60.0, 120.0)
) -> dict[str, Written | None]:
    """Write every shape into its own sub-folder of ``folder``.

    Each case draws from ``numpy.random.default_rng([seed, index])`` (index in
    :data:`CASES`); its answer records ``seed = [seed, index]``.  The bag case is ``None`` when ``rosbags`` is missing.

    Parameters
    ----------
    folder : path-like
        Root folder.
    seed : int
        Root seed.
    duration_s : sequence of float
        Run-length range of the wheeled cases, s.

    Returns
    -------
    dict
        Case name -> :class:`Written` (or ``None``).
    """
    root = pathlib.Path(folder)
    result: dict[str, Written | None] = {}
    for index, name in enumerate(CASES):
        case_seed = [seed, index]
        sub = root / name
        if name == "text_title_mirrored":
            result[name] = text_title_mirrored(case_seed, sub, duration_s=duration_s)
        elif name == "text_title_mirrored_pipe":
            result[name] = text_title_mirrored(
                case_seed, sub, separator="pipe", duration_s=duration_s
            )
        elif name == "multirate_one_file":
            result[name] = multirate_one_file(case_seed, sub, duration_s=duration_s)
        elif name == "multirate_two_files":
            result[name] = multirate_one_file(case_seed, sub, layout="split", duration_s=duration_s)
        elif name == "mat_file":
            result[name] = mat_file(case_seed, sub, duration_s=duration_s)
        elif name == "ros2_bag":
            try:
                result[name] = ros2_bag(case_seed, sub, duration_s=duration_s)
            except ImportError:
                result[name] = None
        elif name == "skid_steer":
            result[name] = skid_steer(case_seed, sub, duration_s=duration_s)
        else:
            result[name] = arm_csv(case_seed, sub)
    return result


def summary(folder: str | os.PathLike[str]) -> str:
    """One line per data set found under ``folder`` (read from the answer files).

    Parameters
    ----------
    folder : path-like
        A folder written by :func:`write_all` (or a single data set folder).

    Returns
    -------
    str
    """
    root = pathlib.Path(folder)
    answers = sorted(root.glob("*/answer.json")) or sorted(root.glob("answer.json"))
    lines = []
    for path in answers:
        a = json.loads(path.read_text(encoding="utf-8"))
        name = path.parent.name
        if a["shape"] == "arm_csv":
            off = np.abs(a["true"]["joint_offsets_rad"]).max() * 1e3
            err = np.abs(a["origin_errors_m"]).max() * 1e3
            lines.append(
                f"{name:26s} arm: {a['n_poses']} poses, |offset| <= {off:.2f} mrad, "
                f"|length error| <= {err:.2f} mm"
            )
            continue
        e = a["errors"]
        n_runs = {d: len(f) for d, f in a["days"].items()}
        text = (
            f"{name:26s} {a['robot']}: runs day1={n_runs['1']} day2={n_runs['2']}, "
            f"radius L/R {e['wheel_radius_left_rel'] * 100:+.2f}/{e['wheel_radius_right_rel'] * 100:+.2f} %"
        )
        if a["robot"] == "differential_drive":
            text += f", wheelbase {e['wheelbase_rel'] * 100:+.2f} %"
        else:
            text += f", chi {a['true']['chi']:.3f} (B_eff {a['true']['effective_track_m']:.3f} m)"
        mo = a["true"]["mocap_offset_m"]
        text += f", mocap offset ({mo[0] * 1e3:.1f}, {mo[1] * 1e3:.1f}) mm"
        lines.append(text)
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: write every shape into a folder and print the summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", help="output folder")
    parser.add_argument("--seed", type=int, default=0, help="root seed (default 0)")
    parser.add_argument(
        "--duration",
        type=float,
        nargs=2,
        default=(60.0, 120.0),
        metavar=("MIN", "MAX"),
        help="run-length range, s",
    )
    args = parser.parse_args(argv)
    result = write_all(args.folder, args.seed, duration_s=args.duration)
    if result.get("ros2_bag") is None:
        print("ros2_bag skipped: rosbags is not installed", file=sys.stderr)
    print(summary(args.folder))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
