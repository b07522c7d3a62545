"""Arm-calibration experiments: ``arm002``, ``arm-real``, ``arm-policy``.

``arm002``
    Seed 002's monocular calibration in simulation. A true arm with realistic
    geometric errors (joint offsets ~0.1°, lengths ~0.5 mm, Hayati twists β
    ~0.05° on the parallel rows, twists α ~0.05°, hand–eye ~1 mm) is calibrated
    from images rendered by PyBullet's TinyRenderer (blur, noise) of the coded
    board: poses chosen by the observability-greedy policy, camera poses by
    :func:`measure_board`, hierarchical displacements between all pose pairs,
    MDH identification on distance residuals. Reported on the env's held-out
    validation poses against the true arm; the same pair data fitted with
    classical DH (no β) for comparison.

``arm-real``
    The identification on measured arms: every ``Series_*/measurements_*.csv``
    of the UR10 laser-tracker set (position residuals, registration and probe
    offset estimated) and every ``*.npz`` of the FR3 eye-in-hand set (camera
    poses against a board; displacement residuals after an AX = XB start),
    calibrated on the even-numbered poses and reported on the odd-numbered ones.
    A garbled file stops the run with the file, line and column at fault.

``arm-policy``
    Observability-greedy against random pose selection (both from the same pool
    of poses the nominal model expects to see the board from) at equal budgets
    ``K``: held-out positioning error after the campaign and the smallest
    singular value of the pair Jacobian of the poses measured (fixed column
    scaling), over seeded campaigns.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from realitygap.experiments import RunContext, experiment

__all__ = ["arm002", "arm_policy", "arm_real", "run_campaign"]


def run_campaign(env: Any, policy: Any, seed: int) -> dict[str, Any]:
    """One seeded campaign of ``policy`` in an ``ArmCalib-v0`` env; the last step's info plus
    wall time and the joint readings of the poses measured."""
    obs, info = env.reset(seed=seed)
    start = True
    t0 = time.perf_counter()
    done = False
    while not done:
        action, _ = policy.predict(obs, episode_start=np.array([start]), deterministic=True)
        start = False
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    e = env.unwrapped
    out = dict(info)
    out["wall_seconds"] = time.perf_counter() - t0
    out["q_measured"] = np.array([m.q for m in e.estimator.measurements])
    return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


# =============================================================================
@experiment(
    "arm002",
    "seed 002: MDH calibration of a 6-DOF arm from rendered images of a coded board",
)
def arm002(ctx: RunContext) -> dict[str, Any]:
    from realitygap.baselines.arm_policy import GreedyConfig, ObservabilityGreedyPolicy
    from realitygap.envs.arm_calib import ArmCalibEnv, random_arm_reality
    from realitygap.estimators.arm.identification import IdentificationSettings, identify

    budget = int(ctx.options.get("budget", 20 if ctx.quick else 40))
    mode = str(ctx.options.get("sensor_mode", "image"))
    reality = random_arm_reality(np.random.default_rng(ctx.seed))
    env = ArmCalibEnv(
        sensor_mode=mode,
        reality=reality,
        budget=budget,
        identify_every=budget,  # one identification, at the end of the campaign
        n_validation=60,
    )
    try:
        ctx.progress(f"arm002: {budget} poses, {mode} capture, greedy pose selection")
        policy = ObservabilityGreedyPolicy.from_env(env, GreedyConfig(pool_seed=ctx.seed + 7))
        info = run_campaign(env, policy, ctx.seed)
        est = env.estimator.estimate
        if not est.identified or est.result is None:
            raise RuntimeError(f"arm002: no calibration was adopted ({est.status})")
        res = est.result
        err_nom = env.validation_errors(env.params.mdh, env.tool0)
        err_cal = env.validation_errors(res.table, res.tool)
        # the same pair data with the classical DH model (beta held at 0)
        pairs = env.estimator.pair_observations()
        t0 = time.perf_counter()
        dh = identify(
            env.params.mdh,
            pairs,
            tool=env.tool0,
            settings=IdentificationSettings(mode="distance", param_set="dh"),
        )
        dh_seconds = time.perf_counter() - t0
        err_dh = env.validation_errors(dh.table, dh.tool)
        true = env.true_params.mdh.param_dict()
        nom = env.params.mdh.param_dict()
        got = res.table.param_dict()
        rel = [
            abs(got[n] - true[n]) / abs(true[n] - nom[n])
            for n in res.free_params
            if n in true and abs(true[n] - nom[n]) > 1e-9
        ]
        calib_seconds = env.measure_seconds + env.estimator.identify_seconds
        figures = {
            "rms_err_mm_nominal": 1e3 * _rms(err_nom),
            "rms_err_mm_calibrated": 1e3 * _rms(err_cal),
            "max_err_mm_calibrated": 1e3 * float(np.max(err_cal)),
            "param_rel_err_median": float(np.median(rel)) if rel else math.nan,
            "dh_vs_mdh_rms_mm": 1e3 * _rms(err_dh),
            "poses_used": int(info["poses_used"]),
            "calib_seconds": float(calib_seconds),
        }
        rows = [
            {
                "param": n,
                "nominal": nom[n],
                "true": true[n],
                "estimated": got[n],
                "std": res.std.get(n, math.nan),
            }
            for n in res.free_params
            if n in true
        ]
        notes = [
            f"goal: calibrated RMS <= 0.1 mm and max <= 0.3 mm on {len(err_cal)} held-out "
            f"poses: {'met' if figures['rms_err_mm_calibrated'] <= 0.1 and figures['max_err_mm_calibrated'] <= 0.3 else 'NOT met'}",
            f"fixed (not identifiable from distances): {', '.join(res.fixed_params)}",
            f"DH fit rms {1e3 * dh.rms_after:.4f} mm vs MDH {1e3 * res.rms_after:.4f} mm on the "
            "training pairs",
            f"rendering took {env.capture_seconds:.1f} s (simulator, not part of calib_seconds)",
        ]
        return {
            "figures": figures,
            "config": {
                "budget": budget,
                "sensor_mode": mode,
                "reality": reality.to_dict(),
                "n_validation": len(err_cal),
                "attempts": int(info["attempts"]),
                "campaign_wall_seconds": float(info["wall_seconds"]),
                "dh_seconds": dh_seconds,
                "condition_number": res.condition_number,
            },
            "tables": {"parameters": rows},
            "notes": notes,
        }
    finally:
        env.close()


# =============================================================================
@experiment(
    "arm-real",
    "UR10 laser tracker and FR3 eye-in-hand: MDH calibration on half the poses, held-out error",
    data_subdir="ipa_ur10_lasertracker",
)
def arm_real(ctx: RunContext) -> dict[str, Any]:
    from realitygap.diagnosis.logs.importers.franka import read_franka_npz
    from realitygap.diagnosis.logs.importers.ur10 import read_ur10_dataset
    from realitygap.estimators.arm.calibration import calibrate_fr3, calibrate_ur10

    ur_root = ctx.data_subdir("ipa_ur10_lasertracker")
    fr_root = ctx.data_subdir("franka_fr3_eyeinhand")
    tables: dict[str, list[dict[str, Any]]] = {"ur10": [], "fr3": []}
    notes: list[str] = []

    ds = read_ur10_dataset(ur_root)  # garbled files raise naming file, line, column
    sq_nom = sq_cal = 0.0
    n_ur = 0
    for s in ds.series:
        idx = np.arange(s.n)
        if ctx.quick and s.n > 2000:
            idx = idx[:: int(math.ceil(s.n / 2000))]
        if idx.size < 20:
            raise ValueError(f"{s.source}: {idx.size} poses are too few to calibrate and test")
        ctx.progress(f"UR10 {s.name}: {idx.size} poses")
        rep = calibrate_ur10(s, idx[0::2], idx[1::2])
        sq_nom += rep.n_test * rep.nominal.rms**2
        sq_cal += rep.n_test * rep.calibrated.rms**2
        n_ur += rep.n_test
        tables["ur10"].append(
            {
                "series": s.name,
                "n_train": rep.n_train,
                "n_test": rep.n_test,
                "nominal_rms_mm": 1e3 * rep.nominal.rms,
                "calibrated_rms_mm": 1e3 * rep.calibrated.rms,
                "nominal_median_mm": 1e3 * rep.nominal.median,
                "calibrated_median_mm": 1e3 * rep.calibrated.median,
                "calibrated_max_mm": 1e3 * rep.calibrated.max,
            }
        )

    files = sorted(Path(fr_root).glob("*.npz"))
    if not files:
        raise FileNotFoundError(f"no *.npz eye-in-hand file under {fr_root}")
    sq_nom_f = sq_cal_f = 0.0
    n_fr = 0
    for f in files:
        data = read_franka_npz(f)
        if data.joint_positions.shape[1] != 7:
            raise ValueError(
                f"{f.name}: expected 7 joint positions per pose (FR3), got "
                f"{data.joint_positions.shape[1]}"
            )
        if data.n < 20:
            raise ValueError(f"{f.name}: {data.n} poses are too few to calibrate and test")
        ctx.progress(f"FR3 {f.name}: {data.n} poses")
        idx = np.arange(data.n)
        rep = calibrate_fr3(data, idx[0::2], idx[1::2])
        n_pairs = rep.calibrated.n
        sq_nom_f += n_pairs * rep.nominal.rms**2
        sq_cal_f += n_pairs * rep.calibrated.rms**2
        n_fr += n_pairs
        tables["fr3"].append(
            {
                "file": f.name,
                "n_train": rep.n_train,
                "n_test": rep.n_test,
                "test_pairs": n_pairs,
                "nominal_rms_mm": 1e3 * rep.nominal.rms,
                "calibrated_rms_mm": 1e3 * rep.calibrated.rms,
                "nominal_median_mm": 1e3 * rep.nominal.median,
                "calibrated_median_mm": 1e3 * rep.calibrated.median,
            }
        )
    figures = {
        "ur10_heldout_err_mm_nominal": 1e3 * math.sqrt(sq_nom / n_ur),
        "ur10_heldout_err_mm_calibrated": 1e3 * math.sqrt(sq_cal / n_ur),
        "fr3_heldout_dist_err_mm_nominal": 1e3 * math.sqrt(sq_nom_f / n_fr),
        "fr3_heldout_dist_err_mm_calibrated": 1e3 * math.sqrt(sq_cal_f / n_fr),
    }
    for arm, a, b in (
        ("UR10", "ur10_heldout_err_mm_nominal", "ur10_heldout_err_mm_calibrated"),
        ("FR3", "fr3_heldout_dist_err_mm_nominal", "fr3_heldout_dist_err_mm_calibrated"),
    ):
        ratio = figures[a] / max(figures[b], 1e-12)
        notes.append(
            f"{arm}: held-out error reduced {ratio:.1f}x (goal: at least 2x): "
            f"{'met' if ratio >= 2.0 else 'NOT met'}"
        )
    notes.append(
        "UR10: 3-D probe error after a rigid registration refitted on the held-out poses; "
        "FR3: distance-accuracy error over all pairs of held-out poses (RMS over all series/files)"
    )
    return {
        "figures": figures,
        "config": {
            "split": "even poses train, odd poses test",
            "ur10_series": [s.name for s in ds.series],
            "fr3_files": [f.name for f in files],
            "ur10_test_poses": n_ur,
            "fr3_test_pairs": n_fr,
        },
        "tables": tables,
        "notes": notes,
    }


# =============================================================================
@experiment(
    "arm-policy",
    "observability-greedy vs random pose selection at equal budget K: held-out error",
)
def arm_policy(ctx: RunContext) -> dict[str, Any]:
    from realitygap.baselines.arm_policy import (
        GreedyConfig,
        ObservabilityGreedyPolicy,
        RandomPosePolicy,
    )
    from realitygap.envs.arm_calib import ArmCalibEnv, random_arm_reality

    budgets = tuple(ctx.options.get("budgets", (10, 20) if ctx.quick else (10, 20, 40)))
    n_seeds = int(ctx.options.get("seeds", 2 if ctx.quick else 4))
    mode = str(ctx.options.get("sensor_mode", "geometric" if ctx.quick else "fast"))
    figures: dict[str, Any] = {}
    rows: list[dict[str, Any]] = []
    for K in budgets:
        res: dict[str, list[tuple[float, float, float]]] = {"greedy": [], "random": []}
        for s in range(n_seeds):
            seed = ctx.seed + s
            env = ArmCalibEnv(
                sensor_mode=mode,
                reality=random_arm_reality(np.random.default_rng(1000 + seed)),
                budget=K,
                identify_every=K,
            )
            try:
                greedy = ObservabilityGreedyPolicy.from_env(env, GreedyConfig(pool_seed=7))
                model = greedy.obs_model
                policies = {
                    "greedy": greedy,
                    "random": RandomPosePolicy.from_env(env, seed=seed, pool_seed=7),
                }
                for name, pol in policies.items():
                    info = run_campaign(env, pol, seed)
                    sv = model.singular_values_of(info["q_measured"])
                    res[name].append((info["validation_rms_mm"], float(sv[-1]), info["poses_used"]))
                    rows.append(
                        {
                            "K": K,
                            "seed": seed,
                            "policy": name,
                            "validation_rms_mm": info["validation_rms_mm"],
                            "validation_max_mm": info["validation_max_mm"],
                            "sigma_min": float(sv[-1]),
                            "poses_used": info["poses_used"],
                            "estimate_status": info["estimate_status"],
                            "wall_seconds": info["wall_seconds"],
                        }
                    )
                    ctx.progress(
                        f"K={K} seed={seed} {name}: {info['validation_rms_mm']:.4f} mm, "
                        f"sigma_min {sv[-1]:.3g}"
                    )
            finally:
                env.close()
        for name in ("greedy", "random"):
            arr = np.array(res[name], dtype=float)
            figures[f"val_rms_mm_{name}_K{K}"] = float(np.mean(arr[:, 0]))
            figures[f"sigma_min_{name}_K{K}"] = float(np.mean(arr[:, 1]))
        figures[f"greedy_better_K{K}"] = int(
            sum(g[0] < r[0] for g, r in zip(res["greedy"], res["random"]))
        )
    return {
        "figures": figures,
        "config": {"budgets": budgets, "seeds": n_seeds, "sensor_mode": mode, "pool_size": 600},
        "tables": {"campaigns": rows},
        "notes": [
            "both policies draw from the same pool of poses the nominal model expects to see the "
            "board from; val_rms_mm_* is the mean held-out positioning error over seeds, "
            "greedy_better_K* counts seeds where greedy beat random",
        ],
    }
