"""Flat (z = 0) plant models: weeds, crop plants and plant residue, in field coordinates.

A plant is a list of `Part`s (leaf blades, petioles, grass blades) drawn in painter's order, and
its known biological centre — where leaves emerge, the MPOI X̄_w of the paper. Shapes are made
uneven on purpose (leaf count, lengths, angular gaps, bends) so that the mask centroid is not the
biological centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

WEED_KINDS = ("rosette", "seedling", "grass", "clover")
PLANT_KINDS = WEED_KINDS + ("crop", "dead_leaf")


@dataclass(frozen=True)
class Part:
    """One flat polygon with a shading axis from `base` to `tip` (m, field frame)."""

    poly: np.ndarray  # (N, 2)
    base: np.ndarray  # (2,)
    tip: np.ndarray  # (2,)
    colour: tuple[float, float, float]  # BGR, 0..255, before lighting
    height: float = 0.01  # m above ground: length of its cast shadow per unit sun slope
    midrib: float = 0.0  # strength of a lighter midrib line (0..1)
    chevron: float = 0.0  # strength of a pale chevron band (clover)
    sheen: float = 0.0  # specular highlight strength (waxy leaves)


@dataclass(frozen=True)
class Plant:
    kind: str
    centre: np.ndarray  # (2,) biological centre, field frame (m)
    parts: tuple[Part, ...]
    extent: float  # radius (m) around `centre` containing every part

    @property
    def bbox(self) -> tuple[float, float, float, float]:
        pts = np.concatenate([p.poly for p in self.parts])
        return float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max())

    def area_centroid(self) -> np.ndarray:
        """Centroid of the union of the parts' areas, rasterised at 1 mm (what a mask centroid gives)."""
        x0, y0, x1, y1 = self.bbox
        res = 0.001
        w, h = int((x1 - x0) / res) + 3, int((y1 - y0) / res) + 3
        m = np.zeros((h, w), np.uint8)
        for p in self.parts:
            q = np.round((p.poly - [x0, y0]) / res * 16).astype(np.int32)
            cv2.fillPoly(m, [q], 1, cv2.LINE_8, shift=4)
        ys, xs = np.nonzero(m)
        if len(xs) == 0:
            return self.centre.copy()
        return np.array([x0 + xs.mean() * res, y0 + ys.mean() * res])


# ---- leaf outline --------------------------------------------------------------------------------
def leaf_outline(
    base: np.ndarray,
    angle: float,
    length: float,
    width: float,
    *,
    peak: float = 0.45,
    fullness: float = 0.8,
    petiole: float = 0.0,
    petiole_width: float = 0.0,
    bend: float = 0.0,
    teeth: int = 0,
    tooth_depth: float = 0.0,
    notch: float = 0.0,
    n: int = 28,
) -> tuple[np.ndarray, np.ndarray]:
    """Polygon (2n, 2) of a leaf blade from `base` towards `angle`, and its tip point.

    Half-width profile sin(π·s^p)^fullness peaks at s = `peak` of the blade; `petiole` is the
    fraction of the length that is a narrow stalk; `bend` curves the axis sideways (fraction of
    length); teeth add a serrated/runcinate margin; `notch` indents the tip (obcordate leaflets).
    """
    t = np.linspace(0.0, 1.0, n)
    d = np.array([math.cos(angle), math.sin(angle)])
    nrm = np.array([-d[1], d[0]])
    axis = base + length * (t[:, None] * d + (bend * t**2)[:, None] * nrm)
    tang = length * (d[None, :] + (2 * bend * t)[:, None] * nrm[None, :])
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    nn = np.c_[-tang[:, 1], tang[:, 0]]
    s = np.clip((t - petiole) / max(1 - petiole, 1e-6), 0, 1)
    p = math.log(0.5) / math.log(min(max(peak, 0.05), 0.95))
    prof = np.sin(np.pi * s**p) ** fullness
    if teeth:
        prof = prof * (1 - tooth_depth * (0.5 + 0.5 * np.sin(2 * np.pi * teeth * s)) * (s > 0.1))
    if notch:
        prof = prof * (1 - notch * np.exp(-(((1 - s) / 0.12) ** 2)))
    hw = np.where(t < petiole, petiole_width / 2, np.maximum(width / 2 * prof, petiole_width / 2 * (1 - s)))
    hw[-1] = 0.0 if not notch else hw[-1]
    left = axis + hw[:, None] * nn
    right = axis - hw[:, None] * nn
    if notch:  # pull the tip in so the leaflet is heart-shaped
        tipc = axis[-1] - d * length * notch * 0.25
        poly = np.concatenate([left, [tipc], right[::-1]])
    else:
        poly = np.concatenate([left, right[::-1]])
    return poly, axis[-1]


def _green(rng: np.random.Generator, hue=(65.0, 115.0), sat=(0.4, 0.85), val=(0.28, 0.65)) -> np.ndarray:
    """A leaf green in BGR 0..255 from HSV ranges (hue in degrees)."""
    hsv = np.uint8([[[rng.uniform(*hue) / 2, rng.uniform(*sat) * 255, rng.uniform(*val) * 255]]])
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0].astype(float)


