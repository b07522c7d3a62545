"""The sim-to-real gap: logs, replay, localise, attribute, shrink, validate, report.

Typical use::

    from realitygap.diagnosis import diagnose, read_logs, write_report

    train = read_logs("shared/data/optiodom_diffdrive/square/230620202042")
    held = read_logs("shared/data/optiodom_diffdrive/ivanjko/231220200057")
    result = diagnose(train, held)
    print(result.verdict.label)        # ["wheelbase_error"] or "unexplained"
    write_report(result, "out/")

Modules: :mod:`~realitygap.diagnosis.logs.log` (the :class:`Log` and its file
format), :mod:`~realitygap.diagnosis.logs.read` and ``importers`` (OptiOdom, CSV, ROS
bags), :mod:`~realitygap.diagnosis.adapters.diffdrive.record` (:class:`RecordLog` wrapper),
:mod:`~realitygap.diagnosis.adapters.diffdrive.replay` (PyBullet replay, on the core in
:mod:`~realitygap.robots.diffdrive_replay`),
:mod:`~realitygap.robots.diffdrive_surrogate` (the fit's fast model),
:mod:`~realitygap.diagnosis.problem.features`, :mod:`~realitygap.diagnosis.stages.localise`,
:mod:`~realitygap.diagnosis.fit.model`, :mod:`~realitygap.diagnosis.fit.verify`,
:mod:`~realitygap.diagnosis.verdict.rules`, :mod:`~realitygap.diagnosis.fit.identifiability`,
:mod:`~realitygap.diagnosis.problem.shrink`, :mod:`~realitygap.diagnosis.diagnose` (the
pipeline of those stages), :mod:`~realitygap.diagnosis.adapters.contract` (the robot-adapter
interface and registry) with one adapter per robot
(:mod:`~realitygap.diagnosis.adapters.diffdrive.adapter`,
:mod:`~realitygap.diagnosis.adapters.arm.adapter`, :mod:`~realitygap.diagnosis.adapters.climber.adapter`),
:mod:`~realitygap.core.parallel` (serial / processes / Ray),
:mod:`~realitygap.diagnosis.report.writer`, :mod:`~realitygap.diagnosis.validation.suite`
(blind validation) and :mod:`~realitygap.diagnosis.cli` (``realitygap diagnose``).

Attributes are imported lazily, so ``import realitygap.diagnosis`` stays light.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Log": "realitygap.diagnosis.logs.log",
    "LogError": "realitygap.diagnosis.logs.log",
    "ChannelSpec": "realitygap.diagnosis.logs.log",
    "read_logs": "realitygap.diagnosis.logs.read",
    "read_many": "realitygap.diagnosis.logs.read",
    "ReadOptions": "realitygap.diagnosis.logs.read",
    "logs_from_optiodom": "realitygap.diagnosis.logs.read",
    "RecordLog": "realitygap.diagnosis.adapters.diffdrive.record",
    "replay": "realitygap.diagnosis.adapters.diffdrive.replay",
    "simulate": "realitygap.diagnosis.adapters.diffdrive.replay",
    "SimSettings": "realitygap.robots.simulation",
    "diagnose": "realitygap.diagnosis.diagnose",
    "Diagnosis": "realitygap.diagnosis.diagnose",
    "DiagnosisSettings": "realitygap.diagnosis.settings",
    "AttributionSettings": "realitygap.diagnosis.problem.problem",
    "FeatureSettings": "realitygap.diagnosis.problem.features",
    "write_report": "realitygap.diagnosis.report.writer",
    "write_json": "realitygap.diagnosis.report.writer",
    "make_backend": "realitygap.core.parallel",
    "get_adapter": "realitygap.diagnosis.adapters.registry",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'realitygap.diagnosis' has no attribute {name!r}")
