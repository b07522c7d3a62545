"""Wind-turbine blade geometry: a lofted NACA 4-digit blade, its mesh, texture and CAD cloud.

Pure numpy (no PyBullet): the simulation loads the mesh written by :func:`write_obj`,
the estimators use the point cloud of :func:`cad_point_cloud` as the "CAD model".

Blade frame (``blade``, also the CAD frame): origin on the pitch axis at the root,
``x`` along the span from root (``x = 0``) to tip (``x = length``), ``y`` along the
chord from the leading edge towards the trailing edge, ``z`` towards the suction
(upper) side. All lengths in m, angles in rad.

Surface parameters: ``span`` :math:`s \\in [0, 1]` (``x = s L``) and the profile
parameter :math:`u \\in [0, 1)`, which runs from the trailing edge along the pressure
(lower) side to the leading edge (:math:`u = 1/2`) and back along the suction side.
The chord station is :math:`\\xi = \\cos^2(\\pi u)` (cosine spacing, dense at both
edges), and the NACA 4-digit half-thickness with a closed trailing edge is

.. math::

    y_t(\\xi) = 5 t \\left(0.2969 \\sqrt{\\xi} - 0.1260 \\xi - 0.3516 \\xi^2
                + 0.2843 \\xi^3 - 0.1036 \\xi^4\\right),

applied normal to the camber line :math:`y_c(\\xi)` of maximum camber ``m`` at ``p``.
A section at span ``s`` is scaled by the chord :math:`c(s)`, shifted so that the
pitch axis (chord fraction ``pitch_axis``) lies on the ``x`` axis, rotated nose-up
by the twist :math:`\\theta(s)` and offset along ``z`` by the pre-bend.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from realitygap.core.io import atomic_write_text

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = [
    "BladeParams",
    "BladeSurface",
    "BumpField",
    "blade_mesh",
    "blade_texture",
    "cad_point_cloud",
    "deformed",
    "naca4_digits",
    "write_obj",
]

_FD_STEP = 1e-6
"""Finite-difference step in the (dimensionless) surface parameters."""


def naca4_digits(code: str) -> tuple[float, float, float]:
    """Parse a NACA 4-digit code into ``(m, p, t)`` as chord fractions.

    ``"4418"`` → maximum camber ``m = 0.04`` at ``p = 0.4``, thickness ``t = 0.18``.

    >>> naca4_digits("4418")
    (0.04, 0.4, 0.18)
    """
    if not isinstance(code, str) or len(code) != 4 or not code.isdigit():
        raise ValueError(f"NACA profile must be a 4-digit string such as '4418', got {code!r}")
    m = int(code[0]) / 100.0
    p = int(code[1]) / 10.0
    t = int(code[2:]) / 100.0
    if t <= 0.0:
        raise ValueError(f"NACA profile {code!r} has zero thickness; use e.g. '4412'")
    if (m > 0.0) != (p > 0.0):
        raise ValueError(
            f"NACA profile {code!r}: camber and camber position must both be zero "
            "(symmetric, e.g. '0012') or both non-zero (e.g. '4412')"
        )
    return m, p, t


@dataclass(frozen=True)
class BladeParams:
    """Geometric parameters of the blade (SI units, angles in rad).

    Attributes
    ----------
    length
        Span, m.
    root_chord, tip_chord
        Chord at the root and the tip, m; linear taper in between.
    root_profile, tip_profile
        NACA 4-digit codes at root and tip; camber, camber position and thickness
        are interpolated linearly along the span (e.g. ``"4418"`` → ``"4412"``).
    twist_root, twist_tip
        Nose-up twist at root and tip, rad.
    twist_exponent
        Shape of the twist distribution,
        :math:`\\theta(s) = \\theta_{tip} + (\\theta_{root} - \\theta_{tip})(1 - s)^k`.
    pitch_axis
        Chord fraction of the twist axis (on the chord line), in ``(0, 1)``.
    prebend_tip
        Offset of the tip section along ``+z``, m; quadratic in span (0: straight).
    n_sections
        Number of sections of the mesh along the span (≥ 2).
    n_profile_points
        Number of distinct points around each section of the mesh (even, ≥ 8).
    texture_tile
        Edge of one texture repeat on the surface, m; the mesh UVs are surface
        lengths divided by it (renderers wrap them).
    """

    length: float = 8.0
    root_chord: float = 1.2
    tip_chord: float = 0.5
    root_profile: str = "4418"
    tip_profile: str = "4412"
    twist_root: float = 0.2
    twist_tip: float = 0.0
    twist_exponent: float = 2.0
    pitch_axis: float = 0.3
    prebend_tip: float = 0.0
    n_sections: int = 81
    n_profile_points: int = 160
    texture_tile: float = 0.25

    def __post_init__(self) -> None:
        for name in ("length", "root_chord", "tip_chord", "texture_tile"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(
                    f"BladeParams.{name} must be a positive length in m, got {value!r}"
                )
        for name in ("twist_root", "twist_tip", "prebend_tip", "twist_exponent"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"BladeParams.{name} must be finite, got {value!r}")
        if abs(self.twist_root) > 1.0 or abs(self.twist_tip) > 1.0:
            raise ValueError(
                "BladeParams twist must be in rad (|twist| ≤ 1 rad), got "
                f"root={self.twist_root!r}, tip={self.twist_tip!r}; convert degrees with np.deg2rad"
            )
        if self.twist_exponent <= 0.0:
            raise ValueError(f"BladeParams.twist_exponent must be > 0, got {self.twist_exponent!r}")
        if not 0.0 < self.pitch_axis < 1.0:
            raise ValueError(f"BladeParams.pitch_axis must be in (0, 1), got {self.pitch_axis!r}")
        naca4_digits(self.root_profile)
        naca4_digits(self.tip_profile)
        if int(self.n_sections) != self.n_sections or self.n_sections < 2:
            raise ValueError(
                f"BladeParams.n_sections must be an integer ≥ 2, got {self.n_sections!r}"
            )
        if (
            int(self.n_profile_points) != self.n_profile_points
            or self.n_profile_points < 8
            or self.n_profile_points % 2
        ):
            raise ValueError(
                "BladeParams.n_profile_points must be an even integer ≥ 8, "
                f"got {self.n_profile_points!r}"
            )

    def chord_at(self, span: npt.ArrayLike) -> FloatArray:
        """Chord in m at span fraction(s) ``span``."""
        s = np.asarray(span, dtype=float)
        return self.root_chord + (self.tip_chord - self.root_chord) * s

    def twist_at(self, span: npt.ArrayLike) -> FloatArray:
        """Nose-up twist in rad at span fraction(s) ``span``."""
        s = np.clip(np.asarray(span, dtype=float), -0.5, 1.5)
        return self.twist_tip + (self.twist_root - self.twist_tip) * np.abs(1.0 - s) ** (
            self.twist_exponent
        )

    def profile_at(self, span: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Camber ``m``, camber position ``p`` and thickness ``t`` (chord fractions) at ``span``."""
        s = np.asarray(span, dtype=float)
        m0, p0, t0 = naca4_digits(self.root_profile)
        m1, p1, t1 = naca4_digits(self.tip_profile)
        return m0 + (m1 - m0) * s, p0 + (p1 - p0) * s, t0 + (t1 - t0) * s

    def prebend_at(self, span: npt.ArrayLike) -> FloatArray:
        """Pre-bend offset along ``+z`` in m at ``span``."""
        s = np.asarray(span, dtype=float)
        return self.prebend_tip * s**2


