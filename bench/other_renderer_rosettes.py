"""Rosettes drawn by a renderer other than sim_bench: how far the detector's centre is from the
true one, in units of the longest leaf L. Prints two tables:

1. masks: uneven rosettes as clean binary masks (~80 px, the detector's stage-2 grid), centre by
   `leaf_axes.tip_axes_centre`, the tree median and the geometric median;
2. images: the same kind of rosettes drawn with OpenCV on plain noisy soil at 1280×720, the
   whole `detect_centre` (no ROI), per leaf outline and per estimator the detector used.

    .venv/bin/python bench/other_renderer_rosettes.py [--n 100] [--seed 0]

Leaves are lens-shaped, elliptic, obovate or petiolate, 3–10 per plant, with Dirichlet gaps
between their directions (uneven), longest first so shorter leaves overlap them.
"""

from __future__ import annotations

import argparse
import math
from collections import defaultdict

import cv2
import numpy as np

from capm_field import leaf_axes
from capm_field.detector import detect_centre
from capm_field.plant_centre import geometric_median
from capm_field.tree_median import tree_median

SHAPES = ("lens", "ellipse", "obovate", "petiolate")


def leaf_poly(c: np.ndarray, a: float, L: float, W: float, shape: str) -> np.ndarray:
    """Outline of a leaf of length L and width W from `c` towards angle `a`."""
    t = np.linspace(0, 1, 30)
    if shape == "lens":
        hw = W / 2 * np.sin(np.pi * t**0.8)
    elif shape == "ellipse":
        hw = W / 2 * np.sqrt(np.clip(1 - (2 * t - 1) ** 2, 0, 1))
    elif shape == "obovate":
        hw = W / 2 * np.sin(np.pi * t**1.8) ** 0.7
    else:  # petiolate: a narrow stalk for the first quarter
        hw = W / 2 * np.where(t < 0.25, 0.12, np.sin(np.pi * np.clip((t - 0.25) / 0.75, 0, 1) ** 0.9))
    pts = np.c_[t * L, hw]
    pts = np.r_[pts, pts[::-1] * [1, -1]]
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    return pts @ R.T + c


def leaves(rng: np.random.Generator, L: float, n_range=(3, 11)):
    n = int(rng.integers(*n_range))
    angs = rng.uniform(0, 2 * np.pi) + np.cumsum(rng.dirichlet(np.full(n, rng.uniform(0.8, 3.0))) * 2 * np.pi)
    lens = L * rng.uniform(0.4, 1.0, n)
    lens[0] = L
    return [(angs[k], lens[k]) for k in np.argsort(-lens)]


def render(rng: np.random.Generator, W: int = 1280, H: int = 720):
    """(BGR image, true centre, L, leaf outline) of one rosette on noisy brown/grey soil."""
    v = rng.uniform(60, 160)
    red = v * rng.uniform(1.0, 1.3)
    img = np.empty((H, W, 3), np.float32)
    img[:] = (v * rng.uniform(0.55, 0.95), red * rng.uniform(0.8, 1.0), red)
    n = cv2.resize(rng.normal(0, 1, (H // 16 + 1, W // 16 + 1)).astype(np.float32), (W, H))
    img *= (1 + 0.12 * n)[..., None]
    c = np.array([W / 2 + rng.uniform(-150, 150), H / 2 + rng.uniform(-100, 100)])
    L = rng.uniform(60, 220)
    shape = str(rng.choice(SHAPES))
    col = np.array([rng.uniform(20, 70), rng.uniform(100, 190), rng.uniform(30, 110)])
    for a, ln in leaves(rng, L):
        p = leaf_poly(c, a + rng.uniform(-0.05, 0.05), ln, ln * rng.uniform(0.25, 0.5), shape)
        cc = col * rng.uniform(0.85, 1.15)
        cv2.fillPoly(img, [np.round(p * 16).astype(np.int32)], cc.tolist(), cv2.LINE_AA, shift=4)
        if rng.random() < 0.5:  # a lighter midrib
            tip = c + ln * np.array([math.cos(a), math.sin(a)])
            cv2.line(img, tuple(np.round(c * 16).astype(int)), tuple(np.round(tip * 16).astype(int)),
                     (cc * 1.25).tolist(), max(1, int(ln / 70)), cv2.LINE_AA, shift=4)
    img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.5, 1.5))
    img += rng.normal(0, rng.uniform(1, 5), img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8), c, L, shape


def mask_rosette(rng: np.random.Generator, S: int = 80):
    """(mask, true centre, L, outline) of a rosette of longest leaf S/2 on an (S+40)² grid."""
    m = np.zeros((S + 40, S + 40), np.uint8)
    c = np.array([S / 2 + 20 + rng.uniform(-10, 10), S / 2 + 20 + rng.uniform(-10, 10)])
    shape = str(rng.choice(SHAPES[:3]))
    for a, ln in leaves(rng, S / 2, (3, 9)):
        p = leaf_poly(c, a, ln, ln * rng.uniform(0.25, 0.5), shape)
        cv2.fillPoly(m, [np.round(p * 16).astype(np.int32)], 1, cv2.LINE_8, shift=4)
    return m > 0, c, S / 2, shape


def _row(name: str, e: list[float]) -> str:
    a = np.asarray(e, float)
    f = a[np.isfinite(a)]
    if len(f) == 0:
        return f"  {name:18s} n {len(a):3d}  no answer"
    return (f"  {name:18s} n {len(a):3d}  answered {len(f) / len(a):4.0%}  median {np.median(f):.3f} L  "
            f"p90 {np.percentile(f, 90):.3f} L  within 0.1 L {np.mean(a < 0.1):4.0%}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    cv2.setNumThreads(1)

    rng = np.random.default_rng(args.seed)
    est: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for _ in range(args.n):
        plant, c, L, shape = mask_rosette(rng)
        ys, xs = np.nonzero(plant)
        g = geometric_median(np.c_[xs, ys].astype(float))
        ta = leaf_axes.tip_axes_centre(plant, g)
        for name, p in (("tip_axes", None if ta is None else ta[0]), ("tree_median", tree_median(plant)[0]),
                        ("geometric_median", g)):
            est[name][shape].append(math.inf if p is None else float(np.linalg.norm(np.asarray(p) - c) / L))
    print(f"masks ({args.n} rosettes, seed {args.seed}): error / L")
    for name, by_shape in est.items():
        print(_row(name, [e for v in by_shape.values() for e in v]))

    rng = np.random.default_rng(args.seed + 1)
    by_shape, by_method, errs = defaultdict(list), defaultdict(list), []
    for _ in range(args.n):
        img, c, L, shape = render(rng)
        dbg: dict = {}
        d = detect_centre(img, debug=dbg)
        e = math.inf if d.pixel is None else math.hypot(d.pixel[0] - c[0], d.pixel[1] - c[1]) / L
        errs.append(e)
        by_shape[shape].append(e)
        by_method[dbg.get("method") or f"({d.reason})"].append(e)
    print(f"images ({args.n} rosettes 1280×720, seed {args.seed + 1}): detect_centre error / L")
    print(_row("all", errs))
    for k, v in sorted(by_shape.items()):
        print(_row(k, v))
    print("  by estimator:")
    for k, v in sorted(by_method.items(), key=lambda kv: -len(kv[1])):
        print(_row(k, v))


if __name__ == "__main__":
    main()
