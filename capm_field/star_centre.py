"""Stage 2's check of an answer by straight lines of sight inside the plant (session 59).

Leaves, blades and stalks grow out from the biological centre in nearly straight lines, so a
plant's mask is close to star-shaped round its centre: from there, the segment to almost any
plant pixel stays on the plant. `visibility(plant, X)` is that share for a point X (the targets:
up to TARGETS plant pixels; a segment counts when each of its SAMPLES points falls on the plant
grown by one pixel, so a blurred 1-px gap does not break a petiole). A point on one leaf sees
little more than that leaf.

`star_check` replaces an estimator's answer that sees < LOW × what the plant's best point sees
when that best point sees ≥ STAR_MIN of the plant (the mask is star-shaped about it: a rosette,
a grass fan), by the mean of the points within TOP of the best. Where the mask is not star-shaped
(clover trefoils whose petioles the threshold missed: their centre sees ~0.4–0.8 of the plant) it
does nothing: there the estimators' hubs and stalks know more than the outline.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .compiled import kernel

TARGETS = 300  # plant pixels a point must see (a raster-order subsample of the mask)
SAMPLES = 32  # points along each line of sight
STRIDE = 2  # candidate points: plant pixels on this grid
LOW = 0.5  # an answer seeing less than this × the best point's share is replaced ...
STAR_MIN = 0.9  # ... when the best point sees at least this share of the plant
TOP = 0.03  # the star centre: the mean of the points within this share of the best
COARSE, COARSE_SLACK = 6, 0.1  # `star_check` makes the map only if a point of this grid sees ≥ STAR_MIN − slack
MAX_CANDIDATES = 2500  # (a plant window is ~80 px across: ≤ ~1 600 candidates at STRIDE 2)


def _grown(plant: np.ndarray) -> np.ndarray:
    return cv2.dilate(plant.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0


def _targets(plant: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(plant)
    step = max(1, math.ceil(len(xs) / TARGETS))
    return np.c_[xs[::step], ys[::step]].astype(np.float32)


def _seen(grown: np.ndarray, C: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Share of the targets T (n, 2) seen from each point of C (m, 2) along lines inside `grown`:
    the compiled loop (it stops at a line's first sample off the plant; a drawn disc of ~700
    points, where no line stops early, 42 against 420 ms in numpy, the other core busy), else
    numpy, in the same float32 arithmetic: the same shares."""
    if _seen_loop is not None:
        return _seen_loop(np.ascontiguousarray(grown, np.uint8), np.ascontiguousarray(C, np.float32),
                          np.ascontiguousarray(T, np.float32), _tk())
    return _seen_numpy(grown, C, T)


def _tk() -> np.ndarray:
    return np.linspace(0.0, 1.0, SAMPLES, dtype=np.float32)


@kernel(lambda nb: nb.float32[::1](nb.uint8[:, ::1], nb.float32[:, ::1], nb.float32[:, ::1], nb.float32[::1]))
def _seen_loop(grown, C, T, tk):  # pragma: no cover - compiled
    h, w = grown.shape
    out = np.empty(C.shape[0], np.float32)
    for a in range(C.shape[0]):
        cx, cy = C[a, 0], C[a, 1]
        n = 0
        for b in range(T.shape[0]):
            dx, dy = T[b, 0] - cx, T[b, 1] - cy
            ok = True
            for k in range(tk.shape[0]):
                xi = min(max(np.int64(np.rint(cx + dx * tk[k])), 0), w - 1)
                yi = min(max(np.int64(np.rint(cy + dy * tk[k])), 0), h - 1)
                if grown[yi, xi] == 0:
                    ok = False
                    break
            n += ok
        out[a] = np.float32(n / T.shape[0])
    return out


def _seen_numpy(grown: np.ndarray, C: np.ndarray, T: np.ndarray) -> np.ndarray:
    tk = _tk()[None, None, :, None]
    h, w = grown.shape
    out = np.empty(len(C), np.float32)
    for a in range(0, len(C), 128):  # (blocks of 128 points: ~1.2 M samples at a time)
        c = C[a:a + 128, None, None, :]
        pts = c + (T[None, :, None, :] - c) * tk  # (float32 throughout, as the loop)
        xi = np.clip(np.rint(pts[..., 0]).astype(np.int32), 0, w - 1)
        yi = np.clip(np.rint(pts[..., 1]).astype(np.int32), 0, h - 1)
        out[a:a + 128] = grown[yi, xi].all(axis=2).mean(axis=1)
    return out


def visibility(plant: np.ndarray, X: np.ndarray) -> float:
    """Share of the plant seen from X (mask pixels (x, y)) along straight lines on the plant."""
    if not plant.any():
        return 0.0
    return _share(_grown(plant), _targets(plant), X)


def _share(grown: np.ndarray, T: np.ndarray, X: np.ndarray) -> float:
    return float(_seen(grown, np.asarray(X, np.float32).reshape(1, 2), T)[0])


def _candidates(plant: np.ndarray, stride: int) -> np.ndarray:
    ys, xs = np.nonzero(plant[::stride, ::stride])
    return np.c_[xs * stride, ys * stride].astype(np.float32)


def star_point(plant: np.ndarray, at_least: float = 0.0) -> tuple[np.ndarray, float] | None:
    """(the star centre, the share its best point sees), or None for an empty or huge mask, or
    when no point of a coarser grid (COARSE) sees at least `at_least` − COARSE_SLACK (a clover
    whose petioles are missing from the mask: its map, 7–30 ms on bench seed 0, is not made)."""
    return _star(plant, _grown(plant), _targets(plant), at_least)


def _star(plant: np.ndarray, grown: np.ndarray, T: np.ndarray, at_least: float) -> tuple[np.ndarray, float] | None:
    C = _candidates(plant, STRIDE)
    if len(C) == 0 or len(C) > MAX_CANDIDATES:
        return None
    if at_least > 0 and float(_seen(grown, _candidates(plant, COARSE), T).max()) < at_least - COARSE_SLACK:
        return None
    V = _seen(grown, C, T)
    best = float(V.max())
    return C[V >= best - TOP].mean(axis=0), best


def star_check(plant: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
    """The star centre if it should replace the answer uv (see the module's docstring), else None."""
    if not plant.any():
        return None
    grown, T = _grown(plant), _targets(plant)
    v = _share(grown, T, uv)
    if v >= LOW:  # (the answer already sees ≥ LOW ≥ LOW × any best: the map is not needed)
        return None
    got = _star(plant, grown, T, STAR_MIN)
    if got is None:
        return None
    X, best = got
    return X if best >= STAR_MIN and v < LOW * best else None
