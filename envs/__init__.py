"""Gymnasium environments: robot + task + observation pipeline."""

from realitygap.envs.wheeled_nav import NAV8_STARTS, WheeledNavEnv

__all__ = ["NAV8_STARTS", "WheeledNavEnv"]
