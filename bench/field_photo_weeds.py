"""Held-out benchmark: close-up field photos of single weeds on soil, rendered from scratch.

What this is
    An INDEPENDENT test renderer for ``capm_field.detector.detect_centre``. It was written without
    looking at the detector, at the repository's other renderers, tests or docs: only the detector's
    public contract was known. The scenes are designed from general knowledge of what real
    close-up photos of weeds look like (hand-held phone or robot-arm camera looking roughly straight
    down), so the numbers measure how the detector generalises to images it was never tuned on.

    Every image holds one main weed, built organ by organ (leaf blades with midribs and veins,
    petioles, stems, spines, flowers) around an exact crown point: the place where the organs
    emerge from the ground. That crown is the ground truth, NOT the centroid of the green mask
    (leaning grass tufts, few-trefoil clovers, lopsided rosettes and leaning seedlings put the
    centroid well away from it). The plant is laid on procedurally generated soil (sandy, loam,
    clay, gravel, cracked crust, straw mulch; stones, clods, litter, moss, dead leaves, a few much
    smaller other weeds), lit by overcast sky, sun with cast shadows or low evening sun, and
    passed through a simple camera model (auto exposure with errors, white-balance errors,
    vignetting, defocus or motion blur, chromatic aberration, noise, sharpening, JPEG).

    Kinds: dandelion (runcinate toothed rosette), plantain (ribbed ovate blades on petioles, some
    flower spikes), grass (tuft of keeled blades, some bent or leaning one way), clover (trefoils on
    thin pale/reddish petioles, stolons, chevrons), seedling (2 cotyledons + 0-2 true leaves, maybe
    leaning on a visible hypocotyl), chickweed (branching stems with opposite leaf pairs, tiny white
    flowers), thistle (lobed spiny rosette, white midribs), purslane (fleshy obovate leaves on red
    radiating stems), fathen (upright spiral of rhombic mealy leaves seen from above), mallow
    (round lobed palmate blades on long petioles). Images are 640x480 .. 2000x1500, 4:3 or 16:9
    (some portrait); the plant spans 15-70 % of the short side, off-centre by up to 20 % of the
    frame, never cut by the border; the main weed is always the largest and the nearest to the
    image centre. Rendering takes ~0.25 s per image (median, one core).

Run
    cd <repository root>
    PYTHONPATH=. .venv/bin/python bench/field_photo_weeds.py --n 160 --seed 0
    PYTHONPATH=. .venv/bin/python bench/field_photo_weeds.py --n 160 --seed 0 --roi
    PYTHONPATH=. .venv/bin/python bench/field_photo_weeds.py --kinds clover,grass --save-fails fails/
    PYTHONPATH=. .venv/bin/python bench/field_photo_weeds.py --n 80 --seed 0 --person-shadow [--bare]
    PYTHONPATH=. .venv/bin/python bench/field_photo_weeds.py --n 160 --seed 0 --fill 1.1

    A single case can be re-rendered with ``render(np.random.default_rng([seed, index]), kind)``.

Columns of the summary table (per kind and overall)
    n       images of that kind
    det     share detected: det.pixel is not None and det.reason is None ("ambiguous" etc. with a
            pixel do NOT count as detections)
    med     median of |answer - truth| / S over detections (S = diameter of the plant's visible
            extent in pixels, from its minimum enclosing circle)
    p90     90th percentile of the same
    <0.1S   share of ALL images of that kind detected within 0.1*S of the truth
    <0.2S   share of ALL images detected within 0.2*S
    wrong   share of ALL images detected but more than 0.5*S away (a confident wrong answer)
    ms      median detector latency in milliseconds
    Below the table: per kind, counts of det.reason and of debug["method"]; one line per failing
    case (not detected, or error > 0.2*S); total run time.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

KINDS: tuple[str, ...] = (
    "dandelion", "plantain", "grass", "clover", "seedling",
    "chickweed", "thistle", "purslane", "fathen", "mallow",
)

# Typical real diameters (cm) of each kind at the growth stage we render; they set the
# ground sampling distance, hence how coarse the soil grain, stones and straw look.
PLANT_CM: dict[str, tuple[float, float]] = {
    "dandelion": (10, 35), "plantain": (10, 30), "grass": (6, 25), "clover": (6, 20),
    "seedling": (1.5, 5), "chickweed": (5, 20), "thistle": (12, 40), "purslane": (6, 25),
    "fathen": (6, 25), "mallow": (8, 30),
}

F32 = np.float32
TAU = 2 * math.pi


# ============================================================================ colour and noise
def lin(rgb: tuple[float, float, float]) -> np.ndarray:
    """sRGB (R, G, B) in 0..255 -> linear BGR albedo (we shade in linear light)."""
    c = np.asarray(rgb[::-1], np.float64) / 255.0
    c = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return c.astype(F32)


def jit(rng: np.random.Generator, c: np.ndarray, val: float = 0.12, chroma: float = 0.05) -> np.ndarray:
    """Random brightness and hue jitter of a linear colour (no two plants/stones alike)."""
    return (np.asarray(c, F32) * math.exp(rng.normal(0, val)) * np.exp(rng.normal(0, chroma, 3))).astype(F32)


def mixc(a: np.ndarray, b: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    return a + (b - a) * t


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def noise(rng: np.random.Generator, h: int, w: int, cell: float) -> np.ndarray:
    """Smooth zero-mean noise of roughly unit std whose blobs are about `cell` px wide.

    Large cells are made at low resolution and enlarged with repeated pyrUp (Gaussian
    upsampling): a single big cubic resize leaves curvature seams along the grid that show
    up as straight bands once the field is used as a height map and lit."""
    cell = float(cell)
    if cell <= 1.2:
        return rng.standard_normal((h, w), dtype=F32)
    if cell > 8.0:
        n = int(math.floor(math.log2(cell / 4.0)))
        k = 2 ** n
        big = noise(rng, h // k + 3, w // k + 3, cell / k)
        for _ in range(n):
            big = cv2.pyrUp(big)
    else:
        gh, gw = int(h / cell) + 3, int(w / cell) + 3
        g = rng.standard_normal((gh, gw), dtype=F32)
        big = cv2.resize(g, (int(gw * cell), int(gh * cell)), interpolation=cv2.INTER_CUBIC)
    oy = int(rng.integers(0, max(1, big.shape[0] - h + 1)))
    ox = int(rng.integers(0, max(1, big.shape[1] - w + 1)))
    out = big[oy:oy + h, ox:ox + w]
    s = float(out[::7, ::7].std()) + 1e-6
    return out * F32(1.0 / s)


def fbm(rng: np.random.Generator, h: int, w: int, cell: float, octaves: int = 3, gain: float = 0.5) -> np.ndarray:
    """Fractal sum of noise octaves (texture at several scales), unit std."""
    out = np.zeros((h, w), F32)
    amp, tot = 1.0, 0.0
    for i in range(octaves):
        out += F32(amp) * noise(rng, h, w, max(1.0, cell / 2 ** i))
        tot += amp * amp
        amp *= gain
    return out * F32(1.0 / math.sqrt(tot))


def periodic_noise(rng: np.random.Generator, n: int, cell: float) -> np.ndarray:
    """Seamless n x n noise tile (Gaussian-filtered white noise in Fourier space), unit std."""
    white = rng.standard_normal((n, n))
    fy = np.fft.fftfreq(n)[:, None]
    fx = np.fft.rfftfreq(n)[None, :]
    sig = cell / 2.0
    g = np.exp(-2 * (math.pi * sig) ** 2 * (fx ** 2 + fy ** 2))
    out = np.fft.irfft2(np.fft.rfft2(white) * g, s=(n, n))
    return ((out - out.mean()) / (out.std() + 1e-9)).astype(F32)


TILE = 512  # leaf-surface noise tiles are sampled with wrap-around


def tile_at(tile: np.ndarray, x: np.ndarray, y: np.ndarray, k: float = 1.0, off: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Sample a periodic noise tile at pixel coordinates scaled by k (bilinear when magnifying,
    so large leaves get smooth blotches rather than blocks)."""
    if k >= 1.0:
        xi = (np.asarray(x * k, np.int64) + off[0]) & (TILE - 1)
        yi = (np.asarray(y * k, np.int64) + off[1]) & (TILE - 1)
        return tile[yi, xi]
    xf, yf = x * F32(k) + F32(off[0]), y * F32(k) + F32(off[1])
    x0, y0 = np.floor(xf), np.floor(yf)
    fx, fy = (xf - x0).astype(F32), (yf - y0).astype(F32)
    xa, ya = x0.astype(np.int64) & (TILE - 1), y0.astype(np.int64) & (TILE - 1)
    xb, yb = (xa + 1) & (TILE - 1), (ya + 1) & (TILE - 1)
    top = tile[ya, xa] * (1 - fx) + tile[ya, xb] * fx
    bot = tile[yb, xa] * (1 - fx) + tile[yb, xb] * fx
    return top * (1 - fy) + bot * fy


def fill_mask(poly: np.ndarray, h: int, w: int) -> np.ndarray:
    """Anti-aliased polygon coverage (0..1) with 1/16 px vertex precision."""
    m = np.zeros((h, w), np.uint8)
    cv2.fillPoly(m, [np.round(poly * 16).astype(np.int32)], 255, cv2.LINE_AA, shift=4)
    return m.astype(F32) * F32(1 / 255)


# ============================================================================ plant organs
@dataclass
class Leaf:
    """A leaf blade (or leaflet, cotyledon, grass blade, dead leaf) in the image plane.

    The blade is split into two half-polygons along the midrib so each half can have its
    own tilt (a V-folded leaf in sun has one bright and one darker half, as in real photos)."""
    mid: np.ndarray              # (n, 2) midrib, base -> tip
    left: np.ndarray             # half-polygon on the +normal side
    right: np.ndarray            # half-polygon on the -normal side
    margin: np.ndarray           # margin points (for chewing damage)
    hts: np.ndarray              # (n,) height above soil along the midrib
    half_w: float                # max half-width (for relative coordinates)
    colour: np.ndarray
    base_colour: np.ndarray      # colour near the base (petiole end / young tissue)
    vein_colour: np.ndarray
    veins: list = field(default_factory=list)   # (polyline, width0, width1, strength)
    base_len: float = 0.2        # fraction of the leaf taking the base colour
    fold: float = 0.2            # radians: each half rises from the midrib
    gloss: float = 0.05
    shine: float = 30.0
    radial: bool = False         # palmate blade: t = distance from the base point
    narrow: bool = False         # grass-like: t from nearest midrib vertex
    pleats: float = 0.0
    n_pleats: int = 0
    cup: float = 0.0
    wave: float = 0.0
    n_waves: int = 0
    bump: float = 0.08           # normal jitter (surface unevenness -> glints)
    rim: float = 0.2             # lighter translucent margin
    red_rim: float = 0.0
    tip_dry: float = 0.0         # 0: none; else t where browning starts
    spots: float = 0.0           # chlorotic blotches
    chevron: float = 0.0         # white clover's pale V mark
    mealy: float = 0.0           # fat-hen's whitish bloom
    hairy: float = 0.0
    holes: int = 0
    chew: int = 0
    splash: float = 0.0          # soil splashed by rain
    texture: float = 1.0
    thick: float = 0.01


@dataclass
class Stem:
    """A stem, petiole, stolon, spine or flower stalk: a tapered tube along a polyline."""
    pts: np.ndarray
    w0: float
    w1: float
    c0: np.ndarray
    c1: np.ndarray
    hts: np.ndarray
    gloss: float = 0.05
    shine: float = 20.0


@dataclass
class Blob:
    """A small flat-ish object: flower, crown hub, bud."""
    poly: np.ndarray
    colour: np.ndarray
    h: float
    centre_colour: np.ndarray | None = None
    centre_frac: float = 0.0
    texture: float = 0.08     # granular texture (florets)
    dome: float = 0.0         # rounded top: normals tilt outwards


Organ = Leaf | Stem | Blob


def organ_points(o: Organ) -> np.ndarray:
    if isinstance(o, Leaf):
        return np.vstack([o.left, o.right])
    if isinstance(o, Stem):
        return o.pts
    return o.poly


def transform_organ(o: Organ, A: np.ndarray, s: float) -> Organ:
    """Apply p' = A[:, :2] @ p + A[:, 2] (rotation*scale(+mirror) and translation) to an organ."""
    def tp(p: np.ndarray) -> np.ndarray:
        return p @ A[:, :2].T + A[:, 2]
    if isinstance(o, Leaf):
        return replace(o, mid=tp(o.mid), left=tp(o.left), right=tp(o.right), margin=tp(o.margin),
                       hts=o.hts * s, half_w=o.half_w * s, thick=o.thick * s,
                       veins=[(tp(p), w0 * s, w1 * s, st) for p, w0, w1, st in o.veins])
    if isinstance(o, Stem):
        return replace(o, pts=tp(o.pts), w0=o.w0 * s, w1=o.w1 * s, hts=o.hts * s)
    return replace(o, poly=tp(o.poly), h=o.h * s)


# ---------------------------------------------------------------------------- geometry helpers
def unit(a: float) -> np.ndarray:
    return np.array([math.cos(a), math.sin(a)])


def arc(p0: np.ndarray, heading: float, length: float, bend: float = 0.0, n: int = 28,
        wiggle: float = 0.0, rng: np.random.Generator | None = None) -> np.ndarray:
    """Planar curve whose heading turns by `bend` radians over its length (leaf midrib)."""
    s = np.linspace(0, 1, n)
    ang = heading + bend * s
    if wiggle and rng is not None:
        ang = ang + wiggle * np.sin(s * rng.uniform(2, 5) + rng.uniform(0, TAU))
    steps = np.stack([np.cos(ang), np.sin(ang)], 1) * (length / (n - 1))
    pts = np.vstack([np.zeros(2), np.cumsum(steps[:-1], 0)])
    return pts + np.asarray(p0, float)


