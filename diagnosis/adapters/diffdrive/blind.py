"""The differential drive's blind logs: ordinary manoeuvres recorded with a hidden reality.

A blind case of the validation suite records the training manoeuvres
(:data:`TRAIN_MANOEUVRES`) and the held-out ones (:data:`HOLDOUT_MANOEUVRES`) of the
PyBullet robot with the hidden effects built in, with motion-capture and camera noise:
the firmware-ramped manoeuvres through :class:`~realitygap.envs.wheeled_nav.WheeledNavEnv`
and :class:`~realitygap.diagnosis.adapters.diffdrive.record.RecordLog`, hard starts by
driving the robot directly (:func:`record_case_logs`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from realitygap.diagnosis.adapters.diffdrive.manoeuvres import MANOEUVRES
from realitygap.diagnosis.adapters.diffdrive.record import RecordLog
from realitygap.diagnosis.adapters.diffdrive.replay import simulate
from realitygap.diagnosis.logs.log import Log
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import Reality
from realitygap.robots.simulation import MeasurementNoise

__all__ = ["BLIND_NOISE", "HOLDOUT_MANOEUVRES", "TRAIN_MANOEUVRES", "record_case_logs"]

TRAIN_MANOEUVRES = ("straight_runs", "turns_in_place", "arcs", "accelerations")
"""Manoeuvres of a blind case's training logs."""
HOLDOUT_MANOEUVRES = ("square_cw", "square_ccw", "tour", "hard_starts")
"""Manoeuvres of a blind case's held-out logs."""

BLIND_NOISE = MeasurementNoise(
    truth_xy=0.0005, truth_theta=0.001, camera_xy=0.001, camera_theta=0.002
)
"""Motion-capture and camera noise of the blind suite's logs."""


def _record_env(
    manoeuvre: str, reality: Reality, params: DiffDriveParams, noise: MeasurementNoise, rng: Any
) -> Log:
    from realitygap.envs.wheeled_nav import WheeledNavEnv

    env = WheeledNavEnv(
        reality=reality,
        params=params,
        n_obstacles=0,
        room_half_size=20.0,
        start=(0.0, 0.0, float(rng.uniform(-math.pi, math.pi))),
        goal=(15.0, 15.0, 0.0),
        terminate_on_success=False,
        n_beams=8,
    )
    rec = RecordLog(env, noise=noise, rng=rng, meta={"name": manoeuvre})
    try:
        rec.reset(seed=int(rng.integers(2**31)))
        t, req = MANOEUVRES[manoeuvre].requested(env.dt)
        scale = np.array([params.v_max, params.w_max])
        for k in range(t.shape[0] - 1):
            rec.step(req[k] / scale)
        return rec.log
    finally:
        env.close()


def record_case_logs(
    reality: Reality,
    rng: np.random.Generator,
    noise: MeasurementNoise,
    manoeuvres: Sequence[str],
    params: DiffDriveParams | None = None,
) -> list[Log]:
    """Record ``manoeuvres`` with the robot ``reality``: ramped ones through the env, steps directly."""
    params = params if params is not None else DiffDriveParams()
    logs = []
    for m in manoeuvres:
        man = MANOEUVRES[m]
        if man.ramp:
            logs.append(_record_env(m, reality, params, noise, rng))
        else:
            t, cmd = man.applied(0.05, params)
            start = np.array([0.0, 0.0, float(rng.uniform(-math.pi, math.pi))])
            logs.append(
                simulate(
                    t,
                    params=params,
                    reality=reality,
                    commands=cmd,
                    start=start,
                    noise=noise,
                    rng=rng,
                    meta={"name": m},
                    source=m,
                )
            )
    return logs
