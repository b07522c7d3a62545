"""Pieces shared by the environments: action checks and constructor-argument checks."""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import numbers
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt
from gymnasium import error as gym_error

from realitygap.core.checks import check_finite_float, check_positive_int

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ESTIMATOR_METHODS",
    "ESTIMATOR_PROTOCOL",
    "MAX_PHYSICS_HZ",
    "available_memory_bytes",
    "check_action_array",
    "check_bool",
    "check_estimator",
    "check_finite_fields",
    "check_instance",
    "check_obstacles",
    "check_open",
    "check_rates",
    "check_reality",
    "check_render_mode",
    "check_reset_options",
    "check_seed",
    "check_started",
    "check_twist_action",
    "check_vector",
    "release_freed_memory",
]

T = TypeVar("T")

ESTIMATOR_METHODS = {"reset": "reset(initial=None)", "update": "update(measurement)"}
"""The methods an ``estimator=`` plug-in of WheeledNav and WallClimb must have
(:class:`~realitygap.estimators.base.Estimator`)."""
ESTIMATOR_PROTOCOL = "the realitygap.estimators.base.Estimator protocol"

MAX_PHYSICS_HZ = 10_000.0
"""Highest physics rate an env accepts (Hz): beyond it a second of simulation takes minutes."""


def release_freed_memory() -> None:
    """Hand memory freed by the C heap back to the operating system (glibc only; else nothing).

    A PyBullet client with a large triangle mesh (the climber's blade) frees its
    tens of megabytes on disconnect, but glibc keeps them in fragmented arenas, so
    making and closing envs in a loop grows the resident size by ~2 MB per env;
    ``malloc_trim(0)`` returns them.
    """
    global _LIBC
    if _LIBC is None:
        try:
            _LIBC = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            _LIBC.malloc_trim  # noqa: B018  (glibc has it; musl and macOS do not)
        except (OSError, AttributeError):
            _LIBC = False
    if _LIBC:
        _LIBC.malloc_trim(0)


_LIBC: Any = None


def available_memory_bytes() -> int | None:
    """Bytes this process may still allocate: ``MemAvailable`` of ``/proc/meminfo`` (else
    the free physical pages), capped by the cgroup's ``memory.max - memory.current``
    when a container limits memory; ``None`` when the platform tells neither."""
    avail: int | None = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
                break
    except (OSError, ValueError, IndexError):
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, OSError, ValueError):
            return None
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            used = int(Path("/sys/fs/cgroup/memory.current").read_text().strip())
            avail = min(avail, max(int(limit) - used, 0))
    except (OSError, ValueError):
        pass
    return avail


def check_action_array(action: Any, shape: tuple[int, ...], name: str = "action") -> FloatArray:
    """``action`` as a finite float64 array of ``shape``.

    Raises
    ------
    TypeError
        Strings, ``None`` or objects that are not numbers, naming the expected
        dtype and shape.
    ValueError
        A wrong shape or a NaN/inf entry.
    """
    raw = np.asarray(action) if not isinstance(action, (str, bytes)) else None
    if raw is None or raw.dtype.kind not in "biuf":
        got = type(action).__name__ if raw is None else f"dtype {raw.dtype}"
        expected = f"a float array of shape {shape} with entries in [-1, 1]"
        raise TypeError(f"{name} must be {expected}, got {got}: {action!r:.60}")
    a = np.asarray(raw, dtype=np.float64)  # no copy for a float64 action (the hot path)
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite, got {a.reshape(-1).tolist()}")
    if a.size != math.prod(shape):
        expected = f"a float array of shape {shape} with entries in [-1, 1]"
        raise ValueError(f"{name} must be {expected}, got shape {raw.shape}")
    return a.reshape(shape)


def check_twist_action(action: npt.ArrayLike) -> tuple[float, float]:
    """Validate a normalised ``(v, ω)`` action and clip it to ``[-1, 1]``.

    Raises ``TypeError`` for a non-numeric action and ``ValueError`` for a wrong
    shape or a non-finite entry (a NaN action would otherwise drive the simulation
    into NaN states silently).
    """
    if type(action) is np.ndarray and action.shape == (2,) and action.dtype.char in "fde":
        # the hot path (a policy's float array): the same checks on two floats
        a0, a1 = action.tolist()
        if -1.0 <= a0 <= 1.0 and -1.0 <= a1 <= 1.0:  # within the box (NaN is not): as is
            return a0, a1
        if math.isfinite(a0) and math.isfinite(a1):
            return min(1.0, max(-1.0, a0)), min(1.0, max(-1.0, a1))
    a = check_action_array(action, (2,))  # any other form, and the errors
    return min(1.0, max(-1.0, float(a[0]))), min(1.0, max(-1.0, float(a[1])))


