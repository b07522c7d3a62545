"""The sim-to-real gap diagnosis, end to end: localise → attribute → verify → shrink.

:func:`diagnose` takes real logs (training and, optionally, held-out ones) and
returns a :class:`Diagnosis`:

1. every log is checked and replayed in the nominal PyBullet simulation
   (same commands or wheel rotation, same start);
2. :func:`~realitygap.diagnosis.localise.localise` tabulates where replay and
   reality part (per channel, regime, pipeline stage);
3. each candidate effect, then pairs of the best, is fitted on the training
   windows and scored on the held-out ones
   (:mod:`realitygap.diagnosis.attribute`), fits running in parallel through a
   backend (:mod:`realitygap.core.parallel`);
4. the best models are verified in PyBullet, and the verdict is drawn — an
   effect (or pair) only if it closes enough of the held-out gap and leaves
   unstructured residuals, else ``"unexplained"``; confounded explanations
   are flagged with a manoeuvre that would separate them;
5. :mod:`realitygap.diagnosis.shrink` reports the held-out gap before and
   after, per channel and regime.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.parallel import Backend, SerialBackend
from realitygap.diagnosis.adapters import PreparedLog, RobotAdapter, get_adapter
from realitygap.diagnosis.attribute import (
    AttributionSettings,
    ModelFit,
    Problem,
    Verdict,
    _finish,
    _spec,
    _to_u,
    describe_residual,
    fit_model,
    model_keys,
)
from realitygap.diagnosis.features import FeatureSettings
from realitygap.diagnosis.localise import localise
from realitygap.diagnosis.log import Log, LogError
from realitygap.diagnosis.replay import Drive, SimSettings
from realitygap.diagnosis.shrink import overall_shrink, shrink_table, trajectory_gap
from realitygap.robots.effects import EFFECTS

FloatArray = npt.NDArray[np.float64]

__all__ = ["Diagnosis", "DiagnosisSettings", "diagnose"]


@dataclass(frozen=True)
class DiagnosisSettings:
    """Settings of :func:`diagnose`.

    Attributes
    ----------
    robot : str
        Adapter name (``"diffdrive"``).
    drive : {"commands", "ticks"}
        What drives the replay: the logged commands, or the logged wheel
        rotation (then only effects after the wheels can be attributed).
    effects : tuple of str or None
        Candidate library; ``None`` means every effect of the robot.
    features : FeatureSettings
    attribution : AttributionSettings
    sim : SimSettings or None
        Replay fidelity (default: a simulated log's own settings, else
        :class:`SimSettings` ()).
    holdout_fraction : float
        Without explicit held-out logs and with several logs, the last
        ``ceil(fraction · n)`` logs are held out.
    block_windows : int
        With a single log, alternate blocks of this many windows are held out.
    """

    robot: str = "diffdrive"
    drive: str = "commands"
    effects: tuple[str, ...] | None = None
    features: FeatureSettings = field(default_factory=FeatureSettings)
    attribution: AttributionSettings = field(default_factory=AttributionSettings)
    sim: SimSettings | None = None
    holdout_fraction: float = 1.0 / 3.0
    block_windows: int = 10


@dataclass
class Diagnosis:
    """Result of :func:`diagnose` (see :meth:`to_json` for the exported form)."""

    settings: DiagnosisSettings
    prepared: list[PreparedLog]
    candidates: list[str]
    not_observable: dict[str, str]
    localisation: dict[str, Any]
    ranking: list[ModelFit]
    verdict: Verdict
    identifiability: list[dict[str, Any]]
    shrink: list[dict[str, Any]]
    gap: dict[str, Any]
    agreement: list[dict[str, Any]]
    corrected_replays: dict[int, Log]
    timing: dict[str, float]
    nominal_heldout: FloatArray
    problem: Problem
    gap_mask: npt.NDArray[np.bool_] | None = None
    shrink_best: list[dict[str, Any]] = field(default_factory=list)

    @property
    def chosen(self) -> ModelFit | None:
        """The model named by the verdict, if any."""
        if self.verdict.kind != "effects":
            return None
        for fit in self.ranking:
            if fit.effects == self.verdict.effects:
                return fit
        return None

    def ranking_rows(self) -> list[dict[str, Any]]:
        """The ranking as JSON-able rows (fitted values with units and uncertainty)."""
        rows = []
        mask = self.gap_mask
        if mask is None or not mask.any():
            mask = np.ones(self.nominal_heldout.shape, dtype=bool)
        nominal_rms = (
            float(np.sqrt(np.mean(self.nominal_heldout[mask] ** 2))) if mask.any() else 0.0
        )
        for rank, fit in enumerate(self.ranking, start=1):
            params = {}
            for k in fit.keys:
                effect, _, pname = k.partition(".")
                spec = EFFECTS[effect]().spec(pname)
                params[k] = {
                    "value": fit.values[k],
                    "stderr": fit.stderr.get(k, math.nan),
                    "unit": spec.unit,
                    "nominal": spec.nominal,
                }
            nxt = next((f for f in self.ranking[rank:] if f.effects != fit.effects), None)
            rows.append(
                {
                    "rank": rank,
                    "name": fit.name,
                    "effects": list(fit.effects),
                    "params": params,
                    "heldout_shrink_pct": overall_shrink(
                        self.nominal_heldout[mask], fit.z_heldout[mask]
                    )
                    if nominal_rms > 0 and fit.z_heldout.size == mask.size
                    else 0.0,
                    "heldout_rms": fit.heldout_rms,
                    "heldout_score": fit.heldout_score,
                    "rank_score": fit.rank_score,
                    "bic_train": fit.bic,
                    "margin_to_next": (nxt.rank_score - fit.rank_score) if nxt else math.inf,
                    "verified_in_pybullet": fit.verified,
                }
            )
        return rows

    def to_json(self) -> dict[str, Any]:
        """The JSON form: ``ranking`` (each candidate with fitted values and held-out shrink),
        ``verdict`` (effect names or ``"unexplained"`` / ``"none"``) and the details."""
        v = self.verdict
        return {
            "robot": self.settings.robot,
            "drive": self.settings.drive,
            "logs": {
                "train": [p.name for p in self.prepared if p.split == "train"],
                "holdout": [p.name for p in self.prepared if p.split == "holdout"],
                "window_split": any(
                    p.split == "train" and p.holdout_windows.any() for p in self.prepared
                ),
            },
            "verdict": v.label,
            "verdict_detail": {
                "kind": v.kind,
                "effects": list(v.effects),
                "reason": v.reason,
                "confidence": v.confidence,
                "margin": v.margin,
                "ambiguous_with": v.ambiguous_with,
                "remaining_residual": v.residual,
            },
            "ranking": self.ranking_rows(),
            "candidates": self.candidates,
            "not_observable": self.not_observable,
            "identifiability": self.identifiability,
            "localisation": self.localisation,
            "shrink": self.shrink,
            "shrink_best_candidate": self.shrink_best,
            "gap": self.gap,
            "surrogate_agreement": self.agreement,
            "timing_s": self.timing,
        }


# --------------------------------------------------------------------------- worker tasks
def _prepare_task(shared: tuple[Any, ...], item: tuple[Log, str]) -> PreparedLog:
    robot, drive, feats, sim = shared
    log, split = item
    return get_adapter(robot).prepare(
        log, split=split, drive=Drive(drive), features_settings=feats, sim=sim
    )


def _fit_task(problem: Problem, item: tuple[tuple[str, ...], list[dict[str, float]]]) -> ModelFit:
    effects, starts = item
    return fit_model(problem, effects, starts=starts)


def _replay_task(
    problem: Problem, item: tuple[int, dict[str, float]]
) -> tuple[dict[str, FloatArray], Log]:
    i, values = item
    p = problem.logs[i]
    sim = problem.sim if problem.sim is not None else p.context["sim"]
    return problem.adapter.replay_features(p, values, problem.drive, sim)


# --------------------------------------------------------------------------- helpers
def _split(
    logs: Sequence[Log], holdout: Sequence[Log] | None, settings: DiagnosisSettings
) -> list[tuple[Log, str]]:
    if holdout:
        return [(lg, "train") for lg in logs] + [(lg, "holdout") for lg in holdout]
    if len(logs) >= 2:
        n_ho = max(1, math.ceil(settings.holdout_fraction * len(logs)))
        n_ho = min(n_ho, len(logs) - 1)
        return [(lg, "train") for lg in logs[:-n_ho]] + [(lg, "holdout") for lg in logs[-n_ho:]]
    return [(logs[0], "train")]


def _window_split(prepared: list[PreparedLog], block: int) -> None:
    """Single-log diagnosis: alternate blocks of windows are held out."""
    p = prepared[0]
    m = p.bounds.shape[0]
    block = max(1, min(block, m // 2))
    p.holdout_windows = (np.arange(m) // block) % 2 == 1


def _rescore(problem: Problem, fit: ModelFit, z_tr: FloatArray, z_ho: FloatArray) -> ModelFit:
    u = np.array([_to_u(k, fit.values[k]) for k in fit.keys])
    new = _finish(problem, fit.effects, fit.keys, u, z_tr, z_ho, np.zeros((z_tr.size, 0)), True)
    new.stderr, new.corr = fit.stderr, fit.corr
    return new


def _surrogate_point(values: Mapping[str, float]) -> dict[str, FloatArray]:
    return {k: np.array([v]) for k, v in values.items()}


def _verify(
    problem: Problem, fit: ModelFit, backend: Backend
) -> tuple[ModelFit, dict[int, Log], dict[str, Any]]:
    """Defect-corrected refit and PyBullet scores for one model."""
    values = dict(fit.values)
    train_idx = [i for i, p in enumerate(problem.logs) if (~p.holdout_windows).any()]
    for _ in range(problem.settings.defect_iterations):
        reps = backend.map(_replay_task, [(i, values) for i in train_idx], problem)
        bias = {}
        for i, (feats, _) in zip(train_idx, reps):
            p = problem.logs[i]
            sur = problem.adapter.surrogate_features(p, _surrogate_point(values), problem.drive)
            bias[i] = {g: feats[g] - sur[g][0] for g in p.groups}
        fit = fit_model(problem, fit.effects, starts=[values], bias=bias, local_only=True)
        values = dict(fit.values)
    all_idx = list(range(len(problem.logs)))
    reps = backend.map(_replay_task, [(i, values) for i in all_idx], problem)
    pb = {i: feats for i, (feats, _) in zip(all_idx, reps)}
    logs = {i: lg for i, (_, lg) in zip(all_idx, reps)}

    def predict(p: PreparedLog, i: int) -> dict[str, FloatArray]:
        return {g: pb[i][g][None] for g in p.groups}

    z_tr = problem.real_minus(problem.train, predict, 1)[0]
    z_ho = problem.real_minus(problem.holdout, predict, 1)[0] if problem.holdout.n else np.zeros(0)
    verified = _rescore(problem, fit, z_tr, z_ho)
    # surrogate agreement: bias-corrected surrogate vs PyBullet at the fitted point
    num = den = 0.0
    for i, p in enumerate(problem.logs):
        sur = problem.adapter.surrogate_features(p, _surrogate_point(values), problem.drive)
        for g in p.groups:
            s = problem.features.scale(g)
            pred = sur[g][0] + p.bias[g]
            num += float(np.sum(((pred - pb[i][g]) / s) ** 2))
            den += float(np.sum(((pb[i][g] - p.nominal[g]) / s) ** 2))
    agreement = {
        "model": fit.name,
        "values": values,
        "relative_error": math.sqrt(num / den) if den > 0 else 0.0,
        "rms_difference": math.sqrt(num / max(sum(p.bounds.shape[0] for p in problem.logs), 1)),
    }
    return verified, logs, agreement


def _jacobian(
    residual: Callable[[dict[str, FloatArray]], FloatArray],
    keys: Sequence[str],
    point: Mapping[str, float],
) -> FloatArray:
    """Finite-difference Jacobian (n, p) of a batched residual in natural parameter units."""
    p = len(keys)
    steps = []
    for k in keys:
        effect, _, pname = k.partition(".")
        spec = EFFECTS[effect]().spec(pname)
        h = 1e-3 * (spec.high - spec.low)
        if k == "velocity_saturation.v_limit":
            h = 1e-3 * max(point[k], 0.2)
        steps.append(h if point[k] + h <= spec.high else -h)
    # row 0: the point; row j + 1: the point with key j stepped
    batch = {
        k: np.array([point[k]] + [point[k] + (steps[i] if i == j else 0.0) for j in range(p)])
        for i, k in enumerate(keys)
    }
    z = residual(batch)
    return ((z[1:] - z[0]) / np.asarray(steps)[:, None]).T


def _corr(J: FloatArray) -> FloatArray:
    info = J.T @ J
    cov = np.linalg.pinv(info)
    sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    return cov / np.outer(sd, sd)


def _identifiability(problem: Problem, a: ModelFit, b: ModelFit) -> dict[str, Any]:
    """Can the logged motions tell model ``a`` from ``b``? Which motion would?"""
    effects = tuple(dict.fromkeys(a.effects + b.effects))
    keys = model_keys(effects)
    point: dict[str, float] = {}
    for k in keys:
        effect, _, pname = k.partition(".")
        point[k] = EFFECTS[effect]().spec(pname).nominal
    point.update(b.values)
    point.update(a.values)

    def train_res(batch: dict[str, FloatArray]) -> FloatArray:
        n = len(next(iter(batch.values())))
        return problem.surrogate_residuals(problem.train, batch, n)

    J = _jacobian(train_res, keys, point)
    C = _corr(J)
    ka = [j for j, k in enumerate(keys) if k.split(".")[0] in a.effects]
    kb = [j for j, k in enumerate(keys) if k.split(".")[0] not in a.effects]
    cross = max((abs(C[i, j]) for i in ka for j in kb), default=0.0)
    out: dict[str, Any] = {
        "effects": [a.name, b.name],
        "correlation": float(cross),
        "separable": bool(cross < problem.settings.confound_corr),
    }
    if out["separable"]:
        return out
    best = None
    ref = problem.logs[0]
    probes = problem.adapter.probe_manoeuvres()
    for name in probes:

        def probe_res(batch: dict[str, FloatArray], name: str = name) -> FloatArray:
            feats, groups = problem.adapter.probe_features(name, ref, batch)
            parts = [
                (feats[g] / problem.features.scale(g)).reshape(feats[g].shape[0], -1)
                for g in groups
            ]
            return np.concatenate(parts, axis=1)

        Jm = _jacobian(probe_res, keys, point)
        Cm = _corr(np.vstack([J, Jm]))
        cross_m = max((abs(Cm[i, j]) for i in ka for j in kb), default=0.0)
        if best is None or cross_m < best[1]:
            best = (name, cross_m)
    assert best is not None
    out["separating_motion"] = {
        "name": best[0],
        "description": probes[best[0]],
        "correlation_after": float(best[1]),
    }
    out["message"] = (
        f"the logged motions cannot tell {a.name} from {b.name} (parameter correlation "
        f"{cross:.2f}); recording '{best[0]}' ({probes[best[0]]}) would "
        f"separate them (correlation {best[1]:.2f})"
    )
    return out


def _pinned(problem: Problem, fit: ModelFit) -> list[str]:
    """Parameters of ``fit`` that sit at the far edge of their plausible range and matter.

    An effect fitted at the bound of its plausible range (the end away from "no
    effect") is being stretched to absorb a gap it does not cause. Parameters
    the logs cannot see (moving them back to nominal changes the training
    residual by less than the floor) are ignored.
    """
    out = []
    point = {k: np.array([v]) for k, v in fit.values.items()}
    base: FloatArray | None = None
    for key, value in fit.values.items():
        spec = _spec(key)
        span = spec.high - spec.low
        at_low = spec.low != spec.nominal and value - spec.low < 0.005 * span
        at_high = spec.high != spec.nominal and spec.high - value < 0.005 * span
        if not (at_low or at_high):
            continue
        if base is None:
            base = problem.surrogate_residuals(problem.train, point, 1)[0]
        alt = problem.surrogate_residuals(
            problem.train, {**point, key: np.array([spec.nominal])}, 1
        )[0]
        if float(np.sqrt(np.mean((alt - base) ** 2))) > problem.settings.floor:
            out.append(key)
    return out


def _confidence(margin: float, settings: AttributionSettings) -> str:
    if margin >= settings.margin_strong:
        return "strong"
    if margin >= 2.0:
        return "moderate"
    return "weak"


# --------------------------------------------------------------------------- main entry
def diagnose(
    logs: Sequence[Log],
    holdout: Sequence[Log] | None = None,
    *,
    settings: DiagnosisSettings | None = None,
    backend: Backend | None = None,
    progress: Callable[[str], None] | None = None,
) -> Diagnosis:
    """Diagnose the gap between real ``logs`` and the nominal simulation.

    Parameters
    ----------
    logs : sequence of Log
        Training logs (regular time stamps; for a differential drive ``cmd``
        and ``pose_gt``, or ``ticks`` and ``pose_gt`` with ``drive="ticks"``).
    holdout : sequence of Log, optional
        Held-out logs for scoring (other trajectories). Without them, the last
        third of several logs is held out, or alternate blocks of windows of a
        single log.
    settings : DiagnosisSettings, optional
    backend : Backend, optional
        Where replays and fits run (default: this process).
    progress : callable, optional
        Receives short progress messages.

    Returns
    -------
    Diagnosis

    Raises
    ------
    LogError
        A log is unusable (missing channels, irregular time, …); the message
        names the file, the channel and the fix.
    ValueError
        Unknown robot or effect names.
    """
    s = settings if settings is not None else DiagnosisSettings()
    be = backend if backend is not None else SerialBackend()
    say = progress if progress is not None else (lambda msg: None)
    if not logs:
        raise ValueError("diagnose needs at least one log")
    adapter: RobotAdapter = get_adapter(s.robot)
    drive = Drive(s.drive)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    library = adapter.effect_names()
    if s.effects is not None:
        unknown = [e for e in s.effects if e not in library]
        if unknown:
            import difflib

            hints = [difflib.get_close_matches(u, library, n=1) for u in unknown]
            hint = "; ".join(
                f"{u!r} (did you mean {h[0]!r}?)" if h else repr(u) for u, h in zip(unknown, hints)
            )
            raise ValueError(
                f"unknown effect(s) {hint} for robot {s.robot!r}; known: {', '.join(library)}"
            )
        library = tuple(s.effects)
    all_logs = list(logs) + list(holdout or [])
    for lg in all_logs:
        adapter.check(lg, drive)
    items = _split(list(logs), list(holdout) if holdout else None, s)

    say(f"replaying {len(items)} log(s) in the nominal simulation")
    prepared: list[PreparedLog] = be.map(
        _prepare_task, items, (s.robot, drive.value, s.features, s.sim)
    )
    if not any(p.split == "holdout" for p in prepared):
        _window_split(prepared, s.block_windows)
    timing["prepare"] = time.perf_counter() - t0

    problem = Problem(adapter, prepared, drive, s.features, s.sim, s.attribution)
    if problem.holdout.n == 0 or problem.train.n == 0:
        raise LogError("the logs give no training or no held-out windows; record longer episodes")
    loc = localise(prepared, adapter, s.features)

    not_observable = {}
    candidates = []
    for e in library:
        why = adapter.observable(e, prepared, drive)
        if why:
            not_observable[e] = why
        else:
            candidates.append(e)

    t1 = time.perf_counter()
    say(f"fitting {len(candidates)} single effects")
    singles: list[ModelFit] = be.map(_fit_task, [((e,), []) for e in candidates], problem)
    nominal_fit = fit_model(problem, ())
    singles.sort(key=lambda f: f.rank_score)
    top = [f for f in singles if f.rank_score < nominal_fit.rank_score][
        : s.attribution.pair_candidates
    ]
    # pairs: the best single with every other candidate (forward selection: a second effect
    # is often masked by a dominant one), and every pair among the best singles
    combos: dict[frozenset[str], tuple[ModelFit, ModelFit]] = {}
    if top:
        for other in singles:
            if other.effects != top[0].effects:
                combos.setdefault(frozenset(top[0].effects + other.effects), (top[0], other))
    for fa, fb in ((x, y) for i, x in enumerate(top) for y in top[i + 1 :]):
        combos.setdefault(frozenset(fa.effects + fb.effects), (fa, fb))
    pairs_items = []
    for fa, fb in combos.values():
        nominal_b = {k: EFFECTS[fb.effects[0]]().spec(k.split(".")[1]).nominal for k in fb.keys}
        starts = [{**fa.values, **fb.values}, {**fa.values, **nominal_b}]
        pairs_items.append(((fa.effects[0], fb.effects[0]), starts))
    say(f"fitting {len(pairs_items)} pairs")
    pairs: list[ModelFit] = be.map(_fit_task, pairs_items, problem)
    timing["fit"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    verified_logs: dict[tuple[str, ...], dict[int, Log]] = {}
    agreement: list[dict[str, Any]] = []
    st = s.attribution
    # a model "demoted" in favour of a simpler sub-model ranks right behind that sub-model
    demoted: dict[tuple[str, ...], tuple[str, ...]] = {}

    def resort(models: list[ModelFit]) -> list[ModelFit]:
        score = {f.effects: f.rank_score for f in models}

        def key(f: ModelFit) -> tuple[float, int]:
            if f.effects in demoted:
                return (score[demoted[f.effects]], 1)
            return (f.rank_score, 0)

        return sorted(models, key=key)

    ranking = resort([*singles, *pairs, nominal_fit])

    def verified(fit: ModelFit) -> ModelFit:
        nonlocal ranking
        if fit.verified or not fit.effects:
            return fit
        say(f"verifying {fit.name} in PyBullet")
        new, reps, agree = _verify(problem, fit, be)
        verified_logs[new.effects] = reps
        agreement.append(agree)
        ranking = resort([new if f is fit else f for f in ranking])
        return new

    def improves(fit: ModelFit) -> bool:
        return fit.rank_score < nominal_fit.rank_score - 1.0

    def sub_models(fit: ModelFit) -> list[ModelFit]:
        return [f for f in ranking if f.effects and set(f.effects) < set(fit.effects)]

    for _ in range(3 * st.verify_top + 6):
        best = ranking[0]
        if len(best.effects) > 1:
            # an effect whose fitted size changes the predictions by less than the floor is
            # not named: the model without it takes the place (no replay needed to see that)
            negligible = {e for e, size in best.effect_sizes.items() if size < st.floor}
            drop = [f for f in sub_models(best) if set(best.effects) - set(f.effects) <= negligible]
            if drop:
                demoted[best.effects] = min(drop, key=lambda f: f.rank_score).effects
                ranking = resort(ranking)
                continue
        if best.effects and not best.verified:
            verified(best)
            continue
        # Occam: prefer a verified sub-model within the parsimony margin
        if len(best.effects) > 1:
            for sub in sub_models(best):
                if not sub.verified and improves(sub):
                    verified(sub)
            best = ranking[0]
            simpler = [
                f
                for f in sub_models(best)
                if f.verified and f.rank_score - best.rank_score < st.parsimony_margin
            ]
            if simpler and len(best.effects) > 1:
                demoted[best.effects] = min(simpler, key=lambda f: f.rank_score).effects
                ranking = resort(ranking)
                continue
        n_ver = sum(1 for f in ranking if f.verified)
        todo = [
            f
            for f in ranking[1:]
            if f.effects and not f.verified and improves(f) and f.effects not in demoted
        ]
        if n_ver < st.verify_top and todo:
            verified(todo[0])
            continue
        break
    timing["verify"] = time.perf_counter() - t2

    # ------------------------------------------------------------------ verdict
    z_nom = problem.nominal_residuals(problem.holdout)
    noise_fn = getattr(adapter, "noise_levels", None)
    noise = noise_fn(prepared, s.features) if noise_fn is not None else None
    nominal_desc = describe_residual(z_nom, problem.holdout, st, s.features, noise)
    best = ranking[0]
    # the runner-up: the best model that is neither this one nor a superset rejected for it
    runner = next(
        (
            f
            for f in ranking[1:]
            if f.effects != best.effects
            and not (best.effects and set(f.effects) > set(best.effects))
        ),
        None,
    )
    margin = (runner.rank_score - best.rank_score) if runner is not None else math.inf
    # the gap lives in the channels whose nominal held-out residual exceeds twice the floor;
    # channels the effects do not touch would only add their noise to both sides of the shrink
    gap_mask = np.zeros(z_nom.shape, dtype=bool)
    for g in np.unique(problem.holdout.group):
        sel = problem.holdout.group == g
        if float(np.sqrt(np.mean(z_nom[sel] ** 2))) > 2.0 * st.floor:
            gap_mask |= sel
    if not gap_mask.any():
        gap_mask[:] = True
    shrink_all = overall_shrink(z_nom[gap_mask], best.z_heldout[gap_mask])
    best_desc = describe_residual(best.z_heldout, problem.holdout, st, s.features, noise)
    gain = nominal_fit.rank_score - best.rank_score
    if not nominal_desc["structured"] and gain < st.margin_strong:
        verdict = Verdict(
            "none",
            (),
            "the held-out residual of the nominal replay already looks like noise",
            margin,
            "n/a",
            nominal_desc,
        )
    elif not best.effects:
        verdict = Verdict(
            "unexplained",
            (),
            "no candidate effect improves on the nominal replay on held-out data",
            margin,
            "n/a",
            best_desc,
        )
    elif shrink_all < 100.0 * st.min_shrink:
        verdict = Verdict(
            "unexplained",
            (),
            f"the best candidate ({best.name}) closes only {shrink_all:.0f} % of the held-out "
            f"gap (needs {100 * st.min_shrink:.0f} %)",
            margin,
            "n/a",
            best_desc,
        )
    elif pinned := _pinned(problem, best):
        edges = ", ".join(
            f"{k} = {best.values[k]:.4g} {_spec(k).unit} (range {_spec(k).low:g} … "
            f"{_spec(k).high:g})"
            for k in pinned
        )
        verdict = Verdict(
            "unexplained",
            (),
            f"the best candidate ({best.name}, {shrink_all:.0f} % of the held-out gap) needs "
            f"{edges}: at the edge of the plausible range, so the effect is being stretched to "
            "absorb a gap it does not cause",
            margin,
            "n/a",
            best_desc,
        )
    elif best_desc["structured"]:
        verdict = Verdict(
            "unexplained",
            (),
            f"after the best candidate ({best.name}, {shrink_all:.0f} % of the held-out gap) "
            "the residual is still structured: " + "; ".join(best_desc["reasons"]),
            margin,
            "n/a",
            best_desc,
        )
    else:
        verdict = Verdict(
            "effects",
            best.effects,
            f"{best.name} closes {shrink_all:.0f} % of the held-out gap and leaves unstructured "
            "residuals",
            margin,
            _confidence(margin, st),
            best_desc,
        )

    # ------------------------------------------------------------------ identifiability
    ident: list[dict[str, Any]] = []
    contenders = [f for f in ranking if f.effects and f.effects != best.effects]
    close = [f for f in contenders if f.rank_score - best.rank_score < st.margin_strong][:2]
    if best.effects:
        for other in close:
            if set(other.effects) >= set(best.effects) or set(best.effects) >= set(other.effects):
                continue
            info = _identifiability(problem, best, other)
            ident.append(info)
            if not info["separable"] and verdict.kind == "effects":
                verdict.ambiguous_with.append(other.name)
        if verdict.ambiguous_with:
            verdict.confidence = "not identifiable"

    # ------------------------------------------------------------------ shrink
    chosen = best if verdict.kind == "effects" else None
    z_after = chosen.z_heldout if chosen is not None else z_nom
    rows = shrink_table(z_nom, z_after, problem.holdout, s.features)
    ho_idx = [i for i, p in enumerate(prepared) if p.holdout_windows.any()]
    real_ho = [prepared[i].log for i in ho_idx]
    nominal_ho = [prepared[i].replay_log for i in ho_idx]
    gap = {
        "heldout_rms_nominal": float(np.sqrt(np.mean(z_nom**2))),
        "heldout_rms_best": float(best.heldout_rms),
        "heldout_shrink_pct_best": shrink_all,
        "heldout_shrink_pct": overall_shrink(z_nom[gap_mask], z_after[gap_mask]),
        "heldout_shrink_pct_all_channels": overall_shrink(z_nom, z_after),
        "heldout_shrink_pct_best_all_channels": overall_shrink(z_nom, best.z_heldout),
        "gap_channels": sorted({str(g) for g in problem.holdout.group[gap_mask]}),
        "heldout_trajectory_gap_m_nominal": trajectory_gap(real_ho, nominal_ho),
    }
    reps_best = verified_logs.get(best.effects)
    if reps_best is not None:
        gap["heldout_trajectory_gap_m_best"] = trajectory_gap(
            real_ho, [reps_best[i] for i in ho_idx]
        )
    gt_sel = problem.holdout.group == "pose_gt"
    if gt_sel.any():
        scale = s.features.scale("pose_gt")[0]
        xy = gt_sel & np.isin(problem.holdout.column, ["dx", "dy"])
        gap["heldout_window_gap_m_nominal"] = float(np.sqrt(np.mean(z_nom[xy] ** 2)) * scale)
        gap["heldout_window_gap_m_best"] = float(np.sqrt(np.mean(best.z_heldout[xy] ** 2)) * scale)
    timing["total"] = time.perf_counter() - t0
    say(f"verdict: {verdict.label}")
    return Diagnosis(
        settings=s,
        prepared=prepared,
        candidates=candidates,
        not_observable=not_observable,
        localisation=loc,
        ranking=ranking,
        verdict=verdict,
        identifiability=ident,
        shrink=rows,
        gap=gap,
        agreement=agreement,
        corrected_replays=reps_best or {},
        timing=timing,
        nominal_heldout=z_nom,
        problem=problem,
        gap_mask=gap_mask,
        shrink_best=shrink_table(z_nom, best.z_heldout, problem.holdout, s.features),
    )
