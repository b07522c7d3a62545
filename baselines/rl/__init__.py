"""Learned baselines: stable-baselines3 PPO and SAC for every registered environment.

=================  ===========================================================================
module             contents
=================  ===========================================================================
``config``         algorithms, hyperparameter files and their keys, the curriculum, run settings
``features``       observation feature maps and action maps that are part of a policy
``wrappers``       training-only wrappers (feature maps, reward shaping, start states)
``policy_io``      :class:`PolicyIO` and :class:`ObsNormalizer`: the policy around its network
``vec_env``        seeded vectorised training envs
``callbacks``      the training callback and deterministic evaluation
``training``       :func:`train`
``persistence``    saving, exporting, loading and shipping policies; run files
``plots``          learning-curve figures
=================  ===========================================================================

How the shipped policies were trained is told in ``docs/baselines.md``.
"""

from __future__ import annotations

from realitygap.baselines.rl.callbacks import evaluate_model, make_callback
from realitygap.baselines.rl.config import (
    ALGOS,
    EVAL_SEED_OFFSET,
    HYPERPARAMS_DIR,
    POLICIES_DIR,
    TRAIN_KEYS,
    VECTOR_ENVS,
    Curriculum,
    TrainConfig,
    TrainResult,
    algo_class,
    check_algo,
    check_env_id,
    check_gate,
    env_slug,
    load_hyperparams,
    require_sb3,
    resolve_policy_kwargs,
    vector_env_id,
)
from realitygap.baselines.rl.features import (
    BEARING_FADE,
    OBS_FEATURES,
    OBS_FEATURES_DROP,
    WHEELED_NAV_SCENE_START,
    WORLD_FRAME_COLUMNS,
    ZOOM_ANG_SCALES,
    ZOOM_POS_SCALES,
    deadband,
    obs_feature_fn,
    scene_fade,
    stop_gate,
    wheeled_nav_egocentric_features,
    wheeled_nav_egocentric_mirror,
    wheeled_nav_goal_features,
    wheeled_nav_goal_smooth_features,
    wheeled_nav_goal_zoom_features,
)
from realitygap.baselines.rl.persistence import (
    LearnedPolicy,
    check_policy_matches,
    export_policy,
    jsonable,
    load_policy,
    read_csv,
    read_policy_meta,
    save_policy,
    ship_policy,
    shipped_policy,
    space_summary,
    write_csv_atomic,
)
from realitygap.baselines.rl.plots import (
    learning_curve_files,
    plot_learning_curve,
    plot_learning_curves,
)
from realitygap.baselines.rl.policy_io import OBS_MIRRORS, ObsNormalizer, PolicyIO
from realitygap.baselines.rl.training import train
from realitygap.baselines.rl.vec_env import (
    make_env_fn,
    make_vec_env,
    make_vector_train_env,
    measure_vec_env_speed,
    sb3_vector_env,
)
from realitygap.baselines.rl.wrappers import (
    TRAIN_WRAPPERS,
    ArmObservabilityShaping,
    AttributeSetter,
    ObsFeatures,
    WheeledNavDockingStarts,
    WheeledNavRestRelaxation,
    WheeledNavShaping,
    apply_train_wrappers,
    check_train_wrappers,
    set_env_attrs,
    wheeled_nav_potential,
)

__all__ = [
    "ALGOS",
    "BEARING_FADE",
    "EVAL_SEED_OFFSET",
    "HYPERPARAMS_DIR",
    "OBS_FEATURES",
    "OBS_FEATURES_DROP",
    "OBS_MIRRORS",
    "POLICIES_DIR",
    "TRAIN_KEYS",
    "TRAIN_WRAPPERS",
    "VECTOR_ENVS",
    "WHEELED_NAV_SCENE_START",
    "WORLD_FRAME_COLUMNS",
    "ZOOM_ANG_SCALES",
    "ZOOM_POS_SCALES",
    "ArmObservabilityShaping",
    "AttributeSetter",
    "Curriculum",
    "LearnedPolicy",
    "ObsFeatures",
    "ObsNormalizer",
    "PolicyIO",
    "TrainConfig",
    "TrainResult",
    "WheeledNavDockingStarts",
    "WheeledNavRestRelaxation",
    "WheeledNavShaping",
    "algo_class",
    "apply_train_wrappers",
    "check_algo",
    "check_env_id",
    "check_gate",
    "check_policy_matches",
    "check_train_wrappers",
    "deadband",
    "env_slug",
    "evaluate_model",
    "export_policy",
    "jsonable",
    "learning_curve_files",
    "load_hyperparams",
    "load_policy",
    "make_callback",
    "make_env_fn",
    "make_vec_env",
    "make_vector_train_env",
    "measure_vec_env_speed",
    "obs_feature_fn",
    "plot_learning_curve",
    "plot_learning_curves",
    "read_csv",
    "read_policy_meta",
    "require_sb3",
    "resolve_policy_kwargs",
    "save_policy",
    "sb3_vector_env",
    "scene_fade",
    "set_env_attrs",
    "ship_policy",
    "shipped_policy",
    "space_summary",
    "stop_gate",
    "train",
    "vector_env_id",
    "wheeled_nav_egocentric_features",
    "wheeled_nav_egocentric_mirror",
    "wheeled_nav_goal_features",
    "wheeled_nav_goal_smooth_features",
    "wheeled_nav_goal_zoom_features",
    "wheeled_nav_potential",
    "write_csv_atomic",
]
