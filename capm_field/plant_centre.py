"""Stage 2 of the weed-centre detector: where a plant's leaves emerge, from its mask.

Every estimator works on one plant's mask (bool, ~PLANT_PX across, see `capm_field.centre_cascade`)
and, where it needs colour, the vegetation index on the same grid; coordinates are (x, y) grid
pixels. They assume nothing about the camera. `capm_field.centre_cascade.centre_fullres` chooses,
the first that answers:
  - thin blades leaning one way (a grass fan): `fan_apex`, where the blade axes converge;
  - plants with rounded parts (clover, seedlings, broad rosettes): `petiole_centre` (straight
    stalks crossing), `line_hub` (thin parts converging), each only inside the broad parts'
    hull (`within_broad_hull`);
  - leaf axes converging at ≥ 2 points (`vote_peaks`): first stalks the index misses but
    the grey image shows, `capm_field.stalks` (where they meet); then
  - compound leaves whose stalks do not show (clover trefoils): `capm_field.compound_leaf`,
    where rays back from the three-lobed hubs agree; then, for rounded parts,
    `component_median` (separate parts round an empty middle, same hull rule);
  - leaf axes converging at several separate points (`vote_peaks` of `axis_votes`): where the
    leaves' axes traced back from their tips meet (`capm_field.leaf_axes`, rosettes), else the
    `geometric_median` of the plant;
  - otherwise the `tree_median`: Σ geodesic distance to the leaf tips minus leaf-axis votes.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from .components import components
from .order_stats import percentile

GAP_COST = 4.0  # geodesic cost per pixel outside the vegetation mask (bridges lost petioles)
BAND = 0.04  # gaps up to ~2·BAND·size wide may be crossed
HULL_BAND = True  # the band is cut to the plant's convex hull (tree median only): shortest paths between the
# plant's pixels seldom detour outside it at GAP_COST, and its centre is not there. Session 29: graph nodes 3 847 →
# 2 991 on average over bench seed 0's 300 frames (fan_apex's graphs, which keep the band, included); bench seeds 0–7
# 3 answers better, 2 worse by > 2 mm (grass, rosettes; wrong 42 → 42), field-photo tree-median answers 4 better
# (seedlings, a thistle), none worse; per frame −0.27 ms median, −0.42 ms mean (paired, 300 cached bench frames)
FILL_HOLES = True  # soil enclosed by the plant costs as much as the plant (`crossing_cost`). Session 23:
# field-photo bench seed 0 p90 0.278 → 0.272 S (a plantain with a bare middle 0.28 → 0.11 S), photo-like
# seed 4 p90 0.354 → 0.287 S; bench seeds 0–7: 2 answers moved (2.7 → 1.9, 0.4 → 3.7 mm)
BRIDGE_ALL = True  # parts further apart than the band are joined across the plant's hull (tree median only).
# Session 23: field-photo seed 0 p90 0.272 → 0.235 S (purslane: leaf clusters on red stalks); bench seeds 0–7:
# 25 answers moved, 14 better (20.7 → 7.6, 6.5 → 1.8 mm), 11 worse (15.8 → 24.9, 3.3 → 6.9 mm), wrong unchanged




PET_MINLEN = 0.07  # of the plant size
PET_K = 1.0  # ridge threshold, × the 99th percentile of the ridge response on the soil
PET_RIM = 2.0  # px: a piece whose median distance from the broad parts is this or less runs along a leaf's rim
PET_LEAF_GAP = 0.10  # of the plant size: farthest a stalk piece may stay from every broad part


def petiole_centre(plant: np.ndarray, vi: np.ndarray, soil: float, thr: float, parts: tuple[float, np.ndarray] | None = None) -> np.ndarray | None:
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
        m = P.mean(0)
        ev, evec = np.linalg.eigh(np.cov((P - m).T) + 1e-9 * np.eye(2))
        d = evec[:, 1]
        t = (P - m) @ d
        L = float(t.max() - t.min()) + 1
        wdt = math.sqrt(12 * max(ev[0], 0)) + 0.5
        if L < PET_MINLEN * size or L < 3 * wdt:
            continue
        segs.append((m + d * (t.max() + t.min()) / 2, d, L / 2, L))
        used.append(c)
    if len(segs) < 2:
        return None
    X = meeting_point(segs, max(1.5, 0.04 * size), 0.35 * size)
    if X is None:
        return None
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
    A = np.zeros((2, 2))
    bb = np.zeros(2)
    sup = supporting(segs, best, tol, reach, directed)
    for (c, d, h, w) in sup:
        Pm = np.eye(2) - np.outer(d, d)
        A += w * Pm
        bb += w * Pm @ c
    if len(sup) < 2:
        return None
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


SCATTER_PEAKS = 4  # vote peaks (≥ 0.7 of the highest, 0.12·size apart) that mark a plant without one apex
# measured on the bench (seed 0, tree-median cases): clover ≥ 2 always, mostly ≥ 3; rosettes 1 in
# 46 of 64; geometric median at ≥ 4 peaks: wrong 22 → 8, p90 29.7 → 19.7 mm, median 5.7 → 5.2 mm


def vote_peaks(votes: np.ndarray, size: float) -> int:
    """Number of separate strong peaks of a leaf-axis vote map (see `axis_votes`)."""
    r = max(2, int(0.12 * size))
    mx = cv2.dilate(votes, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    return int(np.count_nonzero((votes >= mx) & (votes >= 0.7)))


def crossing_cost(plant: np.ndarray, size: float, bridge: bool = True) -> np.ndarray:
    """Geodesic cost per pixel for paths through a plant: 1 on the mask and in the soil it
    encloses (a rosette's middle often shows soil or pale stalks between the leaf bases: paths
    round such a hole pulled the median onto a leaf), GAP_COST in a band BAND × size round it
    (gaps across lost petioles), ∞ beyond. When the band leaves the plant in several pieces
    (leaf clusters on stalks the index misses), the band takes in the plant's convex hull, so
    that every tip is reachable from every part (else a median sees only one piece); not with
    `bridge` False (`fan_apex`, whose straightness test measures the paths along the blades).
    With `bridge`, the band outside the convex hull is dropped (HULL_BAND)."""
    m8 = plant.astype(np.uint8)
    band = cv2.dilate(m8, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)), iterations=max(1, int(BAND * size)))
    if bridge and (BRIDGE_ALL or HULL_BAND):
        ys, xs = np.nonzero(plant)
        hull = np.zeros_like(m8)
        cv2.fillConvexPoly(hull, cv2.convexHull(np.c_[xs, ys].astype(np.int32)), 1)
        if BRIDGE_ALL and cv2.connectedComponents(band, connectivity=8)[0] > 2:
            band |= hull
        if HULL_BAND:
            band &= hull
    on = plant.copy()
    if FILL_HOLES:
        n, lab = cv2.connectedComponents(1 - m8, connectivity=4)
        if n > 2:  # soil pieces not reaching the window's border
            edge = np.unique(np.r_[lab[0], lab[-1], lab[:, 0], lab[:, -1]])
            on |= ~plant & ~np.isin(lab, edge)
    return np.where(on, 1.0, np.where(band > 0, GAP_COST, np.inf))


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


def tree_median(plant: np.ndarray, vi: np.ndarray | None = None, out: dict | None = None,
                votes: np.ndarray | None = None) -> tuple[np.ndarray | None, int, float]:
    """Point minimising Σ geodesic distance to the leaf tips of a plant mask, in mask pixels.

    With the vegetation index `vi`, the cost is combined with leaf-axis convergence votes
    (`axis_votes`), which find the apex of fan-shaped plants (grass) where tips alone cannot;
    they count in proportion to the plant's thinness and to how much they pile up (VOTE_CONC).
    With a single tip the centre is the stem between it and the plant's far end (see below).
    Returns ((x, y), number of tips, sharpness 0..1 of the minimum).
    """
    h, w = plant.shape
    area = int(plant.sum())
    if area < 3:
        return None, 0, 0.0
    ys, xs = np.nonzero(plant)
    size = math.hypot(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1)
    # nodes: the plant plus a band around it that gaps may be crossed through, at a cost
    G, node = _grid_graph(crossing_cost(plant, size))
    # provisional centre: deepest point of the mask (overlapping leaves are thickest at the centre)
    dt = cv2.distanceTransform(plant.astype(np.uint8), cv2.DIST_L2, 5)
    c0 = np.unravel_index(int(np.argmax(dt)), dt.shape)
    tips: np.ndarray = np.zeros(0, int)
    centre_node = node[c0]
    prev: set = set()
    rows: dict[int, np.ndarray] = {}  # geodesic distances from each tip: the second pass finds mostly the same tips
    for _ in range(TM_ITER):
        g0 = dijkstra(G, directed=True, indices=[centre_node])[0]
        tips = _tips(g0, node, plant, size)
        if len(tips) == 0 or set(tips.tolist()) == prev:
            break  # same tips from the new centre: F, and so the minimum, would not change
        prev = set(tips.tolist())
        new = [t for t in tips.tolist() if t not in rows]
        if new:  # each source's row is computed on its own: the same as in a call with all tips
            rows.update(zip(new, dijkstra(G, directed=True, indices=new, limit=np.inf)))
        F = _tip_cost(np.array([rows[t] for t in tips.tolist()]), tips, size)
        centre_node = int(np.argmin(F))
    if len(tips) == 0:
        yx = np.array(c0, float)
        return np.array([yx[1], yx[0]]), 0, 0.0
    inv = np.argwhere(node >= 0) if len(tips) == 1 or out is not None else None  # node index → (y, x)
    if len(tips) == 1:
        # one tip (two opposite leaves or cotyledons, seen from inside one of them): Σ distance
        # to it is least at the tip itself. The plant's far end from it is the other tip; the
        # centre is the narrowest point (the stem between the two leaves) of the middle 70 % of
        # the geodesic path between them
        t0 = int(tips[0])
        on_plant = node[plant]
        d0 = rows[t0][on_plant]
        far = int(on_plant[np.argmax(np.where(np.isfinite(d0), d0, -1.0))])
        if far not in rows:
            rows[far] = dijkstra(G, directed=True, indices=[far], limit=np.inf)[0]
        tips = np.array([t0, far])
        D0, D1 = rows[t0], rows[far]
        L = float(D0[far])
        width = dt[inv[:, 0], inv[:, 1]]
        path = (D0 + D1 <= L + 1.5) & (D0 >= 0.15 * L) & (D0 <= 0.85 * L)
        if np.isfinite(L) and L > 0 and path.any():
            F = np.full(D0.shape, np.inf)  # on the path only (elsewhere D0 − D1 may be ∞ − ∞)
            F[path] = L + width[path] + 0.01 * np.abs(D0[path] - D1[path])
        else:
            F = _tip_cost(np.array([D0, D1]))
    if out is not None:
        out["tips"] = inv[tips][:, ::-1].astype(float)
    flat = np.full(h * w, np.inf)
    valid = node.ravel() >= 0
    flat[valid] = F[node.ravel()[valid]]
    Fm = flat.reshape(h, w)
    if vi is not None and VOTE_WEIGHT > 0:
        A = votes if votes is not None else axis_votes(vi, plant, size)
        fmin = float(np.min(Fm))
        # trust the votes in proportion to how elongated the parts are: thin blades and narrow
        # leaves point at the centre, round leaflets and cotyledons do not
        thin = float(dt[plant].mean()) / size
        wv = VOTE_WEIGHT * float(np.clip((THIN_ROUND - thin) / (THIN_ROUND - THIN_BLADE), 0.0, 1.0))
        if VOTE_CONC is not None and wv > 0:
            # and in proportion to how much they pile up at one point: the veins and lobes of
            # broad leaves vote all over the plant, and the map's maximum is then anywhere
            iy, ix = np.unravel_index(int(np.argmax(A)), A.shape)
            r = 0.08 * size
            y0, y1, x0, x1 = max(int(iy - r), 0), int(iy + r) + 1, max(int(ix - r), 0), int(ix + r) + 1
            gy, gx = np.mgrid[y0:min(y1, h), x0:min(x1, w)]
            near = float(A[y0:y1, x0:x1][(gx - ix) ** 2 + (gy - iy) ** 2 <= r * r].sum())
            conc = near / max(float(A.sum()), 1e-9)
            wv *= float(np.clip((conc - VOTE_CONC[0]) / (VOTE_CONC[1] - VOTE_CONC[0]), 0.0, 1.0))
        Fm = (Fm - fmin) / (fmin + 1e-9) - wv * A
    iy, ix = np.unravel_index(int(np.argmin(Fm)), Fm.shape)
    # sub-pixel: weighted mean of the near-minimum region
    fmin = Fm[iy, ix]
    tol = 0.02 * fmin + 1e-6
    y0_, y1_ = max(iy - 3, 0), min(iy + 4, h)
    x0_, x1_ = max(ix - 3, 0), min(ix + 4, w)
    win = Fm[y0_:y1_, x0_:x1_]
    wgt = np.clip(1 - (win - fmin) / tol, 0, None)
    wgt[~np.isfinite(wgt)] = 0
    gy, gx = np.mgrid[y0_:y1_, x0_:x1_]
    cx, cy = float((wgt * gx).sum() / wgt.sum()), float((wgt * gy).sum() / wgt.sum())
    # sharpness: how much F rises 10 % of the plant size away from the minimum
    ring = (np.hypot(gx - ix, gy - iy) >= 2)
    rise = float(np.nanmin(np.where(ring & np.isfinite(win), win, np.nan))) - fmin if ring.any() else 0.0
    sharp = float(np.clip(rise / (0.02 * fmin + 1e-6), 0, 1)) if np.isfinite(rise) else 0.0
    return np.array([cx, cy]), len(tips), sharp


def _tip_cost(D: np.ndarray, tips: np.ndarray | None = None, size: float = 0.0) -> np.ndarray:
    """Tree-median cost per node from the geodesic distances D (tips × nodes): Σ over the tips
    plus a tenth of the farthest (a tie-break towards the middle); ∞ where a tip is unreachable.

    With the tips' node indices `tips` (≥ 3) and the plant's size, each tip counts in inverse
    proportion to how many tips lie within ~TIP_SPREAD × size of it along the plant: a bunch of
    leaves at the end of one stem (purslane, chickweed, a seedling's true leaves) counts about
    as one tip, and does not pull the median off the crown towards itself."""
    if TIP_SPREAD > 0 and tips is not None and len(tips) > 2 and size > 0:
        near = np.exp(-(D[:, tips] / (TIP_SPREAD * size)) ** 2)  # (∞ between unconnected tips: 0)
        wt = 1.0 / near.sum(axis=1)
        F = (wt * (len(tips) / wt.sum())) @ D + 0.1 * D.max(axis=0)
    else:
        F = D.sum(axis=0) + 0.1 * D.max(axis=0)
    F[~np.isfinite(F)] = np.inf
    return F


VOTE_WEIGHT = 2.0
VOTE_CONC = (0.06, 0.08)  # share of the votes within 0.08 × size of their peak: no weight at the first, full
# from the second (None: always full). Votes that meet measured 0.08–0.12 (rosettes, grass fans), the veins
# and trefoils of clovers and broad leaves 0.05–0.08. Session 23: bench seeds 0–7 wrong 44 → 42, p90 lower
# on seeds 1, 3, 4, 7 (31.0 → 4.3, 65.9 → 27.1, 24.3 → 5.9 mm; seedlings ≤ 5 mm worse); photo-like seeds
# 3–6 within 0.1 S +1 or +2 answers each (one more wrong on seed 6); field-photo seed 0 with a ROI p90
# 0.223 → 0.204 S, seed 1 0.229 → 0.240 S; other renderer slightly worse (medians +0.001–0.005 S, seed 1
# p90 0.154 → 0.178 S). (0.05, 0.07) moved only 3 bench answers
AXIS_K, AXIS_MAX = 1.0, 0.05  # tree-median vote scale = AXIS_K × mean half-width (≤ AXIS_MAX), × size
TIP_SPREAD = 0.5  # × plant size: ρ of the tree-median tips' weight kernel exp(−(d/ρ)²) over their geodesic
# distances d (tips that near share one weight; 0: every tip counts 1). Field-photo seeds 0–5 + shadow set, the
# 767 tree-median answers: > 0.2 S off 82 → 62 (purslane 16 → 8, chickweed 14 → 9, plantain 9 → 6), 62 better
# and 29 worse by > 0.02 S; bench seeds 0–7: wrong 42 → 42, 43 answers better and 25 worse by > 2 mm (seedlings
# 12–31 → 0.5–6 mm; a grass 4.3 → 30.9 mm), p90 lower on 6 of 8 seeds (seed 6 16.31 → 15.89 mm); drawn hollow
# rosettes (tests) 10 → 9 of 12 within 0.06 × size. 0.2 gained less (82 → 74), 0.35 as much on the photos
# (82 → 64) but 44 wrong on the bench. More weight on the farthest tip instead (2 × max: a minimax centre)
# gained as much on the photos but made 32 bench rosettes worse (their uneven leaves). Applied only where the
# leaf-axis votes get no weight (which spares the grass above), the photos' gain fell to 82 → 70
TM_ITER = 2  # tips from the provisional centre, then again from the first estimate
THIN_BLADE, THIN_ROUND = 0.02, 0.06  # mean half-width / plant size


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
    t = np.arange(-L, L + 1, dtype=np.float32)
    # nearest pixel along each line in float32/int32 (half the time of float64 rint); the
    # offset keeps the values positive so the cast rounds like floor(x + ½)
    off = np.float32(L + 1.5)
    px = _line_pixels(xs, dx, t, off, L + 1, np.int32)
    idx = _line_pixels(ys, dy, t, off, L + 1, np.int64)  # py, then the flat index (int64: no copy in bincount)
    # points off the grid go to one extra bin (dropped), not through boolean selections of both
    # arrays: every other bin sums the same weights in the same order
    off_grid = (px.view(np.uint32) >= w) | (idx.view(np.uint64) >= h)  # negative → huge unsigned
    idx *= w
    idx += px
    np.putmask(idx, off_grid, h * w)
    ww = np.repeat(wgt[ys, xs].astype(np.float64), len(t))  # each line's weight on its points
    acc = np.bincount(idx.ravel(), weights=ww, minlength=h * w + 1)[:h * w].reshape(h, w).astype(np.float32)
    acc = cv2.GaussianBlur(acc, (0, 0), max(1.0, 0.02 * size))
    return acc / (acc.max() + 1e-9)


def _line_pixels(c: np.ndarray, d: np.ndarray, t: np.ndarray, off: np.float32, shift: int,
                 dtype: type[np.signedinteger]) -> np.ndarray:
    """(n, len(t)) integers (c + d·t + off) truncated, − shift, for each start c (n,) and direction
    d (n,) float32 (float32 arithmetic); in place in one buffer (fresh large temporaries cost
    page faults on the VM)."""
    p = np.multiply(d[:, None], t[None, :])
    p += c.astype(np.float32)[:, None]
    p += off
    q = p.astype(dtype)
    q -= shift
    return q


FAN_GAP = 3.6  # rad: the far tips, seen from the apex, leave an empty sector at least this wide
FAN_STRAIGHT = 1.15  # Σ geodesic / Σ straight-line distance from the apex to the far tips
FAN_MIN_TIPS = 2
FAN_MAX_PEAKS = 2  # more `vote_peaks`: leaves converge at several points (clover trefoil hubs) ...
FAN_CLEAR_GAP = 3.6  # ... unless the plant, seen from the apex, spans ≤ 2π − this (≈ 154°) ...
FAN_DENSE_PEAKS = 4  # ... and with this many peaks or more, ≤ 2π − FAN_DENSE_GAP (≈ 74°)
FAN_DENSE_GAP = 5.0
# measured: on clover the fan test passes at a peak on the rim of the plant (≥ 4 peaks); dense
# grass fans reach 3–5 peaks along their blades. Until session 21 one gap (4.4, ≈ 108°) for > 2
# peaks; bench seeds 0–7 then: 2 clovers of 4 and 6 peaks passed, spanning 85–95° (51.5, 42.5 mm off
# → 0.7, 13.0 mm with FAN_DENSE_GAP), while 3-peak grass fans failed (44.4 → 4.5, 21.2 → 2.7,
# 10.4 → 7.9 mm with 3.6; a 3-peak seedling 0.3 → 21.7 mm). Lost: a 5-peak bench grass spanning 95°
# (4.5 → 19.3 mm); a drawn dense fan of 4 peaks spans 55° (tests). Of the 231 fan answers of seeds
# 0–7 (200 on grass), 9 had ≥ 3 peaks.


def _longest_empty_sector(angles: np.ndarray, bins: int = 72) -> float:
    """Widest empty sector (rad) among directions `angles`, on a `bins`-bin circle."""
    occ = np.zeros(bins, bool)
    occ[((angles + np.pi) / (2 * np.pi) * bins).astype(int) % bins] = True
    if occ.all():
        return 0.0
    occ = np.roll(occ, -int(np.argmax(occ)))  # start on an occupied bin: no run wraps round
    edges = np.flatnonzero(np.diff(np.r_[occ, True].astype(np.int8)))  # run starts and ends
    runs = edges[1::2] - edges[0::2]
    return float(runs.max() if len(runs) else 0) * 2 * np.pi / bins


def fan_apex(plant: np.ndarray, votes: np.ndarray, size: float, n_peaks: int) -> np.ndarray | None:
    """Apex of a fan-shaped plant (a grass tuft leaning one way), or None if it is not one.

    The blades of a fan run straight from their common base to tips that all lie on one side,
    so the tree median (Σ distance to the tips) slides along the blades towards the tips, and
    so does any middle of the mask; the blade axes still converge at the base, the peak of
    `axis_votes`. Accepted only when, seen from that peak, the far tips leave an empty sector
    ≥ FAN_GAP, the plant's paths to them are straight (a peak on the end of one long blade
    reaches the other tips round a bend), and the votes have ≤ FAN_MAX_PEAKS peaks
    (`n_peaks`, from `vote_peaks`) or the whole plant lies in a sector the narrower the more
    peaks there are (leaves converging at several points: trefoil hubs, rosette leaves).
    """
    near = cv2.dilate(plant.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    B = np.where(near, votes, 0)
    iy, ix = np.unravel_index(int(np.argmax(B)), B.shape)
    if B[iy, ix] <= 0:
        return None
    y0, y1 = max(iy - 2, 0), min(iy + 3, B.shape[0])
    x0, x1 = max(ix - 2, 0), min(ix + 3, B.shape[1])
    wg = np.clip(B[y0:y1, x0:x1] - 0.8 * B[iy, ix], 0, None)
    gy, gx = np.mgrid[y0:y1, x0:x1]
    p = np.array([(wg * gx).sum() / wg.sum(), (wg * gy).sum() / wg.sum()])
    # cheap test first: the plant itself, seen from the peak, must leave an empty sector
    py, px = np.nonzero(plant)
    dx, dy = px - p[0], py - p[1]
    sel = dx * dx + dy * dy > (0.15 * size) ** 2
    if np.count_nonzero(sel) < 3:
        return None
    pix_gap = _longest_empty_sector(np.arctan2(dy[sel], dx[sel]))
    if pix_gap < 0.8 * FAN_GAP or (n_peaks > FAN_MAX_PEAKS and pix_gap < FAN_CLEAR_GAP) or (n_peaks >= FAN_DENSE_PEAKS and pix_gap < FAN_DENSE_GAP):
        return None
    G, node = _grid_graph(crossing_cost(plant, size, bridge=False))
    # paths start from the plant pixel nearest the peak (the apex may lie just off the mask,
    # and a start in the gap band would count its crossing cost on every path)
    k = int(np.argmin(dx * dx + dy * dy))
    src = np.array([px[k], py[k]], float)
    g0 = dijkstra(G, directed=True, indices=[node[py[k], px[k]]])[0]
    tips = _tips(g0, node, plant, size)
    if len(tips) == 0:
        return None
    d = np.argwhere(node >= 0)[tips][:, ::-1] - src
    r = np.hypot(d[:, 0], d[:, 1])
    far = r > 0.15 * size
    if far.sum() < FAN_MIN_TIPS:
        return None
    ang = np.sort(np.arctan2(d[far, 1], d[far, 0]))
    gap = float(np.max(np.diff(np.r_[ang, ang[0] + 2 * np.pi])))
    straight = float(g0[tips[far]].sum() / r[far].sum())
    if gap < FAN_GAP or not straight <= FAN_STRAIGHT:
        return None
    return p


def _tips(g0: np.ndarray, node: np.ndarray, plant: np.ndarray, size: float) -> np.ndarray:
    """Leaf tips: local maxima of geodesic distance from the centre, one per 0.15·size window."""
    h, w = plant.shape
    valid = node >= 0
    gm = np.zeros((h, w), np.float32)
    gm[valid] = g0[node[valid]]
    gm[~np.isfinite(gm)] = 0
    gm[~plant] = 0
    r = max(2, int(0.08 * size))
    mx = cv2.dilate(gm, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    peak = (gm >= mx) & (gm > 0.2 * gm.max()) & plant
    ys, xs = np.nonzero(peak)
    if len(xs) == 0:
        return np.zeros(0, int)
    order = np.argsort(-gm[ys, xs])
    chosen: list[tuple[int, int]] = []
    for i in order:
        if all((xs[i] - x) ** 2 + (ys[i] - y) ** 2 > (1.5 * r) ** 2 for y, x in chosen):
            chosen.append((ys[i], xs[i]))
        if len(chosen) >= 14:
            break
    return np.array([node[y, x] for y, x in chosen], int)


def _grid_graph(cost: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """8-connected grid graph over finite-cost pixels, both directions of every edge (for
    `dijkstra(..., directed=True)`); edge weight = length × mean cost."""
    h, w = cost.shape
    ok = np.isfinite(cost)
    node = -np.ones((h, w), np.int64)
    node[ok] = np.arange(int(ok.sum()))
    I, J, Wt = [], [], []
    for dy, dx, L in ((0, 1, 1.0), (1, 0, 1.0), (1, 1, math.sqrt(2)), (1, -1, math.sqrt(2))):
        xs0, xs1 = max(0, -dx), w - max(0, dx)
        a = node[0 : h - dy, xs0:xs1]
        b = node[dy:h, xs0 + dx : xs1 + dx]
        wgt = L * 0.5 * (cost[0 : h - dy, xs0:xs1] + cost[dy:h, xs0 + dx : xs1 + dx])
        sel = (a >= 0) & (b >= 0)
        I.append(a[sel])
        J.append(b[sel])
        Wt.append(wgt[sel])
    n = int(ok.sum())
    # both directions stored: Dijkstra then runs as directed (the same distances; undirected,
    # scipy builds the transpose on every call: ~0.1 ms a call, ~8 calls a tree median)
    I, J, Wt = np.concatenate(I), np.concatenate(J), np.concatenate(Wt)
    G = sp.csr_matrix((np.r_[Wt, Wt], (np.r_[I, J], np.r_[J, I])), shape=(n, n))
    return G, node
