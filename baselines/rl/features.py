"""Observation feature maps and action maps that are part of a learned policy."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt


def wheeled_nav_goal_features(obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
    r"""WheeledNav observation plus the goal in polar form in the estimated robot frame.

    Appends five columns to ``obs`` (``(..., 12 + n_beams)``): the distance to the goal
    ``ρ`` (m), ``cos α, sin α`` of the bearing of the goal and ``cos β, sin β`` of the goal
    heading, both relative to the estimated robot heading ``θ``:

    .. math::

        \rho = \lVert p_g^{r} \rVert, \quad \alpha = \operatorname{atan2}(y_g^r, x_g^r),
        \quad \beta = \theta_g - \theta

    These are computed from the observation alone (no ground truth); they spare the network
    from learning products such as :math:`\cos\theta_g\cos\theta + \sin\theta_g\sin\theta`.
    """
    x = np.asarray(obs, dtype=np.float32)
    c, s_, cg, sg = x[..., 2], x[..., 3], x[..., 6], x[..., 7]
    xr, yr = x[..., 8], x[..., 9]
    rho = np.hypot(xr, yr)
    safe = np.where(rho > 1e-6, rho, 1.0)
    cos_a = np.where(rho > 1e-6, xr / safe, 1.0)
    sin_a = np.where(rho > 1e-6, yr / safe, 0.0)
    cos_b = cg * c + sg * s_
    sin_b = sg * c - cg * s_
    extra = np.stack([rho, cos_a, sin_a, cos_b, sin_b], axis=-1).astype(np.float32)
    return np.concatenate([x, extra], axis=-1)


ZOOM_POS_SCALES: tuple[float, ...] = (0.05, 0.3)
"""Length scales (m) of :func:`wheeled_nav_goal_zoom_features`' goal-offset columns."""

ZOOM_ANG_SCALES: tuple[float, ...] = (0.1, 0.5)
"""Angle scales (rad) of :func:`wheeled_nav_goal_zoom_features`' heading-error columns."""


