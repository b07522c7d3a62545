"""A second, independent simulator of a differential drive and a UR10 with a laser tracker.

It shares no code with the package's robots, envs or diagnosis: its kinematics,
actuators, contact, timing and noise are its own, and it writes the recorded-data
formats (OptiOdom sessions, UR10 laser-tracker series) from their on-disk layout.
:mod:`realitygap.independent.cases` lists the hidden effects it can plant.
"""

from __future__ import annotations
