"""The sim-to-real gap: logs, replay, localise, attribute, shrink, validate, report.

Typical use::

    from realitygap.diagnosis import diagnose, read_logs, write_report

    train = read_logs("shared/data/optiodom_diffdrive/square/230620202042")
    held = read_logs("shared/data/optiodom_diffdrive/ivanjko/231220200057")
    result = diagnose(train, held)
    print(result.verdict.label)        # ["wheelbase_error"] or "unexplained"
    write_report(result, "out/")

Modules: :mod:`~realitygap.diagnosis.log` (the :class:`Log` and its file
format), :mod:`~realitygap.diagnosis.io` and ``importers`` (OptiOdom, CSV, ROS
bags), :mod:`~realitygap.diagnosis.record` (:class:`RecordLog` wrapper),
:mod:`~realitygap.diagnosis.replay` (PyBullet replay),
:mod:`~realitygap.diagnosis.surrogate` (the fit's fast model),
:mod:`~realitygap.diagnosis.features`, :mod:`~realitygap.diagnosis.localise`,
:mod:`~realitygap.diagnosis.attribute`, :mod:`~realitygap.diagnosis.verify`,
:mod:`~realitygap.diagnosis.verdict`, :mod:`~realitygap.diagnosis.identifiability`,
:mod:`~realitygap.diagnosis.shrink`, :mod:`~realitygap.diagnosis.diagnose` (the
pipeline of those stages), :mod:`~realitygap.diagnosis.adapters` (the robot-adapter
interface and registry) with one adapter per robot
(:mod:`~realitygap.diagnosis.diffdrive_adapter`,
:mod:`~realitygap.diagnosis.arm_adapter`, :mod:`~realitygap.diagnosis.climb_adapter`),
:mod:`~realitygap.core.parallel` (serial / processes / Ray),
:mod:`~realitygap.diagnosis.report`, :mod:`~realitygap.diagnosis.suite`
(blind validation) and :mod:`~realitygap.diagnosis.cli` (``realitygap diagnose``).

Attributes are imported lazily, so ``import realitygap.diagnosis`` stays light.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Log": "realitygap.diagnosis.log",
    "LogError": "realitygap.diagnosis.log",
    "ChannelSpec": "realitygap.diagnosis.log",
    "read_logs": "realitygap.diagnosis.io",
    "read_many": "realitygap.diagnosis.io",
    "ReadOptions": "realitygap.diagnosis.io",
    "logs_from_optiodom": "realitygap.diagnosis.io",
    "RecordLog": "realitygap.diagnosis.record",
    "replay": "realitygap.diagnosis.replay",
    "simulate": "realitygap.diagnosis.replay",
    "SimSettings": "realitygap.diagnosis.replay",
    "diagnose": "realitygap.diagnosis.diagnose",
    "Diagnosis": "realitygap.diagnosis.diagnose",
    "DiagnosisSettings": "realitygap.diagnosis.diagnose",
    "AttributionSettings": "realitygap.diagnosis.attribute",
    "FeatureSettings": "realitygap.diagnosis.features",
    "write_report": "realitygap.diagnosis.report",
    "write_json": "realitygap.diagnosis.report",
    "make_backend": "realitygap.core.parallel",
    "get_adapter": "realitygap.diagnosis.adapters",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'realitygap.diagnosis' has no attribute {name!r}")