def polyline_frame(mid: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, unit normal and unit tangent at fractional arc length t on a polyline."""
    seg = np.diff(mid, axis=0)
    sl = np.hypot(seg[:, 0], seg[:, 1]) + 1e-12
    cum = np.concatenate([[0.0], np.cumsum(sl)])
    u = cum / cum[-1]
    t = np.asarray(t, float)
    x = np.interp(t, u, mid[:, 0])
    y = np.interp(t, u, mid[:, 1])
    vt = np.gradient(mid, axis=0)
    vt /= np.hypot(vt[:, 0], vt[:, 1])[:, None] + 1e-12
    tx = np.interp(t, u, vt[:, 0])
    ty = np.interp(t, u, vt[:, 1])
    tn = np.hypot(tx, ty) + 1e-12
    tan = np.stack([tx / tn, ty / tn], 1)
    nrm = np.stack([-tan[:, 1], tan[:, 0]], 1)
    return np.stack([x, y], 1), nrm, tan


def arc_length(p: np.ndarray) -> float:
    d = np.diff(p, axis=0)
    return float(np.hypot(d[:, 0], d[:, 1]).sum())


def half_polygon(mid: np.ndarray, ts: np.ndarray, ws: np.ndarray, side: float) -> tuple[np.ndarray, np.ndarray]:
    """Half-blade polygon: base -> margin (t, w pairs; t may step backwards for hooked lobes)
    -> back along the midrib from the last margin t to the base."""
    P, N, _ = polyline_frame(mid, ts)
    margin = P + side * N * ws[:, None]
    t_end = float(ts[-1]) if ws[-1] <= 1e-9 else 1.0
    back, _, _ = polyline_frame(mid, np.linspace(t_end, 0.0, 16))
    return np.vstack([mid[:1], margin, back]), margin


def profile(t: np.ndarray, a: float, b: float) -> np.ndarray:
    """Blade width profile t^a (1-t)^b scaled to max 1; the widest point is at a/(a+b)."""
    t = np.clip(np.asarray(t, float), 0, 1)
    ts = a / (a + b)
    return t ** a * (1 - t) ** b / (ts ** a * (1 - ts) ** b)


def simple_margin(rng: np.random.Generator, n: int = 28, a: float = 0.7, b: float = 0.9,
                  notch: float = 0.0, teeth: float = 0.0, n_teeth: int = 0, teeth_from: float = 0.15,
                  wavy: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Entire, wavy, toothed or notched (obcordate) margin as (t, w) with w in 0..1."""
    n = max(n, n_teeth * 8 + 8)
    ts = np.linspace(0, 1, n)
    u = ts * (1 - 1.3 * notch) if notch else ts
    w = profile(u, a, b)
    if teeth and n_teeth:
        frac = (ts * n_teeth + rng.uniform(0, 1)) % 1.0
        w = w * (1 - teeth * (1 - frac) * (ts > teeth_from))
    if wavy:
        w = w * (1 + wavy * np.sin(ts * rng.uniform(6, 14) + rng.uniform(0, TAU)))
    if notch:
        ts = np.append(ts, 1 - notch)
        w = np.append(w, 0.0)
    w[0] = max(w[0], 0.0)
    return ts, np.maximum(w, 0.0)


def make_leaf(mid: np.ndarray, tl: np.ndarray, wl: np.ndarray, tr: np.ndarray, wr: np.ndarray,
              half_w: float, **kw) -> Leaf:
    left, ml = half_polygon(mid, tl, wl * half_w, +1)
    right, mr = half_polygon(mid, tr, wr * half_w, -1)
    kw.setdefault("hts", np.zeros(len(mid)))
    return Leaf(mid=mid, left=left, right=right, margin=np.vstack([ml, mr]), half_w=half_w, **kw)


def heights(n: int, h0: float, h1: float, arch: float = 0.0) -> np.ndarray:
    s = np.linspace(0, 1, n)
    return np.maximum(h0 + (h1 - h0) * s + 4 * arch * s * (1 - s), 0.002)


def midrib_vein(mid: np.ndarray, w0: float, w1: float, strength: float = 1.0) -> tuple:
    return (mid, w0, w1, strength)


def lateral_veins(mid: np.ndarray, wfun: Callable[[np.ndarray], np.ndarray], half_w: float, n: int,
                  fwd: float = 0.18, reach: float = 0.85, w: float = 0.004, strength: float = 0.6,
                  t0: float = 0.12, t1: float = 0.85) -> list:
    """Pinnate secondary veins from the midrib towards the margin, curving forward."""
    out = []
    for side in (1, -1):
        for tv in np.linspace(t0, t1, n):
            te = min(tv + fwd, 0.98)
            P, N, _ = polyline_frame(mid, np.array([tv, (tv + te) / 2, te]))
            wm = wfun(np.array([te]))[0] * half_w
            pts = np.array([P[0], P[1] + side * N[1] * wm * reach * 0.55, P[2] + side * N[2] * wm * reach])
            out.append((pts, w, w * 0.5, strength))
    return out


def parallel_veins(mid: np.ndarray, wfun: Callable[[np.ndarray], np.ndarray], half_w: float,
                   fracs: list[float], w: float, strength: float = 0.8) -> list:
    """Arcuate veins running base -> tip at a fixed fraction of the local half-width (plantain)."""
    t = np.linspace(0.0, 0.97, 20)
    P, N, _ = polyline_frame(mid, t)
    out = []
    for f in fracs:
        for side in (1, -1):
            pts = P + side * N * (f * wfun(t) * half_w)[:, None]
            out.append((pts, w, w * 0.4, strength))
    return out


def golden_angles(rng: np.random.Generator, n: int, jitter: float = 0.22) -> np.ndarray:
    """Phyllotaxis: successive leaves ~137.5 degrees apart, with natural irregularity."""
    return rng.uniform(0, TAU) + np.arange(n) * 2.39996 + rng.normal(0, jitter, n)


# ---------------------------------------------------------------------------- plant colours
GREENS: dict[str, tuple[int, int, int]] = {
    "yellow": (124, 148, 56), "fresh": (96, 138, 50), "mid": (70, 112, 44), "dark": (44, 80, 36),
    "blue": (62, 98, 72), "olive": (98, 102, 50), "grey": (104, 124, 92), "grass": (88, 128, 46),
}


def pick_green(rng: np.random.Generator, weights: dict[str, float]) -> tuple[np.ndarray, str]:
    names = list(weights)
    p = np.array([weights[k] for k in names], float)
    name = names[int(rng.choice(len(names), p=p / p.sum()))]
    return jit(rng, lin(GREENS[name]), 0.12, 0.05), name


@dataclass
class Style:
    """Per-plant appearance choices shared by its leaves."""
    green: np.ndarray
    green_name: str
    dmg: float        # how damaged / stressed the plant is (0..1)
    splash: float     # soil splashed on leaves
    gloss: float

    def leaf(self, rng: np.random.Generator, var: float = 0.07) -> np.ndarray:
        return jit(rng, self.green, var, 0.03)


def make_style(rng: np.random.Generator, weights: dict[str, float], gloss: float) -> Style:
    g, name = pick_green(rng, weights)
    dmg = float(rng.uniform(0, 1) ** 2)
    splash = float(rng.uniform(0, 1) ** 3) if rng.random() < 0.4 else 0.0
    return Style(g, name, dmg, splash, gloss * float(rng.uniform(0.6, 1.4)))


def damage_kw(rng: np.random.Generator, st: Style, scale: float = 1.0) -> dict:
    """Random insect holes, chewed margins, dry tips, chlorotic spots and soil splash."""
    d = st.dmg * scale
    return dict(
        holes=int(rng.poisson(2.0 * d)) if rng.random() < 0.5 * d + 0.05 else 0,
        chew=int(rng.poisson(1.5 * d)) if rng.random() < 0.4 * d + 0.05 else 0,
        tip_dry=float(rng.uniform(0.6, 0.92)) if rng.random() < 0.25 * d + 0.02 else 0.0,
        spots=float(rng.uniform(0.2, 0.7)) if rng.random() < 0.4 * d else 0.0,
        splash=st.splash * float(rng.uniform(0.3, 1.0)),
    )


PALE_STEM = (196, 204, 160)
PURPLE = (128, 60, 96)


# ---------------------------------------------------------------------------- kind builders
# All builders work in "plant units": the plant's radius is about 1, the crown is (0, 0).

def build_dandelion(rng: np.random.Generator) -> tuple[list[Organ], dict]:
    st = make_style(rng, {"mid": 3, "fresh": 2, "dark": 2, "yellow": 1, "olive": 1}, 0.12)
    n = int(rng.integers(6, 15))
    ang = golden_angles(rng, n, 0.3)
    purple_base = rng.random() < 0.5
    organs: list[Organ] = []
    for i in range(n):
        age = 1 - i / n
        length = rng.uniform(0.55, 1.0) * (0.5 + 0.5 * age)
        hw = length * rng.uniform(0.14, 0.26)
        mid = arc(unit(ang[i]) * rng.uniform(0, 0.02), ang[i], length, rng.normal(0, 0.25))
        depth = rng.uniform(0.35, 0.85) if rng.random() < 0.8 else rng.uniform(0.1, 0.35)
        nl = int(rng.integers(3, 7))
        tl, wl = runcinate(rng, nl, depth)
        tr, wr = runcinate(rng, nl, depth * rng.uniform(0.8, 1.2))
        env = lambda t: np.clip(0.25 + t, 0, 1)  # noqa: E731 - envelope for vein reach
        c = st.leaf(rng)
        base = lin(PURPLE) if purple_base and rng.random() < 0.8 else lin(PALE_STEM)
        veins = [midrib_vein(mid, 0.045 * hw * 2, 0.006, 1.0)]
        veins += lateral_veins(mid, env, hw, nl, fwd=0.12, reach=0.6, w=0.004, strength=0.15)
        organs.append(make_leaf(
            mid, tl, wl, tr, wr, hw, hts=heights(len(mid), 0.05 + 0.07 * (1 - age), rng.uniform(0.0, 0.1),
                                                     rng.uniform(0.02, 0.1)),
            colour=c, base_colour=jit(rng, base, 0.1), vein_colour=mixc(c, lin((200, 210, 170)), 0.55),
            veins=veins, base_len=rng.uniform(0.12, 0.35), fold=rng.uniform(0.05, 0.35), gloss=st.gloss,
            shine=35, bump=0.1, rim=0.15, **damage_kw(rng, st)))
    organs += young_centre_leaves(rng, st, int(rng.integers(2, 5)), 0.12, 0.25, toothed=True)
    return organs, {"n_leaves": n, "green": st.green_name, "purple_base": purple_base}


def runcinate(rng: np.random.Generator, n_lobes: int, depth: float) -> tuple[np.ndarray, np.ndarray]:
    """Dandelion margin: triangular lobes hooked back towards the base, big terminal lobe."""
    def env(t: float) -> float:
        return float(np.clip(0.3 + 0.7 * t / 0.7, 0, 1))
    t_start = rng.uniform(0.15, 0.3)
    t_term = rng.uniform(0.6, 0.76)
    sinus = np.linspace(t_start, t_term, n_lobes + 1)
    sinus[1:-1] += rng.normal(0, 0.012, n_lobes - 1)
    ts, ws = [0.0, t_start * 0.6], [0.05, 0.09]
    for i in range(n_lobes):
        s0, s1 = sinus[i], sinus[i + 1]
        seg = s1 - s0
        d = float(np.clip(depth * rng.uniform(0.7, 1.25), 0.05, 0.9))
        back = rng.uniform(0.1, 0.45) * seg
        ts += [s0, s0 - back, s0 + 0.45 * seg]
        ws += [env(s0) * (1 - d), env(s0) * rng.uniform(0.85, 1.05), env(s0 + 0.45 * seg) * (1 - 0.55 * d)]
        if rng.random() < 0.4:  # small denticle on the distal edge
            ts += [s0 + 0.7 * seg]
            ws += [env(s0 + 0.7 * seg) * (1 - 0.45 * d)]
    s = sinus[-1]
    ts += [s, s - 0.03, s + 0.35 * (1 - s), s + 0.7 * (1 - s), 1.0]
    ws += [env(s) * (1 - 0.8 * depth), 0.95, rng.uniform(0.55, 0.8), rng.uniform(0.25, 0.45), 0.0]
    return np.array(ts), np.array(ws)


def young_centre_leaves(rng: np.random.Generator, st: Style, n: int, lmin: float, lmax: float,
                        toothed: bool = False, hairy: float = 0.0, colour: np.ndarray | None = None) -> list[Organ]:
    """The newest leaves of a rosette: small, paler, more upright, folded, right at the crown."""
    out: list[Organ] = []
    for a in golden_angles(rng, n, 0.4):
        length = rng.uniform(lmin, lmax)
        mid = arc(np.zeros(2), a, length, rng.normal(0, 0.2), n=16)
        ts, w = simple_margin(rng, 20, 0.8, 1.0, teeth=0.25 if toothed else 0.0, n_teeth=5)
        c = colour if colour is not None else mixc(st.leaf(rng), lin(GREENS["yellow"]), rng.uniform(0.2, 0.5))
        out.append(make_leaf(
            mid, ts, w, ts, w * rng.uniform(0.8, 1.0), length * rng.uniform(0.12, 0.2),
            hts=heights(16, 0.1, rng.uniform(0.12, 0.2)), colour=c, base_colour=mixc(c, lin(PALE_STEM), 0.4),
            vein_colour=mixc(c, lin((210, 220, 180)), 0.4), veins=[midrib_vein(mid, 0.02 * length, 0.004, 0.6)],
            fold=rng.uniform(0.4, 0.8), gloss=st.gloss, hairy=hairy, rim=0.25))
    return out


def build_plantain(rng: np.random.Generator) -> tuple[list[Organ], dict]:
    st = make_style(rng, {"mid": 3, "dark": 2, "fresh": 2, "yellow": 1, "olive": 1}, 0.2)
    n = int(rng.integers(4, 11))
    ang = golden_angles(rng, n, 0.3)
    organs: list[Organ] = []
    stem_c = lin(PALE_STEM) if rng.random() < 0.6 else lin((150, 100, 110))
    for i in range(n):
        age = 1 - i / n
        total = rng.uniform(0.7, 1.0) * (0.55 + 0.45 * age)
        lp = total * rng.uniform(0.18, 0.38)
        lb = total - lp
        hb = 0.05 + 0.08 * (1 - age)
        p_mid = arc(np.zeros(2), ang[i], lp, rng.normal(0, 0.1), n=8)
        organs.append(Stem(p_mid, 0.06 * lb + 0.01, 0.035 * lb + 0.008, jit(rng, stem_c, 0.08),
                           mixc(st.green, stem_c, 0.5), heights(8, 0.01, hb), gloss=0.1))
        mid = arc(p_mid[-1], ang[i] + rng.normal(0, 0.1), lb, rng.normal(0, 0.15))
        a, b = rng.uniform(0.45, 0.9), rng.uniform(0.7, 1.1)
        ts, w = simple_margin(rng, 30, a, b, wavy=rng.uniform(0, 0.05),
                              teeth=rng.uniform(0, 0.08), n_teeth=int(rng.integers(4, 9)))
        ts2, w2 = simple_margin(rng, 30, a, b, wavy=rng.uniform(0, 0.05))
        hw = lb * rng.uniform(0.27, 0.42)
        c = st.leaf(rng)
        wf = lambda t, a=a, b=b: profile(t, a, b)  # noqa: E731
        fracs = [0.35, 0.7] if rng.random() < 0.5 else [0.28, 0.55, 0.8]
        veins = [midrib_vein(mid, 0.05 * hw, 0.01 * hw, 0.8)] + parallel_veins(mid, wf, hw, fracs, 0.018 * hw, 0.45)
        organs.append(make_leaf(
            mid, ts, w, ts2, w2, hw, hts=heights(len(mid), hb, rng.uniform(0.0, 0.1), rng.uniform(0.01, 0.07)),
            colour=c, base_colour=mixc(c, stem_c, 0.5), vein_colour=mixc(c, lin((190, 205, 160)), 0.5),
            veins=veins, base_len=0.1, fold=rng.uniform(0.0, 0.2), gloss=st.gloss, shine=40, bump=0.12,
            rim=0.1, **damage_kw(rng, st)))
    organs += young_centre_leaves(rng, st, int(rng.integers(1, 4)), 0.1, 0.2)
    n_spikes = int(rng.integers(1, 4)) if rng.random() < 0.25 else 0
    for _ in range(n_spikes):  # flower spikes: tall stalks, seen foreshortened from above
        a = rng.uniform(0, TAU)
        elev = rng.uniform(0.5, 1.3)
        length = rng.uniform(0.7, 1.2)
        horiz = length * math.cos(elev)
        pts = arc(np.zeros(2), a, horiz, rng.normal(0, 0.2), n=12)
        hs = np.linspace(0.02, length * math.sin(elev), 12)
        k = 7
        organs.append(Stem(pts[:k + 1], 0.018, 0.014, lin((150, 160, 110)), lin((120, 130, 80)), hs[:k + 1]))
        organs.append(Stem(pts[k:], 0.04, 0.025, lin((110, 105, 70)), lin((140, 130, 90)), hs[k:], gloss=0.0))
    return organs, {"n_leaves": n, "green": st.green_name, "spikes": n_spikes}


def blade_path(rng: np.random.Generator, base: np.ndarray, az: float, length: float, beta0: float,
               beta1: float, curl: float, kink: float | None, n: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """3-D grass blade: starts steep, bends over under its weight, lies on the soil if it gets there."""
    s = np.linspace(0, 1, n)
    beta = beta0 + (beta1 - beta0) * s ** 1.4
    if kink is not None:
        beta = np.where(s > kink, min(beta1, -0.3) - 0.3, beta)
    az_s = az + curl * s
    ds = length / (n - 1)
    xy = [np.asarray(base, float)]
    z = [0.004]
    for i in range(1, n):
        b = beta[i - 1]
        zn = z[-1] + math.sin(b) * ds
        if zn < 0.004:           # reached the soil: continue lying flat
            zn, b = 0.004, 0.0
        xy.append(xy[-1] + math.cos(b) * ds * np.array([math.cos(az_s[i]), math.sin(az_s[i])]))
        z.append(zn)
    return np.array(xy), np.array(z)


def build_grass(rng: np.random.Generator) -> tuple[list[Organ], dict]:
    st = make_style(rng, {"grass": 4, "fresh": 2, "mid": 2, "yellow": 1, "blue": 1}, 0.25)
    n = int(rng.integers(8, 41))
    lean_dir = rng.uniform(0, TAU)
    lean_k = float(rng.choice([0.0, rng.uniform(0.3, 0.7), rng.uniform(0.7, 1.0)]))
    sheath_c = lin(PALE_STEM) if rng.random() < 0.6 else lin((150, 90, 110))
    tiller_r = rng.uniform(0.01, 0.05)
    blades = []
    for _ in range(n):
        az = lean_dir + rng.normal(0, 0.7) if rng.random() < lean_k else rng.uniform(0, TAU)
        base = unit(rng.uniform(0, TAU)) * tiller_r * math.sqrt(rng.random())
        length = rng.uniform(0.5, 1.35)
        beta0 = rng.uniform(0.6, 1.4)
        beta1 = beta0 - rng.uniform(0.6, 2.3)
        kink = rng.uniform(0.3, 0.7) if rng.random() < 0.15 else None
        mid, z = blade_path(rng, base, az, length, beta0, beta1, rng.normal(0, 0.4), kink)
        if arc_length(mid) < 0.05:
            continue
        blades.append((mid, z))
    blades.sort(key=lambda b: float(b[1].mean()))  # lower blades first; z-buffer sorts the rest
    organs: list[Organ] = []
    dead_share = rng.uniform(0, 0.25) * (0.5 + st.dmg)
    for mid, z in blades:
        hw = rng.uniform(0.008, 0.022)
        ts = np.linspace(0, 1, 24)
        w = np.clip((1 - ts) / rng.uniform(0.15, 0.35), 0, 1) ** 0.8 * (0.75 + 0.25 * np.minimum(1, ts / 0.08))
        dead = rng.random() < dead_share
        c = jit(rng, lin((176, 156, 104)), 0.15, 0.05) if dead else st.leaf(rng, 0.1)
        organs.append(make_leaf(
            mid, ts, w, ts, w, hw, hts=z, colour=c, base_colour=jit(rng, sheath_c, 0.1),
            vein_colour=mixc(c, lin((200, 215, 170)), 0.4), veins=[midrib_vein(mid, hw * 0.5, hw * 0.2, 0.7)],
            base_len=rng.uniform(0.05, 0.15), fold=rng.uniform(0.2, 0.6), gloss=st.gloss, shine=50,
            narrow=True, bump=0.05, rim=0.05,
            tip_dry=(rng.uniform(0.7, 0.95) if rng.random() < 0.2 + 0.5 * st.dmg else 0.0),
            splash=st.splash * rng.uniform(0, 1)))
    return organs, {"n_blades": len(blades), "lean": round(lean_k, 2), "green": st.green_name}


def trefoil(rng: np.random.Generator, centre: np.ndarray, a: float, ll: float, ht: float, st: Style,
            chev: float) -> list[Organ]:
    """Three obcordate leaflets round the tip of a petiole, with white clover's pale chevron."""
    out: list[Organ] = []
    rot = a + rng.normal(0, 0.4)
    c_tref = st.leaf(rng, 0.06)
    for k in range(3):
        h_ = rot + k * TAU / 3 + rng.normal(0, 0.12)
        mid = arc(centre + unit(h_) * 0.008, h_, ll * rng.uniform(0.9, 1.1), rng.normal(0, 0.05), n=16)
        tsm, w = simple_margin(rng, 28, rng.uniform(0.7, 1.1), rng.uniform(0.25, 0.45),
                               notch=rng.uniform(0.03, 0.09), teeth=0.03, n_teeth=12, teeth_from=0.4)
        hw = ll * rng.uniform(0.36, 0.48)
        c = jit(rng, c_tref, 0.04, 0.02)
        wf = lambda t: profile(t, 0.9, 0.35)  # noqa: E731
        veins = [midrib_vein(mid, 0.02 * ll, 0.01 * ll, 0.6)]
        veins += lateral_veins(mid, wf, hw, 7, fwd=0.08, reach=0.9, w=0.006 * ll, strength=0.3, t0=0.1, t1=0.85)
        out.append(make_leaf(
            mid, tsm, w, tsm, w, hw, hts=heights(16, ht + 0.01, ht + rng.uniform(-0.02, 0.03)),
            colour=c, base_colour=c, vein_colour=mixc(c, lin((200, 215, 190)), 0.45), veins=veins,
            base_len=0.0, fold=rng.uniform(0.0, 0.35), gloss=st.gloss, shine=30, chevron=chev,
            rim=0.1, **damage_kw(rng, st, 0.4)))
    return out


def build_clover(rng: np.random.Generator) -> tuple[list[Organ], dict]:
    st = make_style(rng, {"mid": 3, "dark": 2, "blue": 2, "fresh": 1}, 0.12)
    n = int(rng.integers(3, 13))
    spread = rng.uniform(0.4, 1.0)
    a0 = rng.uniform(0, TAU)
    ang = a0 + (np.sort(rng.uniform(0, TAU * spread, n)))
    pet_c = lin((166, 186, 128)) if rng.random() < 0.65 else lin((128, 88, 76))
    chev = rng.uniform(0.3, 0.8) if rng.random() < 0.7 else 0.0
    organs: list[Organ] = []
    n_stolons = int(rng.integers(0, 3))
    for _ in range(n_stolons):  # creeping stolons on the soil, a young trefoil at the growing tip
        a = rng.uniform(0, TAU)
        pts = arc(np.zeros(2), a, rng.uniform(0.2, 0.45), rng.normal(0, 0.5), n=12)
        sc = jit(rng, pet_c * F32(0.85), 0.1)
        organs.append(Stem(pts, 0.018, 0.014, sc, sc, heights(12, 0.006, 0.006)))
        tip = arc(pts[-1], a, rng.uniform(0.04, 0.1), 0.0, n=4)
        organs.append(Stem(tip, 0.008, 0.007, sc, sc, np.linspace(0.006, 0.05, 4)))
        organs += trefoil(rng, tip[-1], a, rng.uniform(0.05, 0.09), 0.05, st, chev)
    for a in ang:
        lp = rng.uniform(0.25, 0.75)
        ht = rng.uniform(0.05, 0.3)
        start = unit(rng.uniform(0, TAU)) * rng.uniform(0, 0.03)
        pts = arc(start, a, lp, rng.normal(0, 0.4), n=14)
        hs = ht * np.sqrt(np.linspace(0, 1, 14)) + 0.005
        organs.append(Stem(pts, 0.011, 0.008, jit(rng, pet_c, 0.1), jit(rng, pet_c, 0.1), hs, gloss=0.1))
        organs += trefoil(rng, pts[-1], a, rng.uniform(0.12, 0.21), ht, st, chev)
    n_flowers = int(rng.integers(1, 3)) if rng.random() < 0.15 else 0
    for _ in range(n_flowers):  # globular heads of small white florets on long peduncles
        a = rng.uniform(0, TAU)
        pts = arc(np.zeros(2), a, rng.uniform(0.3, 0.7), rng.normal(0, 0.3), n=12)
        organs.append(Stem(pts, 0.015, 0.012, jit(rng, pet_c, 0.1), jit(rng, pet_c, 0.1), np.linspace(0.01, 0.4, 12)))
        organs.append(Blob(blob_poly(rng, pts[-1], rng.uniform(0.06, 0.09), 18, 0.08),
                           jit(rng, lin((226, 220, 206)), 0.05), 0.42, texture=0.45, dome=1.2))
    return organs, {"n_trefoils": n, "stolons": n_stolons, "spread": round(spread, 2), "green": st.green_name}


def blob_poly(rng: np.random.Generator, c: np.ndarray, r: float, k: int, irr: float,
              star: int = 0, elong: float = 1.0, rot: float | None = None) -> np.ndarray:
    """Irregular round polygon, optionally star-shaped (flowers)."""
    a = np.linspace(0, TAU, k, endpoint=False) + rng.uniform(0, TAU)
    rr = r * (1 + irr * rng.normal(0, 1, k))
    if star:
        rr = rr * (0.45 + 0.55 * (np.arange(k) % 2 == 0))
    rot = rng.uniform(0, TAU) if rot is None else rot
    x, y = np.cos(a) * rr * elong, np.sin(a) * rr
    return np.stack([x * math.cos(rot) - y * math.sin(rot), x * math.sin(rot) + y * math.cos(rot)], 1) + c


def build_seedling(rng: np.random.Generator) -> tuple[list[Organ], dict]:
    st = make_style(rng, {"fresh": 3, "yellow": 2, "mid": 2, "blue": 1}, 0.2)
    lean = rng.uniform(0, 0.12) if rng.random() < 0.6 else 0.0
    node = unit(rng.uniform(0, TAU)) * lean
    h_node = rng.uniform(0.12, 0.3)
    hyp_c = lin((170, 90, 100)) if rng.random() < 0.4 else lin(PALE_STEM)
    organs: list[Organ] = []
    if lean > 0.02:
        pts = np.linspace(np.zeros(2), node, 8)
        organs.append(Stem(pts, 0.045, 0.04, jit(rng, hyp_c, 0.1), jit(rng, hyp_c, 0.1), np.linspace(0.005, h_node, 8)))
    ctype = str(rng.choice(["oval", "lanceolate", "notched", "round"]))
    phi = rng.uniform(0, TAU)
    lc = rng.uniform(0.32, 0.5)
    cot_c = mixc(st.leaf(rng), lin(GREENS["yellow"]), rng.uniform(0, 0.3))
    for k in range(2):
        h_ = phi + k * math.pi + rng.normal(0, 0.15)
        p0 = node + unit(h_) * 0.03
        mid = arc(p0, h_, lc * rng.uniform(0.92, 1.08), rng.normal(0, 0.1), n=20)
        if ctype == "oval":
            ts, w = simple_margin(rng, 24, 0.7, 0.7)
            hw = lc * rng.uniform(0.22, 0.3)
        elif ctype == "lanceolate":
            ts, w = simple_margin(rng, 24, 0.8, 1.2)
            hw = lc * rng.uniform(0.12, 0.18)
        elif ctype == "notched":
            ts, w = simple_margin(rng, 24, 0.6, 0.3, notch=rng.uniform(0.08, 0.16))
            hw = lc * rng.uniform(0.35, 0.5)
        else:
            ts, w = simple_margin(rng, 24, 0.55, 0.45)
            hw = lc * rng.uniform(0.3, 0.42)
        c = jit(rng, cot_c, 0.04, 0.02)
        organs.append(make_leaf(
            mid, ts, w, ts, w, hw, hts=heights(20, h_node, h_node + rng.uniform(-0.08, 0.04)), colour=c,
            base_colour=mixc(c, hyp_c, 0.4), vein_colour=mixc(c, lin((200, 215, 180)), 0.3),
            veins=[midrib_vein(mid, 0.025 * lc, 0.005, 0.5)], base_len=0.15, fold=rng.uniform(0.05, 0.4),
            gloss=st.gloss, shine=30, rim=0.2, thick=0.02, **damage_kw(rng, st, 0.5)))
    n_true = int(rng.choice([0, 1, 2], p=[0.3, 0.3, 0.4]))
    true_c = st.leaf(rng) * F32(0.85)
    toothed = rng.random() < 0.6
    hairy = rng.uniform(0, 0.5) if rng.random() < 0.4 else 0.0
    for k in range(n_true):
        h_ = phi + math.pi / 2 + k * math.pi + rng.normal(0, 0.25)
        lt = rng.uniform(0.1, 0.35) * (1.0 if k == 0 else rng.uniform(0.4, 1.0))
        mid = arc(node + unit(h_) * 0.02, h_, lt, rng.normal(0, 0.2), n=18)
        ts, w = simple_margin(rng, 24, 0.7, 0.9, teeth=0.25 if toothed else 0.0, n_teeth=int(rng.integers(3, 7)))
        hw = lt * rng.uniform(0.25, 0.38)
        wf = lambda t: profile(t, 0.7, 0.9)  # noqa: E731
        organs.append(make_leaf(
            mid, ts, w, ts, w, hw, hts=heights(18, h_node + 0.03, h_node + 0.06), colour=true_c,
            base_colour=true_c, vein_colour=mixc(true_c, lin((190, 210, 170)), 0.4),
            veins=[midrib_vein(mid, 0.04 * lt, 0.006, 0.7)] + lateral_veins(mid, wf, hw, 3, w=0.008 * lt, strength=0.4),
            fold=rng.uniform(0.2, 0.6), gloss=st.gloss * 0.6, hairy=hairy, rim=0.2))
    if n_true == 0:
        organs.append(Blob(blob_poly(rng, node, 0.025, 8, 0.2), jit(rng, true_c, 0.1), h_node + 0.02))
    return organs, {"cotyledons": ctype, "true_leaves": n_true, "lean": round(lean, 3), "green": st.green_name}


def build_chickweed(rng: np.random.Generator) -> tuple[list[Organ], dict]:
    st = make_style(rng, {"fresh": 3, "yellow": 2, "mid": 2}, 0.1)
    stem_c = lin((150, 180, 100)) if rng.random() < 0.6 else lin((150, 100, 90))
    stems: list[Organ] = []
    leaves: list[Organ] = []
    flowers: list[Organ] = []
    n_main = int(rng.integers(3, 8))
    az = rng.uniform(0, TAU) + np.arange(n_main) * TAU / n_main + rng.normal(0, 0.35, n_main)
    leaf_l = rng.uniform(0.1, 0.17)
    p_flower = rng.uniform(0.2, 0.6) if rng.random() < 0.35 else 0.0

    def grow(p: np.ndarray, heading: float, length: float, depth: int, h0: float) -> None:
        internode = rng.uniform(0.08, 0.14)
        n_nodes = max(2, int(length / internode))
        pts = [p]
        hs = [h0]
        bend = rng.normal(0, 0.25)
        for j in range(n_nodes):
            heading += bend + rng.normal(0, 0.3)
            pts.append(pts[-1] + unit(heading) * internode * rng.uniform(0.8, 1.2))
            hs.append(min(h0 + 0.01 * (j + 1), 0.08))
            frac = (j + 1) / n_nodes
            size = leaf_l * (1.1 - 0.5 * frac) * rng.uniform(0.75, 1.2)
            for sd in (1, -1):  # opposite pair of ovate leaves at each node
                la = heading + sd * rng.uniform(0.7, 1.4)
                mid = arc(pts[-1] + unit(la) * 0.01, la, size, rng.normal(0, 0.2), n=14)
                ts, w = simple_margin(rng, 18, 0.6, 1.0)
                c = st.leaf(rng, 0.06)
                leaves.append(make_leaf(
                    mid, ts, w, ts, w, size * rng.uniform(0.25, 0.35), hts=heights(14, hs[-1] + 0.01, hs[-1] + 0.02),
                    colour=c, base_colour=c, vein_colour=mixc(c, lin((200, 220, 170)), 0.3),
                    veins=[midrib_vein(mid, 0.05 * size, 0.01 * size, 0.5)], fold=rng.uniform(0.1, 0.4),
                    gloss=st.gloss, rim=0.3, **damage_kw(rng, st, 0.4)))
            if depth < 2 and rng.random() < 0.4 and j < n_nodes - 1:
                grow(pts[-1], heading + rng.choice([-1, 1]) * rng.uniform(0.4, 0.9),
                     length * (1 - frac) * rng.uniform(0.5, 0.9), depth + 1, hs[-1])
        stems.append(Stem(np.array(pts), 0.014, 0.009, jit(rng, stem_c, 0.1), jit(rng, stem_c, 0.1), np.array(hs)))
        for k in range(int(rng.integers(2, 5))):  # terminal cluster of small leaves
            la = heading + rng.normal(0, 0.8)
            size = leaf_l * rng.uniform(0.35, 0.6)
            mid = arc(pts[-1], la, size, 0.0, n=10)
            ts, w = simple_margin(rng, 14, 0.6, 1.0)
            c = mixc(st.leaf(rng), lin(GREENS["yellow"]), 0.3)
            leaves.append(make_leaf(mid, ts, w, ts, w, size * 0.3, hts=heights(10, hs[-1] + 0.02, hs[-1] + 0.03),
                                    colour=c, base_colour=c, vein_colour=c, fold=0.4, gloss=st.gloss, rim=0.3))
        if rng.random() < p_flower:
            flowers.append(Blob(blob_poly(rng, pts[-1], rng.uniform(0.025, 0.04), 20, 0.1, star=1),
                                jit(rng, lin((236, 238, 232)), 0.04), hs[-1] + 0.05, lin((190, 200, 120)), 0.25))

    for a in az:
        grow(unit(a) * 0.01, a, rng.uniform(0.55, 1.0), 0, 0.01)
    organs = stems + leaves + flowers
    return organs, {"n_stems": n_main, "flowers": len(flowers), "green": st.green_name}


def thistle_margin(rng: np.random.Generator, n_lobes: int, depth: float, phase: float,
                   spine: float) -> tuple[np.ndarray, np.ndarray, list[tuple[float, float, float]]]:
    """Pinnatifid margin with forward-pointing lobes; returns lobe tips for the spines."""
    def env(t: float) -> float:
        return float(profile(np.array([t]), 0.8, 0.9)[0] * 0.85 + 0.15 * (t < 0.9))
    sinus = np.linspace(0.12 + phase, 0.92, n_lobes + 1)
    ts, ws, tips = [0.0], [0.06], []
    for i in range(n_lobes):
        s0, s1 = sinus[i], sinus[i + 1]
        seg = s1 - s0
        d = float(np.clip(depth * rng.uniform(0.75, 1.2), 0.1, 0.88))
        tt = s0 + rng.uniform(0.55, 0.8) * seg
        ts += [s0, s0 + 0.3 * seg, tt]
        ws += [env(s0) * (1 - d), env(s0 + 0.3 * seg) * (1 - 0.3 * d), env(tt) * rng.uniform(0.95, 1.1)]
        tips.append((tt, ws[-1], spine * rng.uniform(0.6, 1.3)))
    ts += [0.96, 1.0]
    ws += [0.08, 0.0]
    tips.append((1.0, 0.0, spine * 1.2))
    return np.array(ts), np.array(ws), tips


def build_thistle(rng: np.random.Generator) -> tuple[list[Organ], dict]:
    st = make_style(rng, {"dark": 3, "blue": 3, "grey": 1, "mid": 2}, 0.08)
    n = int(rng.integers(6, 13))
    ang = golden_angles(rng, n, 0.25)
    spine_c = lin((214, 208, 170))
    organs: list[Organ] = []
    spines: list[Organ] = []
    hairy = rng.uniform(0.0, 0.35)
    for i in range(n):
        age = 1 - i / n
        length = rng.uniform(0.6, 1.0) * (0.5 + 0.5 * age)
        hw = length * rng.uniform(0.16, 0.27)
        mid = arc(unit(ang[i]) * 0.01, ang[i], length, rng.normal(0, 0.2))
        nl = int(rng.integers(4, 9))
        depth = rng.uniform(0.35, 0.8)
        spine = rng.uniform(0.025, 0.06)
        tl, wl, tips_l = thistle_margin(rng, nl, depth, 0.0, spine)
        tr, wr, tips_r = thistle_margin(rng, nl, depth, rng.uniform(0.01, 0.04), spine)
        c = st.leaf(rng)
        h0 = 0.05 + 0.07 * (1 - age)
        hts = heights(len(mid), h0, rng.uniform(0.0, 0.1), rng.uniform(0.02, 0.09))
        env = lambda t: profile(t, 0.8, 0.9)  # noqa: E731
        organs.append(make_leaf(
            mid, tl, wl, tr, wr, hw, hts=hts, colour=c, base_colour=mixc(c, lin((210, 210, 190)), 0.4),
            vein_colour=mixc(c, lin((228, 232, 215)), 0.75),
            veins=[midrib_vein(mid, 0.09 * hw, 0.02 * hw, 1.0)] + lateral_veins(mid, env, hw, nl, 0.1, 0.8, 0.025 * hw, 0.5),
            base_len=0.1, fold=rng.uniform(0.1, 0.4), gloss=st.gloss, wave=rng.uniform(0.25, 0.55),
            n_waves=nl, hairy=hairy, rim=0.35, bump=0.15, **damage_kw(rng, st, 0.6)))
        for side, tips in ((1, tips_l), (-1, tips_r)):
            for tt, ww, sl in tips:  # a sharp pale spine at every lobe tip
                P, N, T = polyline_frame(mid, np.array([min(tt, 1.0)]))
                p0 = P[0] + side * N[0] * ww * hw
                d = side * N[0] * 0.6 + T[0] * 0.8 if ww > 0 else T[0]
                d = d / np.linalg.norm(d)
                hh = float(np.interp(tt, np.linspace(0, 1, len(hts)), hts)) + 0.005
                spines.append(Stem(np.array([p0, p0 + d * sl]), 0.005, 0.0015, spine_c, spine_c,
                                   np.array([hh, hh]), gloss=0.2))
    organs += spines
    organs += young_centre_leaves(rng, st, int(rng.integers(2, 5)), 0.1, 0.22, toothed=True,
                                  hairy=max(hairy, 0.5), colour=mixc(st.green, lin((200, 210, 190)), 0.3))
    return organs, {"n_leaves": n, "hairy": round(hairy, 2), "green": st.green_name}


def build_purslane(rng: np.random.Generator) -> tuple[list[Organ], dict]:
    st = make_style(rng, {"mid": 3, "fresh": 2, "olive": 1, "dark": 1}, 0.4)
    stem_c = jit(rng, lin((118, 52, 50)) if rng.random() < 0.75 else lin((104, 96, 56)), 0.1)
    n = int(rng.integers(4, 10))
    az = rng.uniform(0, TAU) + np.sort(rng.uniform(0, TAU, n))
    stems: list[Organ] = []
    leaves: list[Organ] = []
    red_rim = rng.uniform(0, 0.6)

    def leaf_at(p: np.ndarray, a: float, size: float, h: float) -> None:
        mid = arc(p, a, size, rng.normal(0, 0.15), n=14)
        ts, w = simple_margin(rng, 18, rng.uniform(1.0, 1.8), rng.uniform(0.3, 0.5))
        c = st.leaf(rng, 0.06)
        leaves.append(make_leaf(
            mid, ts, w, ts, w, size * rng.uniform(0.3, 0.42), hts=heights(14, h, h + 0.01), colour=c,
            base_colour=mixc(c, stem_c, 0.3), vein_colour=c, veins=[], fold=-rng.uniform(0.1, 0.35),
            gloss=st.gloss, shine=40, bump=0.12, red_rim=red_rim, rim=0.1, thick=0.02, **damage_kw(rng, st, 0.3)))

    def grow(p: np.ndarray, heading: float, length: float, w0: float, depth: int) -> None:
        pts = arc(p, heading, length, rng.normal(0, 0.6), n=14, wiggle=0.1, rng=rng)
        hs = np.linspace(0.012, 0.03, 14)
        stems.append(Stem(pts, w0, w0 * 0.55, stem_c, jit(rng, stem_c, 0.08), hs, gloss=0.3, shine=30))
        for j in range(3, 13, int(rng.integers(2, 4))):
            d = pts[j + 1] - pts[j - 1]
            a = math.atan2(d[1], d[0]) + (1 if j % 2 else -1) * rng.uniform(0.6, 1.2)
            leaf_at(pts[j], a, rng.uniform(0.08, 0.16), 0.03)
            if depth == 0 and rng.random() < 0.25:
                grow(pts[j], a, length * rng.uniform(0.3, 0.5), w0 * 0.6, 1)
        d = pts[-1] - pts[-2]
        tip_a = math.atan2(d[1], d[0])
        for k in range(int(rng.integers(3, 7))):  # leaf rosette at the stem tip
            leaf_at(pts[-1], tip_a + rng.normal(0, 1.2), rng.uniform(0.09, 0.2), 0.045)

    for a in az:
        grow(np.zeros(2), a, rng.uniform(0.4, 0.85), rng.uniform(0.03, 0.05), 0)
    for k in range(int(rng.integers(2, 6))):
        leaf_at(np.zeros(2), rng.uniform(0, TAU), rng.uniform(0.06, 0.12), 0.05)
    hub = Blob(blob_poly(rng, np.zeros(2), 0.035, 10, 0.15), jit(rng, stem_c, 0.1), 0.035)
    return stems + [hub] + leaves, {"n_stems": n, "red_rim": round(red_rim, 2), "green": st.green_name}


def build_fathen(rng: np.random.Generator) -> tuple[list[Organ], dict]:
    st = make_style(rng, {"grey": 2, "mid": 2, "blue": 1, "fresh": 1}, 0.04)
    n = int(rng.integers(8, 21))
    ang = golden_angles(rng, n, 0.15)
    lean = unit(rng.uniform(0, TAU)) * rng.uniform(0, 0.08)
    magenta = rng.random() < 0.4
    organs: list[Organ] = []
    for i in range(n):
        frac = i / max(1, n - 1)                     # 0 = lowest, largest leaf
        lb = 0.6 * (1 - 0.72 * frac) * rng.uniform(0.85, 1.15)
        lp = lb * rng.uniform(0.3, 0.6) * (1 - 0.6 * frac)
        z = 0.05 + 0.5 * frac
        attach = lean * frac                         # slightly leaning stem seen from above
        p_pts = arc(attach, ang[i], lp, rng.normal(0, 0.1), n=8)
        c = st.leaf(rng)
        organs.append(Stem(p_pts, 0.022, 0.016, mixc(c, lin(PALE_STEM), 0.5), mixc(c, lin(PALE_STEM), 0.3),
                           heights(8, z * 0.8, z)))
        mid = arc(p_pts[-1], ang[i] + rng.normal(0, 0.1), lb, rng.normal(0, 0.15), n=24)
        ts = np.linspace(0, 1, 40)
        wmax_at = rng.uniform(0.3, 0.42)
        w = np.where(ts < wmax_at, ts / wmax_at, (1 - ts) / (1 - wmax_at)) ** rng.uniform(0.8, 1.0)
        frac_t = (ts * rng.integers(4, 9) + rng.uniform(0, 1)) % 1.0
        w = w * (1 - rng.uniform(0.08, 0.2) * (1 - frac_t) * (ts > 0.3))  # coarse irregular teeth
        hw = lb * rng.uniform(0.3, 0.45)
        young = frac > 0.55
        base = lin((170, 90, 150)) if magenta and young else mixc(c, lin(PALE_STEM), 0.4)
        wf = lambda t, a=wmax_at: np.where(t < a, t / a, (1 - t) / (1 - a))  # noqa: E731
        organs.append(make_leaf(
            mid, ts, w, ts, w * rng.uniform(0.9, 1.05), hw, hts=heights(24, z, z + rng.uniform(-0.08, 0.02)),
            colour=c, base_colour=base, vein_colour=mixc(c, lin((200, 210, 190)), 0.45),
            veins=[midrib_vein(mid, 0.05 * hw, 0.01 * hw, 0.8)] + lateral_veins(mid, wf, hw, 4, 0.15, 0.8, 0.02 * hw, 0.4),
            base_len=0.35 if young else 0.12, fold=rng.uniform(0.4, 0.9) if young else rng.uniform(0.05, 0.3),
            gloss=st.gloss, mealy=rng.uniform(0.4, 0.9) if young else rng.uniform(0.0, 0.15),
            rim=0.2, **damage_kw(rng, st, 0.8)))
    bud = Blob(blob_poly(rng, lean, 0.04, 12, 0.25), mixc(st.green, lin((215, 220, 210)), 0.6), 0.6)
    organs.append(bud)
    return organs, {"n_leaves": n, "magenta": magenta, "lean": round(float(np.linalg.norm(lean)), 3),
                    "green": st.green_name}


def mallow_blade(rng: np.random.Generator, P: np.ndarray, axis: float, rb: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Round-reniform palmately lobed blade around the petiole attachment P (polar outline)."""
    phimax = rng.uniform(2.6, 2.95)
    k_l = int(rng.integers(5, 8))
    ph = rng.uniform(0, TAU)
    cren = rng.uniform(0.015, 0.04)
    n_cren = int(rng.integers(30, 50))

    def r(phi: np.ndarray) -> np.ndarray:
        return rb * (0.9 + 0.1 * np.cos(phi)) * (1 + 0.06 * np.cos(k_l * phi * math.pi / phimax + ph)) \
            * (1 + cren * np.abs(np.sin(n_cren * phi)))

    def half(sign: float) -> np.ndarray:
        phi = np.linspace(0, phimax, 60) * sign
        rr = r(phi)
        pts = P + np.stack([np.cos(axis + phi), np.sin(axis + phi)], 1) * rr[:, None]
        return np.vstack([P, pts])
    left, right = half(1.0), half(-1.0)
    return left, right, np.vstack([left[1:], right[1:]])


def build_mallow(rng: np.random.Generator) -> tuple[list[Organ], dict]:
    st = make_style(rng, {"mid": 3, "dark": 2, "fresh": 1, "blue": 1}, 0.05)
    n = int(rng.integers(4, 13))
    ang = golden_angles(rng, n, 0.3)
    pet_c = lin((160, 180, 120)) if rng.random() < 0.6 else lin((124, 80, 72))
    organs: list[Organ] = []
    n_young = int(rng.integers(1, 4))
    for i in range(n + n_young):
        young = i >= n
        age = 1 - i / n if not young else 0.0
        lp = rng.uniform(0.3, 0.6) * (0.6 + 0.4 * age) if not young else rng.uniform(0.03, 0.08)
        rb = rng.uniform(0.16, 0.3) * (0.6 + 0.4 * age) if not young else rng.uniform(0.04, 0.08)
        hb = rng.uniform(0.05, 0.2) if not young else rng.uniform(0.15, 0.25)
        a_i = ang[i] if not young else rng.uniform(0, TAU)
        pts = arc(unit(a_i) * 0.015, a_i, lp, rng.normal(0, 0.3), n=12)
        organs.append(Stem(pts, 0.02, 0.015, jit(rng, pet_c, 0.1), jit(rng, pet_c, 0.1),
                           0.01 + (hb - 0.01) * np.linspace(0, 1, 12) ** 2))
        d = pts[-1] - pts[-2]
        axis = math.atan2(d[1], d[0]) + rng.normal(0, 0.2)
        P = pts[-1]
        left, right, margin = mallow_blade(rng, P, axis, rb)
        c = st.leaf(rng) if not young else mixc(st.leaf(rng), lin(GREENS["yellow"]), 0.25)
        veins = []
        for phi in np.linspace(-2.3, 2.3, int(rng.integers(5, 8))):
            end = P + unit(axis + phi) * rb * 0.85 * (0.9 + 0.1 * math.cos(phi))
            veins.append((np.linspace(P, end, 6), 0.03 * rb, 0.008 * rb, 0.7))
        mid = np.linspace(P, P + unit(axis) * rb, 12)
        organs.append(Leaf(
            mid=mid, left=left, right=right, margin=margin, hts=np.full(12, hb), half_w=rb, colour=c,
            base_colour=mixc(c, pet_c, 0.3), vein_colour=mixc(c, lin((195, 210, 170)), 0.45), veins=veins,
            base_len=0.08, fold=0.05, gloss=st.gloss, radial=True, pleats=rng.uniform(0.15, 0.35),
            n_pleats=int(rng.integers(5, 8)), cup=rng.uniform(0.1, 0.4) if not young else 0.6,
            hairy=rng.uniform(0, 0.3), rim=0.1, **{**damage_kw(rng, st), "tip_dry": 0.0}))
    return organs, {"n_leaves": n, "green": st.green_name}


BUILDERS: dict[str, Callable[[np.random.Generator], tuple[list[Organ], dict]]] = {
    "dandelion": build_dandelion, "plantain": build_plantain, "grass": build_grass, "clover": build_clover,
    "seedling": build_seedling, "chickweed": build_chickweed, "thistle": build_thistle,
    "purslane": build_purslane, "fathen": build_fathen, "mallow": build_mallow,
}


def build_dead_leaf(rng: np.random.Generator) -> list[Organ]:
    """A fallen brown leaf (tree leaf or dead weed leaf) lying on the soil."""
    length = 1.0
    mid = arc(np.zeros(2), rng.uniform(0, TAU), length, rng.normal(0, 0.3))
    ts, w = simple_margin(rng, 28, rng.uniform(0.5, 0.9), rng.uniform(0.7, 1.1),
                          teeth=rng.uniform(0, 0.15), n_teeth=int(rng.integers(4, 10)))
    hw = rng.uniform(0.2, 0.4)
    c = jit(rng, lin(((120, 84, 50), (100, 72, 46), (140, 106, 66), (84, 66, 50))[int(rng.integers(4))]), 0.12)
    wf = lambda t: profile(t, 0.7, 0.9)  # noqa: E731
    return [make_leaf(mid, ts, w, ts, w * rng.uniform(0.8, 1.1), hw, hts=heights(len(mid), 0.01, 0.03, 0.02),
                      colour=c, base_colour=c * F32(0.8), vein_colour=c * F32(1.25),
                      veins=[midrib_vein(mid, 0.03, 0.006, 0.8)] + lateral_veins(mid, wf, hw, 6, w=0.008, strength=0.5),
                      fold=rng.uniform(0.4, 0.9), gloss=0.02, rim=-0.3, holes=int(rng.integers(0, 4)),
                      spots=0.0, texture=3.0, bump=0.3)]


# ============================================================================ scene layers
@dataclass
class Light:
    kind: str                 # overcast / sun / evening
    elev: float               # sun elevation (rad)
    sdir: np.ndarray          # unit image-plane direction TOWARDS the sun
    sun: np.ndarray           # sun irradiance colour (linear BGR), 0 for overcast
    sky: np.ndarray           # sky (ambient) irradiance colour
    penumbra: float           # shadow edge softness (px at 1000 px images)
    person_shadow: bool

    @property
    def l(self) -> np.ndarray:
        c = math.cos(self.elev)
        return np.array([c * self.sdir[0], c * self.sdir[1], math.sin(self.elev)])

    @property
    def half(self) -> np.ndarray:
        h = self.l + np.array([0.0, 0.0, 1.0])
        return h / np.linalg.norm(h)


@dataclass
class Env:
    """Everything organ drawing needs besides the layers."""
    rng: np.random.Generator
    light: Light
    tiles: dict[str, np.ndarray]
    soil_colour: np.ndarray
    px: float                 # plant unit (radius) in pixels, for sizing details


@dataclass
class Layers:
    alb: np.ndarray           # HxWx3 linear albedo
    top: np.ndarray           # surface height (px) for shadows / occlusion
    bot: np.ndarray           # underside height; very negative for solid ground
    soil_top: np.ndarray      # soil height before plants
    nd: np.ndarray            # direct sun factor n.l
    spec: np.ndarray          # specular factor (x sun)
    pz: np.ndarray            # plant z-buffer (height above soil), -inf where no plant
    plant: np.ndarray         # coverage of the main plant
    soil_base: np.ndarray | None = None   # smoothed soil height that plant heights are measured from


GROUND = -1e4


def composite(L: Layers, gy: np.ndarray, gx: np.ndarray, av: np.ndarray, col: np.ndarray, nd: np.ndarray,
              spec: np.ndarray, h: np.ndarray, thick: float, main: bool) -> None:
    """Z-buffered alpha compositing of organ pixels (a later organ only shows where it is higher)."""
    ok = h >= L.pz[gy, gx] - 0.5
    av = av * ok
    a3 = av[:, None]
    L.alb[gy, gx] = L.alb[gy, gx] * (1 - a3) + col * a3
    L.nd[gy, gx] = L.nd[gy, gx] * (1 - av) + nd * av
    L.spec[gy, gx] = L.spec[gy, gx] * (1 - av) + spec * av
    solid = av > 0.5
    sy, sx = gy[solid], gx[solid]
    L.pz[sy, sx] = h[solid]
    base = L.soil_base if L.soil_base is not None else L.soil_top
    L.top[sy, sx] = np.maximum(base[sy, sx] + h[solid], L.soil_top[sy, sx] + 0.3)
    L.bot[sy, sx] = L.top[sy, sx] - max(thick, 1.0)
    if main:
        L.plant[gy, gx] = np.maximum(L.plant[gy, gx], av)


def shade_normals(nhx: np.ndarray, nhy: np.ndarray, light: Light, gloss: float | np.ndarray,
                  shine: float) -> tuple[np.ndarray, np.ndarray]:
    """Direct-sun factor and specular from a normal given by its horizontal components."""
    # python floats keep float32 arrays float32 (numpy 2 promotes with numpy float64 scalars)
    inv = 1.0 / np.sqrt(nhx * nhx + nhy * nhy + 1.0)
    l0, l1, l2 = (float(v) for v in light.l)
    ndl = np.maximum((nhx * l0 + nhy * l1 + l2) * inv, 0.0).astype(F32, copy=False)
    if np.isscalar(gloss) and gloss == 0:
        return ndl, np.zeros_like(ndl)
    h0, h1, h2 = (float(v) for v in light.half)
    ndh = np.maximum((nhx * h0 + nhy * h1 + h2) * inv, 0.0)
    return ndl, (gloss * ndh ** shine).astype(F32, copy=False)


def bbox(pts: np.ndarray, pad: float, W: int, H: int) -> tuple[int, int, int, int] | None:
    x0 = max(int(math.floor(pts[:, 0].min() - pad)), 0)
    x1 = min(int(math.ceil(pts[:, 0].max() + pad)) + 1, W)
    y0 = max(int(math.floor(pts[:, 1].min() - pad)), 0)
    y1 = min(int(math.ceil(pts[:, 1].max() + pad)) + 1, H)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    return x0, y0, x1, y1


@dataclass
class LeafPixels:
    """Per-pixel coordinates of a leaf's covered pixels in the leaf's own frame."""
    X: np.ndarray             # image x, y of each pixel
    Y: np.ndarray
    side: np.ndarray          # +1 / -1: which half of the blade
    t: np.ndarray             # 0 at the base .. 1 at the tip (radial distance for palmate blades)
    s: np.ndarray             # signed distance from the midrib axis (px)
    tx: np.ndarray            # unit tangent of the midrib
    ty: np.ndarray
    rx: np.ndarray | None = None   # palmate only: unit radial direction and angle from the axis
    ry: np.ndarray | None = None
    phi: np.ndarray | None = None


def leaf_pixels(lf: Leaf, X: np.ndarray, Y: np.ndarray, side: np.ndarray) -> LeafPixels:
    b = lf.mid[0]
    ax = lf.mid[-1] - b
    alen = float(np.hypot(*ax)) + 1e-9
    ux, uy = (float(v) for v in ax / alen)
    dx, dy = X - F32(b[0]), Y - F32(b[1])
    if lf.radial:
        r = np.hypot(dx, dy)
        phi = np.arctan2(ux * dy - uy * dx, ux * dx + uy * dy)
        return LeafPixels(X, Y, side, np.clip(r / alen, 0, 1.2), r * np.sin(phi), np.full_like(X, ux),
                          np.full_like(X, uy), dx / (r + 1e-6), dy / (r + 1e-6), phi)
    if lf.narrow:   # long curved blade: t from the nearest midrib vertex
        m = lf.mid
        d2 = (X[:, None] - m[None, :, 0]) ** 2 + (Y[:, None] - m[None, :, 1]) ** 2
        j = np.argmin(d2, axis=1)
        vt = np.gradient(m, axis=0)
        vt /= np.hypot(vt[:, 0], vt[:, 1])[:, None] + 1e-9
        return LeafPixels(X, Y, side, (j / (len(m) - 1)).astype(F32), np.zeros_like(X),
                          vt[j, 0].astype(F32), vt[j, 1].astype(F32))
    return LeafPixels(X, Y, side, np.clip((dx * ux + dy * uy) / alen, 0, 1), dx * -uy + dy * ux,
                      np.full_like(X, ux), np.full_like(X, uy))


def leaf_surface(lf: Leaf, px: LeafPixels, llen: float, env: Env,
                 offs: tuple[tuple[int, int], tuple[int, int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Height, direct-sun factor and specular of the blade: pitch along the leaf, V-fold across
    it, cupping and pleats (palmate), wavy margins (thistle) and gentle random bumps."""
    u_mid = np.linspace(0, 1, len(lf.hts))
    hh = np.interp(px.t, u_mid, lf.hts).astype(F32)
    pitch = np.interp(px.t, u_mid, np.gradient(lf.hts, u_mid) / llen).astype(F32)
    nx_, ny_ = -px.ty, px.tx          # left normal, matches polyline_frame's convention
    tf = math.tan(lf.fold)
    nhx = -pitch * px.tx - px.side * tf * nx_
    nhy = -pitch * px.ty - px.side * tf * ny_
    if lf.radial:
        nhx -= 2 * lf.cup * px.t * px.rx
        nhy -= 2 * lf.cup * px.t * px.ry
        hh = hh + F32(lf.cup * lf.half_w * 0.3) * px.t * px.t
        if lf.n_pleats:
            pl = lf.pleats * np.sin(lf.n_pleats * px.phi * 2.2) * np.minimum(px.t * 3, 1)
            nhx += pl * -px.ry
            nhy += pl * px.rx
    if lf.wave:
        wv = lf.wave * np.sin(TAU * lf.n_waves * px.t + px.side * 1.3)
        nhx += wv * px.tx
        nhy += wv * px.ty
    kb = float(np.clip(5.0 / (0.12 * llen + 1e-6), 0.02, 2.0))  # a few gentle bumps per leaf
    nhx += lf.bump * tile_at(env.tiles["mid"], px.X, px.Y, kb, offs[0])
    nhy += lf.bump * tile_at(env.tiles["mid"], px.X, px.Y, kb, offs[1])
    nd, spec = shade_normals(nhx, nhy, env.light, lf.gloss, lf.shine)
    return hh, nd, spec


def leaf_albedo(lf: Leaf, px: LeafPixels, a: np.ndarray, ys: np.ndarray, xs: np.ndarray, off: np.ndarray,
                llen: float, env: Env, offs: tuple[tuple[int, int], tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """Leaf colour: texture, pale/purple base, lighter veins, translucent or red rim, chlorotic
    spots, dry tips, clover chevron, mealy bloom, hairs. Also returns a dryness mask (dry
    tissue is matte and curls, so it is shaded a little darker)."""
    rng = env.rng
    t = px.t
    fine = tile_at(env.tiles["fine"], px.X, px.Y, 1.0, offs[0])
    midn = tile_at(env.tiles["mid"], px.X, px.Y, 1.0, offs[1])
    coarse = tile_at(env.tiles["coarse"], px.X, px.Y, float(np.clip(64.0 / llen, 0.05, 4.0)), offs[0])
    col = lf.colour[None, :] * (1 + lf.texture * (0.06 * midn + 0.035 * fine))[:, None]
    dry_m = np.zeros_like(t)
    if lf.base_len > 0:
        gb = np.clip(1 - t / lf.base_len, 0, 1) ** 1.3
        col = mixc(col, lf.base_colour[None, :], gb[:, None])
    if lf.veins:
        h, w = a.shape
        vm = vein_mask(lf.veins, off, h, w)[ys, xs]
        col = mixc(col, lf.vein_colour[None, :], vm[:, None])
    if lf.rim:
        sig = max(0.8, 0.012 * llen)
        rim = np.clip((a - cv2.GaussianBlur(a, (0, 0), sig))[ys, xs] * 2.5, 0, 1)
        tint = col * F32(1.2) + lin((30, 36, 8))[None, :] if lf.rim > 0 else col * F32(0.6)
        col = mixc(col, tint, (abs(lf.rim) * rim)[:, None])
        if lf.red_rim:
            red = np.clip((a - cv2.GaussianBlur(a, (0, 0), 2.5 * sig))[ys, xs] * 2.0, 0, 1)
            col = mixc(col, lin((150, 50, 45))[None, :], (lf.red_rim * red)[:, None])
    if lf.spots:
        m = np.clip((coarse - 0.8) * 1.5, 0, 1) * lf.spots
        col = mixc(col, lin((160, 156, 64))[None, :], m[:, None])
    if lf.tip_dry:
        dry_m = smoothstep(lf.tip_dry, lf.tip_dry + 0.1, t + 0.05 * coarse)
        dry = lin((150, 118, 66)) if rng.random() < 0.6 else lin((176, 160, 100))
        col = mixc(col, dry[None, :], dry_m[:, None])
    if lf.chevron:
        sn = np.abs(px.s) / (lf.half_w + 1e-6)
        band = np.exp(-(((t - (0.3 + 0.3 * sn)) / 0.08) ** 2)) * (sn < 0.9) * lf.chevron
        col = mixc(col, lin((176, 196, 160))[None, :], band[:, None])
    if lf.mealy:
        m = lf.mealy * np.clip(0.55 + 0.6 * fine, 0, 1) * (1 - 0.4 * t)
        col = mixc(col, lin((196, 204, 194))[None, :], m[:, None] * 0.5)
    if lf.hairy:
        col = mixc(col, lin((200, 204, 196))[None, :], (lf.hairy * (0.12 + 0.2 * (fine > 1.2)))[:, None])
    return col + F32(0.03 * lf.gloss), dry_m     # + sky sheen on waxy cuticles


def draw_leaf(L: Layers, lf: Leaf, env: Env, main: bool) -> None:
    H, W = L.top.shape
    bb = bbox(np.vstack([lf.left, lf.right]), 3, W, H)
    if bb is None:
        return
    x0, y0, x1, y1 = bb
    h, w = y1 - y0, x1 - x0
    off = np.array([x0, y0], float)
    rng = env.rng
    ml = fill_mask(lf.left - off, h, w)     # the two halves share the midrib edge, so their
    mr = fill_mask(lf.right - off, h, w)    # anti-aliased coverages add up to 1 there
    a = np.minimum(ml + mr, 1.0)
    llen = max(arc_length(lf.mid), 1.0)
    hole_ring = None
    if lf.holes or lf.chew:
        a, hole_ring = leaf_damage(rng, a, lf, off, llen)
    ys, xs = np.nonzero(a > 0.01)
    if ys.size == 0:
        return
    side = np.where(ml[ys, xs] >= mr[ys, xs], F32(1), F32(-1))
    px = leaf_pixels(lf, (xs + x0).astype(F32), (ys + y0).astype(F32), side)
    offs = (tuple(int(v) for v in rng.integers(0, TILE, 2)), tuple(int(v) for v in rng.integers(0, TILE, 2)))
    hh, nd, spec = leaf_surface(lf, px, llen, env, offs)
    col, dry_m = leaf_albedo(lf, px, a, ys, xs, off, llen, env, offs)
    nd = nd * (1 - 0.2 * dry_m)
    if lf.splash:   # soil specks: matte, lit like the ground
        sp = splash_mask(rng, a, px.t, ys, xs, lf, llen)
        col = mixc(col, env.soil_colour[None, :] * F32(0.85), sp[:, None])
        spec = spec * (1 - sp)
        nd = mixc(nd, F32(env.light.l[2]), sp)
    if hole_ring is not None:
        col = mixc(col, lin((120, 90, 50))[None, :], hole_ring[ys, xs][:, None])
    composite(L, ys + y0, xs + x0, a[ys, xs], col.astype(F32), nd.astype(F32), spec.astype(F32), hh,
              lf.thick, main)


def leaf_damage(rng: np.random.Generator, a: np.ndarray, lf: Leaf, off: np.ndarray,
                llen: float) -> tuple[np.ndarray, np.ndarray]:
    """Insect holes inside the blade and chewed bites out of the margin, with brown rims."""
    h, w = a.shape
    hole = np.zeros((h, w), np.uint8)
    ys, xs = np.nonzero(a > 0.9)
    for _ in range(lf.holes if len(ys) else 0):
        k = int(rng.integers(len(ys)))
        r = max(1.0, rng.uniform(0.015, 0.06) * llen)
        cv2.ellipse(hole, (int(xs[k] * 16), int(ys[k] * 16)), (int(r * 16), int(r * rng.uniform(0.5, 1) * 16)),
                    rng.uniform(0, 180), 0, 360, 255, -1, cv2.LINE_AA, 4)
    for _ in range(lf.chew):
        p = lf.margin[int(rng.integers(len(lf.margin)))] - off
        r = max(1.5, rng.uniform(0.05, 0.15) * llen * 0.5)
        cv2.circle(hole, (int(p[0] * 16), int(p[1] * 16)), int(r * 16), 255, -1, cv2.LINE_AA, 4)
    hf = hole.astype(F32) / 255
    ring = np.clip(cv2.GaussianBlur(hf, (0, 0), 1.2) * 1.8 - hf, 0, 1) * 0.7
    return a * (1 - hf), ring


def splash_mask(rng: np.random.Generator, a: np.ndarray, t: np.ndarray, ys: np.ndarray, xs: np.ndarray,
                lf: Leaf, llen: float) -> np.ndarray:
    """Specks of soil splashed by rain, mostly on the lower half of the blade."""
    h, w = a.shape
    m = np.zeros((h, w), np.uint8)
    low = np.nonzero(t < 0.55)[0]
    n = int(lf.splash * 25 * (llen / 100) ** 0.5)
    if len(low) == 0 or n == 0:
        return np.zeros(len(ys), F32)
    for _ in range(n):
        k = low[int(rng.integers(len(low)))]
        r = max(0.6, rng.uniform(0.004, 0.02) * llen)
        cv2.circle(m, (int(xs[k] * 16), int(ys[k] * 16)), int(r * 16), 255, -1, cv2.LINE_AA, 4)
    return (m[ys, xs].astype(F32) / 255) * 0.9


def vein_mask(veins: list, off: np.ndarray, h: int, w: int) -> np.ndarray:
    """Anti-aliased tapered vein lines, weighted by strength (thin veins drawn faint)."""
    m = np.zeros((h, w), np.uint8)
    for pts, w0, w1, strength in veins:
        p = np.round((pts - off) * 16).astype(np.int32)
        n = len(p)
        for i in range(n - 1):
            wi = w0 + (w1 - w0) * i / max(1, n - 2)
            th = max(1, int(round(wi)))
            val = int(255 * strength * min(1.0, max(wi, 0.35)))
            if val < 8:
                continue
            cv2.line(m, tuple(p[i]), tuple(p[i + 1]), val, th, cv2.LINE_AA, 4)
    return m.astype(F32) / 255


def draw_stem(L: Layers, st: Stem, env: Env, main: bool) -> None:
    H, W = L.top.shape
    wmax = max(st.w0, st.w1)
    bb = bbox(st.pts, wmax + 3, W, H)
    if bb is None:
        return
    x0, y0, x1, y1 = bb
    h, w = y1 - y0, x1 - x0
    off = np.array([x0, y0], float)
    m = np.zeros((h, w), np.uint8)
    tm = np.zeros((h, w), F32)
    n = len(st.pts)
    p16 = np.round((st.pts - off) * 16).astype(np.int32)
    pi = np.round(st.pts - off).astype(np.int32)
    for i in range(n - 1):
        wi = st.w0 + (st.w1 - st.w0) * i / max(1, n - 2)
        th = max(1, int(round(wi)))
        cv2.line(m, tuple(p16[i]), tuple(p16[i + 1]), 255, th, cv2.LINE_AA, 4)
        cv2.line(tm, tuple(pi[i]), tuple(pi[i + 1]), float(i / (n - 1)), th + 2)
    fade = min(1.0, max(min(st.w0, st.w1), 0.4))  # sub-pixel stems show up faint
    a = m.astype(F32) / 255 * F32(fade)
    ys, xs = np.nonzero(a > 0.01)
    if ys.size == 0:
        return
    t = tm[ys, xs]
    X, Y = xs + x0, ys + y0
    col = mixc(st.c0[None, :], st.c1[None, :], t[:, None])
    col = col * (1 + 0.05 * tile_at(env.tiles["fine"], X, Y))[:, None]
    if wmax >= 3:   # round cross-section: normals from the distance-to-edge gradient
        d = cv2.distanceTransform((m > 127).astype(np.uint8), cv2.DIST_L2, 3)
        gx = cv2.Sobel(d, cv2.CV_32F, 1, 0, ksize=3) / 8
        gy = cv2.Sobel(d, cv2.CV_32F, 0, 1, ksize=3) / 8
        r = max(wmax / 2, 1.0)
        k = np.sqrt(np.clip(1 - (d[ys, xs] / r), 0, 1)) * 1.5
        g = np.hypot(gx[ys, xs], gy[ys, xs]) + 1e-6
        nhx, nhy = -gx[ys, xs] / g * k, -gy[ys, xs] / g * k
    else:
        nhx = np.zeros(len(ys), F32)
        nhy = np.zeros(len(ys), F32)
    nd, spec = shade_normals(nhx, nhy, env.light, st.gloss, st.shine)
    hh = np.interp(t, np.linspace(0, 1, len(st.hts)), st.hts).astype(F32)
    composite(L, ys + y0, xs + x0, a[ys, xs], col.astype(F32), nd * F32(0.92), spec, hh, max(wmax, 1.0), main)


def draw_blob(L: Layers, bl: Blob, env: Env, main: bool) -> None:
    H, W = L.top.shape
    bb = bbox(bl.poly, 3, W, H)
    if bb is None:
        return
    x0, y0, x1, y1 = bb
    off = np.array([x0, y0], float)
    a = fill_mask(bl.poly - off, y1 - y0, x1 - x0)
    ys, xs = np.nonzero(a > 0.01)
    if ys.size == 0:
        return
    X, Y = xs + x0, ys + y0
    k = float(np.clip(12.0 / (np.ptp(bl.poly[:, 0]) + 1e-6), 0.1, 1.0))   # ~6 grains across
    col = bl.colour[None, :] * (1 + bl.texture * tile_at(env.tiles["fine"], X, Y, k))[:, None]
    c = bl.poly.mean(0)
    rmax = np.hypot(*(bl.poly - c).T).max() + 1e-6
    if bl.centre_colour is not None and bl.centre_frac > 0:
        r = np.hypot(X - c[0], Y - c[1]) / rmax
        col = mixc(col, bl.centre_colour[None, :], (r < bl.centre_frac)[:, None].astype(F32))
    n = len(ys)
    nhx = ((X - c[0]) / rmax * bl.dome).astype(F32)
    nhy = ((Y - c[1]) / rmax * bl.dome).astype(F32)
    nd, spec = shade_normals(nhx, nhy, env.light, 0.0, 1.0)
    composite(L, Y, X, a[ys, xs], col.astype(F32), nd, spec, np.full(n, bl.h, F32), 2.0, main)


def draw_organ(L: Layers, o: Organ, env: Env, main: bool) -> None:
    if isinstance(o, Leaf):
        draw_leaf(L, o, env, main)
    elif isinstance(o, Stem):
        draw_stem(L, o, env, main)
    else:
        draw_blob(L, o, env, main)


def place(organs: list[Organ], size_px: float, crown: np.ndarray, rot: float, mirror: bool) -> list[Organ]:
    """Scale (plant units -> px so the enclosing circle has diameter size_px), rotate, mirror, move."""
    d0 = plant_diameter(organs)
    s = size_px / d0
    c, si = math.cos(rot), math.sin(rot)
    R = np.array([[c, -si], [si, c]]) * s
    if mirror:
        R = R @ np.diag([-1.0, 1.0])
    A = np.hstack([R, np.asarray(crown, float)[:, None]])
    return [transform_organ(o, A, s) for o in organs]


def plant_diameter(organs: list[Organ]) -> float:
    pts = np.vstack([organ_points(o) for o in organs]).astype(np.float32)
    _, r = cv2.minEnclosingCircle(pts)
    return 2.0 * float(r)


def extent(organs: list[Organ]) -> tuple[np.ndarray, np.ndarray]:
    pts = np.vstack([organ_points(o) for o in organs])
    return pts.min(0), pts.max(0)


# ============================================================================ soil
SOILS: dict[str, dict] = {
    # base/alt: two albedos mixed in patches; grain: per-grain albedo scatter;
    # relief: surface roughness amplitude (cm); p_*: chance of clods/stones/cracks/straw/litter
    "sandy": dict(base=(178, 158, 126), alt=(150, 128, 100), grain=0.16, relief=0.12, p_crumbs=0.2, p_clods=0.2,
                  p_stones=0.6, p_cracks=0.0, p_straw=0.1, p_litter=0.5),
    "loam": dict(base=(92, 74, 58), alt=(64, 52, 42), grain=0.14, relief=0.3, p_crumbs=0.8, p_clods=0.6,
                 p_stones=0.4, p_cracks=0.0, p_straw=0.15, p_litter=0.6),
    "clay": dict(base=(156, 98, 68), alt=(126, 78, 56), grain=0.1, relief=0.25, p_crumbs=0.4, p_clods=0.6,
                 p_stones=0.3, p_cracks=0.35, p_straw=0.1, p_litter=0.4),
    "gravel": dict(base=(132, 126, 116), alt=(104, 98, 90), grain=0.2, relief=0.15, p_crumbs=0.2, p_clods=0.1,
                   p_stones=1.0, p_cracks=0.0, p_straw=0.05, p_litter=0.4),
    "crust": dict(base=(172, 154, 130), alt=(148, 130, 108), grain=0.08, relief=0.08, p_crumbs=0.0, p_clods=0.0,
                  p_stones=0.3, p_cracks=1.0, p_straw=0.05, p_litter=0.4),
    "mulch": dict(base=(96, 78, 60), alt=(72, 58, 46), grain=0.14, relief=0.25, p_crumbs=0.6, p_clods=0.3,
                  p_stones=0.2, p_cracks=0.0, p_straw=1.0, p_litter=0.8),
}


def make_soil(rng: np.random.Generator, H: int, W: int, ppc: float, notes: dict,
              tiles: dict[str, np.ndarray]) -> Layers:
    """Soil albedo and height field with texture at several scales, then objects on it.

    Smooth components (patches, mottling, relief, crumbs, clods) are made at a working
    resolution of ~640 px and upsampled; per-pixel grain is added at full resolution."""
    soil = str(rng.choice(list(SOILS), p=[0.2, 0.22, 0.16, 0.14, 0.13, 0.15]))
    pal = SOILS[soil]
    moist = float(rng.uniform(0.65, 1.1)) if soil not in ("crust", "sandy") else float(rng.uniform(0.85, 1.15))
    base = jit(rng, lin(pal["base"]), 0.12, 0.04) * F32(moist)
    alt = jit(rng, lin(pal["alt"]), 0.12, 0.04) * F32(moist)
    alt = base + (alt - base) * F32(rng.uniform(0.3, 1.0))
    notes["soil"] = soil
    extras: list[str] = []

    g = min(1.0, 640.0 / min(H, W))
    hw, ww = max(8, round(H * g)), max(8, round(W * g))
    pw = ppc * g                                              # px per cm at working resolution
    patch = fbm(rng, hw, ww, 6.0 * pw, 2)                     # moisture / organic-matter patches
    mix_t = 1 / (1 + np.exp(-1.0 * patch))
    alb = base[None, None, :] + (alt - base)[None, None, :] * mix_t[..., None]
    tex = 0.07 * fbm(rng, hw, ww, 1.0 * pw, 2)
    top = F32(pal["relief"] * pw) * fbm(rng, hw, ww, 2.0 * pw, 3)
    gcell = 0.06 * ppc                                        # sand grain / micro-aggregate size, full-res px
    alb *= (1 + tex)[..., None]
    if gcell >= 2.5:                                          # grains resolved (macro shots): discrete bumps
        add_aggregates(rng, alb, top, pw, rng.uniform(0.05, 0.1), 1.5 * pal["grain"], 0.25)
    if rng.random() < pal["p_crumbs"] and add_aggregates(rng, alb, top, pw, rng.uniform(0.25, 0.7), 0.12):
        extras.append("crumbs")
    if rng.random() < pal["p_clods"] and add_aggregates(rng, alb, top, pw, rng.uniform(1.2, 3.5), 0.1):
        extras.append("clods")
    if rng.random() < 0.1 and soil in ("loam", "clay", "crust", "mulch"):
        add_algae(rng, alb, pw)
        extras.append("algae")
    band = None
    if g < 1.0:
        alb = cv2.resize(alb, (W, H), interpolation=cv2.INTER_LINEAR)
        top = cv2.resize(top, (W, H), interpolation=cv2.INTER_CUBIC) * F32(1 / g)
        band = noise(rng, H, W, max(1.5, 0.6 / g))            # detail lost by the working resolution
        top += F32(0.5) * band
    # per-pixel grain plus rare light (quartz) and dark (organic) specks
    u = rng.random((H, W), dtype=F32)
    amp = pal["grain"] if gcell < 2.5 else 0.3 * pal["grain"]
    mult = 1 + F32(amp * 3.46) * (u - 0.5) + 0.5 * (u > 0.993) - 0.35 * (u < 0.006)
    if band is not None:
        mult += F32(0.5 * pal["grain"]) * band
    alb *= merge3([mult, mult, mult])
    top += F32(0.3) * (u - 0.5)
    L = Layers(alb=alb.astype(F32, copy=False), top=top.astype(F32, copy=False),
               bot=np.full((H, W), GROUND, F32), soil_top=top, nd=np.zeros((H, W), F32),
               spec=np.zeros((H, W), F32), pz=np.full((H, W), -np.inf, F32), plant=np.zeros((H, W), F32))

    if rng.random() < pal["p_cracks"]:
        add_cracks(rng, L, ppc)
        extras.append("cracks")
    if rng.random() < pal["p_stones"]:
        n = add_stones(rng, L, ppc, tiles, many=(soil == "gravel"))
        extras.append(f"stones{n}")
    if rng.random() < pal["p_litter"]:
        add_litter(rng, L, ppc, tiles)
        extras.append("litter")
    if rng.random() < pal["p_straw"]:
        n = add_straw(rng, L, ppc, tiles, many=(soil == "mulch"))
        extras.append(f"straw{n}")
    L.soil_top = L.top.copy()
    notes["soil_extras"] = extras
    return L


def add_aggregates(rng: np.random.Generator, alb: np.ndarray, top: np.ndarray, ppc: float, cell_cm: float,
                   shade_var: float, height_k: float = 0.3) -> bool:
    """Soil aggregates (mm-size crumbs or cm-size clods): irregular domes around random seeds,
    each with its own shade; once lit, the gaps between them become dark crevices."""
    H, W = top.shape
    cell = cell_cm * ppc
    if cell < 3.0:
        return False
    f = min(1.0, 10.0 / cell)
    h, w = max(8, int(H * f)), max(8, int(W * f))
    img = np.full((h, w), 255, np.uint8)
    n = int(h * w / 100 * rng.uniform(0.6, 1.0))
    img[rng.integers(0, h, n), rng.integers(0, w, n)] = 0
    d, lab = cv2.distanceTransformWithLabels(img, cv2.DIST_L2, 3, labelType=cv2.DIST_LABEL_PIXEL)
    nlab = int(lab.max()) + 1
    rad = (10 * 0.6 * np.exp(rng.normal(0, 0.35, nlab))).astype(F32)   # mixed sizes
    shade = rng.normal(0, shade_var, nlab).astype(F32)
    r = rad[lab] * (1 + 0.25 * noise(rng, h, w, 4))
    dome = np.clip(1 - (d / np.maximum(r, 1)) ** 2, 0, 1).astype(F32)
    dome = cv2.GaussianBlur(dome, (0, 0), 0.8)          # no kinks: upsampling must not ring
    # each aggregate gets its own shade; the gaps between aggregates are a little darker
    mult = 1 + shade[lab] * dome + 0.12 * (dome - 0.5)
    if f < 1.0:
        dome = cv2.resize(dome, (W, H), interpolation=cv2.INTER_CUBIC)
        mult = cv2.resize(mult, (W, H), interpolation=cv2.INTER_LINEAR)
    top += dome * F32(rng.uniform(0.4, 1.0) * cell * height_k)
    alb *= mult[..., None]
    return True


def add_cracks(rng: np.random.Generator, L: Layers, ppc: float) -> None:
    """Dry crust cracked into polygons (Voronoi cells, edges warped by a smooth noise field)."""
    H, W = L.top.shape
    cell = rng.uniform(3, 10) * ppc
    m = np.zeros((H, W), np.uint8)
    for level, (cs, wmul) in enumerate(((cell, 1.0), (cell * 0.45, 0.5))):
        if level == 1 and rng.random() < 0.7:
            break
        margin = cs
        rect = (int(-margin), int(-margin), int(W + 2 * margin), int(H + 2 * margin))
        sub = cv2.Subdiv2D(rect)
        n = max(4, int((W + 2 * margin) * (H + 2 * margin) / cs ** 2))
        pts = np.stack([rng.uniform(-margin + 1, W + margin - 1, n), rng.uniform(-margin + 1, H + margin - 1, n)], 1)
        for p in pts:
            sub.insert((float(p[0]), float(p[1])))
        facets, _ = sub.getVoronoiFacetList([])
        th = max(1, int(round(rng.uniform(0.05, 0.2) * ppc * wmul)))
        polys = [np.round(np.clip(f, -1e5, 1e5) * 4).astype(np.int32) for f in facets]
        cv2.polylines(m, polys, True, 255, th, cv2.LINE_AA, 2)
    amp = cell * 0.035
    k = min(1.0, 8.0 / (cell * 0.3))              # the warp field is smooth: make it small, upsample
    hs, ws = max(4, int(H * k)), max(4, int(W * k))
    wx = cv2.resize(noise(rng, hs, ws, cell * 0.3 * k), (W, H), interpolation=cv2.INTER_LINEAR)
    wy = cv2.resize(noise(rng, hs, ws, cell * 0.3 * k), (W, H), interpolation=cv2.INTER_LINEAR)
    mapx = np.arange(W, dtype=F32)[None, :] + F32(amp) * wx
    mapy = np.arange(H, dtype=F32)[:, None] + F32(amp) * wy
    mw = cv2.remap(m, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT).astype(F32) / 255
    mw *= np.clip(0.75 + 0.35 * cv2.resize(noise(rng, hs, ws, 3.0), (W, H)), 0.3, 1.0)   # uneven width/depth
    L.alb *= (1 - 0.7 * mw)[..., None]
    L.top -= mw * F32(0.3 * ppc)
    edge = cv2.GaussianBlur(mw, (0, 0), max(1.0, 0.3 * ppc))
    L.top += edge * F32(0.15 * ppc)   # plate edges curl up a little


STONE_COLOURS = [(150, 146, 138), (182, 176, 166), (120, 112, 104), (168, 150, 126), (96, 92, 90),
                 (200, 194, 184), (150, 120, 100), (130, 134, 136)]


def tile_patch(tiles: dict[str, np.ndarray], name: str, rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A random h x w window of a periodic noise tile (cheap texture for small objects)."""
    oy, ox = (int(v) for v in rng.integers(0, TILE, 2))
    return tiles[name][np.ix_((np.arange(h) + oy) & (TILE - 1), (np.arange(w) + ox) & (TILE - 1))]


def add_stones(rng: np.random.Generator, L: Layers, ppc: float, tiles: dict[str, np.ndarray], many: bool) -> int:
    """Pebbles and small stones: rounded polygons, mottled, a bit of soil stuck round the base."""
    H, W = L.top.shape
    area_cm2 = H * W / ppc ** 2
    n = int(area_cm2 * (rng.uniform(0.08, 0.3) if many else rng.uniform(0.005, 0.04)))
    n = int(min(n, 300 if many else 60))
    drawn = 0
    for _ in range(n):
        size_cm = float(np.clip(math.exp(rng.normal(math.log(0.7 if many else 1.0), 0.6)), 0.2, 5.0))
        r = size_cm * ppc / 2
        if r < 1.5:
            continue
        c = np.array([rng.uniform(0, W), rng.uniform(0, H)])
        poly = blob_poly(rng, c, r, int(rng.integers(9, 16)), 0.08, elong=rng.uniform(1.0, 1.6))
        bb = bbox(poly, 2, W, H)
        if bb is None:
            continue
        x0, y0, x1, y1 = bb
        h, w = y1 - y0, x1 - x0
        a = fill_mask(poly - np.array([x0, y0]), h, w)
        d = cv2.distanceTransform((a > 0.5).astype(np.uint8), cv2.DIST_L2, 3)
        dmax = max(float(d.max()), 1.0)
        dome = np.sqrt(np.clip(1 - (1 - d / dmax) ** 2, 0, 1)) * F32(r * rng.uniform(0.3, 0.6))
        col = jit(rng, lin(STONE_COLOURS[int(rng.integers(len(STONE_COLOURS)))]), 0.1, 0.03)
        g1 = tile_patch(tiles, "mid" if r < 25 else "coarse", rng, h, w)
        g2 = tile_patch(tiles, "fine", rng, h, w)
        stone = col[None, None, :] * (1 + 0.1 * g1 + 0.05 * g2)[..., None]
        if rng.random() < 0.15:  # speckled granite-like stone
            stone *= (1 + 0.35 * (g2 > 1.8) - 0.3 * (g2 < -1.8))[..., None]
        sl = (slice(y0, y1), slice(x0, x1))
        dirt = (1 - np.clip(d / (0.4 * dmax), 0, 1)) * F32(rng.uniform(0.2, 0.8))
        stone = stone + (L.alb[sl] - stone) * dirt[..., None]
        a3 = a[..., None]
        L.alb[sl] = L.alb[sl] * (1 - a3) + stone * a3
        L.top[sl] = np.where(a > 0.5, L.top[sl] + dome, L.top[sl])
        drawn += 1
    return drawn


def add_litter(rng: np.random.Generator, L: Layers, ppc: float, tiles: dict[str, np.ndarray]) -> None:
    """Fine dead plant litter: weathered leaf fragments (partly buried, soil-tinted) and twigs."""
    H, W = L.top.shape
    area_cm2 = H * W / ppc ** 2
    n = int(min(area_cm2 * rng.uniform(0.01, 0.08), 150))
    cols = [(84, 66, 50), (104, 90, 74), (120, 100, 76), (70, 58, 48), (140, 122, 96)]
    for _ in range(n):
        c = np.array([rng.uniform(0, W), rng.uniform(0, H)])
        col = jit(rng, lin(cols[int(rng.integers(len(cols)))]), 0.12)
        if rng.random() < 0.3:   # twig
            pts = arc(c, rng.uniform(0, TAU), rng.uniform(1, 6) * ppc, rng.normal(0, 0.4), n=6)
            th = max(1, int(round(rng.uniform(0.08, 0.25) * ppc)))
            bb = bbox(pts, th + 2, W, H)
            if bb is None:
                continue
            x0, y0, x1, y1 = bb
            m = np.zeros((y1 - y0, x1 - x0), np.uint8)
            cv2.polylines(m, [np.round((pts - [x0, y0]) * 4).astype(np.int32)], False, 255, th, cv2.LINE_AA, 2)
            a = m.astype(F32) / 255
            hgt = th * 0.5
        else:
            r = min(rng.uniform(0.1, 0.6) * ppc, rng.uniform(0.005, 0.025) * min(H, W))
            if r < 1:
                continue
            poly = blob_poly(rng, c, r, int(rng.integers(5, 10)), 0.3, elong=rng.uniform(1, 2.5))
            bb = bbox(poly, 2, W, H)
            if bb is None:
                continue
            x0, y0, x1, y1 = bb
            a = fill_mask(poly - np.array([x0, y0]), y1 - y0, x1 - x0)
            # partly buried / crumbled: patchy coverage
            a *= np.clip(0.7 + 0.6 * tile_patch(tiles, "mid", rng, y1 - y0, x1 - x0), 0, 1) * F32(rng.uniform(0.5, 1.0))
            hgt = 0.05 * ppc
        h, w = a.shape
        sl = (slice(y0, y1), slice(x0, x1))
        lc = col[None, None, :] * (1 + 0.15 * tile_patch(tiles, "fine", rng, h, w))[..., None]
        lc = lc + (L.alb[sl] - lc) * F32(rng.uniform(0.0, 0.5))     # weathered towards soil colour
        L.alb[sl] = L.alb[sl] * (1 - a[..., None]) + lc * a[..., None]
        L.top[sl] += a * F32(hgt)


def add_straw(rng: np.random.Generator, L: Layers, ppc: float, tiles: dict[str, np.ndarray], many: bool) -> int:
    """Straw / mulch residue: shiny pale hollow stalks lying on the soil, some broken or weathered."""
    H, W = L.top.shape
    area_cm2 = H * W / ppc ** 2
    n = int(area_cm2 * rng.uniform(0.01, 0.05)) if many else int(rng.integers(1, 6))
    n = int(min(max(n, 1), 120))
    for _ in range(n):
        length = math.exp(rng.uniform(math.log(1.0), math.log(15))) * ppc   # many short broken bits
        width = max(1.5, rng.uniform(0.12, 0.5) * ppc)
        c = np.array([rng.uniform(0, W), rng.uniform(0, H)])
        pts = arc(c, rng.uniform(0, TAU), length, rng.normal(0, 0.15), n=5)
        if rng.random() < 0.2:   # kinked straw
            k = int(rng.integers(1, 4))
            pts = np.vstack([pts[:k + 1], arc(pts[k], rng.uniform(0, TAU), length * 0.4, 0.0, n=3)[1:]])
        bb = bbox(pts, width + 3, W, H)
        if bb is None:
            continue
        x0, y0, x1, y1 = bb
        m = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.polylines(m, [np.round((pts - [x0, y0]) * 4).astype(np.int32)], False, 255, int(round(width)),
                      cv2.LINE_AA, 2)
        d = cv2.distanceTransform((m > 127).astype(np.uint8), cv2.DIST_L2, 3)
        r = width / 2
        prof = np.sqrt(np.clip(1 - (1 - np.minimum(d / r, 1)) ** 2, 0, 1)).astype(F32)
        col = jit(rng, lin([(204, 182, 130), (184, 166, 124), (156, 146, 126), (140, 116, 80),
                            (120, 108, 92)][int(rng.integers(5))]), 0.12)
        a = m.astype(F32) / 255
        g = tile_patch(tiles, "coarse", rng, y1 - y0, x1 - x0)
        sc = col[None, None, :] * (0.8 + 0.2 * prof + 0.08 * g)[..., None]
        sl = (slice(y0, y1), slice(x0, x1))
        L.alb[sl] = L.alb[sl] * (1 - a[..., None]) + sc * a[..., None]
        L.top[sl] = np.maximum(L.top[sl], L.top[sl] * (1 - a) + (L.top[sl] + prof * F32(r)) * a)
    return n


def add_algae(rng: np.random.Generator, alb: np.ndarray, ppc: float) -> None:
    """Dark greenish algae film on moist soil: a faint green cast over an irregular area."""
    H, W = alb.shape[:2]
    m = np.clip(fbm(rng, H, W, rng.uniform(4, 10) * ppc, 2) * 0.8 - rng.uniform(0.0, 0.6), 0, 1)
    tint = lin((70, 84, 52))
    alb *= (1 - 0.45 * m[..., None])
    alb += tint * F32(0.45) * m[..., None]


def add_moss(rng: np.random.Generator, L: Layers, env: Env, ppc: float, centre: np.ndarray, radius: float) -> None:
    """A moss cushion: granular olive-green patch with soft ragged edge (green, but no leaves)."""
    H, W = L.top.shape
    c = np.asarray(centre)
    bb = bbox(np.array([c - radius * 1.3, c + radius * 1.3]), 2, W, H)
    if bb is None:
        return
    x0, y0, x1, y1 = bb
    h, w = y1 - y0, x1 - x0
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(F32)
    rr = np.hypot(xx - c[0], yy - c[1]) / radius
    m = np.clip((1 - rr) * 2.5 + 0.9 * fbm(rng, h, w, radius * 0.4, 3), 0, 1)
    m = smoothstep(0.3, 0.7, m).astype(F32)
    col = jit(rng, lin([(88, 100, 46), (66, 84, 40), (108, 112, 56), (80, 90, 56)][int(rng.integers(4))]), 0.1)
    g = noise(rng, h, w, max(1.0, 0.06 * ppc))
    mc = col[None, None, :] * (1 + 0.3 * g + 0.15 * fbm(rng, h, w, 0.5 * ppc, 2))[..., None]
    sl = (slice(y0, y1), slice(x0, x1))
    L.alb[sl] = L.alb[sl] * (1 - m[..., None]) + mc * m[..., None]
    L.top[sl] += m * F32(0.25 * ppc) * (1 + 0.3 * g)
    L.soil_top[sl] = L.top[sl]


def smooth_height(top: np.ndarray, sigma: float) -> np.ndarray:
    """Large-sigma blur done at reduced resolution (cheap on big frames)."""
    H, W = top.shape
    f = min(1.0, 4.0 / max(sigma, 1e-6))
    small = cv2.resize(top, (max(4, int(W * f)), max(4, int(H * f))), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), max(sigma * f, 0.5))
    return cv2.resize(small, (W, H), interpolation=cv2.INTER_LINEAR)


def soil_normals(L: Layers, light: Light) -> None:
    """Direct-sun factor of the bare soil from its height-field gradient."""
    gx = cv2.Sobel(L.top, cv2.CV_32F, 1, 0, ksize=3) * F32(1 / 8)
    gy = cv2.Sobel(L.top, cv2.CV_32F, 0, 1, ksize=3) * F32(1 / 8)
    L.nd, _ = shade_normals(-gx, -gy, light, 0.0, 1.0)


# ============================================================================ lighting
def sample_light(rng: np.random.Generator, notes: dict, person_shadow: bool = False) -> Light:
    """Overcast, sun (15 % with the photographer's shadow) or evening; `person_shadow`: always sun
    with the photographer's shadow."""
    kind = "sun" if person_shadow else str(rng.choice(["overcast", "sun", "evening"], p=[0.35, 0.45, 0.2]))
    sdir = unit(rng.uniform(0, TAU))
    person = False
    if kind == "overcast":
        light = Light(kind, 1.2, sdir, np.zeros(3, F32), jit(rng, lin((236, 240, 255)), 0.0, 0.02),
                      0.0, False)
    elif kind == "sun":
        elev = math.radians(rng.uniform(28, 72))
        person = person_shadow or rng.random() < 0.15
        light = Light(kind, elev, sdir, jit(rng, lin((255, 250, 240)), 0.0, 0.01),
                      jit(rng, lin((150, 170, 215)), 0.15, 0.03), float(rng.uniform(0.8, 5.0)), person)
    else:
        elev = math.radians(rng.uniform(7, 22))
        light = Light(kind, elev, sdir, jit(rng, lin((255, 200, 140)), 0.0, 0.04),
                      jit(rng, lin((126, 130, 150)), 0.15, 0.04), float(rng.uniform(1.0, 4.0)), False)
    notes["light"] = kind + ("+person_shadow" if person else "")
    notes["sun_elev"] = round(math.degrees(light.elev), 1) if kind != "overcast" else None
    return light


def shifted(a: np.ndarray, ox: int, oy: int, fill: float) -> np.ndarray:
    """out[y, x] = a[y + oy, x + ox] (fill outside)."""
    H, W = a.shape
    out = np.full_like(a, fill)
    ys0, ys1 = max(0, -oy), min(H, H - oy)
    xs0, xs1 = max(0, -ox), min(W, W - ox)
    if ys1 > ys0 and xs1 > xs0:
        out[ys0:ys1, xs0:xs1] = a[ys0 + oy:ys1 + oy, xs0 + ox:xs1 + ox]
    return out


def cast_shadow(top: np.ndarray, bot: np.ndarray, light: Light) -> np.ndarray:
    """March towards the sun over the height field; leaves are thin sheets (light passes under them)."""
    tan_e = math.tan(light.elev)
    hmax = float(top.max() - np.percentile(top[::4, ::4], 5))
    dmax = min(hmax / tan_e, 1.5 * max(top.shape))
    occ = np.zeros(top.shape, bool)
    z0 = top + 0.4
    t = 1.0
    while t < dmax:
        step = max(1.0, 0.09 * t)
        ox, oy = int(round(t * light.sdir[0])), int(round(t * light.sdir[1]))
        tq = shifted(top, ox, oy, GROUND)
        bq = shifted(bot, ox, oy, GROUND)
        z = z0 + t * tan_e
        occ |= (z <= tq) & (z >= bq - 1.5 * step * tan_e)
        t += step
    return occ.astype(F32)


def person_shadow(rng: np.random.Generator, H: int, W: int) -> np.ndarray:
    """The photographer's own shadow: a big soft-edged dark region entering from one side."""
    a = rng.uniform(0, TAU)
    yy, xx = np.mgrid[0:H, 0:W].astype(F32)
    d = (xx - W / 2) * math.cos(a) + (yy - H / 2) * math.sin(a)
    along = -(xx - W / 2) * math.sin(a) + (yy - H / 2) * math.cos(a)
    edge = rng.uniform(0.15, 0.45) * math.hypot(W, H) / 2
    # head/shoulder bulge and a wobbly outline rather than a straight edge
    bulge = F32(rng.uniform(0.1, 0.3) * min(H, W)) * np.exp(-(along / F32(rng.uniform(0.15, 0.3) * min(H, W))) ** 2)
    wob = noise(rng, H, W, 0.2 * min(H, W)) * F32(0.04 * min(H, W)) + bulge
    soft = 0.015 * min(H, W)
    # (logistic clipped: far from the edge exp() would overflow float32, with a warning, to 0 or 1 anyway)
    return (1 / (1 + np.exp(np.clip(-(d + wob - edge) / soft, -60, 60)))).astype(F32)


def merge3(planes: list[np.ndarray]) -> np.ndarray:
    return cv2.merge([np.ascontiguousarray(p, F32) for p in planes])


def illuminate(L: Layers, light: Light, rng: np.random.Generator, S: float, notes: dict,
               gain: np.ndarray, vig: np.ndarray | None) -> np.ndarray:
    """Radiance = albedo * (sky * ambient occlusion + sun * n.l * unshadowed) + sun * specular.

    The camera's white-balance gains and vignetting are folded in here (cheaper than extra
    full-resolution passes later)."""
    H, W = L.top.shape
    f = min(1.0, 420.0 / min(H, W))
    ws, hs = max(8, int(W * f)), max(8, int(H * f))
    top_s = cv2.resize(L.top, (ws, hs), interpolation=cv2.INTER_AREA) * F32(f)
    # ambient occlusion: points lower than their surroundings see less sky
    # (capped, so a leaf standing over the soil darkens it softly instead of drawing an outline)
    occl = 0.0
    for sig, k in ((max(1.5, 0.05 * S * f), 1.0), (2.0, 1.5)):
        occl = occl + k * np.clip(cv2.GaussianBlur(top_s, (0, 0), sig) - top_s, 0, 0.6 * sig) / F32(sig)
    ao = cv2.resize((1 / (1 + 1.2 * occl)).astype(F32), (W, H), interpolation=cv2.INTER_LINEAR)
    if vig is not None:
        ao *= vig
    sky = [float(v) for v in light.sky * gain]
    sun = [float(v) for v in light.sun * gain]
    if light.kind == "overcast":
        E = merge3([ao * sky[c] for c in range(3)])
        E *= L.alb
        return E
    bot_s = cv2.resize(L.bot, (ws, hs), interpolation=cv2.INTER_NEAREST) * F32(f)
    sh = cast_shadow(top_s, bot_s, light)
    sh = cv2.GaussianBlur(sh, (0, 0), 0.7)
    notes["shadow_share"] = round(float(sh[::4, ::4].mean()), 3)
    sh = cv2.resize(sh, (W, H), interpolation=cv2.INTER_LINEAR)
    pen = light.penumbra * min(H, W) / 1000
    if pen > 0.5:
        sh = cv2.GaussianBlur(sh, (0, 0), pen)
    lit = 1 - sh
    if light.person_shadow:
        lit *= 1 - person_shadow(rng, H, W)
    if vig is not None:
        lit *= vig
    direct = L.nd * lit
    E = merge3([ao * sky[c] + direct * sun[c] for c in range(3)])
    E *= L.alb
    rows = np.nonzero(np.isfinite(L.pz).any(axis=1))[0]   # specular only exists on plants
    cols = np.nonzero(np.isfinite(L.pz).any(axis=0))[0]
    if len(rows):
        sl = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        sp = L.spec[sl] * lit[sl]
        E[sl] += merge3([sp * sun[c] for c in range(3)])
    return E


# ============================================================================ camera
@dataclass
class Camera:
    ev: float                 # exposure error (stops) relative to the auto-exposure
    wb: str
    gain: np.ndarray          # white-balance gains (linear BGR)
    vig: float
    base_sigma: float         # lens + demosaicking softness
    blur: str
    defocus: float
    motion: int
    motion_angle: float
    ca: float
    iso: float                # shot-noise gain
    contrast: float
    sharp: float
    jpeg: int


def sample_camera(rng: np.random.Generator, light: Light, short: int) -> Camera:
    u = rng.random()
    ev = float(rng.uniform(-1.3, -0.5) if u < 0.12 else rng.uniform(0.3, 0.9) if u < 0.24 else rng.normal(0, 0.25))
    # white balance: mostly corrects the illuminant, with a bluish/yellowish error on some images
    illum = light.sky * 0.4 + (light.sun * 0.6 if light.kind != "overcast" else light.sky * 0.6)
    gain = (illum[1] / illum) ** rng.uniform(0.6, 0.95)
    u = rng.random()
    wb = "ok"
    if u < 0.2:
        wb, err = "bluish", np.array([rng.uniform(1.08, 1.25), 1.0, rng.uniform(0.82, 0.93)])
    elif u < 0.4:
        wb, err = "yellowish", np.array([rng.uniform(0.8, 0.92), 1.0, rng.uniform(1.03, 1.12)])
    else:
        err = np.exp(rng.normal(0, 0.03, 3))
    vig = float(rng.uniform(0.1, 0.45)) if rng.random() < 0.6 else 0.0
    scale = max(short / 1000, 0.6)
    u = rng.random()
    blur, defocus, motion = "none", 0.0, 0
    if u < 0.25:
        defocus = float(rng.uniform(0.8, 2.8) * scale)
        blur = f"defocus{defocus:.1f}"
    elif u < 0.4:
        motion = int(rng.integers(3, 13) * scale) | 1
        blur = f"motion{motion}"
    return Camera(ev=ev, wb=wb, gain=(gain * err).astype(F32), vig=vig, base_sigma=float(rng.uniform(0.45, 0.8)),
                  blur=blur, defocus=defocus, motion=motion, motion_angle=float(rng.uniform(0, 180)),
                  ca=float(rng.uniform(0.0008, 0.0025)) if rng.random() < 0.35 else 0.0,
                  iso=float(10 ** rng.uniform(-3.6, -2.4) * (2 ** max(0.0, -ev))),
                  contrast=float(rng.uniform(0.1, 0.35)), sharp=float(rng.uniform(0.0, 0.8)),
                  jpeg=int(rng.integers(60, 96)))


def vignette_map(H: int, W: int, vig: float) -> np.ndarray | None:
    if not vig:
        return None
    den = (W / 2) ** 2 + (H / 2) ** 2
    rx = ((np.arange(W, dtype=F32) - W / 2) ** 2 / den)[None, :]
    ry = ((np.arange(H, dtype=F32) - H / 2) ** 2 / den)[:, None]
    return (1 - F32(vig) * (rx + ry)).astype(F32)


def develop(rad: np.ndarray, cam: Camera, rng: np.random.Generator, notes: dict) -> np.ndarray:
    """Auto exposure (+error), blur, chromatic aberration, noise, tone curve, sharpening, JPEG."""
    H, W = rad.shape[:2]
    # centre-weighted metering of mean luminance -> mid grey
    sub = rad[::8, ::8]
    Y = 0.114 * sub[..., 0] + 0.587 * sub[..., 1] + 0.299 * sub[..., 2]
    yy, xx = np.mgrid[0:Y.shape[0], 0:Y.shape[1]]
    wgt = np.exp(-(((xx - Y.shape[1] / 2) / (0.44 * Y.shape[1])) ** 2 + ((yy - Y.shape[0] / 2) / (0.44 * Y.shape[0])) ** 2))
    meter = float((Y * wgt).sum() / wgt.sum())
    k = 0.16 / max(meter, 1e-6) * 2 ** cam.ev
    sig = math.hypot(cam.base_sigma, cam.defocus)
    img = cv2.GaussianBlur(rad, (3, 3) if sig < 0.9 else (0, 0), sig)
    if cam.motion:
        ln = cam.motion
        ker = np.zeros((ln, ln), F32)
        ker[ln // 2, :] = 1
        ker = cv2.warpAffine(ker, cv2.getRotationMatrix2D((ln / 2 - 0.5, ln / 2 - 0.5), cam.motion_angle, 1), (ln, ln))
        img = cv2.filter2D(img, -1, ker / ker.sum())
    if cam.ca:   # lateral chromatic aberration: red and blue images at slightly different scale
        chans = list(cv2.split(img))
        for ch, s in ((2, 1 + cam.ca), (0, 1 - cam.ca)):
            M = cv2.getRotationMatrix2D((W / 2, H / 2), 0, s)
            chans[ch] = cv2.warpAffine(chans[ch], M, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        img = cv2.merge(chans)
    # sensor noise (in exposed units: shot noise ~ sqrt(signal)), plus blotchy chroma noise
    lum = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    sd = np.sqrt(np.maximum(lum, 0) * F32(cam.iso * k) + F32(2e-6)) * F32(3.46 / k)
    n1 = (rng.random((H, W), dtype=F32) - F32(0.5)) * sd
    chroma = rng.standard_normal((H // 4 + 2, W // 4 + 2, 3), dtype=F32) * F32(math.sqrt(cam.iso) * 0.1 / k)
    noise3 = cv2.resize(chroma, (W, H), interpolation=cv2.INTER_LINEAR)
    noise3 += merge3([n1, n1, n1])
    img += noise3
    # tone curve (sRGB gamma, gentle S, highlight shoulder) via a 13-bit lookup table
    np.multiply(img, F32(4096 * k), out=img)
    img = cv2.threshold(img, 8191, 0, cv2.THRESH_TRUNC)[1]
    img = cv2.max(img, 0.0)
    out = tone_lut(cam.contrast)[img.astype(np.uint16)]
    if cam.sharp > 0.05:
        out = cv2.addWeighted(out, 1 + cam.sharp, cv2.GaussianBlur(out, (0, 0), 1.0), -cam.sharp, 0)
    ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, cam.jpeg])
    out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    notes.update(ev=round(cam.ev, 2), wb=cam.wb, vignette=round(cam.vig, 2), blur=cam.blur, ca=round(cam.ca, 4),
                 iso=round(math.log10(cam.iso), 2), sharpen=round(cam.sharp, 2), jpeg=cam.jpeg)
    return out


_LUTS: dict[float, np.ndarray] = {}


def tone_lut(contrast: float) -> np.ndarray:
    key = round(contrast, 2)
    if key not in _LUTS:
        x = np.arange(8192) / 4096.0
        x = np.where(x < 0.75, x, 0.75 + 0.3 * np.tanh((x - 0.75) / 0.3))      # highlight shoulder
        y = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0), 1 / 2.4) - 0.055)
        y = np.clip(y, 0, 1)
        y = y + key * (y * y * (3 - 2 * y) - y)                                  # gentle S-curve
        _LUTS[key] = np.clip(y * 255 + 0.5, 0, 255).astype(np.uint8)
    return _LUTS[key]


# ============================================================================ scene assembly
def sample_size(rng: np.random.Generator) -> tuple[int, int]:
    common = [(640, 480), (800, 600), (1024, 768), (1280, 720), (1280, 960), (1600, 1200), (1920, 1080),
              (2000, 1500), (1440, 1080)]
    if rng.random() < 0.5:
        W, H = common[int(rng.integers(len(common)))]
    else:
        aspect = 4 / 3 if rng.random() < 0.65 else 16 / 9
        short = rng.uniform(480, 1500 if aspect < 1.5 else 1125)
        H, W = int(short) // 2 * 2, int(short * aspect) // 2 * 2
    if rng.random() < 0.15:  # portrait orientation
        W, H = H, W
    return W, H


def render(rng: np.random.Generator, kind: str, person_shadow: bool = False,
           bare: bool = False) -> tuple[np.ndarray, np.ndarray, float, dict]:
    """Render one photo of a single `kind` weed. Returns (BGR uint8, crown (u, v), S px, notes).
    `person_shadow`: sun with the photographer's shadow in every photo; `bare`: no weed drawn (the
    main one nor others; moss, dead leaves and straw stay), crown and S as if it were there."""
    notes: dict = {"kind": kind}
    W, H = sample_size(rng)
    notes["size"] = f"{W}x{H}"
    short = min(W, H)
    light = sample_light(rng, notes, person_shadow)

    # --- main plant geometry, scaled and placed (never cut by the border)
    organs_u, pinfo = BUILDERS[kind](rng)
    notes["plant"] = pinfo
    s_target = float(rng.uniform(0.15, 0.7)) * short
    rot, mirror = float(rng.uniform(0, TAU)), bool(rng.random() < 0.5)
    margin = max(6.0, 0.03 * short)
    for _ in range(8):
        organs = place(organs_u, s_target, np.zeros(2), rot, mirror)
        lo, hi = extent(organs)
        if (hi - lo)[0] <= W - 2 * margin and (hi - lo)[1] <= H - 2 * margin:
            break
        s_target *= 0.9
    want = np.array([W / 2 + rng.uniform(-0.2, 0.2) * W, H / 2 + rng.uniform(-0.2, 0.2) * H])
    crown = np.clip(want, margin - lo, np.array([W, H]) - margin - hi)
    organs = place(organs_u, s_target, crown, rot, mirror)
    plant_cm = float(rng.uniform(*PLANT_CM[kind]))
    ppc = s_target / plant_cm                            # pixels per cm on the ground
    notes["plant_cm"] = round(plant_cm, 1)

    # --- soil, clutter
    tiles = {"fine": periodic_noise(rng, TILE, 1.3), "mid": periodic_noise(rng, TILE, 5.0),
             "coarse": periodic_noise(rng, TILE, 24.0)}
    L = make_soil(rng, H, W, ppc, notes, tiles)
    soil_col = np.median(L.alb[::16, ::16].reshape(-1, 3), axis=0).astype(F32)
    env = Env(rng, light, tiles, soil_col, s_target / 2)
    clutter: list[str] = []
    if rng.random() < 0.12:
        pos = free_spot(rng, W, H, crown, s_target, 0.25 * s_target, allow_overlap=True)
        if pos is not None:
            add_moss(rng, L, env, ppc, pos, rng.uniform(0.12, 0.3) * s_target)
            clutter.append("moss")
    soil_normals(L, light)
    L.soil_base = smooth_height(L.soil_top, 0.04 * s_target)   # leaves bridge cracks and crumbs
    if rng.random() < 0.15:
        pos = free_spot(rng, W, H, crown, s_target, 0.3 * s_target, allow_overlap=True)
        if pos is not None:
            dl = place(build_dead_leaf(rng), rng.uniform(0.15, 0.35) * s_target, pos, rng.uniform(0, TAU), False)
            for o in dl:
                draw_organ(L, o, env, False)
            clutter.append("dead_leaf")
    n_other = 0 if bare else int(rng.choice([0, 1, 2], p=[0.68, 0.22, 0.1]))
    for _ in range(n_other):
        ok = add_other_weed(rng, L, env, W, H, crown, s_target)
        if ok:
            clutter.append("other:" + ok)
    notes["clutter"] = clutter

    # --- the main weed
    for o in organs if not bare else []:
        draw_organ(L, o, env, True)
    ys, xs = np.nonzero(L.plant > 0.5)
    S = plant_diameter_px(xs, ys) if len(xs) else s_target
    notes["S"] = round(S, 1)

    cam = sample_camera(rng, light, short)
    rad = illuminate(L, light, rng, S, notes, cam.gain, vignette_map(H, W, cam.vig))
    img = develop(rad, cam, rng, notes)
    return img, np.array(crown, float), float(S), notes


def plant_diameter_px(xs: np.ndarray, ys: np.ndarray) -> float:
    pts = np.stack([xs, ys], 1).astype(np.float32)
    if len(pts) > 20000:
        hull = cv2.convexHull(pts)
        pts = hull.reshape(-1, 2)
    _, r = cv2.minEnclosingCircle(pts)
    return 2.0 * float(r) + 1.0


def free_spot(rng: np.random.Generator, W: int, H: int, crown: np.ndarray, S: float, r: float,
              allow_overlap: bool = False) -> np.ndarray | None:
    """A random position for clutter: inside the frame, away from the crown (and, unless
    allow_overlap, outside the main plant), farther from the image centre than the crown."""
    centre = np.array([W / 2, H / 2])
    dmin = 0.4 * S + r if allow_overlap else 0.5 * S + r * 1.1 + 4
    for _ in range(40):
        p = np.array([rng.uniform(r, W - r), rng.uniform(r, H - r)]) if W > 2 * r and H > 2 * r else None
        if p is None:
            return None
        if np.linalg.norm(p - crown) > dmin and np.linalg.norm(p - centre) > np.linalg.norm(crown - centre):
            return p
    return None


def add_other_weed(rng: np.random.Generator, L: Layers, env: Env, W: int, H: int, crown: np.ndarray,
                   S: float) -> str | None:
    """A much smaller other weed or seedling elsewhere in the frame (not overlapping the main one)."""
    kind = str(rng.choice(["seedling", "grass", "clover", "chickweed", "dandelion", "purslane"]))
    size = float(rng.uniform(0.08, 0.25)) * S
    pos = free_spot(rng, W, H, crown, S, size * 0.7)
    if pos is None:
        return None
    organs_u, _ = BUILDERS[kind](rng)
    organs = place(organs_u, size, pos, float(rng.uniform(0, TAU)), bool(rng.random() < 0.5))
    lo, hi = extent(organs)
    if lo[0] < 1 or lo[1] < 1 or hi[0] > W - 2 or hi[1] > H - 2:
        return None
    for o in organs:
        draw_organ(L, o, env, False)
    return kind


# ============================================================================ benchmark
def notes_summary(n: dict) -> str:
    ex = "+".join(n.get("soil_extras", []))
    cl = ",".join(n.get("clutter", []))
    return (f"{n['size']} S={n['S']:.0f} soil={n['soil']}{'[' + ex + ']' if ex else ''} "
            f"light={n['light']} ev={n['ev']:+.1f} wb={n['wb']} blur={n['blur']} q={n['jpeg']}"
            f"{' clutter=' + cl if cl else ''}")


def roi_near(seed: int, i: int, truth: np.ndarray, S: float) -> tuple:
    """The ROI of case i with --roi: an ellipse-style circle of 1.3 S round a point within 0.15 S of
    the crown, from its own stream (so the image does not depend on --roi)."""
    r2 = np.random.default_rng([seed, i, 1])
    off = unit(r2.uniform(0, TAU)) * 0.15 * S * math.sqrt(r2.random())
    return ((float(truth[0] + off[0]), float(truth[1] + off[1])), (1.3 * S, 1.3 * S), 0.0)


def fill_crop(img: np.ndarray, truth: np.ndarray, S: float, k: float, rng: np.random.Generator,
              off: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """The photo cropped to a square of k·S (clipped to the frame) round a point up to `off`·S from the
    crown along each axis, and the crown in the crop (--fill: close-ups where the plant fills the frame)."""
    c = truth + rng.uniform(-off, off, 2) * S
    h = 0.5 * k * S
    H, W = img.shape[:2]
    x0, y0 = int(max(0, c[0] - h)), int(max(0, c[1] - h))
    x1, y1 = int(min(W, c[0] + h)), int(min(H, c[1] + h))
    return np.ascontiguousarray(img[y0:y1, x0:x1]), truth - np.array([x0, y0], float)


def draw_fail(img: np.ndarray, truth: np.ndarray, pix: tuple[float, float] | None, S: float,
              roi: tuple | None) -> np.ndarray:
    out = img.copy()
    r = max(4, int(0.03 * S))
    t = (int(round(truth[0])), int(round(truth[1])))
    cv2.drawMarker(out, t, (0, 255, 0), cv2.MARKER_CROSS, 2 * r, 2)
    cv2.circle(out, t, int(0.2 * S), (0, 255, 0), 1, cv2.LINE_AA)
    if pix is not None:
        cv2.drawMarker(out, (int(round(pix[0])), int(round(pix[1]))), (0, 0, 255), cv2.MARKER_TILTED_CROSS, 2 * r, 2)
    if roi is not None:
        (cu, cv_), (fw, fh), ang = roi
        cv2.ellipse(out, (int(cu), int(cv_)), (int(fw / 2), int(fh / 2)), ang, 0, 360, (0, 255, 255), 1, cv2.LINE_AA)
    return out


def pct(x: float) -> str:
    return f"{100 * x:5.1f}%"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=100, help="number of images (kinds cycle)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--roi", action="store_true", help="give the detector an ellipse ROI near the truth")
    ap.add_argument("--kinds", type=str, default="", help="comma separated subset of " + ",".join(KINDS))
    ap.add_argument("--save-fails", type=str, default="", metavar="DIR")
    ap.add_argument("--person-shadow", action="store_true",
                    help="every photo in sun with the photographer's shadow in it (15 %% of sunny ones otherwise)")
    ap.add_argument("--bare", action="store_true",
                    help="no weeds drawn: report how many photos get 'no_plant' (and where the others point)")
    ap.add_argument("--fill", type=float, default=0.0, metavar="K",
                    help="crop each photo to a square of K·S round a point within 0.1 S of the crown before "
                         "detection (K ≈ 1: the plant fills the frame; K < 1: its leaves are cut by the border)")
    args = ap.parse_args(argv)
    if not (args.fill == 0 or 0 < args.fill < math.inf) or (args.fill and (args.roi or args.bare)):
        ap.error("--fill takes a finite K > 0 and goes without --roi and --bare")
    cv2.setNumThreads(1)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from capm_field.detector import detect_centre  # noqa: E402 - after the path tweak

    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()] or list(KINDS)
    bad = [k for k in kinds if k not in BUILDERS]
    if bad:
        ap.error(f"unknown kinds {bad}; choose from {KINDS}")
    fail_dir = Path(args.save_fails) if args.save_fails else None
    if fail_dir:
        fail_dir.mkdir(parents=True, exist_ok=True)

    t_start = time.perf_counter()
    rows: list[dict] = []
    for i in range(args.n):
        kind = kinds[i % len(kinds)]
        rng = np.random.default_rng([args.seed, i])
        t0 = time.perf_counter()
        img, truth, S, notes = render(rng, kind, args.person_shadow, args.bare)
        t_render = time.perf_counter() - t0
        if args.fill:
            img, truth = fill_crop(img, truth, S, args.fill, np.random.default_rng([args.seed, i, 2]))
        roi = roi_near(args.seed, i, truth, S) if args.roi else None
        dbg: dict = {}
        t1 = time.perf_counter()
        try:
            det = detect_centre(img, roi=roi, debug=dbg)
            pix, reason = det.pixel, det.reason
        except Exception as e:  # a crash is a result too
            pix, reason = None, f"exception:{type(e).__name__}"
        lat = time.perf_counter() - t1
        detected = pix is not None and reason is None
        err = float(np.hypot(pix[0] - truth[0], pix[1] - truth[1]) / S) if pix is not None else float("nan")
        row = dict(i=i, kind=kind, detected=detected, err=err, reason=reason, method=dbg.get("method"),
                   lat=lat, t_render=t_render, notes=notes, S=S)
        rows.append(row)
        if fail_dir is not None and ((reason != "no_plant") if args.bare else (not detected or err > 0.2)):
            cv2.imwrite(str(fail_dir / f"{args.seed}_{i}_{kind}.png"), draw_fail(img, truth, pix, S, roi))

    print(f"field_photo_weeds: n={args.n} seed={args.seed} roi={'yes' if args.roi else 'no'}"
          + (f" fill={args.fill:g}" if args.fill else "") + (" person_shadow" if args.person_shadow else "")
          + (" bare" if args.bare else ""))
    if args.bare:  # no weed: every answer but "no_plant" is a false plant
        answered = [r for r in rows if r["reason"] != "no_plant"]
        print(f"no_plant {len(rows) - len(answered)} of {len(rows)} ({pct(1 - len(answered) / len(rows))}); "
              f"reasons {dict(Counter(str(r['reason']) for r in rows))}")
        for r in answered:
            print(f"  {r['i']:4d} {str(r['reason']):<13} {str(r['method']):<14} | {notes_summary(r['notes'])}")
        print(f"\nrender median {1000 * np.median([r['t_render'] for r in rows]):.0f} ms/image, "
              f"total run time {time.perf_counter() - t_start:.1f} s")
        return 0
    hdr = f"{'kind':<10} {'n':>4} {'det':>7} {'med':>6} {'p90':>6} {'<0.1S':>7} {'<0.2S':>7} {'wrong':>7} {'ms':>7}"
    print(hdr)
    print("-" * len(hdr))
    for k in kinds + ["ALL"]:
        rs = [r for r in rows if k == "ALL" or r["kind"] == k]
        if not rs:
            continue
        n = len(rs)
        errs = np.array([r["err"] for r in rs if r["detected"]])
        med = f"{np.median(errs):6.3f}" if len(errs) else "     -"
        p90 = f"{np.percentile(errs, 90):6.3f}" if len(errs) else "     -"
        if k == "ALL":
            print("-" * len(hdr))
        print(f"{k:<10} {n:>4} {pct(len(errs) / n):>7} {med} {p90} {pct(float((errs <= 0.1).sum()) / n):>7} "
              f"{pct(float((errs <= 0.2).sum()) / n):>7} {pct(float((errs > 0.5).sum()) / n):>7} "
              f"{1000 * np.median([r['lat'] for r in rs]):7.1f}")
    print("\nreasons / methods per kind")
    for k in kinds:
        rs = [r for r in rows if r["kind"] == k]
        if not rs:
            continue
        rc = Counter(str(r["reason"]) for r in rs)
        mc = Counter(str(r["method"]) for r in rs)
        print(f"  {k:<10} reason: {dict(rc)}  method: {dict(mc)}")
    fails = [r for r in rows if not r["detected"] or r["err"] > 0.2]
    print(f"\nfailing cases ({len(fails)}): index kind reason err/S method | conditions")
    for r in fails:
        e = f"{r['err']:.2f}" if r["err"] == r["err"] else "-"
        print(f"  {r['i']:4d} {r['kind']:<10} {str(r['reason']):<13} {e:>5} {str(r['method']):<14} | "
              f"{notes_summary(r['notes'])}")
    tot = time.perf_counter() - t_start
    print(f"\nrender median {1000 * np.median([r['t_render'] for r in rows]):.0f} ms/image, "
          f"total run time {tot:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
