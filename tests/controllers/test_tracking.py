"""Closed-loop properties of the velocity limits, timed reference, tracker and stabiliser.

The plant is an exact unicycle under zero-order hold at 20 Hz, the pose rate
of the wheeled robot's localisation.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pytest
from scipy.spatial import cKDTree

from realitygap.controllers import (
    ImprovedAPF,
    KanayamaTracker,
    PolarStabiliser,
    SmoothPath,
    TimedReference,
    VelocityLimits,
    polar_coordinates,
    shortcut_waypoints,
    smooth_path,
    tracking_error,
    unicycle_step,
)
from realitygap.core.geometry import wrap_angle

FloatArray = npt.NDArray[np.float64]
Reference = Callable[[float], tuple[FloatArray, float, float]]

DT = 0.05
LIMITS = VelocityLimits()
TOL = 1e-9


def circle_reference(radius: float = 1.0, speed: float = 0.5) -> Reference:
    rate = speed / radius

    def at(t: float) -> tuple[FloatArray, float, float]:
        theta = rate * t
        pose = np.array([radius * math.sin(theta), radius * (1 - math.cos(theta)), theta])
        return pose, speed, rate

    return at


def lemniscate_reference(size: float = 1.5, period: float = 40.0) -> Reference:
    """Lemniscate of Gerono ``x = a sin u, y = a sin u cos u`` with ``u = 2πt / period``."""
    c = 2 * math.pi / period

    def at(t: float) -> tuple[FloatArray, float, float]:
        u = c * t
        dx, dy = size * c * math.cos(u), size * c * math.cos(2 * u)
        ddx, ddy = -size * c * c * math.sin(u), -2 * size * c * c * math.sin(2 * u)
        speed = math.hypot(dx, dy)
        pose = np.array([size * math.sin(u), size * math.sin(u) * math.cos(u), math.atan2(dy, dx)])
        return pose, speed, (dx * ddy - dy * ddx) / speed**2

    return at


def circle_path(
    radius: float = 1.0, arc: float = 1.5 * math.pi, spacing: float = 0.01
) -> SmoothPath:
    s = np.linspace(0.0, radius * arc, math.ceil(radius * arc / spacing) + 1)
    theta = s / radius
    xy = np.column_stack([radius * np.sin(theta), radius * (1 - np.cos(theta))])
    return SmoothPath(xy, theta, np.full_like(s, 1 / radius), s, True, "ok")


def assert_within_limits(v: float, w: float, v_prev: float, w_prev: float, dt: float) -> None:
    assert abs(v) <= LIMITS.v_max + TOL and abs(w) <= LIMITS.w_max + TOL
    assert abs(v - v_prev) <= LIMITS.a_max * dt + TOL
    assert abs(w - w_prev) <= LIMITS.alpha_max * dt + TOL


# -- limits and kinematics --------------------------------------------------------------------


def test_clip_respects_velocity_and_acceleration_limits() -> None:
    rng = np.random.default_rng(0)
    for _ in range(2000):
        v_prev = rng.uniform(-LIMITS.v_max, LIMITS.v_max)
        w_prev = rng.uniform(-LIMITS.w_max, LIMITS.w_max)
        v, w = rng.normal(0.0, 1.0, 2) * [1.0, 4.0]
        dt = rng.choice([0.01, 0.05, 0.2])
        out_v, out_w = LIMITS.clip(v, w, v_prev, w_prev, dt)
        assert_within_limits(out_v, out_w, v_prev, w_prev, dt)


def test_clip_passes_feasible_commands_unchanged_and_keeps_curvature() -> None:
    assert LIMITS.clip(0.3, 0.5, 0.29, 0.45, DT) == (0.3, 0.5)
    # Saturation keeps the curvature w / v.
    v, w = LIMITS.saturate(2.0, 20.0)
    assert abs(w) == pytest.approx(LIMITS.w_max)
    assert w / v == pytest.approx(10.0)
    # From rest the acceleration limit scales the command along its own direction.
    v, w = LIMITS.clip(0.6, 1.2, 0.0, 0.0, DT)
    assert w / v == pytest.approx(2.0)
    assert v == pytest.approx(LIMITS.a_max * DT)


def test_clip_and_limits_validate_input() -> None:
    with pytest.raises(ValueError, match="dt must be finite and > 0"):
        LIMITS.clip(0.1, 0.1, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match=r"VelocityLimits\.a_max must be finite and > 0"):
        VelocityLimits(a_max=-1.0)


def test_unicycle_step_is_exact() -> None:
    pose = np.array([0.3, -0.2, 0.7])
    # A full circle in 40 steps returns to the start.
    w = 2 * math.pi / (40 * DT)
    moved = pose
    for _ in range(40):
        moved = unicycle_step(moved, 0.4, w, DT)
    np.testing.assert_allclose(moved, pose, atol=1e-12)
    straight = unicycle_step(pose, 0.5, 0.0, 2.0)
    np.testing.assert_allclose(straight, [0.3 + math.cos(0.7), -0.2 + math.sin(0.7), 0.7])


def test_tracking_error_and_polar_coordinates_closed_form() -> None:
    pose = np.array([1.0, 2.0, math.pi / 2])
    np.testing.assert_allclose(
        tracking_error(pose, [1.0, 2.5, 0.0]), [0.5, 0.0, -math.pi / 2], atol=1e-15
    )
    np.testing.assert_allclose(
        tracking_error(pose, [0.0, 2.0, math.pi / 2]), [0.0, 1.0, 0.0], atol=1e-15
    )
    rho, alpha, beta = polar_coordinates([0.0, 0.0, 0.0], [1.0, 1.0, math.pi / 2])
    assert (rho, alpha, beta) == pytest.approx((math.sqrt(2), math.pi / 4, math.pi / 4))
    with pytest.raises(ValueError, match=r"ref_pose must have shape \(3,\)"):
        tracking_error(pose, [0.0, 0.0])


# -- Kanayama tracker -------------------------------------------------------------------------


def test_kanayama_on_the_reference_feeds_forward_exactly() -> None:
    tracker = KanayamaTracker()
    pose = np.array([0.2, 0.1, -0.4])
    assert tracker.command(pose, pose, 0.4, 0.3) == pytest.approx((0.4, 0.3), abs=1e-15)
    with pytest.raises(ValueError, match="ky must be finite and > 0"):
        KanayamaTracker(ky=0.0)


@pytest.mark.parametrize(
    "reference", [circle_reference(), lemniscate_reference()], ids=["circle", "lemniscate"]
)
def test_kanayama_converges_from_perturbed_starts(reference: Reference) -> None:
    tracker = KanayamaTracker()
    rng = np.random.default_rng(1)
    for _ in range(4):
        start_pose, _, _ = reference(0.0)
        pose = start_pose + np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(-0.5, 0.5)])
        v = w = 0.0
        errors = []
        for k in range(int(30.0 / DT)):
            ref_pose, v_r, w_r = reference(k * DT)
            v_cmd, w_cmd = tracker.command(pose, ref_pose, v_r, w_r)
            v_new, w_new = LIMITS.clip(v_cmd, w_cmd, v, w, DT)
            assert_within_limits(v_new, w_new, v, w, DT)
            v, w = v_new, w_new
            pose = unicycle_step(pose, v, w, DT)
            errors.append(tracking_error(pose, reference((k + 1) * DT)[0]))
        tail = np.abs(np.array(errors)[-int(10.0 / DT) :])
        assert tail[:, 0].max() < 2e-3 and tail[:, 1].max() < 2e-3
        assert tail[:, 2].max() < math.radians(0.5)


# -- timed reference --------------------------------------------------------------------------


@pytest.mark.parametrize("fraction", [0.5, 0.8, 1.0])
def test_timed_reference_respects_the_limits(fraction: float) -> None:
    rng = np.random.default_rng(2)
    heading = np.cumsum(rng.normal(0, 0.15, 80))
    waypoints = np.vstack(
        [[0.0, 0.0], np.cumsum(0.05 * np.c_[np.cos(heading), np.sin(heading)], 0)]
    )
    path = smooth_path(waypoints, 0.0, None)
    assert path.feasible
    reference = TimedReference(path, LIMITS, speed_fraction=fraction)
    assert reference.v[0] == 0.0 and reference.v[-1] == 0.0
    assert reference.duration >= path.length / LIMITS.v_max
    samples = [reference.sample(t) for t in np.arange(0.0, reference.duration, 0.01)]
    v = np.array([r.v for r in samples])
    w = np.array([r.w for r in samples])
    s = np.array([r.s for r in samples])
    assert np.all(v <= fraction * LIMITS.v_max + TOL) and np.all(v >= 0.0)
    assert np.all(np.abs(w) <= fraction * LIMITS.w_max + 1e-6)
    assert np.all(np.abs(np.diff(v)) / 0.01 <= fraction * LIMITS.a_max + 1e-6)
    assert np.all(np.diff(s) >= 0.0)
    np.testing.assert_allclose(reference.sample(0.0).pose, path.pose_at(0.0))
    np.testing.assert_allclose(reference.sample(reference.duration).pose, path.pose_at(path.length))
    assert reference.sample(reference.duration).s == pytest.approx(path.length)


def test_timed_reference_on_a_circle_has_consistent_speed_and_yaw_rate() -> None:
    path = circle_path(radius=0.5)
    reference = TimedReference(path, LIMITS, speed_fraction=0.8)
    middle = reference.sample(0.5 * reference.duration)
    # Cruise is capped by the yaw-rate limit: v = 0.8 w_max r < 0.8 v_max.
    assert middle.v == pytest.approx(min(0.8 * LIMITS.v_max, 0.8 * LIMITS.w_max * 0.5), rel=1e-6)
    assert middle.w == pytest.approx(middle.v / 0.5, rel=1e-3)
    # Integrating the reference speed over time gives the arc length.
    t = np.linspace(0.0, reference.duration, 20001)
    travelled = np.trapezoid([reference.sample(ti).v for ti in t], t)
    assert travelled == pytest.approx(path.length, rel=1e-3)


def test_projection_finds_the_nearest_arc_length() -> None:
    path = circle_path(radius=1.0, arc=1.5 * math.pi)
    reference = TimedReference(path)
    rng = np.random.default_rng(3)
    for s in rng.uniform(0.0, path.length, 20):
        theta = s
        outward = 1.0 + rng.uniform(-0.3, 0.3)
        xy = [outward * math.sin(theta), 1.0 - outward * math.cos(theta)]
        # Exact up to projecting onto 1 cm chords instead of the arc: < 0.3 · 0.5 · 1 cm.
        assert reference.project(xy) == pytest.approx(s, abs=2e-3)
        assert reference.project(xy, s_hint=s + 0.1, window=0.3) == pytest.approx(s, abs=2e-3)
    assert reference.time_at(path.length) == pytest.approx(reference.duration)


def test_timed_reference_validates_input() -> None:
    path = circle_path()
    with pytest.raises(ValueError, match=r"speed_fraction must lie in \(0, 1\]"):
        TimedReference(path, speed_fraction=1.5)
    broken = SmoothPath(path.xy, path.heading, path.curvature, path.s[::-1], True, "ok")
    with pytest.raises(ValueError, match=r"path\.s must be strictly increasing"):
        TimedReference(broken)


# -- polar stabiliser -------------------------------------------------------------------------


def run_stabiliser(
    stabiliser: PolarStabiliser, start: FloatArray, goal: FloatArray, horizon: float = 15.0
) -> tuple[float | None, FloatArray, list[tuple[float, float]]]:
    """Time when done (or None), final pose and commands, holding on for 2 s after done."""
    stabiliser.reset()
    pose, v, w = start.astype(float), 0.0, 0.0
    commands = []
    done_at = None
    for k in range(int(horizon / DT)):
        v_cmd, w_cmd = stabiliser.command(pose, goal)
        v_new, w_new = LIMITS.clip(v_cmd, w_cmd, v, w, DT)
        assert_within_limits(v_new, w_new, v, w, DT)
        v, w = v_new, w_new
        commands.append((v, w))
        pose = unicycle_step(pose, v, w, DT)
        if done_at is None and PolarStabiliser.done(pose, goal):
            done_at = k * DT
        if done_at is not None and k * DT > done_at + 2.0:
            break
    return done_at, pose, commands


@pytest.mark.slow
@pytest.mark.parametrize("goal", [[0.0, 0.0, math.pi / 2], [1.0, -0.5, -2.5]])
def test_polar_stabiliser_converges_from_every_start_within_half_a_metre(goal: list[float]) -> None:
    goal_pose = np.array(goal)
    stabiliser = PolarStabiliser()
    reversed_starts = 0
    for radius in (0.02, 0.2, 0.5):
        for bearing in np.linspace(-math.pi, math.pi, 8, endpoint=False):
            for heading in np.linspace(-math.pi, math.pi, 4, endpoint=False):
                offset = [radius * math.cos(bearing), radius * math.sin(bearing), heading - goal[2]]
                start = goal_pose + np.array(offset)
                done_at, pose, commands = run_stabiliser(stabiliser, start, goal_pose)
                assert done_at is not None and done_at < 12.0, (start, pose)
                # Still there 2 s later: within 2 mm and 0.3°.
                assert math.hypot(*(pose[:2] - goal_pose[:2])) <= 2e-3
                assert abs(float(wrap_angle(pose[2] - goal_pose[2]))) <= math.radians(0.3)
                v = np.array([c[0] for c in commands])
                w = np.array([c[1] for c in commands])
                moving = v[np.abs(v) > 1e-4]
                # No back-and-forth: the driving direction changes at most once.
                assert np.count_nonzero(np.diff(np.sign(moving))) <= 1
                reversed_starts += int(moving[0] < 0) if len(moving) else 0
                # No chatter when settling: the yaw rate keeps its sign in the last second.
                tail = w[-int(1.0 / DT) :]
                tail = tail[np.abs(tail) > 1e-6]
                assert np.count_nonzero(np.diff(np.sign(tail))) == 0
    assert reversed_starts > 0  # goals behind the robot were approached backwards


def test_goal_straight_behind_is_approached_backwards() -> None:
    stabiliser = PolarStabiliser()
    goal = np.array([0.0, 0.0, 0.0])
    v, w = stabiliser.command([0.4, 0.0, 0.0], goal)
    assert v < 0.0 and w == pytest.approx(0.0)
    assert stabiliser.direction == -1
    done_at, _, commands = run_stabiliser(stabiliser, np.array([0.4, 0.0, 0.0]), goal)
    assert done_at is not None
    assert all(c[0] <= 0.0 for c in commands)
    forwards_only = PolarStabiliser(allow_reverse=False)
    assert forwards_only.command([0.4, 0.0, 0.0], goal)[0] > 0.0


def test_turns_in_place_at_the_goal_position() -> None:
    stabiliser = PolarStabiliser()
    v, w = stabiliser.command([1.0, 1.0, 0.0], [1.0, 1.0, 2.0])
    assert v == 0.0 and 0.0 < w <= stabiliser.align_rate
    done_at, pose, _ = run_stabiliser(
        stabiliser, np.array([1.0, 1.0, 0.0]), np.array([1.0, 1.0, 2.0])
    )
    assert done_at is not None
    np.testing.assert_allclose(pose[:2], [1.0, 1.0], atol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"k_beta": 0.5}, "k_beta must be finite and < 0"),
        ({"k_alpha": 0.5}, r"k_alpha must be finite and > k_rho"),
        ({"k_rho": 0.0}, "k_rho must be finite and > 0"),
        ({"align_radius": -1.0}, "align_radius must be finite and > 0"),
    ],
)
def test_polar_stabiliser_rejects_unstable_gains(kwargs: dict[str, float], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        PolarStabiliser(**kwargs)


# -- the whole chain --------------------------------------------------------------------------


@pytest.mark.parametrize("start", [[-2.4, -2.4, 0.0], [0.0, -2.4, 0.0], [2.4, 0.0, 0.0]])
def test_plan_smooth_track_and_stabilise_reaches_the_goal_pose(start: list[float]) -> None:
    angle = np.linspace(0.0, 2 * math.pi, 100, endpoint=False)
    obstacles = np.vstack(
        [
            np.c_[0.3 * np.cos(angle), -1.2 + 0.3 * np.sin(angle)],
            np.c_[-1.2 + 0.25 * np.cos(angle), 0.25 * np.sin(angle)],
        ]
    )
    goal = np.array([0.0, 0.0, math.pi / 2])
    plan = ImprovedAPF().plan(start[:2], goal[:2], obstacles)
    assert plan.reached
    waypoints = shortcut_waypoints(plan.waypoints, obstacles, 0.22)
    path = smooth_path(waypoints, start[2], None)
    assert path.feasible, path.message
    reference = TimedReference(path, LIMITS)
    tracker, stabiliser = KanayamaTracker(), PolarStabiliser()
    pose, v, w = np.array(start), 0.0, 0.0
    trajectory = [pose]
    k = 0
    while not stabiliser.done(pose, goal):
        t = k * DT
        assert t < reference.duration + 15.0
        if t <= reference.duration:
            sample = reference.sample(t)
            v_cmd, w_cmd = tracker.command(pose, sample.pose, sample.v, sample.w)
        else:
            v_cmd, w_cmd = stabiliser.command(pose, goal)
        v_new, w_new = LIMITS.clip(v_cmd, w_cmd, v, w, DT)
        assert_within_limits(v_new, w_new, v, w, DT)
        v, w = v_new, w_new
        pose = unicycle_step(pose, v, w, DT)
        trajectory.append(pose)
        k += 1
    assert math.hypot(*(pose[:2] - goal[:2])) <= 2e-3
    assert abs(float(wrap_angle(pose[2] - goal[2]))) <= math.radians(0.3)
    body_radius = 0.176
    assert cKDTree(obstacles).query(np.array(trajectory)[:, :2])[0].min() > body_radius


def test_the_final_turn_can_stop_before_the_goal_heading() -> None:
    """On the goal position the stabiliser turns in place no faster than the robot can stop
    from within the turn that is left: |ω| ≤ √(2 α_max |Δθ|)."""
    limits = VelocityLimits(v_max=0.7, w_max=3.0, a_max=0.5, alpha_max=0.8)
    stab = PolarStabiliser(limits=limits, align_rate=3.0)
    rng = np.random.default_rng(7)
    for _ in range(200):
        err = float(rng.uniform(-1.0, 1.0)) * 10.0 ** float(rng.uniform(-4, 0))
        _, w = stab.command([1.0, 2.0, 0.3], [1.0, 2.0, 0.3 + err])
        assert abs(w) <= math.sqrt(2.0 * limits.alpha_max * abs(err)) + 1e-12
        assert w * err >= 0.0  # towards the goal heading
