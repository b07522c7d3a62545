"""Recording a run of the PyBullet climber: drive a chart path, record IMU, camera and tether.

:func:`record_climb_run` drives :class:`~realitygap.robots.climber.ClimberRobot` along
chart waypoints ``(x [m], ξ)`` on the blade with a pure-pursuit controller on the true
pose, records the IMU (at its rate), the down-looking camera's relative motion and the
tether (at the camera rate) with ground truth, and returns a
:class:`~realitygap.robots.climb_synthetic.ClimbRecording`. The ``climb003`` experiment
and the diagnosis's blind climber cases both record through it.
"""

from __future__ import annotations

import itertools
import math
import time
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.robots.climb_synthetic import ClimbRecording
from realitygap.robots.climber import (
    ClimberParams,
    ClimberRobot,
    ClimbFaults,
    ClimbWorld,
    chart_pose,
)
from realitygap.robots.climber_sensors import CameraModel, ImuModel, TetherModel
from realitygap.robots.sensors import SensorMode

FloatArray = npt.NDArray[np.float64]

__all__ = ["dense_chart", "record_climb_run"]


def dense_chart(waypoints: FloatArray, step: float = 0.01) -> FloatArray:
    out = [waypoints[:1]]
    for a, b in itertools.pairwise(waypoints):
        n = max(int(math.ceil(np.linalg.norm((b - a) * [1.0, 1.2]) / step)), 1)
        lam = np.linspace(0, 1, n + 1)[1:, None]
        out.append(a + lam * (b - a))
    return np.concatenate(out)


def _order_key(m: Any) -> tuple[float, int]:
    from realitygap.estimators.climb import ImuSample, TetherReading

    if isinstance(m, ImuSample):
        return (m.t, 0)
    if isinstance(m, TetherReading):
        return (m.t, 2)
    return (m.t1, 1)


