"""A diagnosis's answer as a reality file: the simulator of the robot the logs came from.

:func:`twin_of` (``Diagnosis.to_reality()``, ``realitygap diagnose … --export twin.json``)
collects what the diagnosis found about the *robot* and writes it as a
:class:`~realitygap.robots.effects.Twin`:

* the budget's entries that carry over to the held-out data, at the values the budget's
  final model fitted them to jointly, each with its standard error; an entry whose value
  varies between sessions gets its per-session range (:attr:`Twin.observed`), so a
  randomised twin spans what the sessions showed;
* the calibrated baseline's values of effects that act on the robot (its commands, drive,
  body or sensors), without an error bar (the baseline fits no standard errors).

Left out, with the reason in ``source["left_out"]``: budget entries that made the held-out
data worse, and effects that only act on the recording (a clock offset or a tracked frame of
the ground truth: they change what was logged, not how the robot moves).
"""

from __future__ import annotations

import math
from typing import Any

from realitygap.diagnosis.problem.parameters import split_key
from realitygap.robots.effects import EFFECTS, Reality, Twin, make_effect

__all__ = ["acts_on_robot", "twin_of"]


def acts_on_robot(name: str, values: dict[str, float], robot: str) -> bool:
    """Whether effect ``name`` at ``values`` changes how the ``robot`` moves or reads its
    sensors, rather than only the stamps or frame of a recorded channel: it changes the
    physical parameters or makes a command, wheel or encoder hook; an effect that does
    neither but re-stamps or re-frames a channel acts on the recording alone."""
    import dataclasses

    from realitygap.robots.effects.twin import nominal_params

    effect = make_effect(name, **values)
    if not (effect.channel_time_offsets() or effect.channel_frames()):
        return True
    nominal = nominal_params(robot)
    if nominal is not None:
        if dataclasses.is_dataclass(nominal) and effect.apply_params(nominal) != nominal:
            return True
        hooks = (
            effect.make_command_hook(0.05, nominal),
            effect.make_wheel_hook(0.05, nominal),
            effect.make_ticks_hook(),
        )
        if any(h is not None for h in hooks):
            return True
    return False


def twin_of(d: Any, name: str = "") -> Twin:
    """The :class:`Twin` of diagnosis ``d`` (a :class:`~realitygap.diagnosis.diagnose.Diagnosis`;
    module docstring). It reads the diagnosis's parts, so it sits below the pipeline."""
    robot = d.settings.robot
    values: dict[str, float] = {}
    stderr: dict[str, float] = {}
    observed: dict[str, tuple[float, float]] = {}
    origin: dict[str, str] = {}
    left_out: dict[str, str] = {}
    for key, v in d.baseline.values.items():
        values[key] = float(v)
        origin.setdefault(split_key(key)[0], "baseline")
    budget = d.budget
    shares: dict[str, Any] = {}
    if budget is not None:
        for e in budget.entries:
            if not e.carries:
                left_out[e.effect] = "made the held-out data worse (its share lies below zero)"
                continue
            keys = [k for k in budget.values if split_key(k)[0] == e.effect] or list(e.values)
            for k in keys:
                values[k] = float(budget.values.get(k, e.values.get(k, math.nan)))
                se = float(e.stderr.get(k, math.nan))
                if math.isfinite(se):
                    stderr[k] = se
                row = e.stability.get("parameters", {}).get(k, {})
                if not e.constant and math.isfinite(row.get("min", math.nan)):
                    observed[k] = (float(row["min"]), float(row["max"]))
            origin[e.effect] = "budget"
            shares[e.effect] = {
                "share_pct": dict(e.share),
                "interval_pct": {s: list(iv) for s, iv in e.interval.items()},
                "varies_between": None if e.constant else e.stability.get("unit", "fold"),
            }
    grouped: dict[str, dict[str, float]] = {}
    for k, v in values.items():
        effect, param = split_key(k)
        grouped.setdefault(effect, {})[param] = v
    effects = []
    for effect, vals in grouped.items():
        if effect not in EFFECTS:
            left_out[effect] = "not an effect of this library version"
            continue
        if not acts_on_robot(effect, vals, robot):
            left_out[effect] = "acts on the recording (clock or tracked frame), not the robot"
            continue
        effects.append(make_effect(effect, **vals))
    kept = {e.name for e in effects}
    reality = Reality(tuple(effects), name=name or f"twin of {robot}")
    keys = {f"{e.name}.{s.name}" for e in effects for s in e.specs}
    source = {
        "robot": robot,
        "logs": {
            "train": [p.name for p in d.prepared if p.split == "train"],
            "holdout": [p.name for p in d.prepared if p.split == "holdout"],
        },
        "verdict": d.verdict.label,
        "budget_kind": budget.kind if budget is not None else None,
        "budget": {k: v for k, v in shares.items() if k in kept},
        "unexplained_share_pct": budget.unexplained_share if budget is not None else None,
        "left_out": left_out,
    }
    return Twin(
        reality,
        stderr={k: v for k, v in stderr.items() if k in keys},
        observed={k: v for k, v in observed.items() if k in keys},
        origin={k: v for k, v in origin.items() if k in kept},
        source=source,
    )
