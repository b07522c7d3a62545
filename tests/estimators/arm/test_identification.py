"""Kinematic identification: exact recovery, Jacobians, identifiability, errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.estimators.arm.identifiability import analyse_identifiability
from realitygap.estimators.arm.identification import IdentificationSettings, identify
from realitygap.estimators.arm.least_squares import kabsch
from realitygap.estimators.arm.mdh import TOOL_PARAM_NAMES, MDHTable, tool_positions
from realitygap.estimators.arm.residuals import (
    FRAME_PARAM_NAMES,
    PairObservations,
    ParameterLayout,
    PositionObservations,
    ResidualMode,
    ResidualModel,
)

NOMINAL = MDHTable.ur_like_6dof()
TOOL0 = np.array([0.0, 0.05, 0.1])
#: what a position-only measurement cannot tell apart on a UR-like arm
EXPECTED_FIXED = {
    "theta1", "d1", "beta1",  # rotation about / shift along the first axis: the frame
    "d2", "d3",  # offsets along parallel axes (Hayati)
    "beta4", "beta5",  # beta on non-parallel rows
    "theta6", "d6", "a6", "alpha6", "beta6",  # absorbed by the tool point
}  # fmt: skip
R_MB = Rotation.from_rotvec([0.01, -0.02, 0.5]).as_matrix()
T_MB = np.array([0.3, -0.2, 0.1])


def perturbed(rng: np.random.Generator, scale: float = 1e-3) -> MDHTable:
    free = [n for n in NOMINAL.param_names() if n not in EXPECTED_FIXED]
    vals = [NOMINAL.param_dict()[n] + rng.normal(0.0, scale) for n in free]
    return NOMINAL.with_params(vals, free)


def measurements(table, tool, q, noise=0.0, rng=None) -> np.ndarray:
    p = tool_positions(table, q, tool) @ R_MB.T + T_MB
    if noise:
        p = p + rng.normal(0.0, noise, p.shape)
    return p


def observations(mode: str, q: np.ndarray, m: np.ndarray):
    if mode == "position":
        return PositionObservations(q, m)
    return PairObservations.from_positions(q, m)


@pytest.mark.parametrize(
    ("mode", "solver"),
    [
        ("displacement", "gauss_newton"),
        ("distance", "gauss_newton"),
        ("position", "gauss_newton"),
        ("displacement", "lm"),
        ("distance", "trf"),
    ],
)
def test_recovers_perturbed_table_from_exact_data(mode: str, solver: str) -> None:
    rng = np.random.default_rng(0)
    true = perturbed(rng)
    tool = TOOL0 + rng.normal(0, 2e-3, 3)
    q = rng.uniform(-np.pi, np.pi, (30, 6))
    res = identify(
        NOMINAL,
        observations(mode, q, measurements(true, tool, q)),
        tool=TOOL0,
        settings=IdentificationSettings(mode=mode, solver=solver),
    )
    assert set(res.fixed_params) == EXPECTED_FIXED
    for nm in res.free_params:
        if nm in true.param_dict():
            assert abs(res.table.param_dict()[nm] - true.param_dict()[nm]) < 1e-8, nm
    np.testing.assert_allclose(res.tool, tool, atol=1e-8)
    assert res.converged and res.rms_after < 1e-10 < res.rms_before
    if mode != "distance":
        np.testing.assert_allclose(res.T_meas_base[:3, :3], R_MB, atol=1e-8)
    if mode == "position":
        np.testing.assert_allclose(res.T_meas_base[:3, 3], T_MB, atol=1e-8)


@pytest.mark.parametrize("mode", ["distance", "displacement", "position"])
def test_residual_jacobian_matches_finite_differences(mode: str) -> None:
    rng = np.random.default_rng(1)
    q = rng.uniform(-np.pi, np.pi, (8, 6))
    obs = observations(mode, q, measurements(perturbed(rng), TOOL0, q))
    kin = tuple(NOMINAL.param_names())
    frame = FRAME_PARAM_NAMES if mode == "position" else FRAME_PARAM_NAMES[:3]
    layout = ParameterLayout(kin, TOOL_PARAM_NAMES, frame if mode != "distance" else ())
    model = ResidualModel(NOMINAL, TOOL0, R_MB, T_MB, obs, ResidualMode(mode), layout)
    u = model.start() + rng.normal(0, 0.05, len(layout.names))  # away from the start
    _, J = model.residual(u)
    h = 1e-7
    for k in range(len(u)):
        e = np.zeros_like(u)
        e[k] = h
        fd = (model.residual(u + e, False)[0] - model.residual(u - e, False)[0]) / (2 * h)
        np.testing.assert_allclose(J[:, k], fd, atol=1e-7, err_msg=layout.names[k])


def test_singular_problems_are_reported_by_name() -> None:
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(2, 50))
    J = np.column_stack([a, b, a - 2 * b, np.zeros(50)])
    ana = analyse_identifiability(J, ["p", "q", "r", "s"])
    assert ana.free == ("p", "q") and ana.fixed == ("r", "s")
    assert "linearly dependent" in ana.reasons["r"]
    assert ana.reasons["s"] == "no effect on the residuals"
    assert len(ana.combinations) == 1 and "r" in ana.combinations[0]

    # only joints 2 and 3 move: most of the wrist cannot be seen
    q = np.tile([0.3, 0.0, 0.0, -1.0, 0.5, 0.2], (20, 1))
    q[:, 1:3] = rng.uniform(-2, 2, (20, 2))
    res = identify(
        NOMINAL,
        PositionObservations(q, measurements(NOMINAL, TOOL0, q)),
        tool=TOOL0,
        settings=IdentificationSettings(mode="position"),
    )
    assert {"theta4", "theta5", "a4", "alpha4"} <= set(res.fixed_params)
    assert res.unidentifiable and res.rms_after < 1e-12
    assert np.isfinite(res.condition_number)


def test_mdh_fits_a_parallel_axis_tilt_that_dh_cannot() -> None:
    rng = np.random.default_rng(3)
    true = NOMINAL.with_params([2e-3, -1e-3], ["beta2", "beta3"])
    q = rng.uniform(-np.pi, np.pi, (30, 6))
    obs = PairObservations.from_positions(q, measurements(true, TOOL0, q))
    mdh = identify(NOMINAL, obs, tool=TOOL0, settings=IdentificationSettings(param_set="mdh"))
    dh = identify(NOMINAL, obs, tool=TOOL0, settings=IdentificationSettings(param_set="dh"))
    assert mdh.rms_after < 1e-10
    assert dh.rms_after > 1e-5
    assert not any(n.startswith("beta") for n in dh.free_params)


def test_noise_std_and_solvers_agree() -> None:
    rng = np.random.default_rng(4)
    true = perturbed(rng)
    q = rng.uniform(-np.pi, np.pi, (60, 6))
    obs = PositionObservations(q, measurements(true, TOOL0, q, 5e-5, rng))
    results = {
        s: identify(NOMINAL, obs, tool=TOOL0, settings=IdentificationSettings("position", s))
        for s in ("gauss_newton", "lm", "trf")
    }
    gn = results["gauss_newton"]
    for other in ("lm", "trf"):
        for nm in gn.free_params:
            assert abs(gn.deltas[nm] - results[other].deltas[nm]) < 1e-7, (other, nm)
    z = [
        (gn.table.param_dict()[nm] - true.param_dict()[nm]) / gn.std[nm]
        for nm in gn.free_params
        if nm in true.param_dict()
    ]
    assert np.max(np.abs(z)) < 5.0
    assert 0.5 < gn.rms_after / (5e-5 * np.sqrt(3)) < 1.5


def test_prior_pulls_toward_the_start_values() -> None:
    rng = np.random.default_rng(5)
    true = perturbed(rng)
    q = rng.uniform(-np.pi, np.pi, (20, 6))
    obs = PairObservations.from_positions(q, measurements(true, TOOL0, q))
    free = identify(NOMINAL, obs, tool=TOOL0)
    tight = identify(
        NOMINAL,
        obs,
        tool=TOOL0,
        settings=IdentificationSettings(prior_std_length=1e-6, prior_std_angle=1e-6),
    )
    kin = [n for n in free.free_params if n in NOMINAL.param_dict()]
    assert sum(abs(tight.deltas[n]) for n in kin) < 0.1 * sum(abs(free.deltas[n]) for n in kin)


def test_kabsch_is_exact() -> None:
    rng = np.random.default_rng(8)
    P = rng.normal(size=(10, 3))
    T = np.eye(4)
    T[:3, :3] = R_MB
    T[:3, 3] = T_MB
    np.testing.assert_allclose(kabsch(P, P @ R_MB.T + T_MB), T, atol=1e-12)


def test_errors() -> None:
    q = np.zeros((5, 6))
    m = np.zeros((5, 3))
    with pytest.raises(ValueError, match="needs PositionObservations"):
        identify(
            NOMINAL,
            PairObservations.from_positions(q, m),
            settings=IdentificationSettings("position"),
        )
    with pytest.raises(ValueError, match=r"did you mean \['d2'"):
        identify(
            NOMINAL,
            PairObservations.from_positions(q, m),
            settings=IdentificationSettings(fixed=("d22",)),
        )
    with pytest.raises(ValueError, match="mode must be one of"):
        IdentificationSettings(mode="angles")
    with pytest.raises(ValueError, match="rank_tol"):
        IdentificationSettings(rank_tol=0.0)
    with pytest.raises(ValueError, match="prior_std_length"):
        IdentificationSettings(prior_std_length=-1.0)
    with pytest.raises(ValueError, match=r"displacement must have shape \(2, 3\)"):
        PairObservations(np.zeros((2, 6)), np.zeros((2, 6)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="pairs index out of range"):
        PairObservations.from_positions(q, m, np.array([[0, 5]]))
    with pytest.raises(ValueError, match=r"tool must have shape \(3,\)"):
        identify(NOMINAL, PairObservations.from_positions(q, m), tool=np.zeros(2))
    rng = np.random.default_rng(9)
    q2 = rng.uniform(-3, 3, (2, 6))  # one pair: three residuals, three frame angles
    with pytest.raises(ValueError, match="cannot determine"):
        identify(NOMINAL, PairObservations.from_positions(q2, measurements(NOMINAL, TOOL0, q2)))
