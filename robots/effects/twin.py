"""A reality on file, with how well each value is known: a diagnosis's answer as a simulator.

A *reality file* (schema :data:`SCHEMA`) holds the effects of one real robot with their
values, and for each parameter its unit, nominal value, standard error and the box a
domain randomisation draws it from. :func:`~realitygap.diagnosis.diagnose.Diagnosis.to_reality`
writes one from a diagnosis (``realitygap diagnose … --export twin.json``); every env reads one
(``gym.make(id, reality="twin.json")``), and ``randomize=twin.randomize`` draws each episode's
robot from its boxes (``--reality twin.json --randomize`` on the command line).

The box of a parameter is where the data put it:

* an effect that holds one value across sessions: the value ± 1.96 standard errors (its
  95 % interval), clipped to the parameter's physical bounds;
* an effect whose value varies between sessions: the range of its per-session values,
  widened to include the 95 % interval of the pooled value;
* a parameter without a standard error: the value alone (no spread is invented).

The older form ``{"name": ..., "effects": [{"name": ..., "values": {...}}]}`` is read too (no
uncertainty: every box is the value alone).

Example
-------
>>> from realitygap.robots.effects import Reality, make_effect
>>> twin = Twin(Reality((make_effect("command_latency", delay=0.05),)),
...             stderr={"command_latency.delay": 0.004})
>>> twin.randomize["command_latency.delay"]  # doctest: +ELLIPSIS
(0.042..., 0.057...)
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from realitygap.robots.effects.base import (
    EFFECTS,
    REALITY_EXAMPLE,
    REALITY_SCHEMA,
    ROBOT_PARAMS,
    Reality,
    make_effect,
    reality_from_file_form,
)

__all__ = [
    "SCHEMA",
    "Twin",
    "draw_reality",
    "load_reality",
    "nominal_parameters",
    "nominal_params",
]

SCHEMA = REALITY_SCHEMA
"""Version of a reality file's layout (this module's docstring)."""

Z95 = 1.959963984540054
"""Half-width of a two-sided 95 % normal interval, in standard errors."""


def _key(effect: str, param: str) -> str:
    return f"{effect}.{param}"


def nominal_params(robot: str | None) -> Any:
    """A registered ``robot``'s nominal physical parameters (its parameter class's
    defaults); ``None`` for ``None`` or a robot without registered parameters."""
    import importlib

    if robot is None or robot not in ROBOT_PARAMS:
        return None
    module, _, cls = ROBOT_PARAMS[robot].rpartition(".")
    return getattr(importlib.import_module(module), cls)()


def nominal_parameters(robot: str | None) -> dict[str, Any]:
    """:func:`nominal_params` as plain data (numbers and nested mappings); empty for ``None``
    or a robot without registered dataclass parameters."""
    import dataclasses

    params = nominal_params(robot)
    if params is None or not dataclasses.is_dataclass(params):
        return {}
    out = dataclasses.asdict(params)  # type: ignore[arg-type]
    return {k: v for k, v in out.items() if isinstance(v, (int, float, str, dict, list, tuple))}


@dataclass(frozen=True)
class Twin:
    """A :class:`Reality` with the uncertainty of each value (see the module docstring).

    Attributes
    ----------
    reality : Reality
        The effects at their fitted values.
    stderr : dict of str to float
        Standard error of each ``"effect.param"`` (absent or NaN: unknown).
    observed : dict of str to (float, float)
        For a parameter that varies between sessions, the lowest and highest per-session value.
    origin : dict of str to str
        Per effect, where its value came from (``"budget"``, ``"baseline"``, ``"file"``).
    source : dict
        What the values were fitted on (logs, verdict, budget shares), as plain data.
    """

    reality: Reality
    stderr: Mapping[str, float] = field(default_factory=dict)
    observed: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    origin: Mapping[str, str] = field(default_factory=dict)
    source: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.reality, Reality):
            raise TypeError(f"Twin.reality must be a Reality, got {type(self.reality).__name__}")
        keys = {_key(e.name, s.name) for e in self.reality.effects for s in e.specs}
        for what, mapping in (("stderr", self.stderr), ("observed", self.observed)):
            extra = sorted(set(mapping) - keys)
            if extra:
                raise ValueError(
                    f"Twin.{what} names {extra}, which are no parameters of its effects "
                    f"({sorted(keys)}). Fix: give {what} only for the reality's parameters"
                )
        for k, se in self.stderr.items():
            if not (isinstance(se, (int, float)) and (math.isnan(se) or se >= 0.0)):
                raise ValueError(f"Twin.stderr[{k!r}] must be >= 0 or NaN, got {se!r}")
        for k, pair in self.observed.items():
            lo, hi = (float(v) for v in pair)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(f"Twin.observed[{k!r}] must be a finite (low <= high), got {pair}")

    # ------------------------------------------------------------------ the boxes
    @property
    def robot(self) -> str | None:
        return self.reality.robot

    @property
    def randomize(self) -> dict[str, tuple[float, float]]:
        """``{"effect.param": (low, high)}``: the box each parameter is drawn from (module
        docstring), for every parameter with a spread; the form the envs' ``randomize``
        argument takes."""
        out: dict[str, tuple[float, float]] = {}
        for e in self.reality.effects:
            for s in e.specs:
                k = _key(e.name, s.name)
                v = float(e.values[s.name])
                lo, hi = v, v
                se = float(self.stderr.get(k, math.nan))
                if math.isfinite(se) and se > 0.0:
                    lo, hi = v - Z95 * se, v + Z95 * se
                if k in self.observed:
                    a, b = self.observed[k]
                    lo, hi = min(lo, float(a)), max(hi, float(b))
                lo, hi = max(lo, s.low), min(hi, s.high)
                if hi > lo:
                    out[k] = (lo, hi)
        return out

    def sample(self, rng: np.random.Generator) -> Reality:
        """One robot drawn from the boxes (:func:`draw_reality`)."""
        return draw_reality(self.reality, self.randomize, rng)

    # ------------------------------------------------------------------ the file
    def to_dict(self) -> dict[str, Any]:
        """The file's content (schema :data:`SCHEMA`); :meth:`from_dict` reads it back."""
        boxes = self.randomize
        effects = []
        for e in self.reality.effects:
            params = {}
            for s in e.specs:
                k = _key(e.name, s.name)
                row: dict[str, Any] = {
                    "unit": s.unit,
                    "nominal": s.nominal,
                    "stderr": float(self.stderr.get(k, math.nan)),
                    "varies": k in self.observed,
                }
                if k in self.observed:
                    row["observed"] = [float(v) for v in self.observed[k]]
                row["randomize"] = list(boxes.get(k, (e.values[s.name],) * 2))
                params[s.name] = row
            effects.append(
                {
                    "name": e.name,
                    "values": dict(e.values),
                    "parameters": params,
                    "origin": self.origin.get(e.name, "file"),
                }
            )
        return {
            "schema": SCHEMA,
            "name": self.reality.name,
            "robot": self.robot,
            "effects": effects,
            "nominal": nominal_parameters(self.robot),
            "source": dict(self.source),
        }

    @classmethod
    def from_dict(cls, data: Any, where: str = "reality") -> Twin:
        """Read :meth:`to_dict`'s form, or the older ``{"name", "effects"}`` one.

        Every effect and value is checked (:func:`make_effect`), and so are the uncertainty
        fields; each message names ``where`` (the file) and the entry.

        Raises
        ------
        ValueError
            An unknown key, schema, effect or parameter; a value out of bounds; a standard
            error that is negative; an observed range that is not ``[low, high]``.
        """
        reality = reality_from_file_form(data, where)  # keys, schema, effects checked
        stderr: dict[str, float] = {}
        observed: dict[str, tuple[float, float]] = {}
        origin: dict[str, str] = {}
        by_name = {e.name: e for e in reality.effects}
        for i, item in enumerate(data.get("effects", [])):
            at = f"{where}: effects[{i}]"
            effect = by_name[item["name"]]
            origin[effect.name] = str(item.get("origin", "file"))
            params = item.get("parameters", {})
            if not isinstance(params, Mapping):
                raise ValueError(f"{at} ({effect.name!r}): 'parameters' must be an object")
            for pname, row in params.items():
                spec_names = [s.name for s in effect.specs]
                if pname not in spec_names or not isinstance(row, Mapping):
                    raise ValueError(
                        f"{at} ({effect.name!r}): 'parameters' entry {pname!r} must be one of "
                        f"{spec_names} holding an object, got {row!r:.60}"
                    )
                k = _key(effect.name, str(pname))
                se = row.get("stderr")
                if se is not None:
                    if isinstance(se, bool) or not isinstance(se, (int, float)) or se < 0:
                        raise ValueError(
                            f"{at} ({k}): 'stderr' must be a number >= 0 or null, got {se!r}"
                        )
                    stderr[k] = float(se)
                obs = row.get("observed")
                if obs is not None:
                    ok = (
                        isinstance(obs, list)
                        and len(obs) == 2
                        and all(
                            isinstance(v, (int, float)) and not isinstance(v, bool) for v in obs
                        )
                        and math.isfinite(obs[0])
                        and math.isfinite(obs[1])
                        and obs[0] <= obs[1]
                    )
                    if not ok:
                        raise ValueError(
                            f"{at} ({k}): 'observed' must be [low, high] with low <= high, "
                            f"got {obs!r:.60}"
                        )
                    observed[k] = (float(obs[0]), float(obs[1]))
        source = data.get("source", {})
        if not isinstance(source, Mapping):
            raise ValueError(f"{where}: 'source' must be an object, got {type(source).__name__}")
        return cls(reality, stderr, observed, origin, dict(source))

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the file atomically (``core.io.write_json``); returns its path."""
        from realitygap.core.io import write_json

        return write_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | os.PathLike[str], option: str = "reality") -> Twin:
        """Read a JSON or YAML reality file (errors name ``option`` and the file)."""
        from realitygap.core.checks import load_json_or_yaml

        data = load_json_or_yaml(Path(path), option, expect=dict, example=REALITY_EXAMPLE)
        twin = cls.from_dict(data, where=f"{option} {os.fspath(path)}")
        if "name" not in data:
            object.__setattr__(twin, "reality", Reality(twin.reality.effects, name=Path(path).stem))
        return twin


def load_reality(path: str | os.PathLike[str], option: str = "reality") -> Reality:
    """The :class:`Reality` (fitted values) of a reality file; see :meth:`Twin.load`."""
    return Twin.load(path, option).reality


def draw_reality(
    reality: Reality, boxes: Mapping[str, tuple[float, float]], rng: np.random.Generator
) -> Reality:
    """``reality`` with each parameter of ``boxes`` drawn uniformly from its box.

    A box may name an effect ``reality`` lacks (plain domain randomisation over the
    library): it is added, its other parameters nominal. Draws are made in sorted key order,
    so the same generator state gives the same robot.
    """
    values: dict[str, dict[str, float]] = {e.name: dict(e.values) for e in reality.effects}
    for key in sorted(boxes):
        lo, hi = boxes[key]
        name, _, param = key.partition(".")
        values.setdefault(name, {})[param] = float(rng.uniform(lo, hi)) if hi > lo else float(lo)
    effects = tuple(make_effect(n, **v) for n, v in values.items() if n in EFFECTS)
    return Reality(effects, name=reality.name, meta=reality.meta)
