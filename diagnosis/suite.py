"""Blind validation of the diagnosis: hidden effects realised in PyBullet, then diagnosed.

Each :class:`BlindCase` draws one hidden effect (sometimes two) with a
realistic magnitude from a seeded generator, realises it in the PyBullet
robot, records ordinary manoeuvres — through
:class:`~realitygap.envs.wheeled_nav.WheeledNavEnv` and
:class:`~realitygap.diagnosis.record.RecordLog` for the firmware-ramped ones,
by driving the robot directly for hard starts — with motion-capture and
camera noise, and runs :func:`~realitygap.diagnosis.diagnose.diagnose`
without telling it the truth. In a quarter of the cases a true effect is
removed from the candidate library (open set): the right answer is then
``"unexplained"``.

For the arm (``SuiteSettings(robot="arm")``) the hidden effects are the
kinematic, drive and encoder effects of :data:`ARM_HIDDEN_EFFECTS`; each case
measures one training and one held-out set of random poses of the PyBullet arm
with a simulated laser tracker
(:func:`~realitygap.diagnosis.arm_adapter.record_arm_log`). For the climber
(``robot="climber"``) each case drives the PyBullet climber along a training
and a held-out path on the blade
(:func:`~realitygap.diagnosis.climb_adapter.record_climber_logs`).

:func:`summarise` turns case outcomes into the suite's figures (top-1 / top-2
accuracy, parameter error, held-out shrink, open-set and false-attribution
rates) and a confusion matrix.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from realitygap.core.parallel import Backend, SerialBackend
from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
from realitygap.diagnosis.log import Log
from realitygap.diagnosis.manoeuvres import MANOEUVRES
from realitygap.diagnosis.record import RecordLog
from realitygap.diagnosis.replay import MeasurementNoise, simulate
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import EFFECTS, Reality, make_effect

__all__ = [
    "ARM_HIDDEN_EFFECTS",
    "CLIMBER_HIDDEN_EFFECTS",
    "HIDDEN_BY_ROBOT",
    "HIDDEN_EFFECTS",
    "BlindCase",
    "SuiteSettings",
    "draw_cases",
    "record_case_logs",
    "run_case",
    "summarise",
]

# (param, low, high, symmetric): |deviation from nominal| ~ U(low, high), random sign if symmetric
HIDDEN_EFFECTS: dict[str, tuple[tuple[str, float, float, bool], ...]] = {
    "wheel_radius_scale": (("scale", 0.01, 0.04, True),),
    "wheel_diameter_ratio": (("E_d", 0.004, 0.015, True),),
    "wheelbase_error": (("E_b", 0.015, 0.06, True),),
    "longitudinal_slip": (("mu", 0.15, 0.5, False),),
    "command_latency": (("delay", 0.05, 0.2, False),),
    "motor_deadband": (("threshold", 0.02, 0.06, False),),
    "velocity_saturation": (("v_limit", 0.35, 0.55, False),),
    "encoder_scale": (("scale", 0.01, 0.04, True),),
    "camera_mount_offset": (
        ("dx", 0.005, 0.025, True),
        ("dy", 0.005, 0.025, True),
        ("dyaw", 0.01, 0.05, True),
    ),
    "timestamp_offset": (("offset", 0.04, 0.2, True),),
}
"""Realistic magnitudes of the hidden effects (absolute values for the non-symmetric ones)."""

ARM_HIDDEN_EFFECTS: dict[str, tuple[tuple[str, float, float, bool], ...]] = {
    # joint 1's offset and d1 are invisible to tool-point distances: left at nominal
    "arm_joint_offset": tuple((f"dtheta{k}", 5e-4, 2.5e-3, True) for k in range(2, 7)),
    "arm_link_length": tuple((nm, 2e-4, 1e-3, True) for nm in ("da2", "da3", "dd4", "dd5", "dd6")),
    "arm_parallel_twist": tuple(
        (nm, 3e-4, 1.5e-3, True) for nm in ("beta2", "beta3", "dalpha2", "dalpha3")
    ),
    "arm_tool_offset": tuple((nm, 3e-4, 3e-3, True) for nm in ("dx", "dy", "dz")),
    "arm_twist_error": tuple((f"dalpha{k}", 3e-4, 1.5e-3, True) for k in (1, 4, 5)),
    # wrist 1 carries almost no gravity torque: its compliance stays nominal
    "arm_joint_compliance": (("c2", 1e-5, 4e-5, False), ("c3", 1e-5, 4e-5, False)),
    "arm_backlash": tuple((f"b{k}", 2e-4, 1e-3, False) for k in range(1, 7)),
    "arm_encoder_scale": tuple((f"s{k}", 2e-4, 1e-3, True) for k in range(1, 7)),
}
"""Realistic magnitudes of the arm's hidden effects (joint offsets ~0.1°, lengths ~0.5 mm,
twists ~0.05°, sag of 0.3–1.5 mrad at 30 N·m, play ≤ 1 mrad, encoder scale ≤ 0.1 %)."""

CLIMBER_HIDDEN_EFFECTS: dict[str, tuple[tuple[str, float, float, bool], ...]] = {
    "climber_tether_sag": (("k", 0.001, 0.004, False),),
    "climber_anchor_error": tuple((nm, 0.01, 0.04, True) for nm in ("dx", "dy", "dz")),
    "climber_spool_scale": (("s", 0.004, 0.015, True),),
    "climber_adsorption_gap": (("gap", 0.002, 0.008, False),),
}
"""Realistic magnitudes of the climber's hidden effects: sag of 2.5–10 cm at 5 m, an anchor
surveyed 1–4 cm off, a spool scale off by 0.4–1.5 %, a skirt worn by 2–8 mm. (A tether
stretch reads exactly like a spool-scale error and is not drawn separately; the other
climber effects do not show in tether and ride-height logs, see
:mod:`~realitygap.diagnosis.climb_adapter`.)"""

HIDDEN_BY_ROBOT: dict[str, dict[str, tuple[tuple[str, float, float, bool], ...]]] = {
    "diffdrive": HIDDEN_EFFECTS,
    "arm": ARM_HIDDEN_EFFECTS,
    "climber": CLIMBER_HIDDEN_EFFECTS,
}
"""The hidden-effect table of every robot the suite runs for."""

TRAIN_MANOEUVRES = ("straight_runs", "turns_in_place", "arcs", "accelerations")
HOLDOUT_MANOEUVRES = ("square_cw", "square_ccw", "tour", "hard_starts")


@dataclass(frozen=True)
class SuiteSettings:
    """Settings of the blind suite.

    Attributes
    ----------
    noise : MeasurementNoise
        Motion-capture and camera noise of the recorded logs.
    pair_probability : float
        Chance that a case hides two effects.
    open_set_every : int
        Every this-many-th case withholds a true effect from the library.
    diagnosis : DiagnosisSettings
    robot : str
        ``"diffdrive"``, ``"arm"`` or ``"climber"`` (:data:`HIDDEN_BY_ROBOT`).
    arm_poses : int
        Arm: measured poses per log (one training and one held-out log).
    arm_tracker_noise : float
        Arm: laser-tracker noise per axis (m).
    """

    noise: MeasurementNoise = field(
        default_factory=lambda: MeasurementNoise(
            truth_xy=0.0005, truth_theta=0.001, camera_xy=0.001, camera_theta=0.002
        )
    )
    pair_probability: float = 0.25
    open_set_every: int = 4
    diagnosis: DiagnosisSettings = field(default_factory=DiagnosisSettings)
    robot: str = "diffdrive"
    arm_poses: int = 96
    arm_tracker_noise: float = 2e-5

    def __post_init__(self) -> None:
        if self.robot not in HIDDEN_BY_ROBOT:
            raise ValueError(
                f"the blind suite runs for {', '.join(HIDDEN_BY_ROBOT)}; got robot {self.robot!r}"
            )

    @property
    def hidden_effects(self) -> dict[str, tuple[tuple[str, float, float, bool], ...]]:
        """The hidden-effect table of :attr:`robot`."""
        return HIDDEN_BY_ROBOT[self.robot]


@dataclass(frozen=True)
class BlindCase:
    """One blind case: the hidden truth and what the library lacks."""

    index: int
    truth: tuple[tuple[str, tuple[tuple[str, float], ...]], ...]
    withheld: tuple[str, ...]
    seed: int

    @property
    def truth_names(self) -> tuple[str, ...]:
        return tuple(sorted(name for name, _ in self.truth))

    @property
    def open_set(self) -> bool:
        return bool(self.withheld)

    def reality(self) -> Reality:
        return Reality(tuple(make_effect(n, **dict(v)) for n, v in self.truth))

    def truth_values(self) -> dict[str, float]:
        return {f"{n}.{k}": x for n, vals in self.truth for k, x in vals}


def _draw_values(
    name: str,
    rng: np.random.Generator,
    table: dict[str, tuple[tuple[str, float, float, bool], ...]] | None = None,
) -> tuple[tuple[str, float], ...]:
    out = []
    for param, low, high, symmetric in (table if table is not None else HIDDEN_EFFECTS)[name]:
        nominal = next(s.nominal for s in EFFECTS[name].specs if s.name == param)
        mag = float(rng.uniform(low, high))
        if name in ("longitudinal_slip", "velocity_saturation"):
            value = mag  # drawn directly
        elif symmetric:
            value = nominal + (mag if rng.random() < 0.5 else -mag)
        else:
            value = nominal + mag
        out.append((param, value))
    return tuple(out)


def draw_cases(n: int, seed: int, settings: SuiteSettings | None = None) -> list[BlindCase]:
    """``n`` blind cases from ``np.random.default_rng(seed)``.

    Effects cycle through the library in a shuffled order so every effect is
    hidden about equally often; a quarter of the cases (every
    ``open_set_every``-th) withhold one true effect from the library.
    """
    s = settings if settings is not None else SuiteSettings()
    rng = np.random.default_rng(seed)
    table = s.hidden_effects
    names = list(table)
    order: list[str] = []
    cases = []
    for i in range(n):
        if not order:
            order = list(rng.permutation(names))
        first = order.pop()
        chosen = [first]
        if rng.random() < s.pair_probability:
            others = [x for x in names if x != first]
            chosen.append(str(rng.choice(others)))
        truth = tuple((name, _draw_values(name, rng, table)) for name in chosen)
        withheld: tuple[str, ...] = ()
        if s.open_set_every > 0 and i % s.open_set_every == s.open_set_every - 1:
            withheld = (str(rng.choice(chosen)),)
        cases.append(
            BlindCase(index=i, truth=truth, withheld=withheld, seed=int(rng.integers(2**31)))
        )
    return cases


def _record_env(
    manoeuvre: str, reality: Reality, params: DiffDriveParams, noise: MeasurementNoise, rng: Any
) -> Log:
    from realitygap.envs.wheeled_nav import WheeledNavEnv

    env = WheeledNavEnv(
        reality=reality,
        params=params,
        n_obstacles=0,
        room_half_size=20.0,
        start=(0.0, 0.0, float(rng.uniform(-math.pi, math.pi))),
        goal=(15.0, 15.0, 0.0),
        terminate_on_success=False,
        n_beams=8,
    )
    rec = RecordLog(env, noise=noise, rng=rng, meta={"name": manoeuvre})
    try:
        rec.reset(seed=int(rng.integers(2**31)))
        t, req = MANOEUVRES[manoeuvre].requested(env.dt)
        scale = np.array([params.v_max, params.w_max])
        for k in range(t.shape[0] - 1):
            rec.step(req[k] / scale)
        return rec.log
    finally:
        env.close()


def record_case_logs(
    reality: Reality,
    rng: np.random.Generator,
    noise: MeasurementNoise,
    manoeuvres: Sequence[str],
    params: DiffDriveParams | None = None,
) -> list[Log]:
    """Record ``manoeuvres`` with the robot ``reality``: ramped ones through the env, steps directly."""
    params = params if params is not None else DiffDriveParams()
    logs = []
    for m in manoeuvres:
        man = MANOEUVRES[m]
        if man.ramp:
            logs.append(_record_env(m, reality, params, noise, rng))
        else:
            t, cmd = man.applied(0.05, params)
            start = np.array([0.0, 0.0, float(rng.uniform(-math.pi, math.pi))])
            logs.append(
                simulate(
                    t,
                    params=params,
                    reality=reality,
                    commands=cmd,
                    start=start,
                    noise=noise,
                    rng=rng,
                    meta={"name": m},
                    source=m,
                )
            )
    return logs


def run_case(settings: SuiteSettings, case: BlindCase) -> dict[str, Any]:
    """Record and diagnose one blind case; the outcome as a JSON-able dict."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(case.seed)
    reality = case.reality()
    if settings.robot == "arm":
        from realitygap.diagnosis.arm_adapter import record_arm_log

        train, holdout = (
            [
                record_arm_log(
                    reality,
                    rng,
                    settings.arm_poses,
                    tracker_noise=settings.arm_tracker_noise,
                    name=name,
                )
            ]
            for name in ("arm_train", "arm_holdout")
        )
    elif settings.robot == "climber":
        from realitygap.diagnosis.climb_adapter import record_climber_logs

        train, holdout = record_climber_logs(reality, rng)
    else:
        train = record_case_logs(reality, rng, settings.noise, TRAIN_MANOEUVRES)
        holdout = record_case_logs(reality, rng, settings.noise, HOLDOUT_MANOEUVRES)
    t_rec = time.perf_counter() - t0
    library = tuple(n for n in settings.hidden_effects if n not in case.withheld)
    dset = settings.diagnosis
    dset = DiagnosisSettings(
        robot=settings.robot,
        drive=dset.drive,
        effects=library,
        features=dset.features,
        attribution=dset.attribution,
        sim=dset.sim,
    )
    d = diagnose(train, holdout, settings=dset)
    rows = d.ranking_rows()
    verdict = d.verdict.label
    truth = case.truth_names
    named = tuple(sorted(verdict)) if isinstance(verdict, list) else None
    top = [tuple(sorted(r["effects"])) for r in rows if r["effects"]]
    if case.open_set:
        correct = verdict == "unexplained"
    else:
        correct = named == truth
    param_err: dict[str, float] = {}
    if not case.open_set and named == truth:
        fit = next(r for r in rows if tuple(sorted(r["effects"])) == truth)
        for key, x in case.truth_values().items():
            effect, _, pname = key.partition(".")
            nominal = EFFECTS[effect]().spec(pname).nominal
            dev = abs(x - nominal)
            est = fit["params"][key]["value"]
            param_err[key] = abs(est - x) / dev if dev > 0 else math.nan
    best = rows[0]
    return {
        "index": case.index,
        "truth": {n: dict(v) for n, v in case.truth},
        "truth_names": list(truth),
        "withheld": list(case.withheld),
        "open_set": case.open_set,
        "verdict": verdict,
        "reason": d.verdict.reason,
        "confidence": d.verdict.confidence,
        "correct": bool(correct),
        "top1": (not case.open_set) and bool(top and top[0] == truth),
        "top2": (not case.open_set) and truth in top[:2],
        "best": best["name"],
        "best_params": {k: v["value"] for k, v in best["params"].items()},
        "param_rel_err": param_err,
        "heldout_shrink_pct": float(d.gap["heldout_shrink_pct"]),
        "heldout_shrink_pct_best": float(d.gap["heldout_shrink_pct_best"]),
        "ambiguous_with": d.verdict.ambiguous_with,
        "seconds_record": t_rec,
        "seconds_diagnose": d.timing["total"],
    }


