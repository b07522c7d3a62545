"""Small real objects of the diagnosis for unit tests: a :class:`Problem` on a toy robot whose
residuals a test plants, :class:`ModelFit`, :class:`Judgement` and :class:`Verdict` values.

Every factory takes keyword arguments. The toy robot (:class:`ToyAdapter`) compares feature
groups the real robots declare (default: the climber's one-column ``tether`` group), so
:class:`FeatureSettings` gives their scales. Its nominal replay leaves the residual a test
plants (``holdout`` / ``train``: one entry per layout entry, in layout order: log by log, then
group by group, window by window, column by column); its surrogate adds ``shift(values)`` to
that residual (``shift`` maps the batch of parameter values to one offset per batch member,
or one per member and window). The test modules reach these through the fixtures of
``conftest.py`` (the suite imports test modules in importlib mode).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.adapters.contract import Drive, LogContext, PreparedLog, RobotAdapter
from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.features import FeatureSettings
from realitygap.diagnosis.problem.problem import AttributionSettings, Problem
from realitygap.diagnosis.problem.schemas import FeatureSchema, feature_group
from realitygap.diagnosis.verdict.types import (
    Confidence,
    Judgement,
    Verdict,
    VerdictKind,
    VerdictNotes,
)
from realitygap.robots.simulation import SimSettings

FloatArray = npt.NDArray[np.float64]
Shift = Callable[[Mapping[str, FloatArray]], npt.ArrayLike]
Terms = Mapping[str, tuple[FloatArray, str]]

__all__ = [
    "ToyAdapter",
    "ToyContext",
    "judgement",
    "model_fit",
    "prepared_log",
    "toy_problem",
    "toy_schema",
    "verdict",
]


def toy_schema(*groups: str, regimes: Sequence[str] = ("all_of_it",)) -> FeatureSchema:
    """A schema of feature groups the real robots declare (default ``tether``), with
    ``regimes``."""
    return FeatureSchema(tuple(feature_group(g) for g in groups or ("tether",)), tuple(regimes))


@dataclass
class ToyContext(LogContext):
    """A toy log's context: the discovery terms of its windows."""

    terms: Terms = field(default_factory=dict)


class ToyAdapter(RobotAdapter):
    """A robot of planted residuals (see the module docstring).

    Parameters
    ----------
    schema : FeatureSchema
    shift : callable, optional
        Batch of parameter values (each ``(B,)``) → what the surrogate adds to the nominal
        residual, ``(B,)`` or ``(B, M)``; nothing by default.
    alias_pairs : sequence of (str, str)
        Effects the robot's own alias groups measure as aliases.
    """

    robot = "toy"
    channels = ()

    def __init__(
        self,
        schema: FeatureSchema,
        shift: Shift | None = None,
        alias_pairs: Sequence[tuple[str, str]] = (),
    ) -> None:
        self._schema = schema
        self.features = FeatureSettings()
        self._shift = shift
        self._alias_pairs = [tuple(p) for p in alias_pairs]

    @property
    def schema(self) -> FeatureSchema:
        return self._schema

    # the toy robot is never checked, prepared, replayed nor probed: its logs come prepared
    def check(self, log: Log, drive: Drive) -> Log:
        raise NotImplementedError

    def prepare(self, log: Log, **kw: Any) -> PreparedLog:
        raise NotImplementedError

    def replay_features(self, prepared: PreparedLog, values: Any, drive: Drive, sim: Any) -> Any:
        raise NotImplementedError

    def log_features(self, prepared: PreparedLog, log: Log) -> dict[str, FloatArray]:
        raise NotImplementedError

    def probe_manoeuvres(self) -> dict[str, str]:
        raise NotImplementedError

    def probe_features(self, manoeuvre: str, params_like: PreparedLog, values: Any) -> Any:
        raise NotImplementedError

    def surrogate_features(
        self, prepared: PreparedLog, values: Mapping[str, npt.ArrayLike], drive: Drive
    ) -> dict[str, FloatArray]:
        batch = {k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in values.items()}
        b = max((v.shape[0] for v in batch.values()), default=1)
        m = prepared.bounds.shape[0]
        shift = np.zeros((b, m))
        if self._shift is not None:
            given = np.asarray(self._shift(batch), dtype=float)
            shift = np.broadcast_to(given.reshape(b, -1), (b, m)) if given.ndim < 2 else given
        return {
            g: prepared.nominal[g][None] - shift[:, :, None] * self.features.scale(g)
            for g in prepared.groups
        }

    def discovery_terms(self, prepared: PreparedLog) -> Terms:
        assert isinstance(prepared.context, ToyContext)
        return prepared.context.terms

    def alias_groups(
        self,
        prepared: Sequence[PreparedLog],
        threshold: float = 0.95,
        effects: Sequence[str] | None = None,
    ) -> list[dict[str, Any]]:
        if not self._alias_pairs:
            return []
        members = sorted({e for p in self._alias_pairs for e in p})
        return [{"effects": members, "aliases": [list(p) for p in self._alias_pairs]}]


