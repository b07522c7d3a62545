"""The fast step's smaller kernels give the bits of their reference forms: the bound body ramp (compiled against Python), the ray
cast's skips of boxes behind the origin (beams with direction components of exactly ±0.0),
and the measurement records built without the generated frozen ``__init__`` keep the
dataclass behaviour (frozen, equality, ``replace``, keywords, defaults)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from realitygap.core import jit
from realitygap.envs.layouts import room_walls
from realitygap.estimators.base import DiffDriveMeasurement, Scan, WheelTicks
from realitygap.robots import raycast, world
from realitygap.robots.diffdrive import Deceleration, FirmwareLimits

needs_numba = pytest.mark.skipif(
    not jit.numba_available(), reason="numba is not installed (or REALITYGAP_DISABLE_JIT is set)"
)


@pytest.mark.parametrize("deceleration", list(Deceleration))
def test_bound_body_ramp_gives_the_limit_bits(deceleration: Deceleration) -> None:
    """FirmwareLimits.bound (compiled where Numba is installed) against FirmwareLimits.step,
    request by request, from rest, with reversals, zero requests and saturation."""
    limits = FirmwareLimits(0.7, 2.0, 0.5, 1.5, deceleration=deceleration, decel_factor=2.5)
    dt, wheelbase = 0.05, 0.23
    bound = limits.bound(dt, wheelbase)
    rng = np.random.default_rng(5)
    requests = rng.uniform(-1.2, 1.2, size=(3000, 2))
    requests[rng.random(3000) < 0.1] = 0.0  # exact stops
    v = w = 0.0
    for rv, rw in requests.tolist():
        got = bound(rv, rw, v, w)
        with jit.numpy_only():
            want = limits.step(rv, rw, v, w, dt, wheelbase)
        assert np.array(got).tobytes() == np.array(want).tobytes(), (rv, rw, v, w)
        assert all(type(u) is float for u in got)
        v, w = got


def test_box_skips_keep_the_numpy_cast_bits_for_signed_zero_directions() -> None:
    """Beams whose direction components are exactly +0.0 or -0.0 in the box frames (axis
    beams at heading 0 in a room of axis-aligned walls), from origins beyond the faces,
    on them and inside: the loop cast skips boxes behind the origin and keeps the bits."""
    arrays = raycast.PrimitiveArrays(
        [*room_walls(2.0), world.Primitive("b", world.Shape.BOX, (0.5, 0.5), 0.5, 0.0, (0.2, 0.4))]
    )
    # (cos, sin) of the beams: the four axes with both signs of zero, and oblique ones
    ang = np.random.default_rng(9).uniform(-math.pi, math.pi, 40)
    cos = np.concatenate([[1.0, -1.0, 0.0, -0.0, 0.0, -0.0, 1.0, -1.0], np.cos(ang)])
    sin = np.concatenate([[0.0, -0.0, 1.0, -1.0, -1.0, 1.0, -0.0, 0.0], np.sin(ang)])
    kernels = [raycast.cast_rotated_beams]
    if jit.numba_available():
        kernels.append(raycast.cast_rotated_beams_compiled)
    origins = [(0.0, 0.0), (2.3, 0.1), (-2.3, -0.1), (0.1, 2.3), (0.2, -2.3), (2.0, 2.0)]
    origins += [(0.7, 0.5), (0.5, 0.9), (0.5, 0.5), (3.0, 3.0), (1.9, 0.0), (0.3, 0.5)]
    n_hits = 0
    for ox, oy in origins:
        for c, s in ((1.0, 0.0), (1.0, -0.0), (-1.0, 0.0)):
            d = np.stack([cos, cos])[:, None, :] * np.array([c, s]).reshape(2, 1, 1)
            d += np.stack([sin, sin])[:, None, :] * np.array([-s, c]).reshape(2, 1, 1)
            with np.errstate(invalid="ignore", divide="ignore"):
                want = arrays.cast_directions(ox, oy, d, 6.0)
            for kernel in kernels:
                got = np.empty_like(want)
                with np.errstate(invalid="ignore", divide="ignore"):
                    kernel(ox, oy, c, s, cos, sin, arrays.box_rows, arrays.cyl_rows, 6.0, got)
                assert got.tobytes() == want.tobytes(), (ox, oy, c, s, got, want)
            n_hits += int(np.isfinite(want).sum())
    assert n_hits > 500


def test_measurement_records_keep_their_dataclass_behaviour() -> None:
    ticks = WheelTicks(0.1, 12, -3, 2578.0)
    assert ticks == WheelTicks(t=0.1, left=12, right=-3, ticks_per_rev=2578.0)
    assert hash(ticks) == hash(WheelTicks(0.1, 12, -3, 2578.0))
    assert dataclasses.replace(ticks, left=13).left == 13
    assert [f.name for f in dataclasses.fields(ticks)] == ["t", "left", "right", "ticks_per_rev"]
    with pytest.raises(dataclasses.FrozenInstanceError, match="cannot assign to field 't'"):
        ticks.t = 0.2  # type: ignore[misc]
    scan = Scan(0.1, np.zeros(3), np.ones(3), 0.1, 8.0)
    assert dataclasses.replace(scan, range_max=4.0).range_max == 4.0
    with pytest.raises(dataclasses.FrozenInstanceError, match="cannot assign to field"):
        scan.ranges = np.zeros(3)  # type: ignore[misc]
    m = DiffDriveMeasurement(0.1, ticks)
    assert m.scan is None and m.rgbd is None
    assert m == DiffDriveMeasurement(t=0.1, ticks=ticks, scan=None, rgbd=None)
    assert repr(m).startswith("DiffDriveMeasurement(t=0.1, ticks=WheelTicks(t=0.1, left=12")
    with pytest.raises(TypeError, match="ticks"):
        DiffDriveMeasurement(0.1)  # type: ignore[call-arg]
    with pytest.raises(dataclasses.FrozenInstanceError, match="cannot assign to field"):
        m.scan = scan  # type: ignore[misc]
