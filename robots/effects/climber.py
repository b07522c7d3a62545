"""Effects of the blade climber (``realitygap/WallClimb-v0``).

Each effect is realised on :class:`~realitygap.robots.climber.ClimberParams`:
in the tether and IMU sensor models, in the blade surface, or in the ride
height. The blind ranges are realistic magnitudes: sag of 2.5–10 cm at 5 m, an
anchor surveyed 1–4 cm off, a spool scale off by 0.4–1.5 %, a skirt worn by
2–8 mm. A tether stretch reads exactly like a spool-scale error and has no
blind range of its own; the IMU biases and the surface deviation do not show
in tether and ride-height logs (see :mod:`~realitygap.diagnosis.adapters.climber.adapter`).
"""

from __future__ import annotations

from typing import Any

from realitygap.robots.effects.base import (
    BlindRange,
    Channel,
    Effect,
    ParamSpec,
    Stage,
    register_effect,
    register_robot,
)

register_robot("climber", "realitygap.robots.climber.ClimberParams")


@register_effect
class ClimberTetherSag(Effect):
    name = "climber_tether_sag"
    robot = "climber"
    stage = Stage.SENSOR
    observed_in = (Channel.TETHER,)
    description = (
        "The tether sags under its weight: the paid-out length exceeds the straight line by "
        "k·d². Realised in the tether sensor model."
    )
    specs = (ParamSpec("k", "1/m", 0.0, 0.0, 0.005, "extra length per squared distance"),)
    blind = (BlindRange("k", 0.001, 0.004, False),)

    def apply_params(self, params: Any) -> Any:
        return params.replace(tether_sag=self["k"])


@register_effect
class ClimberTetherStretch(Effect):
    name = "climber_tether_stretch"
    robot = "climber"
    stage = Stage.SENSOR
    observed_in = (Channel.TETHER,)
    description = "The tether stretches under tension: reading grows by strain·d."
    specs = (ParamSpec("strain", "1", 0.0, -0.01, 0.01, "elastic strain of the tether"),)

    def apply_params(self, params: Any) -> Any:
        return params.replace(tether_stretch=self["strain"])


@register_effect
class ClimberAnchorError(Effect):
    name = "climber_anchor_error"
    robot = "climber"
    stage = Stage.SENSOR
    observed_in = (Channel.TETHER,)
    description = "The tether anchor is not where the model puts it (world-frame offset)."
    specs = (
        ParamSpec("dx", "m", 0.0, -0.05, 0.05, "anchor offset along world x"),
        ParamSpec("dy", "m", 0.0, -0.05, 0.05, "anchor offset along world y"),
        ParamSpec("dz", "m", 0.0, -0.05, 0.05, "anchor offset along world z"),
    )
    blind = tuple(BlindRange(nm, 0.01, 0.04, True) for nm in ("dx", "dy", "dz"))

    def apply_params(self, params: Any) -> Any:
        return params.replace(anchor_offset=(self["dx"], self["dy"], self["dz"]))


@register_effect
class ClimberSpoolScale(Effect):
    name = "climber_spool_scale"
    robot = "climber"
    stage = Stage.SENSOR
    observed_in = (Channel.TETHER,)
    description = "The spool encoder's length per count is off: reading = s · paid-out length."
    specs = (ParamSpec("s", "1", 1.0, 0.98, 1.02, "reading / paid-out length"),)
    blind = (BlindRange("s", 0.004, 0.015, True),)

    def apply_params(self, params: Any) -> Any:
        return params.replace(spool_scale=self["s"])


@register_effect
class ClimberGyroBias(Effect):
    name = "climber_gyro_bias"
    robot = "climber"
    stage = Stage.SENSOR
    observed_in = (Channel.IMU,)
    description = "Constant gyroscope bias (body frame) on top of the random turn-on bias."
    specs = tuple(
        ParamSpec(f"b{a}", "rad/s", 0.0, -0.05, 0.05, f"gyro bias about body {a}") for a in "xyz"
    )

    def apply_params(self, params: Any) -> Any:
        return params.replace(gyro_bias=(self["bx"], self["by"], self["bz"]))


@register_effect
class ClimberAccelBias(Effect):
    name = "climber_accel_bias"
    robot = "climber"
    stage = Stage.SENSOR
    observed_in = (Channel.IMU,)
    description = "Constant accelerometer bias (body frame) on top of the random turn-on bias."
    specs = tuple(
        ParamSpec(f"b{a}", "m/s^2", 0.0, -0.3, 0.3, f"accelerometer bias along body {a}")
        for a in "xyz"
    )

    def apply_params(self, params: Any) -> Any:
        return params.replace(accel_bias=(self["bx"], self["by"], self["bz"]))


@register_effect
class ClimberSurfaceDeviation(Effect):
    name = "climber_surface_deviation"
    robot = "climber"
    stage = Stage.BODY
    observed_in = (Channel.SURFACE, Channel.POSE_GT, Channel.TETHER)
    description = (
        "The real blade deviates from its CAD model by a smooth normal displacement (largest "
        "value d, shape from seed). Realised by building the simulated blade from the deformed "
        "surface while the estimator keeps the nominal CAD cloud."
    )
    specs = (
        ParamSpec("d", "m", 0.0, 0.0, 0.02, "largest normal deviation"),
        ParamSpec("seed", "1", 0.0, 0.0, 1000.0, "seed of the deviation's shape"),
    )

    def apply_params(self, params: Any) -> Any:
        return params.replace(surface_deviation=self["d"], surface_seed=int(self["seed"]))


@register_effect
class ClimberAdsorptionGap(Effect):
    name = "climber_adsorption_gap"
    robot = "climber"
    stage = Stage.BODY
    observed_in = (Channel.SURFACE, Channel.POSE_GT, Channel.IMU)
    description = (
        "The adsorption unit rides higher than designed (worn skirt, larger wheels): the body "
        "sits gap m higher than the estimator's h and the suction force drops by exp(-gap/λ). "
        "Realised in the body (wheel radius) and in the adsorption force."
    )
    specs = (ParamSpec("gap", "m", 0.0, -0.005, 0.01, "extra ride height"),)
    blind = (BlindRange("gap", 0.002, 0.008, False),)

    def apply_params(self, params: Any) -> Any:
        return params.replace(gap_offset=self["gap"])