def _prepared(
    schema: FeatureSchema,
    split: str,
    name: str,
    residual: FloatArray,
    regimes: Sequence[str],
    terms: Terms,
) -> PreparedLog:
    """A log of ``len(regimes)`` windows whose features differ from the nominal replay's by
    ``residual`` (its layout entries, group by group) in feature-scale units."""
    m = len(regimes)
    scales = FeatureSettings()
    real: dict[str, FloatArray] = {}
    nominal: dict[str, FloatArray] = {}
    pos = 0
    for g in schema.groups:
        k = len(g.columns)
        block = residual[pos : pos + m * k].reshape(m, k)
        pos += m * k
        nominal[g.name] = np.zeros((m, k))
        real[g.name] = block * scales.scale(g.name)
    t = np.arange(m + 1, dtype=float)
    log = Log(t=t, channels={}, meta={"name": name}, source=name)
    return PreparedLog(
        log=log,
        split=split,
        bounds=np.stack([np.arange(m), np.arange(m) + 1], axis=1).astype(np.int64),
        regimes=list(regimes),
        real=real,
        nominal=nominal,
        replay_log=log,
        holdout_windows=np.full(m, split == "holdout"),
        schema=schema,
        context=ToyContext(SimSettings(), terms=terms),
        bias={g.name: np.zeros((m, len(g.columns))) for g in schema.groups},
    )


def prepared_log(name: str, split: str = "train", n: int = 4) -> PreparedLog:
    """A prepared log ``name`` of ``n`` windows whose features equal the nominal replay's."""
    schema = toy_schema()
    k = sum(len(g.columns) for g in schema.groups)
    return _prepared(schema, split, name, np.zeros(n * k), ["all_of_it"] * n, {})


