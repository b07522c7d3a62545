"""Robots in the diagnosis: the one adapter contract (``contract.py``), the registry from robot
names to adapters (``registry.py``) and one folder per robot (``diffdrive/``, ``arm/``,
``climber/``). Importing this package loads no robot."""
