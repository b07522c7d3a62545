"""realitygap: Gymnasium robot environments on PyBullet and a sim-to-real gap diagnosis tool.

Importing the package registers its environments with Gymnasium::

    import gymnasium as gym
    import realitygap  # noqa: F401

    env = gym.make("realitygap/WheeledNav-v0")
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from realitygap.cards import ENV_CARDS, EnvCard, card_for

__version__ = "0.1.0"

ENV_IDS: tuple[str, ...] = tuple(ENV_CARDS)
"""Every environment id this package registers."""

for _card in ENV_CARDS.values():
    if _card.env_id not in registry:
        register(
            id=_card.env_id,
            entry_point=_card.entry_point,
            max_episode_steps=_card.max_episode_steps,
        )

if "realitygap/WheeledNavVec-v0" not in registry:
    register(
        id="realitygap/WheeledNavVec-v0",
        vector_entry_point="realitygap.envs.vector_nav:WheeledNavVecEnv",
        max_episode_steps=1200,
    )

__all__ = ["ENV_CARDS", "ENV_IDS", "EnvCard", "__version__", "card_for"]
