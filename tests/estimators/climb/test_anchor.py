"""Tether anchor by single-point positioning: exact recovery and observability."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.estimators.climb.anchor import fit_plane, solve_anchor, solve_anchor_with_plane


@pytest.mark.parametrize("seed", range(5))
def test_exact_recovery_noise_free(seed: int) -> None:
    rng = np.random.default_rng(seed)
    anchor = rng.uniform(-3, 3, 3)
    p = rng.uniform(-1, 1, (30, 3))
    sol = solve_anchor(p, np.linalg.norm(p - anchor, axis=1))
    np.testing.assert_allclose(sol.anchor, anchor, atol=1e-9)
    assert sol.observable and sol.message == "ok"
    assert sol.residual_rms < 1e-9
    assert np.all(np.diff(sol.path_spread) <= 0)  # descending
    # path_spread is the RMS extent of the path along its principal axes
    centred = p - p.mean(axis=0)
    expected = np.sqrt(np.linalg.eigvalsh(centred.T @ centred / len(p)))[::-1]
    np.testing.assert_allclose(sol.path_spread, expected, rtol=1e-9)


def test_noisy_lengths_error_is_small() -> None:
    rng = np.random.default_rng(11)
    anchor = np.array([-0.5, 0.2, 1.0])
    p = np.c_[rng.uniform(1.5, 2.5, 200), rng.uniform(-0.4, 0.4, 200), rng.uniform(0, 0.3, 200)]
    lengths = np.linalg.norm(p - anchor, axis=1) + rng.normal(0, 0.002, 200)
    sol = solve_anchor(p, lengths)
    assert sol.observable
    assert np.linalg.norm(sol.anchor - anchor) < 0.05
    assert sol.residual_rms == pytest.approx(0.002, rel=0.3)


def test_straight_line_is_unobservable() -> None:
    t = np.linspace(0, 2, 40)
    direction = np.array([1.0, 0.5, 0.0]) / np.hypot(1, 0.5)
    p = t[:, None] * direction
    anchor = np.array([0.3, -1.0, 1.5])
    sol = solve_anchor(p, np.linalg.norm(p - anchor, axis=1))
    assert not sol.observable
    assert "rotate about the path line" in sol.message
    assert abs(sol.weak_direction @ direction) < 1e-9  # weak direction ⟂ the line
    # any anchor on the circle about the line fits: the range is still exact
    np.testing.assert_allclose(
        np.linalg.norm(p - sol.anchor, axis=1), np.linalg.norm(p - anchor, axis=1), atol=1e-6
    )


def test_planar_path_is_ambiguous_and_plane_constraint_fixes_it() -> None:
    rng = np.random.default_rng(3)
    p = np.c_[rng.uniform(-1, 1, (50, 2)), np.zeros(50)]
    anchor = np.array([0.4, -0.3, -0.8])  # below the plane
    lengths = np.linalg.norm(p - anchor, axis=1)
    sol = solve_anchor(p, lengths)  # picks the side "up" points to: the mirror
    assert not sol.observable and "planar" in sol.message and "mirror" in sol.message
    np.testing.assert_allclose(sol.anchor, anchor * [1, 1, -1], atol=1e-8)
    np.testing.assert_allclose(abs(sol.weak_direction @ [0, 0, 1]), 1.0, atol=1e-9)
    fixed = solve_anchor_with_plane(p, lengths, [0, 0, 1], -0.8)
    assert fixed.observable
    np.testing.assert_allclose(fixed.anchor, anchor, atol=1e-9)
    assert fixed.path_spread.shape == (2,)
    down = solve_anchor(p, lengths, up=(0, 0, -1))
    np.testing.assert_allclose(down.anchor, anchor, atol=1e-8)


def test_zero_weight_drops_a_slack_reading() -> None:
    rng = np.random.default_rng(5)
    anchor = np.array([1.0, 2.0, 3.0])
    p = rng.uniform(-1, 1, (20, 3))
    lengths = np.linalg.norm(p - anchor, axis=1)
    lengths[4] += 0.2
    w = np.ones(20)
    w[4] = 0.0
    np.testing.assert_allclose(solve_anchor(p, lengths, weights=w).anchor, anchor, atol=1e-9)


def test_fit_plane() -> None:
    rng = np.random.default_rng(0)
    n = np.array([0.2, -0.3, 0.9])
    n /= np.linalg.norm(n)
    basis = np.linalg.svd(np.eye(3) - np.outer(n, n))[0][:, :2]
    pts = rng.normal(size=(100, 2)) @ basis.T + 0.7 * n
    c, normal, rms = fit_plane(pts)
    np.testing.assert_allclose(normal, n, atol=1e-12)
    assert normal @ c == pytest.approx(0.7)
    assert rms < 1e-12


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((np.zeros((5, 2)), np.ones(5)), r"\(N, 3\)"),
        ((np.zeros((5, 3)), np.ones(4)), "match positions"),
        ((np.zeros((3, 3)), np.ones(3)), "at least 4"),
        ((np.zeros((5, 3)), -np.ones(5)), "positive"),
        ((np.full((5, 3), np.nan), np.ones(5)), "finite"),
    ],
)
def test_errors(args: tuple[np.ndarray, np.ndarray], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        solve_anchor(*args)


def test_more_errors() -> None:
    p = np.random.default_rng(0).normal(size=(6, 3))
    with pytest.raises(ValueError, match="weights"):
        solve_anchor(p, np.ones(6), weights=-np.ones(6))
    with pytest.raises(ValueError, match="normal"):
        solve_anchor_with_plane(p, np.ones(6), [0, 0, 0], 1.0)
    with pytest.raises(ValueError, match="N ≥ 3"):
        fit_plane(np.zeros((2, 3)))
