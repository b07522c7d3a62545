"""The column map: which column of a user's file is which column of a log, and how to read it.

A column map is a comma-separated list of ``target=SOURCE[:unit]`` entries::

    t=time:ms, ticks.left=-enc_l, ticks.right=enc_r,
    pose_gt.x=x:mm, pose_gt.y=y:mm, pose_gt.theta=-heading:deg

* ``target`` is ``t`` (the time) or ``channel.column`` of a standard channel
  (``cmd.v``, ``ticks.left``, ``pose_gt.theta``, ``joints.q3``, ``tool_pos.x`` …).
* ``SOURCE`` is ``[-]COLUMN[*FACTOR][+OFFSET]``: the file's column (a header name,
  or a 0-based index), its sign (an encoder mounted mirrored, a clockwise-positive
  heading), a scale factor and an offset, all in the file's unit; the value is
  ``sign · column · factor + offset`` in ``unit``, then converted to SI. A name
  holding ``, = : * + -`` or a space at its ends goes in double quotes
  (``pose_gt.x="x [mm]":mm``).
* For the time only, ``row*DT`` says the rows come at a fixed period ``DT``
  (in ``unit``, seconds by default) when the file's own time column is unusable.
* With several files read as one log (``enc.csv+mocap.csv``), ``FILE::COLUMN``
  says which file a column is in (the file's name, or its name without the
  extension); the time may then be given once per file (``t=enc::stamp,
  t=mocap::time``). An unqualified name is looked up in every file.
* ``ticks=increments`` says the encoder columns count per row instead of
  cumulatively.
* **One source per target, one target per source.** A target given twice is an
  error (in a JSON file too: its last value would silently win). A column that
  feeds two targets (``cmd.v=v, cmd.w=v``: usually a slip) is an error unless the
  map says so: mark every further use with ``!`` before the column
  (``pose_gt.theta=yaw, pose_est.theta=!yaw``); a name that starts with ``!`` goes
  in double quotes.

:meth:`ColumnMap.parse` reads that text (or a JSON file of the same entries);
every error names the entry, what was expected and an example.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from realitygap.core.checks import load_json_or_yaml
from realitygap.diagnosis.logs.log import LogError, standard_channels

__all__ = ["ColumnMap", "Source", "split_entries"]

_TARGET = re.compile(r"^(t|[a-z_]+\.[a-z_0-9]+)$")
_NUMBER = r"[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?"
_FACTOR = re.compile(rf"^\s*\*\s*({_NUMBER})(?:\s*/\s*({_NUMBER}))?")
_OFFSET = re.compile(rf"^\s*([-+])\s*({_NUMBER})\s*$")
EXAMPLE = "t=time:ms,ticks.left=-enc_l,ticks.right=enc_r,pose_gt.theta=-heading:deg"


@dataclass(frozen=True)
class Source:
    """Where one log column comes from, and how its values are read.

    Attributes
    ----------
    column : str, int or None
        The file's column: a header name or a 0-based index; ``None`` for a time
        made from the row number (``row_period``).
    unit : str
        The unit of ``sign · column · factor + offset`` in the file (converted to SI).
    sign, factor, offset : float
        ``value = sign · column · factor + offset`` (in ``unit``).
    file : str or None
        The file that holds the column (its name or stem), or ``None`` for any.
    row_period : float or None
        For the time only: rows at this fixed period (in ``unit``).
    shared : bool
        The entry is marked ``!``: the column may also feed another target.
    text : str
        The entry as written (for messages).
    body : str
        The entry without its unit: a file whose header holds exactly this text (a
        column named ``x-1`` or ``-enc``) reads that column as it is.
    """

    column: str | int | None
    unit: str = ""
    sign: float = 1.0
    factor: float = 1.0
    offset: float = 0.0
    file: str | None = None
    row_period: float | None = None
    shared: bool = False
    text: str = ""
    body: str = ""

    @property
    def affine(self) -> bool:
        """Whether the entry changes the file's values (sign, factor or offset)."""
        return self.sign != 1.0 or self.factor != 1.0 or self.offset != 0.0

    def matches_file(self, path: str | os.PathLike[str]) -> bool:
        """Whether the column may be looked up in ``path``."""
        if self.file is None:
            return True
        p = Path(path)
        return self.file in (p.name, p.stem, str(p))


