"""An independent UR10 + laser-tracker simulator that writes the IPA UR10 accuracy format.

Plain numpy: standard Denavit–Hartenberg kinematics of a UR10 with the published
nominal parameters (Universal Robots, "DH parameters for calculations of
kinematics and dynamics"),

.. math:: T_{i-1,i} = R_z(\\theta_i)\\, T_z(d_i)\\, T_x(a_i)\\, R_x(\\alpha_i),

``d = (0.1273, 0, 0, 0.163941, 0.1157, 0.0922)`` m, ``a = (0, −0.612, −0.5723, 0, 0, 0)`` m,
``α = (π/2, 0, 0, π/2, −π/2, 0)`` rad; a probe 0.109 m along the flange z axis; a
laser tracker at a pose of our choosing, measuring the probe with Gaussian noise.

Hidden effects (:class:`ArmHidden`) act on the true joint angles, the true
geometry, the probe or the tracker; the controller reports the commanded
(nominal) joint readings.

Files, per series ``<root>/Series_<X>/``:
``measurements_<name>.csv`` — ``;``-separated, decimal comma, header ``Timestamp;Goal x;…;
measurement_rz``; ``Trafo_TM_F_init.txt`` — the flange pose in the probe frame (mm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "UR10_DH",
    "ArmHidden",
    "Tracker",
    "forward",
    "gravity_torques",
    "grid_poses",
    "measure_series",
    "random_poses",
    "write_series",
]

UR10_DH: dict[str, FloatArray] = {
    "d": np.array([0.1273, 0.0, 0.0, 0.163941, 0.1157, 0.0922]),
    "a": np.array([0.0, -0.612, -0.5723, 0.0, 0.0, 0.0]),
    "alpha": np.array([math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0]),
}
"""Published nominal standard-DH parameters of the UR10 (m, rad)."""

PROBE = np.array([0.0, 0.0, 0.109])
"""Nominal probe point in the flange frame, m."""

_MASSES = np.array([7.1, 12.7, 4.27, 2.0, 2.0, 0.365])  # kg, published link masses
_PROBE_MASS = 1.2  # kg, our assumption


def _dh(theta: float, d: float, a: float, alpha: float) -> FloatArray:
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def forward(
    q: FloatArray,
    d: FloatArray | None = None,
    a: FloatArray | None = None,
    alpha: FloatArray | None = None,
    scale: float = 1.0,
) -> list[FloatArray]:
    """Frames ``T_0i`` (i = 0…6) of joint vector ``q`` (rad); lengths scaled by ``scale``."""
    q = np.asarray(q, dtype=float)
    if q.shape != (6,):
        raise ValueError(f"q must have shape (6,), got {q.shape}")
    d = UR10_DH["d"] if d is None else d
    a = UR10_DH["a"] if a is None else a
    alpha = UR10_DH["alpha"] if alpha is None else alpha
    frames = [np.eye(4)]
    for i in range(6):
        frames.append(frames[-1] @ _dh(q[i], scale * d[i], scale * a[i], alpha[i]))
    return frames


def _probe(probe: npt.ArrayLike | None) -> FloatArray:
    """The declared probe point in the flange frame (3,), m; ``None``: :data:`PROBE`."""
    if probe is None:
        return PROBE
    p = np.asarray(probe, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)) or not 0.0 < np.linalg.norm(p) < 0.5:
        raise ValueError(
            f"probe must be a point (3,) in the flange frame within 0.5 m of the flange, m; "
            f"got {probe!r}"
        )
    return p


def gravity_torques(q: FloatArray, probe: npt.ArrayLike | None = None) -> FloatArray:
    """Holding torque of each joint (N·m) under gravity (−z): link masses at link mid-points,
    the probe mass at ``probe`` (flange frame, m; default :data:`PROBE`)."""
    frames = forward(q)
    origins = [f[:3, 3] for f in frames]
    points = [0.5 * (origins[i] + origins[i + 1]) for i in range(6)]
    masses = list(_MASSES)
    points.append((frames[6] @ np.append(_probe(probe), 1.0))[:3])
    masses.append(_PROBE_MASS)
    tau = np.zeros(6)
    force = np.array([0.0, 0.0, -9.81])
    for j in range(6):
        axis, origin = frames[j][:3, 2], frames[j][:3, 3]
        for i in range(j, 7):
            tau[j] -= axis @ np.cross(points[i] - origin, masses[i] * force)
    return tau


@dataclass(frozen=True)
class ArmHidden:
    """What the real arm and tracker do differently (all neutral by default).

    Attributes (units)
    ------------------
    zero_err : (6,) joint zero errors, true − read [rad]
    dd, da : (6,) errors of the DH lengths d and a [m]
    dalpha : (6,) errors of the DH twists [rad]
    probe_err : (3,) error of the probe point in the flange frame [m]
    flex : (6,) joint flexibility, angle per holding torque [rad/(N·m)]
    play : (6,) full backlash of each joint [rad]
    ratio_err : (6,) relative gear-ratio error, true = read·(1 + e) [1]
    eccentric : (6,) amplitude of a twice-per-turn gear error [rad]
    thermal : growth of every length per °C above 20 °C [1/K]
    tracker_cyclic : amplitude of the tracker's range error, period 0.4 m [m]
    """

    zero_err: tuple[float, ...] = (0.0,) * 6
    dd: tuple[float, ...] = (0.0,) * 6
    da: tuple[float, ...] = (0.0,) * 6
    dalpha: tuple[float, ...] = (0.0,) * 6
    probe_err: tuple[float, ...] = (0.0, 0.0, 0.0)
    flex: tuple[float, ...] = (0.0,) * 6
    play: tuple[float, ...] = (0.0,) * 6
    ratio_err: tuple[float, ...] = (0.0,) * 6
    eccentric: tuple[float, ...] = (0.0,) * 6
    thermal: float = 0.0
    tracker_cyclic: float = 0.0

    def __post_init__(self) -> None:
        for name in ("zero_err", "dd", "da", "dalpha", "flex", "play", "ratio_err", "eccentric"):
            v = getattr(self, name)
            if len(v) != 6:
                raise ValueError(f"ArmHidden.{name} needs 6 values (one per joint), got {len(v)}")
        if len(self.probe_err) != 3:
            raise ValueError(f"ArmHidden.probe_err needs 3 values, got {len(self.probe_err)}")
        if any(p < 0 for p in self.play) or any(c < 0 for c in self.flex):
            raise ValueError("ArmHidden.play and .flex must be >= 0 (a play or a flexibility)")


@dataclass(frozen=True)
class Tracker:
    """Laser-tracker pose in the robot base (rotation about z, then position) and its noise.

    Attributes
    ----------
    position : (3,) tracker origin in the robot base, m
    yaw : tracker heading about the base z axis, rad
    sigma : measurement noise per coordinate, m (one standard deviation)
    temperature_start : cell temperature at the first pose, °C
    temperature_rise : warming of the cell over a series, K
    """

    position: tuple[float, float, float] = (2.3, -1.6, -0.4)
    yaw: float = 0.55
    sigma: float = 1.5e-5
    temperature_start: float = 22.0
    temperature_rise: float = 3.0

    def __post_init__(self) -> None:
        if len(self.position) != 3 or not np.all(np.isfinite(self.position)):
            raise ValueError(f"Tracker.position needs 3 finite values (m), got {self.position!r}")
        if not 0.0 <= self.sigma < 1e-3:
            raise ValueError(
                f"Tracker.sigma is a laser tracker's noise in m, expected [0, 1e-3), "
                f"got {self.sigma!r}"
            )

    def base_to_tracker(self) -> FloatArray:
        """``T_tracker,base`` (4×4)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        T = np.eye(4)
        T[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        T[:3, 3] = self.position
        inv = np.eye(4)
        inv[:3, :3] = T[:3, :3].T
        inv[:3, 3] = -T[:3, :3].T @ T[:3, 3]
        return inv


def random_poses(n: int, rng: np.random.Generator) -> FloatArray:
    """``n`` joint vectors (rad) in a reachable, table-top part of the workspace."""
    lo = np.array([-2.6, -2.4, -2.2, -2.8, 0.4, -2.5])
    hi = np.array([-0.6, -0.6, -0.4, -0.4, 2.6, 2.5])
    return rng.uniform(lo, hi, size=(n, 6))


def grid_poses(n: int, rng: np.random.Generator) -> FloatArray:
    """``n`` joint vectors visiting a grid of shoulder/elbow values with random wrists."""
    k = max(2, int(math.ceil(n ** (1 / 3))))
    q1 = np.linspace(-2.4, -0.8, k)
    q2 = np.linspace(-2.2, -0.8, k)
    q3 = np.linspace(-2.0, -0.6, k)
    grid = np.array(np.meshgrid(q1, q2, q3, indexing="ij")).reshape(3, -1).T[:n]
    wrists = rng.uniform([-2.6, 0.5, -2.5], [-0.5, 2.5, 2.5], size=(grid.shape[0], 3))
    return np.column_stack([grid, wrists])


@dataclass(frozen=True)
class Series:
    """One simulated measurement series."""

    q_read: FloatArray
    probe_tracker: FloatArray
    rot_tracker: FloatArray
    temperature: FloatArray
    goal_pos: FloatArray
    goal_rpy: FloatArray
    extra: dict[str, float] = field(default_factory=dict)


def _true_joints(
    q: FloatArray, hidden: ArmHidden, probe: npt.ArrayLike | None = None
) -> FloatArray:
    """True joint angles behind readings ``q`` (N, 6) in visiting order (``probe``: the
    declared probe point whose mass loads the joints, m)."""
    q = np.asarray(q, dtype=float)
    out = q * (1.0 + np.asarray(hidden.ratio_err)) + np.asarray(hidden.zero_err)
    out = out + np.asarray(hidden.eccentric) * np.sin(2.0 * q)
    play = np.asarray(hidden.play)
    if np.any(play):
        # the output lags the motor by half the play against the last direction of motion;
        # the first pose is reached from the home position q = 0
        prev = np.zeros(6)
        for i in range(q.shape[0]):
            direction = np.sign(q[i] - prev)
            out[i] -= 0.5 * play * direction
            prev = q[i]
    flex = np.asarray(hidden.flex)
    if np.any(flex):
        # a compliant joint gives way to gravity: it deflects against its holding torque
        for i in range(q.shape[0]):
            out[i] -= flex * gravity_torques(out[i], probe)
    return out


def measure_series(
    q_read: FloatArray,
    hidden: ArmHidden,
    tracker: Tracker,
    rng: np.random.Generator,
    *,
    probe: npt.ArrayLike | None = None,
) -> Series:
    """Probe positions and orientations the tracker reports for readings ``q_read`` (N, 6).

    ``probe``: the declared probe point in the flange frame (m; default :data:`PROBE`);
    the hidden ``probe_err`` is added to it.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    q_read = np.asarray(q_read, dtype=float)
    n = q_read.shape[0]
    q_true = _true_joints(q_read, hidden, probe)
    temp = tracker.temperature_start + tracker.temperature_rise * np.linspace(0.0, 1.0, n)
    T_tb = tracker.base_to_tracker()
    d = UR10_DH["d"] + np.asarray(hidden.dd)
    a = UR10_DH["a"] + np.asarray(hidden.da)
    alpha = UR10_DH["alpha"] + np.asarray(hidden.dalpha)
    declared = _probe(probe)
    probe_true = declared + np.asarray(hidden.probe_err)
    pos = np.zeros((n, 3))
    rot = np.zeros((n, 3, 3))
    goal = np.zeros((n, 3))
    rpy = np.zeros((n, 3))
    for i in range(n):
        scale = 1.0 + hidden.thermal * (temp[i] - 20.0)
        T = forward(q_true[i], d, a, alpha, scale)[-1]
        p_base = T @ np.append(scale * probe_true, 1.0)
        p = (T_tb @ p_base)[:3]
        if hidden.tracker_cyclic:
            r = float(np.linalg.norm(p))
            p = p * (1.0 + hidden.tracker_cyclic * math.sin(2 * math.pi * r / 0.4) / r)
        pos[i] = p + rng.normal(0.0, tracker.sigma, 3)
        rot[i] = T_tb[:3, :3] @ T[:3, :3]
        Tn = forward(q_read[i])[-1]
        goal[i] = (Tn @ np.append(declared, 1.0))[:3]
        rpy[i] = _rpy(Tn[:3, :3])
    return Series(q_read, pos, rot, temp, goal, rpy)


def _rpy(R: FloatArray) -> FloatArray:
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    return np.array([math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])])


def _euler_xyz_deg(R: FloatArray) -> FloatArray:
    """Intrinsic X-Y-Z Euler angles (deg) of rotation ``R``: R = Rx(a) Ry(b) Rz(c)."""
    b = math.asin(max(-1.0, min(1.0, R[0, 2])))
    a = math.atan2(-R[1, 2], R[2, 2])
    c = math.atan2(-R[0, 1], R[0, 0])
    return np.degrees([a, b, c])


def _cell(x: float, digits: int = 9) -> str:
    return f"{x:.{digits}g}".replace(".", ",")


def write_series(
    root: str | Path,
    name: str,
    series: Series,
    *,
    file_stem: str = "grid",
    start_hour: int = 9,
    probe: npt.ArrayLike | None = None,
) -> Path:
    """Write ``series`` as ``<root>/Series_<name>/measurements_<file_stem>.csv`` plus the probe transform.

    ``probe``: the declared probe point in the flange frame written to
    ``Trafo_TM_F_init.txt`` (m; default :data:`PROBE`), the one the series was measured with.

    Returns
    -------
    Path
        The series folder.
    """
    if not name or not name.replace("_", "").isalnum():
        raise ValueError(f"series name must be alphanumeric (e.g. 'A'), got {name!r}")
    folder = Path(root) / f"Series_{name}"
    folder.mkdir(parents=True, exist_ok=True)
    # flange pose in the probe frame (mm): probe frame = flange frame turned 90° about z,
    # shifted along z by the probe length
    Rz = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T_fp = np.eye(4)
    T_fp[:3, :3] = Rz.T
    T_fp[:3, 3] = _probe(probe) * 1000.0
    T_pf = np.linalg.inv(T_fp)
    text = "\n".join(" ".join(f"{v:.8f}" for v in row) for row in T_pf) + "\n"
    (folder / "Trafo_TM_F_init.txt").write_text(text, encoding="utf-8")
    header = (
        "Timestamp;Goal x;Goal y;Goal z;Goal roll;Goal pitch;Goal yaw;shoulder_pan_joint;"
        "shoulder_lift_joint;elbow_joint;wrist_1_joint;wrist_2_joint;wrist_3_joint;"
        "measurement_temperature;measurement_x;measurement_y;measurement_z;measurement_rx;"
        "measurement_ry;measurement_rz"
    )
    lines = [header]
    for i in range(series.q_read.shape[0]):
        secs = start_hour * 3600 + 20 * i
        stamp = f"20240301{secs // 3600:02d}{(secs // 60) % 60:02d}{secs % 60:02d}"
        eul = _euler_xyz_deg(series.rot_tracker[i] @ Rz)
        cells = [stamp]
        cells += [_cell(v) for v in series.goal_pos[i]]
        cells += [_cell(v) for v in series.goal_rpy[i]]
        cells += [_cell(v, 12) for v in series.q_read[i]]
        cells.append(_cell(series.temperature[i]))
        cells += [_cell(1000.0 * v, 12) for v in series.probe_tracker[i]]
        cells += [_cell(v, 10) for v in eul]
        lines.append(";".join(cells))
    path = folder / f"measurements_{file_stem}.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return folder