def _jitter(rng: np.random.Generator, c: np.ndarray, amount: float = 0.12) -> tuple[float, float, float]:
    c = c * rng.uniform(1 - amount, 1 + amount) * rng.uniform(1 - amount / 3, 1 + amount / 3, 3)
    return tuple(float(v) for v in np.clip(c, 0, 255))


def _uneven_angles(rng: np.random.Generator, n: int, concentration: float = 1.0) -> np.ndarray:
    """n angles round a circle with Dirichlet-distributed gaps (uneven by design)."""
    gaps = rng.dirichlet(np.full(n, concentration)) * 2 * np.pi
    return rng.uniform(0, 2 * np.pi) + np.cumsum(gaps)


# ---- plant kinds --------------------------------------------------------------------------------
def rosette(rng: np.random.Generator, centre: np.ndarray, size: float) -> Plant:
    """Broadleaf rosette: 3–10 uneven, overlapping leaves plus small young leaves at the centre."""
    n = int(rng.integers(3, 11))
    base_col = _green(rng)
    angles = _uneven_angles(rng, n, rng.uniform(0.8, 3.0))
    lengths = size * rng.uniform(0.35, 1.0, n)
    lengths[rng.integers(n)] = size  # one leaf reaches the nominal size
    style = rng.choice(["lanceolate", "obovate", "toothed"])
    parts: list[tuple[float, Part]] = []
    for a, L in zip(angles, lengths):
        off = centre + rng.uniform(0, 0.05 * size) * np.array([math.cos(a), math.sin(a)])
        kw = dict(
            peak=rng.uniform(0.35, 0.6) if style != "obovate" else rng.uniform(0.6, 0.8),
            fullness=rng.uniform(0.5, 1.0),
            petiole=rng.uniform(0.0, 0.3),
            petiole_width=L * rng.uniform(0.05, 0.1),
            bend=rng.uniform(-0.15, 0.15),
        )
        if style == "toothed":
            kw.update(teeth=int(rng.integers(3, 8)), tooth_depth=rng.uniform(0.2, 0.55))
        poly, tip = leaf_outline(off, a + rng.uniform(-0.1, 0.1), L, L * rng.uniform(0.22, 0.45), **kw)
        part = Part(poly, off, tip, _jitter(rng, base_col), height=0.004 + 0.02 * L / size * rng.uniform(0.3, 1),
                    midrib=rng.uniform(0.2, 0.6), sheen=rng.uniform(0.0, 0.5))
        parts.append((L + rng.uniform(0, 0.15 * size), part))
    parts.sort(key=lambda x: -x[0])  # old, long leaves underneath
    young = []
    for a in _uneven_angles(rng, int(rng.integers(1, 4))):
        L = size * rng.uniform(0.08, 0.22)
        poly, tip = leaf_outline(centre, a, L, L * rng.uniform(0.3, 0.5), peak=0.55)
        young.append(Part(poly, centre.copy(), tip, _jitter(rng, base_col * rng.uniform(1.1, 1.35)), height=0.02, midrib=0.2))
    allp = tuple(p for _, p in parts) + tuple(young)
    return Plant("rosette", np.asarray(centre, float), allp, _extent(centre, allp))


def seedling(rng: np.random.Generator, centre: np.ndarray, size: float) -> Plant:
    """Two cotyledons (opposite, ovate) and 0–2 small true leaves across them."""
    col = _green(rng, hue=(60, 100), val=(0.35, 0.7))
    a = rng.uniform(0, 2 * np.pi)
    parts = []
    for k, ang in enumerate((a, a + np.pi + rng.uniform(-0.35, 0.35))):
        L = size * rng.uniform(0.6, 1.0)
        poly, tip = leaf_outline(centre, ang, L, L * rng.uniform(0.35, 0.55), peak=rng.uniform(0.45, 0.65),
                                 fullness=0.7, petiole=rng.uniform(0.05, 0.2), petiole_width=L * 0.12)
        parts.append(Part(poly, centre.copy(), tip, _jitter(rng, col), height=0.01, midrib=0.1, sheen=rng.uniform(0, 0.4)))
    for k in range(int(rng.integers(0, 3))):
        ang = a + np.pi / 2 + k * np.pi + rng.uniform(-0.4, 0.4)
        L = size * rng.uniform(0.25, 0.7)
        poly, tip = leaf_outline(centre, ang, L, L * rng.uniform(0.4, 0.6), peak=0.5, teeth=int(rng.integers(0, 4)), tooth_depth=0.2)
        parts.append(Part(poly, centre.copy(), tip, _jitter(rng, col * 0.85), height=0.015, midrib=0.3))
    return Plant("seedling", np.asarray(centre, float), tuple(parts), _extent(centre, parts))


