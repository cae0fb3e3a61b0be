"""Photo-like synthetic weed photos: a black-box test of `capm_field.detector.detect_centre`.

    .venv/bin/python bench/photo_plants.py --n 70 --seed 0 [--kinds dandelion grass ...] [--roi]
        [--save-fails DIR] [--save-all DIR]

Written independently of the detector and of the other renderers. Case i uses
np.random.default_rng([seed, i]); kinds are taken in turn. One weed per image: dandelion
(runcinate toothed rosette, pale midribs), plantain (broad or lanceolate leaves with parallel veins
on petioles), grass (tuft of curved, crossing, bent-over blades), clover (trifoliate leaves with
pale chevrons on petioles from a crown, which may lie outside the leaves), seedling (two
cotyledons, sometimes first true leaves), chickweed (paired leaves along branching thin stems from
one root), amaranth (alternate ovate leaves on petioles, smaller upper leaves on top). The truth
is the biological centre (crown / blade base / stem / root) and S = twice the largest distance
from it to the plant outline, both in final-image pixels.

Rendering: leaves are polygons from a curved midrib and a width profile; each gets a height field
(fold, dome, tilt, curl, bumps, vein grooves) lit by sun + sky (Lambert, translucency,
Blinn-Phong glare and sky sheen), veins, mottling, yellowing, necrotic spots, dry margins and
holes; leaves cast drop shadows on lower leaves, the plant casts an ambient-occlusion shadow and,
in sun, a hard shadow on the soil. Soil: multi-scale albedo noise, Worley clods and crumbs lit by
the same sun (self-shadowed relief), cracks, pebbles and stones, straw, dead leaves, wet patches,
moss/algae and a few tiny other seedlings (<= 1/4 of the weed's size, away from it). Camera:
640x480 .. 4032x3024 and 320x240, straight down or tilted up to 35 deg (ground-plane homography,
truth warped identically), plant 5-60 % of the short side, auto exposure, white-balance cast,
vignetting, defocus / motion blur, chromatic aberration, sensor noise, tone curve, sharpening
and JPEG (q 60-95) half of the time.

With --roi the detector gets a circle of radius 1.2-2.5 x S/2 around the truth shifted by up to
0.3 of that radius. Prints per-kind detection rate, error/S (median, p90 of detections), share
within 0.1 S and 0.2 S (misses count as outside), share wrong (> 0.5 S off), reasons and median
latency, and what the answers more than 0.15 S off landed on (weed, tiny seedling, moss, stone,
straw, dead leaf, soil; from the renderer's label map). --save-fails writes a PNG per case with
error > 0.15 S or no detection (image downscaled to <= 1600 px wide with truth = green cross,
answer = red cross, plus a close-up of the plant); --save-all writes one for every case.
Limits: plants are layered 2D parts (tilt is a ground-plane homography, no parallax); the soil is
rendered at <= 5 Mpx, so on 4032x3024 images it is softer than the plant.
"""

from __future__ import annotations

import argparse
import colorsys
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

LABELS = ("soil", "weed", "tiny seedling", "moss", "stone", "straw", "dead leaf")
KINDS = ("dandelion", "plantain", "grass", "clover", "seedling", "chickweed", "amaranth")
SIZES = ((640, 480), (1280, 720), (1920, 1080), (4032, 3024), (320, 240))
SIZE_P = (0.24, 0.22, 0.2, 0.12, 0.22)
# real plant diameter range (m) per kind, only used to scale the soil features
D_REAL = {"dandelion": (0.08, 0.35), "plantain": (0.08, 0.35), "grass": (0.05, 0.3),
          "clover": (0.03, 0.15), "seedling": (0.006, 0.04), "chickweed": (0.03, 0.18),
          "amaranth": (0.04, 0.25)}
F32 = np.float32


# ----------------------------------------------------------------------------- small helpers
def U(rng, a, b):
    return float(rng.uniform(a, b))


def lin(rgb):
    """sRGB 0..255 (R, G, B) -> linear BGR float32."""
    c = np.clip(np.asarray(rgb, np.float64)[::-1] / 255.0, 0, 1)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(F32)


def hsv_lin(h, s, v):
    r, g, b = colorsys.hsv_to_rgb((h % 360) / 360.0, float(np.clip(s, 0, 1)), float(np.clip(v, 0, 1)))
    return lin((r * 255, g * 255, b * 255))


def mix(a, b, t):
    return a + (b - a) * t


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0, 1)
    return t * t * (3 - 2 * t)


def randn(shape, rng):
    """Standard normal float32 array (OpenCV's generator, seeded from rng: fast, deterministic)."""
    out = np.empty(shape, F32)
    cv2.setRNGSeed(int(rng.integers(0, 2 ** 31 - 1)))
    cv2.randn(out, 0.0, 1.0)
    return out


def noise(shape, cell, rng):
    """Smooth Gaussian noise (unit std) with feature size ~cell px (blurred white noise on a grid
    at most cell/6 coarser, upsampled linearly: no grid artefacts)."""
    h, w = int(shape[0]), int(shape[1])
    if cell < 1.2:
        return randn((h, w), rng)
    f = max(1, int(cell / 6))
    lh, lw = h // f + 3, w // f + 3
    low = randn((lh, lw), rng)
    sg = cell / (2.0 * f)
    low = cv2.GaussianBlur(low, (0, 0), sg, borderType=cv2.BORDER_REFLECT)
    low *= F32(2.0 * math.sqrt(math.pi) * sg if sg >= 1.0 else 1.0 / max(float(low.std()), 1e-6))
    if f == 1:
        return low[:h, :w]
    big = cv2.resize(low, (lw * f, lh * f), interpolation=cv2.INTER_LINEAR)
    oy, ox = int(rng.integers(0, f)), int(rng.integers(0, f))
    return big[oy:oy + h, ox:ox + w]


def fbm(shape, cell, rng, octaves=4, gain=0.5, lac=2.1):
    out = np.zeros(shape, F32)
    a, tot = 1.0, 0.0
    for o in range(octaves):
        c = cell / lac ** o
        if c < 1.0 and o > 0:
            break
        out += F32(a) * noise(shape, c, rng)
        tot += a * a
        a *= gain
    return out / F32(math.sqrt(tot))