def _case_task(settings: SuiteSettings, case: BlindCase) -> dict[str, Any]:
    return run_case(settings, case)


def run_suite(
    cases: Sequence[BlindCase],
    settings: SuiteSettings | None = None,
    backend: Backend | None = None,
    progress: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """Run cases (in parallel through ``backend``) and return their outcomes in order."""
    s = settings if settings is not None else SuiteSettings()
    be = backend if backend is not None else SerialBackend()
    say = progress if progress is not None else (lambda m: None)
    say(f"{len(cases)} blind cases on the {be.name} backend")
    out = be.map(_case_task, list(cases), s)
    for r in out:
        mark = "ok " if r["correct"] else "BAD"
        say(
            f"case {r['index']:2d} {mark} truth={'+'.join(r['truth_names'])}"
            f"{' (withheld ' + r['withheld'][0] + ')' if r['open_set'] else ''} → {r['verdict']}"
        )
    return out


def summarise(outcomes: Sequence[dict[str, Any]]) -> tuple[dict[str, float], dict[str, Any]]:
    """The suite's figures and tables (confusion matrix, per-case rows)."""
    closed = [o for o in outcomes if not o["open_set"]]
    opened = [o for o in outcomes if o["open_set"]]
    errs = [e for o in closed for e in o["param_rel_err"].values() if math.isfinite(e)]
    false_attr = [
        o
        for o in outcomes
        if isinstance(o["verdict"], list)
        and (o["open_set"] or tuple(sorted(o["verdict"])) != tuple(o["truth_names"]))
    ]
    figures = {
        "n_cases": float(len(outcomes)),
        "top1_accuracy": float(np.mean([o["top1"] and o["correct"] for o in closed]))
        if closed
        else math.nan,
        "top2_accuracy": float(np.mean([o["top2"] for o in closed])) if closed else math.nan,
        "param_rel_err_median": float(np.median(errs)) if errs else math.nan,
        "heldout_shrink_pct_median": float(np.median([o["heldout_shrink_pct"] for o in closed]))
        if closed
        else math.nan,
        "open_set_unexplained_rate": float(np.mean([o["verdict"] == "unexplained" for o in opened]))
        if opened
        else math.nan,
        "false_attribution_rate": len(false_attr) / len(outcomes) if outcomes else math.nan,
    }

    def label_truth(o: dict[str, Any]) -> str:
        name = "+".join(o["truth_names"])
        return f"{name} (withheld {o['withheld'][0]})" if o["open_set"] else name

    def label_verdict(o: dict[str, Any]) -> str:
        v = o["verdict"]
        return "+".join(sorted(v)) if isinstance(v, list) else str(v)

    confusion: dict[str, dict[str, int]] = {}
    for o in outcomes:
        row = confusion.setdefault(label_truth(o), {})
        col = label_verdict(o)
        row[col] = row.get(col, 0) + 1
    tables = {
        "confusion": [
            {"truth": t, **{f"→ {k}": v for k, v in sorted(cols.items())}}
            for t, cols in sorted(confusion.items())
        ],
        "cases": [
            {
                "index": o["index"],
                "truth": o["truth"],
                "withheld": o["withheld"],
                "verdict": o["verdict"],
                "correct": o["correct"],
                "best": o["best"],
                "best_params": o["best_params"],
                "param_rel_err": o["param_rel_err"],
                "heldout_shrink_pct": o["heldout_shrink_pct"],
                "reason": o["reason"],
            }
            for o in outcomes
        ],
    }
    return figures, tables
