"""Five-parameter modified Denavit–Hartenberg (Hayati) kinematics of serial arms.

Every joint is revolute. Joint ``i`` (1-based) carries five geometric parameters,
the joint-angle offset :math:`\\theta_i`, the offset :math:`d_i`, the length
:math:`a_i`, and the twists :math:`\\alpha_i` and :math:`\\beta_i`. With the joint
reading :math:`q_i` the transform from frame ``i-1`` to frame ``i`` is

.. math::

    T_i = R_z(q_i + \\theta_i)\\, T_z(d_i)\\, T_x(a_i)\\, R_x(\\alpha_i)\\, R_y(\\beta_i),

so with :math:`\\beta_i = 0` it is the classical (distal) Denavit–Hartenberg
transform. The axis of joint ``i`` is the z axis of frame ``i-1``; row ``i``
therefore describes how the axis of joint ``i+1`` sits relative to the axis of
joint ``i``.

Why β: when the axes of joints ``i`` and ``i+1`` are (nominally) parallel,
:math:`\\alpha_i = 0` and the common normal is not unique, so a tiny tilt of the
real axis about the y axis makes the DH offset :math:`d_i` jump by metres. The
Hayati convention fixes :math:`d_i = 0` on such rows and lets :math:`\\beta_i`
carry the small misalignment; on rows whose axes are not parallel
:math:`\\beta_i = 0` and the model is plain DH.

The forward kinematics of ``n`` joints from a base frame to a tool frame is

.. math::

    T_{\\mathrm{base},\\mathrm{tool}}(q) = T_{\\mathrm{base}}\\, T_1(q_1) \\cdots T_n(q_n)\\,
    T_{\\mathrm{tool}}.

All lengths are in m, all angles in rad. Parameter vectors are ordered joint by
joint as ``[theta_i, d_i, a_i, alpha_i, beta_i]`` and named ``"theta1"``,
``"d1"``, …, ``"beta6"``; the tool-point translation in the last frame is
``"tool_x"``, ``"tool_y"``, ``"tool_z"``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

#: Order of the five parameters of one joint inside a parameter vector.
JOINT_PARAM_KINDS: tuple[str, ...] = ("theta", "d", "a", "alpha", "beta")
#: Names of the tool-point translation parameters (m, in the last joint frame).
TOOL_PARAM_NAMES: tuple[str, ...] = ("tool_x", "tool_y", "tool_z")

_PARALLEL_TOL = 1e-6


class ParamSet(str, Enum):
    """Which kinematic parameters a parameter vector or Jacobian covers.

    ``MDH``: all five per joint. ``DH``: the four classical ones (β held at its
    current value, normally 0), the comparison model.
    """

    MDH = "mdh"
    DH = "dh"


def _as_param_vector(name: str, value: npt.ArrayLike) -> FloatArray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"MDHTable.{name} must be numeric, got {value!r}") from exc
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"MDHTable.{name} must be a non-empty 1-D array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"MDHTable.{name} must be finite, got {arr!r}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class MDHTable:
    """Geometric parameters of an ``n``-joint revolute arm in the 5-parameter MDH form.

    Parameters
    ----------
    theta_offset : array_like, shape (n,)
        Joint-angle offsets :math:`\\theta_i` (rad), added to the joint readings.
    d : array_like, shape (n,)
        Offsets along the axis of joint ``i`` (m).
    a : array_like, shape (n,)
        Lengths of the common normals (m).
    alpha : array_like, shape (n,)
        Twists about the common normal (rad).
    beta : array_like, shape (n,)
        Hayati twists about the new y axis (rad); 0 on rows whose axes are not parallel.
    name : str
        Human-readable name.

    Notes
    -----
    Arrays are copied and made read-only. Equality compares values
    (:meth:`isclose` for a tolerance).
    """

    theta_offset: FloatArray
    d: FloatArray
    a: FloatArray
    alpha: FloatArray
    beta: FloatArray
    name: str = "arm"

    def __post_init__(self) -> None:
        n = None
        for kind in ("theta_offset", "d", "a", "alpha", "beta"):
            arr = _as_param_vector(kind, getattr(self, kind))
            if n is None:
                n = arr.size
            elif arr.size != n:
                raise ValueError(
                    f"MDHTable.{kind} has {arr.size} entries but theta_offset has {n}; "
                    "every parameter array needs one entry per joint"
                )
            object.__setattr__(self, kind, arr)

    # ------------------------------------------------------------------ basics
    @property
    def n_joints(self) -> int:
        """Number of joints ``n``."""
        return int(self.theta_offset.size)

    @property
    def parallel_rows(self) -> npt.NDArray[np.bool_]:
        """Mask (n,): row ``i`` relates (nominally) parallel axes, :math:`\\sin\\alpha_i \\approx 0`.

        On such rows :math:`d_i` is not identifiable and :math:`\\beta_i` carries the
        misalignment. The last row never relates two joint axes and is always False.
        """
        mask = np.abs(np.sin(self.alpha)) < _PARALLEL_TOL
        mask[-1] = False
        return mask

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MDHTable):
            return NotImplemented
        return self.isclose(other, atol=0.0)

    __hash__ = None  # type: ignore[assignment]

    def isclose(self, other: MDHTable, atol: float = 1e-12) -> bool:
        """True when both tables have the same joints and parameters within ``atol``."""
        if other.n_joints != self.n_joints:
            return False
        return bool(np.allclose(self.params(), other.params(), rtol=0.0, atol=atol))

    # ------------------------------------------------------- parameter vectors
    def param_names(self, which: ParamSet | str = ParamSet.MDH) -> tuple[str, ...]:
        """Names of the parameters in the vector of :meth:`params` for ``which``."""
        kinds = _kinds_for(which)
        return tuple(f"{k}{i + 1}" for i in range(self.n_joints) for k in kinds)

    def params(self, which: ParamSet | str = ParamSet.MDH) -> FloatArray:
        """Parameter vector, joint by joint ``[theta, d, a, alpha(, beta)]``, shape (4n or 5n,)."""
        kinds = _kinds_for(which)
        cols = [self._column(k) for k in kinds]
        return np.stack(cols, axis=1).reshape(-1).copy()

    def param_dict(self) -> dict[str, float]:
        """All 5n parameters by name."""
        return dict(zip(self.param_names(), self.params().tolist()))

    def with_params(self, values: npt.ArrayLike, names: Sequence[str] | None = None) -> MDHTable:
        """New table with the named parameters replaced.

        Parameters
        ----------
        values : array_like, shape (k,)
            New values (m or rad).
        names : sequence of str, optional
            Parameter names such as ``"d2"``; ``None`` means all 5n in :meth:`params` order.
        """
        vals = np.asarray(values, dtype=float).reshape(-1)
        names = self.param_names() if names is None else tuple(names)
        if vals.size != len(names):
            raise ValueError(f"got {vals.size} values for {len(names)} parameter names")
        cols = {k: self._column(k).copy() for k in JOINT_PARAM_KINDS}
        for nm, v in zip(names, vals):
            kind, idx = split_param_name(nm, self.n_joints)
            cols[kind][idx] = v
        return MDHTable(
            theta_offset=cols["theta"],
            d=cols["d"],
            a=cols["a"],
            alpha=cols["alpha"],
            beta=cols["beta"],
            name=self.name,
        )

    def dh_only(self) -> MDHTable:
        """The same table with every β set to 0 (the classical DH model)."""
        return MDHTable(
            self.theta_offset, self.d, self.a, self.alpha, np.zeros(self.n_joints), self.name
        )

    def _column(self, kind: str) -> FloatArray:
        return self.theta_offset if kind == "theta" else getattr(self, kind)

    # ----------------------------------------------------------- nominal arms
    @classmethod
    def ur10(cls) -> MDHTable:
        """Nominal Universal Robots UR10 (CB3) from its published DH table.

        ``d1 = 0.1273, a2 = -0.612, a3 = -0.5723, d4 = 0.163941, d5 = 0.1157,
        d6 = 0.0922`` m; ``alpha = [pi/2, 0, 0, pi/2, -pi/2, 0]`` rad.

        Joints 2, 3 and 4 are parallel, so rows 2 and 3 (α = 0) are MDH rows
        with β = 0 nominally and d = 0 by convention. The physical offsets of
        the shoulder, elbow and wrist-1 links along that common axis direction
        are all summed into ``d4`` (frame 4 is the first frame after the
        parallel group whose origin is well defined); this is how the published
        table already reads, so no value has to move. The flange frame is
        frame 6.
        """
        return cls(
            theta_offset=np.zeros(6),
            d=np.array([0.1273, 0.0, 0.0, 0.163941, 0.1157, 0.0922]),
            a=np.array([0.0, -0.612, -0.5723, 0.0, 0.0, 0.0]),
            alpha=np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]),
            beta=np.zeros(6),
            name="ur10",
        )

    @classmethod
    def ur_like_6dof(cls) -> MDHTable:
        """Nominal geometry of the simulated 6-DOF arm (UR5-sized, three parallel axes).

        ``d1 = 0.089159, a2 = -0.425, a3 = -0.39225, d4 = 0.10915, d5 = 0.09465,
        d6 = 0.0823`` m, twists as the UR10 (:meth:`ur10`), β = 0, offsets 0.
        """
        return cls(
            theta_offset=np.zeros(6),
            d=np.array([0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823]),
            a=np.array([0.0, -0.425, -0.39225, 0.0, 0.0, 0.0]),
            alpha=np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]),
            beta=np.zeros(6),
            name="ur_like_6dof",
        )

    @classmethod
    def franka_fr3(cls) -> MDHTable:
        """Nominal Franka FR3 / Panda, 7 joints, flange = ``panda_link8``.

        Franka publishes the model in Craig's (proximal) convention,
        :math:`{}^{i-1}T_i = R_x(\\alpha_{i-1}) T_x(a_{i-1}) R_z(q_i) T_z(d_i)`, with
        ``a = [0, 0, 0, 0.0825, -0.0825, 0, 0.088]``, ``d = [0.333, 0, 0.316, 0,
        0.384, 0, 0]``, ``alpha = [0, -pi/2, pi/2, pi/2, -pi/2, pi/2, pi/2]`` and a
        flange 0.107 m along z7. Regrouping the product (``R_x`` and ``T_x`` commute)
        gives the distal rows below, with the flange folded into ``d7``:

        ``d = [0.333, 0, 0.316, 0, 0.384, 0, 0.107]``,
        ``a = [0, 0, 0.0825, -0.0825, 0, 0.088, 0]``,
        ``alpha = [-pi/2, pi/2, pi/2, -pi/2, pi/2, pi/2, 0]``.
        """
        h = np.pi / 2
        return cls(
            theta_offset=np.zeros(7),
            d=np.array([0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.107]),
            a=np.array([0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088, 0.0]),
            alpha=np.array([-h, h, h, -h, h, h, 0.0]),
            beta=np.zeros(7),
            name="franka_fr3",
        )


# ---------------------------------------------------------------------------
def _kinds_for(which: ParamSet | str) -> tuple[str, ...]:
    mode = check_param_set(which)
    return JOINT_PARAM_KINDS if mode is ParamSet.MDH else JOINT_PARAM_KINDS[:4]


def check_param_set(which: ParamSet | str) -> ParamSet:
    """Convert ``which`` to a :class:`ParamSet`, raising ``ValueError`` on unknown names."""
    try:
        return ParamSet(which)
    except ValueError:
        raise ValueError(
            f"which must be one of {[m.value for m in ParamSet]} or a sequence of parameter "
            f"names, got {which!r}"
        ) from None


def split_param_name(name: str, n_joints: int) -> tuple[str, int]:
    """Split ``"alpha3"`` into ``("alpha", 2)`` (kind, 0-based joint index).

    Raises
    ------
    ValueError
        If the kind is unknown or the joint index is out of ``1..n_joints``.
    """
    for kind in ("theta", "alpha", "beta", "d", "a"):
        if name.startswith(kind) and name[len(kind) :].isdigit():
            idx = int(name[len(kind) :]) - 1
            if not 0 <= idx < n_joints:
                raise ValueError(
                    f"parameter {name!r} refers to joint {idx + 1}, the arm has joints "
                    f"1..{n_joints}"
                )
            return kind, idx
    raise ValueError(
        f"unknown kinematic parameter {name!r}; expected <kind><joint> with kind in "
        f"{list(JOINT_PARAM_KINDS)} (e.g. 'd2', 'beta3') or one of {list(TOOL_PARAM_NAMES)}"
    )


def check_joint_angles(q: npt.ArrayLike, n_joints: int) -> FloatArray:
    """Return joint readings as a float array of shape (N, n_joints).

    A single configuration of shape (n_joints,) becomes (1, n_joints).
    """
    try:
        arr = np.asarray(q, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"joint angles must be numeric, got {type(q).__name__}") from exc
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != n_joints:
        raise ValueError(
            f"joint angles must have shape (N, {n_joints}) or ({n_joints},), got {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError("joint angles must be finite")
    return arr


def _check_transform(name: str, T: npt.ArrayLike | None) -> FloatArray | None:
    if T is None:
        return None
    arr = np.asarray(T, dtype=float)
    if arr.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 homogeneous transform, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _joint_transforms(table: MDHTable, q: FloatArray) -> FloatArray:
    """Per-joint transforms, shape (N, n, 4, 4)."""
    th = q + table.theta_offset[None, :]
    ct, st = np.cos(th), np.sin(th)
    ca, sa = np.cos(table.alpha), np.sin(table.alpha)
    cb, sb = np.cos(table.beta), np.sin(table.beta)
    N, n = q.shape
    T = np.zeros((N, n, 4, 4))
    # Rz(th) Tz(d) Tx(a) Rx(alpha): classical DH block.
    R = np.zeros((N, n, 3, 3))
    R[..., 0, 0] = ct
    R[..., 0, 1] = -st * ca
    R[..., 0, 2] = st * sa
    R[..., 1, 0] = st
    R[..., 1, 1] = ct * ca
    R[..., 1, 2] = -ct * sa
    R[..., 2, 1] = sa
    R[..., 2, 2] = ca
    # followed by Ry(beta)
    Ry = np.zeros((n, 3, 3))
    Ry[:, 0, 0] = cb
    Ry[:, 0, 2] = sb
    Ry[:, 1, 1] = 1.0
    Ry[:, 2, 0] = -sb
    Ry[:, 2, 2] = cb
    T[..., :3, :3] = R @ Ry[None]
    T[..., 0, 3] = table.a * ct
    T[..., 1, 3] = table.a * st
    T[..., 2, 3] = table.d
    T[..., 3, 3] = 1.0
    return T


def joint_frames(
    table: MDHTable, q: npt.ArrayLike, T_base: npt.ArrayLike | None = None
) -> FloatArray:
    """Frames 0..n of the arm in the world frame for every configuration.

    Parameters
    ----------
    table : MDHTable
        Arm geometry.
    q : array_like, shape (N, n) or (n,)
        Joint readings (rad).
    T_base : array_like, shape (4, 4), optional
        Pose of frame 0 in the world frame; identity when omitted.

    Returns
    -------
    frames : ndarray, shape (N, n + 1, 4, 4)
        ``frames[:, i]`` is :math:`T_{\\mathrm{world},i}`; index 0 is the base frame.
    """
    qa = check_joint_angles(q, table.n_joints)
    Tb = _check_transform("T_base", T_base)
    Ts = _joint_transforms(table, qa)
    N, n = qa.shape
    frames = np.empty((N, n + 1, 4, 4))
    frames[:, 0] = np.eye(4) if Tb is None else Tb
    for i in range(n):
        frames[:, i + 1] = frames[:, i] @ Ts[:, i]
    return frames


def forward_kinematics(
    table: MDHTable,
    q: npt.ArrayLike,
    T_base: npt.ArrayLike | None = None,
    T_tool: npt.ArrayLike | None = None,
) -> FloatArray:
    """Tool poses :math:`T_{\\mathrm{world},\\mathrm{tool}}(q)`, vectorised over configurations.

    Parameters
    ----------
    table : MDHTable
        Arm geometry.
    q : array_like, shape (N, n) or (n,)
        Joint readings (rad).
    T_base : array_like, shape (4, 4), optional
        Pose of the arm's base frame 0 in the world frame (identity by default).
    T_tool : array_like, shape (4, 4), optional
        Pose of the tool in the last joint frame (identity: the flange).

    Returns
    -------
    T : ndarray, shape (N, 4, 4)
    """
    Tt = _check_transform("T_tool", T_tool)
    T = joint_frames(table, q, T_base)[:, -1]
    return T if Tt is None else T @ Tt


def tool_positions(
    table: MDHTable,
    q: npt.ArrayLike,
    tool: npt.ArrayLike | None = None,
    T_base: npt.ArrayLike | None = None,
) -> FloatArray:
    """Positions (N, 3) in m of the tool point ``tool`` (3,) given in the last joint frame."""
    t = np.zeros(3) if tool is None else np.asarray(tool, dtype=float).reshape(3)
    F = joint_frames(table, q, T_base)[:, -1]
    return F[:, :3, :3] @ t + F[:, :3, 3]


def resolve_param_names(
    table: MDHTable, which: ParamSet | str | Sequence[str] = ParamSet.MDH
) -> tuple[str, ...]:
    """Parameter names selected by ``which``: a :class:`ParamSet` or explicit names.

    Explicit names may include the tool-point translation (:data:`TOOL_PARAM_NAMES`).
    """
    if isinstance(which, (ParamSet, str)):
        return table.param_names(which)
    names = tuple(which)
    for nm in names:
        if nm not in TOOL_PARAM_NAMES:
            split_param_name(nm, table.n_joints)
    if len(set(names)) != len(names):
        raise ValueError(f"parameter names must be unique, got {names}")
    return names


def jacobian_params(
    table: MDHTable,
    q: npt.ArrayLike,
    which: ParamSet | str | Sequence[str] = ParamSet.MDH,
    tool: npt.ArrayLike | None = None,
    T_base: npt.ArrayLike | None = None,
) -> FloatArray:
    """Jacobian of the tool-point position with respect to kinematic parameters.

    Each elementary factor of :math:`T_i` is a screw: a rotation about a unit axis
    :math:`w` through a point :math:`o` or a translation along :math:`w`. At the tool
    point :math:`p` their derivatives are

    .. math::

        \\frac{\\partial p}{\\partial \\phi} = w \\times (p - o), \\qquad
        \\frac{\\partial p}{\\partial s} = w,

    with, for joint ``i``: :math:`\\theta_i` about :math:`z_{i-1}` through
    :math:`o_{i-1}`; :math:`d_i` along :math:`z_{i-1}`; :math:`a_i` along the x axis
    after :math:`R_z`; :math:`\\alpha_i` about that x axis and :math:`\\beta_i` about
    the following y axis, both through :math:`o_i`. The tool translation enters
    through the rotation of the last frame.

    Parameters
    ----------
    table : MDHTable
        Arm geometry at which to linearise.
    q : array_like, shape (N, n) or (n,)
        Joint readings (rad).
    which : ParamSet or str or sequence of str
        ``"mdh"`` (all 5n), ``"dh"`` (4n, no β) or explicit names, e.g.
        ``["d2", "beta2", "tool_z"]``.
    tool : array_like, shape (3,), optional
        Tool point in the last joint frame (m), zero by default.
    T_base : array_like, shape (4, 4), optional
        Pose of frame 0 in the world frame; derivatives are expressed in the world frame.

    Returns
    -------
    J : ndarray, shape (N, 3, n_params)
        m/rad for angles, m/m for lengths, columns in the order of
        :func:`resolve_param_names`.
    """
    names = resolve_param_names(table, which)
    qa = check_joint_angles(q, table.n_joints)
    t = np.zeros(3) if tool is None else np.asarray(tool, dtype=float).reshape(3)
    frames = joint_frames(table, qa, T_base)
    N = qa.shape[0]
    F_end = frames[:, -1]
    p = F_end[:, :3, :3] @ t + F_end[:, :3, 3]

    th = qa + table.theta_offset[None, :]
    ct, st = np.cos(th), np.sin(th)
    cols: dict[str, FloatArray] = {}
    wanted = set(names)
    for i in range(table.n_joints):
        F = frames[:, i]
        R = F[:, :3, :3]
        o = F[:, :3, 3]
        z = R[:, :, 2]
        # x axis after Rz(theta): R @ [c, s, 0]
        x_a = R[:, :, 0] * ct[:, i, None] + R[:, :, 1] * st[:, i, None]
        o_b = frames[:, i + 1, :3, 3]
        tag = str(i + 1)
        if "theta" + tag in wanted:
            cols["theta" + tag] = np.cross(z, p - o)
        if "d" + tag in wanted:
            cols["d" + tag] = z
        if "a" + tag in wanted:
            cols["a" + tag] = x_a
        if "alpha" + tag in wanted:
            cols["alpha" + tag] = np.cross(x_a, p - o_b)
        if "beta" + tag in wanted:
            # y axis after Rx(alpha): R_{i-1} Rz(th) Rx(alpha) e_y
            y_a = R[:, :, 1] * ct[:, i, None] - R[:, :, 0] * st[:, i, None]
            ca, sa = np.cos(table.alpha[i]), np.sin(table.alpha[i])
            y_c = ca * y_a + sa * z
            cols["beta" + tag] = np.cross(y_c, p - o_b)
    for k, nm in enumerate(TOOL_PARAM_NAMES):
        if nm in wanted:
            cols[nm] = F_end[:, :3, k]
    J = np.empty((N, 3, len(names)))
    for k, nm in enumerate(names):
        J[:, :, k] = cols[nm]
    return J