def blur(img, sigma):
    h, w = img.shape[:2]
    if sigma < 0.3 or min(h, w) < 4:
        return img
    img = np.ascontiguousarray(img)
    sigma = min(sigma, 2.0 * max(h, w))
    f = min(int(sigma // 4), max(1, min(h, w) // 8))
    if f >= 2:     # large kernels: blur a downscaled copy
        small = cv2.resize(img, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA)
        small = cv2.GaussianBlur(small, (0, 0), math.sqrt(max(sigma ** 2 / f ** 2 - 0.25, 0.1)))
        return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    return cv2.GaussianBlur(img, (0, 0), float(sigma))


def sines(s, rng, amp, fmin=1.0, fmax=6.0, n=3):
    f = rng.uniform(fmin, fmax, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    a = rng.uniform(0.3, 1.0, n)
    return amp * (a[:, None] * np.sin(2 * np.pi * f[:, None] * s[None, :] + ph[:, None])).sum(0) / a.sum()


def dist_in(mask):
    """Distance to the outside of a 0/1 mask (the region's border counts as outside)."""
    m = cv2.copyMakeBorder(mask.astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    return cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]


def pts16(p):
    return np.round(np.asarray(p) * 16).astype(np.int32)


# ----------------------------------------------------------------------------- leaf geometry
def leaf_geom(rng, base, ang, length, hw, shape, *, bend=0.0, pf=0.0, pw=0.0, lobes=None, teeth=0.0,
              nteeth=0, notch=0.0, wavy=0.03, asym=0.08, n=72, kink=None):
    """Leaf outline around a curved midrib. shape(sl) in 0..1 over the lamina (sl 0..1 after the
    petiole fraction pf); hw = max half width. Returns a dict with poly, centreline c, normals,
    directions, s and per-side half widths."""
    s = np.linspace(0.0, 1.0, n)
    th = ang + bend * s + sines(s, rng, 0.05, 0.5, 2.0)
    if kink is not None:
        sk, dth = kink
        th = th + dth * np.clip((s - sk) / 0.07, 0, 1)
    d = np.stack([np.cos(th), np.sin(th)], 1)
    c = np.vstack([[0.0, 0.0], np.cumsum(d[:-1] * (length / (n - 1)), 0)]) + np.asarray(base, float)
    nrm = np.stack([-d[:, 1], d[:, 0]], 1)
    sl = np.clip((s - pf) / max(1.0 - pf, 1e-6), 0, 1)
    sh = shape(sl * (1.0 - 0.1 * (notch > 0)))
    w = hw * sh
    if pf > 0:
        pet = pw * (1 + 0.6 * np.clip(s / pf, 0, 1))
        w = np.maximum(w, np.where(s <= pf + 0.12 * (1 - pf), pet, 0.0))
    wl = w * (1 + U(rng, -asym, asym) + sines(s, rng, wavy, 2, 9))
    wr = w * (1 + U(rng, -asym, asym) + sines(s, rng, wavy, 2, 9))
    hl = np.zeros(n)
    hr = np.zeros(n)
    if lobes is not None:
        nl, depth, hook, s0, s1 = lobes
        per = (s1 - s0) / nl
        for side, arr_w, arr_h in ((0, wl, hl), (1, wr, hr)):
            ph = U(rng, 0.0, 0.6) * side + U(rng, -0.1, 0.1)
            dep = depth * U(rng, 0.75, 1.2)
            phi = ((s - s0) / per + ph) % 1.0
            inside = smoothstep(s0 - 0.03, s0 + 0.03, s) * (1 - smoothstep(s1 - 0.02, s1 + 0.05, s))
            g = np.where(phi < 0.78, 1 - dep * phi / 0.78, 1 - dep * (1 - phi) / 0.22)
            g = 1 - (1 - g) * inside
            arr_w *= g
            arr_h += hook * per * length * (g - (1 - dep)) / max(dep, 1e-3) * inside * \
                (hw / max(length, 1e-6)) * 4.0
    if teeth > 0 and nteeth > 0:
        for arr_w in (wl, wr):
            frac = (s * nteeth + U(rng, 0, 1)) % 1.0
            arr_w *= 1 - teeth + teeth * frac * smoothstep(0.05, 0.2, s)
    left = c + nrm * wl[:, None] - d * hl[:, None]
    right = c - nrm * wr[:, None] - d * hr[:, None]
    if notch > 0:
        tip = c[int(np.searchsorted(s, 1 - notch))]
        poly = np.vstack([left, tip[None], right[::-1]])
    else:
        poly = np.vstack([left, right[::-1]])
    return dict(poly=poly, c=c, nrm=nrm, d=d, s=s, wl=wl, wr=wr, pf=pf, length=length, hw=hw,
                notch=notch > 0)


def zpoly(g, zs):
    """Per-vertex heights of a leaf_geom polygon from heights along the midrib."""
    zs = np.broadcast_to(np.asarray(zs, float), g["s"].shape)
    mid = [zs[-1]] if g["notch"] else []
    return np.concatenate([zs, mid, zs[::-1]])


def veins_pinnate(g, rng, nv, s0=0.08, s1=0.85, reach=0.85, fwd=0.16):
    s, c, nrm, pf = g["s"], g["c"], g["nrm"], g["pf"]
    out = []
    for side, w in ((1, g["wl"]), (-1, g["wr"])):
        ph = U(rng, 0, 1)
        for j in range(nv):
            sj = pf + (1 - pf) * (s0 + (s1 - s0) * (j + ph) / nv)
            i = min(int(np.searchsorted(s, sj)), len(s) - 2)
            i2 = min(int(np.searchsorted(s, sj + fwd * (1 - pf))), len(s) - 1)
            im = (i + i2) // 2
            a, e = c[i], c[i2] + side * nrm[i2] * w[i2] * reach
            ctrl = c[im] + side * nrm[im] * w[im] * reach * 0.5
            t = np.linspace(0, 1, 8)[:, None]
            out.append((1 - t) ** 2 * a + 2 * t * (1 - t) * ctrl + t ** 2 * e)
    return out


def veins_parallel(g, fs, s0=None, s1=0.97):
    s, c, nrm, pf = g["s"], g["c"], g["nrm"], g["pf"]
    i0 = int(np.searchsorted(s, max(pf - 0.03, 0.0) if s0 is None else s0))
    i1 = int(np.searchsorted(s, s1))
    out = []
    for f in fs:
        w = g["wl"] if f > 0 else g["wr"]
        sg = 1 if f > 0 else -1
        out.append(c[i0:i1] + sg * nrm[i0:i1] * (abs(f) * w[i0:i1] * 0.93)[:, None])
    return out


def surf(rng, ks=(0.0, 0.2), p=(15, 60), bump=(0.0, 0.3), fold=(-0.2, 0.3), dome=(0.0, 0.35),
         tilt=(-0.2, 0.25), curl=(-0.1, 0.25), sky=(0.0, 0.06)):
    return dict(ks=U(rng, *ks), p=U(rng, *p), bump=U(rng, *bump), fold=U(rng, *fold),
                dome=U(rng, *dome), tilt=U(rng, *tilt), curl=U(rng, *curl), sky=U(rng, *sky))


def part(poly, zv, col, **kw):
    p = dict(poly=np.asarray(poly, float), col=np.asarray(col, F32), typ="leaf", mid=None, mid_w=0.0,
             mid_col=None, mid_k=0.0, veins=[], vein_w=0.0, vein_col=None, vein_k=0.0, groove=0.0,
             axis=None, surf=None, yellow=0.0, ycol=None, necro=0, burn=0.0, chev=None, chev_w=0.0,
             chev_col=None, holes=0, thin=None, vshadow=None, trans=0.25, base_col=None)
    p.update(kw)
    zv = np.asarray(zv, float)
    p["zv"] = np.broadcast_to(zv, (len(p["poly"]),)).copy() if zv.ndim == 0 else zv
    p["z"] = float(np.mean(p["zv"]))
    if p["surf"] is None:
        p["surf"] = dict(ks=0.05, p=20, bump=0.0, fold=0.0, dome=0.3, tilt=0.0, curl=0.0, sky=0.02)
    return p


def leaf_part(g, zs, col, rng, sf, **kw):
    kw.setdefault("mid", g["c"][: max(2, int(0.95 * len(g["c"])))])
    return part(g["poly"], zpoly(g, zs), col, axis=(g["c"][0], g["c"][-1]), surf=sf, **kw)


def stem_part(rng, pts, hw, zs, col, **kw):
    """Ribbon of half width hw along a polyline (stems, petioles)."""
    pts = np.asarray(pts, float)
    d = np.gradient(pts, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True) + 1e-12
    nrm = np.stack([-d[:, 1], d[:, 0]], 1)
    hwv = np.broadcast_to(np.asarray(hw, float), (len(pts),))
    poly = np.vstack([pts + nrm * hwv[:, None], (pts - nrm * hwv[:, None])[::-1]])
    zs = np.broadcast_to(np.asarray(zs, float), (len(pts),))
    sf = dict(ks=U(rng, 0.05, 0.3), p=U(rng, 15, 40), bump=0.0, fold=0.0, dome=0.0, tilt=0.0,
              curl=0.0, sky=0.03)
    return part(poly, np.concatenate([zs, zs[::-1]]), col, typ="stem", mid=pts, thin=float(np.max(hwv)),
                surf=sf, **kw)


def curve(base, ang, length, bend, n=24, rng=None, wig=0.0):
    s = np.linspace(0, 1, n)
    th = ang + bend * s
    if rng is not None and wig > 0:
        th = th + sines(s, rng, wig, 0.5, 3)
    d = np.stack([np.cos(th), np.sin(th)], 1)
    return np.vstack([[0.0, 0.0], np.cumsum(d[:-1] * (length / (n - 1)), 0)]) + np.asarray(base, float)


# ----------------------------------------------------------------------------- plant kinds
def palette(rng):
    r = rng.random()
    if r < 0.22:
        name, h, s, v = "dark green", U(rng, 82, 105), U(rng, 0.45, 0.75), U(rng, 0.2, 0.34)
    elif r < 0.55:
        name, h, s, v = "mid green", U(rng, 74, 98), U(rng, 0.45, 0.72), U(rng, 0.34, 0.52)
    elif r < 0.8:
        name, h, s, v = "yellow-green", U(rng, 64, 82), U(rng, 0.5, 0.75), U(rng, 0.45, 0.62)
    else:
        name, h, s, v = "bluish green", U(rng, 100, 135), U(rng, 0.22, 0.45), U(rng, 0.32, 0.5)
    red = rng.random() < 0.3
    return dict(name=name + (", reddish stems" if red else ""), h=h, s=s, v=v, red=red)


def lcol(pal, rng, dv=0.0, dh=0.0, ds=0.0):
    return hsv_lin(pal["h"] + rng.normal(0, 4) + dh, pal["s"] + rng.normal(0, 0.05) + ds,
                   pal["v"] * (1 + rng.normal(0, 0.08)) * (1 + dv))


def stemcol(pal, rng, leafc=None):
    if pal["red"]:
        return hsv_lin(U(rng, 335, 375), U(rng, 0.35, 0.7), U(rng, 0.3, 0.5))
    return hsv_lin(pal["h"] - U(rng, 0, 12), pal["s"] * U(rng, 0.5, 0.8), pal["v"] * U(rng, 1.0, 1.35))


PALE = lin((215, 228, 190))
YEL = lin((205, 180, 70))
BROWN = lin((110, 75, 40))
DRY = lin((170, 140, 90))


def gen_dandelion(rng, pal):
    parts = []
    n = int(rng.integers(6, 16))
    a0 = U(rng, 0, 2 * np.pi)
    lobed = U(rng, 0.15, 0.75)
    nl = int(rng.integers(3, 7))
    hwf = U(rng, 0.12, 0.2)
    purple = rng.random() < 0.35
    mid_f = U(rng, 0.35, 0.65)
    toothy = rng.random() < 0.6
    for i in range(n):
        q = i / max(n - 1, 1)
        L = float(np.clip(1 - 0.9 * q ** 2.2, 0.1, 1)) * U(rng, 0.8, 1.1)
        ang = a0 + i * 2.3999 + rng.normal(0, 0.15)
        base = U(rng, 0.0, 0.03) * np.array([np.cos(ang), np.sin(ang)])
        asc = U(rng, 0, 0.25) + 0.9 * q ** 2
        Lp = L * math.cos(min(asc, 1.2))
        env = lambda t: np.maximum(np.sin(np.pi * t ** 1.5) ** 0.9, 0.12 * (1 - t))
        g = leaf_geom(rng, base, ang, Lp, L * hwf * U(rng, 0.85, 1.15), env, bend=U(rng, -0.3, 0.3),
                      lobes=(nl, lobed * U(rng, 0.7, 1.1), U(rng, 0.1, 0.5), 0.15, 0.8) if lobed > 0.2 else None,
                      teeth=U(rng, 0.05, 0.18) if toothy else 0.0, nteeth=int(rng.integers(25, 50)),
                      wavy=0.04)
        zb = 0.01 + 0.05 * q
        zs = zb + (0.03 + math.sin(min(asc, 1.2)) * 0.5 * L) * g["s"] * U(rng, 0.2, 1.0)
        col = lcol(pal, rng, dv=0.2 * q - 0.05, dh=-6 * q)
        old = q < 0.4
        sf = surf(rng, ks=(0.03, 0.3), bump=(0.05, 0.3), fold=(0.05, 0.35), dome=(-0.1, 0.2),
                  tilt=(-0.1, 0.15 + asc * 0.6))
        mid_col = mix(col, lin((165, 95, 120)) if purple else PALE, mid_f)
        parts.append(leaf_part(g, zs, col, rng, sf, mid_w=g["hw"] * U(rng, 0.1, 0.18),
                               mid_col=mid_col, mid_k=U(rng, 0.5, 0.8),
                               veins=veins_pinnate(g, rng, nl + 1, fwd=0.1, reach=0.75),
                               vein_w=g["hw"] * 0.05, vein_col=PALE, vein_k=U(rng, 0.1, 0.3), groove=0.3,
                               yellow=U(rng, 0.3, 0.8) if old and rng.random() < 0.3 else 0.0,
                               necro=int(rng.integers(1, 7)) if rng.random() < 0.25 else 0,
                               burn=U(rng, 0.05, 0.15) if old and rng.random() < 0.15 else 0.0,
                               holes=int(rng.integers(1, 4)) if rng.random() < 0.12 else 0,
                               base_col=mix(mid_col, col, 0.3)))
    info = {}
    if rng.random() < 0.18:    # a flower head or bud on a scape lying out of the rosette
        ang = U(rng, 0, 2 * np.pi)
        Ls = U(rng, 0.3, 0.9)
        pts = curve([0, 0], ang, Ls, U(rng, -0.6, 0.6), 20)
        parts.append(stem_part(rng, pts, 0.012, np.linspace(0.05, 0.15, 20), PALE * 0.8))
        r = U(rng, 0.06, 0.12)
        t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
        bud = rng.random() < 0.4
        rr = r * (1 + (0.0 if bud else 0.08) * np.sin(t * 18))
        poly = pts[-1] + np.stack([np.cos(t) * rr * (0.6 if bud else 1), np.sin(t) * rr], 1) @ \
            np.array([[np.cos(ang), np.sin(ang)], [-np.sin(ang), np.cos(ang)]])
        col = lcol(pal, rng, dv=-0.1) if bud else lin((245, 200, 20))
        parts.append(part(poly, 0.18, col, surf=dict(ks=0.05, p=10, bump=0.25, fold=0, dome=0.6, tilt=0,
                                                     curl=0, sky=0.0), trans=0.4))
        info["flower"] = "bud" if bud else "yellow flower"
    return parts, info


def gen_plantain(rng, pal):
    parts = []
    lanceo = rng.random() < 0.3
    n = int(rng.integers(4, 11))
    a0 = U(rng, 0, 2 * np.pi)
    for i in range(n):
        q = i / max(n - 1, 1)
        L = float(np.clip(1 - 0.7 * q ** 1.8, 0.2, 1)) * U(rng, 0.8, 1.1)
        ang = a0 + i * 2.3999 + rng.normal(0, 0.15)
        asc = U(rng, 0.0, 0.5) + 0.6 * q
        Lp = L * math.cos(min(asc, 1.2))
        if lanceo:
            pf, hwl = U(rng, 0.08, 0.2), U(rng, 0.07, 0.12)
            a, b = 1.0, 0.8
        else:
            pf, hwl = U(rng, 0.2, 0.42), U(rng, 0.26, 0.4)
            a, b = U(rng, 0.75, 0.95), U(rng, 0.5, 0.7)
        shp = lambda t, a=a, b=b: np.sin(np.pi * np.clip(t, 0, 1) ** a) ** b
        g = leaf_geom(rng, U(rng, 0, 0.02) * np.array([np.cos(ang), np.sin(ang)]), ang, Lp,
                      Lp * (1 - pf) * hwl, shp, bend=U(rng, -0.25, 0.25), pf=pf,
                      pw=Lp * U(rng, 0.018, 0.03), wavy=U(rng, 0.02, 0.06),
                      teeth=U(rng, 0.0, 0.08) if rng.random() < 0.3 else 0.0, nteeth=int(rng.integers(6, 14)))
        zs = 0.01 + 0.05 * q + math.sin(min(asc, 1.2)) * 0.45 * L * g["s"] ** 0.8
        col = lcol(pal, rng, dv=0.12 * q)
        nv = int(rng.integers(1, 3)) if lanceo else int(rng.integers(1, 4))
        fs = np.linspace(0.25, 0.8, nv)
        sf = surf(rng, ks=(0.03, 0.25), bump=(0.05, 0.35), fold=(-0.1, 0.2), dome=(0.05, 0.4),
                  tilt=(-0.05, 0.2 + asc * 0.5))
        pcol = stemcol(pal, rng) if pal["red"] else mix(col, PALE, 0.4)
        parts.append(leaf_part(g, zs, col, rng, sf, mid_w=Lp * 0.012, mid_col=mix(col, PALE, 0.45),
                               mid_k=0.5, veins=veins_parallel(g, np.concatenate([fs, -fs])),
                               vein_w=Lp * 0.007, vein_col=mix(col, PALE, 0.35), vein_k=U(rng, 0.12, 0.35),
                               groove=U(rng, 0.2, 0.6), base_col=pcol,
                               yellow=U(rng, 0.3, 0.9) if q < 0.35 and rng.random() < 0.35 else 0.0,
                               necro=int(rng.integers(1, 9)) if rng.random() < 0.3 else 0,
                               burn=U(rng, 0.05, 0.2) if q < 0.3 and rng.random() < 0.2 else 0.0,
                               holes=int(rng.integers(1, 5)) if rng.random() < 0.15 else 0))
    info = {"variant": "lanceolate" if lanceo else "broad"}
    if rng.random() < 0.2:    # flower spikes
        for _ in range(int(rng.integers(1, 4))):
            ang = U(rng, 0, 2 * np.pi)
            pts = curve([0, 0], ang, U(rng, 0.5, 1.0), U(rng, -0.4, 0.4), 24)
            parts.append(stem_part(rng, pts, 0.01, np.linspace(0.03, 0.3, 24), mix(lcol(pal, rng), DRY, 0.3)))
            k = int(0.6 * len(pts))
            parts.append(stem_part(rng, pts[k:], 0.022, 0.32, mix(lcol(pal, rng, dv=-0.2), BROWN, 0.5)))
        info["spikes"] = True
    return parts, info


def gen_grass(rng, pal):
    parts = []
    nb = int(rng.integers(3, 21))
    rb = U(rng, 0.01, 0.05)
    a0 = U(rng, 0, 2 * np.pi)
    spread = U(rng, 0.6, 3.2)
    hw0 = U(rng, 0.008, 0.03)
    fold = U(rng, 0.15, 0.6)
    dead_p = U(rng, 0.0, 0.25)
    order = []
    for i in range(nb):
        ang = a0 + rng.normal(0, spread)
        up = rng.random() < 0.25
        L = U(rng, 0.12, 0.35) if up else U(rng, 0.45, 1.0)
        kink = (U(rng, 0.15, 0.6), rng.choice([-1, 1]) * U(rng, 0.4, 1.6)) if rng.random() < 0.3 else None
        base = rb * U(rng, 0, 1) * np.array([np.cos(ang), np.sin(ang)])
        hw = hw0 * U(rng, 0.7, 1.3) * (1.3 if up else 1.0)
        shp = lambda t: (1 - t ** 2.2) ** 0.7 * (0.55 + 0.45 * np.clip(t / 0.06, 0, 1))
        g = leaf_geom(rng, base, ang, L, hw, shp, bend=U(rng, -1.3, 1.3) * (0.4 if up else 1.0), kink=kink,
                      wavy=0.02, asym=0.05, n=90)
        hmax = (U(rng, 0.25, 0.5) if up else U(rng, 0.05, 0.3)) * L
        s = g["s"]
        sk = kink[0] if kink else U(rng, 0.2, 0.5)
        zs = np.where(s < sk, hmax * np.sin(np.pi / 2 * s / sk), hmax * (1 - 0.85 * np.clip((s - sk) / (1 - sk), 0, 1) ** 1.3))
        zs = zs + 0.01 + (0.5 * hmax * s if up else 0)
        dead = rng.random() < dead_p
        col = mix(DRY, BROWN, U(rng, 0, 0.5)) * U(rng, 0.8, 1.2) if dead else lcol(pal, rng)
        sf = surf(rng, ks=(0.03, 0.2), p=(25, 80), bump=(0.0, 0.04), fold=(fold * 0.7, fold * 1.2),
                  dome=(0.0, 0.2), tilt=(-0.1, 0.3 if up else 0.1), curl=(0, 0.1), sky=(0.0, 0.05))
        pr = part(g["poly"], zpoly(g, zs), col, axis=(g["c"][0], g["c"][-1]), surf=sf, mid=g["c"][:-3],
                  mid_w=hw * 0.35, mid_col=mix(col, PALE, 0.35), mid_k=0.35,
                  veins=veins_parallel(g, [0.45, -0.45, 0.8, -0.8], s0=0.0, s1=0.9), vein_w=hw * 0.15,
                  vein_col=mix(col, PALE, 0.2), vein_k=0.15, groove=0.08,
                  yellow=U(rng, 0.4, 1.0) if (not dead and rng.random() < 0.3) else 0.0,
                  ycol=mix(DRY, YEL, 0.4), trans=0.35)
        pr["tipdry"] = True
        order.append(pr)
    parts.extend(order)
    scol = hsv_lin(U(rng, 330, 370), U(rng, 0.3, 0.6), U(rng, 0.35, 0.55)) if pal["red"] else \
        mix(lcol(pal, rng), PALE, 0.5)
    for j in range(int(rng.integers(2, 6))):    # sheaths at the base
        ang = U(rng, 0, 2 * np.pi)
        g = leaf_geom(rng, [0, 0], ang, U(rng, 0.03, 0.08), hw0 * U(rng, 1.2, 1.8),
                      lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 0.6) ** 0.5, n=30)
        parts.append(part(g["poly"], 0.02, scol * U(rng, 0.8, 1.2), axis=(g["c"][0], g["c"][-1]),
                          surf=surf(rng, ks=(0.05, 0.3), fold=(0.1, 0.4)), mid=g["c"]))
    return parts, {"blades": nb}


def gen_clover(rng, pal):
    parts = []
    n = int(rng.integers(2, 8))
    a0 = U(rng, 0, 2 * np.pi)
    sector = U(rng, 1.2, 2 * np.pi) if rng.random() < 0.55 else 2 * np.pi
    l0 = U(rng, 0.22, 0.32)                     # leaflet length
    pet_f = U(rng, 0.3, 1.0)                    # petiole length / leaf size (2 * leaflet length)
    chev = rng.random() < 0.75
    chev_col = mix(PALE, lin((235, 240, 225)), U(rng, 0, 1)) if rng.random() < 0.85 else lin((120, 50, 60))
    pcol = stemcol(pal, rng)
    chev_f = U(rng, 0.45, 0.85)
    for i in range(n):
        ang = a0 + (sector * (i + U(rng, -0.3, 0.3)) / n if sector < 6 else i * 2 * np.pi / n + rng.normal(0, 0.3))
        l = l0 * U(rng, 0.75, 1.15)
        lp = pet_f * 2 * l * U(rng, 0.8, 1.2)
        zl = U(rng, 0.1, 0.45)
        pts = curve([0, 0], ang, lp, U(rng, -0.6, 0.6), 20, rng, 0.1)
        parts.append(stem_part(rng, pts, U(rng, 0.008, 0.014), np.linspace(0.01, zl, 20), pcol * U(rng, 0.85, 1.15)))
        E = pts[-1]
        la = math.atan2(*(pts[-1] - pts[-2])[::-1]) + rng.normal(0, 0.4)
        col = lcol(pal, rng)
        spread = U(rng, 1.85, 2.25)
        nlf = 3 if rng.random() > 0.08 else 2   # sometimes a half-open leaf
        for j, da in enumerate((0.0, spread, -spread)[:nlf]):
            aj = la + da + rng.normal(0, 0.08)
            lj = l * U(rng, 0.9, 1.08) * (0.75 if nlf == 2 else 1)
            shp = lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 1.36) ** 0.6
            g = leaf_geom(rng, E + 0.02 * l * np.array([np.cos(aj), np.sin(aj)]), aj, lj,
                          lj * U(rng, 0.36, 0.46) * (0.6 if nlf == 2 else 1), shp, bend=U(rng, -0.1, 0.1),
                          notch=U(rng, 0.04, 0.1), teeth=U(rng, 0.02, 0.05), nteeth=int(rng.integers(20, 35)),
                          wavy=0.02, asym=0.06, n=60)
            cv_ = None
            if chev:
                c, nr, s = g["c"], g["nrm"], g["s"]
                ia, ib = int(np.searchsorted(s, U(rng, 0.3, 0.4))), int(np.searchsorted(s, U(rng, 0.55, 0.68)))
                wl, wr = g["wl"][ib] * 0.8, g["wr"][ib] * 0.8
                cv_ = [np.array([c[ib] + nr[ib] * wl, c[ia], c[ib] - nr[ib] * wr])]
            zs = zl + U(rng, -0.03, 0.03) + U(rng, -0.06, 0.05) * g["s"]
            sf = surf(rng, ks=(0.05, 0.35), bump=(0.0, 0.2), fold=(0.0, 0.35), dome=(-0.05, 0.25),
                      tilt=(-0.35, 0.35))
            parts.append(leaf_part(g, zs, col * U(rng, 0.92, 1.08), rng, sf, mid_w=lj * 0.02,
                                   mid_col=mix(col, PALE, 0.5), mid_k=0.4,
                                   veins=veins_pinnate(g, rng, int(rng.integers(7, 12)), s0=0.05, s1=0.92,
                                                       fwd=0.08, reach=0.95),
                                   vein_w=lj * 0.01, vein_col=mix(col, PALE, 0.5), vein_k=U(rng, 0.15, 0.35),
                                   groove=0.2, chev=cv_, chev_w=lj * U(rng, 0.03, 0.06), chev_col=mix(col, chev_col, chev_f),
                                   chev_k=U(rng, 0.35, 0.7),
                                   yellow=U(rng, 0.3, 0.8) if rng.random() < 0.12 else 0.0,
                                   necro=int(rng.integers(1, 4)) if rng.random() < 0.15 else 0,
                                   holes=1 if rng.random() < 0.08 else 0))
    t = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    parts.append(part(np.stack([np.cos(t), np.sin(t)], 1) * 0.02, 0.005, mix(pcol, BROWN, 0.4)))
    return parts, {"leaves": n, "crown_in_leaves": bool(sector >= 6)}


def gen_seedling(rng, pal):
    parts = []
    a0 = U(rng, 0, 2 * np.pi)
    hs = U(rng, 0.15, 0.6)                       # hypocotyl height (units of cotyledon length)
    shape = rng.choice(["oval", "spatulate", "kidney", "long"])
    col = lcol(pal, rng, dv=U(rng, 0.0, 0.2), dh=-U(rng, 0, 8))
    scol = hsv_lin(U(rng, 335, 370), U(rng, 0.3, 0.6), U(rng, 0.4, 0.65)) if pal["red"] or rng.random() < 0.3 \
        else mix(col, PALE, 0.5)
    for j in range(2):
        ang = a0 + j * np.pi + rng.normal(0, 0.15)
        L = 0.48 * U(rng, 0.9, 1.05)
        if shape == "oval":
            shp, hw, notch = (lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 0.9) ** 0.6), U(rng, 0.28, 0.42), 0.0
        elif shape == "spatulate":
            shp, hw, notch = (lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 1.6) ** 0.7), U(rng, 0.25, 0.35), 0.0
        elif shape == "kidney":
            shp, hw, notch = (lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 1.2) ** 0.5), U(rng, 0.45, 0.6), U(rng, 0.05, 0.12)
        else:
            shp, hw, notch = (lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 0.8) ** 0.8), U(rng, 0.14, 0.22), 0.0
        g = leaf_geom(rng, 0.03 * np.array([np.cos(ang), np.sin(ang)]), ang, L, L * hw, shp,
                      bend=U(rng, -0.2, 0.2), notch=notch, pf=U(rng, 0.05, 0.18), pw=L * 0.04, wavy=0.03)
        up = U(rng, -0.05, 0.45)
        zs = hs + up * g["s"] * L
        sf = surf(rng, ks=(0.05, 0.35), p=(15, 50), bump=(0.0, 0.1), fold=(0.0, 0.3), dome=(0.1, 0.5),
                  tilt=(up * 0.5, up * 0.9 + 0.05), curl=(0.0, 0.3))
        parts.append(leaf_part(g, zs, col * U(rng, 0.93, 1.07), rng, sf, mid_w=L * 0.02,
                               mid_col=mix(col, PALE, 0.4), mid_k=U(rng, 0.1, 0.4),
                               yellow=U(rng, 0.3, 0.7) if rng.random() < 0.2 else 0.0,
                               necro=int(rng.integers(1, 3)) if rng.random() < 0.1 else 0,
                               base_col=scol if rng.random() < 0.4 else None))
    info = {"cotyledons": str(shape)}
    ntl = int(rng.choice([0, 1, 2], p=[0.5, 0.2, 0.3]))
    tcol = lcol(pal, rng, dv=-0.15)
    for j in range(ntl):
        ang = a0 + np.pi / 2 + j * np.pi + rng.normal(0, 0.2)
        L = U(rng, 0.1, 0.3)
        g = leaf_geom(rng, [0, 0], ang, L, L * U(rng, 0.3, 0.45),
                      lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 0.8) ** 0.7, pf=0.15, pw=L * 0.06,
                      teeth=U(rng, 0.1, 0.3), nteeth=int(rng.integers(4, 9)), wavy=0.05)
        sf = surf(rng, ks=(0.05, 0.3), bump=(0.2, 0.6), fold=(0.1, 0.4))
        parts.append(leaf_part(g, hs + 0.05 + 0.2 * L * g["s"], tcol, rng, sf, mid_w=L * 0.04,
                               mid_col=mix(tcol, PALE, 0.3), mid_k=0.3,
                               veins=veins_pinnate(g, rng, 3), vein_w=L * 0.02, vein_col=mix(tcol, PALE, 0.3),
                               vein_k=0.25, groove=0.5))
    info["true_leaves"] = ntl
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    parts.append(part(np.stack([np.cos(t), np.sin(t)], 1) * 0.018, hs - 0.01, mix(scol, col, 0.5),
                      vshadow=(0.015, hs), surf=dict(ks=0.1, p=20, bump=0, fold=0, dome=0.8, tilt=0, curl=0, sky=0.02)))
    return parts, info