def check_bool(value: Any, name: str) -> bool:
    """``value`` if it is a ``bool`` (or NumPy bool), else ``TypeError``."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r} ({type(value).__name__})")
    return bool(value)


def check_rates(physics_hz: Any, control_hz: Any) -> tuple[float, float, int]:
    """Physics and control rates (Hz) and the physics sub-steps per control step.

    Raises
    ------
    TypeError, ValueError
        Non-numbers, NaN, rates ≤ 0, ``physics_hz`` above :data:`MAX_PHYSICS_HZ`,
        or a ratio that is not a positive whole number.
    """
    ph = check_finite_float(
        physics_hz, "physics_hz", low=0.0, high=MAX_PHYSICS_HZ, strict_low=True, unit="Hz"
    )
    too_fast = isinstance(control_hz, (int, float)) and control_hz > ph
    ch = check_finite_float(
        control_hz,
        "control_hz",
        low=0.0,
        high=ph,
        strict_low=True,
        unit="Hz",
        fix="the control rate cannot exceed physics_hz" if too_fast else "",
    )
    ratio = ph / ch
    if abs(ratio - round(ratio)) > 1e-9:
        raise ValueError(
            f"physics_hz / control_hz must be a positive whole number, got {ph:g} / {ch:g} = "
            f"{ratio:g}. Fix: choose a control rate that divides the physics rate"
        )
    return ph, ch, check_positive_int(round(ratio), "physics_hz / control_hz")


def _describe(value: Any) -> str:
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def check_seed(seed: Any, name: str = "seed") -> int | None:
    """``seed`` for ``reset``: ``None`` or a non-negative whole number, as a Python ``int``.

    Called before ``super().reset(seed=seed)``, so that a bad seed is refused with a
    ``TypeError``/``ValueError`` naming it rather than Gymnasium's ``error.Error``.
    NumPy integers are accepted (and converted); ``bool``, floats (even ``1.0``) and
    strings are not.

    Raises
    ------
    TypeError
        Not ``None`` and not an integer.
    ValueError
        A negative integer.
    """
    fix = f"Fix: pass {name}=None (fresh entropy) or a whole number such as {name}=0"
    if seed is None:
        return None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, numbers.Integral):
        raise TypeError(
            f"{name} must be None or a non-negative integer, got {_describe(seed)}. {fix}"
        )
    if seed < 0:
        raise ValueError(f"{name} must be None or a non-negative integer, got {int(seed)}. {fix}")
    return int(seed)


def _make_fix(env: Any, default_id: str) -> tuple[str, str]:
    spec = getattr(env, "spec", None)
    env_id = getattr(spec, "id", None) or default_id
    make = "gymnasium.make_vec" if "Vec" in env_id else "gymnasium.make"
    return env_id, f"{make}({env_id!r}, ...)"


def check_open(env: Any, call: str, default_id: str) -> None:
    """``RuntimeError`` when ``env`` was closed (its ``closed`` attribute true): ``call``
    (``"step"``, ``"reset"``, ``"render"``) cannot run on a closed env. The one check every
    env's ``step``, ``reset`` and ``render`` make first; ``default_id`` names the env when it
    was built without ``gymnasium.make``."""
    if getattr(env, "closed", False):
        env_id, make = _make_fix(env, default_id)
        raise RuntimeError(
            f"{env_id}: {call}() on a closed env; close() released its simulation and the env "
            f"cannot be used again. Fix: make a new env with {make}"
        )


class ResetNeeded(gym_error.ResetNeeded, RuntimeError):
    """``step()`` before the first ``reset()``: Gymnasium's :class:`~gymnasium.error.ResetNeeded`
    (also a ``RuntimeError``)."""


def check_started(env: Any, started: bool, default_id: str) -> None:
    """:class:`ResetNeeded` when ``env`` has not been reset yet (``started`` false), as
    Gymnasium does, with the fix."""
    if not started:
        env_id, _ = _make_fix(env, default_id)
        raise ResetNeeded(
            f"{env_id}: call reset() before step(); an episode starts at reset(). Fix: call "
            "env.reset(seed=...) first (and again after an episode ends)"
        )


def check_reset_options(options: Any, allowed: Sequence[str], env_name: str) -> dict[str, Any]:
    """``reset(options=...)`` as a dict: ``None`` (no options) or a mapping whose keys are
    among ``allowed``; else ``TypeError``/``ValueError`` naming ``options``. Every env's
    ``reset`` calls it."""
    known = " and/or ".join(map(repr, allowed)) if allowed else "none"
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise TypeError(
            f"{env_name}.reset: options must be None or a dict with keys {known}, got "
            f"{_describe(options)}. Fix: pass options=None"
            + (f" or e.g. options={{{allowed[0]!r}: ...}}" if allowed else "")
        )
    unknown = sorted(str(k) for k in options if k not in allowed)
    if unknown:
        raise ValueError(
            f"{env_name}.reset: unknown reset option(s) {unknown} in options; "
            + (f"known keys: {known}" if allowed else f"{env_name} takes no reset options")
            + ". Fix: remove or rename them"
        )
    return dict(options)


def check_render_mode(render_mode: Any, modes: Sequence[str]) -> str | None:
    """``render_mode`` if it is ``None`` or one of ``modes``, else ``ValueError`` listing them."""
    if render_mode is None or (isinstance(render_mode, str) and render_mode in modes):
        return render_mode
    options = " or ".join(["None", *(repr(m) for m in modes)])
    raise ValueError(
        f"render_mode must be {options}, got {_describe(render_mode)}. Fix: pass one of them"
    )


def check_instance(
    value: Any,
    name: str,
    kind: type[T],
    default: Callable[[], T] | None = None,
    *,
    optional: bool = False,
) -> Any:
    """``value`` if it is a ``kind``, else ``TypeError`` naming the argument, the class and
    what came. ``None`` gives ``default()`` when a default is given, stays ``None`` when
    ``optional``, and is refused otherwise."""
    if value is None and (default is not None or optional):
        return default() if default is not None else None
    if isinstance(value, kind):
        return value
    none = " or None (the default)" if (default is not None or optional) else ""
    raise TypeError(
        f"{name} must be a {kind.__name__}{none}, got {_describe(value)}. "
        f"Fix: pass {kind.__name__}(...) with the fields to change"
    )


def check_vector(
    value: Any,
    name: str,
    sizes: Sequence[int],
    *,
    what: str = "",
    positive: bool = False,
) -> FloatArray:
    """``value`` as a finite 1-D float array whose length is one of ``sizes``.

    ``what`` describes the entries with their units (``"x [m], y [m], θ [rad]"``);
    ``positive`` refuses entries ≤ 0.

    Raises
    ------
    TypeError
        A string, ``None``, a mapping or anything that is not a list of numbers.
    ValueError
        A wrong length, NaN/inf or (with ``positive``) an entry ≤ 0.
    """
    n_text = " or ".join(str(n) for n in sizes)
    kind = f"{n_text} finite{' positive' if positive else ''} numbers"
    expected = f"{kind} ({what})" if what else kind
    raw: Any = None
    if not isinstance(value, (str, bytes, Mapping)) and value is not None:
        try:
            raw = np.asarray(value)
        except (TypeError, ValueError):
            raw = None
    if raw is None or raw.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be {expected}, got {_describe(value)}")
    arr = np.asarray(raw, dtype=np.float64).reshape(-1)
    if raw.ndim != 1 or arr.size not in sizes:
        raise ValueError(f"{name} must be {expected}, got shape {raw.shape}: {value!r:.80}")
    if not np.all(np.isfinite(arr)) or (positive and np.any(arr <= 0.0)):
        raise ValueError(f"{name} must be {expected}, got {arr.tolist()}")
    return arr.copy()


def check_obstacles(obstacles: Any, name: str = "obstacles") -> list[Any] | None:
    """A fixed obstacle layout: ``None`` (random layouts) or a sequence of
    :class:`~realitygap.robots.world.Primitive` footprints, as a list.

    Raises
    ------
    TypeError
        Anything else: a string, a number, or an entry that is no ``Primitive``.
    """
    from realitygap.robots.world import Primitive

    if obstacles is None:
        return None
    fix = (
        f"Fix: pass {name}=None for random layouts (n_obstacles of them), [] for an empty "
        "room, or a list of realitygap.robots.world.Primitive"
    )
    if isinstance(obstacles, (str, bytes, Mapping)) or not isinstance(
        obstacles, (Sequence, np.ndarray, tuple, list)
    ):
        raise TypeError(
            f"{name} must be None or a list of Primitive footprints, got {_describe(obstacles)}. "
            f"{fix}"
        )
    out = list(obstacles)
    for i, p in enumerate(out):
        if not isinstance(p, Primitive):
            raise TypeError(f"{name}[{i}] must be a Primitive footprint, got {_describe(p)}. {fix}")
    return out


def check_estimator(
    estimator: Any,
    methods: Mapping[str, str],
    *,
    attributes: Mapping[str, str] | None = None,
    protocol: str = "",
    name: str = "estimator",
) -> Any:
    """``estimator`` if it follows the plug-in protocol: every one of ``methods`` callable
    and every one of ``attributes`` present (checked on the class, so that a property
    is not evaluated), else ``TypeError`` listing what the protocol requires and what
    the object lacks.

    ``methods`` and ``attributes`` map a name to its signature for the message
    (``{"reset": "reset(initial=None)"}``).
    """
    attributes = attributes or {}
    missing = [sig for m, sig in methods.items() if not callable(getattr(estimator, m, None))]
    missing += [
        sig
        for a, sig in attributes.items()
        if not hasattr(type(estimator), a) and not hasattr(estimator, a)
    ]
    if not missing:
        return estimator
    required = ", ".join([*methods.values(), *attributes.values()])
    where = f" ({protocol})" if protocol else ""
    raise TypeError(
        f"{name} must be an object with {required}{where}; got {_describe(estimator)}, "
        f"which lacks {', '.join(missing)}. Fix: pass an estimator object that has them, or "
        f"leave {name} out for the default pipeline"
    )


def check_reality(
    reality: Any, robot: str, default: Callable[[], Any] | None = None, name: str = "reality"
) -> Any:
    """``reality`` as a :class:`~realitygap.robots.effects.Reality` for a ``robot`` robot.

    Accepts a ``Reality``, a mapping in either form :meth:`Reality.from_dict` reads
    (``{"effects": [...]}`` or ``{"effect_name": {"param": value}}``), the path of a
    reality file (:mod:`~realitygap.robots.effects.twin`: its fitted values), or ``None``
    (``default()``, else the nominal ``Reality()``).

    Raises
    ------
    TypeError
        Anything else (a number, a list of effects).
    ValueError
        An unknown effect, a bad parameter, an unreadable file, or an effect for another
        robot, naming it.
    """
    import os

    from realitygap.robots.effects import Reality, load_reality

    if reality is None:
        reality = default() if default is not None else Reality()
    elif isinstance(reality, (str, os.PathLike)):
        if not str(reality).strip():
            raise ValueError(
                f"{name} is an empty path. Fix: give a reality file (e.g. a diagnosis's "
                "--export), a Reality or its dict form"
            )
        try:
            reality = load_reality(os.path.expanduser(reality), name)
        except FileNotFoundError as exc:  # a bad argument, like any other value
            hint = (
                ""
                if os.sep in str(reality) or str(reality).endswith((".json", ".yaml", ".yml"))
                else "; a profile name such as 'kobuki-worn' is the command line's, in Python "
                "realitygap.baselines.benchmark.reality_for(env_id, name) gives its Reality"
            )
            raise ValueError(
                f"{exc}. Fix: give the path of a reality file (a diagnosis's --export), a "
                f"Reality or its dict form{hint}"
            ) from None
    elif isinstance(reality, Mapping):
        try:
            reality = Reality.from_dict(reality)
        except (KeyError, ValueError, TypeError) as exc:
            msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
            raise ValueError(f"{name}: {msg}") from None
    elif not isinstance(reality, Reality):
        raise TypeError(
            f"{name} must be a Reality, its dict form or a reality file's path, got "
            f"{_describe(reality)}. Fix: pass Reality((make_effect(name, **values), ...)), "
            "{'effect_name': {'param': value}} or 'twin.json'"
        )
    try:
        reality.check_robot(robot)
    except ValueError as exc:
        raise ValueError(f"{name}: {exc}") from None
    return reality


def check_finite_fields(obj: Any) -> None:
    """Every field of the dataclass ``obj`` (a settings or weights class) is a finite real
    number, else ``TypeError``/``ValueError`` naming the class and the field. Called by
    their ``__post_init__``, so that a NaN weight is refused where it is written."""
    import dataclasses

    kind = type(obj).__name__
    for f in dataclasses.fields(obj):
        check_finite_float(
            getattr(obj, f.name),
            f"{kind}.{f.name}",
            fix=f"pass a real number, e.g. {kind}({f.name}={f.default!r})",
        )


def odometry_belief(estimator_reality: Any, params: Any) -> Any:
    """The differential drive an odometry calibrated to ``estimator_reality`` believes in:
    ``params`` with the reality's body effects (wheel sizes, wheelbase) and its encoder gains
    folded into the wheel radii — a wheel whose encoder reads ``g`` times its angle drives
    ``r / g`` per read radian. ``estimator_reality`` takes the forms of :func:`check_reality`.

    The encoder effects of the library are gains; the gain of each wheel is read from the
    reality's inverse encoder hooks at one radian.
    """
    reality = check_reality(estimator_reality, "diffdrive", name="estimator_reality")
    believed = reality.apply_params(params)
    left, right = 1.0, 1.0
    for hook in reality.ticks_inverse_hooks():  # reading -> true angle
        left, right = hook(left, right)
    if (left, right) != (1.0, 1.0):
        believed = believed.replace(
            wheel_radius_left=believed.wheel_radius_left * left,
            wheel_radius_right=believed.wheel_radius_right * right,
        )
    return believed


def robot_effects(robot: str) -> tuple[str, ...]:
    """The names of the registered effects for ``robot``, in registration order."""
    from realitygap.robots.effects import EFFECTS

    return tuple(n for n, c in EFFECTS.items() if c.robot == robot)


def check_randomize(
    randomize: Any, known: Sequence[str], known_what: str = "effects of this robot"
) -> dict[str, tuple[float, float]]:
    """An env's ``randomize``: ``{"effect.param": (low, high)}`` (or
    ``{"effect": {"param": (low, high)}}``, or a :class:`~realitygap.robots.effects.Twin`,
    whose boxes it takes), every effect one of ``known`` (``known_what`` says which those are)
    and every box within the parameter's physical bounds. Each episode draws the parameters
    uniformly from their boxes (:func:`~realitygap.robots.effects.draw_reality`).
    """
    from realitygap.robots.effects import EFFECTS, Twin

    out: dict[str, tuple[float, float]] = {}
    if isinstance(randomize, Twin):
        randomize = randomize.randomize
    if randomize is None:
        return out
    if not isinstance(randomize, Mapping):
        raise TypeError(
            f"randomize must be None or a mapping {{'effect.param': (low, high)}}, got "
            f"{randomize!r:.60} ({type(randomize).__name__}). Fix: e.g. "
            "randomize={'command_latency.delay': (0.0, 0.1)}"
        )
    flat: dict[str, Any] = {}
    for key, value in randomize.items():
        if isinstance(value, Mapping):  # nested form: effect -> {param: (low, high)}
            if str(key) not in known:
                flat[str(key)] = value  # refused below, naming the effect
                continue
            if not value:
                raise ValueError(
                    f"randomize[{key!r}] names no parameter; effect {key!r} has parameters "
                    f"{', '.join(s.name for s in EFFECTS[str(key)].specs)}"
                )
            for param, bounds in value.items():
                flat[f"{key}.{param}"] = bounds
        else:
            flat[str(key)] = value
    for key, bounds in flat.items():
        name, _, param = str(key).partition(".")
        if name not in known:
            raise ValueError(
                f"randomize key {key!r}: expected 'effect.param' with one of the {known_what} "
                f"({', '.join(known)})"
            )
        specs = {s.name: s for s in EFFECTS[name].specs}
        if param not in specs:
            raise ValueError(
                f"randomize key {key!r}: effect {name!r} has parameters {', '.join(specs)}"
            )
        try:
            lo, hi = (float(v) for v in bounds)
        except (TypeError, ValueError):
            raise ValueError(
                f"randomize[{key!r}] must be a (low, high) pair of numbers, got {bounds!r}"
            ) from None
        s = specs[param]
        if not (s.low <= lo <= hi <= s.high):
            raise ValueError(
                f"randomize[{key!r}] = ({lo}, {hi}) must satisfy {s.low} <= low <= high <= "
                f"{s.high} {s.unit} (the parameter's physical bounds)"
            )
        out[f"{name}.{param}"] = (lo, hi)
    return out