def _naca_section(
    u: FloatArray, m: FloatArray, p: FloatArray, t: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Chord-normalised section point ``(xi, eta)`` at profile parameter ``u`` (broadcast)."""
    u = np.mod(u, 1.0)
    cos_pu = np.cos(np.pi * u)
    xi = cos_pu**2
    upper = np.where(u >= 0.5, 1.0, -1.0)
    # sqrt(xi) carries its sign through -cos(pi u): smooth across the leading edge.
    yt = (
        5.0
        * t
        * (
            0.2969 * (-cos_pu)
            + upper * (-0.1260 * xi - 0.3516 * xi**2 + 0.2843 * xi**3 - 0.1036 * xi**4)
        )
    )
    cambered = m > 0.0
    p_safe = np.where(cambered, p, 0.5)
    fore = xi < p_safe
    yc = np.where(
        fore,
        m / p_safe**2 * (2.0 * p_safe * xi - xi**2),
        m / (1.0 - p_safe) ** 2 * ((1.0 - 2.0 * p_safe) + 2.0 * p_safe * xi - xi**2),
    )
    dyc = np.where(
        fore,
        2.0 * m / p_safe**2 * (p_safe - xi),
        2.0 * m / (1.0 - p_safe) ** 2 * (p_safe - xi),
    )
    yc = np.where(cambered, yc, 0.0)
    dyc = np.where(cambered, dyc, 0.0)
    theta = np.arctan(dyc)
    return xi - yt * np.sin(theta), yc + yt * np.cos(theta)


@dataclass(frozen=True)
class BumpField:
    """Smooth, low-frequency normal displacement of the surface (a CAD-vs-real deviation).

    .. math::

        d(s, u) = \\sin^2(\\pi u) \\sum_k a_k
                  \\cos\\left(2\\pi (f_k s + g_k u) + \\phi_k\\right),

    ``f_k`` cycles per span, integer ``g_k`` cycles per section perimeter (so that the
    field is periodic around the section), amplitudes ``a_k`` in m. The
    :math:`\\sin^2(\\pi u)` factor vanishes at the trailing edge.
    """

    amplitudes: FloatArray
    span_cycles: FloatArray
    profile_cycles: FloatArray
    phases: FloatArray

    def __call__(self, span: npt.ArrayLike, u: npt.ArrayLike) -> FloatArray:
        """Displacement in m along the nominal outward normal at ``(span, u)``."""
        s = np.asarray(span, dtype=float)[..., None]
        uu = np.asarray(u, dtype=float)[..., None]
        arg = 2.0 * np.pi * (self.span_cycles * s + self.profile_cycles * uu) + self.phases
        return np.sin(np.pi * uu[..., 0]) ** 2 * np.sum(self.amplitudes * np.cos(arg), axis=-1)


@dataclass(frozen=True)
class BladeSurface:
    """The analytic blade surface, optionally displaced by a :class:`BumpField`.

    ``position`` and ``normal`` broadcast over arrays of ``span`` and ``u`` and return
    ``(..., 3)`` arrays in the blade frame (m; unit outward normals).
    """

    params: BladeParams = field(default_factory=BladeParams)
    bump: BumpField | None = None

    def nominal_position(self, span: npt.ArrayLike, u: npt.ArrayLike) -> FloatArray:
        """Point of the undeformed surface at ``(span, u)``, shape ``(..., 3)`` m."""
        prm = self.params
        s, uu = np.broadcast_arrays(np.asarray(span, dtype=float), np.asarray(u, dtype=float))
        m, p, t = prm.profile_at(s)
        xi, eta = _naca_section(uu, m, p, t)
        c = prm.chord_at(s)
        y0 = (xi - prm.pitch_axis) * c
        z0 = eta * c
        tw = prm.twist_at(s)
        # nose-up: the leading edge (y < 0) moves towards +z.
        cos_t, sin_t = np.cos(tw), np.sin(tw)
        y = cos_t * y0 + sin_t * z0
        z = -sin_t * y0 + cos_t * z0 + prm.prebend_at(s)
        return np.stack([s * prm.length, y, z], axis=-1)

    def _tangents(self, span: FloatArray, u: FloatArray, fn: str) -> tuple[FloatArray, FloatArray]:
        f = getattr(self, fn)
        d_s = (f(span + _FD_STEP, u) - f(span - _FD_STEP, u)) / (2.0 * _FD_STEP)
        d_u = (f(span, u + _FD_STEP) - f(span, u - _FD_STEP)) / (2.0 * _FD_STEP)
        return d_s, d_u

    def nominal_normal(self, span: npt.ArrayLike, u: npt.ArrayLike) -> FloatArray:
        """Unit outward normal of the undeformed surface, shape ``(..., 3)``."""
        s, uu = np.broadcast_arrays(np.asarray(span, dtype=float), np.asarray(u, dtype=float))
        d_s, d_u = self._tangents(s, uu, "nominal_position")
        n = np.cross(d_s, d_u)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def position(self, span: npt.ArrayLike, u: npt.ArrayLike) -> FloatArray:
        """Point of the (possibly displaced) surface at ``(span, u)``, shape ``(..., 3)`` m."""
        x = self.nominal_position(span, u)
        if self.bump is None:
            return x
        d = self.bump(span, u)
        return x + d[..., None] * self.nominal_normal(span, u)

    def normal(self, span: npt.ArrayLike, u: npt.ArrayLike) -> FloatArray:
        """Unit outward normal of the (possibly displaced) surface, shape ``(..., 3)``."""
        if self.bump is None:
            return self.nominal_normal(span, u)
        s, uu = np.broadcast_arrays(np.asarray(span, dtype=float), np.asarray(u, dtype=float))
        d_s, d_u = self._tangents(s, uu, "position")
        n = np.cross(d_s, d_u)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def mesh(self) -> tuple[FloatArray, IntArray, FloatArray]:
        """Triangle mesh of the closed blade; see :func:`blade_mesh`."""
        return _mesh(self)

    def point_cloud(self, spacing: float = 0.01) -> tuple[FloatArray, FloatArray]:
        """Points and unit outward normals on the skin; see :func:`cad_point_cloud`."""
        return _point_cloud(self, spacing)


def _as_surface(blade: BladeParams | BladeSurface) -> BladeSurface:
    if isinstance(blade, BladeSurface):
        return blade
    if isinstance(blade, BladeParams):
        return BladeSurface(blade)
    raise TypeError(
        f"expected BladeParams or BladeSurface, got {type(blade).__name__}; "
        "build one with BladeParams(...)"
    )


def _mesh(surface: BladeSurface) -> tuple[FloatArray, IntArray, FloatArray]:
    prm = surface.params
    ns, n = int(prm.n_sections), int(prm.n_profile_points)
    span = np.linspace(0.0, 1.0, ns)
    u = np.arange(n + 1) / n  # last column duplicates the trailing edge (texture seam)
    grid = surface.position(span[:, None], u[None, :])  # (ns, n+1, 3)
    grid[:, n] = grid[:, 0]
    seg = np.linalg.norm(np.diff(grid, axis=1), axis=-1)
    arc = np.concatenate([np.zeros((ns, 1)), np.cumsum(seg, axis=1)], axis=1)
    uv = (
        np.stack([np.broadcast_to(span[:, None] * prm.length, arc.shape), arc], axis=-1)
        / prm.texture_tile
    )
    vertices = grid.reshape(-1, 3)
    uv = uv.reshape(-1, 2)
    stride = n + 1

    i, j = np.meshgrid(np.arange(ns - 1), np.arange(n), indexing="ij")
    a = (i * stride + j).ravel()
    b = ((i + 1) * stride + j).ravel()
    c = ((i + 1) * stride + j + 1).ravel()
    d = (i * stride + j + 1).ravel()
    side = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])

    def cap(ring0: int) -> IntArray:
        r = ring0 + np.arange(n)
        tris = [[r[0], r[1], r[n - 1]]]
        for k in range(1, n // 2 - 1):
            tris.append([r[k], r[k + 1], r[n - k - 1]])
            tris.append([r[k], r[n - k - 1], r[n - k]])
        tris.append([r[n // 2 - 1], r[n // 2], r[n // 2 + 1]])
        return np.asarray(tris, dtype=np.int64)

    root = cap(0)  # normal along -x
    tip = cap((ns - 1) * stride)[:, ::-1]  # normal along +x
    faces = np.concatenate([side, root, tip]).astype(np.int64)
    return vertices, faces, uv


def _point_cloud(surface: BladeSurface, spacing: float) -> tuple[FloatArray, FloatArray]:
    if not (math.isfinite(spacing) and 1e-4 <= spacing <= 0.5):
        raise ValueError(f"spacing must be in [1e-4, 0.5] m, got {spacing!r}")
    prm = surface.params
    n_span = int(math.ceil(prm.length / spacing)) + 1
    span = np.linspace(0.0, 1.0, n_span)
    dense = 4096
    u_dense = np.arange(dense + 1) / dense
    u_all: list[FloatArray] = []
    s_all: list[FloatArray] = []
    chunk = 64
    for start in range(0, n_span, chunk):
        s_chunk = span[start : start + chunk]
        ring = surface.nominal_position(s_chunk[:, None], u_dense[None, :])
        seg = np.linalg.norm(np.diff(ring, axis=1), axis=-1)
        arc = np.concatenate([np.zeros((len(s_chunk), 1)), np.cumsum(seg, axis=1)], axis=1)
        for k, s in enumerate(s_chunk):
            perimeter = arc[k, -1]
            count = max(int(math.ceil(perimeter / spacing)), 8)
            targets = np.arange(count) * (perimeter / count)
            u_k = np.interp(targets, arc[k], u_dense)
            u_all.append(u_k)
            s_all.append(np.full(count, s))
    s_flat = np.concatenate(s_all)
    u_flat = np.concatenate(u_all)
    return surface.position(s_flat, u_flat), surface.normal(s_flat, u_flat)


def blade_mesh(blade: BladeParams | BladeSurface) -> tuple[FloatArray, IntArray, FloatArray]:
    """Closed, outward-oriented triangle mesh of the blade.

    Sections are lofted at ``n_sections`` equally spaced span stations with
    ``n_profile_points`` points each (cosine spacing, dense at both edges); the root
    and tip are closed by caps.

    Parameters
    ----------
    blade
        Nominal parameters, or a :class:`BladeSurface` (e.g. from :func:`deformed`).

    Returns
    -------
    vertices : (V, 3) float array
        Blade frame, m. Each section's trailing-edge vertex appears twice (profile
        parameter 0 and 1) so that the texture seam has its own UVs; welding
        coincident vertices gives a closed 2-manifold.
    faces : (F, 3) int array
        Vertex indices, counter-clockwise seen from outside (right-hand normals point
        out of the blade).
    uv : (V, 2) float array
        Texture coordinates: span length and section arc length (from the trailing
        edge along the pressure side), both divided by ``texture_tile``; values
        beyond 1 repeat the texture.
    """
    return _as_surface(blade).mesh()


def cad_point_cloud(
    blade: BladeParams | BladeSurface, spacing: float = 0.01
) -> tuple[FloatArray, FloatArray]:
    """Dense point cloud with normals on the blade skin (the "CAD model").

    Sections every ``spacing`` along the span, each resampled at equal arc length
    ``≈ spacing``; points come from the analytic surface, not from the mesh. The
    root and tip caps are not sampled.

    Parameters
    ----------
    blade
        Nominal parameters, or a :class:`BladeSurface`.
    spacing
        Sample spacing in m, in ``[1e-4, 0.5]``.

    Returns
    -------
    points : (N, 3) float array
        Blade frame, m.
    normals : (N, 3) float array
        Unit outward normals.
    """
    return _as_surface(blade).point_cloud(spacing)


def deformed(
    params: BladeParams,
    deviation_m: float,
    rng: np.random.Generator,
    *,
    n_modes: int = 6,
    min_wavelength: float = 1.0,
) -> BladeSurface:
    """The blade with a smooth random normal displacement (CAD-vs-real surface deviation).

    Parameters
    ----------
    params
        Nominal blade.
    deviation_m
        Largest absolute displacement along the normal, m (≥ 0; 0 gives the nominal).
    rng
        Source of the random modes.
    n_modes
        Number of cosine modes.
    min_wavelength
        Shortest spanwise wavelength in m; around the section at most 3 cycles.

    Returns
    -------
    BladeSurface
        Use ``.position``/``.normal`` for ground truth, :func:`blade_mesh` for the
        simulated body and :func:`cad_point_cloud` of the *nominal* params for the
        estimator.
    """
    if not isinstance(params, BladeParams):
        raise TypeError(f"params must be BladeParams, got {type(params).__name__}")
    if not (math.isfinite(deviation_m) and deviation_m >= 0.0):
        raise ValueError(f"deviation_m must be a non-negative length in m, got {deviation_m!r}")
    if n_modes < 1:
        raise ValueError(f"n_modes must be ≥ 1, got {n_modes!r}")
    if not min_wavelength > 0.0:
        raise ValueError(f"min_wavelength must be > 0 m, got {min_wavelength!r}")
    if deviation_m == 0.0:
        return BladeSurface(params)
    max_cycles = params.length / min_wavelength
    span_cycles = rng.uniform(0.2, max_cycles, n_modes)
    profile_cycles = rng.integers(0, 4, n_modes).astype(float)
    phases = rng.uniform(0.0, 2.0 * np.pi, n_modes)
    amplitudes = rng.uniform(0.3, 1.0, n_modes)
    field0 = BumpField(amplitudes, span_cycles, profile_cycles, phases)
    s, u = np.meshgrid(np.linspace(0, 1, 401), np.linspace(0, 1, 401), indexing="ij")
    peak = float(np.max(np.abs(field0(s, u))))
    scale = deviation_m / peak if peak > 0 else 0.0
    return BladeSurface(params, BumpField(amplitudes * scale, span_cycles, profile_cycles, phases))


def blade_texture(rng: np.random.Generator, size_px: int = 1024) -> npt.NDArray[np.uint8]:
    """Seamlessly tileable speckle texture for close-range visual odometry.

    Band-limited noise at several scales (synthesised on the torus by FFT, so the
    image wraps without seams) plus dark and light blobs of several radii drawn with
    wrap-around, then mildly tinted.

    Parameters
    ----------
    rng
        Random generator.
    size_px
        Edge of the square image in pixels, in ``[32, 8192]``.

    Returns
    -------
    (size_px, size_px, 3) uint8 array
        RGB image (note OpenCV writes BGR).
    """
    if int(size_px) != size_px or not 32 <= size_px <= 8192:
        raise ValueError(f"size_px must be an integer in [32, 8192], got {size_px!r}")
    n = int(size_px)
    f = np.fft.fftfreq(n)
    radius = np.hypot(f[:, None], f[None, :])
    img = np.zeros((n, n))
    for wavelength_px, weight in ((64.0, 0.6), (24.0, 0.8), (9.0, 1.0), (3.5, 0.7)):
        centre = 1.0 / wavelength_px
        band = np.exp(-0.5 * ((radius - centre) / (0.35 * centre)) ** 2)
        spectrum = np.fft.fft2(rng.standard_normal((n, n))) * band
        layer = np.real(np.fft.ifft2(spectrum))
        img += weight * layer / (layer.std() + 1e-12)
    for radius_px, count in ((14.0, 40), (6.0, 150), (2.5, 600)):
        count_scaled = max(1, int(count * (n / 1024) ** 2))
        centres = rng.uniform(0, n, (count_scaled, 2))
        signs = rng.choice([-1.0, 1.0], count_scaled)
        for (cy, cx), sign in zip(centres, signs):
            r = int(math.ceil(3 * radius_px))
            ys = np.arange(int(cy) - r, int(cy) + r + 1)
            xs = np.arange(int(cx) - r, int(cx) + r + 1)
            dy = (ys - cy)[:, None]
            dx = (xs - cx)[None, :]
            blob = np.exp(-0.5 * (dx**2 + dy**2) / radius_px**2)
            img[np.ix_(ys % n, xs % n)] += 2.5 * sign * blob
    img = (img - img.mean()) / (img.std() + 1e-12)
    grey = np.clip(128.0 + 45.0 * img, 0.0, 255.0)
    tint = np.array([1.0, 0.97, 0.9]) * rng.uniform(0.9, 1.0, 3)
    rgb = np.clip(grey[..., None] * tint[None, None, :] + 10.0, 0, 255)
    return rgb.astype(np.uint8)


def write_obj(
    path: str | os.PathLike[str],
    vertices: npt.ArrayLike,
    faces: npt.ArrayLike,
    uv: npt.ArrayLike | None = None,
    *,
    texture_file: str | None = None,
) -> Path:
    """Write a Wavefront OBJ atomically (temporary file + rename).

    Parameters
    ----------
    path
        Target ``.obj`` file; its folder must exist.
    vertices : (V, 3)
        Positions, m.
    faces : (F, 3) int
        0-based vertex indices (written 1-based).
    uv : (V, 2), optional
        Per-vertex texture coordinates, written as ``vt`` and referenced by the faces.
    texture_file
        If given, also writes ``<stem>.mtl`` with ``map_Kd texture_file`` and references
        it from the OBJ.

    Returns
    -------
    Path
        The written OBJ path.
    """
    path = Path(path)
    if path.suffix.lower() != ".obj":
        raise ValueError(f"path must end in .obj, got {str(path)!r}")
    if not path.parent.is_dir():
        raise ValueError(f"folder {str(path.parent)!r} does not exist; create it first")
    v = np.asarray(vertices, dtype=float)
    fc = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
        raise ValueError(f"vertices must be a finite (V, 3) array, got shape {v.shape}")
    if fc.ndim != 2 or fc.shape[1] != 3 or not np.issubdtype(fc.dtype, np.integer):
        raise ValueError(f"faces must be an integer (F, 3) array, got {fc.dtype} {fc.shape}")
    if fc.size and (fc.min() < 0 or fc.max() >= len(v)):
        raise ValueError(f"faces index vertices 0..{len(v) - 1}, got {fc.min()}..{fc.max()}")
    lines: list[str] = ["# blade mesh: vertices in m"]
    mtl_text = None
    if texture_file is not None:
        mtl_name = path.with_suffix(".mtl").name
        lines.append(f"mtllib {mtl_name}")
        mtl_text = (
            f"newmtl blade\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\nmap_Kd {texture_file}\n"
        )
    lines.extend(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in v)
    if uv is not None:
        t = np.asarray(uv, dtype=float)
        if t.shape != (len(v), 2) or not np.all(np.isfinite(t)):
            raise ValueError(f"uv must be a finite ({len(v)}, 2) array, got shape {t.shape}")
        lines.extend(f"vt {a:.9g} {b:.9g}" for a, b in t)
        if mtl_text is not None:
            lines.append("usemtl blade")
        lines.extend(f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in fc + 1)
    else:
        if mtl_text is not None:
            lines.append("usemtl blade")
        lines.extend(f"f {a} {b} {c}" for a, b, c in fc + 1)
    if mtl_text is not None:
        atomic_write_text(path.with_suffix(".mtl"), mtl_text, encoding="ascii")
    atomic_write_text(path, "\n".join(lines) + "\n", encoding="ascii")
    return path