def gen_chickweed(rng, pal):
    parts = []
    leaves = []
    ns = int(rng.integers(3, 8))
    a0 = U(rng, 0, 2 * np.pi)
    scol = stemcol(pal, rng)
    lsz = U(rng, 0.09, 0.16)
    shp = lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 0.8) ** 0.75

    def branch(base, ang, length, depth, z0):
        pts = curve(base, ang, length, U(rng, -1.0, 1.0), 30, rng, 0.15)
        zs = np.linspace(z0, z0 + U(rng, 0.02, 0.12), 30)
        parts.append(stem_part(rng, pts, U(rng, 0.005, 0.009), zs, scol * U(rng, 0.85, 1.15)))
        nn = max(2, int(length / U(rng, 0.1, 0.16)))
        rot = U(rng, 0, np.pi / 2)
        for j in range(1, nn + 1):
            t = j / nn
            k = min(int(t * 29), 29)
            dvec = pts[min(k + 1, 29)] - pts[max(k - 1, 0)]
            sa = math.atan2(dvec[1], dvec[0])
            L = lsz * (0.55 + 0.6 * math.sin(np.pi * min(t, 0.95) ** 0.7)) * U(rng, 0.8, 1.15) * (1 - 0.25 * depth)
            pa = sa + np.pi / 2 + ((j % 2) * rot) + rng.normal(0, 0.25)
            for sgn in (0, np.pi):
                a = pa + sgn + rng.normal(0, 0.15)
                g = leaf_geom(rng, pts[k], a, L, L * U(rng, 0.28, 0.4), shp, bend=U(rng, -0.3, 0.3),
                              pf=U(rng, 0.0, 0.3) * (1 - t), pw=L * 0.05, wavy=0.03, n=36)
                leaves.append((zs[k] + 0.01 + 0.02 * t, g, L))
            if depth < 1 and 0.2 < t < 0.8 and rng.random() < 0.3:
                branch(pts[k], sa + rng.choice([-1, 1]) * U(rng, 0.5, 1.1), length * (1 - t) * U(rng, 0.6, 1.0),
                       depth + 1, zs[k])
        if rng.random() < 0.7:    # terminal bud cluster
            for _ in range(int(rng.integers(2, 4))):
                a = U(rng, 0, 2 * np.pi)
                L = lsz * U(rng, 0.3, 0.55)
                g = leaf_geom(rng, pts[-1], a, L, L * 0.4, shp, n=24)
                leaves.append((zs[-1] + 0.03, g, L))

    for i in range(ns):
        branch([0, 0], a0 + i * 2 * np.pi / ns + rng.normal(0, 0.4), U(rng, 0.55, 1.0), 0, 0.01)
    col0 = lcol(pal, rng, dv=0.05)
    for z, g, L in sorted(leaves, key=lambda x: x[0]):
        col = col0 * U(rng, 0.88, 1.12)
        sf = surf(rng, ks=(0.05, 0.35), bump=(0.0, 0.2), fold=(0.0, 0.3), dome=(0.05, 0.4), tilt=(-0.2, 0.3))
        parts.append(leaf_part(g, z + 0.02 * g["s"], col, rng, sf, mid_w=L * 0.05, mid_col=mix(col, PALE, 0.35),
                               mid_k=0.35, yellow=U(rng, 0.3, 0.8) if rng.random() < 0.08 else 0.0))
    return parts, {"stems": ns, "leaves": len(leaves)}


