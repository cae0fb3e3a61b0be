"""The apex of a fan-shaped plant (a grass tuft leaning one way): the peak of its leaf-axis
votes (`capm_field.axis_votes`), accepted only when the plant, seen from there, is a fan of
straight blades. First estimator of the stage-2 cascade for thin plants (`capm_field.centre_cascade`).
Coordinates are (x, y) pixels of the plant's grid (see `capm_field.plant_centre`).
"""

from __future__ import annotations

import cv2
import numpy as np

from .geodesic import crossing_cost, distances, geodesic_tips, grid_graph

FAN_PIX_GAP = 2.88  # rad: the plant's pixels beyond 0.15 of its size, seen from the apex, leave an empty sector
# at least this wide (≈ 165°: the cheap first test) ...
FAN_PIX_GAP_ONE = 2.08  # ... or this (≈ 119°) for thin blades (roundness < FAN_BLADE_ROUND) whose leaf axes meet
FAN_BLADE_ROUND = 0.031  # at one point (one `vote_peaks` peak: not a clover's several trefoil hubs) ...
FAN_GAP = 2.6  # ... and its far geodesic tips one of at least this (≈ 149°; the tips lie among those pixels, so
# after FAN_PIX_GAP this one rarely decides; after FAN_PIX_GAP_ONE it does: such fans' tips span ≤ ~211°).
# Until session 42: 3.6 for the tips and 0.8 × that for the pixels, for every plant. Grass tufts whose tips
# span 155–211° then went to the estimators for round plants, which land mid-tuft. Bench seeds 0–7: wrong 41 → 38;
# 37 answers better by > 1 mm, 14 worse; by > 5 mm 12 better (30.8 → 5.3, 61.5 → 29.0, 48.9 → 2.2, 27.7 → 7.8,
# 16.9 → 0.9 mm), 3 worse (3.2 → 8.7, 7.0 → 20.2, 4.1 → 13.4 mm). Field-photo seeds 0–5 (with and without a
# ROI): one answer 0.19 → 0.10 S, one 0.03 → 0.13 S, the rest within 0.02 S. The looser pixel test for every
# plant (not only one-peak blades) took a clover with stalks off `stalk_centre` (0.6 → 38.5 mm, 2 peaks) and
# rosettes of roundness 0.035 off the tree median (2.8 → 33.4, 10.5 → 64.9 mm)
FAN_STRAIGHT = 1.15  # Σ geodesic / Σ straight-line distance from the apex to the far tips
FAN_MIN_TIPS = 2  # far tips (beyond 0.15 of the size from the apex) ...
WIDE_FAN_TIPS = 3  # ... for round plants, tried late in the cascade (`centre_cascade.WIDE_FAN_ROUND`): two far
# tips are two leaves, not a fan (session 24: with two, only seedlings moved, all worse)
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


def fan_apex(plant: np.ndarray, votes: np.ndarray, size: float, n_peaks: int, roundness: float = 1.0,
             min_tips: int = FAN_MIN_TIPS) -> np.ndarray | None:
    """Apex of a fan-shaped plant (a grass tuft leaning one way), or None if it is not one.

    The blades of a fan run straight from their common base to tips that all lie on one side,
    so the tree median (Σ distance to the tips) slides along the blades towards the tips, and
    so does any middle of the mask; the blade axes still converge at the base, the peak of
    `axis_votes`. Accepted only when, seen from that peak, the far tips leave an empty sector
    ≥ FAN_GAP and its pixels one ≥ FAN_PIX_GAP (FAN_PIX_GAP_ONE for thin blades of one vote peak:
    `roundness`, the cascade's mean half-width / size), the plant's paths to them are straight (a peak
    on the end of one long blade reaches the other tips round a bend), and the votes have ≤ FAN_MAX_PEAKS peaks
    (`n_peaks`, from `vote_peaks`) or the whole plant lies in a sector the narrower the more
    peaks there are (leaves converging at several points: trefoil hubs, rosette leaves).
    `min_tips`: how many far tips (beyond 0.15 of the size) it needs.
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
    one_fan = n_peaks <= 1 and roundness < FAN_BLADE_ROUND  # thin blades whose axes meet at one point
    if pix_gap < (FAN_PIX_GAP_ONE if one_fan else FAN_PIX_GAP) or (n_peaks > FAN_MAX_PEAKS and pix_gap < FAN_CLEAR_GAP) \
            or (n_peaks >= FAN_DENSE_PEAKS and pix_gap < FAN_DENSE_GAP):
        return None
    G, node = grid_graph(crossing_cost(plant, size, bridge=False))
    # paths start from the plant pixel nearest the peak (the apex may lie just off the mask,
    # and a start in the gap band would count its crossing cost on every path)
    k = int(np.argmin(dx * dx + dy * dy))
    src = np.array([px[k], py[k]], float)
    g0 = distances(G, [node[py[k], px[k]]])[0]
    tips = geodesic_tips(g0, node, plant, size)
    if len(tips) == 0:
        return None
    d = np.argwhere(node >= 0)[tips][:, ::-1] - src
    r = np.hypot(d[:, 0], d[:, 1])
    far = r > 0.15 * size
    if far.sum() < min_tips:
        return None
    ang = np.sort(np.arctan2(d[far, 1], d[far, 0]))
    gap = float(np.max(np.diff(np.r_[ang, ang[0] + 2 * np.pi])))
    straight = float(g0[tips[far]].sum() / r[far].sum())
    if gap < FAN_GAP or not straight <= FAN_STRAIGHT:
        return None
    return p
