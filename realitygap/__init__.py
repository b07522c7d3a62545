"""realitygap: Gymnasium robot environments on PyBullet and a sim-to-real gap diagnosis tool.

Importing the package registers its environments with Gymnasium::

    import gymnasium as gym
    import realitygap  # noqa: F401

    env = gym.make("realitygap/WheeledNav-v0")
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"

ENV_IDS: tuple[str, ...] = (
    "realitygap/WheeledNav-v0",
    "realitygap/ArmCalib-v0",
    "realitygap/WallClimb-v0",
)
"""Every environment id this package registers."""

_ENTRY_POINTS = {
    "realitygap/WheeledNav-v0": ("realitygap.envs.wheeled_nav:WheeledNavEnv", 1200),
    "realitygap/ArmCalib-v0": ("realitygap.envs.arm_calib:ArmCalibEnv", 200),
    "realitygap/WallClimb-v0": ("realitygap.envs.wall_climb:WallClimbEnv", 1200),
}

for _env_id, (_entry, _steps) in _ENTRY_POINTS.items():
    if _env_id not in registry:
        register(id=_env_id, entry_point=_entry, max_episode_steps=_steps)

__all__ = ["ENV_IDS", "__version__"]
