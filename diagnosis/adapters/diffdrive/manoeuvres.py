"""Ordinary test manoeuvres of a differential drive, as command sequences.

A :class:`Manoeuvre` is a list of segments ``(duration s, v m/s, ω rad/s)``
held in turn. With ``ramp=True`` the commands pass through the firmware's
acceleration limits (``a_max``, ``alpha_max`` of the robot), as they do in
:class:`~realitygap.envs.wheeled_nav.WheeledNavEnv`; with ``ramp=False`` they
are applied as steps (hard starts and stops).

:data:`MANOEUVRES` holds the library used by the validation suite and by the
identifiability advice ("drive X to tell A from B").
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from realitygap.robots.diffdrive import DiffDriveParams, FirmwareLimits

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "MANOEUVRES",
    "PROBE_MANOEUVRES",
    "Manoeuvre",
    "probe_description",
    "scale_speeds_in_text",
    "square",
]


@dataclass(frozen=True)
class Manoeuvre:
    """A named command sequence.

    Attributes
    ----------
    name : str
    description : str
    segments : tuple of (float, float, float)
        ``(duration, v, w)`` in s, m/s, rad/s.
    ramp : bool
        Pass the commands through the firmware's acceleration limits.
    """

    name: str
    description: str
    segments: tuple[tuple[float, float, float], ...]
    ramp: bool = True

    @property
    def duration(self) -> float:
        return float(sum(s[0] for s in self.segments))

    def within(self, v_max: float, w_max: float) -> Manoeuvre:
        """This manoeuvre scaled into a robot's speed limits.

        Every speed is multiplied by ``k_v = min(1, v_max / max|v|)`` and every
        turn rate by ``k_ω = min(1, w_max / max|ω|)``, so the ratios between the
        legs (what makes the manoeuvre informative) are kept; durations are
        unchanged. The description's speeds (numbers followed by ``m/s`` or
        ``rad/s``) are rescaled the same way.

        Parameters
        ----------
        v_max : float
            The robot's speed limit, m/s (> 0).
        w_max : float
            Its turn-rate limit, rad/s (> 0).

        Returns
        -------
        Manoeuvre
            ``self`` when it already fits.
        """
        if not (v_max > 0 and w_max > 0):
            raise ValueError(
                f"within: v_max and w_max must be positive limits (m/s, rad/s); got "
                f"v_max={v_max!r}, w_max={w_max!r}; pass the robot's DiffDriveParams limits"
            )
        peak_v = max(abs(s[1]) for s in self.segments)
        peak_w = max(abs(s[2]) for s in self.segments)
        kv = min(1.0, v_max / peak_v) if peak_v > 0 else 1.0
        kw = min(1.0, w_max / peak_w) if peak_w > 0 else 1.0
        if kv == 1.0 and kw == 1.0:
            return self
        segments = tuple((d, v * kv, w * kw) for d, v, w in self.segments)
        return replace(
            self, segments=segments, description=scale_speeds_in_text(self.description, kv, kw)
        )

    def requested(self, dt: float) -> tuple[FloatArray, FloatArray]:
        """Time stamps (N,) and requested twists (N, 2), with one rest row at each end."""
        rows = [np.zeros((1, 2))]
        for duration, v, w in self.segments:
            k = max(1, int(round(duration / dt)))
            rows.append(np.tile([v, w], (k, 1)))
        rows.append(np.zeros((1, 2)))
        cmd = np.concatenate(rows, axis=0).astype(np.float64)
        return (dt * np.arange(cmd.shape[0])).astype(np.float64), cmd

    def applied(self, dt: float, params: DiffDriveParams) -> tuple[FloatArray, FloatArray]:
        """Time stamps and the twists the drive receives (ramped if ``ramp``), (N,), (N, 2).

        The manoeuvre is first scaled into the robot's ``v_max`` and ``w_max``
        (:meth:`within`): a robot is never asked for more than it can do."""
        t, cmd = self.within(params.v_max, params.w_max).requested(dt)
        if not self.ramp:
            return t, cmd
        out = np.empty_like(cmd)
        v = w = 0.0
        firmware = FirmwareLimits(a_max=params.a_max, alpha_max=params.alpha_max)
        for k in range(cmd.shape[0]):
            v, w = firmware.limit(float(cmd[k, 0]), float(cmd[k, 1]), v, w, dt)
            out[k] = v, w
        return t, out


_SPEEDS = re.compile(r"((?:\d+(?:\.\d+)?(?:, | and | or ))*\d+(?:\.\d+)?) ?(m/s|rad/s)")


def scale_speeds_in_text(text: str, kv: float, kw: float) -> str:
    """Rescale the speeds a description states: numbers (or lists of them) before
    ``m/s`` by ``kv`` and before ``rad/s`` by ``kw``."""

    def one(m: re.Match[str]) -> str:
        k = kv if m.group(2) == "m/s" else kw
        nums = re.sub(r"\d+(?:\.\d+)?", lambda n: f"{float(n.group(0)) * k:.2g}", m.group(1))
        return m.group(0).replace(m.group(1), nums, 1)

    return _SPEEDS.sub(one, text)


def square(name: str, side: float, v: float, w: float, clockwise: bool) -> Manoeuvre:
    """A square of side ``side`` m driven at ``v`` m/s with in-place turns at ``w`` rad/s."""
    sign = -1.0 if clockwise else 1.0
    seg: list[tuple[float, float, float]] = []
    for _ in range(4):
        seg += [
            (side / v, v, 0.0),
            (0.5, 0.0, 0.0),
            (0.5 * math.pi / w, 0.0, sign * w),
            (0.5, 0, 0),
        ]
    direction = "clockwise" if clockwise else "counter-clockwise"
    return Manoeuvre(name, f"{side} m square, {direction}, turning in place", tuple(seg))


MANOEUVRES: dict[str, Manoeuvre] = {
    m.name: m
    for m in (
        Manoeuvre(
            "straight_runs",
            "straight runs forward at 0.3, 0.65 and 0.05 m/s and backward, with stops",
            (
                (3.0, 0.3, 0.0),
                (1.0, 0.0, 0.0),
                (3.0, 0.65, 0.0),
                (1.0, 0.0, 0.0),
                (4.0, 0.05, 0.0),
                (1.0, 0.0, 0.0),
                (2.0, -0.3, 0.0),
                (1.0, 0.0, 0.0),
            ),
        ),
        Manoeuvre(
            "turns_in_place",
            "turning in place both ways, fast (1.5 rad/s) and slow (0.4 rad/s)",
            (
                (2.5, 0.0, 1.5),
                (1.0, 0.0, 0.0),
                (2.5, 0.0, -1.5),
                (1.0, 0.0, 0.0),
                (3.0, 0.0, 0.4),
                (1.0, 0.0, 0.0),
                (3.0, 0.0, -0.4),
                (1.0, 0.0, 0.0),
            ),
        ),
        Manoeuvre(
            "arcs",
            "arcs to the left and right at two curvatures",
            (
                (3.0, 0.3, 0.8),
                (1.0, 0.0, 0.0),
                (3.0, 0.3, -0.8),
                (1.0, 0.0, 0.0),
                (3.0, 0.5, 0.4),
                (3.0, 0.5, -0.4),
                (1.0, 0.0, 0.0),
            ),
        ),
        Manoeuvre(
            "accelerations",
            "hard starts and stops (step commands) straight and turning",
            (
                (1.5, 0.4, 0.0),
                (1.0, 0.0, 0.0),
                (1.5, 0.6, 0.0),
                (1.0, 0.0, 0.0),
                (1.0, 0.0, 1.5),
                (1.0, 0.0, 0.0),
                (1.5, -0.4, 0.0),
                (1.0, 0.0, 0.0),
                (1.0, 0.2, 0.0),
                (1.0, 0.0, 0.0),
            ),
            ramp=False,
        ),
        square("square_cw", 0.8, 0.25, 0.8, clockwise=True),
        square("square_ccw", 0.8, 0.25, 0.8, clockwise=False),
        Manoeuvre(
            "tour",
            "a mixed path: cruising, creeping, a fast leg, arcs both ways, a hard stop",
            (
                (2.0, 0.35, 0.0),
                (2.0, 0.3, 0.6),
                (2.0, 0.3, -0.6),
                (2.5, 0.06, 0.0),
                (1.0, 0.0, 0.0),
                (2.0, 0.6, 0.0),
                (1.5, 0.0, 0.0),
                (1.5, 0.0, 1.0),
                (1.5, 0.0, -0.3),
                (2.0, -0.2, 0.0),
                (1.0, 0.0, 0.0),
            ),
        ),
        Manoeuvre(
            "circle_ccw",
            "a full counter-clockwise circle (0.3 m/s, 0.5 rad/s)",
            ((12.6, 0.3, 0.5), (1.0, 0.0, 0.0)),
        ),
        Manoeuvre(
            "circle_cw",
            "a full clockwise circle (0.3 m/s, −0.5 rad/s)",
            ((12.6, 0.3, -0.5), (1.0, 0.0, 0.0)),
        ),
        Manoeuvre(
            "straight_fast",
            "a straight run at 0.65 m/s",
            ((4.0, 0.65, 0.0), (1.0, 0.0, 0.0)),
        ),
        Manoeuvre(
            "straight_slow",
            "a straight creep at 0.04 m/s",
            ((6.0, 0.04, 0.0), (1.0, 0.0, 0.0)),
        ),
        Manoeuvre(
            "turn_ccw",
            "turning in place counter-clockwise at 1 rad/s",
            ((3.0, 0.0, 1.0), (1.0, 0.0, 0.0)),
        ),
        Manoeuvre(
            "turn_cw",
            "turning in place clockwise at 1 rad/s",
            ((3.0, 0.0, -1.0), (1.0, 0.0, 0.0)),
        ),
        Manoeuvre(
            "straight_medium",
            "a straight run at 0.3 m/s",
            ((4.0, 0.3, 0.0), (1.0, 0.0, 0.0)),
        ),
        Manoeuvre(
            "hard_starts",
            "hard starts and stops at 0.3 m/s and 0.6 m/s (step commands)",
            ((1.0, 0.3, 0.0), (1.0, 0.0, 0.0), (1.0, 0.6, 0.0), (1.0, 0.0, 0.0)),
            ramp=False,
        ),
    )
}
"""The manoeuvre library, by name."""

PROBE_MANOEUVRES: tuple[str, ...] = (
    "straight_medium",
    "straight_fast",
    "straight_slow",
    "turn_ccw",
    "turn_cw",
    "circle_ccw",
    "circle_cw",
    "hard_starts",
)
"""Short single-purpose manoeuvres proposed to separate confounded effects."""


def probe_description(name: str, params: DiffDriveParams) -> str:
    """The description of the library manoeuvre ``name`` scaled into the speed limits of the
    robot ``params`` (:meth:`Manoeuvre.within`; unchanged where it states no ``v_max`` or
    ``w_max``), as :meth:`Manoeuvre.applied` drives it."""
    man = MANOEUVRES[name]
    v_max, w_max = params.v_max, params.w_max
    if v_max and w_max:
        return man.within(float(v_max), float(w_max)).description
    return man.description