def grass(rng: np.random.Generator, centre: np.ndarray, size: float) -> Plant:
    """Grass-like tuft: narrow blades fanning out from a common base (the biological centre)."""
    n = int(rng.integers(4, 19))
    col = _green(rng, hue=(65, 115), sat=(0.3, 0.7), val=(0.3, 0.6))
    lean = rng.uniform(0, 2 * np.pi)
    spread = rng.uniform(1.0, 2 * np.pi)
    parts = []
    for _ in range(n):
        ang = lean + spread * (rng.random() - 0.5)
        L = size * rng.uniform(0.4, 1.0)
        b = centre + rng.normal(0, 0.08 * min(size, 0.05), 2)
        w = rng.uniform(0.0015, 0.0045)
        poly, tip = leaf_outline(b, ang, L, w, peak=0.15, fullness=0.35, bend=rng.uniform(-0.25, 0.25), n=20)
        parts.append(Part(poly, b, tip, _jitter(rng, col, 0.2), height=0.03 * rng.random(), midrib=0.3))
    return Plant("grass", np.asarray(centre, float), tuple(parts), _extent(centre, parts))


def clover(rng: np.random.Generator, centre: np.ndarray, size: float) -> Plant:
    """Clover-like: 3–7 petioles from the centre, each ending in three obcordate leaflets."""
    col = _green(rng, hue=(75, 110), sat=(0.35, 0.7), val=(0.3, 0.6))
    stems, leaflets = [], []
    for a in _uneven_angles(rng, int(rng.integers(3, 8)), 1.5):
        s = size * rng.uniform(0.18, 0.32)
        P = size * rng.uniform(0.35, 0.95) - s
        P = max(P, 0.15 * size)
        pw = rng.uniform(0.001, 0.002)
        poly, end = leaf_outline(centre, a, P, pw, peak=0.5, fullness=0.0, n=8)
        stems.append(Part(poly, centre.copy(), end, _jitter(rng, col * 0.9 + [0, 10, 30]), height=0.02))
        for da in (-2.0, 0.0, 2.0):
            ang = a + da + rng.uniform(-0.2, 0.2)
            lp, tip = leaf_outline(end, ang, s, s * rng.uniform(0.7, 0.95), peak=0.7, fullness=0.6, notch=0.25)
            leaflets.append(Part(lp, end.copy(), tip, _jitter(rng, col, 0.08), height=0.025, chevron=rng.uniform(0.2, 0.6)))
    parts = tuple(stems) + tuple(leaflets)
    return Plant("clover", np.asarray(centre, float), parts, _extent(centre, parts))


def crop(rng: np.random.Generator, centre: np.ndarray, size: float, row_dir: float) -> Plant:
    """Maize-like crop plant: long strap leaves alternating across the row."""
    col = _green(rng, hue=(70, 95), sat=(0.5, 0.85), val=(0.35, 0.6))
    parts = []
    for k in range(int(rng.integers(4, 9))):
        ang = row_dir + np.pi / 2 + (k % 2) * np.pi + rng.uniform(-0.5, 0.5)
        L = size * rng.uniform(0.5, 1.0)
        poly, tip = leaf_outline(centre, ang, L, L * rng.uniform(0.07, 0.12), peak=0.4, fullness=0.6, bend=rng.uniform(-0.3, 0.3))
        parts.append(Part(poly, centre.copy(), tip, _jitter(rng, col), height=0.05, midrib=0.5, sheen=0.3))
    return Plant("crop", np.asarray(centre, float), tuple(parts), _extent(centre, parts))


def dead_leaf(rng: np.random.Generator, centre: np.ndarray, size: float) -> Plant:
    """Brown residue leaf: plant-shaped but not green (a negative for the detector)."""
    hsv = np.uint8([[[rng.uniform(8, 22), rng.uniform(60, 170), rng.uniform(70, 180)]]])
    col = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0].astype(float)
    a = rng.uniform(0, 2 * np.pi)
    poly, tip = leaf_outline(centre, a, size, size * rng.uniform(0.3, 0.5), bend=rng.uniform(-0.3, 0.3))
    parts = (Part(poly, np.asarray(centre, float), tip, _jitter(rng, col), height=0.003, midrib=0.3),)
    return Plant("dead_leaf", np.asarray(centre, float), parts, _extent(centre, parts))


def make_plant(kind: str, rng: np.random.Generator, centre, size: float | None = None) -> Plant:
    """A plant of `kind` with its biological centre at `centre` (m); `size` = longest leaf (m)."""
    centre = np.asarray(centre, float)
    default = {"rosette": (0.04, 0.14), "seedling": (0.012, 0.04), "grass": (0.05, 0.16),
               "clover": (0.04, 0.10), "crop": (0.15, 0.35), "dead_leaf": (0.02, 0.08)}
    if kind not in default:
        raise ValueError(f"unknown plant kind {kind!r}; choose from {', '.join(PLANT_KINDS)}")
    if size is None:
        lo, hi = default[kind]
        size = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    if kind == "crop":
        return crop(rng, centre, size, rng.uniform(0, np.pi))
    return {"rosette": rosette, "seedling": seedling, "grass": grass, "clover": clover, "dead_leaf": dead_leaf}[kind](
        rng, centre, size
    )


def _extent(centre: np.ndarray, parts) -> float:
    pts = np.concatenate([p.poly for p in parts])
    return float(np.max(np.linalg.norm(pts - centre, axis=1)))
