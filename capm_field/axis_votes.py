"""Leaf-axis votes: where a plant's leaf and blade edges, drawn on along their own direction,
converge (the biological centre of a rosette or a grass fan; several separate points for compound
leaves). `axis_votes` makes the map, `vote_peaks` counts its separate strong peaks, which the
stage-2 cascade (`capm_field.centre_cascade`) uses to tell plants of one apex from scattered or
compound ones. Coordinates are (x, y) pixels of the plant's grid (see `capm_field.plant_centre`).
"""

from __future__ import annotations

import cv2
import numpy as np

from .compiled import kernel
from .local_peaks import disc_peaks

THIN_BLADE, THIN_ROUND = 0.02, 0.06  # a plant's mean half-width / its size: below THIN_ROUND its parts are blades
# (`fan_apex` is tried first, and the tree median's votes count: fully from THIN_BLADE down); round parts' edges
# vote all over the plant
SCATTER_PEAKS = 4  # vote peaks (≥ 0.7 of the highest, 0.12·size apart) that mark a plant without one apex
# measured on the bench (seed 0, tree-median cases): clover ≥ 2 always, mostly ≥ 3; rosettes 1 in
# 46 of 64; geometric median at ≥ 4 peaks: wrong 22 → 8, p90 29.7 → 19.7 mm, median 5.7 → 5.2 mm


def vote_peaks(votes: np.ndarray, size: float) -> int:
    """Number of separate strong peaks of a leaf-axis vote map (see `axis_votes`)."""
    r = max(2, int(0.12 * size))
    return int(np.count_nonzero(disc_peaks(votes, votes >= 0.7, r)))


def axis_votes(vi: np.ndarray, plant: np.ndarray, size: float, scale: float = 0.015) -> np.ndarray:
    """Leaf-axis convergence map in [0, 1]: every leaf/blade edge votes along its own direction.

    Blade edges, midribs and elongated leaf margins run towards where the leaves emerge, so
    lines drawn along them (structure-tensor orientation) pile up at the biological centre.
    """
    h, w = vi.shape
    f = cv2.GaussianBlur(vi, (0, 0), 1.0)
    gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)
    sg = max(1.0, scale * size)
    jxx = cv2.GaussianBlur(gx * gx, (0, 0), sg)
    jyy = cv2.GaussianBlur(gy * gy, (0, 0), sg)
    jxy = cv2.GaussianBlur(gx * gy, (0, 0), sg)
    tr = jxx + jyy
    coh = np.sqrt((jxx - jyy) ** 2 + 4 * jxy**2) / (tr + 1e-9)
    near = cv2.dilate(plant.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    wgt = coh * np.sqrt(tr) * near
    ys, xs = np.nonzero(wgt > 0.2 * wgt.max())
    if len(xs) < 5:
        return np.zeros((h, w), np.float32)
    if len(xs) > 1500:  # subsample for speed
        sel = np.random.default_rng(0).choice(len(xs), 1500, replace=False)
        ys, xs = ys[sel], xs[sel]
    # edge direction = perpendicular to the dominant gradient
    phi = 0.5 * np.arctan2(2 * jxy[ys, xs], jxx[ys, xs] - jyy[ys, xs]) + np.pi / 2
    dx, dy = np.cos(phi).astype(np.float32), np.sin(phi).astype(np.float32)
    L = int(0.6 * size)
    acc = line_votes(xs, ys, dx, dy, wgt[ys, xs].astype(np.float64), L, h, w).reshape(h, w).astype(np.float32)
    acc = cv2.GaussianBlur(acc, (0, 0), max(1.0, 0.02 * size))
    return acc / (acc.max() + 1e-9)


def line_votes(xs: np.ndarray, ys: np.ndarray, dx: np.ndarray, dy: np.ndarray, wts: np.ndarray, L: int, h: int,
               w: int) -> np.ndarray:
    """Each point (xs[i], ys[i]) (int64) votes `wts[i]` (float64) into every grid pixel nearest to
    the points at t = −L … L along its direction (dx[i], dy[i]) (float32): a flat (h·w,) float64
    map. Pixels off the grid get no vote. "Nearest" is x + d·t + L + 1.5 in float32, truncated,
    − (L + 1): the offset keeps the values positive so truncation rounds like floor(x + ½).

    The compiled loop (`capm_field.compiled`) makes no arrays: 0.8 against 2.4 ms a call for
    ~150 000 points (session 41). Without it, numpy: the (n, 2L + 1) index and weight arrays summed
    by `np.bincount`, in the same float32 arithmetic and the same order, so the same map to the
    last bit (tests/test_axis_votes.py).
    """
    if _line_votes_loop is not None:
        return _line_votes_loop(xs, ys, dx, dy, wts, L, h, w)
    return _line_votes_numpy(xs, ys, dx, dy, wts, L, h, w)


@kernel(lambda nb: nb.float64[::1](nb.int64[:], nb.int64[:], nb.float32[:], nb.float32[:], nb.float64[:], nb.int64,
                                   nb.int64, nb.int64))
def _line_votes_loop(xs, ys, dx, dy, wts, L, h, w):  # pragma: no cover - compiled
    acc = np.zeros(h * w, np.float64)
    off = np.float32(L + 1.5)
    for i in range(xs.shape[0]):
        cx, cy = np.float32(xs[i]), np.float32(ys[i])
        ddx, ddy, wt = dx[i], dy[i], wts[i]
        for k in range(2 * L + 1):
            t = np.float32(k - L)
            px = np.int64(ddx * t + cx + off) - (L + 1)
            py = np.int64(ddy * t + cy + off) - (L + 1)
            if 0 <= px < w and 0 <= py < h:
                acc[py * w + px] += wt
    return acc


def _line_votes_numpy(xs, ys, dx, dy, wts, L, h, w) -> np.ndarray:
    t = np.arange(-L, L + 1, dtype=np.float32)
    off = np.float32(L + 1.5)

    def along(c: np.ndarray, d: np.ndarray) -> np.ndarray:  # (c + d·t + off) in float32, truncated, − (L + 1)
        p = np.multiply(d[:, None], t[None, :])
        p += c.astype(np.float32)[:, None]
        p += off
        return p.astype(np.int64) - (L + 1)

    px, py = along(xs, dx), along(ys, dy)
    idx = np.where((px >= 0) & (px < w) & (py >= 0) & (py < h), py * w + px, h * w)  # off the grid: a dropped bin
    ww = np.repeat(np.asarray(wts, np.float64), len(t))
    return np.bincount(idx.ravel(), weights=ww, minlength=h * w + 1)[: h * w]
