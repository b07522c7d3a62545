"""One recorded episode, :class:`Log`, and its on-disk format.

A log holds a time base ``t`` (N,) in s and named *channels*, each an
``(N, k)`` float array sampled on that time base, with a unit per column and a
*role*: what the robot was told (``command``), what its sensors reported
(``sensor``), where it really was (``truth``, e.g. motion capture) and what its
estimator believed (``estimate``). Metadata (nominal robot parameters,
firmware limits, provenance) is a JSON-able dict.

Standard channels of a differential drive
-----------------------------------------

==========  ==================  ==========================  ========  =====================================
channel     columns             units                       role      meaning
==========  ==================  ==========================  ========  =====================================
``cmd``     v, w                m/s, rad/s                  command   body twist issued at ``t[k]``, held
                                                                      until ``t[k+1]`` (zero-order hold)
``ticks``   left, right         count, count                sensor    cumulative encoder counts at ``t[k]``
``pose_gt`` x, y, theta         m, m, rad                   truth     base pose in the world (continuous θ)
``pose_est`` x, y, theta        m, m, rad                   estimate  the robot's own estimate of it
``pose_cam`` x, y, theta        m, m, rad                   sensor    planar pose of the camera (optical
                                                                      centre, optical-axis heading) from a
                                                                      camera localisation
==========  ==================  ==========================  ========  =====================================

Standard channels of an arm (one row per measurement pose, the arm at rest)
-------------------------------------------------------------------------------

============  ==================  =========  ========  ==========================================
channel       columns             units      role      meaning
============  ==================  =========  ========  ==========================================
``joints``    q1 … q6             rad        sensor    joint encoder readings
``tool_pos``  x, y, z             m          truth     tool point measured by an external
                                                       instrument (laser tracker) in its frame
============  ==================  =========  ========  ==========================================

Standard channels of a climber (at the tether rate)
---------------------------------------------------

============  ==========================  ==============  ========  ===========================
channel       columns                     units           role      meaning
============  ==========================  ==============  ========  ===========================
``pose3_gt``  x, y, z, rx, ry, rz         m ×3, rad ×3    truth     body pose (rotation vector)
``tether``    length                      m               sensor    spool reading
============  ==========================  ==============  ========  ===========================

Other channels may be stored with any units; the standard ones must use the
units above (importers convert).

Metadata keys used by the diagnosis
-----------------------------------
``robot``
    Robot kind, ``"diffdrive"``, ``"arm"`` or ``"climber"``.
``params``
    Nominal robot parameters in SI units (for a differential drive the fields
    of :class:`~realitygap.robots.diffdrive.DiffDriveParams`, at least
    ``wheel_radius_left``, ``wheel_radius_right``, ``wheelbase``,
    ``ticks_per_rev``).
``firmware``
    Optional ``{"a_max": m/s², "alpha_max": rad/s²}``: the ``cmd`` channel then
    holds *requested* twists that the robot's firmware rate-limits before use;
    without it ``cmd`` holds the twists actually applied.
``sim``
    For simulated logs, ``{"physics_hz", "solver_iterations"}`` of the
    simulation that produced it (a replay uses the same).

On-disk format (``.npz``)
-------------------------
One NumPy zip archive, read with ``allow_pickle=False``:

* ``t`` — float64 (N,);
* ``ch.<name>`` — float64 (N, k) per channel;
* ``meta.json`` — uint8 (M,), the UTF-8 bytes of a JSON object
  ``{"format": "realitygap-log", "version": 1, "channels": {name: {"columns",
  "units", "role", "description"}}, "meta": {...}, "source": str}``.

:meth:`Log.save` writes it atomically (temporary file in the same folder,
then :func:`os.replace`), so a failed save never leaves a partial file.
Nothing is ever unpickled.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from realitygap.core.checks import check_regular_file
from realitygap.core.io import atomic_write
from realitygap.diagnosis.logs.channels import ChannelSpec, Role, standard_channels
from realitygap.diagnosis.logs.schema import SchemaError, as_real, clock_resets

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ChannelSpec",
    "Log",
    "LogError",
    "Role",
    "convert_units",
    "fill_gaps",
    "known_units",
    "sniff_file_kind",
    "standard_channels",
]

FORMAT_NAME = "realitygap-log"
FORMAT_VERSION = 1


class LogError(ValueError):
    """A log (or the file it came from) is not usable; the message names file, channel and fix."""


# unit → (SI unit, factor to SI)
_UNITS: dict[str, tuple[str, float]] = {
    "s": ("s", 1.0),
    "ms": ("s", 1e-3),
    "us": ("s", 1e-6),
    "µs": ("s", 1e-6),
    "ns": ("s", 1e-9),
    "m": ("m", 1.0),
    "cm": ("m", 1e-2),
    "mm": ("m", 1e-3),
    "m/s": ("m/s", 1.0),
    "cm/s": ("m/s", 1e-2),
    "mm/s": ("m/s", 1e-3),
    "km/h": ("m/s", 1.0 / 3.6),
    "rad": ("rad", 1.0),
    "deg": ("rad", math.pi / 180.0),
    "rad/s": ("rad/s", 1.0),
    "deg/s": ("rad/s", math.pi / 180.0),
    "count": ("count", 1.0),
    "1": ("1", 1.0),
}


def known_units() -> frozenset[str]:
    """The units :func:`convert_units` knows."""
    return frozenset(_UNITS)


def convert_units(values: npt.ArrayLike, unit: str, to: str, *, what: str = "value") -> FloatArray:
    """Convert ``values`` from ``unit`` to ``to`` (both from the table of known units).

    Raises
    ------
    LogError
        Unknown unit or incompatible dimensions (e.g. ``mm`` to ``rad/s``).
    """
    arr = np.asarray(values, dtype=float)
    if unit == to:
        return arr
    for u in (unit, to):
        if u not in _UNITS:
            raise LogError(f"{what}: unknown unit {u!r}; known units: {', '.join(sorted(_UNITS))}")
    si_from, f_from = _UNITS[unit]
    si_to, f_to = _UNITS[to]
    if si_from != si_to:
        raise LogError(
            f"{what}: cannot convert {unit!r} to {to!r} (a {si_from} quantity is not a {si_to} "
            "quantity); check the column map"
        )
    inverse = f_to / f_from
    if inverse > 1.0 and inverse == round(inverse):
        # mm → m: dividing by the exact 1000 rounds once; multiplying by 0.001 (not exact in
        # binary) can differ from it in the last bit
        return arr / inverse
    return arr * (f_from / f_to)


def sniff_file_kind(path: str | os.PathLike[str]) -> str:
    """What a file really is, from its first bytes (not its extension).

    Returns one of ``"npz"`` (zip archive), ``"npy"``, ``"rosbag1"``,
    ``"sqlite"`` (ROS 2 ``.db3``), ``"mcap"``, ``"pickle"``, ``"text"``,
    ``"binary"``, ``"empty"`` or ``"directory"``.
    """
    p = Path(path)
    if p.is_dir():
        return "directory"
    with open(p, "rb") as fh:
        head = fh.read(4096)
    if not head:
        return "empty"
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return "npz"
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head.startswith(b"#ROSBAG"):
        return "rosbag1"
    if head.startswith(b"SQLite format 3"):
        return "sqlite"
    if head.startswith(b"\x89MCAP"):
        return "mcap"
    if head[:1] == b"\x80" and len(head) > 1 and head[1] in range(2, 6):
        return "pickle"
    if b"\x00" in head:
        return "binary"
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # not just a multi-byte character cut at 4096
            try:
                head.decode("latin-1")
            except UnicodeDecodeError:  # pragma: no cover - latin-1 decodes anything
                return "binary"
            return "text"
    return "text"


def _where(source: str) -> str:
    return f"{source}: " if source else ""


@dataclass(frozen=True, eq=False)
class Log:
    """One recorded episode (see the module docstring for channels and format).

    Parameters
    ----------
    t : array_like, shape (N,)
        Time stamps, s, strictly increasing (``datetime64`` stamps are converted to POSIX
        seconds, ``timedelta64`` ones to seconds).
    channels : mapping of str to array_like, shape (N, k) or (N,)
        Channel values, real numbers (float or integer arrays; booleans, complex numbers,
        text, objects and dates are refused by their dtype, see
        :mod:`~realitygap.diagnosis.logs.schema`); a 1-D array is one column.
    specs : mapping of str to ChannelSpec, optional
        Columns, units and role of non-standard channels (standard ones are
        known); a standard channel given with other units is an error.
    meta : mapping, optional
        JSON-able metadata.
    source : str
        Where the log came from (file, bag, simulation); used in messages.

    Raises
    ------
    LogError
        Non-monotonic (a clock reset named as such) or non-finite time, a channel of a dtype
        its schema refuses, a channel of the wrong length or
        column count, NaN/inf values, a standard channel in other units, or
        metadata that is not JSON-able. The message names the file (``source``),
        the channel and the fix.
    """

    t: FloatArray
    channels: Mapping[str, FloatArray]
    specs: Mapping[str, ChannelSpec] = field(default_factory=dict)
    meta: Mapping[str, Any] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        where = _where(self.source)
        if not isinstance(self.channels, Mapping):
            raise LogError(
                f"{where}channels must be a mapping of channel name → (N, k) array (e.g. "
                f"{{'pose_gt': poses}}), got {type(self.channels).__name__}"
            )
        if not isinstance(self.meta, Mapping):
            raise LogError(f"{where}meta must be a mapping, got {type(self.meta).__name__}")
        try:
            t = as_real(self.t, "t", where)
        except SchemaError as exc:
            raise LogError(str(exc)) from None
        except (TypeError, ValueError) as exc:
            raise LogError(f"{where}time stamps must be numbers ({exc})") from None
        if t.ndim != 1 or t.shape[0] < 2:
            raise LogError(
                f"{where}time must be a 1-D array of at least 2 samples, got shape {t.shape}"
            )
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise LogError(
                f"{where}time stamp at row {bad[0]} is {t[bad[0]]!r}; every time stamp must be "
                "finite. Fix: drop those rows or repair the time column"
            )
        step = np.diff(t)
        if np.any(step <= 0):
            resets, _ = clock_resets(t)
            if resets:
                i = resets[0]
                raise LogError(
                    f"{where}the clock was reset at sample {i}: time goes from "
                    f"{t[i - 1]:.6g} s back to {t[i]:.6g} s. Fix: split the log there "
                    f"(log pieces of rows 0..{i - 1} and {i}.., e.g. Log.slice), or read the file "
                    "with read_logs, whose table reader splits a recording at its clock resets"
                )
            i = int(np.flatnonzero(step <= 0)[0]) + 1
            raise LogError(
                f"{where}time stamps must increase strictly, but row {i} (t={t[i]:.6g} s) "
                f"follows row {i - 1} (t={t[i - 1]:.6g} s). Fix: sort the rows by time and "
                "drop repeated samples"
            )
        t.flags.writeable = False
        object.__setattr__(self, "t", t)
        specs: dict[str, ChannelSpec] = {}
        chans: dict[str, FloatArray] = {}
        given = dict(self.specs)
        for name, values in self.channels.items():
            spec = given.pop(name, None)
            std = standard_channels().get(name)
            if spec is None:
                if std is None:
                    raise LogError(
                        f"{where}channel {name!r} is not a standard channel "
                        f"({', '.join(standard_channels())}); give its ChannelSpec (columns, units)"
                    )
                spec = std
            elif std is not None:
                if spec.columns != std.columns:
                    raise LogError(
                        f"{where}channel {name!r} must have columns {std.columns}, got "
                        f"{spec.columns}"
                    )
                for col, u, u_std in zip(spec.columns, spec.units, std.units):
                    if u != u_std:
                        raise LogError(
                            f"{where}channel {name!r} column {col!r} is in {u!r} but logs store "
                            f"{u_std!r}. Fix: convert it (importers take a unit per column, e.g. "
                            f"'{name}.{col}=COLUMN:{u}', and convert to {u_std!r})"
                        )
                spec = std
            try:
                arr = as_real(values, name, where)
            except SchemaError as exc:
                raise LogError(str(exc)) from None
            except (TypeError, ValueError) as exc:
                raise LogError(f"{where}channel {name!r} must be numeric ({exc})") from None
            if arr.ndim == 1:
                arr = arr[:, None]
            if arr.ndim != 2 or arr.shape != (t.shape[0], len(spec.columns)):
                raise LogError(
                    f"{where}channel {name!r} must have shape ({t.shape[0]}, "
                    f"{len(spec.columns)}) (one row per time stamp, columns {spec.columns}), "
                    f"got {arr.shape}"
                )
            finite = np.isfinite(arr)
            if not finite.all():
                row, col_index = (int(v) for v in np.argwhere(~finite)[0])
                count = int((~finite).sum())
                raise LogError(
                    f"{where}channel {name!r} column {spec.columns[col_index]!r} has {count} NaN/inf "
                    f"value(s), the first at row {row} (t={t[row]:.6g} s). Fix: drop those rows or "
                    "fill the gaps (log.fill_gaps, or the importer option nan='interpolate')"
                )
            arr.flags.writeable = False
            chans[name] = arr
            specs[name] = spec
        if given:
            raise LogError(f"{where}specs given for absent channel(s) {sorted(given)}")
        try:
            json.dumps(dict(self.meta))
        except (TypeError, ValueError) as exc:
            raise LogError(f"{where}metadata must be JSON-able ({exc})") from None
        object.__setattr__(self, "channels", chans)
        object.__setattr__(self, "specs", specs)
        object.__setattr__(self, "meta", json.loads(json.dumps(dict(self.meta))))

    # ------------------------------------------------------------------ access
    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.shape[0])

    @property
    def dt(self) -> float:
        """Median time step, s."""
        return float(np.median(np.diff(self.t)))

    @property
    def duration(self) -> float:
        """``t[-1] − t[0]``, s."""
        return float(self.t[-1] - self.t[0])

    @property
    def name(self) -> str:
        """``meta["name"]`` or the source."""
        return str(self.meta.get("name", self.source or "log"))

    def has(self, channel: str) -> bool:
        """Whether the log holds ``channel``."""
        return channel in self.channels

    def __getitem__(self, channel: str) -> FloatArray:
        if channel not in self.channels:
            raise KeyError(
                f"{_where(self.source)}no channel {channel!r}; the log has "
                f"{', '.join(self.channels) or 'no channels'}"
            )
        return self.channels[channel]

    def require(self, channels: Iterable[str], purpose: str) -> None:
        """Raise :class:`LogError` naming the missing channels, the purpose and the fix."""
        missing = [c for c in channels if c not in self.channels]
        if missing:
            raise LogError(
                f"{_where(self.source)}missing channel(s) {', '.join(map(repr, missing))} needed "
                f"for {purpose}; the log has {', '.join(self.channels) or 'no channels'}. Fix: map "
                "them in the importer (e.g. --columns for CSV, --truth-topic for bags) or choose "
                "another replay drive"
            )

    def check_uniform(self, max_jitter: float = 0.25) -> float:
        """Check the time steps are regular and return the median step (s).

        Raises
        ------
        LogError
            If some step differs from the median by more than ``max_jitter``
            times the median (jittery or gappy stamps), with the fix.
        """
        step = np.diff(self.t)
        med = float(np.median(step))
        dev = np.abs(step - med)
        worst = int(np.argmax(dev))
        if dev[worst] > max_jitter * med:
            raise LogError(
                f"{_where(self.source)}time stamps are irregular: step {worst} is "
                f"{step[worst] * 1e3:.3g} ms against a median of {med * 1e3:.3g} ms (more than "
                f"{max_jitter:.0%} off; {int((dev > max_jitter * med).sum())} such steps). Fix: "
                f"resample to a fixed step (Log.resampled(dt), CLI --resample {med:.3g})"
            )
        return med

    def spec(self, channel: str) -> ChannelSpec:
        """The :class:`ChannelSpec` of ``channel``."""
        self[channel]
        return self.specs[channel]

    # ------------------------------------------------------------------ derived logs
    def replace(
        self,
        *,
        t: npt.ArrayLike | None = None,
        channels: Mapping[str, npt.ArrayLike] | None = None,
        meta: Mapping[str, Any] | None = None,
        source: str | None = None,
        specs: Mapping[str, ChannelSpec] | None = None,
    ) -> Log:
        """A new log with some parts replaced (channels replace the whole set)."""
        chans: dict[str, Any] = dict(self.channels if channels is None else channels)
        all_specs = dict(self.specs)
        all_specs.update(specs or {})
        return Log(
            t=self.t if t is None else np.asarray(t, dtype=float),
            channels=chans,
            specs={k: v for k, v in all_specs.items() if k in chans},
            meta=self.meta if meta is None else meta,
            source=self.source if source is None else source,
        )

    def with_channels(self, specs: Mapping[str, ChannelSpec] | None = None, **new: Any) -> Log:
        """A new log with channels added or replaced."""
        chans = dict(self.channels)
        chans.update(new)
        return self.replace(channels=chans, specs=specs)

    def without(self, *names: str) -> Log:
        """A new log without the named channels."""
        return self.replace(channels={k: v for k, v in self.channels.items() if k not in names})

    def slice(self, start: int, stop: int) -> Log:
        """Rows ``start:stop`` as a new log."""
        return self.replace(
            t=self.t[start:stop], channels={k: v[start:stop] for k, v in self.channels.items()}
        )

    def interpolated(self, t_new: npt.ArrayLike, *, hold: Iterable[str] = ("cmd",)) -> Log:
        """Channels evaluated at new times: linear (angles unwrapped), zero-order hold for ``hold``.

        Times outside the log are clamped to the first / last sample.
        """
        t_new = np.asarray(t_new, dtype=float)
        hold = set(hold)
        out: dict[str, FloatArray] = {}
        for name, arr in self.channels.items():
            spec = self.specs[name]
            if name in hold or spec.role is Role.COMMAND:
                idx = np.clip(np.searchsorted(self.t, t_new, side="right") - 1, 0, self.n - 1)
                out[name] = arr[idx]
                continue
            cols = []
            for j in range(arr.shape[1]):
                col = np.unwrap(arr[:, j]) if j in spec.angle_columns else arr[:, j]
                cols.append(np.interp(t_new, self.t, col))
            out[name] = np.column_stack(cols)
        return self.replace(t=t_new, channels=out)

    def resampled(self, dt: float) -> Log:
        """Resample to a fixed step ``dt`` (s) from ``t[0]`` (see :meth:`interpolated`)."""
        if not (dt > 0 and math.isfinite(dt)):
            raise LogError(f"resampling step must be a positive number of seconds, got {dt!r}")
        n = int(math.floor(self.duration / dt + 1e-9)) + 1
        return self.interpolated(self.t[0] + dt * np.arange(n))

    # ------------------------------------------------------------------ comparison
    def equals(self, other: Log) -> bool:
        """Exact equality of time, channels (values, columns, units, role), metadata and source."""
        if not isinstance(other, Log):
            return False
        if self.source != other.source or self.meta != other.meta:
            return False
        if not np.array_equal(self.t, other.t) or set(self.channels) != set(other.channels):
            return False
        return all(
            np.array_equal(self.channels[k], other.channels[k]) and self.specs[k] == other.specs[k]
            for k in self.channels
        )

    # ------------------------------------------------------------------ disk
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the log as ``.npz`` (see the module docstring), atomically."""
        from realitygap.core.checks import check_output_path

        path = check_output_path(path, "path")
        header = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "channels": {k: self.specs[k].to_dict() for k in self.channels},
            "meta": dict(self.meta),
            "source": self.source,
        }
        meta_bytes = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
        arrays: dict[str, np.ndarray] = {"t": np.asarray(self.t), "meta.json": meta_bytes}
        for k, v in self.channels.items():
            arrays[f"ch.{k}"] = np.asarray(v)

        def write(fh: IO[bytes]) -> None:
            np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]

        return atomic_write(path, write)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Log:
        """Read a log written by :meth:`save` (never unpickles).

        The loaded log's ``source`` is ``path`` (so messages name the file);
        the source it was saved with is kept in ``meta["recorded_from"]``.

        Raises
        ------
        LogError
            If the file is not a realitygap log (wrong content whatever its
            extension, pickled objects, missing parts, newer format version).
        """
        from realitygap.diagnosis.logs.importers.archive import (
            ArchiveError,
            parse_log_header,
            read_log_archive,
        )

        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"log file not found: {path}")
        try:
            check_regular_file(path, "log")
        except ValueError as exc:
            raise LogError(str(exc)) from None
        kind = sniff_file_kind(path)
        if kind != "npz":
            raise LogError(
                f"{path}: not a realitygap log (.npz zip archive); the file content looks like "
                f"{_KIND_TEXT.get(kind, kind)}. Fix: pass it with the right importer or "
                "re-save it with Log.save"
            )
        try:
            data = read_log_archive(path)
            if "meta.json" not in data or "t" not in data:
                raise LogError(
                    f"{path}: a zip/npz archive but not a realitygap log (no 't' and "
                    "'meta.json' arrays). Fix: re-save it with Log.save"
                )
            header = parse_log_header(data["meta.json"], path, FORMAT_NAME, FORMAT_VERSION)
        except ArchiveError as exc:
            raise LogError(str(exc)) from None
        t = np.asarray(data["t"])
        raw = {k[3:]: np.asarray(v) for k, v in data.items() if k.startswith("ch.")}
        chan_meta = header["channels"]
        if set(chan_meta) != set(raw):
            raise LogError(
                f"{path}: channels in the metadata ({sorted(chan_meta)}) and arrays "
                f"({sorted(raw)}) differ; the file is damaged"
            )
        try:
            specs = {k: ChannelSpec.from_dict(k, v) for k, v in chan_meta.items()}
        except ValueError as exc:
            raise LogError(f"{path}: {exc}") from None
        meta = dict(header["meta"])
        if header["source"]:
            meta.setdefault("recorded_from", header["source"])
        return cls(t=t, channels=raw, specs=specs, meta=meta, source=str(path))

    def __repr__(self) -> str:
        chans = ", ".join(f"{k}{tuple(v.shape)}" for k, v in self.channels.items())
        return f"Log({self.name!r}, n={self.n}, dt={self.dt:.4g} s, channels=[{chans}])"


