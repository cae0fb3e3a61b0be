"""Where a plant's visible stalks meet: the centre of a plant whose leaves sit at the ends of
long, thin stalks that the vegetation index does not segment (olive, reddish or pale petioles
of clover and its kin, on any soil).

Stage-2 estimator of the weed-centre detector (see `capm_field.plant_centre` for the others).
It works on the grey image, not on colour: a stalk is a straight line darker or lighter than
the soil on both sides. Line strength is measured per pixel (Hessian across the line, minus
what a step edge explains), and its direction tensor is averaged over a stalk-length
neighbourhood (`capm_field.line_strength`): along a straight stalk the directions agree, in the
soil's texture they do not. Straight pieces that leave a leaf and point away from it are stalks, and the plant's
centre is where ≥ 2 of them point to (`plant_centre.meeting_point`); a lone stalk between two
leaf clusters gives its end on the side of the rest of the plant (`_bridge_end`). Measured with
`bench/perception_failures.py` on bench seeds 0–3. Coordinates are (x, y) pixels of the grid the caller passes.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from .components import components
from .line_strength import N_DIRS, line_strength
from .order_stats import percentile
from .plant_centre import HUB_OPEN, HULL_TOL, meeting_point, supporting

SEG_LEN = 0.12  # × plant size: the neighbourhood (3 σ) over which line directions must agree
PX_K = 0.15  # a stalk pixel: its own line strength ≥ this × the 99th percentile on the soil ...
LINE_K = 1.0  # ... and its neighbourhood's agreeing strength ≥ this × that percentile
CLUSTER = 0.05  # × the plant's area: smallest leaf cluster (≥ 2 needed)
MIN_LEN = 0.12  # × size: shortest stalk piece
ATTACH = 0.10  # × size: farthest a stalk's far end may be from a leaf (a stalk carries a leaf)
AWAY = 0.08  # × size (+ 2 px): how far from every leaf a stalk piece must get somewhere along it
REACH = 0.25  # × size: how far beyond a piece's free end the centre may lie (hidden stalk start)
TOL = 0.04  # × size (≥ 1.5 px): how close a supporting piece's line must pass the centre
MAX_BARE = 0.5  # × size: farthest the centre may be from the plant
MARGIN = 0.5  # × the plant window: how far round it the caller looks for stalks and the centre
TAIL_K = 3.0  # `_soil_ref`: the soil's 99th percentile of agreeing strength at most this × its 90th. Session 61,
# bench seeds 0–11: 5 answers moved, 3 clovers better (24.0 → 0.8, 14.2 → 2.3, 12.1 → 5.9 mm), none worse; at 2.0,
# 11 moved, 4 better, 3 worse (a grass 4.0 → 25.5 mm). Held out (field photos seeds 0–1, other renderer seeds
# 0–1, photo-like seed 3): the same but the other renderer's clovers with a ROI, median 0.033 → 0.024 S
TAIL_FLOOR = 10.0  # ... and at least 1/this × its 99th
MAX_PX = 100  # longest side of the plant window on the stalk grid (the image is shrunk beyond)


def _soil_ref(strength: np.ndarray) -> float:
    """The soil's reference agreeing line strength: its 99th percentile, at most TAIL_K × its 90th
    (TAIL_K 0: uncapped). A few straight straws or stone edges in the soil round the plant, or the
    middle of the plant's own long stalks (as far from the leaves as that soil), are the soil's
    strongest 1 % on their own and would lift the reference to their strength, over the fainter
    stalks sought; the soil's texture alone has a 99th percentile ~1.7–4.9× its 90th (p10–p90 of
    bench seed 0's stalk searches). Never below 1/TAIL_FLOOR of the 99th percentile: a soil flat in
    most of the window (clipped, or blurred) has a 90th percentile near 0, and its few textured pixels
    would all read as lines."""
    p99 = percentile(strength, 99)
    if TAIL_K > 0:
        p99 = max(min(p99, TAIL_K * percentile(strength, 90)), p99 / TAIL_FLOOR)
    return max(p99, 1e-6)


def _disc(size: float) -> np.ndarray:
    """The opening disc that leaves a plant's broad parts (HUB_OPEN × its size)."""
    r = max(1, int(round(HUB_OPEN * size)))
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def has_leaf_clusters(plant: np.ndarray) -> bool:
    """Whether a plant mask (any grid) is ≥ 2 separate leaf clusters (broad parts, each ≥ CLUSTER
    of its area): leaves on stalks. One blob or a tuft of blades has no stalks to find."""
    ys, xs = np.nonzero(plant)
    if len(xs) < 20:
        return False
    size = math.hypot(np.ptp(xs) + 1, np.ptp(ys) + 1)
    _, _, st, _ = components(cv2.morphologyEx(plant.astype(np.uint8), cv2.MORPH_OPEN, _disc(size)))
    return int(np.count_nonzero(st[1:, cv2.CC_STAT_AREA] >= CLUSTER * len(xs))) >= 2