def wheeled_nav_goal_zoom_features(obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
    r"""The polar goal features (:func:`wheeled_nav_goal_features`) plus "zoomed" ones.

    Success needs the robot within 3 cm and 5° of the goal pose, errors that vanish next to
    the metre-scale distances once the observation is normalised. For each length scale
    ``s`` in :data:`ZOOM_POS_SCALES` and each angle scale ``σ`` in :data:`ZOOM_ANG_SCALES`
    this appends

    .. math::

        \tanh(x_g^r / s),\ \tanh(y_g^r / s), \qquad \tanh(\beta / \sigma)

    with the goal position ``(x_g^r, y_g^r)`` in the estimated robot frame and the goal
    heading error ``β = θ_g − θ`` wrapped to ``(−π, π]``: ±1 far away, linear with a steep
    slope close to the goal, so the last centimetres and degrees are visible to the network.
    """
    x = wheeled_nav_goal_features(obs)
    xr, yr = x[..., 8], x[..., 9]
    beta = np.arctan2(x[..., -1], x[..., -2])
    cols = [np.tanh(c / s) for s in ZOOM_POS_SCALES for c in (xr, yr)]
    cols += [np.tanh(beta / s) for s in ZOOM_ANG_SCALES]
    return np.concatenate([x, np.stack(cols, axis=-1).astype(np.float32)], axis=-1)


BEARING_FADE: float = 0.05
"""Distance (m) below which :func:`wheeled_nav_goal_smooth_features` fades the goal bearing."""


def wheeled_nav_goal_smooth_features(obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
    r"""The zoomed goal features (:func:`wheeled_nav_goal_zoom_features`) with a goal
    bearing that is continuous at the goal.

    ``cos α, sin α`` are undefined at the goal position: a millimetre of motion next to it
    swings them through the whole circle, and a network that reads them turns this into
    noise in its command just where it must turn in place and stop. Here the two bearing
    columns are

    .. math::

        \frac{(x_g^r,\ y_g^r)}{\sqrt{\rho^2 + \rho_0^2}}

    the unit bearing far from the goal, fading to zero within ``ρ0`` =
    :data:`BEARING_FADE`; every other column is the zoomed features'.
    """
    x = wheeled_nav_goal_zoom_features(obs)
    n0 = np.shape(obs)[-1]
    xr, yr = x[..., 8], x[..., 9]
    scale = 1.0 / np.sqrt(xr.astype(np.float64) ** 2 + yr.astype(np.float64) ** 2 + BEARING_FADE**2)
    x[..., n0 + 1] = (xr * scale).astype(np.float32)
    x[..., n0 + 2] = (yr * scale).astype(np.float32)
    return x


WORLD_FRAME_COLUMNS: int = 8
"""The leading WheeledNav observation columns given in the world frame: the estimated pose
``x, y, cos θ, sin θ`` and the goal ``x_g, y_g, cos θ_g, sin θ_g``."""


def wheeled_nav_egocentric_features(obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
    r"""The smooth goal features (:func:`wheeled_nav_goal_smooth_features`) without the
    world-frame columns: everything the network reads is in the estimated robot frame.

    The task is the same wherever the room puts the robot and whichever way it faces it:
    the command depends only on where the goal and the obstacles lie relative to the robot.
    A network that also reads the absolute pose and goal (the first
    :data:`WORLD_FRAME_COLUMNS` columns) can, and does, learn a bias that depends on where in
    the room it is. Next to the goal such a bias of a tenth of the turn-rate limit cancels
    the small turn that is left to do, and the robot stalls a few degrees off the goal
    heading. Dropping these columns makes the map invariant to any rigid motion of the
    world by construction; the goal stays visible through the robot-frame columns
    ``x_g^r, y_g^r`` and the polar and zoomed features.
    """
    x = wheeled_nav_goal_smooth_features(obs)
    return np.ascontiguousarray(x[..., WORLD_FRAME_COLUMNS:])


def wheeled_nav_egocentric_mirror(
    n_beams: int, n_sectors: int = 0, rest_timer: bool = False
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.float32]]:
    r"""The left–right mirror of a network input of :func:`wheeled_nav_egocentric_features`.

    Reflecting the world about the robot's heading line maps a WheeledNav scene onto
    another valid scene, and the expert's command ``(v, ω)`` onto ``(v, −ω)``. In the
    robot frame the reflection is ``y → −y``; each input column goes to a column of the
    mirrored input (``perm``) with a sign (``sign``): ``mirrored = x[..., perm] * sign``.

    The input is the env observation less its world-frame columns —
    ``x_g^r, y_g^r, v, ω`` then ``n_beams`` scan beams, whose bearings must be symmetric
    about the optical axis — followed by ``n_sectors`` obstacle-memory sectors (sector
    ``k`` centred on bearing ``2πk / n``), a rest-timer column if ``rest_timer``, and the
    polar and zoomed goal columns
    ``ρ, b_x, b_y, cos β, sin β, tanh(x/s₁), tanh(y/s₁), tanh(x/s₂), tanh(y/s₂),
    tanh(β/σ₁), tanh(β/σ₂)``.
    """
    if n_beams < 1 or n_sectors < 0:
        raise ValueError(f"need n_beams >= 1 and n_sectors >= 0, got {n_beams}, {n_sectors}")
    perm: list[int] = [0, 1, 2, 3]
    sign: list[float] = [1.0, -1.0, 1.0, -1.0]
    k0 = 4
    perm += [k0 + n_beams - 1 - k for k in range(n_beams)]  # beams reversed
    sign += [1.0] * n_beams
    k0 += n_beams
    perm += [k0 + (-k) % n_sectors for k in range(n_sectors)]  # bearing -> -bearing
    sign += [1.0] * n_sectors
    k0 += n_sectors
    if rest_timer:
        perm.append(k0)
        sign.append(1.0)
        k0 += 1
    goal_signs = [1.0, 1.0, -1.0, 1.0, -1.0]  # ρ, b_x, b_y, cos β, sin β
    goal_signs += [1.0, -1.0] * len(ZOOM_POS_SCALES) + [-1.0] * len(ZOOM_ANG_SCALES)
    perm += [k0 + k for k in range(len(goal_signs))]
    sign += goal_signs
    return np.asarray(perm, dtype=np.intp), np.asarray(sign, dtype=np.float32)


OBS_FEATURES: dict[str, tuple[Callable[[npt.ArrayLike], npt.NDArray[np.float32]], int]] = {
    "wheeled_nav_goal_polar": (wheeled_nav_goal_features, 5),
    "wheeled_nav_goal_zoom": (
        wheeled_nav_goal_zoom_features,
        5 + 2 * len(ZOOM_POS_SCALES) + len(ZOOM_ANG_SCALES),
    ),
    "wheeled_nav_goal_smooth": (
        wheeled_nav_goal_smooth_features,
        5 + 2 * len(ZOOM_POS_SCALES) + len(ZOOM_ANG_SCALES),
    ),
    "wheeled_nav_egocentric": (
        wheeled_nav_egocentric_features,
        5 + 2 * len(ZOOM_POS_SCALES) + len(ZOOM_ANG_SCALES) - WORLD_FRAME_COLUMNS,
    ),
}
"""Feature maps a learned policy may apply to its observation: name → (function, change in
the number of columns). A map appends columns to the observation and may first drop some
of its leading ones (:data:`OBS_FEATURES_DROP`)."""

OBS_FEATURES_DROP: dict[str, int] = {"wheeled_nav_egocentric": WORLD_FRAME_COLUMNS}
"""Leading observation columns a feature map drops (none where not listed)."""


def obs_feature_fn(name: str | None) -> Callable[[npt.ArrayLike], npt.NDArray[np.float32]] | None:
    """The feature map called ``name`` (``None`` for none); ``ValueError`` on an unknown name."""
    if not name:
        return None
    if name not in OBS_FEATURES:
        raise ValueError(f"unknown obs_features {name!r}; known: {', '.join(OBS_FEATURES)}")
    return OBS_FEATURES[name][0]


def deadband(action: npt.ArrayLike, width: float) -> npt.NDArray[np.float32]:
    r"""A continuous dead band on each action component in ``[-1, 1]``:

    .. math:: a' = \operatorname{sign}(a)\,\max(0, |a| - \delta) / (1 - \delta)

    Commands within ``δ`` of zero become exactly zero (the robot can stop), the full range
    ``[-1, 1]`` is kept. ``width = 0`` is the identity.
    """
    a = np.asarray(action, dtype=np.float32)
    if width <= 0.0:
        return a
    if not width < 1.0:
        raise ValueError(f"action_deadband must be in [0, 1), got {width}")
    mag = np.maximum(np.abs(a) - width, 0.0) / (1.0 - width)
    return (np.sign(a) * mag).astype(np.float32)


def stop_gate(action: npt.ArrayLike, width: float = 0.0) -> npt.NDArray[np.float32]:
    """Map a model action ``(..., n + 1)`` with a stop gate to an env action ``(..., n)``.

    The last component is the gate: where it is positive the env action is zero (stop);
    elsewhere the first ``n`` components pass (through :func:`deadband` of ``width``).
    Stopping is then one decision of the policy instead of ``n`` components that must all
    be near zero at once.
    """
    a = np.asarray(action, dtype=np.float32)
    motion = deadband(a[..., :-1], width)
    return np.where(a[..., -1:] > 0.0, np.float32(0.0), motion).astype(np.float32)


WHEELED_NAV_SCENE_START: int = 12
"""First scan column of a WheeledNav observation; the goal in the robot frame is in
columns 8 and 9."""


def scene_fade(x: npt.ArrayLike, stop: int, radius: float) -> npt.NDArray[np.float32]:
    r"""WheeledNav inputs with the scene columns faded out next to the goal.

    Columns ``12 … stop − 1`` (the scan, then the obstacle memory; 1 means nothing seen
    there) become :math:`1 - (1 - x) \min(1, \rho / R)`, with :math:`\rho` the distance to
    the goal in the estimated robot frame (columns 8, 9) and :math:`R` ``radius``.

    The env keeps obstacles ``body_radius + 0.25`` m clear of the goal, so the last
    ``R`` (≤ 0.25 m) of a route never depend on them — but a network that reads the scene
    there can, and does, learn a turn bias that depends on how the obstacles around the goal
    happen to lie, which a few degrees off the goal heading cancels the turn that is left.
    Faded, every goal is approached through the same empty scene. The fade is continuous,
    and the identity beyond ``R``.
    """
    out = np.array(x, dtype=np.float32, copy=True)
    rho = np.hypot(out[..., 8].astype(np.float64), out[..., 9].astype(np.float64))
    keep = np.minimum(1.0, rho / float(radius)).astype(np.float32)[..., None]
    scene = out[..., WHEELED_NAV_SCENE_START:stop]
    out[..., WHEELED_NAV_SCENE_START:stop] = np.where(keep < 1.0, 1.0 - (1.0 - scene) * keep, scene)
    return out
