"""Gymnasium environments: robot + task + observation pipeline."""

from realitygap.envs.arm_calib import ArmCalibEnv
from realitygap.envs.wall_climb import WallClimbEnv
from realitygap.envs.wheeled_nav import NAV8_STARTS, WheeledNavEnv

__all__ = ["NAV8_STARTS", "ArmCalibEnv", "WallClimbEnv", "WheeledNavEnv"]