BRIDGE_RATIO = 2.0  # the leaves on a lone stalk's centre side: ≥ this × those on its other side


def _bridge_end(bridges: list, lv: np.ndarray) -> tuple[np.ndarray | None, bool]:
    """Centre from one lone stalk running between two leaf clusters (no second stalk to meet):
    a stalk carries one leaf away from the centre, where the rest of the plant's leaves sit, so
    the centre is the end on whose side the leaves are (all clusters but the one at the other
    end: ≥ BRIDGE_RATIO × the other side's; a stalk may start under those leaves, so this is its
    visible end). Failing that, the end by how deep each lies in its cluster (`CARRIED_END`):
    (end, True). `bridges`: (end 0, end 1, length / width) of pieces whose both ends are near
    leaves; stalks between different pairs of clusters: None."""
    if not bridges:
        return None, False
    # each pixel's nearest leaf cluster (`lv`'s connected parts), and each cluster's area
    _, near = cv2.distanceTransformWithLabels(1 - lv, cv2.DIST_L2, 3, labelType=cv2.DIST_LABEL_CCOMP)
    area = np.bincount(near[lv > 0])
    ends = [(e0, e1, _at(near, e0), _at(near, e1), q) for e0, e1, q in bridges]
    ends = [b for b in ends if b[2] != b[3]]
    # (one stalk may come as several pieces: neighbouring direction bands, parallel strips)
    if not ends or len({frozenset((b[2], b[3])) for b in ends}) > 1:
        return None, False
    e0, e1, k0, k1, _ = max(ends, key=lambda b: b[4])  # the most line-like piece
    total = int(area.sum())
    side0, side1 = total - int(area[k1]), total - int(area[k0])
    if side0 >= BRIDGE_RATIO * side1:
        return e0, False
    if side1 >= BRIDGE_RATIO * side0:
        return e1, False
    if not CARRIED_END:
        return None, False
    # neither side holds most leaves: a stalk enters the leaf it carries at that leaf's middle
    # (a trefoil's hub), and only touches the other cluster's rim on its centre end
    ly, lx = np.nonzero(lv)
    lab = near[ly, lx]
    cx = np.bincount(lab, weights=lx, minlength=area.size) / np.maximum(area, 1)
    cy = np.bincount(lab, weights=ly, minlength=area.size) / np.maximum(area, 1)
    r0 = math.hypot(e0[0] - cx[k0], e0[1] - cy[k0]) / math.sqrt(area[k0] / math.pi)
    r1 = math.hypot(e1[0] - cx[k1], e1[1] - cy[k1]) / math.sqrt(area[k1] / math.pi)
    if r1 <= CARRIED_DEEP and r0 >= CARRIED_RATIO * r1:
        return e0, True
    if r0 <= CARRIED_DEEP and r1 >= CARRIED_RATIO * r0:
        return e1, True
    return None, False


CARRIED_END = True  # (session 73) when neither side holds most leaves, the end told by the leaf the stalk enters:
# the carried end lies ≤ CARRIED_DEEP equivalent radii from its cluster's centroid (a trefoil's petiole enters
# between its side leaflets, at the hub), the centre end ≥ CARRIED_RATIO × as far out in its own (it touches a
# leaflet's rim). Used only for compound leaves, after the finer stalk grid (`centre_cascade`). Bench seeds 0–11:
# clovers 23.9 → 4.4 and 4.9 → 3.7 mm, nothing else moved; seeds 30–33: a clover 36.8 → 13.1 mm (wrong 32 → 31)
CARRIED_RATIO = 1.5
CARRIED_DEEP = 0.9  # (two round leaves touched at their rims, both ends ≥ 1 radius out: no answer)


def _at(img: np.ndarray, e: np.ndarray):
    """`img` at the grid pixel nearest to point e (x, y), clamped to the grid."""
    h, w = img.shape
    return img[min(max(int(round(e[1])), 0), h - 1), min(max(int(round(e[0])), 0), w - 1)]


class StalkPoints(NamedTuple):
    """What `stalk_points` found (grid pixels; None: not found)."""
    meet: np.ndarray | None  # where ≥ 2 stalks meet
    lone: np.ndarray | None  # a lone stalk's centre end (only when no meeting)
    carried: bool = False  # that end told by the leaf the stalk enters (`CARRIED_END`), not by where the leaves are


