"""Classical navigation controllers (pure numpy / scipy / CasADi).

The classical wheeled-navigation pipeline chains them:
:class:`ImprovedAPF` way-points → :func:`smooth_path` → :class:`TimedReference`
tracked by :class:`KanayamaTracker` → :class:`PolarStabiliser` onto the goal pose,
every command passed through :meth:`VelocityLimits.clip`.
"""

from __future__ import annotations

from realitygap.controllers.apf import APFOutcome, APFParams, APFResult, ImprovedAPF
from realitygap.controllers.paths import (
    grid_shortest_path,
    grid_shortest_path_length,
    path_length,
    points_from_occupancy,
    segment_clearance,
    shortcut_waypoints,
)
from realitygap.controllers.smoothing import (
    QP_SOLVERS,
    SmoothPath,
    available_qp_solvers,
    smooth_path,
)
from realitygap.controllers.tracking import (
    KanayamaTracker,
    PolarStabiliser,
    ReferenceSample,
    TimedReference,
    VelocityLimits,
    polar_coordinates,
    tracking_error,
    unicycle_step,
)

__all__ = [
    "QP_SOLVERS",
    "APFOutcome",
    "APFParams",
    "APFResult",
    "ImprovedAPF",
    "KanayamaTracker",
    "PolarStabiliser",
    "ReferenceSample",
    "SmoothPath",
    "TimedReference",
    "VelocityLimits",
    "available_qp_solvers",
    "grid_shortest_path",
    "grid_shortest_path_length",
    "path_length",
    "points_from_occupancy",
    "polar_coordinates",
    "segment_clearance",
    "shortcut_waypoints",
    "smooth_path",
    "tracking_error",
    "unicycle_step",
]