@dataclass(frozen=True)
class ColumnMap:
    """Which file column feeds which log column (see the module docstring).

    Attributes
    ----------
    entries : mapping of str to Source
        ``"channel.column"`` → its source; the time is in :attr:`times`.
    times : tuple of Source
        The time: one source for every file, or one per file (qualified); empty
        for a log whose rows are poses rather than instants (an arm's measurements),
        where the row number stands for the time.
    ticks : {"cumulative", "increments"}
        How the encoder columns count.
    """

    entries: Mapping[str, Source] = field(default_factory=dict)
    times: tuple[Source, ...] = ()
    ticks: str = "cumulative"
    source: str = ""
    """The file the map was read from (empty for a map given as text)."""

    def __post_init__(self) -> None:
        if not self.entries:
            raise LogError(f"column map: no channel column given (e.g. {EXAMPLE!r})")
        for target in self.entries:
            check_target(target)
        if self.ticks not in ("cumulative", "increments"):
            raise LogError(
                f"column map: ticks must be 'cumulative' or 'increments', got {self.ticks!r}"
            )
        if len(self.times) > 1 and any(s.file is None for s in self.times):
            raise LogError(
                "column map: the time is given more than once; with several files, qualify each "
                "with its file (e.g. 't=enc::stamp,t=mocap::time')"
            )
        check_one_target_per_source(self.entries)

    @property
    def time(self) -> Source | None:
        """The time source when there is one for every file (else the first)."""
        return self.times[0] if self.times else None

    def time_for(self, path: str | os.PathLike[str]) -> Source | None:
        """The time source of ``path``'s rows (``None`` if the map has none for it)."""
        for s in self.times:
            if s.matches_file(path):
                return s
        return None

    def channels(self) -> dict[str, dict[str, Source]]:
        """The entries grouped by channel: ``{channel: {column: source}}``."""
        out: dict[str, dict[str, Source]] = {}
        for target, src in self.entries.items():
            chan, col = target.split(".", 1)
            out.setdefault(chan, {})[col] = src
        return out

    @classmethod
    def parse(cls, text: str) -> ColumnMap:
        """Parse ``"t=time:ms, cmd.v=vx:mm/s, …[, ticks=increments]"`` or a JSON file path.

        A JSON file holds ``{"t": ["time", "ms"], "cmd.v": ["vx", "mm/s"], …}``
        (or the entries as strings: ``{"ticks.left": "-enc_l"}``) and optionally
        ``"ticks": "increments"``.
        """
        if not isinstance(text, str):
            raise LogError(
                f"column map (--columns) must be text like {EXAMPLE!r} or a JSON file name, got "
                f"{type(text).__name__} {text!r}"
            )
        text = text.strip()
        if text.endswith((".json", ".yaml", ".yml")) or os.path.isfile(text):
            try:
                raw = load_json_or_yaml(
                    text, "column map (--columns)", expect=dict, example='{"t": ["time", "ms"]}'
                )
                return dataclasses.replace(cls.from_dict(raw), source=text)
            except LogError as exc:
                raise LogError(str(exc).replace("column map:", f"column map {text}:", 1)) from None
            except ValueError as exc:
                raise LogError(str(exc)) from None
        entries: dict[str, Source] = {}
        times: list[Source] = []
        ticks = "cumulative"
        for part in split_entries(text):
            target, sep, source = part.partition("=")
            target, source = target.strip(), source.strip()
            if not sep or not target or not source:
                raise LogError(
                    f"column map: expected 'target=column[:unit]', got {part!r} (e.g. {EXAMPLE!r})"
                )
            if target == "ticks":
                ticks = source
                continue
            src = parse_source(source, target)
            _add(entries, times, target, src)
        return cls(entries, tuple(times), ticks)

    @classmethod
    def from_dict(cls, raw: Mapping[str, Any]) -> ColumnMap:
        """A map from ``{target: source}`` (source: ``"col"``, ``"-col*2:mm"``, ``[col, unit]``
        or a list of those for a time given per file)."""
        if not isinstance(raw, Mapping):
            raise LogError(
                f"column map must be a mapping of target → column (e.g. {{'t': 'time'}}), got "
                f"{type(raw).__name__} {raw!r}"
            )
        entries: dict[str, Source] = {}
        times: list[Source] = []
        for target, value in raw.items():
            if target == "ticks":
                continue
            values = value if target == "t" and _is_list_of_sources(value) else [value]
            for v in values:
                if isinstance(v, (list, tuple)):
                    if not 1 <= len(v) <= 2:
                        raise LogError(
                            f"column map: {target!r} must be a column or [column, unit], got {v!r}"
                        )
                    col = v[0]
                    unit = str(v[1]) if len(v) > 1 else ""
                    src_text = f"{_quote(col)}:{unit}" if unit else _quote(col)
                elif isinstance(v, (str, int)) and not isinstance(v, bool):
                    src_text = str(v) if isinstance(v, str) else str(int(v))
                else:
                    raise LogError(
                        f"column map: {target!r} must be a column name, an index or "
                        f"[column, unit], got {v!r}"
                    )
                _add(entries, times, str(target), parse_source(src_text, str(target)))
        return cls(entries, tuple(times), str(raw.get("ticks", "cumulative")))


