"""Online localiser: VIO, global initialisation and constrained tracking on a synthetic run."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from realitygap.estimators.climb.localiser import ClimbLocaliser, LocaliserConfig, LocaliserPhase
from realitygap.estimators.climb.measurements import ImuSample
from realitygap.estimators.climb.surface import SurfaceModel
from realitygap.robots.climb_synthetic import ClimbScenario, synthesise_recording

SC = ClimbScenario()
ANCHOR = np.asarray(SC.anchor_cad)


@pytest.mark.slow
def test_localiser_phases_on_synthetic_recording(surface: SurfaceModel) -> None:
    sc = dataclasses.replace(SC, speed=0.2, camera_rate=5.0, sweep_waypoints=((2.6, 0.12),))
    rec = synthesise_recording(sc, np.random.default_rng(1))
    loc = ClimbLocaliser(
        surface,
        ANCHOR,
        SC.h,
        localiser_config=LocaliserConfig(init_path_length=0.97 * rec.init_path_length),
    )
    phases, last, between = [], None, []
    for m in rec.measurements:
        last = loc.update(m)
        if not phases or phases[-1] is not loc.phase:
            phases.append(loc.phase)
            assert last.ok == (loc.phase is LocaliserPhase.TRACKING)
        if loc.phase is LocaliserPhase.TRACKING and isinstance(m, ImuSample):
            between.append(last)  # carried forward by the VIO at the IMU rate
        elif loc.phase is not LocaliserPhase.TRACKING:
            assert not last.ok
    assert phases == [LocaliserPhase.VIO_INIT, LocaliserPhase.GLOBAL_INIT, LocaliserPhase.TRACKING]
    assert last is not None and last.ok and last.frame == "cad"
    assert loc.global_init is not None and loc.global_init.converged
    p_true, _ = rec.truth_at(last.t)
    assert np.linalg.norm(last.position - p_true[0]) < 0.03
    assert len({round(e.t, 6) for e in between}) > 0.9 * len(between)  # IMU-rate times
    t_b = np.array([e.t for e in between])
    p_b, _ = rec.truth_at(t_b)
    assert np.linalg.norm(np.array([e.position for e in between]) - p_b, axis=1).max() < 0.03
    assert all(e.frame == "cad" for e in between)
    with pytest.raises(ValueError, match="no initial state"):
        loc.reset(initial=last)  # type: ignore[arg-type]


def test_config_errors() -> None:
    with pytest.raises(ValueError, match="init_max_path_length"):
        LocaliserConfig(init_path_length=3.0, init_max_path_length=2.0)
