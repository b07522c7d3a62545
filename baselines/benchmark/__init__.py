"""The benchmark harness: every policy on identical seeded episodes, nominal and "real".

Every policy — classical pipeline, trained PPO/SAC, uniform random — goes
through one episode loop (:func:`run_episode`) that calls SB3's
``predict(obs, state, episode_start, deterministic=True)`` and also collects
the env's ``info``. For each environment, policy, reality profile and sensor
mode the harness runs the same episode seeds, so differences in the table are
the policies', and the drop from the nominal robot to a reality profile is each
policy's own sim-to-real drop.

Reality profiles are named sets of effects (:data:`REALITY_PROFILES`), e.g.
``kobuki-worn``: right wheel 2 % larger than the left, wheelbase 4 % wider, 60 ms
command latency. A JSON file in :meth:`Reality.to_dict` format works as well.

Episode metrics (:func:`run_episode`)

======================  =====================================================
``success``             the env reported ``is_success`` (default criterion)
``reached_10cm``        the true position came within 10 cm of the goal before
                        any collision (a looser figure)
``final_pos_error_cm``  true position error at the end (cm)
``final_heading_deg``   true heading error at the end (deg)
``path_length_m``       length of the true path (m)
``time_to_goal_s``      time of the first success (s; successful episodes only)
``collision``           the robot touched an obstacle or wall (or detached, climber)
``effort``              mean squared action, ``mean(|a|²)`` (normalised units)
``jerk``                mean ``|a_t − 2a_{t−1} + a_{t−2}| / dt²`` (1/s²), normalised
``compute_ms``          mean wall time of one ``predict`` call (ms)
``error``               the exception that ended the episode, if the policy or env raised
                        one (the episode counts as failed; its other metrics are NaN)
======================  =====================================================

Aggregates per cell are mean ± standard deviation and a 95 % confidence
interval: Student-t for continuous metrics, Wilson score for rates.

Results are streamed: each finished episode is appended to ``episodes.jsonl``
(flushed and synced) as soon as it ends, so a crashed worker or an interrupted
run loses nothing that finished, and a re-run with the same output folder
resumes where it stopped. Tables (CSV, Markdown) and plots are written
atomically at the end.

Backends: ``local`` (this process, or a pool of ``workers`` processes) and
``ray`` (a local Ray cluster by default, ``address`` for a real one; installed
with ``pip install 'realitygap[ray]'``).
"""

from __future__ import annotations

from realitygap.baselines.benchmark.config import BenchmarkConfig, episode_seeds, n_episodes
from realitygap.baselines.benchmark.policies import (
    POLICY_KINDS,
    PolicySpec,
    RandomPolicy,
    build_policy,
    parse_policies,
    resolve_learned_paths,
)
from realitygap.baselines.benchmark.profiles import (
    REALITY_PROFILES,
    SENSOR_MODES,
    check_reality_applies,
    default_realities,
    env_keywords,
    env_sensor_mode,
    profile_robot,
    reality_for,
    reality_from_profile,
    simulator_kwargs,
)
from realitygap.baselines.benchmark.report import markdown_report, plot_success
from realitygap.baselines.benchmark.runner import (
    INSTALL_RAY,
    RAY_MISSING,
    BenchmarkResult,
    ChunkTask,
    Progress,
    ResultStore,
    check_run_options,
    execute,
    iter_chunk,
    plan_tasks,
    require_ray,
    run_benchmark,
    run_chunk,
    run_episode,
)
from realitygap.baselines.benchmark.stats import (
    METRICS,
    RATE_METRICS,
    REACHED_RADIUS,
    difference_interval,
    extra_metrics,
    mode_gap_rows,
    record_key,
    summarise,
    t_interval,
    transfer_rows,
    wilson_interval,
)

__all__ = [
    "INSTALL_RAY",
    "METRICS",
    "POLICY_KINDS",
    "RATE_METRICS",
    "RAY_MISSING",
    "REACHED_RADIUS",
    "REALITY_PROFILES",
    "SENSOR_MODES",
    "BenchmarkConfig",
    "BenchmarkResult",
    "ChunkTask",
    "PolicySpec",
    "Progress",
    "RandomPolicy",
    "ResultStore",
    "build_policy",
    "check_reality_applies",
    "check_run_options",
    "default_realities",
    "difference_interval",
    "env_keywords",
    "env_sensor_mode",
    "episode_seeds",
    "execute",
    "extra_metrics",
    "iter_chunk",
    "markdown_report",
    "mode_gap_rows",
    "n_episodes",
    "parse_policies",
    "plan_tasks",
    "plot_success",
    "profile_robot",
    "reality_for",
    "reality_from_profile",
    "record_key",
    "require_ray",
    "resolve_learned_paths",
    "run_benchmark",
    "run_chunk",
    "run_episode",
    "simulator_kwargs",
    "summarise",
    "t_interval",
    "transfer_rows",
    "wilson_interval",
]