def check_one_target_per_source(entries: Mapping[str, Source]) -> None:
    """Refuse a column that feeds several targets unless every use but one is marked ``!``.

    Raises
    ------
    LogError
        Naming the column, its targets and the fix.
    """
    uses: dict[tuple[str | None, str | int | None], list[tuple[str, Source]]] = {}
    for target, src in entries.items():
        uses.setdefault((src.file, src.column), []).append((target, src))
    for (file, column), targets in uses.items():
        unmarked = [t for t, src in targets if not src.shared]
        if len(targets) > 1 and len(unmarked) > 1:
            name = f"{file}::{column}" if file else str(column)
            raise LogError(
                f"column map: the column {name!r} feeds {', '.join(t for t, _ in targets)}; one "
                "column is one quantity (is one of them a slip?). Fix: map each target to its "
                f"own column, or, if the column really is both, mark the further use with '!' "
                f"(e.g. '{unmarked[-1]}=!{column}')"
            )


def _is_list_of_sources(value: Any) -> bool:
    """Whether a JSON time entry lists one source per file: a list of ``[column, unit]`` lists,
    or of ``"FILE::column"`` strings (``["time", "ms"]`` is one source with its unit)."""
    if not isinstance(value, list) or not value:
        return False
    return all(isinstance(v, list) for v in value) or all(
        isinstance(v, str) and "::" in v for v in value
    )


def _quote(col: Any) -> str:
    s = str(col)
    return f'"{s}"' if any(c in s for c in ',=:*+-"') or s != s.strip() else s


def _add(entries: dict[str, Source], times: list[Source], target: str, src: Source) -> None:
    if target == "t":
        times.append(src)
        return
    check_target(target)
    if src.row_period is not None:
        raise LogError(
            f"column map: {target}={src.text}: 'row*DT' stands for the time only; give {target!r} "
            "a column"
        )
    if target in entries:
        raise LogError(
            f"column map: {target!r} is given twice ({entries[target].text!r} and "
            f"{src.text!r}); keep one"
        )
    entries[target] = src


def check_target(target: str) -> None:
    """Refuse a target that is not ``t`` or a standard ``channel.column``."""
    if not _TARGET.match(target):
        raise LogError(
            f"column map: target {target!r} must be 't' or 'channel.column' "
            "(e.g. 'cmd.v', 'pose_gt.theta')"
        )
    if target == "t":
        return
    chan, col = target.split(".", 1)
    spec = standard_channels().get(chan)
    if spec is None:
        raise LogError(
            f"column map: unknown channel {chan!r} in {target!r}; channels: "
            f"{', '.join(standard_channels())}"
        )
    if col not in spec.columns:
        raise LogError(f"column map: channel {chan!r} has columns {spec.columns}, not {col!r}")


