"""Weeds of five kinds drawn by a renderer other than sim_bench (numpy + OpenCV only, written
without looking at sim_bench or the detector): how far `detect_centre` lands from the true
biological centre, in units of the plant size S (diameter of the plant's extent).

    .venv/bin/python bench/other_renderer_plants.py [--n 40] [--seed 0]
        [--kinds grass,clover,seedling,rosette,lobed] [--save-fails DIR] [--roi]

Each image is a top-down photo (640×480, 1280×720, 1920×1080, sometimes 2592×1944) of ONE weed
of size S from 40 px (grass 60 px) to 40 % of the short side, fully inside the frame (margin
≥ 5 % S), on textured soil (brown / grey / reddish / sandy / dark wet) with clods, stones,
straw, bits of dead leaf and sometimes a few tiny weed seedlings (≤ S/4) away from it; then
global gain, colour cast, a soft cast shadow, vignetting, blur, sensor noise and (half of the
time) JPEG re-encoding. Kinds and where their centre is:

- grass:    3–15 narrow curved blades (some bent over) from a small base / sheath → base;
- clover:   2–6 trifoliate leaves on thin petioles of varied length → crown of the petioles;
- seedling: two cotyledons around a short hypocotyl, sometimes 1–2 true leaves → stem point;
- rosette:  4–12 broad leaves of uneven length overlapping at the centre → where they meet;
- lobed:    dandelion-like runcinate, serrated leaves in a rosette → where they meet.

Kinds are taken in turn; case i is rendered from `default_rng([seed, i])`, so an image depends
only on the seed, i and its kind, not on --roi. With --roi the detector gets a circle of radius
1.2–2.5 × S/2 around the true centre, shifted by up to 0.3 of that radius. Prints, per kind and
overall: detection rate (reason None), error / S of the detections (median, p90), share within
0.1 S and 0.2 S (misses count as outside), share "wrong" (detected but > 0.5 S off, over all
cases), reasons, the estimator named in debug["method"] ("-" when none), and the median
detector latency. --save-fails DIR writes every case with error > 0.15 S or no detection as a
PNG: the image with a green cross at the truth and a red one at the answer, a close-up of the
plant, and kind / error / reason / method.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from collections import Counter, defaultdict

import cv2
import numpy as np

from capm_field.detector import detect_centre

KINDS = ("grass", "clover", "seedling", "rosette", "lobed")
SIZES = ((640, 480), (1280, 720), (1920, 1080))
TAU = 2 * math.pi

# RGB; the image is built in RGB float and turned into BGR uint8 at the end.
PLANT_COLOURS = {
    "dark green": (36, 82, 30),
    "green": (62, 128, 44),
    "fresh green": (92, 158, 54),
    "yellow-green": (138, 168, 56),
    "olive": (104, 110, 46),
    "bluish green": (56, 112, 94),
}
SOIL_COLOURS = {
    "brown": (118, 88, 62),
    "grey": (112, 108, 102),
    "reddish": (140, 82, 56),
    "sandy": (190, 166, 126),
    "dark wet": (60, 48, 40),
}
REDDISH_STEM = np.array([128, 52, 50], float)


# ----------------------------------------------------------------------------- geometry
def spine(p0, heading: float, length: float, curv: float = 0.0, kink=None, n: int = 60):
    """Centre line of `n` points from p0, heading changing by `curv` rad over its length and by
    a further kink = (where 0..1, angle) over a short stretch (a bent-over blade)."""
    s = np.linspace(0.0, 1.0, n)
    h = heading + curv * s
    if kink is not None:
        f, ang = kink
        h = h + ang / (1 + np.exp(-(s - f) / 0.035))
    d = np.c_[np.cos(h), np.sin(h)] * (length / (n - 1))
    pts = np.asarray(p0, float) + np.r_[[[0.0, 0.0]], np.cumsum((d[1:] + d[:-1]) / 2, axis=0)]
    return pts, h


def ribbon_poly(pts, h, wl, wr, sl=None, sr=None):
    """Outline around a centre line: half-widths wl (left) / wr (right), tangential shifts sl/sr."""
    nrm = np.c_[-np.sin(h), np.cos(h)]
    tan = np.c_[np.cos(h), np.sin(h)]
    left = pts + nrm * wl[:, None] + (0 if sl is None else tan * sl[:, None])
    right = pts - nrm * wr[:, None] + (0 if sr is None else tan * sr[:, None])
    return np.r_[left, right[::-1]]


def rot(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def blob_poly(rng, c, r, n=None, rough=0.25, aspect=1.0, ang=0.0):
    """Irregular closed outline (clods, dead leaf bits)."""
    n = n or int(rng.integers(7, 14))
    a = np.sort(rng.uniform(0, TAU, n))
    rr = r * (1 + rough * rng.uniform(-1, 1, n))
    p = np.c_[np.cos(a) * rr, np.sin(a) * rr * aspect]
    # smooth it with a periodic Chaikin pass
    for _ in range(2):
        q = np.roll(p, -1, axis=0)
        p = np.stack([0.75 * p + 0.25 * q, 0.25 * p + 0.75 * q], 1).reshape(-1, 2)
    return p @ rot(ang).T + c


# ----------------------------------------------------------------------------- painter
def prim(poly=None, *, spine_=None, wl=None, wr=None, sl=None, sr=None, minw=0.0, a, b, c0, c1,
         alpha=1.0, shadow=0.35, edge=0.0, tex=0.04, gamma=1.0):
    """One filled shape: `poly`, or a ribbon around `spine_` = (pts, headings) (rebuilt after
    scaling so thin stalks can be kept ≥ minw px wide). Colour runs from c0 at a to c1 at b."""
    return dict(poly=poly, spine=spine_, wl=wl, wr=wr, sl=sl, sr=sr, minw=minw, a=np.asarray(a, float),
                b=np.asarray(b, float), c0=np.asarray(c0, float), c1=np.asarray(c1, float), alpha=alpha,
                shadow=shadow, edge=edge, tex=tex, gamma=gamma)


def placed(p: dict, sc: float, off) -> dict:
    """Copy of a primitive scaled by sc and moved by off, with its outline built."""
    q = dict(p)
    off = np.asarray(off, float)
    if p["spine"] is not None:
        pts, h = p["spine"]
        half = p["minw"] / 2
        wl = np.maximum(p["wl"] * sc, half)
        wr = np.maximum(p["wr"] * sc, half)
        sl = None if p["sl"] is None else p["sl"] * sc
        sr = None if p["sr"] is None else p["sr"] * sc
        q["poly"] = ribbon_poly(pts * sc + off, h, wl, wr, sl, sr)
    else:
        q["poly"] = p["poly"] * sc + off
    q["a"], q["b"] = p["a"] * sc + off, p["b"] * sc + off
    q["edge"] = p["edge"] * sc
    return q


def outline(p: dict) -> np.ndarray:
    if p["spine"] is not None:
        return ribbon_poly(p["spine"][0], p["spine"][1], p["wl"], p["wr"], p["sl"], p["sr"])
    return p["poly"]


def paint(img, p: dict, rng, sh_sigma: float = 0.0, sh_off=(0.0, 0.0), light=None) -> None:
    """Paint one placed primitive into the RGB float image: first its soft drop shadow on what is
    already there, then the shape with an along-axis colour gradient, darker rims (`edge` px),
    fine texture and an optional plant-wide brightness gradient light = (centre, dir, R, g)."""
    H, W = img.shape[:2]
    poly = p["poly"]
    pad = int(3 * sh_sigma + abs(sh_off[0]) + abs(sh_off[1]) + 3)
    x0, y0 = np.floor(poly.min(0)).astype(int) - pad
    x1, y1 = np.ceil(poly.max(0)).astype(int) + pad + 1
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return
    h, w = y1 - y0, x1 - x0
    m = np.zeros((h, w), np.uint8)
    cv2.fillPoly(m, [np.round((poly - [x0, y0]) * 16).astype(np.int32)], 255, cv2.LINE_AA, shift=4)
    al = m.astype(np.float32) / 255.0
    out = img[y0:y1, x0:x1]
    if p["shadow"] > 0 and sh_sigma > 0:
        sh = cv2.GaussianBlur(al, (0, 0), sh_sigma)
        sh = cv2.warpAffine(sh, np.float32([[1, 0, sh_off[0]], [0, 1, sh_off[1]]]), (w, h))
        out *= (1 - p["shadow"] * sh)[..., None]
    xs = np.arange(x0, x1, dtype=np.float32)[None, :]
    ys = np.arange(y0, y1, dtype=np.float32)[:, None]
    ab = p["b"] - p["a"]
    t = ((xs - p["a"][0]) * ab[0] + (ys - p["a"][1]) * ab[1]) / max(float(ab @ ab), 1e-6)
    t = np.clip(t, 0, 1) ** p["gamma"]
    col = p["c0"].astype(np.float32) + (p["c1"] - p["c0"]).astype(np.float32) * t[..., None]
    k = np.ones((h, w), np.float32)
    if p["edge"] > 0.3:
        k *= 0.8 + 0.2 * np.clip(2 * cv2.GaussianBlur(al, (0, 0), p["edge"]) - 0.6, 0, 1) / 1.4
    if p["tex"] > 0:
        cell = max(2, int(min(h, w) / 12))
        nz = rng.normal(0, 1, (h // cell + 2, w // cell + 2)).astype(np.float32)
        k *= 1 + p["tex"] * cv2.resize(nz, (w, h), interpolation=cv2.INTER_CUBIC)
    if light is not None:
        c, d, R, g = light
        k *= 1 + g * ((xs - c[0]) * d[0] + (ys - c[1]) * d[1]) / R
    col *= k[..., None]
    a = (al * p["alpha"])[..., None]
    out[:] = out * (1 - a) + col * a


# ----------------------------------------------------------------------------- plants
def jit(rng, c, s=0.08) -> np.ndarray:
    return np.asarray(c, float) * rng.uniform(1 - s, 1 + s, 3)


def shaded(rng, col, base=(0.75, 0.95), tip=(1.0, 1.3)):
    """(base colour, tip colour) of one leaf: darker base, lighter tip, or the other way."""
    c = jit(rng, col)
    if rng.random() < 0.25:
        return c * rng.uniform(*tip), c * rng.uniform(*base)
    return c * rng.uniform(*base), c * rng.uniform(*tip)


def spread_angles(rng, n: int, conc=(0.8, 3.0)) -> np.ndarray:
    return rng.uniform(0, TAU) + np.cumsum(rng.dirichlet(np.full(n, rng.uniform(*conc))) * TAU)


def leaf_prims(rng, p0, heading, L, W, prof, col, curv=0.0, veins="mid", n=90, vein_col=None,
               minw=0.0, shadow=0.35):
    """A flat leaf along a curved midline with half-width profile prof(t) ∈ [0, 1] (or a pair
    of profiles for the two sides), plus veins ("mid", "parallel", "pinnate" or None)."""
    t = np.linspace(0, 1, n)
    pts, h = spine(p0, heading, L, curv, n=n)
    pr = prof(t)
    if isinstance(pr, tuple):  # ((width, tangential shift) left, (width, shift) right)
        wl, wr = W / 2 * pr[0][0], W / 2 * pr[1][0]
        sl, sr = W / 2 * pr[0][1], W / 2 * pr[1][1]
    else:
        wl = wr = W / 2 * pr
        sl = sr = None
    c0, c1 = shaded(rng, col)
    out = [prim(spine_=(pts, h), wl=wl, wr=wr, sl=sl, sr=sr, minw=minw, a=pts[0], b=pts[-1], c0=c0, c1=c1,
                edge=0.12 * W, tex=0.05, shadow=shadow)]
    if veins is None:
        return out
    vc = vein_col if vein_col is not None else (c0 + c1) / 2 * rng.uniform(1.12, 1.35)
    vw = W * rng.uniform(0.025, 0.05)
    m = int(0.9 * n)
    out.append(prim(spine_=(pts[:m], h[:m]), wl=vw / 2 * (1 - 0.7 * t[:m]), wr=vw / 2 * (1 - 0.7 * t[:m]),
                    a=pts[0], b=pts[m - 1], c0=vc, c1=vc * 0.95, alpha=0.6, shadow=0, tex=0.0))
    if veins == "parallel":  # plantain: arcs that follow the margin
        for f in rng.uniform(0.3, 0.8, int(rng.integers(1, 3))):
            for s in (1, -1):
                nrm = np.c_[-np.sin(h), np.cos(h)] * (s * f * (wl if s > 0 else wr))[:, None]
                q = pts + nrm
                out.append(prim(spine_=(q[2:m], h[2:m]), wl=np.full(m - 2, vw / 4), wr=np.full(m - 2, vw / 4),
                                a=q[0], b=q[m - 1], c0=vc, c1=vc, alpha=0.4, shadow=0, tex=0.0))
    elif veins == "pinnate":
        for f in np.linspace(0.2, 0.8, int(rng.integers(3, 7))):
            i = int(f * (n - 1))
            for s in (1, -1):
                ang = h[i] + s * rng.uniform(0.6, 1.0)
                ln = 0.8 * (wl if s > 0 else wr)[i] / math.sin(abs(ang - h[i]))
                q, hq = spine(pts[i], ang, ln, n=8)
                out.append(prim(spine_=(q, hq), wl=np.full(8, vw / 4), wr=np.full(8, vw / 4), a=q[0], b=q[-1],
                                c0=vc, c1=vc, alpha=0.35, shadow=0, tex=0.0))
    return out


def grass(rng, col) -> list[dict]:
    n = int(rng.integers(3, 16))
    spread = TAU if rng.random() < 0.6 else rng.uniform(math.pi, TAU)
    angs = rng.uniform(0, TAU) + spread * (np.arange(n) + rng.uniform(-0.4, 0.4, n)) / n  # no bundles
    lens = rng.uniform(0.45, 1.0, n)
    lens[int(rng.integers(n))] = 1.0
    dry = rng.random() < 0.25
    out = []
    for k in rng.permutation(n):
        L = lens[k]
        w = L * rng.uniform(0.02, 0.08)
        kink = (rng.uniform(0.3, 0.7), rng.choice([-1, 1]) * rng.uniform(0.5, 1.3)) if rng.random() < 0.25 else None
        pts, h = spine(rng.normal(0, 0.012, 2), angs[k], L, rng.normal(0, 0.35), kink, n=70)
        t = np.linspace(0, 1, 70)
        hw = w / 2 * (1 - t**2.2) ** 0.8 * (0.7 + 0.3 * np.clip(t * 4, 0, 1))
        c0, c1 = shaded(rng, col, base=(0.7, 0.95), tip=(0.95, 1.3))
        if dry and rng.random() < 0.6:
            c1 = np.array([175, 150, 95.0]) * rng.uniform(0.8, 1.1)
        out.append(prim(spine_=(pts, h), wl=hw, wr=hw, minw=1.5, a=pts[0], b=pts[-1], c0=c0, c1=c1,
                        edge=0.3 * w, tex=0.04, shadow=0.3))
    if rng.random() < 0.5:  # sheath around the base
        sc = np.array([172, 182, 140.0]) if rng.random() < 0.6 else np.array([120, 62, 70.0])
        r = rng.uniform(0.025, 0.045)
        p = blob_poly(rng, rng.normal(0, 0.005, 2), r, rough=0.1, aspect=rng.uniform(0.5, 0.9),
                      ang=rng.uniform(0, TAU))
        out.append(prim(p, a=p.min(0), b=p.max(0), c0=sc * 0.9, c1=sc, alpha=0.9, shadow=0.2, tex=0.02))
    return out


def leaflet_poly(base, heading, length, aspect, heart, n=120):
    """Clover leaflet: a blend of a heart (notch at the apex) and an oval, attached at `base`."""
    t = np.linspace(0, TAU, n, endpoint=False)
    xh = 16 * np.sin(t) ** 3
    yh = 13 * np.cos(t) - 5 * np.cos(2 * t) - 2 * np.cos(3 * t) - np.cos(4 * t)
    xe = 14.5 * np.sin(t)
    ye = -2.5 + 14.5 * np.cos(t)
    x = heart * xh + (1 - heart) * xe
    y = heart * yh + (1 - heart) * ye + 17
    # local: along = y (0 at the base), across = x
    p = np.c_[y, x * aspect] * (length / 29.0)
    return p @ rot(heading).T + base


def clover(rng, col) -> list[dict]:
    n = int(rng.integers(2, 7))
    angs = spread_angles(rng, n, (1.5, 5.0))
    style = rng.choice(["pale", "red", "dark"])
    pet_col = {"pale": jit(rng, col) * 1.25 + 20, "red": jit(rng, REDDISH_STEM), "dark": jit(rng, col) * 0.6}[style]
    pet_w = rng.uniform(0.006, 0.02)
    heart = rng.uniform(0.2, 1.0)
    aspect = rng.uniform(0.75, 1.0)
    chevron = rng.random() < 0.4
    stalks, leaves = [], []
    for a in angs:
        P = rng.uniform(0.3, 0.8)
        pts, h = spine(rng.normal(0, 0.004, 2), a, P, rng.normal(0, 0.4), n=40)
        t = np.linspace(0, 1, 40)
        hw = pet_w * (1 - 0.3 * t)
        stalks.append(prim(spine_=(pts, h), wl=hw, wr=hw, minw=0.8, a=pts[0], b=pts[-1], c0=pet_col * 0.9,
                           c1=pet_col, shadow=0.25, tex=0.0))
        l = rng.uniform(0.17, 0.27) * (0.8 + 0.4 * P)
        T, he = pts[-1], h[-1]
        spread = rng.uniform(1.75, 2.2)
        leaf = []
        for da in (-spread, spread, 0.0):
            ang = he + da + rng.normal(0, 0.1)
            lp = leaflet_poly(T, ang, l * rng.uniform(0.9, 1.05), aspect, heart)
            c0, c1 = shaded(rng, col, base=(0.8, 0.95), tip=(0.95, 1.15))
            tip = T + l * np.array([math.cos(ang), math.sin(ang)])
            leaf.append(prim(lp, a=T, b=tip, c0=c0, c1=c1, edge=0.1 * l, tex=0.04, shadow=0.35))
            if chevron:  # the pale V of white clover
                R = rot(ang)
                v = np.array([[0.6 * l, -0.32 * l * aspect], [0.35 * l, 0.0], [0.6 * l, 0.32 * l * aspect]])
                v = v @ R.T + T
                for q0, q1 in ((v[0], v[1]), (v[1], v[2])):
                    d = q1 - q0
                    sp, hs = spine(q0, math.atan2(d[1], d[0]), float(np.hypot(*d)), n=6)
                    leaf.append(prim(spine_=(sp, hs), wl=np.full(6, 0.025 * l), wr=np.full(6, 0.025 * l),
                                     a=sp[0], b=sp[-1], c0=(c0 + 90) * 0.9, c1=(c0 + 90) * 0.9, alpha=0.4,
                                     shadow=0, tex=0.0))
        leaves.append(leaf)
    out = stalks
    for k in rng.permutation(n):
        out += leaves[k]
    return out


def seedling(rng, col, true_leaves=True) -> list[dict]:
    a = rng.uniform(0, TAU)
    out = []
    stem = jit(rng, REDDISH_STEM) if rng.random() < 0.35 else jit(rng, col) * 1.2 + 15
    r = rng.uniform(0.025, 0.045)
    p = blob_poly(rng, (0, 0), r, rough=0.08)
    out.append(prim(p, a=(-r, 0), b=(r, 0), c0=stem, c1=stem * 0.9, shadow=0.2, tex=0.0))
    cot = jit(rng, col) * rng.uniform(1.0, 1.2) if rng.random() < 0.6 else jit(rng, col)
    obov = rng.random() < 0.4
    stalked = rng.random() < 0.5
    L0 = rng.uniform(0.38, 0.5)
    W0 = L0 * rng.uniform(0.4, 0.65)

    def prof(t):
        u = np.clip((t - 0.15) / 0.85, 0, 1) if stalked else t
        body = np.sin(np.pi * u**1.5) ** 0.6 if obov else np.sqrt(np.clip(1 - (2 * u - 1) ** 2, 0, 1))
        return np.where(t < 0.15, 0.12, body) if stalked else body

    for side in (0, 1):
        ang = a + side * math.pi + rng.normal(0, 0.12)
        L = L0 * rng.uniform(0.88, 1.0)
        gap = rng.uniform(0.005, 0.04)
        out += leaf_prims(rng, gap * np.array([math.cos(ang), math.sin(ang)]), ang, L, W0, prof, cot,
                          curv=rng.normal(0, 0.15), veins="mid" if rng.random() < 0.4 else None, minw=0.8)
    if true_leaves and rng.random() < 0.6:
        for k in range(int(rng.integers(1, 3))):
            ang = a + math.pi / 2 + k * math.pi + rng.normal(0, 0.3)
            L = rng.uniform(0.12, 0.3)
            serr = rng.uniform(0, 0.15)
            out += leaf_prims(rng, (0, 0), ang, L, L * rng.uniform(0.45, 0.7),
                              lambda t: np.sin(np.pi * t**0.9) ** 0.7 * (1 + serr * ((t * 7) % 1 - 0.5)),
                              jit(rng, col) * 0.85, curv=rng.normal(0, 0.2), veins="mid", minw=0.8)
    return out


def rosette(rng, col) -> list[dict]:
    n = int(rng.integers(4, 13))
    angs = spread_angles(rng, n)
    lens = rng.uniform(0.45, 1.0, n)
    lens[0] = 1.0
    shape = rng.choice(["elliptic", "obovate", "spatulate", "plantain", "lanceolate"])
    wrel = rng.uniform(0.25, 0.55)
    veins = {"plantain": "parallel"}.get(shape, rng.choice(["mid", "pinnate", None]))
    wav = rng.uniform(0, 0.06)
    pet = rng.uniform(0.15, 0.35)

    def prof_for(ph):
        def prof(t):
            if shape == "elliptic":
                b = np.sin(np.pi * t) ** 0.6
            elif shape == "obovate":
                b = np.sin(np.pi * t**1.7) ** 0.6
            elif shape == "spatulate":
                b = np.sin(np.pi * t**2.6) ** 0.5
            elif shape == "plantain":
                u = np.clip((t - pet) / (1 - pet), 0, 1)
                b = np.where(t < pet, 0.1 + 0.15 * t / pet, np.maximum(np.sin(np.pi * u**0.85) ** 0.7, 0.25 * (u < 0.3)))
            else:
                b = np.sin(np.pi * t**0.8) ** 0.8
            return b * (1 + wav * np.sin(TAU * 5 * t + ph))
        return prof

    out = []
    for k in np.argsort(-lens):
        L = lens[k]
        out += leaf_prims(rng, rng.normal(0, 0.01, 2), angs[k], L, L * wrel * rng.uniform(0.85, 1.15),
                          prof_for(rng.uniform(0, TAU)), col, curv=rng.normal(0, 0.25), veins=veins)
    if rng.random() < 0.6:  # young leaves in the heart of the rosette
        for a in spread_angles(rng, int(rng.integers(1, 4)))[: 3]:
            L = rng.uniform(0.1, 0.25)
            out += leaf_prims(rng, (0, 0), a, L, L * wrel, prof_for(0.0), jit(rng, col) * 1.15 + 8,
                              curv=rng.normal(0, 0.2), veins=None)
    return out


def lobed(rng, col) -> list[dict]:
    n = int(rng.integers(5, 13))
    angs = spread_angles(rng, n)
    lens = rng.uniform(0.5, 1.0, n)
    lens[0] = 1.0
    rib = jit(rng, REDDISH_STEM) if rng.random() < 0.35 else None
    out = []
    for k in np.argsort(-lens):
        L = lens[k]
        nl = rng.uniform(3, 6.5)
        depth = rng.uniform(0.15, 0.5)  # width left in the sinuses
        hook = rng.uniform(0.2, 0.9)
        serr = rng.uniform(0.0, 0.12)
        p = rng.uniform(1.2, 2.2)
        ph = rng.uniform(0, 1, 2)

        def prof(t, nl=nl, depth=depth, hook=hook, serr=serr, p=p, ph=ph):
            env = np.sin(np.pi * np.clip(t, 0, 1) ** 1.8) ** 0.75
            sides = []
            for s in (0, 1):
                fr = (t * nl + ph[s]) % 1.0
                lobe = depth + (1 - depth) * (1 - fr) ** p
                term = np.clip((t - 0.78) / 0.1, 0, 1)  # entire terminal lobe
                lobe = lobe * (1 - term) + term
                wing = np.clip(t / 0.18, 0, 1)  # narrow winged petiole
                lobe = lobe * wing + 0.15 * (1 - wing)
                teeth = 1 + serr * (((t * 45 + ph[s]) % 1.0) - 0.5)
                w = env * lobe * teeth
                sh = -hook * 0.5 * env * (lobe - depth) * (1 - term) * wing
                sides.append((w, sh))
            return tuple(sides)

        out += leaf_prims(rng, rng.normal(0, 0.01, 2), angs[k], L, L * rng.uniform(0.3, 0.5), prof, col,
                          curv=rng.normal(0, 0.2), veins="mid", n=400, vein_col=rib)
    return out


# smallest plant size S in px: blades of a 40 px tuft would be ~1 px wide and invisible
MIN_S = {"grass": 60, "clover": 40, "seedling": 40, "rosette": 40, "lobed": 40}
PLANTS = {"grass": grass, "clover": clover, "seedling": seedling, "rosette": rosette, "lobed": lobed}


# ----------------------------------------------------------------------------- scene
def noise_field(rng, H, W, cell: float) -> np.ndarray:
    c = max(1.0, cell)
    small = rng.normal(0, 1, (int(H / c) + 3, int(W / c) + 3)).astype(np.float32)
    return cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC if c > 1 else cv2.INTER_NEAREST)


def soil(rng, H, W, k):
    """Soil of one colour family with multi-scale texture, wet patches and fine grit."""
    name = str(rng.choice(list(SOIL_COLOURS)))
    base = jit(rng, SOIL_COLOURS[name], 0.1)
    img = np.empty((H, W, 3), np.float32)
    img[:] = base
    lum = np.zeros((H, W), np.float32)
    amp = rng.uniform(0.6, 1.4)
    for cell, a in ((1.5, 0.05), (5, 0.06), (18, 0.07), (60, 0.07), (220, 0.08)):
        lum += amp * a * noise_field(rng, H, W, cell * k)
    img *= (1 + lum)[..., None]
    # slow colour drift along soil-like axes only (redder / yellower), never towards green
    red, yel = noise_field(rng, H, W, 250 * k), noise_field(rng, H, W, 250 * k)
    img *= 1 + 0.04 * np.stack([red + 0.5 * yel, 0.3 * yel, -0.5 * red - yel], -1)
    if rng.random() < 0.4:  # darker damp patches
        wet = np.clip(noise_field(rng, H, W, 120 * k) - rng.uniform(0.3, 1.0), 0, 1)
        img *= (1 - rng.uniform(0.2, 0.4) * cv2.GaussianBlur(wet, (0, 0), 8 * k))[..., None]
    grit = (rng.random((H, W)) < 0.004).astype(np.float32) * rng.choice([-1, 1], (H, W))
    img *= (1 + 0.35 * cv2.GaussianBlur(grit, (0, 0), 0.7 * k))[..., None]
    return img, name


def clutter(rng, img, k, ld):
    """Clods, stones, dead leaf bits and straw, all lit from the same side (shadows along ld)."""
    H, W = img.shape[:2]
    area = H * W / (480 * 640 * k * k)

    def loc():
        return np.array([rng.uniform(0, W), rng.uniform(0, H)])

    def sample(c):
        u, v = int(np.clip(c[0], 0, W - 1)), int(np.clip(c[1], 0, H - 1))
        return img[v, u].astype(float)

    for _ in range(int(rng.integers(10, 90) * area)):  # clods
        c, r = loc(), k * rng.uniform(3, 22)
        col = sample(c) * rng.uniform(0.85, 1.2)
        p = blob_poly(rng, c, r, aspect=rng.uniform(0.6, 1.0), ang=rng.uniform(0, TAU))
        paint(img, dict(poly=p, a=c - ld * r, b=c + ld * r, c0=col * 1.25, c1=col * 0.75, alpha=1.0, shadow=0.45,
                        edge=0.15 * r, tex=0.08, gamma=1.0), rng, sh_sigma=0.25 * r, sh_off=ld * 0.3 * r)
    for _ in range(int(rng.integers(0, 25) * area)):  # stones
        c, r = loc(), k * rng.uniform(3, 28)
        pts = (rng.normal(0, 1, (9, 2)) * [1, rng.uniform(0.5, 1)]) @ rot(rng.uniform(0, TAU)).T
        hull = cv2.convexHull(pts.astype(np.float32))[:, 0].astype(float)
        hull = hull / np.abs(hull).max() * r + c
        g = rng.uniform(95, 195)
        col = np.array([g, g, g]) * rng.uniform(0.93, 1.07, 3)
        paint(img, dict(poly=hull, a=c - ld * r, b=c + ld * r, c0=col * 1.2, c1=col * 0.7, alpha=1.0, shadow=0.5,
                        edge=0.2 * r, tex=0.05, gamma=1.0), rng, sh_sigma=0.2 * r, sh_off=ld * 0.3 * r)
    for _ in range(int(rng.integers(0, 15) * area)):  # bits of dead leaf
        c, r = loc(), k * rng.uniform(3, 20)
        col = np.array([105, 76, 46.0]) * rng.uniform(0.6, 1.3) * rng.uniform(0.92, 1.08, 3)
        p = blob_poly(rng, c, r, rough=0.45, aspect=rng.uniform(0.3, 0.8), ang=rng.uniform(0, TAU))
        paint(img, dict(poly=p, a=p.min(0), b=p.max(0), c0=col, c1=col * 0.8, alpha=0.95, shadow=0.25,
                        edge=0.1 * r, tex=0.1, gamma=1.0), rng, sh_sigma=0.1 * r + 0.5, sh_off=ld * 0.1 * r)
    for _ in range(int(rng.integers(0, 25) * area)):  # straw
        c, L = loc(), k * rng.uniform(15, 110)
        wd = k * rng.uniform(1.2, 4.0)
        pts, h = spine(c, rng.uniform(0, TAU), L, rng.normal(0, 0.2), n=20)
        col = np.array([205, 180, 118.0]) * rng.uniform(0.65, 1.15) * rng.uniform(0.95, 1.05, 3)
        hw = np.full(20, wd / 2)
        paint(img, dict(poly=ribbon_poly(pts, h, hw, hw), a=pts[0], b=pts[-1], c0=col, c1=col * rng.uniform(0.8, 1.1),
                        alpha=1.0, shadow=0.35, edge=0.3 * wd, tex=0.05, gamma=1.0), rng, sh_sigma=0.4 * wd,
              sh_off=ld * 0.6 * wd)


def lighting(rng, img) -> None:
    H, W = img.shape[:2]
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    if rng.random() < 0.35:  # soft cast shadow over part of the image
        a = rng.uniform(0, TAU)
        d = (xs - rng.uniform(0, W)) * math.cos(a) + (ys - rng.uniform(0, H)) * math.sin(a)
        d += 0.03 * min(H, W) * noise_field(rng, H, W, 0.2 * min(H, W))
        m = 0.5 + 0.5 * np.tanh(d / (2 * rng.uniform(0.005, 0.05) * min(H, W)))
        f = rng.uniform(0.45, 0.75)
        img *= (1 - (1 - f) * m)[..., None] * (1 + m[..., None] * np.float32([-0.03, 0.0, 0.08]))
    cast = rng.uniform(0, 0.1) * rng.choice([-1, 1])  # warm (+) or cool (-)
    img *= np.float32([1 + cast, 1.0, 1 - cast]) * rng.uniform(0.7, 1.3)
    v = rng.uniform(0, 0.4)
    r2 = ((xs - W / 2) ** 2 + (ys - H / 2) ** 2) / ((W / 2) ** 2 + (H / 2) ** 2)
    img *= (1 - v * r2)[..., None]


def camera(rng, img) -> tuple[np.ndarray, int | None]:
    s = rng.uniform(0, 2)
    if s > 0.25:
        img = cv2.GaussianBlur(img, (0, 0), s)
    img = img + rng.normal(0, rng.uniform(1, 6), img.shape).astype(np.float32)
    img += np.sqrt(np.clip(img, 0, None)) * rng.uniform(0, 0.4) * rng.normal(0, 1, img.shape).astype(np.float32)
    bgr = cv2.cvtColor(np.clip(img, 0, 255).astype(np.uint8), cv2.COLOR_RGB2BGR)
    q = None
    if rng.random() < 0.5:
        q = int(rng.integers(50, 96))
        bgr = cv2.imdecode(cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, q])[1], cv2.IMREAD_COLOR)
    return bgr, q


def render(rng, kind: str):
    """(BGR image, true centre (u, v), plant size S px, notes) of one `kind` weed on soil."""
    W, H = SIZES[int(rng.integers(3))] if rng.random() > 0.1 else (2592, 1944)
    short = min(W, H)
    k = short / 480 * rng.uniform(0.7, 1.4)  # clutter scale
    img, soil_name = soil(rng, H, W, k)
    la = rng.uniform(0, TAU)
    ld = np.array([math.cos(la), math.sin(la)])  # direction shadows are cast
    clutter(rng, img, k, ld)

    colour = str(rng.choice(list(PLANT_COLOURS)))
    col = jit(rng, PLANT_COLOURS[colour], 0.1)
    prims = PLANTS[kind](rng, col)
    pts = np.concatenate([outline(p) for p in prims]).astype(np.float32)
    (ex, ey), rad = cv2.minEnclosingCircle(pts)
    S = math.exp(rng.uniform(math.log(MIN_S[kind]), math.log(0.4 * short)))
    sc = S / (2 * rad)
    lo, hi = pts.min(0) * sc, pts.max(0) * sc
    m = 0.05 * S + 2
    cu = rng.uniform(m - lo[0], W - 1 - m - hi[0])
    cv = rng.uniform(m - lo[1], H - 1 - m - hi[1])
    c = np.array([cu, cv])
    ec = np.array([ex, ey]) * sc + c  # centre of the enclosing circle

    # tiny weeds well away from the plant
    if rng.random() < 0.4:
        for _ in range(int(rng.integers(1, 4))):
            s = rng.uniform(min(6.0, S / 4), S / 4)
            for _try in range(50):
                q = np.array([rng.uniform(s, W - s), rng.uniform(s, H - s)])
                if np.linalg.norm(q - ec) > S / 2 + 0.3 * S + s:
                    break
            else:
                continue
            sp = seedling(rng, jit(rng, col, 0.15), true_leaves=False) if rng.random() < 0.6 else \
                grass(rng, jit(rng, col, 0.15))[:3]
            spts = np.concatenate([outline(p) for p in sp]).astype(np.float32)
            _, srad = cv2.minEnclosingCircle(spts)
            for p in sp:
                paint(img, placed(p, s / (2 * srad), q), rng, sh_sigma=0.5, sh_off=ld * 0.5)

    sh_sigma = max(0.7, 0.012 * S)
    sh_off = ld * S * rng.uniform(0.004, 0.02)
    light = None
    if rng.random() < 0.5:
        b = rng.uniform(0, TAU)
        light = (c, np.array([math.cos(b), math.sin(b)]), S / 2, rng.uniform(0.05, 0.2))
    for p in prims:
        paint(img, placed(p, sc, c), rng, sh_sigma=sh_sigma, sh_off=sh_off, light=light)

    lighting(rng, img)
    bgr, q = camera(rng, img)
    return bgr, (float(cu), float(cv)), S, dict(size=f"{W}x{H}", soil=soil_name, colour=colour, jpeg=q)


# ----------------------------------------------------------------------------- evaluation
def save_fail(path: str, img, truth, ans, S: float, text: str) -> None:
    """The whole image (≤ 880 px wide) and, to its right, a 400 px close-up of 2.4 S around the
    truth; green cross = truth, red cross = answer."""

    def crosses(im, s, o):
        for p, colr in ((truth, (0, 255, 0)), (ans, (0, 0, 255))):
            if p is not None:
                u, v = int(round((p[0] - o[0]) * s)), int(round((p[1] - o[1]) * s))
                cv2.drawMarker(im, (u, v), (0, 0, 0), cv2.MARKER_CROSS, 26, 4, cv2.LINE_AA)
                cv2.drawMarker(im, (u, v), colr, cv2.MARKER_CROSS, 24, 2, cv2.LINE_AA)

    s = min(1.0, 880 / img.shape[1])
    full = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA) if s < 1 else img.copy()
    crosses(full, s, (0, 0))
    h = int(1.2 * S)
    pad = cv2.copyMakeBorder(img, h, h, h, h, cv2.BORDER_CONSTANT)
    u, v = int(round(truth[0])), int(round(truth[1]))
    zs = 400 / (2 * h)
    zoom = cv2.resize(pad[v:v + 2 * h, u:u + 2 * h], (400, 400),
                      interpolation=cv2.INTER_AREA if zs < 1 else cv2.INTER_CUBIC)
    crosses(zoom, zs, (u - h, v - h))
    H = max(full.shape[0], 400)
    out = np.zeros((H + 24, full.shape[1] + 400, 3), np.uint8)
    out[24:24 + full.shape[0], :full.shape[1]] = full
    out[24:424, full.shape[1]:] = zoom
    cv2.putText(out, text, (5, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.imwrite(path, out)


def table(rows: dict[str, list[dict]]) -> None:
    print(f"  {'kind':9s} {'n':>3s} {'det':>5s} {'med e/S':>8s} {'p90 e/S':>8s} {'≤0.1S':>6s} {'≤0.2S':>6s}"
          f" {'wrong':>6s} {'ms':>6s}")
    for name, rs in rows.items():
        e = np.array([r["err"] for r in rs])
        det = np.isfinite(e)
        f = e[det]
        med = f"{np.median(f):8.3f}" if len(f) else "       -"
        p90 = f"{np.percentile(f, 90):8.3f}" if len(f) else "       -"
        print(f"  {name:9s} {len(rs):3d} {det.mean():5.0%} {med} {p90} {np.mean(e <= 0.1):6.0%} "
              f"{np.mean(e <= 0.2):6.0%} {np.mean(det & (e > 0.5)):6.0%} {np.median([r['ms'] for r in rs]):6.1f}")
    for name, rs in rows.items():
        reasons = Counter(r["reason"] or "ok" for r in rs)
        methods = Counter(r["method"] for r in rs)
        print(f"  {name:9s} reasons: {dict(reasons.most_common())}  methods: {dict(methods.most_common())}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--save-fails", metavar="DIR")
    ap.add_argument("--roi", action="store_true", help="give the detector an ellipse around the true centre")
    args = ap.parse_args(argv)
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    for k in kinds:
        if k not in PLANTS:
            ap.error(f"unknown kind {k!r}; choose from {', '.join(KINDS)}")
    cv2.setNumThreads(1)
    if args.save_fails:
        os.makedirs(args.save_fails, exist_ok=True)

    t0 = time.perf_counter()
    by_kind: dict[str, list[dict]] = defaultdict(list)
    for i in range(args.n):
        kind = kinds[i % len(kinds)]
        img, truth, S, notes = render(np.random.default_rng([args.seed, i]), kind)
        roi = None
        if args.roi:
            r2 = np.random.default_rng([args.seed, i, 1])
            r = r2.uniform(1.2, 2.5) * S / 2
            a, o = r2.uniform(0, TAU), r2.uniform(0, 0.3 * r)
            roi = ((truth[0] + o * math.cos(a), truth[1] + o * math.sin(a)), (2 * r, 2 * r), 0.0)
        dbg: dict = {}
        ts = time.perf_counter()
        d = detect_centre(img, roi, debug=dbg)
        ms = (time.perf_counter() - ts) * 1000
        ok = d.reason is None and d.pixel is not None
        err = math.hypot(d.pixel[0] - truth[0], d.pixel[1] - truth[1]) / S if ok else math.inf
        rec = dict(err=err, reason=d.reason, method=dbg.get("method") or "-", ms=ms)
        by_kind[kind].append(rec)
        if args.save_fails and not err <= 0.15:
            text = (f"#{i} {kind} S={S:.0f} err={err:.2f}S reason={d.reason} method={rec['method']} "
                    f"conf={d.confidence:.2f} {notes['size']} {notes['soil']}/{notes['colour']}")
            save_fail(os.path.join(args.save_fails, f"{i:03d}_{kind}.png"), img, truth, d.pixel, S, text)
    rows = {k: by_kind[k] for k in kinds if by_kind[k]}
    rows["all"] = [r for k in kinds for r in by_kind[k]]
    print(f"other_renderer_plants: n {args.n}, seed {args.seed}, roi {'on' if args.roi else 'off'}; "
          f"error / S (median, p90 of detections; ≤0.1S, ≤0.2S and wrong = detected > 0.5 S off, "
          f"as shares of all)")
    table(rows)
    print(f"  total run time {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
