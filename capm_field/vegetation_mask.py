"""Stage 1's vegetation mask: the soil threshold of an index image, hysteresis, and grouping
components into plants (`capm_field.detector` uses them on the search window, and
`capm_field.centre_cascade` on the plant crop)."""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy import ndimage

from .order_stats import median, percentile

def threshold(v: np.ndarray) -> tuple[float, float, float]:
    """(threshold, soil level, contrast) of the index over the search window.

    Soil is the bulk of the pixels; its spread σ is measured from the median to the 90th
    percentile (plants rarely fill a tenth of a TROI view; the lower side, or the smaller of the
    two, measured worse on bench seeds 0–3: more wrong centres). When a plant does fill ≥ a
    tenth of the window (a close-up, a photo without a ROI: the 90th percentile lands on
    leaves), the soil is the lower class of an Otsu split whose upper class is green and
    ≥ BIG_SEP σ above it (dull rosettes covering 11–15 % of a frame: 13 of 30 "no_plant" → 4;
    bench seeds 0–3: two frames of 1200 moved by ≤ 0.3 mm). Vegetation must stand
    5 σ above the soil level, with the threshold kept within G* ∈ [0, 0.10] (the old floor 0.02
    lost olive grass and yellow-green seedlings; the per-candidate colour rule `plant_like`
    now keeps bare soil empty).
    """
    v = v.ravel()
    lo, med, p90, hi = percentile(v, (0.5, 50, 90, 99.5))  # one partition
    sig = max((p90 - med) / 1.28, 0.004)
    if p90 > med:
        # a plant filling ≥ a tenth of the window (a close-up, a photo without a ROI) puts the
        # 90th percentile, or the median, on leaves: then the soil is the lower class of a
        # two-class (Otsu) split of the index, when the upper one is green and far above it
        if hi > lo:
            q = np.clip((v - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)
            t, _ = cv2.threshold(q.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
            t = lo + t * (hi - lo) / 255.0
            n_low = int(np.count_nonzero(v <= t))
            frac = 1.0 - n_low / len(v)
            up = v[v > t] if frac >= BIG_PLANT and n_low > 100 else v[:0]
            # (the upper class's median is > 0 only if at least half of it is; on most frames
            # Otsu splits a mottled soil and the upper class is soil, G* < 0: no percentiles then)
            if len(up) and 2 * np.count_nonzero(up > 0) >= len(up):
                m_l, p_l = percentile(v[v <= t], (50, 90))
                s_l = max((p_l - m_l) / 1.28, 0.004)
                m_u = median(up)
                if m_u > 0 and m_u - m_l >= BIG_SEP * s_l:
                    med, sig = m_l, s_l
    thr = float(np.clip(med + THR_SIGMAS * sig, THR_FLOOR, 0.10))
    above = v[v > thr]
    contrast = float(np.float32(median(above)) - med) if len(above) else 0.0  # (float32, as np.median's was)
    return thr, med, contrast


BIG_PLANT, BIG_SEP = 0.1, 8.0  # upper Otsu class share, and its median over the lower's in the lower's σ
THR_FLOOR = 0.0  # G* > 0: green above both red and blue; soil/stone/straw are rejected per candidate
THR_SIGMAS = 5.0


def hysteresis(vi: np.ndarray, thr: float, soil: float, inside: np.ndarray) -> np.ndarray:
    """Pixels halfway from soil to thr connected to a pixel above thr (keeps stems, leaf margins)."""
    strong = (vi > thr) & inside
    strong = cv2.morphologyEx(strong.astype(np.uint8), cv2.MORPH_OPEN, np.ones((2, 2), np.uint8)).astype(bool)
    weak = (vi > 0.5 * (thr + max(soil, 0.0))) & inside
    n, lab = cv2.connectedComponents(weak.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[lab[strong]] = True  # (repeated labels set the same flag: no need to sort them out)
    keep[0] = False
    return np.take(keep, lab)  # = keep[lab], ~2× faster than fancy indexing


GROUP_GAP = 0.35  # × the group's diameter: largest gap a component may be joined across


def group_box(stats: np.ndarray, g: list[int]) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1), x1 and y1 exclusive: the union of the boxes of components `g` (rows of
    OpenCV's component `stats`), which holds every pixel of the group."""
    x0, y0 = int(stats[g, cv2.CC_STAT_LEFT].min()), int(stats[g, cv2.CC_STAT_TOP].min())
    x1 = int((stats[g, cv2.CC_STAT_LEFT] + stats[g, cv2.CC_STAT_WIDTH]).max())
    y1 = int((stats[g, cv2.CC_STAT_TOP] + stats[g, cv2.CC_STAT_HEIGHT]).max())
    return x0, y0, x1, y1


def group_components(lab: np.ndarray, stats: np.ndarray, comps: list[int]) -> list[list[int]]:
    """Join components separated by a gap smaller than GROUP_GAP × the larger one's diameter.

    Largest first: a group grows by every smaller component whose nearest pixel is within
    GROUP_GAP × the group's diameter (distance transform of the group, minimum per label).
    """
    comps = sorted(comps, key=lambda k: -stats[k, cv2.CC_STAT_AREA])
    if not comps:
        return []
    groups: list[list[int]] = []
    # the candidate test on arrays in `comps` order (a Python loop over all components per group
    # step was quadratic: ~2 800 specks of a regular dot grid took 3–6 s a frame)
    ids = np.asarray(comps)
    area = stats[ids, cv2.CC_STAT_AREA]
    left, top = stats[ids, cv2.CC_STAT_LEFT], stats[ids, cv2.CC_STAT_TOP]
    right, bottom = left + stats[ids, cv2.CC_STAT_WIDTH], top + stats[ids, cv2.CC_STAT_HEIGHT]
    free = np.ones(len(ids), bool)  # not yet in a group
    for i, k in enumerate(comps):
        if not free[i]:
            continue
        g = [k]
        free[i] = False
        while True:
            # the group's pixel extent is the union of its components' boxes (no mask needed)
            gx0, gy0, gx1, gy1 = group_box(stats, g)  # (gx1, gy1 exclusive)
            diam = math.hypot(gx1 - gx0, gy1 - gy0)
            # only components whose box comes within reach can join: crop to that window
            r = int(math.ceil(GROUP_GAP * diam)) + 1
            y0, y1 = max(gy0 - r, 0), min(gy1 + r, lab.shape[0])
            x0, x1 = max(gx0 - r, 0), min(gx1 + r, lab.shape[1])
            sel = np.flatnonzero(free & (area <= area[i]) & (left < x1) & (right > x0) & (top < y1) & (bottom > y0))
            if not len(sel):
                break
            cand = [comps[j] for j in sel]
            sub = lab[y0:y1, x0:x1]
            dist = cv2.distanceTransform((~np.isin(sub, g)).astype(np.uint8), cv2.DIST_L2, 3)
            dmin = np.atleast_1d(ndimage.minimum(dist, sub, cand))
            near = sel[np.isfinite(dmin) & (dmin < GROUP_GAP * diam)]
            if not len(near):
                break
            g += [comps[j] for j in near]
            free[near] = False
        groups.append(g)
    return groups
