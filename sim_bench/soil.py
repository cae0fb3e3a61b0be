"""Ground texture: soil colour field, stones, straw and other residue, and the part rasteriser.

Everything is a function of field coordinates (hashed noise, per-cell seeded objects), so a tile
at any level of detail can be produced independently and tiles join without seams.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from .noise import LATTICE_UNIT, fractal_grid
from .plants import Part, dead_leaf, leaf_outline

CELL = 0.25  # m: cell size of the per-cell object generator and of the plant index


@dataclass(frozen=True)
class SoilStyle:
    """Per-scene soil appearance (BGR 0..255 colours before lighting)."""

    colour_a: tuple[float, float, float]
    colour_b: tuple[float, float, float]
    moisture: float  # 0..1: strength of darker moist patches
    clod: float  # 0..1: contrast of clods and crevices
    stones_per_m2: float
    straw_per_m2: float
    dead_leaves_per_m2: float

    @staticmethod
    def random(rng: np.random.Generator) -> "SoilStyle":
        def soil_colour(v):
            hsv = np.uint8([[[rng.uniform(6, 22), rng.uniform(40, 125), v]]])
            return tuple(float(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0])

        v = rng.uniform(60, 190)
        return SoilStyle(
            soil_colour(v),
            soil_colour(np.clip(v * rng.uniform(0.7, 1.3), 30, 230)),
            float(rng.uniform(0, 0.8)),
            float(rng.uniform(0.1, 1.0)),
            float(rng.choice([0.0, rng.uniform(5, 120)])),
            float(rng.choice([0.0, rng.uniform(2, 60)])),
            float(rng.choice([0.0, 0.0, rng.uniform(1, 10)])),
        )


def soil_colour(seed: int, style: SoilStyle, xs: np.ndarray, ys: np.ndarray, res: float) -> np.ndarray:
    """Soil colour (len(ys), len(xs), 3) float32 at pixel-centre coordinates (m).

    xs, ys: texel centres of a regular grid of pitch `res` = LATTICE_UNIT·2^l aligned with the
    texel lattice (as the renderer's tiles are). See `ground_fields` for the texture channel.
    """
    return ground_fields(seed, style, xs, ys, res)[0]


def ground_fields(seed: int, style: SoilStyle, xs: np.ndarray, ys: np.ndarray, res: float) -> tuple[np.ndarray, np.ndarray]:
    """(soil colour (h, w, 3), leaf texture (h, w)) float32, every noise field in one pass.

    All octaves come from `noise.fractal_grid` (hierarchical power-of-two lattices): hue and
    moisture patches, clods and crevices, grain where a texel is small enough to show it, and the
    fine texture modulating leaves and residue.
    """
    fine = max(2 * res, 0.002)
    level_q = int(round(math.log2(res / LATTICE_UNIT)))
    gx0 = int(round(xs[0] / res - 0.5))
    gy0 = int(round(ys[0] / res - 0.5))
    fields = [(1, 0.4, max(0.05, fine), 0.5), (2, 1.2, max(0.15, fine), 0.5), (3, 0.06, fine, 0.6)]
    grain_on = res <= 0.0015
    tex_on = res < 0.004
    if grain_on:
        fields.append((4, 0.004, fine, 0.7))
    if tex_on:
        fields.append((9, 0.02, max(2 * res, 0.001), 0.6))
    F = fractal_grid(seed, fields, gx0, gy0, len(xs), len(ys), level_q)
    hue, moist, clod = F[..., 0], F[..., 1], F[..., 2]
    f32 = np.float32
    mix = np.minimum(np.maximum(hue * f32(0.35) + f32(0.5), f32(0)), f32(1))
    lum = np.minimum(np.maximum(moist * f32(0.8), f32(0)), f32(1))
    lum *= f32(-0.45 * style.moisture)
    lum += f32(1)  # 1 − 0.45·m
    lum *= clod * f32(0.22 * style.clod) + f32(1)
    crev = np.maximum(-clod - f32(0.9), f32(0))
    np.minimum(crev, f32(2), out=crev)
    lum *= f32(1) - crev * f32(0.35 * style.clod)
    if grain_on:  # grain only where a pixel is small enough to show it
        grain = F[..., 3]
        lum *= grain * f32(0.07) + f32(1)
        lum += np.minimum(np.maximum(grain - f32(1.6), f32(0)), f32(1)) * f32(0.10)
    a = np.asarray(style.colour_a, np.float32)
    b = np.asarray(style.colour_b, np.float32)
    out = np.empty(lum.shape + (3,), np.float32)
    for c in range(3):
        np.multiply(mix * f32(b[c] - a[c]) + f32(a[c]), lum, out=out[..., c])
    tex = np.ascontiguousarray(F[..., -1]) if tex_on else np.zeros(lum.shape, np.float32)
    return out, tex


def cell_objects(seed: int, style: SoilStyle, cx: int, cy: int) -> tuple[Part, ...]:
    """Stones, straw and dead leaves of one CELL×CELL ground cell (deterministic per cell)."""
    return _cell_objects(seed, style, cx, cy)


@lru_cache(maxsize=4096)
def _cell_objects(seed: int, style: SoilStyle, cx: int, cy: int) -> tuple[Part, ...]:
    rng = np.random.default_rng([seed & 0xFFFFFFFF, 11, cx & 0xFFFFFFFF, cy & 0xFFFFFFFF])
    x0, y0 = cx * CELL, cy * CELL
    parts: list[Part] = []
    area = CELL * CELL
    for _ in range(rng.poisson(style.dead_leaves_per_m2 * area)):
        c = np.array([x0 + rng.uniform(0, CELL), y0 + rng.uniform(0, CELL)])
        parts += dead_leaf(rng, c, rng.uniform(0.015, 0.07)).parts
    for _ in range(rng.poisson(style.straw_per_m2 * area)):
        c = np.array([x0 + rng.uniform(0, CELL), y0 + rng.uniform(0, CELL)])
        L = rng.uniform(0.02, 0.12)
        a = rng.uniform(0, 2 * np.pi)
        poly, tip = leaf_outline(c, a, L, rng.uniform(0.0015, 0.004), peak=0.5, fullness=0.05, bend=rng.uniform(-0.1, 0.1), n=6)
        v = rng.uniform(0.45, 0.95)
        col = (rng.uniform(90, 150) * v, rng.uniform(160, 200) * v, rng.uniform(180, 220) * v)
        if rng.random() < 0.3:  # weathered grey straw
            g = rng.uniform(90, 170)
            col = (g * 0.95, g, g * 1.02)
        parts.append(Part(poly, c, tip, col, height=0.003, midrib=0.0))
    for _ in range(rng.poisson(style.stones_per_m2 * area)):
        c = np.array([x0 + rng.uniform(0, CELL), y0 + rng.uniform(0, CELL)])
        r = math.exp(rng.uniform(math.log(0.003), math.log(0.03)))
        k = int(rng.integers(7, 14))
        ang = np.sort(rng.uniform(0, 2 * np.pi, k))
        rad = r * rng.uniform(0.65, 1.0, k) * np.r_[1.0, rng.uniform(0.6, 1.0)][0]
        ell = rng.uniform(0.5, 1.0)
        rot = rng.uniform(0, np.pi)
        pts = np.c_[rad * np.cos(ang), ell * rad * np.sin(ang)] @ np.array([[math.cos(rot), math.sin(rot)], [-math.sin(rot), math.cos(rot)]])
        g = rng.uniform(80, 210)
        tint = rng.uniform(0.88, 1.08, 3)
        tint[1] = min(tint[1], max(tint[0], tint[2]))  # grey/brown stones, not green
        col = tuple(float(v) for v in np.clip(g * tint, 0, 255))
        parts.append(Part(c + pts, c - [r, 0], c + [r, 0], col, height=0.6 * r))
    return tuple(parts)


def draw_parts(
    img: np.ndarray, X0: float, Y0: float, res: float, parts, sun: np.ndarray, tex: np.ndarray
) -> None:
    """Rasterise parts (painter's order) into `img` (float32 h×w×3, ground pixel grid) in place.

    Pixel (col, row) has its centre at field (X0 + (col+0.5)·res, Y0 + (row+0.5)·res). Each part
    first casts a soft shadow displaced by `sun`·height (sun: ground offset per metre of height),
    then is painted with shading along its base→tip axis, a midrib, chevron and sheen.
    """
    h, w = img.shape[:2]
    for p in parts:
        px = (p.poly - (X0, Y0)) / res - 0.5
        off = sun * p.height / res
        # cull: neither the part nor its (blurred) shadow reaches this tile
        reach = 3 * max(0.6, 0.25 * p.height / res) + 2
        lo_ = px.min(axis=0) - reach + np.minimum(off, 0)
        hi_ = px.max(axis=0) + reach + np.maximum(off, 0)
        if hi_[0] < 0 or hi_[1] < 0 or lo_[0] > w or lo_[1] > h:
            continue
        if abs(off[0]) + abs(off[1]) > 0.7:
            sig = max(0.6, 0.25 * p.height / res)
            _shadow(img, px + off, sig, 0.42)
        lo = np.floor(px.min(axis=0)).astype(int) - 1
        hi = np.ceil(px.max(axis=0)).astype(int) + 2
        x0, y0 = max(lo[0], 0), max(lo[1], 0)
        x1, y1 = min(hi[0], w), min(hi[1], h)
        if x1 <= x0 or y1 <= y0:
            continue
        a = _raster(px, x0, y0, x1 - x0, y1 - y0)
        if not a.any():
            continue
        col = _shade(p, (np.asarray(p.base) - (X0, Y0)) / res - 0.5, (np.asarray(p.tip) - (X0, Y0)) / res - 0.5,
                     x0, y0, x1 - x0, y1 - y0, tex[y0:y1, x0:x1])
        sub = img[y0:y1, x0:x1]
        a3 = a[..., None]
        sub += (col - sub) * a3


def _raster(px: np.ndarray, x0: int, y0: int, w: int, h: int) -> np.ndarray:
    m = np.zeros((h, w), np.uint8)
    q = np.round((px - (x0, y0)) * 16).astype(np.int32)
    cv2.fillPoly(m, [q], 255, cv2.LINE_AA, shift=4)
    return m.astype(np.float32) * (1 / 255)


def _shadow(img: np.ndarray, px: np.ndarray, sigma: float, strength: float) -> None:
    h, w = img.shape[:2]
    mg = int(math.ceil(3 * sigma)) + 1
    lo = np.floor(px.min(axis=0)).astype(int) - mg
    hi = np.ceil(px.max(axis=0)).astype(int) + mg
    x0, y0, x1, y1 = max(lo[0], 0), max(lo[1], 0), min(hi[0], w), min(hi[1], h)
    if x1 <= x0 or y1 <= y0:
        return
    # rasterise on the unclipped box so the blur near tile borders matches the neighbour tile
    a = _raster(px, lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1])
    a = cv2.GaussianBlur(a, (0, 0), sigma)[y0 - lo[1] : y1 - lo[1], x0 - lo[0] : x1 - lo[0]]
    img[y0:y1, x0:x1] *= (1 - strength * a)[..., None]


def _shade(p: Part, b: np.ndarray, t: np.ndarray, x0: int, y0: int, w: int, h: int, tex: np.ndarray) -> np.ndarray:
    d = t - b
    L = float(np.hypot(*d)) + 1e-6
    gx = (np.arange(x0, x0 + w, dtype=np.float32) - np.float32(b[0]))[None, :]
    gy = (np.arange(y0, y0 + h, dtype=np.float32) - np.float32(b[1]))[:, None]
    along = (gx * d[0] + gy * d[1]) / (L * L)
    across = (gx * d[1] - gy * d[0]) / L
    base = np.asarray(p.colour, np.float32)
    lum = (0.8 + 0.32 * np.clip(along, 0, 1)) * (1 + 0.06 * tex)
    col = base[None, None, :] * lum[..., None]
    if p.midrib > 0:
        mw = max(0.7, 0.015 * L)
        m = p.midrib * np.exp(-((across / mw) ** 2)) * (along < 0.92)
        col += (base * 1.45 + 18 - col) * m[..., None]
    if p.chevron > 0:
        ch = p.chevron * np.exp(-(((along - 0.42 - 0.5 * np.abs(across) / L) / 0.07) ** 2))
        col += (base * 0.4 + 130 - col) * ch[..., None]
    if p.sheen > 0:
        s = p.sheen * np.exp(-(((along - 0.55) / 0.2) ** 2) - (across / (0.18 * L)) ** 2)
        col += (200 - col) * (0.45 * s)[..., None]
    return col


def soft_polygon_alpha(poly: np.ndarray, softness: float, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Soft-edged coverage (0..1) of a convex polygon (m) on the grid ys × xs, float32."""
    P = np.asarray(poly, float)
    cen = P.mean(axis=0)
    X = np.asarray(xs, np.float32)[None, :]
    Y = np.asarray(ys, np.float32)[:, None]
    sd = np.full((len(ys), len(xs)), np.inf, np.float32)
    for i in range(len(P)):
        a, b = P[i], P[(i + 1) % len(P)]
        e = b - a
        n = np.array([e[1], -e[0]]) / (np.hypot(*e) + 1e-12)
        if np.dot(cen - a, n) < 0:
            n = -n
        c = np.float32(-(a[0] * n[0] + a[1] * n[1]))
        np.minimum(sd, X * np.float32(n[0]) + Y * np.float32(n[1]) + c, out=sd)
    return np.clip(0.5 + sd / np.float32(max(softness, 1e-6)), 0, 1)