def split_entries(text: str) -> list[str]:
    """``text`` split at the commas outside double quotes (empty parts dropped)."""
    parts: list[str] = []
    cur: list[str] = []
    quoted = False
    for ch in text:
        if ch == '"':
            quoted = not quoted
        if ch == "," and not quoted:
            parts.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    if quoted:
        raise LogError(f"column map: unbalanced double quote in {text!r}")
    parts.append("".join(cur))
    return [p.strip() for p in parts if p.strip()]


def _split_unit(source: str) -> tuple[str, str]:
    """``source`` and its unit: the text after the last ``:`` outside quotes that is not part
    of a ``FILE::`` qualifier."""
    quoted = False
    cut = -1
    i = 0
    while i < len(source):
        ch = source[i]
        if ch == '"':
            quoted = not quoted
        elif ch == ":" and not quoted:
            if source[i : i + 2] == "::":
                i += 2
                continue
            cut = i
        i += 1
    if cut < 0:
        return source.strip(), ""
    return source[:cut].strip(), source[cut + 1 :].strip()


def parse_source(source: str, target: str) -> Source:
    """One entry's ``SOURCE[:unit]`` (see the module docstring)."""
    body, unit = _split_unit(source)
    where = f"column map: {target}={source}"
    shared = body.startswith("!")
    if shared:
        body = body[1:].lstrip()
    if not body:
        raise LogError(f"{where}: no column given (e.g. {EXAMPLE!r})")
    file: str | None = None
    sign = 1.0
    rest = body
    if rest.startswith("-"):
        sign, rest = -1.0, rest[1:].lstrip()
    # FILE:: qualifier (outside quotes)
    m = re.match(r'^([^":]+)::', rest)
    if m:
        file, rest = m.group(1).strip(), rest[m.end() :].lstrip()
    if rest.startswith('"'):
        end = rest.find('"', 1)
        name: str | int = rest[1:end]
        tail = rest[end + 1 :]
    else:
        m2 = re.match(r"^([^*+\-]+?)\s*(?=[*+\-]|$)", rest)
        if m2 is None:
            # a name that starts with an operator: the whole text is the name
            name, tail = rest, ""
        else:
            name, tail = m2.group(1).strip(), rest[m2.end() :]
    factor, offset = 1.0, 0.0
    fm = _FACTOR.match(tail)
    if fm:
        factor = float(fm.group(1)) / (float(fm.group(2)) if fm.group(2) else 1.0)
        tail = tail[fm.end() :]
    if tail.strip():
        om = _OFFSET.match(tail)
        if om is None:
            # not an affine expression: the text is a column name holding those characters
            if re.match(r"^-?\s*row\s*\*", body):
                raise LogError(
                    f"{where}: a time from the row number is 'row*DT' with a positive period DT "
                    "(e.g. 't=row*0.033' for 30 Hz rows, or 't=row*33:ms')"
                )
            name, factor, offset, sign, file = body, 1.0, 0.0, 1.0, None
        else:
            offset = float(om.group(2)) * (1.0 if om.group(1) == "+" else -1.0)
    if factor == 0.0:
        raise LogError(f"{where}: a factor of 0 erases the column; give a non-zero factor")
    row_period: float | None = None
    if name == "row":
        if target != "t":
            raise LogError(f"{where}: 'row*DT' stands for the time only")
        if not fm or sign < 0 or offset:
            raise LogError(
                f"{where}: a time from the row number is 'row*DT' with a positive period DT "
                "(e.g. 't=row*0.033' for 30 Hz rows, or 't=row*33:ms')"
            )
        row_period, name, factor = factor, None, 1.0  # type: ignore[assignment]
    if isinstance(name, str) and name.isdigit():
        name = int(name)
    if isinstance(name, str) and not name:
        raise LogError(f"{where}: empty column name")
    return Source(
        column=name,
        unit=unit,
        sign=sign,
        factor=factor,
        offset=offset,
        file=file,
        row_period=row_period,
        shared=shared,
        text=source,
        body=body,
    )
