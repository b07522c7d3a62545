"""Blade geometry: NACA sections, closed mesh, UVs, CAD cloud, deformation, texture, OBJ."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from realitygap.robots.blade_geometry import (
    BladeParams,
    BladeSurface,
    blade_mesh,
    blade_texture,
    cad_point_cloud,
    deformed,
    naca4_digits,
    write_obj,
)


def _half_thickness(xi: np.ndarray, t: float) -> np.ndarray:
    return (
        5
        * t
        * (0.2969 * np.sqrt(xi) - 0.1260 * xi - 0.3516 * xi**2 + 0.2843 * xi**3 - 0.1036 * xi**4)
    )


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6)


def test_naca4_digits() -> None:
    assert naca4_digits("4418") == (0.04, 0.4, 0.18)
    assert naca4_digits("0012") == (0.0, 0.0, 0.12)


@pytest.mark.parametrize(
    ("code", "match"),
    [("44A8", "4-digit"), ("441", "4-digit"), ("4400", "zero thickness"), ("4012", "both")],
)
def test_naca4_digits_errors(code: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        naca4_digits(code)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"length": -1.0}, "length"),
        ({"twist_root": 12.0}, "rad"),
        ({"pitch_axis": 1.2}, "pitch_axis"),
        ({"n_profile_points": 41}, "even"),
        ({"n_sections": 1}, "n_sections"),
        ({"root_profile": "44x8"}, "4-digit"),
    ],
)
def test_params_errors(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        BladeParams(**kwargs)  # type: ignore[arg-type]


def test_mesh_is_closed_and_outward() -> None:
    prm = BladeParams(n_sections=21, n_profile_points=60, prebend_tip=0.2)
    v, f, uv = blade_mesh(prm)
    assert v.shape[1] == 3 and f.shape[1] == 3 and uv.shape == (len(v), 2)
    assert f.dtype.kind == "i" and f.min() >= 0 and f.max() < len(v)
    # weld the duplicated trailing-edge seam by position
    _, weld = np.unique(np.round(v, 9), axis=0, return_inverse=True)
    fw = weld.ravel()[f]
    directed = np.concatenate([fw[:, [0, 1]], fw[:, [1, 2]], fw[:, [2, 0]]])
    # consistent orientation: every directed edge once, and its reverse once
    keys = {tuple(e) for e in directed.tolist()}
    assert len(keys) == len(directed)
    assert all((b, a) in keys for a, b in keys)
    assert _signed_volume(v, f) > 0  # outward normals


def test_mesh_volume_matches_sections() -> None:
    prm = BladeParams(n_sections=41, n_profile_points=200)
    v, f, _ = blade_mesh(prm)
    surf = BladeSurface(prm)
    s = np.linspace(0, 1, 401)
    u = np.arange(2000) / 2000
    ring = surf.position(s[:, None], u[None, :])
    y, z = ring[..., 1], ring[..., 2]
    area = 0.5 * np.abs(np.sum(y * np.roll(z, -1, 1) - np.roll(y, -1, 1) * z, axis=1))
    expected = float(np.trapezoid(area, s * prm.length))
    assert _signed_volume(v, f) == pytest.approx(expected, rel=5e-3)


def test_chord_and_twist_closed_form() -> None:
    prm = BladeParams(
        root_profile="0012", tip_profile="0012", twist_root=0.2, twist_tip=-0.05, twist_exponent=1.5
    )
    surf = BladeSurface(prm)
    for s in (0.0, 0.37, 1.0):
        le = surf.position(s, 0.5)
        te = surf.position(s, 0.0)
        assert np.linalg.norm(te - le) == pytest.approx(float(prm.chord_at(s)), rel=1e-9)
        # nose-up twist: the leading edge rises, so the chord line LE → TE points down
        angle = np.arctan2(te[2] - le[2], te[1] - le[1])
        assert angle == pytest.approx(-float(prm.twist_at(s)), abs=1e-9)
        # the pitch axis lies on the x axis
        axis = le + prm.pitch_axis * (te - le)
        np.testing.assert_allclose(axis[1:], 0.0, atol=1e-12)
        assert axis[0] == pytest.approx(s * prm.length)


def test_uv_are_surface_lengths_over_tile() -> None:
    prm = BladeParams(n_sections=11, n_profile_points=40, texture_tile=0.5)
    v, _, uv = blade_mesh(prm)
    np.testing.assert_allclose(uv[:, 0], v[:, 0] / 0.5, atol=1e-12)
    ring = v[:41]
    perimeter = np.sum(np.linalg.norm(np.diff(ring, axis=0), axis=1))
    assert uv[0, 1] == 0.0
    assert uv[40, 1] == pytest.approx(perimeter / 0.5)
    np.testing.assert_allclose(v[40], v[0])  # seam duplicate


def test_cad_cloud_on_symmetric_untwisted_blade() -> None:
    prm = BladeParams(
        length=1.0,
        root_chord=0.5,
        tip_chord=0.5,
        root_profile="0012",
        tip_profile="0012",
        twist_root=0.0,
        twist_tip=0.0,
    )
    pts, nrm = cad_point_cloud(prm, 0.005)
    xi = pts[:, 1] / 0.5 + prm.pitch_axis
    expected = _half_thickness(np.clip(xi, 0, 1), 0.12) * 0.5
    np.testing.assert_allclose(np.abs(pts[:, 2]), expected, atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-12)
    # convex section: normals point away from the section's centre line
    centre = np.c_[pts[:, 0], np.full(len(pts), (0.5 - prm.pitch_axis) * 0.5), np.zeros(len(pts))]
    assert np.all(np.einsum("ij,ij->i", nrm, pts - centre) > 0)
    # closed-form normal on the upper surface away from the edges: (0, -dz/dy, 1)
    sel = (pts[:, 2] > 0) & (xi > 0.1) & (xi < 0.9)
    d = 1e-6
    slope = (_half_thickness(xi[sel] + d, 0.12) - _half_thickness(xi[sel] - d, 0.12)) / (2 * d)
    n_ref = np.c_[np.zeros(sel.sum()), -slope, np.ones(sel.sum())]
    n_ref /= np.linalg.norm(n_ref, axis=1, keepdims=True)
    np.testing.assert_allclose(nrm[sel], n_ref, atol=1e-6)
    # spacing
    tree_d = np.sort(np.linalg.norm(pts[:200, None] - pts[None], axis=2), axis=1)[:, 1]
    assert np.median(tree_d) == pytest.approx(0.005, rel=0.3)


def test_cad_cloud_errors() -> None:
    with pytest.raises(ValueError, match="spacing"):
        cad_point_cloud(BladeParams(), 0.0)
    with pytest.raises(TypeError, match="BladeParams"):
        cad_point_cloud("blade", 0.01)  # type: ignore[arg-type]


def test_deformed_is_smooth_bounded_and_reproducible() -> None:
    prm = BladeParams()
    nominal = BladeSurface(prm)
    real = deformed(prm, 0.004, np.random.default_rng(3))
    again = deformed(prm, 0.004, np.random.default_rng(3))
    s, u = np.meshgrid(np.linspace(0, 1, 201), np.linspace(0, 1, 201), indexing="ij")
    d = np.einsum(
        "...i,...i->...", real.position(s, u) - nominal.position(s, u), nominal.normal(s, u)
    )
    assert np.abs(d).max() <= 0.004 * (1 + 1e-6)
    assert np.abs(d).max() >= 0.003
    np.testing.assert_allclose(real.position(s, u), again.position(s, u))
    np.testing.assert_allclose(d[:, 0], 0.0, atol=1e-12)  # trailing edge kept
    # low frequency: |∂d/∂s| ≤ 2π Σ |a_k| f_k (closed-form bound of the cosine modes)
    assert real.bump is not None
    bound = 2 * np.pi * np.sum(np.abs(real.bump.amplitudes) * real.bump.span_cycles) / 200
    assert np.abs(np.diff(d, axis=0)).max() <= bound * (1 + 1e-6)
    assert np.all(real.bump.span_cycles <= prm.length / 1.0)  # wavelength ≥ 1 m
    assert deformed(prm, 0.0, np.random.default_rng(0)).bump is None


def test_deformed_errors() -> None:
    with pytest.raises(ValueError, match="deviation_m"):
        deformed(BladeParams(), -0.001, np.random.default_rng(0))
    with pytest.raises(TypeError, match="BladeParams"):
        deformed(BladeSurface(), 0.001, np.random.default_rng(0))  # type: ignore[arg-type]


def test_texture_tiles_and_has_features_at_several_scales() -> None:
    tex = blade_texture(np.random.default_rng(0), 256)
    assert tex.shape == (256, 256, 3) and tex.dtype == np.uint8
    grey = cv2.cvtColor(tex, cv2.COLOR_RGB2GRAY).astype(float)
    inner = np.abs(np.diff(grey, axis=1)).mean()
    seam = np.abs(grey[:, 0] - grey[:, -1]).mean()
    assert seam < 1.5 * inner  # no visible seam when tiled
    big = cv2.cvtColor(np.tile(tex, (2, 2, 1)), cv2.COLOR_RGB2GRAY)
    for scale in (1, 2, 4):
        img = cv2.resize(big, None, fx=1 / scale, fy=1 / scale, interpolation=cv2.INTER_AREA)
        corners = cv2.goodFeaturesToTrack(img, 500, 0.01, 3)
        assert corners is not None and len(corners) > 40
    assert not np.array_equal(tex, blade_texture(np.random.default_rng(1), 256))
    with pytest.raises(ValueError, match="size_px"):
        blade_texture(np.random.default_rng(0), 10)


def test_write_obj_round_trip(tmp_path: os.PathLike[str]) -> None:
    v, f, uv = blade_mesh(BladeParams(n_sections=5, n_profile_points=16))
    path = write_obj(os.path.join(tmp_path, "blade.obj"), v, f, uv, texture_file="blade.png")
    lines = path.read_text().splitlines()
    assert sum(line.startswith("v ") for line in lines) == len(v)
    assert sum(line.startswith("vt ") for line in lines) == len(v)
    faces = [line for line in lines if line.startswith("f ")]
    assert len(faces) == len(f)
    a, b, c = (int(tok.split("/")[0]) for tok in faces[0].split()[1:])
    assert (a - 1, b - 1, c - 1) == tuple(f[0])
    parsed = np.array(
        [[float(x) for x in line.split()[1:]] for line in lines if line.startswith("v ")]
    )
    np.testing.assert_allclose(parsed, v, atol=1e-8)
    assert "map_Kd blade.png" in path.with_suffix(".mtl").read_text()
    assert sorted(os.listdir(tmp_path)) == ["blade.mtl", "blade.obj"]  # no temp files left


def test_write_obj_errors(tmp_path: os.PathLike[str]) -> None:
    v, f, uv = blade_mesh(BladeParams(n_sections=3, n_profile_points=8))
    with pytest.raises(ValueError, match=r"\.obj"):
        write_obj(os.path.join(tmp_path, "blade.stl"), v, f)
    with pytest.raises(ValueError, match="does not exist"):
        write_obj(os.path.join(tmp_path, "missing", "blade.obj"), v, f)
    with pytest.raises(ValueError, match="index vertices"):
        write_obj(os.path.join(tmp_path, "blade.obj"), v, f + len(v))
    with pytest.raises(ValueError, match="uv must"):
        write_obj(os.path.join(tmp_path, "blade.obj"), v, f, uv[:-1])
