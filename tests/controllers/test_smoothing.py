"""Properties of the QP path smoother."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from realitygap.controllers import SmoothPath, available_qp_solvers, smooth_path
from realitygap.controllers import smoothing as smoothing_module
from realitygap.core.geometry import wrap_angle

FloatArray = npt.NDArray[np.float64]


def sine_waypoints(
    length: float = 6.0, amplitude: float = 0.3, spacing: float = 0.05
) -> FloatArray:
    x = np.arange(0.0, length + 1e-9, spacing)
    return np.column_stack([x, amplitude * np.sin(x)])


def distance_to_polyline(points: FloatArray, polyline: FloatArray) -> FloatArray:
    """Distance (m) from each point to the polyline."""
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    t = np.clip(
        np.einsum("kij,ij->ki", points[:, None, :] - a[None], ab) / np.einsum("ij,ij->i", ab, ab),
        0.0,
        1.0,
    )
    closest = a[None] + t[..., None] * ab[None]
    return np.min(np.linalg.norm(closest - points[:, None, :], axis=2), axis=1)


def random_gentle_path(rng: np.random.Generator) -> FloatArray:
    """Way-points of a random walk with bounded turning, 5 cm apart, 2 to 5 m long."""
    count = int(rng.integers(40, 100))
    heading = np.cumsum(rng.normal(0.0, 0.06, count)) + rng.uniform(-math.pi, math.pi)
    steps = 0.05 * np.column_stack([np.cos(heading), np.sin(heading)])
    return np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)]) + rng.uniform(-3, 3, 2)


@pytest.mark.parametrize("seed", range(8))
def test_endpoints_and_headings_are_exact(seed: int) -> None:
    rng = np.random.default_rng(seed)
    waypoints = random_gentle_path(rng)
    first_direction = math.atan2(*(waypoints[1] - waypoints[0])[::-1])
    last_direction = math.atan2(*(waypoints[-1] - waypoints[-2])[::-1])
    start_heading = first_direction + rng.uniform(-0.4, 0.4)
    end_heading = last_direction + rng.uniform(-0.4, 0.4)
    path = smooth_path(waypoints, start_heading, end_heading)
    assert path.feasible, path.message
    np.testing.assert_allclose(path.xy[0], waypoints[0], atol=1e-9)
    np.testing.assert_allclose(path.xy[-1], waypoints[-1], atol=1e-6)
    assert abs(float(wrap_angle(path.heading[0] - start_heading))) < 1e-6
    assert abs(float(wrap_angle(path.heading[-1] - end_heading))) < 1e-6
    assert -math.pi <= path.heading[0] < math.pi
    np.testing.assert_allclose(
        path.pose_at(0.0), [*waypoints[0], wrap_angle(start_heading)], atol=1e-6
    )


@pytest.mark.parametrize("heading", [math.pi / 2, -math.pi / 2, math.pi])
def test_heading_constraint_has_no_tangent_singularity_and_no_reversal(heading: float) -> None:
    direction = np.array([math.cos(heading), math.sin(heading)])
    lateral = np.array([-direction[1], direction[0]])
    s = np.linspace(0.0, 2.0, 41)
    waypoints = s[:, None] * direction + 0.2 * np.sin(1.5 * s)[:, None] * lateral
    end_heading = heading + math.atan(0.3 * math.cos(3.0))
    path = smooth_path(waypoints, heading + math.atan(0.3), end_heading)
    assert path.feasible, path.message
    # The tangent points forwards, not at heading + pi (which satisfies the same line constraint).
    assert abs(float(wrap_angle(path.heading[0] - heading - math.atan(0.3)))) < 1e-6
    assert abs(float(wrap_angle(path.heading[-1] - end_heading))) < 1e-6


def test_samples_follow_a_long_curved_path_with_continuous_heading_and_curvature() -> None:
    waypoints = sine_waypoints()
    path = smooth_path(waypoints, math.atan(0.3), math.atan(0.3 * math.cos(6.0)))
    assert path.feasible, path.message
    assert distance_to_polyline(waypoints, path.xy).max() < 0.01
    # Several receding segments were needed: the path is 4 segment lengths long.
    assert path.length > 4 * 1.5
    ds = np.diff(path.s)
    assert np.all(ds > 0.0)
    # No kink or curvature jump at the segment junctions: the exact curvature of y = 0.3 sin x
    # is at most 0.3 1/m and changes slowly.
    assert np.max(np.abs(np.diff(path.heading)) / ds) < 0.4
    assert np.max(np.abs(np.diff(path.curvature))) < 0.02
    exact = -0.3 * np.sin(path.xy[:, 0]) / (1 + (0.3 * np.cos(path.xy[:, 0])) ** 2) ** 1.5
    assert np.max(np.abs(path.curvature - exact)[20:-20]) < 0.1


def test_s_is_arc_length_and_sampling_is_uniform() -> None:
    path = smooth_path(sine_waypoints(3.0), math.atan(0.3), None, sample_spacing=0.02)
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path.xy, axis=0), axis=1))])
    np.testing.assert_allclose(path.s, chord, atol=1e-4)
    np.testing.assert_allclose(np.diff(path.s), 0.02, atol=1e-3)
    assert path.length == path.s[-1]


def test_two_aligned_points_give_a_straight_segment() -> None:
    path = smooth_path([[0.0, 0.0], [2.0, 1.0]], math.atan2(1, 2), math.atan2(1, 2))
    assert path.feasible
    assert path.length == pytest.approx(math.hypot(2, 1), abs=1e-6)
    np.testing.assert_allclose(path.curvature, 0.0, atol=1e-6)
    np.testing.assert_allclose(path.xy[:, 1], path.xy[:, 0] / 2, atol=1e-9)


def test_free_end_heading_follows_the_last_way_points() -> None:
    waypoints = sine_waypoints(3.0)
    path = smooth_path(waypoints, math.atan(0.3), None)
    assert path.feasible
    assert abs(path.heading[-1] - math.atan(0.3 * math.cos(3.0))) < 0.05


@pytest.mark.parametrize("solver", available_qp_solvers())
def test_result_is_deterministic_whatever_was_solved_before(solver: str) -> None:
    waypoints = random_gentle_path(np.random.default_rng(3))
    first = smooth_path(waypoints, 0.3, -0.2, solver=solver)
    smooth_path(sine_waypoints(), 0.1, 0.2, solver=solver)  # warm-starting solvers keep state
    second = smooth_path(waypoints, 0.3, -0.2, solver=solver)
    for name in ("xy", "heading", "curvature", "s"):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name))


@pytest.mark.parametrize("solver", available_qp_solvers())
def test_every_available_solver_gives_the_same_path(solver: str) -> None:
    waypoints = sine_waypoints(4.0)
    reference = smooth_path(waypoints, 0.2, -0.1)
    path = smooth_path(waypoints, 0.2, -0.1, solver=solver)
    assert path.feasible, path.message
    assert path.solver == solver
    np.testing.assert_allclose(path.xy, reference.xy, atol=1e-4)


@pytest.mark.parametrize(
    ("waypoints", "message"),
    [
        ([[1.0, 2.0]], "fewer than two distinct way-points"),
        ([[1.0, 2.0], [1.0, 2.0], [1.0, 2.0]], "fewer than two distinct way-points"),
        (np.zeros((0, 2)), "fewer than two distinct way-points"),
    ],
)
def test_degenerate_input_is_reported_not_raised(waypoints: object, message: str) -> None:
    path = smooth_path(waypoints, 0.0, None)
    assert not path.feasible
    assert message in path.message
    assert isinstance(path, SmoothPath)


def test_solver_failure_is_reported_with_the_polyline(monkeypatch: pytest.MonkeyPatch) -> None:
    def broken_solver(*_: object, **__: object) -> object:
        def solve(**___: object) -> object:
            raise RuntimeError("Error in Function::call\nsolver exploded")

        return solve

    monkeypatch.setattr(smoothing_module, "_qp_solver", broken_solver)
    waypoints = sine_waypoints(1.0)
    path = smooth_path(waypoints, 0.0, 0.0)
    assert not path.feasible
    assert "failed" in path.message and "solver exploded" in path.message
    np.testing.assert_array_equal(path.xy, waypoints)


def test_constraint_violation_is_reported(monkeypatch: pytest.MonkeyPatch) -> None:
    def sloppy_solver(*_: object, **__: object) -> object:
        class Sloppy:
            def __call__(self, **kwargs: object) -> dict[str, FloatArray]:
                return {"x": np.zeros(len(np.asarray(kwargs["g"])))}  # ignores the constraints

            def stats(self) -> dict[str, object]:
                return {"success": True, "return_status": "pretend"}

        return Sloppy()

    monkeypatch.setattr(smoothing_module, "_qp_solver", sloppy_solver)
    path = smooth_path(sine_waypoints(1.0), 0.0, 0.0)
    assert not path.feasible
    assert "constraint violated" in path.message


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"waypoints": np.zeros((4, 3))}, r"waypoints must have shape \(K, 2\)"),
        ({"waypoints": [[0.0, 0.0], [np.nan, 1.0]]}, "waypoints must be finite"),
        ({"start_heading": math.inf}, "start_heading must be finite"),
        ({"end_heading": math.nan}, "end_heading must be finite"),
        ({"degree": 2}, "degree must be an integer >= 3"),
        ({"overlap": 1.5}, r"overlap must lie in \[0, 0.9\]"),
        ({"segment_length": 0.0}, "segment_length must be finite and > 0"),
        ({"smoothness_weight": -1.0}, "smoothness_weight must be finite and >= 0"),
        ({"solver": "no_such_plugin"}, "solver 'no_such_plugin' is not available"),
    ],
)
def test_malformed_input_raises(kwargs: dict[str, object], match: str) -> None:
    arguments: dict[str, object] = {"waypoints": [[0.0, 0.0], [1.0, 0.0]], "start_heading": 0.0}
    arguments.update(kwargs)
    with pytest.raises(ValueError, match=match):
        smooth_path(**arguments)
