"""Localisation of a climbing robot on a CAD-known surface: VIO, tether and adsorption.

Measurements (produced by the robot layer): :class:`ImuSample`, :class:`CameraFrame`,
:class:`RelativeMotion` (visual motion in the fast geometric mode),
:class:`TetherReading`. Output: :class:`ClimbEstimate` (position + ``quat_xyzw``).

Pipeline (:class:`ClimbLocaliser`): :class:`SlidingWindowVIO` → excitation path →
:func:`initialise_global_pose` (anchor by :func:`solve_anchor`, yaw by Algorithm 1 on
the :class:`SurfaceModel`) → :class:`ConstrainedEstimator` (VIO increments + tether +
adsorption constraints) in the CAD frame.

:mod:`realitygap.robots.climb_synthetic` synthesises recordings on the blade (a fast
geometric sensor model) and computes the drift figures with these estimators.
"""

from __future__ import annotations

from realitygap.estimators.climb.anchor import (
    AnchorSolution,
    fit_plane,
    solve_anchor,
    solve_anchor_with_plane,
)
from realitygap.estimators.climb.constrained import ConstrainedConfig, ConstrainedEstimator
from realitygap.estimators.climb.frontend import relative_motion_from_images
from realitygap.estimators.climb.global_init import (
    GlobalInit,
    PlaneConstraint,
    initialise_global_pose,
)
from realitygap.estimators.climb.localiser import ClimbLocaliser, LocaliserConfig, LocaliserPhase
from realitygap.estimators.climb.measurements import (
    CameraFrame,
    ClimbEstimate,
    ImuSample,
    RelativeMotion,
    TetherReading,
)
from realitygap.estimators.climb.preintegration import (
    Preintegration,
    StaticInit,
    static_initialise,
)
from realitygap.estimators.climb.surface import Projection, SurfaceModel
from realitygap.estimators.climb.vio import SlidingWindowVIO, VioConfig

__all__ = [
    "AnchorSolution",
    "CameraFrame",
    "ClimbEstimate",
    "ClimbLocaliser",
    "ConstrainedConfig",
    "ConstrainedEstimator",
    "GlobalInit",
    "ImuSample",
    "LocaliserConfig",
    "LocaliserPhase",
    "PlaneConstraint",
    "Preintegration",
    "Projection",
    "RelativeMotion",
    "SlidingWindowVIO",
    "StaticInit",
    "SurfaceModel",
    "TetherReading",
    "VioConfig",
    "fit_plane",
    "initialise_global_pose",
    "relative_motion_from_images",
    "solve_anchor",
    "solve_anchor_with_plane",
    "static_initialise",
]
