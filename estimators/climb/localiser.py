"""Online localisation of a climbing robot: VIO, global initialisation, constrained tracking.

:class:`ClimbLocaliser` composes :class:`.SlidingWindowVIO`, the global
initialisation (:func:`.initialise_global_pose`) and
:class:`.ConstrainedEstimator` into one online estimator; :class:`LocaliserConfig`
holds its settings and :class:`LocaliserPhase` names its phases.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import quat_xyzw_from_matrix
from realitygap.estimators.climb.constrained import ConstrainedConfig, ConstrainedEstimator
from realitygap.estimators.climb.global_init import (
    GlobalInit,
    PlaneConstraint,
    initialise_global_pose,
)
from realitygap.estimators.climb.measurements import (
    CameraFrame,
    ClimbEstimate,
    ImuSample,
    RelativeMotion,
    TetherReading,
)
from realitygap.estimators.climb.surface import SurfaceModel
from realitygap.estimators.climb.vio import SlidingWindowVIO, VioConfig

FloatArray = npt.NDArray[np.float64]

__all__ = ["ClimbLocaliser", "LocaliserConfig", "LocaliserPhase"]


class LocaliserPhase(str, Enum):
    """Phase of :class:`ClimbLocaliser`."""

    VIO_INIT = "vio_init"
    """Static IMU initialisation of the VIO."""
    GLOBAL_INIT = "global_init"
    """Collecting the excitation path for the global pose initialisation."""
    TRACKING = "tracking"


@dataclass(frozen=True)
class LocaliserConfig:
    """Settings of :class:`ClimbLocaliser`.

    Attributes
    ----------
    init_path_length
        VIO path length (m) collected before the global initialisation is tried.
    init_retry_length
        Extra path (m) before trying again after a failed attempt.
    init_max_path_length
        Beyond this (m) tracking starts with the best attempt, status ``init_degraded``.
    tether_max_age
        Largest time gap (s) between a tether reading and the keyframe it is paired
        with during the initialisation.
    init_position_sigma, init_yaw_sigma, init_tilt_sigma
        Initial EKF uncertainty after the global initialisation (m, rad, rad).
    plane_constraint
        Passed to :func:`.initialise_global_pose`.
    """

    init_path_length: float = 2.0
    init_retry_length: float = 0.5
    init_max_path_length: float = 6.0
    tether_max_age: float = 0.06
    init_position_sigma: float = 0.01
    init_yaw_sigma: float = 0.03
    init_tilt_sigma: float = 0.005
    plane_constraint: PlaneConstraint = PlaneConstraint.AUTO

    def __post_init__(self) -> None:
        for name in (
            "init_path_length",
            "init_retry_length",
            "init_max_path_length",
            "tether_max_age",
            "init_position_sigma",
            "init_yaw_sigma",
            "init_tilt_sigma",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"LocaliserConfig.{name} must be positive, got {value!r}")
        if self.init_max_path_length < self.init_path_length:
            raise ValueError("LocaliserConfig.init_max_path_length must be ≥ init_path_length")
        object.__setattr__(self, "plane_constraint", PlaneConstraint(self.plane_constraint))


class ClimbLocaliser:
    """VIO → global initialisation → adsorption-constrained tracking, online.

    Feed :class:`.ImuSample`, :class:`.CameraFrame` or :class:`.RelativeMotion`, and
    :class:`.TetherReading` in time order through :meth:`update`. Phases
    (:class:`LocaliserPhase`): static VIO initialisation; collecting the excitation
    path (VIO keyframes paired with tether readings) until
    :func:`.initialise_global_pose` succeeds; then tracking with
    :class:`.ConstrainedEstimator` in the CAD frame, updated at every keyframe and
    carried forward between keyframes by the VIO's IMU-rate motion. Before tracking
    the estimate is the VIO's (``frame="world"``, ``ok=False``).

    Parameters
    ----------
    surface
        CAD surface model.
    anchor_cad : (3,)
        Tether anchor in the CAD frame, m.
    h
        Height above the surface of the body origin (point contact) or of the wheel
        centres (two-wheel contact, ``ConstrainedConfig.wheel_track > 0``), m.
    vio_config, config, localiser_config
        :class:`.VioConfig`, :class:`.ConstrainedConfig`, :class:`LocaliserConfig`.
    """

    def __init__(
        self,
        surface: SurfaceModel,
        anchor_cad: npt.ArrayLike,
        h: float,
        *,
        vio_config: VioConfig | None = None,
        config: ConstrainedConfig | None = None,
        localiser_config: LocaliserConfig | None = None,
    ) -> None:
        self.vio = SlidingWindowVIO(vio_config)
        self.backend = ConstrainedEstimator(surface, anchor_cad, h, config)
        self.localiser_config = LocaliserConfig() if localiser_config is None else localiser_config
        self.reset()

    def reset(self, initial: None = None) -> ClimbEstimate:
        """Start over (the VIO re-initialises from still IMU data)."""
        if initial is not None:
            raise ValueError("ClimbLocaliser.reset takes no initial state; it initialises itself")
        self.vio.reset()
        self.backend.reset()
        self.global_init: GlobalInit | None = None
        self._phase = LocaliserPhase.VIO_INIT
        self._kf_count = 0
        self._init_p: list[FloatArray] = []
        self._init_z: list[FloatArray] = []
        self._init_t: list[float] = []
        self._path = 0.0
        self._next_try = self.localiser_config.init_path_length
        self._tethers: list[TetherReading] = []
        self._kf_last: ClimbEstimate | None = None
        self._backend_last: ClimbEstimate | None = None
        self._rotations_of: tuple[ClimbEstimate, ClimbEstimate] | None = None
        self._rotations = (np.eye(3), np.eye(3))
        self._last = self.vio.estimate()
        return self._last

    @property
    def phase(self) -> LocaliserPhase:
        """Current :class:`LocaliserPhase`."""
        return self._phase

    def update(
        self,
        measurement: ImuSample | CameraFrame | RelativeMotion | TetherReading | None,
    ) -> ClimbEstimate:
        """Consume one measurement (or ``None``) and return the current estimate."""
        if measurement is None:
            return self._last
        if isinstance(measurement, TetherReading):
            if self._phase is LocaliserPhase.TRACKING:
                self._backend_last = self.backend.update(measurement)
                self._last = self._backend_last
            else:
                self._tethers.append(measurement)
                if not self._init_t:
                    self._tethers = self._tethers[-10:]
            return self._last
        vio_est = self.vio.update(measurement)
        new_kf = self.vio.keyframe_count != self._kf_count
        self._kf_count = self.vio.keyframe_count
        if not new_kf or not self.vio.initialised:
            if self._phase is LocaliserPhase.TRACKING:
                self._last = self._propagated(vio_est)
            elif self._phase is LocaliserPhase.GLOBAL_INIT:
                self._last = dataclasses.replace(vio_est, ok=False, status="global_init_pending")
            else:
                self._last = vio_est
            return self._last
        kf = self.vio.keyframe_estimate()
        if self._phase is LocaliserPhase.VIO_INIT:
            self._phase = LocaliserPhase.GLOBAL_INIT
        if self._phase is LocaliserPhase.GLOBAL_INIT:
            self._collect(kf)
            if self._phase is not LocaliserPhase.TRACKING:
                self._last = ClimbEstimate(
                    t=kf.t,
                    position=kf.position,
                    quat_xyzw=kf.quat_xyzw,
                    velocity=kf.velocity,
                    cov=kf.cov,
                    ok=False,
                    status="global_init_pending",
                    frame="world",
                )
            return self._last
        self._kf_last = kf
        self._backend_last = self.backend.update(kf)
        self._last = self._backend_last
        return self._last

    def _propagated(self, vio_now: ClimbEstimate) -> ClimbEstimate:
        """The constrained keyframe pose carried forward by the VIO's motion since then."""
        kf, c = self._kf_last, self._backend_last
        if kf is None or c is None:
            return self._last
        key = self._rotations_of
        if key is None or key[0] is not kf or key[1] is not c:
            # rotation matrices of the keyframe pair, converted once per keyframe
            self._rotations = (kf.rotation, c.rotation)
            self._rotations_of = (kf, c)
        R_kf, R_c = self._rotations
        dR = R_kf.T @ vio_now.rotation
        dp = R_kf.T @ (vio_now.position - kf.position)
        return dataclasses.replace(
            c,
            t=vio_now.t,
            position=c.position + R_c @ dp,
            quat_xyzw=quat_xyzw_from_matrix(R_c @ dR),
            velocity=R_c @ R_kf.T @ vio_now.velocity,
        )

    def _collect(self, kf: ClimbEstimate) -> None:
        cfg = self.localiser_config
        if self._init_p:
            self._path += float(np.linalg.norm(kf.position - self._init_p[-1]))
        self._init_p.append(kf.position.copy())
        self._init_z.append(kf.rotation[:, 2].copy())
        self._init_t.append(kf.t)
        if self._path < self._next_try:
            return
        # pair keyframes with tether readings
        times = np.array(self._init_t)
        readings = [m for m in self._tethers if m.ok]
        if len(readings) < 4:
            self._next_try += cfg.init_retry_length
            return
        rt = np.array([m.t for m in readings])
        rl = np.array([m.length for m in readings])
        idx = np.clip(np.searchsorted(rt, times), 1, len(rt) - 1)
        left = np.where(np.abs(rt[idx - 1] - times) <= np.abs(rt[idx] - times), idx - 1, idx)
        age = np.abs(rt[left] - times)
        use = age <= cfg.tether_max_age
        if use.sum() < 4:
            self._next_try += cfg.init_retry_length
            return
        gi = initialise_global_pose(
            np.array(self._init_p)[use],
            rl[left][use],
            self.backend.anchor,
            self.backend.surface,
            self.backend.h,
            body_z_w=np.array(self._init_z)[use],
            yaw0=None,
            plane_constraint=cfg.plane_constraint,
        )
        if gi.converged or self._path >= cfg.init_max_path_length:
            self.global_init = gi
            R_gw = gi.R_world_cad.T
            p_g = gi.cad_from_world(kf.position)
            R_gb = R_gw @ kf.rotation
            P = np.diag(
                [cfg.init_position_sigma**2] * 3
                + [cfg.init_tilt_sigma**2] * 2
                + [cfg.init_yaw_sigma**2]
            )
            start = ClimbEstimate(
                t=kf.t,
                position=p_g,
                quat_xyzw=quat_xyzw_from_matrix(R_gb),
                velocity=R_gw @ kf.velocity,
                frame="cad",
            )
            self.backend.reset(start, P, note=None if gi.converged else "init_degraded")
            self._kf_last = kf
            self._backend_last = self.backend.update(kf)
            self._last = self._backend_last
            self._phase = LocaliserPhase.TRACKING
            self._tethers = []
        else:
            self._next_try += cfg.init_retry_length
