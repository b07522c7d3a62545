"""Policies (classical and learned), training and the benchmark harness."""

from realitygap.baselines.classical import ClassicalNavConfig, ClassicalNavPolicy

__all__ = ["ClassicalNavConfig", "ClassicalNavPolicy"]
