"""Kinematic identification of MDH parameters from distance, displacement or position data.

The residuals and observations are those of :mod:`.residuals`; the parameters
estimated are the identifiable subset that :mod:`.identifiability` selects.

Solvers: Gauss–Newton with the pseudo-inverse,

.. math::

    u_{n+1} = u_n - J^{+}(u_n)\\, e(u_n),

with step halving when the cost would rise, or ``scipy.optimize.least_squares``
(``"lm"`` or ``"trf"``).

Optionally (``prior_std_length`` / ``prior_std_angle``) a Gaussian prior about
the start values turns the fit into a maximum-a-posteriori estimate; it helps
when the test poses lie outside the region the training poses cover.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from realitygap.core.geometry import check_finite

from .identifiability import analyse_identifiability, preference_order
from .least_squares import column_norms, kabsch, lstsq_min_norm, singular_values, thin_qr, wahba
from .mdh import (
    TOOL_PARAM_NAMES,
    MDHTable,
    ParamSet,
    check_joint_angles,
    check_param_set,
    tool_positions,
)
from .residuals import (
    FRAME_PARAM_NAMES,
    PairObservations,
    ParameterLayout,
    PositionObservations,
    ResidualMode,
    ResidualModel,
)

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "IdentificationResult",
    "IdentificationSettings",
    "Solver",
    "identify",
]


class Solver(str, Enum):
    """Nonlinear least-squares solver."""

    GAUSS_NEWTON = "gauss_newton"  #: own Gauss–Newton, u <- u - J^+ e, step halving
    LM = "lm"  #: scipy.optimize.least_squares, Levenberg–Marquardt (MINPACK)
    TRF = "trf"  #: scipy.optimize.least_squares, trust-region reflective


@dataclass(frozen=True)
class IdentificationSettings:
    r"""Settings of :func:`identify`.

    Attributes
    ----------
    mode : ResidualMode
        Residual type; must match the observations (pairs for distance and
        displacement, positions for position).
    solver : Solver
    param_set : ParamSet
        ``MDH`` (five per joint) or ``DH`` (β held at its start value).
    estimate_tool : bool
        Estimate the tool point in the last joint frame.
    estimate_frame : bool
        Estimate the measurement-frame rotation (displacement) or registration
        (position); ignored in distance mode.
    fixed : tuple of str
        Parameters held at their start values in any case.
    rank_tol : float
        Admission threshold of the identifiability analysis: the fraction of a
        unit-scaled Jacobian column that must lie outside the span of the
        columns admitted before it.
    max_iterations : int
    xtol : float
        Stop when the step is below ``xtol * (|u| + xtol)``.
    ftol : float
        Stop when the cost falls by less than this fraction.
    prior_std_length, prior_std_angle : float or None
        Optional Gaussian prior on the kinematic parameters about their start
        values, std in m and rad (maximum a posteriori instead of least squares):
        rows :math:`(\sigma_e / \sigma_u)(u - u_0)` are appended to the residuals.
        ``None`` (default): no prior.
    measurement_std : float
        :math:`\sigma_e`, the std of one residual component (m), weighting the prior.
    """

    mode: ResidualMode = ResidualMode.DISPLACEMENT
    solver: Solver = Solver.GAUSS_NEWTON
    param_set: ParamSet = ParamSet.MDH
    estimate_tool: bool = True
    estimate_frame: bool = True
    fixed: tuple[str, ...] = ()
    rank_tol: float = 1e-6
    max_iterations: int = 100
    xtol: float = 1e-13
    ftol: float = 1e-15
    prior_std_length: float | None = None
    prior_std_angle: float | None = None
    measurement_std: float = 1e-4

    def __post_init__(self) -> None:
        object.__setattr__(self, "mode", _enum(ResidualMode, self.mode, "mode"))
        object.__setattr__(self, "solver", _enum(Solver, self.solver, "solver"))
        object.__setattr__(self, "param_set", check_param_set(self.param_set))
        object.__setattr__(self, "fixed", tuple(self.fixed))
        if not 0.0 < self.rank_tol < 1.0:
            raise ValueError(f"rank_tol must be in (0, 1), got {self.rank_tol!r}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations!r}")
        for nm in ("prior_std_length", "prior_std_angle"):
            v = getattr(self, nm)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"{nm} must be a positive number or None, got {v!r}")
        if not (np.isfinite(self.measurement_std) and self.measurement_std > 0):
            raise ValueError(f"measurement_std must be positive, got {self.measurement_std!r}")


def _enum(cls: type[Enum], value: object, name: str) -> Enum:
    try:
        return cls(value)
    except ValueError:
        raise ValueError(f"{name} must be one of {[m.value for m in cls]}, got {value!r}") from None


# =========================================================================== result
@dataclass(frozen=True)
class IdentificationResult:
    """Outcome of :func:`identify`.

    Attributes
    ----------
    table : MDHTable
        Fitted geometry (fixed parameters at their start values).
    tool : ndarray, shape (3,)
        Fitted tool point in the last joint frame (m).
    T_meas_base : ndarray, shape (4, 4) or None
        Fitted pose of the base in the measurement frame (position mode: full;
        displacement mode: rotation only, zero translation; distance mode: None).
    free_params, fixed_params : tuple of str
        Estimated and fixed parameter names.
    fixed_reasons : dict of str to str
    deltas : dict of str to float
        Fitted minus start value of every free parameter (m or rad).
    std : dict of str to float
        Standard deviations from :math:`\\hat\\sigma^2 (J^\\top J)^{-1}`,
        :math:`\\hat\\sigma^2 = \\|e\\|^2 / (m - p)`.
    singular_values : ndarray
        Of the unit-column-scaled Jacobian of the free parameters at the solution.
    condition_number : float
        Their ratio max/min.
    unidentifiable : tuple of str
        Near-null parameter combinations found before fixing.
    rms_before, rms_after : float
        Root mean square of the per-observation residual norms (m) at the start
        and at the solution.
    iterations : int
    converged : bool
    mode : ResidualMode
    solver : Solver
    """

    table: MDHTable
    tool: FloatArray
    T_meas_base: FloatArray | None
    free_params: tuple[str, ...]
    fixed_params: tuple[str, ...]
    fixed_reasons: dict[str, str]
    deltas: dict[str, float]
    std: dict[str, float]
    singular_values: FloatArray
    condition_number: float
    unidentifiable: tuple[str, ...]
    rms_before: float
    rms_after: float
    iterations: int
    converged: bool
    mode: ResidualMode
    solver: Solver
    residuals: FloatArray = field(repr=False, default_factory=lambda: np.zeros(0))

    def tool_positions(self, q: npt.ArrayLike) -> FloatArray:
        """Fitted tool-point positions (N, 3) in the base frame (m)."""
        return tool_positions(self.table, q, self.tool)


def _rms(r: FloatArray, n_obs: int) -> float:
    return float(np.sqrt(np.sum(r**2) / max(n_obs, 1)))


def identify(
    table: MDHTable,
    observations: PairObservations | PositionObservations,
    *,
    tool: npt.ArrayLike | None = None,
    T_meas_base: npt.ArrayLike | None = None,
    settings: IdentificationSettings | None = None,
) -> IdentificationResult:
    """Identify kinematic parameters, tool point and measurement frame.

    Parameters
    ----------
    table : MDHTable
        Start (nominal) geometry.
    observations : PairObservations or PositionObservations
        Pairs for ``distance``/``displacement`` mode, positions for ``position`` mode.
    tool : array_like, shape (3,), optional
        Start tool point in the last joint frame (m), e.g. from hand–eye; zero if omitted.
    T_meas_base : array_like, shape (4, 4), optional
        Start pose of the base in the measurement frame; when omitted it is
        fitted to the start model (Kabsch on positions, Wahba on displacements).
    settings : IdentificationSettings, optional

    Returns
    -------
    IdentificationResult

    Raises
    ------
    ValueError
        On mismatched observations, unknown fixed names, or too few observations.
    """
    s = settings or IdentificationSettings()
    mode = ResidualMode(s.mode)
    is_pos = isinstance(observations, PositionObservations)
    if is_pos != (mode is ResidualMode.POSITION):
        raise ValueError(
            f"mode {mode.value!r} needs "
            f"{'PositionObservations' if mode is ResidualMode.POSITION else 'PairObservations'},"
            f" got {type(observations).__name__}"
        )
    n = table.n_joints
    tool0 = np.zeros(3) if tool is None else check_finite("tool", tool, (3,))
    all_names = set(table.param_names()) | set(TOOL_PARAM_NAMES) | set(FRAME_PARAM_NAMES)
    for nm in s.fixed:
        if nm not in all_names:
            close = difflib.get_close_matches(nm, sorted(all_names), n=3)
            raise ValueError(f"unknown parameter {nm!r} in fixed; did you mean {close}?")

    # ---- start frame
    if isinstance(observations, PositionObservations):
        check_joint_angles(observations.q, n)
        p_start = tool_positions(table, observations.q, tool0)
        T0 = kabsch(p_start, observations.positions)
    else:
        check_joint_angles(observations.q_from, n)
        d_start = tool_positions(table, observations.q_to, tool0) - tool_positions(
            table, observations.q_from, tool0
        )
        T0 = np.eye(4)
        if mode is ResidualMode.DISPLACEMENT:
            T0[:3, :3] = wahba(d_start, observations.displacement)
    if T_meas_base is not None:
        T0 = check_finite("T_meas_base", T_meas_base, (4, 4))
    R0, t0 = T0[:3, :3].copy(), T0[:3, 3].copy()

    # ---- candidate parameters in order of preference
    kin_all = [nm for nm in table.param_names(s.param_set) if nm not in s.fixed]
    kin_pref = preference_order(table, kin_all)
    tool_c = [nm for nm in TOOL_PARAM_NAMES if s.estimate_tool and nm not in s.fixed]
    if mode is ResidualMode.POSITION and s.estimate_frame:
        frame_c = [nm for nm in FRAME_PARAM_NAMES if nm not in s.fixed]
    elif mode is ResidualMode.DISPLACEMENT and s.estimate_frame:
        frame_c = [nm for nm in FRAME_PARAM_NAMES[:3] if nm not in s.fixed]
    else:
        frame_c = []
    cand = ParameterLayout(tuple(kin_pref), tuple(tool_c), tuple(frame_c))
    model_c = ResidualModel(table, tool0, R0, t0, observations, mode, cand)
    r0, J0 = model_c.residual(model_c.start())
    assert J0 is not None
    order = list(cand.frame_names) + list(cand.tool_names) + list(cand.kin_names)
    col = {nm: k for k, nm in enumerate(cand.names)}
    ana = analyse_identifiability(J0[:, [col[nm] for nm in order]], order, s.rank_tol)
    free = set(ana.free)
    layout = ParameterLayout(
        tuple(nm for nm in table.param_names() if nm in free and nm in cand.kin_names),
        tuple(nm for nm in TOOL_PARAM_NAMES if nm in free),
        tuple(nm for nm in FRAME_PARAM_NAMES if nm in free),
    )
    p = len(layout.names)
    n_obs = observations.n
    if r0.size <= p:
        raise ValueError(
            f"{r0.size} residuals cannot determine {p} identifiable parameters with any "
            "redundancy; add observations"
        )
    model = ResidualModel(table, tool0, R0, t0, observations, mode, layout)
    u0 = model.start()
    if s.prior_std_length is not None or s.prior_std_angle is not None:
        wts = np.zeros(p)
        for k, nm in enumerate(layout.kin_names):
            kind = nm.rstrip("0123456789")
            std_k = s.prior_std_length if kind in ("d", "a") else s.prior_std_angle
            if std_k is not None:
                wts[k] = s.measurement_std / std_k
        model.set_prior(wts)

    # ---- solve
    if s.solver is Solver.GAUSS_NEWTON:
        u, iterations, converged = _gauss_newton(model, u0, s)
    else:
        sol = least_squares(
            lambda x: model.residual(x, with_jac=False)[0],
            u0,
            jac=lambda x: model.residual(x)[1],
            method=s.solver.value,
            xtol=max(s.xtol, 1e-15),
            ftol=max(s.ftol, 1e-15),
            gtol=1e-15,
            x_scale="jac",
            max_nfev=s.max_iterations * 10,
        )
        u, iterations, converged = sol.x, int(sol.nfev), bool(sol.success)
    r, J = model.data_residual(u)  # data rows only (no prior)
    assert J is not None
    table_f, tool_f, R_f, t_f, _ = model.unpack(u)

    # ---- statistics
    norms = column_norms(J)
    norms[norms == 0] = 1.0
    sv = singular_values(J / norms)
    cond = float(sv[0] / sv[-1]) if p and sv[-1] > 0 else float("inf")
    dof = max(r.size - p, 1)
    sigma2 = float(np.einsum("i,i->", r, r)) / dof
    if p:
        _, Rj = thin_qr(J / norms)
        _, sj, Vt = np.linalg.svd(Rj)
        inv = np.where(sj > sj[0] * 1e-14, 1.0 / np.maximum(sj, 1e-300) ** 2, 0.0)
        var = sigma2 * np.einsum("ki,k,ki->i", Vt, inv, Vt) / norms**2
    else:
        var = np.zeros(0)
    names = layout.names
    deltas = {nm: float(u[k] - u0[k]) for k, nm in enumerate(names)}
    std = {nm: float(np.sqrt(max(var[k], 0.0))) for k, nm in enumerate(names)}
    if mode is ResidualMode.DISTANCE:
        T_out = None
    else:
        T_out = np.eye(4)
        T_out[:3, :3] = R_f
        T_out[:3, 3] = t_f if mode is ResidualMode.POSITION else 0.0
    fixed_reasons = dict(ana.reasons)
    for nm in s.fixed:
        fixed_reasons[nm] = "fixed by the settings"
    fixed_all = tuple(nm for nm in ana.fixed) + tuple(s.fixed)
    return IdentificationResult(
        table=table_f,
        tool=tool_f,
        T_meas_base=T_out,
        free_params=names,
        fixed_params=fixed_all,
        fixed_reasons=fixed_reasons,
        deltas=deltas,
        std=std,
        singular_values=sv,
        condition_number=cond,
        unidentifiable=ana.combinations,
        rms_before=_rms(r0, n_obs),
        rms_after=_rms(r, n_obs),
        iterations=iterations,
        converged=converged,
        mode=mode,
        solver=s.solver,
        residuals=r,
    )


def _gauss_newton(
    model: ResidualModel, u0: FloatArray, s: IdentificationSettings
) -> tuple[FloatArray, int, bool]:
    u = u0.copy()
    r, J = model.residual(u)
    cost = float(np.einsum("i,i->", r, r))
    for it in range(1, s.max_iterations + 1):
        assert J is not None
        step = -lstsq_min_norm(J, r)  # u <- u - J^+ e
        lam = 1.0
        while True:
            u_new = u + lam * step
            r_new, _ = model.residual(u_new, with_jac=False)
            cost_new = float(np.einsum("i,i->", r_new, r_new))
            if cost_new <= cost or lam < 1e-6:
                break
            lam *= 0.5
        small_step = np.linalg.norm(lam * step) <= s.xtol * (np.linalg.norm(u) + s.xtol)
        small_gain = cost - cost_new <= s.ftol * cost
        if cost_new <= cost:
            u = u_new
            r, J = model.residual(u)
            cost = float(np.einsum("i,i->", r, r))
        if small_step or small_gain or cost == 0.0:
            return u, it, True
    return u, s.max_iterations, False
