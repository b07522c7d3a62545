"""Procedural surface textures of a lab room, at metric scale.

A camera tracks what a real room shows it: posters and notices on painted
walls, a tiled floor with scuffs, labelled boxes and furniture. The images
here are drawn at a fixed texel density (:data:`PX_PER_M` texels per metre),
so a 7 m wall is as sharp as a 0.3 m box and texture size never depends on
how a face is stretched. Every random choice comes from the generator passed
in, so a seeded env renders the same room.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from enum import Enum
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

__all__ = [
    "MAX_TEXTURE_PX",
    "PX_PER_M",
    "SurfaceKind",
    "clear_texture_cache",
    "set_texture_cache_limit",
    "surface_texture",
    "texture_cache_info",
]

Image = npt.NDArray[np.uint8]

PX_PER_M = 200.0
"""Texel density of the textures (texels per metre): a 320-pixel-wide camera with a
70° field of view sees about this many pixels per metre at 1.1 m."""

MAX_TEXTURE_PX = 4096
"""Largest side of a texture (px); longer surfaces get a lower density."""


class SurfaceKind(str, Enum):
    """What a surface looks like."""

    WALL = "wall"
    """Painted wall with posters, notices and switches; a skirting board at the bottom."""
    FLOOR = "floor"
    """Tiles with grout lines, per-tile tint and mottling, scuffs and tape marks."""
    OBJECT = "object"
    """Boxes and furniture: a painted or cardboard body with printed labels and tape."""


def _mottle(rng: np.random.Generator, h: int, w: int, cell_px: float, amp: float) -> npt.NDArray:
    """Smooth random brightness variation (±amp grey levels) with features of ``cell_px``."""
    gh, gw = max(2, int(h / cell_px) + 2), max(2, int(w / cell_px) + 2)
    coarse = rng.uniform(-amp, amp, size=(gh, gw)).astype(np.float32)
    return cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)


def _colour(rng: np.random.Generator, low: int = 0, high: int = 256) -> tuple[int, int, int]:
    return tuple(int(c) for c in rng.integers(low, high, size=3))  # type: ignore[return-value]


def _print_text(rng: np.random.Generator, img: Image, x0: int, y0: int, x1: int, y1: int) -> None:
    """Rows of word-like dark dashes, as printed text looks from a distance."""
    line_h = int(rng.integers(4, 9))
    ink = _colour(rng, 0, 90)
    y = y0
    while y + line_h <= y1:
        x = x0 + int(rng.integers(0, 4))
        end = x1 - int(rng.integers(0, max(1, (x1 - x0) // 3)))
        while x < end:
            word = int(rng.integers(line_h, 5 * line_h))
            cv2.rectangle(img, (x, y), (min(x + word, end), y + line_h - 2), ink, -1)
            x += word + int(rng.integers(line_h // 2 + 1, line_h + 2))
        y += line_h + int(rng.integers(2, line_h + 2))


def _poster(rng: np.random.Generator, img: Image, x0: int, y0: int, x1: int, y1: int) -> None:
    """A poster or notice: paper, a picture block, shapes and text lines."""
    paper = _colour(rng, 150, 256)
    cv2.rectangle(img, (x0, y0), (x1, y1), paper, -1)
    cv2.rectangle(img, (x0, y0), (x1, y1), _colour(rng, 0, 120), int(rng.integers(1, 4)))
    w, h = x1 - x0, y1 - y0
    if w < 12 or h < 12:
        return
    # a title band and a picture block with shapes
    split = y0 + int(h * rng.uniform(0.25, 0.6))
    cv2.rectangle(img, (x0 + 3, y0 + 3), (x1 - 3, y0 + max(6, h // 8)), _colour(rng), -1)
    for _ in range(int(rng.integers(3, 9))):
        cx, cy = int(rng.integers(x0 + 3, x1 - 3)), int(rng.integers(y0 + h // 8, split))
        r = int(rng.integers(3, max(4, min(w, h) // 5)))
        colour = _colour(rng)
        if rng.random() < 0.5:
            cv2.circle(img, (cx, cy), r, colour, -1)
        else:
            cv2.rectangle(img, (cx - r, cy - r // 2), (cx + r, cy + r), colour, -1)
    _print_text(rng, img, x0 + 4, split + 3, x1 - 4, y1 - 4)


def _wall(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    img = np.empty((h, w, 3), np.uint8)
    img[:] = _colour(rng, 150, 235)
    # skirting board along the bottom (row h-1 is the floor edge)
    skirt = max(2, int(0.08 * ppm))
    cv2.rectangle(img, (0, h - skirt), (w, h), _colour(rng, 30, 120), -1)
    # posters, notices and charts: about one per 0.5 m² of wall, 0.2-0.7 m wide
    n = max(1, int(round(w * h / (0.5 * ppm * ppm) * rng.uniform(0.8, 1.2))))
    for _ in range(n):
        pw = int(ppm * rng.uniform(0.2, 0.7))
        ph = int(ppm * rng.uniform(0.2, 0.6))
        x0 = int(rng.integers(0, max(1, w - pw)))
        y0 = int(rng.integers(0, max(1, h - skirt - ph)))
        _poster(rng, img, x0, y0, min(w - 1, x0 + pw), min(h - skirt - 1, y0 + ph))
    # switches, sockets and small labels: about three per metre
    for _ in range(int(3 * w / ppm)):
        sw = int(ppm * rng.uniform(0.04, 0.1))
        x0, y0 = int(rng.integers(0, max(1, w - sw))), int(rng.integers(0, max(1, h - skirt - sw)))
        cv2.rectangle(img, (x0, y0), (x0 + sw, y0 + sw), _colour(rng, 60, 256), -1)
        cv2.rectangle(img, (x0, y0), (x0 + sw, y0 + sw), _colour(rng, 0, 80), 1)
    return img


def _floor(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    base = np.array(_colour(rng, 90, 200), dtype=np.float32)
    tile = max(8, int(ppm * rng.uniform(0.3, 0.6)))
    img = np.empty((h, w, 3), np.float32)
    ny, nx = -(-h // tile), -(-w // tile)
    tint = rng.uniform(-25, 25, size=(ny, nx, 1)).astype(np.float32)
    img[:] = base + np.repeat(np.repeat(tint, tile, 0), tile, 1)[:h, :w]
    img += _mottle(rng, h, w, tile / 4.0, 18.0)[..., None]
    img = np.clip(img, 0, 255).astype(np.uint8)
    grout = _colour(rng, 20, 90)
    width = max(1, int(0.006 * ppm))
    for k in range(nx + 1):
        cv2.line(img, (k * tile, 0), (k * tile, h), grout, width)
    for k in range(ny + 1):
        cv2.line(img, (0, k * tile), (w, k * tile), grout, width)
    # chips of a vinyl floor, scuffs, stains and tape marks
    area_m2 = (h / ppm) * (w / ppm)
    for _ in range(int(80 * area_m2)):
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        r = max(1, int(ppm * rng.uniform(0.004, 0.012)))
        cv2.circle(img, (x, y), r, _colour(rng, 0, 256), -1)
    for _ in range(int(12 * area_m2)):
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        ax = (int(rng.integers(2, max(3, tile // 4))), int(rng.integers(1, max(2, tile // 6))))
        cv2.ellipse(img, (x, y), ax, float(rng.uniform(0, 180)), 0, 360, _colour(rng, 0, 256), -1)
    for _ in range(int(0.5 * area_m2)):
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        length = int(ppm * rng.uniform(0.1, 0.5))
        dx, dy = (length, 0) if rng.random() < 0.5 else (0, length)
        cv2.line(img, (x, y), (x + dx, y + dy), _colour(rng, 100, 256), max(2, int(0.04 * ppm)))
    return img


def _object(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    img = np.empty((h, w, 3), np.uint8)
    img[:] = _colour(rng, 60, 220)
    img[:] = np.clip(img + _mottle(rng, h, w, 0.05 * ppm, 12.0)[..., None], 0, 255)
    # tape strips and printed labels: about four labels per square metre of side
    for _ in range(int(rng.integers(1, 4))):
        y = int(rng.integers(0, h))
        cv2.line(img, (0, y), (w, y), _colour(rng, 120, 256), max(2, int(0.04 * ppm)))
    area_m2 = (h / ppm) * (w / ppm)
    for _ in range(max(2, int(round(6 * area_m2)))):
        lw, lh = int(ppm * rng.uniform(0.06, 0.25)), int(ppm * rng.uniform(0.05, 0.18))
        x0, y0 = int(rng.integers(0, max(1, w - lw))), int(rng.integers(0, max(1, h - lh)))
        _poster(rng, img, x0, y0, x0 + lw, y0 + lh)
    return img


def surface_texture(
    rng: np.random.Generator,
    width_m: float,
    height_m: float,
    kind: SurfaceKind | str = SurfaceKind.OBJECT,
) -> Image:
    """An RGB texture for a ``width_m`` × ``height_m`` surface (m) of the given kind.

    Parameters
    ----------
    rng : np.random.Generator
        Source of every random choice (same seed, same image).
    width_m, height_m : float
        Size of the surface the image covers, m; the image has :data:`PX_PER_M`
        texels per metre, lowered so neither side exceeds :data:`MAX_TEXTURE_PX`.
    kind : SurfaceKind or str
        ``"wall"``, ``"floor"`` or ``"object"``.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB image; row 0 is the top of the surface (for a floor: its +y edge).

    Raises
    ------
    ValueError
        If a size is not a positive finite number or ``kind`` is unknown.
    """
    for name, v in (("width_m", width_m), ("height_m", height_m)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive size in m, got {v!r}")
    try:
        kind = SurfaceKind(getattr(kind, "value", kind))
    except ValueError:
        names = [k.value for k in SurfaceKind]
        raise ValueError(f"kind must be one of {names}, got {kind!r}") from None
    state_key = _state_key(rng)
    key = (kind.value, float(width_m), float(height_m), PX_PER_M, MAX_TEXTURE_PX, state_key)
    hit = _CACHE.get(key) if state_key is not None else None
    if hit is not None:
        image, state_after = hit
        rng.bit_generator.state = state_after  # the generator ends where drawing would leave it
        return image.copy()
    ppm = min(PX_PER_M, MAX_TEXTURE_PX / max(width_m, height_m))
    w, h = max(8, int(round(width_m * ppm))), max(8, int(round(height_m * ppm)))
    make = {SurfaceKind.WALL: _wall, SurfaceKind.FLOOR: _floor, SurfaceKind.OBJECT: _object}
    img = make[kind](rng, h, w, ppm)
    # sensor-scale speckle so that no patch is perfectly flat
    speckle = rng.integers(-4, 5, size=(h, w, 1), dtype=np.int16)
    out = np.clip(img.astype(np.int16) + speckle, 0, 255).astype(np.uint8)
    if state_key is not None:
        _CACHE.put(key, out.copy(), rng.bit_generator.state)
    return out


# ---------------------------------------------------------------------------- cache
def _state_key(rng: np.random.Generator) -> str | None:
    """A hashable key of the generator's exact state (its bit generator's state dict), or
    ``None`` for an object that is not a NumPy ``Generator`` (never cached)."""
    if not isinstance(rng, np.random.Generator):
        return None
    return repr(rng.bit_generator.state)


class _TextureCache:
    """Least-recently-used store of drawn textures, bounded in bytes.

    A texture is a pure function of its kind, size and the generator's state on
    entry; the cache keeps the image and the generator's state on exit, so a hit
    returns the same pixels and leaves the generator exactly where drawing would.
    Seeded episodes that repeat a layout (evaluation seeds, one seed in fast and
    image mode, several policies on one set of seeds) skip the drawing.
    """

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict[tuple[Any, ...], tuple[npt.NDArray[np.uint8], Any]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def get(self, key: tuple[Any, ...]) -> tuple[npt.NDArray[np.uint8], Any] | None:
        with self._lock:
            item = self._items.get(key)
            if item is None:
                self.misses += 1
                return None
            self._items.move_to_end(key)
            self.hits += 1
            return item

    def put(self, key: tuple[Any, ...], image: npt.NDArray[np.uint8], state_after: Any) -> None:
        if image.nbytes > self.max_bytes:
            return
        image.setflags(write=False)
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self._bytes -= old[0].nbytes
            self._items[key] = (image, state_after)
            self._bytes += image.nbytes
            self._evict()

    def resize(self, max_bytes: int) -> None:
        with self._lock:
            self.max_bytes = int(max_bytes)
            self._evict()

    def _evict(self) -> None:
        """Drop the least recently used images until the bound holds (lock held)."""
        while self._bytes > self.max_bytes:
            _, (dropped, _) = self._items.popitem(last=False)
            self._bytes -= dropped.nbytes

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0
            self.hits = self.misses = 0

    def info(self) -> dict[str, int]:
        with self._lock:
            return {
                "entries": len(self._items),
                "bytes": self._bytes,
                "max_bytes": self.max_bytes,
                "hits": self.hits,
                "misses": self.misses,
            }


DEFAULT_TEXTURE_CACHE_BYTES = 128 * 1024 * 1024
"""Default bound of the in-memory texture cache (bytes): about a dozen textured 7 m rooms."""

_CACHE = _TextureCache(DEFAULT_TEXTURE_CACHE_BYTES)


def texture_cache_info() -> dict[str, int]:
    """Entries, bytes held, bound (bytes), hits and misses of the texture cache."""
    return _CACHE.info()


def clear_texture_cache() -> None:
    """Drop every cached texture and reset the hit counts."""
    _CACHE.clear()


def set_texture_cache_limit(max_bytes: int) -> None:
    """Bound the texture cache to ``max_bytes`` (0 turns caching off); drops what exceeds it.

    Raises
    ------
    ValueError
        If ``max_bytes`` is not a whole number ≥ 0.
    """
    if isinstance(max_bytes, bool) or not isinstance(max_bytes, (int, np.integer)) or max_bytes < 0:
        raise ValueError(
            f"max_bytes must be a whole number of bytes >= 0 (0 turns the cache off), "
            f"got {max_bytes!r}"
        )
    _CACHE.resize(int(max_bytes))
