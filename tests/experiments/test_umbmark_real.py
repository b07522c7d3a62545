"""Building blocks of the ``umbmark-real`` experiment."""

from __future__ import annotations

from pathlib import Path

import pytest

from realitygap.calibrate import SessionCalibration, pool_calibrations
from realitygap.estimators.diffdrive_model import DiffDriveKinematics
from realitygap.experiments import EXPERIMENTS
from realitygap.experiments.umbmark_real import _same_period

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "optiodom_diffdrive"


def _calibration(sid: str, b_nominal: float, d_nominal: float, e_b: float) -> SessionCalibration:
    return SessionCalibration(
        session_id=sid,
        path="",
        side_length=0.75,
        n_cw=3,
        n_ccw=3,
        E_d=0.999,
        E_b=e_b,
        c_L=1.0,
        c_R=1.0,
        alpha=0.0,
        beta=0.0,
        E_max_syst=0.0,
        nominal_D_L=d_nominal,
        nominal_D_R=d_nominal,
        nominal_b=b_nominal,
        D_L=d_nominal,
        D_R=d_nominal,
        b=e_b * b_nominal,
        b_over_D=e_b * b_nominal / d_nominal,
        ticks_per_rev=2796.8,
        recorded="",
    )


def test_transfer_does_not_depend_on_the_nominal_description() -> None:
    # one robot (b/D = 2.4) described once as b = 0.200 m and once as b = 0.205 m
    a = _calibration("230620202042", 0.200, 0.084, 2.4 * 0.084 / 0.200)
    b = _calibration("230620202144", 0.205, 0.084, 2.4 * 0.084 / 0.205)
    pooled = pool_calibrations([a, b])
    assert pooled.b_over_D == pytest.approx(2.4) and pooled.b_over_D_std < 1e-12
    held_out = DiffDriveKinematics.from_diameters(0.084, 0.084, 0.200, 2796.8)
    assert pooled.kinematics_for(held_out).wheelbase == pytest.approx(2.4 * 0.084)
    with pytest.raises(ValueError, match="at least one"):
        pool_calibrations([])


def test_same_period_picks_the_day_of_the_nearest_square_session() -> None:
    cals = [
        _calibration("230620202042", 0.2, 0.084, 1.0),
        _calibration("230620202317", 0.2, 0.084, 1.0),
        _calibration("231220200029", 0.2, 0.084, 1.0),
    ]
    assert [c.session_id for c in _same_period("231220200121", cals)] == ["231220200029"]
    june = [c.session_id for c in _same_period("250620202104", cals)]
    assert june == ["230620202042", "230620202317"]
    assert _same_period("020120212354", cals)[0].session_id == "231220200029"
    assert len(_same_period("not-a-date", cals)) == 3


@pytest.mark.slow
def test_umbmark_real_improves_the_held_out_runs() -> None:
    if not DATA.is_dir():
        pytest.skip(f"OptiOdom data not found at {DATA}; needs ../shared/data beside the repo")
    from realitygap.experiments import RunContext

    ctx = RunContext(quick=True, data_dir=DATA.parent, verbose=False)
    out = EXPERIMENTS["umbmark-real"].func(ctx)
    fig = out["figures"]
    assert 0.99 < fig["E_d"] < 1.01 and 0.95 < fig["E_b"] < 1.05
    assert fig["heldout_end_err_cm_calibrated"] < fig["heldout_end_err_cm_nominal"]
    assert fig["heldout_ate_cm_calibrated"] < fig["heldout_ate_cm_nominal"]
    kinds = {r["path_type"] for r in out["tables"]["path_types"]}
    assert {"circular", "all"} <= kinds
    assert all(r["calibrated_from"] for r in out["tables"]["runs"])
