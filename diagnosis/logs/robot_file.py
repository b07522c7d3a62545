"""A user's robot described in one file: ``--robot-file robot.yaml`` (or ``--urdf robot.urdf``).

The robot file holds what the diagnosis needs to know about a robot before it
sees a log: its kind, its nominal geometry, its encoders, its firmware limits,
and where the ground truth's tracked point sits on the body. YAML or JSON, SI
units, every key optional except ``robot``::

    robot: diffdrive            # diffdrive | skid_steer | arm
    name: my-robot
    urdf: my_robot.urdf         # nominal geometry from the URDF (keys below override it)
    wheels:
      radius: 0.035             # m (or radius_left / radius_right)
      track: 0.230              # m, between the left and right wheels' contact lines
      effective_track: 0.41     # skid_steer only, m; fitted from the logs when absent
      ticks_per_rev: 2578.33    # encoder counts per wheel revolution
    firmware:                   # the commands are requests the firmware rate-limits
      a_max: 1.0                # m/s²
      alpha_max: 4.0            # rad/s²
    ground_truth:
      tracked_point: {x: -0.20, y: 0.0, yaw: 0.0}   # m, m, rad; x ahead of the axle, y left
      uncertainty: {xy: 0.01, yaw: 0.02}            # m, rad (default 0.02 m, 0.035 rad)
    arm:                        # robot: arm
      tool: [0.0, 0.0, 0.1]     # m: the measured point in the flange (tip) frame
      noise: 2.0e-5             # m: one measurement's noise per axis
      base_link: base_link      # URDF chain ends (default: root and deepest tip)
      tip_link: tool0

:func:`load_robot_file` reads and validates it into a :class:`RobotDescription`;
:meth:`RobotDescription.read_options` gives the importer options (nominal
parameters, firmware, metadata). Unknown keys are refused with the list of
known ones, so a misspelt key is never silently ignored.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from realitygap.core.checks import load_json_or_yaml

__all__ = [
    "DEFAULT_TRUTH_UNCERTAINTY",
    "ROBOT_KINDS",
    "RobotDescription",
    "RobotFileError",
    "description_from_urdf",
    "load_robot_file",
]

ROBOT_KINDS = ("diffdrive", "skid_steer", "arm")
"""The kinds of robot a robot file describes (``skid_steer`` is diagnosed as a differential
drive whose effective track is fitted)."""

DEFAULT_TRUTH_UNCERTAINTY = {"xy": 0.02, "yaw": 0.035}
"""How far (m, rad) a declared tracked point may be from where it truly is, when the file does
not say: a marker plate measured by hand."""

MAX_FILE_BYTES = 1 << 20
"""Largest robot file read (1 MiB)."""

_KEYS: dict[str, tuple[str, ...]] = {
    "": ("robot", "name", "urdf", "wheels", "firmware", "ground_truth", "arm"),
    "wheels": (
        "radius",
        "radius_left",
        "radius_right",
        "track",
        "effective_track",
        "ticks_per_rev",
        "left_joint",
        "right_joint",
        "base_link",
    ),
    "firmware": ("a_max", "alpha_max"),
    "ground_truth": ("tracked_point", "uncertainty"),
    "ground_truth.tracked_point": ("x", "y", "yaw"),
    "ground_truth.uncertainty": ("xy", "yaw"),
    "arm": ("tool", "noise", "base_link", "tip_link", "masses", "payload_mass"),
}


_RANGES: dict[str, tuple[float, float, str]] = {
    "wheels.radius": (0.005, 1.0, "m"),
    "wheels.radius_left": (0.005, 1.0, "m"),
    "wheels.radius_right": (0.005, 1.0, "m"),
    "wheels.track": (0.05, 5.0, "m"),
    "wheels.effective_track": (0.05, 10.0, "m"),
    "wheels.ticks_per_rev": (1.0, 1e8, "ticks"),
    "firmware.a_max": (1e-3, 1e3, "m/s²"),
    "firmware.alpha_max": (1e-3, 1e4, "rad/s²"),
    "ground_truth.tracked_point.x": (-2.0, 2.0, "m"),
    "ground_truth.tracked_point.y": (-2.0, 2.0, "m"),
    "ground_truth.tracked_point.yaw": (-6.3, 6.3, "rad"),
    "ground_truth.uncertainty.xy": (0.0, 0.5, "m"),
    "ground_truth.uncertainty.yaw": (0.0, 3.15, "rad"),
    "arm.tool": (-2.0, 2.0, "m"),
    "arm.noise": (1e-7, 0.05, "m"),
    "arm.masses": (0.0, 500.0, "kg"),
    "arm.payload_mass": (0.0, 500.0, "kg"),
}
"""Physical range and unit of every number a robot file holds: a value outside is a wrong
unit or a typo (a tool offset of 100 m is 100 mm written as metres)."""

RADIUS_RATIO_MAX = 1.25
"""Largest ratio of the two wheel radii a robot file may state (a 10× ratio is a typo)."""


class RobotFileError(ValueError):
    """A robot file (or URDF) that cannot be used; the message names the file, key and fix."""


@dataclass(frozen=True)
class RobotDescription:
    """A robot as its file describes it.

    Attributes
    ----------
    kind : str
        One of :data:`ROBOT_KINDS`.
    robot : str
        The diagnosis adapter that reads its logs (``diffdrive`` for a skid-steer).
    params : dict
        Nominal parameters for ``meta["params"]`` of its logs.
    meta : dict
        Further metadata for its logs: ``firmware``, ``truth_frame`` (the declared
        tracked point and its uncertainty), ``drive_kind``, ``wheel_track``,
        ``tool`` and ``tool_noise_m`` for an arm.
    source : str
        The file(s) it was read from.
    """

    kind: str
    robot: str
    params: dict[str, Any]
    meta: dict[str, Any] = field(default_factory=dict)
    source: str = ""

    def read_options(self) -> dict[str, Any]:
        """Keyword arguments of :class:`~realitygap.diagnosis.logs.read.ReadOptions`."""
        meta = {k: v for k, v in self.meta.items() if k != "firmware"}
        return {
            "params": dict(self.params),
            "firmware": dict(self.meta["firmware"]) if "firmware" in self.meta else None,
            "meta": meta,
            "robot": self.robot,
        }


def _fail(source: str, key: str, msg: str) -> RobotFileError:
    where = f"{source}: {key}: " if key else f"{source}: "
    return RobotFileError(where + msg)


def _number(
    source: str, key: str, value: Any, *, positive: bool = False, low: float | None = None
) -> float:
    if isinstance(value, str):
        # YAML 1.1 reads '2e-05' (no dot) as text; a number written so is still a number
        try:
            value = float(value)
        except ValueError:
            raise _fail(source, key, f"expected a number, got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(source, key, f"expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise _fail(source, key, f"expected a finite number, got {value!r}")
    if positive and not v > 0:
        raise _fail(source, key, f"expected a positive number (SI units), got {value!r}")
    if low is not None and v < low:
        raise _fail(source, key, f"expected at least {low:g}, got {value!r}")
    if key in _RANGES:
        lo, hi, unit = _RANGES[key]
        if not lo <= v <= hi:
            raise _fail(
                source,
                key,
                f"{value!r} {unit} lies outside the physical range {lo:g}–{hi:g} {unit}: a "
                f"wrong unit (mm written as m?) or a typo. Fix: give {key} in {unit}",
            )
    return v


def _section(source: str, raw: Mapping[str, Any], key: str) -> dict[str, Any]:
    value = raw.get(key.rpartition(".")[2], {}) if key else raw
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise _fail(source, key, f"expected a mapping of keys, got {type(value).__name__}")
    known = _KEYS[key]
    unknown = [k for k in value if k not in known]
    if unknown:
        import difflib

        hints = []
        for u in unknown:
            close = difflib.get_close_matches(str(u), known, n=1)
            hints.append(f"{u!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        raise _fail(
            source,
            key,
            f"unknown key(s) {', '.join(hints)}; known: {', '.join(known)}",
        )
    return dict(value)


def _read_mapping(path: Path) -> dict[str, Any]:
    """The robot file's top-level mapping (:func:`~realitygap.core.checks.load_json_or_yaml`:
    a ``.json`` file as JSON, any other as YAML, plain data only)."""
    try:
        raw = load_json_or_yaml(
            path,
            "robot file",
            expect=dict,
            example="'robot: diffdrive' with a 'wheels:' section",
            max_bytes=MAX_FILE_BYTES,
        )
    except FileNotFoundError:
        raise
    except ValueError as exc:
        raise RobotFileError(str(exc)) from None
    return dict(raw)


def load_robot_file(path: str | os.PathLike[str]) -> RobotDescription:
    """Read and validate a robot file (YAML or JSON; see the module docstring).

    Raises
    ------
    FileNotFoundError
        The file (or the URDF it names) does not exist.
    RobotFileError
        A key unknown, a value of the wrong type or out of its physical range, a
        URDF that does not describe the robot; the message names the file, the
        key and the fix.
    """
    p = Path(path)
    raw = _read_mapping(p)
    src = str(p)
    top = _section(src, raw, "")
    kind = top.get("robot")
    if kind not in ROBOT_KINDS:
        raise _fail(src, "robot", f"expected one of {', '.join(ROBOT_KINDS)}, got {kind!r}")
    urdf = top.get("urdf")
    if urdf is not None and not isinstance(urdf, str):
        raise _fail(src, "urdf", f"expected a file path, got {urdf!r}")
    urdf_path = (p.parent / urdf) if urdf else None
    wheels = _section(src, raw, "wheels")
    arm = _section(src, raw, "arm")
    if urdf_path is not None:
        desc = description_from_urdf(
            urdf_path,
            kind=kind,
            left_joint=wheels.get("left_joint"),
            right_joint=wheels.get("right_joint"),
            base_link=arm.get("base_link") or wheels.get("base_link"),
            tip_link=arm.get("tip_link"),
        )
        params, meta = dict(desc.params), dict(desc.meta)
    else:
        params, meta = {}, {}
    if kind == "arm":
        if wheels:
            raise _fail(src, "wheels", "an arm has no wheels; remove the section")
        if "mdh" not in params:
            raise _fail(
                src,
                "urdf",
                "an arm's nominal geometry comes from its URDF; add 'urdf: my_arm.urdf'",
            )
        _arm_section(src, arm, params, meta)
    else:
        if arm:
            raise _fail(src, "arm", f"a {kind} has no arm section; remove it")
        _wheel_section(src, kind, wheels, params, meta)
    fw = _section(src, raw, "firmware")
    if fw:
        if kind == "arm":
            raise _fail(src, "firmware", "firmware rate limits are a wheeled robot's")
        meta["firmware"] = {
            k: _number(src, f"firmware.{k}", v, positive=True) for k, v in fw.items()
        }
    gt = _section(src, raw, "ground_truth")
    if gt:
        if kind == "arm":
            raise _fail(
                src, "ground_truth", "an arm's measured point is 'arm.tool'; remove ground_truth"
            )
        meta["truth_frame"] = _truth_frame(src, raw["ground_truth"])
    if "name" in top:
        meta["robot_name"] = str(top["name"])
    sources = [src] + ([str(urdf_path)] if urdf_path else [])
    return RobotDescription(
        kind=kind,
        robot="arm" if kind == "arm" else "diffdrive",
        params=params,
        meta=meta,
        source=", ".join(sources),
    )


def _truth_frame(src: str, gt: Mapping[str, Any]) -> dict[str, float]:
    point = _section(src, gt, "ground_truth.tracked_point")
    unc = _section(src, gt, "ground_truth.uncertainty")
    out = {
        k: _number(src, f"ground_truth.tracked_point.{k}", point.get(k, 0.0))
        for k in ("x", "y", "yaw")
    }
    for k in ("xy", "yaw"):
        out[f"sigma_{k}"] = _number(
            src,
            f"ground_truth.uncertainty.{k}",
            unc.get(k, DEFAULT_TRUTH_UNCERTAINTY[k]),
            positive=True,
        )
    if math.hypot(out["x"], out["y"]) > 2.0:
        raise _fail(
            src,
            "ground_truth.tracked_point",
            f"({out['x']:g}, {out['y']:g}) m is more than 2 m from the axle centre; give it in "
            "metres in the robot's base frame (x ahead, y left)",
        )
    if abs(out["yaw"]) > math.pi:
        raise _fail(
            src, "ground_truth.tracked_point.yaw", f"{out['yaw']:g} rad is beyond ±π; give radians"
        )
    return out


def _wheel_section(
    src: str, kind: str, wheels: Mapping[str, Any], params: dict[str, Any], meta: dict[str, Any]
) -> None:
    if "radius" in wheels and ("radius_left" in wheels or "radius_right" in wheels):
        raise _fail(src, "wheels", "give 'radius' or 'radius_left'/'radius_right', not both")
    if "radius" in wheels:
        r = _number(src, "wheels.radius", wheels["radius"], positive=True)
        params["wheel_radius_left"] = params["wheel_radius_right"] = r
    for side in ("left", "right"):
        if f"radius_{side}" in wheels:
            params[f"wheel_radius_{side}"] = _number(
                src, f"wheels.radius_{side}", wheels[f"radius_{side}"], positive=True
            )
    if "track" in wheels:
        track = _number(src, "wheels.track", wheels["track"], positive=True)
        params["wheelbase"] = track
        if kind == "skid_steer":
            meta["wheel_track"] = track
    if "ticks_per_rev" in wheels:
        params["ticks_per_rev"] = _number(
            src, "wheels.ticks_per_rev", wheels["ticks_per_rev"], positive=True
        )
    rl, rr = params.get("wheel_radius_left"), params.get("wheel_radius_right")
    if rl is not None and rr is not None and max(rl, rr) > RADIUS_RATIO_MAX * min(rl, rr):
        raise _fail(
            src,
            "wheels.radius_left/radius_right",
            f"{rl:g} m and {rr:g} m differ by {max(rl, rr) / min(rl, rr):.2g}×; real wheels of "
            f"one axle differ by a few per cent (a typo or a unit?). Fix: correct the radius",
        )
    if kind == "skid_steer":
        meta["drive_kind"] = "skid_steer"
        if "wheelbase" not in params:
            raise _fail(src, "wheels.track", "a skid-steer needs its wheel track (m) or a URDF")
        meta.setdefault("wheel_track", params["wheelbase"])
        if wheels.get("effective_track") is not None:
            eff = _number(src, "wheels.effective_track", wheels["effective_track"], positive=True)
            if eff < 0.9 * meta["wheel_track"]:
                raise _fail(
                    src,
                    "wheels.effective_track",
                    f"{eff:g} m is narrower than the wheel track {meta['wheel_track']:g} m; a "
                    "skid-steer turns as if its track were wider (wheels scrub sideways)",
                )
            params["wheelbase"] = eff
            meta["effective_track_declared"] = True
    elif "effective_track" in wheels:
        raise _fail(src, "wheels.effective_track", "only a skid_steer has an effective track")


def _arm_section(
    src: str, arm: Mapping[str, Any], params: dict[str, Any], meta: dict[str, Any]
) -> None:
    import numpy as np

    tool = np.zeros(3)
    if "tool" in arm:
        t = arm["tool"]
        if not isinstance(t, (list, tuple)) or len(t) != 3:
            raise _fail(src, "arm.tool", f"expected [x, y, z] in metres, got {t!r}")
        tool = np.array([_number(src, "arm.tool", v) for v in t])
    T = np.asarray(meta.pop("urdf_tool", np.eye(4)), dtype=float)
    meta["tool"] = (T[:3, :3] @ tool + T[:3, 3]).tolist()
    if "noise" in arm:
        meta["tool_noise_m"] = _number(src, "arm.noise", arm["noise"], positive=True)
    if "masses" in arm:
        m = arm["masses"]
        if not isinstance(m, (list, tuple)) or len(m) != len(params.get("link_masses", [])):
            raise _fail(
                src, "arm.masses", f"expected {len(params.get('link_masses', []))} link masses (kg)"
            )
        params["link_masses"] = [_number(src, "arm.masses", v, low=0.0) for v in m]
    if "payload_mass" in arm:
        params["payload_mass"] = _number(src, "arm.payload_mass", arm["payload_mass"], low=0.0)


def description_from_urdf(
    path: str | os.PathLike[str],
    *,
    kind: str | None = None,
    left_joint: str | None = None,
    right_joint: str | None = None,
    base_link: str | None = None,
    tip_link: str | None = None,
) -> RobotDescription:
    """A :class:`RobotDescription` from a URDF alone (``--urdf``): wheels → a differential
    drive or a skid-steer, else a revolute chain → an arm (``kind`` forces one)."""
    from realitygap.robots import urdf as urdf_mod

    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"URDF not found: {p}")
    if kind is not None and kind not in ROBOT_KINDS:
        raise RobotFileError(
            f"{p}: kind must be one of {', '.join(ROBOT_KINDS)}, got {kind!r}. Fix: name the "
            "kind of robot the URDF describes, or leave it out to detect it"
        )
    if kind is None and (left_joint or right_joint):
        kind_wheels: str | None = "wheels"  # wheel joints named: a wheeled robot
    else:
        kind_wheels = kind
    wheels_error = ""
    if kind_wheels in (None, "wheels", "diffdrive", "skid_steer"):
        try:
            w = urdf_mod.wheels_from_urdf(
                p, base_link=base_link, left_joint=left_joint, right_joint=right_joint
            )
        except ValueError as exc:
            if kind_wheels is not None:
                raise RobotFileError(str(exc)) from None
            wheels_error = str(exc)
        else:
            found = "skid_steer" if w.drive == "skid_steer" else "diffdrive"
            # a skid-steer may be described by a two-wheel URDF (its wheel track); a
            # differential drive cannot have two wheels per side
            if kind == "diffdrive" and found == "skid_steer":
                raise RobotFileError(
                    f"{p}: the robot file says {kind} but the URDF has {w.n_wheels} driven "
                    f"wheels ({w.drive}). Fix: 'robot: {found}'"
                )
            k = kind or found
            meta: dict[str, Any] = {}
            if k == "skid_steer":
                meta["drive_kind"] = "skid_steer"
                meta["wheel_track"] = float(w.track)
            return RobotDescription(
                kind=k, robot="diffdrive", params=dict(w.params()), meta=meta, source=str(p)
            )
    neither = f" Nor is it a wheeled robot: {wheels_error}" if wheels_error else ""
    try:
        a = urdf_mod.arm_from_urdf(p, base_link=base_link, tip_link=tip_link)
    except ValueError as exc:
        raise RobotFileError(f"{exc}.{neither}") from None
    if a.mdh.n_joints != 6:
        raise RobotFileError(
            f"{p}: the chain has {a.mdh.n_joints} revolute joints "
            f"({', '.join(a.joint_names)}); the arm diagnosis reads 6-joint arms. Fix: give "
            f"tip_link / base_link to choose a 6-joint chain.{neither}"
        )
    from realitygap.robots.arm import ArmParams, arm_params_to_meta

    masses = tuple(float(m) for m in a.masses)
    arm_params = ArmParams(
        mdh=a.mdh,
        joint_lower=tuple(a.lower),
        joint_upper=tuple(a.upper),
        link_masses=masses if len(masses) == 6 and any(masses) else ArmParams().link_masses,
    )
    params = arm_params_to_meta(arm_params)
    # the measured point defaults to the tip link's origin; a robot file's arm.tool moves it
    meta = {"urdf_tool": a.tool.tolist(), "tool": a.tool[:3, 3].tolist()}
    return RobotDescription(kind="arm", robot="arm", params=params, meta=meta, source=str(p))