def gen_amaranth(rng, pal):
    parts = []
    n = int(rng.integers(4, 11))
    a0 = U(rng, 0, 2 * np.pi)
    H = U(rng, 0.3, 0.9)
    pcol = stemcol(pal, rng)
    red_mid = pal["red"] and rng.random() < 0.6
    vmark = rng.random() < 0.2
    for i in range(n):
        q = i / max(n - 1, 1)
        ang = a0 + i * 2.3999 + rng.normal(0, 0.2)
        za = 0.02 + H * q
        L = 0.62 * (1 - 0.75 * q) * U(rng, 0.85, 1.1)
        lp = L * U(rng, 0.35, 0.8) * (1 - 0.7 * q)
        droop = U(rng, 0.1, 0.5) * L
        pts = curve([0, 0], ang, lp, U(rng, -0.3, 0.3), 16)
        parts.append(stem_part(rng, pts, 0.012 * (1 - 0.5 * q), np.linspace(za, za + 0.1 * lp, 16),
                               pcol * U(rng, 0.9, 1.1)))
        la = ang + rng.normal(0, 0.15)
        shp = lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 0.85) ** 0.75
        g = leaf_geom(rng, pts[-1], la, L, L * U(rng, 0.3, 0.42), shp, bend=U(rng, -0.25, 0.25),
                      notch=U(rng, 0.02, 0.05) if rng.random() < 0.4 else 0.0, wavy=U(rng, 0.02, 0.06))
        zs = za + 0.1 * lp - droop * g["s"] ** 1.5
        col = lcol(pal, rng, dv=0.1 * q)
        sf = surf(rng, ks=(0.03, 0.25), bump=(0.1, 0.4), fold=(0.05, 0.35), dome=(0.0, 0.3),
                  tilt=(-0.35, -0.05))
        cv_ = None
        if vmark:
            c, nr, s = g["c"], g["nrm"], g["s"]
            ia, ib = int(np.searchsorted(s, 0.45)), int(np.searchsorted(s, 0.65))
            cv_ = [np.array([c[ib] + nr[ib] * g["wl"][ib] * 0.6, c[ia], c[ib] - nr[ib] * g["wr"][ib] * 0.6])]
        parts.append(leaf_part(g, zs, col, rng, sf, mid_w=L * 0.025,
                               mid_col=pcol if red_mid else mix(col, PALE, 0.5), mid_k=0.6,
                               veins=veins_pinnate(g, rng, int(rng.integers(5, 9)), fwd=0.2), vein_w=L * 0.012,
                               vein_col=mix(col, PALE, 0.45), vein_k=U(rng, 0.25, 0.5), groove=U(rng, 0.4, 1.0),
                               chev=cv_, chev_w=L * 0.06, chev_col=mix(col, PALE, 0.6), chev_k=0.5,
                               yellow=U(rng, 0.3, 0.8) if q < 0.3 and rng.random() < 0.25 else 0.0,
                               necro=int(rng.integers(1, 6)) if rng.random() < 0.2 else 0,
                               holes=int(rng.integers(1, 4)) if rng.random() < 0.15 else 0))
    for j in range(int(rng.integers(2, 5))):    # apical bud
        a = U(rng, 0, 2 * np.pi)
        L = U(rng, 0.04, 0.09)
        g = leaf_geom(rng, [0, 0], a, L, L * 0.35, lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 0.8) ** 0.7, n=20)
        parts.append(leaf_part(g, H + 0.05, lcol(pal, rng, dv=0.1), rng, surf(rng), mid_w=L * 0.05,
                               mid_col=PALE, mid_k=0.3))
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    parts.append(part(np.stack([np.cos(t), np.sin(t)], 1) * 0.02, 0.01, pcol, vshadow=(0.02, H)))
    return parts, {"leaves": n, "v_mark": vmark}


GEN = {"dandelion": gen_dandelion, "plantain": gen_plantain, "grass": gen_grass, "clover": gen_clover,
       "seedling": gen_seedling, "chickweed": gen_chickweed, "amaranth": gen_amaranth}


# ----------------------------------------------------------------------------- plant renderer
class Light:
    def __init__(self, rng):
        self.sun = rng.random() < 0.55
        az = U(rng, 0, 2 * np.pi)
        self.elev = math.radians(U(rng, 22, 72)) if self.sun else math.radians(U(rng, 50, 85))
        ce = math.cos(self.elev)
        self.L = np.array([ce * math.cos(az), ce * math.sin(az), math.sin(self.elev)])
        self.sdir = -np.array([math.cos(az), math.sin(az)])
        self.cot = min(1.0 / math.tan(self.elev), 2.5) if self.sun else 0.0
        if self.sun:
            self.sun_rgb = lin((255, 246, 232)) * F32(U(rng, 0.9, 1.1))
            self.sky_rgb = lin((150, 180, 240)) * F32(U(rng, 0.25, 0.45))
        else:    # overcast / shade: sky light plus a weak directional part, no hard shadows
            tint = U(rng, 0, 1)
            sky = mix(lin((240, 242, 245)), lin((205, 220, 250)), tint)
            self.sun_rgb = sky * F32(U(rng, 0.3, 0.7))
            self.sky_rgb = sky * F32(1.0)

    def desc(self):
        return f"sun elev {math.degrees(self.elev):.0f}" if self.sun else "overcast"


def _region(P, pad, H, W):
    x0 = max(int(np.floor(P[:, 0].min() - pad)), 0)
    y0 = max(int(np.floor(P[:, 1].min() - pad)), 0)
    x1 = min(int(np.ceil(P[:, 0].max() + pad)) + 1, W)
    y1 = min(int(np.ceil(P[:, 1].max() + pad)) + 1, H)
    return x0, y0, x1, y1


def _lines(shape, polys, off, width, value=1.0):
    img = np.zeros(shape, F32)
    th = max(1, int(round(width)))
    val = float(value) * (min(1.0, width) if width < 1 else 1.0)
    for pl in polys:
        cv2.polylines(img, [pts16(pl - off)], False, val, th, cv2.LINE_AA, 4)
    return img