NONE = StalkPoints(None, None, False)


def stalk_points(grey: np.ndarray, index: np.ndarray, leaves: np.ndarray, plant: np.ndarray) -> StalkPoints:
    """(where ≥ 2 stalks meet, the centre end of a lone stalk between two leaf clusters
    (`_bridge_end`, only when no meeting), whether that end was told by the leaf the stalk
    enters (`CARRIED_END`) rather than by where the leaves are), in grid pixels; None for
    either not found.

    grey: float grey image on the grid, reaching ~MARGIN × the plant's size round it; index:
    the vegetation index there (a green stalk on a soil of its brightness); leaves: every
    vegetation pixel there (bool); plant: the chosen plant's mask (bool), of ≥ 2 separate leaf
    clusters. A stalk is a straight piece of line off the leaves' broad parts (≥ MIN_LEN ×
    size, reaching ≥ AWAY from them) whose one end touches a leaf (within ATTACH); the centre
    lies at or beyond its other, free end (within REACH), within MAX_BARE of the plant and
    within the hull of the leaves (or anywhere there if ≥ FAN_STALKS orientations meet).
    """
    if not has_leaf_clusters(plant):
        return NONE
    ys, xs = np.nonzero(plant)
    size = math.hypot(np.ptp(xs) + 1, np.ptp(ys) + 1)
    disc = _disc(size)
    # the leaves a stalk may carry: the plant's, and vegetation within MARGIN × size of it
    # (leaves the plant's grouping left out); not a stone or a plant further off; their broad
    # parts (a stalk the index did segment is a thin part, and may be found as a line)
    near = cv2.distanceTransform((~plant).astype(np.uint8), cv2.DIST_L2, 3) <= MARGIN * size
    n, lab = cv2.connectedComponents(leaves.astype(np.uint8), connectivity=8)
    mine = np.unique(lab[near & leaves])
    lv = cv2.morphologyEx((np.isin(lab, mine[mine > 0]) | plant).astype(np.uint8), cv2.MORPH_OPEN, disc)
    off_leaf = cv2.distanceTransform(1 - lv, cv2.DIST_L2, 3)
    far = off_leaf > 0.25 * size  # soil: the reference for the line strengths
    if np.count_nonzero(far) < 50:
        return NONE
    # lines in the grey image and in the index, each in units of its own soil texture
    strength, idx, on, own = None, None, None, None
    for img in (grey, index):
        st_, id_, px = line_strength(img, SEG_LEN * size)
        st_ = st_ / _soil_ref(st_[far])
        px = px / max(percentile(px[far], 99), 1e-6)
        if strength is None:
            strength, idx, on, own = st_, id_, px > PX_K, px
        else:
            idx = np.where(st_ > strength, id_, idx)
            strength = np.maximum(strength, st_)
            on |= px > PX_K
            own = np.maximum(own, px)
    free = (off_leaf > 1.5).astype(np.uint8)  # off the leaves' broad parts
    on &= (strength > LINE_K) & (free > 0)
    segs = []
    bridges = []  # pieces with both ends near leaves: (end 0, end 1, length / width)
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    h, w = grey.shape
    L = max(5, int(round(SEG_LEN * size)) | 1)
    per_dir = np.bincount(idx[on], minlength=N_DIRS)
    for k in range(N_DIRS):  # pieces of one direction (± one step), so crossing stalks stay apart
        if per_dir[k] + per_dir[(k + 1) % N_DIRS] < MIN_LEN * size:
            continue  # too few pixels for one piece
        band = (on & ((idx == k) | (idx == (k + 1) % N_DIRS))).astype(np.uint8)
        bx0, by0, bw, bh = cv2.boundingRect(band)  # work in the band's box (+ the closing's reach)
        y0, x0 = max(by0 - L, 0), max(bx0 - L, 0)
        band = band[y0:by0 + bh + L, x0:bx0 + bw + L]
        # bridge short breaks along the direction (a stalk under a speck of soil or a leaf edge)
        th = math.pi * (k + 0.5) / N_DIRS
        ker = np.zeros((L, L), np.uint8)
        c0, dx, dy = L // 2, L // 2 * math.cos(th), L // 2 * math.sin(th)
        cv2.line(ker, (int(round(c0 - dx)), int(round(c0 - dy))), (int(round(c0 + dx)), int(round(c0 + dy))), 1, 1)
        band = cv2.morphologyEx(band, cv2.MORPH_CLOSE, ker) & free[y0:y0 + band.shape[0], x0:x0 + band.shape[1]]
        n, lab, stats, _ = components(band)
        for c in range(1, n):
            if stats[c, cv2.CC_STAT_AREA] < MIN_LEN * size:
                continue
            cl, ct, cw, ch = (int(v) for v in stats[c, :4])  # (its box: the same pixels, in the same order)
            yy, xx = np.nonzero(lab[ct:ct + ch, cl:cl + cw] == c)
            yy, xx = yy + (y0 + ct), xx + (x0 + cl)
            P = np.c_[xx, yy].astype(float)
            m = P.mean(0)
            ev, evec = np.linalg.eigh(np.cov((P - m).T) + 1e-9 * np.eye(2))
            d = evec[:, 1]
            t = (P - m) @ d
            Lp = float(t.max() - t.min()) + 1
            # its width: the spread across it of its own line strength, which peaks on the line
            # (the band is as wide as the agreeing strength's smoothing: a strong stalk's band
            # is wide, or splits into parallel strips)
            wgt = own[yy, xx] + 1e-6
            across = (P - m) @ evec[:, 0]
            mu = float(np.average(across, weights=wgt))
            wdt = math.sqrt(12 * float(np.average((across - mu) ** 2, weights=wgt))) + 0.5
            if Lp < MIN_LEN * size or Lp < 4 * wdt:
                continue
            if float(off_leaf[yy, xx].max()) < AWAY * size + 2:
                continue  # it runs along a leaf's edge (a leaflet's rim), not away from it
            e0, e1 = m + d * t.min(), m + d * t.max()
            if any(np.linalg.norm(e0 - a) < 2 and np.linalg.norm(e1 - b) < 2 for a, b in seen):
                continue  # the same piece from the neighbouring direction band
            seen.append((e0, e1))
            d0, d1 = float(_at(off_leaf, e0)), float(_at(off_leaf, e1))
            if max(d0, d1) <= max(ATTACH * size, 2.0):
                bridges.append((e0, e1, Lp / wdt))
            # oriented from the leaf it carries towards its free end (the centre's side)
            for leaf_end, free_end, dl in ((e0, e1, d0), (e1, e0, d1)):
                if dl <= max(ATTACH * size, 2.0):
                    u = (free_end - leaf_end) / max(np.linalg.norm(free_end - leaf_end), 1e-9)
                    segs.append(((leaf_end + free_end) / 2, u, Lp / 2, Lp))
    X = meeting_point(segs, max(1.5, TOL * size), REACH * size, directed=True) if len(segs) >= 2 else None
    lone, carried = _bridge_end(bridges, lv) if X is None else (None, False)
    if X is None and lone is None:
        return NONE  # (most calls: no plausibility maps needed)
    off_plant = cv2.distanceTransform((~plant).astype(np.uint8), cv2.DIST_L2, 3)
    ly, lx = np.nonzero(lv)
    hull = cv2.convexHull(np.c_[lx, ly].astype(np.float32))

    def plausible(P: np.ndarray | None, fan: bool = False) -> np.ndarray | None:
        if P is None or not (0 <= P[0] < w and 0 <= P[1] < h):
            return None
        if off_plant[int(P[1]), int(P[0])] > MAX_BARE * size:
            return None
        # leaves sit round their centre: it lies within the hull of the leaves (the plant's and
        # those its stalks carry), not out where straw or a stone edge crosses a stalk ... unless
        # a fan of stalks meets there (a leaf the index missed would have closed the hull)
        if cv2.pointPolygonTest(hull, (float(P[0]), float(P[1])), True) < -HULL_TOL * size and not fan:
            return None
        return P

    fan = X is not None and _directions(segs, X, max(1.5, TOL * size), REACH * size) >= FAN_STALKS
    return StalkPoints(plausible(X, fan), plausible(lone), carried)


FAN_STALKS = 3  # stalks of ≥ this many orientations (≥ FAN_APART apart) meeting at one point: a centre even
FAN_APART = math.radians(20)  # outside the leaves' hull (straw crossing a stalk gives two)


def _directions(segs: list, X: np.ndarray, tol: float, reach: float) -> int:
    """How many distinct line orientations (≥ FAN_APART apart, modulo π: a piece between two leaves
    comes in `segs` both ways) the pieces that `meeting_point(directed=True)` counts at X have."""
    angles: list[float] = []
    for _, d, _, _ in supporting(segs, X, tol, reach, directed=True):
        a = math.atan2(d[1], d[0]) % math.pi
        if all(min(abs(a - b), math.pi - abs(a - b)) >= FAN_APART for b in angles):
            angles.append(a)
    return len(angles)