_KIND_TEXT = {
    "npy": "a single NumPy array (.npy)",
    "rosbag1": "a ROS 1 bag",
    "sqlite": "an SQLite database (a ROS 2 .db3 bag?)",
    "mcap": "an MCAP file (a ROS 2 bag?)",
    "pickle": "a Python pickle (never loaded)",
    "text": "text (a CSV file?)",
    "binary": "unknown binary data",
    "empty": "an empty file",
    "directory": "a folder",
}


def fill_gaps(t: npt.ArrayLike, values: npt.ArrayLike) -> FloatArray:
    """Linearly interpolate NaN entries of ``values`` (N,) or (N, k) over ``t`` (N,).

    Leading / trailing gaps take the nearest valid value.

    Raises
    ------
    LogError
        If a column has no valid value at all.
    """
    t = np.asarray(t, dtype=float)
    arr = np.array(values, dtype=float)
    flat = arr[:, None] if arr.ndim == 1 else arr
    for j in range(flat.shape[1]):
        ok = np.isfinite(flat[:, j])
        if not ok.any():
            raise LogError(f"column {j} has no finite value to interpolate from")
        if not ok.all():
            flat[~ok, j] = np.interp(t[~ok], t[ok], flat[ok, j])
    return flat[:, 0] if arr.ndim == 1 else flat