def render_plant(parts, k, light, V, rng, canvas_spec=True):
    """Rasterise plant parts (normalised coords, centre at 0) at k px per unit into a patch.
    Returns dict with buffers alb(3), amb, sun, spec, sspec, alpha, soil_sun, soil_amb and off
    (patch px of the plant centre)."""
    allp = np.vstack([p["poly"] for p in parts]) * k
    R = float(np.max(np.linalg.norm(allp, axis=1)))
    zmax = max(float(p["zv"].max()) for p in parts) * k
    disp = light.sdir * light.cot * zmax
    lo = np.minimum(allp.min(0), allp.min(0) + disp)
    hi = np.maximum(allp.max(0), allp.max(0) + disp)
    pad = 0.15 * R + 6
    off = -lo + pad
    W, H = int(np.ceil(hi[0] - lo[0] + 2 * pad)) + 1, int(np.ceil(hi[1] - lo[1] + 2 * pad)) + 1
    B = dict(alb=np.zeros((H, W, 3), F32), amb=np.zeros((H, W), F32), sun=np.zeros((H, W), F32),
             spec=np.zeros((H, W), F32), sspec=np.zeros((H, W), F32), alpha=np.zeros((H, W), F32),
             zb=np.zeros((H, W), F32))
    soil_sh = np.zeros((H, W), np.uint8)
    cover = np.zeros((H, W), np.uint8)
    Lv = light.L
    Hs = (Lv + V) / np.linalg.norm(Lv + V)
    Hk = (np.array([0, 0, 1.0]) + V) / np.linalg.norm(np.array([0, 0, 1.0]) + V)
    ao_k = U(rng, 0.2, 0.35) if light.sun else U(rng, 0.3, 0.5)
    drawn = False
    zsum = []
    for pt in sorted(parts, key=lambda p: p["z"]):
        P = pt["poly"] * k + off
        ZV = pt["zv"] * k
        thin_px = (pt["thin"] * 2 * k) if pt["thin"] is not None else None
        wguess = max(thin_px if thin_px else 2 * pt.get("hwpx", 0) or 4.0, 1.0)
        sa = max(0.6, min(0.04 * R, 0.6 * wguess))
        x0, y0, x1, y1 = _region(P, 3 * sa + 3, H, W)
        if x1 - x0 < 3 or y1 - y0 < 3:
            continue
        o = np.array([x0, y0], float)
        h, w = y1 - y0, x1 - x0
        m8 = np.zeros((h, w), np.uint8)
        if thin_px is not None and thin_px < 1.5:
            cv2.polylines(m8, [pts16(pt["mid"] * k + off - o)], False, int(255 * max(0.3, thin_px / 1.5)), 1,
                          cv2.LINE_AA, 4)
        else:
            cv2.fillPoly(m8, [pts16(P - o)], 255, cv2.LINE_AA, 4)
        if not m8.any():
            continue
        # holes (insect damage)
        if pt["holes"] and pt["mid"] is not None:
            mid = pt["mid"] * k + off - o
            for _ in range(pt["holes"]):
                j = int(rng.integers(len(mid) // 4, max(len(mid) // 4 + 1, len(mid) - 2)))
                dt0 = dist_in(m8 > 127)
                wl = float(dt0.max())
                ctr = mid[j] + rng.normal(0, 0.35 * wl, 2)
                r = U(rng, 0.1, 0.35) * wl
                if r < 1.0:
                    continue
                tt = np.linspace(0, 2 * np.pi, 14, endpoint=False)
                hp = ctr + np.stack([np.cos(tt), np.sin(tt)], 1) * (r * (1 + 0.3 * rng.standard_normal(14)))[:, None]
                cv2.fillPoly(m8, [pts16(hp)], 0, cv2.LINE_AA, 4)
        m = m8.astype(F32) / 255.0
        # --- shadows / occlusion of this part onto the already drawn (lower) plant parts
        if drawn:
            ar = B["alpha"][y0:y1, x0:x1]
            below = ar > 0.5
            if below.any():
                zref = float(np.median(B["zb"][y0:y1, x0:x1][below]))
                if light.sun:
                    dz = np.maximum(ZV - zref, 0.0)
                    if dz.max() > 0.3:
                        Ps = P + light.sdir[None, :] * (dz * light.cot)[:, None]
                        sig = 0.5 + 0.012 * float(dz.mean())
                        sx0, sy0, sx1, sy1 = _region(Ps, 3 * sig + 2, H, W)
                        if sx1 - sx0 > 2 and sy1 - sy0 > 2:
                            sm8 = np.zeros((sy1 - sy0, sx1 - sx0), np.uint8)
                            if thin_px is not None and thin_px < 1.5:
                                sm8 = (_lines(sm8.shape, [Ps[: len(Ps) // 2]], np.array([sx0, sy0]), thin_px) * 255).astype(np.uint8)
                            else:
                                cv2.fillPoly(sm8, [pts16(Ps - [sx0, sy0])], 255, cv2.LINE_AA, 4)
                            sm = blur(sm8.astype(F32) / 255.0, sig)
                            B["sun"][sy0:sy1, sx0:sx1] *= 1 - 0.85 * sm
                            B["spec"][sy0:sy1, sx0:sx1] *= 1 - sm
                aom = blur(m, sa)
                B["amb"][y0:y1, x0:x1] *= 1 - ao_k * aom
                if not light.sun:
                    B["sun"][y0:y1, x0:x1] *= 1 - 1.5 * ao_k * aom
                B["sspec"][y0:y1, x0:x1] *= 1 - 0.5 * aom
        # --- surface of this part
        bin8 = (m8 > 127).astype(np.uint8)
        dt = dist_in(bin8)
        wmax = max(float(dt.max()), 0.5)
        if pt["mid"] is not None:
            mimg = np.full((h, w), 255, np.uint8)
            cv2.polylines(mimg, [np.round(pt["mid"] * k + off - o).astype(np.int32)], False, 0, 1)
            dmid = cv2.distanceTransform(mimg, cv2.DIST_L2, 3)
        else:
            dmid = wmax - dt
        sf = pt["surf"]
        along = np.zeros((h, w), F32)
        alen = 1.0
        if pt["axis"] is not None:
            a, b = pt["axis"][0] * k + off - o, pt["axis"][1] * k + off - o
            ax = b - a
            alen = max(float(np.linalg.norm(ax)), 1.0)
            ax = ax / alen
            xs = np.arange(w, dtype=F32)[None, :] - F32(a[0])
            ys = np.arange(h, dtype=F32)[:, None] - F32(a[1])
            along = xs * F32(ax[0]) + ys * F32(ax[1])
        veins = None
        vw_px = pt["vein_w"] * k
        if pt["veins"] and vw_px > 0.25:
            veins = blur(_lines((h, w), [v * k + off - o for v in pt["veins"]], o * 0, vw_px), 0.5) * m
        if pt["typ"] == "stem":
            hf = np.sqrt(np.clip(wmax * wmax - dmid * dmid, 0, None)) * F32(0.9)
        else:
            hf = F32(sf["fold"]) * dmid
            hf += F32(sf["dome"] * wmax) * np.sqrt(np.clip(dt / wmax, 0, 1))
            hf += F32(sf["tilt"]) * along
            hf += F32(sf["curl"] * wmax) * np.exp(-dt / F32(0.15 * wmax + 0.7))
            if sf["bump"] > 0:
                hf += F32(sf["bump"] * 0.25 * wmax) * noise((h, w), max(1.5, 0.25 * wmax), rng)
            if veins is not None:
                hf -= F32(pt["groove"] * max(1.0, vw_px)) * veins
        # extend the height field outward so the outline does not produce a false rim
        wgt = blur(m, 2.0) + 1e-4
        hf = hf * m + (blur(hf * m, 2.0) / wgt) * (1 - m)
        gx = cv2.Sobel(hf, cv2.CV_32F, 1, 0, ksize=3) * F32(0.125)
        gy = cv2.Sobel(hf, cv2.CV_32F, 0, 1, ksize=3) * F32(0.125)
        inv = 1.0 / np.sqrt(1 + gx * gx + gy * gy)
        nx, ny, nz = -gx * inv, -gy * inv, inv
        ndl = nx * F32(Lv[0]) + ny * F32(Lv[1]) + nz * F32(Lv[2])
        sunv = np.clip(ndl, 0, None) + F32(pt["trans"]) * np.clip(-ndl, 0, None)
        ambv = 0.5 + 0.5 * nz
        ksm = F32(sf["ks"]) * np.clip(0.55 + 0.7 * noise((h, w), max(1.5, 0.6 * wmax), rng), 0, 2.2)
        if light.sun:
            nh = np.clip(nx * F32(Hs[0]) + ny * F32(Hs[1]) + nz * F32(Hs[2]), 0, 1)
            spec = ksm * nh ** F32(sf["p"])
        else:
            spec = np.zeros_like(ndl)
        nh2 = np.clip(nx * F32(Hk[0]) + ny * F32(Hk[1]) + nz * F32(Hk[2]), 0, 1)
        sspec = F32(sf["sky"]) * (0.5 + ksm) * nh2 ** F32(6.0)
        # --- albedo
        col = pt["col"]
        var = 1 + 0.09 * noise((h, w), max(1.5, 0.5 * wmax), rng) + 0.035 * noise((h, w), 1.2, rng)
        A = col[None, None, :] * var[..., None]
        if pt["base_col"] is not None and pt["axis"] is not None:
            t = np.clip(1 - along / F32(0.22 * alen), 0, 1)[..., None] * F32(0.8)
            A = mix(A, pt["base_col"][None, None, :], t)
        if veins is not None:
            A = mix(A, pt["vein_col"][None, None, :] * var[..., None], (F32(pt["vein_k"]) * veins)[..., None])
        mw_px = pt["mid_w"] * k
        if pt["mid"] is not None and pt["mid_col"] is not None and mw_px > 0.3 and pt["typ"] != "stem":
            mv = blur(_lines((h, w), [pt["mid"] * k + off - o], o * 0, mw_px), 0.6) * m
            A = mix(A, pt["mid_col"][None, None, :] * var[..., None], (F32(pt["mid_k"]) * mv)[..., None])
        if pt["chev"] is not None and pt["chev_w"] * k > 0.5:
            cm = blur(_lines((h, w), [c * k + off - o for c in pt["chev"]], o * 0, pt["chev_w"] * k),
                      0.25 * pt["chev_w"] * k + 0.3) * m
            A = mix(A, pt["chev_col"][None, None, :], (F32(pt.get("chev_k", 0.6)) * cm)[..., None])
        if pt["yellow"] > 0:
            ycol = pt["ycol"] if pt["ycol"] is not None else YEL
            edge = np.clip(1 - dt / F32(0.5 * wmax + 1), 0, 1) ** 1.5
            tip = np.clip((along / F32(alen) - 0.5) / 0.5, 0, 1)
            yv = np.clip(F32(pt["yellow"]) * (0.5 * edge + 0.7 * tip) * (0.7 + 0.5 * noise((h, w), max(1.5, wmax), rng)),
                         0, 0.9)
            A = mix(A, mix(ycol, DRY, 0.3)[None, None, :] * var[..., None], yv[..., None])
        if pt.get("tipdry"):
            tip = np.clip((along / F32(alen) - 0.9) / 0.1, 0, 1)
            A = mix(A, DRY[None, None, :], tip[..., None])
        if pt["necro"] and wmax > 1.5:
            idx = np.flatnonzero(bin8)
            sp = np.zeros((h, w), F32)
            halo = np.zeros((h, w), F32)
            for _ in range(pt["necro"]):
                j = int(rng.choice(idx))
                cy, cx = divmod(j, w)
                r = U(rng, 0.06, 0.25) * wmax + 0.6
                cv2.circle(sp, (cx * 16, cy * 16), int(r * 16), 1.0, -1, cv2.LINE_AA, 4)
                cv2.circle(halo, (cx * 16, cy * 16), int(r * 1.8 * 16), 1.0, -1, cv2.LINE_AA, 4)
            sp = blur(sp, 0.05 * wmax + 0.7) * m
            halo = blur(halo, 0.2 * wmax + 0.5) * m
            A = mix(A, YEL[None, None, :] * 0.7, (0.35 * halo)[..., None])
            A = mix(A, (BROWN * F32(U(rng, 0.6, 1.2)))[None, None, :], np.clip(sp * 1.1, 0, 0.9)[..., None])
        if pt["burn"] > 0:
            bm = np.clip(1 - dt / F32(pt["burn"] * wmax + 0.8), 0, 1) * (0.6 + 0.4 * noise((h, w), 2, rng).clip(-1, 1))
            A = mix(A, BROWN[None, None, :], np.clip(bm, 0, 1)[..., None])
        # --- composite
        mm = m[..., None]
        B["alb"][y0:y1, x0:x1] = B["alb"][y0:y1, x0:x1] * (1 - mm) + A * mm
        for key, val in (("amb", ambv), ("sun", sunv), ("spec", spec), ("sspec", sspec)):
            B[key][y0:y1, x0:x1] = B[key][y0:y1, x0:x1] * (1 - m) + val * m
        ar = B["alpha"][y0:y1, x0:x1]
        B["alpha"][y0:y1, x0:x1] = ar + m * (1 - ar)
        B["zb"][y0:y1, x0:x1] = np.where(m > 0.5, F32(pt["z"] * k), B["zb"][y0:y1, x0:x1])
        drawn = True
        # --- shadow on the soil and soil cover
        if thin_px is not None and thin_px < 1.5:
            cl = pt["mid"] * k + off
            nmid = len(cl)
            zc = ZV[:nmid]
            cv2.polylines(cover, [pts16(cl)], False, 255, 1, cv2.LINE_AA, 4)
            if light.sun:
                cv2.polylines(soil_sh, [pts16(cl + light.sdir[None] * (zc * light.cot)[:, None])], False,
                              int(255 * max(0.3, thin_px / 1.5)), 1, cv2.LINE_AA, 4)
        else:
            cv2.fillPoly(cover, [pts16(P)], 255, cv2.LINE_AA, 4)
            if light.sun:
                cv2.fillPoly(soil_sh, [pts16(P + light.sdir[None] * (ZV * light.cot)[:, None])], 255, cv2.LINE_AA, 4)
        if pt["vshadow"] is not None and light.sun:
            r, hh = pt["vshadow"]
            p0 = off
            p1 = off + light.sdir * hh * k * light.cot
            cv2.line(soil_sh, tuple(pts16(p0)), tuple(pts16(p1)), 255, max(1, int(round(2 * r * k))), cv2.LINE_AA, 4)
        zsum.append(float(ZV.mean()))
    zm = float(np.mean(zsum)) if zsum else 0.0
    sh = blur(soil_sh.astype(F32) / 255.0, 0.6 + 0.01 * zm * light.cot)
    cv_ = cover.astype(F32) / 255.0
    soil_amb = 1 - np.clip(0.55 * blur(cv_, 0.015 * R + 0.8) + 0.35 * blur(cv_, 0.08 * R + 1.5), 0, 0.85)
    B["soil_sun"] = 1 - 0.93 * sh if light.sun else 1 - 0.9 * blur(cv_, 0.1 * R + 1)
    B["soil_amb"] = soil_amb
    B["off"] = off
    B["R"] = R
    del B["zb"]
    return B


# ----------------------------------------------------------------------------- soil renderer
SOILS = {"brown loam": (105, 80, 60), "dark humus": (58, 47, 40), "grey clay": (122, 116, 108),
         "reddish": (140, 84, 60), "sandy": (178, 152, 118)}


def voronoi_labels(shape, cpx, rng, warp=0.3, fine=0.4):
    """Voronoi cells of random seeds (mean spacing cpx), with boundaries made irregular by a
    noise displacement. Returns labels (int32) and the distance to the nearest cell boundary."""
    H, W = shape
    n = int(min(H * W / (cpx * cpx) * 1.2, 400000)) + 1
    src = np.full(shape, 255, np.uint8)
    src[rng.integers(0, H, n), rng.integers(0, W, n)] = 0
    _, lab = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, cv2.DIST_MASK_5, labelType=cv2.DIST_LABEL_PIXEL)
    if warp > 0:
        gx, gy = np.meshgrid(np.arange(W, dtype=F32), np.arange(H, dtype=F32))
        a = F32(warp * cpx)
        sc2 = max(1.5, 0.25 * cpx) if fine > 0.2 else 3.0
        mx = gx + a * (noise(shape, max(1.5, 0.7 * cpx), rng) + fine * noise(shape, sc2, rng))
        my = gy + a * (noise(shape, max(1.5, 0.7 * cpx), rng) + fine * noise(shape, sc2, rng))
        lab = cv2.remap(lab.astype(F32), mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REFLECT).astype(np.int32)
    edge = np.zeros(shape, np.uint8)
    edge[:, 1:] |= (lab[:, 1:] != lab[:, :-1])
    edge[1:, :] |= (lab[1:, :] != lab[:-1, :])
    de = cv2.distanceTransform((1 - edge).astype(np.uint8), cv2.DIST_L2, 3)
    return lab, de


def worley_bumps(shape, cpx, rng):
    """Rounded clods / crumbs: height 0 at the cell boundaries rising to a random per-cell height."""
    lab, de = voronoi_labels(shape, cpx, rng)
    hv = rng.uniform(0.35, 1.0, int(lab.max()) + 1).astype(F32)
    t = np.sqrt(np.clip(de / F32(0.4 * cpx), 0, 1))
    bump = hv[lab] * t * (0.8 + 0.2 * noise(shape, max(1.5, 0.3 * cpx), rng))
    bump = blur(bump, 0.06 * cpx)
    return bump, hv[lab]


def render_soil(Hc, Wc, ppm, light, rng, keep):
    """Soil on the ground canvas (ppm canvas px per metre). keep = (x, y, r) canvas region of the
    weed (no moss there). Returns albedo (BGR linear), ambient and sun factors and notes."""
    sh = (Hc, Wc)
    notes = []
    kx, ky, kr = keep
    lab = np.zeros(sh, np.uint8)       # what lies where (for the failure analysis): see LABELS
    name = list(SOILS)[int(rng.integers(len(SOILS)))]
    base = np.array(SOILS[name], float) * np.exp(rng.normal(0, 0.12)) * np.exp(rng.normal(0, 0.04, 3))
    notes.append(name)
    c1 = lin(base)
    c2 = lin(base * np.array([1.12, 1.08, 1.0]) * U(rng, 1.05, 1.3))      # drier, lighter tone
    t = smoothstep(-1.2, 1.6, fbm(sh, 0.06 * ppm, rng, 3)) * F32(U(rng, 0.3, 0.8))
    alb = c1[None, None, :] + (c2 - c1)[None, None, :] * t[..., None]
    alb *= np.exp(0.1 * fbm(sh, 0.18 * ppm, rng, 3) + 0.07 * fbm(sh, 0.015 * ppm, rng, 3))[..., None]
    hpx = fbm(sh, 0.15 * ppm, rng, 2) * F32(0.006 * ppm)
    # texture at the pixel scale whatever the ground resolution (grains, crumbs below one pixel)
    alb *= np.exp(0.09 * fbm(sh, 4.0, rng, 3) + 0.05 * noise(sh, 1.0, rng))[..., None]
    tilth = rng.choice(["fine", "medium", "coarse"], p=[0.35, 0.4, 0.25])
    notes.append(f"{tilth} tilth")
    scales = {"fine": [(U(rng, 0.004, 0.008), 0.45), (0.0018, 0.35)],
              "medium": [(U(rng, 0.01, 0.02), 0.5), (U(rng, 0.003, 0.005), 0.35)],
              "coarse": [(U(rng, 0.025, 0.05), 0.35), (U(rng, 0.006, 0.012), 0.4), (0.002, 0.3)]}[str(tilth)]
    rough = U(rng, 0.6, 1.3)
    clod_px = 2.0
    for cm, amp in scales:
        cpx = cm * ppm
        if cpx < 2.5:
            g = noise(sh, max(1.2, cpx), rng)
            hpx += g * F32(0.3 * amp * max(cpx, 1.0) * rough)
            alb *= (1 + 0.06 * g)[..., None]
            continue
        b, hv = worley_bumps(sh, cpx, rng)
        hpx += b * F32(amp * cpx * rough)
        alb *= (0.96 + 0.08 * hv + 0.08 * b)[..., None]
        clod_px = max(clod_px, cpx)
    # specks: light mineral grains and dark organic bits
    gpx = 0.0012 * ppm
    if gpx > 0.4:
        sp = rng.random(sh, dtype=F32)
        spk = (sp > 0.995).astype(F32) * 0.6 - (sp < 0.004).astype(F32) * 0.5
        spk = blur(spk, max(0.4, 0.5 * gpx)) * F32(max(1.0, gpx))
        alb *= np.clip(1 + spk, 0.4, 2)[..., None]
    # desiccation cracks: part of a polygonal network
    if rng.random() < (0.5 if name in ("grey clay", "brown loam") else 0.2):
        cell = U(rng, 0.04, 0.15) * ppm
        if cell > 12:
            notes.append("cracks")
            _, de = voronoi_labels(sh, cell, rng, warp=0.04, fine=0.04)
            wpx = max(0.6, U(rng, 0.0005, 0.003) * ppm)
            keep_m = smoothstep(-0.3, 0.3, noise(sh, cell, rng) + U(rng, -0.2, 0.8))
            wv = F32(0.5 * wpx) * np.clip(1 + 0.6 * noise(sh, max(1.5, 0.3 * cell), rng), 0.2, 2)
            cr = np.clip(1.0 - (de - wv) / 1.0, 0, 1) * keep_m
            cr = blur(cr, 0.5)
            hpx -= cr * F32(3 * wpx + 1)
            alb *= (1 - 0.55 * cr)[..., None]
    # stones and pebbles
    stone_m = np.zeros(sh, np.uint8)
    area_m2 = Hc * Wc / ppm ** 2
    dens = math.exp(U(rng, math.log(5), math.log(300))) if rng.random() < 0.7 else 0.0
    nst = int(min(dens * area_m2, 2500))
    big = rng.random() < 0.3
    if big:
        nst += int(rng.integers(1, 6))
    if nst:
        notes.append(f"{nst} stones")
    stone_cols = [(125, 122, 118), (160, 150, 135), (200, 195, 185), (120, 90, 70), (80, 78, 76), (175, 160, 130)]
    palette_idx = rng.choice(len(stone_cols), 3)
    for i in range(nst):
        r_m = math.exp(rng.normal(math.log(0.005), 0.55)) if (not big or i < nst - 5) else U(rng, 0.02, 0.06)
        r = min(r_m * ppm, 0.2 * min(Hc, Wc))
        if r < 0.8:
            continue
        x, y = U(rng, 0, Wc), U(rng, 0, Hc)
        # no stone under the weed's centre, no big stone under the weed at all
        if math.hypot(x - kx, y - ky) < r + (0.2 if r < 0.2 * kr else 1.0) * kr:
            continue
        nv = int(np.clip(2 * r, 10, 48))
        tt = np.linspace(0, 2 * np.pi, nv, endpoint=False)
        rr = r * (1 + sines(tt / (2 * np.pi), rng, 0.18, 1, 3))
        el, rot = U(rng, 0.55, 1.0), U(rng, 0, np.pi)
        pp = np.stack([np.cos(tt) * rr, np.sin(tt) * rr * el], 1)
        pp = pp @ np.array([[np.cos(rot), np.sin(rot)], [-np.sin(rot), np.cos(rot)]]) + [x, y]
        col = lin(mix(base, np.array(stone_cols[int(rng.choice(palette_idx))]), U(rng, 0.3, 0.9))
                  * np.exp(rng.normal(0, 0.15)))
        x0, y0, x1, y1 = _region(pp, 2, Hc, Wc)
        if x1 - x0 < 3 or y1 - y0 < 3:
            continue
        m8 = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.fillPoly(m8, [pts16(pp - [x0, y0])], 255, cv2.LINE_AA, 4)
        mm = (m8.astype(F32) / 255)[..., None]
        tex = np.exp(0.15 * fbm(m8.shape, max(1.5, 0.4 * r), rng, 3) + 0.06 * noise(m8.shape, 1.0, rng))
        alb[y0:y1, x0:x1] = alb[y0:y1, x0:x1] * (1 - mm) + col * tex[..., None] * mm
        dts = dist_in(m8 > 127)
        rr_ = max(float(dts.max()), 0.5)
        hd = np.sqrt(np.clip(dts * (2 * rr_ - dts), 0, None)) * F32(U(rng, 0.4, 0.9)) + F32(0.1 * rr_)
        hd = blur(hd, 1.0) + F32(0.04 * rr_) * fbm(m8.shape, max(1.5, 0.3 * r), rng, 3)
        hr = hpx[y0:y1, x0:x1]
        hpx[y0:y1, x0:x1] = np.where(m8 > 127, np.maximum(hr, blur(hr, max(1.0, 0.3 * rr_)) + hd), hr)
        stone_m[y0:y1, x0:x1] = np.maximum(stone_m[y0:y1, x0:x1], m8)
        lab[y0:y1, x0:x1][m8 > 127] = 4
    # straw / dry stems
    if rng.random() < 0.5:
        nstraw = int(min(U(rng, 5, 80) * area_m2, 400)) + 1
        notes.append(f"{nstraw} straws")
        smask = np.zeros(sh, np.uint8)
        for _ in range(nstraw):
            Lm = U(rng, 0.03, 0.15) * ppm
            wpx = U(rng, 0.0008, 0.004) * ppm
            if wpx < 0.5 or Lm < 3:
                continue
            pts = curve([U(rng, 0, Wc), U(rng, 0, Hc)], U(rng, 0, 2 * np.pi), Lm, U(rng, -0.5, 0.5), 12)
            col = lin(mix(np.array([190, 175, 135]), base, U(rng, 0, 0.5)) * np.exp(rng.normal(0, 0.15))
                      * np.array([1, 1, U(rng, 0.8, 1.05)]))
            x0, y0, x1, y1 = _region(pts, wpx + 2, Hc, Wc)
            if x1 <= x0 or y1 <= y0:
                continue
            m8 = np.zeros((y1 - y0, x1 - x0), np.uint8)
            cv2.polylines(m8, [pts16(pts - [x0, y0])], False, 255, max(1, int(round(wpx))), cv2.LINE_AA, 4)
            mm = (m8.astype(F32) / 255)[..., None]
            tex = 1 + 0.12 * noise(m8.shape, max(1.2, wpx), rng) + 0.05 * noise(m8.shape, 1.0, rng)
            alb[y0:y1, x0:x1] = alb[y0:y1, x0:x1] * (1 - mm) + col * tex[..., None] * mm
            smask[y0:y1, x0:x1] = np.maximum(smask[y0:y1, x0:x1], m8)
            lab[y0:y1, x0:x1][m8 > 127] = 5
        dss = cv2.distanceTransform((smask > 127).astype(np.uint8), cv2.DIST_L2, 3)
        hpx = np.where(smask > 127, np.maximum(hpx, hpx + dss * 1.2 + 0.5), hpx)
    # dead leaves
    if rng.random() < 0.35:
        nd = int(rng.integers(1, 9))
        notes.append(f"{nd} dead leaves")
        for _ in range(nd):
            L = min(U(rng, 0.015, 0.06) * ppm, 0.3 * min(Hc, Wc))
            if L < 4:
                continue
            base = np.array([U(rng, 0, Wc), U(rng, 0, Hc)])
            ang = U(rng, 0, 2 * np.pi)
            mid = base + 0.5 * L * np.array([math.cos(ang), math.sin(ang)])
            if math.hypot(mid[0] - kx, mid[1] - ky) < 0.55 * L + 0.2 * kr:    # not under the weed's centre
                continue
            g = leaf_geom(rng, base, ang, L, L * U(rng, 0.2, 0.4),
                          lambda t: np.sin(np.pi * np.clip(t, 0, 1) ** 0.8) ** 0.7, pf=0.15, pw=L * 0.03,
                          wavy=0.08, n=40)
            col = lin(np.array([125, 90, 55]) * np.exp(rng.normal(0, 0.25)) * np.array([1, U(rng, 0.8, 1.1), 1]))
            x0, y0, x1, y1 = _region(g["poly"], 2, Hc, Wc)
            if x1 <= x0 or y1 <= y0:
                continue
            m8 = np.zeros((y1 - y0, x1 - x0), np.uint8)
            cv2.fillPoly(m8, [pts16(g["poly"] - [x0, y0])], 255, cv2.LINE_AA, 4)
            veins = _lines(m8.shape, [g["c"] - [x0, y0]] + [v - [x0, y0] for v in veins_pinnate(g, rng, 5)],
                           np.zeros(2), max(0.5, L * 0.01))
            mm = (m8.astype(F32) / 255)
            dt = dist_in(m8 > 127)
            A = col * (1 + 0.2 * noise(m8.shape, max(1.5, L * 0.1), rng))[..., None] * (1 - 0.35 * veins)[..., None]
            alb[y0:y1, x0:x1] = alb[y0:y1, x0:x1] * (1 - mm[..., None]) + A * mm[..., None]
            curl = F32(0.04 * L * U(rng, -1, 1.5)) * np.clip(1 - dt / F32(0.15 * L), 0, 1) ** 2 + F32(0.01 * L)
            hr = hpx[y0:y1, x0:x1]
            hpx[y0:y1, x0:x1] = np.where(mm > 0.5, np.maximum(hr, blur(hr, 0.08 * L) + curl + 0.5), hr)
            lab[y0:y1, x0:x1][mm > 0.5] = 6
    # wet patches
    if rng.random() < 0.3:
        notes.append("wet patches")
        wm = smoothstep(-0.3, 1.3, fbm(sh, U(rng, 0.05, 0.15) * ppm, rng, 3))
        alb *= (1 - U(rng, 0.2, 0.4) * wm)[..., None]
        hpx = hpx * (1 - 0.5 * wm) + blur(hpx, 3) * (0.5 * wm)
    # a few moss / algae patches, away from the weed
    if rng.random() < 0.25:
        algae = rng.random() < 0.35
        mcol = hsv_lin(U(rng, 70, 100), U(rng, 0.4, 0.7), U(rng, 0.18, 0.4)) if algae else \
            hsv_lin(U(rng, 60, 95), U(rng, 0.45, 0.75), U(rng, 0.2, 0.42))
        npatch = 0
        for _ in range(int(rng.integers(1, 5))):
            r = float(np.clip(U(rng, 0.01, 0.05) * ppm, 3, min(0.08 * min(Hc, Wc), 0.4 * kr)))
            for _try in range(20):
                x, y = U(rng, 0, Wc), U(rng, 0, Hc)
                if math.hypot(x - kx, y - ky) > kr * 1.3 + r * 1.6:
                    break
            else:
                continue
            x0, y0, x1, y1 = _region(np.array([[x - 1.6 * r, y - 1.6 * r], [x + 1.6 * r, y + 1.6 * r]]), 0, Hc, Wc)
            if x1 - x0 < 3 or y1 - y0 < 3:
                continue
            yy, xx = np.ogrid[y0:y1, x0:x1]
            dd = np.sqrt((xx - x) ** 2 + (yy - y) ** 2).astype(F32) / F32(r)
            shp = (y1 - y0, x1 - x0)
            mm = smoothstep(0.0, 0.25, 1 - dd + 0.45 * fbm(shp, max(1.5, 0.5 * r), rng, 3))
            gr = noise(shp, max(1.0, 0.0012 * ppm), rng)
            tex = mcol * (1 + (0.12 if algae else 0.3) * gr)[..., None]
            alb[y0:y1, x0:x1] = mix(alb[y0:y1, x0:x1], tex, (mm * U(rng, 0.6, 0.95))[..., None])
            lab[y0:y1, x0:x1][mm > 0.5] = 3
            if not algae:
                hpx[y0:y1, x0:x1] += mm * (1 + 0.5 * gr) * F32(max(0.5, 0.0015 * ppm))
            npatch += 1
        if npatch:
            notes.append(f"{npatch} {'algae' if algae else 'moss'} patches")
    # shading of the relief
    gx = cv2.Sobel(hpx, cv2.CV_32F, 1, 0, ksize=3) * F32(0.125)
    gy = cv2.Sobel(hpx, cv2.CV_32F, 0, 1, ksize=3) * F32(0.125)
    inv = 1.0 / np.sqrt(1 + gx * gx + gy * gy)
    ndl = (-gx * F32(light.L[0]) - gy * F32(light.L[1]) + F32(light.L[2])) * inv
    sun = np.clip(ndl, 0, None)
    if light.sun:
        # relief self-shadowing by marching towards the sun (half resolution on big canvases)
        f = 2 if Hc * Wc > 3e6 else 1
        hs = cv2.resize(hpx, (Wc // f, Hc // f), interpolation=cv2.INTER_AREA) / f if f > 1 else hpx
        tan_e = math.tan(light.elev)
        rel = float(np.percentile(hs, 99.5) - np.percentile(hs, 5))
        Lmax = min(rel / tan_e, 60)
        occ = np.zeros(hs.shape, F32)
        if Lmax > 1:
            steps = np.unique(np.geomspace(1, Lmax, 8).round(1))
            dx, dy = -light.sdir
            for st in steps:
                M = np.float32([[1, 0, -dx * st], [0, 1, -dy * st]])
                shf = cv2.warpAffine(hs, M, (hs.shape[1], hs.shape[0]), flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE)
                occ = np.maximum(occ, np.clip((shf - hs - st * tan_e) / 1.0, 0, 1))
            occ = blur(occ, 0.7)
            if f > 1:
                occ = cv2.resize(occ, (Wc, Hc), interpolation=cv2.INTER_LINEAR)
        sun = sun * (1 - 0.95 * occ)
    # ambient occlusion: how far the surroundings rise above a point, relative to their distance
    occ = np.zeros(sh, F32)
    sigs = sorted({2.0, max(2.0, 0.3 * clod_px), float(np.clip(clod_px, 2.0, 0.1 * min(Hc, Wc)))})
    for sg in sigs:
        occ += np.clip((blur(hpx, sg) - hpx) / F32(1.5 * sg), -0.3, 1.0)
    ao = np.clip(1 - 0.8 * occ / len(sigs), 0.3, 1.1)
    amb = (0.5 + 0.5 * inv) * ao
    return alb, amb.astype(F32), sun.astype(F32), notes, lab


# ----------------------------------------------------------------------------- camera
def camera(W, H, hfov_deg, tilt_deg, roll_deg):
    f = W / 2 / math.tan(math.radians(hfov_deg) / 2)
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]])
    t, r = math.radians(tilt_deg), math.radians(roll_deg)
    xc = np.array([1.0, 0, 0])
    zc = np.array([0, math.sin(t), -math.cos(t)])
    yc = np.cross(zc, xc)
    xr = math.cos(r) * xc + math.sin(r) * yc
    yr = -math.sin(r) * xc + math.cos(r) * yc
    R = np.stack([xr, yr, zc])
    C = np.array([0, 0, 1.0])
    return K @ np.column_stack([R[:, 0], R[:, 1], -R @ C]), f


def proj(Hm, pts):
    pts = np.atleast_2d(np.asarray(pts, float))
    q = np.column_stack([pts, np.ones(len(pts))]) @ Hm.T
    return q[:, :2] / q[:, 2:3]


def local_scale(Hm, P, eps=1e-4):
    p0 = proj(Hm, P)[0]
    jx = (proj(Hm, P + [eps, 0])[0] - p0) / eps
    jy = (proj(Hm, P + [0, eps])[0] - p0) / eps
    return math.sqrt(abs(jx[0] * jy[1] - jx[1] * jy[0]))


def camera_fx(img, rng, tilt, notes, illum):
    """Linear radiance -> 8-bit BGR photo: auto white balance on the illuminant with a residual
    cast, auto exposure with an error, vignetting, blur, chromatic aberration, signal-dependent
    noise, tone curve + sRGB (one lookup table), sharpening, JPEG."""
    H, W = img.shape[:2]
    sc = W / 1280.0
    g = F32(np.mean(illum)) / np.asarray(illum, F32)
    ev = float(np.clip(rng.normal(0, 0.35), -0.8, 0.7))
    g = g * np.exp(rng.normal(0, 0.05, 3) + np.array([-1, 0, 1]) * rng.normal(0, 0.05)).astype(F32)
    means = np.array(cv2.mean(img)[:3], F32) * g
    g = g * F32(0.2 * 2 ** ev / max(float(means @ np.array([0.0722, 0.7152, 0.2126], F32)), 1e-6))
    notes.append(f"ev {ev:+.1f}")
    vig = U(rng, 0.05, 0.45)
    yy, xx = np.ogrid[0:H, 0:W]
    r2 = (((xx - W / 2) / (W / 2)) ** 2 + ((yy - H / 2) / (W / 2)) ** 2).astype(F32)
    vm = (1 - F32(vig / 1.56) * r2)
    img = img * (vm[..., None] * g[None, None, :])
    r = rng.random()
    if r < 0.35:
        s = U(rng, 0.3, 1.3) * max(sc, 0.5) ** 0.7
        img = blur(img, s)
        notes.append(f"defocus {s:.1f}")
    elif r < 0.5:
        Lm = max(2, int(U(rng, 0.002, 0.008) * W))
        n = Lm | 1                      # odd size: filter2D's anchor is then the kernel's centre
        ker = np.zeros((n, n), F32)
        a = U(rng, 0, np.pi)
        c, e = (n - 1) / 2, (Lm - 1) / 2
        cv2.line(ker, (int(round(c - e * math.cos(a))), int(round(c - e * math.sin(a)))),
                 (int(round(c + e * math.cos(a))), int(round(c + e * math.sin(a)))), 1.0, 1, cv2.LINE_AA)
        ker = ker + ker[::-1, ::-1]     # point-symmetric: blurs without shifting the image off the truth
        img = cv2.filter2D(img, -1, ker / ker.sum())
        notes.append(f"motion {Lm}px")
    if tilt > 10 and rng.random() < 0.4:
        fy = U(rng, 0.3, 0.7) * H
        wgt = np.clip(np.abs(np.arange(H, dtype=F32) - fy) / (0.5 * H), 0, 1)[:, None, None]
        img = img * (1 - wgt) + blur(img, 1.5 * max(sc, 0.5)) * wgt
        notes.append("shallow DoF")
    if rng.random() < 0.3:
        k = U(rng, 0.0005, 0.0015)
        chans = list(cv2.split(img))
        for ch, sgn in ((0, 1), (2, -1)):
            M = cv2.getRotationMatrix2D((W / 2, H / 2), 0, 1 + sgn * k)
            chans[ch] = cv2.warpAffine(chans[ch], M, (W, H), borderMode=cv2.BORDER_REFLECT)
        img = cv2.merge(chans)
    gain = math.exp(U(rng, math.log(0.0002), math.log(0.0025)))
    nse = randn(img.shape, rng)
    if W > 2000:
        nse = blur(nse, 0.8) * F32(1.6)
    img = img + nse * np.sqrt(np.maximum(img, F32(0)) * F32(gain) + F32(2e-6))
    # tone curve (soft shoulder), sRGB encoding and a mild S-curve, as one lookup table
    XMAX, N = 4.0, 16384
    x = np.linspace(0, XMAX, N)
    white = U(rng, 1.0, 2.0)
    y = np.clip(x * (1 + x / white ** 2) / (1 + x) * 1.1, 0, 1)
    y = np.where(y <= 0.0031308, y * 12.92, 1.055 * np.power(y, 1 / 2.4) - 0.055)
    con = U(rng, 0.0, 0.25)
    y = y + con * (y - 0.5) * (1 - np.abs(2 * y - 1))
    lut = np.clip(y * 255 + 0.5, 0, 255).astype(np.uint8)
    idx = np.clip(img, F32(0), F32(XMAX)) * F32((N - 1) / XMAX)
    out = lut[idx.astype(np.int32)]
    if rng.random() < 0.5:
        amt = U(rng, 0.3, 1.0)
        out = cv2.addWeighted(out, 1 + amt, cv2.GaussianBlur(out, (0, 0), max(0.8, sc)), -amt, 0)
        notes.append("sharpened")
    if rng.random() < 0.5:
        q = int(rng.integers(60, 96))
        out = cv2.imdecode(cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, q])[1], cv2.IMREAD_COLOR)
        notes.append(f"jpeg q{q}")
    return out


# ----------------------------------------------------------------------------- one case
def make_case(seed, i, kind):
    rng = np.random.default_rng([seed, i])
    W, H = SIZES[int(rng.choice(len(SIZES), p=SIZE_P))]
    hfov = U(rng, 55, 72)
    tilt = 0.0 if rng.random() < 0.35 else U(rng, 4, 35)
    roll = U(rng, -180, 180) if tilt == 0 else U(rng, -12, 12)
    Hm, f = camera(W, H, hfov, tilt, roll)
    Hinv = np.linalg.inv(Hm)
    short = min(W, H)
    S_t = U(rng, 0.05, 0.6) * short
    pal = palette(rng)
    parts, info = GEN[kind](rng, pal)
    allp = np.vstack([p["poly"] for p in parts])
    Rg = float(np.max(np.linalg.norm(allp, axis=1)))
    m = max(3.0, 0.02 * short)
    u0 = U(rng, S_t / 2 + m, W - S_t / 2 - m)
    v0 = U(rng, S_t / 2 + m, H - S_t / 2 - m)
    for it in range(40):
        P0 = proj(Hinv, [u0, v0])[0]
        lam = local_scale(Hm, P0)
        wpn = S_t / 2 / lam / Rg                # world units per normalised unit
        img_pts = proj(Hm, P0 + allp * [wpn, -wpn])
        lo, hi = img_pts.min(0), img_pts.max(0)
        du = max(0, m - lo[0]) - max(0, hi[0] - (W - m))
        dv = max(0, m - lo[1]) - max(0, hi[1] - (H - m))
        if du == 0 and dv == 0:
            break
        u0, v0 = u0 + 1.05 * du, v0 + 1.05 * dv
        if it % 4 == 3:
            S_t *= 0.9
    truth = proj(Hm, P0)[0]
    S = 2 * float(np.max(np.linalg.norm(img_pts - truth, axis=1)))
    light = Light(rng)
    # ground canvas
    mrg = 0.03
    corners = np.array([[-mrg * W, -mrg * H], [W * (1 + mrg), -mrg * H], [W * (1 + mrg), H * (1 + mrg)],
                        [-mrg * W, H * (1 + mrg)]])
    gc = proj(Hinv, corners)
    Xmin, Ymin = gc.min(0)
    Xmax, Ymax = gc.max(0)
    area = (Xmax - Xmin) * (Ymax - Ymin)
    cap = min((1.3 if tilt < 15 else 2.0) * W * H, 5e6)
    s_c = min(lam * 1.0, math.sqrt(cap / area))
    Wc, Hc = int(math.ceil((Xmax - Xmin) * s_c)), int(math.ceil((Ymax - Ymin) * s_c))
    G_c = np.array([[1 / s_c, 0, Xmin], [0, -1 / s_c, Ymax], [0, 0, 1]])
    H_ic = Hm @ G_c
    D_lo, D_hi = D_REAL[kind]
    D = U(rng, D_lo, D_hi)
    h_m = D / (2 * Rg * wpn)                   # camera height in metres
    if h_m > 2.0:
        D = max(D_lo, D * 2.0 / h_m)
        h_m = D / (2 * Rg * wpn)
    ppm = s_c / h_m
    pc = np.array([(P0[0] - Xmin) * s_c, (Ymax - P0[1]) * s_c])
    alb, amb, sun, snotes, lab = render_soil(Hc, Wc, ppm, light, rng, (pc[0], pc[1], Rg * wpn * s_c))
    V = np.array([-P0[0], P0[1], 1.0])
    V /= np.linalg.norm(V)
    # tiny other seedlings away from the weed
    ndis = 0
    if rng.random() < 0.35:
        for _ in range(int(rng.integers(1, 6))):
            dk = str(rng.choice(["seedling", "seedling", "seedling", "grass", "clover"]))
            Sd = U(rng, 0.08, 0.25) * S
            if Sd < 5:
                continue
            for _try in range(10):
                ud, vd = U(rng, Sd, W - Sd), U(rng, Sd, H - Sd)
                Pd = proj(Hinv, [ud, vd])[0]
                cx, cy = int((Pd[0] - Xmin) * s_c), int((Ymax - Pd[1]) * s_c)
                on_soil = 0 <= cx < Wc and 0 <= cy < Hc and lab[cy, cx] in (0, 3)    # not on a stone / leaf
                if on_soil and math.hypot(ud - truth[0], vd - truth[1]) > 1.15 * (S / 2 + Sd / 2):
                    break
            else:
                continue
            dpal = palette(rng)
            dparts, _ = GEN[dk](rng, dpal)
            if dk == "grass":
                dparts = dparts[: 6]
            dall = np.vstack([p["poly"] for p in dparts])
            Rd = float(np.max(np.linalg.norm(dall, axis=1)))
            kd = (Sd / 2 / local_scale(Hm, Pd) / Rd) * s_c
            Bd = render_plant(dparts, kd, light, V, rng)
            cd = np.array([(Pd[0] - Xmin) * s_c, (Ymax - Pd[1]) * s_c])
            o = np.round(cd - Bd["off"]).astype(int)
            hh, ww = Bd["alpha"].shape
            x0, y0 = max(o[0], 0), max(o[1], 0)
            x1, y1 = min(o[0] + ww, Wc), min(o[1] + hh, Hc)
            if x1 <= x0 or y1 <= y0:
                continue
            sl = (slice(y0, y1), slice(x0, x1))
            ps = (slice(y0 - o[1], y1 - o[1]), slice(x0 - o[0], x1 - o[0]))
            a = Bd["alpha"][ps]
            amb[sl] *= Bd["soil_amb"][ps]
            sun[sl] *= Bd["soil_sun"][ps]
            alb[sl] = alb[sl] * (1 - a[..., None]) + Bd["alb"][ps] * a[..., None]
            amb[sl] = amb[sl] * (1 - a) + Bd["amb"][ps] * a
            sun[sl] = sun[sl] * (1 - a) + Bd["sun"][ps] * a
            lab[sl][a > 0.5] = 2
            ndis += 1
    if ndis:
        snotes.append(f"{ndis} tiny seedlings")
    soilA = cv2.warpPerspective(alb * (amb[..., None] * light.sky_rgb), H_ic, (W, H), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REFLECT)
    soilS = cv2.warpPerspective(alb * (sun[..., None] * light.sun_rgb), H_ic, (W, H), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REFLECT)
    labels = cv2.warpPerspective(lab, H_ic, (W, H), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    del alb, amb, sun, lab
    # the weed, rendered at (about) native resolution and warped separately
    k = lam * wpn
    kmax = 1400 / (2 * Rg)
    k = min(k, kmax)
    B = render_plant(parts, k, light, V, rng)
    rad = (B["alb"] * (B["amb"][..., None] * light.sky_rgb + B["sun"][..., None] * light.sun_rgb)
           + B["spec"][..., None] * light.sun_rgb + B["sspec"][..., None] * light.sky_rgb * F32(1.5))
    prem = rad * B["alpha"][..., None]
    off = B["off"]
    G_p = np.array([[wpn / k, 0, P0[0] - off[0] * wpn / k], [0, -wpn / k, P0[1] + off[1] * wpn / k], [0, 0, 1]])
    H_ip = Hm @ G_p
    hh, ww = B["alpha"].shape
    cr = proj(H_ip, [[0, 0], [ww, 0], [ww, hh], [0, hh]])
    bx0, by0 = np.maximum(np.floor(cr.min(0)).astype(int) - 2, 0)
    bx1, by1 = np.minimum(np.ceil(cr.max(0)).astype(int) + 2, [W, H])
    T = np.array([[1, 0, -bx0], [0, 1, -by0], [0, 0, 1.0]])
    sz = (int(bx1 - bx0), int(by1 - by0))

    def wp(a, bv=0.0):
        return cv2.warpPerspective(a, T @ H_ip, sz, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                   borderValue=bv)
    pa = wp(B["alpha"])[..., None]
    pr = wp(prem)
    ssun = wp(B["soil_sun"], 1.0)[..., None]
    samb = wp(B["soil_amb"], 1.0)[..., None]
    img = soilA + soilS
    sl = (slice(by0, by1), slice(bx0, bx1))
    img[sl] = (soilA[sl] * samb + soilS[sl] * ssun) * (1 - pa) + pr
    labels[sl][pa[..., 0] > 0.5] = 1
    glare = float((B["spec"] * B["alpha"]).max()) if light.sun else 0.0
    notes = [f"{W}x{H}", f"tilt {tilt:.0f}", f"S {S:.0f}px ({S / short:.0%})", pal["name"], light.desc()] + snotes
    if glare > 0.3:
        notes.append("glare")
    for kk, vv in info.items():
        notes.append(f"{kk}={vv}")
    illum = light.sun_rgb + light.sky_rgb * F32(0.6) if light.sun else light.sky_rgb + light.sun_rgb
    out = camera_fx(img, rng, tilt, notes, illum)
    return dict(img=out, truth=(float(truth[0]), float(truth[1])), S=S, kind=kind, notes=notes, W=W, H=H,
                labels=labels)


# ----------------------------------------------------------------------------- evaluation
def roi_for(case, seed, i):
    rng = np.random.default_rng([seed, i, 7])
    r = U(rng, 1.2, 2.5) * case["S"] / 2
    a = U(rng, 0, 2 * np.pi)
    d = U(rng, 0, 0.3) * r
    cx, cy = case["truth"][0] + d * math.cos(a), case["truth"][1] + d * math.sin(a)
    return ((float(cx), float(cy)), (float(2 * r), float(2 * r)), 0.0)


def cross(img, p, col, size, th):
    x, y = int(round(p[0])), int(round(p[1]))
    cv2.line(img, (x - size, y), (x + size, y), (0, 0, 0), th + 2)
    cv2.line(img, (x, y - size), (x, y + size), (0, 0, 0), th + 2)
    cv2.line(img, (x - size, y), (x + size, y), col, th)
    cv2.line(img, (x, y - size), (x, y + size), col, th)


def save_png(path, case, res, err, roi):
    img = case["img"]
    H, W = img.shape[:2]
    s = min(1600 / W, 1.0)
    if H * s < 480:
        s = 480 / H
    full = cv2.resize(img, (int(W * s), int(H * s)), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
    t = np.array(case["truth"])
    if roi is not None:
        (cx, cy), (aw, ah), _ = roi
        cv2.ellipse(full, (int(cx * s), int(cy * s)), (int(aw / 2 * s), int(ah / 2 * s)), 0, 0, 360, (0, 220, 255), 1)
    cross(full, t * s, (0, 255, 0), 10, 2)
    if res.pixel is not None:
        cross(full, np.array(res.pixel) * s, (0, 0, 255), 10, 2)
    half = min(max(0.8 * case["S"], 24), max(W, H))
    x0, y0 = int(t[0] - half), int(t[1] - half)
    side = int(2 * half)
    pad = cv2.copyMakeBorder(img, side, side, side, side, cv2.BORDER_CONSTANT, value=(40, 40, 40))
    crop = pad[y0 + side:y0 + 2 * side, x0 + side:x0 + 2 * side].copy()
    ph = full.shape[0]
    cs = ph / side
    crop = cv2.resize(crop, (ph, ph), interpolation=cv2.INTER_AREA if cs < 1 else cv2.INTER_LINEAR)
    cross(crop, (t - [x0, y0]) * cs, (0, 255, 0), 14, 2)
    if res.pixel is not None:
        cross(crop, (np.array(res.pixel) - [x0, y0]) * cs, (0, 0, 255), 14, 2)
    body = np.hstack([full, crop])
    fs = max(1.0, body.shape[1] / 1400)
    cap = np.zeros((int(58 * fs), body.shape[1], 3), np.uint8)
    e = "miss" if err is None else f"err {err:.2f} S"
    l1 = f"#{case['i']} {case['kind']}  {e}  reason={res.reason}  conf={res.confidence:.2f}"
    cv2.putText(cap, l1, (6, int(22 * fs)), cv2.FONT_HERSHEY_SIMPLEX, 0.65 * fs, (255, 255, 255), max(1, int(fs)),
                cv2.LINE_AA)
    cv2.putText(cap, ", ".join(case["notes"])[:200], (6, int(48 * fs)), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * fs,
                (200, 200, 200), 1, cv2.LINE_AA)
    cv2.imwrite(str(path), np.vstack([cap, body]))


def summarise(rows, label):
    n = len(rows)
    det = [r for r in rows if r["err"] is not None]
    errs = np.array([r["err"] for r in det]) if det else np.array([])
    reasons = {}
    for r in rows:
        reasons[str(r["reason"])] = reasons.get(str(r["reason"]), 0) + 1
    lat = np.median([r["lat"] for r in rows]) * 1000
    fmt = lambda x: f"{x:6.3f}" if x == x else "   nan"
    return (f"{label:<10} {n:3d} {100 * len(det) / n:6.1f} {fmt(np.median(errs) if len(errs) else float('nan'))} "
            f"{fmt(np.percentile(errs, 90) if len(errs) else float('nan'))} {100 * np.sum(errs <= 0.1) / n:6.1f} "
            f"{100 * np.sum(errs <= 0.2) / n:6.1f} {100 * np.sum(errs > 0.5) / n:6.1f} {lat:7.0f}  "
            + " ".join(f"{k}:{v}" for k, v in sorted(reasons.items())))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=70)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    ap.add_argument("--roi", action="store_true")
    ap.add_argument("--save-fails", default=None)
    ap.add_argument("--save-all", default=None)
    ap.add_argument("--cases", type=int, nargs="*", default=None, help="only these case indices")
    args = ap.parse_args(argv)
    if args.cases and not all(0 <= c < args.n for c in args.cases):
        ap.error(f"--cases must be in 0..{args.n - 1} (--n {args.n})")
    from capm_field.detector import detect_centre

    for d in (args.save_fails, args.save_all):
        if d:
            Path(d).mkdir(parents=True, exist_ok=True)
    rows = []
    t_render = []
    for i in range(args.n):
        if args.cases and i not in args.cases:
            continue
        kind = args.kinds[i % len(args.kinds)]
        t0 = time.perf_counter()
        case = make_case(args.seed, i, kind)
        t_render.append(time.perf_counter() - t0)
        case["i"] = i
        roi = roi_for(case, args.seed, i) if args.roi else None
        t0 = time.perf_counter()
        res = detect_centre(case["img"], roi=roi)
        lat = time.perf_counter() - t0
        err = None
        on = "-"
        if res.reason is None and res.pixel is not None:
            err = float(np.hypot(res.pixel[0] - case["truth"][0], res.pixel[1] - case["truth"][1])) / case["S"]
            u = int(np.clip(round(res.pixel[0]), 0, case["W"] - 1))
            v = int(np.clip(round(res.pixel[1]), 0, case["H"] - 1))
            on = LABELS[int(case["labels"][v, u])]
        rows.append(dict(i=i, kind=kind, err=err, reason="ok" if res.reason is None else res.reason, lat=lat, on=on))
        e = "miss" if err is None else f"{err:.3f}"
        print(f"  #{i:3d} {kind:<10} err/S={e:<6} reason={res.reason} on={on} {', '.join(case['notes'])}",
              flush=True)
        name = f"s{args.seed}_{i:03d}_{kind}.png"
        if args.save_all:
            save_png(Path(args.save_all) / name, case, res, err, roi)
        if args.save_fails and (err is None or err > 0.15):
            save_png(Path(args.save_fails) / name, case, res, err, roi)
    print(f"\nseed {args.seed}  roi={'yes' if args.roi else 'no'}  render median {np.median(t_render):.2f} s")
    print(f"{'kind':<10} {'n':>3} {'det%':>6} {'med':>6} {'p90':>6} {'<0.1S':>6} {'<0.2S':>6} {'wrong':>6} "
          f"{'lat_ms':>7}  reasons")
    for kd in args.kinds:
        rk = [r for r in rows if r["kind"] == kd]
        if rk:
            print(summarise(rk, kd))
    print(summarise(rows, "ALL"))
    land = {}
    for r in rows:
        if r["err"] is not None and r["err"] > 0.15:
            land[r["on"]] = land.get(r["on"], 0) + 1
    print("answers > 0.15 S off landed on: " + (" ".join(f"{k}:{v}" for k, v in sorted(land.items())) or "-"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
