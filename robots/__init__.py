"""PyBullet worlds, robots, sensors and effects (the only layer that imports PyBullet).

PyBullet prints its build time (on standard error) when it is first imported; it is
imported here, once, with that line silenced, so that command output stays clean.
"""

from __future__ import annotations

from realitygap.core.progress import quiet_c_output

with quiet_c_output():
    import pybullet  # noqa: F401