def record_climb_run(
    params: ClimberParams,
    waypoints: npt.ArrayLike,
    n_init: int,
    rng: np.random.Generator,
    *,
    speed: float = 0.15,
    static_duration: float = 2.0,
    lookahead: float = 0.12,
    faults: ClimbFaults | None = None,
    scene: ClimbWorld | None = None,
    robot: ClimberRobot | None = None,
) -> tuple[ClimbRecording, dict[str, float]]:
    """Drive the simulated climber along chart ``waypoints`` and record a run.

    Parameters
    ----------
    params
        True robot parameters (nominal when no effects).
    waypoints : (K, 2)
        Chart waypoints ``(x [m], ξ)``; the first ``n_init`` form the excitation loop.
    rng
        Sensor noise.
    speed, static_duration, lookahead
        m/s, s (still at the start), m (pure pursuit).
    scene, robot
        Re-use a built world and its robot (built from ``params``); both or neither.

    Returns
    -------
    recording, stats
        The :class:`.ClimbRecording` (CAD = world frame) and ``{"sim_seconds",
        "wall_seconds", "distance_m"}``.
    """
    wall0 = time.perf_counter()
    own = scene is None
    sc = ClimbWorld(params) if scene is None else scene
    try:
        if robot is None:
            robot = ClimberRobot(sc, params)
        wp = np.asarray(waypoints, dtype=float)
        chart = dense_chart(wp)
        s_span = chart[:, 0] / params.blade.length
        u = 1.0 - np.arccos(np.sqrt(np.clip(chart[:, 1], 1e-6, 1))) / np.pi
        surf = sc.surface
        ref = params.world_from_blade(
            surf.position(s_span, u) + params.h_true * surf.normal(s_span, u)
        )
        init_idx = len(dense_chart(wp[:n_init])) - 1
        first = ref[1] - ref[0]
        pos, R = chart_pose(surf, params, wp[0, 0], wp[0, 1], 0.0, params.h_true)
        d_local = R.T @ first
        pos, R = chart_pose(
            surf, params, wp[0, 0], wp[0, 1], math.atan2(d_local[1], d_local[0]), params.h_true
        )
        robot.reset(pos, R)
        fl = faults or ClimbFaults()
        imu = ImuModel(params, rng)
        tether = TetherModel(params, rng, fl)
        cam = CameraModel(robot, params, SensorMode.FAST, rng, fl)
        world = sc.world
        c = world.bullet
        dtp = world.physics_dt
        imu_every = int(round(1.0 / (params.imu_rate * dtp)))
        cam_every = int(round(1.0 / (params.camera_rate * dtp)))
        meas: list[Any] = []
        truth_t: list[float] = []
        truth_p: list[FloatArray] = []
        truth_R: list[FloatArray] = []
        t = 0.0
        s_prev = robot.state(t)
        idx = 0
        done_at: float | None = None
        init_time: float | None = None
        v_cmd = w_cmd = 0.0
        k = 0
        while True:
            if k % imu_every == 0 and k > 0:
                s = robot.state(t)
                meas.append(imu.sample(s_prev, s))
                truth_t.append(s_prev.t)
                truth_p.append(s_prev.position)
                truth_R.append(s_prev.R)
                s_prev = s
                if k % cam_every == 0:
                    frame = cam.capture(s, params.h_true)
                    if frame is not None:
                        meas.append(frame)
                    meas.append(tether.read(t, s.position, 1.0 / params.camera_rate))
                if k % (imu_every * 6) == 0:  # 20 Hz control on the true pose
                    if t >= static_duration and done_at is None:
                        d = np.linalg.norm(ref[idx : idx + 25] - s.position, axis=1)
                        idx = idx + int(np.argmin(d))
                        if init_time is None and idx >= init_idx:
                            init_time = t
                        j = idx
                        while j < len(ref) - 1 and np.linalg.norm(ref[j] - s.position) < lookahead:
                            j += 1
                        target = s.R.T @ (ref[j] - s.position)
                        alpha = math.atan2(target[1], target[0])
                        v_target = speed * max(0.0, math.cos(alpha)) ** 2
                        if idx >= len(ref) - 3 or np.linalg.norm(ref[-1] - s.position) < 0.02:
                            done_at = t
                            v_target = 0.0
                        w_target = 2.0 * math.sin(alpha) * max(v_target, 0.05) / lookahead
                        w_target = max(-params.w_max, min(params.w_max, w_target))
                        dv, dw = 0.5 * 0.05, 2.0 * 0.05
                        v_cmd += max(-dv, min(dv, v_target - v_cmd))
                        w_cmd += max(-dw, min(dw, w_target - w_cmd))
                        if done_at is not None:
                            v_cmd = w_cmd = 0.0
                        robot.set_twist(v_cmd, w_cmd, params)
                    if done_at is not None and t > done_at + 1.0:
                        break
                    if t > 2000.0:
                        raise RuntimeError("the climber did not finish the path in 2000 s")
            robot.apply_adsorption()
            c.stepSimulation()
            k += 1
            t = k * dtp
        tp = np.array(truth_p)
        if init_time is None:
            raise RuntimeError("the climber never completed the excitation loop")
        t_arr = np.array(truth_t)
        seg = np.linalg.norm(np.diff(tp, axis=0), axis=1)
        init_len = float(np.sum(seg[: int(np.searchsorted(t_arr, init_time))]))
        rec = ClimbRecording(
            measurements=tuple(sorted(meas, key=_order_key)),
            truth_t=t_arr,
            truth_position=tp,
            truth_rotation=np.array(truth_R),
            init_path_length=init_len,
            anchor_cad=params.anchor_world,
            h=params.h,
        )
        stats = {
            "sim_seconds": t,
            "wall_seconds": time.perf_counter() - wall0,
            "distance_m": float(seg.sum()),
        }
        return rec, stats
    finally:
        if own:
            sc.close()
