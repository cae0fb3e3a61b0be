"""Stage 2 of the weed-centre detector: where a plant's leaves emerge, from its mask.

Every estimator works on one plant's mask (bool, ~PLANT_PX across, see `capm_field.centre_cascade`)
and, where it needs colour, the vegetation index on the same grid; coordinates are (x, y) grid
pixels. They assume nothing about the camera. `capm_field.centre_cascade.centre_fullres` chooses,
the first that answers:
  - thin blades leaning one way (a grass fan): `capm_field.fan_apex`, where the blade axes converge;
  - plants with rounded parts (clover, seedlings, broad rosettes): `petiole_centre` (straight
    stalks crossing), `line_hub` (thin parts converging), each only inside the broad parts'
    hull (`within_broad_hull`) — this module;
  - leaf axes converging at ≥ 2 points (`capm_field.axis_votes`): first stalks the index misses
    but the grey image shows, `capm_field.stalks` (where they meet); then
  - compound leaves whose stalks do not show (clover trefoils): `capm_field.compound_leaf`,
    where rays back from the three-lobed hubs agree; then, for compound leaves, `petiole_centre`
    again with bent ridges split (`split`: two petioles meeting in a V); then, for rounded parts,
    `component_median` or `pair_gap` (separate parts round an empty middle, same hull rule);
  - leaf axes converging at several separate points: where the leaves' axes traced back from
    their tips meet (`capm_field.leaf_axes`, rosettes), else the `geometric_median` of the plant;
  - otherwise `capm_field.tree_median`: Σ geodesic distance (`capm_field.geodesic`) to the leaf
    tips minus leaf-axis votes.
This module holds the estimators that work on the plant's parts (its broad parts, thin parts and
straight stalks) and the geometric median.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .components import components
from .order_stats import percentile

PET_MINLEN = 0.07  # of the plant size
PET_K = 1.0  # ridge threshold, × the 99th percentile of the ridge response on the soil
PET_RIM = 2.0  # px: a piece whose median distance from the broad parts is this or less runs along a leaf's rim
PET_LEAF_GAP = 0.10  # of the plant size: farthest a stalk piece may stay from every broad part


PET_DIRS = 8  # `split`: ridge direction bins (two adjacent ones make a piece) that part a bent piece's arms
PET_SPLIT_LEN = 0.12  # `split`: × size, the longest piece meeting at the answer must reach this (bench seeds
# 0–7, the only answers that moved: clovers 20.1 → 0.3, 21.3 → 3.2, 25.6 → 2.3 mm, one better by < 3 mm; with
# no such floor two clovers 8.7 → 27.1 and 36.6 → 60.1 mm, where two short pieces of leaf shading met)


def _piece(P: np.ndarray, size: float) -> tuple | None:
    """A straight stalk piece from its pixels (x, y): (middle, unit direction, half-length, length),
    or None if shorter than PET_MINLEN × size or than 3× its width."""
    m = P.mean(0)
    ev, evec = np.linalg.eigh(np.cov((P - m).T) + 1e-9 * np.eye(2))
    d = evec[:, 1]
    t = (P - m) @ d
    L = float(t.max() - t.min()) + 1
    wdt = math.sqrt(12 * max(ev[0], 0)) + 0.5
    if L < PET_MINLEN * size or L < 3 * wdt:
        return None
    return (m + d * (t.max() + t.min()) / 2, d, L / 2, L)


def petiole_centre(plant: np.ndarray, vi: np.ndarray, soil: float, thr: float, parts: tuple[float, np.ndarray] | None = None,
                   split: bool = False) -> np.ndarray | None:
    """Where ≥ 2 straight stalks (petioles) meet, in mask pixels; or None.

    Clover petioles and rosette leaf stalks are straight lines from the biological centre to
    their leaf. Thin parts (mask minus its opening by a disc ~2.5 % of the plant size) are
    split into pieces; each elongated piece (length ≥ PET_MINLEN of the size, ≥ 3× longer than wide)
    gives a line (principal axis of its second moments) if it comes within PET_LEAF_GAP of a
    broad part (a stalk carries a leaf) and does not run along one (median distance from the
    broad parts > PET_RIM px: a ridge just outside a leaf's edge). Stalks start at the centre, so the
    lines of two stalks cross there, beyond one end of each piece (a stalk's start may be
    hidden under young leaves), whereas a leaf junction is on one stalk only. Every crossing
    of two non-parallel lines near an end of both pieces is a hypothesis; it is supported by
    the pieces whose line passes within 4 % of the size and whose nearer end is within reach;
    the best-supported hypothesis (≥ 2 pieces) is refined by least squares over its support.
    It must lie in the plant's hull and within 0.12 × size of the plant or of a stalk piece
    (petioles seen only as index ridges may be long).
    With `split`, a piece that is not straight (two petioles meeting in a V, one ridge component)
    is also split by the ridge's direction (PET_DIRS) into straight pieces, and the answer needs
    a supporting piece ≥ PET_SPLIT_LEN × size (the cascade asks this late, for compound leaves only).
    """
    if int(plant.sum()) < 20:
        return None
    size, broad = parts if parts is not None else broad_parts(plant)
    ys, xs = np.nonzero(plant)
    pm = plant.astype(np.uint8)
    # ridges of the index (thin lines greener than both sides): Hessian at ~1 px
    f = cv2.GaussianBlur(vi, (0, 0), 1.0)
    fxx = cv2.Sobel(f, cv2.CV_32F, 2, 0, ksize=3)
    fyy = cv2.Sobel(f, cv2.CV_32F, 0, 2, ksize=3)
    fxy = cv2.Sobel(f, cv2.CV_32F, 1, 1, ksize=3)
    disc = np.sqrt((fxx - fyy) ** 2 + 4 * fxy**2)
    lam_min = 0.5 * (fxx + fyy - disc)
    lam_max = 0.5 * (fxx + fyy + disc)
    ridge = np.where((lam_min < 0) & (np.abs(lam_max) < 0.5 * np.abs(lam_min)), -lam_min, 0.0)
    far = cv2.dilate(pm, np.ones((7, 7), np.uint8)) == 0
    noise = percentile(ridge[far], 99) if np.count_nonzero(far) > 50 else percentile(ridge.ravel(), 90)
    hull = np.zeros_like(pm)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.c_[xs, ys].astype(np.int32)), 1)
    thin = ((ridge > max(noise, 1e-4) * PET_K) & ~broad & (vi > soil + 0.3 * (thr - soil)) & (hull > 0)).astype(np.uint8)
    thin |= (pm & ~broad).astype(np.uint8)
    n, lab, stats, _ = components(thin)
    # a stalk carries a leaf (or starts under one): a thin piece far from every broad part is a
    # blade or straw grouped with the plant, and its line crosses the real stalks anywhere
    off_leaf = cv2.distanceTransform((~broad).astype(np.uint8), cv2.DIST_L2, 3) if broad.any() else None
    segs = []  # (centre point, unit direction, half-length, weight)
    used = []  # labels of the stalk pieces
    theta = None  # ridge direction per pixel, made when a bent piece needs splitting
    for c in range(1, n):
        if stats[c, cv2.CC_STAT_AREA] < 0.04 * size:
            continue
        if off_leaf is not None:
            off = off_leaf[lab == c]
            if float(off.min()) > max(PET_LEAF_GAP * size, 2.0) or percentile(off, 50) <= PET_RIM:
                continue  # off every leaf (a blade or straw), or a ridge along a leaf's rim
        yy, xx = np.nonzero(lab[stats[c, cv2.CC_STAT_TOP]:stats[c, cv2.CC_STAT_TOP] + stats[c, cv2.CC_STAT_HEIGHT],
                                stats[c, cv2.CC_STAT_LEFT]:stats[c, cv2.CC_STAT_LEFT] + stats[c, cv2.CC_STAT_WIDTH]] == c)
        P = np.c_[xx + stats[c, cv2.CC_STAT_LEFT], yy + stats[c, cv2.CC_STAT_TOP]].astype(float)
        seg = _piece(P, size)
        if seg is not None:
            segs.append(seg)
            used.append(c)
            continue
        if not split:
            continue
        # a bent piece: two stalks that meet (a V whose apex is the centre) are one component;
        # split it by the ridge's direction into straight pieces
        if theta is None:
            theta = (0.5 * np.arctan2(2 * fxy, fxx - fyy)) % np.pi  # along the ridge (λ_max's eigenvector)
        b = np.floor(theta[P[:, 1].astype(int), P[:, 0].astype(int)] / (np.pi / PET_DIRS)).astype(int) % PET_DIRS
        got = False
        for k in range(PET_DIRS):
            sel = (b == k) | (b == (k + 1) % PET_DIRS)
            if np.count_nonzero(sel) < 0.04 * size:
                continue
            sub = np.zeros((stats[c, cv2.CC_STAT_HEIGHT], stats[c, cv2.CC_STAT_WIDTH]), np.uint8)
            sub[P[sel, 1].astype(int) - stats[c, cv2.CC_STAT_TOP], P[sel, 0].astype(int) - stats[c, cv2.CC_STAT_LEFT]] = 1
            m2, lab2, st2, _ = components(sub)
            for c2 in range(1, m2):
                if st2[c2, cv2.CC_STAT_AREA] < 0.04 * size:
                    continue
                y2, x2 = np.nonzero(lab2 == c2)
                seg = _piece(np.c_[x2 + stats[c, cv2.CC_STAT_LEFT], y2 + stats[c, cv2.CC_STAT_TOP]].astype(float), size)
                if seg is None or any(np.linalg.norm(seg[0] - s_[0]) < 2 and abs(float(seg[1] @ s_[1])) > 0.95 for s_ in segs):
                    continue  # (the same piece from the neighbouring direction band)
                segs.append(seg)
                got = True
        if got:
            used.append(c)
    if len(segs) < 2:
        return None
    X = meeting_point(segs, max(1.5, 0.04 * size), 0.35 * size)
    if X is None:
        return None
    if split:  # (the refined point's support may differ from the hypothesis's: it may even be empty)
        longest = max((s_[3] for s_ in supporting(segs, X, max(1.5, 0.04 * size), 0.35 * size)), default=0.0)
        if longest < PET_SPLIT_LEN * size:
            return None  # short ridge pieces only: a leaf's shading, its rim
    h, w_ = plant.shape
    if not (0 <= X[0] < w_ and 0 <= X[1] < h):
        return None
    # inside the plant's convex hull and on or next to the plant or its stalks (a clover's
    # centre may be bare; its petioles may be seen only as ridges)
    if not hull[int(X[1]), int(X[0])]:
        return None
    near = (pm > 0) | np.isin(lab, used)
    dt = cv2.distanceTransform((~near).astype(np.uint8), cv2.DIST_L2, 3)
    if dt[int(X[1]), int(X[0])] > 0.12 * size:
        return None
    return X


def meeting_point(segs: list, tol: float, reach: float, directed: bool = False) -> np.ndarray | None:
    """Where ≥ 2 straight pieces (centre point, unit direction d, half-length h, weight) point to:
    every crossing of two lines (≥ 20° apart) lying beyond an end of both pieces (between
    h − tol and h + reach from the piece's middle; with `directed`, beyond the end d points to)
    is a hypothesis, supported by the pieces whose line passes within `tol` of it the same way;
    the best-supported one, refined by weighted least squares over its support."""
    def beyond(along: float, h: float) -> bool:
        return h - tol <= (along if directed else abs(along)) <= h + reach

    def passes(along: float, h: float) -> bool:
        return _passes(along, h, tol, reach, directed)

    best, best_sup = None, 0.0
    for i in range(len(segs)):
        for j in range(i + 1, len(segs)):
            (ci, di, hi, _), (cj, dj, hj, _) = segs[i], segs[j]
            cross = di[0] * dj[1] - di[1] * dj[0]
            if abs(cross) < math.sin(math.radians(20)):
                continue
            # ci + a·di = cj + b·dj
            dc = cj - ci
            a = (dc[0] * dj[1] - dc[1] * dj[0]) / cross
            b = (dc[0] * di[1] - dc[1] * di[0]) / cross
            # (directed: one of them may run on past the meeting, a stalk merged with the next)
            if not (beyond(a, hi) and passes(b, hj) or passes(a, hi) and beyond(b, hj)):
                continue
            X = ci + a * di
            sup = sum(w for (_, _, _, w) in supporting(segs, X, tol, reach, directed))
            if sup > best_sup:
                best, best_sup = X, sup
    if best is None:
        return None
    # least-squares point of the supporting lines
    sup = supporting(segs, best, tol, reach, directed)
    if len(sup) < 2:
        return None
    A = np.zeros((2, 2))
    bb = np.zeros(2)
    for (c, d, h, w) in sup:
        Pm = np.eye(2) - np.outer(d, d)
        A += w * Pm
        bb += w * Pm @ c
    return np.linalg.solve(A + 1e-9 * np.eye(2), bb)


def supporting(segs: list, X: np.ndarray, tol: float, reach: float, directed: bool = False) -> list:
    """The pieces of `segs` (centre point, unit direction d, half-length h, weight) whose line passes
    within `tol` of X, with X beyond an end (between h − tol and h + reach from the middle; with
    `directed`, anywhere from the middle on to h + reach, the way d points): those `meeting_point` counts."""
    out = []
    for seg in segs:
        c, d, h, _ = seg
        v = X - c
        if abs(v[0] * d[1] - v[1] * d[0]) <= tol and _passes(float(v @ d), h, tol, reach, directed):
            out.append(seg)
    return out


def _passes(along: float, h: float, tol: float, reach: float, directed: bool) -> bool:
    """Whether a point `along` from a piece's middle lies where `meeting_point` looks (see `supporting`)."""
    if directed:  # anywhere from the piece's middle on
        return 0.0 <= along <= h + reach
    return h - tol <= abs(along) <= h + reach


HUB_MIN_ROUND = 0.022
HULL_TOL = 0.05  # × plant size: how far outside the broad parts' hull a stalk meeting may lie


def within_broad_hull(uv: np.ndarray, parts: tuple[float, np.ndarray]) -> bool:
    """Whether a centre estimate lies within (or HULL_TOL·size of) the convex hull of the plant's
    broad parts: leaves sit round their centre, so a meeting point of thin lines outside them is
    not where the stalks start (it is straw or a stone edge grouped with the plant)."""
    size, broad = parts
    ys, xs = np.nonzero(broad)
    if len(xs) < 3:
        return True
    hull = cv2.convexHull(np.c_[xs, ys].astype(np.float32))
    return cv2.pointPolygonTest(hull, (float(uv[0]), float(uv[1])), True) >= -HULL_TOL * size


def broad_parts(plant: np.ndarray) -> tuple[float, np.ndarray]:
    """(plant size in px, mask of its broad parts): the plant opened with a disc of HUB_OPEN·size,
    grown by one pixel; what is left of the plant are its thin parts (stalks, blades)."""
    ys, xs = np.nonzero(plant)
    size = math.hypot(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1)
    r = max(1, int(round(HUB_OPEN * size)))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    opened = cv2.morphologyEx(plant.astype(np.uint8), cv2.MORPH_OPEN, k)
    return size, cv2.dilate(opened, np.ones((3, 3), np.uint8)) > 0


def line_hub(plant: np.ndarray, parts: tuple[float, np.ndarray] | None = None) -> np.ndarray | None:
    """Where the plant's thin parts (petioles, stems, blades) converge, in mask pixels; or None.

    Thin parts = the mask minus its opening by a disc ~2.5 % of the plant size. Every thin pixel
    votes along its own direction (structure tensor of the thin mask); the hub is the vote peak.
    Needs enough thin pixels from at least three directions voting for the peak, and the hub
    must lie on or next to the plant and within LH_MAX_OFF × size of its centroid.
    """
    if int(plant.sum()) < 10:
        return None
    size, broad = parts if parts is not None else broad_parts(plant)
    pm = plant.astype(np.uint8)
    thin = pm & (~broad).astype(np.uint8)
    if int(thin.sum()) < HUB_MIN_LEN * size * 2:
        return None
    h, w = plant.shape
    f = cv2.GaussianBlur(thin.astype(np.float32), (0, 0), 1.0)
    gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)
    jxx = cv2.GaussianBlur(gx * gx, (0, 0), 1.5)
    jyy = cv2.GaussianBlur(gy * gy, (0, 0), 1.5)
    jxy = cv2.GaussianBlur(gx * gy, (0, 0), 1.5)
    tr = jxx + jyy + 1e-9
    coh = np.sqrt((jxx - jyy) ** 2 + 4 * jxy**2) / tr
    ys, xs = np.nonzero(thin & (coh > 0.6))
    if len(xs) < HUB_MIN_LEN * size:
        return None
    phi = 0.5 * np.arctan2(2 * jxy[ys, xs], jxx[ys, xs] - jyy[ys, xs]) + np.pi / 2
    dx, dy = np.cos(phi), np.sin(phi)
    L = int(0.7 * size)
    t = np.arange(-L, L + 1, dtype=np.float32)
    px = np.rint(xs[:, None] + dx[:, None] * t[None, :]).astype(np.int64)
    py = np.rint(ys[:, None] + dy[:, None] * t[None, :]).astype(np.int64)
    ok = (px >= 0) & (px < w) & (py >= 0) & (py < h)
    acc = np.bincount((py * w + px)[ok], minlength=h * w).reshape(h, w).astype(np.float32)
    acc = cv2.GaussianBlur(acc, (0, 0), max(1.0, 0.015 * size))
    iy, ix = np.unravel_index(int(np.argmax(acc)), acc.shape)
    # support: thin pixels whose line passes near the peak, from ≥ 3 directions
    ddx, ddy = ix - xs, iy - ys
    perp = np.abs(ddx * dy - ddy * dx)
    near = perp < max(1.5, 0.03 * size)
    if near.sum() < HUB_MIN_LEN * size:
        return None
    ang = np.arctan2(ddy[near], ddx[near])
    far = np.hypot(ddx[near], ddy[near]) > 0.05 * size
    hist = np.histogram(ang[far], bins=8, range=(-np.pi, np.pi))[0]
    if np.count_nonzero(hist >= 0.05 * near.sum()) < 3:
        return None
    dt = cv2.distanceTransform((1 - pm).astype(np.uint8), cv2.DIST_L2, 3)
    if dt[iy, ix] > 0.05 * size:
        return None
    pys, pxs = np.nonzero(plant)
    if math.hypot(pxs.mean() - ix, pys.mean() - iy) > LH_MAX_OFF * size:
        return None
    # sub-pixel: centroid of the peak
    y0, y1, x0, x1 = max(iy - 2, 0), min(iy + 3, h), max(ix - 2, 0), min(ix + 3, w)
    win = acc[y0:y1, x0:x1]
    gy_, gx_ = np.mgrid[y0:y1, x0:x1]
    wgt = np.clip(win - 0.7 * acc[iy, ix], 0, None)
    return np.array([(wgt * gx_).sum() / wgt.sum(), (wgt * gy_).sum() / wgt.sum()])


def component_median(plant: np.ndarray) -> np.ndarray | None:
    """Geometric median of the centroids of a plant's separate parts, each counted once, or None.

    For plants whose leaves hang on stems too thin to see (clover trefoils on petioles), the
    centre lies in the empty space the parts are arranged around, not on any part. Needs ≥ 3
    parts, none holding more than half of the plant's area.
    """
    n, lab, stats, cents = components(plant)
    if n < 4:
        return None
    area = stats[1:, cv2.CC_STAT_AREA].astype(float)
    keep = area >= 0.04 * area.sum()
    if keep.sum() < 3 or area.max() > 0.5 * area.sum():
        return None
    return geometric_median(cents[1:][keep], iters=30)


def pair_gap(plant: np.ndarray) -> np.ndarray | None:
    """Middle of the gap between a plant's two parts, or None.

    Two leaves whose stem does not show (cotyledons on a thin hypocotyl, two leaves of a
    seedling) meet where they are closest; the median of the pixels lands in the bigger one.
    Needs two parts holding ≥ PAIR_MIN_SHARE of the plant each and ≥ 0.9 of it together.
    """
    n, lab, stats, _ = components(plant)
    if n < 3:
        return None
    area = stats[1:, cv2.CC_STAT_AREA].astype(float)
    order = np.argsort(area)[::-1]
    a, b = order[0] + 1, order[1] + 1
    if area[order[1]] < PAIR_MIN_SHARE * area.sum() or area[order[0]] + area[order[1]] < 0.9 * area.sum():
        return None
    pts, axes = [], []
    for k in (a, b):
        cs, _ = cv2.findContours((lab == k).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        c = max(cs, key=cv2.contourArea)
        if cv2.contourArea(c) < PAIR_SOLIDITY * cv2.contourArea(cv2.convexHull(c)):
            return None  # lobed (a trefoil, a rosette's half): not a simple leaf
        yy, xx = np.nonzero(lab == k)
        P = np.c_[xx, yy].astype(float)
        ev, evec = np.linalg.eigh(np.cov(P.T) + 0.25 * np.eye(2))
        axes.append((P.mean(0), evec[:, 1], math.sqrt(ev[1] / ev[0])))
        pts.append(c.reshape(-1, 2).astype(float))
    d = np.linalg.norm(pts[0][:, None, :] - pts[1][None, :, :], axis=2)
    i, j = np.unravel_index(int(np.argmin(d)), d.shape)
    gap = 0.5 * (pts[0][i] + pts[1][j])
    for (c0, ax, el) in axes:
        # each leaf elongated and pointing at the gap (its base), not lying beside it
        v = gap - c0
        if el < PAIR_ELONG or abs(float(v @ ax)) < PAIR_AIM * float(np.linalg.norm(v)):
            return None
    return gap


PAIR_MIN_SHARE = 0.15  # (session 16: without the shape guards 23 bench clovers and rosettes went 5–30 mm worse;
# with them bench seeds 0–3 moved one seedling 0.9 → 0.4 mm, photo-like and other-renderer medians 0.001–0.004 S better)
PAIR_SOLIDITY = 0.9  # area / convex hull area of each part
PAIR_ELONG = 1.3  # each part's √(λ1/λ2)
PAIR_AIM = 0.7  # cos of the angle between a part's long axis and the way to the gap
HUB_OPEN = 0.025
HUB_MIN_LEN = 0.1
LH_MAX_OFF = 0.225  # × size: farthest a `line_hub` peak may lie from the plant mask's centroid. Its answers
# on 5 benches (bench seeds 0–7 with ROI; other renderer, photo-like and field-photo without): right ones
# ≤ 0.21 off, wrong ones ≥ 0.24 (peaks where thin parts near the rim cross: a blade's tip, a side branch,
# a leaf's stalk). Session 22: bench 40.4 → 16.8, 46.2 → 4.9, 28.9 → 0.9 mm; other renderer 0.56 → 0.01,
# 0.45 → 0.31, 0.31 → 0.13 S; photo-like 0.45 → 0.13, 0.19 → 0.05 S; field-photo chickweeds 0.44 → 0.09,
# 0.39 → 0.02 S, a plantain 0.35 → 0.06 S; no answer worse


def geometric_median(P: np.ndarray, iters: int = 50) -> np.ndarray:
    """Point minimising Σ‖p − x‖ over the rows of P (Weiszfeld)."""
    x = P.mean(axis=0)
    for _ in range(iters):
        d = np.maximum(np.linalg.norm(P - x, axis=1), 1e-6)
        x_new = (P / d[:, None]).sum(0) / (1 / d).sum()
        if np.linalg.norm(x_new - x) < 1e-3:
            return x_new
        x = x_new
    return x