def toy_problem(
    *,
    windows: int,
    holdout_logs: int = 1,
    train_logs: int = 1,
    schema: FeatureSchema | None = None,
    regimes: Sequence[str] | None = None,
    holdout: npt.ArrayLike | None = None,
    train: npt.ArrayLike | None = None,
    shift: Shift | None = None,
    settings: AttributionSettings | None = None,
    baseline_ranges: Mapping[str, tuple[float, float]] | None = None,
    alias_pairs: Sequence[tuple[str, str]] = (),
    terms: Sequence[Terms] | None = None,
) -> Problem:
    """A :class:`Problem` on the toy robot: ``train_logs`` training logs, then
    ``holdout_logs`` held-out ones, each of ``windows`` windows.

    Parameters
    ----------
    windows : int
        Windows per log.
    schema : FeatureSchema, optional
        Default :func:`toy_schema` ().
    regimes : sequence of str, optional
        The regime of each window (the same in every log); default the schema's first.
    holdout, train : array_like, optional
        The nominal residual of the held-out and training layouts (layout order); zeros by
        default.
    shift : callable, optional
        What the surrogate adds to the nominal residual (:class:`ToyAdapter`).
    settings : AttributionSettings, optional
    baseline_ranges : mapping, optional
        Calibrated-baseline nuisance ranges.
    alias_pairs : sequence of (str, str)
        The robot's known aliases.
    terms : sequence of mapping, optional
        Per log (training first), the discovery terms of its windows.
    """
    schema = schema if schema is not None else toy_schema()
    regimes = list(regimes) if regimes is not None else [schema.regimes[0]] * windows
    if len(regimes) != windows:
        raise ValueError(f"toy_problem: {len(regimes)} regimes for {windows} windows")
    per_log = windows * sum(len(g.columns) for g in schema.groups)
    splits = [("train", train, train_logs), ("holdout", holdout, holdout_logs)]
    prepared: list[PreparedLog] = []
    for split, given, n_logs in splits:
        z = np.zeros(n_logs * per_log) if given is None else np.asarray(given, dtype=float)
        if z.shape != (n_logs * per_log,):
            raise ValueError(
                f"toy_problem: the {split} residual needs {n_logs * per_log} entries, got {z.shape}"
            )
        for j in range(n_logs):
            i = len(prepared)
            prepared.append(
                _prepared(
                    schema,
                    split,
                    f"{split}{j}",
                    z[j * per_log : (j + 1) * per_log],
                    regimes,
                    terms[i] if terms is not None else {},
                )
            )
    problem = Problem(
        ToyAdapter(schema, shift, alias_pairs),
        prepared,
        Drive.COMMANDS,
        FeatureSettings(),
        None,
        settings if settings is not None else AttributionSettings(),
    )
    problem.baseline_ranges = dict(baseline_ranges or {})
    return problem


def model_fit(
    *,
    effects: Sequence[str] = (),
    z_heldout: npt.ArrayLike,
    values: Mapping[str, float] | None = None,
    keys: Sequence[str] | None = None,
    stderr: float = 0.01,
    rank_score: float = 0.0,
    bic: float = 0.0,
    held: Mapping[str, str] | None = None,
) -> ModelFit:
    """A fitted model with held-out residual ``z_heldout`` and parameter ``values``; ``keys``
    (default: every value) are fitted, each with standard error ``stderr``, uncorrelated (the
    other values are nuisances refined with the model)."""
    z = np.asarray(z_heldout, dtype=float)
    vals = dict(values or {})
    fitted = tuple(keys) if keys is not None else tuple(vals)
    return ModelFit(
        effects=tuple(effects),
        keys=fitted,
        values=vals,
        stderr={k: stderr for k in fitted},
        corr=np.eye(len(fitted)),
        train_score=0.0,
        bic=bic,
        heldout_score=0.0,
        rank_score=rank_score,
        heldout_rms=float(np.sqrt(np.mean(z**2))) if z.size else 0.0,
        z_heldout=z,
        held=dict(held or {}),
    )


def judgement(
    *,
    best: ModelFit,
    nominal_heldout: npt.ArrayLike,
    kind: VerdictKind = VerdictKind.EFFECTS,
    shrink_pct_best: float = 80.0,
    shrink_pct_above_noise: float = math.nan,
    gap_mask: npt.ArrayLike | None = None,
) -> Judgement:
    """The held-out figures of ``best`` of ``kind`` (gap channels: every entry by default)."""
    z_nom = np.asarray(nominal_heldout, dtype=float)
    mask = np.ones(z_nom.shape, dtype=bool) if gap_mask is None else np.asarray(gap_mask, bool)
    return Judgement(kind, best, z_nom, mask, shrink_pct_best, shrink_pct_above_noise)


def verdict(
    *,
    kind: VerdictKind = VerdictKind.EFFECTS,
    effects: Sequence[str] = (),
    reason: str = "",
    confidence: Confidence = Confidence.STRONG,
    notes: VerdictNotes | None = None,
    ambiguous_with: Sequence[str] = (),
) -> Verdict:
    """A verdict of ``kind`` naming ``effects``, with ``notes``."""
    return Verdict(
        kind=kind,
        effects=tuple(effects),
        reason=reason,
        margin=20.0,
        confidence=confidence,
        residual={"structured": False, "reasons": [], "groups": {}},
        ambiguous_with=tuple(ambiguous_with),
        notes=notes if notes is not None else VerdictNotes(),
    )
