"""The tree median: where a plant's leaves emerge, as the point of least Σ geodesic distance
(along the plant, `capm_field.geodesic`) to its leaf tips, less the leaf-axis votes
(`capm_field.axis_votes`) where the parts are thin and the votes pile up at one point. The
stage-2 cascade's last estimator (`capm_field.centre_cascade`), for plants of blades and narrow
leaves and round plants no other estimator answered. Coordinates are (x, y) pixels of the plant's
grid (see `capm_field.plant_centre`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .axis_votes import THIN_BLADE, THIN_ROUND, axis_votes
from .geodesic import crossing_cost, distances, geodesic_tips, grid_graph

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


def vote_scale(roundness: float) -> float:
    """Leaf-axis vote scale (× the plant's size) for leaves of mean half-width `roundness` × size:
    AXIS_K × that half-width, within 0.015–AXIS_MAX."""
    return float(np.clip(AXIS_K * roundness, 0.015, AXIS_MAX))


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
    G, node = grid_graph(crossing_cost(plant, size))
    # provisional centre: deepest point of the mask (overlapping leaves are thickest at the centre)
    dt = cv2.distanceTransform(plant.astype(np.uint8), cv2.DIST_L2, 5)
    c0 = np.unravel_index(int(np.argmax(dt)), dt.shape)
    tips: np.ndarray = np.zeros(0, int)
    centre_node = node[c0]
    prev: set = set()
    rows: dict[int, np.ndarray] = {}  # geodesic distances from each tip: the second pass finds mostly the same tips
    for _ in range(TM_ITER):
        g0 = distances(G, [centre_node])[0]
        tips = geodesic_tips(g0, node, plant, size)
        if len(tips) == 0 or set(tips.tolist()) == prev:
            break  # same tips from the new centre: F, and so the minimum, would not change
        prev = set(tips.tolist())
        new = [t for t in tips.tolist() if t not in rows]
        if new:  # each source's row is computed on its own: the same as in a call with all tips
            rows.update(zip(new, distances(G, new)))
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
            rows[far] = distances(G, [far])[0]
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
    ring = (np.hypot(gx - ix, gy - iy) >= 2) & np.isfinite(win)
    rise = float(win[ring].min()) - fmin if ring.any() else 0.0  # none finite there: not sharp
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
